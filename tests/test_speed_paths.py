"""Small-array paths computed on Python floats or with fewer NumPy calls give bit for bit what the
array form gives (the array form is written out here, as the code had it)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rovslam.errors import FilterInconsistencyError
from rovslam.slam.apparent import apparent_frame_cov_m2
from rovslam.slam.health import check_blocks
from rovslam.slam.observation import observation_jacobians, observation_noise_px2
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
