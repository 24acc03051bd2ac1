"""ROS bags (rovslam.io.bag): image encodings, heading and altitude topics and their conventions, CameraInfo,
`rovslam topics`, streaming, and bad bags / topics as one line and exit code 2."""

from __future__ import annotations

import inspect
import math

import cv2
import fuzz_corpus as fc
import numpy as np
import pytest
from rosbag_writer import T0_NS, BagWriter, orientation_xyzw
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.errors import BagError
from rovslam.io.bag import BagSource, open_bag
from rovslam.io.camera_file import read_camera_file
from rovslam.io.source import InputOptions

W, H, N = 64, 48, 5
HEADINGS = [3.0, 3.1, -3.12, -3.0, 2.9]  # across the +-pi wrap
ENCODINGS = ["rgb8", "bgr8", "mono8", "mono16", "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8"]


def _smooth_frames() -> list[np.ndarray]:
    """Smooth colour frames (a demosaicked Bayer image is then close to the original)."""
    rng = np.random.default_rng(7)
    out = []
    for _ in range(N):
        small = rng.integers(30, 220, (6, 8, 3)).astype(np.uint8)
        out.append(cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC))
    return out


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("bags")
    frames = _smooth_frames()
    cam = d / "cam.toml"
    cam.write_text(fc.camera_toml(W, H).replace('format = "rovslam-sequence/1"\n', ""))
    paths = {}
    for flavour, name in (("ros1", "all.bag"), ("mcap", "all_mcap")):
        with BagWriter(d / name, flavour) as bag:
            bag.write(
                "/info",
                "sensor_msgs/msg/CameraInfo",
                bag.camera_info(T0_NS, W, H, [210.0, 0, 30.0, 0, 205.0, 22.0, 0, 0, 1], [0.01, -0.002, 0, 0, 0]),
                T0_NS,
            )
            bag.write(
                "/info_wrong",
                "sensor_msgs/msg/CameraInfo",
                bag.camera_info(T0_NS, 2 * W, H, [210.0, 0, 30.0, 0, 205.0, 22.0, 0, 0, 1], []),
                T0_NS,
            )
            for k, img in enumerate(frames):
                ns = T0_NS + k * 200_000_000
                for enc in ENCODINGS:
                    bag.write(f"/img/{enc}", "sensor_msgs/msg/Image", bag.image(ns, img, enc), ns)
                for fmt in ("png", "jpg"):
                    bag.write(f"/img/{fmt}", "sensor_msgs/msg/CompressedImage", bag.compressed(ns, img, fmt), ns)
                h = HEADINGS[k]
                bag.write("/h/imu_enu", "sensor_msgs/msg/Imu", bag.imu(ns, orientation_xyzw(h, 0.02, -0.03, "enu")), ns)
                bag.write("/h/imu_ned", "sensor_msgs/msg/Imu", bag.imu(ns, orientation_xyzw(h, 0.02, -0.03, "ned")), ns)
                bag.write(
                    "/h/odom", "nav_msgs/msg/Odometry", bag.odometry(ns, orientation_xyzw(h, 0.0, 0.0, "enu")), ns
                )
                bag.write("/h/deg", "std_msgs/msg/Float64", bag.float64(math.degrees(h)), ns)
                bag.write("/h/none", "sensor_msgs/msg/Imu", bag.imu(ns, (0.0, 0.0, 0.0, 1.0), no_orientation=True), ns)
                bag.write("/alt/range", "sensor_msgs/msg/Range", bag.range(ns, 1.3 + 0.01 * k if k != 2 else 50.0), ns)
                bag.write("/alt/f64", "std_msgs/msg/Float64", bag.float64(1.5 + 0.01 * k), ns)
                early = ns - 3_600_000_000_000  # an hour before the images
                bag.write("/h/early", "sensor_msgs/msg/Imu", bag.imu(early, orientation_xyzw(h, 0, 0, "enu")), early)
        paths[flavour] = d / name
    return {"frames": frames, "camera": cam, **paths}


def _source(bags, flavour: str = "ros1", **options):
    return open_bag(
        bags[flavour], read_camera_file(bags["camera"]), InputOptions(camera_file=bags["camera"], **options)
    )


