"""Reader and writer of the rovslam sequence format, version 1 (DESIGN.md, "Sequence format").

A sequence is a folder::

    SEQ/sequence.toml    camera, laser rig, metadata
    SEQ/frames.csv       t_s,image,heading_rad,sonar_altitude_m[,roll_rad,pitch_rad]
    SEQ/images/...       PNG or JPEG, 8-bit RGB or grey
    SEQ/groundtruth.csv  optional: t_s,x_m,y_m,altitude_m,heading_rad[,relief_m]

Reading validates everything that can be checked without decoding images (keys, columns,
numbers, monotonic time, image files present) and raises a
:class:`~rovslam.errors.SequenceFormatError` naming the file, row or key. Images are
decoded lazily, one at a time, by :meth:`Sequence.frames`: a file that cannot be decoded
gives a :class:`Frame` whose ``image`` is ``None`` and whose ``error`` says why, so a run
can log and skip it.
"""

from __future__ import annotations

import csv
import math
import tomllib
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.camera import Camera, LaserPointer
from rovslam.errors import ImageReadError, SequenceFormatError

FORMAT_V1 = "rovslam-sequence/1"
FRAMES_COLUMNS = ("t_s", "image", "heading_rad", "sonar_altitude_m")
ATTITUDE_COLUMNS = ("roll_rad", "pitch_rad")
GROUNDTRUTH_COLUMNS = ("t_s", "x_m", "y_m", "altitude_m", "heading_rad")
RELIEF_COLUMN = "relief_m"  # optional: seabed height above the mean plane under the camera (altitude_m is above the plane)
_CAMERA_REQUIRED = ("width_px", "height_px", "fx_px", "fy_px", "cx_px", "cy_px")
_CAMERA_OPTIONAL = ("distortion", "yaw_offset_rad")
_LASER_KEYS = ("origin_m", "direction")
_TOP_KEYS = ("format", "name", "camera", "laser", "vehicle", "metadata")


@dataclass(frozen=True)
class SequenceInfo:
    """What ``sequence.toml`` holds."""

    name: str
    camera: Camera
    lasers: tuple[LaserPointer, ...] = ()
    fixed_altitude_m: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)


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


@dataclass(frozen=True)
class Frame:
    """One timestamped frame from any source (sequence folder, video, bag).

    ``image`` is ``(H, W, 3) uint8`` RGB, or ``None`` when it could not be read (``error``
    then says why). Attitude is 0 when the source gives none (level camera, as the paper).
    """

    index: int
    t_s: float
    image: np.ndarray | None
    heading_rad: float
    sonar_altitude_m: float | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    has_attitude: bool = False
    source: str = ""
    error: str | None = None


