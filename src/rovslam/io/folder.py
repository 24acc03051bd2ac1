"""A plain folder of images (PNG, JPEG, TIFF) as a stream of frames: ``rovslam run FOLDER --camera CAMERA.toml``.

The frames are the image files directly in the folder, in natural order (``img2.png`` before
``img10.png``), timed by a frame rate (``--fps``) or by a CSV ``image,t_s`` (``--times``: only the
images it lists, in its time order). The camera comes from a camera file; heading and altitude
from a navigation log (``--nav``) or nowhere (the tokens' turn, ``[vehicle] altitude_m``).
Nothing outside the folder is opened: a file that is a symbolic link to elsewhere is refused, a
``--times`` row naming a path outside the folder too.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator
from pathlib import Path

from rovslam.core import Frame
from rovslam.errors import ImageReadError, SequenceFormatError
from rovslam.io.camera_file import CameraFile
from rovslam.io.sequence import read_image
from rovslam.io.source import SourceDescription
from rovslam.io.text import MAX_TIME_S, inside_folder, not_a_file, read_csv_table, time_cell

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
TIMES_COLUMNS = ("image", "t_s")
MAX_FPS = 10_000.0


def natural_key(name: str) -> list[object]:
    """Sort key that orders the digit runs of ``name`` as numbers: ``f2`` < ``f10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def image_files(folder: Path) -> list[str]:
    """Names of the image files directly in ``folder``, in natural order."""
    names = [
        e.name for e in os.scandir(folder) if e.name.lower().endswith(IMAGE_SUFFIXES) and not e.name.startswith(".")
    ]
    return sorted(names, key=natural_key)


def is_image_folder(folder: Path) -> bool:
    """Whether ``folder`` holds image files directly (and so may be run as a plain image folder)."""
    try:
        return any(e.name.lower().endswith(IMAGE_SUFFIXES) for e in os.scandir(folder))
    except OSError:
        return False


class ImageFolderSource:
    """The images of a folder, decoded one at a time, with times from a frame rate or a times file."""

    def __init__(
        self, folder: str | Path, camera: CameraFile, fps: float | None = None, times_file: str | Path | None = None
    ):
        self.folder = Path(folder)
        self.camera_file = camera
        self.info = camera.info
        self.groundtruth_path = None
        self.warnings: list[str] = []
        self.left_out = 0
        root = Path(os.path.realpath(self.folder))
        if fps is not None and times_file is not None:
            raise SequenceFormatError(
                f"{self.folder}: give --fps or --times, one of the two, not both: --fps times the images in name order at a fixed "
                "rate, --times gives each image its own time."
            )
        if fps is None and times_file is None:
            raise SequenceFormatError(
                f"{self.folder}: an image folder needs its frame times: give --fps F (frames per second) or --times "
                "FILE (a CSV with columns image,t_s), one of the two (README, 'Your own dive')."
            )
        if fps is not None:
            if not (isinstance(fps, (int, float)) and math.isfinite(fps) and 0 < fps <= MAX_FPS):
                raise SequenceFormatError(
                    f"--fps must be a frame rate above 0 and at most {MAX_FPS:g} frames per second, got {fps!r}."
                )
            names = image_files(self.folder)
            times = [k / float(fps) for k in range(len(names))]
            if times and times[-1] > MAX_TIME_S:
                raise SequenceFormatError(
                    f"--fps {fps!r} puts the last of {len(names)} images {times[-1]:g} s after the first, more than any "
                    f"dive ({MAX_TIME_S:g} s); give the frame rate in frames per second (e.g. --fps 5), or --times FILE."
                )
        else:
            names, times = self._read_times(Path(times_file), root)  # type: ignore[arg-type]
            if not names:
                raise SequenceFormatError(
                    f"{times_file}: lists no images (only a header); add one row image,t_s per image of {self.folder}."
                )
        if not names:
            raise SequenceFormatError(
                f"{self.folder}: no image files (PNG, JPEG or TIFF: {', '.join(IMAGE_SUFFIXES)}) in this folder."
            )
        for name in names:
            inside_folder(root, name, f"{self.folder}: image '{name}'")
        self.names = names
        self.times_s = times
        self._root = root

    def _read_times(self, path: Path, root: Path) -> tuple[list[str], list[float]]:
        _, rows = read_csv_table(path, TIMES_COLUMNS)
        listed: list[tuple[float, str, str]] = []
        seen: set[str] = set()
        for line, row in rows:
            where = f"{path}, line {line}"
            name = (row.get("image") or "").strip()
            if not name:
                raise SequenceFormatError(f"{where}: column 'image' is empty.")
            if name in seen:
                raise SequenceFormatError(f"{where}: image '{name}' is listed twice.")
            seen.add(name)
            resolved = inside_folder(root, name, f"{where}: column 'image'")
            if not resolved.is_file():
                why = "not found" if not resolved.exists() else not_a_file(resolved)
                raise SequenceFormatError(f"{where}: image file '{name}' {why} in {self.folder}.")
            listed.append((time_cell(row, where), name, where))
        listed.sort()
        for (t0, _, _), (t1, _, where) in zip(listed, listed[1:]):
            if t1 <= t0:
                raise SequenceFormatError(
                    f"{where}: t_s={t1} repeats another image's time; every image needs its own time."
                )
        unlisted = len(set(image_files(self.folder)) - seen)
        if unlisted:
            self.warnings.append(f"{unlisted} image file(s) of {self.folder} are not listed in {path}: left out.")
        return [n for _, n, _ in listed], [t for t, _, _ in listed]

    def __len__(self) -> int:
        return len(self.names)

    @property
    def span_s(self) -> tuple[float, float]:
        return self.times_s[0], self.times_s[-1]

    @property
    def description(self) -> SourceDescription:
        return SourceDescription("image folder", str(self.folder))

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        for k in range(start, len(self.names) if stop is None else min(stop, len(self.names))):
            name = self.names[k]
            where = f"{self.folder / name}"
            try:
                resolved = inside_folder(self._root, name, where)  # checked again: the folder may have changed
                image, error = read_image(resolved, self.info.camera, self.info.bit_depth, "the camera file"), None
            except (ImageReadError, SequenceFormatError) as exc:
                image, error = None, str(exc)
            yield Frame(index=k, t_s=self.times_s[k], image=image, heading_rad=math.nan, source=where, error=error)
