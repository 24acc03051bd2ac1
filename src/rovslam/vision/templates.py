"""High-local-variance template extraction (Misu et al., as used by the paper) and inhibition masks.

Speed templates ("tokens", 16x16, at most 8 per frame) and SLAM landmark templates (32x32,
local variance >= 12.3) are extracted by the same function, :func:`extract_templates`; only
the size, the count and the threshold differ (paper, section 2). The threshold applies to
the output of :func:`rovslam.vision.filters.local_variance` of the band-passed 8-bit channel
(grey levels squared; see :mod:`rovslam.vision.filters` for the exact normalisation).

Pixel conventions: ``uv`` is (u right, v down) in pixels, pixel centres at integers. A
template of side ``s`` whose top-left pixel is ``(u0, v0)`` has its centre at
``(u0 + (s - 1) / 2, v0 + (s - 1) / 2)``; that centre is what the tracker returns and what
equation (3) observes (``m = cy - v``, ``n = u - cx``).

Inhibition (paper, section 3.4, steps 2 and 4): pixels near the laser spots are forbidden
for every template, pixels of tracked / new landmark templates are forbidden for the speed
templates, so that speed and position measurements come from disjoint pixels. A template is
chosen only if its whole window avoids the forbidden pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rovslam.errors import InvalidArgumentError


@dataclass(frozen=True, eq=False)
class Template:
    """One extracted template.

    Attributes
    ----------
    centre_uv_px: ``(2,) float64`` centre (u, v) = top-left corner + (size - 1) / 2.
    patch: ``(size, size) float32`` pixels of the tracking image (read-only), the ones the
        tracker correlates.
    local_variance: the local variance of the window (grey levels squared, see
        :mod:`rovslam.vision.filters`).
    """

    centre_uv_px: np.ndarray
    patch: np.ndarray
    local_variance: float
    self_similarity: float = float("nan")  # :func:`self_similarity` when extraction tested it

    @property
    def size_px(self) -> int:
        return int(self.patch.shape[0])

    @property
    def top_left_uv_px(self) -> np.ndarray:
        """``(2,) float64`` top-left pixel (u0, v0) (integers for extracted templates)."""
        return self.centre_uv_px - 0.5 * (self.size_px - 1)


def _check_shape_hw(shape_hw: tuple[int, ...]) -> tuple[int, int]:
    if len(shape_hw) < 2 or int(shape_hw[0]) <= 0 or int(shape_hw[1]) <= 0:
        raise InvalidArgumentError(f"image shape must be (H, W) with positive sides, got {shape_hw}")
    return int(shape_hw[0]), int(shape_hw[1])


def _points(points_uv_px: np.ndarray | None, name: str) -> np.ndarray:
    if points_uv_px is None:
        return np.zeros((0, 2))
    pts = np.asarray(points_uv_px, dtype=np.float64)
    if pts.size == 0:
        return np.zeros((0, 2))
    if pts.ndim == 1 and pts.shape[0] == 2:
        pts = pts.reshape(1, 2)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InvalidArgumentError(f"{name} must be an (N, 2) array of (u, v) pixels, got shape {pts.shape}")
    return pts[np.all(np.isfinite(pts), axis=1)]


def inhibition_mask(
    shape_hw: tuple[int, ...],
    points_uv_px: np.ndarray | None,
    radius_px: float,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Forbidden discs around points (laser spots, paper step 2).

    Pixel ``(u, v)`` becomes True when ``(u - pu)^2 + (v - pv)^2 <= radius^2`` for some point.
    Rows with NaN are skipped.

    Parameters
    ----------
    shape_hw: image shape ``(H, W[, ...])``.
    points_uv_px: ``(N, 2)`` disc centres (u, v), sub-pixel; ``None`` or empty for none.
    radius_px: disc radius >= 0.
    out: optional ``(H, W) bool`` mask to add the discs to, in place (then returned).

    Returns
    -------
    ``(H, W) bool``, True = forbidden.
    """
    h, w = _check_shape_hw(shape_hw)
    if not np.isfinite(radius_px) or radius_px < 0:
        raise InvalidArgumentError(f"inhibition radius must be finite and >= 0 px, got {radius_px}")
    if out is None:
        out = np.zeros((h, w), dtype=bool)
    elif out.shape != (h, w) or out.dtype != np.bool_:
        raise InvalidArgumentError(f"out must be an ({h}, {w}) bool mask, got {out.shape} {out.dtype}")
    r = float(radius_px)
    r2 = r * r
    for pu, pv in _points(points_uv_px, "points_uv_px").tolist():  # Python floats: ceil/floor as NumPy's
        u0, u1 = max(0, math.ceil(pu - r)), min(w - 1, math.floor(pu + r))
        v0, v1 = max(0, math.ceil(pv - r)), min(h - 1, math.floor(pv + r))
        if u0 > u1 or v0 > v1:
            continue
        du = _offsets(u0, u1 + 1) - pu
        dv = _offsets(v0, v1 + 1) - pv
        du *= du
        dv *= dv
        out[v0 : v1 + 1, u0 : u1 + 1] |= (dv[:, None] + du[None, :]) <= r2
    return out


