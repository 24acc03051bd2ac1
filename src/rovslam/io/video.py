"""Video files as a stream of timestamped frames (PyAV), the same :class:`Frame` records as a sequence.

A video carries no camera model, heading or altitude: they come from a camera file, a
``sequence.toml`` without frames (``[camera]``, optional ``[[laser]]``, ``[vehicle]
altitude_m``). The heading is NaN (no compass): the pipeline then integrates the rotation
the speed tokens measure, starting from 0. Frames are decoded one at a time; nothing is held in memory beyond the current one.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from rovslam.errors import ImageReadError, SequenceFormatError
from rovslam.io.sequence import Frame, SequenceInfo, parse_sequence_toml

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm", ".mpg", ".mpeg", ".ts")


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
                self._n = int(s.frames) if s.frames else None
                w, h = s.codec_context.width, s.codec_context.height
        except av.error.FFmpegError as exc:
            raise SequenceFormatError(f"{self.path}: not a readable video ({exc}).") from None
        cam = info.camera
        if (w, h) != (cam.width_px, cam.height_px):
            raise SequenceFormatError(
                f"{self.path}: video is {w}x{h} px but the camera file says {cam.width_px}x{cam.height_px}."
            )
        self.groundtruth_path = None

    def __len__(self) -> int:
        return self._n or 0

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        import av

        with av.open(str(self.path)) as c:
            stream = c.streams.video[0]
            k = 0
            t_first = None
            # demux + packet.decode: PyAV 18's container.decode() raises EOFError at the end of some files.
            for packet in c.demux(stream):
                try:
                    decoded = packet.decode()
                except av.error.FFmpegError as exc:
                    raise ImageReadError(f"{self.path}: frame {k} could not be decoded ({exc}).") from None
                for vf in decoded:
                    if stop is not None and k >= stop:
                        return
                    t = float(vf.time) if vf.time is not None else k / float(stream.average_rate or 1)
                    if t_first is None:
                        t_first = t
                    if k >= start:
                        yield Frame(
                            index=k, t_s=t - t_first, image=vf.to_ndarray(format="rgb24"),
                            heading_rad=self.heading_rad, source=f"{self.path}#{k}",
                        )
                    k += 1


def open_video(path: str | Path, camera_file: str | Path, heading_rad: float = float("nan")) -> VideoSource:
    """A video plus a camera file (``sequence.toml`` syntax; frames.csv is not needed)."""
    return VideoSource(path, parse_sequence_toml(Path(camera_file)), heading_rad)
