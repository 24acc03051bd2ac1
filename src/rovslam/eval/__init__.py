"""Evaluation against ground truth: trajectory errors, consistency, revisit table, baselines."""

from rovslam.eval.baselines import (
    frame_shifts_px,
    integrate_shifts,
    phase_correlation_path,
)
from rovslam.eval.metrics import (
    AltitudeErrors,
    Consistency,
    Evaluation,
    RevisitRow,
    SpeedConsistency,
    TrajectoryErrors,
    altitude_errors,
    consistency,
    error_jump_before_sigma,
    error_jump_sigma,
    evaluate,
    evaluate_run,
    nees,
    revisit_table,
    speed_consistency,
    trajectory_errors,
    true_body_speed_mps,
)

__all__ = [
    "AltitudeErrors",
    "Consistency",
    "Evaluation",
    "RevisitRow",
    "SpeedConsistency",
    "TrajectoryErrors",
    "altitude_errors",
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
    "speed_consistency",
    "trajectory_errors",
    "true_body_speed_mps",
]
