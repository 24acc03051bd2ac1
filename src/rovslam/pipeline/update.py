"""Step 6's update of the loop: the frame's landmark matches tested, the filter updated by (3), each decided.

:class:`LandmarkUpdate` (one per :class:`~rovslam.pipeline.SlamPipeline`, sharing its filter and
recovery monitor) tests the frame's matches together (joint compatibility), updates the filter
with each kept one (a tentative landmark corrects only itself until confirmed), starts a
recovery when strong matches of the old map are refused frame after frame, and counts each
match's decision (:func:`rovslam.mapping.association.associate`) in its landmark's record.
"""

from __future__ import annotations

import math

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame
from rovslam.mapping.association import (
    REASON_JOINT,
    MatchCandidate,
    MatchDecision,
    RecoveryEvent,
    RecoveryMonitor,
    associate,
    jointly_compatible,
    recovery_inflation_m2,
    strong_refusals,
    told_offset_m,
)
from rovslam.pipeline.geometry import plane_depth_m
from rovslam.pipeline.records import Observation, TrackedLandmark
from rovslam.sensor.heading import HeadingEstimate
from rovslam.slam import EkfSlam
from rovslam.slam.ekf import UpdateResult
from rovslam.vision.laser import AltitudeEstimate

__all__ = ["LandmarkUpdate", "landmark_depth"]


class LandmarkUpdate:
    """The filter's update (3) with the frame's landmark matches, and the decision on each."""

    def __init__(self, config: RunConfig, ekf: EkfSlam, recovery: RecoveryMonitor, focal_px: float) -> None:
        self.config = config
        self.ekf = ekf
        self.recovery = recovery
        self.focal_px = focal_px  # the processed camera's

    def observe(
        self, tracked: list[TrackedLandmark], alt: AltitudeEstimate, heading: HeadingEstimate, frame: Frame
    ) -> list[Observation]:
        """Step 6, after the prediction: the landmark updates (3), the recovery, one observation per match.

        The matches are first tested together (joint compatibility); a tentative landmark
        corrects only itself until confirmed; strong matches refused frame after frame start a
        recovery (:mod:`rovslam.mapping.association`).
        """
        assoc = self.config.association
        candidates = self.update(tracked, alt, heading)
        candidates = self.recover(tracked, candidates, alt, heading, frame)
        return counted(tracked, associate(candidates), frame.t_s, assoc.confirm_observations, self.recovery)

    def update(
        self, tracked: list[TrackedLandmark], alt: AltitudeEstimate, heading: HeadingEstimate
    ) -> list[MatchCandidate]:
        """Step 6: the joint compatibility test of the frame's matches, then the filter's update (3) of each kept one.

        A tentative landmark corrects only itself. Returns one :class:`~rovslam.mapping.association.MatchCandidate`
        per match, in order, with the reason it was refused before the update or the update's outcome.
        """
        assoc = self.config.association
        refused = [t.refused for t in tracked]
        live = [k for k, t in enumerate(tracked) if not t.refused]
        if assoc.joint_compatibility and len(live) > 1:
            args = [self.update_args(tracked[k], alt, heading) for k in live]
            _, out = jointly_compatible(
                lambda ix: self.ekf.joint_nis([args[j] for j in ix]), len(live), assoc.joint_quantile
            )
            for j in out:
                refused[live[j]] = REASON_JOINT
        candidates = []
        for t, why in zip(tracked, refused):
            candidate = MatchCandidate(t.record.id, t.record.confirmed, t.score, why)
            if not why:
                res = self.ekf.update(  # type: ignore[misc]
                    *self.update_args(t, alt, heading),
                    landmark_only=not t.record.confirmed and assoc.confirm_observations > 0,
                )
                candidate = judged(candidate, res)
            candidates.append(candidate)
        return candidates

    def update_args(self, t: TrackedLandmark, alt: AltitudeEstimate, heading: HeadingEstimate) -> tuple:
        """The arguments of ``EkfSlam.update`` / ``joint_nis`` for one match (its depth: :func:`landmark_depth`)."""
        depth_m, sigma_m = landmark_depth(self.config, alt, t.mn_px, self.focal_px)
        return (
            t.record.id,
            t.mn_px,
            heading.heading_rad,
            depth_m,
            self.focal_px,
            None,
            sigma_m,
            heading.observation_sigma_rad,
        )

    def recover(
        self,
        tracked: list[TrackedLandmark],
        candidates: list[MatchCandidate],
        alt: AltitudeEstimate,
        heading: HeadingEstimate,
        frame: Frame,
    ) -> list[MatchCandidate]:
        """Strong, confirmed matches refused by the innovation test: the filter may be the one that is wrong.

        Each tells the vehicle offset that would explain it (:func:`~rovslam.mapping.association.told_offset_m`); when the
        :class:`~rovslam.mapping.association.RecoveryMonitor` finds them consistent for long enough, the
        vehicle covariance is inflated by that offset, they are admitted, and the event recorded.
        Returns the candidates, those admitted with their new update's outcome.
        """
        strong, accepted_older = strong_refusals(candidates, self.config.association.strong_correlation)
        theta = self.ekf.map_heading_rad(heading.heading_rad)
        offsets = [
            told_offset_m(
                candidates[k].innovation_px,  # type: ignore[arg-type]
                self.ekf.landmark_depth_m(candidates[k].landmark_id, alt.altitude_m),
                theta,
                self.focal_px,
            )
            for k in strong
        ]
        offset = self.recovery.refusals(frame.t_s, offsets, [candidates[k].landmark_id for k in strong], accepted_older)
        if offset is None:
            return candidates
        self.ekf.inflate_vehicle_covariance(recovery_inflation_m2(offset))
        candidates = list(candidates)
        for k in strong:
            candidates[k] = judged(candidates[k], self.ekf.update(*self.update_args(tracked[k], alt, heading)))
        self.recovery.recovered(
            RecoveryEvent(
                frame.index,
                frame.t_s,
                (float(offset[0]), float(offset[1])),
                tuple(candidates[k].landmark_id for k in strong),
                "refused matches",
            )
        )
        return candidates