_AXIS = np.arange(4096, dtype=np.float64)
_AXIS.setflags(write=False)


def _offsets(start: int, stop: int) -> np.ndarray:
    """``np.arange(start, stop)`` as float64 (a fresh array), from a slice of one built once when it fits."""
    return _AXIS[start:stop].copy() if stop <= _AXIS.shape[0] else np.arange(start, stop, dtype=np.float64)


def inhibit_boxes(mask: np.ndarray, centres_uv_px: np.ndarray | None, half_size_px: float) -> None:
    """Forbid squares around template centres, in place (landmark templates, paper step 4).

    Pixel ``(u, v)`` becomes True when ``|u - cu| <= half`` and ``|v - cv| <= half``. For a
    template of side ``s`` use ``half = (s - 1) / 2 + margin`` to cover it plus a margin.

    Parameters
    ----------
    mask: ``(H, W) bool``, modified in place.
    centres_uv_px: ``(N, 2)`` square centres (u, v); NaN rows are skipped.
    half_size_px: half side >= 0.
    """
    if mask.ndim != 2 or mask.dtype != np.bool_:
        raise InvalidArgumentError(f"mask must be an (H, W) bool array, got {mask.shape} {mask.dtype}")
    if not np.isfinite(half_size_px) or half_size_px < 0:
        raise InvalidArgumentError(f"half_size_px must be finite and >= 0, got {half_size_px}")
    h, w = mask.shape
    hs = float(half_size_px)
    for cu, cv in _points(centres_uv_px, "centres_uv_px"):
        u0, u1 = max(0, int(np.ceil(cu - hs))), min(w - 1, int(np.floor(cu + hs)))
        v0, v1 = max(0, int(np.ceil(cv - hs))), min(h - 1, int(np.floor(cv + hs)))
        if u0 <= u1 and v0 <= v1:
            mask[v0 : v1 + 1, u0 : u1 + 1] = True


def window_inhibited(mask: np.ndarray, centre_uv_px: np.ndarray, size_hw: tuple[int, int]) -> bool:
    """True when the ``size_hw`` window centred at ``centre_uv_px`` (sub-pixel, rounded to the
    nearest top-left pixel) covers a True pixel of the ``(H, W) bool`` mask.

    Used to refuse a match (speed token or landmark) that lands on forbidden pixels.
    """
    h, w = int(size_hw[0]), int(size_hw[1])
    cu, cv = np.asarray(centre_uv_px, dtype=np.float64).reshape(2).tolist()
    u0 = round(cu - 0.5 * (w - 1))  # half to even, as np.rint
    v0 = round(cv - 0.5 * (h - 1))
    return bool(mask[max(0, v0) : max(0, v0 + h), max(0, u0) : max(0, u0 + w)].any())


_ONES3 = np.ones((3, 3), np.uint8)


def second_peak(corr: np.ndarray, pu: int, pv: int, exclusion_px: int) -> float:
    """Highest 3x3 local maximum of the ``(h, w) float32`` correlation ``corr`` farther than
    ``exclusion_px`` (Chebyshev) from ``(pu, pv)``; -1 (the lowest correlation) when there is none."""
    mask = cv2.compare(corr, cv2.dilate(corr, _ONES3), cv2.CMP_GE)  # 255 at the local maxima (corr >= dilated)
    ex = max(0, int(exclusion_px))
    mask[max(0, pv - ex) : pv + ex + 1, max(0, pu - ex) : pu + ex + 1] = 0
    # OpenCV's masked maximum: the same value as NumPy's, at half its cost
    if not cv2.countNonZero(mask):
        return -1.0
    return max(-1.0, cv2.minMaxLoc(corr, mask)[1])


