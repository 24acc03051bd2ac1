"""Step 5 of the loop: the previous frame's speed tokens tracked -> surge, sway and the turn.

:class:`SpeedStep` (one per :class:`~rovslam.pipeline.SlamPipeline`, sharing its token tracker,
speed estimator and filter) predicts where the tokens should be now (the last good speed and
the compass turn, seen through the attitudes), tracks them, and measures the speed from their
displacements (:class:`rovslam.sensor.odometry.SpeedEstimator`); under a rolling shutter, the
tokens and the landmark observations are moved to the frame's time (:mod:`rovslam.sensor.shutter`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from rovslam.camera import Camera
from rovslam.config import RunConfig
from rovslam.core import Frame
from rovslam.pipeline.assist import (
    beyond_reach,
    feature_speed,
    is_weak,
    predicted_tokens,
    reduced_grey,
    token_gate,
    turn_agrees,
)
from rovslam.pipeline.geometry import landmark_mn_at_frame_time, motion_hint, token_predictions
from rovslam.pipeline.records import TrackedLandmark
from rovslam.sensor.heading import HeadingPrior
from rovslam.sensor.odometry import SpeedEstimator, SpeedMeasurement
from rovslam.sensor.shutter import tokens_at_frame_time
from rovslam.slam import EkfSlam
from rovslam.vision.features import FeatureMotion, feature_motion
from rovslam.vision.laser import AltitudeEstimate
from rovslam.vision.tracking import TokenTracker, TokenTracks

__all__ = ["PreviousFrame", "SpeedStep"]

_GRID_THRESHOLD_PX = 50.0  # the feature speed's grid points: none an outlier (a zoom the altitudes miss moves them)


@dataclasses.dataclass(frozen=True)
class PreviousFrame:
    """What step 5 measures against: the last frame's time, image depth Z and (roll, pitch) (None: no frame yet)."""

    t_s: float | None = None
    altitude_m: float | None = None
    attitude_rad: tuple[float, float] = (0.0, 0.0)


