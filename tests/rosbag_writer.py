"""Write a sequence folder's frames and navigation as a ROS 1 or ROS 2 bag, with rosbags (tests only).

The orientation messages are built from rovslam's heading / roll / pitch with the textbook
relation between the two conventions (ENU yaw = 90 deg - NED heading, pitch negated, roll kept),
not with rovslam's own conversion, so that a test of the reader checks it.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

T0_NS = 1_700_000_000_123_456_789  # the bag's clock at the first frame (a UNIX time)


def typestore(flavour: str):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if flavour == "ros1" else Stores.ROS2_HUMBLE)


def orientation_xyzw(
    heading_rad: float, roll_rad: float, pitch_rad: float, convention: str = "enu"
) -> tuple[float, ...]:
    """The quaternion (x, y, z, w) of an Imu / Odometry orientation for a rovslam heading, roll and pitch."""
    from scipy.spatial.transform import Rotation

    if convention == "enu":
        euler = (math.pi / 2 - heading_rad, -pitch_rad, roll_rad)
    else:
        euler = (heading_rad, pitch_rad, roll_rad)
    return tuple(float(v) for v in Rotation.from_euler("ZYX", euler).as_quat())


class BagWriter:
    """A minimal bag writer over rosbags: ``flavour`` "ros1", "sqlite3" or "mcap"."""

    def __init__(self, path: Path, flavour: str):
        self.flavour = flavour
        self.store = typestore(flavour)
        self.types = self.store.types
        if flavour == "ros1":
            from rosbags.rosbag1 import Writer

            self.writer = Writer(path)
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if flavour == "mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(path, version=9, storage_plugin=plugin)
        self.conns: dict[str, object] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def header(self, ns: int):
        T = self.types
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if self.flavour == "ros1":
            return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="camera")
        return T["std_msgs/msg/Header"](stamp=stamp, frame_id="camera")

    def write(self, topic: str, msgtype: str, msg, bag_ns: int) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store)
        raw = (
            self.store.serialize_ros1(msg, msgtype)
            if self.flavour == "ros1"
            else self.store.serialize_cdr(msg, msgtype)
        )
        self.writer.write(self.conns[topic], bag_ns, raw)

    # ----------------------------------------------------------------- messages
    def image(self, ns: int, rgb: np.ndarray, encoding: str = "rgb8"):
        h, w = rgb.shape[:2]
        if encoding == "rgb8":
            data, step = rgb, 3 * w
        elif encoding == "bgr8":
            data, step = rgb[:, :, ::-1], 3 * w
        elif encoding == "mono8":
            data, step = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), w
        elif encoding == "mono16":
            data, step = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype("<u2") * 257, 2 * w
        elif encoding.startswith("bayer_"):
            pattern = encoding[6:10]  # e.g. rggb: top-left 2x2 of the sensor
            data = np.zeros((h, w), np.uint8)
            idx = {"r": 0, "g": 1, "b": 2}
            for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
                data[dy::2, dx::2] = rgb[dy::2, dx::2, idx[pattern[k]]]
            step = w
        else:
            raise ValueError(encoding)
        raw = np.ascontiguousarray(data).view(np.uint8).ravel()
        return self.types["sensor_msgs/msg/Image"](
            header=self.header(ns), height=h, width=w, encoding=encoding, is_bigendian=0, step=step, data=raw
        )

    def compressed(self, ns: int, rgb: np.ndarray, fmt: str = "png"):
        ok, buf = cv2.imencode("." + fmt, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        assert ok
        return self.types["sensor_msgs/msg/CompressedImage"](
            header=self.header(ns), format=fmt, data=np.frombuffer(buf.tobytes(), np.uint8)
        )

    def imu(self, ns: int, q: tuple[float, ...], no_orientation: bool = False):
        T = self.types
        cov = np.zeros(9)
        if no_orientation:
            cov[0] = -1.0
        return T["sensor_msgs/msg/Imu"](
            header=self.header(ns),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            orientation_covariance=cov,
            angular_velocity=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            linear_acceleration_covariance=np.zeros(9),
        )

    def odometry(self, ns: int, q: tuple[float, ...]):
        T = self.types
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        twist = T["geometry_msgs/msg/Twist"](
            linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        )
        return T["nav_msgs/msg/Odometry"](
            header=self.header(ns),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )

    def range(self, ns: int, value_m: float, lo: float = 0.1, hi: float = 30.0):
        return self.types["sensor_msgs/msg/Range"](
            header=self.header(ns), radiation_type=0, field_of_view=0.1, min_range=lo, max_range=hi, range=value_m
        )

    def float64(self, value: float):
        return self.types["std_msgs/msg/Float64"](data=value)

    def camera_info(self, ns: int, w: int, h: int, K: list[float], D: list[float]):
        T = self.types
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        P = [K[0], 0.0, K[2], 0.0, 0.0, K[4], K[5], 0.0, 0.0, 0.0, 1.0, 0.0]
        fields = dict(
            header=self.header(ns), height=h, width=w, distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=roi
        )
        if self.flavour == "ros1":
            fields.update(D=np.asarray(D, float), K=np.asarray(K, float), R=np.eye(3).ravel(), P=np.asarray(P, float))
        else:
            fields.update(d=np.asarray(D, float), k=np.asarray(K, float), r=np.eye(3).ravel(), p=np.asarray(P, float))
        return T["sensor_msgs/msg/CameraInfo"](**fields)


def sequence_to_bag(
    seq: Path,
    out: Path,
    flavour: str,
    *,
    heading: str = "imu",
    altitude: str = "range",
    attitude: bool = False,
    encoding: str = "rgb8",
    compressed: str | None = None,
    camera_info: tuple[list[float], list[float]] | None = None,
    t0_ns: int = T0_NS,
    nav_between: bool = True,
    convention: str = "enu",
) -> dict[str, str]:
    """Write the frames of sequence folder ``seq`` to a bag; returns the topic names by role.

    Images on /camera/image (stamped t0 + t_s), heading on /nav/heading (Imu, Odometry or Float64),
    altitude on /nav/altitude (Range or Float64) from the sonar column, attitude on /nav/heading
    (roll and pitch of the same orientation) when ``attitude``. With ``nav_between``, navigation
    messages are also written half-way between frames (values interpolated on the unit circle),
    so that the reader interpolates.
    """
    from rovslam.io.sequence import open_sequence

    s = open_sequence(seq)
    rows = s.rows
    topics = {"image": "/camera/image", "heading": "/nav/heading", "altitude": "/nav/altitude", "info": "/camera/info"}
    with BagWriter(out, flavour) as bag:
        if camera_info is not None:
            cam = s.info.camera
            bag.write(
                topics["info"],
                "sensor_msgs/msg/CameraInfo",
                bag.camera_info(t0_ns, cam.width_px, cam.height_px, *camera_info),
                t0_ns,
            )
        nav_rows = []
        for i, r in enumerate(rows):
            nav_rows.append((r.t_s, r.heading_rad, r.roll_rad or 0.0, r.pitch_rad or 0.0, r.sonar_altitude_m))
            if nav_between and i + 1 < len(rows):
                n = rows[i + 1]
                mid = lambda a, b: math.atan2(math.sin(a) + math.sin(b), math.cos(a) + math.cos(b))  # noqa: E731
                alt = (
                    None
                    if r.sonar_altitude_m is None or n.sonar_altitude_m is None
                    else (r.sonar_altitude_m + n.sonar_altitude_m) / 2
                )
                nav_rows.append(
                    (
                        (r.t_s + n.t_s) / 2,
                        mid(r.heading_rad, n.heading_rad),
                        ((r.roll_rad or 0.0) + (n.roll_rad or 0.0)) / 2,
                        ((r.pitch_rad or 0.0) + (n.pitch_rad or 0.0)) / 2,
                        alt,
                    )
                )
        for t, h, roll, pitch, alt in nav_rows:
            ns = t0_ns + int(round(t * 1e9))
            if heading == "float64":
                bag.write(topics["heading"], "std_msgs/msg/Float64", bag.float64(h), ns)
            else:
                q = orientation_xyzw(h, roll if attitude else 0.0, pitch if attitude else 0.0, convention)
                if heading == "imu":
                    bag.write(topics["heading"], "sensor_msgs/msg/Imu", bag.imu(ns, q), ns)
                else:
                    bag.write(topics["heading"], "nav_msgs/msg/Odometry", bag.odometry(ns, q), ns)
            if alt is not None:
                if altitude == "range":
                    bag.write(topics["altitude"], "sensor_msgs/msg/Range", bag.range(ns, alt), ns)
                else:
                    bag.write(topics["altitude"], "std_msgs/msg/Float64", bag.float64(alt), ns)
        for frame in s.frames(prefetch=0):
            ns = t0_ns + int(round(frame.t_s * 1e9))
            if compressed:
                bag.write(
                    topics["image"], "sensor_msgs/msg/CompressedImage", bag.compressed(ns, frame.image, compressed), ns
                )
            else:
                bag.write(topics["image"], "sensor_msgs/msg/Image", bag.image(ns, frame.image, encoding), ns)
    return topics
