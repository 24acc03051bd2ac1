"""Evaluation maths on hand-made trajectories with known answers."""

import numpy as np
import pytest

from rovslam.errors import SequenceFormatError
from rovslam.eval.align import align_by_time
from rovslam.eval.metrics import consistency, nees, trajectory_errors


def test_ate_of_a_constant_offset():
    gt = np.column_stack([np.linspace(0, 3, 301), np.zeros(301)])
    est = gt + np.array([0.03, -0.04])  # 5 cm everywhere
    e = trajectory_errors(est, gt, segment_m=1.0)
    assert e.ate_rmse_m == pytest.approx(0.05)
    assert e.ate_max_m == pytest.approx(0.05)
    assert e.final_error_m == pytest.approx(0.05)
    assert e.distance_m == pytest.approx(3.0)
    assert e.relative_error_m_per_m == pytest.approx(0.0, abs=1e-12)  # no drift, only an offset


def test_relative_error_of_a_scale_error():
    gt = np.column_stack([np.linspace(0, 3, 301), np.zeros(301)])
    est = gt * 1.02  # 2 % scale error: 2 cm per metre
    e = trajectory_errors(est, gt, segment_m=1.0)
    assert e.relative_error_m_per_m == pytest.approx(0.02, rel=1e-6)
    assert e.relative_error_pct == pytest.approx(2.0, rel=1e-6)
    assert e.final_error_pct == pytest.approx(2.0, rel=1e-6)


def test_consistency_of_a_matched_gaussian():
    rng = np.random.default_rng(7)
    cov = np.array([[4e-4, 1e-4], [1e-4, 1e-4]])
    err = rng.multivariate_normal([0, 0], cov, size=20000)
    c = consistency(err, np.broadcast_to(cov, (20000, 2, 2)))
    assert c.nees_mean == pytest.approx(2.0, rel=0.05)
    assert c.coverage_2sigma == pytest.approx(1 - np.exp(-2.0), abs=0.01)  # 86.5 % in 2-D
    assert c.nees_in_95_interval == pytest.approx(0.95, abs=0.01)


def test_nees_of_an_overconfident_filter_is_large():
    err = np.full((10, 2), 0.01)
    assert np.all(nees(err, np.broadcast_to(np.eye(2) * 1e-6, (10, 2, 2))) > 100)


def test_align_by_time_rejects_foreign_ground_truth():
    t = np.arange(10) * 0.2
    np.testing.assert_array_equal(align_by_time(t[2:5], t), [2, 3, 4])
    with pytest.raises(SequenceFormatError, match="no row at t_s"):
        align_by_time(np.array([0.1]), t)


# --------------------------------------------------------------------------- error jumps, typed result


def test_error_jump_is_the_step_of_the_error_in_sigmas_of_the_ellipse():
    from rovslam.eval.metrics import error_jump_sigma

    n = 20
    cov = np.broadcast_to(np.diag([1e-4, 4e-4]), (n, 2, 2))  # sigma 1 cm in x, 2 cm in y
    err = np.zeros((n, 2))
    err[5:, 0] = 0.03  # the error jumps by 3 cm in x at frame 5: 3 sigma
    err[12:, 1] = 0.01  # then by 1 cm in y at frame 12: 0.5 sigma
    j = error_jump_sigma(err, cov)
    assert j.shape == (n - 1,)
    assert j[4] == pytest.approx(3.0) and j[11] == pytest.approx(0.5)
    assert np.count_nonzero(j) == 2
    c = consistency(err, cov, t_s=np.arange(n) * 0.2)
    assert c.max_error_jump_sigma == pytest.approx(3.0)
    assert c.max_error_jump_t_s == pytest.approx(1.0)  # frame 5, the frame after the jump


def test_consistency_of_one_frame_has_no_jump():
    c = consistency(np.zeros((1, 2)), np.zeros((1, 2, 2)))
    assert c.max_error_jump_sigma is None and c.max_error_jump_t_s is None
    assert c.max_error_jump_before_sigma is None and c.max_error_jump_before_t_s is None


