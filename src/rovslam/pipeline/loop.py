"""The per-frame loop of the paper (section 3.4), one :class:`FrameResult` per frame.

:meth:`SlamPipeline.process` runs the loop's steps on a frame (:meth:`SlamPipeline._steps`,
which reads as the paper's list, docs/architecture.md, "The loop"), feeds the back end with
what the frame measured, and returns the frame's record (:mod:`rovslam.pipeline.records`).
The order of the steps keeps the speed and the landmark measurements independent:

* Step 1: laser spots -> image depth Z (fused with the sonar when given);
* Step 2: inhibit pixels near the laser spots;
* Step 3: landmark templates: search those passing the visibility gate (5) around their
  predicted position; if none is tracked and the new-landmark test (6) allows it, choose a
  new one;
* Step 4: inhibit pixels near the tracked / new landmark templates;
* Step 5: track the previous frame's speed templates -> surge, sway and the turn;
* Step 6: EKF prediction (1), (2) with that speed and the heading, then update (3) with the
  landmark observations, each match accepted or refused by :func:`rovslam.mapping.association.associate`;
* Step 7: augment the state with the new landmark (4);
* Step 8: extract fresh speed templates for the next frame.

The pipeline consumes any iterable of :class:`rovslam.io.sequence.Frame` (a sequence
folder, a video, a bag) and never holds more than the current and previous frame.
"""

from __future__ import annotations

import dataclasses
import math
from array import array
from collections.abc import Iterable, Iterator

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame, SequenceInfo
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
from rovslam.mapping.landmarks import LandmarkRecord
from rovslam.pipeline import records
from rovslam.pipeline.depth import DepthModel
from rovslam.pipeline.geometry import consensus_tokens, landmark_mn_at_frame_time, motion_hint, token_predictions
from rovslam.pipeline.image import SunlightWatch, tracking_image
from rovslam.pipeline.records import Estimate, FrameRecords, FrameResult, FrameStep, Observation, TrackedLandmark
from rovslam.pipeline.search import LandmarkSearch
from rovslam.sensor.altitude import AltitudeFilter
from rovslam.sensor.heading import HeadingEstimate, HeadingPrior, HeadingTracker
from rovslam.sensor.odometry import SpeedEstimator, SpeedMeasurement
from rovslam.sensor.shutter import tokens_at_frame_time
from rovslam.slam import EkfSlam, MotionInput
from rovslam.slam.apparent import apparent_sigmas
from rovslam.slam.ekf import UpdateResult
from rovslam.slam.measurements import FrameMeasurements
from rovslam.slam.motion import motion_step_m
from rovslam.slam.observation import pixels_to_mn
from rovslam.vision.filters import local_variance
from rovslam.vision.laser import AltitudeEstimate, LaserAltimeter
from rovslam.vision.scale import processing_scale
from rovslam.vision.templates import Template, inhibit_boxes, inhibition_mask
from rovslam.vision.tracking import TokenTracker, TokenTracks

__all__ = ["SlamPipeline"]


