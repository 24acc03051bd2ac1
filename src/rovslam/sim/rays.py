"""The ray-cast geometry of a frame: where each pixel's ray meets the seabed and its relief.

Every ray ``C + t D`` (camera centre C, world direction D per unit of depth below the camera,
t the depth) is intersected with the relief by Newton steps on ``t = Z - h(C + t D)``
(``RAY_ITERATIONS`` of them, each one ``cv2.remap`` of the window of heights and slopes). The
rays are cast on a grid of every ``ray_step_px(camera)``-th pixel (with a one-sample apron)
and :meth:`RayCaster.upsample` interpolates a field on that grid to every pixel; the albedo is
sampled at every pixel where its ray lands. Under a rolling shutter each row has its own pose.
See :mod:`rovslam.sim.render` for the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from rovslam.camera import Camera, body_from_camera, level_from_body, undistort_pixels
from rovslam.errors import SimulationError
from rovslam.sim.world import World

if TYPE_CHECKING:
    from rovslam.sim.params import Pose, SensorParams

RAY_ITERATIONS = 3  # Newton steps of the ray-relief intersection
_MIN_CLEARANCE_M = 0.05  # the camera must stay this far above the highest relief


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
class RayHits:
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


class RayCaster:
    """The rays of one camera on the coarse ray grid, cast onto the seabed of a frame.

    The grid has every ``step``-th pixel plus a one-sample apron, so that :meth:`upsample` is
    exact for linear fields up to the image border; ``xn``, ``yn`` ``(h, w) float32`` are the
    undistorted normalised coordinates of its nodes.
    """

    def __init__(self, camera: Camera, sensor: SensorParams) -> None:
        self.camera = camera
        self.sensor = sensor
        h, w = camera.height_px, camera.width_px
        self._body_cam = body_from_camera(camera)
        step = ray_step_px(camera)
        self.step = step
        pos_u = step * (np.arange(w // step + 2) - 1.0) + 0.5 * (step - 1)
        pos_v = step * (np.arange(h // step + 2) - 1.0) + 0.5 * (step - 1)
        cu, cv = np.meshgrid(pos_u, pos_v)
        coarse = undistort_pixels(camera, np.column_stack([cu.ravel(), cv.ravel()]))
        self.xn = ((coarse[:, 0] - camera.cx_px) / camera.fx_px).reshape(cu.shape).astype(np.float32)
        self.yn = ((coarse[:, 1] - camera.cy_px) / camera.fy_px).reshape(cu.shape).astype(np.float32)
        self._row_frac = ((pos_v - 0.5 * (h - 1)) / max(h - 1, 1))[:, None]
        self._level_untilted: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def level_rays(self, pose: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ax, ay, sec) float32 on the ray grid: level-frame ray slopes and the path per unit depth."""
        untilted = pose.roll_rad == 0.0 and pose.pitch_rad == 0.0
        if untilted and self._level_untilted is not None:
            return self._level_untilted
        r = level_from_body(pose.roll_rad, pose.pitch_rad) @ self._body_cam
        q = [float(r[i, 0]) * self.xn + float(r[i, 1]) * self.yn + np.float32(r[i, 2]) for i in range(3)]
        if not np.all(q[2] > 1e-3):
            raise SimulationError("the camera does not see the seabed at this pose (tilt too large)")
        inv = 1.0 / q[2]
        ax, ay = q[0] * inv, q[1] * inv
        out = (ax, ay, np.sqrt(1.0 + ax * ax + ay * ay))
        if untilted:
            self._level_untilted = out
        return out

    def cast(self, world: World, pose: Pose, velocity_mps: tuple[float, float], yaw_rate_radps: float) -> RayHits:
        """Intersect the rays of the ray grid with the relief (Newton) and sample the albedo at every pixel."""
        cam, z = self.camera, pose.altitude_m
        ax, ay, sec = self.level_rays(pose)
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
            cos_v, sin_v = np.float32(np.cos(pose.heading_rad)), np.float32(np.sin(pose.heading_rad))  # type: ignore[assignment]
        dx = cos_v * ax - sin_v * ay  # world direction per unit depth, north
        dy = sin_v * ax + cos_v * ay  # east
        h_lo, h_hi = world.relief.height_range_m if world.relief is not None else (0.0, 0.0)
        t_lo, t_hi = z - h_hi, z - h_lo
        if t_lo < _MIN_CLEARANCE_M:
            raise SimulationError(
                f"the relief reaches {h_hi:.3f} m above the mean seabed: the camera at {z:.3f} m would touch it; "
                f"fly higher or lower the relief"
            )
        box = (
            float(cx.min()) + min(t_lo * float(dx.min()), t_hi * float(dx.min())),
            float(cx.max()) + max(t_lo * float(dx.max()), t_hi * float(dx.max())),
            float(cy.min()) + min(t_lo * float(dy.min()), t_hi * float(dy.min())),
            float(cy.max()) + max(t_lo * float(dy.max()), t_hi * float(dy.max())),
        )
        relief_maps = None
        slopes = None
        t = np.float32(z)
        if world.relief is not None:
            inv_r = 1.0 / world.relief.texel_m
            rc = world.relief_canvas(
                int(np.floor(box[0] * inv_r)) - 1,
                int(np.ceil(box[1] * inv_r)) + 2,
                int(np.floor(box[2] * inv_r)) - 1,
                int(np.ceil(box[3] * inv_r)) + 2,
            )
            a_row = (cx * inv_r - rc.row0).astype(np.float32)
            a_col = (cy * inv_r - rc.col0).astype(np.float32)
            b_row, b_col = dx * np.float32(inv_r), dy * np.float32(inv_r)
            zf = np.float32(z)
            for _ in range(RAY_ITERATIONS):  # Newton on g(t) = t - Z + h(C + t D), g' = 1 + grad h . D
                hs = cv2.remap(
                    rc.relief, a_col + t * b_col, a_row + t * b_row, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
                )
                h, sx, sy = cv2.split(hs)
                dg = np.maximum(1.0 + sx * dx + sy * dy, np.float32(0.25))
                t = t - (t - zf + h) / dg
            row_map, col_map = a_row + t * b_row, a_col + t * b_col
            slopes = hs[..., 1:]  # at the last step's t: the Newton step moved t by far less than a texel
            relief_maps = (rc, row_map, col_map, b_row, b_col)
        else:
            t = np.full(ax.shape, z, dtype=np.float32)  # type: ignore[assignment]
        north, east = cx + t * dx, cy + t * dy
        # The albedo where the rays land, prefiltered for the pixel footprint as on the plane path;
        # its map is interpolated from the ray grid to every pixel (exact where it is linear).
        tex = world.texel_m
        texels_per_px = z / (cam.focal_px * tex)
        blur = self.sensor.antialias * texels_per_px if texels_per_px > 1.0 else 0.0
        # (a prefilter of at least 0.8 texel allows keeping every 2nd texel: a 4x smaller canvas to sample)
        step = 2 if blur >= 0.8 else 1
        canvas = world.canvas(
            int(np.floor(box[0] / tex)) - 2,
            int(np.ceil(box[1] / tex)) + 3,
            int(np.floor(box[2] / tex)) - 2,
            int(np.ceil(box[3] / tex)) + 3,
            blur,
            step,
        )
        inv_t = 1.0 / (tex * step)
        col_a = ((cy / tex - canvas.col0) / step).astype(np.float32) + t * (dy * np.float32(inv_t))
        row_a = ((cx / tex - canvas.row0) / step).astype(np.float32) + t * (dx * np.float32(inv_t))
        albedo = cv2.remap(  # type: ignore[call-overload]
            canvas.texels,
            self.upsample(cv2.merge([col_a, row_a])),
            None,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )
        return RayHits(t, albedo, slopes, ax, ay, sec, north.astype(np.float32), east.astype(np.float32), relief_maps)  # type: ignore[arg-type]

    def upsample(self, grid: np.ndarray) -> np.ndarray:
        """A field on the ray grid (with its apron) -> ``(H, W[, C])`` at every pixel, bilinear.

        Exact for fields linear in the pixel coordinates (the grid nodes sit at pixel
        positions ``step * j + (step - 1) / 2``, cv2.resize's sample positions).
        """
        s, cam = self.step, self.camera
        if s == 1:
            return np.ascontiguousarray(grid[1:-1, 1:-1])
        big = cv2.resize(grid, (grid.shape[1] * s, grid.shape[0] * s), interpolation=cv2.INTER_LINEAR)
        return big[s : s + cam.height_px, s : s + cam.width_px]
