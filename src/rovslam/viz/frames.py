"""The images of a run, found again after it: the sequence folder or video named in summary.json.

The report and the mosaic need some frames back (by index) and the camera model. A run
records the path of its source (``summary.json`` ``sequence``, and ``camera_file`` for a
video); ``--seq`` overrides it when the data moved. A video is decoded with PyAV, once,
in order, keeping only the frames asked for.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.camera import Camera
from rovslam.errors import RovslamError, SequenceFormatError


@dataclass(frozen=True)
class FrameStore:
    """An opened image source of a run: the camera, attitude per frame and random access by index."""

    path: Path
    camera: Camera
    source: Any  # rovslam.io.sequence.Sequence or rovslam.io.video.VideoSource
    roll_rad: np.ndarray  # (N,) per frame (0 when the source has none)
    pitch_rad: np.ndarray  # (N,)

    @property
    def is_video(self) -> bool:
        return not hasattr(self.source, "rows")

    def images(self, indices: Iterable[int]) -> dict[int, np.ndarray]:
        """{index: (H, W, 3) uint8 RGB} for the frames asked for (unreadable ones left out)."""
        want = sorted({int(i) for i in indices})
        return {i: img for i, img in self.stream(want)}

    def stream(self, indices: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(index, image)`` for the sorted ``indices``, decoding one frame at a time."""
        if not indices:
            return
        if self.is_video:
            wanted = set(indices)
            for fr in self.source.frames(stop=max(indices) + 1):
                if fr.index in wanted and fr.image is not None:
                    yield fr.index, fr.image
            return
        from rovslam.io.sequence import read_image

        rows = self.source.rows
        for i in indices:
            if 0 <= i < len(rows):
                try:
                    yield i, read_image(self.source.folder / rows[i].image, self.camera)
                except RovslamError:
                    continue


def source_path(summary: dict, seq: str | Path | None) -> Path | None:
    """The image source of a run: ``seq`` if given, else the one summary.json names."""
    if seq is not None:
        return Path(seq)
    named = summary.get("sequence")
    return Path(named) if named else None


def open_frames(
    summary: dict,
    seq: str | Path | None = None,
    camera_file: str | Path | None = None,
    results_dir: str | Path | None = None,
) -> FrameStore:
    """Open the frames of a run. Raises :class:`SequenceFormatError` saying what is missing and how to fix it."""
    path = source_path(summary, seq)
    if path is None:
        where = Path(results_dir) / "summary.json" if results_dir is not None else "summary.json"
        what = "names no sequence" if summary else "is missing (or empty), so the run's sequence is unknown"
        raise SequenceFormatError(f"{where} {what}; give the sequence folder or video with --seq.")
    if not path.exists():
        raise SequenceFormatError(f"{path}: the run's sequence is not there any more; give its new place with --seq.")
    if path.is_dir():
        from rovslam.io.sequence import open_sequence

        s = open_sequence(path, check_images=False)
        roll = np.array([r.roll_rad or 0.0 for r in s.rows])
        pitch = np.array([r.pitch_rad or 0.0 for r in s.rows])
        return FrameStore(path, s.info.camera, s, roll, pitch)
    cam = camera_file or summary.get("camera_file")
    if not cam or not Path(cam).is_file():
        raise SequenceFormatError(
            f"{path}: a video needs its camera file (sequence.toml syntax); summary.json names "
            f"{cam!r}. Give it with --camera FILE.toml."
        )
    from rovslam.io.video import open_video

    v = open_video(path, cam)
    n = len(v) or 0
    return FrameStore(path, v.info.camera, v, np.zeros(n), np.zeros(n))
