"""The loop's records: what one frame found, its measurements for the back ends, its :class:`FrameResult`.

Plain data and the functions that build it from the loop's state; nothing here changes the
filter. :class:`FrameRecords` (one per :class:`~rovslam.pipeline.SlamPipeline`) turns the steps'
:class:`FrameStep` into the frame's :class:`~rovslam.slam.measurements.FrameMeasurements` (what
either back end reads) and, with the back end's :class:`Estimate`, into its :class:`FrameResult`;
it reports covariances with the apparent frame's errors and writes the map's rows. The
``*_summary`` / ``*_warnings`` functions say what ``summary.json`` says of a run.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame
from rovslam.mapping.association import RecoveryEvent
from rovslam.mapping.landmarks import LandmarkRecord
from rovslam.sensor.heading import HeadingEstimate
from rovslam.sensor.odometry import SpeedMeasurement
from rovslam.sensor.sunlight import SunlightEvent
from rovslam.slam import EkfSlam
from rovslam.slam.apparent import apparent_frame_cov_m2
from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement
from rovslam.slam.motion import altitude_offset_sigma_m
from rovslam.slam.observation import observation_noise_px2
from rovslam.vision.laser import AltitudeEstimate
from rovslam.vision.scale import ProcessingScale
from rovslam.vision.tracking import TokenTracks

__all__ = ["Estimate", "FrameRecords", "FrameResult", "FrameStep", "Observation", "TrackedLandmark"]

_NO_POINTS = np.zeros((0, 2))
_NO_COV = np.zeros((2, 2))


@dataclass(frozen=True)
class Observation:
    """One landmark template seen in a frame ("init" when it created the landmark)."""

    landmark_id: int
    kind: str  # "track" | "init"
    uv_px: np.ndarray  # (2,) template centre in the image
    mn_px: np.ndarray  # (2,) level-equivalent (m, n) of (3)
    score: float
    nis: float
    accepted: bool
    reason: str = ""  # why it was refused ("" when accepted)
    tentative: bool = False  # a landmark not yet confirmed: it corrected only itself


@dataclass(frozen=True)
class TrackedLandmark:
    """A landmark template found again in this frame (step 3), before the filter judges it (step 6)."""

    record: LandmarkRecord
    uv_px: np.ndarray  # (2,) template centre in the image
    mn_px: np.ndarray  # (2,) level-equivalent (m, n) of (3)
    score: float
    refused: str = ""  # refused before the filter saw it (a laser spot inside the template)


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
    speed_source: str  # what measured the speed: "tokens", "features" (the feature motion of step 5), "" none
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
    measurements: FrameMeasurements | None = None  # what this frame measured, as both back ends consume it
    recovery: RecoveryEvent | None = None  # the filter re-admitted to its map in this frame


@dataclass(frozen=True)
class FrameStep:
    """What the loop's steps found in one frame (processed or skipped), before the back end's estimate.

    ``observations`` are in full-resolution pixels (:meth:`FrameRecords.full_res`); ``dr_m`` is
    the ``(2,)`` dead reckoning after the frame.
    """

    frame: Frame
    dt_s: float
    heading: HeadingEstimate
    altitude_m: float
    speed: SpeedMeasurement | None
    dr_m: np.ndarray
    altitude: AltitudeEstimate | None = None
    tracks: TokenTracks | None = None
    visible: int = 0  # landmarks that passed the visibility gate (5)
    observations: tuple[Observation, ...] = ()
    new_id: int | None = None
    skipped_reason: str | None = None
    recovery: RecoveryEvent | None = None


@dataclass(frozen=True)
class Estimate:
    """The back end's vehicle estimate after a frame (map frame): ``(2,)`` position, ``(2, 2)`` covariance, heading."""

    xy_m: np.ndarray
    cov_xy_m2: np.ndarray
    heading_rad: float