def self_similarity(
    track_img: np.ndarray, top_left_uv: tuple[int, int], size_px: int, radius_px: int, exclusion_px: int = 3
) -> float:
    """How much a window looks like its neighbourhood: the highest other peak of its autocorrelation.

    The ``size_px`` window at ``top_left_uv`` of the ``(H, W) float32`` image is correlated
    (normalised, as the tracker does) with every window within ``radius_px`` of it; the
    result is the highest local maximum farther than ``exclusion_px`` (Chebyshev) from the
    window itself, or -1 when there is none. A regular pattern (coral lattice, ripples, a row
    of look-alike burrows) gives a value near 1: the tracker could lock on a neighbour.
    """
    u0, v0 = int(top_left_uv[0]), int(top_left_uv[1])
    img = np.asarray(track_img, dtype=np.float32)
    h, w = img.shape
    patch = img[v0 : v0 + size_px, u0 : u0 + size_px]
    su0, sv0 = max(0, u0 - radius_px), max(0, v0 - radius_px)
    su1, sv1 = min(w, u0 + size_px + radius_px), min(h, v0 + size_px + radius_px)
    # OpenCV's standard deviation (in double precision; numpy's costs five times more on 16x16)
    if patch.shape != (size_px, size_px) or float(cv2.meanStdDev(patch)[1][0, 0]) <= 1e-6:
        return 1.0  # a window that cannot be correlated is as ambiguous as it gets
    corr = cv2.matchTemplate(img[sv0:sv1, su0:su1], patch, cv2.TM_CCOEFF_NORMED)
    return second_peak(corr, u0 - su0, v0 - sv0, exclusion_px)  # the window finds itself at (u0 - su0, v0 - sv0)


def extract_templates(
    track_img: np.ndarray,
    local_var: np.ndarray,
    size_px: int,
    max_count: int,
    min_local_variance: float,
    border_px: int = 0,
    inhibit: np.ndarray | None = None,
    min_spacing_px: int | None = None,
    max_self_similarity: float | None = None,
    similarity_radius_px: int = 8,
) -> list[Template]:
    """Choose the highest-local-variance, non-overlapping windows as templates (Misu et al.).

    A candidate window of side ``s`` is the one :func:`~rovslam.vision.filters.local_variance`
    scored at its anchor pixel ``(u, v)``: top-left ``(u - s//2, v - s//2)``. A candidate
    qualifies when

    * its local variance is ``>= min_local_variance`` and ``> 0`` (a flat window cannot be
      correlated),
    * the whole window lies at least ``border_px`` pixels inside the image,
    * no pixel of the window is True in ``inhibit``.

    Selection is greedy: the strongest qualifying window is taken, every candidate whose
    window would overlap it (anchor closer than ``s`` pixels in both u and v) is suppressed,
    and so on until ``max_count`` templates or no candidate is left. ``min_spacing_px``
    (default ``s``) widens that suppression: speed tokens spread over the image measure the
    rotation better, and one bright particle cannot carry several of them.

    Parameters
    ----------
    track_img: ``(H, W) float32`` image the templates are cut from, the one the tracker
        will correlate (the pipeline uses the band-passed channel).
    local_var: ``(H, W) float32`` local variance of the band-passed channel over ``size_px``.
    size_px: template side (16 speed, 32 landmark).
    max_count: at most this many templates (>= 0).
    min_local_variance: threshold, grey levels squared (paper: 12.3 for landmarks).
    border_px: margin between the window and the image border (>= 0).
    inhibit: optional ``(H, W) bool`` forbidden pixels.
    min_spacing_px: least distance (in u or v) between two template anchors; >= size.
    max_self_similarity: refuse a candidate whose :func:`self_similarity` within
        ``similarity_radius_px`` (where the tracker will look for it) exceeds this: it is
        ambiguous. None: no test (the paper). After ``4 max_count`` refused candidates the
        search stops (fewer templates, never an untested one).

    Returns
    -------
    ``list[Template]``, strongest first, possibly empty (flat, black or saturated frame).
    """
    img, lv = _check_extract_args(track_img, local_var, size_px, max_count, min_local_variance, border_px, inhibit)
    size = int(size_px)
    spacing = size if min_spacing_px is None else max(size, int(min_spacing_px))
    score = None if max_count == 0 else _anchor_scores(lv, size, int(border_px), inhibit)
    if score is None:
        return []
    threshold = max(float(min_local_variance), np.finfo(np.float32).tiny)
    return _choose_greedily(img, score, size, max_count, threshold, spacing, max_self_similarity, similarity_radius_px)  # type: ignore[arg-type]


