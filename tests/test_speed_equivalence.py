"""The speed work of issue 13 changed how things are computed, never what: each faster path gives
bit for bit what the straightforward one gives (the straightforward one is written out here).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovslam.averages import median0
from rovslam.config import LaserConfig
from rovslam.io.sequence import decode_image, to_rgb
from rovslam.process import keep_freed_memory
from rovslam.vision import spots
from rovslam.vision.filters import bandpass, gaussian_kernel, local_variance

_ONES3 = np.ones((3, 3), np.uint8)


def _spot_candidates_reference(image_rgb, config, near_uv_px):
    """The blob search over the whole search window (before the bounding-box crop), as it was."""
    h, w = image_rgb.shape[:2]
    near = near_uv_px[np.all(np.isfinite(near_uv_px), axis=1)]
    reach = config.search_radius_px + np.sqrt(max(config.max_spot_area_px, 1)) + 2.0
    lo = np.floor(near.min(axis=0) - reach)
    hi = np.ceil(near.max(axis=0) + reach) + 1
    u0, v0 = int(max(0, lo[0])), int(max(0, lo[1]))
    u1, v1 = int(min(w, hi[0])), int(min(h, hi[1]))
    crop = image_rgb[v0:v1, u0:u1]
    excess = cv2.subtract(
        np.ascontiguousarray(crop[:, :, 0]),
        cv2.max(np.ascontiguousarray(crop[:, :, 1]), np.ascontiguousarray(crop[:, :, 2])),
    )
    thr = int(np.clip(np.ceil(config.min_red_excess), 1, 255))
    _, mask = cv2.threshold(excess, thr - 1, 1, cv2.THRESH_BINARY)
    if cv2.countNonZero(mask) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    n, labels = cv2.connectedComponents(cv2.dilate(mask, _ONES3), connectivity=8)
    pix = cv2.findNonZero(mask).reshape(-1, 2)
    us, vs = pix[:, 0], pix[:, 1]
    lab = labels[vs, us]
    weight = excess[vs, us].astype(np.float64)
    area = np.bincount(lab, minlength=n)
    total = np.bincount(lab, weight, minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        cu = np.bincount(lab, weight * us, minlength=n) / total + u0
        cv = np.bincount(lab, weight * vs, minlength=n) / total + v0
    keep = (area >= config.min_spot_area_px) & (area <= config.max_spot_area_px) & (total > 0)
    keep[0] = False
    ids, cents, weights = np.flatnonzero(keep), np.column_stack([cu, cv])[keep], total[keep]
    if len(cents):
        close = np.any(np.linalg.norm(cents[:, None, :] - near[None, :, :], axis=2) <= config.search_radius_px, axis=1)
        ids, cents, weights = ids[close], cents[close], weights[close]
    if config.spot_skirt_px > 0 and len(
        ids
    ):  # the centre with the fade beyond the threshold, labels of the whole window
        cents = np.array(
            [_skirt_centre_reference(excess, labels, mask, int(i), int(area[i]), config.spot_skirt_px) for i in ids]
        ) + (u0, v0)
    order = (
        np.lexsort((cents[:, 0], cents[:, 1], -weights)) if len(cents) else np.zeros(0, dtype=np.intp)
    )  # ties: top, left
    return cents[order], weights[order]


def _skirt_centre_reference(excess, labels, mask, label, area_px, skirt_px):
    """The spot centre with its fade, over the whole window's labels (before the per-blob window)."""
    r = int(np.ceil(skirt_px + np.sqrt(area_px / np.pi)))
    reach = r + 2
    blob = ((labels == label) & (mask > 0)).astype(np.uint8)
    bu, bv, bw, bh = cv2.boundingRect(blob)
    u0, v0 = max(0, bu - reach), max(0, bv - reach)
    u1, v1 = min(excess.shape[1], bu + bw + reach), min(excess.shape[0], bv + bh + reach)
    own, lab = blob[v0:v1, u0:u1], labels[v0:v1, u0:u1]
    others = (lab != label) & (lab != 0)
    grown = cv2.dilate(own, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    ring = cv2.dilate(own, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1)))
    ex = excess[v0:v1, u0:u1].astype(np.float64)
    outside = (ring > 0) & (grown == 0) & ~others
    pedestal = float(np.median(ex[outside])) if np.any(outside) else 0.0
    w = np.where((grown > 0) & ~others, np.maximum(ex - pedestal, 0.0), 0.0)
    vv, uu = np.indices(w.shape)
    return float((w * uu).sum() / w.sum() + u0), float((w * vv).sum() / w.sum() + v0)


