"""The closed loop in the simulator: frames rendered from the true state, the vehicle steered by the estimate.

The acceptance test of issue 16 (a short survey, then 5 points over 1 m x 1 m) runs the slam mission
of about 1,900 frames (about 40 s of CPU). The requirement that dead reckoning steers at least 3 times
farther from the points than slam is measured on the hard preset after a 5-minute survey, 3 seeds
(marked slow: 6 missions of 2,700 to 4,000 frames); a short mission of both runs in the default suite.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from rovslam.core import Goal
from rovslam.io.sequence import open_sequence
from rovslam.navigate import navigate
from rovslam.sim import SCENARIOS, simulate
from rovslam.sim.live import LiveSimulator, TrueState
from rovslam.sim.scenarios import frame_pose
from rovslam.sim.vehicle import simulate_trajectory

CORNERS_AND_CENTRE = [("ne", 0.5, 0.5), ("nw", 0.5, -0.5), ("sw", -0.5, -0.5), ("se", -0.5, 0.5), ("centre", 0.0, 0.0)]
# The requirement: steered by dead reckoning, the vehicle arrives at least 3 times farther from the points
# (mean true arrival error) than steered by slam.
REQUIRED_DR_OVER_SLAM = 3.0


def rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _mission(tmp_path_factory, estimator: str):
    """portofino, seed 1: a 120 s survey, then the 4 corners and the centre of a 1 m square, 5 s holds."""
    base = tmp_path_factory.mktemp("nav")
    pois = [Goal(n, np.array([x, y])) for n, x, y in CORNERS_AND_CENTRE]
    return navigate(
        "portofino", pois, base / estimator, estimator, survey_s=120.0, hold_s=5.0, seed=1
    ), base / estimator


@pytest.fixture(scope="module")
def acceptance(tmp_path_factory):
    """The mission steered by slam (about 50 s of CPU)."""
    return {"slam": _mission(tmp_path_factory, "slam")}


def test_slam_reaches_every_point_within_2_cm_of_the_truth(acceptance):
    summary, _ = acceptance["slam"]
    assert summary.status == "complete" and len(summary.arrivals) == 5
    errs = [r["true_err_m"] for r in summary.arrivals]
    assert all(r["reached"] == 1 for r in summary.arrivals)
    # Measured (this mission, summary.arrivals): true arrival errors 1.9, 1.8, 6.2, 2.8, 4.1 mm (mean 3.4 mm),
    # hold RMS 2.7 to 8.6 mm. The issue asks for 2 cm; the bounds are 2.4 and 2.3 times the measured worst,
    # and the mean above a third of its figure (steering by the truth would arrive about 0 mm off).
    assert max(errs) < 0.015, errs
    assert np.mean(errs) > 0.001, errs
    assert all(r["hold_rms_true_m"] < 0.02 for r in summary.arrivals)
    # the controller stopped on its estimate: within the arrival radius of the point
    assert all(r["est_err_m"] <= 0.005 for r in summary.arrivals)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_dead_reckoning_arrives_at_least_3_times_farther_from_the_points(tmp_path, seed):
    """``portofino-relief`` (the paper's camera and site over 12 cm of relief, lamps): a 300 s survey,
    then the 4 corners and the centre of the 1 m square, 5 s holds, steered by slam and then by dead
    reckoning; the mean true arrival error of the two against the requirement, per seed.

    Measured (these missions; ``navigate`` then ``summary.arrivals``), slam / dead reckoning:
    seed 1 3.32 / 44.54 mm (13.4 times), seed 2 2.55 / 34.72 mm (13.6), seed 3 4.38 / 16.77 mm (3.83);
    every point reached. About 150 to 190 s of CPU a seed (2,700 to 4,000 frames a mission).
    On the acceptance mission above (``portofino``, 120 s survey, seed 1) the ratio is 2.20
    (3.37 / 7.41 mm): after 2 minutes dead reckoning has not drifted enough for the comparison
    to measure anything but the arrival noise, so the requirement is measured here.
    """
    pois = [Goal(n, np.array([x, y])) for n, x, y in CORNERS_AND_CENTRE]
    mean_err = {}
    for estimator in ("slam", "dead-reckoning"):
        s = navigate(
            "portofino-relief", pois, tmp_path / estimator, estimator, survey_s=300.0, hold_s=5.0, seed=seed, plot=False
        )
        assert s.status == "complete" and all(r["reached"] == 1 for r in s.arrivals)
        mean_err[estimator] = float(np.mean([r["true_err_m"] for r in s.arrivals]))
    assert mean_err["dead-reckoning"] >= REQUIRED_DR_OVER_SLAM * mean_err["slam"], mean_err


def test_a_larger_approach_gain_arrives_sooner_on_a_rough_sea(tmp_path):
    """``rovslam navigate --approach-gain-per-s 0.3`` against the default: ``rough-turns`` seed 2 (2 cm/s of
    current under a swell), no survey, one point 42 cm away, 1 s hold.

    Measured (arrival times from ``arrivals.csv``): 39.0 s at 0.3 /s against 66.2 s at the default 0.2 /s,
    2.7 and 5.3 mm from the point. The default's vehicle hovers 1 to 2 cm off until its estimate has
    stayed within the 5 mm radius for 2 s (docs/navigation.md, "The approach gain").
    """
    from typer.testing import CliRunner

    from rovslam.cli import app

    poi = tmp_path / "poi.csv"
    poi.write_text("name,x_m,y_m\nrock,0.3,0.3\n", encoding="utf-8")
    res = CliRunner().invoke(
        app,
        ["navigate", "--scenario", "rough-turns", "--poi", str(poi), "--out", str(tmp_path / "fast"), "--hold-s", "1"]
        + ["--seed", "2", "--approach-gain-per-s", "0.3", "--quiet"],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "fast" / "summary.json").read_text(encoding="utf-8"))
    assert summary["guidance"]["approach_gain_per_s"] == 0.3
    with open(tmp_path / "fast" / "arrivals.csv", encoding="utf-8") as fh:
        fast = next(csv.DictReader(fh))
    slow = navigate(
        "rough-turns",
        [Goal("rock", np.array([0.3, 0.3]))],
        tmp_path / "default",
        "slam",
        hold_s=1.0,
        seed=2,
        plot=False,
    )
    default = json.loads((tmp_path / "default" / "summary.json").read_text(encoding="utf-8"))
    assert default["guidance"]["approach_gain_per_s"] == 0.2
    assert fast["reached"] == "1" and slow.arrivals[0]["reached"] == 1
    assert float(fast["arrival_t_s"]) < 0.8 * float(slow.arrivals[0]["arrival_t_s"]), (fast, slow.arrivals)
    assert float(fast["true_err_m"]) < 0.015 and float(slow.arrivals[0]["true_err_m"]) < 0.015


def test_the_approach_gain_options_state_the_default():
    """The help of ``--approach-gain-per-s`` (navigate, live) gives :class:`GuidanceConfig`'s default."""
    import typer

    from rovslam.cli import app
    from rovslam.nav.guidance import GuidanceConfig

    default = f"default {GuidanceConfig().approach_gain_per_s:g};"
    commands = typer.main.get_command(app).commands  # type: ignore[attr-defined]
    for name in ("navigate", "live"):
        (param,) = [p for p in commands[name].params if "--approach-gain-per-s" in p.opts]
        assert default in param.help and param.default is None, (name, param.help)


def test_a_short_mission_steered_by_dead_reckoning_arrives_farther(tmp_path):
    """The fast version of the slow comparison above: ``portofino`` seed 1, a 40 s survey, then one
    point (the square's north-east corner), 2 s hold; steered by slam, then by dead reckoning.

    Measured (these two missions, mean true arrival error from ``summary.arrivals``): slam 2.92 mm
    (411 frames), dead reckoning 9.40 mm (346 frames), 3.2 times. Bounds: slam under 2.5 times its
    figure, dead reckoning above its figure / 2.5, the ratio above half its figure. This short
    mission is not where the 3x requirement is measured: on seeds 2 and 3 (two points) the ratio
    was 1.35 and 1.11, dead reckoning having drifted little in 40 s; the slow test measures it.
    """
    pois = [Goal("ne", np.array([0.5, 0.5]))]
    errs = {}
    for estimator in ("slam", "dead-reckoning"):
        s = navigate("portofino", pois, tmp_path / estimator, estimator, survey_s=40.0, hold_s=2.0, seed=1, plot=False)
        assert s.status == "complete" and [r["reached"] for r in s.arrivals] == [1]
        errs[estimator] = float(s.arrivals[0]["true_err_m"])
    assert errs["slam"] < 0.0073, errs
    assert errs["dead-reckoning"] > 0.0038, errs
    assert errs["dead-reckoning"] > 1.6 * errs["slam"], errs


def test_the_mission_writes_the_usual_results_and_its_own(acceptance):
    summary, out = acceptance["slam"]
    arr = rows(out / "arrivals.csv")
    with open(out / "arrivals.csv") as fh:
        header = fh.readline().strip().split(",")
    assert header[:7] == ["name", "x_m", "y_m", "arrival_t_s", "est_err_m", "true_err_m", "hold_rms_true_m"]
    assert [r["name"] for r in arr] == [n for n, _, _ in CORNERS_AND_CENTRE]
    assert [float(r["true_err_m"]) for r in arr] == pytest.approx([r["true_err_m"] for r in summary.arrivals], rel=1e-8)
    traj = rows(out / "trajectory.csv")
    truth = rows(out / "groundtruth.csv")
    nav = rows(out / "navigation.csv")
    assert len(traj) == len(truth) == len(nav) == summary.frames
    assert "dr_x_m" in traj[0] and float(truth[0]["x_m"]) == 0.0 and float(truth[0]["y_m"]) == 0.0
    # arrival error from the files: the truth at the arrival time against the point
    t_arr = float(arr[0]["arrival_t_s"])
    k = next(i for i, r in enumerate(truth) if abs(float(r["t_s"]) - t_arr) < 1e-6)
    d = math.hypot(float(truth[k]["x_m"]) - 0.5, float(truth[k]["y_m"]) - 0.5)
    assert d == pytest.approx(float(arr[0]["true_err_m"]), abs=1e-8)
    assert (out / "navigation.png").stat().st_size > 10_000
    s = json.loads((out / "summary.json").read_text())
    # frame 600 (t = 120 s) ends the survey: its command is the first towards a point, frame 601 the first flown so
    assert s["status"] == "complete" and s["estimator"] == "slam" and s["navigation_start_frame"] == 601
    assert len(rows(out / "landmarks.csv")) == summary.landmarks > 10
    # the sunlight watch and the speed error as `rovslam run` reports them (no caustics on this preset)
    assert s["sunlight"]["frames_removed"] == 0 and s["sunlight"]["changes"] == []
    assert s["speed_bias"]["frames"] == 0


def test_ctrl_c_keeps_what_is_written(tmp_path):
    def stop(step, _done):
        if step.k == 29:
            raise KeyboardInterrupt

    s = navigate("portofino", [Goal("a", np.array([0.3, 0.0]))], tmp_path / "o", on_step=stop, seed=2)
    assert s.status == "interrupted" and s.frames == 30 and s.exit_code == 130
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["interrupted"] and summary["signal"] == "SIGINT" and summary["frames_processed"] == 30
    assert len(rows(tmp_path / "o" / "trajectory.csv")) == 30 == len(rows(tmp_path / "o" / "navigation.csv"))
    assert rows(tmp_path / "o" / "arrivals.csv") == []


def test_back_to_landmark_0_after_a_short_survey(tmp_path):
    pois = [Goal("away", np.array([0.25, 0.2]), hold_s=1.0), Goal("landmark 0", None, landmark_id=0, hold_s=2.0)]
    s = navigate("portofino", pois, tmp_path / "o", survey_s=20.0, seed=3)
    assert s.status == "complete"
    back = s.arrivals[1]
    assert back["reached"] == 1 and back["landmark_id"] == 0
    lm0 = rows(tmp_path / "o" / "landmarks.csv")[0]
    # the point is the landmark's map position (at the arrival; the map moves little after it)
    assert (back["x_m"], back["y_m"]) == pytest.approx((float(lm0["x_m"]), float(lm0["y_m"])), abs=2e-3)
    assert back["true_err_m"] < 0.01  # measured 4.4 mm (this mission, summary.arrivals): 2.3 times under the bound


def test_a_live_frame_is_the_frame_simulate_writes_for_the_same_pose(tmp_path):
    """The closed loop sees exactly the simulator's images (relief, lamps, noise by frame index)."""
    sc = SCENARIOS["portofino-relief"]
    simulate("portofino-relief", tmp_path / "seq", frames=3, seed=4)
    written = list(open_sequence(tmp_path / "seq").frames())
    traj = simulate_trajectory(sc.vehicle, sc.grid, 3, sc.frame_rate_hz, 4)
    live = LiveSimulator("portofino-relief", 4, area_m=(-1.0, 1.0, -1.0, 1.0))
    for k in (0, 2):
        p = frame_pose(traj, k)
        state = TrueState(
            float(traj.t_s[k]),
            p.x_m,
            p.y_m,
            p.altitude_m,
            p.heading_rad,
            p.roll_rad,
            p.pitch_rad,
            float(traj.surge_mps[k]),
            float(traj.sway_mps[k]),
        )
        np.testing.assert_array_equal(live.render(k, state), written[k].image)
    frame = live.capture(2, state)
    assert frame.index == 2 and frame.sonar_altitude_m == pytest.approx(state.altitude_m, abs=0.2)
    assert abs(frame.heading_rad - state.heading_rad) < math.radians(3)
