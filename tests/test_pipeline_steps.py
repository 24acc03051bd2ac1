"""The per-frame loop, step by step, on small synthetic frames: a specification of SlamPipeline.

Frames are windows of one seeded band-limited texture (tests/synth.py): a window that moves
``s`` px up between frames is a vehicle moving forward by ``s Z / f`` metres (the seabed
moves down in the image, "mirrored motion").
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from synth import paper_camera, seabed_frame, seabed_spectrum

from rovslam.config import RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.pipeline import SlamPipeline
from rovslam.sensor.heading import HeadingTracker
from rovslam.vision.laser import AltitudeEstimate

CAM = paper_camera()
Z = 1.31
DT = 0.2
M_PER_PX = Z / CAM.focal_px


@pytest.fixture(scope="module")
def spectrum():
    return seabed_spectrum((512, 512), seed=3)


def _info() -> SequenceInfo:
    return SequenceInfo(name="steps", camera=CAM, lasers=(), fixed_altitude_m=Z)


def _frame(k: int, image: np.ndarray, heading_rad: float = 0.0, **kw) -> Frame:
    return Frame(index=k, t_s=k * DT, image=image, heading_rad=heading_rad, **kw)


def _forward_frames(spectrum, n: int, step_px: float, start=(60.0, 120.0)):
    """n frames of a vehicle moving forward by step_px per frame at heading 0."""
    return [_frame(k, seabed_frame(spectrum, (start[0], start[1] - step_px * k), seed=k)) for k in range(n)]


def _with_bright_patch(image: np.ndarray, centre_uv: tuple[int, int], half: int = 12) -> np.ndarray:
    """A high-contrast checker patch: the landmark and the best speed token both want it."""
    out = image.copy()
    u, v = centre_uv
    yy, xx = np.mgrid[-half:half, -half:half]
    checker = (((xx // 4) + (yy // 4)) % 2) * 160 + 40
    for c in range(3):
        out[v - half : v + half, u - half : u + half, c] = checker
    return out


def test_speed_and_position_follow_the_known_shift(spectrum):
    pipe = SlamPipeline(_info())
    step_px = 3.0
    results = [pipe.process(f) for f in _forward_frames(spectrum, 8, step_px)]
    surge_true = step_px * M_PER_PX / DT
    for r in results[1:]:
        assert r.speed_ok
        assert r.surge_mps == pytest.approx(surge_true, abs=0.1 * M_PER_PX / DT)  # within 0.1 px per frame
        assert abs(r.sway_mps) < 0.1 * M_PER_PX / DT
    last = results[-1]
    # 7 steps of about 0.03 px of noise each (8 tokens of 0.07 px): within 0.3 px, 0.4 mm.
    assert last.x_m == pytest.approx(7 * step_px * M_PER_PX, abs=0.3 * M_PER_PX)
    assert abs(last.y_m) < 0.3 * M_PER_PX
    assert abs(last.dr_x_m - last.x_m) < 0.3 * M_PER_PX
    # Landmark 0, cut at the first frame, stays in view and is tracked in every later frame.
    assert all([(o.landmark_id, o.kind) for o in r.observations] == [(0, "track")] for r in results[1:])


def test_steps_run_in_the_papers_order(spectrum):
    calls: list[str] = []
    pipe = SlamPipeline(_info())
    steps = [
        "_measure_altitude",
        "_inhibit_laser_spots",
        "_track_landmarks",
        "_choose_new_landmark",
        "_inhibit_landmarks",
        "_measure_speed",
        "_fuse_heading",
        "_predict_and_update",
        "_add_landmark",
        "_extract_tokens",
    ]
    for name in steps:
        method = getattr(pipe, name)

        def spy(*args, _m=method, _n=name, **kwargs):
            calls.append(_n)
            return _m(*args, **kwargs)

        setattr(pipe, name, spy)
    frames = _forward_frames(spectrum, 2, 2.0)
    pipe.process(frames[0])
    assert calls == steps  # the first frame creates landmark 0 (step 7 runs)
    calls.clear()
    pipe.process(frames[1])
    assert calls == [s for s in steps if s != "_add_landmark"]  # landmark 0 tracked: no new one


def test_a_laser_spot_inside_the_landmark_template_refuses_the_match(spectrum, monkeypatch):
    frames = _forward_frames(spectrum, 2, 2.0)

    def run(with_spot: bool):
        pipe = SlamPipeline(_info())
        first = pipe.process(frames[0])
        (init,) = [o for o in first.observations if o.kind == "init"]
        if with_spot:
            spot = init.uv_px + np.array([5.0, 2.0 + 5.0])  # inside the 32x32 template after a 2 px shift
            estimate = AltitudeEstimate(Z, 0.01, "laser", spot[None, :], 1)
            monkeypatch.setattr(pipe.altimeter, "measure", lambda *a, **k: estimate)
        return pipe.process(frames[1])

    control = run(with_spot=False)
    assert [(o.landmark_id, o.kind, o.accepted) for o in control.observations] == [(0, "track", True)]
    spotted = run(with_spot=True)
    # Found by the correlation, refused before the filter sees it, and the reason kept.
    assert [(o.landmark_id, o.kind, o.accepted, o.reason) for o in spotted.observations if o.kind == "track"] == [
        (0, "track", False, "laser spot inside the template")
    ]


def test_landmark_boxes_are_masked_before_the_speed_tokens_are_chosen(spectrum):
    image = _with_bright_patch(seabed_frame(spectrum, (60.0, 120.0), seed=0), (120, 100))
    frame = _frame(0, image)
    lm = RunConfig().landmark_templates
    keep_out = lm.size_px // 2 + lm.inhibit_margin_px + RunConfig().speed_templates.size_px // 2

    pipe = SlamPipeline(_info())
    r = pipe.process(frame)
    (init,) = [o for o in r.observations if o.kind == "init"]
    assert np.max(np.abs(init.uv_px - [120, 100])) <= 8  # the landmark is the bright patch
    centres = np.array([t.centre_uv_px for t in pipe.tokens.tokens])
    assert len(centres) >= 4
    assert np.all(np.max(np.abs(centres - init.uv_px), axis=1) >= keep_out)

    unmasked = SlamPipeline(_info())
    unmasked._inhibit_landmarks = lambda *a, **k: None
    unmasked.process(frame)
    centres = np.array([t.centre_uv_px for t in unmasked.tokens.tokens])
    assert np.any(np.max(np.abs(centres - init.uv_px), axis=1) < keep_out)  # the patch would carry a token


def test_first_frame_with_attitude_starts_with_the_tilt_uncertainty(spectrum):
    image = seabed_frame(spectrum, (60.0, 120.0), seed=0)
    sigma = RunConfig().odometry.attitude_sigma_rad
    pipe = SlamPipeline(_info())
    r = pipe.process(_frame(0, image, roll_rad=0.0, pitch_rad=0.0, has_attitude=True))
    np.testing.assert_allclose(pipe.ekf.vehicle_cov_m2, np.eye(2) * (Z * sigma) ** 2, rtol=1e-12)
    # Reported: the filter's (apparent position) plus the tilt offset of the true one.
    np.testing.assert_allclose(r.cov_xy_m2, 2 * np.eye(2) * (Z * sigma) ** 2, rtol=1e-12)

    level = SlamPipeline(_info())
    r = level.process(_frame(0, image))
    np.testing.assert_array_equal(r.cov_xy_m2, np.zeros((2, 2)))


def test_an_unusable_frame_is_bridged_with_the_held_speed(spectrum):
    frames = _forward_frames(spectrum, 5, 3.0)
    black = _frame(3, np.zeros_like(frames[3].image))
    pipe = SlamPipeline(_info())
    results = [pipe.process(f) for f in frames[:3]]
    skipped = pipe.process(black)
    assert skipped.skipped_reason and "no texture" in skipped.skipped_reason
    assert not skipped.speed_ok and skipped.tokens_tracked == 0
    held = results[-1].surge_mps
    assert skipped.x_m == pytest.approx(results[-1].x_m + held * DT, abs=1e-9)
    assert skipped.cov_xy_m2[0, 0] > results[-1].cov_xy_m2[0, 0]  # the held speed is less certain
    assert pipe.skipped == [(3, 3 * DT, skipped.skipped_reason)]
    after = pipe.process(frames[4])  # tokens were reset: the next frame measures nothing, then recovers
    assert after.tokens_given == 0 and after.skipped_reason is None


def test_heading_tracker_predicts_with_the_compass_and_integrates_tokens_without_one():
    tracker = HeadingTracker()
    p0 = tracker.prior(0.30)
    assert (p0.previous_rad, p0.step_rad) == (0.30, 0.0)
    tracker.update(p0, None, math.inf)
    p1 = tracker.prior(0.32)
    assert p1.step_rad == pytest.approx(0.02)
    assert p1.step_sigma_rad == pytest.approx(math.sqrt(2) * RunConfig().odometry.compass_sigma_rad)
    est = tracker.update(p1, 0.0201, 1e-4)  # the tokens measured the turn far better than the compass
    assert est.heading_rad == pytest.approx(0.3201, abs=2e-4)

    bare = HeadingTracker()
    bare.update(bare.prior(math.nan), None, math.inf)
    for _ in range(10):
        est = bare.update(bare.prior(math.nan), 0.01, 1e-3)
    assert est.heading_rad == pytest.approx(0.10, abs=1e-12)
    assert est.sigma_rad == pytest.approx(math.sqrt(10) * 1e-3)