def _red_image(seed: int, n_blobs: int, h: int = 120, w: int = 160) -> np.ndarray:
    """A textured RGB frame with red blobs of random size, some touching each other or the border."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 90, (h, w, 3), dtype=np.uint8)
    for _ in range(n_blobs):
        cu, cv = rng.uniform(-3, w + 3), rng.uniform(-3, h + 3)
        r = rng.uniform(0.5, 6.0)
        vv, uu = np.mgrid[0:h, 0:w]
        blob = (uu - cu) ** 2 + (vv - cv) ** 2 <= r * r
        img[blob, 0] = rng.integers(150, 256)
        speckle = blob & (rng.random((h, w)) < 0.2)  # 1-px gaps the dilation closes
        img[speckle, 0] = 0
    return img


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1), n_blobs=st.integers(0, 12), n_near=st.integers(1, 4), radius=st.floats(5.0, 60.0)
)
def test_spot_candidates_match_the_whole_window_search(seed, n_blobs, n_near, radius):
    img = _red_image(seed, n_blobs)
    rng = np.random.default_rng(seed + 1)
    near = np.column_stack([rng.uniform(0, 160, n_near), rng.uniform(0, 120, n_near)])
    cfg = LaserConfig(search_radius_px=radius, max_spot_area_px=60)
    got_c, got_w = spots._spot_candidates(img, cfg, near)
    ref_c, ref_w = _spot_candidates_reference(img, cfg, near)
    np.testing.assert_array_equal(got_c, ref_c)
    np.testing.assert_array_equal(got_w, ref_w)


def test_spot_candidates_find_the_blobs_of_a_known_image():
    img = np.zeros((100, 100, 3), np.uint8)
    img[20:23, 30:33, 0] = 200  # 9 px at centre (31, 21)
    img[70:74, 60:64, 0] = 250  # 16 px at centre (61.5, 71.5), the stronger
    cents, weights = spots._spot_candidates(img, LaserConfig(), np.array([[35.0, 25.0], [60.0, 70.0]]))
    np.testing.assert_allclose(cents, [[61.5, 71.5], [31.0, 21.0]])
    np.testing.assert_array_equal(weights, [16 * 250.0, 9 * 200.0])


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.05, 30.0), min_size=1, max_size=9))
def test_small_median_is_numpys(values):
    a = np.array(values)
    assert float(median0(a)) == float(np.median(a))  # the laser fusion's reference altitude


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 255), min_size=1, max_size=60))
def test_uint8_median_is_numpys(values):
    a = np.array(values, np.uint8)
    assert spots._median_u8(a) == float(np.median(a.astype(np.float64)))


@pytest.mark.parametrize("shape", [(272, 360), (57, 91)])
def test_in_place_filters_equal_the_plain_arithmetic(shape):
    rng = np.random.default_rng(3)
    img = (rng.random(shape) * 255).astype(np.float32)
    kf, kc = gaussian_kernel(1.0), gaussian_kernel(4.0)
    ref_bp = cv2.subtract(cv2.sepFilter2D(img, cv2.CV_32F, kf, kf), cv2.sepFilter2D(img, cv2.CV_32F, kc, kc))
    np.testing.assert_array_equal(bandpass(img, 1.0, 4.0), ref_bp)
    mean = cv2.boxFilter(ref_bp, cv2.CV_32F, (16, 16))
    ref_lv = cv2.max(cv2.subtract(cv2.sqrBoxFilter(ref_bp, cv2.CV_32F, (16, 16)), cv2.multiply(mean, mean)), 0.0)
    np.testing.assert_array_equal(local_variance(ref_bp, 16), ref_lv)
    before = img.copy()
    bandpass(img, 0.0, 2.0)
    local_variance(img, 8)
    np.testing.assert_array_equal(img, before)  # the input is never written


def test_rgb_conversion_in_place_only_for_a_freshly_decoded_image():
    rng = np.random.default_rng(4)
    bgr = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    ok, png = cv2.imencode(".png", bgr)
    assert ok
    np.testing.assert_array_equal(decode_image(png.tobytes(), "x.png"), bgr[:, :, ::-1])
    mine = bgr.copy()
    out = to_rgb(mine, "frame")  # not owned: the caller's array is left alone
    np.testing.assert_array_equal(mine, bgr)
    np.testing.assert_array_equal(out, bgr[:, :, ::-1])
    frozen = bgr.copy()
    frozen.setflags(write=False)
    np.testing.assert_array_equal(to_rgb(frozen, "frame", owned=True), bgr[:, :, ::-1])


def test_keep_freed_memory_where_glibc_is():
    import platform
    import sys

    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    assert keep_freed_memory() is glibc


@pytest.mark.parametrize("channel", ["grey", "green", "blue"])
@pytest.mark.parametrize("despeckle_px", [0, 1, 3, 5])
def test_despeckled_channel_is_the_opening_of_the_float_channel(channel, despeckle_px):
    from rovslam.vision.filters import despeckled_channel, remove_specks, template_channel

    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (61, 83, 3), dtype=np.uint8)
    img[rng.random((61, 83)) < 0.02] = 255  # bright specks
    want = remove_specks(template_channel(img, channel), despeckle_px)
    got = despeckled_channel(img, channel, despeckle_px)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(
        despeckled_channel(img[:, :, 1], channel, despeckle_px),
        remove_specks(template_channel(img[:, :, 1], channel), despeckle_px),
    )


def test_despeckled_channel_refuses_what_template_channel_refuses():
    from rovslam.errors import InvalidArgumentError
    from rovslam.vision.filters import despeckled_channel

    with pytest.raises(InvalidArgumentError, match="red is reserved"):
        despeckled_channel(np.zeros((8, 8, 3), np.uint8), "red", 3)
    with pytest.raises(InvalidArgumentError, match="8-bit"):
        despeckled_channel(np.zeros((8, 8, 3), np.float32), "grey", 3)
    with pytest.raises(InvalidArgumentError, match="shape"):
        despeckled_channel(np.zeros((8, 8, 4), np.uint8), "grey", 3)


@pytest.mark.parametrize("scale", [0.0, 0.3, 40.0])
def test_contrast_std_is_numpys_std_up_to_float32_rounding(scale):
    from rovslam.vision.filters import contrast_std

    rng = np.random.default_rng(6)
    img = (rng.standard_normal((272, 360)) * scale).astype(np.float32)
    ref = float(img.astype(np.float64).std())
    assert contrast_std(img) == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert contrast_std(img) == pytest.approx(float(img.std()), rel=1e-5, abs=1e-7)


def test_self_similarity_flat_and_textured_windows():
    from rovslam.vision.templates import self_similarity

    rng = np.random.default_rng(7)
    flat = np.full((80, 80), 3.0, np.float32)
    assert self_similarity(flat, (30, 30), 16, 8) == 1.0  # cannot be correlated: as ambiguous as it gets
    noise = rng.standard_normal((80, 80)).astype(np.float32)
    assert self_similarity(noise, (30, 30), 16, 8) < 0.6  # white noise: no look-alike neighbour
    tiled = np.tile(noise[:10, :10], (8, 8))  # period 10 px: the neighbour 10 px away is the window itself
    assert self_similarity(tiled, (30, 30), 16, 12) == pytest.approx(1.0, abs=1e-5)


def test_extract_reuses_the_reduction_track_made_of_the_same_image():
    from rovslam.config import SpeedTemplateConfig, TrackerConfig
    from rovslam.vision.tracking import TokenTracker, global_scale, reduce_image

    rng = np.random.default_rng(8)
    frames = [cv2.GaussianBlur(rng.standard_normal((272, 360)).astype(np.float32) * 20, (0, 0), 1.5) for _ in range(3)]
    lv = [local_variance(f, 16) for f in frames]
    tr = TokenTracker(SpeedTemplateConfig(), TrackerConfig())
    tr.extract(frames[0], lv[0])
    for f, v in zip(frames[1:], lv[1:]):
        tr.track(f, None)
        tr.extract(f, v)
        np.testing.assert_array_equal(tr._prev_small, reduce_image(f, global_scale(f.shape)))
    other = frames[0] + 1.0  # a different image than the one tracked: reduced afresh, not reused
    tr.track(frames[1], None)
    tr.extract(other, lv[0])
    np.testing.assert_array_equal(tr._prev_small, reduce_image(other, global_scale(other.shape)))


def _best_hypothesis_reference(a, b, prior_rad, prior_var, thr, sigma0, joint):
    """The hypothesis search with one pair at a time (a Python loop, ``rot2(t) @ v``), as it was."""
    from rovslam.camera import rot2, wrap_angle
    from rovslam.sensor.odometry import _MAX_HYPOTHESES

    thetas = [prior_rad]
    ds = [np.median(a - b @ rot2(prior_rad).T, axis=0)]
    pick = (
        np.linspace(0, len(a) - 1, _MAX_HYPOTHESES).astype(np.intp) if len(a) > _MAX_HYPOTHESES else np.arange(len(a))
    )
    singles = a[pick] - b[pick] @ rot2(prior_rad).T
    thetas += [prior_rad] * len(singles)
    ds += list(singles)
    if joint and len(a) >= 2:
        i, j = np.triu_indices(len(a), 1)
        da, db = a[i] - a[j], b[i] - b[j]
        base2 = np.einsum("kj,kj->k", db, db)
        keep = base2 >= max((8.0 * thr) ** 2, float(np.max(base2)) / 16.0)
        if np.any(keep) and len(keep) > _MAX_HYPOTHESES:
            keep &= base2 >= np.sort(base2)[-_MAX_HYPOTHESES]
        th = np.arctan2(da[keep, 1], da[keep, 0]) - np.arctan2(db[keep, 1], db[keep, 0])
        th = prior_rad + wrap_angle(th - prior_rad)
        for t, ii, jj in zip(th, i[keep], j[keep]):
            thetas.append(float(t))
            ds.append(0.5 * (a[ii] + a[jj]) - rot2(t) @ (0.5 * (b[ii] + b[jj])))
    thetas_a, ds_a = np.asarray(thetas), np.asarray(ds)
    c, s = np.cos(thetas_a)[:, None], np.sin(thetas_a)[:, None]
    rb = np.stack([c * b[None, :, 0] - s * b[None, :, 1], s * b[None, :, 0] + c * b[None, :, 1]], axis=-1)
    r2 = np.einsum("kmj,kmj->km", a[None] - rb - ds_a[:, None, :], a[None] - rb - ds_a[:, None, :])
    score = np.minimum(r2, thr**2).sum(axis=1) / sigma0**2
    if joint and prior_var > 0:
        score = score + wrap_angle(thetas_a - prior_rad) ** 2 / prior_var
    k = int(np.argmin(score))
    return float(thetas_a[k]), ds_a[k], r2[k] <= thr**2


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 14),
    joint=st.booleans(),
    turn=st.floats(-0.2, 0.2),
    outliers=st.integers(0, 4),
)
def test_best_hypothesis_is_the_pair_by_pair_search(seed, n, joint, turn, outliers):
    """Rigid-motion hypotheses of all token pairs at once: the same turn, translation and inliers, bit for bit."""
    from rovslam.camera import rot2
    from rovslam.sensor.odometry import _best_hypothesis

    rng = np.random.default_rng(seed)
    b = rng.uniform(-0.2, 0.2, (n, 2))
    a = b @ rot2(turn).T + rng.uniform(-0.05, 0.05, 2) + rng.normal(0, 2e-4, (n, 2))
    a[: min(outliers, n)] += rng.normal(0, 0.01, (min(outliers, n), 2))  # tokens that disagree
    args = (a, b, turn + rng.normal(0, 0.01), 1e-4, 6e-4, 3e-4, joint)
    theta, d, inl = _best_hypothesis(*args)
    theta_ref, d_ref, inl_ref = _best_hypothesis_reference(*args)
    assert theta == theta_ref
    assert np.array_equal(d, d_ref)
    assert np.array_equal(inl, inl_ref)