@dataclass(frozen=True)
class GroundTruth:
    """``groundtruth.csv`` as arrays, each ``(N,)`` float64."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    altitude_m: np.ndarray
    heading_rad: np.ndarray
    relief_m: np.ndarray | None = None  # (N,) when the file has the optional relief_m column

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def xy_m(self) -> np.ndarray:
        """(N, 2) true positions."""
        return np.column_stack([self.x_m, self.y_m])


# --------------------------------------------------------------------------- reading


def _number(value: Any, where: str, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SequenceFormatError(f"{where}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0):
        raise SequenceFormatError(
            f"{where}: expected a {'positive ' if positive else ''}finite number, got {value!r}"
        )
    return v


def _triple(value: Any, where: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise SequenceFormatError(f"{where}: expected a list of 3 numbers, got {value!r}")
    return tuple(_number(v, f"{where}[{i}]") for i, v in enumerate(value))  # type: ignore[return-value]


def parse_sequence_toml(path: Path) -> SequenceInfo:
    """Read and validate ``sequence.toml``."""
    if not path.is_file():
        raise SequenceFormatError(
            f"{path}: missing. A sequence folder needs sequence.toml (see the README, 'Sequence format')."
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SequenceFormatError(f"{path}: not valid TOML: {exc}") from None
    fmt = data.get("format")
    if fmt != FORMAT_V1:
        raise SequenceFormatError(
            f"{path}: key 'format' must be \"{FORMAT_V1}\", got {fmt!r}. Add format = \"{FORMAT_V1}\"."
        )
    for key in data:
        if key not in _TOP_KEYS:
            raise SequenceFormatError(
                f"{path}: unknown key '{key}'. Known keys: {', '.join(_TOP_KEYS)}."
            )
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
    camera = Camera(
        width_px=int(width),
        height_px=int(height),
        fx_px=_number(cam["fx_px"], f"{path}: camera.fx_px", positive=True),
        fy_px=_number(cam["fy_px"], f"{path}: camera.fy_px", positive=True),
        cx_px=_number(cam["cx_px"], f"{path}: camera.cx_px"),
        cy_px=_number(cam["cy_px"], f"{path}: camera.cy_px"),
        distortion=tuple(_number(v, f"{path}: camera.distortion[{i}]") for i, v in enumerate(dist)),
        yaw_offset_rad=_number(cam.get("yaw_offset_rad", 0.0), f"{path}: camera.yaw_offset_rad"),
    )
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
    )


def _csv_rows(path: Path, required: tuple[str, ...]) -> tuple[list[str], Iterator[tuple[int, dict[str, str]]]]:
    """Open a CSV, check its header holds ``required``; yield (line number, row dict)."""
    if not path.is_file():
        raise SequenceFormatError(f"{path}: missing.")
    fh = path.open(newline="", encoding="utf-8")
    reader = csv.DictReader(fh)
    header = [h.strip() for h in (reader.fieldnames or [])]
    reader.fieldnames = header
    missing = [c for c in required if c not in header]
    if missing:
        fh.close()
        raise SequenceFormatError(
            f"{path}: header is missing column(s) {', '.join(missing)}. "
            f"The header must start with: {','.join(required)}."
        )

    def rows() -> Iterator[tuple[int, dict[str, str]]]:
        with fh:
            for row in reader:
                yield reader.line_num, row

    return header, rows()


def _float_cell(row: dict[str, str], key: str, where: str, *, optional: bool = False) -> float | None:
    text = (row.get(key) or "").strip()
    if text == "":
        if optional:
            return None
        raise SequenceFormatError(f"{where}: column '{key}' is empty; it needs a number.")
    try:
        v = float(text)
    except ValueError:
        raise SequenceFormatError(f"{where}: column '{key}' is not a number: {text!r}.") from None
    if not math.isfinite(v):
        raise SequenceFormatError(f"{where}: column '{key}' is not finite: {text!r}.")
    return v


def read_frames_csv(path: Path, folder: Path, check_images: bool = True) -> list[FrameRow]:
    """Read and validate ``frames.csv``: numbers, strictly increasing time, images present."""
    header, rows = _csv_rows(path, FRAMES_COLUMNS)
    has_att = all(c in header for c in ATTITUDE_COLUMNS)
    if any(c in header for c in ATTITUDE_COLUMNS) and not has_att:
        raise SequenceFormatError(f"{path}: give both roll_rad and pitch_rad columns, or neither.")
    out: list[FrameRow] = []
    last_t = -math.inf
    for line, row in rows:
        where = f"{path}, line {line}"
        t = float(_float_cell(row, "t_s", where))  # type: ignore[arg-type]
        if t <= last_t:
            raise SequenceFormatError(
                f"{where}: t_s={t} is not after the previous row's t_s={last_t}; rows must be in strictly increasing time."
            )
        last_t = t
        image = (row.get("image") or "").strip()
        if not image:
            raise SequenceFormatError(f"{where}: column 'image' is empty.")
        if check_images and not (folder / image).is_file():
            raise SequenceFormatError(f"{where}: image file '{image}' not found in {folder}.")
        heading = _float_cell(row, "heading_rad", where)
        sonar = _float_cell(row, "sonar_altitude_m", where, optional=True)
        roll = _float_cell(row, "roll_rad", where, optional=True) if has_att else None
        pitch = _float_cell(row, "pitch_rad", where, optional=True) if has_att else None
        out.append(FrameRow(len(out), t, image, heading, sonar, roll, pitch))  # type: ignore[arg-type]
    if not out:
        raise SequenceFormatError(f"{path}: no frames (only a header).")
    return out


def read_groundtruth(path: str | Path) -> GroundTruth:
    """Read ``groundtruth.csv`` (t_s,x_m,y_m,altitude_m,heading_rad[,relief_m]), validated."""
    p = Path(path)
    header, rows = _csv_rows(p, GROUNDTRUTH_COLUMNS)
    names = GROUNDTRUTH_COLUMNS + ((RELIEF_COLUMN,) if RELIEF_COLUMN in header else ())
    cols: dict[str, list[float]] = {c: [] for c in names}
    last_t = -math.inf
    for line, row in rows:
        where = f"{p}, line {line}"
        for c in names:
            cols[c].append(_float_cell(row, c, where))  # type: ignore[arg-type]
        if cols["t_s"][-1] <= last_t:
            raise SequenceFormatError(f"{where}: t_s is not after the previous row's; rows must be in time order.")
        last_t = cols["t_s"][-1]
    if not cols["t_s"]:
        raise SequenceFormatError(f"{p}: no rows (only a header).")
    return GroundTruth(**{c: np.asarray(v, dtype=np.float64) for c, v in cols.items()})


def read_image(path: Path, camera: Camera | None = None) -> np.ndarray:
    """Decode an 8-bit image file to ``(H, W, 3) uint8`` RGB (grey is replicated)."""
    import cv2

    data = np.fromfile(path, dtype=np.uint8) if path.is_file() else None
    if data is None:
        raise ImageReadError(f"{path}: image file not found.")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise ImageReadError(f"{path}: not a readable PNG/JPEG image (corrupt or truncated?).")
    if img.dtype != np.uint8:
        raise ImageReadError(f"{path}: {img.dtype} pixels; rovslam reads 8-bit images only.")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        raise ImageReadError(f"{path}: {img.shape[2]} channels; expected grey, RGB or RGBA.")
    if camera is not None and img.shape[:2] != camera.shape:
        raise ImageReadError(
            f"{path}: image is {img.shape[1]}x{img.shape[0]} px but sequence.toml says "
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

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def groundtruth(self) -> GroundTruth | None:
        return None if self.groundtruth_path is None else read_groundtruth(self.groundtruth_path)

    def _load(self, row: FrameRow) -> Frame:
        path = self.folder / row.image
        try:
            image, error = read_image(path, self.info.camera), None
        except ImageReadError as exc:
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


def open_sequence(folder: str | Path, check_images: bool = True) -> Sequence:
    """Open and validate a sequence folder (format v1)."""
    f = Path(folder)
    if not f.is_dir():
        raise SequenceFormatError(f"{f}: not a folder. Give the sequence folder (with sequence.toml and frames.csv).")
    info = parse_sequence_toml(f / "sequence.toml")
    rows = read_frames_csv(f / "frames.csv", f, check_images=check_images)
    gt = f / "groundtruth.csv"
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
