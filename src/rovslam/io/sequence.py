"""Reader and writer of the rovslam sequence format, version 1 (DESIGN.md, "Sequence format").

A sequence is a folder::

    SEQ/sequence.toml    camera, laser rig, metadata
    SEQ/frames.csv       t_s,image,heading_rad,sonar_altitude_m[,roll_rad,pitch_rad]
    SEQ/images/...       PNG, JPEG or TIFF, 8- or 16-bit, RGB or grey
    SEQ/groundtruth.csv  optional: t_s,x_m,y_m,altitude_m,heading_rad[,relief_m]

Reading validates everything that can be checked without decoding images (encoding, keys,
columns, numbers, monotonic time, image files present and inside the folder) and raises a
:class:`~rovslam.errors.SequenceFormatError` naming the file, row or key. Text files are
UTF-8 (a byte-order mark is accepted). Nothing outside the sequence folder is ever opened:
an image path that is absolute, climbs out with ``..`` or resolves outside through a
symbolic link is refused with its row named, and so is a ``frames.csv``, ``sequence.toml``
or ``groundtruth.csv`` that is a link to a file elsewhere. Images are decoded lazily, one at
a time, by :meth:`Sequence.frames`: a file that cannot be decoded gives a :class:`Frame`
whose ``image`` is ``None`` and whose ``error`` says why, so a run can log and skip it.
16-bit images are scaled to 8 bits by ``255 / (2**bit_depth - 1)`` (``[camera] bit_depth``,
default 16; 12 for a 12-bit sensor stored in 16-bit files), values above the range saturate.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
import stat
import struct
import tomllib
from collections import abc
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.camera import Camera, LaserPointer
from rovslam.core import Frame, GroundTruth, SequenceInfo
from rovslam.errors import ImageReadError, SequenceFormatError, parse_toml
from rovslam.io.source import ALTITUDE_INPUTS, HEADING_INPUTS, SourceDescription
from rovslam.io.text import (
    float_cell,
    inside_folder,
    not_a_file,
    read_csv_table,
    read_text,
    time_cell,
)

FORMAT_V1 = "rovslam-sequence/1"
FRAMES_COLUMNS = ("t_s", "image", "heading_rad", "sonar_altitude_m")
ATTITUDE_COLUMNS = ("roll_rad", "pitch_rad")
GROUNDTRUTH_COLUMNS = ("t_s", "x_m", "y_m", "altitude_m", "heading_rad")
RELIEF_COLUMN = (
    "relief_m"  # optional: seabed height above the mean plane under the camera (altitude_m is above the plane)
)
_CAMERA_REQUIRED = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
_CAMERA_OPTIONAL = ("distortion", "yaw_offset_rad", "readout_s", "bit_depth")
_LASER_KEYS = ("origin_m", "direction")
_TOP_KEYS = ("format", "name", "camera", "laser", "vehicle", "metadata")


@dataclass(frozen=True)
class FrameRow:
    """One row of ``frames.csv`` (metadata only; the image is not decoded)."""

    index: int
    t_s: float
    image: str
    heading_rad: float
    sonar_altitude_m: float | None = None
    roll_rad: float | None = None
    pitch_rad: float | None = None


# --------------------------------------------------------------------------- reading

MAX_GROUNDTRUTH_M = 1e8  # a ground-truth coordinate beyond this is no place on Earth (its squares overflowed)
# A heading column whose median step between frames is above this looks like degrees read as radians
# (a survey's compass moves by a few hundredths of a radian a frame; 0.1 rad a frame, sustained over half
# the dive, is a turn of 29 degrees a second at 5 Hz).
DEGREES_LIKE_STEP_RAD = 0.1
# ... and roll or pitch whose median size is above this (20 degrees: an ROV's camera tilted that far on
# half of the frames is rare; 3 degrees written as 3 "radians" is refused anyway, 0.5 to 1.5 degrees is not).
DEGREES_LIKE_ATTITUDE_RAD = 0.35
MAX_ATTITUDE_RAD = math.pi / 2  # roll or pitch beyond 90 degrees: the camera no longer looks down
MAX_HEADING_RAD = 1e4  # an unwrapped heading of 1,600 turns is still one; 1e308 is garbage (cos of it means nothing)


def _number(value: Any, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SequenceFormatError(f"{where}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0):
        raise SequenceFormatError(f"{where}: expected a {'positive ' if positive else ''}finite number, got {value!r}")
    return v


def _triple(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise SequenceFormatError(f"{where}: expected a list of 3 numbers, got {value!r}")
    return tuple(_number(v, f"{where}[{i}]") for i, v in enumerate(value))  # type: ignore[return-value]


def parse_sequence_toml(path: Path, root: Path | None = None) -> SequenceInfo:
    """Read and validate ``sequence.toml`` (``root``: the folder it must resolve inside, if any)."""
    if not path.is_file():
        raise SequenceFormatError(
            f"{path}: {not_a_file(path)}. A sequence folder needs sequence.toml (docs/formats.md, 'Sequence folder (format v1)'); "
            "a folder of plain images runs with --camera CAMERA.toml and --fps or --times (README, 'Your own dive')."
        )
    if root is not None:
        inside_folder(root, path.name, f"{path}")
    return info_from_toml(load_toml(path), path)


def load_toml(path: Path) -> dict[str, Any]:
    """The tables of a UTF-8 TOML file, or SequenceFormatError naming it."""
    try:
        return parse_toml(read_text(path))
    except tomllib.TOMLDecodeError as exc:
        raise SequenceFormatError(f"{path}: not valid TOML: {exc}") from None


def info_from_toml(
    data: dict[str, Any], path: Path, *, require_format: bool = True, extra_keys: tuple[str, ...] = ()
) -> SequenceInfo:
    """Validate the tables of a ``sequence.toml`` (or of a camera file: ``require_format=False``).

    ``extra_keys``: further top-level keys the caller reads itself (a camera file's ``nav``).
    """
    fmt = data.get("format")
    if fmt != FORMAT_V1 and (require_format or fmt is not None):
        raise SequenceFormatError(
            f'{path}: key \'format\' must be "{FORMAT_V1}", got {fmt!r}. Add format = "{FORMAT_V1}".'
        )
    known = _TOP_KEYS + extra_keys
    for key in data:
        if key not in known:
            raise SequenceFormatError(f"{path}: unknown key '{key}'. Known keys: {', '.join(known)}.")
    cam = data.get("camera")
    if not isinstance(cam, dict):
        raise SequenceFormatError(f"{path}: missing [camera] table (width_px, height_px, fx_px, fy_px, cx_px, cy_px).")
    for key in cam:
        if key not in _CAMERA_REQUIRED + _CAMERA_OPTIONAL:
            raise SequenceFormatError(
                f"{path}: unknown key 'camera.{key}'. Known: {', '.join(_CAMERA_REQUIRED + _CAMERA_OPTIONAL)}."
            )
    for key in _CAMERA_REQUIRED:
        if key not in cam:
            hint = " (the focal length in pixels)" if key.startswith("f") else ""
            raise SequenceFormatError(f"{path}: [camera] is missing key '{key}'{hint}.")
    width = _number(cam["width_px"], f"{path}: camera.width_px", positive=True)
    height = _number(cam["height_px"], f"{path}: camera.height_px", positive=True)
    if not (width.is_integer() and height.is_integer()):
        raise SequenceFormatError(f"{path}: camera.width_px and height_px must be whole numbers.")
    dist = cam.get("distortion", [0.0, 0.0, 0.0, 0.0, 0.0])
    if not isinstance(dist, list) or len(dist) not in (4, 5, 8):
        raise SequenceFormatError(
            f"{path}: camera.distortion must list 4, 5 or 8 OpenCV coefficients (k1 k2 p1 p2 k3), got {dist!r}"
        )
    bit_depth = cam.get("bit_depth")
    if bit_depth is not None and (
        isinstance(bit_depth, bool) or not isinstance(bit_depth, int) or not 8 <= bit_depth <= 16
    ):
        raise SequenceFormatError(
            f"{path}: camera.bit_depth must be a whole number of bits from 8 to 16 (12 for a 12-bit sensor "
            f"in 16-bit files), got {bit_depth!r}"
        )
    try:
        camera = Camera(
            width_px=int(width),
            height_px=int(height),
            fx_px=_number(cam["fx_px"], f"{path}: camera.fx_px", positive=True),
            fy_px=_number(cam["fy_px"], f"{path}: camera.fy_px", positive=True),
            cx_px=_number(cam["cx_px"], f"{path}: camera.cx_px"),
            cy_px=_number(cam["cy_px"], f"{path}: camera.cy_px"),
            distortion=tuple(_number(v, f"{path}: camera.distortion[{i}]") for i, v in enumerate(dist)),
            yaw_offset_rad=_number(cam.get("yaw_offset_rad", 0.0), f"{path}: camera.yaw_offset_rad"),
            readout_s=_number(cam.get("readout_s", 0.0), f"{path}: camera.readout_s"),
        )
    except SequenceFormatError as exc:
        if str(exc).startswith(str(path)):
            raise
        raise SequenceFormatError(f"{path}: [camera]: {exc}") from None
    lasers_raw = data.get("laser", [])
    if not isinstance(lasers_raw, list):
        raise SequenceFormatError(f"{path}: 'laser' must be an array of tables ([[laser]]).")
    lasers = []
    for i, las in enumerate(lasers_raw):
        where = f"{path}: laser[{i}]"
        if not isinstance(las, dict):
            raise SequenceFormatError(f"{where}: must be a table with origin_m and direction.")
        for key in las:
            if key not in _LASER_KEYS:
                raise SequenceFormatError(f"{where}: unknown key '{key}'. Known: origin_m, direction.")
        if "origin_m" not in las:
            raise SequenceFormatError(f"{where}: missing key 'origin_m' (body frame, metres).")
        origin = _triple(las["origin_m"], f"{where}.origin_m")
        direction = _triple(las.get("direction", [0.0, 0.0, 1.0]), f"{where}.direction")
        try:
            lasers.append(LaserPointer(origin, direction))
        except SequenceFormatError as exc:
            raise SequenceFormatError(f"{where}: {exc}") from None
    vehicle = data.get("vehicle", {})
    if not isinstance(vehicle, dict):
        raise SequenceFormatError(f"{path}: [vehicle] must be a table.")
    for key in vehicle:
        if key != "altitude_m":
            raise SequenceFormatError(f"{path}: unknown key 'vehicle.{key}'. Known: altitude_m.")
    fixed = vehicle.get("altitude_m")
    fixed_alt = None if fixed is None else _number(fixed, f"{path}: vehicle.altitude_m", positive=True)
    metadata = data.get("metadata", {})
    if not isinstance(metadata, dict):
        raise SequenceFormatError(f"{path}: [metadata] must be a table.")
    return SequenceInfo(
        name=str(data.get("name", path.parent.name)),
        camera=camera,
        lasers=tuple(lasers),
        fixed_altitude_m=fixed_alt,
        metadata=metadata,
        bit_depth=bit_depth,
    )


_KNOWN_STEMS = ("roll", "pitch", "heading", "yaw", "sonar", "altitude")


def _meant_as_known_columns(header: abc.Sequence[str]) -> list[str]:
    """The header's extra columns that look like one ``frames.csv`` reads: misspelt (``rol_rad``) or in
    other units (``roll_deg``). Read as extra, they would be ignored without a word; any other extra
    column (a navigation log's ``depth_m``, ``lat``) is ignored, as the format allows."""
    known = FRAMES_COLUMNS + ATTITUDE_COLUMNS
    return [
        c
        for c in header
        if c not in known
        and (
            c.strip().lower().startswith(_KNOWN_STEMS)
            or difflib.get_close_matches(c.strip().lower(), known, n=1, cutoff=0.75)
        )
    ]


def read_frames_csv(path: Path, folder: Path, check_images: bool = True) -> list[FrameRow]:
    """Read and validate ``frames.csv``: numbers, strictly increasing time, images present inside ``folder``.

    ``heading_rad`` may be ``nan`` (no compass); ``sonar_altitude_m`` may be empty or ``nan``
    (no reading); ``roll_rad``/``pitch_rad`` must be within +-90 degrees.
    """
    root = Path(os.path.realpath(folder))
    inside_folder(root, path.name, str(path))
    header, rows = read_csv_table(path, FRAMES_COLUMNS)
    unknown = _meant_as_known_columns(header)
    if unknown:  # a misspelt roll_rad would leave the tilt uncompensated without a word
        raise SequenceFormatError(
            f"{path}: unknown column(s) {', '.join(repr(c) for c in unknown)} in the header. The columns are "
            f"{','.join(FRAMES_COLUMNS)} and the optional {','.join(ATTITUDE_COLUMNS)} (radians); rename or remove the others."
        )
    has_att = all(c in header for c in ATTITUDE_COLUMNS)
    if any(c in header for c in ATTITUDE_COLUMNS) and not has_att:
        raise SequenceFormatError(f"{path}: give both roll_rad and pitch_rad columns, or neither.")
    out: list[FrameRow] = []
    last_t = -math.inf
    for line, row in rows:
        where = f"{path}, line {line}"
        t = time_cell(row, where)
        if t <= last_t:
            raise SequenceFormatError(
                f"{where}: t_s={t} is not after the previous row's t_s={last_t}; rows must be in strictly increasing time."
            )
        last_t = t
        image = (row.get("image") or "").strip()
        if not image:
            raise SequenceFormatError(f"{where}: column 'image' is empty.")
        resolved = inside_folder(root, image, f"{where}: column 'image'")
        try:
            present = not check_images or resolved.is_file()
        except OSError as exc:  # a folder on the way that may not be searched (chmod)
            raise SequenceFormatError(
                f"{where}: image file '{image}' cannot be reached ({exc.strerror or exc}); give read access to "
                f"the folders of {folder}."
            ) from None
        if not present:
            why = (
                "is a folder, not an image file"
                if resolved.is_dir()
                else "is not a regular file (a pipe, socket or device)"
                if resolved.exists()
                else "not found"
            )
            raise SequenceFormatError(f"{where}: image file '{image}' {why} in {folder}.")
        text = (row.get("heading_rad") or "").strip()
        if text == "":
            raise SequenceFormatError(f"{where}: column 'heading_rad' is empty; write nan when there is no compass.")
        heading = float_cell(row, "heading_rad", where, allow_nan=True)
        if abs(heading) > MAX_HEADING_RAD:  # type: ignore[arg-type]  # NaN passes: no compass
            raise SequenceFormatError(
                f"{where}: column 'heading_rad' is {heading} rad, beyond +-{MAX_HEADING_RAD:g} rad: not a heading "
                "(write nan where the compass gave no reading; headings are in radians)."
            )
        sonar = float_cell(row, "sonar_altitude_m", where, optional=True, allow_nan=True)
        if sonar is not None and math.isnan(sonar):
            sonar = None  # nan = no reading, like an empty cell
        roll = pitch = None
        if has_att:
            roll = float_cell(row, "roll_rad", where, optional=True)
            pitch = float_cell(row, "pitch_rad", where, optional=True)
            for key, v in (("roll_rad", roll), ("pitch_rad", pitch)):
                if v is not None and abs(v) >= MAX_ATTITUDE_RAD:
                    raise SequenceFormatError(
                        f"{where}: column '{key}' is {v} rad, beyond +-pi/2: a camera tilted that far does not "
                        "see the seabed. Attitudes are in radians."
                    )
        out.append(FrameRow(len(out), t, image, heading, sonar, roll, pitch))  # type: ignore[arg-type]
    if not out:
        raise SequenceFormatError(f"{path}: no frames (only a header).")
    return out


def angle_unit_warnings(rows: abc.Sequence[FrameRow], where: str = "frames.csv") -> list[str]:
    """Warnings for angle columns of ``rows`` that look like degrees written where radians are read.

    The heading's median wrapped step between consecutive readings above ``DEGREES_LIKE_STEP_RAD``,
    or the median size of roll or pitch above ``DEGREES_LIKE_ATTITUDE_RAD``: read as radians such a
    column turns the estimate by tens of degrees a frame (and the compass gate then refuses much of
    it). Only a warning: a dive can turn that fast, a camera can be mounted that tilted.
    """
    out: list[str] = []
    heading = np.array([r.heading_rad for r in rows], dtype=np.float64)
    heading = heading[np.isfinite(heading)]
    if len(heading) >= 3:
        step = float(np.median(np.abs(np.angle(np.exp(1j * np.diff(heading))))))
        if step > DEGREES_LIKE_STEP_RAD:
            out.append(
                f"{where}: heading_rad changes by {step:.2f} rad ({math.degrees(step):.0f} degrees) from one frame to "
                f"the next (median over {len(heading)} readings): is the column in degrees? headings are in radians "
                "(multiply degrees by pi/180)"
            )
    for key in ATTITUDE_COLUMNS:
        v = np.array([getattr(r, key) for r in rows if getattr(r, key) is not None], dtype=np.float64)
        if len(v) and float(np.median(np.abs(v))) > DEGREES_LIKE_ATTITUDE_RAD:
            size = float(np.median(np.abs(v)))
            out.append(
                f"{where}: {key} is {size:.2f} rad ({math.degrees(size):.0f} degrees) on half of the frames: is the "
                "column in degrees? attitudes are in radians (multiply degrees by pi/180)"
            )
    return out


def read_groundtruth(path: str | Path) -> GroundTruth:
    """Read ``groundtruth.csv`` (t_s,x_m,y_m,altitude_m,heading_rad[,relief_m]), validated."""
    p = Path(path)
    header, rows = read_csv_table(p, GROUNDTRUTH_COLUMNS)
    names = GROUNDTRUTH_COLUMNS + ((RELIEF_COLUMN,) if RELIEF_COLUMN in header else ())
    cols: dict[str, list[float]] = {c: [] for c in names}
    last_t = -math.inf
    for line, row in rows:
        where = f"{p}, line {line}"
        for c in names:
            cols[c].append(float_cell(row, c, where))  # type: ignore[arg-type]
            if c.endswith("_m") and abs(cols[c][-1]) > MAX_GROUNDTRUTH_M:
                raise SequenceFormatError(
                    f"{where}: column '{c}' is {cols[c][-1]:g} m, beyond any place on Earth ({MAX_GROUNDTRUTH_M:g} m); "
                    "give metres (x north, y east from the start, or projected coordinates such as UTM)."
                )
        if cols["t_s"][-1] <= last_t:
            raise SequenceFormatError(f"{where}: t_s is not after the previous row's; rows must be in time order.")
        last_t = cols["t_s"][-1]
    if not cols["t_s"]:
        raise SequenceFormatError(f"{p}: no rows (only a header).")
    return GroundTruth(**{c: np.asarray(v, dtype=np.float64) for c, v in cols.items()})


def _png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from a PNG header, read before decoding (a huge declared size is refused unread)."""
    if len(data) >= 24 and data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    return None


def to_uint8(img: np.ndarray, bit_depth: int | None = None, where: str = "image") -> np.ndarray:
    """8-bit pixels of an 8- or 16-bit image: 16-bit values are scaled by ``255 / (2**bit_depth - 1)``.

    ``bit_depth`` (default 16) is the number of significant bits of the 16-bit values (12 for a
    12-bit sensor); values above ``2**bit_depth - 1`` saturate at 255. The same scale applies to
    every frame, so brightness is comparable along the dive (no per-frame stretch).
    """
    import cv2

    if img.dtype == np.uint8:
        return img
    if img.dtype == np.uint16:
        depth = 16 if bit_depth is None else int(bit_depth)
        return cv2.convertScaleAbs(img, alpha=255.0 / (2**depth - 1))
    raise ImageReadError(f"{where}: {img.dtype} pixels; rovslam reads 8- or 16-bit unsigned images.")


def read_image(
    path: Path, camera: Camera | None = None, bit_depth: int | None = None, camera_source: str = "sequence.toml"
) -> np.ndarray:
    """Decode an 8- or 16-bit image file to ``(H, W, 3) uint8`` RGB (grey is replicated; see :func:`to_uint8`).

    ``camera_source`` names where ``camera`` comes from in a size error.
    """
    try:
        # Non-blocking open, then a look at what was opened: a pipe named like an image would
        # otherwise wait for a writer for ever.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise ImageReadError(f"{path}: {not_a_file(Path(path))}; an image must be a PNG, JPEG or TIFF file.")
        with os.fdopen(fd, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise ImageReadError(f"{path}: image file not found.") from None
    except OSError as exc:
        raise ImageReadError(f"{path}: cannot be read ({exc.strerror or exc}).") from None
    return decode_image(data, str(path), camera, bit_depth, camera_source)


def decode_image(
    data: bytes,
    where: str,
    camera: Camera | None = None,
    bit_depth: int | None = None,
    camera_source: str = "the camera file",
) -> np.ndarray:
    """Decode the bytes of a PNG, JPEG or TIFF file to ``(H, W, 3) uint8`` RGB; ``where`` names it in errors."""
    import cv2

    declared = _png_size(data)
    if camera is not None and declared is not None and declared != (camera.width_px, camera.height_px):
        raise ImageReadError(
            f"{where}: image is {declared[0]}x{declared[1]} px but {camera_source} says "
            f"{camera.width_px}x{camera.height_px}."
        )
    # A JPEG is decoded straight to RGB (its grey replicated), any depth, its EXIF orientation ignored:
    # what the BGR decoding turned round gives, bit for bit, in 7 % less time at 1920x1080.
    jpeg = data[:3] == b"\xff\xd8\xff"
    flags = cv2.IMREAD_COLOR_RGB | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION if jpeg else cv2.IMREAD_UNCHANGED
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    if img is None:
        raise ImageReadError(f"{where}: not a readable PNG/JPEG/TIFF image (corrupt or truncated?).")
    return to_rgb(img, where, camera, bit_depth, camera_source, owned=True, rgb=jpeg)


def to_rgb(
    img: np.ndarray,
    where: str,
    camera: Camera | None = None,
    bit_depth: int | None = None,
    camera_source: str = "the camera file",
    owned: bool = False,
    rgb: bool = False,
) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB from OpenCV's decoded grey, BGR or BGRA, 8 or 16 bits (see :func:`to_uint8`).

    ``owned``: ``img`` belongs to the caller alone (freshly decoded), so BGR is turned into RGB in
    place instead of into a new image (one image-sized allocation fewer per frame). ``rgb``: three
    channels are already in RGB order.
    """
    import cv2

    owned = owned or img.dtype != np.uint8  # to_uint8 returns a new array then
    img = to_uint8(img, bit_depth, where)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.ndim == 3 and img.shape[2] == 3:
        if not rgb:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB, dst=img if owned and img.flags.writeable else None)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        raise ImageReadError(f"{where}: pixel layout {img.shape}; expected grey, RGB or RGBA.")
    if camera is not None and img.shape[:2] != camera.shape:
        raise ImageReadError(
            f"{where}: image is {img.shape[1]}x{img.shape[0]} px but {camera_source} says "
            f"{camera.width_px}x{camera.height_px}."
        )
    return img


class Sequence:
    """An opened, validated sequence folder. Iterate :meth:`frames` to stream the images."""

    def __init__(self, folder: Path, info: SequenceInfo, rows: list[FrameRow], groundtruth_path: Path | None):
        self.folder = folder
        self.info = info
        self.rows = rows
        self.groundtruth_path = groundtruth_path
        self.has_attitude = any(r.roll_rad is not None for r in rows)
        self._root = Path(os.path.realpath(folder))
        self.warnings: list[str] = angle_unit_warnings(rows, str(folder / "frames.csv"))

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def description(self) -> SourceDescription:
        """Where the altitude, heading and attitude of frames.csv come from (an imported sequence says so in
        ``[metadata]``: ``heading_input``, ``heading_detail``, ``altitude_input``, ``altitude_detail``, ``attitude_detail``)."""
        meta = self.info.metadata

        def text(key: str, default: str | None) -> str | None:
            v = meta.get(key)
            return v if isinstance(v, str) and v else default

        heading = text("heading_input", "compass")
        altitude = text("altitude_input", "sonar")
        return SourceDescription(
            "sequence folder",
            str(self.folder),
            altitude_input=altitude if altitude in ALTITUDE_INPUTS else "sonar",
            altitude_detail=text("altitude_detail", "frames.csv sonar_altitude_m") or "",
            heading_input=heading if heading in HEADING_INPUTS else "compass",
            heading_detail=text("heading_detail", "frames.csv heading_rad") or "",
            attitude_detail=text("attitude_detail", "frames.csv roll_rad, pitch_rad") if self.has_attitude else None,
        )

    @property
    def groundtruth(self) -> GroundTruth | None:
        return None if self.groundtruth_path is None else read_groundtruth(self.groundtruth_path)

    def _load(self, row: FrameRow) -> Frame:
        path = self.folder / row.image
        try:
            # Checked again at the moment of reading: the folder may have changed since it was opened.
            resolved = inside_folder(self._root, row.image, f"{self.folder / 'frames.csv'}, frame {row.index}")
            image, error = read_image(resolved, self.info.camera, self.info.bit_depth), None
        except (ImageReadError, SequenceFormatError) as exc:
            image, error = None, str(exc)
        return Frame(
            index=row.index,
            t_s=row.t_s,
            image=image,
            heading_rad=row.heading_rad,
            sonar_altitude_m=row.sonar_altitude_m,
            roll_rad=row.roll_rad or 0.0,
            pitch_rad=row.pitch_rad or 0.0,
            has_attitude=row.roll_rad is not None,
            source=str(path),
            error=error,
        )

    def frames(self, start: int = 0, stop: int | None = None, prefetch: int = 4) -> Iterator[Frame]:
        """Stream frames in time order, decoding ``prefetch`` images ahead in a thread."""
        rows = self.rows[start:stop]
        if prefetch <= 0:
            for row in rows:
                yield self._load(row)
            return
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="rovslam-read") as pool:
            pending: list[Future[Frame]] = []
            it = iter(rows)
            try:
                for row in it:
                    pending.append(pool.submit(self._load, row))
                    if len(pending) > prefetch:
                        break
                while pending:
                    frame = pending.pop(0).result()
                    nxt = next(it, None)
                    if nxt is not None:
                        pending.append(pool.submit(self._load, nxt))
                    yield frame
            finally:
                for fut in pending:  # a stream closed early: do not decode what nobody will read
                    fut.cancel()


