"""Camera geometry: equation (3), its inverse, tilt and distortion round trips."""

import numpy as np
import pytest

from rovslam.camera import (
    Camera,
    LaserPointer,
    footprint_m,
    ground_to_mn,
    ground_to_pixels,
    mn_to_ground,
    pixels_to_ground,
    rot2,
)
from rovslam.errors import SequenceFormatError

CAM = Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5)


def test_level_projection_is_equation_3():
    # A seabed point 5 cm forward, 3 cm starboard at Z = 1.31 m: m = f a / Z, n = f b / Z.
    g = np.array([[0.05, 0.03]])
    uv = ground_to_pixels(CAM, g, 1.31)
    m = CAM.cy_px - uv[0, 1]
    n = uv[0, 0] - CAM.cx_px
    assert m == pytest.approx(1075.0 * 0.05 / 1.31, abs=1e-9)
    assert n == pytest.approx(1075.0 * 0.03 / 1.31, abs=1e-9)


def test_world_point_through_heading_matches_equation_3():
    rng = np.random.default_rng(3)
    psi, xy, Z = 0.7, np.array([1.0, -2.0]), 1.31
    X = xy + rng.uniform(-0.1, 0.1, size=(20, 2))
    g = (X - xy) @ rot2(psi)  # R(psi)^T (X - x) for row vectors
    uv = ground_to_pixels(CAM, g, Z)
    mn = np.column_stack([CAM.cy_px - uv[:, 1], uv[:, 0] - CAM.cx_px])
    expected = (1075.0 / Z) * (X - xy) @ rot2(psi)
    np.testing.assert_allclose(mn, expected, atol=1e-9)


@pytest.mark.parametrize("roll,pitch,yaw", [(0.0, 0.0, 0.0), (0.02, -0.015, 0.0), (0.01, 0.02, 0.3)])
def test_pixels_ground_round_trip_with_tilt_and_yaw(roll, pitch, yaw):
    cam = Camera(360, 272, 1075.0, 1070.0, 181.0, 133.0, yaw_offset_rad=yaw)
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [360, 272], size=(50, 2))
    g = pixels_to_ground(cam, uv, 1.2, roll, pitch)
    back = ground_to_pixels(cam, g, 1.2, roll, pitch)
    np.testing.assert_allclose(back, uv, atol=1e-9)


def test_tilt_moves_image_centre_by_altitude_times_angle():
    # A 1 degree tilt at 1.3 m moves the image centre by about 2.3 cm.
    centre = np.array([[CAM.cx_px, CAM.cy_px]])
    g = pixels_to_ground(CAM, centre, 1.3, 0.0, np.deg2rad(1.0))
    assert np.hypot(*g[0]) == pytest.approx(1.3 * np.tan(np.deg2rad(1.0)), rel=1e-9)
    assert np.hypot(*g[0]) == pytest.approx(0.0227, abs=5e-4)


def test_distortion_round_trip():
    cam = Camera(384, 288, 405.6, 405.6, 189.9, 139.9, distortion=(-0.367, 0.203, 0.0033, -0.0005, 0.0))
    rng = np.random.default_rng(1)
    uv = rng.uniform([20, 20], [364, 268], size=(40, 2))
    g = pixels_to_ground(cam, uv, 2.0)
    np.testing.assert_allclose(ground_to_pixels(cam, g, 2.0), uv, atol=1e-4)


def test_mn_helpers_invert_each_other():
    g = np.array([[0.1, -0.2], [0.0, 0.05]])
    np.testing.assert_allclose(mn_to_ground(ground_to_mn(g, 1.31, 1075.0), 1.31, 1075.0), g)


def test_footprint_is_the_papers_33_by_44_cm():
    h, w = footprint_m(CAM, 1.31)
    assert h == pytest.approx(0.331, abs=0.002)
    assert w == pytest.approx(0.439, abs=0.002)


def test_bad_camera_and_laser_are_typed_errors():
    with pytest.raises(SequenceFormatError, match="focal"):
        Camera(360, 272, 0.0, 1075.0, 179.5, 135.5)
    with pytest.raises(SequenceFormatError, match="direction"):
        LaserPointer((0.05, 0.05, 0.0), (0.0, 0.0, -1.0))


@pytest.mark.parametrize(
    "make,needle",
    [
        (
            lambda: Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5, distortion=(1e308, 0.0, 0.0, 0.0, 0.0)),
            "distortion coefficients must be within",
        ),
        (lambda: Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5, yaw_offset_rad=90.0), "give radians, not degrees"),
        (lambda: LaserPointer((0.05, 0.05, 0.0), (0.0, 1e308, 1.0)), "90.0 degrees from the optical axis"),
        (lambda: LaserPointer((0.05, 0.05, 0.0), (1.0, 0.0, 0.1)), "never reaches the seabed"),
    ],
)
def test_absurd_numbers_in_a_camera_or_laser_are_refused_where_they_enter(make, needle):
    # 1e308 in these ran on with overflow warnings and a garbage projection; 90 is degrees.
    with pytest.raises(SequenceFormatError, match=needle):
        make()


def test_a_realistic_inclined_laser_and_a_strong_lens_are_accepted():
    LaserPointer((0.1, 0.0, 0.0), (-0.36, 0.0, 1.0))  # 20 degrees towards the optical axis
    Camera(360, 272, 1075.0, 1075.0, 179.5, 135.5, distortion=(-0.4, 0.2, 0.001, -0.001, -0.05))


def test_level_from_camera_is_the_product_of_the_two_rotations_and_read_only():
    from rovslam.camera import body_from_camera, level_from_body, level_from_camera

    cam = Camera(360, 272, 400.0, 400.0, 180.0, 136.0, yaw_offset_rad=0.02)
    rot = level_from_camera(cam, 0.03, -0.05)
    assert np.array_equal(rot, level_from_body(0.03, -0.05) @ body_from_camera(cam))
    assert level_from_camera(cam, 0.03, -0.05) is rot  # one per attitude
    with pytest.raises(ValueError):
        rot[0, 0] = 1.0
