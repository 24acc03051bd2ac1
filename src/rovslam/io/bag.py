"""ROS bags as a stream of frames, through ``rosbags`` (no ROS installation): ROS 1 ``.bag``, ROS 2 (sqlite3, MCAP).

``rovslam run BAG --camera CAMERA.toml --image-topic T [--heading-topic T] [--altitude-topic T]
[--attitude-topic T] [--camera-info-topic T]``:

* images: ``sensor_msgs/Image`` (mono8, mono16, rgb8, bgr8, rgba8, bgra8, rgb16, bgr16, bayer_*8
  and bayer_*16, demosaicked by OpenCV; 16-bit values scaled as a sequence's 16-bit files) or
  ``sensor_msgs/CompressedImage`` (JPEG, PNG, TIFF). Streamed: one message decoded at a time.
* heading: ``sensor_msgs/Imu`` or ``nav_msgs/Odometry`` (the orientation, ROS's ENU convention,
  body x forward, y left, z up; ``heading_convention = "ned"`` for x forward, y right, z down in
  a north-east-down world), or ``std_msgs/Float64`` (radians from north towards east, rovslam's
  convention; ``heading_degrees``);
* attitude: roll and pitch of an ``Imu`` or ``Odometry`` orientation, same convention;
* altitude: ``sensor_msgs/Range`` (a sonar: readings outside its min/max range are dropped) or
  ``std_msgs/Float64`` (metres);
* intrinsics: the first ``sensor_msgs/CameraInfo`` replaces ``[camera]``'s focal lengths,
  principal point and distortion (its size must match ``[camera]``'s).

Times are the messages' ``header.stamp`` (the bag's receive time for a message without a header
or with a zero stamp), on a clock whose 0 is the first image. The navigation topics are read
first (they are small) and interpolated to each image's stamp (:mod:`rovslam.io.nav`).
A ROS 2 bag is its folder (with ``metadata.yaml``); nothing outside it is opened.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.camera import Camera
from rovslam.core import Frame, SequenceInfo
from rovslam.errors import (
    BagError,
    ImageReadError,
    NavigationError,
    SequenceFormatError,
)
from rovslam.io.camera_file import CameraFile
from rovslam.io.nav import (
    Navigation,
    NavTrack,
    default_max_gap_s,
    quaternions_to_heading,
)
from rovslam.io.sequence import decode_image, to_rgb
from rovslam.io.source import InputOptions, SourceDescription, option_flag

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ORIENTATION_TYPES = ("sensor_msgs/msg/Imu", "nav_msgs/msg/Odometry")
HEADING_TYPES = (*ORIENTATION_TYPES, "std_msgs/msg/Float64")
ALTITUDE_TYPES = ("sensor_msgs/msg/Range", "std_msgs/msg/Float64")
CAMERA_INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
ROLES = {
    "image_topic": IMAGE_TYPES,
    "heading_topic": HEADING_TYPES,
    "attitude_topic": ORIENTATION_TYPES,
    "altitude_topic": ALTITUDE_TYPES,
    "camera_info_topic": CAMERA_INFO_TYPES,
}
BAG_SUFFIXES = (".bag", ".db3", ".mcap")
MAX_WARNINGS = 20

# ROS encodings -> (channels, dtype, OpenCV conversion to RGB or None)
_ENCODINGS: dict[str, tuple[int, str, str | None]] = {
    "mono8": (1, "u1", None),
    "8UC1": (1, "u1", None),
    "mono16": (1, "u2", None),
    "16UC1": (1, "u2", None),
    "rgb8": (3, "u1", "RGB"),
    "bgr8": (3, "u1", "BGR"),
    "rgba8": (4, "u1", "RGBA"),
    "bgra8": (4, "u1", "BGRA"),
    "rgb16": (3, "u2", "RGB"),
    "bgr16": (3, "u2", "BGR"),
    # ROS names the 2x2 pattern from its top-left pixel; OpenCV 5 has the same names (BayerRGGB...).
    "bayer_rggb8": (1, "u1", "BayerRGGB"),
    "bayer_bggr8": (1, "u1", "BayerBGGR"),
    "bayer_gbrg8": (1, "u1", "BayerGBRG"),
    "bayer_grbg8": (1, "u1", "BayerGRBG"),
    "bayer_rggb16": (1, "u2", "BayerRGGB"),
    "bayer_bggr16": (1, "u2", "BayerBGGR"),
    "bayer_gbrg16": (1, "u2", "BayerGBRG"),
    "bayer_grbg16": (1, "u2", "BayerGRBG"),
}


# --------------------------------------------------------------------------- opening a bag


def bag_location(path: str | Path) -> tuple[Path, str] | None:
    """(what to open, kind) for a ROS bag, or None when ``path`` is not one.

    A ROS 1 bag is a ``.bag`` file; a ROS 2 bag is a folder with ``metadata.yaml`` (a ``.db3`` or
    ``.mcap`` file inside one stands for its folder).
    """
    p = Path(path)
    if p.is_file() and p.suffix.lower() == ".bag":
        return p, "ROS 1 bag"
    if p.is_file() and p.suffix.lower() in (".db3", ".mcap"):
        if not (p.parent / "metadata.yaml").is_file():
            raise BagError(
                f"{p}: a ROS 2 bag is the folder holding this file and its metadata.yaml, and {p.parent} has no "
                "metadata.yaml (rosbags reads a ROS 2 bag through it; `ros2 bag reindex` writes one)."
            )
        p = p.parent
    if p.is_dir() and (p / "metadata.yaml").is_file():
        return p, "ROS 2 bag"
    return None


def _check_inside(folder: Path) -> None:
    """Refuse a ROS 2 bag folder holding a link to a file elsewhere (rosbags would open it)."""
    root = Path(os.path.realpath(folder))
    for entry in os.scandir(folder):
        real = Path(os.path.realpath(entry.path))
        if not real.is_relative_to(root):
            raise BagError(f"{folder}: '{entry.name}' leads outside the bag folder (to {real}); copy the file in.")


class _Reader:
    """An opened rosbags ``AnyReader``; every failure of the library becomes a :class:`BagError` naming the bag."""

    def __init__(self, path: str | Path):
        loc = bag_location(path)
        if loc is None:
            raise BagError(f"{path}: not a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder with metadata.yaml).")
        self.path, self.kind = loc
        self._reader: Any = None

    def __enter__(self) -> _Reader:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        if self.kind == "ROS 2 bag":
            _check_inside(self.path)
        store = get_typestore(Stores.ROS1_NOETIC if self.kind == "ROS 1 bag" else Stores.ROS2_HUMBLE)
        try:
            self._reader = AnyReader([self.path], default_typestore=store)
            self._reader.open()
        except Exception as exc:  # rosbags raises many types for a damaged bag; all are bad input here
            self._reader = None
            raise BagError(f"{self.path}: not a readable {self.kind} ({_why(exc)}).") from None
        if self.kind == "ROS 2 bag":
            mcap = any(e.name.lower().endswith(".mcap") for e in os.scandir(self.path))
            self.kind += " (MCAP)" if mcap else " (sqlite3)"
        return self

    def __exit__(self, *exc: object) -> None:
        if self._reader is not None:
            try:
                self._reader.close()
            except Exception:  # closing a damaged bag: nothing more to learn
                pass
            self._reader = None

    @property
    def topics(self) -> dict[str, tuple[str, int]]:
        """{topic: (message type, count)}."""
        return {name: (info.msgtype or "?", int(info.msgcount)) for name, info in self._reader.topics.items()}

    def connections(self, topic: str) -> list[Any]:
        return [c for c in self._reader.connections if c.topic == topic]

    def _stream(self, topic: str | None) -> Iterator[tuple[Any, int, bytes]]:
        """The library's (connection, bag time ns, raw) of ``topic`` (all topics: None); BagError if the file is damaged."""
        it = self._reader.messages(connections=self.connections(topic) if topic is not None else ())
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as exc:  # a damaged chunk, index or file end
                what = f"the messages of {topic}" if topic is not None else "the messages"
                raise BagError(f"{self.path}: {what} cannot be read ({_why(exc)}).") from None
            yield item

    def raw_messages(self, topic: str) -> Iterator[tuple[int, bytes, str]]:
        """(bag time ns, serialised message, type) of ``topic``, in bag-time order."""
        for conn, t_ns, raw in self._stream(topic):
            yield t_ns, raw, conn.msgtype

    def deserialize(self, raw: bytes, msgtype: str, where: str) -> Any:
        try:
            return self._reader.deserialize(raw, msgtype)
        except Exception as exc:  # a damaged message
            raise BagError(f"{where}: a {msgtype} message that cannot be decoded ({_why(exc)}).") from None

    def messages(self, topic: str) -> Iterator[tuple[int, Any, str]]:
        """(bag time ns, deserialised message, type) of ``topic``, in bag-time order; BagError if one is damaged."""
        for t_ns, raw, msgtype in self.raw_messages(topic):
            yield t_ns, self.deserialize(raw, msgtype, f"{self.path}: {topic} at bag time {t_ns} ns"), msgtype

    def raw_times(self, topic: str | None = None) -> Iterator[tuple[str, int]]:
        """(topic, bag time ns) of every message (of ``topic``), without decoding them."""
        for conn, t_ns, _ in self._stream(topic):
            yield conn.topic, t_ns


