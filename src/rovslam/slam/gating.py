"""Visibility gate (5) and new-landmark test (6) as pure, vectorised functions.

Both tests are Mahalanobis distances of the landmark-to-vehicle offset ``d = X_i - x``:

* (5) ``d^T (P_Xi + P_x + D)^-1 d <= lambda``: landmark i may be in the camera field of view.
  ``D = (Z/f)^2 R(psi) diag((H/2)^2, (W/2)^2) R(psi)^T`` is the seabed footprint of an
  H x W image (H along forward / m, W along starboard / n). The paper prints
  ``diag(H/2, W/2)`` without the squares and without the trailing ``R^T``, which is
  dimensionally wrong (metres, not metres squared); rovslam uses the squared form.
* (6) ``d^T (P_Xi + P_x + L)^-1 d >= mu`` for every i: the vehicle is far enough from all
  landmarks to add a new one; ``L = (spacing^2 / mu) I`` fixes the minimum spacing, so that
  with a certain filter a new landmark is allowed exactly ``spacing`` metres from the others.

The paper adds the two marginal covariances. The covariance of ``d`` is really
``P_Xi + P_x - C_i - C_i^T`` with ``C_i = cov(x, X_i)``; pass ``cross_cov_m2`` to use it
(:class:`rovslam.slam.EkfSlam` does by default, ``SlamConfig.gate_covariance``).

Every function works on all N landmarks at once, with a closed-form 2x2 inverse.
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import rot2

__all__ = [
    "footprint_matrix_m2",
    "spacing_matrix_m2",
    "offset_covariances_m2",
    "mahalanobis_sq_2d",
    "visibility_statistics",
    "visibility_gate",
    "new_landmark_statistics",
    "new_landmark_test",
]


def footprint_matrix_m2(
    heading_rad: float, altitude_m: float, focal_px: float, width_px: float, height_px: float
) -> np.ndarray:
    """D of (5): (2, 2) world-frame footprint 'covariance', metres squared.

    ``D = (Z/f)^2 R(psi) diag((H/2)^2, (W/2)^2) R(psi)^T``: a landmark on the image border
    (with no uncertainty) is at Mahalanobis distance 1.
    """
    s = altitude_m / focal_px
    r = rot2(heading_rad)
    return (r * (s * s * np.array([(0.5 * height_px) ** 2, (0.5 * width_px) ** 2]))) @ r.T


def spacing_matrix_m2(spacing_m: float, mu: float = 1.0) -> np.ndarray:
    """L of (6): (2, 2) ``(spacing^2 / mu) I``: with zero covariance, (6) holds iff |d| >= spacing."""
    return np.eye(2) * float(spacing_m) ** 2 / float(mu)


def offset_covariances_m2(
    landmarks_cov_m2: np.ndarray, vehicle_cov_m2: np.ndarray, cross_cov_m2: np.ndarray | None = None
) -> np.ndarray:
    """(N, 2, 2) covariance of ``X_i - x``.

    Args:
        landmarks_cov_m2: (N, 2, 2) P_Xi.
        vehicle_cov_m2: (2, 2) P_x.
        cross_cov_m2: optional (N, 2, 2) ``C_i = cov(x, X_i)`` (vehicle rows, landmark
            columns). None gives the paper's ``P_Xi + P_x``.
    """
    c = landmarks_cov_m2 + vehicle_cov_m2
    if cross_cov_m2 is not None:
        c = c - cross_cov_m2 - np.swapaxes(cross_cov_m2, 1, 2)
    return c


def mahalanobis_sq_2d(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``d_i^T cov_i^-1 d_i`` for (N, 2) offsets and (N, 2, 2) (or one (2, 2)) covariances -> (N,).

    A singular covariance gives +inf for a non-zero offset and 0 for a zero one.
    """
    d = np.asarray(d, dtype=np.float64).reshape(-1, 2)
    cov = np.asarray(cov, dtype=np.float64)
    if cov.ndim == 2:
        cov = cov[None]
    a = cov[:, 0, 0]
    b = 0.5 * (cov[:, 0, 1] + cov[:, 1, 0])
    c = cov[:, 1, 1]
    x, y = d[:, 0], d[:, 1]
    num = c * x * x - 2.0 * b * x * y + a * y * y
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        q = num / det
    q = np.where(det > 0, q, np.where((x != 0) | (y != 0), np.inf, 0.0))
    return q


def visibility_statistics(
    landmarks_xy_m: np.ndarray,
    landmarks_cov_m2: np.ndarray,
    vehicle_xy_m: np.ndarray,
    vehicle_cov_m2: np.ndarray,
    footprint_m2: np.ndarray,
    cross_cov_m2: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) left-hand side of (5): ``d^T (P_Xi + P_x [- C - C^T] + D)^-1 d``."""
    return _offset_statistics(
        landmarks_xy_m, landmarks_cov_m2, vehicle_xy_m, vehicle_cov_m2, footprint_m2, cross_cov_m2
    )


def _offset_statistics(landmarks_xy_m, landmarks_cov_m2, vehicle_xy_m, vehicle_cov_m2, extra_m2, cross_cov_m2):
    """(N,) ``d^T (P_Xi + P_x [- C - C^T] + extra)^-1 d``, d = X_i - x: the form shared by (5) and (6)."""
    d = np.asarray(landmarks_xy_m, dtype=np.float64).reshape(-1, 2) - np.asarray(vehicle_xy_m).reshape(1, 2)
    cov = offset_covariances_m2(landmarks_cov_m2, vehicle_cov_m2, cross_cov_m2) + extra_m2
    return mahalanobis_sq_2d(d, cov)


def visibility_gate(
    landmarks_xy_m: np.ndarray,
    landmarks_cov_m2: np.ndarray,
    vehicle_xy_m: np.ndarray,
    vehicle_cov_m2: np.ndarray,
    footprint_m2: np.ndarray,
    lambda_: float,
    cross_cov_m2: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) bool: landmarks that pass the visibility gate (5) (statistic <= lambda)."""
    return (
        visibility_statistics(
            landmarks_xy_m, landmarks_cov_m2, vehicle_xy_m, vehicle_cov_m2, footprint_m2, cross_cov_m2
        )
        <= lambda_
    )


def new_landmark_statistics(
    landmarks_xy_m: np.ndarray,
    landmarks_cov_m2: np.ndarray,
    vehicle_xy_m: np.ndarray,
    vehicle_cov_m2: np.ndarray,
    spacing_m2: np.ndarray,
    cross_cov_m2: np.ndarray | None = None,
) -> np.ndarray:
    """(N,) left-hand side of (6): ``d^T (P_Xi + P_x [- C - C^T] + L)^-1 d``."""
    return _offset_statistics(landmarks_xy_m, landmarks_cov_m2, vehicle_xy_m, vehicle_cov_m2, spacing_m2, cross_cov_m2)


def new_landmark_test(
    landmarks_xy_m: np.ndarray,
    landmarks_cov_m2: np.ndarray,
    vehicle_xy_m: np.ndarray,
    vehicle_cov_m2: np.ndarray,
    spacing_m2: np.ndarray,
    mu: float,
    cross_cov_m2: np.ndarray | None = None,
) -> bool:
    """Test (6): True when every landmark is far enough (statistic >= mu); True with no landmarks."""
    if len(landmarks_xy_m) == 0:
        return True
    stats = new_landmark_statistics(
        landmarks_xy_m, landmarks_cov_m2, vehicle_xy_m, vehicle_cov_m2, spacing_m2, cross_cov_m2
    )
    return bool(np.all(stats >= mu))
