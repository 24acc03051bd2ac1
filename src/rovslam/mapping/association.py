"""Which landmark matches the filter believes, and how it notices that it is the one that is wrong.

Beyond the paper, which takes every match its innovation gate lets through (step 6):

* :func:`jointly_compatible`: the landmarks matched in one frame share the vehicle's error, so
  their innovations are tested together (the joint NIS, chi-square with 2K degrees of
  freedom); while the set fails, the match with the largest share of the joint NIS is refused.
* :func:`associate`: the frame's matches, each with what the tests said of it
  (:class:`MatchCandidate`), in; one :class:`MatchDecision` per match out: accepted, or refused
  with its reason, and what it counts for (its landmark's record, the recovery monitor).
  :func:`strong_refusals` picks the matches that speak against the filter.
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

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.stats import chi2

from rovslam.camera import rot2
from rovslam.config import AssociationConfig
from rovslam.errors import InvalidArgumentError

__all__ = [
    "MatchCandidate",
    "MatchDecision",
    "RecoveryEvent",
    "RecoveryMonitor",
    "ToldOffset",
    "associate",
    "jointly_compatible",
    "recovery_inflation_m2",
    "strong_refusals",
    "told_offset_m",
]

REASON_GATE = "innovation test"
REASON_JOINT = "joint compatibility"
REASON_LASER = "laser spot inside the template"
REASON_DEAD = "tentative landmark refused twice"


@lru_cache(maxsize=64)
def _chi2_quantile(quantile: float, dof: int) -> float:
    """The chi-square ``quantile`` with ``dof`` degrees of freedom (scipy's, 0.1 ms a call: kept once per pair)."""
    return float(chi2.ppf(quantile, dof))


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
        if total <= _chi2_quantile(quantile, 2 * len(kept)):
            break
        refused.append(kept.pop(int(np.argmax(share))))
    return kept, refused


@dataclass(frozen=True)
class MatchCandidate:
    """One landmark match of a frame, with what was said of it before the decision (plain numbers).

    ``refused``: the reason it was refused before the filter's innovation test
    (:data:`REASON_LASER`, :data:`REASON_JOINT`), "" when the test ran on it; ``updated``,
    ``accepted``, ``nis``, ``innovation_px``: that test's outcome (the filter's update).
    """

    landmark_id: int
    confirmed: bool  # the landmark's state before this frame's observation is counted
    score: float  # the template's normalised correlation
    refused: str = ""
    updated: bool = False
    accepted: bool = False
    nis: float = math.nan
    innovation_px: np.ndarray | None = None  # (2,) [m, n] measured - predicted, when updated


@dataclass(frozen=True)
class MatchDecision:
    """What happens to one match: accepted, or refused with its reason, and what it counts for."""

    landmark_id: int
    accepted: bool
    reason: str  # "" when accepted, else why it was refused
    nis: float  # the innovation test's NIS (NaN when it did not run)
    tentative: bool  # a landmark not yet confirmed: it corrected only itself
    counts_observation: bool  # counted in its landmark's record (found and judged by the filter)
    counts_search: bool  # tells the recovery monitor whether it was found, once the landmark is confirmed


def associate(candidates: Sequence[MatchCandidate]) -> tuple[MatchDecision, ...]:
    """One decision per candidate, in order: accepted when the filter's test let it through.

    A match refused before the test keeps that reason; one the test refused gets
    :data:`REASON_GATE`. A match refused for a laser spot inside its template says nothing of its
    landmark (it is neither counted in the landmark's record nor as found or missed); one refused
    by the joint compatibility test counts as refused.
    """
    out = []
    for c in candidates:
        accepted = c.updated and c.accepted
        reason = c.refused if c.refused else ("" if accepted else REASON_GATE)
        out.append(
            MatchDecision(
                c.landmark_id,
                accepted,
                reason,
                c.nis if c.updated else math.nan,
                not c.confirmed,
                not c.refused or c.refused == REASON_JOINT,
                reason != REASON_LASER,
            )
        )
    return tuple(out)


def strong_refusals(candidates: Sequence[MatchCandidate], strong_correlation: float) -> tuple[list[int], bool]:
    """``(indices, accepted_older)``: the strong, confirmed matches the filter's test refused, for recovery.

    Strong: a correlation of at least ``strong_correlation``. ``accepted_older``: a confirmed
    landmark older (lower id) than every refused one was accepted (see :meth:`RecoveryMonitor.refusals`).
    """
    strong = [
        k
        for k, c in enumerate(candidates)
        if c.updated and not c.accepted and c.confirmed and c.score >= strong_correlation
    ]
    oldest_refused = min((candidates[k].landmark_id for k in strong), default=-1)
    accepted_older = any(c.accepted for c in candidates if c.updated and c.confirmed and c.landmark_id < oldest_refused)
    return strong, accepted_older


def told_offset_m(innovation_px: np.ndarray, depth_m: float, heading_rad: float, focal_px: float) -> np.ndarray:
    """``(2,)`` vehicle offset (world frame, m) that would explain a refused match's ``(2,)`` innovation.

    ``-(Z - h)/f R(psi) [nu]``: the landmark seen at depth ``depth_m`` (``Z - h``), with the map
    heading ``heading_rad``.
    """
    return -(depth_m / focal_px) * (rot2(heading_rad) @ innovation_px)


def recovery_inflation_m2(offset_m: np.ndarray) -> np.ndarray:
    """``(2, 2)`` covariance added to the vehicle's when it recovers by the ``(2,)`` offset the matches told."""
    return 4.0 * np.outer(offset_m, offset_m) + np.eye(2) * (0.25 * float(offset_m @ offset_m))


@dataclass(frozen=True)
class RecoveryEvent:
    """The filter found inconsistent with its own map and re-admitted to it."""

    frame: int
    t_s: float
    offset_m: tuple[float, float]  # the vehicle offset the refused matches told (world frame)
    landmarks: tuple[int, ...]
    cause: str  # "refused matches" | "landmarks lost"


@dataclass(frozen=True)
class ToldOffset:
    """One strong, confirmed match refused by the innovation test: the vehicle offset that would explain it."""

    t_s: float
    landmark_id: int
    offset_m: np.ndarray  # (2,) world frame


@dataclass
class RecoveryMonitor:
    """Counts, frame by frame, the evidence that the filter (not the matches) is wrong."""

    config: AssociationConfig
    refused_streak: int = 0  # frames in a row with a strong refused match
    missed: dict[int, int] = field(default_factory=dict)  # confirmed landmark -> frames in a row expected, not found
    told: list[ToldOffset] = field(default_factory=list)  # offsets told over the last ``recovery_memory_s``
    expected: set[int] = field(default_factory=set)  # confirmed landmarks expected in view this frame
    events: list[RecoveryEvent] = field(default_factory=list)

    # At most this many landmarks are searched in the wide window per frame (it costs a millisecond each).
    MAX_WIDE_PER_FRAME = 2

    def wide_candidates(self, ids) -> set[int]:
        """Of the confirmed landmarks expected in view this frame (``ids``), those to search in the wide window."""
        ids = [int(i) for i in ids]
        self.expected = set(ids)
        if not self.config.recovery:
            return set()
        lost = [i for i in ids if self.missed.get(i, 0) >= self.config.wide_search_after_frames]
        lost.sort(key=lambda i: -self.missed[i])
        return set(lost[: self.MAX_WIDE_PER_FRAME])

    def searched(self, landmark_id: int, accepted: bool) -> None:
        """A confirmed landmark expected in view (gate (5), inside the image) was accepted, or not (lost or refused)."""
        self.missed[landmark_id] = 0 if accepted else self.missed.get(landmark_id, 0) + 1

    def refusals(
        self, t_s: float, offsets_m: list[np.ndarray], landmark_ids: list[int], accepted_older: bool
    ) -> np.ndarray | None:
        """Step 6: the vehicle offsets (world, metres) told at ``t_s`` by this frame's strong refused matches.

        ``landmark_ids[k]`` is the landmark that told ``offsets_m[k]``. Returns the offset to
        recover by when the evidence is enough, else None. Enough means all of:

        * the offsets of the current streak agree within ``recovery_offset_agreement_m``;
        * they were told ``recovery_after_frames`` frames in a row, or by two landmarks now;
        * at least ``recovery_min_landmarks`` different landmarks speak against the estimate:
          by telling that offset within the last ``recovery_memory_s`` (not necessarily in a
          row), or by being lost (expected in view now, not found for
          ``wide_search_after_frames`` frames). One landmark alone may be a look-alike,
          however long it persists.

        ``accepted_older``: a landmark older than the refused ones was accepted, so the estimate
        agrees with an older part of the map and the refused matches are the suspects: the
        evidence is dropped. (Landmarks mapped since the estimate went wrong agree with it by
        construction: they are no evidence.)
        """
        cfg = self.config
        if len(landmark_ids) != len(offsets_m):
            raise InvalidArgumentError(f"refusals: {len(offsets_m)} offsets but {len(landmark_ids)} landmark ids")
        if not cfg.recovery or accepted_older:
            self._forget()
            return None
        self.told = [o for o in self.told if o.t_s >= t_s - cfg.recovery_memory_s]
        if not offsets_m:
            self.refused_streak = 0
            return None
        self.refused_streak += 1
        self.told.extend(
            ToldOffset(t_s, int(i), np.asarray(o, dtype=np.float64)) for i, o in zip(landmark_ids, offsets_m)
        )
        streak = np.array([o.offset_m for o in self._streak_told()][-cfg.recovery_after_frames * 4 :])
        centre = np.median(streak, axis=0)
        tol = cfg.recovery_offset_agreement_m
        if not np.all(np.linalg.norm(streak - centre, axis=1) <= tol):
            return None
        if self.refused_streak < cfg.recovery_after_frames and len(offsets_m) < 2:
            return None
        witnesses = {o.landmark_id for o in self.told if np.linalg.norm(o.offset_m - centre) <= tol}
        lost = {i for i in self.expected if self.missed.get(i, 0) >= cfg.wide_search_after_frames}
        if len(witnesses | lost) < cfg.recovery_min_landmarks:
            return None
        return centre

    def _streak_told(self) -> list[ToldOffset]:
        """The offsets told during the current streak (the last ``refused_streak`` frames that told one)."""
        times = sorted({o.t_s for o in self.told}, reverse=True)[: self.refused_streak]
        return [o for o in self.told if times and o.t_s >= times[-1]]

    def _forget(self) -> None:
        self.refused_streak = 0
        self.told.clear()

    def recovered(self, event: RecoveryEvent) -> None:
        self.events.append(event)
        self.missed.clear()
        self._forget()
