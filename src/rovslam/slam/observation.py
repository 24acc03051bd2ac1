"""Observation model (3), its inverse (4), their Jacobians and the noise R_m, as pure functions.

``[m, n] = f/Z R(psi)^T [X - x, Y - y]``: the level-equivalent image coordinates of a seabed
point, m forward (``cy - v``), n starboard (``u - cx``). Real pixels from a tilted, distorted
or yaw-offset camera are turned into these with :func:`pixels_to_mn`, so the filter sees
exactly (3) with the vehicle heading psi. These are the only implementations of (3) and (4):
the filter, the landmark search and the tests all call them.
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import Camera, drot2, ground_to_mn, pixels_to_ground, rot2

__all__ = [
    "landmark_from_mn",
    "landmark_jacobians",
    "observation_jacobians",
    "observation_noise_px2",
    "observe_mn",
    "pixels_to_mn",
]


def observe_mn(
    landmarks_xy_m: np.ndarray, vehicle_xy_m: np.ndarray, heading_rad: float, altitude_m: float, focal_px: float
) -> np.ndarray:
    """Equation (3) without noise: (N, 2) world landmarks -> (N, 2) [m, n] pixels."""
    d = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2) - np.asarray(vehicle_xy_m).reshape(1, 2)
    # Row vectors: (R^T d)^T = d^T R.
    return (focal_px / altitude_m) * (d @ rot2(heading_rad))


def observation_jacobians(
    mn_px: np.ndarray, heading_rad: float, altitude_m: float, focal_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of (3) at the predicted (N, 2) [m, n].

    Returns ``(A, J_psi)``: ``A = f/Z R(psi)^T`` (2, 2), the derivative with respect to the
    landmark (and ``-A`` with respect to the vehicle position); ``J_psi`` (N, 2) ``= [n, -m]``,
    the derivative with respect to the heading.
    """
    mn = np.asarray(mn_px, dtype=np.float64).reshape(-1, 2)
    j_psi = np.empty_like(mn)
    j_psi[:, 0] = mn[:, 1]
    np.negative(mn[:, 0], out=j_psi[:, 1])
    return (focal_px / altitude_m) * rot2(heading_rad).T, j_psi


def landmark_from_mn(
    mn_px: np.ndarray, vehicle_xy_m: np.ndarray, heading_rad: float, altitude_m: float, focal_px: float
) -> np.ndarray:
    """Equation (4): (N, 2) [m, n] pixels -> (N, 2) world landmark positions."""
    mn = np.asarray(mn_px, dtype=np.float64).reshape(-1, 2)
    return np.asarray(vehicle_xy_m).reshape(1, 2) + (altitude_m / focal_px) * (mn @ rot2(heading_rad).T)


def landmark_jacobians(
    mn_px: np.ndarray, heading_rad: float, altitude_m: float, focal_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of (4) (the derivative with respect to the vehicle position is I).

    Returns ``(G, J_psi)``: ``G = Z/f R(psi)`` (2, 2), the derivative with respect to [m, n];
    ``J_psi`` (N, 2) ``= Z/f dR/dpsi [m, n]``, the derivative with respect to the heading.
    """
    mn = np.asarray(mn_px, dtype=np.float64).reshape(-1, 2)
    s = altitude_m / focal_px
    return s * rot2(heading_rad), s * (mn @ drot2(heading_rad).T)


def observation_noise_px2(
    mn_px: np.ndarray,
    pixel_sigma_px: float,
    altitude_m: float,
    altitude_sigma_m: float = 0.0,
    heading_sigma_rad: float = 0.0,
) -> np.ndarray:
    """R_m of (3)/(4): (2, 2) covariance of one [m, n] observation, pixels squared.

    ``sigma_px^2 I`` (template localisation) plus the altitude error, which scales the whole
    observation (``mn * sigma_Z / Z``, as the paper's R_m "takes into account ... small errors
    in the estimate of the feature altitude"), plus the heading error propagated through
    ``d mn / d psi = [n, -m]``.
    """
    m, n = np.asarray(mn_px, dtype=np.float64).reshape(2).tolist()
    # Python floats, in the order of sigma^2 I + k mn mn^T + h j j^T (j = [n, -m]): the same bits as the matrix form
    s2 = pixel_sigma_px**2
    r00, r01, r10, r11 = 1.0 * s2, 0.0 * s2, 0.0 * s2, 1.0 * s2
    if altitude_sigma_m > 0.0:
        k = (altitude_sigma_m / altitude_m) ** 2
        r00, r01, r10, r11 = r00 + k * (m * m), r01 + k * (m * n), r10 + k * (n * m), r11 + k * (n * n)
    if heading_sigma_rad > 0.0:
        h = heading_sigma_rad**2
        jm, jn = n, -m
        r00, r01, r10, r11 = r00 + h * (jm * jm), r01 + h * (jm * jn), r10 + h * (jn * jm), r11 + h * (jn * jn)
    return np.array([[r00, r01], [r10, r11]])


def pixels_to_mn(
    camera: Camera, uv_px: np.ndarray, altitude_m: float, roll_rad: float = 0.0, pitch_rad: float = 0.0
) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) level-equivalent [m, n] of (3), tilt compensated.

    Each pixel is mapped through the tilted camera onto the seabed (level-frame offset) and
    scaled by ``f/Z`` with ``f = camera.focal_px``; with roll = pitch = 0, no distortion and
    no yaw offset this is ``m = cy - v``, ``n = u - cx`` (for fx = fy).
    """
    g = pixels_to_ground(camera, uv_px, altitude_m, roll_rad, pitch_rad)
    return ground_to_mn(g, altitude_m, camera.focal_px)
