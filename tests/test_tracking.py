"""Normalised-correlation tracking, global shift and the token tracker (rovslam.vision.tracking)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from synth import DEFAULT_NOISE_SIGMA, seabed_frame, seabed_spectrum

from rovslam.config import BandpassConfig, SpeedTemplateConfig, TrackerConfig
from rovslam.errors import ConfigError, InvalidArgumentError
from rovslam.vision.filters import bandpass, local_variance, template_channel
from rovslam.vision.templates import extract_templates
from rovslam.vision.tracking import (
    REASON_AMBIGUOUS,
    REASON_BORDER,
    REASON_FLAT,
    REASON_INHIBITED,
    REASON_LOW,
    REASON_OUTSIDE,
    TokenTracker,
    _subpixel_offset,
    global_shift,
    match_template,
)

BP = BandpassConfig()
SPEED = SpeedTemplateConfig()
TRACK = TrackerConfig()
SPEC = seabed_spectrum(seed=21)


def _track_img(rgb: np.ndarray) -> np.ndarray:
    return bandpass(template_channel(rgb, BP.channel), BP.sigma_fine_px, BP.sigma_coarse_px)


def _pair(offset0, shift_uv, seed, noise=DEFAULT_NOISE_SIGMA):
    """Two tracking images whose content moves by ``shift_uv``: curr(p) = prev(p - shift)."""
    o0 = np.asarray(offset0, float)
    prev = _track_img(seabed_frame(SPEC, tuple(o0), seed=seed, noise_sigma=noise))
    curr = _track_img(seabed_frame(SPEC, tuple(o0 - np.asarray(shift_uv)), seed=seed + 1000, noise_sigma=noise))
    return prev, curr


def _tracking_errors(noise: float, n_pairs: int = 6) -> tuple[np.ndarray, int, int]:
    """Errors (K, 2) of the speed tokens tracked across exact sub-pixel shifts."""
    rng = np.random.default_rng(7)
    errs, n_given, n_ok = [], 0, 0
    for k in range(n_pairs):
        shift = rng.uniform(-6.0, 6.0, 2)
        prev, curr = _pair(rng.uniform(0, 120, 2), shift, seed=k, noise=noise)
        tracker = TokenTracker(SPEED, TRACK)
        tracker.extract(prev, local_variance(prev, SPEED.size_px))
        prediction = shift + rng.uniform(-2.0, 2.0, 2)  # a speed-based prediction, 2 px off
        tracks = tracker.track(curr, prediction)
        assert not tracks.used_global_search
        n_given += tracks.n_given
        n_ok += tracks.n_tracked
        errs.append(tracks.displacements_uv_px - shift)
    return np.concatenate(errs), n_given, n_ok


def test_speed_tokens_found_again_within_0_1_px_rms_without_noise():
    errs, n_given, n_ok = _tracking_errors(noise=0.0)
    rms = float(np.sqrt(np.mean(np.sum(errs**2, axis=1))))
    assert n_given == 48 and n_ok >= 46
    assert rms < 0.1
    assert np.abs(errs).max() < 0.25


def test_speed_tokens_found_again_within_0_3_px_rms_with_default_noise():
    errs, n_given, n_ok = _tracking_errors(noise=DEFAULT_NOISE_SIGMA)
    rms = float(np.sqrt(np.mean(np.sum(errs**2, axis=1))))
    assert n_ok >= 44
    assert rms < 0.3
    assert np.abs(errs).max() < 0.6


def test_shift_beyond_the_search_radius_reports_lost_not_a_wrong_position():
    radius = SPEED.search_radius_px
    rng = np.random.default_rng(8)
    n_tested = 0
    for k, extra in enumerate([1, 2, 4, 7, 12]):
        direction = rng.choice([-1.0, 1.0], 2) * rng.permutation([1.0, rng.uniform(0, 1)])
        shift = direction * (radius + extra) + rng.uniform(-0.4, 0.4, 2)
        prev, curr = _pair(rng.uniform(0, 120, 2), shift, seed=100 + k)
        for t in extract_templates(prev, local_variance(prev, 16), 16, 8, SPEED.min_local_variance, 24):
            m = match_template(curr, t.patch, t.centre_uv_px, radius, TRACK)  # predicted: no motion
            n_tested += 1
            assert not m.ok, (shift, m)
            assert m.reason in (REASON_LOW, REASON_BORDER, REASON_AMBIGUOUS)
    assert n_tested == 40


def test_match_template_recovers_a_known_offset_and_reports_the_centre():
    prev, curr = _pair((50.0, 60.0), (3.25, -2.5), seed=3, noise=0.0)
    (t,) = extract_templates(prev, local_variance(prev, 16), 16, 1, 4.0, 30)
    m = match_template(curr, t.patch, t.centre_uv_px, 8, TRACK)
    assert m.ok and m.reason == ""
    assert m.score > 0.97
    assert np.allclose(m.uv_px, t.centre_uv_px + [3.25, -2.5], atol=0.1)
    assert -1.0 <= m.second_score < TRACK.max_second_peak_ratio * m.score


def test_correlation_threshold_is_at_or_above():
    prev, curr = _pair((10.0, 10.0), (1.0, 1.0), seed=4)
    (t,) = extract_templates(prev, local_variance(prev, 16), 16, 1, 4.0, 30)
    m = match_template(curr, t.patch, t.centre_uv_px + 1, 8, TRACK)
    assert m.ok
    at = dataclasses.replace(TRACK, min_correlation=m.score)
    assert match_template(curr, t.patch, t.centre_uv_px + 1, 8, at).ok
    above = dataclasses.replace(TRACK, min_correlation=float(np.nextafter(np.float32(m.score), 2)))
    lost = match_template(curr, t.patch, t.centre_uv_px + 1, 8, above)
    assert not lost.ok and lost.reason == REASON_LOW and lost.score == pytest.approx(m.score)


def test_periodic_texture_is_ambiguous():
    u = np.arange(120)
    stripes = np.tile(20.0 * np.sin(2 * np.pi * u / 6.0), (100, 1)).astype(np.float32)
    stripes += np.random.default_rng(9).normal(0, 0.5, stripes.shape).astype(np.float32)
    patch = stripes[40:56, 50:66].copy()
    m = match_template(stripes, patch, (57.5, 47.5), 8, TRACK)
    assert not m.ok and m.reason == REASON_AMBIGUOUS
    assert m.second_score > 0.95


def test_windows_outside_the_image_flat_templates_and_flat_images():
    img = np.random.default_rng(10).normal(0, 10, (60, 80)).astype(np.float32)
    patch = img[20:36, 30:46].copy()
    assert match_template(img, patch, (-50.0, 10.0), 8, TRACK).reason == REASON_OUTSIDE
    assert match_template(img, patch, (np.nan, 10.0), 8, TRACK).reason == REASON_OUTSIDE
    assert match_template(img, np.zeros((16, 16), np.float32), (37.5, 27.5), 8, TRACK).reason == REASON_FLAT
    flat = np.zeros((60, 80), np.float32)
    m = match_template(flat, patch, (37.5, 27.5), 8, TRACK)
    assert not m.ok
    # Clipped by the image border: the true position is on the clipped window's edge.
    edge = img[0:16, 10:26].copy()
    m = match_template(img, edge, (17.5, 7.5), 8, TRACK)
    assert not m.ok and m.reason == REASON_BORDER


def test_match_template_input_checks():
    img = np.zeros((30, 30), np.float32)
    with pytest.raises(InvalidArgumentError, match="search radius"):
        match_template(img, img[:8, :8], (10.0, 10.0), 0, TRACK)
    with pytest.raises(ConfigError, match="subpixel"):
        match_template(img, img[:8, :8], (10.0, 10.0), 4, dataclasses.replace(TRACK, subpixel="cubic"))
    with pytest.raises(InvalidArgumentError, match="2 numbers"):
        match_template(img, img[:8, :8], (10.0, 10.0, 1.0), 4, TRACK)
    with pytest.raises(InvalidArgumentError, match="2-D"):
        match_template(np.zeros((30, 30, 3), np.float32), img[:8, :8], (10.0, 10.0), 4, TRACK)


def test_subpixel_fit_is_exact_for_an_oblique_paraboloid_and_a_gaussian():
    du, dv = 0.3, -0.2
    y, x = np.mgrid[-1:2, -1:2].astype(float)
    a, b, c = 2.0, 0.8, 1.0  # elongated, oblique (cross term b)
    q = 1.0 - (a * (x - du) ** 2 + 2 * b * (x - du) * (y - dv) + c * (y - dv) ** 2) / 10.0
    assert np.allclose(_subpixel_offset(q, "parabolic"), [du, dv], atol=1e-9)
    g = np.exp(-((x - du) ** 2 + (y - dv) ** 2) / 2.0)
    assert np.allclose(_subpixel_offset(g, "gaussian"), [du, dv], atol=1e-9)
    assert np.allclose(_subpixel_offset(g, "none"), 0.0)


@pytest.mark.parametrize("shift", [(3.3, -2.2), (-118.0, 4.0), (6.0, 89.0), (-110.5, -80.25)])
def test_global_shift_finds_shifts_up_to_a_third_of_the_image(shift):
    prev, curr = _pair((130.0, 100.0), shift, seed=11)
    found, confidence = global_shift(prev, curr)
    assert np.allclose(found, shift, atol=0.3)
    assert confidence > 0.1


def test_global_shift_checks_shapes():
    with pytest.raises(InvalidArgumentError, match="same shape"):
        global_shift(np.zeros((10, 10), np.float32), np.zeros((10, 12), np.float32))


def test_token_tracker_recovers_a_large_unknown_motion():
    shift = np.array([-100.0, 70.0])  # more than a quarter of the image each way
    prev, curr = _pair((140.0, 110.0), shift, seed=12)
    tracker = TokenTracker(SPEED, TRACK)
    assert tracker.track(prev, None).n_given == 0  # nothing yet: empty, no error
    assert tracker.extract(prev, local_variance(prev, 16)) == 8
    tracks = tracker.track(curr, None)
    assert tracks.used_global_search
    assert np.allclose(tracks.global_shift_uv_px, shift, atol=0.5)
    assert tracks.n_given == 8
    # Tokens that left the image are lost, the others are found at the right place.
    assert tracks.n_tracked >= 2
    assert np.all(np.abs(tracks.displacements_uv_px - shift) < 0.5)
    assert len(tracks.reasons) == 8 and tracks.reasons.count("") == tracks.n_tracked
    assert REASON_OUTSIDE in tracks.reasons


def test_token_tracker_falls_back_when_the_predicted_windows_fail():
    shift = np.array([25.0, -18.0])
    prev, curr = _pair((60.0, 60.0), shift, seed=13)
    tracker = TokenTracker(SPEED, TRACK)
    tracker.extract(prev, local_variance(prev, 16))
    tracks = tracker.track(curr, np.zeros(2))  # stale prediction: 31 px off
    assert tracks.used_global_search and tracks.n_tracked >= 6
    assert np.all(np.abs(tracks.displacements_uv_px - shift) < 0.5)
    # Without the global search the same call loses every token rather than mislocating one.
    no_global = TokenTracker(SPEED, dataclasses.replace(TRACK, global_search=False))
    no_global.extract(prev, local_variance(prev, 16))
    lost = no_global.track(curr, np.zeros(2))
    assert lost.n_tracked == 0 and not lost.used_global_search and lost.n_given == 8


def test_token_tracker_refuses_matches_on_inhibited_pixels_and_resets():
    prev, curr = _pair((20.0, 30.0), (2.0, 1.0), seed=14)
    tracker = TokenTracker(SPEED, TRACK)
    tracker.extract(prev, local_variance(prev, 16))
    first = tracker.tokens[0].centre_uv_px + [2.0, 1.0]
    mask = np.zeros(curr.shape, bool)
    mask[int(first[1]), int(first[0])] = True
    tracks = tracker.track(curr, np.array([2.0, 1.0]), mask)
    assert tracks.reasons[0] == REASON_INHIBITED
    assert tracks.n_tracked == 7
    tracker.reset()
    assert tracker.tokens == () and tracker.track(curr, None).n_tracked == 0


def test_token_tracker_input_checks():
    tracker = TokenTracker(SPEED, TRACK)
    prev, curr = _pair((0.0, 0.0), (1.0, 1.0), seed=15)
    tracker.extract(prev, local_variance(prev, 16))
    with pytest.raises(InvalidArgumentError, match="predicted_shift_uv_px"):
        tracker.track(curr, np.array([np.nan, 0.0]))
    with pytest.raises(InvalidArgumentError, match="reset"):
        tracker.track(cv2.resize(curr, (100, 80)), None)
    with pytest.raises(ConfigError, match="min_tracked_fraction"):
        TokenTracker(SPEED, dataclasses.replace(TRACK, min_tracked_fraction=2.0))
