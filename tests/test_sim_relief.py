"""Seabed relief: ray-cast geometry (pinhole parallax), lasers and sonar on the relief, lamps on the vehicle."""

from __future__ import annotations

import cv2
import datasets
import numpy as np
import pytest
from test_sim_geometry import BACKGROUND, MM_PER_PX, _centroid
from test_sim_lasers import red_dominance_centres

from rovslam.camera import Camera, ground_to_pixels, rot2
from rovslam.errors import SimulationError
from rovslam.sim import (
    PAPER_LASERS,
    PORTOFINO_CAMERA,
    SCENARIOS,
    Pose,
    SensorParams,
    WaterParams,
    World,
    render_frame,
)
from rovslam.sim._noise import smoothstep
from rovslam.sim.lighting import CausticParams, Lamp, LightingParams, lamp_irradiance
from rovslam.sim.relief import (
    ArrayRelief,
    PhotoReliefParams,
    ProceduralRelief,
    ReliefParams,
    heights_at,
    relief_from_photo,
    sonar_first_return_m,
)
from rovslam.sim.texture import ImageSeabed, ProceduralSeabed, TextureParams

CAM = PORTOFINO_CAMERA
RELIEF_MM = 2.0


def _stones_world(seed: int = 0, dot_sigma_texels: float = 3.0):
    """Bright dots on a dark texture, each on the flat top of a stone 3 to 10 cm high.

    Returns (world, (N, 2) world positions of the dots, (N,) stone heights). The tops are
    flat 12 mm around each dot, the sides fall to the seabed 60 mm out (slope under 3.2).
    """
    n = 1600
    img = np.full((n, n, 3), BACKGROUND, np.uint8)
    rng = np.random.default_rng(seed)
    r0 = c0 = (n - 1) // 2  # the image pixel at the world origin
    pts = []
    for rc in range(64, n - 64, 128):  # dots 64 mm apart
        for cc in range(64, n - 64, 128):
            r, c = rc + rng.uniform(-5, 5), cc + rng.uniform(-5, 5)
            rr, ccs = np.mgrid[int(r) - 16 : int(r) + 17, int(c) - 16 : int(c) + 17]
            blob = BACKGROUND + 200.0 * np.exp(-((rr - r) ** 2 + (ccs - c) ** 2) / (2 * dot_sigma_texels**2))
            img[int(r) - 16 : int(r) + 17, int(c) - 16 : int(c) + 17] = blob.astype(np.uint8)[..., None]
            pts.append(((r0 - r) * MM_PER_PX * 1e-3, (c - c0) * MM_PER_PX * 1e-3))
    pts = np.array(pts)
    tops = rng.uniform(0.03, 0.10, len(pts))
    m = n // 4
    heights = np.zeros((m, m), np.float32)
    yy, xx = np.mgrid[0:m, 0:m]
    o = (m - 1) // 2
    for (x, y), top in zip(pts, tops):
        d = np.hypot(yy - (o - x / (RELIEF_MM * 1e-3)), xx - (o + y / (RELIEF_MM * 1e-3))) * RELIEF_MM * 1e-3
        heights = np.maximum(heights, top * smoothstep(0.06, 0.012, d))
    world = World.from_array(img, MM_PER_PX)
    world.relief = ArrayRelief(heights, RELIEF_MM, origin_px=(o, o))
    return world, pts, tops


def _ideal(world: World, camera: Camera, pose: Pose) -> np.ndarray:
    return render_frame(world, camera, pose, water=WaterParams.none(), sensor=SensorParams.ideal(), noise_free=True)


@pytest.fixture(scope="module")
def stones():
    return _stones_world()


