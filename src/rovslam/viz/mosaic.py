"""The seabed mosaic: every (k-th) frame laid on the seabed by its pose, altitude and camera model.

Geometry: a pixel's viewing ray (lens distortion removed, then the camera's yaw offset,
roll and pitch: :func:`rovslam.camera.level_from_camera`)
meets the seabed plane ``altitude_m`` below the camera and is turned by the heading into
the world: equation (4) of the paper, ``X = x + Z R(psi) q_xy / q_z``. For a pinhole camera
this chain is one 3x3 homography from image pixels to mosaic pixels per frame, applied with
OpenCV ``warpPerspective`` into the frame's footprint only.

The mosaic grid is north up: column c, row r (pixel centres) lie at

    east  y = y_left_m + c * s,    north  x = x_top_m - r * s,    s = mm_per_px / 1000,

in the run's metric frame (x north, y east, the origin where the dive started). The world
file (``.pgw``) says exactly that, with easting as its X and northing as its Y.

Blending: each frame is divided by the flat field of the lamps and lens (the blurred mean
of a sample of frames), its laser spots are masked, and it is weighted by a feather that
falls to 0 at its border; the mosaic is the weighted mean. The accumulators are tiles
allocated only where frames land, so memory follows the surveyed area, not its bounding
box, and frames are streamed one at a time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rovslam.camera import Camera, level_from_camera
from rovslam.errors import ImageReadError, InvalidArgumentError, OutputError
from rovslam.viz.labels import place_labels

TILE_PX = 512
MAX_MOSAIC_PX = 40_000  # per side; beyond it, ask for a coarser --mm-per-px
BACKGROUND_RGB = (235, 235, 235)
LEGEND_BAND_PX = 44  # white band under the mosaic for the scale bar and north arrow (south of the data)


@dataclass(frozen=True)
class Poses:
    """Camera poses of the frames to lay down, each ``(N,)``: frame index, position, altitude, attitude."""

    frame: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    altitude_m: np.ndarray
    heading_rad: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.frame)
        for name in ("x_m", "y_m", "altitude_m", "heading_rad", "roll_rad", "pitch_rad"):
            if len(getattr(self, name)) != n:
                raise InvalidArgumentError(f"Poses.{name} has {len(getattr(self, name))} values for {n} frames")

    def every(self, k: int) -> Poses:
        """Every ``k``-th pose, keeping only finite ones with a positive altitude."""
        if k < 1:
            raise InvalidArgumentError(f"--every must be a whole number >= 1, got {k}")
        ok = np.isfinite(self.x_m) & np.isfinite(self.y_m) & np.isfinite(self.heading_rad) & (self.altitude_m > 0)
        sel = np.nonzero(ok)[0][::k]
        return Poses(*(np.asarray(getattr(self, f))[sel] for f in Poses.__dataclass_fields__))


@dataclass(frozen=True)
class MosaicGrid:
    """North-up pixel grid: pixel centre (c, r) at east ``y_left_m + c s``, north ``x_top_m - r s``."""

    x_top_m: float
    y_left_m: float
    mm_per_px: float
    width_px: int
    height_px: int

    @property
    def m_per_px(self) -> float:
        return self.mm_per_px / 1000.0

    def world_to_px(self, xy_m: np.ndarray) -> np.ndarray:
        """(N, 2) world (x north, y east) -> (N, 2) mosaic pixels (col, row)."""
        xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
        return np.column_stack([(xy[:, 1] - self.y_left_m) / self.m_per_px, (self.x_top_m - xy[:, 0]) / self.m_per_px])

    def px_to_world(self, cr_px: np.ndarray) -> np.ndarray:
        """(N, 2) mosaic pixels (col, row) -> (N, 2) world (x north, y east)."""
        cr = np.asarray(cr_px, dtype=float).reshape(-1, 2)
        return np.column_stack([self.x_top_m - cr[:, 1] * self.m_per_px, self.y_left_m + cr[:, 0] * self.m_per_px])

    @property
    def world_from_px(self) -> np.ndarray:
        """(3, 3) homogeneous map (col, row, 1) -> (x north, y east, 1)."""
        s = self.m_per_px
        return np.array([[0.0, -s, self.x_top_m], [s, 0.0, self.y_left_m], [0.0, 0.0, 1.0]])

    @property
    def px_from_world(self) -> np.ndarray:
        """(3, 3) homogeneous map (x north, y east, 1) -> (col, row, 1)."""
        return np.linalg.inv(self.world_from_px)

    def world_file(self) -> str:
        """ESRI world file text: easting and northing (metres) of each pixel centre, origin at pixel (0, 0)."""
        s = self.m_per_px
        return "\n".join(f"{v:.10f}" for v in (s, 0.0, 0.0, -s, self.y_left_m, self.x_top_m)) + "\n"


def read_world_file(path: str | Path) -> np.ndarray:
    """A ``.pgw`` as the (3, 3) map (col, row, 1) -> (easting, northing, 1)."""
    a, d, b, e, c, f = (float(v) for v in Path(path).read_text(encoding="utf-8").split())
    return np.array([[a, b, c], [d, e, f], [0.0, 0.0, 1.0]])


def frame_homography(
    camera: Camera,
    grid: MosaicGrid,
    x_m: float,
    y_m: float,
    altitude_m: float,
    heading_rad: float,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """(3, 3) map from ideal (undistorted) image pixels (u, v, 1) to mosaic pixels (col, row, 1)."""
    r_lc = level_from_camera(camera, roll_rad, pitch_rad)
    c, s, z = math.cos(heading_rad), math.sin(heading_rad), altitude_m
    world = np.array([[z * c, -z * s, x_m], [z * s, z * c, y_m], [0.0, 0.0, 1.0]])  # eq. (4), homogeneous
    return grid.px_from_world @ world @ r_lc @ np.linalg.inv(camera.K)


def _outline_px(camera: Camera) -> np.ndarray:
    """(K, 2) pixels along the image border (corners and edge points) for footprint bounds."""
    w, h = camera.width_px - 1, camera.height_px - 1
    t = np.linspace(0.0, 1.0, 9)
    return np.vstack(
        [
            np.column_stack([t * w, np.zeros_like(t)]),
            np.column_stack([t * w, np.full_like(t, h)]),
            np.column_stack([np.zeros_like(t), t * h]),
            np.column_stack([np.full_like(t, w), t * h]),
        ]
    )


def _footprints(camera: Camera, poses: Poses, grid: MosaicGrid) -> np.ndarray:
    """(N, 4) footprint bounds [col0, row0, col1, row1] of every pose on ``grid``."""
    border = np.column_stack([_outline_px(camera), np.ones(len(_outline_px(camera)))])
    out = np.empty((len(poses.frame), 4))
    for k in range(len(poses.frame)):
        h = frame_homography(
            camera,
            grid,
            poses.x_m[k],
            poses.y_m[k],
            poses.altitude_m[k],
            poses.heading_rad[k],
            poses.roll_rad[k],
            poses.pitch_rad[k],
        )
        p = border @ h.T
        p = p[:, :2] / p[:, 2:3]
        out[k] = (p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max())
    return out


def plan_grid(camera: Camera, poses: Poses, mm_per_px: float, margin_px: int = 4) -> MosaicGrid:
    """The smallest north-up grid at ``mm_per_px`` holding every footprint (pixel centres on multiples of s)."""
    if not (math.isfinite(mm_per_px) and mm_per_px > 0):
        raise InvalidArgumentError(f"--mm-per-px must be a positive number, got {mm_per_px}")
    if len(poses.frame) == 0:
        raise InvalidArgumentError("no frame to lay down (no pose with a finite position and a positive altitude)")
    s = mm_per_px / 1000.0
    unit = MosaicGrid(0.0, 0.0, mm_per_px, 1, 1)
    fp = _footprints(camera, poses, unit)
    col0, row0 = math.floor(fp[:, 0].min()) - margin_px, math.floor(fp[:, 1].min()) - margin_px
    col1, row1 = math.ceil(fp[:, 2].max()) + margin_px, math.ceil(fp[:, 3].max()) + margin_px
    w, h = col1 - col0 + 1, row1 - row0 + 1
    if max(w, h) > MAX_MOSAIC_PX:
        raise InvalidArgumentError(
            f"the mosaic would be {w}x{h} px at {mm_per_px} mm/px (more than {MAX_MOSAIC_PX} px a side); "
            f"give a coarser --mm-per-px (e.g. {mm_per_px * max(w, h) / MAX_MOSAIC_PX * 1.1:.3g})"
        )
    return MosaicGrid(x_top_m=-row0 * s, y_left_m=col0 * s, mm_per_px=mm_per_px, width_px=w, height_px=h)


class TiledAccumulator:
    """Weighted sums of RGB in ``tile_px`` square float32 tiles, allocated only where something lands."""

    def __init__(self, width_px: int, height_px: int, tile_px: int = TILE_PX):
        self.width_px, self.height_px, self.tile_px = width_px, height_px, tile_px
        self.tiles: dict[tuple[int, int], np.ndarray] = {}

    def add(self, rgb_w: np.ndarray, col0: int, row0: int) -> None:
        """Add ``rgb_w`` (h, w, 4) float32 (weighted RGB, weight) with its top-left at mosaic (col0, row0)."""
        h, w = rgb_w.shape[:2]
        t = self.tile_px
        for tr in range(max(row0, 0) // t, (min(row0 + h, self.height_px) - 1) // t + 1):
            for tc in range(max(col0, 0) // t, (min(col0 + w, self.width_px) - 1) // t + 1):
                r_lo, r_hi = max(row0, tr * t), min(row0 + h, (tr + 1) * t, self.height_px)
                c_lo, c_hi = max(col0, tc * t), min(col0 + w, (tc + 1) * t, self.width_px)
                if r_hi <= r_lo or c_hi <= c_lo:
                    continue
                tile = self.tiles.get((tr, tc))
                if tile is None:
                    tile = self.tiles[(tr, tc)] = np.zeros((t, t, 4), np.float32)
                tile[r_lo - tr * t : r_hi - tr * t, c_lo - tc * t : c_hi - tc * t] += rgb_w[
                    r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0
                ]

    def image(self, background_rgb: tuple[int, int, int] = BACKGROUND_RGB) -> tuple[np.ndarray, np.ndarray]:
        """``(rgb (H, W, 3) uint8, covered (H, W) bool)``: the weighted mean where any weight landed."""
        rgb = np.empty((self.height_px, self.width_px, 3), np.uint8)
        rgb[:] = background_rgb
        covered = np.zeros((self.height_px, self.width_px), bool)
        t = self.tile_px
        for (tr, tc), tile in self.tiles.items():
            h = min(t, self.height_px - tr * t)
            w = min(t, self.width_px - tc * t)
            acc = tile[:h, :w]
            wsum = acc[:, :, 3]
            ok = wsum > 1e-6
            mean = acc[:, :, :3] / np.maximum(wsum, 1e-6)[:, :, None]
            view = rgb[tr * t : tr * t + h, tc * t : tc * t + w]
            view[ok] = np.clip(mean[ok] + 0.5, 0, 255).astype(np.uint8)
            covered[tr * t : tr * t + h, tc * t : tc * t + w] = ok
        return rgb, covered


def feather_weight(camera: Camera) -> np.ndarray:
    """(H, W) float32 blending weight: 1 at the image centre, falling to 0 at the border."""
    h, w = camera.height_px, camera.width_px
    wu = 1.0 - np.abs(np.linspace(-1.0, 1.0, w))
    wv = 1.0 - np.abs(np.linspace(-1.0, 1.0, h))
    return (np.outer(wv, wu) + 1e-3).astype(np.float32)


def laser_mask(rgb: np.ndarray, dilate_px: int = 6) -> np.ndarray:
    """(H, W) bool: saturated red laser spots (and a rim) to leave out of the mosaic."""
    import cv2

    r, g = rgb[:, :, 0].astype(np.int16), rgb[:, :, 1].astype(np.int16)
    m = ((r > 200) & (r - g > 80)).astype(np.uint8)
    if not m.any():
        return m.astype(bool)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * dilate_px + 1, 2 * dilate_px + 1))
    return cv2.dilate(m, k).astype(bool)


def flat_field(images: Iterable[np.ndarray], sigma_frac: float = 0.12) -> np.ndarray | None:
    """(H, W, 3) float32 gain of the lamps and lens, mean 1 per channel (None without images)."""
    import cv2

    acc, n = None, 0
    for img in images:
        f = img.astype(np.float32)
        acc = f if acc is None else acc + f
        n += 1
    if acc is None:
        return None
    mean = acc / n
    sigma = sigma_frac * max(mean.shape[:2])
    flat = cv2.GaussianBlur(mean, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    flat /= np.maximum(flat.reshape(-1, 3).mean(axis=0), 1e-3)  # type: ignore[misc]
    return np.maximum(flat, 0.05)


def lay_frame(
    acc: TiledAccumulator,
    camera: Camera,
    grid: MosaicGrid,
    image: np.ndarray,
    h_px: np.ndarray,
    weight: np.ndarray,
    flat: np.ndarray | None,
) -> None:
    """Warp one frame ``image`` (H, W, 3) uint8 by ``h_px`` (ideal pixels -> mosaic) and add it to ``acc``."""
    import cv2

    img = image
    if camera.has_distortion:
        img = cv2.undistort(image, camera.K, camera.dist_coeffs)
    f = img.astype(np.float32)
    if flat is not None:
        f /= flat
    w = weight * (~laser_mask(image)).astype(np.float32)
    if camera.has_distortion:
        w = cv2.undistort(w, camera.K, camera.dist_coeffs)
    border = np.column_stack([_outline_px(camera), np.ones(len(_outline_px(camera)))]) @ h_px.T
    border = border[:, :2] / border[:, 2:3]
    c0, r0 = int(math.floor(border[:, 0].min())), int(math.floor(border[:, 1].min()))
    c1, r1 = int(math.ceil(border[:, 0].max())), int(math.ceil(border[:, 1].max()))
    c0, r0, c1, r1 = max(c0, 0), max(r0, 0), min(c1, grid.width_px - 1), min(r1, grid.height_px - 1)
    if c1 < c0 or r1 < r0:
        return
    shift = np.array([[1.0, 0.0, -c0], [0.0, 1.0, -r0], [0.0, 0.0, 1.0]]) @ h_px
    size = (c1 - c0 + 1, r1 - r0 + 1)
    src = np.dstack([f * w[:, :, None], w])
    out = cv2.warpPerspective(src, shift, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    acc.add(out, c0, r0)


@dataclass(frozen=True)
class Mosaic:
    rgb: np.ndarray  # (H, W, 3) uint8, the blended seabed (background where nothing landed)
    covered: np.ndarray  # (H, W) bool
    grid: MosaicGrid
    frames_used: int
    tiles: int  # accumulator tiles allocated (memory: tiles x TILE_PX^2 x 16 bytes)


def build_mosaic(
    camera: Camera,
    poses: Poses,
    images: Callable[[list[int]], Iterable[tuple[int, np.ndarray]]],
    mm_per_px: float,
    flat_samples: int = 48,
    progress: Callable[[int, int], None] | None = None,
    grid: MosaicGrid | None = None,
) -> Mosaic:
    """Blend the frames of ``poses`` into a north-up mosaic.

    ``images(indices)`` yields ``(index, (H, W, 3) uint8 RGB)`` in order (e.g.
    :meth:`rovslam.viz.frames.FrameStore.stream`); frames it leaves out are skipped.
    ``grid`` fixes the pixel grid (to compare two mosaics pixel for pixel), else it is planned
    to hold every footprint.
    """
    grid = grid or plan_grid(camera, poses, mm_per_px)
    idx = [int(i) for i in poses.frame]
    sample = idx[:: max(1, len(idx) // flat_samples)][:flat_samples]
    flat = flat_field(img for _, img in images(sample)) if len(idx) >= 8 else None
    acc = TiledAccumulator(grid.width_px, grid.height_px)
    weight = feather_weight(camera)
    row = {f: k for k, f in enumerate(idx)}
    used = 0
    for i, img in images(idx):
        k = row.get(i)
        if k is None or img.shape[:2] != camera.shape:
            continue
        h = frame_homography(
            camera,
            grid,
            poses.x_m[k],
            poses.y_m[k],
            poses.altitude_m[k],
            poses.heading_rad[k],
            poses.roll_rad[k],
            poses.pitch_rad[k],
        )
        lay_frame(acc, camera, grid, img, h, weight, flat)
        used += 1
        if progress is not None:
            progress(used, len(idx))
    rgb, covered = acc.image()
    return Mosaic(rgb, covered, grid, used, len(acc.tiles))


def nice_length_m(max_m: float) -> float:
    """The largest 1-2-5 length (metres) not above ``max_m``."""
    e = 10 ** math.floor(math.log10(max_m))
    for m in (5, 2, 1):
        if m * e <= max_m:
            return m * e
    return e


LANDMARK_RGB = (220, 30, 30)
LABEL_FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX
LABEL_SCALE = 0.35


def landmark_labels(
    points_px: np.ndarray, texts: list[str], shape_hw: tuple[int, int]
) -> list[tuple[str, tuple[int, int], tuple[tuple[int, int], tuple[int, int]] | None]]:
    """Where to write each landmark's id on the mosaic so that no two ids overlap.

    ``points_px`` ``(N, 2)`` the landmarks' pixels (u right, v down), ``texts`` their ids,
    ``shape_hw`` the image's size. The boxes come from :func:`rovslam.viz.labels.place_labels`
    (the report's placement), worked in v up so that a label's first choice is above and to the
    right of its cross, as before; landmarks mapped a few pixels apart get their ids side by side
    instead of one over the other. Returns per label ``(text, origin (u, v) for cv2.putText,
    leader line ((u, v), (u, v)) or None)``; a label moved off its first place has a leader line
    from its cross to the nearest point of its box.
    """
    import cv2

    if len(texts) == 0:
        return []
    sizes = np.array([cv2.getTextSize(t, LABEL_FONT, LABEL_SCALE, 1)[0] for t in texts], float)
    up = points_px * np.array([1.0, -1.0])
    h_px, w_px = shape_hw
    centres, moved = place_labels(up, sizes, gap_px=1.0, bounds_px=(0.0, -float(h_px), float(w_px), 0.0))
    out = []
    for text, (w, h), (cu, cv_up), m, (pu, pv) in zip(texts, sizes, centres, moved, points_px):
        u0, v0 = cu - w / 2.0, -cv_up - h / 2.0  # the box's top-left corner in the image (v down)
        leader = None
        if m:
            end = (int(round(min(max(pu, u0), u0 + w))), int(round(min(max(pv, v0), v0 + h))))
            leader = ((int(pu), int(pv)), end)
        out.append((text, (int(round(u0)), int(round(v0 + h))), leader))
    return out


def decorate(
    mosaic: Mosaic, path_xy_m: np.ndarray | None = None, landmarks: dict | None = None, path_colour=(30, 110, 230)
) -> np.ndarray:
    """The mosaic with the path and landmarks drawn and, in a band below it, a scale bar and a north arrow.

    The band is added under the last row (south), so pixel (0, 0) and the world file stay exact.
    """
    import cv2

    g = mosaic.grid
    img = np.ascontiguousarray(mosaic.rgb.copy())
    aa = cv2.LINE_AA
    if path_xy_m is not None and len(path_xy_m) > 1:
        pts = g.world_to_px(path_xy_m)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        cv2.polylines(img, [np.round(pts * 4).astype(np.int32).reshape(-1, 1, 2)], False, path_colour, 1, aa, shift=2)
    if landmarks and len(landmarks.get("id", [])):
        lp = g.world_to_px(np.column_stack([landmarks["x_m"], landmarks["y_m"]]))
        h_px, w_px = img.shape[:2]
        points, texts = [], []
        for (c, r), lid in zip(lp, landmarks["id"]):
            if not (np.isfinite(c) and np.isfinite(r) and -w_px <= c <= 2 * w_px and -h_px <= r <= 2 * h_px):
                continue  # a landmark far off the mosaic (a damaged landmarks.csv): no marker to draw
            c, r = int(round(c)), int(round(r))
            cv2.drawMarker(img, (c, r), LANDMARK_RGB, cv2.MARKER_CROSS, 9, 1, aa)
            points.append((c, r))
            texts.append(str(int(lid)))
        for text, (u, v), leader in landmark_labels(np.array(points, float).reshape(-1, 2), texts, (h_px, w_px)):
            if leader is not None:
                cv2.line(img, *leader, LANDMARK_RGB, 1, aa)
            cv2.putText(img, text, (u, v), LABEL_FONT, LABEL_SCALE, LANDMARK_RGB, 1, aa)
    band = _legend_band(img.shape[1], g)
    return np.vstack([img, band])


SCALE_FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX
SCALE_TEXT_MIN_PX = 17  # cv2 text height of the scale digits (ink about 14 px) up to LEGEND_REF_WIDTH_PX wide
LEGEND_REF_WIDTH_PX = 800  # wider mosaics get their legend band and text scaled up with the width


def legend_layout(width_px: int) -> tuple[float, int, float]:
    """(font scale, stroke thickness px, size factor) of the legend under a mosaic ``width_px`` wide.

    The scale bar's digits are about :data:`SCALE_TEXT_MIN_PX` tall (cv2's text height) and grow in proportion
    with a mosaic wider than :data:`LEGEND_REF_WIDTH_PX`, so they stay readable when it is shrunk.
    """
    import cv2

    k = max(1.0, width_px / LEGEND_REF_WIDTH_PX)
    thickness = max(1, int(round(k)))
    (_, h_1), _ = cv2.getTextSize("0123456789", SCALE_FONT, 1.0, thickness)
    return SCALE_TEXT_MIN_PX * k / h_1, thickness, k


def _legend_band(w_px: int, g: MosaicGrid) -> np.ndarray:
    """The white (H, w_px, 3) band under a mosaic: scale bar, its length and mm/px, north arrow."""
    import cv2

    aa = cv2.LINE_AA
    font_scale, thick, k = legend_layout(w_px)
    (_, text_h), base = cv2.getTextSize("0 cm", SCALE_FONT, font_scale, thick)
    x0, y0, bar_h = int(10 * k), int(10 * k), max(6, int(round(7 * k)))
    band_px = max(LEGEND_BAND_PX, y0 + bar_h + int(6 * k) + text_h + base + int(6 * k))
    band = np.full((band_px, w_px, 3), 255, np.uint8)
    bar_m = nice_length_m(max(0.25 * w_px * g.m_per_px, 1e-4))
    bar_px = max(1, int(round(bar_m / g.m_per_px)))
    n_seg = 4
    for s in range(n_seg):
        xa = x0 + s * bar_px // n_seg
        xb = x0 + (s + 1) * bar_px // n_seg
        cv2.rectangle(band, (xa, y0), (xb, y0 + bar_h), (0, 0, 0) if s % 2 == 0 else (255, 255, 255), -1)
    cv2.rectangle(band, (x0, y0), (x0 + bar_px, y0 + bar_h), (0, 0, 0), 1)
    label = f"{bar_m * 100:g} cm" if bar_m < 1 else f"{bar_m:g} m"
    baseline = y0 + bar_h + int(6 * k) + text_h
    cv2.putText(band, label, (x0, baseline), SCALE_FONT, font_scale, (0, 0, 0), thick, aa)
    small = 0.85 * font_scale
    cv2.putText(
        band,
        f"{g.mm_per_px:g} mm/px",
        (x0 + bar_px + int(12 * k), baseline),
        SCALE_FONT,
        small,
        (60, 60, 60),
        thick,
        aa,
    )
    (mm_w, _), _ = cv2.getTextSize(f"{g.mm_per_px:g} mm/px", SCALE_FONT, small, thick)
    ax = w_px - int(22 * k)
    if ax > x0 + bar_px + int(12 * k) + mm_w + int(30 * k):
        cv2.arrowedLine(band, (ax, band_px - int(6 * k)), (ax, int(6 * k)), (0, 0, 0), max(2, thick), aa, tipLength=0.3)
        (n_w, n_h), _ = cv2.getTextSize("N", SCALE_FONT, font_scale, thick)
        cv2.putText(band, "N", (ax - n_w - int(6 * k), int(6 * k) + n_h), SCALE_FONT, font_scale, (0, 0, 0), thick, aa)
    return band


def write_mosaic(path: str | Path, rgb: np.ndarray, grid: MosaicGrid) -> tuple[Path, Path]:
    """Write the PNG and its world file (same name, ``.pgw``). Returns both paths."""
    import cv2

    from rovslam.io.output import atomic_write_bytes, atomic_write_text, output_errors

    png = check_mosaic_path(path)
    with output_errors(png.parent, "cannot create the folder"):
        png.parent.mkdir(parents=True, exist_ok=True)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise InvalidArgumentError(f"{png}: OpenCV could not encode the mosaic as PNG")
    atomic_write_bytes(png, buf.tobytes(), "the mosaic")  # never into a device or a FIFO: refused
    pgw = png.with_suffix(".pgw")
    atomic_write_text(pgw, grid.world_file(), "the mosaic's world file")
    return png, pgw


def check_mosaic_path(path: str | Path) -> Path:
    """``path`` as the PNG file of a mosaic, or :class:`OutputError` (a folder, not a ``.png`` name)."""
    from rovslam.io.output import check_output_file

    png = Path(path)
    if not png.is_dir():  # a device, a FIFO, a socket, a dangling link: refused (a folder: told below)
        check_output_file(png, "the mosaic", parent_must_exist=False)
        check_output_file(png.with_suffix(".pgw"), "the mosaic's world file", parent_must_exist=False)
    if png.is_dir():
        raise OutputError(f"{png}: is a folder; the mosaic needs a PNG file name (e.g. {png / 'mosaic.png'}).")
    if png.suffix.lower() != ".png":
        raise OutputError(
            f"{png}: a mosaic is written as PNG; give a file name ending in .png (e.g. {png.with_suffix('.png')})."
        )
    return png


def native_mm_per_px(camera: Camera, altitude_m: np.ndarray) -> float:
    """The camera's ground resolution at the median altitude, rounded up to 0.1 mm."""
    z = float(np.nanmedian(altitude_m)) if len(altitude_m) else 1.0
    return max(0.1, math.ceil(10.0 * 1000.0 * z / camera.focal_px) / 10.0)


