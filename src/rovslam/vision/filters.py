"""Image filters of the Misu et al. template extractor: channel choice, band-pass, local variance.

The paper (section 2) extracts both speed templates and SLAM landmarks with the method of
Misu et al. (1999): "after a 2-D band-pass filtering to enhance specific spatial
wavelengths, local variances are computed to evaluate contrast, and high-local variance
areas are extracted as templates". This module is the filtering half; the selection is in
:mod:`rovslam.vision.templates`.

Intensity scale (what a local-variance threshold such as the paper's 12.3 means)
-------------------------------------------------------------------------------
* :func:`template_channel` returns the chosen channel as float32 on the 8-bit scale
  0..255, whatever the input (no normalisation to 0..1, no contrast stretch).
* :func:`bandpass` is a difference of two unit-gain Gaussians, ``G(sigma_fine) * I -
  G(sigma_coarse) * I``. Its DC gain is exactly 0 and its gain for a sinusoid of wavelength
  ``lambda`` pixels is ``exp(-2 pi^2 sigma_fine^2 / lambda^2) - exp(-2 pi^2 sigma_coarse^2 /
  lambda^2)`` (below 1: at most 0.78, at lambda = 14.6 px, for sigmas 1 and 4). The output is
  therefore in 8-bit grey levels, zero-mean, with no further rescaling.
* :func:`local_variance` is the population variance (divide by N) of that band-passed image
  over a ``size x size`` window, in grey levels squared.

So "local variance >= 12.3" means: over the template's window, the band-passed 8-bit
channel has a standard deviation of at least 3.5 grey levels.

All functions are vectorised OpenCV calls on float32 images; the Gaussian kernels are
computed once per sigma and cached, and the intermediate images are combined in place (each
call allocates only the arrays it returns: every image-sized allocation costs page faults).
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from rovslam.errors import InvalidArgumentError

CHANNELS = ("grey", "green", "blue")
"""Channels the templates may use. Red is reserved for the laser spots (paper, Fig. 1)."""

_CHANNEL_INDEX = {"green": 1, "blue": 2}


def template_channel(image: np.ndarray, channel: str) -> np.ndarray:
    """The image channel the templates are extracted from and tracked on.

    Parameters
    ----------
    image:
        ``(H, W, 3) uint8`` RGB or ``(H, W) uint8`` grey. A grey image is used as it is,
        whatever ``channel`` says.
    channel:
        ``"grey"`` (ITU-R BT.601 luma), ``"green"`` or ``"blue"``. ``"red"`` is refused: the
        red channel carries the laser spots.

    Returns
    -------
    ``(H, W) float32`` on the 8-bit scale 0..255 (a new array).
    """
    return template_channel_u8(image, channel).astype(np.float32)


def template_channel_u8(image: np.ndarray, channel: str) -> np.ndarray:
    """:func:`template_channel` before its conversion: ``(H, W) uint8``, a view of ``image`` or a new array."""
    if channel not in CHANNELS:
        raise InvalidArgumentError(
            f"template channel must be one of {', '.join(CHANNELS)}, got {channel!r}"
            + (" (red is reserved for the laser spots)" if channel == "red" else "")
        )
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise InvalidArgumentError(
            f"template_channel needs an 8-bit image (uint8), got dtype {img.dtype}; "
            "convert with np.clip(x, 0, 255).astype(np.uint8)"
        )
    if img.ndim == 2:
        return img
    if img.ndim != 3 or img.shape[2] != 3:
        raise InvalidArgumentError(
            f"template_channel needs an (H, W) grey or (H, W, 3) RGB image, got shape {img.shape}"
        )
    if channel == "grey":
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img[:, :, _CHANNEL_INDEX[channel]]


_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
OCTAGON_FROM_PX = 16
"""Openings this wide and wider use the octagon (:func:`_open_octagon`); narrower ones OpenCV's disc."""


@lru_cache(maxsize=8)
def _disc(size_px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))


def _open(img: np.ndarray, size_px: int) -> np.ndarray:
    """Grey-level opening by a disc of width ``size_px`` (exact below ``OCTAGON_FROM_PX``, an octagon from it on)."""
    if size_px >= OCTAGON_FROM_PX:
        return _open_octagon(img, size_px)
    return cv2.morphologyEx(img, cv2.MORPH_OPEN, _disc(int(size_px)))