@pytest.mark.parametrize(
    "camera, pose",
    [
        (CAM, Pose(0.0, 0.0, 1.31, 0.0)),
        (CAM, Pose(0.03, -0.05, 1.20, 0.7)),
        (CAM, Pose(0.11, 0.07, 1.31, np.pi / 2)),
        (
            Camera(
                360,
                272,
                1075.0,
                1070.0,
                181.0,
                134.0,
                distortion=(-0.25, 0.12, 0.002, -0.001, 0.0),
                yaw_offset_rad=0.05,
            ),
            Pose(0.01, 0.02, 1.31, 0.4, roll_rad=0.02, pitch_rad=-0.015),
        ),
    ],
)
def test_a_point_on_a_stone_projects_where_a_pinhole_camera_puts_it(stones, camera, pose):
    world, pts, tops = stones
    img = _ideal(world, camera, pose)[..., 1]
    # The dot on a stone of height h is the 3-D point (X, Y, h): a pinhole camera at altitude Z
    # sees it at depth Z - h, i.e. along the ray through (X - x, Y - y) / (Z - h) at unit depth.
    level = (pts - [pose.x_m, pose.y_m]) @ rot2(pose.heading_rad)
    uv = ground_to_pixels(camera, level / (pose.altitude_m - tops)[:, None], 1.0, pose.roll_rad, pose.pitch_rad)
    on_plane = ground_to_pixels(camera, level / pose.altitude_m, 1.0, pose.roll_rad, pose.pitch_rad)
    inside = (uv[:, 0] > 8) & (uv[:, 0] < camera.width_px - 9) & (uv[:, 1] > 8) & (uv[:, 1] < camera.height_px - 9)
    assert inside.sum() >= 20
    err = np.array([np.hypot(*np.subtract(_centroid(img, u, v, half=6), (u, v))) for u, v in uv[inside]])
    assert err.max() < 0.5
    assert err.mean() < 0.05  # in fact about 0.01 px
    # The relief matters: on a flat seabed these dots would be up to 10 px elsewhere.
    assert np.hypot(*(uv - on_plane)[inside].T).max() > 8.0


def test_a_point_on_a_10_cm_stone_moves_8_percent_faster_than_the_sand_beside_it():
    n = 1200
    img = np.full((n, n, 3), BACKGROUND, np.uint8)
    yy, xx = np.mgrid[0:n, 0:n]
    c = (n - 1) // 2
    for dc in (-60, 60):  # two dots 6 cm apart (west: on the stone, east: on the sand)
        blob = 200.0 * np.exp(-((yy - c) ** 2 + (xx - (c + dc)) ** 2) / (2 * 3.0**2))
        img = np.maximum(img, (BACKGROUND + blob).astype(np.uint8)[..., None])
    m = n // 4
    o = (m - 1) // 2
    ry, rx = np.mgrid[0:m, 0:m]
    d = np.hypot(ry - o, rx - (o - 15)) * RELIEF_MM * 1e-3  # stone centred on the west dot
    world = World.from_array(
        img,
        MM_PER_PX,
        relief=ArrayRelief((0.10 * smoothstep(0.06, 0.015, d)).astype(np.float32), RELIEF_MM, origin_px=(o, o)),
    )
    a = _ideal(world, CAM, Pose(-0.02, 0.0, 1.31, 0.0))[..., 1]
    b = _ideal(world, CAM, Pose(0.02, 0.0, 1.31, 0.0))[..., 1]

    def motion(y_m: float, h_m: float) -> float:
        va = CAM.cy_px - CAM.focal_px * 0.02 / (1.31 - h_m)  # rough guesses, refined by the centroid
        vb = CAM.cy_px + CAM.focal_px * 0.02 / (1.31 - h_m)
        u = CAM.cx_px + CAM.focal_px * y_m / (1.31 - h_m)
        return _centroid(b, u, vb, half=6)[1] - _centroid(a, u, va, half=6)[1]

    stone, sand = motion(-0.03, 0.10), motion(0.03, 0.0)
    assert sand == pytest.approx(CAM.focal_px * 0.04 / 1.31, abs=0.05)
    assert stone / sand == pytest.approx(1.31 / 1.21, abs=0.003)  # 8.3 % faster


