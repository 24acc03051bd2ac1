"""The simulated world: a seabed texture source, prefiltered canvases of it, and the water's seed.

The renderer samples the seabed through a *canvas*: one contiguous block of texels, blurred
once with a Gaussian matched to the camera's pixel footprint (a mip level), then sampled
bilinearly per frame. That is the anti-aliasing: the texture is finer than a pixel, and
the prefilter removes what a pixel cannot resolve. Canvases are rebuilt only when a frame's
footprint leaves the current one, growing to cover the surveyed area, so a grid survey
settles on one canvas after a few frames. A texel's blurred value never depends on the
canvas extent (every sampled texel is further than the kernel radius from the canvas
edge), so a pose renders the same whatever was rendered before.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from rovslam.errors import SimulationError
from rovslam.sim.relief import ProceduralRelief, ReliefSource
from rovslam.sim.texture import ImageSeabed, ProceduralSeabed, TextureParams, TextureSource

BLUR_STEP_TEXELS = 0.25  # prefilter sigmas are quantised to this step (one canvas per level)
ALIGN_TEXELS = 64  # canvas and window bounds are multiples of this (see World.canvas)


@dataclass(frozen=True)
class Canvas:
    """A prefiltered block of texels: ``texels[i, j]`` is global texel ``(row0 + step i, col0 + step j)``.

    (Bounds are multiples of ``ALIGN_TEXELS``; ``step`` > 1: decimated after the prefilter.)
    """

    texels: np.ndarray  # (R, C, 3) uint8 RGB, read-only
    row0: int
    col0: int
    blur_sigma_texels: float
    step: int = 1

    def contains(self, row_lo: int, row_hi: int, col_lo: int, col_hi: int) -> bool:
        """Whether global texel rows [row_lo, row_hi) and columns [col_lo, col_hi) are inside."""
        r, c = self.texels.shape[0] * self.step, self.texels.shape[1] * self.step
        return row_lo >= self.row0 and row_hi <= self.row0 + r and col_lo >= self.col0 and col_hi <= self.col0 + c


@dataclass(frozen=True)
class ReliefCanvas:
    """A block of relief texels: ``relief[i, j]`` is global relief texel ``(row0 + i, col0 + j)``.

    Channels: height (m), dh/dx (north), dh/dy (east) (central differences), so one
    bilinear lookup gives a height and its slope.
    """

    relief: np.ndarray  # (R, C, 3) float32, read-only
    row0: int
    col0: int

    @property
    def heights(self) -> np.ndarray:
        """(R, C) float32 heights, metres."""
        return self.relief[..., 0]


class World:
    """A seabed (any :class:`~rovslam.sim.texture.TextureSource`), its optional relief, the seed of the water.

    ``max_canvas_texels`` bounds a canvas side (memory: side^2 x 3 bytes); ``grow_m`` is the
    margin added around a frame's footprint when a canvas has to be rebuilt; ``area_m``
    (north min, north max, east min, east max), when the frames to come are known to stay
    in it, is what a canvas covers when it fits under the cap (one build per canvas). ``relief``
    (any :class:`~rovslam.sim.relief.ReliefSource`, None: a flat seabed) gives the heights
    the renderer casts its rays onto.
    """

    def __init__(
        self,
        seabed: TextureSource,
        seed: int = 0,
        max_canvas_texels: int = 4096,
        grow_m: float = 0.25,
        relief: ReliefSource | None = None,
        area_m: tuple[float, float, float, float] | None = None,
    ) -> None:
        if int(seed) < 0:
            raise SimulationError(f"seed must be >= 0, got {seed}")
        if max_canvas_texels < 256:
            raise SimulationError(f"max_canvas_texels must be >= 256, got {max_canvas_texels}")
        self.seabed = seabed
        self.seed = int(seed)
        self.max_canvas_texels = int(max_canvas_texels)
        self._grow_texels = max(1, int(round(grow_m / seabed.texel_m / ALIGN_TEXELS))) * ALIGN_TEXELS
        self._canvases: dict[float, Canvas] = {}
        self._lock = threading.Lock()
        self.canvas_builds = 0  # how many canvases were built (for benchmarks and tests)
        self.relief = relief
        self._grow_m = float(grow_m)
        self.area_m = area_m
        self._relief_canvas: ReliefCanvas | None = None

    @classmethod
    def procedural(cls, seed: int = 0, params: TextureParams | None = None, relief=None, **kwargs) -> World:
        """A world over the procedural seabed of ``seed`` (seabeds are shared, see :func:`shared_seabed`).

        ``relief``: None (flat), a :class:`~rovslam.sim.relief.ReliefParams` (the procedural
        relief of this seabed) or any relief source.
        """
        from rovslam.sim.relief import ReliefParams

        texture = params if params is not None else TextureParams()
        seabed = shared_seabed(int(seed), texture)
        if isinstance(relief, ReliefParams):
            relief = shared_relief(int(seed), texture, relief)
        return cls(seabed, seed=seed, relief=relief, **kwargs)

    @classmethod
    def from_image(cls, path: Path | str, mm_per_px: float, seed: int = 0, **kwargs) -> World:
        """A world over a seabed photograph / orthomosaic file at ``mm_per_px``."""
        return cls(ImageSeabed.from_file(path, mm_per_px), seed=seed, **kwargs)

    @classmethod
    def from_array(cls, rgb: np.ndarray, mm_per_px: float, seed: int = 0, **kwargs) -> World:
        """A world over an in-memory ``(H, W, 3) uint8`` RGB image at ``mm_per_px``."""
        return cls(ImageSeabed(rgb, mm_per_px), seed=seed, **kwargs)

    @property
    def texel_m(self) -> float:
        return self.seabed.texel_m

    def canvas(
        self, row_lo: int, row_hi: int, col_lo: int, col_hi: int, blur_sigma_texels: float, step: int = 1
    ) -> Canvas:
        """A window of the canvas prefiltered with ``blur_sigma_texels`` (quantised) covering a texel box.

        The box (rows [row_lo, row_hi), columns [col_lo, col_hi)) is what a frame samples; the
        returned window is that box grown to multiples of ``ALIGN_TEXELS``, a view into the
        cached canvas. Its bounds depend on the box only, never on which canvas happens to be
        cached, so the renderer's arithmetic (and so every output bit) does not depend on
        what was rendered before. ``step`` (1, 2 or 4) keeps every step-th prefiltered texel:
        a smaller canvas, for a prefilter wide enough to allow it.
        """
        if step not in (1, 2, 4):
            raise SimulationError(f"canvas step must be 1, 2 or 4, got {step}")
        level = round(max(0.0, blur_sigma_texels) / BLUR_STEP_TEXELS) * BLUR_STEP_TEXELS
        margin = int(np.ceil(3.0 * level)) + 2
        win = _align(row_lo, row_hi, col_lo, col_hi)
        need = _align(row_lo - margin, row_hi + margin, col_lo - margin, col_hi + margin)
        self._check_size(need)
        key = level if step == 1 else (level, step)
        with self._lock:
            current = self._canvases.get(key)  # type: ignore[arg-type]
            if current is None or not current.contains(*need):
                current = self._build(need, level, current, step)
                self._canvases[key] = current  # type: ignore[index]
        view = current.texels[
            (win[0] - current.row0) // step : (win[1] - current.row0) // step,
            (win[2] - current.col0) // step : (win[3] - current.col0) // step,
        ]
        return Canvas(view, win[0], win[2], level, step)

    def _check_size(self, need: tuple[int, int, int, int]) -> None:
        if need[1] - need[0] > self.max_canvas_texels or need[3] - need[2] > self.max_canvas_texels:
            raise SimulationError(
                f"the camera footprint spans {need[1] - need[0]}x{need[3] - need[2]} texels, more than "
                f"max_canvas_texels={self.max_canvas_texels}; lower the altitude or use a coarser texture"
            )

    def _bounds(
        self, need: tuple[int, int, int, int], grow: int, current: tuple[int, int, int, int] | None, texel_m: float
    ):
        """Bounds (r_lo, r_hi, c_lo, c_hi) of a new canvas holding ``need``, grown by ``grow`` texels.

        With ``area_m`` set, the canvas covers that area (and ``need``) when it fits under the
        cap. Otherwise ``current`` (the current canvas's bounds) is merged in if the union
        stays under the cap. (Bounds never change a texel's value, only how often canvases
        are built.)
        """
        r_lo, r_hi, c_lo, c_hi = need[0] - grow, need[1] + grow, need[2] - grow, need[3] + grow
        if self.area_m is not None:
            x0, x1, y0, y1 = self.area_m
            a = _align(
                min(int(np.floor(x0 / texel_m)), need[0]),
                max(int(np.ceil(x1 / texel_m)), need[1]),
                min(int(np.floor(y0 / texel_m)), need[2]),
                max(int(np.ceil(y1 / texel_m)), need[3]),
            )
            if max(a[1] - a[0], a[3] - a[2]) <= self.max_canvas_texels:
                return a
        if current is not None:  # grow the current canvas if the union stays small enough
            u = (min(r_lo, current[0]), max(r_hi, current[1]), min(c_lo, current[2]), max(c_hi, current[3]))
            if max(u[1] - u[0], u[3] - u[2]) <= self.max_canvas_texels:
                r_lo, r_hi, c_lo, c_hi = u
        # Never exceed the cap (the needed box itself fits, checked by the caller).
        r_lo, r_hi = _fit(r_lo, r_hi, need[0], need[1], self.max_canvas_texels)
        c_lo, c_hi = _fit(c_lo, c_hi, need[2], need[3], self.max_canvas_texels)
        return r_lo, r_hi, c_lo, c_hi

    def _build(self, need: tuple[int, int, int, int], level: float, current: Canvas | None, step: int = 1) -> Canvas:
        import cv2

        cur = None
        if current is not None:
            rows, cols = current.texels.shape[0] * step, current.texels.shape[1] * step
            cur = (current.row0, current.row0 + rows, current.col0, current.col0 + cols)
        r_lo, r_hi, c_lo, c_hi = self._bounds(need, self._grow_texels, cur, self.texel_m)
        texels = self.seabed.region(r_lo, c_lo, r_hi - r_lo, c_hi - c_lo)
        if level > 0:
            texels = cv2.GaussianBlur(texels, (0, 0), level, borderType=cv2.BORDER_REFLECT)
        texels = np.ascontiguousarray(texels[::step, ::step])
        texels.setflags(write=False)
        self.canvas_builds += 1
        return Canvas(texels, r_lo, c_lo, level, step)

    # ------------------------------------------------------------------ relief
    def relief_canvas(self, row_lo: int, row_hi: int, col_lo: int, col_hi: int) -> ReliefCanvas:
        """A window of relief heights and slopes covering relief texel rows [row_lo, row_hi), columns [col_lo, col_hi).

        As :meth:`canvas`: bounds are the box grown to multiples of ``ALIGN_TEXELS``, values
        depend on position only (slopes come from a one-texel apron), so rendering does not
        depend on what was rendered before. Raises SimulationError on a flat world.
        """
        if self.relief is None:
            raise SimulationError("this world is flat (no relief); give World(..., relief=...)")
        win = _align(row_lo - 1, row_hi + 1, col_lo - 1, col_hi + 1)
        self._check_size(win)
        with self._lock:
            cur = self._relief_canvas
            rows, cols = (0, 0) if cur is None else cur.relief.shape[:2]
            if cur is None or not (
                win[0] >= cur.row0 and win[1] <= cur.row0 + rows and win[2] >= cur.col0 and win[3] <= cur.col0 + cols
            ):
                cur_b = None if cur is None else (cur.row0, cur.row0 + rows, cur.col0, cur.col0 + cols)
                grow = max(1, int(round(self._grow_m / self.relief.texel_m / ALIGN_TEXELS))) * ALIGN_TEXELS
                cur = self._build_relief(self._bounds(win, grow, cur_b, self.relief.texel_m))
                self._relief_canvas = cur
        r, c = win[0] - cur.row0, win[2] - cur.col0
        return ReliefCanvas(cur.relief[r : r + win[1] - win[0], c : c + win[3] - win[2]], win[0], win[2])

    def _build_relief(self, bounds: tuple[int, int, int, int]) -> ReliefCanvas:
        r_lo, r_hi, c_lo, c_hi = bounds
        apron = self.relief.region(r_lo - 1, c_lo - 1, r_hi - r_lo + 2, c_hi - c_lo + 2).astype(np.float32)  # type: ignore[union-attr]
        inv2t = np.float32(0.5 / self.relief.texel_m)  # type: ignore[union-attr]
        relief = np.empty((r_hi - r_lo, c_hi - c_lo, 3), dtype=np.float32)
        relief[..., 0] = apron[1:-1, 1:-1]
        relief[..., 1] = (apron[2:, 1:-1] - apron[:-2, 1:-1]) * inv2t
        relief[..., 2] = (apron[1:-1, 2:] - apron[1:-1, :-2]) * inv2t
        relief.setflags(write=False)
        self.canvas_builds += 1
        return ReliefCanvas(relief, r_lo, c_lo)


@lru_cache(maxsize=2)
def shared_seabed(seed: int, params: TextureParams) -> ProceduralSeabed:
    """One :class:`ProceduralSeabed` per (seed, params) in a process, so its generated chunks are reused.

    Sharing is safe: a seabed is deterministic and thread-safe.
    """
    return ProceduralSeabed(params, seed)


@lru_cache(maxsize=2)
def shared_relief(seed: int, texture: TextureParams, params) -> ProceduralRelief:
    """One :class:`~rovslam.sim.relief.ProceduralRelief` per (seed, texture, relief params) in a process."""
    return ProceduralRelief(params, shared_seabed(seed, texture))


def _align(r_lo: int, r_hi: int, c_lo: int, c_hi: int) -> tuple[int, int, int, int]:
    """Grow a texel box outwards to multiples of ALIGN_TEXELS."""
    a = ALIGN_TEXELS
    return (r_lo // a * a, -(-r_hi // a) * a, c_lo // a * a, -(-c_hi // a) * a)


def _fit(lo: int, hi: int, need_lo: int, need_hi: int, cap: int) -> tuple[int, int]:
    """Shrink [lo, hi) to at most ``cap`` while keeping [need_lo, need_hi) inside, centred, aligned."""
    if hi - lo <= cap:
        return lo, hi
    spare = cap - (need_hi - need_lo)
    lo = (need_lo - spare // 2) // ALIGN_TEXELS * ALIGN_TEXELS
    return lo, max(lo + cap // ALIGN_TEXELS * ALIGN_TEXELS, need_hi)
