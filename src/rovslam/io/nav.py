"""Navigation logs: heading, roll, pitch and altitude by time, interpolated to each frame's time.

A navigation log (``--nav NAV.csv``, or the heading / altitude / attitude topics of a bag) is a set
of :class:`NavTrack` (one quantity by time) held by a :class:`Navigation`.
:class:`NavigatedSource` attaches it to a stream of frames: each frame gets the values
interpolated at its time (headings on the unit circle, so across the +-pi wrap), and frames that
lie outside the log's time span are left out (counted in the run's ``source_warnings``).

Conventions (docs/architecture.md): rovslam's heading is from north (world x) towards east
(world y); its attitude is roll about forward, pitch about starboard, ``R_world_body = Rz(heading)
Ry(pitch) Rx(roll)`` with the body x forward, y starboard, z down (FRD) in a north-east-down world.

A quaternion ``(x, y, z, w)`` is turned into that through :func:`ned_frd_from_quaternions`:

* ``quaternion_world``: the world it is expressed in, ``"enu"`` (x east, y north, z up: ROS,
  REP 103) or ``"ned"`` (x north, y east, z down);
* ``quaternion_body``: the vehicle or camera frame it orients, ``"flu"`` (x forward = image up,
  y left, z up: ROS ``base_link``), ``"frd"`` (x forward, y right, z down) or ``"optical"``
  (OpenCV camera frame: x image right, y image down, z along the optical axis);
* ``quaternion_rotates``: ``"body-to-world"`` (it turns body vectors into world vectors: the
  orientation of an Imu or Odometry message, the rotation of a pose, of a ROS TF transform from
  the world frame to the body frame) or ``"world-to-body"`` (its inverse).

The Sparus AUV log of ``../shared/data/sparus`` (rows ``world,camera,x,y,z,qx,qy,qz,qw``: a TF
transform from ``world`` to ``camera``) is ``enu`` / ``flu`` / ``body-to-world``: its camera frame's
x axis is image-up (the seabed moves along it in the video) and z points up (the depth z is
negative), and the yaw about z up grows from 65.6 to 89.1 degrees while the video's seabed turns
clockwise on screen: the vehicle turns left, rovslam's heading goes from 24.4 to 0.9 degrees.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.core import Frame
from rovslam.errors import NavigationError
from rovslam.io.sequence import MAX_ATTITUDE_RAD
from rovslam.io.source import SourceDescription
from rovslam.io.text import read_csv_table

ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
WORLDS = ("enu", "ned")
BODIES = ("flu", "frd", "optical")
ROTATES = ("body-to-world", "world-to-body")
HEADING_CONVENTIONS = ("ned", "enu")
MIN_GAP_S = 1.0  # the default largest gap bridged: at least this, or 3 times the median row interval
MAX_WARNINGS = 20

# Rows: a world's axes turned into north-east-down coordinates.
_NED_FROM_WORLD = {
    "ned": np.eye(3),
    "enu": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
}
# Columns: the forward, starboard and down axes (FRD) expressed in each body frame.
_FRD_IN_BODY = {
    "frd": np.eye(3),
    "flu": np.diag([1.0, -1.0, -1.0]),
    "optical": np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
}


# --------------------------------------------------------------------------- the mapping


@dataclass(frozen=True)
class NavMapping:
    """How to read a NAV.csv: the ``[nav]`` table of a camera file, or ``--nav-map KEY=VALUE``.

    Attributes:
        time: column of the time stamps; ``time_unit`` its unit (s, ms, us, ns).
        time_offset_s: the navigation clock's time at the frames' t = 0 (a video's first frame):
            a row at navigation time T belongs to the frame at ``T - time_offset_s``.
        heading: heading column (None: ``heading_rad`` or ``heading_deg`` when the file has one);
            ``heading_convention`` "ned" (from north towards east, a compass) or "enu" (yaw from
            east towards north, ROS).
        angle_unit: "rad", "deg", or "auto" (degrees for a column whose name ends in ``_deg``) of
            the heading, roll and pitch columns.
        quaternion: the four columns x, y, z, w of an orientation quaternion, instead of a heading
            column; ``quaternion_world``, ``quaternion_body``, ``quaternion_rotates``: its
            convention (module notes).
        roll, pitch: attitude columns (rovslam's convention; ``heading_convention = "enu"``: ROS's,
            pitch about the left axis). None: ``roll_rad`` / ``pitch_rad`` when present.
        attitude: use roll and pitch (from these columns or from the quaternion).
        altitude: altitude column in metres above the seabed (None: ``altitude_m`` when present).
        drop_repeated_rows: drop rows whose values repeat the previous row's (a log written faster
            than the navigation updates: values are then interpolated between the updates).
        max_gap_s: the longest time between two rows bridged by interpolation (None: the larger of
            1 s and 3 times the median row interval); frames in a longer gap get no value there.
    """

    time: str = "t_s"
    time_unit: str = "s"
    time_offset_s: float = 0.0
    heading: str | None = None
    heading_convention: str = "ned"
    angle_unit: str = "auto"
    quaternion: tuple[str, str, str, str] | None = None
    quaternion_world: str = "enu"
    quaternion_body: str | None = None
    quaternion_rotates: str = "body-to-world"
    roll: str | None = None
    pitch: str | None = None
    attitude: bool = True
    altitude: str | None = None
    drop_repeated_rows: bool = False
    max_gap_s: float | None = None

    @property
    def body(self) -> str:
        """The quaternion's body frame (default: flu in an enu world, frd in a ned world)."""
        return self.quaternion_body or ("flu" if self.quaternion_world == "enu" else "frd")