@pytest.fixture(scope="module")
def relief_world():
    sc = SCENARIOS["portofino-relief"]
    return World.procedural(2, sc.texture, relief=sc.relief), sc


def test_laser_altitude_equals_the_range_to_the_local_relief(relief_world):
    world, sc = relief_world
    offsets = np.array([las.origin_m[:2] for las in PAPER_LASERS])  # vertical beams 5 cm off each axis
    rng = np.random.default_rng(11)
    errors, relief_effect = [], []
    for _ in range(10):
        z = float(rng.uniform(1.2, 1.42))
        pose = Pose(*rng.uniform(-0.4, 0.4, 2), z, float(rng.uniform(-3, 3)))
        img = render_frame(
            world,
            CAM,
            pose,
            PAPER_LASERS,
            sc.water,
            None,
            sensor=sc.sensor,
            spots=sc.spots,
            lighting=sc.lighting,
            noise_free=True,
        )
        centres = red_dominance_centres(img)
        assert len(centres) == 4
        hit = offsets @ rot2(pose.heading_rad).T + [pose.x_m, pose.y_m]
        local_range = z - heights_at(world.relief, hit[:, 0], hit[:, 1])
        predicted = np.column_stack(
            [
                CAM.cx_px + CAM.focal_px * offsets[:, 1] / local_range,
                CAM.cy_px - CAM.focal_px * offsets[:, 0] / local_range,
            ]
        )
        for u, v in centres:
            i = int(np.argmin(np.hypot(*(predicted - (u, v)).T)))
            triangulated = CAM.focal_px * np.hypot(*offsets[i]) / np.hypot(u - CAM.cx_px, v - CAM.cy_px)
            errors.append(abs(triangulated - local_range[i]) / local_range[i])
            relief_effect.append(abs(local_range[i] - z) / z)
    assert max(errors) < 0.01
    assert max(relief_effect) > 0.02  # the beams did land on relief, not on the mean plane


def test_sonar_reports_the_first_echo_from_the_relief_under_its_beam():
    m = 600
    o = (m - 1) // 2
    yy, xx = np.mgrid[0:m, 0:m]
    d = np.hypot(yy - o, xx - o) * RELIEF_MM * 1e-3
    plateau = ArrayRelief((0.08 * smoothstep(0.10, 0.06, d)).astype(np.float32), RELIEF_MM)  # 8 cm, 6 cm radius
    flat = ArrayRelief(np.zeros((m, m), np.float32), RELIEF_MM)
    x = np.array([0.0, 0.0, 0.5])
    y = np.array([0.0, 0.0, 0.0])
    z = np.array([1.31, 2.0, 1.31])
    beam = np.deg2rad(3.0)
    np.testing.assert_allclose(sonar_first_return_m(flat, x, y, z, beam), z, atol=1e-9)
    r = sonar_first_return_m(plateau, x, y, z, beam)
    assert r[0] == pytest.approx(1.31 - 0.08, abs=1e-3)  # on the plateau
    assert r[1] == pytest.approx(2.0 - 0.08, abs=1e-3)
    assert r[2] == pytest.approx(1.31, abs=1e-9)  # 0.5 m away: flat seabed under the beam
    # A plateau just outside the axis but inside a wide beam gives the first echo.
    wide = sonar_first_return_m(plateau, np.array([0.12]), np.array([0.0]), np.array([1.31]), np.deg2rad(8.0))
    assert wide[0] < 1.31 - 0.02


