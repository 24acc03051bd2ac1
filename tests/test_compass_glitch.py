"""A compass reading that is a glitch (a magnetic spike, a corrupt log line) is refused, not followed.

One reading 1 rad off used to become the heading of that frame (its speed failed too: the
compass step pointed the tokens' turn at the glitch), and the real-photo survey went from
99.3 to 81.7 % inside 2-sigma with four such readings in 2 minutes.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from rovslam.config import OdometryConfig, RunConfig
from rovslam.eval.metrics import evaluate_run
from rovslam.runner import run_sequence
from rovslam.sensor.heading import HeadingFilter, HeadingTracker
from rovslam.sim import simulate

SIGMA = math.radians(0.5)


def _filter(**kw) -> HeadingFilter:
    return HeadingFilter(SIGMA, gate_sigmas=6.0, gate_max_readings=10, **kw)


def _steady(f: HeadingFilter, rng, n: int, heading: float = 0.3) -> None:
    f.update(heading)
    for _ in range(n):
        f.update(heading + SIGMA * rng.standard_normal(), 0.0, 0.001)


def test_a_glitch_is_refused_and_an_ordinary_reading_is_not():
    rng = np.random.default_rng(1)
    f = _filter()
    _steady(f, rng, 50)
    before = f.heading_rad
    f.update(0.3 + 1.0, 0.0, 0.001)  # 1 rad off
    assert f.refused_readings == 1
    assert abs(f.heading_rad - before) < 1e-9
    f.update(0.3 + 2.0 * SIGMA, 0.0, 0.001)  # 2 sigma off: a reading like any other
    assert f.refused_readings == 1 and f.heading_rad > before
    # 1000 readings of the compass's own noise: none refused
    _steady(f, rng, 1000)
    assert f.refused_readings == 1


def test_a_lasting_change_of_the_compass_is_believed_after_the_gates_limit():
    rng = np.random.default_rng(2)
    f = _filter()
    _steady(f, rng, 50)
    for _ in range(10):
        f.update(0.3 + 0.5, 0.0, 0.001)
    assert f.refused_readings == 10 and abs(f.heading_rad - 0.3) < 0.01
    for _ in range(20):  # the 11th is believed, and the next ones are inside the gate
        f.update(0.3 + 0.5, 0.0, 0.001)
    assert f.refused_readings == 10 and abs(f.heading_rad - 0.8) < 0.01


def test_without_a_measured_turn_a_glitch_holds_the_heading():
    rng = np.random.default_rng(3)
    f = _filter()
    _steady(f, rng, 50)
    before, var = f.heading_rad, f.var_rad2
    f.update(0.3 - 2.5, None, math.inf, unmeasured_sigma_rad=0.05)
    assert f.refused_readings == 1 and f.heading_rad == before
    assert f.var_rad2 == pytest.approx(var + 0.05**2)
    f.update(0.3 + 0.01, None, math.inf, unmeasured_sigma_rad=0.05)  # plausible: the compass alone, as before
    assert f.heading_rad == pytest.approx(0.31) and f.refused_readings == 1


def test_the_tokens_prior_ignores_a_glitch_and_the_next_step_starts_from_the_heading():
    tracker = HeadingTracker()
    heading = 0.2
    tracker.update(tracker.prior(heading, 0.2), None, math.inf, 0.2)
    for _k in range(20):
        heading += 0.002
        tracker.update(tracker.prior(heading, 0.2), 0.002, 0.0005, 0.2)
    glitch = tracker.prior(heading + 1.0, 0.2)
    assert glitch.step_rad == 0.0 and glitch.step_sigma_rad == pytest.approx(0.25 * 0.2)
    tracker.update(glitch, 0.002, 0.0005, 0.2)
    heading += 0.002
    after = tracker.prior(heading + 0.002, 0.2)  # the next reading, back to normal
    assert after.step_rad == pytest.approx(0.004, abs=0.002)  # from the heading, not from the glitch (-1 rad)
    assert after.step_sigma_rad == pytest.approx(math.sqrt(2.0) * tracker.compass_sigma_rad)


def _with_glitches(seq, rows, glitches) -> None:
    out = [dict(r) for r in rows]
    for k, d in glitches:
        out[k]["heading_rad"] = str(float(out[k]["heading_rad"]) + d)
    with open(seq / "frames.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(out[0]))
        w.writeheader()
        w.writerows(out)


@pytest.mark.slow  # three 300-frame runs, about 26 s of CPU: the gate itself is checked above, in make test
def test_a_dive_with_compass_glitches_keeps_its_clean_estimate(tmp_path):
    """60 s of the relief preset (seed 6), three readings 1 to 2.5 rad off. Measured: clean 3.86 mm
    ATE, 90.3 % inside 2-sigma; with the glitches 3.87 mm, 90.3 %, 3 refused; the gate off 7.8 mm,
    82.7 %."""
    seq = tmp_path / "seq"
    simulate("portofino-relief", seq, frames=300, seed=6)
    rows = list(csv.DictReader(open(seq / "frames.csv")))
    run_sequence(seq, tmp_path / "clean")
    clean = evaluate_run(tmp_path / "clean", seq / "groundtruth.csv")
    _with_glitches(seq, rows, [(100, 1.0), (101, 1.0), (200, -2.5)])
    run_sequence(seq, tmp_path / "gate")
    run_eval = evaluate_run(tmp_path / "gate", seq / "groundtruth.csv")
    summary = json.loads((tmp_path / "gate" / "summary.json").read_text())
    assert summary["compass"]["readings_refused"] == 3
    assert any("refused as glitches" in w for w in summary["compass"]["warnings"])
    assert run_eval.slam.ate_rmse_m <= 1.05 * clean.slam.ate_rmse_m
    assert run_eval.consistency.coverage_2sigma >= clean.consistency.coverage_2sigma - 0.01
    run_sequence(seq, tmp_path / "off", RunConfig(odometry=OdometryConfig(compass_gate_sigmas=0.0)))
    off = evaluate_run(tmp_path / "off", seq / "groundtruth.csv")
    assert off.slam.ate_rmse_m >= 1.5 * clean.slam.ate_rmse_m  # control: followed, the glitches cost