_CHOICES = {
    "time_unit": tuple(TIME_UNITS),
    "heading_convention": HEADING_CONVENTIONS,
    "angle_unit": ("auto", *ANGLE_UNITS),
    "quaternion_world": WORLDS,
    "quaternion_body": BODIES,
    "quaternion_rotates": ROTATES,
}
_FIELDS = {f.name: f for f in dataclasses.fields(NavMapping)}
_NUMBERS = ("time_offset_s", "max_gap_s")
_BOOLS = ("attitude", "drop_repeated_rows")


def nav_mapping(
    table: dict[str, Any] | None = None,
    where: str = "[nav]",
    overrides: tuple[tuple[str, str], ...] = (),
    time_offset_s: float | None = None,
) -> NavMapping:
    """A validated :class:`NavMapping` from a ``[nav]`` table, ``--nav-map`` overrides and ``--nav-time-offset``.

    Raises :class:`~rovslam.errors.NavigationError` naming the key and where it was given.
    """
    values: dict[str, Any] = {}
    for key, value in (table or {}).items():
        values[key] = _mapping_value(key, value, f"{where}: key '{key}'")
    for key, text in overrides:
        values[key] = _mapping_value(key, _parse_text(key, text), f"--nav-map {key}={text}")
    if time_offset_s is not None:
        values["time_offset_s"] = _mapping_value("time_offset_s", time_offset_s, "--nav-time-offset")
    mapping = NavMapping(**values)
    if mapping.quaternion is not None and mapping.heading is not None:
        raise NavigationError(f"{where}: give a heading column or a quaternion, not both.")
    return mapping


def _parse_text(key: str, text: str) -> Any:
    """A ``--nav-map`` value (text) as the type the key takes."""
    t = text.strip()
    if key in _BOOLS:
        low = t.lower()
        if low in ("true", "yes", "1", "on"):
            return True
        if low in ("false", "no", "0", "off"):
            return False
        return t
    if key in _NUMBERS:
        try:
            return float(t)
        except ValueError:
            return t
    if key == "quaternion":
        return [c.strip() for c in t.split(",")]
    return t


