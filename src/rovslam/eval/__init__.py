"""Evaluation against ground truth: trajectory errors, consistency, revisit table, baselines."""

from rovslam.eval.baselines import frame_shifts_px, integrate_shifts, phase_correlation_path
from rovslam.eval.metrics import (
    Consistency,
    Evaluation,
    RevisitRow,
    TrajectoryErrors,
    consistency,
    error_jump_before_sigma,
    error_jump_sigma,
    evaluate,
    evaluate_run,
    nees,
    revisit_table,
    trajectory_errors,
)

__all__ = [
    "Consistency",
    "Evaluation",
    "RevisitRow",
    "TrajectoryErrors",
    "consistency",
    "error_jump_before_sigma",
    "error_jump_sigma",
    "evaluate",
    "evaluate_run",
    "frame_shifts_px",
    "integrate_shifts",
    "nees",
    "phase_correlation_path",
    "revisit_table",
    "trajectory_errors",
]
