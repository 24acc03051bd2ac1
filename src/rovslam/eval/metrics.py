"""Trajectory errors, filter consistency and the revisit table (the paper's Table 1).

Pure functions on arrays. Trajectories are metric and start at the origin, so they are
compared as they are: no alignment. :func:`evaluate` returns an :class:`Evaluation`, frozen
dataclasses all the way down; ``Evaluation.to_dict()`` is what ``eval.json`` holds.

A figure a run is too short for (the error jump of a one-frame run, the error per distance
of a run that did not move) is ``None``, never NaN, and ``Evaluation.notes`` says why.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from rovslam.camera import rot2, step_mean_heading_rad
from rovslam.core import GroundTruth
from rovslam.errors import InvalidArgumentError, ResultsFormatError, SequenceFormatError
from rovslam.eval.align import align_by_time
from rovslam.io.run_results import RunResults, failure_of_run

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
    final_error_pct: float | None  # final error as a percentage of the distance travelled; None: did not move
    relative_error_m_per_m: float | None  # RMS drift per metre over segments of `segment_m`; None: path shorter
    relative_error_pct: float | None
    segment_m: float
    heading_offset_rad: float = 0.0  # the turn about the start that best fits the path to the truth
    ate_heading_aligned_rmse_m: float = 0.0  # the ATE RMSE with that turn taken out: the path's shape


def path_length_m(xy_m: np.ndarray) -> np.ndarray:
    """(N,) cumulative distance along an (N, 2) path."""
    steps = np.linalg.norm(np.diff(xy_m, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def heading_alignment(est_xy_m: np.ndarray, gt_xy_m: np.ndarray) -> tuple[float, np.ndarray]:
    """The turn about the start that lays an (N, 2) path best onto the (N, 2) truth, and the path so turned.

    Both paths start at the origin. Returns ``(theta_rad, (N, 2) est turned by -theta)`` with theta
    minimising ``sum |R(-theta) est_k - gt_k|^2`` (the estimate's heading minus the truth's, over the
    whole path). Only a compass fixes this turn: with a drifting one, a map right in its shape is still
    turned by the compass's error averaged over the dive, and the ATE carries it at every distance from
    the start. The error left after it, the ATE of the turned path, is the map's shape (0 for a path
    that did not move).
    """
    e, g = np.asarray(est_xy_m, dtype=np.float64), np.asarray(gt_xy_m, dtype=np.float64)
    theta = math.atan2(float(np.sum(g[:, 0] * e[:, 1] - g[:, 1] * e[:, 0])), float(np.sum(g * e)))
    return theta, e @ rot2(theta)  # row-wise R(-theta) e


def trajectory_errors(est_xy_m: np.ndarray, gt_xy_m: np.ndarray, segment_m: float = 1.0) -> TrajectoryErrors:
    """ATE statistics and relative drift of ``est_xy_m`` (N, 2) against ``gt_xy_m`` (N, 2), N >= 1."""
    if est_xy_m.shape != gt_xy_m.shape or est_xy_m.ndim != 2 or est_xy_m.shape[1] != 2 or len(est_xy_m) == 0:
        raise InvalidArgumentError(f"need two (N, 2) paths, N >= 1, got {est_xy_m.shape} and {gt_xy_m.shape}")
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
    rel_rms = float(np.sqrt(np.mean(np.square(rel)))) if len(rel) else None
    final = float(err[-1])
    theta, turned = heading_alignment(est_xy_m, gt_xy_m)
    return TrajectoryErrors(
        ate_rmse_m=float(np.sqrt(np.mean(err**2))),
        ate_mean_m=float(np.mean(err)),
        ate_median_m=float(np.median(err)),
        ate_max_m=float(np.max(err)),
        final_error_m=final,
        distance_m=total,
        final_error_pct=100.0 * final / total if total > 0 else None,
        relative_error_m_per_m=rel_rms,
        relative_error_pct=None if rel_rms is None else 100.0 * rel_rms,
        segment_m=segment_m,
        heading_offset_rad=theta,
        ate_heading_aligned_rmse_m=float(np.sqrt(np.mean(np.sum((turned - gt_xy_m) ** 2, axis=1)))),
    )


def nees(err_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared e^T P^-1 e per frame. (N, 2), (N, 2, 2) -> (N,)."""
    P = cov_m2 + _COV_FLOOR_M2 * np.eye(2)
    return np.einsum("ni,nij,nj->n", err_m, np.linalg.inv(P), err_m)