class SlamPipeline:
    """Stateful runner of the per-frame loop for one sequence."""

    def __init__(self, info: SequenceInfo, config: RunConfig = RunConfig()):
        self.info = info
        self.config = config
        # Any camera runs near the paper's pixels: the vision sees the frame reduced by the processing
        # scale (self.camera, self.focal_px are the processed camera's); the lasers are found in the full
        # frame; the results report full-resolution pixels (rovslam.vision.scale).
        self.scale = processing_scale(info.camera, config.processing, self.altimeter_fallback)
        self.camera = self.scale.camera
        self.focal_px = self.camera.focal_px
        self.altimeter = LaserAltimeter(
            info.camera, info.lasers, self.scale.laser_config(config.laser), self.altimeter_fallback
        )
        self.altitude = AltitudeFilter(config.laser.altitude_accel_sigma_mps2)
        self.tokens = TokenTracker(config.speed_templates, config.tracker)
        self.speed = SpeedEstimator(config.odometry)
        self.heading = HeadingTracker(config.odometry, config.slam)
        self.ekf = EkfSlam(config.slam, initial_altitude_m=self.altimeter_fallback)
        self.depth = DepthModel(config, self.altitude, self.speed, self.ekf)  # step 1's Z over time, the relief's error
        self.smoother = None  # the iSAM2 back end ([slam] backend = "isam2"): the EKF then only associates
        if config.slam.backend == "isam2":
            from rovslam.slam.smoother import Isam2Smoother

            self.smoother = Isam2Smoother(config.smoother)
        # The frames' records; what the reported covariance adds for the back end (rovslam.slam.apparent): fixed by the config.
        self.records = FrameRecords(
            config, self.scale, self.ekf, apparent_sigmas(config, graph=self.smoother is not None)
        )
        self.landmarks: list[LandmarkRecord] = []
        self.recovery = RecoveryMonitor(config.association)
        self.search = LandmarkSearch(config, self.scale, self.ekf, self.landmarks, self.recovery)  # step 3
        # Sunlight caustics: bright structures that do not move with the seabed, taken out while they are seen.
        self.sunlight_watch = SunlightWatch(config.bandpass)
        self.sunlight = self.sunlight_watch.monitor
        self._drag_frames = 0  # predictions that drove the filter's speed error w
        self._drag_sum_mps = np.zeros(2)  # w summed over them, and its sigma
        self._drag_sigma_sum_mps = np.zeros(2)
        self._altitude_bias_sigmas_m = array("d")  # b's process sigma of each prediction (summary.json; 8 bytes each)
        self.skipped: list[tuple[int, float, str]] = []
        self._prev_t_s: float | None = None
        self._prev_altitude_m: float | None = None
        self._prev_attitude = (0.0, 0.0)
        self._last_speed_mps: np.ndarray | None = None  # (surge, sway) of the last good step
        self._dr = np.zeros(2)
        self._n = 0  # frames processed (not skipped)

    @property
    def altimeter_fallback(self) -> float:
        """Altitude assumed without laser and sonar: the sequence's ``[vehicle] altitude_m``, else the configured one."""
        fixed = self.info.fixed_altitude_m
        return fixed if fixed is not None else self.config.laser.assumed_altitude_m

    def run(self, frames: Iterable[Frame]) -> Iterator[FrameResult]:
        """Process frames in order, yielding one result per frame."""
        for frame in frames:
            yield self.process(frame)

    # ------------------------------------------------------------------ the run's records
    def landmark_rows(self) -> list[dict]:
        """The map for landmarks.csv; covariances with the apparent frame's errors (at the last frame's altitude)."""
        return self.records.landmark_rows(self.landmarks)

    def sunlight_summary(self) -> dict:
        """What ``summary.json`` says of the sunlight: frames it was taken out of, and when it changed."""
        watch = self.sunlight_watch
        return records.sunlight_summary(watch.opening_px, watch.frames_removed, watch.events)

    def speed_bias_summary(self) -> dict:
        """What ``summary.json`` says of the speed error w (:func:`rovslam.pipeline.records.speed_bias_summary`)."""
        return records.speed_bias_summary(self._drag_frames, self._drag_sum_mps, self._drag_sigma_sum_mps)

    def altitude_bias_summary(self) -> dict:
        """What ``summary.json`` says of the altitude offset ``b`` (:func:`rovslam.pipeline.records.altitude_bias_summary`)."""
        return records.altitude_bias_summary(self._altitude_bias_sigmas_m)

    def sunlight_warnings(self) -> list[str]:
        """One line for the run's warnings when the sunlight was taken out of any frame."""
        watch = self.sunlight_watch
        return records.sunlight_warnings(
            self.config.bandpass.sunlight_px,
            watch.frames_removed,
            self._n,
            watch.events,
            self._drag_frames,
            self._drag_sum_mps,
            self._drag_sigma_sum_mps,
        )

    # ------------------------------------------------------------------ the loop
    def process(self, frame: Frame) -> FrameResult:
        """One frame: the paper's loop (steps 1 to 8), then the back end fed with what the frame measured."""
        step = self._steps(frame)
        meas = self.records.measurements(step, self.heading.compass_sigma_rad)
        estimate = self._back_end(meas, step.heading)  # the iSAM2 smoother is fed here (else: the EKF's estimate)
        return self.records.result(step, meas, estimate)

    def _steps(self, frame: Frame) -> FrameStep:
        """The paper's loop (steps 1 to 8) over one frame, or the skip of an unusable one."""
        dt_s = 0.0 if self._prev_t_s is None else frame.t_s - self._prev_t_s
        prior = self.heading.prior(frame.heading_rad, dt_s)
        track_img, reason = self._tracking_image(frame)
        if reason is not None:
            return self._skip(frame, dt_s, prior, reason)
        att = (frame.roll_rad, frame.pitch_rad)

        alt = self._measure_altitude(frame, att)  # step 1
        mask = self._inhibit_laser_spots(alt)  # step 2
        visible, tracked = self._track_landmarks(track_img, alt, att, prior, dt_s)  # step 3
        new_template = self._choose_new_landmark(track_img, mask, tracked)
        self._inhibit_landmarks(mask, tracked, new_template)  # step 4
        tracks, speed = self._measure_speed(track_img, mask, alt, att, prior, dt_s, frame.has_attitude)  # step 5
        heading = self._fuse_heading(prior, speed, dt_s)
        tracked = self._landmarks_at_frame_time(tracked, speed, prior, alt, dt_s)  # rolling shutter, if any
        if self._n == 0 and frame.has_attitude:
            self._start_filter(alt.altitude_m)
        n_events = len(self.recovery.events)
        observations = self._predict_and_update(speed, tracked, alt, prior, heading, dt_s, frame)  # step 6
        event = self.recovery.events[-1] if len(self.recovery.events) > n_events else None
        consensus = consensus_tokens(tracks, speed)
        relit = self._watch_sunlight(frame, *consensus)
        if relit is not None:  # the sunlight was taken out (or left in again): steps 7 and 8 cut from that image
            track_img = relit
        new_id = None
        if new_template is not None:  # step 7
            new_id, init = self._add_landmark(track_img, new_template, alt, att, heading, frame, speed, prior, dt_s)
            observations.append(init)
        self._extract_tokens(track_img, mask)  # step 8

        self._prev_t_s, self._prev_altitude_m, self._prev_attitude = frame.t_s, alt.altitude_m, att
        self.sunlight_watch.end_frame(frame.t_s, *consensus)
        self._n += 1
        return FrameStep(
            frame,
            dt_s,
            heading,
            alt.altitude_m,
            speed,
            self._dr.copy(),
            altitude=alt,
            tracks=tracks,
            visible=len(visible),
            observations=self.records.full_res(observations),
            new_id=new_id,
            recovery=event,
        )

    def _back_end(self, meas: FrameMeasurements, heading: HeadingEstimate) -> Estimate:
        """The estimate reported for the frame: the EKF's, or the iSAM2 smoother's once fed this frame's measurements."""
        xy, cov, heading_map = (
            self.ekf.vehicle_xy_m,
            self.ekf.vehicle_cov_m2,
            self.ekf.map_heading_rad(heading.heading_rad),
        )
        if self.smoother is not None:
            est = self.smoother.add_frame(meas)
            xy, cov, heading_map = est.xy_m, est.cov_xy_m2, est.heading_rad
        return Estimate(xy, cov, heading_map)

    # ------------------------------------------------------------------ before step 1
    def _tracking_image(self, frame: Frame) -> tuple[np.ndarray | None, str | None]:
        """``(H, W) float32`` band-passed template channel, or the reason the frame is unusable."""
        if frame.image is None or frame.error is not None:
            return None, frame.error or "no image"
        watch = self.sunlight_watch
        img, bright, reason = tracking_image(
            frame.image, self.config.bandpass, self.scale, watch.opening_px, watch.removing
        )
        if bright is not None:
            watch.bright = bright
        return img, reason

    def _watch_sunlight(self, frame: Frame, uv0: np.ndarray, uv1: np.ndarray) -> np.ndarray | None:
        """After step 6: did the bright structures around the consensus's ``(N, 2)`` tokens move with them?

        This frame's tracking image when the sunlight was just taken out (or left in again), for
        steps 7 and 8; None when nothing changed (:meth:`rovslam.pipeline.image.SunlightWatch.watch`).
        """
        return self.sunlight_watch.watch(
            frame.t_s, self._n, uv0, uv1, self.config.speed_templates.size_px, lambda: self._tracking_image(frame)
        )

    # ------------------------------------------------------------------ step 1
    def _measure_altitude(self, frame: Frame, att: tuple[float, float]) -> AltitudeEstimate:
        """Step 1: laser spots -> image depth Z, fused with the sonar, filtered over time (not an assumed value)."""
        alt = self.altimeter.measure(frame.image, frame.sonar_altitude_m, *att)
        return self.depth.filtered(frame.t_s, alt)

    def _altitude_bias_process(self, altitude_m: float, alt: AltitudeEstimate) -> tuple[float, float]:
        """The altitude offset ``b``'s stationary sigma (m) and correlation time (s) over this step
        (:meth:`rovslam.pipeline.depth.DepthModel.bias_process`: the altimeter's lasting error and the relief's)."""
        return self.depth.bias_process(altitude_m, alt)

    # ------------------------------------------------------------------ step 2
    def _inhibit_laser_spots(self, alt: AltitudeEstimate) -> np.ndarray:
        """Step 2: ``(H, W) bool`` mask of the pixels near the laser spots (no template there)."""
        return inhibition_mask(
            self.camera.shape, self.scale.to_processed_px(alt.spots_uv_px), self.config.laser.inhibit_radius_px
        )

    # ------------------------------------------------------------------ step 3
    def _track_landmarks(
        self, track_img: np.ndarray, alt: AltitudeEstimate, att: tuple[float, float], prior: HeadingPrior, dt_s: float
    ) -> tuple[np.ndarray, list[TrackedLandmark]]:
        """Step 3: search the landmarks that pass the visibility gate (5) around their predicted position, moved by
        the last speed. Returns the ids that passed (5) and the landmarks found (:meth:`LandmarkSearch.track`)."""
        return self.search.track(track_img, alt, att, prior, dt_s, self._last_speed_mps)

    def _choose_new_landmark(
        self, track_img: np.ndarray, mask: np.ndarray, tracked: list[TrackedLandmark]
    ) -> Template | None:
        """Step 3, new-landmark test (6), when none is tracked: a strong template unlike its neighbourhood
        (:meth:`rovslam.pipeline.search.LandmarkSearch.choose_new`)."""
        return self.search.choose_new(track_img, mask, tracked)

    # ------------------------------------------------------------------ step 4
    def _inhibit_landmarks(self, mask: np.ndarray, tracked: list[TrackedLandmark], new: Template | None) -> None:
        """Step 4: the speed templates keep away from the tracked and new landmark templates (in place)."""
        boxes = [t.uv_px for t in tracked if not t.refused] + ([new.centre_uv_px] if new is not None else [])
        if boxes:
            lm = self.config.landmark_templates
            inhibit_boxes(mask, np.asarray(boxes), int(lm.size_px / 2.0) + lm.inhibit_margin_px)

    # ------------------------------------------------------------------ step 5
    def _measure_speed(
        self,
        track_img: np.ndarray,
        mask: np.ndarray,
        alt: AltitudeEstimate,
        att: tuple[float, float],
        prior: HeadingPrior,
        dt_s: float,
        has_attitude: bool,
    ) -> tuple[TokenTracks, SpeedMeasurement | None]:
        """Step 5: track the previous frame's tokens (their windows follow the turn) -> surge, sway, turn."""
        common, offsets = self._token_predictions(prior.step_rad, att, dt_s)
        hint = motion_hint(
            *self.tokens.motion_prior(track_img), common, offsets, self.config.tracker.min_global_confidence
        )
        if self.tokens.reselect_for_motion(hint):
            common, offsets = self._token_predictions(prior.step_rad, att, dt_s)  # the tokens changed
        tracks = self.tokens.track(track_img, common, mask, offsets)
        if self._prev_t_s is None:
            return tracks, None
        uv_prev, uv_curr = tokens_at_frame_time(self.camera, tracks.uv_prev_px, tracks.uv_curr_px, dt_s)
        speed = self.speed.measure(
            self.camera,
            uv_prev,
            uv_curr,
            self._prev_altitude_m,
            alt.altitude_m,
            dt_s,
            dpsi_rad=prior.step_rad,
            altitude_sigma_m=alt.sigma_m,
            attitude_prev_rad=self._prev_attitude,
            attitude_curr_rad=att,
            dpsi_sigma_rad=prior.step_sigma_rad,
            altitude_samples=max(alt.n_spots, 1) if alt.source.startswith("laser") else 1,
            attitude_noise_rad=self.config.odometry.attitude_noise_sigma_rad if has_attitude else 0.0,
        )
        return tracks, speed

    def _token_predictions(
        self, dpsi_rad: float, att: tuple[float, float], dt_s: float
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Where the speed tokens should be now: ``(common (2,) or None, offsets (N, 2) or None)`` pixels
        (:func:`rovslam.pipeline.geometry.token_predictions`; none without tokens or a previous altitude)."""
        toks = self.tokens.tokens
        if not toks or self._prev_altitude_m is None:
            return None, None
        return token_predictions(
            self.camera,
            np.array([t.centre_uv_px for t in toks]),
            self._prev_altitude_m,
            self._prev_attitude,
            att,
            dpsi_rad,
            self._last_speed_mps,
            dt_s,
        )

    def _landmarks_at_frame_time(
        self,
        tracked: list[TrackedLandmark],
        speed: SpeedMeasurement | None,
        prior: HeadingPrior,
        alt: AltitudeEstimate,
        dt_s: float,
    ) -> list[TrackedLandmark]:
        """Step 5, rolling shutter: each landmark's [m, n] moved to the frame's time (:mod:`rovslam.sensor.shutter`)."""
        if self.camera.readout_s == 0.0 or speed is None:
            return tracked
        return [
            dataclasses.replace(
                t,
                mn_px=landmark_mn_at_frame_time(
                    self.camera,
                    t.mn_px,
                    t.uv_px[1],
                    alt.altitude_m - self.ekf.landmark_height_m(t.record.id),
                    speed,
                    prior,
                    dt_s,
                ),
            )
            for t in tracked
        ]

    def _fuse_heading(self, prior: HeadingPrior, speed: SpeedMeasurement | None, dt_s: float) -> HeadingEstimate:
        """Step 5, heading: the compass smoothed with the turn the tokens measured."""
        if speed is not None and speed.ok and math.isfinite(speed.dpsi_sigma_rad):
            return self.heading.update(prior, speed.dpsi_rad, speed.dpsi_sigma_rad, dt_s)
        return self.heading.update(prior, None, math.inf, dt_s)

    def _start_filter(self, altitude_m: float) -> None:
        """First frame with an AHRS: the start is known only up to the tilt offset, x_apparent = x - R b, |b| ~ Z sigma_att."""
        self.ekf.inflate_vehicle_covariance(np.eye(2) * (altitude_m * self.config.odometry.attitude_sigma_rad) ** 2)

    # ------------------------------------------------------------------ step 6
    def _predict_and_update(
        self,
        speed: SpeedMeasurement | None,
        tracked: list[TrackedLandmark],
        alt: AltitudeEstimate,
        prior: HeadingPrior,
        heading: HeadingEstimate,
        dt_s: float,
        frame: Frame,
    ) -> list[Observation]:
        """Step 6: prediction (1), (2) with the measured speed, then the landmark updates (3).

        The matches are first tested together (joint compatibility); a tentative landmark
        corrects only itself until confirmed; strong matches refused frame after frame start a
        recovery (:mod:`rovslam.mapping.association`).
        """
        if speed is not None and dt_s > 0:
            bias_sigma, bias_tau = self._altitude_bias_process(alt.altitude_m, alt)
            self._altitude_bias_sigmas_m.append(bias_sigma)
            walk = heading.walk_var_rad2  # without a compass: the integrated heading's error is eps's random walk
            self._predict(
                speed,
                prior.previous_rad,
                dt_s,
                heading.sigma_rad if walk is None else 0.0,
                alt.altitude_m,
                bias_sigma,
                walk,
                bias_tau,
            )
        assoc = self.config.association
        candidates = self._update_landmarks(tracked, alt, heading)
        candidates = self._recover(tracked, candidates, alt, heading, frame)
        return _counted(tracked, associate(candidates), frame.t_s, assoc.confirm_observations, self.recovery)

    def _update_landmarks(
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
            args = [self._update_args(tracked[k], alt, heading) for k in live]
            _, out = jointly_compatible(
                lambda ix: self.ekf.joint_nis([args[j] for j in ix]), len(live), assoc.joint_quantile
            )
            for j in out:
                refused[live[j]] = REASON_JOINT
        candidates = []
        for t, why in zip(tracked, refused):
            candidate = MatchCandidate(t.record.id, t.record.confirmed, t.score, why)
            if not why:
                res = self.ekf.update(
                    *self._update_args(t, alt, heading),
                    landmark_only=not t.record.confirmed and assoc.confirm_observations > 0,
                )
                candidate = _judged(candidate, res)
            candidates.append(candidate)
        return candidates

    def _update_args(self, t: TrackedLandmark, alt: AltitudeEstimate, heading: HeadingEstimate) -> tuple:
        """The arguments of ``EkfSlam.update`` / ``joint_nis`` for one match."""
        return (
            t.record.id,
            t.mn_px,
            heading.heading_rad,
            alt.altitude_m,
            self.focal_px,
            None,
            alt.sigma_m,
            heading.observation_sigma_rad,
        )

    def _recover(
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
                candidates[k].innovation_px,
                alt.altitude_m - self.ekf.landmark_height_m(candidates[k].landmark_id),
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
            candidates[k] = _judged(candidates[k], self.ekf.update(*self._update_args(tracked[k], alt, heading)))
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

    def _speed_bias_sigma_mps(self) -> float:
        """The odometry's slow speed error: sunlight caustics drifting over the seabed drag the tokens."""
        cfg = self.config.slam
        seen = cfg.speed_bias_when == "always" or (self.sunlight is not None and self.sunlight.active)
        return cfg.speed_bias_sigma_mps if seen else 0.0

    def _predict(
        self,
        speed: SpeedMeasurement,
        heading_rad: float,
        dt_s: float,
        heading_sigma_rad: float | None,
        altitude_m: float | None = None,
        altitude_bias_sigma_m: float | None = None,
        heading_walk_var_rad2: float | None = None,
        altitude_bias_tau_s: float | None = None,
    ) -> None:
        """Prediction (1) of the filter and of the dead reckoning reported beside it."""
        drag_sigma = self._speed_bias_sigma_mps()
        self.ekf.predict(
            MotionInput(
                speed.surge_mps,
                speed.sway_mps,
                speed.cov_mps2,
                heading_rad,
                dt_s,
                heading_sigma_rad,
                altitude_m,
                altitude_bias_sigma_m,
                heading_walk_var_rad2,
                drag_sigma,
                altitude_bias_tau_s,
            )
        )
        if drag_sigma > 0.0:
            self._drag_frames += 1
            self._drag_sum_mps += self.ekf.speed_bias_mps
            self._drag_sigma_sum_mps += np.sqrt(np.maximum(np.diag(self.ekf.speed_bias_cov_mps2), 0.0))
        self._dr += motion_step_m(speed.speed_mps, heading_rad, dt_s)
        if speed.ok:
            self._last_speed_mps = speed.speed_mps

    # ------------------------------------------------------------------ step 7
    def _add_landmark(
        self,
        track_img: np.ndarray,
        template: Template,
        alt: AltitudeEstimate,
        att: tuple[float, float],
        heading: HeadingEstimate,
        frame: Frame,
        speed: SpeedMeasurement | None = None,
        prior: HeadingPrior | None = None,
        dt_s: float = 0.0,
    ) -> tuple[int, Observation]:
        """Step 7: augment the state with the new landmark by (4) and keep its template."""
        mn = pixels_to_mn(self.camera, template.centre_uv_px, alt.altitude_m, *att)[0]
        mn = landmark_mn_at_frame_time(
            self.camera, mn, template.centre_uv_px[1], alt.altitude_m, speed, prior, dt_s
        )  # rolling shutter
        new_id = self.ekf.augment(
            mn,
            heading.heading_rad,
            alt.altitude_m,
            self.focal_px,
            altitude_sigma_m=alt.sigma_m,
            heading_sigma_rad=heading.observation_sigma_rad,
        )
        self.landmarks.append(
            LandmarkRecord.cut(
                new_id, track_img, template, self.ekf.map_heading_rad(heading.heading_rad), frame.t_s, frame.index
            )
        )
        return new_id, Observation(new_id, "init", template.centre_uv_px, mn, 1.0, 0.0, True)

    # ------------------------------------------------------------------ step 8
    def _extract_tokens(self, track_img: np.ndarray, mask: np.ndarray) -> None:
        """Step 8: fresh speed templates for the next frame, away from the inhibited pixels."""
        self.tokens.extract(track_img, local_variance(track_img, self.config.speed_templates.size_px), mask)

    # ------------------------------------------------------------------ unusable frames
    def _skip(self, frame: Frame, dt_s: float, prior: HeadingPrior, reason: str) -> FrameStep:
        """An unusable frame: predict with the held speed, follow the compass, reset the token tracks."""
        self.skipped.append((frame.index, frame.t_s, reason))
        speed = None
        heading = self.heading.skip(frame.heading_rad, dt_s)
        if self._prev_t_s is not None and dt_s > 0:
            speed = self.speed.hold(dt_s)
            self._predict(speed, prior.previous_rad, dt_s, None, heading_walk_var_rad2=heading.walk_var_rad2)
        self.tokens.reset()
        # The next usable frame measures its speed against this frame's time: no tokens span it.
        self._prev_t_s = frame.t_s
        if self._prev_altitude_m is None:
            self._prev_altitude_m = self.altimeter_fallback
        return FrameStep(frame, dt_s, heading, self._prev_altitude_m, speed, self._dr.copy(), skipped_reason=reason)


def _judged(candidate: MatchCandidate, res: UpdateResult) -> MatchCandidate:
    """A match with the outcome of the filter's update (3) on it."""
    return dataclasses.replace(
        candidate, updated=True, accepted=res.accepted, nis=res.nis, innovation_px=res.innovation_px
    )


def _counted(
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
