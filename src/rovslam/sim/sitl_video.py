"""The simulated vehicle's camera stream: H.264 in MPEG-TS over UDP, or H.264 over RTP with its SDP file.

BlueOS streams a BlueROV2's camera as H.264 over RTP on UDP port 5600; a receiver opens the
SDP file that describes it (PyAV / FFmpeg: ``av.open("stream.sdp", options={"protocol_whitelist":
"file,udp,rtp"})``). MPEG-TS over UDP is the other common form (``udp://HOST:PORT``). Either way
each frame's presentation time is its capture time on the stream's axis: seconds from the
first frame, in the 90 kHz time base of both formats.

Each frame leaves at once, whole: no B-frames or lookahead in the encoder, packets flushed as
they are written, and (MPEG-TS) each frame one PES packet with its length written, so a demuxer
can hand it on when its last byte arrives. A receiver that wants every frame as soon as it is
complete opens the MPEG-TS stream with the options ``probesize=4096``, ``analyzeduration=0``
(FFmpeg's default probe waits for seconds of stream) and ``fflags=+noparse+nofillin`` (FFmpeg's
H.264 parser holds each frame until the next one starts: one frame period of latency, and the
last frame until the stream ends); ``fflags=nobuffer`` drops the frames read while probing.
Over RTP the first frame's presentation time is unknown (None); the others count from it.
"""

from __future__ import annotations

import ipaddress
import socket
from fractions import Fraction
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from rovslam.errors import SimulationError

__all__ = ["VideoOut", "parse_video_url", "sdp_text"]

TIME_BASE = Fraction(1, 90000)  # MPEG-TS and RTP video clocks
MPEGTS_PACKET_BYTES = 1316  # 7 transport packets: one UDP datagram under a 1500-byte MTU
RTP_PACKET_BYTES = 1200
# Each frame out at once: packets flushed as written, and the PES length written (a demuxer then
# hands a frame on when its last byte arrives, not when the next frame's first one does).
_MPEGTS_OPTIONS = {"flush_packets": "1", "omit_video_pes_length": "0"}
# A PES length has 16 bits: a frame of more than 64 KiB goes out with none, and waits in the demuxer
# for the next frame. The encoder's buffer (VBV) keeps every MPEG-TS frame below this many bytes.
MAX_FRAME_BYTES = 60_000


def parse_video_url(url: str, rtp: bool = False) -> tuple[str, str, int]:
    """(form, host, port) of ``--video``: form ``mpegts`` (``udp://HOST:PORT``) or ``rtp``
    (``udp://HOST:PORT`` with ``rtp``, or ``rtp://HOST:PORT``).

    Raises :class:`~rovslam.errors.SimulationError` naming what is wrong.
    """
    hint = "give udp://HOST:PORT (MPEG-TS; with --rtp: RTP, as BlueOS) or rtp://HOST:PORT, e.g. udp://127.0.0.1:5600"
    try:
        parts = urlsplit(str(url))
        port = parts.port
    except ValueError as exc:
        raise SimulationError(f"--video {url!r}: {exc}; {hint}") from None
    if parts.scheme not in ("udp", "rtp"):
        raise SimulationError(f"--video {url!r}: the scheme must be udp or rtp; {hint}")
    if not parts.hostname or port is None or not 0 < port < 65536:
        raise SimulationError(f"--video {url!r}: needs a host and a port (1 to 65535); {hint}")
    host = parts.hostname
    try:
        ipaddress.ip_address(host)
    except ValueError:
        try:
            socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except OSError:
            raise SimulationError(f"--video {url!r}: unknown host {host!r}; {hint}") from None
    return ("rtp" if rtp or parts.scheme == "rtp" else "mpegts"), host, int(port)


def sdp_text(host: str, port: int, name: str = "rovslam sitl") -> str:
    """The SDP of an H.264 RTP stream to ``host:port`` (payload type 96, 90 kHz clock)."""
    family = "IP6" if ":" in host else "IP4"
    return (f"v=0\no=- 0 0 IN {family} {host}\ns={name}\nc=IN {family} {host}\nt=0 0\n"
            f"m=video {port} RTP/AVP 96\na=rtpmap:96 H264/90000\na=fmtp:96 packetization-mode=1\n")


