"""Small-array paths computed on Python floats or with fewer NumPy calls, and image stages computed
with fewer or cheaper passes, give bit for bit what the form they replace gives (that form is
written out here, as the code had it)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovslam.camera import Camera
from rovslam.errors import FilterInconsistencyError
from rovslam.slam.apparent import apparent_frame_cov_m2
from rovslam.slam.health import check_blocks
from rovslam.slam.observation import observation_jacobians, observation_noise_px2
from rovslam.vision import spots
from rovslam.vision.scale import ProcessingScale
from rovslam.vision.templates import inhibition_mask, second_peak, window_inhibited

_ONES3 = np.ones((3, 3), np.uint8)
_FINITE = st.floats(-1e4, 1e4, allow_nan=False)
_SIGMA = st.one_of(st.just(0.0), st.floats(1e-6, 10.0))


def _noise_reference(mn_px, pixel_sigma_px, altitude_m, altitude_sigma_m, heading_sigma_rad):
    mn = np.asarray(mn_px, dtype=np.float64).reshape(2)
    r = np.eye(2) * pixel_sigma_px**2
    if altitude_sigma_m > 0.0:
        r += (altitude_sigma_m / altitude_m) ** 2 * np.outer(mn, mn)
    if heading_sigma_rad > 0.0:
        j = np.array([mn[1], -mn[0]])
        r += heading_sigma_rad**2 * np.outer(j, j)
    return r


@settings(max_examples=300, deadline=None)
@given(_FINITE, _FINITE, st.floats(0.01, 10.0), st.floats(0.1, 20.0), _SIGMA, _SIGMA)
def test_observation_noise_is_the_matrix_form(m, n, pixel_sigma, altitude, altitude_sigma, heading_sigma):
    fast = observation_noise_px2(np.array([m, n]), pixel_sigma, altitude, altitude_sigma, heading_sigma)
    ref = _noise_reference(np.array([m, n]), pixel_sigma, altitude, altitude_sigma, heading_sigma)
    assert fast.dtype == ref.dtype and fast.shape == (2, 2)
    assert fast.tobytes() == ref.tobytes()


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(_FINITE, _FINITE), max_size=5), st.floats(-7.0, 7.0))
def test_heading_jacobian_is_the_column_stack(rows, heading):
    mn = np.array(rows, dtype=np.float64).reshape(-1, 2)
    a, j_psi = observation_jacobians(mn, heading, 3.0, 800.0)
    ref = np.column_stack([mn[:, 1], -mn[:, 0]])
    assert j_psi.shape == ref.shape and j_psi.tobytes() == ref.tobytes()
    assert a.shape == (2, 2)


@settings(max_examples=300, deadline=None)
@given(_FINITE, _FINITE, st.floats(0.1, 20.0), _SIGMA, _SIGMA, _SIGMA)
def test_apparent_cov_of_one_position_is_the_batch_row(x, y, depth, tilt, rotation, scale):
    one = apparent_frame_cov_m2(np.array([x, y]), depth, tilt, rotation, scale)
    batch = apparent_frame_cov_m2(np.array([[x, y]]), np.array([depth]), tilt, rotation, scale)
    assert one.shape == (2, 2) and one.tobytes() == batch[0].tobytes()


def _discs_reference(shape_hw, points, radius):
    h, w = shape_hw
    out = np.zeros((h, w), dtype=bool)
    r = float(radius)
    for pu, pv in points:
        u0, u1 = max(0, int(np.ceil(pu - r))), min(w - 1, int(np.floor(pu + r)))
        v0, v1 = max(0, int(np.ceil(pv - r))), min(h - 1, int(np.floor(pv + r)))
        if u0 > u1 or v0 > v1:
            continue
        du = np.arange(u0, u1 + 1) - pu
        dv = np.arange(v0, v1 + 1) - pv
        out[v0 : v1 + 1, u0 : u1 + 1] |= (dv[:, None] ** 2 + du[None, :] ** 2) <= r * r
    return out


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-30.0, 90.0), st.floats(-30.0, 70.0)), max_size=5),
    st.one_of(st.integers(0, 20).map(float), st.floats(0.0, 25.0)),
)
def test_inhibition_discs_are_the_per_point_arrays(points, radius):
    pts = np.array(points, dtype=np.float64).reshape(-1, 2)
    assert np.array_equal(inhibition_mask((40, 60), pts, radius), _discs_reference((40, 60), pts, radius))


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(3, 30), st.integers(3, 30), st.integers(0, 4), st.booleans())
def test_second_peak_is_the_boolean_mask_form(seed, h, w, exclusion, coarse):
    rng = np.random.default_rng(seed)
    corr = (rng.random((h, w)) * 2 - 1).astype(np.float32)
    if coarse:  # plateaus: ties between a pixel and its dilation
        corr = np.round(corr * 3) / np.float32(3)
    pu, pv = int(rng.integers(0, w)), int(rng.integers(0, h))
    is_max = corr >= cv2.dilate(corr, _ONES3)
    is_max[max(0, pv - exclusion) : pv + exclusion + 1, max(0, pu - exclusion) : pu + exclusion + 1] = False
    ref = max(-1.0, float(corr[is_max].max())) if is_max.any() else -1.0
    assert second_peak(corr, pu, pv, exclusion) == ref


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-20.0, 80.0), st.floats(-20.0, 60.0), st.sampled_from([16, 32, 7]))
def test_window_check_rounds_as_numpy(seed, cu, cv, size):
    mask = np.random.default_rng(seed).random((40, 60)) < 0.02
    u0 = int(np.rint(cu - 0.5 * (size - 1)))
    v0 = int(np.rint(cv - 0.5 * (size - 1)))
    ref = bool(mask[max(0, v0) : max(0, v0 + size), max(0, u0) : max(0, u0 + size)].any())
    assert window_inhibited(mask, np.array([cu, cv]), (size, size)) == ref


def _block_sums_reference(ch, k, shape_hw):
    """The k x k block averages summed by ``cv2.add`` in float32, rows then columns."""
    ch = np.ascontiguousarray(ch)
    rows = cv2.add(ch[0::k], ch[1::k], dtype=cv2.CV_32F)
    for j in range(2, k):
        rows = cv2.add(rows, ch[j::k], dtype=cv2.CV_32F)
    cols = rows.reshape(shape_hw[0], shape_hw[1], k)
    out = cv2.add(cols[:, :, 0], cols[:, :, 1])
    for j in range(2, k):
        out = cv2.add(out, cols[:, :, j])
    return np.multiply(out, np.float32(1.0 / (k * k)), out=np.asarray(out, dtype=np.float32))


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from([2, 3, 4, 5, 8, 16, 17]),  # 17: the float32 sums
    st.integers(32, 40),
    st.integers(32, 36),
    st.sampled_from([0, 1, 2, None]),  # a channel of an RGB frame (a strided view) or a grey frame
    st.booleans(),
)
def test_block_sums_are_the_cv2_add_form(seed, k, w_px, h_px, channel, saturated):
    sc = ProcessingScale.for_camera(Camera(w_px * k, h_px * k, 1000.0, 1000.0, 10.0, 10.0), 1.0 / k)
    assert (sc.camera.width_px, sc.camera.height_px) == (w_px, h_px)
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (h_px * k, w_px * k, 3), dtype=np.uint8)
    if saturated:  # the largest sums
        frame[: h_px * k // 2] = 255
    ch = frame[:, :, 0].copy() if channel is None else frame[:, :, channel]
    got = sc.reduce_channel(ch)
    ref = _block_sums_reference(ch, k, (h_px, w_px))
    assert got.dtype == ref.dtype == np.float32 and got.shape == ref.shape == (h_px, w_px)
    assert got.tobytes() == ref.tobytes()


def _skirt_centre_reference(excess, labels, mask, offset, label, area_px, skirt_px, box):
    """The spot centre with its fade, the blob dilated in its window as it is (not widened)."""
    r = int(np.ceil(skirt_px + np.sqrt(area_px / np.pi)))
    ou, ov = offset
    reach = r + 2
    u0, v0 = max(0, ou + box[0] - reach), max(0, ov + box[1] - reach)
    u1, v1 = min(excess.shape[1], ou + box[2] + reach), min(excess.shape[0], ov + box[3] + reach)
    lu0, lv0 = max(u0, ou), max(v0, ov)
    lu1, lv1 = min(u1, ou + labels.shape[1]), min(v1, ov + labels.shape[0])
    lab = labels[lv0 - ov : lv1 - ov, lu0 - ou : lu1 - ou]
    own = np.zeros((v1 - v0, u1 - u0), np.uint8)
    others = np.zeros((v1 - v0, u1 - u0), bool)
    own[lv0 - v0 : lv1 - v0, lu0 - u0 : lu1 - u0] = (lab == label) & (
        mask[lv0 - ov : lv1 - ov, lu0 - ou : lu1 - ou] > 0
    )
    others[lv0 - v0 : lv1 - v0, lu0 - u0 : lu1 - u0] = (lab != label) & (lab != 0)
    grown = cv2.dilate(own, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) > 0
    ring = cv2.dilate(own, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))) > 0
    exu8 = excess[v0:v1, u0:u1]
    ex = exu8.astype(np.float64)
    outside = exu8[ring & ~grown & ~others]
    pedestal = float(np.median(outside.astype(np.float64))) if outside.size else 0.0
    w = np.where(grown & ~others, np.maximum(ex - pedestal, 0.0), 0.0)
    total = w.sum()
    uu, vv = np.arange(w.shape[1], dtype=float), np.arange(w.shape[0], dtype=float)[:, None]
    return float((w * uu).sum() / total + u0), float((w * vv).sum() / total + v0)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.floats(0.0, 9.0), st.integers(20, 90), st.integers(20, 90))
def test_skirt_centre_is_the_unwidened_dilation(seed, n_blobs, skirt_px, w_px, h_px):
    # Blobs of every size, some at the border, a reddish seabed under them: the blobs' windows
    # have every width, clipped by the image or not.
    rng = np.random.default_rng(seed)
    excess = rng.integers(0, 70, (h_px, w_px), dtype=np.uint8)
    vv, uu = np.mgrid[0:h_px, 0:w_px]
    for _ in range(n_blobs):
        cu, cv, r = rng.uniform(-3, w_px + 3), rng.uniform(-3, h_px + 3), rng.uniform(0.5, 9.0)
        disc = (uu - cu) ** 2 + (vv - cv) ** 2 <= r * r
        excess[disc] = np.maximum(excess[disc], rng.integers(80, 256, int(disc.sum()), dtype=np.uint8))
    _, mask = cv2.threshold(excess, 79, 1, cv2.THRESH_BINARY)
    if cv2.countNonZero(mask) == 0:
        return
    bu, bv, bw, bh = cv2.boundingRect(mask)  # the sub-window of the labels, as the spot search takes it
    bu0, bv0 = max(0, bu - 1), max(0, bv - 1)
    mask = mask[bv0 : bv + bh + 1, bu0 : bu + bw + 1]
    n, labels = cv2.connectedComponents(cv2.dilate(mask, _ONES3), connectivity=8)
    pix = cv2.findNonZero(mask).reshape(-1, 2)
    lab = labels[pix[:, 1], pix[:, 0]]
    for label in range(1, n):
        own = pix[lab == label]
        if len(own) == 0:
            continue
        box = spots._box(own)
        args = (excess, labels, mask, (bu0, bv0), label, len(own), skirt_px, box)
        assert np.array(spots._skirt_centre(*args)).tobytes() == np.array(_skirt_centre_reference(*args)).tobytes()


def test_block_check_still_refuses_a_negative_determinant():
    p = np.eye(6)
    check_blocks(p, 6, 2, "a test")  # a valid covariance passes
    p[2, 3] = p[3, 2] = 2.0  # the 2x2 block at row 2: det 1 - 4 < 0
    with pytest.raises(FilterInconsistencyError, match="block at state 2"):
        check_blocks(p, 6, 2, "a test")


def test_version_is_answered_without_importing_the_command_line():
    import subprocess
    import sys

    from rovslam import __version__

    res = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "rovslam", "--version"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 0 and res.stdout == f"rovslam {__version__}\n"
    assert "rovslam.cli" not in res.stderr and "typer" not in res.stderr