def error_jump_sigma(err_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Frame-to-frame jump of the error in sigmas of the reported ellipse. (N, 2), (N, 2, 2) -> (N-1,).

    ``j_k = sqrt(de_k^T P_k^-1 de_k)`` with ``de_k = e_k - e_(k-1)`` the change of the position
    error from frame k-1 to frame k and ``P_k`` the position covariance reported at frame k.
    A filter whose error drifts smoothly has jumps far below 1; a landmark that pulls the
    estimate to a wrong place in one update shows as a jump of several sigmas.
    """
    return _sigmas(np.diff(err_m, axis=0), cov_m2[1:])


def error_jump_before_sigma(err_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """Frame-to-frame jump of the error in sigmas of the ellipse claimed *before* it. (N, 2), (N, 2, 2) -> (N-1,).

    ``j_k = sqrt(de_k^T B_k^-1 de_k)`` with ``B_k = P_(k-1) + [P_k - P_(k-1)]_+`` (the positive
    part: along each axis, the larger of the two ellipses). :func:`error_jump_sigma` judges the
    change against the ellipse *after* it, which also counts a correct correction as a jump: a
    landmark seen again that removes an error of 0.8 sigma while the ellipse shrinks five times is a
    "4 sigma jump" there. Here that correction is 0.8, and a match that pulls the estimate to a
    wrong place is as large as before (the ellipse does not grow to meet it). For a consistent
    filter the estimate's change at an update has covariance ``P^- - P^+ <= P^-``, so this is the
    test of the claim a pilot saw. The positive part keeps the start (``P_0 = 0``) and a
    covariance that grows in a step judged against what the step itself allowed.
    """
    before, after = cov_m2[:-1], cov_m2[1:]
    w, v = np.linalg.eigh(after - before)  # (N-1, 2), (N-1, 2, 2)
    grow = np.einsum("nij,nj,nkj->nik", v, np.maximum(w, 0.0), v)
    return _sigmas(np.diff(err_m, axis=0), before + grow)


def _sigmas(de_m: np.ndarray, cov_m2: np.ndarray) -> np.ndarray:
    """``sqrt(de^T P^-1 de)`` per row: (K, 2) changes in sigmas of (K, 2, 2) covariances (floored)."""
    P = cov_m2 + _COV_FLOOR_M2 * np.eye(2)
    return np.sqrt(np.einsum("ni,nij,nj->n", de_m, np.linalg.inv(P), de_m))


@dataclass(frozen=True)
class Consistency:
    """How well the reported 2x2 position covariance describes the actual error (2 dof)."""

    coverage_2sigma: float  # fraction of frames whose truth is inside the 2-sigma ellipse
    nees_mean: float  # mean of e^T P^-1 e over the frames (2 for a consistent filter)
    nees_median: float
    nees_in_95_interval: float  # fraction of frames with NEES inside the 2-dof 95 % interval
    nees_95_interval: tuple[float, float]
    max_error_jump_sigma: float | None = None  # largest :func:`error_jump_sigma`; None: one frame
    max_error_jump_t_s: float | None = None  # when it happened (time of the later frame)
    max_error_jump_before_sigma: float | None = None  # largest :func:`error_jump_before_sigma`; None: one frame
    max_error_jump_before_t_s: float | None = None


def consistency(err_m: np.ndarray, cov_m2: np.ndarray, t_s: np.ndarray | None = None) -> Consistency:
    """2-sigma coverage (Mahalanobis distance <= 2), NEES statistics (2 dof) and the largest error jump.

    ``err_m`` (N, 2) estimate minus truth, ``cov_m2`` (N, 2, 2), ``t_s`` (N,) the frame times.
    """
    e = nees(err_m, cov_m2)
    lo, hi = float(chi2.ppf(0.025, 2)), float(chi2.ppf(0.975, 2))
    jump = jump_t = before = before_t = None
    if len(err_m) >= 2:
        jump, jump_t = _largest(error_jump_sigma(err_m, cov_m2), t_s)
        before, before_t = _largest(error_jump_before_sigma(err_m, cov_m2), t_s)
    return Consistency(
        coverage_2sigma=float(np.mean(e <= 4.0)),
        nees_mean=float(np.mean(e)),
        nees_median=float(np.median(e)),
        nees_in_95_interval=float(np.mean((e >= lo) & (e <= hi))),
        nees_95_interval=(lo, hi),
        max_error_jump_sigma=jump,
        max_error_jump_t_s=jump_t,
        max_error_jump_before_sigma=before,
        max_error_jump_before_t_s=before_t,
    )


def true_body_speed_mps(xy_m: np.ndarray, heading_rad: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """The true mean surge and sway over each step. (N, 2), (N,), (N,) -> (N-1, 2) metres per second.

    Step k (from row k to row k+1) is the world displacement turned into the body frame of the
    mean heading of its two rows (taken on the circle), over the step's duration: what the
    odometry's ``surge_mps, sway_mps`` of row k+1 measure. A step of zero or negative duration is NaN.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    psi = np.asarray(heading_rad, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or psi.shape != (len(xy),) or t.shape != (len(xy),):
        raise InvalidArgumentError(
            f"need (N, 2) positions and (N,) headings and times, got {xy.shape}, {psi.shape}, {t.shape}"
        )
    d = np.diff(xy, axis=0)
    mid = step_mean_heading_rad(psi)
    c, s = np.cos(mid), np.sin(mid)
    body = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])  # R(psi)^T d
    dt = np.diff(t)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((dt > 0)[:, None], body / dt[:, None], np.nan)


