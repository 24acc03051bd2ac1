"""Band-pass, local variance and channel choice (rovslam.vision.filters)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from rovslam.errors import InvalidArgumentError
from rovslam.vision.filters import bandpass, gaussian_kernel, local_variance, template_channel


def _rgb(seed: int = 0, shape=(40, 50)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (*shape, 3), dtype=np.uint8)


def test_template_channel_picks_green_blue_and_grey():
    img = _rgb(1)
    assert np.array_equal(template_channel(img, "green"), img[:, :, 1].astype(np.float32))
    assert np.array_equal(template_channel(img, "blue"), img[:, :, 2].astype(np.float32))
    grey = template_channel(img, "grey")
    expected = 0.299 * img[:, :, 0] + 0.587 * img[:, :, 1] + 0.114 * img[:, :, 2]
    assert grey.dtype == np.float32
    assert np.max(np.abs(grey - expected)) <= 1.0  # OpenCV rounds to uint8


def test_template_channel_grey_input_is_used_as_is():
    g = np.arange(12, dtype=np.uint8).reshape(3, 4)
    out = template_channel(g, "green")
    assert out.dtype == np.float32
    assert np.array_equal(out, g.astype(np.float32))


def test_template_channel_refuses_red_and_bad_input():
    with pytest.raises(InvalidArgumentError, match="reserved for the laser"):
        template_channel(_rgb(), "red")
    with pytest.raises(InvalidArgumentError, match="uint8"):
        template_channel(np.zeros((4, 4, 3), np.float32), "green")
    with pytest.raises(InvalidArgumentError, match="shape"):
        template_channel(np.zeros((4, 4, 4), np.uint8), "green")


def test_bandpass_has_zero_dc_and_matches_difference_of_gaussians():
    rng = np.random.default_rng(2)
    img = (rng.random((80, 90)) * 255).astype(np.float32)
    out = bandpass(img, 1.0, 4.0)
    ref = ndimage.gaussian_filter(img.astype(np.float64), 1.0, truncate=3.0) - ndimage.gaussian_filter(
        img.astype(np.float64), 4.0, truncate=3.0
    )
    inner = (slice(15, -15), slice(15, -15))
    assert np.max(np.abs(out[inner] - ref[inner])) < 1e-3
    flat = bandpass(np.full((30, 30), 200.0, np.float32), 1.0, 4.0)
    assert np.max(np.abs(flat)) < 1e-3


def test_bandpass_gain_for_a_sinusoid_follows_the_documented_formula():
    wavelength = 12.0
    x = np.arange(240)
    img = np.tile(100.0 + 50.0 * np.sin(2 * np.pi * x / wavelength), (64, 1)).astype(np.float32)
    out = bandpass(img, 1.0, 4.0)
    gain = np.exp(-2 * np.pi**2 * 1.0 / wavelength**2) - np.exp(-2 * np.pi**2 * 16.0 / wavelength**2)
    measured = out[32, 60:180].std() * np.sqrt(2) / 50.0
    assert measured == pytest.approx(gain, rel=0.02)
    assert gain == pytest.approx(0.760, abs=0.005)


def test_bandpass_rejects_bad_sigmas():
    img = np.zeros((20, 20), np.float32)
    with pytest.raises(InvalidArgumentError, match="sigma_fine_px < sigma_coarse_px"):
        bandpass(img, 4.0, 1.0)
    with pytest.raises(InvalidArgumentError, match="finite"):
        bandpass(img, np.nan, 4.0)


def test_gaussian_kernel_is_cached_and_normalised():
    k = gaussian_kernel(4.0)
    assert k is gaussian_kernel(4.0)
    assert k.shape == (25, 1)
    assert float(k.sum()) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("size", [16, 15, 32])
def test_local_variance_is_the_window_variance_with_the_documented_anchor(size):
    rng = np.random.default_rng(3)
    img = rng.normal(0, 10, (70, 80)).astype(np.float32)
    lv = local_variance(img, size)
    h = size // 2
    for v, u in [(h, h), (35, 40), (70 - size + h, 80 - size + h), (20, 57)]:
        window = img[v - h : v - h + size, u - h : u - h + size].astype(np.float64)
        assert lv[v, u] == pytest.approx(window.var(), rel=1e-4)
    assert lv.dtype == np.float32
    assert lv.min() >= 0.0


def test_local_variance_of_flat_image_is_zero():
    lv = local_variance(np.full((50, 50), 255.0, np.float32), 16)
    assert np.all(lv == 0.0)


def test_local_variance_rejects_bad_sizes():
    img = np.zeros((20, 20), np.float32)
    with pytest.raises(InvalidArgumentError, match=">= 2"):
        local_variance(img, 1)
    with pytest.raises(InvalidArgumentError, match="larger than the image"):
        local_variance(img, 32)
    with pytest.raises(InvalidArgumentError, match="single-channel"):
        local_variance(np.zeros((20, 20, 3), np.float32), 8)


def test_remove_specks_takes_out_a_caustic_line_and_keeps_dark_stones_and_large_bright_areas():
    from rovslam.vision.filters import remove_specks

    img = np.full((120, 160), 100.0, np.float32)
    img[:, 40:49] = 200.0  # a 9 px bright line (a caustic at 2 m), the whole height
    img[60:66, 100:106] = 20.0  # a dark stone, 6 px
    yy, xx = np.mgrid[:120, :160]
    bright = (yy - 30) ** 2 + (xx - 120) ** 2 <= 22**2  # a bright area 45 px across
    img[bright] = 180.0
    out = remove_specks(img, 31)
    assert out.dtype == np.float32 and out.shape == img.shape
    np.testing.assert_array_equal(out[:, 40:49], 100.0)  # the line is gone
    np.testing.assert_array_equal(out[60:66, 100:106], 20.0)  # the stone is kept, exactly
    assert out[30, 120] == 180.0  # the large bright area's centre is kept
    np.testing.assert_array_equal(remove_specks(img, 0), img)


@pytest.mark.parametrize("size_px", [3, 7, 15, 21, 31, 41])
def test_the_opening_element_is_an_octagon_within_a_pixel_of_the_disc(size_px):
    import cv2

    from rovslam.vision.filters import _CROSS, _octagon, _open_octagon

    # A single bright pixel dilated by the element draws the element; an opening's element is
    # what an erosion then a dilation sweep: dilate a point with the same decomposition.
    n = 2 * size_px + 1
    point = np.zeros((n, n), np.uint8)
    point[size_px, size_px] = 255
    square, a = _octagon(size_px)
    drawn = cv2.dilate(cv2.dilate(point, _CROSS, iterations=a) if a else point, square) > 0
    disc = np.zeros((n, n), bool)
    r0 = size_px // 2
    disc[size_px - r0 : size_px - r0 + size_px, size_px - r0 : size_px - r0 + size_px] = (
        cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px)) > 0
    )
    cols = np.flatnonzero(drawn.any(axis=0))
    assert cols[-1] - cols[0] + 1 == size_px  # the same width as the disc
    assert np.sum(drawn ^ disc) <= 0.15 * disc.sum()  # and nearly the same pixels
    # A structure the element fits in survives the opening; one it does not fit in is removed.
    img = np.zeros((n + 20, n + 20), np.uint8)
    img[10 : 10 + n, 10 : 10 + n][drawn] = 200
    np.testing.assert_array_equal(_open_octagon(img, size_px), img)
    thin = np.zeros_like(img)
    thin[:, 10 : 10 + size_px - 1] = 200  # one pixel narrower than the element
    assert _open_octagon(thin, size_px).max() == 0


@pytest.mark.parametrize("size_px", [3, 7, 15])
def test_narrow_openings_are_opencvs_exact_disc(size_px):
    import cv2

    from rovslam.vision.filters import OCTAGON_FROM_PX, remove_specks

    assert size_px < OCTAGON_FROM_PX
    img = np.random.default_rng(size_px).uniform(0, 255, (60, 80)).astype(np.float32)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))
    np.testing.assert_array_equal(remove_specks(img, size_px), cv2.morphologyEx(img, cv2.MORPH_OPEN, disc))
