"""Loopback peers of a simulated vehicle for the sitl tests: a MAVLink companion and a video receiver.

Both run in threads, stop by themselves (a deadline, or a frame count), and keep what they got.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from pathlib import Path

import numpy as np


def free_udp_port() -> int:
    """A UDP port of 127.0.0.1 free now (the OS's choice)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _udp_bound(port: int) -> bool:
    """Whether a UDP socket is bound to ``port``, read from the kernel's table (Linux), without binding it.

    Probing by binding the port ourselves would hold it for an instant: a receiver binding at that
    instant fails ("address already in use") and never binds (a loopback test then waited 120 s).
    Elsewhere than Linux, that probe is the fallback.
    """
    tables = [Path("/proc/net/udp"), Path("/proc/net/udp6")]
    if any(t.exists() for t in tables):
        for table in tables:
            try:
                rows = table.read_text().splitlines()[1:]
            except OSError:
                continue
            if any(int(row.split()[1].rsplit(":", 1)[1], 16) == port for row in rows if len(row.split()) > 1):
                return True
        return False
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def wait_udp_bound(port: int, deadline_s: float = 120.0) -> bool:
    """Wait until something (a receiver) has bound UDP ``127.0.0.1:port``: then a datagram sent there is kept."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if _udp_bound(port):
            return True
        time.sleep(0.02)
    return False


def mavutil():
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil as mu

    if mu.mavlink.WIRE_PROTOCOL_VERSION != "2.0":
        os.environ["MAVLINK20"] = "1"
        mu.set_dialect("ardupilotmega")
    return mu


class VideoReader(threading.Thread):
    """Receive a stream with PyAV until ``n_frames`` frames, ``deadline_s``, or 10 s without data (then
    :attr:`error` holds the timeout): keeps (pts seconds, image)."""

    def __init__(
        self,
        url: str,
        n_frames: int,
        deadline_s: float = 120.0,
        fmt: str | None = "mpegts",
        options: dict | None = None,
    ):
        super().__init__(daemon=True)
        # A small probe: the stream's first key frame tells its size (FFmpeg's default probe waits for 5 s of
        # stream; "fflags": "nobuffer" would drop the packets read while probing, the first frames). No parser:
        # sitl sends a frame as one PES of known length, which the demuxer hands on whole when it is complete
        # (FFmpeg's H.264 parser would hold each frame until the next one starts).
        self.options = (
            {"probesize": "4096", "analyzeduration": "0", "fflags": "+noparse+nofillin"} if options is None else options
        )
        self.url, self.n_frames, self.fmt = url, n_frames, fmt
        self.deadline = time.monotonic() + deadline_s
        self.frames: list[tuple[float | None, np.ndarray]] = []
        self.error: BaseException | None = None
        self.opened = threading.Event()

    def run(self) -> None:
        import av

        try:
            left = max(1.0, self.deadline - time.monotonic())
            container = av.open(self.url, "r", format=self.fmt, options=self.options, timeout=(left, 10.0))
            self.opened.set()
            stream = container.streams.video[0]
            stream.codec_context.thread_count = 1  # no frame-threading delay: each frame out as it comes in
            try:
                for frame in container.decode(stream):
                    t = None if frame.pts is None else float(frame.pts * frame.time_base)
                    self.frames.append((t, frame.to_ndarray(format="rgb24")))
                    if len(self.frames) >= self.n_frames or time.monotonic() > self.deadline:
                        break
            finally:
                container.close()
        except BaseException as exc:  # reported by the test
            self.error = exc
        finally:
            self.opened.set()


class MavlinkPeer(threading.Thread):
    """A companion computer on ``udpin:127.0.0.1:PORT`` (system 1, component 197): records what the vehicle
    sends; on its first HEARTBEAT calls ``on_first_heartbeat(peer)`` (to send messages back)."""

    def __init__(self, port: int, deadline_s: float = 120.0, on_first_heartbeat=None):
        super().__init__(daemon=True)
        mu = mavutil()
        self.conn = mu.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=197)
        self.deadline = time.monotonic() + deadline_s
        self.messages: list = []
        self.stop_flag = threading.Event()
        self.on_first_heartbeat = on_first_heartbeat
        self.error: BaseException | None = None

    def of(self, name: str) -> list:
        return [m for m in list(self.messages) if m.get_type() == name]

    def vehicle_address(self):
        return next(iter(self.conn.clients))

    def run(self) -> None:
        try:
            while not self.stop_flag.is_set() and time.monotonic() < self.deadline:
                m = self.conn.recv_match(blocking=True, timeout=0.1)
                if m is None:
                    continue
                first = m.get_type() == "HEARTBEAT" and not self.of("HEARTBEAT")
                self.messages.append(m)
                if first and self.on_first_heartbeat is not None:
                    self.on_first_heartbeat(self)
        except BaseException as exc:
            self.error = exc

    def close(self) -> None:
        self.stop_flag.set()
        self.join(5.0)
        self.conn.close()
