"""Camera and laser-rig geometry shared by the simulator, the vision front-end and the filter.

Conventions (docs/architecture.md):

* World frame: x north, y east, z down (metres); heading psi from x towards y.
* Body frame: x forward, y starboard, z down. The camera sits at the body origin.
* "Level" frame: the body frame with roll and pitch removed (x along the heading,
  horizontal); a seabed offset expressed in it maps to the world by R(psi).
* Camera axes: x starboard (image right, u), y aft (image down, v), z down (optical
  axis), then rotated about the optical axis by ``yaw_offset_rad`` (from forward towards
  starboard). With no tilt, a seabed point at level offset (a, b) metres, depth Z, is seen at
  ``[m, n] = f/Z R(gamma)^T [a, b]`` with ``m = cy - v`` (forward) and ``n = u - cx``
  (starboard): equation (3) of the paper with psi -> psi + gamma.
* Attitude: yaw-pitch-roll order, R_world_body = Rz(psi) Ry(pitch) Rx(roll).

All functions take and return arrays of points shaped ``(N, 2)``; they are vectorised and
allocate nothing per point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from rovslam.errors import SequenceFormatError

# Camera axes (x starboard, y aft, z down) expressed in the body frame (x fwd, y stbd, z down).
_BODY_FROM_CAMERA_NOMINAL = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# Input checks of the camera model. A focal length under a pixel is a unit mistake (metres or
# millimetres given for pixels); beyond 1e6 px no camera sees a seabed metres away.
MIN_FOCAL_PX = 1.0
MAX_FOCAL_PX = 1e6
MAX_IMAGE_SIDE_PX = 65535
MIN_LASER_COS = 0.17  # a laser more than 80 degrees off the optical axis never lights the seabed in view
MAX_DISTORTION = 1e4  # largest |distortion coefficient| (real lenses: below 100; 1e308 overflowed the projection)
MAX_LASER_OFFSET_M = 10.0  # a laser pointer mounted farther than this from the camera is a unit mistake
MAX_READOUT_S = 1.0  # a rolling shutter slower than a second is a unit mistake (milliseconds?)


@dataclass(frozen=True)
class Camera:
    """Pinhole camera with optional OpenCV distortion (k1 k2 p1 p2 k3)."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    yaw_offset_rad: float = 0.0
    readout_s: float = 0.0  # rolling shutter: time from the first row's exposure to the last's (0: global shutter)

    def __post_init__(self) -> None:
        if not (0 < self.width_px <= MAX_IMAGE_SIDE_PX and 0 < self.height_px <= MAX_IMAGE_SIDE_PX):
            raise SequenceFormatError(
                f"camera size must be 1 to {MAX_IMAGE_SIDE_PX} px a side, got {self.width_px}x{self.height_px} px"
            )
        focal = (self.fx_px, self.fy_px)
        if not all(np.isfinite(focal)) or not all(MIN_FOCAL_PX <= f <= MAX_FOCAL_PX for f in focal):
            raise SequenceFormatError(
                f"camera focal lengths must be finite, from {MIN_FOCAL_PX:g} to {MAX_FOCAL_PX:g} px, got "
                f"fx={self.fx_px}, fy={self.fy_px} (a focal length is in pixels: millimetres / pixel pitch)"
            )
        if not (np.isfinite(self.cx_px) and np.isfinite(self.cy_px)) or not (
            0.0 <= self.cx_px <= self.width_px and 0.0 <= self.cy_px <= self.height_px
        ):
            raise SequenceFormatError(
                f"camera principal point (cx={self.cx_px}, cy={self.cy_px}) px must lie inside the "
                f"{self.width_px}x{self.height_px} px image"
            )
        if len(self.distortion) not in (4, 5, 8):
            raise SequenceFormatError(
                f"camera distortion needs 4, 5 or 8 OpenCV coefficients (k1 k2 p1 p2 [k3 ...]), "
                f"got {len(self.distortion)}"
            )
        if not (all(np.isfinite(self.distortion)) and np.isfinite(self.yaw_offset_rad)):
            raise SequenceFormatError(
                f"camera distortion and yaw_offset_rad must be finite, got {self.distortion}, {self.yaw_offset_rad}"
            )
        if max(abs(float(k)) for k in self.distortion) > MAX_DISTORTION:
            raise SequenceFormatError(
                f"camera distortion coefficients must be within +-{MAX_DISTORTION:g}, got {self.distortion} "
                "(OpenCV's k1 k2 p1 p2 [k3 ...] of a calibration; real lenses are below 100)"
            )
        if abs(self.yaw_offset_rad) > 2.0 * np.pi:
            raise SequenceFormatError(
                f"camera yaw_offset_rad must be within +-{2.0 * np.pi:.4f} (one turn), got {self.yaw_offset_rad}; "
                "give radians, not degrees"
            )
        if not (np.isfinite(self.readout_s) and 0.0 <= self.readout_s <= MAX_READOUT_S):
            raise SequenceFormatError(
                f"camera readout_s (rolling-shutter readout time) must be from 0 to {MAX_READOUT_S:g} s, got "
                f"{self.readout_s} (0 for a global shutter; a 30 frames/s rolling shutter reads out in at most 0.033 s)"
            )

    def row_time_s(self, v_px: np.ndarray) -> np.ndarray:
        """When row ``v_px`` was exposed, relative to the frame's time (its middle row), in seconds.

        A rolling shutter exposes the rows top to bottom over ``readout_s``: row v at
        ``readout_s (v - (H - 1) / 2) / (H - 1)``. ``(...)`` -> same shape; zeros for a global shutter.
        """
        v = np.asarray(v_px, dtype=np.float64)
        if self.readout_s == 0.0:
            return np.zeros_like(v)
        return self.readout_s * (v - 0.5 * (self.height_px - 1)) / max(self.height_px - 1, 1)

    @property
    def focal_px(self) -> float:
        """The single focal length f of equation (3): mean of fx and fy."""
        return 0.5 * (self.fx_px + self.fy_px)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.distortion, dtype=np.float64)

    @cached_property
    def has_distortion(self) -> bool:  # cached: asked several times a frame, and the camera is frozen
        return bool(np.any(np.asarray(self.distortion) != 0.0))

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the images."""
        return (self.height_px, self.width_px)


@dataclass(frozen=True)
class LaserPointer:
    """One laser pointer: a ray from ``origin_m`` along ``direction`` (body frame, from the camera centre)."""

    origin_m: tuple[float, float, float]
    direction: tuple[float, float, float] = field(default=(0.0, 0.0, 1.0))

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, dtype=float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or not np.any(d) or d[2] <= 0:
            raise SequenceFormatError(
                f"laser direction must be 3 finite numbers pointing down (z > 0), got {self.direction}"
            )
        scaled = d / np.max(np.abs(d))  # no overflow in the norm of huge numbers
        if scaled[2] / np.linalg.norm(scaled) < MIN_LASER_COS:
            raise SequenceFormatError(
                f"laser direction {self.direction} points {np.degrees(np.arccos(scaled[2] / np.linalg.norm(scaled))):.1f} "
                f"degrees from the optical axis: more than {np.degrees(np.arccos(MIN_LASER_COS)):.0f} and its spot never "
                "reaches the seabed in view (direction is (forward, starboard, down), down about 1)"
            )
        if len(self.origin_m) != 3 or not np.all(np.isfinite(self.origin_m)):
            raise SequenceFormatError(f"laser origin_m must be 3 finite numbers, got {self.origin_m}")
        if np.linalg.norm(self.origin_m) > MAX_LASER_OFFSET_M:
            raise SequenceFormatError(
                f"laser origin_m {self.origin_m} is more than {MAX_LASER_OFFSET_M:g} m from the camera: "
                "origins are in metres from the camera centre (body frame)"
            )

    @property
    def unit_direction(self) -> np.ndarray:
        """(3,) the direction scaled to length 1 (a direction of 1e308 or 1e-320 too: its norm would not be finite)."""
        d = np.asarray(self.direction, dtype=float)
        with np.errstate(over="ignore", under="ignore"):
            n = float(np.linalg.norm(d))
        if not (math.isfinite(n) and n > 0.0):
            d = d / np.max(np.abs(d))  # the same ray, in numbers whose norm is finite
            n = float(np.linalg.norm(d))
        return d / n


def rot2(psi_rad: float) -> np.ndarray:
    """R(psi) of equation (1): (2, 2) rotation from body/level to world."""
    c, s = np.cos(psi_rad), np.sin(psi_rad)
    return np.array([[c, -s], [s, c]])


def drot2(psi_rad: float) -> np.ndarray:
    """dR/dpsi: (2, 2) derivative of :func:`rot2`, ``[[-sin, -cos], [cos, -sin]]``."""
    c, s = np.cos(psi_rad), np.sin(psi_rad)
    return np.array([[-s, -c], [c, -s]])


def wrap_angle(angle_rad):
    """Angle(s) wrapped to [-pi, pi). Scalars stay Python floats; arrays are wrapped element-wise."""
    if isinstance(angle_rad, np.ndarray):
        return (angle_rad + np.pi) % (2.0 * np.pi) - np.pi
    return (float(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


def step_mean_heading_rad(heading_rad: np.ndarray) -> np.ndarray:
    """``(N,)`` headings -> ``(N-1,)`` the mean of each consecutive pair, taken on the circle."""
    psi = np.asarray(heading_rad, dtype=np.float64)
    return np.arctan2(np.sin(psi[:-1]) + np.sin(psi[1:]), np.cos(psi[:-1]) + np.cos(psi[1:]))


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def level_from_body(roll_rad: float = 0.0, pitch_rad: float = 0.0) -> np.ndarray:
    """(3, 3) rotation taking body-frame vectors to the level frame: Ry(pitch) Rx(roll)."""
    return rot_y(pitch_rad) @ rot_x(roll_rad)


def body_from_camera(camera: Camera) -> np.ndarray:
    """(3, 3) rotation taking camera-frame vectors to the body frame (includes the yaw offset)."""
    return _body_from_camera(camera.yaw_offset_rad)


def _body_from_camera(yaw_offset_rad: float) -> np.ndarray:
    return rot_z(yaw_offset_rad) @ _BODY_FROM_CAMERA_NOMINAL


@lru_cache(maxsize=16)
def _level_from_camera(roll_rad: float, pitch_rad: float, yaw_offset_rad: float) -> np.ndarray:
    """(3, 3) read-only rotation camera -> level frame, ``level_from_body @ body_from_camera``.

    Computed once per attitude: a frame projects its spots, tokens and landmarks under the same one.
    """
    rot = level_from_body(roll_rad, pitch_rad) @ _body_from_camera(yaw_offset_rad)
    rot.flags.writeable = False
    return rot


def level_from_camera(camera: Camera, roll_rad: float = 0.0, pitch_rad: float = 0.0) -> np.ndarray:
    """(3, 3) rotation taking camera-frame vectors to the level frame (read-only; do not modify)."""
    return _level_from_camera(float(roll_rad), float(pitch_rad), float(camera.yaw_offset_rad))


def undistort_pixels(camera: Camera, uv_px: np.ndarray) -> np.ndarray:
    """Remove lens distortion. (N, 2) distorted pixels -> (N, 2) ideal pinhole pixels."""
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    if not camera.has_distortion or len(uv) == 0:
        return uv.copy()
    import cv2

    out = cv2.undistortPoints(
        uv.reshape(-1, 1, 2),
        camera.K,
        camera.dist_coeffs,
        P=camera.K,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
    )
    return out.reshape(-1, 2)


def distort_pixels(camera: Camera, uv_ideal_px: np.ndarray) -> np.ndarray:
    """Apply lens distortion. (N, 2) ideal pinhole pixels -> (N, 2) distorted pixels."""
    uv = np.asarray(uv_ideal_px, dtype=np.float64).reshape(-1, 2)
    if not camera.has_distortion or len(uv) == 0:
        return uv.copy()
    k = np.zeros(8)
    k[: len(camera.distortion)] = camera.distortion
    k1, k2, p1, p2, k3 = k[0], k[1], k[2], k[3], k[4]
    x = (uv[:, 0] - camera.cx_px) / camera.fx_px
    y = (uv[:, 1] - camera.cy_px) / camera.fy_px
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.column_stack([xd * camera.fx_px + camera.cx_px, yd * camera.fy_px + camera.cy_px])


def pixel_rays_level(camera: Camera, uv_px: np.ndarray, roll_rad: float = 0.0, pitch_rad: float = 0.0) -> np.ndarray:
    """Viewing rays of (N, 2) pixels as (N, 3) level-frame directions with unit z (down)."""
    uv = undistort_pixels(camera, uv_px)
    rays_cam = np.column_stack(
        [
            (uv[:, 0] - camera.cx_px) / camera.fx_px,
            (uv[:, 1] - camera.cy_px) / camera.fy_px,
            np.ones(len(uv)),
        ]
    )
    rays = rays_cam @ level_from_camera(camera, roll_rad, pitch_rad).T
    with np.errstate(divide="ignore", invalid="ignore"):
        rays = rays / rays[:, 2:3]
    rays[~(rays[:, 2] > 0)] = np.nan
    return rays


def pixels_to_ground(
    camera: Camera,
    uv_px: np.ndarray,
    altitude_m: float,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """Seabed points seen at (N, 2) pixels as (N, 2) level-frame offsets (forward, starboard) in metres.

    The seabed is the horizontal plane ``altitude_m`` below the camera. Rays that do not
    reach the seabed give NaN. Inverse of :func:`ground_to_pixels`.
    """
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    if camera.has_distortion or roll_rad != 0.0 or pitch_rad != 0.0 or camera.yaw_offset_rad != 0.0:
        rays = pixel_rays_level(camera, uv, roll_rad, pitch_rad)
        return altitude_m * rays[:, :2]
    # Fast path, level pinhole camera: inverse of equation (3).
    return np.column_stack(
        [
            altitude_m * (camera.cy_px - uv[:, 1]) / camera.fy_px,
            altitude_m * (uv[:, 0] - camera.cx_px) / camera.fx_px,
        ]
    )


def ground_to_pixels(
    camera: Camera,
    ground_m: np.ndarray,
    altitude_m: float,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
) -> np.ndarray:
    """(N, 2) level-frame seabed offsets (forward, starboard) in metres -> (N, 2) pixels (u, v).

    Includes tilt and lens distortion. Points behind the camera give NaN.
    """
    g = np.asarray(ground_m, dtype=np.float64).reshape(-1, 2)
    pts_level = np.empty((len(g), 3))
    pts_level[:, :2] = g
    pts_level[:, 2] = float(altitude_m)
    pts_cam = pts_level @ level_from_camera(camera, roll_rad, pitch_rad)  # rot.T on row vectors: camera = rot^T level
    uv = np.empty((len(g), 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        np.divide(pts_cam[:, 0], pts_cam[:, 2], out=uv[:, 0])
        np.divide(pts_cam[:, 1], pts_cam[:, 2], out=uv[:, 1])
    uv[:, 0] *= camera.fx_px
    uv[:, 0] += camera.cx_px
    uv[:, 1] *= camera.fy_px
    uv[:, 1] += camera.cy_px
    uv[~(pts_cam[:, 2] > 0)] = np.nan
    return distort_pixels(camera, uv)


def ground_to_mn(ground_m: np.ndarray, altitude_m: float, focal_px: float) -> np.ndarray:
    """Level-frame seabed offsets (N, 2) metres -> level-equivalent image coordinates [m, n] (N, 2) px.

    These are the (m, n) of equation (3) for an ideal level camera with no yaw offset; the
    pipeline feeds them to the filter so that tilt, distortion and yaw offset stay out of it.
    """
    return np.asarray(ground_m, dtype=np.float64) * (focal_px / altitude_m)


def mn_to_ground(mn_px: np.ndarray, altitude_m: float, focal_px: float) -> np.ndarray:
    """Inverse of :func:`ground_to_mn`."""
    return np.asarray(mn_px, dtype=np.float64) * (altitude_m / focal_px)


def footprint_m(camera: Camera, altitude_m: float) -> tuple[float, float]:
    """Seabed footprint (along-track height, across-track width) in metres of a level camera."""
    return (
        camera.height_px * altitude_m / camera.fy_px,
        camera.width_px * altitude_m / camera.fx_px,
    )