def test_landmark_patches_under_vehicle_lamps_change_over_relief_not_on_a_flat_seabed():
    """The 8 most contrasted 32x32 patches of a frame, seen again from 9.7 cm further (80 px).

    Flat seabed: only the lamps' smooth light field changes, normalised correlation > 0.999.
    Over 10 cm of relief at the scale of the patches (an egg-crate, 10 cm period): parallax
    and shading change the patch, correlation < 0.99: a landmark is never an exact copy.
    """
    yy, xx = np.mgrid[0:1000, 0:1000] * RELIEF_MM * 1e-3
    egg = ArrayRelief(
        (0.05 * np.sin(2 * np.pi * xx / 0.10) * np.sin(2 * np.pi * yy / 0.10)).astype(np.float32), RELIEF_MM
    )
    lighting = SCENARIOS["portofino-relief"].lighting
    shift, z = 80, 1.31
    d = shift * z / CAM.focal_px

    def best_correlations(world: World, x0: float, y0: float) -> np.ndarray:
        a = render_frame(world, CAM, Pose(x0 - d / 2, y0, z, 0.0), lighting=lighting, noise_free=True)[..., 1]
        b = render_frame(world, CAM, Pose(x0 + d / 2, y0, z, 0.0), lighting=lighting, noise_free=True)[..., 1]
        g = a.astype(np.float32)
        mean = cv2.blur(g, (32, 32))
        sd = np.sqrt(np.maximum(cv2.blur(g * g, (32, 32)) - mean * mean, 0.0))
        keep = np.zeros_like(sd)
        keep[22 : 272 - 22 - shift, 22 : 360 - 22] = 1.0  # patches that stay inside the second frame
        sd *= keep
        out = []
        for _ in range(8):
            v, u = np.unravel_index(np.argmax(sd), sd.shape)
            sd[max(0, v - 24) : v + 24, max(0, u - 24) : u + 24] = 0
            tpl = a[v - 16 : v + 16, u - 16 : u + 16]
            win = b[v + shift - 22 : v + shift + 22, u - 22 : u + 22]  # the seabed moves 80 px down
            out.append(cv2.matchTemplate(win, tpl, cv2.TM_CCOEFF_NORMED).max())
        return np.array(out)

    for seed, (x0, y0) in ((4, (0.0, 0.0)), (5, (0.25, -0.2))):
        flat = best_correlations(World.procedural(seed), x0, y0)
        rough = best_correlations(World.procedural(seed, relief=egg), x0, y0)
        assert flat.min() > 0.999, flat
        assert rough.max() < 0.99, rough


def test_lamps_irradiance_falls_as_one_over_r_squared_and_follows_the_normal():
    axis = np.array([0.0, 0.0, 1.0])
    one = np.ones((1, 1), np.float32)
    up = (0 * one, 0 * one, -one)
    e1, r1, _ = lamp_irradiance(np.zeros(3), axis, 4.0, 0 * one, 0 * one, 1.0 * one, *up)
    e2, r2, _ = lamp_irradiance(np.zeros(3), axis, 4.0, 0 * one, 0 * one, 2.0 * one, *up)
    assert (r1[0, 0], r2[0, 0]) == pytest.approx((1.0, 2.0))
    assert e1[0, 0] / e2[0, 0] == pytest.approx(4.0, rel=1e-5)
    s = np.sqrt(0.5)  # a 45 degree facet: facing the lamp (cos 0) vs sideways (cos 45)
    lamp = np.array([1.0, 0.0, 0.0])
    facing, _, _ = lamp_irradiance(
        lamp, np.array([-1.0, 0.0, 0.0]), 1.0, 0 * one, 0 * one, 1.0 * one, s * one, 0 * one, -s * one
    )
    flat, _, _ = lamp_irradiance(lamp, np.array([-1.0, 0.0, 0.0]), 1.0, 0 * one, 0 * one, 1.0 * one, *up)
    assert facing[0, 0] / flat[0, 0] == pytest.approx(1.0 / s, rel=1e-5)