def _mapping_value(key: str, value: Any, where: str) -> Any:
    if key not in _FIELDS:
        raise NavigationError(f"{where}: unknown key. Known keys: {', '.join(_FIELDS)}.")
    if key in _BOOLS:
        if not isinstance(value, bool):
            raise NavigationError(f"{where}: expected true or false, got {value!r}.")
        return value
    if key in _NUMBERS:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise NavigationError(f"{where}: expected a finite number of seconds, got {value!r}.")
        if key == "max_gap_s" and value <= 0:
            raise NavigationError(f"{where}: expected a positive number of seconds, got {value!r}.")
        return float(value)
    if key == "quaternion":
        if not (isinstance(value, list) and len(value) == 4 and all(isinstance(c, str) and c.strip() for c in value)):
            raise NavigationError(
                f'{where}: expected the four column names x, y, z, w, e.g. ["qx", "qy", "qz", "qw"], got {value!r}.'
            )
        return tuple(c.strip() for c in value)
    if not isinstance(value, str) or not value.strip():
        raise NavigationError(f"{where}: expected a text value (a column name or a choice), got {value!r}.")
    value = value.strip()
    if key in _CHOICES and value not in _CHOICES[key]:
        raise NavigationError(f"{where}: {value!r} is not one of {', '.join(_CHOICES[key])}.")
    return value


# --------------------------------------------------------------------------- rotations


def ned_frd_from_quaternions(
    q_xyzw: np.ndarray, world: str = "enu", body: str = "flu", rotates: str = "body-to-world"
) -> np.ndarray:
    """(N, 3, 3) rotations of rovslam's body (FRD) into a north-east-down world, from (N, 4) quaternions x, y, z, w.

    ``q_xyzw`` must hold unit quaternions (normalised here); see the module notes for the conventions.
    """
    from scipy.spatial.transform import Rotation

    q = np.asarray(q_xyzw, dtype=np.float64).reshape(-1, 4)
    r = Rotation.from_quat(q / np.linalg.norm(q, axis=1, keepdims=True)).as_matrix()
    if rotates == "world-to-body":
        r = np.transpose(r, (0, 2, 1))
    return _NED_FROM_WORLD[world] @ r @ _FRD_IN_BODY[body]


def heading_roll_pitch(r_ned_frd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading, roll and pitch (rad, each (N,)) of (N, 3, 3) rotations ``Rz(heading) Ry(pitch) Rx(roll)``."""
    r = np.asarray(r_ned_frd).reshape(-1, 3, 3)
    heading = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    pitch = -np.arcsin(np.clip(r[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    return heading, roll, pitch


def quaternions_to_heading(
    q_xyzw: np.ndarray, where: list[str], world: str, body: str, rotates: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading, roll, pitch (rad) of (N, 4) quaternions; ``where[i]`` names row i in errors.

    Refuses a quaternion that is not of unit length (columns in the wrong order or mixed up) and
    one that turns the camera to look up or sideways (a wrong world or body convention).
    """
    q = np.asarray(q_xyzw, dtype=np.float64).reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):  # a component of 1e200: an inf length, refused below
        norm = np.linalg.norm(q, axis=1)
    bad = np.nonzero(~(np.abs(norm - 1.0) <= 0.05))[0]
    if len(bad):
        i = int(bad[0])
        raise NavigationError(
            f"{where[i]}: quaternion {tuple(float(v) for v in q[i])} has length {norm[i]:.4g}, not 1: are the "
            "four columns x, y, z, w, in that order?"
        )
    r = ned_frd_from_quaternions(q, world, body, rotates)
    tilt_cos = r[:, 2, 2]  # the body's down axis on the world's down axis
    up = np.nonzero(tilt_cos <= 0.0)[0]
    if len(up):
        i = int(up[0])
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(tilt_cos[i])))))
        raise NavigationError(
            f"{where[i]}: with quaternion_world = {world!r}, quaternion_body = {body!r} and quaternion_rotates = "
            f"{rotates!r} the camera would look {tilt:.0f} degrees away from straight down (up or sideways): "
            "check the convention (README, 'Your own dive')."
        )
    return heading_roll_pitch(r)


# --------------------------------------------------------------------------- tracks


