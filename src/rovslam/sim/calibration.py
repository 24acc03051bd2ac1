"""Calibration errors of a simulated vehicle: the lasting errors a real rig's calibration leaves, drawn per seed.

The presets' sensors are calibrated exactly: the compass has no deviation, the laser pointers
are where ``sequence.toml`` says they are, the sonar altimeter has no offset. A real vehicle
carries lasting errors of all three, and the filter is told of them (``[odometry]
compass_offset_sigma_rad``; ``[slam] altitude_scale_sigma``, the rig's share of the depth, and
``altitude_bias_sigma_m``, an offset). With these errors drawn per seed
(``rovslam simulate --calibration-errors``, ``calibration_errors = true`` in a matrix entry) the
robustness matrix tests whether those terms cover what they stand for:

* a compass deviation: every heading reading is off by the same angle (the whole estimate turns);
* a laser-rig baseline error: the lateral offsets of the pointers written to ``sequence.toml``
  are the true ones times ``1 + s``, so the lasers' altitude (for rays parallel to the optical
  axis, ``Z = f X / (u - c)``) is the true one times ``1 + s``: a lasting scale error of the
  odometry and of every landmark's position;
* a sonar offset: every altimeter reading is off by the same distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rovslam.camera import LaserPointer
from rovslam.errors import SimulationError

_STREAM_CALIBRATION = 14  # the seed's generator stream of the drawn errors (11-13: trajectory, sensors, frames)


@dataclass(frozen=True)
class CalibrationErrors:
    """Standard deviations of the drawn errors; the defaults are what rovslam's configuration assumes.

    ``laser_baseline_sigma`` is relative (0.0076: ``[slam] altitude_scale_sigma``'s default, 1 cm of
    altitude at the paper's 1.31 m); the angle and the offset are absolute.
    """

    compass_deviation_sigma_rad: float = math.radians(0.5)  # [odometry] compass_offset_sigma_rad: 0.0087
    laser_baseline_sigma: float = 0.0076
    sonar_offset_sigma_m: float = 0.01

    def __post_init__(self) -> None:
        for name in ("compass_deviation_sigma_rad", "laser_baseline_sigma", "sonar_offset_sigma_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise SimulationError(f"CalibrationErrors.{name} must be a finite number >= 0, got {value!r}")
        if self.laser_baseline_sigma >= 0.1:
            raise SimulationError(
                f"CalibrationErrors.laser_baseline_sigma must be below 0.1 (10 % of the rig), "
                f"got {self.laser_baseline_sigma}"
            )


@dataclass(frozen=True)
class DrawnCalibration:
    """One seed's errors: the compass reads ``true + compass_deviation_rad``, the recorded rig's
    lateral offsets are ``(1 + laser_baseline_error)`` times the true ones, the sonar reads
    ``true + sonar_offset_m``."""

    compass_deviation_rad: float
    laser_baseline_error: float
    sonar_offset_m: float

    def __post_init__(self) -> None:
        for name in ("compass_deviation_rad", "laser_baseline_error", "sonar_offset_m"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise SimulationError(f"DrawnCalibration.{name} must be a finite number, got {value!r}")
        if abs(self.laser_baseline_error) >= 0.5:
            raise SimulationError(
                f"DrawnCalibration.laser_baseline_error must be within +-0.5 (50 % of the rig), "
                f"got {self.laser_baseline_error}"
            )

    def metadata(self) -> dict[str, float]:
        """The ``[metadata]`` entries of ``sequence.toml`` that record the drawn errors."""
        return {
            "calibration_compass_deviation_deg": round(math.degrees(self.compass_deviation_rad), 4),
            "calibration_laser_baseline_error": round(self.laser_baseline_error, 6),
            "calibration_sonar_offset_m": round(self.sonar_offset_m, 5),
        }


def draw_calibration(errors: CalibrationErrors, seed: int) -> DrawnCalibration:
    """The errors of seed ``seed``: independent zero-mean normals, from the seed's own stream.

    A stream of its own, so the trajectory, the sensors' noise and the images of a seed are the
    same with and without calibration errors: the two dives differ by the errors alone.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"seed must be a whole number >= 0, got {seed!r}")
    z = np.random.default_rng([int(seed), _STREAM_CALIBRATION]).standard_normal(3)
    return DrawnCalibration(
        compass_deviation_rad=float(errors.compass_deviation_sigma_rad * z[0]),
        laser_baseline_error=float(errors.laser_baseline_sigma * z[1]),
        sonar_offset_m=float(errors.sonar_offset_sigma_m * z[2]),
    )


def recorded_lasers(lasers: tuple[LaserPointer, ...], drawn: DrawnCalibration) -> tuple[LaserPointer, ...]:
    """The rig as ``sequence.toml`` describes it: each origin's lateral offsets times ``1 + s``, directions kept."""
    s = 1.0 + drawn.laser_baseline_error
    return tuple(replace(lp, origin_m=(lp.origin_m[0] * s, lp.origin_m[1] * s, lp.origin_m[2])) for lp in lasers)
