"""What every input of ``rovslam run`` has in common: the options that open it and the description
of where its altitude, heading and attitude come from (``summary.json`` ``sources``).

A source is anything with ``.info`` (:class:`~rovslam.io.sequence.SequenceInfo`), ``.frames(start,
stop)`` (a generator of :class:`~rovslam.io.sequence.Frame`), ``len()`` (0 when unknown),
``.warnings`` / ``.left_out`` (what was left out of the stream, and why) and ``.description``
(a :class:`SourceDescription`): a sequence folder, a video, a plain image folder, a ROS bag, or
one of them with a navigation log attached (:class:`rovslam.io.nav.NavigatedSource`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

# What fills a frame's altitude and heading inputs (the pipeline calls the altitude input "sonar").
ALTITUDE_INPUTS = ("sonar", "navigation")
HEADING_INPUTS = ("compass", "navigation")
TOKENS_ONLY = "tokens only (no compass)"
ASSUMED_ALTITUDE = "assumed constant"
HELD_ALTITUDE = "held between readings"


@dataclass(frozen=True)
class SourceDescription:
    """Where a source's frames, altitude, heading and attitude come from.

    Attributes:
        kind: "sequence folder", "video", "image folder", "ROS 1 bag", "ROS 2 bag (sqlite3)", ...
        path: the file or folder given.
        altitude_input: what fills ``Frame.sonar_altitude_m``: "sonar", "navigation" or None (nothing).
        altitude_detail: the file and column, or the topic, it comes from.
        heading_input: what fills ``Frame.heading_rad``: "compass", "navigation" or None (tokens only).
        heading_detail: the file and column(s), or the topic.
        attitude_detail: where roll and pitch come from, or None (a level camera is assumed).
    """

    kind: str
    path: str
    altitude_input: str | None = None
    altitude_detail: str = ""
    heading_input: str | None = None
    heading_detail: str = ""
    attitude_detail: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class InputOptions:
    """How to open an input that is not a sequence folder (the options of ``rovslam run`` / ``import``).

    Attributes:
        camera_file: the camera file (``[camera]``, ``[[laser]]``, ``[vehicle]``, ``[nav]``) of a
            video, an image folder or a bag.
        nav_file: NAV.csv with heading (or a quaternion), roll, pitch, altitude by time.
        nav_map: ``(key, value)`` pairs overriding the camera file's ``[nav]`` table.
        nav_time_offset_s: the navigation clock's time at the first frame (overrides ``[nav] time_offset_s``).
        fps: frame rate of an image folder; or ``times_file``, a CSV ``image,t_s``.
        image_topic ... camera_info_topic: the topics of a bag.
        heading_convention: "enu" (ROS, REP 103) or "ned" for a bag's orientation topics.
        heading_degrees: a bag's std_msgs/Float64 heading is in degrees.
    """

    camera_file: Path | None = None
    nav_file: Path | None = None
    nav_map: tuple[tuple[str, str], ...] = ()
    nav_time_offset_s: float | None = None
    fps: float | None = None
    times_file: Path | None = None
    image_topic: str | None = None
    heading_topic: str | None = None
    altitude_topic: str | None = None
    attitude_topic: str | None = None
    camera_info_topic: str | None = None
    heading_convention: str = "enu"
    heading_degrees: bool = False

    @property
    def bag_options(self) -> dict[str, Any]:
        """The bag-only options that were given (name -> value)."""
        names = ("image_topic", "heading_topic", "altitude_topic", "attitude_topic", "camera_info_topic")
        given = {n: getattr(self, n) for n in names if getattr(self, n) is not None}
        if self.heading_degrees:
            given["heading_degrees"] = True
        if self.heading_convention != "enu":
            given["heading_convention"] = self.heading_convention
        return given

    @property
    def nav_options(self) -> dict[str, Any]:
        """The NAV.csv options that were given (option name -> value)."""
        given: dict[str, Any] = {}
        if self.nav_file is not None:
            given["nav"] = str(self.nav_file)
        if self.nav_map:
            given["nav_map"] = [f"{k}={v}" for k, v in self.nav_map]
        if self.nav_time_offset_s is not None:
            given["nav_time_offset"] = self.nav_time_offset_s
        return given

    def to_dict(self) -> dict[str, Any]:
        """The options given, as JSON-friendly values (for summary.json)."""
        out: dict[str, Any] = {}
        if self.camera_file is not None:
            out["camera_file"] = str(self.camera_file)
        out.update(self.nav_options)
        if self.fps is not None:
            out["fps"] = self.fps
        if self.times_file is not None:
            out["times_file"] = str(self.times_file)
        out.update(self.bag_options)
        return out


def option_flag(name: str) -> str:
    """The command-line spelling of an option name: ``image_topic`` -> ``--image-topic``."""
    return "--" + name.replace("_", "-")
