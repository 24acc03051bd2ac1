"""Navigation logs (rovslam.io.nav): the [nav] mapping, conventions, interpolation to frame times, bad input."""

from __future__ import annotations

import math
from pathlib import Path

import datasets
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from rovslam.errors import NavigationError
from rovslam.io.nav import (
    NavMapping,
    NavTrack,
    interp_angle_rad,
    nav_mapping,
    quaternions_to_heading,
    read_nav_csv,
)

ROOT = Path(__file__).resolve().parents[1]
SPARUS = datasets.folder("sparus")
needs_sparus = datasets.needs("sparus")


# --------------------------------------------------------------------------- interpolation


def test_headings_interpolate_across_the_wrap():
    t_nav = np.array([0.0, 1.0, 2.0])
    h = np.radians([179.0, -179.0, -170.0])
    got = np.degrees(interp_angle_rad(np.array([0.25, 0.5, 0.75, 1.5]), t_nav, h))
    # Through 180 degrees, not through 0 (a plain linear interpolation would give 89.5, 0, -89.5).
    np.testing.assert_allclose(np.abs(got[:3]), [179.5, 180.0, 179.5], atol=1e-9)
    assert got[0] > 0 and got[2] < 0
    assert got[3] == pytest.approx(-174.5, abs=0.01)


def test_a_frame_at_a_row_time_gets_that_row_exactly():
    t_nav = np.array([0.0, 0.1, 0.2])
    h = np.array([0.3, -2.0, 3.1])
    got = interp_angle_rad(np.array([0.0, 0.1, 0.2]), t_nav, h)
    assert list(got) == [0.3, -2.0, 3.1]


def test_gaps_and_ends():
    tr = NavTrack(np.array([0.0, 1.0, 5.0, 6.0]), np.array([1.0, 2.0, 3.0, 4.0]))
    v = tr.at(np.array([-0.4, -0.6, 0.5, 3.0, 5.5, 6.4, 6.6]), max_gap_s=1.0)
    # Held for half a gap beyond the ends; a 4 s gap is not bridged.
    np.testing.assert_allclose(v[[0, 2, 4, 5]], [1.0, 1.5, 3.5, 4.0])
    assert np.isnan(v[1]) and np.isnan(v[3]) and np.isnan(v[6])


# --------------------------------------------------------------------------- quaternion conventions


def _euler_cases(n: int = 50):
    rng = np.random.default_rng(12)
    return rng.uniform(-math.pi, math.pi, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.3, 0.3, n)


def test_enu_flu_orientation_gives_rovslam_heading_roll_pitch():
    # ROS: yaw from east towards north, pitch about the left axis: yaw = 90 deg - heading, pitch negated.
    h, r, p = _euler_cases()
    q = Rotation.from_euler("ZYX", np.column_stack([math.pi / 2 - h, -p, r])).as_quat()
    hh, rr, pp = quaternions_to_heading(q, ["row"] * len(q), "enu", "flu", "body-to-world")
    np.testing.assert_allclose(np.angle(np.exp(1j * (hh - h))), 0, atol=1e-12)
    np.testing.assert_allclose(rr, r, atol=1e-12)
    np.testing.assert_allclose(pp, p, atol=1e-12)


def test_ned_frd_and_world_to_body():
    h, r, p = _euler_cases()
    rot = Rotation.from_euler("ZYX", np.column_stack([h, p, r]))
    for q, rotates in ((rot.as_quat(), "body-to-world"), (rot.inv().as_quat(), "world-to-body")):
        hh, rr, pp = quaternions_to_heading(q, ["row"] * len(q), "ned", "frd", rotates)
        np.testing.assert_allclose(np.angle(np.exp(1j * (hh - h))), 0, atol=1e-12)
        np.testing.assert_allclose(rr, r, atol=1e-12)
        np.testing.assert_allclose(pp, p, atol=1e-12)


