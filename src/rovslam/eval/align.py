"""Matching a run's frames to another record of the same dive by time (ground truth, sequence rows).

Its own module so that the metrics and the baselines both use it without importing each other.
"""

from __future__ import annotations

import numpy as np

from rovslam.errors import SequenceFormatError

__all__ = ["align_by_time"]


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
