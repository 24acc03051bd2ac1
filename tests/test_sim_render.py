"""Rendering: water (attenuation, haze), lamps and vignetting, motion blur, marine snow, sensor noise, JPEG."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rovslam.errors import SimulationError
from rovslam.sim import PORTOFINO_CAMERA, Pose, SensorParams, WaterParams, World, render_frame

CAM = PORTOFINO_CAMERA
POSE = Pose(0.05, -0.04, 1.31, 0.3)


@pytest.fixture(scope="module")
def world():
    return World.procedural(6)


def _render(world, water=None, sensor=None, rng=None, **kw):
    return render_frame(world, CAM, kw.pop("pose", POSE), (), water, rng, sensor=sensor, noise_free=rng is None, **kw)


def test_output_type_and_determinism(world):
    a = _render(world, rng=np.random.default_rng(1))
    b = _render(world, rng=np.random.default_rng(1))
    c = _render(world, rng=np.random.default_rng(2))
    assert a.shape == (272, 360, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)  # only the sensor noise differs
    assert np.abs(a.astype(int) - c.astype(int)).mean() < 4.0


def test_rendering_does_not_depend_on_what_was_rendered_before(world):
    fresh = World.procedural(6, grow_m=0.03)  # small canvases: every move rebuilds one
    first = _render(fresh)
    for x in (-0.15, 0.2, 0.05):
        _render(fresh, pose=Pose(x, -x, 1.2, 1.0))
    assert fresh.canvas_builds >= 3
    np.testing.assert_array_equal(first, _render(fresh))
    np.testing.assert_array_equal(first, _render(world))


def test_red_is_lost_fastest_and_more_with_range(world):
    air = _render(world, WaterParams.none(), SensorParams.ideal()).reshape(-1, 3).mean(axis=0)
    wet = _render(world, WaterParams(), SensorParams.ideal()).reshape(-1, 3).mean(axis=0)
    ratio = wet / air
    assert ratio[0] < 0.6 * min(ratio[1], ratio[2])
    # Uniform albedo: doubling the range multiplies each channel by exp(-a_c * 2 * extra range).
    flat = World.from_array(np.full((3000, 3000, 3), 200, np.uint8), 0.5)
    no_haze = WaterParams(backscatter_rgb=(0.0, 0.0, 0.0))
    centre = (slice(126, 146), slice(170, 190))
    low = _render(flat, no_haze, SensorParams.ideal())[centre].reshape(-1, 3).mean(axis=0)
    high = _render(flat, no_haze, SensorParams.ideal(), pose=Pose(0.05, -0.04, 2.62, 0.3))[centre]
    expect = np.exp(-np.array(WaterParams().attenuation_per_m) * 2.0 * (2.62 - 1.31))
    np.testing.assert_allclose(high.reshape(-1, 3).mean(axis=0) / low, expect, rtol=0.03)


def test_turbid_water_lowers_contrast_and_adds_haze(world):
    clear = _render(world, WaterParams()).astype(float)
    turbid = _render(world, WaterParams.turbid()).astype(float)
    g_clear, g_turbid = clear[..., 1], turbid[..., 1]
    assert g_turbid.std() / g_turbid.mean() < 0.7 * g_clear.std() / g_clear.mean()
    lap = lambda g: np.abs(cv2.Laplacian(g, cv2.CV_64F)).mean()  # noqa: E731
    assert lap(g_turbid) < 0.7 * lap(g_clear)  # forward scatter softens the detail


def test_lamp_cone_and_vignetting_darken_the_corners():
    flat = np.full((2000, 2000, 3), 150, np.uint8)
    world = World.from_array(flat, 0.5)
    img = _render(world, WaterParams.none(), SensorParams())[..., 1].astype(float)
    centre = img[116 - 10 : 116 + 10, 197 - 10 : 197 + 10].mean()  # the cone centre is offset
    corners = np.mean([img[:10, :10].mean(), img[:10, -10:].mean(), img[-10:, :10].mean(), img[-10:, -10:].mean()])
    assert 0.45 < corners / centre < 0.75
    ideal = _render(world, WaterParams.none(), SensorParams.ideal())
    assert np.ptp(ideal) == 0 and ideal[0, 0, 0] == 150


def test_motion_blur_follows_the_image_motion(world):
    sensor = SensorParams(exposure_s=0.06)  # 0.15 m/s over 60 ms at 1.31 m: 7.4 px of image motion
    still = _render(world, sensor=sensor).astype(float)[..., 1]
    surge = _render(world, sensor=sensor, velocity_mps=(0.15, 0.0)).astype(float)[..., 1]
    sway = _render(world, sensor=sensor, velocity_mps=(0.0, 0.15)).astype(float)[..., 1]
    dv = lambda g: np.abs(np.diff(g, axis=0)).mean() / np.abs(np.diff(still, axis=0)).mean()  # noqa: E731
    du = lambda g: np.abs(np.diff(g, axis=1)).mean() / np.abs(np.diff(still, axis=1)).mean()  # noqa: E731
    # Surge moves the seabed along v (image down): detail along v is smeared much more than along u.
    assert dv(surge) < 0.6 * du(surge)
    # Sway moves it along u.
    assert du(sway) < 0.6 * dv(sway)
    np.testing.assert_array_equal(still, _render(world, sensor=sensor, velocity_mps=(0.001, 0.0))[..., 1])


def test_sensor_noise_follows_shot_and_read_noise(world):
    sensor = SensorParams(shot_noise_dn=0.2, read_noise_dn=2.0)
    clean = _render(world, sensor=sensor).astype(float)
    noisy = _render(world, sensor=sensor, rng=np.random.default_rng(3)).astype(float)
    resid = (noisy - clean).ravel()
    level = clean.ravel()
    for lo, hi in ((30, 60), (100, 140)):
        sel = (level >= lo) & (level < hi)
        expect = np.sqrt(0.2 * level[sel].mean() + 2.0**2 + 1.0 / 12.0)
        assert resid[sel].std() == pytest.approx(expect, rel=0.1)
    assert abs(resid.mean()) < 0.1


def test_marine_snow_is_in_the_water_not_on_the_seabed(world):
    snowy = WaterParams(marine_snow_per_m3=3000.0)
    base = _render(world, WaterParams()).astype(int)
    a = _render(world, snowy, t_s=0.0).astype(int)
    b = _render(world, snowy, t_s=3.0).astype(int)
    diff_a = (a - base)[..., 1]
    assert diff_a.min() >= -1  # particles only add light
    n_blobs = cv2.connectedComponents((diff_a > 8).astype(np.uint8))[0] - 1
    assert n_blobs >= 10
    # Same pose three seconds later: the seabed is identical, the drifting particles moved.
    moved = (b - base)[..., 1]
    assert np.mean((diff_a > 8) & (moved > 8)) < 0.5 * np.mean(diff_a > 8)
    # Snow parallax: moving the vehicle 5 cm shifts particles by more than the seabed shifts.
    c = _render(world, snowy, pose=Pose(0.10, -0.04, 1.31, 0.3), t_s=0.0).astype(int)
    base_c = _render(world, WaterParams(), pose=Pose(0.10, -0.04, 1.31, 0.3)).astype(int)
    assert np.any((c - base_c)[..., 1] > 8)


def test_jpeg_round_trip(world):
    raw = _render(world, rng=np.random.default_rng(4))
    jpg = _render(world, sensor=SensorParams(jpeg_quality=60), rng=np.random.default_rng(4))
    err = np.abs(raw.astype(int) - jpg.astype(int))
    assert 0.5 < err.mean() < 6.0


def test_bad_render_arguments(world):
    with pytest.raises(SimulationError, match="altitude"):
        Pose(0.0, 0.0, 0.0, 0.0)
    with pytest.raises(SimulationError, match="roll and pitch"):
        Pose(0.0, 0.0, 1.3, 0.0, roll_rad=1.0)
    with pytest.raises(SimulationError, match="finite"):
        Pose(np.nan, 0.0, 1.3)
    with pytest.raises(SimulationError, match="rng"):
        render_frame(world, CAM, POSE)
    with pytest.raises(SimulationError, match="jpeg_quality"):
        SensorParams(jpeg_quality=0)
    with pytest.raises(SimulationError, match="attenuation"):
        WaterParams(attenuation_per_m=(-1.0, 0.1, 0.1))
