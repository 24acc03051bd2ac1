"""Which landmark matches the filter believes, and how it notices that it is the one that is wrong.

Beyond the paper, which takes every match its innovation gate lets through (step 6):

* :func:`jointly_compatible`: the landmarks matched in one frame share the vehicle's error, so
  their innovations are tested together (the joint NIS, chi-square with 2K degrees of
  freedom); while the set fails, the match with the largest share of the joint NIS is refused.
* :class:`RecoveryMonitor`: correct-looking matches (high correlation, confirmed landmarks)
  refused by the innovation test frame after frame, all telling the same vehicle offset, mean
  that the filter has become inconsistent (a wrong match, an odometry fault moved it outside
  its bounds), not that the matches are wrong. The monitor says when to recover: the vehicle
  covariance is inflated by the offset the matches tell, and they are admitted. A confirmed
  landmark expected in view but not found for several frames (the estimate may be farther off
  than the search window) is searched for in a wider window, with a stricter correlation.

Every refusal keeps its reason; every recovery is an event of the run.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from rovslam.config import AssociationConfig

__all__ = ["RecoveryEvent", "RecoveryMonitor", "jointly_compatible"]

REASON_GATE = "innovation test"
REASON_JOINT = "joint compatibility"
REASON_LASER = "laser spot inside the template"
REASON_DEAD = "tentative landmark refused twice"


def jointly_compatible(joint_nis, n: int, quantile: float) -> tuple[list[int], list[int]]:
    """Indices ``(kept, refused)`` of ``n`` matches after the joint compatibility test.

    ``joint_nis(indices) -> (total, shares)`` evaluates the joint NIS of a subset (see
    :meth:`rovslam.slam.EkfSlam.joint_nis`). While the subset's total exceeds the chi-square
    ``quantile`` with ``2 len(subset)`` degrees of freedom, the match with the largest share is
    refused. One match alone is always kept here (its own innovation test comes later).
    """
    kept = list(range(n))
    refused: list[int] = []
    while len(kept) > 1:
        total, share = joint_nis(kept)
        if total <= chi2.ppf(quantile, 2 * len(kept)):
            break
        refused.append(kept.pop(int(np.argmax(share))))
    return kept, refused


@dataclass(frozen=True)
class RecoveryEvent:
    """The filter found inconsistent with its own map and re-admitted to it."""

    frame: int
    t_s: float
    offset_m: tuple[float, float]  # the vehicle offset the refused matches told (world frame)
    landmarks: tuple[int, ...]
    cause: str  # "refused matches" | "landmarks lost"


@dataclass
class RecoveryMonitor:
    """Counts, frame by frame, the evidence that the filter (not the matches) is wrong."""

    config: AssociationConfig
    refused_streak: int = 0
    missed: dict[int, int] = field(default_factory=dict)  # confirmed landmark -> frames in a row expected, not found
    offsets: list[np.ndarray] = field(default_factory=list)  # vehicle offsets told during the streak
    events: list[RecoveryEvent] = field(default_factory=list)

    # At most this many landmarks are searched in the wide window per frame (it costs a millisecond each).
    MAX_WIDE_PER_FRAME = 2

    def wide_candidates(self, ids) -> set[int]:
        """Of the confirmed landmarks expected in view, those to search in the wide window this frame."""
        if not self.config.recovery:
            return set()
        lost = [i for i in ids if self.missed.get(int(i), 0) >= self.config.wide_search_after_frames]
        lost.sort(key=lambda i: -self.missed[int(i)])
        return {int(i) for i in lost[: self.MAX_WIDE_PER_FRAME]}

    def searched(self, landmark_id: int, accepted: bool) -> None:
        """A confirmed landmark expected in view (gate (5), inside the image) was accepted, or not (lost or refused)."""
        self.missed[landmark_id] = 0 if accepted else self.missed.get(landmark_id, 0) + 1

    def refusals(self, offsets_m: list[np.ndarray], accepted_older: bool) -> np.ndarray | None:
        """Step 6: the vehicle offsets (world, metres) told by this frame's strong refused matches.

        Returns the offset to recover by when the evidence is enough (``recovery_after_frames``
        frames in a row, or two landmarks agreeing now, all within
        ``recovery_offset_agreement_m``), else None. ``accepted_older``: a landmark older than
        the refused ones was accepted, so the estimate agrees with an older part of the map
        and the refused matches are the suspects: the streak ends. (Landmarks mapped since
        the estimate went wrong agree with it by construction: they are no evidence.)
        """
        cfg = self.config
        if not cfg.recovery or accepted_older or not offsets_m:
            self.refused_streak = 0
            self.offsets.clear()
            return None
        self.refused_streak += 1
        self.offsets.extend(np.asarray(o, dtype=np.float64) for o in offsets_m)
        window = np.array(self.offsets[-(cfg.recovery_after_frames * 4) :])
        centre = np.median(window, axis=0)
        agree = bool(np.all(np.linalg.norm(window - centre, axis=1) <= cfg.recovery_offset_agreement_m))
        if agree and (self.refused_streak >= cfg.recovery_after_frames or len(offsets_m) >= 2):
            return centre
        return None

    def recovered(self, event: RecoveryEvent) -> None:
        self.events.append(event)
        self.refused_streak = 0
        self.missed.clear()
        self.offsets.clear()