@pytest.mark.parametrize("flavour", ["ros1", "mcap"])
@pytest.mark.parametrize("enc", ENCODINGS + ["png", "jpg"])
def test_image_encodings(bags, flavour, enc):
    src = _source(bags, flavour, image_topic=f"/img/{enc}")
    got = [f.image for f in src.frames()]
    assert len(got) == N and all(g is not None and g.shape == (H, W, 3) and g.dtype == np.uint8 for g in got)
    for g, want in zip(got, bags["frames"]):
        if enc in ("rgb8", "bgr8", "png"):
            assert np.array_equal(g, want)
        elif enc in ("mono8", "mono16"):
            grey = cv2.cvtColor(want, cv2.COLOR_RGB2GRAY)
            assert np.array_equal(g, np.dstack([grey] * 3))  # mono16 = grey * 257, scaled back by 255 / 65535
        elif enc == "jpg":
            assert np.abs(g.astype(int) - want).mean() < 3.0
        else:  # Bayer: demosaicked; the right pattern gives every channel back, a wrong one swaps red and blue
            err = np.abs(g.astype(int) - want).mean(axis=(0, 1))
            assert np.all(err < 6.0), err
            swapped = np.abs(g[:, :, ::-1].astype(int) - want).mean()
            assert swapped > 3 * err.mean()


def test_frames_are_streamed_one_message_at_a_time(bags, monkeypatch):
    from rovslam.io import bag as bag_module

    decoded = []
    original = bag_module._Reader.deserialize

    def counting(self, raw, msgtype, where):
        decoded.append(msgtype)
        return original(self, raw, msgtype, where)

    src = BagSource(bags["ros1"], read_camera_file(bags["camera"]), InputOptions(image_topic="/img/rgb8"))
    monkeypatch.setattr(bag_module._Reader, "deserialize", counting)
    stream = src.frames()
    assert inspect.isgenerator(stream)
    first = next(stream)
    assert first.index == 0 and first.t_s == 0.0
    assert len(decoded) == 1  # the other images are still in the bag
    stream.close()


@pytest.mark.parametrize("flavour", ["ros1", "mcap"])
@pytest.mark.parametrize(
    "topic, convention, degrees, attitude",
    [
        ("/h/imu_enu", "enu", False, True),
        ("/h/imu_ned", "ned", False, True),
        ("/h/odom", "enu", False, False),
        ("/h/deg", "enu", True, False),
    ],
)
def test_heading_topics_and_conventions(bags, flavour, topic, convention, degrees, attitude):
    src = _source(
        bags,
        flavour,
        image_topic="/img/rgb8",
        heading_topic=topic,
        heading_convention=convention,
        heading_degrees=degrees,
        attitude_topic=topic if attitude else None,
        altitude_topic="/alt/range",
    )
    frames = list(src.frames())
    np.testing.assert_allclose(
        [math.remainder(f.heading_rad - h, 2 * math.pi) for f, h in zip(frames, HEADINGS)], 0, atol=1e-9
    )
    if attitude:
        assert all(f.has_attitude for f in frames)
        np.testing.assert_allclose([f.roll_rad for f in frames], 0.02, atol=1e-9)
        np.testing.assert_allclose([f.pitch_rad for f in frames], -0.03, atol=1e-9)
    # Range: the reading of frame 2 (50 m) is beyond max_range (30 m): dropped, interpolated over.
    np.testing.assert_allclose([f.sonar_altitude_m for f in frames], [1.30, 1.31, 1.32, 1.33, 1.34], atol=1e-9)
    d = src.description
    assert d.heading_input == "navigation" and d.altitude_input == "sonar" and topic in d.heading_detail


def test_camera_info_replaces_the_intrinsics(bags):
    src = _source(bags, image_topic="/img/rgb8", camera_info_topic="/info")
    cam = src.info.camera
    assert (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px) == (210.0, 205.0, 30.0, 22.0)
    assert cam.distortion[:2] == (0.01, -0.002)
    with pytest.raises(BagError, match="CameraInfo is 128x48 px, the camera file says 64x48"):
        _source(bags, image_topic="/img/rgb8", camera_info_topic="/info_wrong")


def test_float64_altitude_is_navigation(bags):
    src = _source(bags, image_topic="/img/rgb8", altitude_topic="/alt/f64")
    assert [round(f.sonar_altitude_m, 6) for f in src.frames()] == [1.5, 1.51, 1.52, 1.53, 1.54]
    assert src.description.altitude_input == "navigation"
    assert all(math.isnan(f.heading_rad) for f in src.frames())  # no heading topic: no compass


