"""The landmarks' heights and the seabed under the laser spots, given the poses: the smoother's relief step.

Equation (3) with the EKF's relief states (:mod:`rovslam.slam.ekf`): landmark i seen at frame k
at the level-equivalent pixel ``[m, n]`` satisfies

    ``[m, n] d_ki / f = R(psi_k)^T (X_i - x_k)``,  ``d_ki = Z_k + s_k - h_i``,

``Z_k`` the laser altitude, ``s_k`` the seabed level under the spots relative to the start's (an
Ornstein-Uhlenbeck process, ``s_0 = 0``: the start's seabed is the datum) and ``h_i`` the
landmark's height above that datum, whose prior is ``h_i - s_{k0} ~ N(0, sigma_h^2)`` at its
first frame ``k0`` (the seabed under the camera then). Bilinear in the unknowns as a whole, (3)
is *linear* in ``(X, h, s)`` once the poses are given: :func:`solve_relief` solves that linear
least-squares problem over every landmark and frame at once (sparse normal equations), with
the observations' noise ``d^2 R_m / f^2`` and the robust loss's weight at the current residual
(one iteratively-reweighted step, as the graph's Huber or Cauchy loss). The smoother
(:mod:`rovslam.slam.smoother`) alternates it with its graph, whose landmark factors take the
depths :func:`observation_depths` gives: the heights come from every view of a landmark, not only
the past ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "ReliefPriors",
    "ReliefObservations",
    "ReliefSolution",
    "solve_relief",
    "observation_depths",
    "robust_weight",
    "landmark_residuals",
    "whitened_norms",
]

# Sigma of the prior holding s_0 at the start's seabed (metres): the datum, as the EKF's zero variance.
_DATUM_SIGMA_M = 1e-4


@dataclass(frozen=True)
class ReliefPriors:
    """The priors of the relief states (the EKF's ``[slam]`` figures by default, via ``[smoother]``).

    Attributes:
        landmark_height_sigma_m: a landmark's height off the seabed under the camera at its first frame.
        seabed_offset_sigma_m, seabed_offset_tau_s: s's stationary sigma and correlation time.
    """

    landmark_height_sigma_m: float
    seabed_offset_sigma_m: float
    seabed_offset_tau_s: float


@dataclass(frozen=True)
class ReliefObservations:
    """Every landmark observation of a dive, stacked (K observations, N frames, M landmarks).

    Attributes:
        pose: (K,) frame number of each observation (0..N-1).
        landmark: (K,) landmark number (0..M-1).
        ray: (K, 2) ``[m, n] / f``: the level-equivalent pixel over the focal length.
        noise: (K, 2, 2) ``R_m / f^2``: the pixel noise in the same units.
        first_pose: (M,) each landmark's first frame.
    """

    pose: np.ndarray
    landmark: np.ndarray
    ray: np.ndarray
    noise: np.ndarray
    first_pose: np.ndarray


@dataclass(frozen=True)
class ReliefSolution:
    """What :func:`solve_relief` found.

    Attributes:
        landmarks_xy_m: (M, 2) landmark positions, world frame.
        height_m: (M,) the landmarks' heights above the start's seabed.
        seabed_m: (N,) s at every frame.
    """

    landmarks_xy_m: np.ndarray
    height_m: np.ndarray
    seabed_m: np.ndarray


def observation_depths(altitude_m: np.ndarray, seabed_m: np.ndarray, height_m: np.ndarray, obs: ReliefObservations):
    """(K,) the image depth of every observation, ``Z_k + s_k - h_i`` (metres)."""
    return altitude_m[obs.pose] + seabed_m[obs.pose] - height_m[obs.landmark]


def _whitening(cov: np.ndarray) -> np.ndarray:
    """(K, 2, 2) upper-triangular W with ``W^T W = cov^-1`` for (K, 2, 2) covariances."""
    return np.linalg.cholesky(np.linalg.inv(cov)).transpose(0, 2, 1)


def landmark_residuals(
    xy_m: np.ndarray, heading_rad: np.ndarray, landmarks_xy_m: np.ndarray, depth_m: np.ndarray, obs: ReliefObservations
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The whitened residuals of (3) at an estimate, every observation at its depth.

    Args:
        xy_m: (N, 2) positions; heading_rad: (N,) headings; landmarks_xy_m: (M, 2) landmarks;
        depth_m: (K,) each observation's image depth (its noise is ``depth^2 R_m / f^2``).

    Returns:
        ``(residual (K, 2), W (K, 2, 2), R^T (K, 2, 2))``: ``W [R(psi_k)^T (X_i - x_k) - ray depth]``,
        the whitening ``W`` (``W^T W = cov^-1``) and each observation's ``R(psi_k)^T``.
    """
    k, i = obs.pose, obs.landmark
    c, s = np.cos(heading_rad[k]), np.sin(heading_rad[k])
    rt = np.stack([np.stack([c, s], 1), np.stack([-s, c], 1)], 1)  # (K, 2, 2) R(psi_k)^T
    w = _whitening(depth_m[:, None, None] ** 2 * obs.noise)
    residual = np.einsum(
        "kij,kj->ki", w, np.einsum("kij,kj->ki", rt, landmarks_xy_m[i] - xy_m[k]) - obs.ray * depth_m[:, None]
    )
    return residual, w, rt


def whitened_norms(
    xy_m: np.ndarray, heading_rad: np.ndarray, landmarks_xy_m: np.ndarray, obs: ReliefObservations, depth_m: np.ndarray
) -> np.ndarray:
    """(K,) the whitened residual norms of (3) at an estimate (:func:`landmark_residuals`)."""
    return np.linalg.norm(landmark_residuals(xy_m, heading_rad, landmarks_xy_m, depth_m, obs)[0], axis=1)


def robust_weight(norm: np.ndarray, robust: str, robust_k: float) -> np.ndarray:
    """(K,) the weight of a robust loss at whitened residual norms (K,): GTSAM's ``mEstimator`` weights."""
    if robust == "huber":
        return np.where(norm > robust_k, robust_k / np.maximum(norm, 1e-300), 1.0)
    if robust == "cauchy":
        return 1.0 / (1.0 + (norm / robust_k) ** 2)
    return np.ones_like(norm)


def solve_relief(
    xy_m: np.ndarray,
    heading_rad: np.ndarray,
    t_s: np.ndarray,
    altitude_m: np.ndarray,
    landmarks_xy_m: np.ndarray,
    depth_m: np.ndarray,
    obs: ReliefObservations,
    priors: ReliefPriors,
    robust: str,
    robust_k: float,
) -> ReliefSolution:
    """Landmark positions, heights and the seabed offset that best explain (3) with the poses held.

    Args:
        xy_m: (N, 2) positions; heading_rad: (N,) headings; t_s: (N,) times; altitude_m: (N,) Z.
        landmarks_xy_m: (M, 2) the current landmark positions and depth_m: (K,) the current
            depths: they set the noise (``d^2 R_m / f^2``) and the robust weights.
        obs: the observations; priors: the relief priors.
        robust, robust_k: the graph's loss on the landmark factors ("huber", "cauchy" or "none")
            and its threshold in whitened sigmas.

    Returns:
        The solution; every landmark is determined (its height prior makes a single view enough).
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spl

    n, m, k_obs = len(t_s), len(landmarks_xy_m), len(obs.pose)
    k, i = obs.pose, obs.landmark
    # Residual of (3), whitened: W [R^T X_i - R^T x_k - ray (Z_k + s_k - h_i)].
    residual, w, rt = landmark_residuals(xy_m, heading_rad, landmarks_xy_m, depth_m, obs)
    norm = np.linalg.norm(residual, axis=1)
    weight = np.sqrt(robust_weight(norm, robust, robust_k))  # on the rows: its square root
    w_rt = np.einsum("kij,kjl->kil", w, rt) * weight[:, None, None]  # (K, 2, 2) on X_i
    w_ray = np.einsum("kij,kj->ki", w, obs.ray) * weight[:, None]  # (K, 2) on h_i (+), s_k (-)
    rhs_obs = np.einsum("kij,kj->ki", w_rt, xy_m[k]) + w_ray * altitude_m[k][:, None]
    # Unknowns: X (2M), then h (M), then s (N).
    col_h, col_s = 2 * m, 3 * m
    rows_o = 2 * np.arange(k_obs)[:, None] + np.arange(2)[None, :]  # (K, 2)
    r_list = [rows_o, rows_o, rows_o, rows_o]
    c_list = [np.broadcast_to(col[:, None], rows_o.shape) for col in (2 * i, 2 * i + 1, col_h + i, col_s + k)]
    v_list = [w_rt[:, :, 0], w_rt[:, :, 1], w_ray, -w_ray]
    # Priors, one row each: s_0 at the datum; the Ornstein-Uhlenbeck links s_j - a s_{j-1};
    # each height about the seabed under the camera at its first frame.
    r0 = 2 * k_obs
    a = np.exp(-np.diff(t_s) / priors.seabed_offset_tau_s)
    sq = priors.seabed_offset_sigma_m * np.sqrt(np.maximum(1.0 - a * a, 1e-12))
    links = r0 + 1 + np.arange(n - 1)
    heights = r0 + n + np.arange(m)
    sig_h = priors.landmark_height_sigma_m
    r_list += [np.array([r0]), links, links, heights, heights]
    c_list += [np.array([col_s]), col_s + 1 + np.arange(n - 1), col_s + np.arange(n - 1), col_h + np.arange(m)]
    c_list.append(col_s + obs.first_pose)
    v_list += [np.array([1.0 / _DATUM_SIGMA_M]), 1.0 / sq, -a / sq, np.full(m, 1.0 / sig_h), np.full(m, -1.0 / sig_h)]
    n_rows, n_cols = r0 + n + m, 3 * m + n
    a_mat = sp.csr_matrix(
        (
            np.concatenate([v.ravel() for v in v_list]),
            (np.concatenate([r.ravel() for r in r_list]), np.concatenate([c.ravel() for c in c_list])),
        ),
        shape=(n_rows, n_cols),
    )
    b = np.zeros(n_rows)
    b[:r0] = rhs_obs.ravel()
    sol = spl.spsolve((a_mat.T @ a_mat).tocsc(), a_mat.T @ b)
    return ReliefSolution(landmarks_xy_m=sol[: 2 * m].reshape(m, 2), height_m=sol[col_h:col_s], seabed_m=sol[col_s:])