def test_a_correction_inside_the_ellipse_before_is_no_jump_before_but_is_after():
    """A landmark seen again removes a 0.8-sigma error while the ellipse shrinks from 10 mm to 2 mm."""
    from rovslam.eval.metrics import error_jump_before_sigma, error_jump_sigma

    cov = np.array([np.eye(2) * 0.010**2, np.eye(2) * 0.002**2])
    err = np.array([[0.008, 0.0], [0.0, 0.0]])
    assert error_jump_sigma(err, cov)[0] == pytest.approx(4.0)  # 8 mm in sigmas of 2 mm
    assert error_jump_before_sigma(err, cov)[0] == pytest.approx(0.8)  # in sigmas of 10 mm


def test_a_pull_to_a_wrong_place_is_a_jump_before_as_after():
    """A wrong match moves the estimate by 4 cm in x while the ellipse (1 cm) shrinks a little in y."""
    from rovslam.eval.metrics import error_jump_before_sigma, error_jump_sigma

    cov = np.array([np.eye(2) * 1e-4, np.diag([1e-4, 0.5e-4])])
    err = np.array([[0.0, 0.0], [0.04, 0.0]])
    assert error_jump_before_sigma(err, cov)[0] == pytest.approx(4.0)
    assert error_jump_sigma(err, cov)[0] == pytest.approx(4.0)


def test_the_jump_before_takes_the_larger_ellipse_axis_by_axis():
    """From a known start (P = 0) the first step is judged against the ellipse it grew to; a covariance
    that grows along x and shrinks along y is judged against the after-ellipse in x, the before in y."""
    from rovslam.eval.metrics import error_jump_before_sigma

    cov = np.array([np.zeros((2, 2)), np.diag([4e-4, 1e-4]), np.diag([16e-4, 0.25e-4])])
    err = np.array([[0.0, 0.0], [0.02, 0.01], [0.02 + 0.04, 0.01 + 0.01]])
    j = error_jump_before_sigma(err, cov)
    assert j[0] == pytest.approx(np.hypot(0.02 / 0.02, 0.01 / 0.01))
    assert j[1] == pytest.approx(np.hypot(0.04 / 0.04, 0.01 / 0.01))
    rng = np.random.default_rng(3)
    a = rng.normal(size=(50, 2, 2)) * 0.01
    p = a @ np.swapaxes(a, 1, 2) + 1e-6 * np.eye(2)  # random covariances
    same = np.repeat(p[:1], 2, axis=0)
    e = rng.normal(size=(2, 2)) * 0.01
    from rovslam.eval.metrics import error_jump_sigma

    assert error_jump_before_sigma(e, same)[0] == pytest.approx(error_jump_sigma(e, same)[0])  # unchanged ellipse
    # B_k is at least both ellipses, so the jump before is never larger than the jump after, nor than
    # the jump in sigmas of the ellipse before alone.
    errs = rng.normal(size=(50, 2)) * 0.01
    jb, ja = error_jump_before_sigma(errs, p), error_jump_sigma(errs, p)
    jprev = error_jump_sigma(errs[::-1], p[::-1])[::-1]  # de_k against P_(k-1)
    assert jb.shape == ja.shape == (49,)
    assert np.all(jb <= ja * (1 + 1e-9)) and np.all(jb <= jprev * (1 + 1e-9))
    assert np.mean(jb < 0.9 * np.minimum(ja, jprev)) > 0.3  # and often smaller than both


def test_trajectory_errors_of_a_standing_vehicle_are_none_not_nan():
    e = trajectory_errors(np.zeros((3, 2)), np.zeros((3, 2)))
    assert e.final_error_pct is None and e.relative_error_m_per_m is None and e.relative_error_pct is None
    assert e.ate_rmse_m == 0.0 and e.distance_m == 0.0


