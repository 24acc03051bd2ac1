"""The relief under the tokens as a lasting scale error of the speed (issue 10).

Over relief the tokens' speed, measured at the laser altitude Z, is off by the tokens' depth:
on the real-photo seabed, traced against the true relief (``photo-turns`` seed 2, 300 s), that
scale error is 1.05 % per step, 0.93 % averaged over 5 steps, correlated 0.95 from one step to
the next, 0.77 after 1 s, 0.41 after 5 s. The speed's per-step Q carried it as white noise, so the
filter averaged it away, and the truth left the 2-sigma ellipse (92.3 % inside). The altitude
offset ``b`` (a consider state) now carries it beside the altimeter's lasting offset: sigma from
the tokens' parallax, correlation ``[slam] altitude_bias_relief_tau_s``, the two held as one
Ornstein-Uhlenbeck process (:func:`rovslam.slam.motion.ou_sum_as_one`). Off by default
(``[slam] altitude_bias_relief``): through ``b`` the relief's variance also reaches the landmarks'
depths, and on ``hd-survey`` seed 6 a revisit then pulled the estimate 8 mm off (100 -> 49.6 %).
"""

from __future__ import annotations

import dataclasses
import math

import datasets
import numpy as np
import pytest

from rovslam.config import RunConfig, SlamConfig
from rovslam.errors import InvalidMeasurementError
from rovslam.slam import EkfSlam, MotionInput
from rovslam.slam.motion import ou_sum_as_one

# The relief in b is off by default (it also widens the landmarks' depths: README); these tests switch it on.
_ON = RunConfig(slam=dataclasses.replace(RunConfig().slam, altitude_bias_relief=True))


def _integrated_ou_var(sigma: float, tau_s: float, t_s: float) -> float:
    """Variance of the integral over t_s of a stationary OU process (sigma, tau)."""
    return 2.0 * sigma**2 * tau_s * (t_s - tau_s * (1.0 - math.exp(-t_s / tau_s)))


# ----------------------------------------------------------------------------- ou_sum_as_one


def test_one_process_keeps_the_variance_and_the_long_run_drift_of_the_sum():
    sigma, tau = ou_sum_as_one(0.01, 30.0, 0.014, 5.0)
    assert sigma == pytest.approx(math.hypot(0.01, 0.014), rel=1e-12)
    assert sigma**2 * tau == pytest.approx(0.01**2 * 30.0 + 0.014**2 * 5.0, rel=1e-12)
    # The drift it stands for, integrated: exact at short and long horizons, within 25 % between.
    for t_s, tol in ((0.2, 0.01), (1.0, 0.05), (10.0, 0.25), (100.0, 0.25), (3000.0, 0.01)):
        both = _integrated_ou_var(0.01, 30.0, t_s) + _integrated_ou_var(0.014, 5.0, t_s)
        assert _integrated_ou_var(sigma, tau, t_s) == pytest.approx(both, rel=tol), t_s


def test_without_relief_it_is_the_altimeter_offset_alone():
    assert ou_sum_as_one(0.01, 30.0, 0.0, 5.0) == (0.01, 30.0)
    assert ou_sum_as_one(0.0, 30.0, 0.0, 5.0) == (0.0, 30.0)
    sigma, tau = ou_sum_as_one(0.0, 30.0, 0.02, 5.0)
    assert sigma == pytest.approx(0.02) and tau == pytest.approx(5.0)


# ----------------------------------------------------------------------------- the EKF's b


Z_M, DT_S, U_MPS = 1.3, 0.2, 0.15


def _drift_var_m2(tau_s: float | None, steps: int, sigma_b_m: float = 0.02) -> float:
    """Along-track position variance after ``steps`` predictions driven only by the consider state b."""
    cfg = SlamConfig(
        landmark_height_sigma_m=0.0,
        heading_bias_sigma_rad=0.0,
        speed_bias_sigma_mps=0.0,
        heading_sigma_rad=0.0,
        altitude_bias_sigma_m=sigma_b_m,
        altitude_bias_tau_s=30.0,
    )
    ekf = EkfSlam(cfg, initial_cov_m2=np.zeros((2, 2)))
    for _ in range(steps):
        ekf.predict(
            MotionInput(
                U_MPS,
                0.0,
                np.zeros((2, 2)),
                0.0,
                DT_S,
                altitude_m=Z_M,
                altitude_bias_sigma_m=sigma_b_m,
                altitude_bias_tau_s=tau_s,
            )
        )
    return float(ekf.covariance_m2[0, 0])


