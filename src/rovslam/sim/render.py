"""Rendering one camera frame of the seabed: geometry, relief, water, lamps, lasers, sensor.

Geometry (exact, inverse mapping): a pixel's viewing ray, after removing lens distortion,
is rotated into the level frame (yaw offset, roll, pitch: ``camera.body_from_camera`` and
``camera.level_from_body``), meets the seabed plane ``altitude_m`` below the camera, and
is rotated by the heading into the world (equation (4) of the paper for a level camera,
``X = x + Z/f R(psi) [m, n]``). For a pinhole camera this chain is one 3x3 homography from
pixels to seabed texels per frame (OpenCV ``warpPerspective``); with distortion the
undistorted pixel grid is precomputed once and pushed through the same homography
(``perspectiveTransform`` + ``remap``). Bilinear sampling of a Gaussian-prefiltered texture
(see :mod:`rovslam.sim.world`) gives the anti-aliasing.

Radiometry (see :mod:`rovslam.sim.water`): seabed albedo x lamp cone x vignetting x
per-channel attenuation with path length, plus backscatter haze; motion blur along the
image motion over the exposure time, forward-scatter blur; marine snow;
the laser spots (saturated red discs with a halo and speckle); shot and read noise;
8-bit quantisation; optional JPEG round trip.

Relief (a world with a :mod:`~rovslam.sim.relief` height field), lamps on the vehicle
(:class:`~rovslam.sim.lighting.LightingParams`) and rolling shutter take the ray-cast path
instead of the homography: every ray ``C + t D`` (camera centre C, world direction D per
unit of depth below the camera, t the depth) is intersected with the relief by Newton steps
on ``t = Z - h(C + t D)`` (``RAY_ITERATIONS`` of them, each one ``cv2.remap`` of the
window of heights and slopes). With slopes under about 3 and fields of view within +-12
degrees the ray meets the relief once and ``1 + grad h . D`` stays well above 0, so three
steps leave far less than a hundredth of a pixel. The rays are cast on a grid of every
``ray_step_px(camera)``-th pixel and interpolated (the depth of the hits is smooth at that
scale); the albedo is sampled at every pixel where its ray lands, the relief's slopes give
the normals for the lamps, and a seabed point ``h`` above the mean plane is seen where a
pinhole camera at ``Z - h`` puts it: a 10 cm stone seen from 1.31 m moves 8 % faster
across the image than the sand beside it. The lasers hit the relief too (Newton per beam).

Everything that does not change from frame to frame (pixel grids, undistortion, vignetting
and lamp maps, the attenuation and haze maps per centimetre of altitude) is computed once
per :class:`FrameRenderer`. :func:`render_frame` is the pure entry point.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np
from scipy.special import erfc

from rovslam.camera import (
    Camera,
    LaserPointer,
    body_from_camera,
    ground_to_pixels,
    level_from_body,
    undistort_pixels,
)
from rovslam.errors import SimulationError
from rovslam.sim._noise import fast_standard_normal
from rovslam.sim.lighting import (
    CAUSTIC_TEXELS,
    LightingParams,
    caustic_pattern,
    lamp_irradiance,
    reference_irradiance,
)
from rovslam.sim.water import WaterParams, marine_snow
from rovslam.sim.world import World

_MAX_TILT_RAD = np.deg2rad(45.0)
_SNOW_SIGMAS_PX = np.array([0.7, 1.5, 3.2, 6.5])  # marine-snow blur levels (particles use the nearest)
RAY_ITERATIONS = 3  # Newton steps of the ray-relief intersection
_LASER_ITERATIONS = 5  # the same for the few laser beams (to full precision)
_MIN_CLEARANCE_M = 0.05  # the camera must stay this far above the highest relief


@dataclass(frozen=True)
class Pose:
    """Camera pose: world position (m), altitude above the seabed (m), heading, roll, pitch (rad)."""

    x_m: float
    y_m: float
    altitude_m: float
    heading_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.x_m, self.y_m, self.altitude_m, self.heading_rad, self.roll_rad, self.pitch_rad)
        if not all(np.isfinite(v) for v in vals):
            raise SimulationError(f"pose values must be finite, got {vals}")
        if self.altitude_m <= 0.05:
            raise SimulationError(f"pose altitude_m must be > 0.05 m above the seabed, got {self.altitude_m}")
        if abs(self.roll_rad) > _MAX_TILT_RAD or abs(self.pitch_rad) > _MAX_TILT_RAD:
            raise SimulationError(
                f"roll and pitch must be within +-45 degrees for a downward camera, got "
                f"{np.rad2deg(self.roll_rad):.1f}, {np.rad2deg(self.pitch_rad):.1f} degrees"
            )


@dataclass(frozen=True)
class SensorParams:
    """Camera sensor, lens and lamps."""

    exposure_gain: float = 0.9  # DN per unit albedo x 255 under the lamps, before the water
    vignetting_power: float = 4.0  # cos^p(off-axis angle) lens falloff
    light_corner_ratio: float = 0.62  # lamp-cone irradiance at the image corner / at the cone centre
    light_centre_frac: tuple[float, float] = (0.10, -0.14)  # cone centre offset (u, v), half-image units
    exposure_s: float = 0.010  # motion blur: image motion integrated over this time
    antialias: float = 0.42  # prefilter sigma, in texels per (texels per pixel)
    shot_noise_dn: float = 0.06  # shot-noise variance per DN of signal
    read_noise_dn: float = 1.3  # read-noise standard deviation, DN
    jpeg_quality: int | None = None  # JPEG round trip inside the camera (None: none)
    psf_sigma_px: float = 0.0  # lens point-spread function: Gaussian core (0: none)
    psf_glare_fraction: float = 0.0  # ... and a wide veiling-glare skirt holding this fraction of the light
    psf_glare_sigma_px: float = 12.0
    readout_s: float = 0.0  # rolling shutter: time from the first to the last row (0: global shutter)

    def __post_init__(self) -> None:
        for name in ("exposure_gain", "vignetting_power", "exposure_s", "antialias", "shot_noise_dn",
                     "read_noise_dn", "psf_sigma_px", "psf_glare_sigma_px", "readout_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"SensorParams.{name} must be a finite number >= 0, got {v}")
        if not (0.0 < self.light_corner_ratio <= 1.0):
            raise SimulationError(
                f"SensorParams.light_corner_ratio must be in (0, 1], got {self.light_corner_ratio}"
            )
        if self.jpeg_quality is not None and not (1 <= self.jpeg_quality <= 100):
            raise SimulationError(f"SensorParams.jpeg_quality must be in 1..100 or None, got {self.jpeg_quality}")
        if not (0.0 <= self.psf_glare_fraction < 1.0):
            raise SimulationError(f"SensorParams.psf_glare_fraction must be in [0, 1), got {self.psf_glare_fraction}")

    @classmethod
    def ideal(cls) -> "SensorParams":
        """Flat, noiseless, blur-free sensor (for geometry tests): unit gain, no falloff, no noise."""
        return cls(exposure_gain=1.0, vignetting_power=0.0, light_corner_ratio=1.0, exposure_s=0.0,
                   shot_noise_dn=0.0, read_noise_dn=0.0)


@dataclass(frozen=True)
class LaserSpotParams:
    """How a laser spot looks: a saturated red disc (the beam footprint) with a faint halo and speckle.

    The core is the beam's footprint on the seabed, ``spot_diameter_mm`` across, seen
    through the optics (edge blur ``optics_sigma_px``): far brighter than full scale, so it
    saturates the red channel with a steep edge. The halo is light scattered forward in
    the water. Green and blue get a little crosstalk of the (clipped) red.
    """

    peak_dn: float = 3000.0  # core irradiance before the water (saturates the red channel by far)
    spot_diameter_mm: float = 4.0  # beam footprint on the seabed (about 3.3 px at 1.31 m)
    optics_sigma_px: float = 0.45  # lens / sensor blur of the disc edge
    halo_fraction: float = 0.03  # forward-scattered glow, relative to the core
    halo_sigma_px: float = 3.0
    speckle: float = 0.35  # multiplicative speckle contrast (off when noise_free)
    crosstalk_green: float = 0.025  # fraction of the (clipped) red reaching the green pixels
    crosstalk_blue: float = 0.01

    def __post_init__(self) -> None:
        for name in ("peak_dn", "spot_diameter_mm", "optics_sigma_px", "halo_fraction", "halo_sigma_px", "speckle",
                     "crosstalk_green", "crosstalk_blue"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise SimulationError(f"LaserSpotParams.{name} must be a finite number >= 0, got {v}")
        if self.optics_sigma_px < 0.1:
            raise SimulationError(f"LaserSpotParams.optics_sigma_px must be >= 0.1 px, got {self.optics_sigma_px}")


def ray_step_px(camera: Camera) -> int:
    """Pixel step of the ray-cast grid: 1 for small images, 2 from 300 px wide, 4 from 1200 px (if it divides).

    The relief seen through the camera is smooth on that scale (a 10 cm stone spans tens of
    pixels), so the depth of the hits is interpolated bilinearly between grid nodes (its
    error is under a hundredth of a pixel on the presets), while the albedo is sampled at
    every pixel.
    """
    for step, min_width in ((4, 1200), (2, 300)):
        if camera.width_px >= min_width and camera.width_px % step == 0 and camera.height_px % step == 0:
            return step
    return 1


@dataclass(frozen=True)
class _Hits:
    """Where the rays meet the seabed (ray-cast path): (h, w) float32 arrays on the coarse ray grid unless noted."""

    depth_m: np.ndarray  # t: depth of the hit below the camera
    albedo: np.ndarray  # (H, W, 3) uint8 at full resolution, the prefiltered texture at the hit
    slopes: np.ndarray | None  # (H, W, 2) world dh/dx, dh/dy at the hit; None on a flat seabed
    ax: np.ndarray  # level-frame ray slopes: the hit is (t ax, t ay, t) from the camera
    ay: np.ndarray
    sec: np.ndarray  # sqrt(1 + ax^2 + ay^2): path length per unit depth
    north_m: np.ndarray  # world position of the hit
    east_m: np.ndarray
    relief_maps: tuple | None  # (relief canvas, row map, col map, world D / texel (x, y)) for the shadow search


class FrameRenderer:
    """Precomputed renderer for one camera, water, sensor, laser-spot and lighting model.

    ``lighting`` None keeps the lamp cone of :class:`SensorParams` fixed to the image (the
    original model); with :class:`~rovslam.sim.lighting.LightingParams` the lamps ride on
    the vehicle and light the relief.
    """

    def __init__(
        self,
        camera: Camera,
        water: WaterParams | None = None,
        sensor: SensorParams | None = None,
        spots: LaserSpotParams | None = None,
        lighting: LightingParams | None = None,
    ) -> None:
        self.camera = camera
        self.water = water if water is not None else WaterParams()
        self.sensor = sensor if sensor is not None else SensorParams()
        self.spots = spots if spots is not None else LaserSpotParams()
        self.lighting = lighting
        h, w = camera.height_px, camera.width_px
        self._k_inv = np.linalg.inv(camera.K)
        self._body_cam = body_from_camera(camera)
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        pix = np.column_stack([uu.ravel(), vv.ravel()])
        if camera.has_distortion:
            ideal = undistort_pixels(camera, pix)
            self._ideal_pts = ideal.astype(np.float32).reshape(-1, 1, 2)
        else:
            ideal = pix
            self._ideal_pts = None
        # Border pixels (every 4th, plus corners), to bound the footprint of a frame.
        border = np.zeros((h, w), dtype=bool)
        border[0, ::4] = border[-1, ::4] = border[::4, 0] = border[::4, -1] = True
        border[0, -1] = border[-1, 0] = border[-1, -1] = True
        self._border_ideal = ideal[border.ravel()]
        # Frame-independent radiometric maps on the ideal (undistorted) rays.
        xn = ((ideal[:, 0] - camera.cx_px) / camera.fx_px).reshape(h, w)
        yn = ((ideal[:, 1] - camera.cy_px) / camera.fy_px).reshape(h, w)
        self._sec = np.sqrt(1.0 + xn * xn + yn * yn)  # path length per unit depth (level camera)
        half_x = max(camera.cx_px, w - 1 - camera.cx_px) / camera.fx_px
        half_y = max(camera.cy_px, h - 1 - camera.cy_px) / camera.fy_px
        ox, oy = self.sensor.light_centre_frac
        r2 = ((xn - ox * half_x) ** 2 + (yn - oy * half_y) ** 2) / (half_x**2 + half_y**2)
        self._cone = self.sensor.light_corner_ratio**r2  # lamp irradiance, 1 at the cone centre
        self._vignette = self._sec ** (-self.sensor.vignetting_power)
        # Ray-cast path: geometry and lighting on a coarse grid (every ray_step-th pixel, with a
        # one-sample apron so that upsampling is exact for linear fields up to the image border).
        step = ray_step_px(camera)
        self._ray_step = step
        pos_u = step * (np.arange(w // step + 2) - 1.0) + 0.5 * (step - 1)
        pos_v = step * (np.arange(h // step + 2) - 1.0) + 0.5 * (step - 1)
        cu, cv = np.meshgrid(pos_u, pos_v)
        coarse = undistort_pixels(camera, np.column_stack([cu.ravel(), cv.ravel()]))
        self._xn = ((coarse[:, 0] - camera.cx_px) / camera.fx_px).reshape(cu.shape).astype(np.float32)
        self._yn = ((coarse[:, 1] - camera.cy_px) / camera.fy_px).reshape(cu.shape).astype(np.float32)
        self._vignette_c = (1.0 + self._xn**2 + self._yn**2) ** np.float32(-0.5 * self.sensor.vignetting_power)
        r2_c = ((self._xn - ox * half_x) ** 2 + (self._yn - oy * half_y) ** 2) / (half_x**2 + half_y**2)
        self._haze_pattern_c = np.sqrt(self.sensor.light_corner_ratio**r2_c).astype(np.float32)  # as the plane path
        self._row_frac = ((pos_v - 0.5 * (h - 1)) / max(h - 1, 1))[:, None]
        self._level_untilted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._e_ref = reference_irradiance(lighting) if lighting is not None else 1.0
        self._maps: OrderedDict[int, tuple[np.ndarray, np.ndarray, bool]] = OrderedDict()
        self._lock = threading.Lock()
        self._lasers_cache: dict[tuple[LaserPointer, ...], tuple[np.ndarray, np.ndarray]] = {}

    # ------------------------------------------------------------------ geometry
    def homography(self, pose: Pose, texel_m: float) -> np.ndarray:
        """(3, 3) map from ideal pixels (u, v, 1) to global texel coordinates (col, row, 1)."""
        r_lc = level_from_body(pose.roll_rad, pose.pitch_rad) @ self._body_cam
        c, s = np.cos(pose.heading_rad), np.sin(pose.heading_rad)
        z = pose.altitude_m
        # Ray q (level frame) -> world [Z R(psi) q_xy + (x, y) q_z ; q_z]  (eq. 4 in homogeneous form).
        world = np.array([[z * c, -z * s, pose.x_m], [z * s, z * c, pose.y_m], [0.0, 0.0, 1.0]])
        to_texel = np.array([[0.0, 1.0 / texel_m, 0.0], [1.0 / texel_m, 0.0, 0.0], [0.0, 0.0, 1.0]])
        return to_texel @ world @ r_lc @ self._k_inv

    def _sample_seabed(self, world: World, pose: Pose) -> np.ndarray:
        """(H, W, 3) uint8: the prefiltered seabed albedo seen by every pixel."""
        cam = self.camera
        hom = self.homography(pose, world.texel_m)
        b = cv2.perspectiveTransform(self._border_ideal.reshape(-1, 1, 2), hom).reshape(-1, 2)
        if not np.all(np.isfinite(b)):
            raise SimulationError("the camera does not see the seabed at this pose (tilt too large)")
        texels_per_px = pose.altitude_m / (cam.focal_px * world.texel_m)
        blur = self.sensor.antialias * texels_per_px if texels_per_px > 1.0 else 0.0
        canvas = world.canvas(
            int(np.floor(b[:, 1].min())) - 1, int(np.ceil(b[:, 1].max())) + 2,
            int(np.floor(b[:, 0].min())) - 1, int(np.ceil(b[:, 0].max())) + 2,
            blur,
        )
        shift = np.array([[1.0, 0.0, -canvas.col0], [0.0, 1.0, -canvas.row0], [0.0, 0.0, 1.0]])
        hom = shift @ hom
        size = (cam.width_px, cam.height_px)
        if self._ideal_pts is None:
            return cv2.warpPerspective(
                canvas.texels, hom, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
        maps = cv2.perspectiveTransform(self._ideal_pts, hom).reshape(cam.height_px, cam.width_px, 2)
        return cv2.remap(canvas.texels, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    # ------------------------------------------------------------------ ray-cast geometry
    def uses_rays(self, world: World) -> bool:
        """Whether frames of ``world`` take the ray-cast path (relief, vehicle lamps or rolling shutter)."""
        return world.relief is not None or self.lighting is not None or self.sensor.readout_s > 0

    def _level_rays(self, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ax, ay, sec) float32 on the ray grid: level-frame ray slopes and the path per unit depth."""
        untilted = pose.roll_rad == 0.0 and pose.pitch_rad == 0.0
        if untilted and self._level_untilted is not None:
            return self._level_untilted
        r = level_from_body(pose.roll_rad, pose.pitch_rad) @ self._body_cam
        q = [float(r[i, 0]) * self._xn + float(r[i, 1]) * self._yn + np.float32(r[i, 2]) for i in range(3)]
        if not np.all(q[2] > 1e-3):
            raise SimulationError("the camera does not see the seabed at this pose (tilt too large)")
        inv = 1.0 / q[2]
        ax, ay = q[0] * inv, q[1] * inv
        out = (ax, ay, np.sqrt(1.0 + ax * ax + ay * ay))
        if untilted:
            self._level_untilted = out
        return out

    def _cast_rays(self, world: World, pose: Pose, velocity_mps: tuple[float, float], yaw_rate_radps: float) -> _Hits:
        """Intersect the rays of the ray grid with the relief (Newton) and sample the albedo at every pixel."""
        cam, z = self.camera, pose.altitude_m
        ax, ay, sec = self._level_rays(pose)
        # Per-row pose under a rolling shutter: row v is exposed readout_s * row_frac(v) after mid-frame.
        if self.sensor.readout_s > 0:
            dt = self.sensor.readout_s * self._row_frac  # (H, 1)
            psi = pose.heading_rad + yaw_rate_radps * dt
            c0, s0 = np.cos(pose.heading_rad), np.sin(pose.heading_rad)
            vx = c0 * velocity_mps[0] - s0 * velocity_mps[1]
            vy = s0 * velocity_mps[0] + c0 * velocity_mps[1]
            cx, cy = pose.x_m + vx * dt, pose.y_m + vy * dt
            cos_v, sin_v = np.cos(psi).astype(np.float32), np.sin(psi).astype(np.float32)
        else:
            cx, cy = np.array([[pose.x_m]]), np.array([[pose.y_m]])
            cos_v, sin_v = np.float32(np.cos(pose.heading_rad)), np.float32(np.sin(pose.heading_rad))
        dx = cos_v * ax - sin_v * ay  # world direction per unit depth, north
        dy = sin_v * ax + cos_v * ay  # east
        h_lo, h_hi = world.relief.height_range_m if world.relief is not None else (0.0, 0.0)
        t_lo, t_hi = z - h_hi, z - h_lo
        if t_lo < _MIN_CLEARANCE_M:
            raise SimulationError(
                f"the relief reaches {h_hi:.3f} m above the mean seabed: the camera at {z:.3f} m would touch it; "
                f"fly higher or lower the relief"
            )
        box = (float(cx.min()) + min(t_lo * float(dx.min()), t_hi * float(dx.min())),
               float(cx.max()) + max(t_lo * float(dx.max()), t_hi * float(dx.max())),
               float(cy.min()) + min(t_lo * float(dy.min()), t_hi * float(dy.min())),
               float(cy.max()) + max(t_lo * float(dy.max()), t_hi * float(dy.max())))
        relief_maps = None
        slopes = None
        t = np.float32(z)
        if world.relief is not None:
            inv_r = 1.0 / world.relief.texel_m
            rc = world.relief_canvas(int(np.floor(box[0] * inv_r)) - 1, int(np.ceil(box[1] * inv_r)) + 2,
                                     int(np.floor(box[2] * inv_r)) - 1, int(np.ceil(box[3] * inv_r)) + 2)
            a_row = (cx * inv_r - rc.row0).astype(np.float32)
            a_col = (cy * inv_r - rc.col0).astype(np.float32)
            b_row, b_col = dx * np.float32(inv_r), dy * np.float32(inv_r)
            zf = np.float32(z)
            for _ in range(RAY_ITERATIONS):  # Newton on g(t) = t - Z + h(C + t D), g' = 1 + grad h . D
                hs = cv2.remap(rc.relief, a_col + t * b_col, a_row + t * b_row, cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)
                h, sx, sy = cv2.split(hs)
                dg = np.maximum(1.0 + sx * dx + sy * dy, np.float32(0.25))
                t = t - (t - zf + h) / dg
            row_map, col_map = a_row + t * b_row, a_col + t * b_col
            slopes = hs[..., 1:]  # at the last step's t: the Newton step moved t by far less than a texel
            relief_maps = (rc, row_map, col_map, b_row, b_col)
        else:
            t = np.full(ax.shape, z, dtype=np.float32)
        north, east = cx + t * dx, cy + t * dy
        # The albedo where the rays land, prefiltered for the pixel footprint as on the plane path;
        # its map is interpolated from the ray grid to every pixel (exact where it is linear).
        tex = world.texel_m
        texels_per_px = z / (cam.focal_px * tex)
        blur = self.sensor.antialias * texels_per_px if texels_per_px > 1.0 else 0.0
        # (a prefilter of at least 0.8 texel allows keeping every 2nd texel: a 4x smaller canvas to sample)
        step = 2 if blur >= 0.8 else 1
        canvas = world.canvas(int(np.floor(box[0] / tex)) - 2, int(np.ceil(box[1] / tex)) + 3,
                              int(np.floor(box[2] / tex)) - 2, int(np.ceil(box[3] / tex)) + 3, blur, step)
        inv_t = 1.0 / (tex * step)
        col_a = ((cy / tex - canvas.col0) / step).astype(np.float32) + t * (dy * np.float32(inv_t))
        row_a = ((cx / tex - canvas.row0) / step).astype(np.float32) + t * (dx * np.float32(inv_t))
        albedo = cv2.remap(canvas.texels, self.upsample(cv2.merge([col_a, row_a])), None, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        return _Hits(t, albedo, slopes, ax, ay, sec, north.astype(np.float32), east.astype(np.float32), relief_maps)

    def upsample(self, grid: np.ndarray) -> np.ndarray:
        """A field on the ray grid (with its apron) -> ``(H, W[, C])`` at every pixel, bilinear.

        Exact for fields linear in the pixel coordinates (the grid nodes sit at pixel
        positions ``step * j + (step - 1) / 2``, cv2.resize's sample positions).
        """
        s, cam = self._ray_step, self.camera
        if s == 1:
            return np.ascontiguousarray(grid[1:-1, 1:-1])
        big = cv2.resize(grid, (grid.shape[1] * s, grid.shape[0] * s), interpolation=cv2.INTER_LINEAR)
        return big[s : s + cam.height_px, s : s + cam.width_px]

    # ------------------------------------------------------------------ radiometry
    def _lamp_gain(self, world: World, pose: Pose, hits: _Hits, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(gain, haze), (H, W, 3) float32 each, under the vehicle's lamps.

        The gain is DN per DN of albedo (as the plane path's), the haze the backscatter added
        over the range of each ray to the seabed (the plane path's model, with the relief's ranges).
        """
        lp, wp, sp = self.lighting, self.water, self.sensor
        t, ax, ay = hits.depth_m, hits.ax, hits.ay
        px, py = t * ax, t * ay
        c, s = float(np.cos(pose.heading_rad)), float(np.sin(pose.heading_rad))
        if hits.slopes is not None:  # upward unit normal in the level frame (z down)
            gx, gy = hits.slopes[..., 0], hits.slopes[..., 1]
            glx, gly = c * gx + s * gy, -s * gx + c * gy
            inv_n = 1.0 / np.sqrt(1.0 + glx * glx + gly * gly)
            nx, ny, nz = -glx * inv_n, -gly * inv_n, -inv_n
        else:
            nx = ny = np.float32(0.0)
            nz = np.float32(-1.0)
        r_lb = level_from_body(pose.roll_rad, pose.pitch_rad)
        total = np.zeros(t.shape, dtype=np.float32)
        r_sum = np.zeros(t.shape, dtype=np.float32)
        for lamp in lp.lamps:
            pos = r_lb @ np.asarray(lamp.position_m, dtype=np.float64)
            axis = r_lb @ (np.asarray(lamp.direction, dtype=np.float64) / np.linalg.norm(lamp.direction))
            e, r, vec = lamp_irradiance(pos, axis, lamp.beam_exponent, px, py, t, nx, ny, nz)
            if lp.shadow_samples > 0 and hits.relief_maps is not None:
                e = e * self._lamp_visibility(world, pose, hits, vec)
            total += np.float32(lamp.intensity / self._e_ref) * e
            r_sum += r
        r_cam = t * hits.sec
        path = r_cam + r_sum * np.float32(1.0 / len(lp.lamps))
        base = np.float32(sp.exposure_gain) * self._vignette_c * (total + np.float32(lp.ambient))
        chans = [base * np.exp(np.float32(-a) * path) for a in wp.attenuation_per_m]
        if lp.caustics is not None:
            sun = self._caustics(world, hits, t_s) * (np.float32(sp.exposure_gain) * self._vignette_c)
            chans = [ch + np.float32(k) * sun * np.exp(np.float32(-a) * r_cam)
                     for ch, k, a in zip(chans, lp.caustics.rgb, wp.attenuation_per_m)]
        veil = (np.float32(255.0 * sp.exposure_gain) * self._haze_pattern_c
                * (1.0 - np.exp(np.float32(-wp.backscatter_per_m) * r_cam)))
        haze = [np.float32(b) * veil for b in wp.backscatter_rgb]
        return self.upsample(cv2.merge(chans)), self.upsample(cv2.merge(haze))

    def _lamp_visibility(self, world: World, pose: Pose, hits: _Hits, vec) -> np.ndarray:
        """(H, W) float32 in [0, 1]: how much of one lamp reaches each hit past the relief (soft cast shadow).

        Steps from the hit towards the lamp until the light ray has risen above the highest
        relief, and takes the largest height by which the relief pokes above the light ray.
        """
        lp = self.lighting
        rc, row_map, col_map, b_row, b_col = hits.relief_maps
        lx, ly, lz = vec
        c, s = float(np.cos(pose.heading_rad)), float(np.sin(pose.heading_rad))
        inv_r = np.float32(1.0 / world.relief.texel_m)
        lrow, lcol = (c * lx - s * ly) * inv_r, (s * lx + c * ly) * inv_r  # P -> lamp, in relief texels
        h_lo, h_hi = world.relief.height_range_m
        h_p = np.float32(pose.altitude_m) - hits.depth_m
        rise_per_step = 1.0 / np.maximum(-lz, np.float32(1e-3))  # tau per metre of rise
        occl = np.full(h_p.shape, -1.0, dtype=np.float32)
        n = lp.shadow_samples
        for k in range(1, n + 1):
            rise = np.float32((h_hi - h_lo) * (k / n) ** 2)
            tau = rise * rise_per_step
            h_q = cv2.remap(rc.heights, col_map + tau * lcol, row_map + tau * lrow, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
            occl = np.maximum(occl, h_q - (h_p + rise))
        return np.clip(1.0 - occl * np.float32(1.0 / lp.shadow_softness_m), 0.0, 1.0)

    def _caustics(self, world: World, hits: _Hits, t_s: float) -> np.ndarray:
        """(H, W) float32 sunlight on the seabed: two drifting layers of the caustic network, mean ``strength``."""
        cp = self.lighting.caustics
        pattern = caustic_pattern(world.seed)
        k = np.float32(CAUSTIC_TEXELS / (4.0 * cp.scale_m))  # pattern texels per metre (4 cells per period)
        out = np.zeros(hits.depth_m.shape, dtype=np.float32)
        for angle, stretch, sign in ((0.0, 1.0, 1.0), (2.1, 1.37, -0.7)):
            ca, sa = np.float32(np.cos(angle) * stretch * k), np.float32(np.sin(angle) * stretch * k)
            ox = (sign * cp.drift_mps[0] * t_s) * float(k)
            oy = (sign * cp.drift_mps[1] * t_s) * float(k)
            u = np.mod(ca * hits.east_m - sa * hits.north_m - np.float32(oy), np.float32(CAUSTIC_TEXELS))
            v = np.mod(sa * hits.east_m + ca * hits.north_m - np.float32(ox), np.float32(CAUSTIC_TEXELS))
            out += cv2.remap(pattern, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out * np.float32(0.5 * cp.strength)

    def _radiometry(self, altitude_m: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """(gain (H, W, 3) f32, haze (H, W, 3) f32, has_haze) for the altitude rounded to 1 cm."""
        key = int(round(altitude_m * 100.0))
        with self._lock:
            hit = self._maps.get(key)
            if hit is not None:
                self._maps.move_to_end(key)
                return hit
        z = key / 100.0
        wp, sp = self.water, self.sensor
        rng_m = z * self._sec  # range from the camera to the seabed along each ray
        att = np.exp(-np.asarray(wp.attenuation_per_m)[None, None, :] * wp.light_path_factor * rng_m[..., None])
        light = sp.exposure_gain * self._cone * self._vignette
        gain = (light[..., None] * att).astype(np.float32)
        haze_level = 255.0 * sp.exposure_gain * np.sqrt(self._cone) * (1.0 - np.exp(-wp.backscatter_per_m * rng_m))
        haze = (haze_level[..., None] * np.asarray(wp.backscatter_rgb)[None, None, :]).astype(np.float32)
        entry = (gain, haze, bool(np.any(haze > 0)))
        with self._lock:
            self._maps[key] = entry
            while len(self._maps) > 48:
                self._maps.popitem(last=False)
        return entry

    def _motion_kernel(self, pose: Pose, velocity_mps: tuple[float, float]) -> np.ndarray | None:
        """Motion blur kernel: the seabed's image motion over the exposure (a line), or None if < 0.25 px."""
        surge, sway = velocity_mps
        k = self.camera.focal_px * self.sensor.exposure_s / pose.altitude_m
        du, dv = -sway * k, surge * k  # the seabed moves against the vehicle ("mirrored motion")
        length = float(np.hypot(du, dv))
        if length < 0.25:
            return None
        half = int(np.ceil(length / 2.0)) + 1
        size = 2 * half + 1
        kern = np.zeros((size, size), dtype=np.float64)
        t = np.linspace(-0.5, 0.5, max(2, int(np.ceil(length * 4.0))))
        px, py = half + du * t, half + dv * t
        x0, y0 = np.floor(px).astype(int), np.floor(py).astype(int)
        fx, fy = px - x0, py - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy),
                            (1, 1, fx * fy)):
            np.add.at(kern, (y0 + dy, x0 + dx), wgt)  # bilinear splat of points along the line
        return (kern / kern.sum()).astype(np.float32)

    def laser_pixels(
        self, pose: Pose, lasers: Sequence[LaserPointer], world: World | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where each laser ray meets the seabed: ((N, 2) pixels (u, v), (N,) path length m).

        On a world with relief the beams hit the relief (see :meth:`laser_hits`).
        """
        uv, path, _ = self.laser_hits(pose, lasers, world)
        return uv, path

    def laser_hits(
        self, pose: Pose, lasers: Sequence[LaserPointer], world: World | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """((N, 2) pixels (u, v), (N,) path length m, (N,) depth of the hit below the camera m) per laser.

        Flat seabed: the beam meets the plane ``altitude_m`` below the camera. With relief:
        the root of ``o_z + t d_z = Z - h(hit(t))`` (beam origin o, direction d; Newton steps).
        """
        if not lasers:
            return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        key = tuple(lasers)
        if key not in self._lasers_cache:
            self._lasers_cache[key] = (
                np.array([lp.origin_m for lp in lasers], dtype=np.float64),
                np.array([lp.unit_direction for lp in lasers]),
            )
        origin_b, dir_b = self._lasers_cache[key]
        r_lb = level_from_body(pose.roll_rad, pose.pitch_rad)
        o, d = origin_b @ r_lb.T, dir_b @ r_lb.T
        t = (pose.altitude_m - o[:, 2]) / d[:, 2]  # ray parameter at the seabed plane z = Z (level frame)
        if world is None or world.relief is None:
            hit = o + t[:, None] * d
            uv = ground_to_pixels(self.camera, hit[:, :2], pose.altitude_m, pose.roll_rad, pose.pitch_rad)
            path = t + np.linalg.norm(hit, axis=1)  # beam down to the seabed, then back to the lens
            return uv, path, np.full(len(t), pose.altitude_m)
        # Newton on g(t) = o_z + t d_z - Z + h(x(t)) over the relief window around the beams.
        c, s = np.cos(pose.heading_rad), np.sin(pose.heading_rad)
        h_lo, h_hi = world.relief.height_range_m
        ends = np.concatenate([o + ((pose.altitude_m - hh - o[:, 2]) / d[:, 2])[:, None] * d for hh in (h_lo, h_hi)])
        inv = 1.0 / world.relief.texel_m
        rows = (pose.x_m + c * ends[:, 0] - s * ends[:, 1]) * inv
        cols = (pose.y_m + s * ends[:, 0] + c * ends[:, 1]) * inv
        rc = world.relief_canvas(int(np.floor(rows.min())) - 1, int(np.ceil(rows.max())) + 2,
                                 int(np.floor(cols.min())) - 1, int(np.ceil(cols.max())) + 2)
        dn, de = c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]  # beam direction, world north / east
        for _ in range(_LASER_ITERATIONS):
            hit = o + t[:, None] * d
            h, sn, se = _bilinear(rc.relief, (pose.x_m + c * hit[:, 0] - s * hit[:, 1]) * inv - rc.row0,
                                  (pose.y_m + s * hit[:, 0] + c * hit[:, 1]) * inv - rc.col0).T
            g = o[:, 2] + t * d[:, 2] - pose.altitude_m + h
            t = t - g / np.maximum(d[:, 2] + sn * dn + se * de, 0.25 * d[:, 2])
        hit = o + t[:, None] * d
        # The hit seen from the camera: its ray at unit depth, projected (ground_to_pixels at depth 1).
        uv = ground_to_pixels(self.camera, hit[:, :2] / hit[:, 2:3], 1.0, pose.roll_rad, pose.pitch_rad)
        return uv, t + np.linalg.norm(hit, axis=1), hit[:, 2]

    def _add_lasers(self, img: np.ndarray, pose: Pose, lasers, rng, noise_free: bool, world: World | None) -> None:
        sp, cam = self.spots, self.camera
        uv, path, depth = self.laser_hits(pose, lasers, world)
        radii = 0.5 * sp.spot_diameter_mm * 1e-3 * cam.focal_px / depth  # disc radius of each spot, px
        rad = int(np.ceil(max(3.0 * sp.halo_sigma_px, float(radii.max(initial=0.0)) + 4.0 * sp.optics_sigma_px))) + 1
        off = np.arange(-rad, rad + 1, dtype=np.float64)
        h, w = img.shape[:2]
        a_red = self.water.attenuation_per_m[0]
        for (u, v), p_m, radius in zip(uv, path, radii):
            if not (np.isfinite(u) and np.isfinite(v)) or not (-rad <= u < w + rad and -rad <= v < h + rad):
                continue
            iu, iv = int(round(u)), int(round(v))
            dx = (iu + off - u)[None, :]
            dy = (iv + off - v)[:, None]
            r = np.sqrt(dx * dx + dy * dy)
            peak = sp.peak_dn * np.exp(-a_red * p_m)
            # Disc of the beam footprint with an erf edge (the optics' Gaussian blur), plus the halo.
            spot = peak * (0.5 * erfc((r - radius) / (np.sqrt(2.0) * sp.optics_sigma_px))
                           + sp.halo_fraction * np.exp(-(r * r) / (2.0 * sp.halo_sigma_px**2)))
            if not noise_free and sp.speckle > 0:
                spot *= np.maximum(1.0 + sp.speckle * fast_standard_normal(rng, spot.shape), 0.0)
            r0, r1 = max(0, iv - rad), min(h, iv + rad + 1)
            c0, c1 = max(0, iu - rad), min(w, iu + rad + 1)
            if r0 >= r1 or c0 >= c1:
                continue
            patch = spot[r0 - (iv - rad): r1 - (iv - rad), c0 - (iu - rad): c1 - (iu - rad)].astype(np.float32)
            clipped = np.minimum(patch, 255.0)
            img[r0:r1, c0:c1, 0] += patch
            img[r0:r1, c0:c1, 1] += sp.crosstalk_green * clipped
            img[r0:r1, c0:c1, 2] += sp.crosstalk_blue * clipped

    def _add_snow(self, img: np.ndarray, world: World, pose: Pose, t_s: float) -> None:
        cam, wp = self.camera, self.water
        reach = 0.5 * np.hypot(cam.width_px, cam.height_px) * pose.altitude_m / cam.focal_px + 0.05
        snow = marine_snow(world.seed, wp, t_s, pose.x_m, pose.y_m, pose.altitude_m, pose.heading_rad, reach)
        if len(snow.depth_m) == 0:
            return
        d = snow.depth_m
        uv = ground_to_pixels(cam, np.column_stack([snow.forward_m / d, snow.starboard_m / d]), 1.0,
                              pose.roll_rad, pose.pitch_rad)
        f = cam.focal_px
        defocus = wp.lens_aperture_mm * 1e-3 * f * np.abs(1.0 / d - 1.0 / pose.altitude_m)
        size = f * snow.diameter_m / d
        sigma = np.sqrt((defocus / 2.5) ** 2 + (size / 2.5) ** 2 + 0.5**2)
        energy = (wp.marine_snow_energy * (snow.diameter_m / 1e-3) ** 2 * (0.6 / d) ** 2
                  * np.exp(-wp.attenuation_per_m[1] * wp.light_path_factor * (d - 0.6)))
        h, w = img.shape[:2]
        u, v = uv[:, 0], uv[:, 1]
        ok = np.isfinite(u) & (u > -3 * sigma) & (u < w - 1 + 3 * sigma) & (v > -3 * sigma) & (v < h - 1 + 3 * sigma)
        if not ok.any():
            return
        u, v, sigma, energy = u[ok], v[ok], sigma[ok], energy[ok]
        level = np.argmin(np.abs(np.log(sigma)[:, None] - np.log(_SNOW_SIGMAS_PX)[None, :]), axis=1)
        # Bilinear splat of every particle's energy into one layer per blur level (one bincount),
        # each layer blurred by its level's Gaussian (normalised: a blob keeps its energy).
        hh, ww = h + 2, w + 2  # one-pixel apron
        x0, y0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
        fx, fy = u - x0, v - y0
        cols = np.clip(np.concatenate([x0, x0 + 1, x0, x0 + 1]) + 1, 0, ww - 1)
        rows = np.clip(np.concatenate([y0, y0, y0 + 1, y0 + 1]) + 1, 0, hh - 1)
        wts = np.concatenate([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]) * np.tile(energy, 4)
        key = (np.tile(level, 4) * hh + rows) * ww + cols
        layers = np.bincount(key, wts, minlength=len(_SNOW_SIGMAS_PX) * hh * ww)
        layers = layers.astype(np.float32).reshape(len(_SNOW_SIGMAS_PX), hh, ww)
        total = np.zeros((h, w), dtype=np.float32)
        for lev in np.unique(level):
            total += cv2.GaussianBlur(layers[lev], (0, 0), float(_SNOW_SIGMAS_PX[lev]),
                                      borderType=cv2.BORDER_CONSTANT)[1:-1, 1:-1]
        img += total[..., None] * np.array([0.75, 1.0, 0.95], dtype=np.float32)

    # ------------------------------------------------------------------ the frame
    def _radiance_plane(self, world: World, pose: Pose, velocity_mps: tuple[float, float]) -> np.ndarray:
        """(H, W, 3) float32 radiance of a flat seabed through the homography (the original model)."""
        seabed = self._blur_in_water(self._sample_seabed(world, pose), pose, velocity_mps)
        gain, haze, has_haze = self._radiometry(pose.altitude_m)
        img = cv2.multiply(seabed, gain, dtype=cv2.CV_32F)
        return cv2.add(img, haze) if has_haze else img

    def _blur_in_water(self, img: np.ndarray, pose: Pose, velocity_mps: tuple[float, float]) -> np.ndarray:
        """Motion blur over the exposure, then the forward scattering of turbid water."""
        kern = self._motion_kernel(pose, velocity_mps)
        if kern is not None:
            img = cv2.filter2D(img, -1, kern, borderType=cv2.BORDER_REFLECT)
        if self.water.forward_scatter_px >= 0.2:
            img = cv2.GaussianBlur(img, (0, 0), self.water.forward_scatter_px, borderType=cv2.BORDER_REFLECT)
        return img

    def _radiance_rays(
        self, world: World, pose: Pose, velocity_mps: tuple[float, float], yaw_rate_radps: float, t_s: float
    ) -> np.ndarray:
        """(H, W, 3) float32 radiance on the ray-cast path: relief, vehicle lamps, rolling shutter."""
        hits = self._cast_rays(world, pose, velocity_mps, yaw_rate_radps)
        if self.lighting is not None:
            gain, haze = self._lamp_gain(world, pose, hits, t_s)
            has_haze = any(b > 0 for b in self.water.backscatter_rgb)
        else:
            gain, haze, has_haze = self._radiometry(pose.altitude_m)
        img = self._blur_in_water(cv2.multiply(hits.albedo, gain, dtype=cv2.CV_32F), pose, velocity_mps)
        return cv2.add(img, haze) if has_haze else img

    def _lens_psf(self, img: np.ndarray) -> np.ndarray:
        """The lens point-spread function: a Gaussian core plus an optional wide glare skirt."""
        sp = self.sensor
        if sp.psf_sigma_px >= 0.1:
            img = cv2.GaussianBlur(img, (0, 0), sp.psf_sigma_px, borderType=cv2.BORDER_REFLECT)
        if sp.psf_glare_fraction > 0:
            glare = cv2.GaussianBlur(img, (0, 0), sp.psf_glare_sigma_px, borderType=cv2.BORDER_REFLECT)
            img = cv2.addWeighted(img, 1.0 - sp.psf_glare_fraction, glare, sp.psf_glare_fraction, 0.0)
        return img

    def render(
        self,
        world: World,
        pose: Pose,
        lasers: Sequence[LaserPointer] = (),
        rng: np.random.Generator | None = None,
        velocity_mps: tuple[float, float] = (0.0, 0.0),
        t_s: float = 0.0,
        noise_free: bool = False,
        yaw_rate_radps: float = 0.0,
    ) -> np.ndarray:
        """One frame, ``(H, W, 3) uint8`` RGB. See :func:`render_frame`."""
        if rng is None and not noise_free:
            raise SimulationError("render needs rng (a seeded np.random.Generator) unless noise_free=True")
        if self.uses_rays(world):
            img = self._radiance_rays(world, pose, velocity_mps, yaw_rate_radps, t_s)
        else:
            img = self._radiance_plane(world, pose, velocity_mps)
        if self.water.marine_snow_per_m3 > 0:
            self._add_snow(img, world, pose, t_s)
        if lasers:
            self._add_lasers(img, pose, lasers, rng, noise_free, world)
        sp = self.sensor
        if sp.psf_sigma_px >= 0.1 or sp.psf_glare_fraction > 0:
            img = self._lens_psf(img)
        if not noise_free and (sp.shot_noise_dn > 0 or sp.read_noise_dn > 0):
            std = cv2.sqrt(cv2.max(img, 0.0) * sp.shot_noise_dn + sp.read_noise_dn**2)
            img += fast_standard_normal(rng, img.shape) * std
        out = cv2.convertScaleAbs(cv2.max(img, 0.0))  # round, saturate to 0..255
        if sp.jpeg_quality is not None and not noise_free:
            ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(sp.jpeg_quality)])
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]
            out = np.ascontiguousarray(out)
        return out


def _bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``(R, C, K)`` grid sampled bilinearly at fractional (rows, cols) ``(N,)`` -> ``(N, K)`` float64."""
    r0 = np.clip(np.floor(rows).astype(np.int64), 0, grid.shape[0] - 2)
    c0 = np.clip(np.floor(cols).astype(np.int64), 0, grid.shape[1] - 2)
    fr, fc = (rows - r0)[:, None], (cols - c0)[:, None]
    return ((1 - fr) * (1 - fc) * grid[r0, c0] + (1 - fr) * fc * grid[r0, c0 + 1]
            + fr * (1 - fc) * grid[r0 + 1, c0] + fr * fc * grid[r0 + 1, c0 + 1])


@lru_cache(maxsize=16)
def renderer_for(
    camera: Camera,
    water: WaterParams | None = None,
    sensor: SensorParams | None = None,
    spots: LaserSpotParams | None = None,
    lighting: LightingParams | None = None,
) -> FrameRenderer:
    """A shared :class:`FrameRenderer` per (camera, water, sensor, spots, lighting) (precomputation cached)."""
    return FrameRenderer(camera, water, sensor, spots, lighting)


def render_frame(
    world: World,
    camera: Camera,
    pose: Pose,
    lasers: Sequence[LaserPointer] = (),
    water: WaterParams | None = None,
    rng: np.random.Generator | None = None,
    *,
    sensor: SensorParams | None = None,
    spots: LaserSpotParams | None = None,
    velocity_mps: tuple[float, float] = (0.0, 0.0),
    t_s: float = 0.0,
    noise_free: bool = False,
    lighting: LightingParams | None = None,
    yaw_rate_radps: float = 0.0,
) -> np.ndarray:
    """Render the seabed of ``world`` seen by ``camera`` at ``pose``: ``(H, W, 3) uint8`` RGB.

    ``lasers`` are drawn where their rays meet the seabed (its relief, if any).
    ``velocity_mps`` is the vehicle's (surge, sway) over the ground, for the motion blur
    and the rolling shutter (with ``yaw_rate_radps``); ``t_s`` places the marine snow and
    the caustics. ``lighting`` puts the lamps on the vehicle (None: the original lamp cone
    fixed to the image). ``rng`` draws the sensor noise and the laser speckle; with
    ``noise_free=True`` there is neither (nor the JPEG round trip) and ``rng`` may be None.
    Deterministic: the same arguments and generator state give the same image.
    """
    return renderer_for(camera, water, sensor, spots, lighting).render(
        world, pose, tuple(lasers), rng, velocity_mps, t_s, noise_free, yaw_rate_radps
    )