def estimate_poses(res, roll_rad: np.ndarray, pitch_rad: np.ndarray) -> Poses:
    """Poses of a run's frames (trajectory.csv row k is frame k), skipped frames left out."""
    tr = res.trajectory
    n = len(res.t_s)
    keep = np.ones(n, bool) if "skipped" not in tr else tr["skipped"] < 0.5
    frame = np.arange(n)[keep]
    heading = tr["heading_rad"] if "heading_rad" in tr else np.zeros(n)
    return Poses(
        frame,
        tr["x_m"][keep],
        tr["y_m"][keep],
        tr["altitude_m"][keep],
        heading[keep],
        _attitude(roll_rad, frame),
        _attitude(pitch_rad, frame),
    )


def truth_poses(gt, frame_t_s: np.ndarray, roll_rad: np.ndarray, pitch_rad: np.ndarray, tol_s: float = 1e-3) -> Poses:
    """Poses from a ground truth (``GroundTruth``), matched to the frames by time."""
    k = np.clip(np.searchsorted(frame_t_s, gt.t_s - tol_s), 0, max(len(frame_t_s) - 1, 0))
    ok = np.abs(frame_t_s[k] - gt.t_s) <= tol_s if len(frame_t_s) else np.zeros(len(gt.t_s), bool)
    frame = k[ok]
    return Poses(
        frame,
        gt.x_m[ok],
        gt.y_m[ok],
        gt.altitude_m[ok],
        gt.heading_rad[ok],
        _attitude(roll_rad, frame),
        _attitude(pitch_rad, frame),
    )