@lru_cache(maxsize=8)
def _octagon(size_px: int) -> tuple[np.ndarray, int]:
    """The disc of diameter ``size_px`` as a square and a diamond: ``(square kernel, diamond radius)``.

    An octagon is the Minkowski sum of a square of half-side ``b`` and a diamond of radius
    ``a`` (``a`` 3x3 crosses); ``b = a / sqrt(2)`` makes its eight sides about equal, so it is
    within a pixel of the disc of the same width ``2 (a + b) + 1``.
    """
    radius = (int(size_px) - 1) / 2.0
    a = int(round(radius / (1.0 + math.sqrt(0.5))))
    b = max(int(round(radius - a)), 0)
    return cv2.getStructuringElement(cv2.MORPH_RECT, (2 * b + 1, 2 * b + 1)), a


def _open_octagon(img: np.ndarray, size_px: int) -> np.ndarray:
    """Grey-level opening by the octagon of width ``size_px`` (a new array, the input's dtype).

    An erosion by a Minkowski sum is the erosions by its terms in turn (and so the dilation),
    so the octagon costs a square's separable passes and ``a`` 3x3 passes: 0.2 ms at 31 px on
    a 360x272 frame, where OpenCV's disc kernel costs 1.6 ms (it visits every kernel pixel;
    at 7 px both cost 0.07 ms, and the exact disc is kept there: the despeckle's results do not
    change, and the decimated Sparus video's path moved by a quarter of its length with the octagon).
    """
    square, a = _octagon(int(size_px))
    out = cv2.erode(img, square)
    if a:
        out = cv2.erode(out, _CROSS, iterations=a)
        out = cv2.dilate(out, _CROSS, iterations=a)
    return cv2.dilate(out, square)


def remove_specks(channel_img: np.ndarray, size_px: int) -> np.ndarray:
    """Grey-level opening with a ``size_px`` disc: removes bright structures narrower than it.

    Two kinds of light are not the seabed and are only ever *added* to it: marine snow (bright
    particles in the water, which make the highest local variance in turbid footage and follow
    the water) and, in shallow water, sunlight caustics (a bright network of lines a few
    centimetres wide that drifts and flickers with the waves: a template on it follows the
    waves, and one that holds a piece of it is not found again). An opening (erosion then
    dilation) removes bright structures the disc (from ``OCTAGON_FROM_PX`` on, an octagon
    within a pixel of it) does not fit in and keeps the dark ones
    (stones, holes, shadows) and larger bright areas, so the templates land on the seabed.
    ``size_px < 2`` returns the image unchanged. ``(H, W) float32 -> (H, W) float32``.
    """
    img = _check_image(channel_img, "remove_specks")
    if size_px < 2:
        return img
    return _open(img, int(size_px))


def despeckled_channel(image: np.ndarray, channel: str, despeckle_px: int) -> np.ndarray:
    """``remove_specks(template_channel(image, channel), despeckle_px)``, bit for bit, in a third of the time.

    The opening is taken on the 8-bit channel before the conversion to float32 (an opening is
    a min then a max: it commutes with the exact, monotonic uint8 -> float32 conversion), so it
    moves a quarter of the bytes: 3 ms instead of 8 ms on a 1920x1080 frame.
    ``(H, W, 3) uint8`` RGB or ``(H, W) uint8`` -> ``(H, W) float32``, a new array.
    """
    return despeckled_channels(image, channel, despeckle_px, 0)[0]


