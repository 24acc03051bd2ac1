"""Video files as a stream of timestamped frames (PyAV), the same :class:`Frame` records as a sequence.

A video carries no camera model, heading or altitude: they come from a camera file
(``[camera]``, optional ``[[laser]]``, ``[vehicle] altitude_m``, ``[nav]``;
:mod:`rovslam.io.camera_file`) and a navigation log (:mod:`rovslam.io.nav`). Without one the
heading is NaN (no compass): the pipeline then integrates the rotation the speed tokens
measure, starting from 0. Frame times come from the stream (its time stamps, the first frame at 0). Frames are decoded one at a time; nothing is held in memory beyond the current one.

A damaged file does not end a run with a traceback: a frame of the wrong size is a skipped
frame (``error`` set); a packet that cannot be decoded or a time stamp that goes backwards is
left out and counted in
:attr:`VideoSource.warnings` (the run's ``summary.json`` lists them); a file that ends before
the duration its header declares is reported there too.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rovslam.core import Frame, SequenceInfo
from rovslam.errors import SequenceFormatError
from rovslam.io.camera_file import read_camera_file
from rovslam.io.source import SourceDescription

MAX_WARNINGS = 20
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm", ".mpg", ".mpeg", ".ts", ".mts", ".m2ts", ".mxf",
                  ".flv", ".wmv", ".3gp", ".ogv", ".nut", ".y4m", ".h264", ".h265", ".hevc")
NOT_VIDEO_SUFFIXES = (".csv", ".txt", ".toml", ".yaml", ".yml", ".json", ".png", ".jpg", ".jpeg", ".tif", ".tiff",
                      ".db3", ".mcap", ".bag")


class VideoSource:
    """Frames of a video file, decoded lazily with PyAV, as RGB ``(H, W, 3) uint8``."""

    def __init__(self, path: str | Path, info: SequenceInfo, heading_rad: float = float("nan")):
        import av

        self.path = Path(path)
        if not self.path.is_file():
            raise SequenceFormatError(f"{self.path}: video file not found.")
        self.info = info
        self.heading_rad = float(heading_rad)
        try:
            with av.open(str(self.path)) as c:
                if not c.streams.video:
                    raise SequenceFormatError(f"{self.path}: has no video stream.")
                s = c.streams.video[0]
                self._n = int(s.frames) if s.frames else _frames_from_duration(c.duration, s.average_rate)
                self.duration_s = c.duration / 1e6 if c.duration else None
                w, h = s.codec_context.width, s.codec_context.height
        except av.error.FFmpegError as exc:
            raise SequenceFormatError(f"{self.path}: not a readable video ({exc}).") from None
        cam = info.camera
        if (w, h) != (cam.width_px, cam.height_px):
            raise SequenceFormatError(
                f"{self.path}: video is {w}x{h} px but the camera file says {cam.width_px}x{cam.height_px}."
            )
        self.groundtruth_path = None
        self.warnings: list[str] = []  # what was left out of the stream, and why (at most MAX_WARNINGS)
        self.left_out = 0

    def _leave_out(self, message: str) -> None:
        self.left_out += 1
        if len(self.warnings) < MAX_WARNINGS:
            self.warnings.append(message)

    def __len__(self) -> int:
        return self._n or 0

    @property
    def span_s(self) -> tuple[float, float] | None:
        """The frames' times, first to last, as the container declares them (None: not declared)."""
        return None if self.duration_s is None else (0.0, self.duration_s)

    @property
    def description(self) -> SourceDescription:
        return SourceDescription("video", str(self.path))

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        import av

        cam = self.info.camera
        with av.open(str(self.path)) as c:
            stream = c.streams.video[0]
            k = 0
            t_first = t_last = None
            packets = c.demux(stream)
            while True:
                # demux + packet.decode: PyAV 18's container.decode() raises EOFError at the end of some files.
                try:
                    packet = next(packets, None)
                except (av.error.FFmpegError, EOFError) as exc:
                    self._leave_out(f"{self.path}: the stream could not be read after frame {k} ({exc}); the rest is left out.")
                    return
                if packet is None:
                    break
                try:
                    decoded = packet.decode()
                except av.error.FFmpegError as exc:
                    self._leave_out(f"{self.path}: a packet after frame {k} could not be decoded ({exc}); left out.")
                    continue
                for vf in decoded:
                    if stop is not None and k >= stop:
                        return
                    t = float(vf.time) if vf.time is not None else k / float(stream.average_rate or 1)
                    if t_first is None:
                        t_first = t
                    if t_last is not None and t <= t_last:
                        self._leave_out(f"{self.path}#{k}: time stamp {t - t_first:g} s is not after the previous frame's; left out.")
                        continue
                    t_last = t
                    if k >= start:
                        error = None
                        if (vf.width, vf.height) != (cam.width_px, cam.height_px):
                            error = (f"{self.path}#{k}: frame is {vf.width}x{vf.height} px, the camera file says "
                                     f"{cam.width_px}x{cam.height_px}.")
                        yield Frame(
                            index=k, t_s=t - t_first, image=None if error else vf.to_ndarray(format="rgb24"),
                            heading_rad=self.heading_rad, source=f"{self.path}#{k}", error=error,
                        )
                    k += 1
        if stop is None and self._n and k < self._n - 1:
            self._leave_out(
                f"{self.path}: ended after {k} frames, its header declares about {self._n}: a truncated or damaged file?"
            )


def is_video(path: str | Path) -> bool:
    """Whether FFmpeg opens ``path`` and finds a video stream in it (any container, whatever its name)."""
    import av

    p = Path(path)
    if p.suffix.lower() in NOT_VIDEO_SUFFIXES or not p.is_file():
        return False
    try:
        with av.open(str(p)) as c:
            return bool(c.streams.video)
    except (av.error.FFmpegError, UnicodeDecodeError, ValueError):
        return False


def _frames_from_duration(duration_us: int | None, rate: Any) -> int | None:
    """Number of frames a container declares through its duration and frame rate (None when unknown)."""
    if not duration_us or not rate:
        return None
    return int(round(duration_us / 1e6 * float(rate)))


def open_video(path: str | Path, camera_file: str | Path, heading_rad: float = float("nan")) -> VideoSource:
    """A video plus a camera file (:func:`rovslam.io.camera_file.read_camera_file`)."""
    return VideoSource(path, read_camera_file(camera_file, name=Path(path).stem).info, heading_rad)
