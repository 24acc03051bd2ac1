"""A live video source over PyAV: a decoder thread that keeps only the newest frame.

What ``--video`` accepts (:func:`resolve_video`): ``udp://HOST:PORT`` (MPEG-TS, H.264 or H.265),
an ``.sdp`` file (RTP, as BlueOS streams on UDP port 5600), ``rtp://HOST:PORT`` (an SDP for
H.264 payload 96 is written and opened), ``rtsp://...``, a V4L2 device (``/dev/video0``) and a
video file (played as fast as it decodes, or at its own rate with ``realtime``).

A frame's time ``t_s`` is its presentation time in the stream, in seconds from the first frame.
When the presentation times jump back (the sender restarted), the times go on from the last one
by the wall-clock time between the two frames, so that ``t_s`` always increases.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import SequenceFormatError

BLIND_S = 0.5  # no new frame for this long: the video is blind (no position is sent)
# Where a stream is not stamped at the socket (see rovslam.live.relay): FFmpeg hands a frame out this many frame
# periods after its data came. MPEG-TS read without the parser: when the next frame's first bytes come (none
# when the sender writes the PES length); RTP: the parser's wait for the next frame. Measured on loopback.
HELD_FRAMES = {"mpegts": 1, "rtp": 1}
READ_TIMEOUT_S = 3.0  # a stream silent this long is opened again (its frames up to the next key frame are lost)
SETTLE_FRAMES = 3  # a file's or a device's clock is taken once this many frames were decoded
PACKETS_AHEAD = 256  # compressed packets read ahead of the decoder (a few MB)


def network_arrival(source: VideoInput) -> bool:
    """Whether a frame's arrival is its packet's (a network stream) or the time it was decoded (a file, a device)."""
    return not source.is_file and source.format != "v4l2"


MPEGTS_NO_PARSER = {"fflags": "+noparse+nofillin", "probesize": "4096", "analyzeduration": "0"}
NETWORK_SCHEMES = ("udp://", "rtp://", "rtsp://", "rtsps://", "tcp://", "srt://", "http://", "https://")
SDP_TEXT = """v=0
o=- 0 0 IN IP4 {host}
s=rovslam live
c=IN IP4 {host}
t=0 0
m=video {port} RTP/AVP 96
a=rtpmap:96 H264/90000
a=fmtp:96 packetization-mode=1
"""


@dataclass(frozen=True)
class VideoInput:
    """How to open one ``--video``: the URL FFmpeg opens, its format and options, and whether it is a file."""

    url: str
    format: str | None
    options: dict[str, str]
    is_file: bool
    given: str


def resolve_video(video: str, sdp_folder: Path | None = None) -> VideoInput:
    """The :class:`VideoInput` of a ``--video`` argument; ``rtp://`` writes ``sdp_folder/stream.sdp``.

    Raises:
        SequenceFormatError: a path that does not exist and is no URL.
    """
    low = video.lower()
    low_latency = {"probesize": "262144", "analyzeduration": "200000"}  # a short probe; "nobuffer" loses frames
    if low.startswith("rtp://"):
        host, _, port = video[6:].partition(":")
        port = port.split("?")[0].split("/")[0]
        if not port.isdigit():
            raise SequenceFormatError(f"{video}: an RTP stream is rtp://HOST:PORT (BlueOS: rtp://0.0.0.0:5600).")
        folder = sdp_folder or Path(".")
        folder.mkdir(parents=True, exist_ok=True)
        sdp = folder / "stream.sdp"
        sdp.write_text(SDP_TEXT.format(host=host or "0.0.0.0", port=port), encoding="utf-8")
        return VideoInput(str(sdp), "sdp", {"protocol_whitelist": "file,udp,rtp", **low_latency}, False, video)
    if low.endswith(".sdp"):
        if not Path(video).is_file():
            raise SequenceFormatError(f"{video}: SDP file not found.")
        return VideoInput(video, "sdp", {"protocol_whitelist": "file,udp,rtp", **low_latency}, False, video)
    if low.startswith("udp://"):
        # MPEG-TS: each PES packet is one frame as encoders and muxers write it, so FFmpeg's parser (which holds
        # every frame until the next one begins: a frame period) is left out, and the probe kept short.
        return VideoInput(video, None, {"overrun_nonfatal": "1", **MPEGTS_NO_PARSER}, False, video)
    if low.startswith(("rtsp://", "rtsps://")):
        return VideoInput(video, None, {"rtsp_transport": "tcp", **low_latency}, False, video)
    if low.startswith(NETWORK_SCHEMES):
        return VideoInput(video, None, dict(low_latency), False, video)
    if low.startswith("/dev/video"):
        return VideoInput(video, "v4l2", {}, False, video)
    if not Path(video).is_file():
        raise SequenceFormatError(
            f"{video}: not found. --video takes udp://HOST:PORT (MPEG-TS), an .sdp file or rtp://HOST:PORT (RTP, "
            "BlueOS: port 5600), rtsp://..., /dev/videoN or a video file."
        )
    return VideoInput(video, None, {}, True, video)


@dataclass(frozen=True)
class StreamFrame:
    """One decoded frame: ``image`` ``(H, W, 3) uint8`` RGB, ``t_s`` stream time, ``arrival_s`` monotonic clock."""

    number: int  # frames received before this one
    t_s: float
    image: np.ndarray
    arrival_s: float  # when its data arrived (a network stream: its packet; a file: when decoded)
    delivered_s: float = 0.0  # when the decoder thread handed it over (monotonic)
    pts_s: float | None = None  # its presentation time as sent (on the axis of VideoStream.floor_s)


class _StreamClock:
    """Turns presentation times into ``t_s`` from the first frame, always increasing."""

    def __init__(self) -> None:
        self.base: float | None = None
        self.offset_s = 0.0
        self.last_t_s: float | None = None
        self.last_arrival_s = 0.0

    def t_s(self, pts_s: float | None, arrival_s: float) -> float | None:
        """The frame's ``t_s``; None for a frame to leave out (no time and no previous frame)."""
        if pts_s is None or not math.isfinite(pts_s):
            if self.last_t_s is None:
                return None
            t = self.last_t_s + max(arrival_s - self.last_arrival_s, 1e-3)
        else:
            if self.base is None:
                self.base = pts_s
            t = pts_s - self.base + self.offset_s
            if self.last_t_s is not None and t <= self.last_t_s:  # the sender restarted: go on from the wall clock
                t_new = self.last_t_s + max(arrival_s - self.last_arrival_s, 1e-3)
                self.offset_s += t_new - t
                t = t_new
        self.last_t_s, self.last_arrival_s = t, arrival_s
        return t


