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
* Step 5: track the previous frame's speed templates -> surge, sway and the turn
  (:mod:`rovslam.pipeline.speed`);
* Step 6: EKF prediction (1), (2) with that speed and the heading, then update (3) with the
  landmark observations, each match accepted or refused by :func:`rovslam.mapping.association.associate`
  (:mod:`rovslam.pipeline.prediction`, :mod:`rovslam.pipeline.update`);
* Step 7: augment the state with the new landmark (4);
* Step 8: extract fresh speed templates for the next frame.

The pipeline consumes any iterable of :class:`rovslam.io.sequence.Frame` (a sequence
folder, a video, a bag) and never holds more than the current and previous frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.mapping.association import RecoveryMonitor
from rovslam.mapping.landmarks import LandmarkRecord
from rovslam.pipeline import records
from rovslam.pipeline.depth import DepthModel
from rovslam.pipeline.geometry import consensus_tokens, landmark_mn_at_frame_time
from rovslam.pipeline.image import SunlightWatch, tracking_image
from rovslam.pipeline.prediction import Prediction
from rovslam.pipeline.prepare import FramePreparer, PreparedFrame
from rovslam.pipeline.records import Estimate, FrameRecords, FrameResult, FrameStep, Observation, TrackedLandmark
from rovslam.pipeline.search import LandmarkSearch
from rovslam.pipeline.speed import PreviousFrame, SpeedStep
from rovslam.pipeline.update import LandmarkUpdate, landmark_depth
from rovslam.sensor.altitude import AltitudeFilter
from rovslam.sensor.heading import HeadingEstimate, HeadingPrior, HeadingTracker
from rovslam.sensor.odometry import SpeedEstimator, SpeedMeasurement
from rovslam.slam import EkfSlam
from rovslam.slam.apparent import apparent_sigmas
from rovslam.slam.measurements import FrameMeasurements
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
        self.speed_step = SpeedStep(config, self.camera, self.tokens, self.speed, self.ekf)  # step 5
        # Sunlight caustics: bright structures that do not move with the seabed, taken out while they are seen.
        self.sunlight_watch = SunlightWatch(config.bandpass)
        self.sunlight = self.sunlight_watch.monitor
        self.prediction = Prediction(config, self.ekf, self.sunlight)  # step 6: (1), (2) and the dead reckoning
        # Step 6: the landmark updates (3) and the decision on each match.
        self.landmark_update = LandmarkUpdate(config, self.ekf, self.recovery, self.focal_px)
        self.skipped: list[tuple[int, float, str]] = []
        self._prev = PreviousFrame()  # what step 5 measures against
        self._n = 0  # frames processed (not skipped)
        self._prepared: PreparedFrame | None = None  # this frame's work done ahead (rovslam.pipeline.prepare)

    @property
    def altimeter_fallback(self) -> float:
        """Altitude assumed without laser and sonar: the sequence's ``[vehicle] altitude_m``, else the configured one."""
        fixed = self.info.fixed_altitude_m
        return fixed if fixed is not None else self.config.laser.assumed_altitude_m

    def run(self, frames: Iterable[Frame]) -> Iterator[FrameResult]:
        """Process frames in order, yielding one result per frame."""
        for frame in frames:
            yield self.process(frame)

    def preparer(self) -> FramePreparer:
        """What :meth:`process` takes as ``prepared``, made ahead of it (:mod:`rovslam.pipeline.prepare`)."""
        watch = self.sunlight_watch
        return FramePreparer(self.config, self.scale, watch.opening_px, lambda: watch.removing)

    # ------------------------------------------------------------------ the run's records
    def landmark_rows(self) -> list[dict]:
        """The map for landmarks.csv; covariances with the apparent frame's errors (at the last frame's altitude)."""
        return self.records.landmark_rows(self.landmarks)

    def sunlight_summary(self) -> dict:
        """What ``summary.json`` says of the sunlight: frames it was taken out of, and when it changed."""
        watch = self.sunlight_watch
        return records.sunlight_summary(watch.opening_px, watch.frames_removed, watch.events)

    def light_summaries(self) -> dict:
        """``summary.json``'s ``sunlight`` (with its warnings) and ``speed_bias`` blocks (``rovslam run`` and ``navigate``)."""
        return {
            "sunlight": {**self.sunlight_summary(), "warnings": self.sunlight_warnings()},
            "speed_bias": self.speed_bias_summary(),
        }

    def speed_bias_summary(self) -> dict:
        """What ``summary.json`` says of the speed error w (:func:`rovslam.pipeline.records.speed_bias_summary`)."""
        return self.prediction.speed_bias_summary()

    def altitude_bias_summary(self) -> dict:
        """What ``summary.json`` says of the altitude offset ``b`` (:func:`rovslam.pipeline.records.altitude_bias_summary`)."""
        return self.prediction.altitude_bias_summary()

    def sunlight_warnings(self) -> list[str]:
        """One line for the run's warnings when the sunlight was taken out of any frame."""
        watch = self.sunlight_watch
        sunlight_px = self.config.bandpass.sunlight_px
        return records.sunlight_warnings(
            sunlight_px, watch.frames_removed, self._n, watch.events, *self.prediction.drag()
        )

    # ------------------------------------------------------------------ the loop
    def process(self, frame: Frame, prepared: PreparedFrame | None = None) -> FrameResult:
        """One frame: the paper's loop (steps 1 to 8), then the back end fed with what the frame measured.

        ``prepared``: the frame's :class:`~rovslam.pipeline.prepare.PreparedFrame` from this pipeline's
        :meth:`preparer` (made ahead, on another thread), or None; the results are the same either way.
        """
        self._prepared = prepared if prepared is not None and prepared.image is frame.image else None
        try:
            step = self._steps(frame)
        finally:
            self._prepared = None
        meas = self.records.measurements(step, self.heading.compass_sigma_rad)
        estimate = self._back_end(meas, step.heading)  # the iSAM2 smoother is fed here (else: the EKF's estimate)
        return self.records.result(step, meas, estimate)

    def _steps(self, frame: Frame) -> FrameStep:
        """The paper's loop (steps 1 to 8) over one frame, or the skip of an unusable one."""
        dt_s = 0.0 if self._prev.t_s is None else frame.t_s - self._prev.t_s
        prior = self.heading.prior(frame.heading_rad, dt_s)
        track_img, reason = self._tracking_image(frame)
        if reason is not None:
            return self._skip(frame, dt_s, prior, reason)
        att = (frame.roll_rad, frame.pitch_rad)

        alt = self._measure_altitude(frame, att)  # step 1
        mask = self._inhibit_laser_spots(alt)  # step 2
        visible, tracked = self._track_landmarks(track_img, alt, att, prior, dt_s)  # type: ignore[arg-type]  # step 3
        new_template = self._choose_new_landmark(track_img, mask, tracked)  # type: ignore[arg-type]
        self._inhibit_landmarks(mask, tracked, new_template)  # step 4
        tracks, speed = self._measure_speed(track_img, mask, alt, att, prior, dt_s, frame.has_attitude, frame)  # type: ignore[arg-type]  # step 5
        heading = self._fuse_heading(prior, speed, dt_s)
        tracked = self.speed_step.landmarks_at_frame_time(tracked, speed, prior, alt, dt_s)  # rolling shutter, if any
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
            new_id, init = self._add_landmark(track_img, new_template, alt, att, heading, frame, speed, prior, dt_s)  # type: ignore[arg-type]
            observations.append(init)
        self._extract_tokens(track_img, mask)  # type: ignore[arg-type]  # step 8

        self._prev = PreviousFrame(frame.t_s, alt.altitude_m, att)
        self.sunlight_watch.end_frame(frame.t_s, *consensus)
        self._n += 1
        return FrameStep(
            frame,
            dt_s,
            heading,
            alt.altitude_m,
            speed,
            self.prediction.dr_m.copy(),
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
        watch, ahead = self.sunlight_watch, self._prepared
        if ahead is not None and ahead.without_bright == watch.removing:  # made ahead as it would be now
            img, bright, reason = ahead.track_img, ahead.bright, ahead.reason
            if img is not None and ahead.small is not None:
                self.tokens.offer_prior(img, ahead.small, ahead.prev_small, ahead.prior)
        else:
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
        alt = self.altimeter.measure(frame.image, frame.sonar_altitude_m, *att)  # type: ignore[arg-type]
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
        return self.search.track(track_img, alt, att, prior, dt_s, self.prediction.last_speed_mps)

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
        frame: Frame | None = None,
    ) -> tuple[TokenTracks, SpeedMeasurement | None]:
        """Step 5: track the previous frame's tokens (their windows follow the turn) -> surge, sway, turn
        (:meth:`rovslam.pipeline.speed.SpeedStep.measure`)."""
        last_speed_mps = self.prediction.last_speed_mps
        return self.speed_step.measure(
            track_img, mask, alt, att, prior, dt_s, has_attitude, self._prev, last_speed_mps, frame
        )

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
        """Step 6: prediction (1), (2) with the measured speed (:class:`rovslam.pipeline.prediction.Prediction`),
        then the landmark updates (3) and the decision on each match (:class:`rovslam.pipeline.update.LandmarkUpdate`)."""
        if speed is not None and dt_s > 0:
            bias = self._altitude_bias_process(alt.altitude_m, alt)
            seabed = self.depth.seabed_offset_sigma_m(alt.altitude_m) if self.ekf.layout.s is not None else None
            self.prediction.measured(speed, prior, heading, dt_s, alt.altitude_m, bias, seabed)
        return self.landmark_update.observe(tracked, alt, heading, frame)

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
        depth_m, depth_sigma_m = landmark_depth(self.config, alt, mn, self.focal_px)  # the spots' plane at its pixel
        new_id = self.ekf.augment(
            mn,
            heading.heading_rad,
            depth_m,
            self.focal_px,
            altitude_sigma_m=depth_sigma_m,
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
        ahead = self._prepared
        variance = ahead.variance if ahead is not None and ahead.track_img is track_img else None
        if variance is None:
            variance = local_variance(track_img, self.config.speed_templates.size_px)
        self.tokens.extract(track_img, variance, mask)

    # ------------------------------------------------------------------ unusable frames
    def _skip(self, frame: Frame, dt_s: float, prior: HeadingPrior, reason: str) -> FrameStep:
        """An unusable frame: predict with the held speed, follow the compass, reset the token tracks."""
        self.skipped.append((frame.index, frame.t_s, reason))
        speed = None
        heading = self.heading.skip(frame.heading_rad, dt_s)
        if self._prev.t_s is not None and dt_s > 0:
            speed = self.speed.hold(dt_s)
            self.prediction.predict(speed, prior.previous_rad, dt_s, None, heading_walk_var_rad2=heading.walk_var_rad2)
        self.tokens.reset()
        # The next usable frame measures its speed against this frame's time: no tokens span it.
        altitude_m = self.altimeter_fallback if self._prev.altitude_m is None else self._prev.altitude_m
        self._prev = PreviousFrame(frame.t_s, altitude_m, self._prev.attitude_rad)
        dr_m = self.prediction.dr_m.copy()
        return FrameStep(frame, dt_s, heading, altitude_m, speed, dr_m, skipped_reason=reason)