def test_heading_alignment_takes_out_the_turn_about_the_start_and_leaves_the_shape():
    """A survey turned about its start by a compass error (0.6 deg) with a 1 mm shape error on top: the turn is
    found to 0.01 deg and the ATE with it taken out is the shape error, while the plain ATE carries the turn."""
    from rovslam.camera import rot2

    rng = np.random.default_rng(7)
    for seed_turn_deg in (0.6, -1.3):
        t = np.linspace(0.0, 300.0, 1500)
        truth = np.column_stack([0.4 * np.sin(0.05 * t), 0.4 * np.cos(0.031 * t) - 0.4])  # a 0.8 m wide survey
        shape = rng.normal(scale=1e-3 / np.sqrt(2), size=truth.shape)
        shape[0] = 0.0
        est = (truth + shape) @ rot2(np.radians(seed_turn_deg)).T
        e = trajectory_errors(est, truth)
        assert np.degrees(e.heading_offset_rad) == pytest.approx(seed_turn_deg, abs=0.01)
        shape_rms = float(np.sqrt(np.mean(np.sum(shape**2, axis=1))))
        assert e.ate_heading_aligned_rmse_m == pytest.approx(shape_rms, rel=0.02)
        assert e.ate_rmse_m > 3 * e.ate_heading_aligned_rmse_m
    still = trajectory_errors(np.zeros((4, 2)), np.zeros((4, 2)))
    assert still.heading_offset_rad == 0.0 and still.ate_heading_aligned_rmse_m == 0.0


def test_trajectory_errors_refuse_mismatched_or_empty_paths():
    from rovslam.errors import InvalidArgumentError

    with pytest.raises(InvalidArgumentError, match=r"\(N, 2\)"):
        trajectory_errors(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(InvalidArgumentError):
        trajectory_errors(np.zeros((0, 2)), np.zeros((0, 2)))


# --------------------------------------------------------------------------- phase-correlation baseline


def _seabed(seed=3, size=900):
    import cv2

    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((size, size)).astype(np.float32), (0, 0), 2.0)
    img = (img - img.min()) / (img.max() - img.min()) * 255.0
    return img.astype(np.uint8)


def test_frame_shifts_measure_a_known_image_shift_to_a_tenth_of_a_pixel():
    from rovslam.eval.baselines import frame_shifts_px

    sea = _seabed()
    # The window moves by (+4, -3) px over the seabed each frame: the content moves by (-4, +3).
    frames = [sea[300 - 3 * k : 572 - 3 * k, 200 + 4 * k : 560 + 4 * k] for k in range(6)]
    shifts = frame_shifts_px(frames)
    assert shifts.shape == (5, 2)
    np.testing.assert_allclose(shifts, np.tile([-4.0, 3.0], (5, 1)), atol=0.1)
    # An unreadable frame breaks the two steps around it; the others are kept.
    broken = frame_shifts_px([frames[0], None, frames[2], frames[3]])
    assert np.isnan(broken[:2]).all() and np.allclose(broken[2], [-4.0, 3.0], atol=0.1)


@pytest.mark.parametrize(
    "heading_rad,yaw_offset_rad,shift_px,step_m",
    [
        (0.0, 0.0, (0.0, 10.0), (0.01, 0.0)),  # seabed moves down the image: the vehicle went forward, north
        (0.0, 0.0, (-10.0, 0.0), (0.0, 0.01)),  # seabed moves left: the vehicle went starboard, east
        (np.pi / 2, 0.0, (0.0, 10.0), (0.0, 0.01)),  # forward while heading east
        (np.pi, 0.0, (-10.0, 0.0), (0.0, -0.01)),  # starboard while heading south: west
        (0.0, np.pi / 2, (0.0, 10.0), (0.0, 0.01)),  # image-up turned to starboard: image-down motion is east
    ],
)
def test_integrated_shifts_follow_the_image_and_world_conventions(heading_rad, yaw_offset_rad, shift_px, step_m):
    from rovslam.eval.baselines import integrate_shifts

    n = 5
    path = integrate_shifts(
        np.tile(shift_px, (n - 1, 1)), np.full(n, 1.0), np.full(n, heading_rad), 1000.0, 1000.0, yaw_offset_rad
    )
    assert path.shape == (n, 2) and np.all(path[0] == 0)
    np.testing.assert_allclose(path[-1], np.array(step_m) * (n - 1), atol=1e-12)