class VideoStream:
    """The decoder thread and its one-frame slot (or, with ``every_frame``, a short blocking queue).

    ``received``: frames decoded; ``dropped``: frames replaced by a newer one before the loop took
    them; ``gaps``: gaps in the camera's frames (stream time) longer than :data:`BLIND_S`. Without
    ``every_frame`` nothing ever queues: the loop always gets the newest frame.
    """

    def __init__(
        self,
        source: VideoInput,
        width_px: int,
        height_px: int,
        *,
        every_frame: bool = False,
        realtime: bool = False,
        wait_s: float = 30.0,
        read_timeout_s: float = READ_TIMEOUT_S,
    ) -> None:
        self.source = source
        self.size_px = (int(width_px), int(height_px))
        self.every_frame = every_frame
        self.realtime = realtime
        self.wait_s = float(wait_s)
        self.read_timeout_s = float(read_timeout_s)
        self.received = 0
        self.dropped = 0
        self.taken = 0
        self.gaps: list[dict[str, float]] = []
        self.error: str | None = None
        self.ended = False
        self.opened_s: float | None = None
        self._slot: deque[StreamFrame] = deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._clock = _StreamClock()
        self._last_arrival_s: float | None = None
        self._prev_t_s = 0.0
        self.floor_s: float | None = None  # smallest arrival - pts seen (the local clock at pts 0, delay's floor)
        self._floor_pts_s: float | None = None
        self.settled = threading.Event()  # set once frames arrive at the stream's pace (past the probe's burst)
        self._thread = threading.Thread(target=self._run, name="rovslam-video", daemon=True)
        self._started_s = 0.0
        self.relay: Any = None  # a UdpRelay: arrival times taken at the socket (MPEG-TS over unicast UDP)
        self._url = source.url

    def start(self) -> VideoStream:
        """Start listening (and decoding).

        Raises:
            SequenceFormatError: a UDP address that cannot be listened on.
        """
        from rovslam.live.relay import UdpRelay, relay_address

        address = relay_address(self.source.url)
        if address is not None:
            self.relay = UdpRelay(*address).start()
            self._url = self.relay.url
        self._started_s = time.monotonic()
        self._thread.start()
        return self

    def close(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            with self._cond:
                self._cond.notify_all()
            self._thread.join(timeout_s)
        if self.relay is not None:
            self.relay.close()

    def __enter__(self) -> VideoStream:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ the consumer side

    def first_frame(self, timeout_s: float | None = None) -> StreamFrame:
        """Wait for the first frame (at most ``wait_s``) and check its size; does not take it.

        Raises:
            SequenceFormatError: the stream never started, could not be opened, or its frames are
                not the camera file's size.
        """
        deadline = time.monotonic() + (self.wait_s if timeout_s is None else timeout_s) + 1.0
        with self._cond:
            while not self._slot and self.error is None and not self.ended and time.monotonic() < deadline:
                self._cond.wait(0.1)
            if self._slot:
                frame = self._slot[0]
                h, w = frame.image.shape[:2]
                if (w, h) != self.size_px:
                    raise SequenceFormatError(
                        f"{self.source.given}: the stream's frames are {w}x{h} px but the camera file says "
                        f"{self.size_px[0]}x{self.size_px[1]}; give the camera file of this camera (--camera)."
                    )
                return frame
        if self.error is not None:
            raise SequenceFormatError(self.error)
        if self.ended:
            raise SequenceFormatError(f"{self.source.given}: the video holds no frame.")
        raise SequenceFormatError(self._no_video())

    def _no_video(self) -> str:
        return (
            f"{self.source.given}: no video after {self.wait_s:g} s; check that the camera streams to this address "
            "(BlueOS: RTP on udp port 5600) or give a longer --wait-s."
        )

    def take(self, timeout_s: float) -> StreamFrame | None:
        """The newest frame not yet taken, waiting at most ``timeout_s``; None if none came (or the stream ended)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._slot:
                left = deadline - time.monotonic()
                if left <= 0 or self.ended or self.error is not None:
                    return None
                self._cond.wait(left)
            frame = self._slot.popleft()
            self.taken += 1
            self._cond.notify_all()
            return frame

    @property
    def finished(self) -> bool:
        """The stream ended (a file's end, or an error) and every frame kept was taken."""
        with self._cond:
            return (self.ended or self.error is not None) and not self._slot

    # ------------------------------------------------------------------ the decoder thread

    def _publish(self, frame: StreamFrame) -> None:
        with self._cond:
            if self.every_frame:
                while len(self._slot) >= 2 and not self._stop.is_set():
                    self._cond.wait(0.1)
            elif self._slot:
                self._slot.clear()
                self.dropped += 1
            self._slot.append(frame)
            self._cond.notify_all()

    def _run(self) -> None:
        import av

        first_open = True
        while not self._stop.is_set():
            try:
                opened = av.open(
                    self._url,
                    format=self.source.format,
                    options=dict(self.source.options),
                    timeout=(min(self.wait_s, 5.0) if first_open else self.read_timeout_s, self.read_timeout_s),
                )
            except (av.error.ExitError, TimeoutError):  # nothing yet: keep waiting (first_frame says when to give up)
                continue
            except (av.error.FFmpegError, OSError, ValueError) as exc:
                self._fail(f"{self.source.given}: cannot open the video ({exc}).")
                return
            first_open = False
            if self.opened_s is None:
                self.opened_s = time.monotonic()
            try:
                with opened as container:
                    if not container.streams.video:
                        self._fail(f"{self.source.given}: has no video stream.")
                        return
                    ended = self._decode(container, av)
            except (av.error.ExitError, TimeoutError):
                ended = False  # the stream paused longer than read_timeout_s: open it again
            except (av.error.FFmpegError, OSError, EOFError) as exc:
                if self.source.is_file:
                    self._fail(f"{self.source.given}: the video could not be read ({exc}).")
                    return
                ended = False
            if ended and (self.source.is_file or self.source.format == "v4l2"):
                self._end()
                return
            if self._stop.wait(0.05):
                break
        self._end()

    def _decode(self, container: Any, av: Any) -> bool:
        """Decode until the end of the container (True) or a stop (False).

        Packets are read by a thread of their own (:meth:`_read`), never held up by the decoder or
        the loop, so that their arrival times (and :attr:`floor_s`) stay true while frames wait.
        """
        stream = container.streams.video[0]
        network = network_arrival(self.source)
        arrivals: dict[int, float] = {}  # packet pts -> when its data arrived
        wall0: float | None = None
        packets: queue.Queue = queue.Queue(maxsize=PACKETS_AHEAD)
        done = threading.Event()
        reader = threading.Thread(
            target=self._read, args=(container, stream, packets, done), daemon=True, name="rovslam-demux"
        )
        reader.start()
        try:
            while True:
                if self._stop.is_set():
                    return False
                try:
                    item = packets.get(timeout=0.1)
                except queue.Empty:
                    continue
                if item is None:
                    return True
                if isinstance(item, BaseException):
                    if isinstance(item, (av.error.ExitError, TimeoutError)):  # paused: the frames the decoder holds
                        for vf in self._flush(stream, av):
                            self._frame(vf, arrivals.pop(vf.pts, None))
                    raise item
                packet, arrival = item
                if network and packet.pts is not None:
                    if len(arrivals) > 64:  # packets that never became frames
                        arrivals.clear()
                    arrivals[packet.pts] = arrival
                try:
                    decoded = packet.decode()
                except av.error.FFmpegError:
                    continue  # a damaged packet (lost UDP datagrams): the decoder recovers at the next key frame
                for vf in decoded:
                    pts_s = float(vf.time) if vf.time is not None else None
                    if self.realtime and pts_s is not None:
                        wall0 = time.monotonic() - pts_s if wall0 is None else wall0
                        delay = wall0 + pts_s - time.monotonic()
                        if delay > 0 and self._stop.wait(delay):
                            return False
                    self._frame(vf, arrivals.pop(vf.pts, None) if network else None)
        finally:
            done.set()
            reader.join(2 * self.read_timeout_s + 1.0)

    def _read(self, container: Any, stream: Any, packets: queue.Queue, done: threading.Event) -> None:
        """The demuxer's thread: each packet with the time its data arrived (network streams), then None or the error.

        A relayed stream's frame arrived when its first datagram did (:mod:`rovslam.live.relay`); any other
        network stream's, :data:`HELD_FRAMES` frame intervals before FFmpeg hands its packet out. The latency
        measured from there includes FFmpeg's wait.
        """
        network = network_arrival(self.source)
        held = HELD_FRAMES["mpegts"] if "mpegts" in container.format.name else HELD_FRAMES["rtp"]
        intervals: deque[float] = deque(maxlen=15)  # the last pts intervals (s)
        prev: tuple[float, float] | None = None  # (pts_s, demux time) of the previous packet
        item: Any = None
        try:
            for packet in container.demux(stream):
                if packet.pts is None or packet.size == 0:
                    continue
                now = time.monotonic()
                pts_s = float(packet.pts * packet.time_base)
                if prev is not None and pts_s > prev[0]:
                    intervals.append(pts_s - prev[0])
                    if network and now - prev[1] >= 0.5 * (pts_s - prev[0]):
                        self.settled.set()  # a packet that came at the stream's pace: past the probe's burst
                stamped = self.relay.arrival_s(packet.pts) if self.relay is not None else None
                if stamped is not None:
                    arrival = stamped  # its first datagram's arrival, taken at the socket
                else:
                    arrival = now - (held * float(np.median(intervals)) if intervals and network else 0.0)
                if network:
                    self._floor(arrival, pts_s)
                prev = (pts_s, now)
                if not self._put(packets, (packet, arrival), done):
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the decoding thread, which raises it
            item = exc
        self._put(packets, item, done)

    def _put(self, packets: queue.Queue, item: Any, done: threading.Event) -> bool:
        while not done.is_set() and not self._stop.is_set():
            try:
                packets.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _floor(self, arrival_s: float, pts_s: float) -> None:
        """Keep :attr:`floor_s`, the smallest ``arrival - pts`` (a sender whose times went back starts it again)."""
        with self._cond:
            if self._floor_pts_s is not None and pts_s < self._floor_pts_s - 1.0:
                self.floor_s = None
            self._floor_pts_s = pts_s
            d = arrival_s - pts_s
            self.floor_s = d if self.floor_s is None else min(self.floor_s, d)

    @staticmethod
    def _flush(stream: Any, av: Any) -> list:
        try:
            return list(stream.codec_context.decode(None))
        except (av.error.FFmpegError, EOFError, ValueError):
            return []

    def _frame(self, vf: Any, arrival_s: float | None) -> None:
        pts_s = float(vf.time) if vf.time is not None else None
        arrival = time.monotonic() if arrival_s is None else arrival_s
        t_s = self._clock.t_s(pts_s, arrival)
        if t_s is None:
            return
        if arrival_s is None and pts_s is not None:  # a file or a device: when decoded (after --realtime's wait)
            self._floor(arrival, pts_s)
            if self.received >= SETTLE_FRAMES - 1:
                self.settled.set()
        image = vf.to_ndarray(format="rgb24")
        if self._last_arrival_s is not None and t_s - self._prev_t_s > BLIND_S:  # a gap in the camera's frames
            self.gaps.append(
                {"t_s": t_s, "stream_gap_s": t_s - self._prev_t_s, "wall_gap_s": arrival - self._last_arrival_s}
            )
        self._prev_t_s = t_s
        self._last_arrival_s = arrival
        self._publish(StreamFrame(self.received, t_s, image, arrival, time.monotonic(), pts_s))
        self.received += 1

    def _fail(self, message: str) -> None:
        self.settled.set()
        with self._cond:
            self.error = message
            self._cond.notify_all()

    def _end(self) -> None:
        self.settled.set()
        with self._cond:
            self.ended = True
            self._cond.notify_all()

    def summary(self) -> dict[str, Any]:
        return {"frames_received": self.received, "frames_dropped": self.dropped, "video_gaps": list(self.gaps)}