def open_sequence(folder: str | Path, check_images: bool = True) -> Sequence:
    """Open and validate a sequence folder (format v1); nothing outside it is opened."""
    f = Path(folder)
    if not f.is_dir():
        raise SequenceFormatError(f"{f}: not a folder. Give the sequence folder (with sequence.toml and frames.csv).")
    root = Path(os.path.realpath(f))
    info = parse_sequence_toml(f / "sequence.toml", root)
    rows = read_frames_csv(f / "frames.csv", f, check_images=check_images)
    gt = f / "groundtruth.csv"
    if gt.is_file() or gt.is_symlink():
        inside_folder(root, gt.name, str(gt))
    return Sequence(f, info, rows, gt if gt.is_file() else None)


# --------------------------------------------------------------------------- writing


def _fmt(v: float | None) -> str:
    return "" if v is None else repr(float(v))


def info_to_toml(info: SequenceInfo) -> dict[str, Any]:
    cam = info.camera
    data: dict[str, Any] = {
        "format": FORMAT_V1,
        "name": info.name,
        "camera": {
            "width_px": cam.width_px,
            "height_px": cam.height_px,
            "fx_px": float(cam.fx_px),
            "fy_px": float(cam.fy_px),
            "cx_px": float(cam.cx_px),
            "cy_px": float(cam.cy_px),
            "distortion": [float(d) for d in cam.distortion],
            "yaw_offset_rad": float(cam.yaw_offset_rad),
        },
    }
    if cam.readout_s > 0:  # (only then: global-shutter sequences' files stay as they were)
        data["camera"]["readout_s"] = float(cam.readout_s)
    if info.bit_depth is not None:
        data["camera"]["bit_depth"] = int(info.bit_depth)
    if info.lasers:
        data["laser"] = [
            {"origin_m": [float(v) for v in las.origin_m], "direction": [float(v) for v in las.direction]}
            for las in info.lasers
        ]
    if info.fixed_altitude_m is not None:
        data["vehicle"] = {"altitude_m": float(info.fixed_altitude_m)}
    if info.metadata:
        data["metadata"] = dict(info.metadata)
    return data