def despeckled_channels(
    image: np.ndarray, channel: str, despeckle_px: int, wide_px: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """The despeckled channel and, when ``wide_px >= 2``, that channel opened again with ``wide_px``.

    Both openings are taken on 8 bits (see :func:`despeckled_channel`); the second is what
    :mod:`rovslam.sensor.sunlight` tracks on under sunlight caustics, and the difference of the two
    is the bright structures between the two widths. Returns ``((H, W) float32, (H, W) float32 or None)``.
    """
    chan = template_channel_u8(image, channel)  # its checks, its messages
    if despeckle_px >= 2:
        chan = _open(np.ascontiguousarray(chan), int(despeckle_px))
    wide = _open(np.ascontiguousarray(chan), int(wide_px)).astype(np.float32) if wide_px >= 2 else None
    return chan.astype(np.float32), wide


@lru_cache(maxsize=32)
def gaussian_kernel(sigma_px: float) -> np.ndarray:
    """``(2 ceil(3 sigma) + 1, 1) float32`` unit-sum Gaussian kernel, cached per sigma."""
    radius = max(1, int(np.ceil(3.0 * sigma_px)))
    kernel = cv2.getGaussianKernel(2 * radius + 1, sigma_px, cv2.CV_32F)
    kernel.setflags(write=False)
    return kernel


def _check_image(img: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(img)
    if arr.ndim != 2:
        raise InvalidArgumentError(f"{name} needs a (H, W) single-channel image, got shape {arr.shape}")
    if arr.dtype != np.float32:
        arr = arr.astype(np.float32)
    return arr


def bandpass(channel_img: np.ndarray, sigma_fine_px: float, sigma_coarse_px: float) -> np.ndarray:
    """2-D band-pass filter of Misu et al.: difference of Gaussians (DoG).

    ``out = G(sigma_fine) * img - G(sigma_coarse) * img`` with unit-sum Gaussian kernels and
    reflected borders (OpenCV ``BORDER_REFLECT_101``). Wavelengths shorter than about
    ``2 pi sigma_fine`` (noise) and longer than about ``2 pi sigma_coarse`` (uneven lighting,
    turbidity haze) are removed. The output keeps the 8-bit intensity units of the input
    (see the module docstring), zero mean.

    Parameters
    ----------
    channel_img: ``(H, W) float32`` (other dtypes are converted).
    sigma_fine_px: standard deviation of the fine Gaussian, > 0 (0 means no smoothing).
    sigma_coarse_px: standard deviation of the coarse Gaussian, > sigma_fine_px.

    Returns
    -------
    ``(H, W) float32``.
    """
    img = _check_image(channel_img, "bandpass")
    if not (np.isfinite(sigma_fine_px) and np.isfinite(sigma_coarse_px)):
        raise InvalidArgumentError(
            f"band-pass sigmas must be finite, got fine={sigma_fine_px}, coarse={sigma_coarse_px}"
        )
    if sigma_fine_px < 0 or sigma_coarse_px <= sigma_fine_px:
        raise InvalidArgumentError(
            "band-pass needs 0 <= sigma_fine_px < sigma_coarse_px, got "
            f"fine={sigma_fine_px}, coarse={sigma_coarse_px}; swap or fix them in [bandpass]"
        )
    if sigma_fine_px > 0:
        kf = gaussian_kernel(float(sigma_fine_px))
        fine = cv2.sepFilter2D(img, cv2.CV_32F, kf, kf)
    else:
        fine = img
    kc = gaussian_kernel(float(sigma_coarse_px))
    coarse = cv2.sepFilter2D(img, cv2.CV_32F, kc, kc)
    return cv2.subtract(fine, coarse, dst=coarse)  # in place: one image-sized array fewer per frame


def contrast_std(img: np.ndarray) -> float:
    """Standard deviation of an ``(H, W)`` image, accumulated in double precision (OpenCV).

    A third of the time of NumPy's ``img.std()`` on a float32 frame, which sums in float32:
    the two differ in the last digits only (used against a threshold: "is there texture").
    """
    return float(cv2.meanStdDev(np.asarray(img))[1][0, 0])


def local_variance(img: np.ndarray, size_px: int) -> np.ndarray:
    """Local variance over a ``size x size`` window: ``E[x^2] - E[x]^2`` (population variance).

    Window convention (the same as OpenCV's default anchor): the value at pixel ``(v, u)`` is
    the variance of ``img[v - h : v - h + size, u - h : u - h + size]`` with
    ``h = size // 2``. For an odd size the window is centred on the pixel; for an even size
    (16, 32) its centre is at ``(u - 0.5, v - 0.5)``. Near the image border the window is
    reflected (``BORDER_REFLECT_101``); :func:`~rovslam.vision.templates.extract_templates`
    only uses windows that lie wholly inside the image.

    Parameters
    ----------
    img: ``(H, W) float32``, usually the output of :func:`bandpass`.
    size_px: window side, >= 2 (the template size).

    Returns
    -------
    ``(H, W) float32``, >= 0, in the input's units squared.
    """
    arr = _check_image(img, "local_variance")
    size = int(size_px)
    if size != size_px or size < 2:
        raise InvalidArgumentError(f"local variance window must be a whole number >= 2 px, got {size_px}")
    if size > min(arr.shape):
        raise InvalidArgumentError(
            f"local variance window {size} px is larger than the image {arr.shape[1]}x{arr.shape[0]}"
        )
    ksize = (size, size)
    mean = cv2.boxFilter(arr, cv2.CV_32F, ksize)
    var = cv2.sqrBoxFilter(arr, cv2.CV_32F, ksize)
    # In place (the same arithmetic, no new image-sized arrays): var = max(E[x^2] - E[x]^2, 0);
    # float32 cancellation can leave tiny negatives on flat areas.
    cv2.multiply(mean, mean, dst=mean)
    cv2.subtract(var, mean, dst=var)
    return cv2.max(var, 0.0, dst=var)  # type: ignore[call-overload]
