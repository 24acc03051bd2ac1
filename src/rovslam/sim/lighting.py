"""Light that travels with the vehicle: lamps on the ROV, shading by the relief, 1/r^2, shadows, caustics.

Irradiance of a seabed point P with upward normal n from lamp i at L_i (level frame,
metres from the camera; beam axis a_i, half-power half-angle beta_i)::

    E_i = I_i * B_i(angle between a_i and P - L_i) * max(n . l_i, 0) / r_i^2 * V_i

with ``l_i`` the unit vector from P to the lamp, ``r_i`` the distance, ``B_i = cos^m`` of
the off-axis angle (``m`` sets half power at ``beta_i``) and ``V_i`` the visibility (1, or
a soft cast shadow found by stepping from P towards the lamp over the relief). The
renderer divides by ``E_ref``, the irradiance of the flat seabed straight below the camera
from ``reference_altitude_m``, so the exposure of the original presets carries over. The
same patch, seen again from elsewhere, is lit from another direction and distance: a
landmark template is never an exact copy. Optional sunlight caustics (shallow dives) are a
moving network of bright lines, a tileable pattern sampled at the seabed position and
drifting with time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from rovslam.errors import SimulationError

RGB = tuple[float, float, float]


@dataclass(frozen=True)
class Lamp:
    """One lamp on the vehicle: body-frame position (forward, starboard, down) from the camera, beam axis."""

    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    beam_half_angle_rad: float = 0.55  # off-axis angle where the beam has half its axial intensity
    intensity: float = 1.0  # relative to the other lamps

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or d[2] <= 0:
            raise SimulationError(
                f"Lamp.direction must be 3 finite numbers pointing down (z > 0), got {self.direction}"
            )
        if len(self.position_m) != 3 or not np.all(np.isfinite(self.position_m)):
            raise SimulationError(f"Lamp.position_m must be 3 finite numbers, got {self.position_m}")
        if not (0.05 <= self.beam_half_angle_rad <= 1.4):
            raise SimulationError(f"Lamp.beam_half_angle_rad must be in [0.05, 1.4], got {self.beam_half_angle_rad}")
        if not (np.isfinite(self.intensity) and self.intensity > 0):
            raise SimulationError(f"Lamp.intensity must be > 0, got {self.intensity}")

    @property
    def beam_exponent(self) -> float:
        """m of the cos^m beam pattern (half power at ``beam_half_angle_rad``)."""
        return float(np.log(0.5) / np.log(np.cos(self.beam_half_angle_rad)))


@dataclass(frozen=True)
class CausticParams:
    """Sunlight caustics of a shallow dive: a bright moving network on the seabed."""

    strength: float = 0.35  # mean sunlight on the seabed, relative to the lamps below the camera
    scale_m: float = 0.12  # size of the network's cells
    drift_mps: tuple[float, float] = (0.05, 0.03)  # speed of the pattern over the seabed
    rgb: RGB = (0.55, 1.0, 0.95)  # sunlight after the water column above (red is gone)

    def __post_init__(self) -> None:
        for name in ("strength", "scale_m"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise SimulationError(f"CausticParams.{name} must be > 0, got {getattr(self, name)}")


def _default_lamps() -> tuple[Lamp, ...]:
    # Two lamps on the vehicle's front corners, 40 cm either side of the camera and 20 cm ahead,
    # aimed at the seabed 1.3 m below the camera: light comes in about 20 degrees off vertical.
    return (Lamp((0.2, -0.4, 0.05), (-0.2, 0.4, 1.3)), Lamp((0.2, 0.4, 0.05), (-0.2, -0.4, 1.3)))


@dataclass(frozen=True)
class LightingParams:
    """Lamps on the vehicle and the optional sun (see the module docstring)."""

    lamps: tuple[Lamp, ...] = field(default_factory=_default_lamps)
    reference_altitude_m: float = 1.31
    ambient: float = 0.03  # light from everywhere (scattered, surface light), relative to E_ref
    shadow_samples: int = 0  # steps of the cast-shadow search per lamp (0: no cast shadows)
    shadow_softness_m: float = 0.004  # occluder height over the light ray that makes a full shadow
    caustics: CausticParams | None = None

    def __post_init__(self) -> None:
        if not self.lamps:
            raise SimulationError("LightingParams.lamps needs at least one Lamp")
        if not (self.reference_altitude_m > 0.1):
            raise SimulationError(
                f"LightingParams.reference_altitude_m must be > 0.1 m, got {self.reference_altitude_m}"
            )
        if not (0.0 <= self.ambient <= 1.0):
            raise SimulationError(f"LightingParams.ambient must be in [0, 1], got {self.ambient}")
        if not (0 <= self.shadow_samples <= 16):
            raise SimulationError(f"LightingParams.shadow_samples must be in 0..16, got {self.shadow_samples}")
        if not self.shadow_softness_m > 0:
            raise SimulationError(f"LightingParams.shadow_softness_m must be > 0, got {self.shadow_softness_m}")


def lamp_irradiance(
    lamp_level: np.ndarray,
    axis_level: np.ndarray,
    exponent: float,
    px: np.ndarray,
    py: np.ndarray,
    pz: np.ndarray,
    nx: np.ndarray,
    ny: np.ndarray,
    nz: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Irradiance from one unit lamp (no shadow) at points P with unit normals n, level frame.

    ``lamp_level`` (3,) is the lamp position, ``axis_level`` (3,) its unit beam axis; the
    points and normals are (H, W) float32 arrays (z down; normals point up, nz < 0).
    Returns (irradiance (H, W), distance r (H, W), the vector P -> lamp (lx, ly, lz)).
    """
    lx = np.float32(lamp_level[0]) - px
    ly = np.float32(lamp_level[1]) - py
    lz = np.float32(lamp_level[2]) - pz
    r2 = lx * lx + ly * ly + lz * lz
    inv_r = 1.0 / np.sqrt(r2)
    incidence = np.maximum((nx * lx + ny * ly + nz * lz) * inv_r, 0.0)  # n . l
    ax, ay, az = (float(v) for v in axis_level)  # Python floats keep the arithmetic in float32
    beam = np.maximum(-(ax * lx + ay * ly + az * lz) * inv_r, 0.0)
    return (beam**exponent) * incidence / r2, r2 * inv_r, (lx, ly, lz)