def _check_extract_args(
    track_img, local_var, size_px, max_count, min_local_variance, border_px, inhibit
) -> tuple[np.ndarray, np.ndarray]:
    """``(track_img, local_var)`` as arrays, or InvalidArgumentError naming the argument of
    :func:`extract_templates` that is wrong."""
    img = np.asarray(track_img)
    lv = np.asarray(local_var)
    if img.ndim != 2 or lv.shape != img.shape:
        raise InvalidArgumentError(
            f"track_img and local_var must be (H, W) arrays of the same shape, got {img.shape} and {lv.shape}"
        )
    size = int(size_px)
    if size != size_px or size < 2:
        raise InvalidArgumentError(f"template size must be a whole number >= 2 px, got {size_px}")
    if int(max_count) != max_count or max_count < 0:
        raise InvalidArgumentError(f"max_count must be a whole number >= 0, got {max_count}")
    if not np.isfinite(min_local_variance) or min_local_variance < 0:
        raise InvalidArgumentError(f"min_local_variance must be finite and >= 0, got {min_local_variance}")
    if int(border_px) != border_px or border_px < 0:
        raise InvalidArgumentError(f"border_px must be a whole number >= 0, got {border_px}")
    if inhibit is not None and (inhibit.shape != img.shape or inhibit.dtype != np.bool_):
        raise InvalidArgumentError(
            f"inhibit must be an (H, W) bool mask of shape {img.shape}, got {inhibit.shape} {inhibit.dtype}"
        )
    return img, lv


def _anchor_scores(lv: np.ndarray, size: int, border: int, inhibit: np.ndarray | None) -> np.ndarray | None:
    """``(H, W) float32`` local variance at every anchor whose window may be chosen, -1 elsewhere.

    An anchor ``a`` has the window ``[a - size//2, a - size//2 + size)``; it must lie ``border``
    pixels inside the image and touch no pixel of ``inhibit``. None when no window fits.
    """
    h_img, w_img = lv.shape
    half = size // 2
    # Anchors whose window [a - half, a - half + size) lies inside [border, side - border).
    a_min = border + half
    a_max_u = w_img - border - size + half  # inclusive
    a_max_v = h_img - border - size + half
    if a_max_u < a_min or a_max_v < a_min:
        return None
    score = np.full((h_img, w_img), -1.0, dtype=np.float32)
    inner = lv[a_min : a_max_v + 1, a_min : a_max_u + 1].astype(np.float32, copy=False)
    score[a_min : a_max_v + 1, a_min : a_max_u + 1] = inner
    if inhibit is not None and inhibit.any():
        # A window touches a forbidden pixel iff the dilation of the mask by the window
        # (same anchor as the local variance) is set at its anchor.
        kernel = np.ones((size, size), np.uint8)
        touched = cv2.dilate(
            inhibit.view(np.uint8), kernel, anchor=(half, half), borderType=cv2.BORDER_CONSTANT, borderValue=0
        )
        np.copyto(score, np.float32(-1.0), where=touched.view(bool))  # = score[touched] = -1, without the gather
    return score


def _choose_greedily(
    img: np.ndarray,
    score: np.ndarray,
    size: int,
    max_count: int,
    threshold: float,
    spacing: int,
    max_self_similarity: float | None,
    similarity_radius_px: int,
) -> list[Template]:
    """The strongest anchors of ``score`` (modified in place), each suppressing its neighbours (see
    :func:`extract_templates`), cut from ``img`` as templates."""
    half = size // 2
    templates: list[Template] = []
    refused = 0
    while len(templates) < max_count:
        _, best, _, (u, v) = cv2.minMaxLoc(score)
        if not best >= threshold:
            break
        u0, v0 = u - half, v - half
        similarity = float("nan")
        if max_self_similarity is not None:
            if refused >= 4 * max_count:
                break  # a repetitive scene: what is left is no better, and an untested window may be ambiguous
            similarity = self_similarity(img, (u0, v0), size, similarity_radius_px)
            if similarity > max_self_similarity:
                refused += 1  # ambiguous: its neighbours look the same; so would the ones next to it
                q = max(1, size // 2)
                score[max(0, v - q) : v + q + 1, max(0, u - q) : u + q + 1] = -1.0
                continue
        patch = np.array(img[v0 : v0 + size, u0 : u0 + size], dtype=np.float32)
        patch.setflags(write=False)
        centre = np.array([u0 + 0.5 * (size - 1), v0 + 0.5 * (size - 1)])
        centre.setflags(write=False)
        templates.append(
            Template(centre_uv_px=centre, patch=patch, local_variance=float(best), self_similarity=similarity)
        )
        # Non-overlap: suppress anchors within one template size (or the spacing) in both axes.
        score[max(0, v - spacing + 1) : v + spacing, max(0, u - spacing + 1) : u + spacing] = -1.0
    return templates
