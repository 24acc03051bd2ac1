"""What the renderer is given: the camera's pose, its sensor and the laser spots' look.

Plain frozen dataclasses, checked at construction, in a module of their own so that the
renderer (:mod:`rovslam.sim.render`) and its parts (rays, shading, spots) all import them
without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.errors import SimulationError

__all__ = ["LaserSpotParams", "Pose", "SensorParams"]

_MAX_TILT_RAD = np.deg2rad(45.0)


@dataclass(frozen=True)
class Pose:
    """Camera pose: world position (m), altitude above the seabed (m), heading, roll, pitch (rad)."""

    x_m: float
    y_m: float
    altitude_m: float
    heading_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.x_m, self.y_m, self.altitude_m, self.heading_rad, self.roll_rad, self.pitch_rad)
        if not all(np.isfinite(v) for v in vals):
            raise SimulationError(f"pose values must be finite, got {vals}")
        if self.altitude_m <= 0.05:
            raise SimulationError(f"pose altitude_m must be > 0.05 m above the seabed, got {self.altitude_m}")
        if abs(self.roll_rad) > _MAX_TILT_RAD or abs(self.pitch_rad) > _MAX_TILT_RAD:
            raise SimulationError(
                f"roll and pitch must be within +-45 degrees for a downward camera, got "
                f"{np.rad2deg(self.roll_rad):.1f}, {np.rad2deg(self.pitch_rad):.1f} degrees"
            )


@dataclass(frozen=True)
class SensorParams:
    """Camera sensor, lens and lamps."""

    exposure_gain: float = 0.9  # DN per unit albedo x 255 under the lamps, before the water
    vignetting_power: float = 4.0  # cos^p(off-axis angle) lens falloff
    light_corner_ratio: float = 0.62  # lamp-cone irradiance at the image corner / at the cone centre
    light_centre_frac: tuple[float, float] = (0.10, -0.14)  # cone centre offset (u, v), half-image units
    exposure_s: float = 0.010  # motion blur: image motion integrated over this time
    antialias: float = 0.42  # prefilter sigma, in texels per (texels per pixel)
    shot_noise_dn: float = 0.06  # shot-noise variance per DN of signal
    read_noise_dn: float = 1.3  # read-noise standard deviation, DN
    jpeg_quality: int | None = None  # JPEG round trip inside the camera (None: none)
    psf_sigma_px: float = 0.0  # lens point-spread function: Gaussian core (0: none)
    psf_glare_fraction: float = 0.0  # ... and a wide veiling-glare skirt holding this fraction of the light
    psf_glare_sigma_px: float = 12.0
    readout_s: float = 0.0  # rolling shutter: time from the first to the last row (0: global shutter)

    def __post_init__(self) -> None:
        for name in (
            "exposure_gain",
            "vignetting_power",
            "exposure_s",
            "antialias",
            "shot_noise_dn",
            "read_noise_dn",
            "psf_sigma_px",
            "psf_glare_sigma_px",
            "readout_s",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"SensorParams.{name} must be a finite number >= 0, got {v}")
        if not (0.0 < self.light_corner_ratio <= 1.0):
            raise SimulationError(f"SensorParams.light_corner_ratio must be in (0, 1], got {self.light_corner_ratio}")
        if self.jpeg_quality is not None and not (1 <= self.jpeg_quality <= 100):
            raise SimulationError(f"SensorParams.jpeg_quality must be in 1..100 or None, got {self.jpeg_quality}")
        if not (0.0 <= self.psf_glare_fraction < 1.0):
            raise SimulationError(f"SensorParams.psf_glare_fraction must be in [0, 1), got {self.psf_glare_fraction}")

    @classmethod
    def ideal(cls) -> SensorParams:
        """Flat, noiseless, blur-free sensor (for geometry tests): unit gain, no falloff, no noise."""
        return cls(
            exposure_gain=1.0,
            vignetting_power=0.0,
            light_corner_ratio=1.0,
            exposure_s=0.0,
            shot_noise_dn=0.0,
            read_noise_dn=0.0,
        )


@dataclass(frozen=True)
class LaserSpotParams:
    """How a laser spot looks: a saturated red disc (the beam footprint) with a faint halo and speckle.

    The core is the beam's footprint on the seabed, ``spot_diameter_mm`` across, seen
    through the optics (edge blur ``optics_sigma_px``): far brighter than full scale, so it
    saturates the red channel with a steep edge. The halo is light scattered forward in
    the water. Green and blue get a little crosstalk of the (clipped) red.
    """

    peak_dn: float = 3000.0  # core irradiance before the water (saturates the red channel by far)
    spot_diameter_mm: float = 4.0  # beam footprint on the seabed (about 3.3 px at 1.31 m)
    optics_sigma_px: float = 0.45  # lens / sensor blur of the disc edge
    halo_fraction: float = 0.03  # forward-scattered glow, relative to the core
    halo_sigma_px: float = 3.0
    speckle: float = 0.35  # multiplicative speckle contrast (off when noise_free)
    crosstalk_green: float = 0.025  # fraction of the (clipped) red reaching the green pixels
    crosstalk_blue: float = 0.01

    def __post_init__(self) -> None:
        for name in (
            "peak_dn",
            "spot_diameter_mm",
            "optics_sigma_px",
            "halo_fraction",
            "halo_sigma_px",
            "speckle",
            "crosstalk_green",
            "crosstalk_blue",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"LaserSpotParams.{name} must be a finite number >= 0, got {v}")
        if self.optics_sigma_px < 0.1:
            raise SimulationError(f"LaserSpotParams.optics_sigma_px must be >= 0.1 px, got {self.optics_sigma_px}")