class SpeedStep:
    """The speed tokens' predicted positions, their tracks, the speed they measure, and the rolling shutter's moves."""

    def __init__(
        self, config: RunConfig, camera: Camera, tokens: TokenTracker, speed: SpeedEstimator, ekf: EkfSlam
    ) -> None:
        self.config = config
        self.camera = camera  # the processed camera
        self.tokens = tokens
        self.speed = speed
        self.ekf = ekf
        self._image: tuple[float, np.ndarray | None] | None = None  # the last frame's time and image

    def measure(
        self,
        track_img: np.ndarray,
        mask: np.ndarray,
        alt: AltitudeEstimate,
        att: tuple[float, float],
        prior: HeadingPrior,
        dt_s: float,
        has_attitude: bool,
        prev: PreviousFrame,
        last_speed_mps: np.ndarray | None,
        frame: Frame | None = None,
    ) -> tuple[TokenTracks, SpeedMeasurement | None]:
        """Step 5: track the previous frame's tokens (their windows follow the turn) -> surge, sway, turn.

        ``track_img``: ``(H, W) float32`` tracking image; ``mask``: ``(H, W) bool`` inhibited pixels;
        ``last_speed_mps``: ``(2,)`` last good (surge, sway), None before the first; ``frame``: the
        frame itself (its image for the feature motion when the tokens are weak, :meth:`_assisted`).
        The speed is None on the first frame (nothing to measure against).
        """
        common, offsets = self.token_predictions(prior.step_rad, att, dt_s, prev, last_speed_mps)
        hint = motion_hint(
            *self.tokens.motion_prior(track_img), common, offsets, self.config.tracker.min_global_confidence
        )
        if self.tokens.reselect_for_motion(hint):
            common, offsets = self.token_predictions(prior.step_rad, att, dt_s, prev, last_speed_mps)  # changed
        tracks = self.tokens.track(track_img, common, mask, offsets)
        before, self._image = self._image, (None if frame is None else (frame.t_s, frame.image))
        if prev.t_s is None:
            return tracks, None
        step = self._step_args(alt, att, prior, has_attitude, prev, dt_s)
        uv_prev, uv_curr = tokens_at_frame_time(self.camera, tracks.uv_prev_px, tracks.uv_curr_px, dt_s)
        threshold = self.config.odometry.feature_assist_inliers
        tokens_only = self.speed.preview(self.camera, uv_prev, uv_curr, **step)
        if not is_weak(tokens_only, threshold):
            return tracks, self.speed.take(tokens_only, dt_s)
        motion = None
        if before is not None and before[0] == prev.t_s and before[1] is not None and frame is not None:
            motion = self._feature_motion(before[1], frame.image, prior)
        if motion is None or not self._beyond_reach(motion, tracks, common, offsets):
            # no feature motion, or one the tokens' search covered: the tokens as they are
            return tracks, self.speed.take(tokens_only, dt_s)
        return self._assisted(track_img, mask, motion, tracks, step, dt_s)

    def _beyond_reach(
        self, motion: FeatureMotion, tracks: TokenTracks, common: np.ndarray | None, offsets: np.ndarray | None
    ) -> bool:
        """Whether the feature motion lies beyond the windows the tokens were searched in (:func:`beyond_reach`):
        around the prediction ``common + offsets``, around the phase correlation's shift, else around zero."""
        toks = self.tokens.tokens
        if not toks:
            return False
        uv = np.array([t.centre_uv_px for t in toks])
        rot = np.zeros((len(toks), 2)) if offsets is None else np.asarray(offsets, dtype=np.float64)
        radius = float(self.tokens.speed_config.search_radius_px)
        windows = [((np.zeros(2) if common is None else common) + rot, radius)]
        g_shift = tracks.global_shift_uv_px
        if g_shift is not None:
            g_radius = float(self.tokens.tracker_config.global_search_radius_px)
            windows.append((np.asarray(g_shift, dtype=np.float64) + rot - rot.mean(axis=0), g_radius))
        return beyond_reach(self.camera, motion, uv, windows)

    def _step_args(
        self,
        alt: AltitudeEstimate,
        att: tuple[float, float],
        prior: HeadingPrior,
        has_attitude: bool,
        prev: PreviousFrame,
        dt_s: float,
    ) -> dict[str, Any]:
        """The keyword arguments of :meth:`SpeedEstimator.measure` beyond the camera and the tokens."""
        return dict(
            altitude_prev_m=prev.altitude_m,
            altitude_curr_m=alt.altitude_m,
            dt_s=dt_s,
            dpsi_rad=prior.step_rad,
            altitude_sigma_m=alt.sigma_m,
            attitude_prev_rad=prev.attitude_rad,
            attitude_curr_rad=att,
            dpsi_sigma_rad=prior.step_sigma_rad,
            altitude_samples=max(alt.n_spots, 1) if alt.source.startswith("laser") else 1,
            attitude_noise_rad=self.config.odometry.attitude_noise_sigma_rad if has_attitude else 0.0,
        )

    def _feature_motion(self, before: np.ndarray, now: np.ndarray | None, prior: HeadingPrior) -> FeatureMotion | None:
        """The similarity from the previous frame's image to this one's (processed pixels); None when unreliable,
        or when it turns where the compass did not (not the next view of the same seabed: a glitch)."""
        if now is None or np.shape(before) != np.shape(now):
            return None
        motion = feature_motion(reduced_grey(before, self.camera), reduced_grey(now, self.camera), camera=self.camera)
        # the compass step, and the reading against the last heading (a fast turn the prior takes for a glitch)
        steps = (prior.step_rad, math.remainder(prior.compass_rad - prior.previous_rad, math.tau))
        sigma = prior.step_sigma_rad if prior.has_compass else None
        if not motion.ok or not turn_agrees(motion, steps, sigma, self.config.odometry.feature_gate_sigmas):
            return None
        return motion

    def _assisted(
        self,
        track_img: np.ndarray,
        mask: np.ndarray,
        motion: FeatureMotion,
        tracks: TokenTracks,
        step: dict[str, Any],
        dt_s: float,
    ) -> tuple[TokenTracks, SpeedMeasurement]:
        """Weak tokens with a feature motion: search again around its prediction, refuse the tokens it contradicts;
        where they still fail, the feature motion is the speed (:mod:`rovslam.pipeline.assist`)."""
        odo = self.config.odometry
        shift = self._predicted_shift(motion)
        if shift is not None:
            self.tokens.reselect_for_motion(np.median(shift, axis=0))  # tokens where the seabed stays in view
            shift = self._predicted_shift(motion)
        if shift is not None:
            common = np.mean(shift, axis=0)
            tracks = self.tokens.track(track_img, common, mask, shift - common)
        uv_prev, uv_curr = tokens_at_frame_time(self.camera, tracks.uv_prev_px, tracks.uv_curr_px, dt_s)
        keep = token_gate(self.camera, motion, uv_prev, uv_curr, odo.outlier_threshold_px, odo.feature_gate_sigmas)
        uv_curr = np.where(keep[:, None], uv_curr, np.nan)
        gated = self.speed.preview(self.camera, uv_prev, uv_curr, **step)
        if not is_weak(gated, odo.feature_assist_inliers):
            return tracks, self.speed.take(gated, dt_s)
        # the grid's points are exact up to the zoom the altitudes miss: all inliers, the zoom fitted
        config = dataclasses.replace(odo, min_inliers=1, outlier_threshold_px=_GRID_THRESHOLD_PX, token_scale=True)
        m = feature_speed(self.camera, motion, len(uv_prev), {**step, "config": config})
        return tracks, self.speed.accept(m, dt_s)

    def _predicted_shift(self, motion: FeatureMotion) -> np.ndarray | None:
        """``(N, 2)`` px: each current token's motion as the feature motion predicts it (None without tokens)."""
        toks = self.tokens.tokens
        if not toks:
            return None
        uv = np.array([t.centre_uv_px for t in toks])
        pred, _ = predicted_tokens(self.camera, motion, uv)
        return pred - uv if np.all(np.isfinite(pred)) else None

    def token_predictions(
        self,
        dpsi_rad: float,
        att: tuple[float, float],
        dt_s: float,
        prev: PreviousFrame,
        last_speed_mps: np.ndarray | None,
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Where the speed tokens should be now: ``(common (2,) or None, offsets (N, 2) or None)`` pixels
        (:func:`rovslam.pipeline.geometry.token_predictions`; none without tokens or a previous altitude)."""
        toks = self.tokens.tokens
        if not toks or prev.altitude_m is None:
            return None, None
        return token_predictions(
            self.camera,
            np.array([t.centre_uv_px for t in toks]),
            prev.altitude_m,
            prev.attitude_rad,
            att,
            dpsi_rad,
            last_speed_mps,
            dt_s,
        )

    def landmarks_at_frame_time(
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
                    self.ekf.landmark_depth_m(t.record.id, alt.altitude_m),
                    speed,
                    prior,
                    dt_s,
                ),
            )
            for t in tracked
        ]