def test_integrated_shifts_move_nothing_without_a_heading():
    from rovslam.eval.baselines import integrate_shifts

    psi = np.array([0.0, np.nan, 0.0, 0.0])
    path = integrate_shifts(np.tile([0.0, 10.0], (3, 1)), np.full(4, 2.0), psi, 1000.0, 1000.0)
    np.testing.assert_allclose(path[:, 0], [0.0, 0.0, 0.0, 0.02])  # the two steps touching the NaN are dropped


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    from rovslam.runner import run_sequence
    from rovslam.sim import simulate

    root = tmp_path_factory.mktemp("pc")
    simulate("portofino-short", root / "seq", frames=300, seed=0)
    run_sequence(root / "seq", root / "out")
    return root


def test_phase_correlation_baseline_on_a_simulated_dive(short_run):
    from rovslam.eval import evaluate_run

    f = evaluate_run(short_run / "out", short_run / "seq" / "groundtruth.csv", short_run / "seq")
    pc, dr = f.phase_correlation, f.dead_reckoning
    # Measured (this fixture's dive, seed 0, 300 frames, then evaluate_run): phase correlation 0.141 cm
    # ATE RMSE, dead reckoning 0.104 cm, SLAM 0.052 cm. The phase correlation's bound is 2.5 times its
    # figure, and above a third of it.
    assert pc is not None and np.isfinite(pc.ate_rmse_m)
    assert 0.5 * dr.ate_rmse_m < pc.ate_rmse_m < 2.0 * dr.ate_rmse_m
    assert 0.00047 < pc.ate_rmse_m < 0.0035
    assert pc.distance_m == pytest.approx(f.slam.distance_m)  # errors in the same cell, same truth
    assert f.phase_correlation_over_slam_rmse == pytest.approx(pc.ate_rmse_m / f.slam.ate_rmse_m)
    d = f.to_dict()
    assert d["phase_correlation"]["ate_rmse_m"] == pc.ate_rmse_m and d["frames"] == 300
    assert d["consistency"]["max_error_jump_sigma"] == f.consistency.max_error_jump_sigma > 0


