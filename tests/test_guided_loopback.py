"""Acceptance: ``rovslam sitl --follow-guided`` and ``rovslam live --poi --guide`` on loopback.

The simulated vehicle (in this process) starts disarmed; its simulated pilot arms it and
switches to GUIDED after 1 s; ``live`` (a subprocess, every frame processed) flies a short
survey then the points of interest; the true arrival errors come from the vehicle's
``events.csv`` (the true position when each "arrived" STATUSTEXT came). The stream runs
``PACE`` times slower than real time and ``live`` stretches its stop delays to match
(``--guide-pace``): the result does not depend on the machine's speed.

The slow test compares with ``rovslam navigate`` (same preset, seed, points, survey and holds):
the mean true arrival error within 1.5x of it. The issue's other goal, dead reckoning
(``navigate --estimator dead-reckoning``) at least 3x worse, is not reached on a mission this short
and is kept as a strict expected failure with the measured figures.
"""

from __future__ import annotations

import math
import re
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from live_peer import finish, free_udp_port, start_live

from rovslam.core import Goal
from rovslam.sim.sitl import SitlConfig, SitlVehicle
from rovslam.sim.sitl_guided import read_events

PRESET = "rough-turns"  # heading turns, altitude swings, roll and pitch, turbid water
PACE = 2.0
CRF = 12  # the stream's H.264 quality (as the live acceptance test)


def write_poi(path: Path, points) -> list[Goal]:
    path.write_text("name,x_m,y_m\n" + "".join(f"{n},{x},{y}\n" for n, x, y in points), encoding="utf-8")
    return [Goal(n, np.array([x, y])) for n, x, y in points]


def fly_guided(
    tmp: Path,
    points,
    survey_s: float,
    hold_s: float,
    dive_s: float,
    seed: int = 0,
    estimator: str = "slam",
    preset: str = PRESET,
) -> tuple[dict[str, float], list[dict], str]:
    """One loopback mission: {point: true arrival error (m)}, the events, live's stderr."""
    tmp.mkdir(parents=True, exist_ok=True)
    poi = tmp / "poi.csv"
    goals = write_poi(poi, points)
    vport, mport = free_udp_port(), free_udp_port()
    truth, out = tmp / "truth", tmp / "out"
    vehicle = SitlVehicle(
        SitlConfig(
            preset,
            truth,
            video=f"udp://127.0.0.1:{vport}",
            seed=seed,
            crf=CRF,
            mavlink=f"udpout:127.0.0.1:{mport}",
            duration_s=dive_s,
            pace=PACE,
            follow_guided=True,
            pilot_guided_s=1.0,
            wait_for_peer_s=120.0,
        )
    )
    p = None
    try:
        vehicle.start()
        p = start_live(
            [
                "--video",
                f"udp://127.0.0.1:{vport}",
                "--camera",
                str(truth / "camera.toml"),
                "--mavlink",
                f"udpin:127.0.0.1:{mport}",
                "--out",
                str(out),
                "--every-frame",
                "--quiet",
                "--poi",
                str(poi),
                "--guide",
                "--survey-s",
                str(survey_s),
                "--hold-s",
                str(hold_s),
                "--estimator",
                estimator,
                "--guide-pace",
                str(PACE),
                "--heartbeat-timeout-s",
                "120",
                "--wait-s",
                "200",
            ],
            tmp,
        )
        end = time.monotonic() + PACE * dive_s + 240.0
        while time.monotonic() < end and not vehicle.done and p.poll() is None:
            if (truth / "events.csv").exists() and "mission done" in (truth / "events.csv").read_text():
                break
            time.sleep(0.5)
    finally:
        if p is not None and p.poll() is None:
            p.send_signal(signal.SIGTERM)
        vehicle.stop()
    _, _, err = finish(p, tmp, timeout_s=120) if p is not None else (None, "", "")
    events = read_events(truth / "events.csv")
    errors = {}
    for g in goals:
        for e in events:
            if re.match(rf"arrived {re.escape(g.name)} ", e["text"]):
                errors[g.name] = math.hypot(e["x_true_m"] - g.xy_m[0], e["y_true_m"] - g.xy_m[1])
                break
    return errors, events, err