def test_optical_camera_frame_in_ned():
    # OpenCV camera frame: x image right (starboard), y image down (aft), z optical axis (down).
    body_from_camera = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    h, r, p = _euler_cases(10)
    world_from_camera = Rotation.from_euler("ZYX", np.column_stack([h, p, r])).as_matrix() @ body_from_camera
    q = Rotation.from_matrix(world_from_camera).as_quat()
    hh, rr, pp = quaternions_to_heading(q, ["row"] * len(q), "ned", "optical", "body-to-world")
    np.testing.assert_allclose(np.angle(np.exp(1j * (hh - h))), 0, atol=1e-12)
    np.testing.assert_allclose(rr, r, atol=1e-12)


def test_a_wrong_convention_that_makes_the_camera_look_up_is_refused():
    q = Rotation.from_euler("ZYX", [[0.3, 0.0, 0.0]]).as_quat()  # level, z up: a FLU body
    with pytest.raises(NavigationError, match="line 7: .*look 180 degrees away from straight down"):
        quaternions_to_heading(q, ["nav.csv, line 7"], "enu", "frd", "body-to-world")


def test_a_quaternion_that_is_not_unit_length_is_refused():
    with pytest.raises(NavigationError, match="line 3: quaternion .* length 2, not 1"):
        quaternions_to_heading(np.array([[0.0, 0.0, 0.0, 2.0]]), ["nav.csv, line 3"], "enu", "flu", "body-to-world")


def test_a_huge_quaternion_is_refused_without_a_numpy_warning():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning would reach the user's stderr before the error
        with pytest.raises(NavigationError, match="line 4: quaternion .* length inf, not 1"):
            quaternions_to_heading(
                np.array([[1e200, 0.0, 0.0, 1.0]]), ["nav.csv, line 4"], "enu", "flu", "body-to-world"
            )


# --------------------------------------------------------------------------- NAV.csv and its mapping