@dataclass(frozen=True)
class SpeedConsistency:
    """How well the odometry's reported covariance Q (1) describes the speed's actual error (2 dof, per step).

    Only the steps the tokens measured (``speed_ok``; a held speed is no measurement) between two
    processed frames count.
    """

    steps: int  # steps judged
    nees_mean: float  # mean of e^T Q^-1 e over those steps (2 for a consistent Q)
    nees_median: float
    coverage_2sigma: float  # fraction of steps whose true speed is inside the 2-sigma ellipse of Q
    rms_error_mps: tuple[float, float]  # RMS error of (surge, sway)
    rms_sigma_mps: tuple[float, float]  # the sigma Q claimed: sqrt of the mean reported variance of (surge, sway)


def speed_consistency(err_mps: np.ndarray, cov_mps2: np.ndarray) -> SpeedConsistency:
    """:class:`SpeedConsistency` of ``(K, 2)`` speed errors (measured - true) with their ``(K, 2, 2)`` covariances."""
    e = np.asarray(err_mps, dtype=np.float64)
    q = np.asarray(cov_mps2, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 2 or q.shape != (len(e), 2, 2) or len(e) == 0:
        raise InvalidArgumentError(
            f"need (K, 2) errors and (K, 2, 2) covariances with K >= 1, got {e.shape}, {q.shape}"
        )
    n = nees(e, q)
    return SpeedConsistency(
        steps=int(len(e)),
        nees_mean=float(np.mean(n)),
        nees_median=float(np.median(n)),
        coverage_2sigma=float(np.mean(n <= 4.0)),
        rms_error_mps=(float(np.sqrt(np.mean(e[:, 0] ** 2))), float(np.sqrt(np.mean(e[:, 1] ** 2)))),
        rms_sigma_mps=(float(np.sqrt(np.mean(q[:, 0, 0]))), float(np.sqrt(np.mean(q[:, 1, 1])))),
    )


def _speed_consistency(results: RunResults, gt: GroundTruth, idx: np.ndarray) -> SpeedConsistency | None:
    """The measured steps of a run against the truth; None when trajectory.csv has no speed covariance or no measured step."""
    tr = results.trajectory
    q = results.speed_cov_mps2
    if q is None or any(k not in tr for k in ("surge_mps", "sway_mps", "speed_ok")) or len(results.t_s) < 2:
        return None
    truth = true_body_speed_mps(gt.xy_m[idx], gt.heading_rad[idx], results.t_s)
    meas = np.column_stack([tr["surge_mps"], tr["sway_mps"]])[1:]
    q = q[1:]
    use = np.asarray(tr["speed_ok"])[1:] > 0
    skipped = tr.get("skipped")
    if skipped is not None:
        use &= (np.asarray(skipped)[1:] == 0) & (np.asarray(skipped)[:-1] == 0)
    use &= np.all(np.isfinite(truth), axis=1) & np.all(np.isfinite(meas), axis=1)
    use &= np.all(np.isfinite(q.reshape(-1, 4)), axis=1) & (q[:, 0, 0] > 0) & (q[:, 1, 1] > 0)
    use &= q[:, 0, 0] * q[:, 1, 1] - q[:, 0, 1] ** 2 > 0
    if not np.any(use):
        return None
    return speed_consistency(meas[use] - truth[use], q[use])


@dataclass(frozen=True)
class AltitudeErrors:
    """The run's altitude against the truth's distance from the camera down to the seabed.

    Over relief (a ground truth with ``relief_m``) the truth is the seabed under the camera,
    ``altitude_m - relief_m``: what an altimeter should read there. Without that column it is
    the truth's ``altitude_m``.
    """

    frames: int  # frames with a measured altitude
    median_error_pct: float  # median |measured - true| / true, per cent
    p95_error_pct: float  # its 95th percentile
    mean_error_pct: float  # mean (measured - true) / true, per cent: the lasting part
    truth: str  # "seabed under the camera" or "altitude_m"


def altitude_errors(measured_m: np.ndarray, true_m: np.ndarray, truth: str) -> AltitudeErrors | None:
    """:class:`AltitudeErrors` of ``(N,)`` measured altitudes (NaN or <= 0: none) against ``(N,)`` true ones."""
    measured_m, true_m = np.asarray(measured_m, dtype=np.float64), np.asarray(true_m, dtype=np.float64)
    use = np.isfinite(measured_m) & (measured_m > 0) & np.isfinite(true_m) & (true_m > 0)
    if not np.any(use):
        return None
    rel = 100.0 * (measured_m[use] / true_m[use] - 1.0)
    return AltitudeErrors(
        frames=int(np.count_nonzero(use)),
        median_error_pct=float(np.median(np.abs(rel))),
        p95_error_pct=float(np.percentile(np.abs(rel), 95.0)),
        mean_error_pct=float(np.mean(rel)),
        truth=truth,
    )


def _altitude_errors(results: RunResults, gt: GroundTruth, idx: np.ndarray) -> AltitudeErrors | None:
    measured = results.trajectory.get("altitude_m")
    if measured is None:
        return None
    if gt.relief_m is not None:
        return altitude_errors(measured, gt.altitude_m[idx] - gt.relief_m[idx], "seabed under the camera")
    return altitude_errors(measured, gt.altitude_m[idx], "altitude_m")


def _largest(jumps: np.ndarray, t_s: np.ndarray | None) -> tuple[float, float | None]:
    """The largest frame-to-frame jump (N-1,) and the time of the frame after it."""
    k = int(np.argmax(jumps))
    return float(jumps[k]), (float(t_s[k + 1]) if t_s is not None else None)


@dataclass(frozen=True)
class RevisitRow:
    """One row of the paper's Table 1: displacements since the landmark's initialisation (metres)."""

    t_s: float
    x_est_m: float
    y_est_m: float
    x_gt_m: float
    y_gt_m: float
    sigma_x_m: float
    sigma_y_m: float


def revisit_table(
    results: RunResults, gt_xy_m: np.ndarray, landmark_id: int = 0, gap_s: float = 2.0
) -> tuple[RevisitRow, ...]:
    """The paper's Table 1 for one landmark: its initialisation and each later passage.

    A passage is a run of accepted observations with gaps shorter than ``gap_s``; its first
    frame is reported with the estimated position and the true one, both as displacements
    from the vehicle position when the landmark was initialised (as in the paper).
    ``gt_xy_m`` is (N, 2), aligned with the trajectory rows.
    """
    obs = results.observations
    if not obs or len(obs.get("landmark_id", [])) == 0:
        return ()
    sel = (obs["landmark_id"] == landmark_id) & (obs["accepted"] > 0)
    times = obs["t_s"][sel]
    if len(times) == 0:
        return ()
    starts = [times[0]] + [t for t0, t in zip(times[:-1], times[1:]) if t - t0 > gap_s]
    t_traj = results.t_s
    est = results.xy_m
    k0 = int(np.argmin(np.abs(t_traj - starts[0])))
    rows = []
    for t in starts:
        k = int(np.argmin(np.abs(t_traj - t)))
        rows.append(
            RevisitRow(
                t_s=float(t),
                x_est_m=float(est[k, 0] - est[k0, 0]),
                y_est_m=float(est[k, 1] - est[k0, 1]),
                x_gt_m=float(gt_xy_m[k, 0] - gt_xy_m[k0, 0]),
                y_gt_m=float(gt_xy_m[k, 1] - gt_xy_m[k0, 1]),
                sigma_x_m=float(math.sqrt(max(results.trajectory["var_x_m2"][k], 0.0))),
                sigma_y_m=float(math.sqrt(max(results.trajectory["var_y_m2"][k], 0.0))),
            )
        )
    return tuple(rows)


@dataclass(frozen=True)
class Evaluation:
    """Everything ``rovslam eval`` reports on one run against its ground truth."""

    frames: int
    duration_s: float
    skipped_frames: int
    landmarks: int
    slam: TrajectoryErrors
    dead_reckoning: TrajectoryErrors  # rovslam's own speed integrated with the heading, no landmarks
    consistency: Consistency
    table1_landmark0: tuple[RevisitRow, ...]
    phase_correlation: TrajectoryErrors | None = None  # frame-to-frame cv2.phaseCorrelate baseline, if computed
    notes: tuple[str, ...] = ()  # why a figure is None
    smoothed: TrajectoryErrors | None = None  # the smoothed path (trajectory_smoothed.csv), if the run was smoothed
    smoothed_consistency: Consistency | None = None  # its marginal covariances against the truth
    run_frame_turn_rad: float = 0.0  # a run without compass: the ground truth was turned by this into its frame
    partial_run: str | None = None  # how a run that stopped before its end stopped (interrupted, unusable, failed)
    groundtruth_shift_m: tuple[float, float] = (
        0.0,
        0.0,
    )  # a ground truth not starting at x = y = 0: its first row, subtracted
    speed: SpeedConsistency | None = (
        None  # the odometry's Q against the true speed, per measured step (None: no Q in trajectory.csv)
    )
    altitude: AltitudeErrors | None = None  # the measured altitude against the truth (None: no altitude)

    @property
    def dead_reckoning_over_slam_rmse(self) -> float | None:
        """ATE RMSE of dead reckoning / SLAM (None when SLAM's is 0)."""
        return _ratio(self.dead_reckoning.ate_rmse_m, self.slam.ate_rmse_m)

    @property
    def phase_correlation_over_slam_rmse(self) -> float | None:
        """ATE RMSE of the phase-correlation baseline / SLAM (None when not computed or SLAM's is 0)."""
        pc = self.phase_correlation
        return None if pc is None else _ratio(pc.ate_rmse_m, self.slam.ate_rmse_m)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (the keys of eval.json; None where a figure is undefined, never NaN)."""
        d = asdict(self)
        d["dead_reckoning_over_slam_rmse"] = self.dead_reckoning_over_slam_rmse
        d["phase_correlation_over_slam_rmse"] = self.phase_correlation_over_slam_rmse
        d["consistency"]["nees_95_interval"] = list(self.consistency.nees_95_interval)
        d["table1_landmark0"] = [asdict(r) for r in self.table1_landmark0]
        if self.smoothed_consistency is not None:
            d["smoothed_consistency"]["nees_95_interval"] = list(self.smoothed_consistency.nees_95_interval)
        d["notes"] = list(self.notes)
        return finite_or_none(d)


def _ratio(a: float, b: float) -> float | None:
    return a / b if b > 0 and math.isfinite(a) else None


def finite_or_none(o: Any) -> Any:
    """``o`` (nested dicts, lists, numbers) with every NaN or infinite float replaced by None (JSON null)."""
    if isinstance(o, dict):
        return {k: finite_or_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [finite_or_none(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def _notes(frames: int, slam: TrajectoryErrors) -> tuple[str, ...]:
    notes = []
    if frames < 2:
        notes.append("one frame only: no frame-to-frame error jump")
    if slam.final_error_pct is None:
        notes.append("the vehicle did not move: no error as a percentage of the distance")
    if slam.relative_error_m_per_m is None:
        notes.append(
            f"the path ({slam.distance_m:.2f} m) is shorter than one {slam.segment_m:g} m segment: no drift per metre"
        )
    return tuple(notes)


def groundtruth_start_m(gt: GroundTruth, first_row: int = 0, tol_m: float = 1e-6) -> np.ndarray:
    """(2,) the ground truth's position at the run's first frame (row ``first_row``) when it is not the origin, else zeros.

    A run starts at x = y = 0 at its first frame; its truth is compared from the same point, as a run
    without compass is compared in its own turned frame (:func:`run_frame_turn_rad`). The truth may be
    in another frame (UTM, a survey's), or the run may begin after the truth does (a live run joins a
    stream already running; ``run --start``).
    """
    first = gt.xy_m[first_row]
    return first if float(np.max(np.abs(first))) > tol_m else np.zeros(2)


def partial_run(summary: dict[str, Any], frames: int) -> str | None:
    """What a run that did not complete covers (from its summary.json), or None for a complete run."""
    status = summary.get("status")
    how = {
        "interrupted": f"interrupted by {summary.get('signal') or 'a signal'}",
        "unusable": "judged unusable",
        "failed": f"stopped by an error ({failure_of_run(summary)})",
        "running": "cut off (summary.json still says running: killed or a power loss)",
    }
    if status not in how:
        return None
    total = summary.get("frames_in_sequence")
    of = f" of {total}" if isinstance(total, int) and total > 0 else ""
    return f"the run was {how[status]} after {frames}{of} frames: these figures cover those {frames} frames only"


def run_frame_turn_rad(results: RunResults, gt_heading_at_first_rad: float) -> float:
    """The angle from the ground truth's world frame to the run's, in radians; 0 for a run with a compass.

    Without a compass on any frame, the run's heading is the tokens' turn integrated from 0 at
    its first frame: its x axis is the vehicle's first heading, not north. The turn is then
    the ground truth's heading at the run's first frame (``gt_heading_at_first_rad``) minus
    the run's own there.
    """
    run_heading = results.trajectory.get("heading_rad")
    if not results.without_compass or run_heading is None or len(run_heading) == 0:
        return 0.0
    d = float(gt_heading_at_first_rad - run_heading[0])
    return math.atan2(math.sin(d), math.cos(d)) if math.isfinite(d) else 0.0


def to_run_frame(xy_m: np.ndarray, turn_rad: float) -> np.ndarray:
    """``(N, 2)`` world positions in a frame turned by ``turn_rad`` (x towards y): ``R(turn)^T p`` per row."""
    if turn_rad == 0.0:
        return xy_m
    return np.asarray(xy_m) @ rot2(turn_rad)


def evaluate(
    results: RunResults,
    gt: GroundTruth,
    segment_m: float = 1.0,
    phase_correlation_xy_m: np.ndarray | None = None,
) -> Evaluation:
    """All figures of ``rovslam eval``: SLAM, dead reckoning, consistency, Table 1.

    ``phase_correlation_xy_m`` (N, 2), one row per trajectory row (see
    :func:`rovslam.eval.baselines.phase_correlation_path`), adds that baseline's errors.
    """
    est = results.xy_m
    if len(est) == 0:
        raise ResultsFormatError(f"{results.folder}: trajectory.csv has no rows; the run processed no frame.")
    idx = align_by_time(results.t_s, gt.t_s)
    turn = run_frame_turn_rad(results, float(gt.heading_rad[idx[0]]))
    start = groundtruth_start_m(gt, int(idx[0]))
    gt_xy = to_run_frame(gt.xy_m[idx] - start, turn)
    slam = trajectory_errors(est, gt_xy, segment_m)
    pc = None
    if phase_correlation_xy_m is not None:
        if np.shape(phase_correlation_xy_m) != est.shape:
            raise InvalidArgumentError(
                f"phase_correlation_xy_m must be {est.shape} (one row per trajectory row), got {np.shape(phase_correlation_xy_m)}"
            )
        pc = trajectory_errors(np.asarray(phase_correlation_xy_m, dtype=np.float64), gt_xy, segment_m)
    skipped = results.trajectory.get("skipped")
    sm = sm_cons = None
    if results.smoothed is not None:
        sm_gt = to_run_frame(gt.xy_m[align_by_time(results.smoothed["t_s"], gt.t_s)] - start, turn)
        sm = trajectory_errors(results.smoothed_xy_m, sm_gt, segment_m)  # type: ignore[arg-type]
        sm_cons = consistency(results.smoothed_xy_m - sm_gt, results.smoothed_cov_m2, results.smoothed["t_s"])  # type: ignore[arg-type]
    return Evaluation(
        frames=int(len(est)),
        duration_s=float(results.t_s[-1] - results.t_s[0]),
        skipped_frames=int(np.nansum(skipped)) if skipped is not None else 0,
        landmarks=int(len(results.landmarks.get("id", []))),
        slam=slam,
        dead_reckoning=trajectory_errors(results.dr_xy_m, gt_xy, segment_m),
        consistency=consistency(est - gt_xy, results.cov_m2, results.t_s),
        table1_landmark0=revisit_table(results, gt_xy, 0),
        phase_correlation=pc,
        notes=_notes(len(est), slam),
        smoothed=sm,
        smoothed_consistency=sm_cons,
        run_frame_turn_rad=turn,
        partial_run=partial_run(results.summary, int(len(est))),
        groundtruth_shift_m=(float(-start[0]), float(-start[1])),
        speed=_speed_consistency(results, gt, idx),
        altitude=_altitude_errors(results, gt, idx),
    )


def evaluate_run(
    results_dir: str | Path, groundtruth: str | Path, sequence_dir: str | Path | None = None, segment_m: float = 1.0
) -> Evaluation:
    """Read a ``rovslam run`` folder and a ``groundtruth.csv`` and :func:`evaluate` them.

    With ``sequence_dir`` (the sequence that was run) the phase-correlation baseline is
    computed on its images, scaled by the altitude the run measured.
    """
    from rovslam.io.run_results import read_results
    from rovslam.io.sequence import open_sequence, read_groundtruth

    results = read_results(results_dir)
    pc = None
    if sequence_dir is not None:
        from rovslam.eval.baselines import phase_correlation_path

        seq = open_sequence(sequence_dir)
        pc = phase_correlation_path(seq, results.trajectory.get("altitude_m"), results.t_s)
    truth = read_groundtruth(groundtruth)  # its errors name the file already
    try:
        return evaluate(results, truth, segment_m, pc)
    except SequenceFormatError as exc:  # the ground truth's times do not cover the run's
        raise SequenceFormatError(f"{groundtruth}: {exc}") from None
