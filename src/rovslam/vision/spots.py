"""Laser spots in the red channel (paper, section 2: the spots of the laser pointers, step 1 of the loop).

:func:`detect_laser_spots` finds the bright red spots anywhere near their predicted pixels;
:func:`find_faint_spots` looks again, close to a prediction, for the spots too faint for the
first pass (a dark seabed, turbid water). Both return pixel centres; their triangulation into
an altitude is :mod:`rovslam.vision.laser`'s.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from rovslam.config import LaserConfig
from rovslam.errors import InvalidArgumentError

_ONES3 = np.ones((3, 3), np.uint8)
# A faint spot's blob: its pixels at or above this share of its peak (at half, a 3 px spot has too few
# pixels for min_spot_area_px: 58 % of the faint spots found against 84 % at 0.3, as accurately)
_FAINT_BLOB_FRACTION = 0.3


def red_excess(image_rgb: np.ndarray) -> np.ndarray:
    """``(H, W) uint8`` red dominance ``max(0, R - max(G, B))`` of an ``(H, W, 3) uint8`` RGB image."""
    img = np.asarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidArgumentError(
            f"laser spots need an (H, W, 3) uint8 RGB image, got shape {img.shape} dtype {img.dtype}"
        )
    r, g, b = cv2.split(np.ascontiguousarray(img))  # a crop is copied first: 3x faster than split on its view
    return cv2.subtract(r, cv2.max(g, b, dst=g), dst=r)


def _spot_candidates(
    image_rgb: np.ndarray, config: LaserConfig, near_uv_px: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) weighted centroids and (K,) total weights of the red blobs, strongest first.

    With ``near_uv_px`` (N, 2), only the bounding box of these points grown by the search
    radius (plus the largest spot) is processed, and blobs whose centroid is farther than
    the search radius from every point are dropped.
    """
    h, w = image_rgb.shape[:2]
    u0, v0, u1, v1 = 0, 0, w, h
    near = None
    if near_uv_px is not None:
        near = near_uv_px[np.all(np.isfinite(near_uv_px), axis=1)]
        if len(near) == 0:
            return np.zeros((0, 2)), np.zeros(0)
        reach = config.search_radius_px + np.sqrt(max(config.max_spot_area_px, 1)) + 2.0
        lo = np.floor(near.min(axis=0) - reach)
        hi = np.ceil(near.max(axis=0) + reach) + 1
        u0, v0 = int(max(0, lo[0])), int(max(0, lo[1]))
        u1, v1 = int(min(w, hi[0])), int(min(h, hi[1]))
        if u0 >= u1 or v0 >= v1:
            return np.zeros((0, 2)), np.zeros(0)
    excess = red_excess(image_rgb[v0:v1, u0:u1])
    thr = int(np.clip(np.ceil(config.min_red_excess), 1, 255))
    _, mask = cv2.threshold(excess, thr - 1, 1, cv2.THRESH_BINARY)
    if cv2.countNonZero(mask) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    # The blobs are grouped only within the bounding box of the red pixels grown by the 1 px the
    # dilation reaches: the same blobs, labelled in the same (raster) order, as over the whole
    # window, on a fraction of its pixels.
    bu, bv, bw, bh = cv2.boundingRect(mask)
    bu0, bv0 = max(0, bu - 1), max(0, bv - 1)
    bu1, bv1 = min(mask.shape[1], bu + bw + 1), min(mask.shape[0], bv + bh + 1)
    mask = mask[bv0:bv1, bu0:bu1]
    # Close 1-px gaps of the speckle so one spot is one blob; the weights use the raw mask.
    grown = cv2.dilate(mask, _ONES3)
    n, labels = cv2.connectedComponents(grown, connectivity=8)
    # Only the pixels above the threshold carry weight: sums per blob over them alone.
    pix = cv2.findNonZero(mask).reshape(-1, 2)
    lab = labels[pix[:, 1], pix[:, 0]]
    us, vs = pix[:, 0] + bu0, pix[:, 1] + bv0  # in the window's pixels, as the sums have always been
    weight = excess[vs, us].astype(np.float64)
    area = np.bincount(lab, minlength=n)  # pixels above the threshold
    total = np.bincount(lab, weight, minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        cu = np.bincount(lab, weight * us, minlength=n) / total + u0
        cv = np.bincount(lab, weight * vs, minlength=n) / total + v0
    keep = (area >= config.min_spot_area_px) & (area <= config.max_spot_area_px) & (total > 0)
    keep[0] = False  # background
    ids = np.flatnonzero(keep)
    cents = np.column_stack([cu, cv])[keep]
    weights = total[keep]
    if near is not None and len(cents):
        dist = np.linalg.norm(cents[:, None, :] - near[None, :, :], axis=2)
        close = np.any(dist <= config.search_radius_px, axis=1)
        ids, cents, weights = ids[close], cents[close], weights[close]
    if config.spot_skirt_px > 0 and len(ids):
        cents = np.array(
            [
                _skirt_centre(
                    excess, labels, mask, (bu0, bv0), int(i), int(area[i]), config.spot_skirt_px, _box(pix[lab == i])
                )
                for i in ids
            ]
        ) + (u0, v0)
    # Strongest first; equal weights (saturated spots of the same size) top to bottom, then left to
    # right: OpenCV's labels follow its block scan, whose order changes with the crop's offset.
    order = np.lexsort((cents[:, 0], cents[:, 1], -weights)) if len(cents) else np.zeros(0, dtype=np.intp)
    return cents[order], weights[order]


def _box(pix: np.ndarray) -> tuple[int, int, int, int]:
    """``(u0, v0, u1, v1)`` the bounding box (end exclusive) of ``(N, 2)`` integer pixels (u, v), N >= 1."""
    lo, hi = pix.min(axis=0).tolist(), pix.max(axis=0).tolist()
    return lo[0], lo[1], hi[0] + 1, hi[1] + 1


def _skirt_centre(
    excess: np.ndarray,
    labels: np.ndarray,
    mask: np.ndarray,
    offset: tuple[int, int],
    label: int,
    area_px: int,
    skirt_px: float,
    box: tuple[int, int, int, int],
) -> tuple[float, float]:
    """``(u, v)`` centre of blob ``label``, weighing its red dominance beyond the threshold too.

    A spot's edge fades below ``min_red_excess``: where that fade is lopsided (a video codec's
    4:2:0 chroma and quantisation smear the red of a small spot unevenly) the thresholded
    pixels' centroid moves although the light's does not (0.4 to 0.6 px towards the image
    centre on the simulator's H.264 turbid dive: its altitude 0.7 to 1 % long). So the centre is
    the centroid of ``max(0, excess - pedestal)`` over the blob grown by ``skirt_px`` plus the
    blob's own radius (a larger spot has a wider fade); the pedestal is the median dominance on
    a 2-px ring just outside (a reddish seabed), other blobs' pixels are left out.

    ``excess``: ``(h, w) uint8`` red dominance of the search window; ``labels`` / ``mask``:
    the blobs' labels and thresholded pixels on its sub-window starting at ``offset`` (u, v);
    ``box``: ``(u0, v0, u1, v1)`` the blob's thresholded pixels' bounding box in that
    sub-window (end exclusive). Returns the centre in the search window's pixels.
    """
    r = int(math.ceil(skirt_px + math.sqrt(area_px / math.pi)))
    ou, ov = offset
    reach = r + 2
    u0, v0 = max(0, ou + box[0] - reach), max(0, ov + box[1] - reach)
    u1, v1 = min(excess.shape[1], ou + box[2] + reach), min(excess.shape[0], ov + box[3] + reach)
    # The label image covers only its sub-window: its overlap with this blob's window.
    lu0, lv0 = max(u0, ou), max(v0, ov)
    lu1, lv1 = min(u1, ou + labels.shape[1]), min(v1, ov + labels.shape[0])
    lab = labels[lv0 - ov : lv1 - ov, lu0 - ou : lu1 - ou]
    # The blob is dilated in rows widened with zeros to a multiple of 16 px: OpenCV's dilation by
    # a disc is fastest on rows of whole 16-byte blocks (a 42 px wide window costs twice a 48 px
    # one), and zeros beyond the window are what the dilation takes there anyway.
    own = np.zeros((v1 - v0, -(-(u1 - u0) // 16) * 16), np.uint8)
    others = np.zeros((v1 - v0, u1 - u0), bool)
    own[lv0 - v0 : lv1 - v0, lu0 - u0 : lu1 - u0] = (lab == label) & (
        mask[lv0 - ov : lv1 - ov, lu0 - ou : lu1 - ou] > 0
    )
    others[lv0 - v0 : lv1 - v0, lu0 - u0 : lu1 - u0] = (lab != label) & (lab != 0)
    grown = cv2.dilate(own, _disc(r))[:, : u1 - u0] > 0
    ring = cv2.dilate(own, _disc(reach))[:, : u1 - u0] > 0
    exu8 = excess[v0:v1, u0:u1]
    ex = exu8.astype(np.float64)
    outside = exu8[ring & ~grown & ~others]
    pedestal = _median_u8(outside) if outside.size else 0.0
    # total > 0: the ring's pixels outside every blob are below the threshold, the blob's own above it
    w = np.where(grown & ~others, np.maximum(ex - pedestal, 0.0), 0.0)
    total = w.sum()
    uu, vv = (
        np.arange(w.shape[1], dtype=float),
        np.arange(w.shape[0], dtype=float)[:, None],
    )  # broadcast: the pixels' u, v
    return float((w * uu).sum() / total + u0), float((w * vv).sum() / total + v0)


@lru_cache(maxsize=64)
def _disc(radius_px: int) -> np.ndarray:
    """``(2r+1, 2r+1) uint8`` OpenCV's elliptic structuring element of radius ``radius_px``."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))


def _median_u8(values: np.ndarray) -> float:
    """The median of ``(N,) uint8`` values (N >= 1) as ``np.median`` gives it, exactly (integers: no rounding)."""
    n = values.size
    k = n // 2
    if n % 2:
        return float(np.partition(values, k)[k])
    part = np.partition(values, (k - 1, k))
    return (int(part[k - 1]) + int(part[k])) / 2.0


def detect_laser_spots(image_rgb: np.ndarray, predicted_uv_px: np.ndarray | None, config: LaserConfig) -> np.ndarray:
    """Detect the laser spots in the red channel and associate them with their pointers.

    A pixel belongs to a spot when its red dominance ``R - max(G, B)`` is at least
    ``config.min_red_excess`` (8-bit units). Such pixels are grouped into blobs (8-connected
    after closing 1-px gaps; ``min_spot_area_px`` to ``max_spot_area_px``) and each blob's
    centre is the centroid of its pixels weighted by their red dominance (sub-pixel). Blobs
    are assigned one-to-one to the predicted spots by minimum total distance (Hungarian),
    only within ``config.search_radius_px``.

    Parameters
    ----------
    image_rgb: ``(H, W, 3) uint8`` RGB.
    predicted_uv_px: ``(L, 2)`` predicted spot pixels (NaN rows: that laser is not
        searched), or None to return every blob unassociated.
    config: thresholds.

    Returns
    -------
    ``(L, 2) float64`` spot centres in laser order, NaN where not found; with
    ``predicted_uv_px=None``, ``(K, 2)`` all blobs, strongest first.
    """
    img = np.asarray(image_rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise InvalidArgumentError(
            f"laser spots need an (H, W, 3) uint8 RGB image, got shape {img.shape} dtype {img.dtype}"
        )
    if predicted_uv_px is None:
        return _spot_candidates(img, config)[0]
    pred = np.asarray(predicted_uv_px, dtype=np.float64)
    if pred.ndim != 2 or pred.shape[1] != 2:
        raise InvalidArgumentError(f"predicted_uv_px must be (L, 2), got shape {pred.shape}")
    cents, _ = _spot_candidates(img, config, pred)
    out = np.full(pred.shape, np.nan)
    if len(cents) == 0 or len(pred) == 0:
        return out
    dist = np.linalg.norm(pred[:, None, :] - cents[None, :, :], axis=2)
    dist[~np.isfinite(dist)] = np.inf
    gate = float(config.search_radius_px)
    big = 1e6
    cost = np.where(dist <= gate, dist, big)
    rows, cols = linear_sum_assignment(cost)
    ok = cost[rows, cols] < big
    out[rows[ok]] = cents[cols[ok]]
    return out


def find_faint_spots(
    image_rgb: np.ndarray, predicted_uv_px: np.ndarray, spots_uv_px: np.ndarray, config: LaserConfig
) -> np.ndarray:
    """The spots :func:`detect_laser_spots` missed, searched close to their prediction with a threshold of their own.

    A faint spot (a dim or green-bleeding laser, turbid water, a video codec's chroma) may peak
    below ``min_red_excess``, or have too few pixels above it (94 % of the simulator's faint,
    green-bleeding spots). Within ``faint_search_radius_px`` of a missing spot's prediction the
    strongest red dominance is its peak; when the peak is at least ``faint_red_excess``, the blob
    is the pixels at or above 30 % of it (and ``faint_red_excess``; 8-connected,
    ``min_spot_area_px`` to ``max_spot_area_px``), centred as a bright spot is. The spot is
    refused when anything else in the window is as red (more than one such blob within the
    radius: a reddish seabed, not a laser), or when its blob is more than half a bright spot's
    area limit.

    ``predicted_uv_px``: ``(L, 2)``; ``spots_uv_px``: ``(L, 2)`` the spots found, NaN where missing.
    Returns a copy of ``spots_uv_px`` with the faint spots filled in.
    """
    out = np.array(spots_uv_px, dtype=np.float64, copy=True)
    if config.faint_red_excess <= 0:
        return out
    h, w = image_rgb.shape[:2]
    radius = float(config.faint_search_radius_px)
    reach = int(math.ceil(radius + math.sqrt(config.max_spot_area_px / math.pi))) + 2
    found = out[np.all(np.isfinite(out), axis=1)]
    missing = [i for i in np.flatnonzero(~np.all(np.isfinite(out), axis=1)) if np.all(np.isfinite(predicted_uv_px[i]))]
    if not missing:
        return out
    # One red dominance image over all the missing spots' windows: most frames without a spot have
    # nothing as red as faint_red_excess anywhere near them (the water takes the red), and stop here.
    near_all = np.asarray(predicted_uv_px, dtype=np.float64)[missing]
    bu0, bv0 = (max(0, int(math.floor(c)) - reach) for c in near_all.min(axis=0))
    bu1, bv1 = (min(n, int(math.ceil(c)) + reach + 1) for c, n in zip(near_all.max(axis=0), (w, h)))
    if bu0 >= bu1 or bv0 >= bv1:
        return out
    excess_all = red_excess(image_rgb[bv0:bv1, bu0:bu1])
    if cv2.minMaxLoc(excess_all)[1] < config.faint_red_excess:
        return out
    for i in missing:
        pred = predicted_uv_px[i]
        u0, v0 = max(0, int(math.floor(pred[0])) - reach), max(0, int(math.floor(pred[1])) - reach)
        u1, v1 = min(w, int(math.ceil(pred[0])) + reach + 1), min(h, int(math.ceil(pred[1])) + reach + 1)
        if u0 >= u1 or v0 >= v1:
            continue
        excess = excess_all[v0 - bv0 : v1 - bv0, u0 - bu0 : u1 - bu0]
        vv, uu = np.ogrid[v0:v1, u0:u1]
        near = (uu - pred[0]) ** 2 + (vv - pred[1]) ** 2 <= radius * radius
        for f in found:  # a bright spot's light is not a faint one
            near &= (uu - f[0]) ** 2 + (vv - f[1]) ** 2 > radius * radius
        if not near.any():
            continue
        peak = int(excess[near].max())
        if peak < config.faint_red_excess:
            continue
        thr = max(config.faint_red_excess, math.ceil(_FAINT_BLOB_FRACTION * peak))
        local = replace(
            config,
            min_red_excess=float(thr),
            search_radius_px=radius,
            max_spot_area_px=max(config.min_spot_area_px, config.max_spot_area_px // 2),
        )
        cents, _ = _spot_candidates(
            np.ascontiguousarray(image_rgb[v0:v1, u0:u1]), local, np.asarray(pred - (u0, v0), dtype=np.float64)[None, :]
        )
        if len(cents) == 1:
            out[i] = cents[0] + (u0, v0)
            found = np.vstack([found, out[i]])
    return out
