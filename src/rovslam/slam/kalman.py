"""The EKF's update (3) as kernels over its buffers: the stacked observation of landmarks, the
Joseph-form covariance update, and the cheap symmetrisation after it.

* :func:`observe_landmarks` is the one implementation of (3) with its Jacobian H under the state
  layout, for one landmark (the update) or many (the landmark search).
* :func:`joseph_update` applies ``P' = (I - K H) P (I - K H)^T + K R K^T`` (valid for any gain K)
  as the rank-4 correction ``P -= [K W] [W K]^T``, ``W = M - K S / 2`` (``M = P H^T``), in place with
  one BLAS ``dgemm``: O(N^2) memory traffic, no dense (2N+2)^3 product.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import dgemm

from rovslam.slam.observation import observation_jacobians, observe_mn
from rovslam.slam.state import StateLayout

__all__ = ["joseph_update", "observe_landmarks", "symmetrise_rows"]


def observe_landmarks(
    layout: StateLayout,
    x: np.ndarray,
    rows: np.ndarray,
    vehicle_xy_m: np.ndarray,
    theta_rad: float,
    depth_m: np.ndarray,
    focal_px: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(3) for K landmarks and its stacked Jacobian.

    Args:
        layout: the state's layout.
        x: (>= n,) the state vector.
        rows: (K,) first state row of each landmark.
        vehicle_xy_m: (2,) where the vehicle is taken to be.
        theta_rad: the map heading ``psi - eps``.
        depth_m: (K,) each landmark's depth ``Z + b - h``.
        focal_px: f.

    Returns:
        ``h`` (K, 2) the predicted [m, n], and ``H`` (K, 2, vehicle_dim + landmark_dim): each
        observation's derivative with respect to the vehicle block (``-A``, then ``d h / d eps =
        -d h / d psi``, ``d h / d b = d h / d s = -h / depth``, ``d h / d w = 0``, for the states present) and to
        its landmark's block (``A = f/depth R^T``, then ``d h / d h_i = h / depth``); the other columns are zero.
    """
    lm_rows = layout.landmark_rows(rows)  # (K, lm)
    h = observe_mn(x[lm_rows[:, :2]], vehicle_xy_m, theta_rad, depth_m[:, None], focal_px)  # type: ignore[arg-type]  # one depth per landmark
    a, j_psi = observation_jacobians(h, theta_rad, depth_m[:, None, None], focal_px)  # type: ignore[arg-type]  # (K, 2, 2), (K, 2)
    dh_ddepth = -(h / depth_m[:, None])[:, :, None]  # (K, 2, 1): b, s (and -h_i) move every depth
    blocks = [-a]
    if layout.eps is not None:
        blocks.append(-j_psi[:, :, None])
    if layout.b is not None:
        blocks.append(dh_ddepth)
    if layout.s is not None:
        blocks.append(dh_ddepth)
    if layout.w is not None:
        blocks.append(np.zeros((len(h), 2, 2)))
    blocks.append(a)
    if layout.has_landmark_heights:
        blocks.append(-dh_ddepth)
    return h, np.concatenate(blocks, axis=2)


def joseph_update(p: np.ndarray, n: int, vpad: np.ndarray, gain: np.ndarray, m: np.ndarray, s: np.ndarray) -> None:
    """Joseph form, rank 4, in place: ``P[:n, :n] -= K W^T + W K^T``, ``W = M - K S / 2``.

    ``p`` (cap, cap) the covariance buffer, ``vpad`` (cap, 4) a Fortran-order work array whose
    rows >= n are zero, ``gain`` K (n, 2), ``m`` M = P H^T (n, 2), ``s`` S (2, 2).
    """
    w = m - 0.5 * (gain @ s)
    u4 = np.empty((n, 4), order="F")
    u4[:, :2] = gain
    u4[:, 2:] = w
    vpad[:n, :2] = w
    vpad[:n, 2:] = gain
    block_t = p[:n, :].T  # (cap, n) Fortran-contiguous view of the used rows
    out = dgemm(-1.0, vpad, u4, beta=1.0, c=block_t, trans_b=1, overwrite_c=1)
    if out is not block_t:  # BLAS wrapper made a copy (should not happen): write back
        block_t[...] = out


def symmetrise_rows(p: np.ndarray, n: int, idx: np.ndarray) -> None:
    """Cheap O(N) symmetrisation of the rows/columns ``idx`` of ``P[:n, :n]`` (those the next update reads)."""
    avg = 0.5 * (p[idx, :n] + p[:n, idx].T)
    p[idx, :n] = avg
    p[:n, idx] = avg.T
