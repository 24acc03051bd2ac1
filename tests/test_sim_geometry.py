"""Simulator geometry: a seabed point of known world position is rendered where equation (3) says."""

from __future__ import annotations

import numpy as np
import pytest

from rovslam.camera import Camera, footprint_m, ground_to_pixels, pixels_to_ground, rot2
from rovslam.sim import PORTOFINO_CAMERA, Pose, SensorParams, WaterParams, World, render_frame

MM_PER_PX = 0.5
BACKGROUND = 40


def _dot_world(seed: int = 0):
    """A dark image with bright Gaussian dots on a jittered 32 mm grid; their world (x, y) positions."""
    h = w = 1400
    img = np.full((h, w, 3), BACKGROUND, np.uint8)
    rng = np.random.default_rng(seed)
    r0, c0 = (h - 1) // 2, (w - 1) // 2  # this image pixel lies at the world origin
    pts = []
    for rc in range(40, h - 40, 64):
        for cc in range(40, w - 40, 64):
            r, c = rc + rng.uniform(-5, 5), cc + rng.uniform(-5, 5)
            rr, ccs = np.mgrid[int(r) - 25 : int(r) + 26, int(c) - 25 : int(c) + 26]
            blob = BACKGROUND + 200.0 * np.exp(-((rr - r) ** 2 + (ccs - c) ** 2) / (2 * 6.0**2))
            img[int(r) - 25 : int(r) + 26, int(c) - 25 : int(c) + 26] = blob.astype(np.uint8)[..., None]
            # Image up is north (+x), image right is east (+y).
            pts.append(((r0 - r) * MM_PER_PX * 1e-3, (c - c0) * MM_PER_PX * 1e-3))
    return World.from_array(img, MM_PER_PX), np.array(pts)


def _centroid(grey: np.ndarray, u: float, v: float, half: int = 10) -> tuple[float, float]:
    iu, iv = int(round(u)), int(round(v))
    win = np.clip(grey[iv - half : iv + half + 1, iu - half : iu + half + 1].astype(float) - BACKGROUND, 0, None)
    yy, xx = np.mgrid[iv - half : iv + half + 1, iu - half : iu + half + 1]
    return float((win * xx).sum() / win.sum()), float((win * yy).sum() / win.sum())


def _render_ideal(world: World, camera: Camera, pose: Pose) -> np.ndarray:
    return render_frame(world, camera, pose, water=WaterParams.none(), sensor=SensorParams.ideal(), noise_free=True)


@pytest.fixture(scope="module")
def dots():
    return _dot_world()


@pytest.mark.parametrize(
    "pose",
    [
        Pose(0.0, 0.0, 1.31, 0.0),
        Pose(0.03, -0.05, 1.20, 0.7),
        Pose(-0.05, 0.02, 1.50, -2.0),
        Pose(0.11, 0.07, 1.31, np.pi / 2),
    ],
)
def test_known_seabed_points_appear_where_equation_3_predicts(dots, pose):
    world, pts = dots
    cam = PORTOFINO_CAMERA
    img = _render_ideal(world, cam, pose)
    # Equation (3): [m, n] = f/Z R(psi)^T [X - x, Y - y]; u = cx + n, v = cy - m.
    mn = (cam.focal_px / pose.altitude_m) * (pts - [pose.x_m, pose.y_m]) @ rot2(pose.heading_rad)
    u, v = cam.cx_px + mn[:, 1], cam.cy_px - mn[:, 0]
    inside = (u > 12) & (u < cam.width_px - 13) & (v > 12) & (v < cam.height_px - 13)
    assert inside.sum() >= 60
    err = [np.hypot(*np.subtract(_centroid(img[..., 1], ui, vi), (ui, vi))) for ui, vi in zip(u[inside], v[inside])]
    assert max(err) < 0.5
    assert np.mean(err) < 0.05  # in fact about 0.004 px


@pytest.mark.parametrize("distortion", [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.25, 0.12, 0.002, -0.001, 0.0)])
def test_tilt_yaw_offset_and_distortion_follow_camera_model(dots, distortion):
    world, pts = dots
    cam = Camera(360, 272, 1075.0, 1070.0, 181.0, 134.0, distortion=distortion, yaw_offset_rad=0.05)
    pose = Pose(0.01, 0.02, 1.31, 0.4, roll_rad=0.02, pitch_rad=-0.015)
    img = _render_ideal(world, cam, pose)
    level = (pts - [pose.x_m, pose.y_m]) @ rot2(pose.heading_rad)  # R(psi)^T [X - x, Y - y]
    uv = ground_to_pixels(cam, level, pose.altitude_m, pose.roll_rad, pose.pitch_rad)
    inside = (uv[:, 0] > 12) & (uv[:, 0] < cam.width_px - 13) & (uv[:, 1] > 12) & (uv[:, 1] < cam.height_px - 13)
    assert inside.sum() >= 60
    err = [np.hypot(*np.subtract(_centroid(img[..., 1], u, v), (u, v))) for u, v in uv[inside]]
    assert max(err) < 0.5


def test_every_pixel_samples_the_inverse_mapped_texture():
    """Compare a whole frame with the texture sampled directly at pixels_to_ground of every pixel."""
    h = w = 1600
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    # A smooth pattern (periods >= 8 mm: no aliasing, no prefilter loss) in all channels.
    pattern = 128 + 60 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + 40 * np.sin((xx + 2 * yy) / 31.0)
    tex = np.repeat(pattern.astype(np.uint8)[..., None], 3, axis=2)
    world = World.from_array(tex, 0.5)
    cam = PORTOFINO_CAMERA
    pose = Pose(0.05, -0.08, 1.25, 0.9)
    img = _render_ideal(world, cam, pose)[..., 0].astype(float)
    vv, uu = np.mgrid[0 : cam.height_px, 0 : cam.width_px]
    ground = pixels_to_ground(cam, np.column_stack([uu.ravel(), vv.ravel()]), pose.altitude_m)
    xy = ground @ rot2(pose.heading_rad).T + [pose.x_m, pose.y_m]  # eq. (4)
    rows = (h - 1) // 2 - xy[:, 0] / 0.5e-3
    cols = (w - 1) // 2 + xy[:, 1] / 0.5e-3
    r0, c0 = np.floor(rows).astype(int), np.floor(cols).astype(int)
    fr, fc = rows - r0, cols - c0
    pf = pattern.astype(np.uint8).astype(float)
    ref = (
        (1 - fr) * (1 - fc) * pf[r0, c0]
        + (1 - fr) * fc * pf[r0, c0 + 1]
        + fr * (1 - fc) * pf[r0 + 1, c0]
        + fr * fc * pf[r0 + 1, c0 + 1]
    )
    diff = np.abs(img.ravel() - ref)
    assert np.mean(diff) < 1.0
    assert np.percentile(diff, 99) < 3.0


def test_footprint_of_the_portofino_camera():
    along, across = footprint_m(PORTOFINO_CAMERA, 1.31)
    assert along == pytest.approx(0.331, abs=0.002)  # the paper's "about 33 x 44 cm"
    assert across == pytest.approx(0.439, abs=0.002)
