"""Trajectory errors, filter consistency and the revisit table (the paper's Table 1).

Pure functions on arrays. Trajectories are metric and start at the origin, so they are
compared as they are: no alignment.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.stats import chi2

from rovslam.errors import SequenceFormatError
from rovslam.io.results import RunResults
from rovslam.io.sequence import GroundTruth

_COV_FLOOR_M2 = 1e-12  # the start is known exactly; keep P invertible there


@dataclass(frozen=True)
class TrajectoryErrors:
    """Absolute and relative errors of one trajectory against the truth (metres)."""

    ate_rmse_m: float
    ate_mean_m: float
    ate_median_m: float
    ate_max_m: float
    final_error_m: float
    distance_m: float
    final_error_pct: float  # final error as a percentage of the distance travelled
    relative_error_m_per_m: float  # RMS drift per metre over segments of `segment_m`
    relative_error_pct: float
    segment_m: float


def align_by_time(t_est_s: np.ndarray, t_gt_s: np.ndarray, tol_s: float = 1e-4) -> np.ndarray:
    """Index into ``t_gt_s`` of the row at each ``t_est_s`` (same clock). (N,) int."""
    idx = np.clip(np.searchsorted(t_gt_s, t_est_s), 0, len(t_gt_s) - 1)
    prev = np.clip(idx - 1, 0, len(t_gt_s) - 1)
    better = np.abs(t_gt_s[prev] - t_est_s) < np.abs(t_gt_s[idx] - t_est_s)
    idx = np.where(better, prev, idx)
    gap = np.abs(t_gt_s[idx] - t_est_s)
    if len(gap) and float(gap.max()) > tol_s:
        k = int(np.argmax(gap))
        raise SequenceFormatError(
            f"ground truth has no row at t_s={t_est_s[k]:.6f} (nearest {t_gt_s[idx[k]]:.6f}); "
            "give the groundtruth.csv of the sequence that was run."
        )
    return idx


def path_length_m(xy_m: np.ndarray) -> np.ndarray:
    """(N,) cumulative distance along an (N, 2) path."""
    steps = np.linalg.norm(np.diff(xy_m, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def trajectory_errors(est_xy_m: np.ndarray, gt_xy_m: np.ndarray, segment_m: float = 1.0) -> TrajectoryErrors:
    """ATE statistics and relative drift of ``est_xy_m`` (N, 2) against ``gt_xy_m`` (N, 2)."""
    err = np.linalg.norm(est_xy_m - gt_xy_m, axis=1)
    dist = path_length_m(gt_xy_m)
    total = float(dist[-1]) if len(dist) else 0.0
    # Relative error: for every start frame, the frame `segment_m` further along the true path.
    rel = []
    if total > segment_m:
        ends = np.searchsorted(dist, dist + segment_m)
        ok = ends < len(dist)
        starts = np.nonzero(ok)[0]
        ends = ends[ok]
        d_est = est_xy_m[ends] - est_xy_m[starts]
        d_gt = gt_xy_m[ends] - gt_xy_m[starts]
        seg_len = dist[ends] - dist[starts]
        rel = np.linalg.norm(d_est - d_gt, axis=1) / seg_len
    rel_rms = float(np.sqrt(np.mean(np.square(rel)))) if len(rel) else math.nan
    final = float(err[-1]) if len(err) else math.nan
    return TrajectoryErrors(
        ate_rmse_m=float(np.sqrt(np.mean(err**2))),
        ate_mean_m=float(np.mean(err)),
        ate_median_m=float(np.median(err)),
        ate_max_m=float(np.max(err)),
        final_error_m=final,
        distance_m=total,
        final_error_pct=100.0 * final / total if total > 0 else math.nan,
        relative_error_m_per_m=rel_rms,
        relative_error_pct=100.0 * rel_rms,
        segment_m=segment_m,
    )


def nees(err_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared e^T P^-1 e per frame. (N, 2), (N, 2, 2) -> (N,)."""
    P = cov_m2 + _COV_FLOOR_M2 * np.eye(2)
    return np.einsum("ni,nij,nj->n", err_m, np.linalg.inv(P), err_m)


