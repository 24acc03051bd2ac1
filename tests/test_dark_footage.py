"""Dark or low-contrast footage: the local-variance thresholds follow the frame's contrast, as a camera's gain would.

The paper's thresholds (12.3 grey levels squared for landmarks, 4.0 here for tokens) are absolute:
on a dark camera (a fixed exposure 2.5 m above a real seabed, a lamp too weak) no window reaches
them, no landmark is made and tokens are lost. Correlation does not depend on the gain, so a frame
whose band-passed standard deviation is below ``[bandpass] min_contrast_std`` is scaled up to it
before the thresholds.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synth import paper_camera, seabed_frame, seabed_spectrum, simulate_variant

from rovslam.config import BandpassConfig, RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.eval.metrics import consistency
from rovslam.io.sequence import read_groundtruth
from rovslam.pipeline import SlamPipeline
from rovslam.runner import run_sequence
from rovslam.sim.render import SensorParams
from rovslam.vision.filters import contrast_std

PAPER = RunConfig(bandpass=BandpassConfig(min_contrast_std=0.0))


def _tracking_std(config: RunConfig, image: np.ndarray) -> float:
    pipe = SlamPipeline(SequenceInfo(name="t", camera=paper_camera(), lasers=(), fixed_altitude_m=1.31), config)
    img, reason = pipe._tracking_image(Frame(index=0, t_s=0.0, image=image, heading_rad=0.0))
    assert reason is None
    return contrast_std(img)


def test_a_dim_frame_is_lifted_to_the_contrast_floor_and_a_bright_one_is_untouched():
    spectrum = seabed_spectrum((512, 512), seed=5)
    bright = seabed_frame(spectrum, (60.0, 80.0), seed=1)
    dim = np.clip(40.0 + 0.08 * (bright.astype(np.float32) - 128.0), 0, 255).astype(np.uint8)
    paper_dim = _tracking_std(PAPER, dim)
    assert 0.5 < paper_dim < 1.7  # textured, but below the floor
    assert _tracking_std(RunConfig(), dim) == pytest.approx(1.7, rel=1e-4)
    assert _tracking_std(RunConfig(), bright) == _tracking_std(PAPER, bright) > 1.7


@pytest.mark.parametrize("bad", [-0.1, float("nan")])
def test_a_negative_or_missing_floor_is_refused(bad):
    with pytest.raises(Exception, match="min_contrast_std"):
        BandpassConfig(min_contrast_std=bad)


@pytest.fixture(scope="module")
def dark_dive(tmp_path_factory):
    """150 frames of the paper's trial with the lamps at an eighth of their power (a frame's band-passed std ~0.7)."""
    return simulate_variant(
        tmp_path_factory.mktemp("dark") / "seq",
        "portofino-short",
        "test-dark",
        seed=0,
        n_frames=150,
        sensor=dataclasses.replace(SensorParams(), exposure_gain=0.12),
    )


def _run(seq, out, config):
    run_sequence(seq, out, config)
    tr = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    gt = read_groundtruth(seq / "groundtruth.csv")
    err = np.column_stack([tr["x_m"] - gt.x_m, tr["y_m"] - gt.y_m])
    cov = np.stack(
        [np.column_stack([tr["var_x_m2"], tr["cov_xy_m2"]]), np.column_stack([tr["cov_xy_m2"], tr["var_y_m2"]])], axis=1
    )
    n_landmarks = sum(1 for _ in open(out / "landmarks.csv")) - 1
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))), consistency(err, cov), np.mean(tr["speed_ok"]), n_landmarks


def test_dark_dive_keeps_its_speed_and_its_map(dark_dive, tmp_path):
    ate_paper, _, speed_paper, lm_paper = _run(dark_dive, tmp_path / "paper", PAPER)
    ate, cons, speed_ok, n_lm = _run(dark_dive, tmp_path / "default", RunConfig())
    # the absolute thresholds: no landmark, the speed lost on about half the frames, decimetres of error
    assert lm_paper == 0 and speed_paper < 0.7 and ate_paper > 0.10
    # lifted: a map, a speed on nearly every frame, millimetres, inside the reported covariance
    assert n_lm >= 4 and speed_ok >= 0.97
    # Measured: ATE RMSE 0.130 cm (100 % inside 2-sigma, speed on 99.3 % of frames, 8 landmarks; the paper's
    # thresholds 27.8 cm), by this test's dive and runs; bound at 2.5 times that, and above a third of it.
    assert 0.0004 < ate < 0.0033
    assert cons.coverage_2sigma >= 0.95