def _csv(tmp_path: Path, text: str, name: str = "nav.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_default_columns_need_no_mapping(tmp_path):
    p = _csv(tmp_path, "t_s,heading_rad,altitude_m,roll_rad,pitch_rad\n0,0.1,1.3,0.01,0.02\n0.5,0.2,1.4,0.02,0.03\n")
    nav = read_nav_csv(p)
    s = nav.sample(0.25)
    assert s.heading_rad == pytest.approx(0.15) and s.altitude_m == pytest.approx(1.35)
    assert s.roll_rad == pytest.approx(0.015) and s.pitch_rad == pytest.approx(0.025)
    assert "column heading_rad (rad" in nav.heading_detail


def test_mapping_units_offset_and_enu_heading(tmp_path):
    p = _csv(tmp_path, "stamp_ms,yaw_deg,alt\n1000000,90,2.0\n1000500,80,2.2\n")
    m = nav_mapping(
        {"time": "stamp_ms", "time_unit": "ms", "heading": "yaw_deg", "heading_convention": "enu", "altitude": "alt"},
        "cam.toml: [nav]",
        overrides=(("angle_unit", "deg"),),
        time_offset_s=1000.0,
    )
    nav = read_nav_csv(p, m)
    assert nav.span_s[0] <= 0.0 and nav.span_s[1] >= 0.5
    s = nav.sample(0.5)
    assert math.degrees(s.heading_rad) == pytest.approx(10.0)  # ENU yaw 80 deg = 10 deg from north towards east
    assert s.altitude_m == pytest.approx(2.2)


def test_repeated_rows_are_dropped_when_asked(tmp_path):
    text = "t,h\n0.0,10\n0.1,10\n0.2,10\n0.3,20\n0.4,20\n0.5,20\n"
    p = _csv(tmp_path, text)
    m = dict(time="t", heading="h", angle_unit="deg")
    held = read_nav_csv(p, nav_mapping(m))
    dropped = read_nav_csv(p, nav_mapping({**m, "drop_repeated_rows": True}))
    assert list(dropped.heading.t_s) == [0.0, 0.3, 0.5]  # the updates, and the last row
    assert math.degrees(held.sample(0.15).heading_rad) == pytest.approx(10.0)
    assert math.degrees(dropped.sample(0.15).heading_rad) == pytest.approx(15.0)


@pytest.mark.parametrize(
    "table, overrides, needle",
    [
        ({"heading": "hdg"}, (), "[nav] heading = 'hdg' is not a column; the header has: t_s, heading_rad"),
        ({"colour": "red"}, (), "cam.toml: [nav]: key 'colour': unknown key"),
        ({"angle_unit": "grad"}, (), "'grad' is not one of auto, rad, deg"),
        ({"quaternion": ["a", "b"]}, (), "four column names"),
        ({"time_offset_s": "soon"}, (), "key 'time_offset_s': expected a finite number"),
        ({}, (("drop_repeated_rows", "maybe"),), "--nav-map drop_repeated_rows=maybe: expected true or false"),
        ({"quaternion_world": "nwu"}, (), "'nwu' is not one of enu, ned"),
    ],
)
def test_bad_mappings_name_the_key(tmp_path, table, overrides, needle):
    p = _csv(tmp_path, "t_s,heading_rad\n0,0.1\n1,0.2\n")
    with pytest.raises(NavigationError) as exc:
        read_nav_csv(p, nav_mapping(table, "cam.toml: [nav]", overrides))
    assert needle in str(exc.value)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("t_s,heading_rad\n0,0.1\n0,0.2\n", "line 3: time 0 is not after the previous row's"),
        ("t_s,heading_rad\n0,0.1\n1,north\n", "line 3: column 'heading_rad' is not a number: 'north'"),
        ("t_s,heading_rad\n0,0.1\n,0.2\n", "line 3: column 't_s' is empty"),
        ("t_s,heading_rad\n0,0.1\n1,inf\n", "line 3: column 'heading_rad' is not finite"),
        ("t_s,altitude_m\n0,-13.9\n", "line 2: column 'altitude_m' is -13.9: an altitude above the seabed is positive"),
        ("t_s,roll_rad,pitch_rad\n0,10,0\n", "line 2: column 'roll_rad' is 10 rad, beyond +-90 degrees"),
        ("t_s,depth\n0,3\n", "no heading, attitude or altitude column found (header: t_s, depth)"),
        ("t_s,heading_rad\n", "no rows"),
        ("time,heading_rad\n0,1\n", "header is missing column(s) t_s"),
        ("t_s,heading_rad,x\n0,1\n", "line 2: 2 fields, the header has 3"),
        ("t_s,roll_rad\n0,0.1\n", "both roll and pitch"),
    ],
)
def test_bad_rows_name_the_file_line_and_column(tmp_path, text, needle):
    p = _csv(tmp_path, text)
    with pytest.raises(NavigationError) as exc:
        read_nav_csv(p)
    assert str(p) in str(exc.value) and needle in str(exc.value)


def test_a_log_that_does_not_overlap_the_frames_is_refused(tmp_path):
    nav = read_nav_csv(_csv(tmp_path, "t_s,heading_rad\n100,0.1\n101,0.2\n"))
    with pytest.raises(NavigationError, match="do not overlap.*--nav-time-offset"):
        nav.check_overlap((0.0, 20.0), "video", "Align the clocks with --nav-time-offset S.")
    nav.check_overlap((0.0, 100.2), "video", "")  # partly covered: fine