def reference_irradiance(params: LightingParams) -> float:
    """E_ref: the lamps' irradiance of a flat seabed straight below the camera at ``reference_altitude_m``."""
    z = params.reference_altitude_m
    one = np.ones((1, 1), dtype=np.float32)
    total = 0.0
    for lamp in params.lamps:
        axis = np.asarray(lamp.direction, dtype=np.float64) / np.linalg.norm(lamp.direction)
        e, _, _ = lamp_irradiance(
            np.asarray(lamp.position_m), axis, lamp.beam_exponent, 0 * one, 0 * one, z * one, 0 * one, 0 * one, -one
        )
        total += lamp.intensity * float(e[0, 0])
    return total


CAUSTIC_TEXELS = 256  # side of the tileable caustic pattern (one period)


@lru_cache(maxsize=4)
def caustic_pattern(seed: int) -> np.ndarray:
    """A tileable caustic network, ``(256, 256) float32`` with mean 1 (one period = 4 cells).

    Bright thin lines where two periodic band-limited noise fields cross zero, as the
    focused sunlight under a wavy surface.
    """
    rng = np.random.default_rng([seed, 0xCA05])
    n = CAUSTIC_TEXELS
    k = np.fft.fftfreq(n) * n
    kk = np.hypot(k[:, None], k[None, :])
    band = np.exp(-0.5 * ((kk - 4.0) / 1.2) ** 2)  # about 4 cells per period
    out = np.zeros((n, n))
    for _ in range(2):
        spec = band * np.exp(2j * np.pi * rng.random((n, n)))
        f = np.real(np.fft.ifft2(spec))
        f /= f.std()
        out += np.exp(-0.5 * (f / 0.18) ** 2)
    out /= out.mean()
    return out.astype(np.float32)