def landmark_depth(config: RunConfig, alt: AltitudeEstimate, mn_px: np.ndarray, focal_px: float) -> tuple[float, float]:
    """The image depth Z of (3), (4) for a landmark seen at the ``(2,)`` [m, n], and its sigma (metres).

    With ``[laser] plane_depth`` the laser spots' plane (averaged, :mod:`rovslam.pipeline.depth`) at that
    pixel (:func:`rovslam.pipeline.geometry.plane_depth_m`), else the one depth below the camera. The
    sigma is Z's, widened in quadrature by ``[slam] landmark_relief_gain`` times the relief off the
    spots' plane: the landmark's own height off that plane, a consider parameter of (3) (0: not added).
    """
    depth_m = alt.altitude_m
    if config.laser.plane_depth:
        depth_m = float(plane_depth_m(alt.altitude_m, alt.slope_rad, mn_px, focal_px)[0])
    sigma_m = alt.sigma_m
    gain = config.slam.landmark_relief_gain
    if gain > 0.0 and math.isfinite(alt.relief_var_m2):
        sigma_m = math.hypot(sigma_m, gain * math.sqrt(max(alt.relief_var_m2, 0.0)))
    return depth_m, sigma_m


def judged(candidate: MatchCandidate, res: UpdateResult) -> MatchCandidate:
    """A match with the outcome of the filter's update (3) on it."""
    c = candidate  # built directly: dataclasses.replace costs five times more
    return MatchCandidate(
        c.landmark_id, c.confirmed, c.score, c.refused, True, res.accepted, res.nis, res.innovation_px
    )


def counted(
    tracked: list[TrackedLandmark],
    decisions: tuple[MatchDecision, ...],
    t_s: float,
    confirm_after: int,
    recovery: RecoveryMonitor,
) -> list[Observation]:
    """Step 6: each match's decision counted in its landmark's record and by the recovery monitor; its observation."""
    observations = []
    for t, d in zip(tracked, decisions):
        if d.counts_observation:
            t.record.observed(d.accepted, t_s, confirm_after)
        if t.record.confirmed and d.counts_search:  # found and refused still counts as missing
            recovery.searched(t.record.id, d.accepted)
        observations.append(
            Observation(t.record.id, "track", t.uv_px, t.mn_px, t.score, d.nis, d.accepted, d.reason, d.tentative)
        )
    return observations