@pytest.mark.slow  # 1.5 to 3 minutes of a real-time mission on 2 cores
def test_guided_mission_short_reaches_the_point(tmp_path):
    """The fast version: clear water (portofino), no survey, one point 6 cm away, 1 s hold (about 2 min)."""
    errors, events, err = fly_guided(
        tmp_path, [("rock", 0.05, 0.03)], survey_s=0.0, hold_s=1.0, dive_s=90.0, preset="portofino-short"
    )
    texts = [e["text"] for e in events]
    assert set(errors) == {"rock"}, (texts, err[-2000:])
    assert errors["rock"] < 0.015, errors
    assert "mission done" in texts and any(t.startswith("holding rock") for t in texts)
    assert (tmp_path / "out" / "arrivals.csv").exists() and (tmp_path / "out" / "navigation.csv").exists()


ACCEPTANCE_POINTS = [("rock", 0.3, 0.3), ("crack", 0.3, -0.3), ("sponge", -0.3, -0.3), ("wreck", -0.3, 0.3)]


@pytest.fixture(scope="module")
def acceptance_mission(tmp_path_factory):
    """The acceptance mission flown once: {point: true error} over loopback, and the mean true errors of navigate."""
    from rovslam.navigate import navigate

    tmp = tmp_path_factory.mktemp("guided_acceptance")
    goals = [Goal(n, np.array([x, y])) for n, x, y in ACCEPTANCE_POINTS]
    offline = navigate(PRESET, goals, tmp / "nav", "slam", survey_s=30.0, hold_s=2.0, seed=0, plot=False)
    dr = navigate(PRESET, goals, tmp / "dr", "dead-reckoning", survey_s=30.0, hold_s=2.0, seed=0, plot=False)
    errors, events, err = fly_guided(tmp / "live", ACCEPTANCE_POINTS, 30.0, 2.0, dive_s=600.0)
    nav_mean = float(np.mean([r["true_err_m"] for r in offline.arrivals]))
    dr_mean = float(np.mean([r["true_err_m"] for r in dr.arrivals]))
    print(
        f"mean true arrival error: live {1000 * np.mean(list(errors.values()) or [np.nan]):.2f} mm, "
        f"navigate {1000 * nav_mean:.2f} mm, dead reckoning {1000 * dr_mean:.2f} mm"
    )
    return errors, events, err, nav_mean, dr_mean


@pytest.mark.slow
def test_guided_mission_matches_navigate(acceptance_mission):
    """A 30 s survey then 4 points (0.6 m square), 2 s holds, seed 0: every point reached, the mean true
    arrival error within 1.5x of navigate's (measured 5.65 against 4.79 mm; about 20 minutes here)."""
    errors, events, err, nav_mean, _ = acceptance_mission
    assert set(errors) == {n for n, _, _ in ACCEPTANCE_POINTS}, ([e["text"] for e in events], err[-2000:])
    assert float(np.mean(list(errors.values()))) <= 1.5 * nav_mean


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="not reached: dead reckoning arrives only 1.0-1.6x farther off on missions of a few minutes "
    "(it drifts 4-8 mm in 6 minutes; the SLAM arrivals are 3-6 mm off: the estimate's own error and "
    "the 5 mm arrival radius). Measured in docs/vehicle.md.",
)
def test_guided_mission_beats_dead_reckoning_threefold(acceptance_mission):
    """The issue's goal: steering by dead reckoning at least 3x worse than the guided mission."""
    errors, _, _, _, dr_mean = acceptance_mission
    assert errors and dr_mean >= 3.0 * float(np.mean(list(errors.values())))
