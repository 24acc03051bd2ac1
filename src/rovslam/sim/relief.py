"""Seabed relief: a height field above the mean seabed plane, on its own texel grid.

Heights are metres, positive up, about zero on average (the ground truth's ``altitude_m``
is the altitude above that mean plane). Relief texel ``(i, j)`` lies at world
``x = i * texel_m`` (north), ``y = j * texel_m`` (east), like the texture texels. A source
answers ``region(row0, col0, n_rows, n_cols) -> (n_rows, n_cols) float32`` heights and
declares ``height_range_m``, bounds that no height leaves (the renderer sizes its windows
and shadow searches with them).

* :class:`ProceduralRelief` - over a :class:`~rovslam.sim.texture.ProceduralSeabed`: sand
  ripples under the texture's ripple crests, the texture's stones and boulders raised as
  domes, ledges (a terrace edge along the contour of a slow noise field) and a slow
  undulation. Chunked and cached like the texture, every feature a function of world
  position, so chunks join without seams.
* :class:`ArrayRelief` - heights given as an array (centred on the world origin, mirrored
  at its borders like :class:`~rovslam.sim.texture.ImageSeabed`).
* :func:`relief_from_photo` - an :class:`ArrayRelief` derived from a seabed photograph:
  brighter is higher, dark crevices lower, at two scales.

Every source keeps its slopes moderate (below about 3): then each viewing ray of a camera
with a field of view up to about +-20 degrees meets the relief once, and the renderer's
fixed-point ray cast converges (see :mod:`rovslam.sim.render`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from rovslam.errors import SimulationError
from rovslam.sim._chunks import ChunkedGrid
from rovslam.sim._noise import lattice_noise_grid, smoothstep
from rovslam.sim.texture import ImageSeabed, ProceduralSeabed, mirror_indices

# Lattice-noise layers of the relief (distinct from the texture's).
_L_LEDGE, _L_LEDGE_WARP, _L_UNDULATION = 201, 202, 203
_RIPPLE_PROFILE_MAX = 1.35 / 1.2  # max |sin p + 0.35 sin(2p + 0.8)| / 1.2 bound


class ReliefSource(Protocol):
    """Anything that gives seabed heights on a world-anchored texel grid."""

    @property
    def texel_m(self) -> float: ...

    @property
    def height_range_m(self) -> tuple[float, float]:
        """(lowest, highest) height any texel can have, metres."""
        ...

    def region(self, row0: int, col0: int, n_rows: int, n_cols: int) -> np.ndarray:
        """``(n_rows, n_cols) float32`` heights of texels ``row0 .. row0 + n_rows - 1`` etc."""
        ...


@dataclass(frozen=True)
class ReliefParams:
    """Procedural relief over a procedural seabed. Heights and lengths in metres.

    ``ripple_height_m`` is the crest height of the sand ripples above their mean;
    ``stone_height_ratio`` the height of a stone or boulder over its mean radius (a dome);
    ``ledge_height_m`` the step of a terrace edge (the seabed is ``+-ledge_height_m / 2``
    either side), ``ledge_width_m`` the horizontal width of its face; ``undulation_m`` the
    standard deviation of a slow swell of the seabed over ``undulation_scale_m``.
    """

    texel_mm: float = 2.0
    chunk_texels: int = 256
    cache_chunks: int = 64
    ripple_height_m: float = 0.0
    stone_height_ratio: float = 0.0
    ledge_height_m: float = 0.0
    ledge_scale_m: float = 0.6
    ledge_width_m: float = 0.04
    undulation_m: float = 0.0
    undulation_scale_m: float = 0.9

    def __post_init__(self) -> None:
        if not (0.2 <= self.texel_mm <= 20.0):
            raise SimulationError(f"ReliefParams.texel_mm must be in [0.2, 20] mm, got {self.texel_mm}")
        if self.chunk_texels < 32 or self.cache_chunks < 4:
            raise SimulationError(
                f"ReliefParams needs chunk_texels >= 32 and cache_chunks >= 4, got {self.chunk_texels}, "
                f"{self.cache_chunks}"
            )
        for name in ("ripple_height_m", "stone_height_ratio", "ledge_height_m", "undulation_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"ReliefParams.{name} must be a finite number >= 0, got {v}")
        if self.stone_height_ratio > 1.0:
            raise SimulationError(
                f"ReliefParams.stone_height_ratio must be <= 1 (steeper stones would hide the seabed behind "
                f"them), got {self.stone_height_ratio}"
            )
        for name in ("ledge_scale_m", "ledge_width_m", "undulation_scale_m"):
            if not getattr(self, name) > 0:
                raise SimulationError(f"ReliefParams.{name} must be > 0, got {getattr(self, name)}")
        if self.ledge_height_m > 2.0 * self.ledge_width_m:
            raise SimulationError(
                f"ReliefParams: a ledge {self.ledge_height_m} m high needs a face at least "
                f"{self.ledge_height_m / 2.0:.3f} m wide (ledge_width_m), got {self.ledge_width_m}"
            )


class ProceduralRelief(ChunkedGrid):
    """The relief of a :class:`ProceduralSeabed` (see the module docstring).

    ``region`` gives ``(n_rows, n_cols) float32`` heights. Thread-safe.
    """

    def __init__(self, params: ReliefParams, seabed: ProceduralSeabed) -> None:
        super().__init__(params.chunk_texels, params.cache_chunks, (), np.float32)
        self.params = params
        self.seabed = seabed
        self.seed = seabed.seed
        self._texel_m = params.texel_mm * 1e-3
        tp = seabed.params
        # Largest stone / boulder radius the texture draws (sizes are capped to their reach).
        max_radius = 3.0 * tp.stone_radius_mm * 1e-3
        if tp.boulder_density_per_m2 > 0:
            max_radius = max(max_radius, 2.0 * tp.boulder_radius_mm * 1e-3)
        p = params
        ripple = p.ripple_height_m * _RIPPLE_PROFILE_MAX
        undulation = 4.0 * p.undulation_m
        self._range = (
            -(ripple + 0.5 * p.ledge_height_m + undulation),
            ripple + 0.5 * p.ledge_height_m + undulation + p.stone_height_ratio * max_radius,
        )

    @property
    def texel_m(self) -> float:
        return self._texel_m

    @property
    def height_range_m(self) -> tuple[float, float]:
        return self._range

    def _generate_chunk(self, ci: int, cj: int) -> np.ndarray:
        p, t, n = self.params, self._texel_m, self.params.chunk_texels
        x0, y0 = ci * n * t, cj * n * t
        xs = (x0 + t * np.arange(n, dtype=np.float64))[:, None]
        ys = (y0 + t * np.arange(n, dtype=np.float64))[None, :]

        def field(layer: int, cell: float | tuple[float, float]) -> np.ndarray:
            return lattice_noise_grid(self.seed, layer, x0, y0, n, n, t, cell)

        h = np.zeros((n, n), dtype=np.float64)
        if p.ripple_height_m > 0 and self.seabed.params.ripple_strength > 0:
            amp, profile = self.seabed.ripples(field, xs, ys)
            h += p.ripple_height_m * amp * profile
        if p.ledge_height_m > 0:
            # The terrace edge is the zero contour of a slow field; dividing by the field's
            # gradient makes the face about ledge_width_m wide wherever it runs.
            # (evaluated with a one-texel apron, so the gradient is central everywhere: no seams)
            f = (
                lattice_noise_grid(self.seed, _L_LEDGE, x0 - t, y0 - t, n + 2, n + 2, t, p.ledge_scale_m)
                + 0.25
                * lattice_noise_grid(self.seed, _L_LEDGE_WARP, x0 - t, y0 - t, n + 2, n + 2, t, p.ledge_scale_m / 3.0)
            ).astype(np.float64)
            g_north, g_east = np.gradient(f, t)
            f, slope = f[1:-1, 1:-1], np.hypot(g_north, g_east)[1:-1, 1:-1]
            dist = f / np.maximum(slope, 0.5 / p.ledge_scale_m)
            h += p.ledge_height_m * (smoothstep(-0.5 * p.ledge_width_m, 0.5 * p.ledge_width_m, dist) - 0.5)
        if p.undulation_m > 0:
            h += p.undulation_m * np.clip(field(_L_UNDULATION, p.undulation_scale_m), -4.0, 4.0)
        if p.stone_height_ratio > 0:
            for objs in self.seabed.stones_near(x0, y0, n * t):
                _raise_domes(h, objs, x0, y0, t, p.stone_height_ratio)
        lo, hi = self._range
        return np.clip(h, lo, hi).astype(np.float32)


def _raise_domes(h: np.ndarray, objs, x0: float, y0: float, texel_m: float, ratio: float) -> None:
    """Add a stone ``H (1 - r^4)^1.5`` (H = ratio x mean radius) over every stone's outline, in place.

    The outline is the texture's (ellipse with the same harmonics), so the raised stone is
    the one drawn on the texture. The profile has a rounded top and steep sides (its
    steepest slope, at r = 0.88, is about 2.6 H / radius) meeting the sand smoothly.
    """
    n_r, n_c = h.shape
    for k in range(len(objs.x_m)):
        a, b, th = float(objs.a_m[k]), float(objs.b_m[k]), float(objs.angle_rad[k])
        reach = 1.4 * a
        r_c, c_c = (objs.x_m[k] - x0) / texel_m, (objs.y_m[k] - y0) / texel_m
        r_lo, r_hi = max(0, int(np.floor(r_c - reach / texel_m))), min(n_r, int(np.ceil(r_c + reach / texel_m)) + 1)
        c_lo, c_hi = max(0, int(np.floor(c_c - reach / texel_m))), min(n_c, int(np.ceil(c_c + reach / texel_m)) + 1)
        if r_lo >= r_hi or c_lo >= c_hi:
            continue
        dx = (np.arange(r_lo, r_hi) - r_c)[:, None] * texel_m
        dy = (np.arange(c_lo, c_hi) - c_c)[None, :] * texel_m
        c, s = np.cos(th), np.sin(th)
        u, v = (dx * c + dy * s) / a, (-dx * s + dy * c) / b
        phi = np.arctan2(v, u)
        hk = objs.harmonics[k]
        outline = 1.0 + sum(hk[q, 0] * np.cos((q + 2) * phi + hk[q, 1]) for q in range(4))
        r2 = (u * u + v * v) / (outline * outline)
        h[r_lo:r_hi, c_lo:c_hi] += ratio * np.sqrt(a * b) * np.maximum(1.0 - r2 * r2, 0.0) ** 1.5


class ArrayRelief:
    """Heights given as a ``(H, W)`` array at ``mm_per_px``, mirrored at its borders.

    Array pixel ``origin_px`` (default the centre, ``((H - 1) // 2, (W - 1) // 2)``) lies at
    the world origin; array up is north (+x), right is east (+y), as for
    :class:`~rovslam.sim.texture.ImageSeabed`.
    """

    def __init__(self, heights_m: np.ndarray, mm_per_px: float, origin_px: tuple[int, int] | None = None) -> None:
        arr = np.asarray(heights_m, dtype=np.float32)
        if arr.ndim != 2 or min(arr.shape) < 4:
            raise SimulationError(f"relief heights must be a (H, W) array of at least 4x4, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise SimulationError("relief heights must all be finite numbers (metres)")
        if not (np.isfinite(mm_per_px) and mm_per_px > 0):
            raise SimulationError(f"relief scale must be a positive number of mm per pixel, got {mm_per_px}")
        self.heights = np.ascontiguousarray(arr)
        self.heights.setflags(write=False)
        self._texel_m = float(mm_per_px) * 1e-3
        self._r0, self._c0 = origin_px if origin_px is not None else ((arr.shape[0] - 1) // 2, (arr.shape[1] - 1) // 2)  # type: ignore[var-annotated]
        self._range = (float(arr.min()), float(arr.max()))

    @property
    def texel_m(self) -> float:
        return self._texel_m

    @property
    def height_range_m(self) -> tuple[float, float]:
        return self._range

    def region(self, row0: int, col0: int, n_rows: int, n_cols: int) -> np.ndarray:
        h, w = self.heights.shape
        rows = mirror_indices(self._r0 - (row0 + np.arange(n_rows)), h)  # world +x is array up
        cols = mirror_indices(self._c0 + col0 + np.arange(n_cols), w)
        return self.heights[rows[:, None], cols[None, :]]


@dataclass(frozen=True)
class PhotoReliefParams:
    """Relief derived from a seabed photograph: brighter is higher, dark crevices lower.

    Height = coarse band (luminance blurred at ``coarse_sigma_mm`` minus its blur at
    ``background_sigma_mm``) + ``fine_weight`` x fine band (blur at ``fine_sigma_mm`` minus
    the coarse blur), scaled so that the 1st-99th percentile span is ``relief_m``; where
    that is steeper than ``max_slope`` somewhere, the fine band is blurred more (x1.25 at a
    time) until it is not.
    """

    relief_m: float = 0.08
    fine_sigma_mm: float = 4.0
    coarse_sigma_mm: float = 20.0
    background_sigma_mm: float = 150.0
    fine_weight: float = 0.5
    max_slope: float = 2.5

    def __post_init__(self) -> None:
        for name in ("relief_m", "fine_sigma_mm", "coarse_sigma_mm", "background_sigma_mm", "max_slope"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise SimulationError(f"PhotoReliefParams.{name} must be > 0, got {getattr(self, name)}")
        if not self.fine_sigma_mm < self.coarse_sigma_mm < self.background_sigma_mm:
            raise SimulationError("PhotoReliefParams needs fine_sigma_mm < coarse_sigma_mm < background_sigma_mm")
        if self.fine_weight < 0:
            raise SimulationError(f"PhotoReliefParams.fine_weight must be >= 0, got {self.fine_weight}")


def relief_from_photo(seabed: ImageSeabed, params: PhotoReliefParams | None = None) -> ArrayRelief:
    """The relief of a seabed photograph (see :class:`PhotoReliefParams`), on the photo's own pixel grid."""
    import cv2

    p = params if params is not None else PhotoReliefParams()
    mm = seabed.texel_m * 1e3
    rgb = seabed.image.astype(np.float32)
    lum = 0.3 * rgb[..., 0] + 0.55 * rgb[..., 1] + 0.15 * rgb[..., 2]

    def blur(img: np.ndarray, sigma_mm: float) -> np.ndarray:  # mirrored borders, as the photo is
        sigma_px = sigma_mm / mm
        if sigma_px <= 12.0:
            return cv2.GaussianBlur(img, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)
        # Wide blurs on a decimated copy (the result is smooth at that scale anyway).
        f = int(sigma_px // 6.0)
        small = cv2.resize(img, (max(1, img.shape[1] // f), max(1, img.shape[0] // f)), interpolation=cv2.INTER_AREA)
        small = cv2.GaussianBlur(small, (0, 0), sigma_px / f, borderType=cv2.BORDER_REFLECT)
        return cv2.resize(small, (img.shape[1], img.shape[0]), interpolation=cv2.INTER_LINEAR)

    coarse = blur(lum, p.coarse_sigma_mm)
    band = coarse - blur(lum, p.background_sigma_mm)
    fine_sigma = p.fine_sigma_mm
    for _ in range(20):  # widen the fine band's blur until the slope bound holds at the full relief span
        h = band + p.fine_weight * (blur(lum, fine_sigma) - coarse)
        lo, hi = np.percentile(h, [1.0, 99.0])
        h = (h - 0.5 * (lo + hi)) * (p.relief_m / max(float(hi - lo), 1e-6))
        h -= float(h.mean())
        g_north, g_east = np.gradient(h, seabed.texel_m)
        if float(np.sqrt(g_north * g_north + g_east * g_east).max()) <= p.max_slope:
            break
        fine_sigma *= 1.25
    else:
        raise SimulationError(
            f"the photo relief stays steeper than max_slope={p.max_slope}; lower relief_m or fine_weight"
        )
    return ArrayRelief(h, mm, origin_px=seabed.origin_px)


def scaled_relief(
    relief: ReliefParams | PhotoReliefParams | None, scale: float
) -> ReliefParams | PhotoReliefParams | None:
    """A scenario's relief with every height multiplied by ``scale`` (0: a flat seabed, None).

    Photo relief: its span ``relief_m``. Procedural relief: the ripples, the stones' height over
    their radius, the ledge's step (its face widened where the step would be steeper than the
    preset's) and the undulation. Raises SimulationError for a negative or non-finite scale, a
    scale on a flat scenario, or stones steeper than a hemisphere.
    """
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (math.isfinite(scale) and scale >= 0):
        raise SimulationError(f"relief scale must be a number >= 0, got {scale!r}")
    if scale == 1.0:
        return relief
    if relief is None:
        raise SimulationError("this scenario has a flat seabed: a relief scale applies only to a scenario with relief")
    if scale == 0.0:
        return None
    if isinstance(relief, PhotoReliefParams):
        return replace(relief, relief_m=relief.relief_m * scale)
    stones = relief.stone_height_ratio * scale
    if stones > 1.0:
        raise SimulationError(
            f"relief scale {scale:g}: the stones would be {stones:.2f} times as high as their radius (at most 1); "
            f"use a scale of at most {1.0 / relief.stone_height_ratio:.2f} on this scenario"
        )
    ledge = relief.ledge_height_m * scale
    return replace(
        relief,
        ripple_height_m=relief.ripple_height_m * scale,
        stone_height_ratio=stones,
        ledge_height_m=ledge,
        ledge_width_m=max(relief.ledge_width_m, ledge / 2.0),
        undulation_m=relief.undulation_m * scale,
    )


def heights_at(relief: ReliefSource, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
    """Relief heights at world points (bilinear between texels): ``(N,)`` -> ``(N,)`` float64 metres."""
    x = np.asarray(x_m, dtype=np.float64).ravel()
    y = np.asarray(y_m, dtype=np.float64).ravel()
    if len(x) == 0:
        return np.zeros(0)
    t = relief.texel_m
    r, c = x / t, y / t
    r0, c0 = int(np.floor(r.min())), int(np.floor(c.min()))
    block = relief.region(r0, c0, int(np.floor(r.max())) - r0 + 2, int(np.floor(c.max())) - c0 + 2).astype(np.float64)
    ri, ci = np.floor(r).astype(np.int64), np.floor(c).astype(np.int64)
    fr, fc = r - ri, c - ci
    ri, ci = ri - r0, ci - c0
    return (
        (1 - fr) * (1 - fc) * block[ri, ci]
        + (1 - fr) * fc * block[ri, ci + 1]
        + fr * (1 - fc) * block[ri + 1, ci]
        + fr * fc * block[ri + 1, ci + 1]
    )


def sonar_first_return_m(
    relief: ReliefSource,
    x_m: np.ndarray,
    y_m: np.ndarray,
    altitude_m: np.ndarray,
    beam_half_angle_rad: float,
    batch: int = 1000,
) -> np.ndarray:
    """Range an echo-sounder altimeter reports over the relief: the nearest seabed point in its beam.

    A vertical cone of half-angle ``beam_half_angle_rad`` below each (N,) position at
    ``altitude_m`` above the mean plane is sampled at its axis and two rings (6 and 12
    points, at half and full beam radius); the shortest slant range to the relief wins (the
    first echo). On a flat seabed that is ``altitude_m``. Returns (N,) metres.
    """
    if not (0.0 < beam_half_angle_rad < 0.8):
        raise SimulationError(f"sonar beam half-angle must be in (0, 0.8) rad, got {beam_half_angle_rad}")
    ang = np.concatenate([[0.0], np.full(6, 0.5), np.ones(12)]) * beam_half_angle_rad  # off-axis angles
    az = np.concatenate([[0.0], np.arange(6) * np.pi / 3.0, np.arange(12) * np.pi / 6.0])
    x, y, z = (np.asarray(a, dtype=np.float64).ravel() for a in (x_m, y_m, altitude_m))
    out = np.empty(len(x))
    for lo in range(0, len(x), batch):
        sl = slice(lo, lo + batch)
        # Where each beam direction meets the mean plane; then the range to the relief along it,
        # to first order (the relief is small against the altitude): r = (Z - h) / cos(angle).
        rho = z[sl, None] * np.tan(ang)[None, :]
        px, py = x[sl, None] + rho * np.cos(az), y[sl, None] + rho * np.sin(az)
        h = heights_at(relief, px, py).reshape(px.shape)
        out[sl] = np.min((z[sl, None] - h) / np.cos(ang)[None, :], axis=1)
    return out
