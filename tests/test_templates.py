"""Template extraction and inhibition masks (rovslam.vision.templates)."""

from __future__ import annotations

import numpy as np
import pytest
from synth import draw_laser_spots, laser_hit_pixels, paper_camera, paper_lasers, seabed_frame, seabed_spectrum

from rovslam.config import BandpassConfig, LandmarkTemplateConfig, LaserConfig, SpeedTemplateConfig
from rovslam.errors import InvalidArgumentError
from rovslam.vision.filters import bandpass, local_variance, template_channel
from rovslam.vision.laser import LaserAltimeter
from rovslam.vision.templates import (
    Template,
    extract_templates,
    inhibit_boxes,
    inhibition_mask,
    window_inhibited,
)

BP = BandpassConfig()


def _filtered(rgb: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    channel = template_channel(rgb, BP.channel)
    bp = bandpass(channel, BP.sigma_fine_px, BP.sigma_coarse_px)
    return bp, local_variance(bp, size)


def _windows_overlap(a: Template, b: Template) -> bool:
    d = np.abs(a.centre_uv_px - b.centre_uv_px)
    return bool(d[0] < a.size_px and d[1] < a.size_px)


def _min_distance_to_window(t: Template, point_uv: np.ndarray) -> float:
    """Distance from a point to the nearest pixel centre of the template's window."""
    lo = t.top_left_uv_px
    hi = lo + t.size_px - 1
    nearest = np.clip(point_uv, lo, hi)
    return float(np.linalg.norm(point_uv - nearest))


def test_inhibition_mask_discs_have_the_right_pixels():
    mask = inhibition_mask((40, 50), np.array([[10.0, 20.0], [np.nan, 3.0]]), 3.0)
    assert mask.dtype == np.bool_ and mask.shape == (40, 50)
    assert mask.sum() == 29  # lattice points within radius 3 of a lattice point
    assert mask[20, 10] and mask[20, 13] and not mask[22, 13]
    # Sub-pixel centre, clipped at the border, added in place.
    out = inhibition_mask((40, 50), [[0.5, 0.5]], 1.0, out=mask)
    assert out is mask
    assert mask[0, 0] and mask[1, 1] and mask[0, 1] and not mask[2, 2]


def test_inhibition_mask_with_no_points_is_empty_and_checks_input():
    assert not inhibition_mask((5, 6), None, 4.0).any()
    assert not inhibition_mask((5, 6), np.zeros((0, 2)), 4.0).any()
    with pytest.raises(InvalidArgumentError, match="radius"):
        inhibition_mask((5, 6), [[1.0, 1.0]], -1.0)
    with pytest.raises(InvalidArgumentError, match=r"\(N, 2\)"):
        inhibition_mask((5, 6), np.zeros((3, 3)), 1.0)


def test_inhibit_boxes_marks_squares_in_place():
    mask = np.zeros((30, 30), bool)
    inhibit_boxes(mask, np.array([[10.5, 12.5]]), 2.5)  # a 6x6 template-sized box
    assert mask.sum() == 36
    assert mask[10:16, 8:14].all()
    inhibit_boxes(mask, np.array([[29.0, 29.0]]), 1.0)
    assert mask.sum() == 36 + 4
    with pytest.raises(InvalidArgumentError, match="bool"):
        inhibit_boxes(np.zeros((3, 3), np.uint8), [[1.0, 1.0]], 1.0)


def test_extract_templates_threshold_centre_and_patch():
    # One 8x8 square of 20 grey levels on a flat image: a 16x16 window holding it covers a
    # fraction p = 1/4 at 20, variance 20^2 p (1 - p) = 75 grey levels squared.
    img = np.zeros((64, 64), np.float32)
    img[20:28, 30:38] = 20.0
    lv = local_variance(img, 16)
    assert lv.max() == pytest.approx(75.0, rel=1e-5)
    tpls = extract_templates(img, lv, 16, 8, 74.9)
    assert len(tpls) == 1
    t = tpls[0]
    u0, v0 = (int(x) for x in t.top_left_uv_px)
    assert np.array_equal(t.patch, img[v0 : v0 + 16, u0 : u0 + 16])
    assert np.allclose(t.centre_uv_px, [u0 + 7.5, v0 + 7.5])
    assert t.local_variance == pytest.approx(75.0, rel=1e-5)
    # The window holds the whole square (variance maximal).
    assert u0 <= 30 and u0 + 16 >= 38 and v0 <= 20 and v0 + 16 >= 28
    assert extract_templates(img, lv, 16, 8, 75.1) == []


def test_extract_templates_on_texture_non_overlapping_strongest_first_inside_border():
    spec = seabed_spectrum(seed=11)
    rgb = seabed_frame(spec, (30.0, 40.0), seed=1)
    cfg = SpeedTemplateConfig()
    bp, lv = _filtered(rgb, cfg.size_px)
    tpls = extract_templates(bp, lv, cfg.size_px, cfg.max_count, cfg.min_local_variance, cfg.border_px)
    assert len(tpls) == cfg.max_count == 8
    variances = [t.local_variance for t in tpls]
    assert variances == sorted(variances, reverse=True)
    assert variances[0] == pytest.approx(
        float(lv[cfg.border_px + 8 : -cfg.border_px - 7, cfg.border_px + 8 : -cfg.border_px - 7].max())
    )
    for i, a in enumerate(tpls):
        assert a.patch.shape == (16, 16) and a.patch.dtype == np.float32
        assert a.local_variance >= cfg.min_local_variance
        lo, hi = a.top_left_uv_px, a.top_left_uv_px + 15
        assert lo.min() >= cfg.border_px and hi[0] <= 359 - cfg.border_px and hi[1] <= 271 - cfg.border_px
        for b in tpls[i + 1 :]:
            assert not _windows_overlap(a, b)


def test_min_spacing_spreads_the_tokens():
    spec = seabed_spectrum(seed=11)
    rgb = seabed_frame(spec, (30.0, 40.0), seed=1)
    cfg = SpeedTemplateConfig()
    bp, lv = _filtered(rgb, cfg.size_px)
    tight = extract_templates(bp, lv, 16, 30, cfg.min_local_variance, cfg.border_px)
    wide = extract_templates(bp, lv, 16, 30, cfg.min_local_variance, cfg.border_px, min_spacing_px=40)
    assert len(wide) >= 8 and wide[0].local_variance == tight[0].local_variance  # the strongest is kept
    for i, a in enumerate(wide):
        for b in wide[i + 1 :]:
            assert np.max(np.abs(a.centre_uv_px - b.centre_uv_px)) >= 40
    gaps = [np.max(np.abs(a.centre_uv_px - b.centre_uv_px)) for i, a in enumerate(tight) for b in tight[i + 1 :]]
    assert min(gaps) < 40  # without the spacing they crowd (one structure can carry several)


def test_extract_templates_honours_the_inhibition_mask():
    spec = seabed_spectrum(seed=12)
    rgb = seabed_frame(spec, (5.0, 9.0), seed=2)
    bp, lv = _filtered(rgb, 16)
    free = extract_templates(bp, lv, 16, 3, 4.0, 4)
    mask = np.zeros(bp.shape, bool)
    inhibit_boxes(mask, np.array([t.centre_uv_px for t in free]), 7.5)  # forbid the best three
    again = extract_templates(bp, lv, 16, 40, 4.0, 4, inhibit=mask)
    assert len(again) > 10
    for t in again:
        u0, v0 = (int(x) for x in t.top_left_uv_px)
        assert not mask[v0 : v0 + 16, u0 : u0 + 16].any()


def test_landmark_templates_keep_away_from_laser_spots_and_each_other():
    cam, lasers = paper_camera(), paper_lasers()
    laser_cfg, lm = LaserConfig(), LandmarkTemplateConfig()
    spec = seabed_spectrum(seed=13)
    rgb = seabed_frame(spec, (20.0, 20.0), seed=3)
    rgb = draw_laser_spots(rgb, laser_hit_pixels(cam, lasers, 1.31), seed=3)
    est = LaserAltimeter(cam, lasers, laser_cfg, 1.31).measure(rgb)
    assert len(est.spots_uv_px) == 4
    bp, lv = _filtered(rgb, lm.size_px)

    # Without the mask the spots attract templates (they are high-variance blobs) ...
    unmasked = extract_templates(bp, lv, lm.size_px, 40, lm.min_local_variance, lm.border_px)
    near = [
        t for t in unmasked for s in est.spots_uv_px if _min_distance_to_window(t, s) <= laser_cfg.inhibit_radius_px
    ]
    assert near
    # ... with it, no template window comes within the inhibition radius of a spot.
    mask = inhibition_mask(bp.shape, est.spots_uv_px, laser_cfg.inhibit_radius_px)
    tpls = extract_templates(bp, lv, lm.size_px, 40, lm.min_local_variance, lm.border_px, inhibit=mask)
    assert len(tpls) >= 10
    for i, t in enumerate(tpls):
        assert t.local_variance >= 12.3
        for s in est.spots_uv_px:
            assert _min_distance_to_window(t, s) > laser_cfg.inhibit_radius_px
        for other in tpls[i + 1 :]:
            assert not _windows_overlap(t, other)


@pytest.mark.parametrize("value", [0, 128, 255])
@pytest.mark.parametrize("noise", [False, True])
def test_flat_black_and_saturated_frames_give_no_templates(value, noise):
    rgb = np.full((272, 360, 3), value, np.uint8)
    if noise:  # sensor noise on a featureless frame stays below both thresholds
        rng = np.random.default_rng(value)
        rgb = np.clip(rgb + rng.normal(0, 3.0, rgb.shape), 0, 255).astype(np.uint8)
    for size, count, thr, border in [
        (16, 8, SpeedTemplateConfig().min_local_variance, 4),
        (32, 5, LandmarkTemplateConfig().min_local_variance, 8),
    ]:
        bp, lv = _filtered(rgb, size)
        assert extract_templates(bp, lv, size, count, thr, border) == []


def test_extract_templates_zero_threshold_still_refuses_flat_windows():
    img = np.full((40, 40), 7.0, np.float32)
    assert extract_templates(img, local_variance(img, 8), 8, 5, 0.0) == []


def test_extract_templates_input_checks():
    img = np.zeros((40, 40), np.float32)
    lv = np.zeros((40, 40), np.float32)
    with pytest.raises(InvalidArgumentError, match="same shape"):
        extract_templates(img, lv[:-1], 16, 8, 4.0)
    with pytest.raises(InvalidArgumentError, match="max_count"):
        extract_templates(img, lv, 16, -1, 4.0)
    with pytest.raises(InvalidArgumentError, match="inhibit"):
        extract_templates(img, lv, 16, 8, 4.0, inhibit=np.zeros((40, 40), np.uint8))
    assert extract_templates(img, lv, 16, 0, 4.0) == []
    assert extract_templates(img, lv, 16, 8, 4.0, border_px=20) == []


def test_template_is_frozen_and_read_only():
    img = np.random.default_rng(5).normal(0, 10, (40, 40)).astype(np.float32)
    (t,) = extract_templates(img, local_variance(img, 8), 8, 1, 1.0)
    with pytest.raises(AttributeError):
        t.local_variance = 3.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        t.patch[0, 0] = 1.0


def test_inhibited_windows_are_exactly_those_touching_a_forbidden_pixel():
    # One forbidden pixel at (24, 24) and a single candidate window per case: the window is
    # refused iff it contains the pixel (windows that just miss it are allowed).
    rng = np.random.default_rng(6)
    img = rng.normal(0, 5, (48, 48)).astype(np.float32)
    mask = np.zeros((48, 48), bool)
    mask[24, 24] = True
    for u0, v0 in [(25, 10), (9, 24), (8, 24), (24, 9), (24, 25), (9, 9), (25, 25)]:
        lv = np.zeros((48, 48), np.float32)
        lv[v0 + 8, u0 + 8] = 50.0  # the only candidate: window with top-left (u0, v0)
        got = extract_templates(img, lv, 16, 1, 1.0, inhibit=mask)
        touches = u0 <= 24 <= u0 + 15 and v0 <= 24 <= v0 + 15
        assert (len(got) == 0) == touches, (u0, v0)


def test_window_inhibited_rounds_the_centre_to_the_window():
    mask = np.zeros((40, 40), bool)
    mask[20, 20] = True
    assert window_inhibited(mask, (12.5, 12.5), (16, 16))  # window 5..20
    assert not window_inhibited(mask, (11.5, 12.5), (16, 16))  # window u 4..19
    assert not window_inhibited(mask, (-30.0, -30.0), (16, 16))


def test_second_peak_is_the_highest_other_local_maximum_as_numpy_finds_it():
    """OpenCV's masked maximum gives NumPy's masked maximum, -1 when no local maximum is left."""
    import cv2

    from rovslam.vision.templates import second_peak

    rng = np.random.default_rng(11)
    for k in range(400):
        h, w = (int(v) for v in rng.integers(1, 25, 2))
        corr = rng.uniform(-1.05, 1.0, (h, w)).astype(np.float32)
        if k % 4 == 0:
            corr = np.round(corr, 1)  # ties: plateaus are local maxima too
        pu, pv, ex = int(rng.integers(0, w)), int(rng.integers(0, h)), int(rng.integers(0, 6))
        is_max = corr >= cv2.dilate(corr, np.ones((3, 3), np.uint8))
        is_max[max(0, pv - ex) : pv + ex + 1, max(0, pu - ex) : pu + ex + 1] = False
        assert second_peak(corr, pu, pv, ex) == float(np.max(corr, where=is_max, initial=-1.0))
    flat = np.full((5, 5), 0.3, np.float32)
    assert second_peak(flat, 2, 2, 10) == -1.0  # every maximum inside the exclusion