class VideoOut:
    """Encode ``(H, W, 3) uint8`` RGB frames with libx264 (ultrafast, zero latency) and send each at once.

    ``url`` as :func:`parse_video_url`; ``sdp_path``: where to write the SDP of an RTP stream.
    Packets go out as each frame is encoded (no B-frames, no lookahead); a key frame every
    ``keyframe_s`` seconds lets a receiver join at any time.
    """

    def __init__(self, url: str, width_px: int, height_px: int, frame_rate_hz: float, rtp: bool = False,
                 sdp_path: Path | None = None, crf: int = 20, keyframe_s: float = 1.0) -> None:
        import av

        form, host, port = parse_video_url(url, rtp)
        if width_px % 2 or height_px % 2:
            raise SimulationError(f"H.264 needs even image sizes, got {width_px}x{height_px}")
        self.form, self.host, self.port = form, host, port
        self.shape = (int(height_px), int(width_px), 3)
        target = f"[{host}]" if ":" in host else host
        self._out: Any = None
        try:
            if form == "rtp":
                self._out = av.open(f"rtp://{target}:{port}?pkt_size={RTP_PACKET_BYTES}", "w", format="rtp",
                                    options={"flush_packets": "1"})
            else:
                self._out = av.open(f"udp://{target}:{port}?pkt_size={MPEGTS_PACKET_BYTES}", "w", format="mpegts",
                                    options=_MPEGTS_OPTIONS)
        except av.error.FFmpegError as exc:
            raise SimulationError(f"--video {url}: cannot open the stream ({exc}); check the host and port") from None
        rate = Fraction(frame_rate_hz).limit_denominator(1000)
        st = self._stream = self._out.add_stream("libx264", rate=rate)
        st.width, st.height, st.pix_fmt = int(width_px), int(height_px), "yuv420p"
        st.codec_context.time_base = TIME_BASE
        st.codec_context.options = {
            "preset": "ultrafast", "tune": "zerolatency", "crf": str(int(crf)), "bf": "0", "threads": "1",
            "g": str(max(1, int(round(keyframe_s * frame_rate_hz)))),
        }
        if form == "mpegts":  # at most MAX_FRAME_BYTES a frame (quality drops only where a frame would be larger)
            bits = 8 * MAX_FRAME_BYTES
            st.codec_context.options = dict(st.codec_context.options, bufsize=str(bits),
                                            maxrate=str(int(bits * frame_rate_hz)))
        self.sdp_path = None
        if form == "rtp" and sdp_path is not None:
            self.sdp_path = Path(sdp_path)
            self.sdp_path.write_text(sdp_text(host, port), encoding="utf-8")
        self.frames = 0
        self.bytes = 0
        self._last_pts = -1

    def send(self, image_rgb: np.ndarray, t_s: float) -> None:
        """Encode and send one frame captured at ``t_s`` (seconds from the first frame; increasing)."""
        import av

        if image_rgb.shape != self.shape or image_rgb.dtype != np.uint8:
            raise SimulationError(f"video frame must be {self.shape} uint8, got {image_rgb.shape} {image_rgb.dtype}")
        pts = int(round(float(t_s) / TIME_BASE))
        if pts <= self._last_pts:
            raise SimulationError(f"frame time {t_s} s is not after the previous frame's; frame times must increase")
        self._last_pts = pts
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image_rgb), format="rgb24")
        frame.pts, frame.time_base = pts, TIME_BASE
        for packet in self._stream.encode(frame):
            self.bytes += packet.size
            self._mux(packet)
        self.frames += 1

    def _mux(self, packet) -> None:
        try:
            self._out.mux(packet)
        except OSError:  # nobody listening yet (an ICMP refusal): UDP drops it, as a camera's stream would be
            pass

    def close(self) -> None:
        """Flush the encoder and close the stream (idempotent)."""
        if self._out is None:
            return
        try:
            for packet in self._stream.encode(None):
                self._mux(packet)
        finally:
            try:
                self._out.close()
            except OSError:
                pass
            self._out = None