def _attitude(values: np.ndarray, frame: np.ndarray) -> np.ndarray:
    if len(values) == 0:
        return np.zeros(len(frame))
    return np.asarray(values, dtype=float)[np.clip(frame, 0, len(values) - 1)]


@dataclass(frozen=True)
class MosaicFiles:
    png: Path
    world_file: Path
    mosaic: Mosaic


def mosaic_of_run(
    results_dir: str | Path,
    out_png: str | Path | None = None,
    seq: str | Path | None = None,
    mm_per_px: float | None = None,
    every: int = 1,
    groundtruth: str | Path | None = None,
    overlay: bool = True,
    grid: MosaicGrid | None = None,
    progress: Callable[[int, int], None] | None = None,
    camera_file: str | Path | None = None,
) -> MosaicFiles:
    """The mosaic of a run: laid by the estimate, or by ``groundtruth`` (a groundtruth.csv) when given.

    Writes ``out_png`` (default ``OUT/mosaic.png``, ``OUT/mosaic_truth.png`` for the truth) and
    its ``.pgw`` world file; with ``overlay`` the path (and, for the estimate, the landmarks) is drawn.
    ``camera_file`` is the camera of a video run (default: the one summary.json names).
    """
    from rovslam.io.run_results import read_results
    from rovslam.viz.frames import open_frames

    if out_png is not None:
        check_mosaic_path(out_png)  # before the work: a bad name is refused at once
    res = read_results(results_dir)
    store = open_frames(res.summary, seq, camera_file, results_dir)
    if groundtruth is not None:
        from rovslam.io.sequence import read_groundtruth

        gt = read_groundtruth(groundtruth)
        t_frames = np.array([r.t_s for r in store.source.rows]) if not store.is_video else res.t_s
        poses = truth_poses(gt, t_frames, store.roll_rad, store.pitch_rad)
        path_xy = np.column_stack([gt.x_m, gt.y_m])
        lms = None
        default_name = "mosaic_truth.png"
    else:
        poses = estimate_poses(res, store.roll_rad, store.pitch_rad)
        path_xy = res.xy_m
        lms = res.landmarks
        default_name = "mosaic.png"
    if mm_per_px is None:
        mm_per_px = grid.mm_per_px if grid is not None else native_mm_per_px(store.camera, poses.altitude_m)
    poses = poses.every(int(every))
    mosaic = build_mosaic(store.camera, poses, store.stream, mm_per_px, progress=progress, grid=grid)
    if mosaic.frames_used == 0:  # an empty mosaic would pass for a result
        raise ImageReadError(
            f"{store.path}: none of the {len(poses.frame)} frames to lay could be read (images missing, unreadable "
            "or of another size); give the run's sequence or video with --seq."
        )
    rgb = decorate(mosaic, path_xy if overlay else None, lms if overlay else None)
    png, pgw = write_mosaic(
        Path(out_png) if out_png is not None else Path(results_dir) / default_name, rgb, mosaic.grid
    )
    return MosaicFiles(png, pgw, mosaic)