def test_rendered_brightness_follows_the_lamps_distance_and_the_slope_of_the_seabed():
    albedo = World.from_array(np.full((3000, 3000, 3), 100, np.uint8), MM_PER_PX)
    one_lamp = LightingParams(lamps=(Lamp((0.0, 0.0, 0.0)),), ambient=0.0)
    centre = (slice(130, 142), slice(174, 186))

    def centre_level(world, pose, lighting=one_lamp):
        img = render_frame(
            world, CAM, pose, water=WaterParams.none(), sensor=SensorParams.ideal(), lighting=lighting, noise_free=True
        )
        return img[centre][..., 1].astype(float).mean()

    near = centre_level(albedo, Pose(0.0, 0.0, 1.31))
    far = centre_level(albedo, Pose(0.0, 0.0, 2.62))
    assert near == pytest.approx(100.0, abs=0.6)  # exposure set at the reference altitude 1.31 m
    assert far / near == pytest.approx(0.25, abs=0.01)  # 1/r^2
    # A plane sloping up to the east at 1:2, lamp straight above: cos(26.6 deg) of the light.
    m = 800
    yy, xx = np.mgrid[0:m, 0:m]
    slope = ArrayRelief((0.5 * (xx - (m - 1) // 2) * RELIEF_MM * 1e-3).astype(np.float32), RELIEF_MM)
    tilted = World.from_array(np.full((3000, 3000, 3), 100, np.uint8), MM_PER_PX, relief=slope)
    lit = centre_level(tilted, Pose(0.0, 0.0, 1.31))
    assert lit / near == pytest.approx(1.0 / np.sqrt(1.25), abs=0.01)
    # The same with the heading turned: the slope is in the world, the normal turns with it.
    assert centre_level(tilted, Pose(0.0, 0.0, 1.31, 1.2)) == pytest.approx(lit, abs=0.6)


def test_caustics_drift_over_the_seabed_with_time():
    world = World.from_array(np.full((3000, 3000, 3), 100, np.uint8), MM_PER_PX)
    sun = LightingParams(caustics=CausticParams(strength=0.3))
    frames = [
        render_frame(
            world,
            CAM,
            Pose(0.0, 0.0, 1.31),
            water=WaterParams.none(),
            sensor=SensorParams.ideal(),
            lighting=sun,
            noise_free=True,
            t_s=t,
        )[..., 1].astype(float)
        for t in (0.0, 0.0, 2.0)
    ]
    lamps_only = render_frame(
        world,
        CAM,
        Pose(0.0, 0.0, 1.31),
        water=WaterParams.none(),
        sensor=SensorParams.ideal(),
        lighting=LightingParams(),
        noise_free=True,
    )[..., 1].astype(float)
    np.testing.assert_array_equal(frames[0], frames[1])
    assert np.abs(frames[0] - frames[2]).mean() > 2.0  # the network moved
    ratio = frames[0].mean() / lamps_only.mean()
    assert 1.15 < ratio < 1.45  # sunlight adds about 30 % on average
    assert (frames[0] - lamps_only).std() > 10.0  # ... as a contrasted network


def test_procedural_relief_is_seamless_bounded_and_centred():
    seabed = ProceduralSeabed(TextureParams(boulder_density_per_m2=2.0), 5)
    params = ReliefParams(
        ripple_height_m=0.006, stone_height_ratio=0.6, ledge_height_m=0.04, ledge_width_m=0.03, undulation_m=0.008
    )
    a = ProceduralRelief(params, seabed).region(-300, -300, 600, 600)
    b = ProceduralRelief(ReliefParams(**{**params.__dict__, "chunk_texels": 100}), seabed).region(-300, -300, 600, 600)
    np.testing.assert_array_equal(a, b)  # chunk size does not change the relief: no seams
    lo, hi = ProceduralRelief(params, seabed).height_range_m
    assert lo <= a.min() and a.max() <= hi
    assert np.ptp(a) > 0.08  # boulders, ledge and ripples: about 12 cm of relief
    assert abs(float(a.mean())) < 0.015
    gn, ge = np.gradient(a.astype(float), params.texel_mm * 1e-3)
    assert np.hypot(gn, ge).max() < 4.0  # every ray of a +-12 degree camera meets it once
    with pytest.raises(SimulationError, match="ledge_width_m"):
        ReliefParams(ledge_height_m=0.1, ledge_width_m=0.02)


def test_relief_from_the_chamber3_photo_puts_dark_crevices_lower():
    from rovslam.sim.scenarios import shared_data_file

    datasets.skip_unless("chamber3")
    photo = shared_data_file("chamber3/seabed.jpg")
    seabed = ImageSeabed.from_file(photo, 1.0)
    relief = relief_from_photo(seabed, PhotoReliefParams(relief_m=0.08))
    h = relief.heights
    lum = cv2.GaussianBlur(seabed.image[..., 1].astype(np.float32), (0, 0), 20.0)
    assert np.corrcoef(lum[::8, ::8].ravel(), h[::8, ::8].ravel())[0, 1] > 0.5  # brighter is higher
    p1, p99 = np.percentile(h, [1, 99])
    assert p99 - p1 == pytest.approx(0.08, rel=0.05)
    gn, ge = np.gradient(h.astype(float), 1e-3)
    assert np.hypot(gn, ge).max() <= 2.5
    # The relief grid is the photo's: the world origin is the photo's centre pixel on both.
    assert heights_at(relief, np.array([0.0]), np.array([0.0]))[0] == pytest.approx(
        float(h[seabed.origin_px]), abs=1e-6
    )


def test_ray_cast_frames_do_not_depend_on_what_was_rendered_before(relief_world):
    world, sc = relief_world
    fresh = World.procedural(2, sc.texture, relief=sc.relief, grow_m=0.03)  # small canvases: every move rebuilds
    pose = Pose(0.05, -0.04, 1.31, 0.3, 0.01, -0.01)

    def frame(w):
        return render_frame(w, CAM, pose, PAPER_LASERS, lighting=sc.lighting, noise_free=True)

    first = frame(fresh)
    for x in (-0.3, 0.25, 0.05):
        render_frame(fresh, CAM, Pose(x, -x, 1.2, 1.0), lighting=sc.lighting, noise_free=True)
    np.testing.assert_array_equal(first, frame(fresh))
    np.testing.assert_array_equal(first, frame(world))


def test_relief_reaching_the_camera_is_refused():
    tall = ArrayRelief(np.full((64, 64), 1.0, np.float32), RELIEF_MM)
    world = World.from_array(np.full((500, 500, 3), 100, np.uint8), MM_PER_PX, relief=tall)
    with pytest.raises(SimulationError, match="relief reaches"):
        render_frame(world, CAM, Pose(0.0, 0.0, 1.0), noise_free=True)
    with pytest.raises(SimulationError, match="finite"):
        ArrayRelief(np.full((8, 8), np.nan), 1.0)


def test_rolling_shutter_skews_the_image_by_the_motion_during_readout():
    from dataclasses import replace

    from test_sim_geometry import _dot_world

    world, pts = _dot_world()
    readout, speed = 0.03, 0.5
    sensor = replace(SensorParams.ideal(), readout_s=readout)
    pose = Pose(0.0, 0.0, 1.31, 0.0)
    img = render_frame(
        world, CAM, pose, water=WaterParams.none(), sensor=sensor, velocity_mps=(speed, 0.0), noise_free=True
    )[..., 1]
    glob = _ideal(world, CAM, pose)[..., 1]
    mn = (CAM.focal_px / pose.altitude_m) * pts  # heading 0: forward = north
    u, v = CAM.cx_px + mn[:, 1], CAM.cy_px - mn[:, 0]
    inside = (u > 12) & (u < CAM.width_px - 13) & (v > 20) & (v < CAM.height_px - 21)
    shifts, expected = [], []
    for ui, vi in zip(u[inside], v[inside]):
        _, v_glob = _centroid(glob, ui, vi)
        _, v_roll = _centroid(img, ui, vi)
        _, v_roll = _centroid(img, ui, v_roll)  # again, centred on the shifted dot
        shifts.append(v_roll - v_glob)
        # Row v is exposed readout * (v - centre) / (H - 1) after mid-frame (v: where the dot is
        # seen): the camera is speed * that further north, so the seabed appears further down.
        expected.append(
            CAM.focal_px
            * speed
            * readout
            * (v_roll - 0.5 * (CAM.height_px - 1))
            / (CAM.height_px - 1)
            / pose.altitude_m
        )
    np.testing.assert_allclose(shifts, expected, atol=0.05)
    assert max(np.abs(expected)) > 4.0


def test_a_relief_scale_multiplies_every_height_and_zero_is_flat():
    from rovslam.sim.relief import scaled_relief

    base = SCENARIOS["portofino-relief"].relief
    assert isinstance(base, ReliefParams)
    half = scaled_relief(base, 0.5)
    assert isinstance(half, ReliefParams)
    assert half.ripple_height_m == pytest.approx(0.5 * base.ripple_height_m)
    assert half.stone_height_ratio == pytest.approx(0.5 * base.stone_height_ratio)
    assert half.ledge_height_m == pytest.approx(0.5 * base.ledge_height_m)
    assert half.undulation_m == pytest.approx(0.5 * base.undulation_m)
    assert scaled_relief(base, 1.0) is base and scaled_relief(base, 0.0) is None
    deep = scaled_relief(base, 1.6)  # the ledge's face widens so that it stays no steeper than the preset's
    assert isinstance(deep, ReliefParams) and deep.ledge_height_m <= 2.0 * deep.ledge_width_m
    photo = scaled_relief(PhotoReliefParams(relief_m=0.08), 1.5)
    assert isinstance(photo, PhotoReliefParams) and photo.relief_m == pytest.approx(0.12)
    # the heights themselves scale: the same seabed, half as deep
    x, y = np.linspace(-0.4, 0.4, 50), np.linspace(0.3, -0.2, 50)
    texture = SCENARIOS["portofino-relief"].texture
    full_h = heights_at(World.procedural(4, texture, relief=base, grow_m=0.05).relief, x, y)
    half_h = heights_at(World.procedural(4, texture, relief=half, grow_m=0.05).relief, x, y)
    assert np.std(half_h) == pytest.approx(0.5 * np.std(full_h), rel=0.15)


@pytest.mark.parametrize(
    "relief,scale,needle",
    [
        (None, 2.0, "flat seabed"),
        (ReliefParams(stone_height_ratio=0.6), 2.0, "at most 1.67"),
        (ReliefParams(ripple_height_m=0.01), -1.0, "a number >= 0"),
        (ReliefParams(ripple_height_m=0.01), float("nan"), "a number >= 0"),
    ],
)
def test_a_bad_relief_scale_says_why(relief, scale, needle):
    from rovslam.sim.relief import scaled_relief

    with pytest.raises(SimulationError, match=needle):
        scaled_relief(relief, scale)


def test_simulate_records_the_relief_scale_and_refuses_it_on_a_flat_scenario(tmp_path):
    import tomllib

    from rovslam.sim import simulate

    simulate("portofino-relief", tmp_path / "deep", frames=2, seed=1, relief_scale=1.5)
    meta = tomllib.loads((tmp_path / "deep" / "sequence.toml").read_text())["metadata"]
    assert meta["relief_scale"] == 1.5 and meta["relief"].startswith("ProceduralRelief")
    simulate("portofino-relief", tmp_path / "flat", frames=2, seed=1, relief_scale=0.0)
    assert (
        not (tmp_path / "flat" / "groundtruth.csv")
        .read_text()
        .startswith("t_s,x_m,y_m,altitude_m,heading_rad,relief_m")
    )
    with pytest.raises(SimulationError, match="flat seabed"):
        simulate("portofino-short", tmp_path / "no", frames=2, relief_scale=2.0)
    assert not (tmp_path / "no").exists()  # refused before anything was written
