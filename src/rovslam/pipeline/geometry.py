"""The image geometry the loop's steps work with, as pure functions of plain numbers.

Where a template may be (inside the image, the landmark search radius, a laser spot inside
it), where the speed tokens should be now (:func:`token_predictions`, :func:`motion_hint`),
which tokens the speed consensus kept, and a landmark's [m, n] moved to the frame's time under a
rolling shutter (:mod:`rovslam.sensor.shutter`).
"""

from __future__ import annotations

import math

import numpy as np

from rovslam.camera import Camera, ground_to_pixels, pixels_to_ground, rot2
from rovslam.config import LandmarkTemplateConfig
from rovslam.sensor.heading import HeadingPrior
from rovslam.sensor.odometry import SpeedMeasurement
from rovslam.sensor.shutter import mn_at_frame_time, mn_rate_px_s
from rovslam.vision.tracking import TokenTracks

__all__ = [
    "consensus_tokens",
    "covers_laser_spot",
    "inside_image",
    "landmark_mn_at_frame_time",
    "motion_hint",
    "plane_depth_m",
    "search_radius_px",
    "token_predictions",
    "yaw_rate_radps",
]


def inside_image(uv_px: np.ndarray, half_px: float, camera: Camera) -> bool:
    """Is the ``(2,)`` centre (u, v) finite and ``half_px`` inside the image's border? (Python floats: cheaper)"""
    u, v = float(uv_px[0]), float(uv_px[1])
    return (
        math.isfinite(u)
        and math.isfinite(v)
        and half_px <= u <= camera.width_px - 1 - half_px
        and half_px <= v <= camera.height_px - 1 - half_px
    )


def plane_depth_m(
    altitude_m: float, slope_rad: tuple[float, float] | None, mn_px: np.ndarray, focal_px: float
) -> np.ndarray:
    """Image depth of the seabed plane below the camera at the ``(N, 2)`` level-equivalent [m, n]: ``(N,)`` metres.

    The plane ``z = Z + tan(a) x + tan(b) y`` (level frame, x forward, y starboard; ``slope_rad = (a, b)``,
    positive: deeper forward / to starboard) cut by the ray of [m, n], whose seabed offset at depth z
    is ``z [m, n] / f``: ``z = Z / (1 - (tan(a) m + tan(b) n) / f)``. No slope (None): ``Z`` everywhere.
    A ray that grazes or misses the plane (denominator below 0.5) keeps ``Z``.
    """
    mn = np.asarray(mn_px, dtype=np.float64).reshape(-1, 2)
    if slope_rad is None:
        return np.full(len(mn), float(altitude_m))
    k = (math.tan(slope_rad[0]) * mn[:, 0] + math.tan(slope_rad[1]) * mn[:, 1]) / focal_px
    den = 1.0 - k
    return np.where(den >= 0.5, altitude_m / np.maximum(den, 0.5), altitude_m)


def search_radius_px(innovation_cov_px2: np.ndarray, slack_px: float, lm: LandmarkTemplateConfig) -> int:
    """Search radius: 3 sigma of the ``(2, 2)`` predicted position and of the speed change, plus a margin."""
    sigma_px = math.hypot(math.sqrt(max(float(np.max(np.linalg.eigvalsh(innovation_cov_px2))), 0.0)), slack_px)
    return int(min(lm.max_search_radius_px, math.ceil(3.0 * sigma_px) + lm.search_margin_px))


def covers_laser_spot(uv_px: np.ndarray, spots_uv_px: np.ndarray, size_px: int) -> bool:
    """Whether a ``(K, 2)`` laser spot lies inside the ``size_px`` template centred at ``uv_px`` (with 2 px to spare)."""
    half = size_px / 2.0
    return bool(len(spots_uv_px)) and bool(np.any(np.max(np.abs(spots_uv_px - uv_px), axis=1) < half + 2))


