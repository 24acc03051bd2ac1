"""A compass noisier than configured: learned from its readings, used, and said in the summary."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from rovslam.config import OdometryConfig, RunConfig
from rovslam.eval.metrics import evaluate_run
from rovslam.runner import run_sequence
from rovslam.sim import simulate
from rovslam.sim.scenarios import SCENARIOS


@pytest.fixture(scope="module")
def noisy_compass_runs(tmp_path_factory):
    """60 s over the relief preset with a 1 degree compass, configured (by default) as 0.5 degree."""
    base = SCENARIOS["portofino-relief"]
    SCENARIOS["relief-compass1"] = dataclasses.replace(
        base, name="relief-compass1", nav=dataclasses.replace(base.nav, compass_sigma_rad=float(np.deg2rad(1.0)))
    )
    root = tmp_path_factory.mktemp("compass")
    try:
        simulate("relief-compass1", root / "seq", frames=300, seed=6)
    finally:
        del SCENARIOS["relief-compass1"]
    runs = {}
    # b as it was when this was measured (altitude_bias_relief = false): the relief under the tokens in
    # b moves this dive (seed 6) to 80.3 % inside 2-sigma learned, 78.0 % fixed, and seed 2 of the same
    # dive from 74.6 to 99.0 % (tests/test_relief_scale.py); the compass noise's part is what this isolates.
    # And b the offset alone (altitude_scale_sigma = 0): with the laser rig's share of the depth in b the
    # wider ellipse covers this dive's compass error either way (97.7 % learned, 98.7 % fixed).
    # And the relief off the laser spots' plane neither in the altitude reading nor in the landmarks'
    # observations ([laser] relief_altitude_gain, [slam] landmark_relief_gain = 0): with the first (gain 3) this
    # dive is 96.3 % inside 2-sigma learned, 98.0 % fixed, the fixed compass's deficit covered by the relief.
    # And no seabed offset s in the state ([slam] seabed_offset_sigma_m = 0): with it, the landmarks' depths
    # follow the relief under the laser spots and this dive is 98.0 % inside 2-sigma learned, 98.7 % fixed.
    slam = dataclasses.replace(
        RunConfig().slam,
        altitude_bias_relief=False,
        altitude_scale_sigma=0.0,
        landmark_relief_gain=0.0,
        seabed_offset_sigma_m=0.0,
    )
    # And the rigid token fit ([odometry] token_scale = false, relief_turn_gain = 0): with the zoom and the
    # relief's parallax discounted in the turn, the tokens' turns hold this dive inside its bounds either way
    # (97.3 % inside 2-sigma learned, 97.7 % fixed).
    laser = dataclasses.replace(RunConfig().laser, relief_altitude_gain=0.0)
    rigid = OdometryConfig(token_scale=False, relief_turn_gain=0.0)
    for key, cfg in (
        ("learned", RunConfig(odometry=rigid, slam=slam, laser=laser)),
        ("fixed", RunConfig(odometry=dataclasses.replace(rigid, compass_sigma_learned=False), slam=slam, laser=laser)),
    ):
        run_sequence(root / "seq", root / key, cfg)
        runs[key] = (
            json.loads((root / key / "summary.json").read_text()),
            evaluate_run(root / key, root / "seq" / "groundtruth.csv"),
        )
    return runs


def test_the_compass_noise_is_learned_and_said(noisy_compass_runs):
    summary, _ = noisy_compass_runs["learned"]
    c = summary["compass"]
    assert c["sigma_configured_deg"] == pytest.approx(0.4985, abs=1e-3)
    assert c["sigma_learned_deg"] == pytest.approx(1.0, rel=0.2)
    assert c["sigma_used_deg"] == c["sigma_learned_deg"] and c["learning"] is True
    assert (
        len(c["warnings"]) == 1
        and "compass_sigma_rad" in c["warnings"][0]
        and "learned value was used" in c["warnings"][0]
    )
    # Not learning, the run still says what to set.
    fixed = noisy_compass_runs["fixed"][0]["compass"]
    assert fixed["sigma_used_deg"] == fixed["sigma_configured_deg"] and "set compass_sigma_rad" in fixed["warnings"][0]


def test_the_learned_compass_noise_keeps_the_truth_inside_its_bounds(noisy_compass_runs):
    learned, fixed = noisy_compass_runs["learned"][1], noisy_compass_runs["fixed"][1]
    # Measured: 92.7 against 87.7 % inside 2-sigma, mean NEES 1.16 against 1.67.
    assert learned.consistency.coverage_2sigma > fixed.consistency.coverage_2sigma + 0.03
    assert learned.consistency.nees_mean < 0.8 * fixed.consistency.nees_mean
    assert learned.slam.ate_rmse_m <= fixed.slam.ate_rmse_m