class FrameRecords:
    """Builds each frame's measurements and :class:`FrameResult` from the loop's state (read only).

    ``apparent_sigmas``: what the reported covariance adds for the back end
    (:func:`rovslam.slam.apparent.apparent_sigmas`). Keeps the latest frame's measurements
    (:meth:`landmark_rows` reports the map in that frame's apparent frame).
    """

    def __init__(
        self, config: RunConfig, scale: ProcessingScale, ekf: EkfSlam, apparent_sigmas: tuple[float, float, float]
    ) -> None:
        self.config = config
        self.scale = scale
        self.ekf = ekf
        self.apparent_sigmas = apparent_sigmas
        self.last_measurements: FrameMeasurements | None = None

    def full_res(self, observations: Sequence[Observation]) -> tuple[Observation, ...]:
        """Observations in full-resolution pixels: template centres, and [m, n] over the full focal length."""
        if self.scale.identity:
            return tuple(observations)
        return tuple(
            dataclasses.replace(o, uv_px=self.scale.to_full_px(o.uv_px), mn_px=o.mn_px * self.scale.focal_ratio)
            for o in observations
        )

    def measurements(self, step: FrameStep, compass_sigma_rad: float) -> FrameMeasurements:
        """This frame's measurements in plain numbers (:mod:`rovslam.slam.measurements`), for either back end."""
        frame, speed, heading, altitude_m = step.frame, step.speed, step.heading, step.altitude_m
        slam = self.config.slam
        sigma_z = step.altitude.sigma_m if step.altitude else math.nan
        turn = speed is not None and speed.ok and math.isfinite(speed.dpsi_sigma_rad) and speed.dpsi_sigma_rad > 0
        landmarks = tuple(self._landmark_measurement(o, altitude_m, sigma_z) for o in step.observations)
        meas = FrameMeasurements(
            index=frame.index,
            t_s=frame.t_s,
            dt_s=step.dt_s,
            speed_mps=speed.speed_mps if speed else np.zeros(2),
            speed_cov_mps2=speed.cov_mps2 if speed else _NO_COV,
            speed_ok=bool(speed.ok) if speed else False,
            heading_rad=heading.heading_rad,
            heading_sigma_rad=heading.sigma_rad if heading.sigma_rad is not None else slam.heading_sigma_rad,
            compass_rad=frame.heading_rad,
            compass_sigma_rad=compass_sigma_rad,
            heading_step_rad=speed.dpsi_rad if turn else math.nan,  # type: ignore[union-attr]
            heading_step_sigma_rad=speed.dpsi_sigma_rad if turn else math.nan,  # type: ignore[union-attr]
            altitude_m=altitude_m,
            altitude_sigma_m=sigma_z,
            focal_px=self.scale.full.focal_px,
            landmarks=landmarks,
            attitude_sigma_rad=self.config.odometry.attitude_sigma_rad if frame.has_attitude else 0.0,
        )
        self.last_measurements = meas
        return meas

    def _landmark_measurement(self, o: Observation, altitude_m: float, sigma_z: float) -> LandmarkMeasurement:
        """An observation as the flat-seabed model (3) at the frame's altitude sees it (for the smoother).

        A landmark ``h`` above the seabed is seen at depth ``Z - h`` (``Z + s - h`` with the seabed offset
        s): its [m, n] scaled by ``depth / Z`` is what a flat seabed at Z would show (the filter's current
        estimates).
        """
        depth = altitude_m + self.ekf.seabed_offset_m - self.ekf.landmark_height_m(o.landmark_id)
        scale = depth / altitude_m
        noise = observation_noise_px2(o.mn_px, self.config.slam.pixel_sigma_px * self.scale.focal_ratio, depth, sigma_z)
        return LandmarkMeasurement(o.landmark_id, o.kind, o.mn_px * scale, noise * scale**2, o.accepted)

    def result(self, step: FrameStep, meas: FrameMeasurements, estimate: Estimate) -> FrameResult:
        """The one place a :class:`FrameResult` is built (processed and skipped frames alike).

        Pixels are reported in the full-resolution frame, whatever the processing scale.
        """
        xy, altitude, speed, tracks, observations = (
            estimate.xy_m,
            step.altitude,
            step.speed,
            step.tracks,
            step.observations,
        )
        return FrameResult(
            index=step.frame.index,
            t_s=step.frame.t_s,
            dt_s=step.dt_s,
            x_m=float(xy[0]),
            y_m=float(xy[1]),
            cov_xy_m2=self.reported_cov(estimate.cov_xy_m2, xy, meas),
            heading_rad=estimate.heading_rad,
            altitude_m=step.altitude_m,
            altitude_sigma_m=altitude.sigma_m if altitude else math.nan,
            altitude_source=altitude.source if altitude else "none",
            laser_spots_uv_px=altitude.spots_uv_px if altitude else _NO_POINTS,
            surge_mps=speed.surge_mps if speed else 0.0,
            sway_mps=speed.sway_mps if speed else 0.0,
            speed_ok=bool(speed.ok) if speed else False,
            speed_cov_mps2=speed.cov_mps2 if speed else _NO_COV,
            tokens_given=tracks.n_given if tracks else 0,
            tokens_tracked=tracks.n_tracked if tracks else 0,
            tokens_inliers=speed.n_inliers if speed else 0,
            speed_source=speed.source if speed is not None and speed.ok else "",
            used_global_search=tracks.used_global_search if tracks else False,
            landmarks_visible=step.visible,
            landmarks_tracked=sum(o.accepted for o in observations if o.kind == "track"),
            n_landmarks=self.ekf.n_landmarks,
            observations=observations,
            new_landmark_id=step.new_id,
            dr_x_m=float(step.dr_m[0]),
            dr_y_m=float(step.dr_m[1]),
            skipped_reason=step.skipped_reason,
            token_uv_px=self.scale.to_full_px(tracks.uv_curr_px) if tracks else _NO_POINTS,
            measurements=meas,
            recovery=step.recovery,
        )

    def reported_cov(self, cov_m2: np.ndarray, xy_m: np.ndarray, meas: FrameMeasurements) -> np.ndarray:
        """(2, 2) covariance of the true position: the back end's, plus the apparent frame's errors.

        The tilt the AHRS leaves, the heading error every frame shares (the compass's constant
        error; its drift too when the back end does not estimate it) and, for the iSAM2 back end,
        which does not hold it, the altimeter's lasting error move the whole estimate, and no
        image can see them (:mod:`rovslam.slam.apparent`).
        """
        heading_sigma_rad, altitude_sigma_m, altitude_scale = self.apparent_sigmas
        return np.asarray(cov_m2, dtype=np.float64) + apparent_frame_cov_m2(
            xy_m,
            meas.altitude_m,
            meas.attitude_sigma_rad,
            heading_sigma_rad if meas.has_compass else 0.0,
            altitude_offset_sigma_m(altitude_sigma_m, altitude_scale, meas.altitude_m) / meas.altitude_m,
        )

    def landmark_rows(self, landmarks: Sequence[LandmarkRecord]) -> list[dict]:
        """The map for landmarks.csv; covariances with the apparent frame's errors (at the last frame's altitude)."""
        rows = []
        for rec in landmarks:
            xy = self.ekf.landmark_xy_m(rec.id)
            c = self.ekf.landmark_cov_m2(rec.id)
            if self.last_measurements is not None:
                c = self.reported_cov(c, xy, self.last_measurements)
            rows.append(
                {
                    "id": rec.id,
                    "x_m": float(xy[0]),
                    "y_m": float(xy[1]),
                    "var_x_m2": float(c[0, 0]),
                    "cov_xy_m2": float(c[0, 1]),
                    "var_y_m2": float(c[1, 1]),
                    "first_t_s": rec.first_t_s,
                    "observations": rec.observations,
                    "local_variance": rec.local_variance,
                    "height_m": self.ekf.landmark_height_m(rec.id),
                    "height_sigma_m": self.ekf.landmark_height_sigma_m(rec.id),
                    "self_similarity": rec.self_similarity,
                    "confirmed": int(rec.confirmed),
                    "rejected": rec.rejected,
                }
            )
        return rows


