"""The light on the seabed: the lamp cone fixed to the image, or lamps riding on the vehicle.

:class:`LampCone` is the original model (see :mod:`rovslam.sim.water`): seabed albedo x lamp
cone x vignetting x per-channel attenuation with the path length, plus backscatter haze, as
maps per centimetre of altitude. :class:`VehicleLamps` lights the hits of the ray-cast path
(:mod:`rovslam.sim.rays`) with the lamps of :class:`~rovslam.sim.lighting.LightingParams`:
the relief's normals, soft cast shadows and the sunlight's caustics.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import TYPE_CHECKING

import cv2
import numpy as np

from rovslam.camera import Camera, level_from_body
from rovslam.sim.lighting import (
    CAUSTIC_TEXELS,
    LightingParams,
    caustic_pattern,
    lamp_irradiance,
    reference_irradiance,
)
from rovslam.sim.rays import RayCaster, RayHits
from rovslam.sim.water import WaterParams
from rovslam.sim.world import World

if TYPE_CHECKING:
    from rovslam.sim.params import Pose, SensorParams


class LampCone:
    """The lamp cone fixed to the image, with the water: gain and haze maps at full resolution.

    ``ideal`` are the ``(H * W, 2)`` undistorted pixel positions (row-major) of the image.
    """

    def __init__(self, camera: Camera, ideal: np.ndarray, water: WaterParams, sensor: SensorParams) -> None:
        self.water = water
        self.sensor = sensor
        h, w = camera.height_px, camera.width_px
        # Frame-independent radiometric maps on the ideal (undistorted) rays.
        xn = ((ideal[:, 0] - camera.cx_px) / camera.fx_px).reshape(h, w)
        yn = ((ideal[:, 1] - camera.cy_px) / camera.fy_px).reshape(h, w)
        self._sec = np.sqrt(1.0 + xn * xn + yn * yn)  # path length per unit depth (level camera)
        half_x = max(camera.cx_px, w - 1 - camera.cx_px) / camera.fx_px
        half_y = max(camera.cy_px, h - 1 - camera.cy_px) / camera.fy_px
        ox, oy = sensor.light_centre_frac
        r2 = ((xn - ox * half_x) ** 2 + (yn - oy * half_y) ** 2) / (half_x**2 + half_y**2)
        self._cone = sensor.light_corner_ratio**r2  # lamp irradiance, 1 at the cone centre
        self._vignette = self._sec ** (-sensor.vignetting_power)
        self._maps: OrderedDict[int, tuple[np.ndarray, np.ndarray, bool]] = OrderedDict()
        self._lock = threading.Lock()

    def maps(self, altitude_m: float) -> tuple[np.ndarray, np.ndarray, bool]:
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


class VehicleLamps:
    """The lamps on the vehicle lighting the hits of ``rays``, with the water (see :meth:`gain_and_haze`)."""

    def __init__(
        self, camera: Camera, water: WaterParams, sensor: SensorParams, lighting: LightingParams, rays: RayCaster
    ) -> None:
        self.water = water
        self.sensor = sensor
        self.lighting = lighting
        self.rays = rays
        h, w = camera.height_px, camera.width_px
        half_x = max(camera.cx_px, w - 1 - camera.cx_px) / camera.fx_px
        half_y = max(camera.cy_px, h - 1 - camera.cy_px) / camera.fy_px
        ox, oy = sensor.light_centre_frac
        self._vignette_c = (1.0 + rays.xn**2 + rays.yn**2) ** np.float32(-0.5 * sensor.vignetting_power)
        r2_c = ((rays.xn - ox * half_x) ** 2 + (rays.yn - oy * half_y) ** 2) / (half_x**2 + half_y**2)
        self._haze_pattern_c = np.sqrt(sensor.light_corner_ratio**r2_c).astype(np.float32)  # as the plane path
        self._e_ref = reference_irradiance(lighting)

    def gain_and_haze(self, world: World, pose: Pose, hits: RayHits, t_s: float) -> tuple[np.ndarray, np.ndarray]:
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
            nx = ny = np.float32(0.0)  # type: ignore[assignment]
            nz = np.float32(-1.0)  # type: ignore[assignment]
        r_lb = level_from_body(pose.roll_rad, pose.pitch_rad)
        total = np.zeros(t.shape, dtype=np.float32)
        r_sum = np.zeros(t.shape, dtype=np.float32)
        for lamp in lp.lamps:
            pos = r_lb @ np.asarray(lamp.position_m, dtype=np.float64)
            axis = r_lb @ (np.asarray(lamp.direction, dtype=np.float64) / np.linalg.norm(lamp.direction))
            e, r, vec = lamp_irradiance(pos, axis, lamp.beam_exponent, px, py, t, nx, ny, nz)
            if lp.shadow_samples > 0 and hits.relief_maps is not None:
                e = e * self._visibility(world, pose, hits, vec)
            total += np.float32(lamp.intensity / self._e_ref) * e
            r_sum += r
        r_cam = t * hits.sec
        path = r_cam + r_sum * np.float32(1.0 / len(lp.lamps))
        base = np.float32(sp.exposure_gain) * self._vignette_c * (total + np.float32(lp.ambient))
        chans = [base * np.exp(np.float32(-a) * path) for a in wp.attenuation_per_m]
        if lp.caustics is not None:
            sun = self._caustics(world, hits, t_s) * (np.float32(sp.exposure_gain) * self._vignette_c)
            chans = [
                ch + np.float32(k) * sun * np.exp(np.float32(-a) * r_cam)
                for ch, k, a in zip(chans, lp.caustics.rgb, wp.attenuation_per_m)
            ]
        veil = (
            np.float32(255.0 * sp.exposure_gain)
            * self._haze_pattern_c
            * (1.0 - np.exp(np.float32(-wp.backscatter_per_m) * r_cam))
        )
        haze = [np.float32(b) * veil for b in wp.backscatter_rgb]
        return self.rays.upsample(cv2.merge(chans)), self.rays.upsample(cv2.merge(haze))

    def _visibility(self, world: World, pose: Pose, hits: RayHits, vec) -> np.ndarray:
        """(H, W) float32 in [0, 1]: how much of one lamp reaches each hit past the relief (soft cast shadow).

        Steps from the hit towards the lamp until the light ray has risen above the highest
        relief, and takes the largest height by which the relief pokes above the light ray.
        """
        lp = self.lighting
        rc, row_map, col_map, b_row, b_col = hits.relief_maps  # type: ignore[misc]
        lx, ly, lz = vec
        c, s = float(np.cos(pose.heading_rad)), float(np.sin(pose.heading_rad))
        inv_r = np.float32(1.0 / world.relief.texel_m)  # type: ignore[union-attr]
        lrow, lcol = (c * lx - s * ly) * inv_r, (s * lx + c * ly) * inv_r  # P -> lamp, in relief texels
        h_lo, h_hi = world.relief.height_range_m  # type: ignore[union-attr]
        h_p = np.float32(pose.altitude_m) - hits.depth_m
        rise_per_step = 1.0 / np.maximum(-lz, np.float32(1e-3))  # tau per metre of rise
        occl = np.full(h_p.shape, -1.0, dtype=np.float32)
        n = lp.shadow_samples
        for k in range(1, n + 1):
            rise = np.float32((h_hi - h_lo) * (k / n) ** 2)
            tau = rise * rise_per_step
            h_q = cv2.remap(
                rc.heights,
                col_map + tau * lcol,
                row_map + tau * lrow,
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REPLICATE,
            )
            occl = np.maximum(occl, h_q - (h_p + rise))
        return np.clip(1.0 - occl * np.float32(1.0 / lp.shadow_softness_m), 0.0, 1.0)

    def _caustics(self, world: World, hits: RayHits, t_s: float) -> np.ndarray:
        """(H, W) float32 sunlight on the seabed: two drifting layers of the caustic network, mean ``strength``."""
        cp = self.lighting.caustics
        pattern = caustic_pattern(world.seed)
        k = np.float32(CAUSTIC_TEXELS / (4.0 * cp.scale_m))  # type: ignore[union-attr]  # pattern texels per metre (4 cells per period)
        out = np.zeros(hits.depth_m.shape, dtype=np.float32)
        for angle, stretch, sign in ((0.0, 1.0, 1.0), (2.1, 1.37, -0.7)):
            ca, sa = np.float32(np.cos(angle) * stretch * k), np.float32(np.sin(angle) * stretch * k)
            ox = (sign * cp.drift_mps[0] * t_s) * float(k)  # type: ignore[union-attr]
            oy = (sign * cp.drift_mps[1] * t_s) * float(k)  # type: ignore[union-attr]
            u = np.mod(ca * hits.east_m - sa * hits.north_m - np.float32(oy), np.float32(CAUSTIC_TEXELS))
            v = np.mod(sa * hits.east_m + ca * hits.north_m - np.float32(ox), np.float32(CAUSTIC_TEXELS))
            out += cv2.remap(pattern, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        return out * np.float32(0.5 * cp.strength)  # type: ignore[operator,union-attr]
