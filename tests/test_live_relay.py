"""rovslam live: a UDP video's frames are stamped when their first datagram arrives, whatever the sender.

FFmpeg hands a frame out one or two frame periods after its data came, depending on how the
sender muxes (PES length written or not); the relay's time does not depend on it. On loopback.
"""

from __future__ import annotations

import fractions
import io
import statistics
import threading
import time

import numpy as np
import pytest
from live_peer import free_udp_port

from rovslam.errors import SequenceFormatError
from rovslam.live.relay import UdpRelay, pes_pts, relay_address
from rovslam.live.stream import VideoStream, resolve_video

W, H, FPS = 160, 120, 10


def images(n: int = 30) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    base = rng.integers(0, 255, size=(H + 40, W + 80, 3), dtype=np.uint8)
    return [np.ascontiguousarray(base[10:-30, 2 * k : 2 * k + W]) for k in range(n)]


def encode(container, frames: list[np.ndarray], sent: list[float] | None = None, pace_s: float = 0.0) -> None:
    import av

    stream = container.add_stream("libx264", rate=FPS)
    stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
    stream.options = {"crf": "20", "preset": "ultrafast", "tune": "zerolatency", "bf": "0", "g": "10"}
    tb = fractions.Fraction(1, 90000)
    stream.codec_context.time_base = tb
    start = time.monotonic()
    for k, img in enumerate(frames):
        if pace_s:
            time.sleep(max(0.0, start + k * pace_s - time.monotonic()))
        if sent is not None:
            sent.append(time.monotonic())
        frame = av.VideoFrame.from_ndarray(img, format="rgb24")
        frame.pts, frame.time_base = k * 9000, tb
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)


def test_the_pts_of_each_frame_is_read_from_the_datagrams_as_the_demuxer_reads_it():
    import av

    buf = io.BytesIO()
    with av.open(buf, "w", format="mpegts") as c:
        encode(c, images(12))
    data = buf.getvalue()
    found = [p for k in range(0, len(data), 1316) for p in pes_pts(data[k : k + 1316])]
    with av.open(io.BytesIO(data), "r", format="mpegts") as c:
        demuxed = [int(p.pts) for p in c.demux(c.streams.video[0]) if p.pts is not None and p.size]
    assert len(found) == 12 and found == demuxed


def test_only_mpegts_over_unicast_udp_is_relayed():
    assert relay_address("udp://127.0.0.1:5600") == ("127.0.0.1", 5600)
    assert relay_address("udp://0.0.0.0:5600?overrun_nonfatal=1") == ("0.0.0.0", 5600)
    assert relay_address("udp://:5600") == ("0.0.0.0", 5600)
    assert relay_address("udp://239.1.1.1:5600") is None  # multicast: FFmpeg joins the group itself
    assert relay_address("rtsp://10.0.0.2/stream") is None
    assert relay_address("/dev/video0") is None


def test_a_port_taken_by_another_receiver_is_a_clear_error():
    port = free_udp_port()
    first = UdpRelay("127.0.0.1", port)
    try:
        with pytest.raises(SequenceFormatError, match=rf"udp://127.0.0.1:{port}: cannot listen for the video there"):
            UdpRelay("127.0.0.1", port)
    finally:
        first.close()


@pytest.mark.parametrize("pes_length", [False, True], ids=["ffmpeg-default-muxer", "pes-length-written"])
def test_a_frame_arrives_when_its_first_datagram_does_whatever_the_muxer(pes_length):
    import av

    port = free_udp_port()
    sent: list[float] = []
    frames = images(30)
    options = {"flush_packets": "1", "omit_video_pes_length": "0"} if pes_length else {}

    def run() -> None:
        time.sleep(0.5)
        with av.open(f"udp://127.0.0.1:{port}?pkt_size=1316", "w", format="mpegts", options=options) as c:
            encode(c, frames, sent, pace_s=1.0 / FPS)

    sender = threading.Thread(target=run, daemon=True)
    with VideoStream(resolve_video(f"udp://127.0.0.1:{port}"), W, H, every_frame=True, wait_s=20) as s:
        sender.start()
        s.first_frame()
        got = []
        deadline = time.monotonic() + 30
        while len(got) < len(frames) - 1 and time.monotonic() < deadline:  # the last may wait for the stream's end
            f = s.take(0.2)
            if f is not None:
                got.append(f)
        sender.join(10)
    assert s.relay is not None and s.relay.datagrams > 0
    assert len(got) >= len(frames) - 2
    late_s = [f.arrival_s - sent[int(round(f.pts_s * FPS)) - int(round(got[0].pts_s * FPS))] for f in got]
    # A frame period is 100 ms: a stamp taken where FFmpeg hands the frame out is 100 to 200 ms late.
    assert 0.0 <= statistics.median(late_s) < 0.03