class SequenceWriter:
    """Write a sequence folder frame by frame (a context manager).

    Images are encoded on a small thread pool (OpenCV releases the GIL), so a simulator's
    render loop overlaps with PNG compression. Rows are flushed as they are written, so an
    interrupted write leaves a readable prefix.
    """

    def __init__(
        self,
        folder: str | Path,
        info: SequenceInfo,
        image_format: str = "png",
        jpeg_quality: int = 90,
        with_attitude: bool = False,
        with_groundtruth: bool = True,
        encode_threads: int = 2,
        with_relief: bool = False,
    ):
        if image_format not in ("png", "jpg"):
            raise SequenceFormatError(f"image format must be 'png' or 'jpg', got {image_format!r}")
        self.folder = Path(folder)
        self.info = info
        self.image_format = image_format
        self.jpeg_quality = int(jpeg_quality)
        self.with_attitude = with_attitude
        self.with_relief = with_relief
        (self.folder / "images").mkdir(parents=True, exist_ok=True)
        import tomli_w

        (self.folder / "sequence.toml").write_text(tomli_w.dumps(info_to_toml(info)), encoding="utf-8")
        self._frames_fh = (self.folder / "frames.csv").open("w", newline="", encoding="utf-8")
        self._frames = csv.writer(self._frames_fh, lineterminator="\n")
        self._frames.writerow(FRAMES_COLUMNS + (ATTITUDE_COLUMNS if with_attitude else ()))
        self._gt_fh = None
        if with_groundtruth:
            self._gt_fh = (self.folder / "groundtruth.csv").open("w", newline="", encoding="utf-8")
            self._gt = csv.writer(self._gt_fh, lineterminator="\n")
            self._gt.writerow(GROUNDTRUTH_COLUMNS + ((RELIEF_COLUMN,) if with_relief else ()))
        self._pool = ThreadPoolExecutor(max_workers=max(1, encode_threads), thread_name_prefix="rovslam-enc")
        self._pending: list[Future[None]] = []
        self.count = 0

    def _encode(self, path: Path, image_rgb: np.ndarray) -> None:
        import cv2

        bgr = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR) if image_rgb.ndim == 3 else image_rgb
        if self.image_format == "png":
            ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        else:
            ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ImageReadError(f"{path}: OpenCV could not encode the image")
        path.write_bytes(buf.tobytes())

    def write_frame(
        self,
        t_s: float,
        image_rgb: np.ndarray,
        heading_rad: float,
        sonar_altitude_m: float | None = None,
        roll_rad: float | None = None,
        pitch_rad: float | None = None,
        truth: tuple[float, ...] | None = None,
    ) -> None:
        """Write one frame; ``truth`` = (x_m, y_m, altitude_m, heading_rad[, relief_m]) for groundtruth.csv."""
        cam = self.info.camera
        if image_rgb.dtype != np.uint8 or image_rgb.shape[:2] != cam.shape:
            raise ImageReadError(
                f"frame {self.count}: image must be ({cam.height_px}, {cam.width_px}[, 3]) uint8, "
                f"got {image_rgb.shape} {image_rgb.dtype}"
            )
        name = f"images/{self.count:06d}.{self.image_format}"
        # Keep at most a few images in flight so memory stays bounded on long sequences.
        while len(self._pending) > 8:
            self._pending.pop(0).result()
        self._pending.append(self._pool.submit(self._encode, self.folder / name, np.ascontiguousarray(image_rgb)))
        row = [repr(float(t_s)), name, _fmt(heading_rad), _fmt(sonar_altitude_m)]
        if self.with_attitude:
            row += [_fmt(roll_rad), _fmt(pitch_rad)]
        self._frames.writerow(row)
        if self._gt_fh is not None and truth is not None:
            if len(truth) != 4 + self.with_relief:
                raise SequenceFormatError(
                    f"frame {self.count}: truth needs {4 + self.with_relief} values (x_m, y_m, altitude_m, heading_rad"
                    f"{', relief_m' if self.with_relief else ''}), got {len(truth)}"
                )
            self._gt.writerow([repr(float(t_s))] + [_fmt(v) for v in truth])
        self.count += 1

    def close(self) -> None:
        for fut in self._pending:
            fut.result()
        self._pending.clear()
        self._pool.shutdown(wait=True)
        self._frames_fh.close()
        if self._gt_fh is not None:
            self._gt_fh.close()

    def __enter__(self) -> SequenceWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