@pytest.mark.parametrize("tau_s", [2.0, 5.0, 30.0])
def test_the_filter_drifts_as_the_correlation_time_it_is_given_says(tau_s):
    # (u / Z)^2 times the integrated OU variance of b, within the discretisation (dt / tau <= 10 %).
    for steps in (5, 50, 500):
        expected = (U_MPS / Z_M) ** 2 * _integrated_ou_var(0.02, tau_s, steps * DT_S)
        assert _drift_var_m2(tau_s, steps) == pytest.approx(expected, rel=0.12), steps


def test_the_configured_correlation_time_is_the_default():
    assert _drift_var_m2(None, 200) == _drift_var_m2(30.0, 200)
    assert _drift_var_m2(5.0, 200) < 0.5 * _drift_var_m2(30.0, 200)  # over 40 s the shorter one drifts less


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_a_bad_correlation_time_is_refused_and_the_state_is_unchanged(bad):
    ekf = EkfSlam(SlamConfig(altitude_bias_sigma_m=0.01))
    before = ekf.covariance_m2.copy()
    with pytest.raises(InvalidMeasurementError, match="altitude_bias_tau_s"):
        ekf.predict(MotionInput(U_MPS, 0.0, np.eye(2) * 1e-6, 0.0, DT_S, altitude_m=Z_M, altitude_bias_tau_s=bad))
    np.testing.assert_array_equal(ekf.covariance_m2, before)


def test_the_relief_correlation_time_is_checked_at_load():
    from rovslam.errors import ConfigError

    for bad in (0.0, -5.0):
        with pytest.raises(ConfigError, match="altitude_bias_relief_tau_s"):
            SlamConfig(altitude_bias_relief_tau_s=bad)


# ----------------------------------------------------------------------------- on a dive


def _photo_turns(tmp_path, seed: int, frames: int):
    from rovslam.sim import simulate

    datasets.skip_unless("chamber3")
    seq = tmp_path / f"seq{seed}"
    simulate("photo-turns", seq, frames=frames, seed=seed)
    return seq


def _inside_2sigma(seq, cfg: RunConfig) -> tuple[float, list[float]]:
    """Share of frames with the truth inside the 2-sigma ellipse, and b's process sigma of each prediction."""
    import csv

    from rovslam.io.sequence import open_sequence
    from rovslam.pipeline import SlamPipeline

    s = open_sequence(seq)
    gt = list(csv.DictReader(open(seq / "groundtruth.csv")))
    pipe = SlamPipeline(s.info, cfg)
    inside, sigmas = [], []
    process = pipe._altitude_bias_process

    def recorded(*args):
        out = process(*args)
        sigmas.append(out[0])
        return out

    pipe._altitude_bias_process = recorded
    for fr in s.frames():
        r = pipe.process(fr)
        e = np.array([r.x_m - float(gt[fr.index]["x_m"]), r.y_m - float(gt[fr.index]["y_m"])])
        if fr.index > 0:
            inside.append(float(e @ np.linalg.pinv(r.cov_xy_m2) @ e) <= 4.0)
    return float(np.mean(inside)), sigmas


@pytest.mark.slow  # an opt-in setting ([slam] altitude_bias_relief) on two runs of 2 minutes of the photo (35 s of CPU)
def test_over_the_real_photo_relief_b_carries_more_than_the_altimeter_offset(tmp_path):
    # The photo relief (8 cm span) under the tokens: b's sigma above the configured 1 cm over
    # most of the dive (medians per 20 s: 11, 18, 18, 10, 26, 20 mm measured), and never below it.
    # b's sigma as it was measured: the altimeter's offset without the laser rig's share of the depth
    # (altitude_scale_sigma, which puts hypot(1 cm, 0.76 % of 1.31 m) = 1.41 cm under every run).
    offset_only = dataclasses.replace(RunConfig().slam, altitude_scale_sigma=0.0)
    seq = _photo_turns(tmp_path, 2, 600)
    _, sigmas = _inside_2sigma(seq, RunConfig(slam=dataclasses.replace(offset_only, altitude_bias_relief=True)))
    later = np.array(sigmas[100:])
    assert np.median(later) > 0.014
    assert np.all(later >= RunConfig().slam.altitude_bias_sigma_m - 1e-12)
    before = RunConfig(slam=offset_only)
    _, sigmas_before = _inside_2sigma(seq, before)  # the control: the altimeter's offset, the relief under its spots
    assert np.median(sigmas_before[100:]) < 0.011


