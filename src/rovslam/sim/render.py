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
per :class:`FrameRenderer`, which forms the image; the ray casting is :mod:`rovslam.sim.rays`,
the lamps and the water's light :mod:`rovslam.sim.shading`, the laser spots :mod:`rovslam.sim.spots`. :func:`render_frame` is the pure entry point.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import cv2
import numpy as np

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
from rovslam.sim.lighting import LightingParams
from rovslam.sim.params import LaserSpotParams, Pose, SensorParams  # noqa: F401 (imported from here too)
from rovslam.sim.rays import RAY_ITERATIONS, RayCaster, ray_step_px  # noqa: F401 (the ray grid's, named here too)
from rovslam.sim.shading import LampCone, VehicleLamps
from rovslam.sim.spots import LaserSpots
from rovslam.sim.water import WaterParams, marine_snow
from rovslam.sim.world import World

_SNOW_SIGMAS_PX = np.array([0.7, 1.5, 3.2, 6.5])  # marine-snow blur levels (particles use the nearest)


class FrameRenderer:
    """Precomputed renderer for one camera, water, sensor, laser-spot and lighting model.

    ``lighting`` None keeps the lamp cone of :class:`SensorParams` fixed to the image (the
    original model); with :class:`~rovslam.sim.lighting.LightingParams` the lamps ride on
    the vehicle and light the relief.

    The renderer forms the image (seabed through the homography or the rays, blur, marine
    snow, lens, noise, quantisation); its parts do the rest: ``rays``
    (:class:`~rovslam.sim.rays.RayCaster`, the ray-cast geometry), ``lamp_cone``
    (:class:`~rovslam.sim.shading.LampCone`, the lamp cone fixed to the image and the water),
    ``lamps`` (:class:`~rovslam.sim.shading.VehicleLamps`, the lamps on the vehicle; None
    without ``lighting``) and ``laser_spots`` (:class:`~rovslam.sim.spots.LaserSpots`).
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
            self._ideal_pts = None  # type: ignore[assignment]
        # Border pixels (every 4th, plus corners), to bound the footprint of a frame.
        border = np.zeros((h, w), dtype=bool)
        border[0, ::4] = border[-1, ::4] = border[::4, 0] = border[::4, -1] = True
        border[0, -1] = border[-1, 0] = border[-1, -1] = True
        self._border_ideal = ideal[border.ravel()]
        self.lamp_cone = LampCone(camera, ideal, self.water, self.sensor)
        self.rays = RayCaster(camera, self.sensor)
        self.lamps = None if lighting is None else VehicleLamps(camera, self.water, self.sensor, lighting, self.rays)
        self.laser_spots = LaserSpots(camera, self.spots, self.water)

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
            int(np.floor(b[:, 1].min())) - 1,
            int(np.ceil(b[:, 1].max())) + 2,
            int(np.floor(b[:, 0].min())) - 1,
            int(np.ceil(b[:, 0].max())) + 2,
            blur,
        )
        shift = np.array([[1.0, 0.0, -canvas.col0], [0.0, 1.0, -canvas.row0], [0.0, 0.0, 1.0]])
        hom = shift @ hom
        size = (cam.width_px, cam.height_px)
        if self._ideal_pts is None:
            return cv2.warpPerspective(
                canvas.texels,
                hom,
                size,
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
        maps = cv2.perspectiveTransform(self._ideal_pts, hom).reshape(cam.height_px, cam.width_px, 2)
        return cv2.remap(canvas.texels, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)  # type: ignore[call-overload]

    # ------------------------------------------------------------------ ray-cast geometry
    def uses_rays(self, world: World) -> bool:
        """Whether frames of ``world`` take the ray-cast path (relief, vehicle lamps or rolling shutter)."""
        return world.relief is not None or self.lighting is not None or self.sensor.readout_s > 0

    # ------------------------------------------------------------------ radiometry
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
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
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
        return self.laser_spots.laser_hits(pose, lasers, world)

    def _add_snow(self, img: np.ndarray, world: World, pose: Pose, t_s: float) -> None:
        cam, wp = self.camera, self.water
        reach = 0.5 * np.hypot(cam.width_px, cam.height_px) * pose.altitude_m / cam.focal_px + 0.05
        snow = marine_snow(world.seed, wp, t_s, pose.x_m, pose.y_m, pose.altitude_m, pose.heading_rad, reach)
        if len(snow.depth_m) == 0:
            return
        d = snow.depth_m
        uv = ground_to_pixels(
            cam, np.column_stack([snow.forward_m / d, snow.starboard_m / d]), 1.0, pose.roll_rad, pose.pitch_rad
        )
        f = cam.focal_px
        defocus = wp.lens_aperture_mm * 1e-3 * f * np.abs(1.0 / d - 1.0 / pose.altitude_m)
        size = f * snow.diameter_m / d
        sigma = np.sqrt((defocus / 2.5) ** 2 + (size / 2.5) ** 2 + 0.5**2)
        energy = (
            wp.marine_snow_energy
            * (snow.diameter_m / 1e-3) ** 2
            * (0.6 / d) ** 2
            * np.exp(-wp.attenuation_per_m[1] * wp.light_path_factor * (d - 0.6))
        )
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
        layers = layers.astype(np.float32).reshape(len(_SNOW_SIGMAS_PX), hh, ww)  # type: ignore[assignment]
        total = np.zeros((h, w), dtype=np.float32)
        for lev in np.unique(level):
            total += cv2.GaussianBlur(layers[lev], (0, 0), float(_SNOW_SIGMAS_PX[lev]), borderType=cv2.BORDER_CONSTANT)[
                1:-1, 1:-1
            ]
        img += total[..., None] * np.array([0.75, 1.0, 0.95], dtype=np.float32)

    # ------------------------------------------------------------------ the frame
    def _radiance_plane(self, world: World, pose: Pose, velocity_mps: tuple[float, float]) -> np.ndarray:
        """(H, W, 3) float32 radiance of a flat seabed through the homography (the original model)."""
        seabed = self._blur_in_water(self._sample_seabed(world, pose), pose, velocity_mps)
        gain, haze, has_haze = self.lamp_cone.maps(pose.altitude_m)
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
        hits = self.rays.cast(world, pose, velocity_mps, yaw_rate_radps)
        if self.lamps is not None:
            gain, haze = self.lamps.gain_and_haze(world, pose, hits, t_s)
            has_haze = any(b > 0 for b in self.water.backscatter_rgb)
        else:
            gain, haze, has_haze = self.lamp_cone.maps(pose.altitude_m)
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
            self.laser_spots.draw(img, pose, lasers, rng, noise_free, world)
        sp = self.sensor
        if sp.psf_sigma_px >= 0.1 or sp.psf_glare_fraction > 0:
            img = self._lens_psf(img)
        if not noise_free and (sp.shot_noise_dn > 0 or sp.read_noise_dn > 0):
            std = cv2.sqrt(cv2.max(img, 0.0) * sp.shot_noise_dn + sp.read_noise_dn**2)  # type: ignore[call-overload]
            img += fast_standard_normal(rng, img.shape) * std  # type: ignore[arg-type]
        out = cv2.convertScaleAbs(cv2.max(img, 0.0))  # type: ignore[call-overload]  # round, saturate to 0..255
        if sp.jpeg_quality is not None and not noise_free:
            ok, buf = cv2.imencode(".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(sp.jpeg_quality)])
            out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1]  # type: ignore[index]
            out = np.ascontiguousarray(out)
        return out


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