def test_eval_of_a_one_frame_run_says_what_it_cannot_compute(short_run, tmp_path):
    import json

    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.runner import run_sequence

    run_sequence(short_run / "seq", tmp_path / "one", max_frames=1)
    res = CliRunner().invoke(app, ["eval", str(tmp_path / "one"), "-g", str(short_run / "seq" / "groundtruth.csv")])
    assert res.exit_code == 0, res.output
    assert "n/a: one frame only: no frame-to-frame error jump" in res.output
    assert "n/a: the vehicle did not move" in res.output
    text = (tmp_path / "one" / "eval.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    d = json.loads(text)
    assert d["frames"] == 1 and d["consistency"]["max_error_jump_sigma"] is None
    assert d["slam"]["final_error_pct"] is None and len(d["notes"]) == 3


def test_a_run_that_begins_after_its_truth_is_compared_from_where_it_began(short_run, tmp_path):
    """A live run joins a stream already running: its origin is the truth at its first frame, not at the truth's."""
    import shutil

    from rovslam.eval import evaluate_run
    from rovslam.runner import run_sequence

    seq = tmp_path / "late"
    shutil.copytree(short_run / "seq", seq)
    rows = (seq / "frames.csv").read_text(encoding="utf-8").splitlines()
    (seq / "frames.csv").write_text("\n".join([rows[0], *rows[1 + 60 :]]) + "\n", encoding="utf-8")
    run_sequence(seq, tmp_path / "out")
    full = evaluate_run(short_run / "out", short_run / "seq" / "groundtruth.csv")
    late = evaluate_run(tmp_path / "out", seq / "groundtruth.csv")
    gt = np.loadtxt(seq / "groundtruth.csv", delimiter=",", skiprows=1, usecols=(1, 2))
    assert np.linalg.norm(gt[60]) > 0.02  # the vehicle moved before the run began: a shift that matters
    assert late.groundtruth_shift_m == pytest.approx((-gt[60][0], -gt[60][1]))
    assert late.frames == 240 and late.slam.ate_rmse_m < 2 * full.slam.ate_rmse_m


# --------------------------------------------------------------------------- the speed's own consistency


@pytest.mark.parametrize(
    ("heading_rad", "world_mps", "body_mps"),
    [
        (0.0, (0.1, 0.0), (0.1, 0.0)),  # north at heading north: surge
        (np.pi / 2, (0.0, 0.1), (0.1, 0.0)),  # east at heading east: surge
        (np.pi / 2, (0.1, 0.0), (0.0, -0.1)),  # north at heading east: to port
        (np.pi, (0.0, 0.05), (0.0, -0.05)),  # east at heading south: to port
    ],
)
def test_true_body_speed_turns_the_world_step_into_the_body_frame(heading_rad, world_mps, body_mps):
    from rovslam.eval.metrics import true_body_speed_mps

    t = np.arange(5) * 0.2
    xy = np.outer(t, world_mps)
    v = true_body_speed_mps(xy, np.full(5, heading_rad), t)
    assert v.shape == (4, 2)
    np.testing.assert_allclose(v, np.tile(body_mps, (4, 1)), atol=1e-12)


def test_true_body_speed_takes_the_mean_heading_on_the_circle_and_refuses_bad_shapes():
    from rovslam.errors import InvalidArgumentError
    from rovslam.eval.metrics import true_body_speed_mps

    # a step across +-pi: the mean heading is pi (south), not 0
    v = true_body_speed_mps(
        np.array([[0.0, 0.0], [-0.02, 0.0]]), np.array([np.pi - 0.01, -np.pi + 0.01]), np.array([0.0, 0.2])
    )
    np.testing.assert_allclose(v, [[0.1, 0.0]], atol=1e-12)
    assert np.all(np.isnan(true_body_speed_mps(np.zeros((2, 2)), np.zeros(2), np.array([1.0, 1.0]))))  # no time passed
    with pytest.raises(InvalidArgumentError, match="need"):
        true_body_speed_mps(np.zeros((3, 2)), np.zeros(2), np.zeros(3))


def test_speed_consistency_of_a_matched_and_of_an_overstated_covariance():
    from rovslam.errors import InvalidArgumentError
    from rovslam.eval.metrics import speed_consistency

    rng = np.random.default_rng(11)
    q = np.array([[4e-6, -1e-6], [-1e-6, 1e-6]])  # mm/s-level speed noise, correlated surge and sway
    err = rng.multivariate_normal([0, 0], q, size=20000)
    s = speed_consistency(err, np.broadcast_to(q, (20000, 2, 2)))
    assert s.steps == 20000
    assert s.nees_mean == pytest.approx(2.0, rel=0.05)
    assert s.coverage_2sigma == pytest.approx(1 - np.exp(-2.0), abs=0.01)
    assert s.rms_error_mps[0] == pytest.approx(2e-3, rel=0.03) and s.rms_sigma_mps == pytest.approx((2e-3, 1e-3))
    wide = speed_consistency(err, np.broadcast_to(4.0 * q, (20000, 2, 2)))  # sigmas claimed twice too large
    assert wide.nees_mean == pytest.approx(0.5, rel=0.05) and wide.coverage_2sigma > 0.99
    with pytest.raises(InvalidArgumentError, match="K >= 1"):
        speed_consistency(np.zeros((0, 2)), np.zeros((0, 2, 2)))


def test_eval_judges_the_measured_speed_of_a_simulated_dive_against_the_truth(short_run):
    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.eval import evaluate_run
    from rovslam.io.run_results import read_results

    f = evaluate_run(short_run / "out", short_run / "seq" / "groundtruth.csv")
    s = f.speed
    ok = read_results(short_run / "out").trajectory["speed_ok"]
    # every measured step but the first row's (no step before it) is judged
    assert s is not None and s.steps == int(np.sum(ok[1:] > 0)) >= 290
    # Measured (seed 0, 300 frames): speed error 0.24 mm/s RMS per axis, NEES 0.12; Q's floor (the error all
    # tokens share, [odometry] common_sigma_px) claims about 1 mm/s, so its NEES is far below 2.
    assert 0.0 < s.nees_mean < 2.0 and s.coverage_2sigma > 0.9
    assert max(s.rms_error_mps) < 1e-3 < min(s.rms_sigma_mps) * 1.5
    assert f.to_dict()["speed"]["steps"] == s.steps
    res = CliRunner().invoke(app, ["eval", str(short_run / "out"), "-g", str(short_run / "seq" / "groundtruth.csv")])
    assert res.exit_code == 0 and "speed NEES mean" in res.output


def test_altitude_errors_are_relative_to_the_true_altitude_and_skip_frames_without_one():
    from rovslam.eval import altitude_errors

    true = np.full(5, 1.25)
    measured = np.array([1.25 * 1.01, 1.25 * 0.98, np.nan, 0.0, 1.25 * 1.002])
    a = altitude_errors(measured, true, "altitude_m")
    assert a is not None and a.frames == 3  # NaN and 0: no altitude on those frames
    assert a.median_error_pct == pytest.approx(1.0) and a.mean_error_pct == pytest.approx((1.0 - 2.0 + 0.2) / 3)
    assert a.p95_error_pct == pytest.approx(np.percentile([1.0, 2.0, 0.2], 95))
    assert altitude_errors(np.full(3, np.nan), np.ones(3), "altitude_m") is None


def test_over_relief_the_altitude_is_judged_against_the_seabed_under_the_camera():
    from types import SimpleNamespace

    from rovslam.core import GroundTruth
    from rovslam.eval.metrics import _altitude_errors

    n = 4
    relief = np.array([0.00, 0.05, -0.03, 0.10])
    gt = GroundTruth(np.arange(n) * 0.2, np.zeros(n), np.zeros(n), np.full(n, 1.30), np.zeros(n), relief)
    below = 1.30 - relief  # what a perfect altimeter reads
    run = SimpleNamespace(trajectory={"altitude_m": below})
    a = _altitude_errors(run, gt, np.arange(n))  # type: ignore[arg-type]
    assert (
        a is not None and a.truth == "seabed under the camera" and a.median_error_pct == pytest.approx(0.0, abs=1e-12)
    )
    flat = GroundTruth(gt.t_s, gt.x_m, gt.y_m, gt.altitude_m, gt.heading_rad)  # no relief column: altitude_m
    b = _altitude_errors(run, flat, np.arange(n))  # type: ignore[arg-type]
    assert b is not None and b.truth == "altitude_m"
    assert b.median_error_pct == pytest.approx(100 * np.median(np.abs(below / 1.30 - 1)))


def test_eval_reports_the_altitude_error_of_a_simulated_dive(short_run):
    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.eval import evaluate_run

    f = evaluate_run(short_run / "out", short_run / "seq" / "groundtruth.csv")
    a = f.altitude
    # Measured (seed 0, 300 frames over the flat seabed): median 0.060 %, 95th percentile 0.154 %, mean +0.010 %.
    assert a is not None and a.frames == 300 and a.truth == "altitude_m"
    assert 0.0 < a.median_error_pct < 0.2 and a.p95_error_pct < 0.5
    assert f.to_dict()["altitude"]["frames"] == 300
    res = CliRunner().invoke(app, ["eval", str(short_run / "out"), "-g", str(short_run / "seq" / "groundtruth.csv")])
    assert res.exit_code == 0 and "altitude error" in res.output