# ---------------------------------------------------------------------- summary.json
def sunlight_summary(opening_px: int, sunlit_frames: int, events: Sequence[SunlightEvent]) -> dict:
    """What ``summary.json`` says of the sunlight: frames it was taken out of, and when it changed."""
    return {
        "opening_px": opening_px,
        "frames_removed": int(sunlit_frames),
        "changes": [{"frame": e.frame, "t_s": e.t_s, "removed": e.removed, "share": e.share} for e in events],
    }


def drag_means_mps(frames: int, sum_mps: np.ndarray, sigma_sum_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(2,)`` mean of the speed error w and ``(2,)`` mean of its sigma over the ``frames`` that drove it."""
    n = max(frames, 1)
    return sum_mps / n, sigma_sum_mps / n


def speed_bias_summary(frames: int, sum_mps: np.ndarray, sigma_sum_mps: np.ndarray) -> dict:
    """What ``summary.json`` says of the speed error w: the frames it was driven, its mean and mean sigma
    over them (m/s, world frame x north, y east)."""
    mean, sigma = drag_means_mps(frames, sum_mps, sigma_sum_mps)
    return {"frames": int(frames), "mean_mps": [float(v) for v in mean], "mean_sigma_mps": [float(v) for v in sigma]}


def altitude_bias_summary(sigmas_m: Sequence[float]) -> dict:
    """What ``summary.json`` says of the altitude offset ``b``: its process sigma over the predictions
    (median and 95th percentile, m; with the relief under the tokens it exceeds the configured one)."""
    sig = np.asarray(sigmas_m, dtype=float)
    if sig.size == 0:
        return {"predictions": 0, "sigma_median_m": None, "sigma_p95_m": None}
    return {
        "predictions": int(sig.size),
        "sigma_median_m": float(np.median(sig)),
        "sigma_p95_m": float(np.percentile(sig, 95)),
    }


def sunlight_warnings(
    sunlight_px: int,
    sunlit_frames: int,
    n_frames: int,
    events: Sequence[SunlightEvent],
    drag_frames: int,
    drag_sum_mps: np.ndarray,
    drag_sigma_sum_mps: np.ndarray,
) -> list[str]:
    """One line for the run's warnings when the sunlight was taken out of any frame (of ``n_frames`` processed)."""
    if not sunlit_frames:
        return []
    first = next(e for e in events if e.removed)
    return [
        f"bright light that does not move with the seabed (sunlight caustics) was seen from t = "
        f"{first.t_s:.1f} s: bright structures narrower than {sunlight_px} px were "
        f"removed from {sunlit_frames} of {n_frames} frames before tracking ([bandpass] sunlight_px; "
        "0 turns this off)" + _drag_note(drag_frames, drag_sum_mps, drag_sigma_sum_mps)
    ]


def _drag_note(frames: int, sum_mps: np.ndarray, sigma_sum_mps: np.ndarray) -> str:
    if not frames:
        return ""
    mean, sigma = drag_means_mps(frames, sum_mps, sigma_sum_mps)
    (wx, wy), (sx, sy) = mean * 1e3, sigma * 1e3
    return (
        f"; the drag it leaves on the speed, as the filter estimated it (mean over those frames): "
        f"{wx:+.1f} +- {sx:.1f} mm/s north, {wy:+.1f} +- {sy:.1f} mm/s east ([slam] speed_bias_sigma_mps)"
    )
