"""Vehicle motion model (1) as pure functions: ``[x, y](k+1) = [x, y](k) + R(psi) [u, v] dt``.

Used by the filter's prediction, by the dead reckoning the pipeline reports beside it, and
by the landmark search (where the vehicle is expected before this frame's speed is known).
"""

from __future__ import annotations

import math

import numpy as np

from rovslam.camera import drot2, rot2

__all__ = ["altitude_offset_sigma_m", "motion_step_m", "motion_jacobians", "ou_sum_as_one"]


def motion_step_m(speed_mps: np.ndarray, heading_rad: float, dt_s: float) -> np.ndarray:
    """(1) without noise: (2,) body speed [u, v] over ``dt_s`` at heading psi -> (2,) world displacement, metres."""
    return rot2(heading_rad) @ np.asarray(speed_mps, dtype=np.float64) * dt_s


def motion_jacobians(speed_mps: np.ndarray, heading_rad: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of (1)'s displacement: ``(G (2, 2) = d/d[u, v] = R dt, j (2,) = d/dpsi = dR/dpsi [u, v] dt)``."""
    return rot2(heading_rad) * dt_s, drot2(heading_rad) @ np.asarray(speed_mps, dtype=np.float64) * dt_s


def ou_sum_as_one(sigma_a: float, tau_a_s: float, sigma_b: float, tau_b_s: float) -> tuple[float, float]:
    """The sum of two independent Ornstein-Uhlenbeck processes held as one: ``(sigma, tau_s)``.

    The one process has the sum's variance, ``sigma^2 = sigma_a^2 + sigma_b^2``, and its integrated
    autocovariance, ``sigma^2 tau = sigma_a^2 tau_a + sigma_b^2 tau_b``: a scale error it stands for
    then drifts the position as fast as the sum does over long times (``2 sigma^2 tau T``), and
    over short ones (``sigma^2 T^2``). With ``sigma_b = 0`` it is process a; both 0 gives ``(0, tau_a_s)``.
    """
    var = sigma_a * sigma_a + sigma_b * sigma_b
    if var <= 0.0:
        return 0.0, tau_a_s
    return math.sqrt(var), (sigma_a * sigma_a * tau_a_s + sigma_b * sigma_b * tau_b_s) / var


def altitude_offset_sigma_m(offset_sigma_m: float, scale_sigma: float, altitude_m):
    """Sigma of the measured altitude's lasting error at depth Z: an offset and a share of Z, in quadrature.

    ``offset_sigma_m`` (an altimeter's offset, a codec's spot) is the same at any depth; a laser rig
    whose baseline is off by ``s`` measures ``(1 + s) Z``, an error that grows with the depth. ``altitude_m``
    () or (N,); returns the same shape (a float for a float). With ``scale_sigma = 0``: ``offset_sigma_m``.
    """
    if scale_sigma == 0.0:
        return offset_sigma_m if np.ndim(altitude_m) == 0 else np.full(np.shape(altitude_m), float(offset_sigma_m))
    if np.ndim(altitude_m) == 0:
        return math.hypot(offset_sigma_m, scale_sigma * float(altitude_m))
    return np.hypot(offset_sigma_m, scale_sigma * np.asarray(altitude_m, dtype=np.float64))