def test_topics_command_lists_types_counts_rates_and_options(bags):
    res = CliRunner().invoke(app, ["topics", str(bags["mcap"])], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.stderr
    out = res.stdout
    assert "ROS 2 bag (MCAP)" in out
    line = next(ln for ln in out.splitlines() if "/img/rgb8" in ln)
    assert "sensor_msgs/msg/Image" in line and f" {N} " in line and "5.00" in line and "--image-topic" in line
    line = next(ln for ln in out.splitlines() if "/h/deg" in ln)
    assert "std_msgs/msg/Float64" in line and "--heading-topic, --altitude-topic" in line
    res1 = CliRunner().invoke(app, ["topics", str(bags["ros1"])], env={"COLUMNS": "200"})
    assert res1.exit_code == 0 and "ROS 1 bag" in res1.stdout and "/alt/range" in res1.stdout


def _cli_error(args: list[str]) -> str:
    res = CliRunner().invoke(app, [str(a) for a in args])
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("rovslam: error: "), (
        res.exit_code,
        res.stderr,
    )
    return lines[0]


def test_a_topic_that_does_not_exist_lists_those_that_do(bags, tmp_path):
    line = _cli_error(
        [
            "run",
            bags["ros1"],
            "--camera",
            bags["camera"],
            "--image-topic",
            "/camera/image_raw",
            "--out",
            tmp_path / "o",
            "-q",
        ]
    )
    assert "no topic '/camera/image_raw' (--image-topic). The bag has: /alt/f64 (std_msgs/msg/Float64, 5);" in line
    assert "/img/rgb8 (sensor_msgs/msg/Image, 5)" in line


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--heading-topic", "/alt/range"], "topic '/alt/range' is sensor_msgs/msg/Range; --heading-topic takes"),
        (["--heading-topic", "/h/none"], "this Imu gives no orientation"),
        (["--heading-topic", "/h/early"], "do not overlap"),
        (["--nav", "x.csv"], "--nav cannot be used with ROS 1 bag"),
        (["--fps", "5"], "--fps cannot be used"),
        (["--heading-convention", "nwu"], "--heading-convention must be enu or ned"),
    ],
)
def test_bad_bag_options(bags, tmp_path, extra, needle):
    line = _cli_error(
        [
            "run",
            bags["ros1"],
            "--camera",
            bags["camera"],
            "--image-topic",
            "/img/rgb8",
            *extra,
            "--out",
            tmp_path / "o",
            "-q",
        ]
    )
    assert needle in line


def test_a_bag_needs_an_image_topic_and_a_camera(bags, tmp_path):
    line = _cli_error(["run", bags["ros1"], "--camera", bags["camera"], "--out", tmp_path / "o"])
    assert "a bag needs --image-topic T. Its image topics: /img/bayer_bggr8" in line
    line = _cli_error(["run", bags["ros1"], "--image-topic", "/img/rgb8", "--out", tmp_path / "o"])
    assert "a ROS 1 bag needs --camera CAMERA.toml, a camera file with [camera] (width_px" in line


def test_damaged_bags(bags, tmp_path):
    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    assert "not a readable ROS 1 bag" in _cli_error(["topics", garbage])
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bags["ros1"].read_bytes()[:3000])
    assert "cut.bag" in _cli_error(["topics", cut])
    folder = tmp_path / "ros2"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2\n")
    assert "not a readable ROS 2 bag" in _cli_error(["topics", folder])
    lone = tmp_path / "lone" / "dive_0.mcap"
    lone.parent.mkdir()
    lone.write_bytes((next(bags["mcap"].glob("*.mcap"))).read_bytes())
    assert "has no metadata.yaml" in _cli_error(["topics", lone])
    assert "not a ROS bag" in _cli_error(["topics", tmp_path])


def test_a_bag_folder_linking_outside_is_refused(bags, tmp_path):
    import shutil

    folder = tmp_path / "linked"
    shutil.copytree(bags["mcap"], folder)
    data = next(folder.glob("*.mcap"))
    outside = tmp_path / "elsewhere.mcap"
    data.rename(outside)
    data.symlink_to(outside)
    assert "leads outside the bag folder" in _cli_error(["topics", folder])