def test_a_flat_seabed_keeps_the_altimeter_offset_alone(tmp_path):
    # The same real-photo survey with its relief taken away: once the tokens have measured the
    # seabed, b stays near the configured lasting error at the dive's depth, the 1 cm offset and the
    # laser rig's 0.76 % of Z in quadrature (the relief prior of the first seconds faded).
    from synth import photo_available, simulate_variant

    from rovslam.sim import SCENARIOS
    from rovslam.slam.motion import altitude_offset_sigma_m

    if not photo_available():
        datasets.skip_unless("chamber3")
    seq = simulate_variant(tmp_path / "flat", "photo-survey", "photo-survey-flat", 0, n_frames=150, relief=None)
    _, sigmas = _inside_2sigma(seq, _ON)
    slam = RunConfig().slam
    lasting = altitude_offset_sigma_m(
        slam.altitude_bias_sigma_m, slam.altitude_scale_sigma, SCENARIOS["photo-survey"].vehicle.altitude_m
    )
    assert 0.97 * lasting < np.median(sigmas[50:]) < 1.15 * lasting
    # summary.json says what b carried, as the run used it
    import json

    from rovslam.runner import run_sequence

    run_sequence(seq, tmp_path / "out", _ON)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())["altitude_bias"]
    assert summary["predictions"] == len(sigmas) == 149
    assert summary["sigma_median_m"] == pytest.approx(float(np.median(sigmas)), rel=1e-12)
    assert summary["sigma_p95_m"] >= summary["sigma_median_m"] >= RunConfig().slam.altitude_bias_sigma_m


@pytest.mark.slow  # the same opt-in setting against the default on a 60 s relief dive (20 s of CPU)
def test_over_the_relief_trial_with_a_noisy_compass_the_truth_stays_inside(tmp_path):
    # portofino-relief (12 cm of procedural relief: another seabed than the photo's) for 60 s with a
    # 1 degree compass, seed 2: measured 99.0 % inside 2-sigma, against 74.6 % with b as before.
    # (Seeds 0 to 5: 99.0 to 100 %, against 74.6 to 100 %; seed 6, tests/test_compass_noise.py's
    # dive, is the one that loses: 80.3 against 92.3 %.)
    from rovslam.sim import SCENARIOS, simulate

    base = SCENARIOS["portofino-relief"]
    SCENARIOS["relief-compass1"] = dataclasses.replace(
        base, name="relief-compass1", nav=dataclasses.replace(base.nav, compass_sigma_rad=math.radians(1.0))
    )
    try:
        simulate("relief-compass1", tmp_path / "seq", frames=300, seed=2)
    finally:
        del SCENARIOS["relief-compass1"]
    # As it was measured: without the terms added since that widen this dive's ellipse (the relief off the laser
    # spots' plane in the altitude, on since 7f125a4: the default then reached 100 %; the laser rig's share of the
    # depth in b; the relief off the plane in the landmarks; the zoom between frames and the relief-weighted turn).
    from test_consistency import without_widening_terms

    base_cfg = without_widening_terms(RunConfig())
    on = dataclasses.replace(base_cfg, slam=dataclasses.replace(base_cfg.slam, altitude_bias_relief=True))
    inside, _ = _inside_2sigma(tmp_path / "seq", on)
    assert inside >= 0.95
    inside_before, _ = _inside_2sigma(tmp_path / "seq", base_cfg)
    assert inside_before < 0.85


@pytest.mark.slow
def test_the_worst_real_photo_dive_stays_inside_its_bounds(tmp_path):
    # The check matrix's worst cell (photo-turns seed 2, 300 s): 92.3 % inside 2-sigma with the
    # relief as white noise in Q only, 98.3 % with it in b too (measured). Without the seabed offset s
    # ([slam] seabed_offset_sigma_m = 0), which this b term was measured without: with s the default
    # run is 97.1 % inside (the check matrix's photo-turns seed 2).
    # Nor with the other terms added since that widen this dive's ellipse (the laser rig's share of the depth in b,
    # the relief off the laser spots' plane in the altitude and the landmarks, the zoom between frames and the
    # relief-weighted turn): with them the control reached 97.7 %.
    from test_consistency import without_widening_terms

    base_cfg = without_widening_terms(RunConfig())
    no_s = dataclasses.replace(base_cfg.slam, seabed_offset_sigma_m=0.0)
    seq = _photo_turns(tmp_path, 2, 1500)
    inside, _ = _inside_2sigma(
        seq, dataclasses.replace(base_cfg, slam=dataclasses.replace(no_s, altitude_bias_relief=True))
    )
    assert inside >= 0.95
    inside_before, _ = _inside_2sigma(
        seq, dataclasses.replace(base_cfg, slam=no_s)
    )  # the relief as white noise in Q only
    assert inside_before < 0.95