def _why(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text if len(text) < 300 else text[:300] + "..."


def stamp_ns(msg: Any, bag_ns: int) -> int:
    """A message's ``header.stamp`` in ns, or its bag time when it has no header or a zero stamp."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return int(bag_ns)
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns > 0 else int(bag_ns)


# --------------------------------------------------------------------------- topics


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: type, message count, first and last bag time (s), mean rate (Hz)."""

    topic: str
    msgtype: str
    count: int
    first_s: float | None
    last_s: float | None

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first_s is None or self.last_s is None or self.last_s <= self.first_s:
            return None
        return (self.count - 1) / (self.last_s - self.first_s)

    @property
    def role(self) -> str:
        """Which ``rovslam run`` option may take this topic ("" when none)."""
        return ", ".join(option_flag(r) for r, types in ROLES.items() if self.msgtype in types)


def list_topics(path: str | Path) -> tuple[str, Path, list[TopicSummary]]:
    """(kind, bag path, topics) of a bag; the times come from one pass over the messages (not decoded)."""
    with _Reader(path) as r:
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        for topic, t in r.raw_times():
            first.setdefault(topic, t)
            last[topic] = t
        out = [
            TopicSummary(
                name,
                msgtype,
                count,
                first[name] / 1e9 if name in first else None,
                last[name] / 1e9 if name in last else None,
            )
            for name, (msgtype, count) in sorted(r.topics.items())
        ]
        return r.kind, r.path, out


def _topic_list(topics: dict[str, tuple[str, int]]) -> str:
    return "; ".join(f"{name} ({msgtype}, {count})" for name, (msgtype, count) in sorted(topics.items())) or "none"


def check_topics(path: Path, topics: dict[str, tuple[str, int]], options: InputOptions) -> None:
    """Refuse a topic the bag does not have (listing those it has) or of a type its option cannot take."""
    for role, types in ROLES.items():
        name = getattr(options, role)
        if name is None:
            continue
        if name not in topics:
            raise BagError(f"{path}: no topic '{name}' ({option_flag(role)}). The bag has: {_topic_list(topics)}.")
        msgtype, count = topics[name]
        if msgtype not in types:
            raise BagError(f"{path}: topic '{name}' is {msgtype}; {option_flag(role)} takes {' or '.join(types)}.")
        if count == 0:
            raise BagError(f"{path}: topic '{name}' ({option_flag(role)}) holds no message.")


# --------------------------------------------------------------------------- images


def image_from_msg(
    msg: Any, msgtype: str, where: str, camera: Camera | None = None, bit_depth: int | None = None
) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB of a sensor_msgs/Image or CompressedImage; :class:`ImageReadError` if it cannot be."""
    if msgtype.endswith("CompressedImage"):
        fmt = str(getattr(msg, "format", "")).lower()
        if "compresseddepth" in fmt:
            raise ImageReadError(f"{where}: a compressedDepth image (a depth map, not a camera image).")
        return decode_image(bytes(msg.data), where, camera, bit_depth, "the camera file")
    import cv2

    enc = str(msg.encoding)
    if enc not in _ENCODINGS:
        raise ImageReadError(
            f"{where}: image encoding '{enc}' is not read by rovslam; it reads {', '.join(_ENCODINGS)}."
        )
    channels, kind, conv = _ENCODINGS[enc]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    size = 2 if kind == "u2" else 1
    data = np.asarray(msg.data, dtype=np.uint8)
    if h <= 0 or w <= 0 or step < w * channels * size or data.size < step * h:
        raise ImageReadError(
            f"{where}: {w}x{h} px with a row step of {step} bytes does not fit its {data.size} bytes of data."
        )
    rows = data[: step * h].reshape(h, step)[:, : w * channels * size]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian and size == 2 else "<")
    img = np.ascontiguousarray(rows).view(dtype).reshape(h, w, channels).astype(np.dtype(kind).newbyteorder("="))
    if conv is not None and conv.startswith("Bayer"):
        img = cv2.cvtColor(img[:, :, 0], getattr(cv2, f"COLOR_{conv}2BGR"))
    elif conv == "RGB":
        img = img[:, :, ::-1]
    elif conv == "RGBA":
        img = img[:, :, [2, 1, 0, 3]]
    elif channels == 1:
        img = img[:, :, 0]
    return to_rgb(np.ascontiguousarray(img), where, camera, bit_depth, "the camera file")


# --------------------------------------------------------------------------- navigation topics


def _orientation(msg: Any, msgtype: str, where: str) -> tuple[float, float, float, float]:
    if msgtype.endswith("Odometry"):
        q = msg.pose.pose.orientation
    else:
        cov = np.asarray(msg.orientation_covariance)
        if cov.size and cov[0] == -1:
            raise NavigationError(f"{where}: this Imu gives no orientation (orientation_covariance[0] = -1).")
        q = msg.orientation
    return float(q.x), float(q.y), float(q.z), float(q.w)


def _series(reader: _Reader, topic: str, t0_ns: int, value: Any) -> tuple[np.ndarray, list[Any], list[str]]:
    """(times s on the frames' clock, values, where) of a topic, sorted by stamp, repeated stamps dropped."""
    t, vals, where = [], [], []
    for bag_ns, msg, msgtype in reader.messages(topic):
        w = f"{reader.path}: {topic} at stamp {stamp_ns(msg, bag_ns)} ns"
        t.append((stamp_ns(msg, bag_ns) - t0_ns) / 1e9)
        vals.append(value(msg, msgtype, w))
        where.append(w)
    order = np.argsort(np.asarray(t), kind="stable")
    ts = np.asarray(t)[order]
    keep = np.concatenate([[True], np.diff(ts) > 0]) if len(ts) else np.zeros(0, bool)
    idx = order[keep]
    return ts[keep], [vals[i] for i in idx], [where[i] for i in idx]


def _require_samples(reader: _Reader, topic: str, what: str, t_s: np.ndarray) -> None:
    """NavigationError naming the bag and topic when the topic gave no usable sample of ``what``."""
    if len(t_s) == 0:
        raise NavigationError(
            f"{reader.path}: topic {topic} ({reader.topics[topic][0]}) holds no usable {what} (no message, or every "
            "value NaN or infinite); give another topic, or leave the option out."
        )


def read_bag_navigation(reader: _Reader, options: InputOptions, t0_ns: int) -> Navigation | None:
    """The heading, attitude and altitude topics as a :class:`Navigation` (None when none is given)."""
    conv = options.heading_convention
    body = "flu" if conv == "enu" else "frd"
    heading = roll = pitch = altitude = None
    details = {"heading": "", "attitude": "", "altitude": ""}
    altitude_input = "navigation"
    topics = reader.topics
    if options.heading_topic is not None:
        name = options.heading_topic
        msgtype = topics[name][0]
        if msgtype.endswith("Float64"):
            scale = math.pi / 180 if options.heading_degrees else 1.0
            t, v, _ = _series(reader, name, t0_ns, lambda m, _t, _w: float(m.data) * scale)
            keep = np.isfinite(v)
            _require_samples(reader, name, "heading", t[keep])
            heading = NavTrack(t[keep], np.asarray(v)[keep], angle=True)
            details["heading"] = (
                f"topic {name} ({msgtype}, {'degrees' if options.heading_degrees else 'radians'} from north towards east)"
            )
        else:
            t, q, where = _series(reader, name, t0_ns, _orientation)
            _require_samples(reader, name, "heading", t)  # no message: said before the quaternions are read
            h, _, _ = quaternions_to_heading(np.asarray(q), where, conv, body, "body-to-world")
            heading = NavTrack(t, h, angle=True)
            details["heading"] = f"topic {name} ({msgtype} orientation, {conv.upper()})"
    if options.attitude_topic is not None:
        name = options.attitude_topic
        t, q, where = _series(reader, name, t0_ns, _orientation)
        _require_samples(reader, name, "attitude", t)
        _, r, p = quaternions_to_heading(np.asarray(q), where, conv, body, "body-to-world")
        roll, pitch = NavTrack(t, r), NavTrack(t, p)
        details["attitude"] = f"topic {name} ({topics[name][0]} orientation, {conv.upper()})"
    if options.altitude_topic is not None:
        name = options.altitude_topic
        msgtype = topics[name][0]
        if msgtype.endswith("Range"):
            altitude_input = "sonar"

            def reading(m: Any, _t: str, _w: str) -> float:
                r = float(m.range)
                return r if math.isfinite(r) and float(m.min_range) <= r <= float(m.max_range) and r > 0 else math.nan
        else:

            def reading(m: Any, _t: str, _w: str) -> float:
                v = float(m.data)
                return v if math.isfinite(v) and v > 0 else math.nan

        t, v, _ = _series(reader, name, t0_ns, reading)
        v = np.asarray(v)  # type: ignore[assignment]
        keep = np.isfinite(v)
        if not np.any(keep):
            raise NavigationError(
                f"{reader.path}: topic {name} ({msgtype}) holds no usable altitude (every reading is "
                "outside its range, not positive or not finite)."
            )
        altitude = NavTrack(t[keep], v[keep])
        details["altitude"] = f"topic {name} ({msgtype}, m)"
    tracks = [x for x in (heading, roll, pitch, altitude) if x is not None]
    if not tracks:
        return None
    return Navigation(
        path=str(reader.path),
        heading=heading,
        roll=roll,
        pitch=pitch,
        altitude=altitude,
        max_gap_s=default_max_gap_s(tracks),
        heading_detail=details["heading"],
        altitude_detail=details["altitude"],
        attitude_detail=details["attitude"],
        altitude_input=altitude_input,
    )


def camera_from_info(msg: Any, camera: Camera, where: str) -> Camera:
    """``camera`` with the focal lengths, principal point and distortion of a sensor_msgs/CameraInfo."""
    width, height = int(msg.width), int(msg.height)
    if (width, height) != (camera.width_px, camera.height_px):
        raise BagError(
            f"{where}: CameraInfo is {width}x{height} px, the camera file says {camera.width_px}x{camera.height_px}."
        )
    k = np.asarray(getattr(msg, "k", getattr(msg, "K", ())), dtype=np.float64).ravel()
    d = [float(x) for x in np.asarray(getattr(msg, "d", getattr(msg, "D", ())), dtype=np.float64).ravel()]
    model = str(getattr(msg, "distortion_model", "")).strip()
    if k.size != 9 or k[0] <= 0 or k[4] <= 0:
        raise BagError(
            f"{where}: CameraInfo holds no calibration (K = {k.tolist()}); leave out --camera-info-topic to use "
            "the camera file's."
        )
    if d and model not in ("plumb_bob", "rational_polynomial", ""):
        raise BagError(f"{where}: distortion model '{model}' is not read by rovslam (plumb_bob, rational_polynomial).")
    if any(d[8:]):
        raise BagError(f"{where}: {len(d)} distortion coefficients; rovslam reads up to 8 (k1 k2 p1 p2 k3 k4 k5 k6).")
    d = d[:8] if len(d) in (4, 5) or len(d) >= 8 else (d + [0.0] * 8)[: 8 if len(d) > 5 else 5]
    try:
        return dataclasses.replace(
            camera, fx_px=float(k[0]), fy_px=float(k[4]), cx_px=float(k[2]), cy_px=float(k[5]), distortion=tuple(d)
        )
    except SequenceFormatError as exc:
        raise BagError(f"{where}: {exc}") from None


# --------------------------------------------------------------------------- the source


class BagSource:
    """The images of one topic of a bag with its navigation topics, streamed as :class:`Frame` records."""

    def __init__(self, path: str | Path, camera: CameraFile, options: InputOptions):
        if options.image_topic is None:
            with _Reader(path) as r:
                images = {n: v for n, v in r.topics.items() if v[0] in IMAGE_TYPES}
            raise BagError(f"{r.path}: a bag needs --image-topic T. Its image topics: {_topic_list(images)}.")
        self.options = options
        self.groundtruth_path = None
        self.warnings: list[str] = []
        self.left_out = 0
        with _Reader(path) as r:
            self.path, self.kind = r.path, r.kind
            topics = r.topics
            check_topics(r.path, topics, options)
            self.image_topic = options.image_topic
            self._n = topics[self.image_topic][1]
            info = camera.info
            if options.camera_info_topic is not None:
                _, msg, _ = next(r.messages(options.camera_info_topic))
                info = dataclasses.replace(
                    info, camera=camera_from_info(msg, info.camera, f"{r.path}: {options.camera_info_topic}")
                )
            self.info: SequenceInfo = info
            bag_ns, first, msgtype = next(r.messages(self.image_topic))
            self.t0_ns = stamp_ns(first, bag_ns)
            try:
                image_from_msg(first, msgtype, f"{r.path}: {self.image_topic}, first image")
            except ImageReadError as exc:
                raise BagError(str(exc)) from None
            self.end_s = (r._reader.end_time - self.t0_ns) / 1e9
            self.navigation = read_bag_navigation(r, options, self.t0_ns)

    def __len__(self) -> int:
        return self._n

    @property
    def span_s(self) -> tuple[float, float]:
        return 0.0, max(self.end_s, 0.0)

    @property
    def description(self) -> SourceDescription:
        return SourceDescription(self.kind, str(self.path))

    def _leave_out(self, message: str) -> None:
        self.left_out += 1
        if len(self.warnings) < MAX_WARNINGS:
            self.warnings.append(message)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        cam, depth = self.info.camera, self.info.bit_depth
        k = 0
        last_ns: int | None = None
        with _Reader(self.path) as r:
            stream = r.raw_messages(self.image_topic)
            while stop is None or k < stop:
                try:
                    item = next(stream, None)
                except Exception as exc:  # a damaged chunk or file end: what was read stands
                    self._leave_out(
                        f"{self.path}: the bag could not be read after frame {k} ({_why(exc)}); the rest is left out."
                    )
                    return
                if item is None:
                    return
                bag_ns, raw, msgtype = item
                try:
                    msg = r.deserialize(raw, msgtype, f"{self.path}: {self.image_topic} #{k}")
                except BagError as exc:
                    self._leave_out(f"{exc}; left out.")
                    continue
                ns = stamp_ns(msg, bag_ns)
                where = f"{self.path}: {self.image_topic} #{k} (stamp {ns} ns)"
                if last_ns is not None and ns <= last_ns:
                    self._leave_out(f"{where}: stamp is not after the previous image's; left out.")
                    continue
                last_ns = ns
                if k >= start:
                    try:
                        image, error = image_from_msg(msg, msgtype, where, cam, depth), None
                    except ImageReadError as exc:
                        image, error = None, str(exc)
                    yield Frame(
                        index=k,
                        t_s=(ns - self.t0_ns) / 1e9,
                        image=image,
                        heading_rad=math.nan,
                        source=where,
                        error=error,
                    )
                k += 1


def open_bag(path: str | Path, camera: CameraFile, options: InputOptions) -> Any:
    """A bag's image topic with its navigation topics attached (a :class:`~rovslam.io.nav.NavigatedSource`)."""
    from rovslam.io.nav import NavigatedSource

    src = BagSource(path, camera, options)
    if src.navigation is None:
        return src
    hint = (
        "The image and navigation topics must share a clock: their header stamps (or, without a header, "
        "the bag's receive times) are compared."
    )
    return NavigatedSource(src, src.navigation, src.span_s, "bag", hint)
