"""Seabed albedo (its colour in air) as an unbounded texel grid.

Texel ``(i, j)`` of every texture source lies at world ``x = i * texel_m`` (north),
``y = j * texel_m`` (east): rows run north, columns east. A source answers
``region(row0, col0, n_rows, n_cols) -> (n_rows, n_cols, 3) uint8 RGB``.

* :class:`ProceduralSeabed` - a procedural sandy seabed, generated in square chunks keyed by
  integer chunk coordinates and cached (LRU). Every feature is a function of world position
  (lattice noise keyed by lattice indices, ripples as a function of position, objects placed
  per world cell by a per-cell generator and drawn into every chunk they overlap), so chunks
  join without seams, nothing tiles, and the same seed gives the same seabed.
* :class:`ImageSeabed` - a real orthomosaic or seabed photograph at a known scale, mirrored
  at its borders when the path leaves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.special import ndtri

from rovslam.errors import SimulationError
from rovslam.sim._chunks import ChunkedGrid
from rovslam.sim._noise import lattice_noise_grid, lattice_noise_points, smoothstep

RGB = tuple[float, float, float]


class TextureSource(Protocol):
    """Anything that gives seabed albedo texels on the world-anchored texel grid."""

    @property
    def texel_m(self) -> float: ...

    def region(self, row0: int, col0: int, n_rows: int, n_cols: int) -> np.ndarray:
        """``(n_rows, n_cols, 3) uint8`` RGB texels ``row0 .. row0 + n_rows - 1`` etc."""
        ...


@dataclass(frozen=True)
class TextureParams:
    """Procedural seabed: sand with ripples, gravel, stones, shells, burrows and weed patches.

    Colours are RGB albedo in air, 0..1. Densities are mean counts per square metre; sizes are
    median radii (log-normal spread). Strengths are relative brightness modulations.
    """

    texel_mm: float = 0.5  # finer than the ~1.2 mm pixel footprint at 1.31 m (anti-aliasing)
    chunk_texels: int = 512  # generation unit, 0.256 m at 0.5 mm
    cache_chunks: int = 64  # LRU size (a 1.6 m x 1.6 m survey needs about 40)
    sand_rgb: RGB = (0.70, 0.62, 0.48)
    brightness_variation: float = 0.16  # darker / brighter areas over tens of centimetres
    brightness_scale_m: float = 0.40
    mottling: float = 0.13  # mid-scale (5-25 mm) patchiness of the sand
    grain: float = 0.07  # fine (1-2 mm) grain noise
    speck_contrast: float = 0.55  # dark mineral grains and bright shell grit, ~1-2 mm
    ripple_wavelength_m: float = 0.075
    ripple_strength: float = 0.16
    ripple_azimuth_rad: float | None = None  # crest normal; None: drawn from the seed
    ripple_irregularity: float = 1.6  # phase warp (radians per unit noise) bending the crests
    pebble_density_per_m2: float = 700.0
    pebble_radius_mm: float = 3.5
    gravel_patchiness: float = 1.0  # 0: pebbles spread evenly; 1: gravel patches and bare sand
    stone_density_per_m2: float = 10.0
    stone_radius_mm: float = 22.0
    shell_density_per_m2: float = 160.0
    shell_radius_mm: float = 5.0
    burrow_density_per_m2: float = 12.0
    burrow_radius_mm: float = 5.0
    weed_cover: float = 0.14  # fraction of the seabed under algae / weed
    weed_scale_m: float = 0.16
    weed_rgb: RGB = (0.25, 0.27, 0.15)
    light_azimuth_rad: float = 2.4  # sun / ambient light direction for the relief shading
    light_elevation_rad: float = 0.95
    # Features that fool correlation; all off by default, so the original presets
    # are unchanged. Boulders are large stones (the relief gives them height).
    boulder_density_per_m2: float = 0.0
    boulder_radius_mm: float = 80.0
    urchin_density_per_m2: float = 0.0  # dark spiny look-alike blobs
    urchin_radius_mm: float = 14.0
    fine_ripple_strength: float = 0.0  # a regular second ripple train at the scale of a 16 px token
    fine_ripple_wavelength_m: float = 0.02
    fine_ripple_azimuth_rad: float = 0.7
    coral_cover: float = 0.0  # fraction under coral: a warped hexagonal lattice of corallites + branches
    coral_spacing_m: float = 0.014  # corallite spacing (about 11 px at 1.31 m: a 16 px token holds two)
    coral_scale_m: float = 0.25  # size of the coral patches
    coral_rgb: RGB = (0.62, 0.50, 0.40)
    mud_cover: float = 0.0  # fraction under smooth, low-contrast mud
    mud_contrast: float = 0.18  # how much of the texture beneath shows through the mud
    mud_scale_m: float = 0.35
    mud_rgb: RGB = (0.50, 0.46, 0.38)

    def __post_init__(self) -> None:
        if not (0.05 <= self.texel_mm <= 20.0):
            raise SimulationError(f"TextureParams.texel_mm must be in [0.05, 20] mm, got {self.texel_mm}")
        if self.chunk_texels < 64:
            raise SimulationError(f"TextureParams.chunk_texels must be >= 64, got {self.chunk_texels}")
        if self.cache_chunks < 4:
            raise SimulationError(f"TextureParams.cache_chunks must be >= 4, got {self.cache_chunks}")
        for name in ("weed_cover", "coral_cover", "mud_cover"):
            if not (0.0 <= getattr(self, name) < 0.9):
                raise SimulationError(f"TextureParams.{name} must be in [0, 0.9), got {getattr(self, name)}")
        for name in (
            "pebble_density_per_m2",
            "stone_density_per_m2",
            "shell_density_per_m2",
            "burrow_density_per_m2",
            "boulder_density_per_m2",
            "urchin_density_per_m2",
            "fine_ripple_strength",
        ):
            if getattr(self, name) < 0:
                raise SimulationError(f"TextureParams.{name} must be >= 0, got {getattr(self, name)}")
        for name in (
            "boulder_radius_mm",
            "urchin_radius_mm",
            "fine_ripple_wavelength_m",
            "coral_spacing_m",
            "coral_scale_m",
            "mud_scale_m",
        ):
            if not getattr(self, name) > 0:
                raise SimulationError(f"TextureParams.{name} must be > 0, got {getattr(self, name)}")
        if not (0.0 <= self.mud_contrast <= 1.0):
            raise SimulationError(f"TextureParams.mud_contrast must be in [0, 1], got {self.mud_contrast}")


# Lattice-noise layer identifiers (one independent field each).
_L_BRIGHT1, _L_BRIGHT2, _L_MOTTLE1, _L_MOTTLE2, _L_GRAIN, _L_SPECK = 1, 2, 3, 4, 5, 6
_L_RIPPLE_PHASE, _L_RIPPLE_AMP, _L_WEED1, _L_WEED2, _L_WEED_FIBRE, _L_TINT, _L_GRAVEL, _L_WEED_FIL = (
    7,
    8,
    9,
    10,
    11,
    12,
    13,
    14,
)
_L_CORAL, _L_CORAL_WARP_X, _L_CORAL_WARP_Y, _L_CORAL_BRANCH, _L_MUD, _L_FINE_RIPPLE = 15, 16, 17, 18, 19, 20
# Object kinds (per-cell generators).
_K_PEBBLE, _K_STONE, _K_SHELL, _K_BURROW, _K_BOULDER, _K_URCHIN = 101, 102, 103, 104, 105, 106
# How far (in sizes) an object's drawing reaches: outline harmonics and shadow, fan, rim.
_EXTENT = {_K_PEBBLE: 1.5, _K_STONE: 1.5, _K_SHELL: 1.1, _K_BURROW: 2.2, _K_BOULDER: 1.5, _K_URCHIN: 1.7}

_PEBBLE_PALETTE = np.array(
    [
        [0.62, 0.60, 0.56],  # grey limestone
        [0.82, 0.79, 0.72],  # pale
        [0.31, 0.31, 0.30],  # dark
        [0.53, 0.43, 0.32],  # brown
        [0.60, 0.42, 0.34],  # reddish
        [0.40, 0.44, 0.35],  # greenish, encrusted
    ],
    dtype=np.float32,
)
_PEBBLE_WEIGHTS = np.array([0.30, 0.18, 0.17, 0.15, 0.10, 0.10])
_SHELL_PALETTE = np.array(
    [[0.93, 0.90, 0.83], [0.88, 0.76, 0.66], [0.78, 0.74, 0.67], [0.62, 0.55, 0.50]], dtype=np.float32
)
_SHELL_WEIGHTS = np.array([0.45, 0.2, 0.25, 0.10])


@dataclass(frozen=True)
class _Objects:
    """Flat arrays describing objects of one kind (world metres, radians, 0..1 colours)."""

    x_m: np.ndarray
    y_m: np.ndarray
    a_m: np.ndarray  # semi-major axis (shells: radius)
    b_m: np.ndarray  # semi-minor axis (shells: half-angle in radians)
    angle_rad: np.ndarray
    rgb: np.ndarray  # (N, 3)
    extra: np.ndarray  # kind-specific: shells: 1 = fragment arc; stones: encrustation key
    harmonics: np.ndarray  # (N, 4, 2): outline harmonics k = 2..5, (amplitude, phase)


class ProceduralSeabed(ChunkedGrid):
    """Procedural, unbounded, deterministic seabed (see the module docstring).

    ``region`` gives ``(n_rows, n_cols, 3) uint8`` albedo texels. Thread-safe: chunks are
    generated under a lock and cached read-only.
    """

    def __init__(self, params: TextureParams | None = None, seed: int = 0) -> None:
        if int(seed) < 0:
            raise SimulationError(f"seed must be >= 0, got {seed}")
        self.params = params if params is not None else TextureParams()
        super().__init__(self.params.chunk_texels, self.params.cache_chunks, (3,), np.uint8)
        self.seed = int(seed)
        self._texel_m = self.params.texel_mm * 1e-3
        p = self.params
        if p.ripple_azimuth_rad is None:
            self._ripple_az = float(np.random.default_rng([self.seed, 7001]).uniform(0.0, np.pi))
        else:
            self._ripple_az = float(p.ripple_azimuth_rad)
        # Weed threshold for the requested cover on the sum of two unit-variance fields.
        self._weed_threshold = float(np.sqrt(1.25) * ndtri(1.0 - p.weed_cover)) if p.weed_cover > 0 else np.inf

    @property
    def texel_m(self) -> float:
        return self._texel_m

    # ------------------------------------------------------------------ generation
    def _generate_chunk(self, ci: int, cj: int) -> np.ndarray:
        p, s, t, n = self.params, self.seed, self._texel_m, self.params.chunk_texels
        x0, y0 = ci * n * t, cj * n * t

        def field(layer: int, cell: float | tuple[float, float]) -> np.ndarray:
            return lattice_noise_grid(s, layer, x0, y0, n, n, t, cell)

        xs = (x0 + t * np.arange(n, dtype=np.float64))[:, None]
        ys = (y0 + t * np.arange(n, dtype=np.float64))[None, :]

        # Sand: mid-scale mottling, fine grain, ripples (sinusoids whose crests are bent by a
        # slowly varying phase warp, with an asymmetric profile and patchy amplitude).
        fine = field(_L_MOTTLE2, 0.006)
        lum = 1.0 + p.mottling * (0.75 * field(_L_MOTTLE1, 0.022) + 0.55 * fine)
        grain = field(_L_GRAIN, 0.0014)
        lum += p.grain * grain
        if p.ripple_strength > 0:
            amp, profile = self.ripples(field, xs, ys)
            lum += (p.ripple_strength * amp * profile).astype(np.float32)
        if p.fine_ripple_strength > 0:
            lum += self._fine_ripples(field, xs, ys)
        speck = field(_L_SPECK, 0.0011)
        lum *= 1.0 - p.speck_contrast * smoothstep(1.9, 2.6, speck)
        lum *= 1.0 + 0.6 * p.speck_contrast * smoothstep(-2.0, -2.7, speck)
        tint = field(_L_TINT, 0.20)
        sand = np.asarray(p.sand_rgb, dtype=np.float32)
        img = lum[..., None] * sand + (0.035 * tint)[..., None] * np.array([1.0, 0.6, -0.4], dtype=np.float32)

        # Algae / weed patches: a low-frequency patch field; inside, clumps of turf (isotropic
        # 3-6 mm tufts) whose cover falls off towards the patch edges, filaments within tufts.
        if np.isfinite(self._weed_threshold):
            w = field(_L_WEED1, p.weed_scale_m) + 0.5 * field(_L_WEED2, p.weed_scale_m / 3.2)
            patch = smoothstep(self._weed_threshold - 0.45, self._weed_threshold + 0.45, w)
            if patch.any():
                tuft = field(_L_WEED_FIBRE, 0.0032) + 0.5 * fine
                # (zero where patch is zero, so chunks that skip this block agree with the others)
                cover = smoothstep(-0.45, 0.35, tuft + 6.0 * (patch - 0.6)) * np.minimum(10.0 * patch, 1.0)
                fil = field(_L_WEED_FIL, 0.0012)
                weed = np.asarray(p.weed_rgb, dtype=np.float32) + (0.5 + 0.5 * tint)[..., None] * np.array(
                    [0.07, 0.0, 0.0], dtype=np.float32
                )
                weed = weed * (0.72 + 0.16 * fil + 0.18 * np.clip(tuft, -1.0, 1.5))[..., None]
                img *= (1.0 - 0.3 * smoothstep(0.05, 0.6, patch))[..., None]  # shade under the turf
                img += (0.95 * cover)[..., None] * (weed - img)

        if p.coral_cover > 0:
            self._draw_coral(img, field, xs, ys, fine)

        # Objects, drawn in a fixed global order so overlaps resolve the same in every chunk.
        light = self._light_vector()
        self._draw_burrows(img, x0, y0, n, fine)
        surface = 0.2 * fine + 0.14 * grain  # stone surface texture
        self._draw_ellipsoids(img, self._objects(_K_PEBBLE, x0, y0, n), x0, y0, n, surface, light)
        self._draw_ellipsoids(img, self._objects(_K_STONE, x0, y0, n), x0, y0, n, surface, light)
        if p.boulder_density_per_m2 > 0:
            self._draw_ellipsoids(img, self._objects(_K_BOULDER, x0, y0, n), x0, y0, n, surface, light)
        self._draw_shells(img, self._objects(_K_SHELL, x0, y0, n), x0, y0, n, light)
        if p.urchin_density_per_m2 > 0:
            self._draw_urchins(img, self._objects(_K_URCHIN, x0, y0, n), x0, y0, n)
        if p.mud_cover > 0:
            mud = smoothstep(-0.35, 0.35, field(_L_MUD, p.mud_scale_m) - float(ndtri(1.0 - p.mud_cover)))
            veil = np.asarray(p.mud_rgb, dtype=np.float32) * (1.0 + 0.04 * fine)[..., None]
            veil += p.mud_contrast * (img - np.asarray(p.sand_rgb, dtype=np.float32))
            img += mud[..., None] * (veil - img)

        # Darker and brighter areas over tens of centimetres.
        bright = 1.0 + p.brightness_variation * (
            0.8 * field(_L_BRIGHT1, p.brightness_scale_m) + 0.45 * field(_L_BRIGHT2, p.brightness_scale_m / 3.5)
        )
        img *= bright[..., None]
        return np.clip(img * 255.0 + 0.5, 0.0, 255.0).astype(np.uint8)

    def ripples(self, field, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(amplitude (R, C) float32 in [0, 1], profile (R, C) float64 in about [-1.1, 1.1]) of the sand ripples.

        ``field(layer, cell_m)`` evaluates a lattice-noise layer on the grid whose north and
        east coordinates are ``xs`` (R, 1) and ``ys`` (1, C): the same crests on any grid,
        so the relief's ripples lie under the texture's.
        """
        p = self.params
        ca, sa = np.cos(self._ripple_az), np.sin(self._ripple_az)
        phase = (2.0 * np.pi / p.ripple_wavelength_m) * (xs * ca + ys * sa)
        phase = phase + p.ripple_irregularity * field(_L_RIPPLE_PHASE, 0.16)
        profile = (np.sin(phase) + 0.35 * np.sin(2.0 * phase + 0.8)) * (1.0 / 1.2)
        amp = smoothstep(-0.7, 0.9, field(_L_RIPPLE_AMP, 0.32))
        return amp, profile

    def _fine_ripples(self, field, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """A regular ripple train at the scale of a speed token (little irregularity): (R, C) float32."""
        p = self.params
        ca, sa = np.cos(p.fine_ripple_azimuth_rad), np.sin(p.fine_ripple_azimuth_rad)
        phase = (2.0 * np.pi / p.fine_ripple_wavelength_m) * (xs * ca + ys * sa)
        phase = phase + 0.5 * field(_L_FINE_RIPPLE, 0.3)
        return (p.fine_ripple_strength * (np.sin(phase) + 0.25 * np.sin(2.0 * phase))).astype(np.float32)

    def _draw_coral(self, img: np.ndarray, field, xs: np.ndarray, ys: np.ndarray, fine: np.ndarray) -> None:
        """Coral patches: corallites on a slowly warped hexagonal lattice, bright branch ridges between them.

        The lattice repeats every ``coral_spacing_m``: a 16 px token sees several identical
        cells, so a correlation peak one cell away is almost as high as the true one.
        """
        p = self.params
        patch = smoothstep(-0.3, 0.3, field(_L_CORAL, p.coral_scale_m) - float(ndtri(1.0 - p.coral_cover)))
        if not patch.any():
            return
        s = p.coral_spacing_m
        wx = xs + 0.8 * s * field(_L_CORAL_WARP_X, 0.3)  # the lattice bends slowly, as a colony grows
        wy = ys + 0.8 * s * field(_L_CORAL_WARP_Y, 0.3)
        k = 4.0 * np.pi / (np.sqrt(3.0) * s)
        g = sum(np.cos(k * (wx * np.cos(a) + wy * np.sin(a))) for a in (0.0, np.pi / 3.0, 2.0 * np.pi / 3.0))
        wall = smoothstep(-0.2, 1.0, g) * smoothstep(2.7, 1.9, g)  # a ring around each cell's centre
        pit = smoothstep(2.0, 2.8, g)  # the dark mouth of the corallite
        branch = smoothstep(0.8, 0.97, 1.0 - np.abs(field(_L_CORAL_BRANCH, 0.01)))
        lum = (0.55 + 0.6 * wall - 0.4 * pit + 0.12 * branch + 0.05 * fine).astype(np.float32)
        coral = lum[..., None] * np.asarray(p.coral_rgb, dtype=np.float32)
        img += patch.astype(np.float32)[..., None] * (coral - img)

    def _light_vector(self) -> tuple[float, float, float]:
        p = self.params
        ch = np.cos(p.light_elevation_rad)
        return (ch * np.cos(p.light_azimuth_rad), ch * np.sin(p.light_azimuth_rad), np.sin(p.light_elevation_rad))

    def _kind_setup(self, kind: int) -> tuple[float, float, float, float]:
        """(cell size m, density per m^2, median size m, max reach m) of an object kind.

        An object is drawn within ``_EXTENT[kind]`` times its size of its centre, and its size
        is capped so that this stays within the reach: so every chunk an object touches
        enumerates its cell, and chunks join exactly.
        """
        p = self.params
        if kind == _K_PEBBLE:
            return 0.05, p.pebble_density_per_m2, p.pebble_radius_mm * 1e-3, 6.0 * p.pebble_radius_mm * 1e-3
        if kind == _K_STONE:
            return 0.20, p.stone_density_per_m2, p.stone_radius_mm * 1e-3, 4.5 * p.stone_radius_mm * 1e-3
        if kind == _K_SHELL:
            return 0.08, p.shell_density_per_m2, p.shell_radius_mm * 1e-3, 3.0 * p.shell_radius_mm * 1e-3
        if kind == _K_BOULDER:
            return 0.5, p.boulder_density_per_m2, p.boulder_radius_mm * 1e-3, 3.0 * p.boulder_radius_mm * 1e-3
        if kind == _K_URCHIN:
            return 0.12, p.urchin_density_per_m2, p.urchin_radius_mm * 1e-3, 2.2 * p.urchin_radius_mm * 1e-3
        return 0.15, p.burrow_density_per_m2, p.burrow_radius_mm * 1e-3, 6.0 * p.burrow_radius_mm * 1e-3

    def stones_near(self, x0: float, y0: float, extent_m: float) -> tuple[_Objects, ...]:
        """Stones and boulders that can reach the square ``[x0, x0 + extent_m) x [y0, y0 + extent_m)`` (m).

        (For the relief, which raises the stones drawn on the texture.)
        """
        kinds = (_K_STONE, _K_BOULDER) if self.params.boulder_density_per_m2 > 0 else (_K_STONE,)
        return tuple(self._objects(k, x0, y0, 0, extent_m) for k in kinds)

    def _objects(self, kind: int, x0: float, y0: float, n: int, extent_m: float | None = None) -> _Objects:
        """All objects of ``kind`` whose cells can reach the chunk at (x0, y0), in global order.

        The chunk is ``n`` texels square, or ``extent_m`` metres when given.
        """
        cell, density, median, reach = self._kind_setup(kind)
        extent = n * self._texel_m if extent_m is None else extent_m
        i_lo, i_hi = int(np.floor((x0 - reach) / cell)), int(np.floor((x0 + extent + reach) / cell))
        j_lo, j_hi = int(np.floor((y0 - reach) / cell)), int(np.floor((y0 + extent + reach) / cell))
        ii, jj = np.meshgrid(np.arange(i_lo, i_hi + 1), np.arange(j_lo, j_hi + 1), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()  # type: ignore[assignment]
        lam = np.full(len(ii), density * cell * cell)
        if kind == _K_PEBBLE and self.params.gravel_patchiness > 0:
            g = lattice_noise_points(self.seed, _L_GRAVEL, (ii + 0.5) * cell, (jj + 0.5) * cell, 0.22)
            patch = 0.1 + 1.9 * smoothstep(-0.4, 1.0, g)
            lam *= (1.0 - self.params.gravel_patchiness) + self.params.gravel_patchiness * patch
        cols: list[list[Any]] = [[] for _ in range(8)]  # per column: arrays of the cells (x, y, ..., harmonics)
        for ci, cj, lam_k in zip(ii.tolist(), jj.tolist(), lam.tolist()):
            rng = np.random.default_rng([self.seed, kind, ci & 0xFFFFFFFF, cj & 0xFFFFFFFF])  # type: ignore[operator]
            k = int(rng.poisson(lam_k))
            if k == 0:
                continue
            x = (ci + rng.random(k)) * cell
            y = (cj + rng.random(k)) * cell
            spread = 0.12 if kind == _K_URCHIN else 0.5  # urchins: all much the same size (look-alike blobs)
            a = median * np.exp(spread * rng.standard_normal(k))
            a = np.minimum(a, reach / _EXTENT[kind])
            angle = rng.uniform(0.0, np.pi * 2.0, k)
            if kind == _K_SHELL:
                b = rng.uniform(0.9, 1.3, k)  # half-angle of the fan
                pal, wts = _SHELL_PALETTE, _SHELL_WEIGHTS
                extra = (rng.random(k) < 0.35).astype(np.float32)  # broken fragment: an arc
            else:
                b = a * rng.uniform(0.55, 0.95, k)
                pal, wts = _PEBBLE_PALETTE, _PEBBLE_WEIGHTS
                extra = rng.random(k).astype(np.float32)
            rgb = pal[rng.choice(len(pal), size=k, p=wts)] * rng.uniform(0.85, 1.12, k)[:, None]
            harm = np.stack(
                [
                    np.clip(rng.normal(0.0, 1.0, (k, 4)), -2.0, 2.0) * np.array([0.07, 0.05, 0.035, 0.025]),
                    rng.uniform(0.0, 2.0 * np.pi, (k, 4)),
                ],
                axis=-1,
            )
            for lst, val in zip(cols, (x, y, a, b, angle, rgb, extra, harm)):
                lst.append(val)
        if not cols[0]:
            empty = np.zeros(0)
            return _Objects(empty, empty, empty, empty, empty, np.zeros((0, 3)), empty, np.zeros((0, 4, 2)))
        return _Objects(*(np.concatenate(c) for c in cols))

    def _box(self, xc: float, yc: float, reach_m: float, x0: float, y0: float, n: int):
        """Texel window (row slice, col slice, local row offsets, local col offsets) or None."""
        t = self._texel_m
        r_c, c_c = (xc - x0) / t, (yc - y0) / t
        rr = reach_m / t + 1.5
        r_lo, r_hi = max(0, int(np.floor(r_c - rr))), min(n, int(np.ceil(r_c + rr)) + 1)
        c_lo, c_hi = max(0, int(np.floor(c_c - rr))), min(n, int(np.ceil(c_c + rr)) + 1)
        if r_lo >= r_hi or c_lo >= c_hi:
            return None
        du = (np.arange(r_lo, r_hi, dtype=np.float32) - r_c)[:, None] * t
        dv = (np.arange(c_lo, c_hi, dtype=np.float32) - c_c)[None, :] * t
        return slice(r_lo, r_hi), slice(c_lo, c_hi), du, dv

    def _draw_ellipsoids(self, img, obj: _Objects, x0, y0, n, surface, light) -> None:
        """Pebbles and stones: shaded half-ellipsoids with a soft cast shadow and surface texture."""
        t = self._texel_m
        lx, ly, lz = light
        for k in range(len(obj.x_m)):
            a, b, th = float(obj.a_m[k]), float(obj.b_m[k]), float(obj.angle_rad[k])
            box = self._box(obj.x_m[k], obj.y_m[k], _EXTENT[_K_PEBBLE] * a, x0, y0, n)
            if box is None:
                continue
            rs, cs, dx, dy = box
            c, s = np.cos(th), np.sin(th)
            # Shadow: a soft darker ellipse displaced away from the light.
            sx, sy = dx + 0.35 * a * lx, dy + 0.35 * a * ly
            su, sv = (sx * c + sy * s) / (1.12 * a), (-sx * s + sy * c) / (1.12 * b)
            shadow = 0.38 * smoothstep(1.0, 0.55, np.sqrt(su * su + sv * sv))
            patch = img[rs, cs]
            patch *= (1.0 - shadow)[..., None]
            # Body: an irregular outline (radius modulated by harmonics 2..5 of the polar angle),
            # a flattened-dome normal, Lambert + ambient shading, a darker embedded rim.
            u, v = (dx * c + dy * s) / a, (-dx * s + dy * c) / b
            phi = np.arctan2(v, u)
            hk = obj.harmonics[k]
            outline = 1.0 + sum(hk[q, 0] * np.cos((q + 2) * phi + hk[q, 1]) for q in range(4))
            r2 = (u * u + v * v) / (outline * outline)
            alpha = np.clip((1.0 - np.sqrt(r2)) * (np.sqrt(a * b) / t) + 0.5, 0.0, 1.0)
            if not alpha.any():
                continue
            h = np.sqrt(np.maximum(1.0 - r2, 0.0))
            lu, lv = lx * c + ly * s, -lx * s + ly * c
            lam = np.maximum((0.7 * (u * lu + v * lv) + h * lz) / np.sqrt(0.49 * r2 + h * h + 1e-6), 0.0)
            shade = (0.5 + 0.55 * lam) * (0.78 + 0.22 * h) * (1.0 + surface[rs, cs])
            col = obj.rgb[k]
            if a > 0.01 and obj.extra[k] < 0.5:  # stones: encrusting algae on part of the top
                enc = smoothstep(0.06, 0.18, surface[rs, cs]) * 0.7
                col = col[None, None, :] + enc[..., None] * (np.array([0.30, 0.36, 0.20]) - col)
            body = shade[..., None] * col
            patch += alpha[..., None] * (body - patch)

    def _draw_shells(self, img, obj: _Objects, x0, y0, n, light) -> None:
        """Shells: bright ribbed fans (valves) and thin bright arcs (broken fragments)."""
        t = self._texel_m
        lx, ly, _ = light
        for k in range(len(obj.x_m)):
            rad, half, th = float(obj.a_m[k]), float(obj.b_m[k]), float(obj.angle_rad[k])
            box = self._box(obj.x_m[k], obj.y_m[k], _EXTENT[_K_SHELL] * rad, x0, y0, n)
            if box is None:
                continue
            rs, cs, dx, dy = box
            c, s = np.cos(th), np.sin(th)
            u, v = (dx * c + dy * s) / rad, (-dx * s + dy * c) / rad
            rho = np.sqrt(u * u + v * v)
            phi = np.arctan2(v, u)
            edge_px = rad / t
            ang_in = np.clip((half - np.abs(phi)) * rho * edge_px + 0.5, 0.0, 1.0)
            if obj.extra[k] > 0.5:  # fragment: an arc of the rim, ~1 mm wide
                width = max(0.9e-3 / rad, 0.08)
                alpha = np.clip((width - np.abs(rho - 0.8)) * edge_px + 0.5, 0.0, 1.0) * ang_in
                shade = 1.05 + 0.0 * rho
            else:
                outline = 1.0 - 0.22 * (phi / half) ** 2
                alpha = np.clip((outline - rho) * edge_px + 0.5, 0.0, 1.0) * ang_in
                ribs = 0.86 + 0.14 * np.cos(phi * (9.0 * np.pi / half))
                rings = 0.93 + 0.07 * np.cos(rho * 22.0)
                side = 1.0 + 0.18 * ((dx * lx + dy * ly) / rad)
                shade = ribs * rings * side
            if not alpha.any():
                continue
            patch = img[rs, cs]
            body = shade[..., None] * obj.rgb[k]
            patch += (0.95 * alpha)[..., None] * (body - patch)

    def _draw_urchins(self, img, obj: _Objects, x0, y0, n) -> None:
        """Sea urchins: dark round tests with radial spines, all much alike (look-alike blobs)."""
        t = self._texel_m
        for k in range(len(obj.x_m)):
            a = float(obj.a_m[k])
            box = self._box(obj.x_m[k], obj.y_m[k], _EXTENT[_K_URCHIN] * a, x0, y0, n)
            if box is None:
                continue
            rs, cs, dx, dy = box
            r = np.sqrt(dx * dx + dy * dy) / a
            phi = np.arctan2(dy, dx) + float(obj.angle_rad[k])
            spines = 14 + int(obj.extra[k] * 8.0)
            reach = 1.0 + 0.55 * np.abs(np.cos(0.5 * spines * phi)) ** 6  # spines reach further than the test
            body = np.clip((0.62 - r) * (a / t) + 0.5, 0.0, 1.0)
            spine = np.clip((reach - r) * (a / t) * 0.6 + 0.5, 0.0, 1.0) * (r > 0.55)
            alpha = np.maximum(body, 0.85 * spine)
            if not alpha.any():
                continue
            colour = np.array([0.13, 0.09, 0.11], dtype=np.float32) * (0.8 + 0.4 * float(obj.extra[k]))
            patch = img[rs, cs]
            patch += alpha[..., None] * (colour - patch)

    def _draw_burrows(self, img, x0, y0, n, fine) -> None:
        """Burrow openings: a dark hole with a lighter raised rim of worked sand."""
        obj = self._objects(_K_BURROW, x0, y0, n)
        for k in range(len(obj.x_m)):
            a = float(obj.a_m[k])
            box = self._box(obj.x_m[k], obj.y_m[k], _EXTENT[_K_BURROW] * a, x0, y0, n)
            if box is None:
                continue
            rs, cs, dx, dy = box
            r = np.sqrt(dx * dx + dy * dy) / a
            hole = smoothstep(0.75, 0.45, r) * (0.75 + 0.1 * fine[rs, cs])
            rim = 0.22 * smoothstep(0.5, 1.0, r) * smoothstep(2.1, 1.2, r)
            patch = img[rs, cs]
            patch *= (1.0 + rim - hole)[..., None]


class ImageSeabed:
    """A seabed photograph or orthomosaic at ``mm_per_px``, mirrored at its borders.

    The image's top is north (world +x) and its right is east (+y); image pixel
    ``((h - 1) // 2, (w - 1) // 2)`` lies at the world origin.
    """

    def __init__(self, rgb: np.ndarray, mm_per_px: float) -> None:
        arr = np.asarray(rgb)
        if arr.ndim == 2:
            arr = np.repeat(arr[..., None], 3, axis=2)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
            raise SimulationError(
                f"texture image must be (H, W, 3) uint8 RGB or (H, W) uint8 grey, got {arr.shape} {arr.dtype}"
            )
        if min(arr.shape[:2]) < 8:
            raise SimulationError(f"texture image is too small ({arr.shape[1]}x{arr.shape[0]} px); need >= 8x8")
        if not (np.isfinite(mm_per_px) and mm_per_px > 0):
            raise SimulationError(f"texture scale must be a positive number of mm per pixel, got {mm_per_px}")
        self.image = np.ascontiguousarray(arr)
        self._texel_m = float(mm_per_px) * 1e-3
        self._r0 = (arr.shape[0] - 1) // 2
        self._c0 = (arr.shape[1] - 1) // 2

    @classmethod
    def from_file(cls, path: Path | str, mm_per_px: float) -> ImageSeabed:
        """Read an image file (any format OpenCV reads); a non-image raises SimulationError."""
        import cv2

        p = Path(path)
        if not p.is_file():
            raise SimulationError(f"texture file {p} does not exist; give an existing image file")
        bgr = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if bgr is None:
            raise SimulationError(f"texture file {p} is not an image OpenCV can read (use PNG, JPEG or TIFF)")
        return cls(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), mm_per_px)

    @property
    def texel_m(self) -> float:
        return self._texel_m

    @property
    def origin_px(self) -> tuple[int, int]:
        """The image pixel (row, column) at the world origin."""
        return self._r0, self._c0

    def region(self, row0: int, col0: int, n_rows: int, n_cols: int) -> np.ndarray:
        h, w = self.image.shape[:2]
        rows = mirror_indices(self._r0 - (row0 + np.arange(n_rows)), h)  # world +x is image up
        cols = mirror_indices(self._c0 + col0 + np.arange(n_cols), w)
        return self.image[rows[:, None], cols[None, :]]


def mirror_indices(idx: np.ndarray, size: int) -> np.ndarray:
    """Indices mirrored at the borders (edge texel repeated), period 2 * size."""
    m = np.mod(idx, 2 * size)
    return np.where(m >= size, 2 * size - 1 - m, m)
