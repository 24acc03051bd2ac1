"""The per-frame loop of the paper (section 3.4), one :class:`FrameResult` per frame.

Order (DESIGN.md, "Per-frame loop"), which keeps the speed and the landmark measurements
independent:

1. laser spots -> image depth Z (fused with the sonar when given);
2. inhibit pixels near the laser spots;
3. landmark templates: search those passing the visibility gate (5) around their predicted
   position; if none is tracked and the new-landmark test (6) allows it, extract a new one;
4. inhibit pixels near the tracked / new landmark templates;
5. track the previous frame's speed templates -> surge and sway;
6. EKF prediction (1), (2) with that speed and the heading, then update (3) with the
   landmark observations;
7. augment the state with the new landmark (4);
8. extract fresh speed templates for the next frame.

The pipeline consumes any iterable of :class:`rovslam.io.sequence.Frame` (a sequence
folder, a video, a bag) and never holds more than the current and previous frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from rovslam.camera import ground_to_mn, ground_to_pixels, pixels_to_ground, rot2
from rovslam.config import RunConfig
from rovslam.io.sequence import Frame, SequenceInfo
from rovslam.odometry import HeadingFilter, SpeedEstimator
from rovslam.slam import EkfSlam
from rovslam.vision.filters import bandpass, local_variance, remove_specks, template_channel
from rovslam.vision.laser import LaserAltimeter
from rovslam.vision.templates import extract_templates, inhibit_boxes, inhibition_mask
from rovslam.vision.tracking import TokenTracker, match_template

# Landmark templates are re-oriented when the heading differs from the one they were cut at
# by more than this (beyond the paper, which flew at constant heading).
_ROTATE_TEMPLATE_RAD = math.radians(0.5)

# Prior standard deviation of one step's heading change when no compass is given.
_NO_COMPASS_STEP_RAD = 0.2

# A frame whose template channel has less contrast than this (8-bit units, std of the
# band-passed image) carries no texture to track: black, saturated or flat.
_MIN_TEXTURE_STD = 0.5


@dataclass(frozen=True)
class Observation:
    """One landmark template seen in a frame ("init" when it created the landmark)."""

    landmark_id: int
    kind: str  # "track" | "init"
    uv_px: np.ndarray  # (2,) template centre in the image
    mn_px: np.ndarray  # (2,) level-equivalent (m, n) of eq. (3)
    score: float
    nis: float
    accepted: bool


@dataclass(frozen=True)
class FrameResult:
    """What the pipeline knows after one frame (a record for writers, plots and viewers)."""

    index: int
    t_s: float
    dt_s: float
    x_m: float
    y_m: float
    cov_xy_m2: np.ndarray  # (2, 2)
    heading_rad: float
    altitude_m: float
    altitude_sigma_m: float
    altitude_source: str
    laser_spots_uv_px: np.ndarray  # (K, 2)
    surge_mps: float
    sway_mps: float
    speed_ok: bool
    speed_cov_mps2: np.ndarray  # (2, 2)
    tokens_given: int
    tokens_tracked: int
    tokens_inliers: int
    used_global_search: bool
    landmarks_visible: int
    landmarks_tracked: int
    n_landmarks: int
    observations: tuple[Observation, ...]
    new_landmark_id: int | None
    dr_x_m: float
    dr_y_m: float
    skipped_reason: str | None = None
    token_uv_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (K, 2) tracked tokens


@dataclass
class LandmarkRecord:
    """A landmark's template and its history (the map's bookkeeping beside the filter state)."""

    id: int
    patch: np.ndarray  # (32, 32) float32
    local_variance: float
    first_t_s: float
    first_frame: int
    heading_rad: float = 0.0  # heading when the template was cut
    patch_wide: np.ndarray | None = None  # (S, S) float32, S > 32 * sqrt(2): rotated on re-observation
    observations: int = 0
    rejected: int = 0
    last_seen_t_s: float = math.nan


class SlamPipeline:
    """Stateful runner of the per-frame loop for one sequence."""

    def __init__(self, info: SequenceInfo, config: RunConfig = RunConfig()):
        self.info = info
        self.config = config
        self.camera = info.camera
        self.focal_px = info.camera.focal_px
        self.altimeter = LaserAltimeter(info.camera, info.lasers, config.laser, self.altimeter_fallback)
        self.tokens = TokenTracker(config.speed_templates, config.tracker)
        self.speed = SpeedEstimator(config.odometry)
        self.heading = HeadingFilter(config.odometry.compass_sigma_rad)
        self.ekf = EkfSlam(config.slam)
        self.landmarks: list[LandmarkRecord] = []
        self.skipped: list[tuple[int, float, str]] = []
        self._prev: Frame | None = None
        self._prev_altitude_m: float | None = None
        self._prev_heading_rad: float | None = None  # filtered heading of the previous frame
        self._prev_compass_rad: float | None = None
        self._has_compass = True
        self._prev_attitude = (0.0, 0.0)
        self._last_speed_mps: np.ndarray | None = None  # (surge, sway) of the last good step
        self._dr = np.zeros(2)
        self._n = 0

    # ------------------------------------------------------------------ helpers
    def _to_mn(self, uv_px: np.ndarray, altitude_m: float, att: tuple[float, float]) -> np.ndarray:
        g = pixels_to_ground(self.camera, uv_px.reshape(1, 2), altitude_m, *att)
        return ground_to_mn(g, altitude_m, self.focal_px)[0]

    def _inside(self, uv_px: np.ndarray, half_px: float) -> bool:
        return bool(
            np.all(np.isfinite(uv_px))
            and half_px <= uv_px[0] <= self.camera.width_px - 1 - half_px
            and half_px <= uv_px[1] <= self.camera.height_px - 1 - half_px
        )

    def _oriented_patch(self, rec: LandmarkRecord, heading_rad: float) -> np.ndarray:
        """The landmark template as the camera sees it at ``heading_rad``: rotated by the heading change."""
        dpsi = _wrap(heading_rad - rec.heading_rad)
        if abs(dpsi) < _ROTATE_TEMPLATE_RAD or rec.patch_wide is None:
            return rec.patch
        n = rec.patch_wide.shape[0]
        c = (n - 1) / 2.0
        # The seabed turns by -dpsi in the (m, n) frame, i.e. by +dpsi in OpenCV's (u, v-down) angle.
        rot = cv2.getRotationMatrix2D((c, c), math.degrees(dpsi), 1.0)
        turned = cv2.warpAffine(rec.patch_wide, rot, (n, n), flags=cv2.INTER_LINEAR)
        k = (n - rec.patch.shape[0]) // 2
        return turned[k : k + rec.patch.shape[0], k : k + rec.patch.shape[1]]

    def _reported_cov(self, altitude_m: float, has_attitude: bool) -> np.ndarray:
        """(2, 2) covariance of the true position: the filter's, plus the apparent-frame errors.

        A tilt error b (AHRS) shifts every seabed point seen, so the odometry and the landmarks
        place the vehicle at x - R b: the filter is exact for that apparent position, and the
        true one is off by b, of covariance (Z sigma_att)^2 I. A slow compass error delta turns
        the apparent frame about the origin: the position is off by delta J x, J = [[0, -1], [1, 0]]
        (only when the filter does not hold that error in its state: slam.heading_bias_sigma_rad = 0).
        """
        cov = self.ekf.vehicle_cov_m2.copy()
        odo = self.config.odometry
        if has_attitude:
            cov += np.eye(2) * (altitude_m * odo.attitude_sigma_rad) ** 2
        if odo.compass_sigma_rad > 0 and self._has_compass and self.config.slam.heading_bias_sigma_rad == 0:
            jx = np.array([[0.0, -1.0], [1.0, 0.0]]) @ self.ekf.vehicle_xy_m
            cov += odo.compass_drift_sigma_rad**2 * np.outer(jx, jx)
        return cov

    def _token_predictions(
        self, dpsi_rad: float, att: tuple[float, float], dt_s: float
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Where the speed tokens should be now: a common shift and per-token offsets, in pixels.

        The motion model of (1) moves each token's seabed point by the last good speed and
        turns it by the compass heading change, seen through the current attitude. Returns
        ``(common (2,) or None, offsets (N, 2) or None)``: the common part is the translation
        (None when no speed is known yet, so the tracker searches globally); the offsets hold
        what rotation and tilt change add per token.
        """
        toks = self.tokens.tokens
        if not toks or self._prev_altitude_m is None:
            return None, None
        uv0 = np.array([t.centre_uv_px for t in toks])
        z = self._prev_altitude_m
        g0 = pixels_to_ground(self.camera, uv0, z, *self._prev_attitude)
        rot = ground_to_pixels(self.camera, g0 @ rot2(dpsi_rad), z, *att) - uv0  # R(dpsi)^T g
        if not np.all(np.isfinite(rot)):
            return None, None
        if self._last_speed_mps is None:
            return None, rot
        full = ground_to_pixels(self.camera, (g0 - self._last_speed_mps * dt_s) @ rot2(dpsi_rad), z, *att) - uv0
        if not np.all(np.isfinite(full)):
            return None, rot
        common = np.mean(full - rot, axis=0)
        return common, full - common

    # ------------------------------------------------------------------ the loop
    def run(self, frames: Iterable[Frame]) -> Iterator[FrameResult]:
        """Process frames in order, yielding one result per frame."""
        for frame in frames:
            yield self.process(frame)

    def process(self, frame: Frame) -> FrameResult:
        cfg = self.config
        att = (frame.roll_rad, frame.pitch_rad)
        dt_s = 0.0 if self._prev is None else frame.t_s - self._prev.t_s
        compass = frame.heading_rad  # NaN: no compass (a bare video); the tokens give the turn
        has_compass = math.isfinite(compass)
        compass_prev = compass if self._prev_compass_rad is None else self._prev_compass_rad
        psi_prev = (compass if has_compass else 0.0) if self._prev_heading_rad is None else self._prev_heading_rad
        # Heading change from the compass, until the tokens measure it (0, very uncertain, without one).
        compass_step = _wrap(compass - compass_prev) if has_compass and math.isfinite(compass_prev) else 0.0
        self._has_compass = has_compass
        psi = psi_prev + compass_step

        reason = frame.error
        bp = None
        if frame.image is not None:
            chan = remove_specks(template_channel(frame.image, cfg.bandpass.channel), cfg.bandpass.despeckle_px)
            bp = bandpass(chan, cfg.bandpass.sigma_fine_px, cfg.bandpass.sigma_coarse_px)
            if float(bp.std()) < _MIN_TEXTURE_STD:
                reason = "no texture (black, saturated or flat frame)"
        if reason is not None:
            return self._skip(frame, dt_s, psi_prev, reason)

        # (1) laser altimeter -> image depth Z
        alt = self.altimeter.measure(frame.image, frame.sonar_altitude_m, *att)
        Z = alt.altitude_m
        # (2) inhibit the laser neighbourhoods
        mask = inhibition_mask(self.camera.shape, alt.spots_uv_px, cfg.laser.inhibit_radius_px)

        # (3) landmark templates
        lm_cfg = cfg.landmark_templates
        half_lm = lm_cfg.size_px / 2.0
        visible = self.ekf.visible_landmarks(psi, Z, self.focal_px, self.camera.width_px, self.camera.height_px)
        tracked: list[tuple[LandmarkRecord, np.ndarray, np.ndarray, float]] = []
        # The filter still holds the previous frame's position (its prediction comes at step 6,
        # once this frame's speed is measured): move it by the last speed for the search
        # (x_pred of the paper's Fig. 1), mn -> mn - f/Z R(psi)^T delta.
        px_per_m = self.focal_px / Z
        psi_map = psi - self.ekf.heading_bias_rad  # the heading the filter believes (slow compass error removed)
        if self._last_speed_mps is not None and dt_s > 0:
            delta = rot2(psi_prev - self.ekf.heading_bias_rad) @ self._last_speed_mps * dt_s
            shift_mn = px_per_m * (rot2(psi_map).T @ delta)
            slack_px = px_per_m * cfg.odometry.gap_speed_sigma_mps * dt_s  # speed change over one step
        else:
            shift_mn = np.zeros(2)
            slack_px = px_per_m * 0.15 * dt_s  # survey speed unknown: up to 0.15 m/s either way
        # Predicted pixels of all gated landmarks at once; only those inside the image are searched.
        uv_all = np.zeros((0, 2))
        if len(visible):
            g = (self.ekf.landmarks_xy_m()[visible] - self.ekf.vehicle_xy_m) @ rot2(psi_map)  # R^T (X - x)
            uv_all = ground_to_pixels(self.camera, g - shift_mn / px_per_m, Z, *att)
        for i, uv_pred in zip(visible, uv_all):
            if not self._inside(uv_pred, half_lm - 2):
                continue
            rec = self.landmarks[int(i)]
            _, S = self.ekf.predict_observation(int(i), psi, Z, self.focal_px)
            sigma_px = math.hypot(math.sqrt(max(float(np.max(np.linalg.eigvalsh(S))), 0.0)), slack_px)
            radius = int(min(lm_cfg.max_search_radius_px, math.ceil(3.0 * sigma_px) + lm_cfg.search_margin_px))
            m = match_template(bp, self._oriented_patch(rec, psi_map), uv_pred, radius, cfg.tracker)
            if not m.ok or not self._inside(m.uv_px, half_lm):
                continue
            if len(alt.spots_uv_px) and np.any(
                np.max(np.abs(alt.spots_uv_px - m.uv_px), axis=1) < half_lm + 2
            ):
                continue  # a laser spot inside the template corrupts the correlation
            tracked.append((rec, m.uv_px, self._to_mn(m.uv_px, Z, att), m.score))

        new_template = None
        if not tracked and self.ekf.may_add_landmark():
            cands = extract_templates(
                bp, local_variance(bp, lm_cfg.size_px), lm_cfg.size_px, 1, lm_cfg.min_local_variance,
                lm_cfg.border_px, mask,
            )
            if cands:
                new_template = cands[0]

        # (4) inhibit the landmark templates for the speed templates
        boxes = [uv for _, uv, _, _ in tracked]
        if new_template is not None:
            boxes.append(new_template.centre_uv_px)
        if boxes:
            inhibit_boxes(mask, np.asarray(boxes), int(half_lm) + lm_cfg.inhibit_margin_px)

        # (5) speed templates -> surge, sway (each token's search window also follows the turn)
        common, offsets = self._token_predictions(compass_step, att, dt_s)
        tracks = self.tokens.track(bp, common, mask, offsets)
        sigma_c = cfg.odometry.compass_sigma_rad if has_compass else 0.0
        # Without a compass the tokens alone measure the turn: a vague prior of 0.2 rad per step.
        step_sigma = math.sqrt(2.0) * sigma_c if sigma_c > 0 else (None if has_compass else _NO_COMPASS_STEP_RAD)
        if self._prev is not None:
            speed = self.speed.measure(
                self.camera, tracks.uv_prev_px, tracks.uv_curr_px, self._prev_altitude_m, Z, dt_s,
                dpsi_rad=compass_step, altitude_sigma_m=alt.sigma_m,
                attitude_prev_rad=self._prev_attitude, attitude_curr_rad=att,
                dpsi_sigma_rad=step_sigma,
            )
        else:
            speed = None
        # Heading: the compass smoothed with the tokens' rotation (odometry.HeadingFilter).
        measured = speed is not None and speed.ok and math.isfinite(speed.dpsi_sigma_rad)
        psi = self.heading.update(
            compass, speed.dpsi_rad if measured else None, speed.dpsi_sigma_rad if measured else math.inf
        )
        # The heading noise the filter is told of: what the smoothing leaves of the compass's white
        # noise. Its slow drift is a state of the filter (slam.heading_bias_sigma_rad); without that
        # state (the paper's filter) the observations are told of the drift instead, since a
        # landmark seen again minutes later was mapped under another drift, and the reported
        # covariance carries the turn of the whole map (_reported_cov). The AHRS tilt error shifts
        # odometry and landmarks alike: it enters the start and the reported covariance only.
        psi_sigma = self.heading.sigma_rad if sigma_c > 0 or not has_compass else None
        obs_psi_sigma = (
            math.hypot(psi_sigma, cfg.odometry.compass_drift_sigma_rad)
            if sigma_c > 0 and cfg.slam.heading_bias_sigma_rad == 0 else psi_sigma
        )
        if self._n == 0 and frame.has_attitude:
            # The start is known only up to the tilt offset: x_apparent = x - R b, |b| ~ Z sigma_att.
            self.ekf = EkfSlam(cfg.slam, initial_cov_m2=np.eye(2) * (Z * cfg.odometry.attitude_sigma_rad) ** 2)

        # (6) EKF prediction with the measured speed, then update with the landmarks
        observations: list[Observation] = []
        if speed is not None and dt_s > 0:
            self.ekf.predict(speed.surge_mps, speed.sway_mps, speed.cov_mps2, psi_prev, dt_s, psi_sigma)
            self._dr += rot2(psi_prev) @ np.array([speed.surge_mps, speed.sway_mps]) * dt_s
            if speed.ok:
                self._last_speed_mps = np.array([speed.surge_mps, speed.sway_mps])
        for rec, uv, mn, score in tracked:
            res = self.ekf.update(
                rec.id, mn, psi, Z, self.focal_px, altitude_sigma_m=alt.sigma_m,
                heading_sigma_rad=obs_psi_sigma,
            )
            if res.accepted:
                rec.observations += 1
                rec.last_seen_t_s = frame.t_s
            else:
                rec.rejected += 1
            observations.append(Observation(rec.id, "track", uv, mn, score, float(res.nis), bool(res.accepted)))

        # (7) augment with the new landmark
        new_id = None
        if new_template is not None:
            mn = self._to_mn(new_template.centre_uv_px, Z, att)
            new_id = self.ekf.augment(
                mn, psi, Z, self.focal_px, altitude_sigma_m=alt.sigma_m,
                heading_sigma_rad=obs_psi_sigma,
            )
            wide = int(math.ceil(lm_cfg.size_px * math.sqrt(2.0))) + 2
            wide += (wide - lm_cfg.size_px) % 2  # same parity: both share the template centre
            self.landmarks.append(
                LandmarkRecord(
                    new_id, new_template.patch, float(new_template.local_variance), frame.t_s, frame.index,
                    observations=1, last_seen_t_s=frame.t_s, heading_rad=psi - self.ekf.heading_bias_rad,
                    patch_wide=cv2.getRectSubPix(bp, (wide, wide), tuple(float(c) for c in new_template.centre_uv_px)),
                )
            )
            observations.append(Observation(new_id, "init", new_template.centre_uv_px, mn, 1.0, 0.0, True))

        # (8) fresh speed templates for the next frame
        self.tokens.extract(bp, local_variance(bp, cfg.speed_templates.size_px), mask)

        self._prev = frame
        self._prev_altitude_m = Z
        self._prev_heading_rad = psi
        self._prev_compass_rad = compass
        self._prev_attitude = att
        xy = self.ekf.vehicle_xy_m
        self._n += 1
        return FrameResult(
            index=frame.index, t_s=frame.t_s, dt_s=dt_s, x_m=float(xy[0]), y_m=float(xy[1]),
            cov_xy_m2=self._reported_cov(Z, frame.has_attitude), heading_rad=psi - self.ekf.heading_bias_rad, altitude_m=Z,
            altitude_sigma_m=alt.sigma_m, altitude_source=alt.source, laser_spots_uv_px=alt.spots_uv_px,
            surge_mps=speed.surge_mps if speed else 0.0, sway_mps=speed.sway_mps if speed else 0.0,
            speed_ok=bool(speed.ok) if speed else False,
            speed_cov_mps2=speed.cov_mps2 if speed else np.zeros((2, 2)),
            tokens_given=tracks.n_given, tokens_tracked=len(tracks.uv_curr_px),
            tokens_inliers=speed.n_inliers if speed else 0, used_global_search=tracks.used_global_search,
            landmarks_visible=len(visible), landmarks_tracked=sum(o.accepted for o in observations if o.kind == "track"),
            n_landmarks=self.ekf.n_landmarks, observations=tuple(observations), new_landmark_id=new_id,
            dr_x_m=float(self._dr[0]), dr_y_m=float(self._dr[1]),
            token_uv_px=tracks.uv_curr_px,
        )

    def _skip(self, frame: Frame, dt_s: float, psi_prev: float, reason: str) -> FrameResult:
        """An unusable frame: predict with the held speed, reset the token tracks."""
        self.skipped.append((frame.index, frame.t_s, reason))
        speed = None
        if self._prev is not None and dt_s > 0:
            empty = np.zeros((0, 2))
            Z = self._prev_altitude_m or self.altimeter_fallback
            speed = self.speed.measure(self.camera, empty, empty, Z, Z, dt_s)
            self.ekf.predict(speed.surge_mps, speed.sway_mps, speed.cov_mps2, psi_prev, dt_s)
            self._dr += rot2(psi_prev) @ np.array([speed.surge_mps, speed.sway_mps]) * dt_s
        self.tokens.reset()
        # The next usable frame measures its speed against this frame's time: no tokens span it.
        self._prev = frame
        self._prev_heading_rad = self.heading.update(frame.heading_rad)
        self._prev_compass_rad = frame.heading_rad
        xy = self.ekf.vehicle_xy_m
        if self._prev_altitude_m is None:
            self._prev_altitude_m = self.altimeter_fallback
        Z = self._prev_altitude_m
        return FrameResult(
            index=frame.index, t_s=frame.t_s, dt_s=dt_s, x_m=float(xy[0]), y_m=float(xy[1]),
            cov_xy_m2=self._reported_cov(Z, frame.has_attitude), heading_rad=self._prev_heading_rad, altitude_m=Z,
            altitude_sigma_m=float("nan"), altitude_source="none", laser_spots_uv_px=np.zeros((0, 2)),
            surge_mps=speed.surge_mps if speed else 0.0, sway_mps=speed.sway_mps if speed else 0.0,
            speed_ok=False, speed_cov_mps2=speed.cov_mps2 if speed else np.zeros((2, 2)),
            tokens_given=0, tokens_tracked=0, tokens_inliers=0, used_global_search=False,
            landmarks_visible=0, landmarks_tracked=0, n_landmarks=self.ekf.n_landmarks, observations=(),
            new_landmark_id=None, dr_x_m=float(self._dr[0]), dr_y_m=float(self._dr[1]), skipped_reason=reason,
        )

    @property
    def altimeter_fallback(self) -> float:
        return self.info.fixed_altitude_m if self.info.fixed_altitude_m is not None else 1.31

    def landmark_rows(self) -> list[dict]:
        """The map for landmarks.csv."""
        rows = []
        for rec in self.landmarks:
            xy = self.ekf.landmark_xy_m(rec.id)
            c = self.ekf.landmark_cov_m2(rec.id)
            rows.append(
                {"id": rec.id, "x_m": float(xy[0]), "y_m": float(xy[1]), "var_x_m2": float(c[0, 0]),
                 "cov_xy_m2": float(c[0, 1]), "var_y_m2": float(c[1, 1]), "first_t_s": rec.first_t_s,
                 "observations": rec.observations, "local_variance": rec.local_variance}
            )
        return rows


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi
