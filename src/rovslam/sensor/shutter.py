"""Rolling shutter: measurements moved to the frame's time.

A rolling-shutter camera (most CMOS sensors) exposes its rows top to bottom over the readout
time ``Camera.readout_s``; row v is seen ``Camera.row_time_s(v)`` after the frame's time (its
middle row). The paper's loop treats every pixel of a frame as seen at one instant. Under a
rolling shutter that is not so, and the error does not average out:

* speed: a token at row v in one frame and row v' in the next moved over
  ``dt + row_time(v') - row_time(v)``, not ``dt``. Moving forward, the seabed slides down the
  image and the interval is longer; moving back, shorter. Both make the surge read
  ``+ (f readout / (Z H)) u^2`` too high: a bias that does not change sign with the direction
  of travel (2 mm/s at 0.15 m/s for the paper's camera with a 30 ms readout).
* landmarks: a template seen at row v is where the seabed was ``row_time(v)`` away from the
  frame's pose, an offset of up to ``readout / 2`` times the image speed that the filter would
  read as an error of the vehicle or of the map.

Both are moved, to first order, to where they would be at the frame's time. With
``readout_s = 0`` (a global shutter, the default) nothing changes.
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import Camera

_J = np.array([[0.0, -1.0], [1.0, 0.0]])  # d R(psi) / d psi = J R(psi)


def tokens_at_frame_time(
    camera: Camera, uv_prev_px: np.ndarray, uv_curr_px: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Token positions of two consecutive frames, each moved to its frame's time by its own flow.

    ``uv_prev_px``, ``uv_curr_px``: ``(N, 2)`` the same tokens in the previous and the current
    frame (NaN rows stay NaN). Each token moved ``d = uv_curr - uv_prev`` between its two
    exposures, ``T = dt_s + row_time(v_curr) - row_time(v_prev)`` apart, at the rate ``d / T``;
    it was at ``uv - (d / T) row_time(v)`` at its frame's time. Exact for an image moving at a
    constant rate (a vehicle at constant speed and heading over a flat seabed). Returns the two
    ``(N, 2)`` arrays (the inputs themselves for a global shutter or ``dt_s <= 0``).
    """
    if camera.readout_s == 0.0 or not dt_s > 0:
        return uv_prev_px, uv_curr_px
    a = np.asarray(uv_prev_px, dtype=np.float64)
    b = np.asarray(uv_curr_px, dtype=np.float64)
    ta, tb = camera.row_time_s(a[:, 1]), camera.row_time_s(b[:, 1])
    span_s = np.maximum(dt_s + tb - ta, 0.5 * dt_s)  # kept positive should the readout outlast the frame interval
    rate = (b - a) / span_s[:, None]
    return a - rate * ta[:, None], b - rate * tb[:, None]


def mn_rate_px_s(
    mn_px: np.ndarray, speed_mps: np.ndarray, yaw_rate_radps: float, depth_m: float, focal_px: float
) -> np.ndarray:
    """How fast a seabed point's ``[m, n]`` of (3) moves in the image, pixels per second.

    Differentiating (3), ``[m, n] = f / Z R(psi)^T (X - x)``, with the vehicle moving at
    ``speed_mps`` = ``[surge, sway]`` and turning at ``yaw_rate_radps``:
    ``d[m, n]/dt = -yaw_rate J [m, n] - f / Z [surge, sway]``. ``mn_px`` ``(2,)`` -> ``(2,)``.
    """
    mn = np.asarray(mn_px, dtype=np.float64)
    return -yaw_rate_radps * (_J @ mn) - (focal_px / depth_m) * np.asarray(speed_mps, dtype=np.float64)


def mn_at_frame_time(camera: Camera, v_px: float, mn_px: np.ndarray, mn_rate: np.ndarray) -> np.ndarray:
    """``[m, n]`` seen at image row ``v_px`` moved to the frame's time: ``mn - rate row_time(v)``. ``(2,)``."""
    if camera.readout_s == 0.0:
        return mn_px
    return np.asarray(mn_px, dtype=np.float64) - np.asarray(mn_rate) * float(camera.row_time_s(v_px))  # type: ignore[arg-type]
