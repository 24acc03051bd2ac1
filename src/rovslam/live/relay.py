"""A video stream's arrival times taken at the socket: a UDP relay in front of FFmpeg.

FFmpeg hands a network video's frame out some time after its data came: when the demuxer knows
the frame ended (the next frame's first bytes, or the PES length when the sender writes it) and
after its H.264 parser's own wait. How long depends on the sender, so an arrival time taken
where the packet leaves FFmpeg is off by a frame period or two. :class:`UdpRelay` receives the
stream on the address the user gave, notes when each frame's first datagram came (by the PTS of
its MPEG-TS PES header), and forwards every datagram unchanged to FFmpeg on a loopback port.

Only MPEG-TS over unicast UDP is relayed (``udp://HOST:PORT``); other streams keep FFmpeg's
own times (see :data:`rovslam.live.stream.HELD_FRAMES`).
"""

from __future__ import annotations

import ipaddress
import socket
import threading
import time
from collections import OrderedDict
from urllib.parse import urlsplit

from rovslam.errors import SequenceFormatError

PTS_MODULO = 1 << 33  # MPEG-TS time stamps have 33 bits (90 kHz)
TS_PACKET_BYTES = 188
KEEP_FRAMES = 512  # arrival times kept for frames FFmpeg has not handed out yet
RECEIVE_BUFFER_BYTES = 4 << 20


def pes_pts(datagram: bytes) -> list[int]:
    """The PTS (90 kHz ticks, 33 bits) of every video PES packet that starts in ``datagram`` (MPEG-TS)."""
    found = []
    d = datagram
    for off in range(0, len(d) - TS_PACKET_BYTES + 1, TS_PACKET_BYTES):
        if d[off] != 0x47 or not d[off + 1] & 0x40:  # no sync byte, or no payload unit starts here
            continue
        control = (d[off + 3] >> 4) & 3
        p = off + 4
        if control & 2:  # an adaptation field first
            p += 1 + d[p]
        if not control & 1 or p + 14 > off + TS_PACKET_BYTES:
            continue
        if d[p : p + 3] != b"\x00\x00\x01" or not 0xE0 <= d[p + 3] <= 0xEF or not d[p + 7] & 0x80:
            continue  # not a video PES header, or no PTS in it
        q = p + 9
        found.append(((d[q] >> 1) & 7) << 30 | d[q + 1] << 22 | (d[q + 2] >> 1) << 15 | d[q + 3] << 7 | d[q + 4] >> 1)
    return found


def relay_address(url: str) -> tuple[str, int] | None:
    """(host, port) to receive ``url`` on when it is MPEG-TS over unicast UDP; None for anything else."""
    if not url.lower().startswith("udp://"):
        return None
    try:
        parts = urlsplit(url)
        port = parts.port
        host = parts.hostname or "0.0.0.0"
        address = ipaddress.ip_address(host)
    except ValueError:
        return None
    if port is None or address.version != 4 or address.is_multicast:
        return None
    return str(address), int(port)


class UdpRelay:
    """Receives on ``(host, port)``, stamps each frame's first datagram, forwards to ``127.0.0.1:forward_port``.

    Raises:
        SequenceFormatError: the address cannot be listened on (in use, or not this machine's).
    """

    def __init__(self, host: str, port: int) -> None:
        self._in = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._in.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
            self._in.bind((host, port))
        except OSError as exc:
            self._in.close()
            raise SequenceFormatError(
                f"udp://{host}:{port}: cannot listen for the video there ({exc.strerror or exc}); "
                "is another program receiving it? Give a free port or stop the other receiver."
            ) from None
        self._in.settimeout(0.1)
        self._out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        self.forward_port = int(probe.getsockname()[1])
        probe.close()
        self._arrivals: OrderedDict[int, float] = OrderedDict()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.datagrams = 0
        self._thread = threading.Thread(target=self._run, name="rovslam-relay", daemon=True)

    @property
    def url(self) -> str:
        """Where FFmpeg reads the relayed stream."""
        return f"udp://127.0.0.1:{self.forward_port}"

    def start(self) -> UdpRelay:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self._in.close()
        self._out.close()

    def arrival_s(self, pts: int) -> float | None:
        """When the first datagram of the frame with this PTS (90 kHz ticks) came (monotonic clock); None: unknown."""
        with self._lock:
            return self._arrivals.get(int(pts) % PTS_MODULO)

    def _run(self) -> None:
        target = ("127.0.0.1", self.forward_port)
        while not self._stop.is_set():
            try:
                data = self._in.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            now = time.monotonic()
            found = pes_pts(data)
            if found:
                with self._lock:
                    for pts in found:
                        self._arrivals.setdefault(pts, now)
                    while len(self._arrivals) > KEEP_FRAMES:
                        self._arrivals.popitem(last=False)
            self.datagrams += 1
            try:
                self._out.sendto(data, target)
            except OSError:  # FFmpeg not listening yet: the datagram is lost, as it would have been
                pass
