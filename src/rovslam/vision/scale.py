"""The processing scale: any camera brought near the paper's pixels, results reported in the camera's.

The paper's figures (16x16 tokens, 32x32 landmarks, the band-pass sigmas, search radii of a
few pixels, laser spots of a few pixels) are tuned for a 360x272 image of a 44 x 33 cm
footprint. A 1920x1080 camera over a similar footprint has five times finer pixels: a 16 px
token covers a twenty-fifth of the seabed, the band-pass passes sensor noise, the search
radii cover a fifth of the motion, and each frame costs thirty times more. So the vision runs
on the frame reduced by a *processing scale* ``s`` (area average), with the intrinsics scaled
to match, and every pixel it reports is converted back to the full frame.

Pixel-centre convention (OpenCV's ``resize``): processed pixel ``p'`` covers the full pixels
around ``(p' + 0.5) / s - 0.5``. With per-axis scales ``s_u = W'/W``, ``s_v = H'/H``::

    u' = (u + 0.5) s_u - 0.5        fx' = fx s_u,  cx' = (cx + 0.5) s_u - 0.5
    v' = (v + 0.5) s_v - 0.5        fy' = fy s_v,  cy' = (cy + 0.5) s_v - 0.5

Lens distortion acts on normalised coordinates ``(u - cx) / fx``, which the scaling leaves
unchanged: the same coefficients hold, and observations are still undistorted as points.
An observation ``[m, n]`` of (3) is a pixel offset from the principal point over the focal
length: reported at the full resolution it is multiplied by ``f / f'``, with ``f`` in place of
``f'``, so ``[m, n] / f`` (what the filter uses) is unchanged.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np

from rovslam.camera import Camera
from rovslam.config import LaserConfig, ProcessingConfig
from rovslam.errors import InvalidArgumentError

__all__ = ["ProcessingScale", "auto_scale", "processing_scale"]


def auto_scale(camera: Camera, altitude_m: float, config: ProcessingConfig = ProcessingConfig()) -> float:
    """The reduction ``s`` in (0, 1] that ``[processing] scale = "auto"`` chooses.

    The largest reduction such that the long side is at most ``max_side_px`` and the ground
    resolution at ``altitude_m``, ``f s / Z`` pixels per metre, stays at least
    ``min_px_per_m`` (the footprint: a wide-angle camera keeps more pixels than a narrow one
    of the same size). Never above 1.
    """
    if not (math.isfinite(altitude_m) and altitude_m > 0):
        raise InvalidArgumentError(f"the expected altitude must be a positive number of metres, got {altitude_m}")
    by_size = config.max_side_px / max(camera.width_px, camera.height_px)
    by_ground = config.min_px_per_m * altitude_m / camera.focal_px
    return float(min(1.0, max(by_size, by_ground)))


@dataclass(frozen=True)
class ProcessingScale:
    """A camera, its processed twin and the conversions between their pixels.

    Attributes:
        full: the camera of the frames (``sequence.toml`` / the camera file).
        camera: the processed camera (intrinsics scaled; the same distortion and yaw offset).
        scale_u, scale_v: ``W'/W`` and ``H'/H`` (equal up to the rounding of the sizes).
    """

    full: Camera
    camera: Camera
    scale_u: float
    scale_v: float

    @classmethod
    def for_camera(cls, full: Camera, scale: float) -> ProcessingScale:
        """The processed camera at reduction ``scale`` in (0, 1] (sizes rounded, at least 32 px a side)."""
        if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
            raise InvalidArgumentError(f"processing scale must be in (0, 1], got {scale}")
        if scale == 1.0:
            return cls(full, full, 1.0, 1.0)
        w = max(32, int(round(full.width_px * scale)))
        h = max(32, int(round(full.height_px * scale)))
        su, sv = w / full.width_px, h / full.height_px
        cam = dataclasses.replace(
            full,
            width_px=w,
            height_px=h,
            fx_px=full.fx_px * su,
            fy_px=full.fy_px * sv,
            cx_px=min(w, max(0.0, (full.cx_px + 0.5) * su - 0.5)),
            cy_px=min(h, max(0.0, (full.cy_px + 0.5) * sv - 0.5)),
        )
        return cls(full, cam, su, sv)

    @property
    def identity(self) -> bool:
        """True when the frames are processed as they are."""
        return self.scale_u == 1.0 and self.scale_v == 1.0

    @property
    def scale(self) -> float:
        """The mean reduction (the one pixel figures are divided by)."""
        return 0.5 * (self.scale_u + self.scale_v)

    @property
    def focal_ratio(self) -> float:
        """``f / f'``: full-resolution pixels per processed pixel along the focal length."""
        return self.full.focal_px / self.camera.focal_px

    def reduce(self, image: np.ndarray) -> np.ndarray:
        """``(H', W'[, C])`` the ``(H, W[, C])`` image reduced by area average (the same array when identity)."""
        if self.identity:
            return image
        img = np.asarray(image)
        if img.shape[:2] != self.full.shape:
            raise InvalidArgumentError(
                f"frame is {img.shape[1]}x{img.shape[0]} px but the camera says "
                f"{self.full.width_px}x{self.full.height_px}; fix [camera] width_px / height_px"
            )
        return cv2.resize(img, (self.camera.width_px, self.camera.height_px), interpolation=cv2.INTER_AREA)

    def reduce_channel(self, channel: np.ndarray) -> np.ndarray:
        """``(H', W') float32``: an ``(H, W) uint8`` channel reduced as :meth:`reduce` reduces its float32 copy, bit for bit.

        When the frame is a whole number ``k`` of processed pixels on both axes (1920x1080 at
        480x270: 4), the ``k x k`` blocks are summed and scaled by ``1 / k^2`` in float32, which is
        what OpenCV's area average computes on float32; the full-size float32 copy is never made
        (about 1 ms of a 1920x1080 frame). The sums are whole numbers: up to ``k = 16`` they are
        taken in uint16 (at most ``256 * 255``: exact in any order, and half the bytes of float32),
        rows first then columns, by NumPy's widening add, which sums the rows in about half the
        time of ``cv2.add`` to float32; above, in float32 and in the same order (rows, then the
        columns one by one), so that sums past ``2^24`` round as they did with ``cv2.add``. The
        channel (a view with a stride of 3 in a frame) is copied first: one sequential read of the
        frame, and every sum after it reads contiguous bytes. Other sizes: :meth:`reduce`.
        """
        ch = np.asarray(channel)
        k = self.full.width_px // self.camera.width_px
        whole = (
            not self.identity
            and k >= 2
            and self.camera.width_px * k == self.full.width_px
            and self.camera.height_px * k == self.full.height_px
        )
        if not whole or ch.dtype != np.uint8 or ch.shape != self.full.shape:
            return self.reduce(ch.astype(np.float32))
        ch = np.ascontiguousarray(ch)
        acc = np.uint16 if k * k * 255 <= np.iinfo(np.uint16).max else np.float32
        rows = np.add(ch[0::k], ch[1::k], dtype=acc)  # (H', W) the sums of k rows
        for j in range(2, k):
            rows += ch[j::k]
        sums = np.add(rows[:, 0::k], rows[:, 1::k])  # (H', W') the sums of k x k blocks
        for j in range(2, k):
            sums += rows[:, j::k]
        return np.multiply(sums, np.float32(1.0 / (k * k)), dtype=np.float32)

    def to_full_px(self, uv_px: np.ndarray) -> np.ndarray:
        """``(N, 2)`` or ``(2,)`` processed pixels (u, v) -> the same points in full-resolution pixels."""
        uv = np.asarray(uv_px, dtype=np.float64)
        if self.identity:
            return uv
        return (uv + 0.5) / np.array([self.scale_u, self.scale_v]) - 0.5

    def to_processed_px(self, uv_px: np.ndarray) -> np.ndarray:
        """``(N, 2)`` or ``(2,)`` full-resolution pixels (u, v) -> processed pixels."""
        uv = np.asarray(uv_px, dtype=np.float64)
        if self.identity:
            return uv
        return (uv + 0.5) * np.array([self.scale_u, self.scale_v]) - 0.5

    def laser_config(self, config: LaserConfig) -> LaserConfig:
        """The laser figures for the full frame: search radii and spot noise / s, largest spot area / s^2.

        The spots are found in the full frame (their centroids are finer there, and only a
        window around the predicted spots is read). The smallest area is left as it is: it
        rejects single noisy pixels, whatever the resolution. The inhibition radius stays in
        processed pixels (it is applied to the processed image).
        """
        if self.identity:
            return config
        s = self.scale
        return dataclasses.replace(
            config,
            search_radius_px=config.search_radius_px / s,
            spot_sigma_px=config.spot_sigma_px / s,
            faint_search_radius_px=config.faint_search_radius_px / s,
            max_spot_area_px=max(config.min_spot_area_px, int(round(config.max_spot_area_px / (s * s)))),
        )


def processing_scale(camera: Camera, config: ProcessingConfig, altitude_m: float) -> ProcessingScale:
    """The :class:`ProcessingScale` that ``config`` asks for (``"auto"``: :func:`auto_scale` at ``altitude_m``)."""
    s = auto_scale(camera, altitude_m, config) if config.scale == "auto" else float(config.scale)
    return ProcessingScale.for_camera(camera, s)
