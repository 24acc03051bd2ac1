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
    "PathSteps",
    "ReliefPriors",
    "ReliefObservations",
    "ReliefSolution",
    "solve_relief",
    "observation_depths",
    "robust_weight",
    "gross_outliers",
    "landmark_residuals",
    "whitened_norms",
]

# Sigma of the prior holding s_0 at the start's seabed (metres): the datum, as the EKF's zero variance.
_DATUM_SIGMA_M = 1e-4
# Under a robust loss, an observation this many times the loss's threshold off is a wrong association.
GROSS_OUTLIER_FACTOR = 10.0


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
class PathSteps:
    """The translation part of the odometry (1) as the smoother's graph holds it (N frames).

    Attributes:
        step_m: (N-1, 2) ``[u, v] dt`` of each step, in the frame of the pose before it.
        cov_m2: (N-1, 2, 2) its covariance ``dt^2 Q`` (positive definite).
    """

    step_m: np.ndarray
    cov_m2: np.ndarray


@dataclass(frozen=True)
class ReliefSolution:
    """What :func:`solve_relief` found.

    Attributes:
        landmarks_xy_m: (M, 2) landmark positions, world frame.
        height_m: (M,) the landmarks' heights above the start's seabed.
        seabed_m: (N,) s at every frame.
        xy_m: (N, 2) the positions: solved with the rest when the path's steps were given, else
            the ones held.
    """

    landmarks_xy_m: np.ndarray
    height_m: np.ndarray
    seabed_m: np.ndarray
    xy_m: np.ndarray


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