def motion_hint(
    g_shift: np.ndarray | None,
    g_conf: float,
    common: np.ndarray | None,
    offsets: np.ndarray | None,
    min_confidence: float,
) -> np.ndarray:
    """The image motion the tokens should survive: the phase correlation's when confident, else the predicted one.

    ``g_shift``, ``g_conf``: the phase correlation's ``(2,)`` shift and confidence
    (:meth:`rovslam.vision.tracking.TokenTracker.motion_prior`); ``common``, ``offsets``: from
    :func:`token_predictions`. Returns ``(2,)`` pixels (NaN when neither is known); the mean
    per-token offset (turn, tilt) is included.
    """
    mean_offset = np.zeros(2) if offsets is None else np.mean(offsets, axis=0)
    if g_shift is not None and (common is None or g_conf >= min_confidence):
        return g_shift
    return np.full(2, np.nan) if common is None else common + mean_offset


def token_predictions(
    camera: Camera,
    uv0: np.ndarray,
    altitude_m: float,
    attitude_prev: tuple[float, float],
    attitude: tuple[float, float],
    dpsi_rad: float,
    last_speed_mps: np.ndarray | None,
    dt_s: float,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Where the ``(N, 2)`` speed tokens ``uv0`` of the previous frame should be now: a common shift and per-token offsets.

    The motion model (1) moves each token's seabed point (at the previous frame's altitude and
    attitude) by the last good speed and turns it by the compass heading change, seen through
    the current attitude. Returns ``(common (2,) or None, offsets (N, 2) or None)`` in pixels:
    the common part is the translation (None when no speed is known yet, so the tracker searches
    globally); the offsets hold what rotation and tilt change add per token.
    """
    z = altitude_m
    g0 = pixels_to_ground(camera, uv0, z, *attitude_prev)
    rot = ground_to_pixels(camera, g0 @ rot2(dpsi_rad), z, *attitude) - uv0  # R(dpsi)^T g
    if not np.all(np.isfinite(rot)):
        return None, None
    if last_speed_mps is None:
        return None, rot
    full = ground_to_pixels(camera, (g0 - last_speed_mps * dt_s) @ rot2(dpsi_rad), z, *attitude) - uv0
    if not np.all(np.isfinite(full)):
        return None, rot
    common = np.mean(full - rot, axis=0)
    return common, full - common


def consensus_tokens(tracks: TokenTracks, speed: SpeedMeasurement | None) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 2)`` previous and current centres of the tokens the speed consensus kept (all, without one)."""
    uv0, uv1 = tracks.uv_prev_px, tracks.uv_curr_px
    if speed is not None and speed.ok and len(speed.inlier_mask) == len(uv0):
        uv0, uv1 = uv0[speed.inlier_mask], uv1[speed.inlier_mask]
    return uv0, uv1


def yaw_rate_radps(speed: SpeedMeasurement, prior: HeadingPrior, dt_s: float) -> float:
    """The turn rate over the last frame interval: the tokens' turn when they measured it, else the compass's."""
    if not dt_s > 0:
        return 0.0
    step = speed.dpsi_rad if speed.ok and math.isfinite(speed.dpsi_rad) else prior.step_rad
    return float(step) / dt_s if math.isfinite(step) else 0.0


def landmark_mn_at_frame_time(
    camera: Camera,
    mn_px: np.ndarray,
    v_px: float,
    depth_m: float,
    speed: SpeedMeasurement | None,
    prior: HeadingPrior | None,
    dt_s: float,
) -> np.ndarray:
    """A landmark's ``(2,)`` [m, n] seen at image row ``v_px`` moved to the frame's time (unchanged for a global shutter)."""
    if camera.readout_s == 0.0 or speed is None or prior is None:
        return mn_px
    rate = mn_rate_px_s(mn_px, speed.speed_mps, yaw_rate_radps(speed, prior, dt_s), depth_m, camera.focal_px)
    return mn_at_frame_time(camera, v_px, mn_px, rate)
