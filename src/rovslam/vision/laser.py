"""Laser-triangulation altimeter (paper, section 2 and Fig. 1: the red channel gives the image depth Z).

Pipeline step 1: the laser spots are detected in the red channel, associated with their
pointers by the positions predicted from the last altitude, and each spot is triangulated
by intersecting its laser ray with the camera ray through the spot. The per-spot altitudes
are checked against each other (outliers dropped), combined (a seabed plane when three or
more spots agree: altitude and slope), fused with the sonar altitude when there is one
(variance-weighted), and replaced by the sonar or the configured fixed altitude when no spot
is usable. The estimate says which source it used and returns the spot pixels, which the
pipeline inhibits for template extraction (step 2).

Frames: laser origins and directions are in the body frame from the camera centre (x
forward, y starboard, z down, ``sequence.toml`` ``[[laser]]``); triangulated points are in
the level frame (roll and pitch removed), so their z is the vertical depth below the camera.
Altitude = vertical distance from the camera down to the seabed (plane) below it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import cv2
import numpy as np

from rovslam.averages import median0
from rovslam.camera import (
    Camera,
    LaserPointer,
    ground_to_pixels,
    level_from_body,
    pixel_rays_level,
)
from rovslam.config import LaserConfig
from rovslam.errors import InvalidArgumentError, InvalidMeasurementError
from rovslam.vision.spots import detect_laser_spots, find_faint_spots, red_excess

SOURCE_LASER = "laser"
SOURCE_LASER_SONAR = "laser+sonar"
SOURCE_SONAR = "sonar"
SOURCE_FIXED = "fixed"
SOURCE_HELD = "held"  # no reading in this frame: the altitude filter's prediction (rovslam.sensor.altitude)


@dataclass(frozen=True, eq=False)
class AltitudeEstimate:
    """Image depth Z of one frame.

    Attributes
    ----------
    altitude_m: vertical distance camera -> seabed.
    sigma_m: its standard deviation.
    source: ``"laser"``, ``"laser+sonar"``, ``"sonar"`` or ``"fixed"`` (the pipeline adds ``"held"``:
        the altitude filter's prediction between readings).
    spots_uv_px: ``(K, 2)`` every laser spot detected in the frame (outliers included: they
        are still bright blobs to keep templates away from).
    n_spots: number of spots that agreed and were used for the laser altitude.
    slope_rad: seabed slope ``(along forward, along starboard)`` from the plane fit of three
        or more spots (positive = the seabed gets deeper forward / to starboard), else None.
    laser_altitude_m: the laser-only altitude before the sonar fusion (NaN when none).
    sonar_rejected: why the frame's sonar reading was not used (outside the plausible range),
        None when it was used or there was none.
    relief_var_m2: the relief off the spots' plane, measured: the spots' squared residuals from
        the plane fit, less what their centroid noise explains, per degree of freedom (four or more
        spots; NaN otherwise). The pipeline averages it over frames (:mod:`rovslam.pipeline.depth`).
    """

    altitude_m: float
    sigma_m: float
    source: str
    spots_uv_px: np.ndarray
    n_spots: int
    slope_rad: tuple[float, float] | None = None
    laser_altitude_m: float = float("nan")
    sonar_rejected: str | None = None
    relief_var_m2: float = float("nan")


def sonar_reading_problem(sonar_altitude_m: float | None, config: LaserConfig) -> str | None:
    """Why a sonar altitude reading cannot be used, or None (usable, or no reading: None / NaN).

    A reading outside ``[config.min_altitude_m, config.max_altitude_m]`` (the range the laser
    triangulation also accepts) or infinite is physically implausible for this vehicle: it is
    dropped for that frame, which then uses the lasers or the fixed altitude.
    """
    if sonar_altitude_m is None:
        return None
    v = float(sonar_altitude_m)
    if math.isnan(v):
        return None
    lo, hi = float(config.min_altitude_m), float(config.max_altitude_m)
    if not (math.isfinite(v) and lo <= v <= hi):
        return (
            f"sonar altitude {v:g} m outside the plausible range [{lo:g}, {hi:g}] m "
            "(laser.min_altitude_m, laser.max_altitude_m): not used"
        )
    return None


def _laser_arrays(lasers: Sequence[LaserPointer], roll_rad: float, pitch_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """(L, 3) origins and (L, 3) unit directions in the level frame."""
    if len(lasers) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    origins, dirs = _rig_body(tuple(lasers))
    if roll_rad == 0.0 and pitch_rad == 0.0:
        return origins, dirs
    rot = level_from_body(roll_rad, pitch_rad)
    return origins @ rot.T, dirs @ rot.T


@lru_cache(maxsize=16)
def _rig_body(lasers: tuple[LaserPointer, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(L, 3) origins and unit directions in the body frame, computed once per rig (read-only)."""
    origins = np.array([las.origin_m for las in lasers], dtype=np.float64)
    dirs = np.array([las.unit_direction for las in lasers], dtype=np.float64)
    origins.setflags(write=False)
    dirs.setflags(write=False)
    return origins, dirs


def _check_attitude(roll_rad: float, pitch_rad: float) -> None:
    if not (np.isfinite(roll_rad) and np.isfinite(pitch_rad)):
        raise InvalidMeasurementError(f"roll and pitch must be finite radians, got roll={roll_rad}, pitch={pitch_rad}")


def predict_spot_pixels(
    camera: Camera,
    lasers: Sequence[LaserPointer],
    altitude_m: float,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """Pixels where the laser spots appear over a horizontal seabed ``altitude_m`` below the camera.

    Each ray ``o + t d`` (level frame) is cut with the plane ``z = altitude_m`` and the hit
    point projected with :func:`rovslam.camera.ground_to_pixels` (tilt and distortion
    included).

    Returns
    -------
    ``(L, 2) float64`` (u, v); NaN for a ray that does not reach the seabed ahead of the camera.
    """
    if not (np.isfinite(altitude_m) and altitude_m > 0):
        raise InvalidMeasurementError(f"altitude_m must be a positive finite number, got {altitude_m}")
    _check_attitude(roll_rad, pitch_rad)
    origins, dirs = _laser_arrays(lasers, roll_rad, pitch_rad)
    if len(origins) == 0:
        return np.zeros((0, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (altitude_m - origins[:, 2]) / dirs[:, 2]
    hits = origins + t[:, None] * dirs
    uv = ground_to_pixels(camera, hits[:, :2], altitude_m, roll_rad, pitch_rad)
    uv[~(t > 0)] = np.nan
    return uv


def lasers_never_in_view(
    camera: Camera, lasers: Sequence[LaserPointer], min_altitude_m: float, max_altitude_m: float
) -> list[int]:
    """Indices of the pointers whose spot is outside the image at every altitude of the range (level camera).

    Such a pointer cannot give an altitude: its ``origin_m`` or ``direction`` is wrong (millimetres
    for metres, a sign), or it belongs to another camera. The range is sampled on 200 altitudes,
    evenly in log, clipped to 0.05 to 50 m.
    """
    lo, hi = max(min_altitude_m, 0.05), min(max_altitude_m, 50.0)
    if not lasers or not lo < hi:
        return []
    zs = np.geomspace(lo, hi, 200)
    seen = np.zeros(len(lasers), dtype=bool)
    for z in zs:
        uv = predict_spot_pixels(camera, lasers, float(z))
        seen |= (
            (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width_px - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height_px - 1)
        )
    return [int(i) for i in np.flatnonzero(~seen)]


def triangulate_points(
    camera: Camera,
    lasers: Sequence[LaserPointer],
    spots_uv_px: np.ndarray,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
    min_altitude_m: float = 0.0,
    max_altitude_m: float = np.inf,
) -> np.ndarray:
    """Seabed points of the spots: each laser ray intersected with the camera ray of its spot.

    With the camera ray ``s r`` (level frame, through the spot pixel, undistorted) and the
    laser ray ``o + t d``, ``(s, t)`` minimise ``|s r - o - t d|^2`` (closest approach; the
    rays meet exactly for a noise-free spot) and the point is taken on the laser ray,
    ``o + t d``, whose geometry is known; pixel noise across the epipolar line is thus
    projected out. Works for pointers parallel to the optical axis and for tilted ones.

    Returns
    -------
    ``(L, 3) float64`` level-frame points (forward, starboard, down) in metres; NaN rows for
    a missing spot, a laser through the camera centre (no baseline), rays that do not cross
    ahead of the camera, or a depth outside ``[min_altitude_m, max_altitude_m]``.
    """
    _check_attitude(roll_rad, pitch_rad)
    spots = np.asarray(spots_uv_px, dtype=np.float64).reshape(-1, 2)
    if len(spots) != len(lasers):
        raise InvalidArgumentError(
            f"spots_uv_px has {len(spots)} rows but there are {len(lasers)} lasers; pass one row "
            "per laser (NaN for a missing spot)"
        )
    out = np.full((len(spots), 3), np.nan)
    if len(spots) == 0:
        return out
    origins, dirs = _laser_arrays(lasers, roll_rad, pitch_rad)
    finite = np.all(np.isfinite(spots), axis=1)
    if not finite.any():
        return out
    rays = np.full((len(spots), 3), np.nan)
    rays[finite] = pixel_rays_level(camera, spots[finite], roll_rad, pitch_rad)
    a = np.einsum("ij,ij->i", rays, rays)
    b = np.einsum("ij,ij->i", rays, dirs)
    c = np.einsum("ij,ij->i", dirs, dirs)
    e = np.einsum("ij,ij->i", rays, origins)
    f = np.einsum("ij,ij->i", dirs, origins)
    den = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (b * e - a * f) / den
        s = (e + b * t) / a
    pts = origins + t[:, None] * dirs
    # The baseline must be seen from the camera: rays not (nearly) parallel, point ahead.
    good = (
        finite
        & (den > 1e-12 * a * c)
        & (s > 0)
        & np.isfinite(pts[:, 2])
        & (pts[:, 2] >= min_altitude_m)
        & (pts[:, 2] <= max_altitude_m)
    )
    out[good] = pts[good]
    return out


def triangulate_spots(
    camera: Camera,
    lasers: Sequence[LaserPointer],
    spots_uv_px: np.ndarray,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """``(L,)`` altitude of each spot's seabed point (vertical depth below the camera), NaN if none.

    See :func:`triangulate_points`.
    """
    return triangulate_points(camera, lasers, spots_uv_px, roll_rad, pitch_rad)[:, 2]


def spot_altitude_sigmas(
    camera: Camera,
    lasers: Sequence[LaserPointer],
    spots_uv_px: np.ndarray,
    spot_sigma_px: float,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """``(L,)`` standard deviation of each spot's altitude for an isotropic centroid noise.

    First-order propagation by finite differences: ``sigma_Z^2 = sigma_px^2 ((dZ/du)^2 +
    (dZ/dv)^2)``. For a pointer parallel to the optical axis at distance ``b`` from it this
    is ``Z^2 sigma_px / (f b)``. NaN where the spot is missing.
    """
    return _points_and_sigmas(camera, lasers, spots_uv_px, spot_sigma_px, roll_rad, pitch_rad)[1]


def _points_and_sigmas(
    camera: Camera,
    lasers: Sequence[LaserPointer],
    spots_uv_px: np.ndarray,
    spot_sigma_px: float,
    roll_rad: float,
    pitch_rad: float,
    min_altitude_m: float = 0.0,
    max_altitude_m: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """(L, 3) triangulated points and (L,) altitude sigmas from one stacked triangulation."""
    if not (np.isfinite(spot_sigma_px) and spot_sigma_px > 0):
        raise InvalidArgumentError(f"spot_sigma_px must be positive, got {spot_sigma_px}")
    spots = np.asarray(spots_uv_px, dtype=np.float64).reshape(-1, 2)
    n = len(spots)
    if n != len(lasers):
        raise InvalidArgumentError(
            f"spots_uv_px has {n} rows but there are {len(lasers)} lasers; pass one row "
            "per laser (NaN for a missing spot)"
        )
    step = 0.1
    stacked = np.concatenate([spots, spots + [step, 0.0], spots + [0.0, step]])
    pts3 = triangulate_points(camera, tuple(lasers) * 3, stacked, roll_rad, pitch_rad)
    z = pts3[:, 2]
    dz_du = (z[n : 2 * n] - z[:n]) / step
    dz_dv = (z[2 * n :] - z[:n]) / step
    pts = pts3[:n].copy()
    pts[~((pts[:, 2] >= min_altitude_m) & (pts[:, 2] <= max_altitude_m))] = np.nan
    return pts, spot_sigma_px * np.hypot(dz_du, dz_dv)


def _fit_plane(points: np.ndarray, sigmas: np.ndarray) -> tuple[float, float, tuple[float, float], float] | None:
    """Weighted LS plane ``z = a + b x + c y`` of ``(K, 3)`` points with ``(K,)`` depth sigmas.

    Returns ``(a, sigma_a, (atan b, atan c), relief_var_m2)`` or None if degenerate (collinear).
    ``relief_var_m2``: the points' relief off the plane, ``(sum r^2 - sum sigma^2 (K - 3) / K) / (K - 3)``
    (their residuals less what the depth noise explains, at least 0), NaN for three points (no residual).
    """
    design = np.column_stack([np.ones(len(points)), points[:, 0], points[:, 1]])
    w = 1.0 / sigmas**2
    normal = design.T @ (design * w[:, None])
    eig = np.linalg.eigvalsh(normal)  # the normal matrix is symmetric: its condition number from its eigenvalues
    if not eig[0] > 1e-12 * eig[-1]:
        return None  # collinear spots: no plane
    cov = np.linalg.inv(normal)
    coef = cov @ (design.T @ (w * points[:, 2]))
    dof = len(points) - 3
    relief_var = float("nan")
    if dof > 0:
        resid = points[:, 2] - design @ coef
        noise = float(np.sum(sigmas**2)) * dof / len(points)
        relief_var = max(float(resid @ resid) - noise, 0.0) / dof
    return (
        float(coef[0]),
        float(np.sqrt(cov[0, 0])),
        (float(np.arctan(coef[1])), float(np.arctan(coef[2]))),
        relief_var,
    )


def _consistent(alts: np.ndarray, valid: np.ndarray, sonar: float | None, rel: float) -> np.ndarray:
    """Inlier mask: spots within ``rel`` (relative) of the others' median (or of the sonar)."""
    idx = np.flatnonzero(valid)
    inl = np.zeros(len(alts), dtype=bool)
    if len(idx) == 0:
        return inl
    if len(idx) >= 3:
        ref = float(median0(alts[idx]))
    elif sonar is not None:
        ref = sonar
    elif len(idx) == 2:
        ref = float(np.mean(alts[idx]))
    else:
        inl[idx] = True
        return inl
    inl[idx] = np.abs(alts[idx] - ref) <= rel * ref
    if len(idx) == 2 and sonar is None and inl.sum() < 2:
        inl[:] = False  # two spots that disagree: no way to tell which one is right
    return inl


def fuse_altitude(
    laser_altitudes_m: np.ndarray,
    laser_sigmas_m: np.ndarray,
    sonar_altitude_m: float | None,
    fallback_altitude_m: float,
    config: LaserConfig,
    spots_uv_px: np.ndarray | None = None,
    points_level_m: np.ndarray | None = None,
) -> AltitudeEstimate:
    """Combine the per-spot altitudes, the sonar and the fallback into one image depth Z.

    1. Outliers: with three or more spots, a spot farther than
       ``config.max_relative_disagreement`` (relative) from the median is dropped; with one
       or two spots the sonar value is the reference when there is one; two spots that
       disagree with no sonar are both dropped.
    2. Laser altitude: with three or more agreeing spots and their level-frame points, the
       weighted least-squares seabed plane ``z = a + b x + c y``: altitude ``a`` (the plane
       straight below the camera) and slope ``(atan b, atan c)``; otherwise the
       inverse-variance weighted mean of the spot altitudes.
    3. Sonar (NaN or None = no reading): variance-weighted mean with the laser altitude
       (``config.sonar_sigma_m``), or the sonar alone when no spot agreed.
    4. Neither: ``fallback_altitude_m`` with ``config.fixed_altitude_sigma_m``.

    Parameters
    ----------
    laser_altitudes_m, laser_sigmas_m: ``(L,)`` per spot, NaN for missing spots.
    sonar_altitude_m: the altimeter reading of frames.csv, None or NaN when empty.
    fallback_altitude_m: the configured fixed altitude (sequence.toml ``[vehicle]``).
    config: thresholds and sigmas.
    spots_uv_px: ``(L, 2)`` the spot pixels (NaN rows dropped), returned for the
        inhibition mask.
    points_level_m: ``(L, 3)`` triangulated points (for the plane fit), optional.

    Returns
    -------
    :class:`AltitudeEstimate`.
    """
    alts = np.asarray(laser_altitudes_m, dtype=np.float64).reshape(-1)
    sigs = np.asarray(laser_sigmas_m, dtype=np.float64).reshape(-1)
    if sigs.shape != alts.shape:
        raise InvalidArgumentError(
            f"laser_sigmas_m has shape {sigs.shape}, laser_altitudes_m {alts.shape}: give one sigma per spot"
        )
    if not (np.isfinite(fallback_altitude_m) and fallback_altitude_m > 0):
        raise InvalidMeasurementError(
            f"fallback altitude must be a positive finite number of metres, got {fallback_altitude_m}; "
            "set [vehicle] altitude_m in sequence.toml"
        )
    sonar: float | None = None
    if sonar_altitude_m is not None and not np.isnan(sonar_altitude_m):
        if not (np.isfinite(sonar_altitude_m) and sonar_altitude_m > 0):
            raise InvalidMeasurementError(
                f"sonar altitude must be a positive finite number of metres (or empty), got {sonar_altitude_m}"
            )
        sonar = float(sonar_altitude_m)
    if spots_uv_px is None:
        spots = np.zeros((0, 2))
    else:
        spots = np.asarray(spots_uv_px, dtype=np.float64).reshape(-1, 2)
        spots = spots[np.all(np.isfinite(spots), axis=1)]

    valid = np.isfinite(alts) & np.isfinite(sigs) & (sigs > 0) & (alts > 0)
    inl = _consistent(alts, valid, sonar, float(config.max_relative_disagreement))
    n_in = int(inl.sum())
    laser_alt, laser_sig, slope, relief_var = float("nan"), float("nan"), None, float("nan")
    if n_in >= 3 and points_level_m is not None:
        pts = np.asarray(points_level_m, dtype=np.float64).reshape(-1, 3)
        if len(pts) == len(alts) and np.all(np.isfinite(pts[inl])):
            fit = _fit_plane(pts[inl], sigs[inl])
            if fit is not None:
                laser_alt, laser_sig, slope, relief_var = fit
    if n_in >= 1 and not np.isfinite(laser_alt):
        w = 1.0 / sigs[inl] ** 2
        laser_alt = float(np.sum(w * alts[inl]) / np.sum(w))
        laser_sig = float(1.0 / np.sqrt(np.sum(w)))

    if np.isfinite(laser_alt) and sonar is not None:
        w_l, w_s = 1.0 / laser_sig**2, 1.0 / config.sonar_sigma_m**2
        alt = (w_l * laser_alt + w_s * sonar) / (w_l + w_s)
        return AltitudeEstimate(
            alt,
            float(1.0 / np.sqrt(w_l + w_s)),
            SOURCE_LASER_SONAR,
            spots,
            n_in,
            slope,
            laser_alt,
            relief_var_m2=relief_var,
        )
    if np.isfinite(laser_alt):
        return AltitudeEstimate(
            laser_alt, laser_sig, SOURCE_LASER, spots, n_in, slope, laser_alt, relief_var_m2=relief_var
        )
    if sonar is not None:
        return AltitudeEstimate(sonar, float(config.sonar_sigma_m), SOURCE_SONAR, spots, 0)
    return AltitudeEstimate(float(fallback_altitude_m), float(config.fixed_altitude_sigma_m), SOURCE_FIXED, spots, 0)


class LaserAltimeter:
    """Stateful wrapper: remembers the last altitude to predict where the spots will be.

    Parameters
    ----------
    camera, lasers: the rig of ``sequence.toml``.
    config: :class:`~rovslam.config.LaserConfig`.
    fallback_altitude_m: fixed altitude used when no spot and no sonar value is available,
        and as the first prediction of the spot positions.
    """

    def __init__(
        self, camera: Camera, lasers: Sequence[LaserPointer], config: LaserConfig, fallback_altitude_m: float
    ) -> None:
        if not (np.isfinite(fallback_altitude_m) and fallback_altitude_m > 0):
            raise InvalidArgumentError(
                f"fallback altitude must be a positive number of metres, got {fallback_altitude_m}; "
                "set [vehicle] altitude_m in sequence.toml"
            )
        self.camera = camera
        self.lasers = tuple(lasers)
        self.config = config
        self.fallback_altitude_m = float(fallback_altitude_m)
        self._last_altitude_m = float(fallback_altitude_m)
        self._spots_seen = False  # any laser spot used yet (the spot prediction no longer the fallback's)
        self._frames = 0  # frames searched for spots

    @property
    def last_altitude_m(self) -> float:
        """The altitude the next spot prediction uses (last laser or sonar value)."""
        return self._last_altitude_m

    def reset(self) -> None:
        self._last_altitude_m = self.fallback_altitude_m
        self._spots_seen = False
        self._frames = 0

    def measure(
        self,
        image_rgb: np.ndarray,
        sonar_altitude_m: float | None = None,
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
    ) -> AltitudeEstimate:
        """Altitude of one frame: detect, associate, triangulate, check, fuse (see :func:`fuse_altitude`).

        Parameters
        ----------
        image_rgb: ``(H, W, 3) uint8`` RGB frame (a grey frame has no laser channel: only the
            sonar or the fallback can be used).
        sonar_altitude_m: the frame's sonar altitude, None/NaN when empty; a reading outside the
            plausible range is not used (:func:`sonar_reading_problem`, the reason is in
            ``sonar_rejected`` of the estimate).
        roll_rad, pitch_rad: body attitude (frames.csv), 0 for a level camera.
        """
        cfg = self.config
        img = np.asarray(image_rgb)
        sonar_rejected = sonar_reading_problem(sonar_altitude_m, cfg)
        if sonar_rejected is not None:
            sonar_altitude_m = None
        if img.ndim == 2 or not self.lasers:
            n = len(self.lasers)
            est = fuse_altitude(np.full(n, np.nan), np.full(n, np.nan), sonar_altitude_m, self.fallback_altitude_m, cfg)
        else:
            est = self._measure_at(img, self._last_altitude_m, sonar_altitude_m, roll_rad, pitch_rad)
            if est.n_spots < len(self.lasers) and (
                len(detect_laser_spots(img, None, cfg)) > len(est.spots_uv_px) or self._faint_ladder_due(img)
            ):
                est = self._search_altitudes(img, est, sonar_altitude_m, roll_rad, pitch_rad)
            self._frames += 1
        if est.n_spots:
            self._spots_seen = True
        if est.source != SOURCE_FIXED:
            self._last_altitude_m = est.altitude_m
        return est if sonar_rejected is None else replace(est, sonar_rejected=sonar_rejected)

    def _faint_ladder_due(self, img: np.ndarray) -> bool:
        """Whether to search faint spots over the altitude ladder: until the first spot, every 5th frame,
        when anything in the frame is as red as ``faint_red_excess``.

        Before any spot the prediction is the fallback altitude's, which may be far from the
        vehicle's: a faint spot is searched only near its prediction (bright blobs anywhere
        start the ladder themselves). Every 5th frame bounds the cost when the lasers never show.
        """
        cfg = self.config
        if cfg.faint_red_excess <= 0 or self._spots_seen or self._frames % 5:
            return False
        return cv2.minMaxLoc(red_excess(img))[1] >= cfg.faint_red_excess

    def _measure_at(
        self,
        img: np.ndarray,
        predict_altitude_m: float,
        sonar_altitude_m: float | None,
        roll_rad: float,
        pitch_rad: float,
    ) -> AltitudeEstimate:
        cfg = self.config
        pred = predict_spot_pixels(self.camera, self.lasers, predict_altitude_m, roll_rad, pitch_rad)
        spots = find_faint_spots(img, pred, detect_laser_spots(img, pred, cfg), cfg)
        pts, sig = _points_and_sigmas(
            self.camera,
            self.lasers,
            spots,
            cfg.spot_sigma_px,
            roll_rad,
            pitch_rad,
            cfg.min_altitude_m,
            cfg.max_altitude_m,
        )
        return fuse_altitude(
            pts[:, 2], sig, sonar_altitude_m, self.fallback_altitude_m, cfg, spots_uv_px=spots, points_level_m=pts
        )

    def _search_altitudes(
        self, img: np.ndarray, best: AltitudeEstimate, sonar_altitude_m: float | None, roll_rad: float, pitch_rad: float
    ) -> AltitudeEstimate:
        """Re-predict the spots over a ladder of altitudes (ratio 1.4), nearest the last one first.

        Used only when red blobs are in the image but not where the last altitude puts the
        spots: at start-up with a poor fallback altitude, or after a jump in altitude. Keeps
        the estimate with the most agreeing spots.
        """
        lo = max(self.config.min_altitude_m, 0.25)
        hi = min(self.config.max_altitude_m, 12.0)
        if not lo < hi:
            return best
        ladder = lo * 1.4 ** np.arange(int(np.ceil(np.log(hi / lo) / np.log(1.4))) + 1)
        ladder = ladder[np.argsort(np.abs(np.log(ladder / self._last_altitude_m)))]
        for z in ladder:
            trial = self._measure_at(img, float(z), sonar_altitude_m, roll_rad, pitch_rad)
            if trial.n_spots > best.n_spots:
                best = trial
                if best.n_spots == len(self.lasers):
                    break
        return best