@dataclass(frozen=True)
class Consistency:
    coverage_2sigma: float  # fraction of frames whose truth is inside the 2-sigma ellipse
    nees_mean: float
    nees_median: float
    nees_in_95_interval: float  # fraction of frames with NEES inside the 2-dof 95 % interval
    nees_95_interval: tuple[float, float]


def consistency(err_m: np.ndarray, cov_m2: np.ndarray) -> Consistency:
    """2-sigma coverage (Mahalanobis distance <= 2) and NEES statistics (2 dof)."""
    e = nees(err_m, cov_m2)
    lo, hi = float(chi2.ppf(0.025, 2)), float(chi2.ppf(0.975, 2))
    return Consistency(
        coverage_2sigma=float(np.mean(e <= 4.0)),
        nees_mean=float(np.mean(e)),
        nees_median=float(np.median(e)),
        nees_in_95_interval=float(np.mean((e >= lo) & (e <= hi))),
        nees_95_interval=(lo, hi),
    )


def revisit_table(
    results: RunResults, gt_xy_m: np.ndarray, landmark_id: int = 0, gap_s: float = 2.0
) -> list[dict[str, float]]:
    """The paper's Table 1 for one landmark: its initialisation and each later passage.

    A passage is a run of accepted observations with gaps shorter than ``gap_s``; its first
    frame is reported with the estimated position and the true one, both as displacements
    from the vehicle position when the landmark was initialised (as in the paper).
    ``gt_xy_m`` is (N, 2), aligned with the trajectory rows.
    """
    obs = results.observations
    if not obs or len(obs.get("landmark_id", [])) == 0:
        return []
    sel = (obs["landmark_id"] == landmark_id) & (obs["accepted"] > 0)
    times = obs["t_s"][sel]
    if len(times) == 0:
        return []
    starts = [times[0]] + [t for t0, t in zip(times[:-1], times[1:]) if t - t0 > gap_s]
    t_traj = results.t_s
    est = results.xy_m
    k0 = int(np.argmin(np.abs(t_traj - starts[0])))
    rows = []
    for t in starts:
        k = int(np.argmin(np.abs(t_traj - t)))
        rows.append(
            {
                "t_s": float(t),
                "x_est_m": float(est[k, 0] - est[k0, 0]),
                "y_est_m": float(est[k, 1] - est[k0, 1]),
                "x_gt_m": float(gt_xy_m[k, 0] - gt_xy_m[k0, 0]),
                "y_gt_m": float(gt_xy_m[k, 1] - gt_xy_m[k0, 1]),
                "sigma_x_m": float(math.sqrt(max(results.trajectory["var_x_m2"][k], 0.0))),
                "sigma_y_m": float(math.sqrt(max(results.trajectory["var_y_m2"][k], 0.0))),
            }
        )
    return rows


def evaluate(results: RunResults, gt: GroundTruth, segment_m: float = 1.0) -> dict:
    """All figures of ``rovslam eval``: SLAM and dead reckoning, consistency, Table 1."""
    idx = align_by_time(results.t_s, gt.t_s)
    gt_xy = gt.xy_m[idx]
    est = results.xy_m
    slam = trajectory_errors(est, gt_xy, segment_m)
    dr = trajectory_errors(results.dr_xy_m, gt_xy, segment_m)
    cons = consistency(est - gt_xy, results.cov_m2)
    skipped = results.trajectory.get("skipped")
    lm = results.landmarks
    return {
        "frames": int(len(est)),
        "duration_s": float(results.t_s[-1] - results.t_s[0]) if len(est) else 0.0,
        "skipped_frames": int(np.nansum(skipped)) if skipped is not None else 0,
        "landmarks": int(len(lm.get("id", []))),
        "slam": asdict(slam),
        "dead_reckoning": asdict(dr),
        "dead_reckoning_over_slam_rmse": dr.ate_rmse_m / slam.ate_rmse_m if slam.ate_rmse_m > 0 else math.inf,
        "consistency": asdict(cons),
        "table1_landmark0": revisit_table(results, gt_xy, 0),
    }
