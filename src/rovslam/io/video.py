"""Video files as a stream of timestamped frames (PyAV), the same :class:`Frame` records as a sequence.

A video carries no camera model, heading or altitude: they come from a camera file
(``[camera]``, optional ``[[laser]]``, ``[vehicle] altitude_m``, ``[nav]``;
:mod:`rovslam.io.camera_file`) and a navigation log (:mod:`rovslam.io.nav`). Without one the
heading is NaN (no compass): the pipeline then integrates the rotation the speed tokens
measure, starting from 0. Frames are decoded one at a time; nothing is held in memory beyond
the current one.

Frame times: the frames are taken in the decoder's output order, which is the order FFmpeg
players show them in, and every decodable frame is kept whatever its time stamp. The k-th
frame's time is the k-th smallest presentation time of the stream's packets (the first frame
at 0), so a container whose time stamps are written out of order (a muxer that wrote decode
times, say) still gives each frame its own time. Where a time would not be after the previous
frame's (a repeated stamp) or the stream has none (a raw H.264/H.265 file), the time is the
previous one plus one frame period of the stream's declared rate. Each kind of repair is said
once, with how many frames it concerned, in :attr:`VideoSource.warnings`. A variable frame
rate is kept as its time stamps give it.

A damaged file does not end a run with a traceback: a frame of the wrong size is a skipped
frame (``error`` set); a packet that cannot be decoded is left out and counted in
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
FALLBACK_RATE_HZ = 25.0  # frame rate assumed for times when a stream declares none and has no time stamps
VIDEO_SUFFIXES = (
    ".mp4",
    ".mov",
    ".mkv",
    ".avi",
    ".m4v",
    ".webm",
    ".mpg",
    ".mpeg",
    ".ts",
    ".mts",
    ".m2ts",
    ".mxf",
    ".flv",
    ".wmv",
    ".3gp",
    ".ogv",
    ".nut",
    ".y4m",
    ".h264",
    ".h265",
    ".hevc",
)
NOT_VIDEO_SUFFIXES = (
    ".csv",
    ".txt",
    ".toml",
    ".yaml",
    ".yml",
    ".json",
    ".png",
    ".jpg",
    ".jpeg",
    ".tif",
    ".tiff",
    ".db3",
    ".mcap",
    ".bag",
)


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
        self._packet_times_s: list[float] | None = None
        self._time_notes: set[str] = set()

    def _note(self, message: str) -> None:
        """A warning about the stream that leaves nothing out (said once per message)."""
        if message not in self._time_notes and len(self.warnings) < MAX_WARNINGS:
            self._time_notes.add(message)
            self.warnings.append(message)

    def packet_times_s(self) -> list[float]:
        """The presentation times (s) of the video stream's packets, sorted; empty when any packet has none.

        Read once by demuxing the file without decoding it (a few seconds for an hour of video).
        """
        if self._packet_times_s is None:
            import av

            times: list[float] = []
            try:
                with av.open(str(self.path)) as c:
                    stream = c.streams.video[0]
                    for packet in c.demux(stream):
                        if packet.size == 0:  # the flush packet at the end
                            continue
                        if packet.pts is None or packet.time_base is None:
                            times = []
                            break
                        times.append(float(packet.pts * packet.time_base))
            except (av.error.FFmpegError, EOFError):
                pass  # a damaged tail: the frames' own times decide past what could be read
            self._packet_times_s = sorted(times)
        return self._packet_times_s

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
            t_first = None
            clock = _FrameClock(self.packet_times_s(), _declared_rate_hz(stream))
            packets = c.demux(stream)
            while True:
                # demux + packet.decode: PyAV 18's container.decode() raises EOFError at the end of some files.
                try:
                    packet = next(packets, None)
                except (av.error.FFmpegError, EOFError) as exc:
                    self._leave_out(
                        f"{self.path}: the stream could not be read after frame {k} ({exc}); the rest is left out."
                    )
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
                    t = clock.time_s(k, None if vf.time is None else float(vf.time))
                    if t_first is None:
                        t_first = t
                    if k >= start:
                        error = None
                        if (vf.width, vf.height) != (cam.width_px, cam.height_px):
                            error = (
                                f"{self.path}#{k}: frame is {vf.width}x{vf.height} px, the camera file says "
                                f"{cam.width_px}x{cam.height_px}."
                            )
                        yield Frame(
                            index=k,
                            t_s=t - t_first,
                            image=None if error else vf.to_ndarray(format="rgb24"),
                            heading_rad=self.heading_rad,
                            source=f"{self.path}#{k}",
                            error=error,
                        )
                    k += 1
        for message in clock.notes(str(self.path)):
            self._note(message)
        if stop is None and self._n and k < self._n - 1 and not self._decoded_all(k, clock.period_s):
            self._leave_out(
                f"{self.path}: ended after {k} frames, its header declares about {self._n}: a truncated or damaged file?"
            )

    def _decoded_all(self, k: int, period_s: float) -> bool:
        """Whether ``k`` decoded frames are every packet of a file whose packets span its declared duration
        (a variable frame rate makes the header's count, duration x average rate, a guess)."""
        times = self.packet_times_s()
        if not times or self.duration_s is None or k < len(times) - 1:
            return False
        return times[-1] - times[0] >= self.duration_s - 3 * period_s


class _FrameClock:
    """The time of each decoded frame (see the module's docstring): the k-th smallest packet time,
    or the previous time plus one frame period where that would not move forward or is missing."""

    def __init__(self, packet_times_s: list[float], rate_hz: float | None) -> None:
        self.packet_times_s = packet_times_s
        self.period_s = 1.0 / (rate_hz or FALLBACK_RATE_HZ)
        self.rate_declared = rate_hz is not None
        self.t_last: float | None = None
        self.reordered = self.repeated = self.missing = 0
        self.first_reordered: tuple[int, float, float] | None = None  # frame, its own stamp, the time given

    def time_s(self, k: int, own_s: float | None) -> float:
        """Frame ``k``'s time (seconds, the stream's clock); ``own_s`` is the frame's own time stamp."""
        t = self.packet_times_s[k] if k < len(self.packet_times_s) else own_s
        if t is None:
            self.missing += 1
            t = 0.0 if self.t_last is None else self.t_last + self.period_s
        elif self.t_last is not None and t <= self.t_last:
            self.repeated += 1
            t = self.t_last + self.period_s
        elif own_s is not None and abs(own_s - t) > 1e-9:
            self.reordered += 1
            if self.first_reordered is None:
                self.first_reordered = (k, own_s, t)
        self.t_last = t
        return t

    def notes(self, where: str) -> list[str]:
        """One line per kind of repair made, for the run's warnings."""
        rate = (
            f"the stream's frame rate ({1.0 / self.period_s:g} Hz)"
            if self.rate_declared
            else f"{FALLBACK_RATE_HZ:g} frames per second (the stream declares no rate)"
        )
        out = []
        if self.reordered:
            k, own, t = self.first_reordered  # type: ignore[misc]
            out.append(
                f"{where}: {self.reordered} frames carry time stamps out of order in the container (frame {k} "
                f"says {own:g} s, its place in the stream {t:g} s); every frame is kept in the decoder's order, "
                "timed by the container's time stamps sorted, as video players show it."
            )
        if self.repeated:
            out.append(
                f"{where}: {self.repeated} frames repeat or go back on the previous frame's time stamp; "
                f"they are kept, timed one period of {rate} after the frame before."
            )
        if self.missing:
            out.append(f"{where}: {self.missing} frames have no time stamp; they are timed by {rate}.")
        return out


def _declared_rate_hz(stream: Any) -> float | None:
    """The frame rate a video stream declares (average, else guessed), None when it declares none."""
    for rate in (stream.average_rate, stream.guessed_rate):
        if rate and float(rate) > 0:
            return float(rate)
    return None


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