NAV_CELLS = st.one_of(
    st.sampled_from(["0", "0.5", "-1", "1e9", "nan", "inf", "", "x", "1e309", "-0"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rows=st.lists(st.lists(NAV_CELLS, min_size=4, max_size=4), max_size=6),
    header=st.sampled_from(
        [
            ["t_s", "heading_rad", "altitude_m", "x"],
            ["t", "qx", "qy", "qz"],
            ["t_s", "roll_rad", "pitch_rad", "heading_deg"],
        ]
    ),
    table=st.sampled_from([{}, {"time": "t", "quaternion": ["qx", "qy", "qz", "t"]}, {"drop_repeated_rows": True}]),
)
def test_nav_parser_returns_valid_tracks_or_a_named_error(rows, header, table, tmp_path):
    p = tmp_path / "fuzz_nav.csv"
    p.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n", encoding="utf-8")
    try:
        nav = read_nav_csv(p, nav_mapping(table))
    except NavigationError as exc:
        assert "fuzz_nav.csv" in str(exc) or "[nav]" in str(exc)
        return
    for tr in nav.tracks:
        assert np.all(np.isfinite(tr.t_s)) and np.all(np.diff(tr.t_s) > 0) and np.all(np.isfinite(tr.values))
    if nav.altitude is not None:
        assert np.all(nav.altitude.values > 0)


# --------------------------------------------------------------------------- the Sparus log


@needs_sparus
def test_sparus_mapping_of_the_example_camera_file():
    import tomllib

    table = tomllib.loads((ROOT / "examples" / "sparus-camera.toml").read_text())["nav"]
    nav = read_nav_csv(SPARUS / "sparus_snippet.csv", nav_mapping(table))
    # The log's yaw about z up grows from 65.6 to 89.1 deg: rovslam's heading from 24.4 to 0.9 deg.
    h0, h1 = (math.degrees(nav.sample(t).heading_rad) for t in (0.0, 4.2))
    assert h0 == pytest.approx(90 - 65.59, abs=0.05)
    assert h1 - h0 == pytest.approx(-23.1, abs=0.3)
    assert len(nav.heading.t_s) == 13  # 12 navigation updates and the last row; the repeats dropped
    assert nav.roll is None  # attitude = false: its tilt is not the camera's (README, 'Your own dive')


@needs_sparus
def test_sparus_convention_agrees_with_the_video_itself():
    """Independent of rovslam's trackers: SIFT matches between frames give the seabed's rotation and motion.

    The seabed turns clockwise on screen (vehicle turning left: heading decreasing) and moves down
    the image (vehicle moving towards image-up, the camera frame's x axis in the log).
    """
    import av
    import cv2

    frames = []
    with av.open(str(SPARUS / "sparus_snippet.mp4")) as c:
        for packet in c.demux(c.streams.video[0]):
            frames += [cv2.cvtColor(f.to_ndarray(format="rgb24"), cv2.COLOR_RGB2GRAY) for f in packet.decode()]
    sift = cv2.SIFT_create(2000)
    turn_deg, shift = 0.0, np.zeros(2)
    for a, b in zip(frames, frames[1:]):
        ka, da = sift.detectAndCompute(a, None)
        kb, db = sift.detectAndCompute(b, None)
        good = [
            m[0] for m in cv2.BFMatcher().knnMatch(da, db, k=2) if len(m) == 2 and m[0].distance < 0.75 * m[1].distance
        ]
        pa = np.float32([ka[g.queryIdx].pt for g in good])
        pb = np.float32([kb[g.trainIdx].pt for g in good])
        m, _ = cv2.estimateAffinePartial2D(pa, pb, method=cv2.RANSAC)
        turn_deg += math.degrees(math.atan2(m[1, 0], m[0, 0]))  # (u right, v down): > 0 is clockwise on screen
        centre = np.array([192.0, 144.0])
        shift += m[:, :2] @ centre + m[:, 2] - centre
    vehicle_turn_deg = -turn_deg  # the seabed turns one way on screen when the camera turns the other
    import tomllib

    nav = read_nav_csv(
        SPARUS / "sparus_snippet.csv",
        nav_mapping(tomllib.loads((ROOT / "examples" / "sparus-camera.toml").read_text())["nav"]),
    )
    nav_turn_deg = math.degrees(nav.sample(4.2).heading_rad - nav.sample(0.0).heading_rad)
    assert vehicle_turn_deg == pytest.approx(nav_turn_deg, abs=4.0)
    assert shift[1] > 100 and abs(shift[0]) < 0.4 * shift[1]  # mostly down the image: moving forward (image-up)


def test_the_mapping_defaults_are_documented_choices():
    m = NavMapping()
    assert (m.time, m.time_unit, m.heading_convention, m.quaternion_world, m.body) == ("t_s", "s", "ned", "enu", "flu")
    assert NavMapping(quaternion_world="ned").body == "frd"
