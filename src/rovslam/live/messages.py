"""The MAVLink messages of one frame's estimate, as field values (pure numbers, no sockets).

Frames and units as the MAVLink definitions (common.xml, ardupilotmega.xml) say:

* VISION_POSITION_ESTIMATE: local NED (x north, y east, z down) in metres, the filter's
  position; ``covariance``: the upper-right triangle of the 6x6 pose covariance (x, y, z, roll,
  pitch, yaw) row by row, 21 values. rovslam's world frame is x north, y east with the heading
  from north towards east, so x, y and the 2x2 block are the filter's as they are. z is not
  estimated (the autopilot's depth sensor gives it): 0, with the altimeter's variance; roll and
  pitch are the AHRS's with its noise, yaw the filter's heading with the compass noise.
* VISION_SPEED_ESTIMATE: the ground velocity in NED (m/s), ``R(psi) [surge, sway]``, and its
  3x3 covariance row by row (vertical: not measured, the larger horizontal variance).
* VISION_POSITION_DELTA: the position change from the previous frame's body frame (FRD) to
  this one's, expressed in this one's (m); the angle change [roll, pitch, yaw] (rad); the time
  between the frames (us); a confidence 0-100 from the speed's covariance
  (:func:`confidence_percent`).
* DISTANCE_SENSOR: the laser altimeter's altitude, facing down (orientation 25,
  ROTATION_PITCH_270), in cm, with its variance in cm^2 (at most 254; 255 means unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ORIENTATION_DOWN = 25  # MAV_SENSOR_ROTATION_PITCH_270
DISTANCE_SENSOR_LASER = 0  # MAV_DISTANCE_SENSOR_LASER
CONFIDENCE_SIGMA_MPS = 0.05  # a speed 1-sigma of this gives a confidence of 50 %
UNKNOWN_COV_CM2 = 255


@dataclass(frozen=True)
class Estimate:
    """One processed frame's estimate, as the messages need it (world: x north, y east; heading from north)."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float
    roll_rad: float
    pitch_rad: float
    cov_xy_m2: np.ndarray  # (2, 2)
    surge_mps: float
    sway_mps: float
    speed_cov_mps2: np.ndarray  # (2, 2) body frame (surge, sway)
    speed_ok: bool
    altitude_m: float
    altitude_sigma_m: float
    altitude_source: str
    yaw_sigma_rad: float
    attitude_sigma_rad: float


def rotation(psi_rad: float) -> np.ndarray:
    """``R(psi)`` (2, 2): body (forward, starboard) to world (north, east)."""
    c, s = math.cos(psi_rad), math.sin(psi_rad)
    return np.array([[c, -s], [s, c]])


def upper_triangle(cov: np.ndarray) -> list[float]:
    """The upper-right triangle of a square matrix, row by row (6x6 -> 21 values, 3x3 -> 6)."""
    n = cov.shape[0]
    return [float(cov[i, j]) for i in range(n) for j in range(i, n)]


def pose_covariance_6x6(e: Estimate) -> np.ndarray:
    """(6, 6) covariance of (x, y, z, roll, pitch, yaw): the filter's 2x2, then the diagonal described above."""
    cov = np.zeros((6, 6))
    cov[:2, :2] = e.cov_xy_m2
    cov[2, 2] = e.altitude_sigma_m**2
    cov[3, 3] = cov[4, 4] = e.attitude_sigma_rad**2
    cov[5, 5] = e.yaw_sigma_rad**2
    return cov


def position_estimate(e: Estimate, usec: int, reset_counter: int) -> dict:
    """VISION_POSITION_ESTIMATE fields."""
    return {
        "usec": int(usec),
        "x": float(e.x_m),
        "y": float(e.y_m),
        "z": 0.0,
        "roll": float(e.roll_rad),
        "pitch": float(e.pitch_rad),
        "yaw": float(wrap_pi(e.heading_rad)),
        "covariance": upper_triangle(pose_covariance_6x6(e)),
        "reset_counter": int(reset_counter) % 256,
    }


def speed_estimate(e: Estimate, usec: int, reset_counter: int) -> dict:
    """VISION_SPEED_ESTIMATE fields: NED velocity and its 3x3 covariance (9 values, row by row)."""
    r = rotation(e.heading_rad)
    v = r @ np.array([e.surge_mps, e.sway_mps])
    c2 = r @ e.speed_cov_mps2 @ r.T
    cov = np.zeros((3, 3))
    cov[:2, :2] = c2
    cov[2, 2] = max(c2[0, 0], c2[1, 1])
    return {
        "usec": int(usec),
        "x": float(v[0]),
        "y": float(v[1]),
        "z": 0.0,
        "covariance": [float(c) for c in cov.ravel()],
        "reset_counter": int(reset_counter) % 256,
    }


def wrap_pi(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def confidence_percent(e: Estimate) -> float:
    """0-100: ``100 / (1 + (sigma / CONFIDENCE_SIGMA_MPS)^2)`` of the speed's larger 1-sigma; 0 without a speed."""
    if not e.speed_ok:
        return 0.0
    var = float(np.max(np.linalg.eigvalsh(0.5 * (e.speed_cov_mps2 + e.speed_cov_mps2.T))))
    if not math.isfinite(var):
        return 0.0
    return float(100.0 / (1.0 + max(var, 0.0) / CONFIDENCE_SIGMA_MPS**2))


def position_delta(prev: Estimate, e: Estimate, usec: int) -> dict:
    """VISION_POSITION_DELTA fields from the previous processed frame to this one."""
    d_world = np.array([e.x_m - prev.x_m, e.y_m - prev.y_m])
    d_body = rotation(e.heading_rad).T @ d_world  # expressed in the current body frame (forward, starboard)
    return {
        "time_usec": int(usec),
        "time_delta_usec": max(0, int(round((e.t_s - prev.t_s) * 1e6))),
        "angle_delta": [
            float(e.roll_rad - prev.roll_rad),
            float(e.pitch_rad - prev.pitch_rad),
            float(e.heading_rad - prev.heading_rad),
        ],
        "position_delta": [float(d_body[0]), float(d_body[1]), 0.0],
        "confidence": confidence_percent(e),
    }


def distance_sensor(e: Estimate, time_boot_ms: int, min_m: float, max_m: float) -> dict:
    """DISTANCE_SENSOR fields of the laser altimeter (downward)."""
    var_cm2 = (100.0 * e.altitude_sigma_m) ** 2
    cov = UNKNOWN_COV_CM2 if not math.isfinite(var_cm2) else int(min(254, max(0, round(var_cm2))))

    def cm(v: float) -> int:
        return int(min(65535, max(0, round(100.0 * v))))

    return {
        "time_boot_ms": int(time_boot_ms) % 2**32,
        "min_distance": cm(min_m),
        "max_distance": cm(max_m),
        "current_distance": cm(e.altitude_m),
        "type": DISTANCE_SENSOR_LASER,
        "id": 1,
        "orientation": ORIENTATION_DOWN,
        "covariance": cov,
    }
