"""Speed-token tracking on the real, turbid Sparus AUV video (../shared/data/sparus/).

The acceptance figure of issue 3: at least 4 speed tokens tracked per frame pair on average
at the paper's correlation threshold (0.89). The test is skipped when the data folder is
absent.
"""

from __future__ import annotations

import cv2
import datasets
import numpy as np
import pytest

from rovslam.config import BandpassConfig, SpeedTemplateConfig, TrackerConfig
from rovslam.vision.filters import bandpass, local_variance, template_channel
from rovslam.vision.tracking import TokenTracker, global_shift

SPARUS = datasets.folder("sparus")
VIDEO = SPARUS / "sparus_snippet.mp4"


def _frames() -> list[np.ndarray]:
    av = pytest.importorskip("av")
    frames = []
    with av.open(str(VIDEO)) as container:
        stream = container.streams.video[0]
        # container.decode() raises EOFError at the end with PyAV 18; demux + decode does not.
        for packet in container.demux(stream):
            for frame in packet.decode():
                frames.append(frame.to_ndarray(format="rgb24"))
    return frames


@pytest.fixture(scope="module")
def track_images() -> list[np.ndarray]:
    if not VIDEO.is_file():
        datasets.skip_unless("sparus")
    bp = BandpassConfig()
    return [bandpass(template_channel(f, bp.channel), bp.sigma_fine_px, bp.sigma_coarse_px) for f in _frames()]


def test_sparus_video_decodes(track_images):
    assert len(track_images) == 22
    assert track_images[0].shape == (288, 384)


def test_at_least_four_speed_tokens_per_pair_at_the_paper_threshold(track_images):
    speed, tracker_cfg = SpeedTemplateConfig(), TrackerConfig()
    assert tracker_cfg.min_correlation == 0.89 and speed.max_count == 8
    tracker = TokenTracker(speed, tracker_cfg)
    prediction = None
    counts, residuals, motions = [], [], []
    for k, img in enumerate(track_images):
        if k > 0:
            tracks = tracker.track(img, prediction)
            counts.append(tracks.n_tracked)
            d = tracks.displacements_uv_px
            # Constant image velocity prediction, as the pipeline does with the last speed.
            prediction = np.median(d, axis=0) if tracks.n_tracked else None
            if tracks.n_tracked >= 3:
                # The tokens must agree with one rigid image motion (the vehicle turns ~1 deg
                # per frame here, so a rotation + translation, not a pure translation).
                m, _ = cv2.estimateAffinePartial2D(tracks.uv_prev_px, tracks.uv_curr_px, method=cv2.LMEDS)
                fitted = tracks.uv_prev_px @ m[:2, :2].T + m[:, 2]
                residuals.extend(np.linalg.norm(tracks.uv_curr_px - fitted, axis=1))
                motions.append(np.linalg.norm(np.median(d, axis=0)))
        tracker.extract(img, local_variance(img, speed.size_px))
    mean_tracked = float(np.mean(counts))
    print(f"Sparus: {mean_tracked:.2f} speed tokens tracked per pair (min {min(counts)}) over {len(counts)} pairs")
    assert len(counts) == 21
    assert mean_tracked >= 4.0
    assert min(counts) >= 3
    residuals = np.array(residuals)
    assert np.median(residuals) < 0.35
    assert np.mean(residuals > 1.0) < 0.05
    # About 7 px of image motion per frame (README of the data).
    assert 5.0 < np.median(motions) < 10.0


def test_global_shift_on_the_real_video_matches_the_tokens(track_images):
    shift, confidence = global_shift(track_images[4], track_images[5])
    assert 4.0 < np.linalg.norm(shift) < 10.0
    assert confidence > 0.05