def interp_angle_rad(t_s: np.ndarray, t_nav_s: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Angles at ``t_s`` interpolated along the shorter arc between (``t_nav_s``, ``angle_rad``) samples.

    Between 179 and -179 degrees the path goes through 180, not through 0, at a uniform rate. At a
    sample's time the sample itself is returned (wrapped to (-pi, pi]); outside the samples, the end values.
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    out = _wrap(np.interp(t, t_nav_s, np.unwrap(angle_rad)))
    k = np.clip(np.searchsorted(t_nav_s, t), 0, len(t_nav_s) - 1)
    hit = t_nav_s[k] == t
    out[hit] = _wrap(angle_rad[k[hit]])
    return out


def _wrap(angle_rad: np.ndarray) -> np.ndarray:
    """Angles in (-pi, pi]; an angle already inside is returned unchanged."""
    a = np.asarray(angle_rad, dtype=np.float64)
    return np.where((a > -math.pi) & (a <= math.pi), a, np.arctan2(np.sin(a), np.cos(a)))


@dataclass(frozen=True)
class NavTrack:
    """One navigation quantity by time: ``t_s`` (N,) strictly increasing, ``values`` (N,) finite."""

    t_s: np.ndarray
    values: np.ndarray
    angle: bool = False  # interpolate on the unit circle

    def __post_init__(self) -> None:
        if len(self.t_s) == 0 or len(self.t_s) != len(self.values) or np.any(np.diff(self.t_s) <= 0):
            raise NavigationError("a navigation track needs at least one sample, in strictly increasing time")

    @property
    def span_s(self) -> tuple[float, float]:
        return float(self.t_s[0]), float(self.t_s[-1])

    def median_interval_s(self) -> float:
        return float(np.median(np.diff(self.t_s))) if len(self.t_s) > 1 else 0.0

    def at(self, t_s: np.ndarray | float, max_gap_s: float) -> np.ndarray:
        """Values at ``t_s`` ((M,) array); NaN inside a gap longer than ``max_gap_s`` or beyond the ends.

        Up to ``max_gap_s / 2`` before the first sample or after the last, the end value is held.
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if self.angle:
            v = interp_angle_rad(t, self.t_s, self.values)
        else:
            v = np.interp(t, self.t_s, self.values)
        k = np.searchsorted(self.t_s, t)
        inside = (k > 0) & (k < len(self.t_s))
        gap = np.zeros(len(t))
        gap[inside] = self.t_s[k[inside]] - self.t_s[k[inside] - 1]
        hit = (k < len(self.t_s)) & (self.t_s[np.minimum(k, len(self.t_s) - 1)] == t)
        ok = (inside & (gap <= max_gap_s)) | hit
        ok |= (t < self.t_s[0]) & (self.t_s[0] - t <= max_gap_s / 2)
        ok |= (t > self.t_s[-1]) & (t - self.t_s[-1] <= max_gap_s / 2)
        return np.where(ok, v, np.nan)


@dataclass(frozen=True)
class NavSample:
    """The navigation at one frame's time (NaN / None where it has no value there)."""

    heading_rad: float = math.nan
    roll_rad: float | None = None
    pitch_rad: float | None = None
    altitude_m: float | None = None


@dataclass(frozen=True)
class Navigation:
    """A navigation log: heading, roll, pitch and altitude tracks (any may be None) and where they came from.

    ``altitude_input`` is "navigation" or "sonar" (a bag's sensor_msgs/Range); the ``*_detail``
    texts name the file and columns, or the topics, for ``summary.json`` ``sources``.
    """

    path: str
    heading: NavTrack | None = None
    roll: NavTrack | None = None
    pitch: NavTrack | None = None
    altitude: NavTrack | None = None
    max_gap_s: float = MIN_GAP_S
    heading_detail: str = ""
    altitude_detail: str = ""
    attitude_detail: str = ""
    altitude_input: str = "navigation"

    def __post_init__(self) -> None:
        if not self.tracks:
            raise NavigationError(f"{self.path}: gives neither heading, attitude nor altitude.")
        if (self.roll is None) != (self.pitch is None):
            raise NavigationError(f"{self.path}: give both roll and pitch, or neither.")

    @property
    def tracks(self) -> list[NavTrack]:
        return [t for t in (self.heading, self.roll, self.pitch, self.altitude) if t is not None]

    @property
    def times_s(self) -> tuple[float, float]:
        """The first and last times of the log (of every track), as the file holds them: what messages print."""
        return (max(t.span_s[0] for t in self.tracks), min(t.span_s[1] for t in self.tracks))

    @property
    def span_s(self) -> tuple[float, float]:
        """The times every track covers (frames outside are left out), end values held for max_gap_s / 2."""
        half = self.max_gap_s / 2
        return (max(t.span_s[0] for t in self.tracks) - half, min(t.span_s[1] for t in self.tracks) + half)

    def sample(self, t_s: float) -> NavSample | None:
        """The values at ``t_s``, or None when ``t_s`` is outside :attr:`span_s`."""
        lo, hi = self.span_s
        if not lo <= t_s <= hi:
            return None

        def value(track: NavTrack | None) -> float | None:
            if track is None:
                return None
            v = float(track.at(t_s, self.max_gap_s)[0])
            return None if math.isnan(v) else v

        heading = value(self.heading)
        return NavSample(
            heading_rad=math.nan if heading is None else heading,
            roll_rad=value(self.roll),
            pitch_rad=value(self.pitch),
            altitude_m=value(self.altitude),
        )

    def check_overlap(self, frames_span_s: tuple[float, float] | None, what: str, offset_hint: str) -> None:
        """Refuse a log whose times miss the frames' ``frames_span_s`` (None: not known in advance)."""
        if frames_span_s is None:
            return
        lo, hi = self.span_s
        f0, f1 = frames_span_s
        if hi < f0 or lo > f1:
            t0, t1 = self.times_s
            raise NavigationError(
                f"{self.path}: its times run from {t0:.3f} to {t1:.3f} s on the frames' clock, the {what}'s frames from "
                f"{f0:.3f} to {f1:.3f} s: they do not overlap. {offset_hint}"
            )


def default_max_gap_s(tracks: list[NavTrack]) -> float:
    """The larger of 1 s and 3 times the longest median row interval of ``tracks``."""
    return max([MIN_GAP_S] + [3.0 * t.median_interval_s() for t in tracks])


# --------------------------------------------------------------------------- NAV.csv

OFFSET_HINT = (
    "Align the clocks with --nav-time-offset S or [nav] time_offset_s (the navigation's time at the "
    "first frame; a row at time T belongs to the frame at T - S)."
)


def read_nav_csv(path: str | Path, mapping: NavMapping = NavMapping()) -> Navigation:
    """Read a navigation log (UTF-8 CSV with a header) as the ``mapping`` says.

    Raises :class:`~rovslam.errors.NavigationError` naming the file, line and column.
    """
    p = Path(path)
    if p.is_dir():
        raise NavigationError(f"{p}: is a folder; --nav takes a CSV file.")
    header, rows = read_csv_table(p, (mapping.time,), NavigationError)
    if not rows:
        raise NavigationError(f"{p}: no rows (only a header).")
    cols = _columns(p, header, mapping)
    if mapping.drop_repeated_rows:
        used = [c for key, c in cols.items() if c and key != "time"]
        rows = _drop_repeats(rows, [name for c in used for name in ((c,) if isinstance(c, str) else c)])
    where = [f"{p}, line {line}" for line, _ in rows]
    t = _nav_times(rows, where, mapping)
    heading = roll = pitch = altitude = None
    heading_detail = attitude_detail = altitude_detail = ""
    if mapping.quaternion is not None:
        heading, roll, pitch, heading_detail, attitude_detail = _quaternion_tracks(
            p, rows, where, t, mapping.quaternion, mapping
        )
    elif cols["heading"]:
        heading, heading_detail = _heading_column(p, rows, where, t, cols["heading"], mapping)
    if mapping.attitude and cols["roll"] and mapping.quaternion is None:
        roll, pitch, attitude_detail = _attitude_columns(p, rows, where, t, cols, mapping)
    if cols["altitude"]:
        altitude, altitude_detail = _altitude_column(p, rows, where, t, cols["altitude"])
    tracks = [x for x in (heading, roll, pitch, altitude) if x is not None]
    if not tracks:
        raise NavigationError(
            f"{p}: no heading, attitude or altitude column found (header: {', '.join(header)}). Name them in the camera "
            "file's [nav] table (heading, quaternion, roll, pitch, altitude) or with --nav-map KEY=VALUE."
        )
    return Navigation(
        path=str(p),
        heading=heading,
        roll=roll,
        pitch=pitch,
        altitude=altitude,
        max_gap_s=mapping.max_gap_s or default_max_gap_s(tracks),
        heading_detail=heading_detail,
        altitude_detail=altitude_detail,
        attitude_detail=attitude_detail,
    )


_Rows = list[tuple[int, dict[str, str]]]  # (line number, the row's cells by column name) per row


def _nav_times(rows: _Rows, where: list[str], mapping: NavMapping) -> np.ndarray:
    """(N,) the rows' times in seconds on the frames' clock, or NavigationError where they do not increase."""
    t = _numbers(rows, mapping.time, where, required=True) * TIME_UNITS[mapping.time_unit] - mapping.time_offset_s
    for i in range(1, len(t)):
        if not t[i] > t[i - 1]:
            raise NavigationError(
                f"{where[i]}: time {rows[i][1][mapping.time].strip()} is not after the previous row's; rows must be in "
                "strictly increasing time"
                + ("" if mapping.drop_repeated_rows else " (a log that repeats rows: [nav] drop_repeated_rows = true)")
                + "."
            )
    return t


def _quaternion_tracks(
    p: Path, rows: _Rows, where: list[str], t: np.ndarray, quaternion: tuple[str, ...], mapping: NavMapping
) -> tuple[NavTrack, NavTrack | None, NavTrack | None, str, str]:
    """(heading, roll, pitch, heading detail, attitude detail) from the ``quaternion`` columns (x, y, z, w);
    roll and pitch only when ``mapping.attitude`` (else None and "")."""
    q = np.column_stack([_numbers(rows, c, where) for c in quaternion])
    have = np.all(np.isfinite(q), axis=1)
    h, r, pt = quaternions_to_heading(
        q[have],
        [w for w, k in zip(where, have) if k],
        mapping.quaternion_world,
        mapping.body,
        mapping.quaternion_rotates,
    )
    qdesc = (
        f"quaternion {','.join(quaternion)} ({mapping.quaternion_world} world, {mapping.body} body, "
        f"{mapping.quaternion_rotates})"
    )
    heading, detail = _track(p, t[have], h, "quaternion", angle=True), f"{p.name}, {qdesc}"
    if not mapping.attitude:
        return heading, None, None, detail, ""
    return heading, _track(p, t[have], r, "quaternion"), _track(p, t[have], pt, "quaternion"), detail, detail


def _heading_column(
    p: Path, rows: _Rows, where: list[str], t: np.ndarray, column: str, mapping: NavMapping
) -> tuple[NavTrack, str]:
    """(heading, its detail) from the heading column ``column``, turned into rovslam's convention."""
    conv = mapping.heading_convention
    unit = _angle_unit(mapping, column)
    v = _numbers(rows, column, where) * ANGLE_UNITS[unit]
    if conv == "enu":
        v = math.pi / 2 - v
    have = np.isfinite(v)
    kind = "compass: from north towards east" if conv == "ned" else "ENU yaw"
    return _track(p, t[have], v[have], column, angle=True), f"{p.name}, column {column} ({unit}, {kind})"


def _attitude_columns(
    p: Path, rows: _Rows, where: list[str], t: np.ndarray, cols: dict[str, Any], mapping: NavMapping
) -> tuple[NavTrack, NavTrack, str]:
    """(roll, pitch, their detail) from the roll and pitch columns, or NavigationError at an angle beyond +-90 degrees."""
    unit = _angle_unit(mapping, cols["roll"])
    r = _numbers(rows, cols["roll"], where) * ANGLE_UNITS[unit]
    pt = _numbers(rows, cols["pitch"], where) * ANGLE_UNITS[unit]
    if mapping.heading_convention == "enu":
        pt = -pt
    for name, v in ((cols["roll"], r), (cols["pitch"], pt)):
        bad = np.nonzero(np.abs(v) >= MAX_ATTITUDE_RAD)[0]
        if len(bad):
            raise NavigationError(
                f"{where[bad[0]]}: column '{name}' is {v[bad[0]]:.4g} rad, beyond +-90 degrees: "
                f"check angle_unit (now {unit})."
            )
    have = np.isfinite(r) & np.isfinite(pt)
    roll, pitch = _track(p, t[have], r[have], cols["roll"]), _track(p, t[have], pt[have], cols["pitch"])
    return roll, pitch, f"{p.name}, columns {cols['roll']}, {cols['pitch']} ({unit})"


def _altitude_column(p: Path, rows: _Rows, where: list[str], t: np.ndarray, column: str) -> tuple[NavTrack, str]:
    """(altitude, its detail) from the altitude column ``column``, or NavigationError at a value not above 0."""
    a = _numbers(rows, column, where)
    neg = np.nonzero(a <= 0)[0]
    if len(neg):
        raise NavigationError(
            f"{where[neg[0]]}: column '{column}' is {a[neg[0]]:g}: an altitude above the seabed is positive "
            "(a depth is not an altitude)."
        )
    have = np.isfinite(a)
    return _track(p, t[have], a[have], column), f"{p.name}, column {column} (m)"


def _columns(p: Path, header: list[str], m: NavMapping) -> dict[str, Any]:
    """The columns each quantity comes from (None: not given), checked against the header."""

    def named(key: str, name: str | None, default: tuple[str, ...]) -> str | None:
        if name is not None:
            if name not in header:
                raise NavigationError(
                    f"{p}: [nav] {key} = {name!r} is not a column; the header has: {', '.join(header)}."
                )
            return name
        return next((d for d in default if d in header), None)

    cols: dict[str, Any] = {"time": m.time}
    if m.quaternion is not None:
        missing = [c for c in m.quaternion if c not in header]
        if missing:
            raise NavigationError(
                f"{p}: [nav] quaternion column(s) {', '.join(missing)} not in the header: {', '.join(header)}."
            )
        cols["heading"] = m.quaternion
    else:
        cols["heading"] = named("heading", m.heading, ("heading_rad", "heading_deg"))
    cols["roll"] = named("roll", m.roll, ("roll_rad", "roll_deg"))
    cols["pitch"] = named("pitch", m.pitch, ("pitch_rad", "pitch_deg"))
    if (cols["roll"] is None) != (cols["pitch"] is None):
        raise NavigationError(f"{p}: give both roll and pitch columns, or neither.")
    cols["altitude"] = named("altitude", m.altitude, ("altitude_m",))
    return cols


def _angle_unit(m: NavMapping, column: str) -> str:
    if m.angle_unit != "auto":
        return m.angle_unit
    return "deg" if column.lower().endswith(("_deg", "deg")) else "rad"


def _numbers(
    rows: list[tuple[int, dict[str, str]]], column: str, where: list[str], required: bool = False
) -> np.ndarray:
    """(N,) values of a column; an empty cell or ``nan`` is NaN (no value), unless ``required``."""
    out = np.empty(len(rows))
    for i, (_, row) in enumerate(rows):
        text = (row.get(column) or "").strip()
        if text == "" or text.lower() == "nan":
            if required:
                raise NavigationError(
                    f"{where[i]}: column '{column}' is {'empty' if not text else 'nan'}; it needs a number."
                )
            out[i] = math.nan
            continue
        try:
            v = float(text)
        except ValueError:
            raise NavigationError(f"{where[i]}: column '{column}' is not a number: {text!r}.") from None
        if not math.isfinite(v):
            raise NavigationError(f"{where[i]}: column '{column}' is not finite: {text!r}.")
        out[i] = v
    return out


def _drop_repeats(rows: list[tuple[int, dict[str, str]]], columns: list[str]) -> list[tuple[int, dict[str, str]]]:
    """Rows whose ``columns`` differ from the previous kept row's, and the last row."""
    kept: list[tuple[int, dict[str, str]]] = []
    last: tuple[str, ...] | None = None
    for i, (line, row) in enumerate(rows):
        key = tuple((row.get(c) or "").strip() for c in columns)
        if key != last or i == len(rows) - 1:
            kept.append((line, row))
            last = key
    return kept


def _track(p: Path, t_s: np.ndarray, values: np.ndarray, column: str, angle: bool = False) -> NavTrack:
    if len(t_s) == 0:
        raise NavigationError(f"{p}: column {column!r} holds no value in any row.")
    return NavTrack(np.asarray(t_s, dtype=np.float64), np.asarray(values, dtype=np.float64), angle)


# --------------------------------------------------------------------------- attaching it to frames


class NavigatedSource:
    """A source of frames (video, image folder, bag) with a :class:`Navigation` attached.

    Each frame gets the navigation's heading, attitude and altitude at its time (replacing the
    source's own). Frames outside the navigation's time span are left out; frames inside a gap
    longer than its ``max_gap_s`` keep no value there (no compass for that frame: NaN heading).
    """

    def __init__(
        self,
        source: Any,
        nav: Navigation,
        frames_span_s: tuple[float, float] | None,
        what: str,
        offset_hint: str = OFFSET_HINT,
    ):
        nav.check_overlap(frames_span_s, what, offset_hint)
        self.source = source
        self.nav = nav
        self.info = source.info
        self.groundtruth_path = None
        self.what = what
        self.offset_hint = offset_hint
        self._before: list[float] = []  # times of the frames left out before / after the span (first, last)
        self._after: list[float] = []
        self._before_n = self._after_n = 0
        self._gaps = 0

    def __len__(self) -> int:
        return len(self.source)

    @property
    def left_out(self) -> int:
        return int(getattr(self.source, "left_out", 0)) + self._before_n + self._after_n

    @property
    def warnings(self) -> list[str]:
        out = list(getattr(self.source, "warnings", []))
        lo, hi = self.nav.times_s  # the file's own first and last times (frames within max_gap_s / 2 still take them)
        if self._before_n:
            out.append(
                f"{self._before_n} frame(s) from t = {self._before[0]:.6g} to {self._before[-1]:.6g} s come before the "
                f"navigation starts ({self.nav.path}, t = {lo:.6g} s on the frames' clock): left out."
            )
        if self._after_n:
            out.append(
                f"{self._after_n} frame(s) from t = {self._after[0]:.6g} to {self._after[-1]:.6g} s come after the "
                f"navigation ends ({self.nav.path}, t = {hi:.6g} s on the frames' clock): left out."
            )
        if self._gaps:
            out.append(
                f"{self._gaps} frame(s) fall in gaps of the navigation longer than {self.nav.max_gap_s:g} s: "
                "processed without its values there (no compass: the tokens' turn)."
            )
        return out

    @property
    def description(self) -> SourceDescription:
        base: SourceDescription = self.source.description
        nav = self.nav
        return dataclasses.replace(
            base,
            heading_input="navigation" if nav.heading is not None else base.heading_input,
            heading_detail=nav.heading_detail if nav.heading is not None else base.heading_detail,
            altitude_input=nav.altitude_input if nav.altitude is not None else base.altitude_input,
            altitude_detail=nav.altitude_detail if nav.altitude is not None else base.altitude_detail,
            attitude_detail=nav.attitude_detail if nav.roll is not None else base.attitude_detail,
        )

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """The source's frames with the navigation's values; raises NavigationError if none lies in its span."""
        lo, hi = self.nav.span_s
        given = 0
        stream = self.source.frames(start, stop)
        try:
            for f in stream:
                s = self.nav.sample(f.t_s)
                if s is None:
                    self._leave_out(f.t_s, before=f.t_s < lo)
                    continue
                yield self._with(f, s)
                given += 1
        finally:
            stream.close()
        if given == 0 and (self._before_n or self._after_n):
            lo, hi = self.nav.times_s
            raise NavigationError(
                f"{self.nav.path}: no frame of the {self.what} lies in the navigation's time span ({lo:.3f} to {hi:.3f} s on "
                f"the frames' clock). {self.offset_hint}"
            )

    def _leave_out(self, t_s: float, before: bool) -> None:
        """Count a frame outside the navigation's span; keep the first and last such time."""
        times = self._before if before else self._after
        times[1:] = [t_s]  # [first] or [first, last]
        if before:
            self._before_n += 1
        else:
            self._after_n += 1

    def _with(self, f: Frame, s: NavSample) -> Frame:
        nav = self.nav
        changes: dict[str, Any] = {}
        if nav.heading is not None:
            changes["heading_rad"] = s.heading_rad
            if math.isnan(s.heading_rad):
                self._gaps += 1
        if nav.altitude is not None:
            changes["sonar_altitude_m"] = s.altitude_m
        if nav.roll is not None:
            have = s.roll_rad is not None and s.pitch_rad is not None
            changes.update(
                roll_rad=s.roll_rad if have else 0.0, pitch_rad=s.pitch_rad if have else 0.0, has_attitude=have
            )
        return dataclasses.replace(f, **changes)
