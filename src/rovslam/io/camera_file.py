"""The camera file of a video, an image folder or a bag: ``[camera]``, ``[[laser]]``, ``[vehicle]``, ``[nav]``.

A camera file is not a sequence: it needs no ``format`` key (a ``sequence.toml`` given as a
camera file, with its ``format``, ``name`` and ``[metadata]``, is accepted too). Its optional
``[nav]`` table says how to read the navigation log given with ``--nav``
(:class:`rovslam.io.nav.NavMapping`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rovslam.core import SequenceInfo
from rovslam.errors import SequenceFormatError
from rovslam.io.sequence import info_from_toml, load_toml

CAMERA_TABLES = (
    "[camera] (width_px, height_px, fx_px, fy_px, cx_px, cy_px), optional [[laser]], [vehicle] altitude_m and [nav]"
)


@dataclass(frozen=True)
class CameraFile:
    """A parsed camera file: the camera model and rig, and its ``[nav]`` table as written (or None)."""

    path: Path
    info: SequenceInfo
    nav: dict[str, Any] | None = None


def read_camera_file(path: str | Path, name: str | None = None) -> CameraFile:
    """Read and validate a camera file; ``name`` names the dive when the file has no ``name``.

    Raises :class:`~rovslam.errors.SequenceFormatError` naming the file and key.
    """
    p = Path(path)
    if not p.is_file():
        state = "is a folder" if p.is_dir() else "not found"
        raise SequenceFormatError(f"{p}: camera file {state}. A camera file is a TOML file with {CAMERA_TABLES}.")
    data = load_toml(p)
    nav = data.get("nav")
    if nav is not None and not isinstance(nav, dict):
        raise SequenceFormatError(f"{p}: 'nav' must be a table ([nav]) mapping the columns of the navigation log.")
    info = info_from_toml(data, p, require_format=False, extra_keys=("nav",))
    if "name" not in data and name:
        info = dataclasses.replace(info, name=name)
    return CameraFile(p, info, nav)