def gross_outliers(norm: np.ndarray, robust: str, robust_k: float, landmark: np.ndarray) -> np.ndarray:
    """(K,) bool: the observations whose whitened residual norms (K,) are ``GROSS_OUTLIER_FACTOR`` times
    the robust loss's threshold or more (none under least squares), of landmarks (K,) that keep another
    view (a landmark whose every view is that far off keeps them, under the loss: else nothing holds it).

    A bounded-influence loss (Huber) still pulls with ``robust_k`` sigmas however wrong the
    association: with the path's scale and the heights free together, one association 60 cm off
    moved the seabed offset at its frame by centimetres and the path by up to 3.7 mm (a survey
    smoothed to 1 mm). The relief step leaves these out of its solve and of the graph it rebuilds.
    """
    if robust == "none":
        return np.zeros(norm.shape, bool)
    gross = norm >= GROSS_OUTLIER_FACTOR * robust_k
    kept_views = np.bincount(landmark[~gross], minlength=int(landmark.max(initial=-1)) + 1)
    return gross & (kept_views[landmark] > 0)


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
    path: PathSteps | None = None,
) -> ReliefSolution:
    """Landmark positions, heights and the seabed offset that best explain (3), the headings held.

    Without ``path`` the positions are held too. With it, every position but the first is solved
    together with the rest, under the odometry's translation (``R(psi_{k-1})^T (x_k - x_{k-1})
    = [u, v] dt``, covariance ``dt^2 Q``), still linear once the headings are given: the path's
    scale and the heights, which trade along the motion, are found together rather than in turn.

    Args:
        xy_m: (N, 2) positions; heading_rad: (N,) headings; t_s: (N,) times; altitude_m: (N,) Z.
        landmarks_xy_m: (M, 2) the current landmark positions and depth_m: (K,) the current
            depths: they set the noise (``d^2 R_m / f^2``) and the robust weights.
        obs: the observations; priors: the relief priors.
        robust, robust_k: the graph's loss on the landmark factors ("huber", "cauchy" or "none")
            and its threshold in whitened sigmas.
        path: the odometry's steps (N-1 of them), or None to hold the positions.

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
    weight = np.sqrt(robust_weight(norm, robust, robust_k)) * ~gross_outliers(norm, robust, robust_k, obs.landmark)
    w_rt = np.einsum("kij,kjl->kil", w, rt) * weight[:, None, None]  # (K, 2, 2) on X_i
    w_ray = np.einsum("kij,kj->ki", w, obs.ray) * weight[:, None]  # (K, 2) on h_i (+), s_k (-)
    held = np.ones(k_obs, bool) if path is None else k == 0  # the observations whose pose is held
    rhs_obs = w_ray * altitude_m[k][:, None]
    rhs_obs[held] += np.einsum("kij,kj->ki", w_rt[held], xy_m[k[held]])
    # Unknowns: X (2M), then h (M), then s (N), then (with the path) x_1 .. x_{N-1} (2 (N-1)).
    col_h, col_s, col_x = 2 * m, 3 * m, 3 * m + n
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
    b_parts = [rhs_obs.ravel(), np.zeros(n + m)]
    if path is not None:
        free = ~held  # observations of x_1 .. x_{N-1}: -W R^T on their pose
        r_list += [rows_o[free], rows_o[free]]
        col_free = np.broadcast_to((col_x + 2 * (k[free] - 1))[:, None], (int(free.sum()), 2))
        c_list += [col_free, col_free + 1]
        v_list += [-w_rt[free][:, :, 0], -w_rt[free][:, :, 1]]
        rows, cols, vals, rhs = _odometry_rows(xy_m[0], heading_rad, path, n_rows, col_x)
        r_list += rows
        c_list += cols
        v_list += vals
        b_parts.append(rhs)
        n_rows, n_cols = n_rows + 2 * (n - 1), n_cols + 2 * (n - 1)
    a_mat = sp.csr_matrix(
        (
            np.concatenate([v.ravel() for v in v_list]),
            (np.concatenate([r.ravel() for r in r_list]), np.concatenate([c.ravel() for c in c_list])),
        ),
        shape=(n_rows, n_cols),
    )
    # Eliminated frame by frame (each frame's position and seabed offset, a band), the landmarks last: the
    # fill stays in the band and the landmarks' border (a 3,000-frame dive: 0.1 s a solve, against 6 s
    # for SuperLU's own ordering).
    order = _frames_then_landmarks(n, m, col_h, col_s, col_x, path is not None)
    normal = (a_mat.T @ a_mat)[order][:, order].tocsc()
    sol = np.empty(n_cols)
    sol[order] = spl.splu(normal, permc_spec="NATURAL", diag_pivot_thresh=0.0).solve(
        (a_mat.T @ np.concatenate(b_parts))[order]
    )
    xy = xy_m.copy()
    if path is not None:
        xy[1:] = sol[col_x:].reshape(n - 1, 2)
    return ReliefSolution(
        landmarks_xy_m=sol[: 2 * m].reshape(m, 2), height_m=sol[col_h:col_s], seabed_m=sol[col_s:col_x], xy_m=xy
    )


def _frames_then_landmarks(n: int, m: int, col_h: int, col_s: int, col_x: int, with_path: bool) -> np.ndarray:
    """(n_cols,) the unknowns' elimination order: per frame its position (from x_1) and seabed offset, then per
    landmark its position and height."""
    frames = [col_s + np.arange(n)[:, None]]
    if with_path:
        x = col_x + 2 * (np.arange(n) - 1)[:, None] + np.arange(2)[None, :]
        frames.insert(0, np.where(np.arange(n)[:, None] > 0, x, -1))
    per_frame = np.concatenate(frames, axis=1).ravel()
    landmarks = np.column_stack([2 * np.arange(m), 2 * np.arange(m) + 1, col_h + np.arange(m)]).ravel()
    return np.concatenate([per_frame[per_frame >= 0], landmarks])


def _odometry_rows(xy0_m: np.ndarray, heading_rad: np.ndarray, path: PathSteps, row0: int, col_x: int):
    """The whitened rows ``W R(psi_{k-1})^T (x_k - x_{k-1}) = W [u, v] dt`` of the N-1 steps, x_0 held.

    Returns (rows, columns, values) lists for the sparse matrix (from row ``row0``; ``x_k`` at
    column ``col_x + 2 (k - 1)``) and the (2 (N-1),) right-hand side.
    """
    n1 = len(path.step_m)
    c, s = np.cos(heading_rad[:-1]), np.sin(heading_rad[:-1])
    rt = np.stack([np.stack([c, s], 1), np.stack([-s, c], 1)], 1)  # (N-1, 2, 2) R(psi_{k-1})^T
    b = np.einsum("kij,kjl->kil", _whitening(path.cov_m2), rt)  # (N-1, 2, 2) on x_k (+), x_{k-1} (-)
    rhs = np.einsum("kij,kj->ki", _whitening(path.cov_m2), path.step_m)
    rhs[0] += b[0] @ xy0_m  # the first step starts from the held x_0
    rows = 2 * np.arange(n1)[:, None, None] + np.arange(2)[None, :, None] + row0  # (N-1, 2, 1)
    rows = np.broadcast_to(rows, (n1, 2, 2))
    cols_k = np.broadcast_to(col_x + 2 * np.arange(n1)[:, None, None] + np.arange(2)[None, None, :], (n1, 2, 2))
    out_r, out_c, out_v = [rows], [cols_k], [b]
    if n1 > 1:  # x_{k-1} of steps 2 .. N-1
        out_r.append(rows[1:])
        out_c.append(cols_k[:-1])
        out_v.append(-b[1:])
    return out_r, out_c, out_v, rhs.ravel()
