"""The laser pointers' spots: where the beams meet the seabed (its relief too), and how the spots look.

A spot is the beam's footprint on the seabed, ``spot_diameter_mm`` across, seen through the
optics (an erf edge of ``optics_sigma_px``): a saturated red disc, with a faint halo of light
scattered forward in the water, speckle, and a little crosstalk of the clipped red into green
and blue (:class:`~rovslam.sim.render.LaserSpotParams`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import erfc

from rovslam.camera import Camera, LaserPointer, ground_to_pixels, level_from_body
from rovslam.sim._noise import fast_standard_normal
from rovslam.sim.water import WaterParams
from rovslam.sim.world import World

if TYPE_CHECKING:
    from rovslam.sim.params import LaserSpotParams, Pose

_LASER_ITERATIONS = 5  # Newton steps of the beam-relief intersection (to full precision)


class LaserSpots:
    """The laser spots of one camera, spot model and water: :meth:`laser_hits` and :meth:`draw`."""

    def __init__(self, camera: Camera, spots: LaserSpotParams, water: WaterParams) -> None:
        self.camera = camera
        self.spots = spots
        self.water = water
        self._cache: dict[tuple[LaserPointer, ...], tuple[np.ndarray, np.ndarray]] = {}

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
        if key not in self._cache:
            self._cache[key] = (
                np.array([lp.origin_m for lp in lasers], dtype=np.float64),
                np.array([lp.unit_direction for lp in lasers]),
            )
        origin_b, dir_b = self._cache[key]
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
        rc = world.relief_canvas(
            int(np.floor(rows.min())) - 1,
            int(np.ceil(rows.max())) + 2,
            int(np.floor(cols.min())) - 1,
            int(np.ceil(cols.max())) + 2,
        )
        dn, de = c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]  # beam direction, world north / east
        for _ in range(_LASER_ITERATIONS):
            hit = o + t[:, None] * d
            h, sn, se = _bilinear(
                rc.relief,
                (pose.x_m + c * hit[:, 0] - s * hit[:, 1]) * inv - rc.row0,
                (pose.y_m + s * hit[:, 0] + c * hit[:, 1]) * inv - rc.col0,
            ).T
            g = o[:, 2] + t * d[:, 2] - pose.altitude_m + h
            t = t - g / np.maximum(d[:, 2] + sn * dn + se * de, 0.25 * d[:, 2])
        hit = o + t[:, None] * d
        # The hit seen from the camera: its ray at unit depth, projected (ground_to_pixels at depth 1).
        uv = ground_to_pixels(self.camera, hit[:, :2] / hit[:, 2:3], 1.0, pose.roll_rad, pose.pitch_rad)
        return uv, t + np.linalg.norm(hit, axis=1), hit[:, 2]

    def draw(
        self,
        img: np.ndarray,
        pose: Pose,
        lasers: Sequence[LaserPointer],
        rng: np.random.Generator | None,
        noise_free: bool,
        world: World | None,
    ) -> None:
        """Add the spots of ``lasers`` to the ``(H, W, 3) float32`` radiance ``img``, in place (speckle from ``rng``)."""
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
            spot = peak * (
                0.5 * erfc((r - radius) / (np.sqrt(2.0) * sp.optics_sigma_px))
                + sp.halo_fraction * np.exp(-(r * r) / (2.0 * sp.halo_sigma_px**2))
            )
            if not noise_free and sp.speckle > 0:
                spot *= np.maximum(1.0 + sp.speckle * fast_standard_normal(rng, spot.shape), 0.0)  # type: ignore[arg-type]
            r0, r1 = max(0, iv - rad), min(h, iv + rad + 1)
            c0, c1 = max(0, iu - rad), min(w, iu + rad + 1)
            if r0 >= r1 or c0 >= c1:
                continue
            patch = spot[r0 - (iv - rad) : r1 - (iv - rad), c0 - (iu - rad) : c1 - (iu - rad)].astype(np.float32)
            clipped = np.minimum(patch, 255.0)
            img[r0:r1, c0:c1, 0] += patch
            img[r0:r1, c0:c1, 1] += sp.crosstalk_green * clipped
            img[r0:r1, c0:c1, 2] += sp.crosstalk_blue * clipped


def _bilinear(grid: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``(R, C, K)`` grid sampled bilinearly at fractional (rows, cols) ``(N,)`` -> ``(N, K)`` float64."""
    r0 = np.clip(np.floor(rows).astype(np.int64), 0, grid.shape[0] - 2)
    c0 = np.clip(np.floor(cols).astype(np.int64), 0, grid.shape[1] - 2)
    fr, fc = (rows - r0)[:, None], (cols - c0)[:, None]
    return (
        (1 - fr) * (1 - fc) * grid[r0, c0]
        + (1 - fr) * fc * grid[r0, c0 + 1]
        + fr * (1 - fc) * grid[r0 + 1, c0]
        + fr * fc * grid[r0 + 1, c0 + 1]
    )
