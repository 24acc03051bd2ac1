"""Evaluation against ground truth: trajectory errors, consistency, revisit table."""

from rovslam.eval.metrics import consistency, evaluate, nees, revisit_table, trajectory_errors

__all__ = ["consistency", "evaluate", "nees", "revisit_table", "trajectory_errors"]
