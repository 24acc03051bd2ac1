"""The water between the camera and the seabed: attenuation, backscatter, forward scatter, marine snow.

Light model (per colour channel c, range r from the camera to the seabed point)::

    I_c = albedo_c * E(pixel) * exp(-a_c * k * r) + B_c * E_h(pixel) * (1 - exp(-b * r))

``a_c`` is the attenuation coefficient (red lost fastest), ``k`` how many times the light
crosses the range (2: lamps beside the camera, down and back), ``E`` the lamps' light cone
with the lens vignetting, ``B_c`` the veiling backscatter at infinite range, growing with
``b``. The renderer evaluates these maps once per centimetre of altitude.

Marine snow: particles on a 3-D lattice of cells in a frame drifting with the water (a
per-cell generator keyed by the world seed and the cell indices, cached), so they stay
fixed in the water, not on the seabed, and parallax moves them against it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rovslam.errors import SimulationError

RGB = tuple[float, float, float]

SNOW_CELL_M = 0.25  # side of the marine-snow lattice cells
SNOW_NEAR_M = 0.12  # particles closer than this to the lens are not drawn
_SNOW_LAYER = 0x5E0  # generator key of the marine-snow cells


@dataclass(frozen=True)
class WaterParams:
    """Water optics. The defaults are a clear coastal Mediterranean site with lamps on the ROV."""

    attenuation_per_m: RGB = (0.35, 0.075, 0.10)  # a_c, 1/m: red is lost fastest
    light_path_factor: float = 2.0  # k: lamps beside the camera, light travels down and back
    backscatter_rgb: RGB = (0.04, 0.15, 0.17)  # B_c, fraction of full scale at infinite range
    backscatter_per_m: float = 0.35  # b: growth of the haze with range
    forward_scatter_px: float = 0.0  # Gaussian blur sigma of forward scattering (turbidity)
    marine_snow_per_m3: float = 0.0  # particle density; 0 disables marine snow
    marine_snow_size_mm: float = 1.0  # median particle diameter (log-normal)
    marine_snow_energy: float = 900.0  # DN x px^2 of a 1 mm particle 0.6 m from the lens
    marine_snow_drift_mps: tuple[float, float, float] = (0.012, 0.006, 0.004)  # north, east, sinking
    lens_aperture_mm: float = 3.0  # sets the defocus blur of near particles (focus on the seabed)

    def __post_init__(self) -> None:
        if len(self.attenuation_per_m) != 3 or min(self.attenuation_per_m) < 0:
            raise SimulationError(f"WaterParams.attenuation_per_m must be 3 values >= 0, got {self.attenuation_per_m}")
        if len(self.backscatter_rgb) != 3 or min(self.backscatter_rgb) < 0:
            raise SimulationError(f"WaterParams.backscatter_rgb must be 3 values >= 0, got {self.backscatter_rgb}")
        for name in (
            "light_path_factor",
            "backscatter_per_m",
            "forward_scatter_px",
            "marine_snow_per_m3",
            "marine_snow_energy",
            "lens_aperture_mm",
        ):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise SimulationError(f"WaterParams.{name} must be a finite number >= 0, got {getattr(self, name)}")
        if self.marine_snow_size_mm <= 0:
            raise SimulationError(f"WaterParams.marine_snow_size_mm must be > 0, got {self.marine_snow_size_mm}")

    @classmethod
    def none(cls) -> WaterParams:
        """No water at all (air): no attenuation, no haze, no scattering, no particles."""
        return cls(attenuation_per_m=(0.0, 0.0, 0.0), backscatter_rgb=(0.0, 0.0, 0.0))

    @classmethod
    def turbid(cls) -> WaterParams:
        """Turbid coastal water with marine snow: strong haze, soft detail, drifting particles."""
        return cls(
            attenuation_per_m=(0.75, 0.30, 0.34),
            backscatter_rgb=(0.06, 0.34, 0.36),
            backscatter_per_m=0.9,
            forward_scatter_px=0.7,
            marine_snow_per_m3=100.0,
        )


@dataclass(frozen=True)
class SnowParticles:
    """Marine-snow particles in the camera's view at one instant (level frame, metres)."""

    forward_m: np.ndarray  # (N,) level-frame offsets from the camera
    starboard_m: np.ndarray  # (N,)
    depth_m: np.ndarray  # (N,) vertical distance below the camera (> SNOW_NEAR_M)
    diameter_m: np.ndarray  # (N,)


@lru_cache(maxsize=8192)
def _snow_cell(seed: int, density_per_m3: float, size_mm: float, i: int, j: int, k: int):
    """Particles of one lattice cell in the drifting frame: ((n, 3) positions m, (n,) diameters m)."""
    rng = np.random.default_rng([seed, _SNOW_LAYER, i & 0xFFFFFFFF, j & 0xFFFFFFFF, k & 0xFFFFFFFF])
    n = int(rng.poisson(density_per_m3 * SNOW_CELL_M**3))
    pos = (np.array([i, j, k], dtype=np.float64) + rng.random((n, 3))) * SNOW_CELL_M
    diam = size_mm * 1e-3 * np.exp(0.5 * rng.standard_normal(n))
    pos.setflags(write=False)
    diam.setflags(write=False)
    return pos, diam


def marine_snow(
    seed: int,
    water: WaterParams,
    t_s: float,
    x_m: float,
    y_m: float,
    altitude_m: float,
    heading_rad: float,
    reach_m: float,
) -> SnowParticles:
    """Particles within ``reach_m`` (horizontally) of the camera at time ``t_s``, between it and the seabed.

    Particle heights are measured up from the seabed; the lattice drifts with
    ``water.marine_snow_drift_mps`` (north, east, sinking).
    """
    if water.marine_snow_per_m3 <= 0:
        e = np.zeros(0)
        return SnowParticles(e, e, e, e)
    dn, de, ds = water.marine_snow_drift_mps
    # Drifting-frame coordinates: q = p - drift * t (height: q_h = h + sink * t).
    qx, qy, qh = x_m - dn * t_s, y_m - de * t_s, ds * t_s
    i_rng = range(int(np.floor((qx - reach_m) / SNOW_CELL_M)), int(np.floor((qx + reach_m) / SNOW_CELL_M)) + 1)
    j_rng = range(int(np.floor((qy - reach_m) / SNOW_CELL_M)), int(np.floor((qy + reach_m) / SNOW_CELL_M)) + 1)
    k_rng = range(int(np.floor(qh / SNOW_CELL_M)), int(np.floor((qh + altitude_m) / SNOW_CELL_M)) + 1)
    cells = [
        _snow_cell(seed, float(water.marine_snow_per_m3), float(water.marine_snow_size_mm), i, j, k)
        for i in i_rng
        for j in j_rng
        for k in k_rng
    ]
    pos = np.concatenate([c[0] for c in cells]) if cells else np.zeros((0, 3))
    diam = np.concatenate([c[1] for c in cells]) if cells else np.zeros(0)
    dx, dy = pos[:, 0] + dn * t_s - x_m, pos[:, 1] + de * t_s - y_m
    height = pos[:, 2] - ds * t_s
    depth = altitude_m - height
    keep = (height > 0.0) & (depth > SNOW_NEAR_M)
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    fwd, stb = c * dx + s * dy, -s * dx + c * dy  # R(psi)^T [dx, dy]
    return SnowParticles(fwd[keep], stb[keep], depth[keep], diam[keep])
