"""Step 3 of the loop: the landmark templates searched again, and the choice of a new one.

:class:`LandmarkSearch` (one per :class:`~rovslam.pipeline.SlamPipeline`, sharing its filter,
landmark records and recovery monitor) predicts where each landmark that passes the
visibility gate (5) is seen by (3), searches its template around there, and refuses a match
with a laser spot inside its template; when none is tracked and the new-landmark test (6)
allows it, it chooses the new landmark's template.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rovslam.camera import ground_to_pixels, mn_to_ground
from rovslam.config import RunConfig
from rovslam.mapping.association import REASON_LASER, RecoveryMonitor
from rovslam.mapping.landmarks import LandmarkRecord, most_distinctive, oriented_patch
from rovslam.pipeline.geometry import covers_laser_spot, inside_image, search_radius_px
from rovslam.pipeline.records import TrackedLandmark
from rovslam.sensor.heading import HeadingPrior
from rovslam.slam import EkfSlam
from rovslam.slam.motion import motion_step_m
from rovslam.slam.observation import pixels_to_mn
from rovslam.vision.filters import local_variance
from rovslam.vision.laser import AltitudeEstimate
from rovslam.vision.scale import ProcessingScale
from rovslam.vision.templates import Template, extract_templates
from rovslam.vision.tracking import match_template

__all__ = ["LandmarkSearch"]


class LandmarkSearch:
    """Where each landmark should be in this frame, what its template matched there, and new landmarks."""

    def __init__(
        self,
        config: RunConfig,
        scale: ProcessingScale,
        ekf: EkfSlam,
        landmarks: list[LandmarkRecord],
        recovery: RecoveryMonitor,
    ) -> None:
        self.config = config
        self.scale = scale
        self.camera = scale.camera
        self.focal_px = self.camera.focal_px
        self.ekf = ekf
        self.landmarks = landmarks  # the pipeline's records, by id (step 7 appends to them)
        self.recovery = recovery
        # The tracker settings of a wide search (built once: a checked dataclass costs 50 us to build)
        self._strict_tracker = dataclasses.replace(
            config.tracker,
            min_correlation=config.association.strong_correlation,
            max_second_peak_ratio=min(config.tracker.max_second_peak_ratio, 0.9),
        )

    def track(
        self,
        track_img: np.ndarray,
        alt: AltitudeEstimate,
        att: tuple[float, float],
        prior: HeadingPrior,
        dt_s: float,
        last_speed_mps: np.ndarray | None,
    ) -> tuple[np.ndarray, list[TrackedLandmark]]:
        """Search the landmarks that pass the visibility gate (5) around their predicted position.

        The filter still holds the previous frame's position (its prediction comes at step 6,
        once this frame's speed is measured): the search moves it by the last speed
        ``last_speed_mps`` (x_pred of the paper's Fig. 1) and widens by what the speed may have
        changed. Landmarks whose predicted template leaves the image, matches on the border, and
        matches with a laser spot inside the template (it corrupts the correlation) are not tracked.
        Returns the ids that passed (5) and the landmarks found.
        """
        lm = self.config.landmark_templates
        z = alt.altitude_m
        psi = prior.predicted_rad
        visible = self.ekf.visible_landmarks(psi, z, self.focal_px, self.camera.width_px, self.camera.height_px)
        if len(visible) == 0:
            return visible, []
        offset_m, slack_px = self._expected_motion(prior, z, dt_s, last_speed_mps)
        mn_pred, s_pred = self.ekf.predict_observations(visible, psi, z, self.focal_px, offset_m)  # (3)
        uv_pred = ground_to_pixels(self.camera, mn_to_ground(mn_pred, z, self.focal_px), z, *att)
        psi_map = self.ekf.map_heading_rad(psi)
        half = lm.size_px / 2.0
        assoc = self.config.association
        inside = [
            k
            for k, uv in enumerate(uv_pred)
            if not self.landmarks[int(visible[k])].dead and inside_image(uv, half - 2, self.camera)
        ]
        wide = self.recovery.wide_candidates(
            int(visible[k]) for k in inside if self.landmarks[int(visible[k])].confirmed
        )
        # A landmark lost for several frames: a wider window, and only clear, unambiguous matches.
        strict = self._strict_tracker
        tracked = []
        spots_px = self.scale.to_processed_px(alt.spots_uv_px)
        for k in inside:
            i, uv, s = int(visible[k]), uv_pred[k], s_pred[k]
            rec = self.landmarks[i]
            if i in wide:
                m = match_template(track_img, oriented_patch(rec, psi_map), uv, assoc.wide_search_radius_px, strict)
            else:
                m = match_template(
                    track_img, oriented_patch(rec, psi_map), uv, search_radius_px(s, slack_px, lm), self.config.tracker
                )
            if not (m.ok and inside_image(m.uv_px, half, self.camera)):
                if rec.confirmed:
                    self.recovery.searched(i, False)
                continue
            refused = REASON_LASER if covers_laser_spot(m.uv_px, spots_px, lm.size_px) else ""
            tracked.append(
                TrackedLandmark(rec, m.uv_px, pixels_to_mn(self.camera, m.uv_px, z, *att)[0], m.score, refused)
            )
        return visible, tracked

    def _expected_motion(
        self, prior: HeadingPrior, altitude_m: float, dt_s: float, last_speed_mps: np.ndarray | None
    ) -> tuple[np.ndarray, float]:
        """Vehicle displacement since the last frame by (1) with the last speed, and the search slack in pixels."""
        px_per_m = self.focal_px / altitude_m
        if last_speed_mps is not None and dt_s > 0:
            heading = self.ekf.map_heading_rad(prior.previous_rad)
            return motion_step_m(
                last_speed_mps, heading, dt_s
            ), px_per_m * self.config.odometry.gap_speed_sigma_mps * dt_s
        # No speed measured yet: the survey speed bounds the motion either way.
        return np.zeros(2), px_per_m * self.config.odometry.survey_speed_mps * dt_s

    def choose_new(self, track_img: np.ndarray, mask: np.ndarray, tracked: list[TrackedLandmark]) -> Template | None:
        """The new-landmark test (6), when none is tracked: a strong template unlike its neighbourhood.

        The paper takes the highest local variance; a template whose autocorrelation within
        the search region has another high peak (a lattice, ripples, look-alike burrows)
        would be confused with its neighbour, so it is never chosen, and of the strongest
        candidates the most distinctive is (:func:`rovslam.mapping.landmarks.most_distinctive`).
        ``mask``: ``(H, W) bool`` pixels where no template may be.
        """
        if any(not t.refused for t in tracked) or not self.ekf.may_add_landmark():
            return None
        lm, assoc = self.config.landmark_templates, self.config.association
        cands = extract_templates(
            track_img,
            local_variance(track_img, lm.size_px),
            lm.size_px,
            assoc.candidates,
            lm.min_local_variance,
            lm.border_px,
            mask,
            None,
            assoc.max_self_similarity if assoc.max_self_similarity < 1.0 else None,
            assoc.similarity_radius_px,
        )
        return most_distinctive(cands)
