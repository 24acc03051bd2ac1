"""rovslam live, the video side: the decoder thread on a PyAV-written MPEG-TS file and on UDP (loopback)."""

from __future__ import annotations

import csv
import time

import pytest
from live_peer import free_udp_port, make_dive, stream_udp

from rovslam.errors import SequenceFormatError
from rovslam.live.stream import VideoStream, resolve_video

W, H = 360, 272


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    root = tmp_path_factory.getbasetemp() / "live_dive"
    root.mkdir(exist_ok=True)
    return make_dive(root)


def frame_times(seq) -> list[float]:
    with (seq / "frames.csv").open(encoding="utf-8") as fh:
        return [float(r["t_s"]) for r in csv.DictReader(fh)]


def take_all(stream: VideoStream, limit_s: float = 60.0, pause_s: float = 0.0, check_slot: bool = False) -> list:
    got, deadline = [], time.monotonic() + limit_s
    while time.monotonic() < deadline and not stream.finished:
        if check_slot:
            assert len(stream._slot) <= 1  # never a queue: one frame, the newest
        f = stream.take(0.2)
        if f is not None:
            got.append(f)
            if pause_s:
                time.sleep(pause_s)
    return got


def test_file_every_frame_gives_each_frame_at_its_presentation_time(dive):
    seq, video, _ = dive
    with VideoStream(resolve_video(str(video)), W, H, every_frame=True, wait_s=10) as s:
        first = s.first_frame()
        assert first.image.shape == (H, W, 3)
        got = take_all(s)
    truth = frame_times(seq)
    assert len(got) == len(truth) == s.received and s.dropped == 0
    t0 = truth[0]
    assert max(abs(f.t_s - (t - t0)) for f, t in zip(got, truth)) < 1e-3  # pts in ms, from the first frame


def test_a_slow_loop_gets_the_newest_frame_and_the_others_are_counted_as_dropped(dive):
    seq, video, _ = dive
    with VideoStream(resolve_video(str(video)), W, H, realtime=True, wait_s=10) as s:
        s.first_frame()
        got = take_all(s, pause_s=0.35, check_slot=True)  # a loop slower than the 10 Hz frames
    assert s.received == len(frame_times(seq))
    assert s.dropped >= 10 and len(got) + s.dropped == s.received
    assert all(b.t_s > a.t_s for a, b in zip(got, got[1:]))
    assert [f.number for f in got] == sorted({f.number for f in got})


def test_udp_mpegts_stream_that_starts_after_the_reader(dive):
    seq, _, _ = dive
    port = free_udp_port()
    with VideoStream(resolve_video(f"udp://127.0.0.1:{port}"), W, H, every_frame=True, wait_s=20) as s:
        sender = stream_udp(seq, port, start_delay_s=1.0)
        s.first_frame()
        got = []
        deadline = time.monotonic() + 60
        while len(got) < 40 and time.monotonic() < deadline:
            f = s.take(0.2)
            if f is not None:
                got.append(f)
        sender.join(30)
    truth = frame_times(seq)
    assert len(got) == len(truth)
    assert max(abs(f.t_s - (t - truth[0])) for f, t in zip(got, truth)) < 1e-3


def test_a_stream_that_never_starts_is_a_clear_error():
    port = free_udp_port()
    t0 = time.monotonic()
    with VideoStream(resolve_video(f"udp://127.0.0.1:{port}"), W, H, wait_s=1.5) as s:
        with pytest.raises(SequenceFormatError, match=r"no video after 1.5 s"):
            s.first_frame()
    assert time.monotonic() - t0 < 15


def test_frames_of_another_size_than_the_camera_file_are_refused(dive):
    _, video, _ = dive
    with VideoStream(resolve_video(str(video)), 320, 240, wait_s=10) as s:
        with pytest.raises(SequenceFormatError, match=r"360x272 px but the camera file says 320x240"):
            s.first_frame()


def test_a_file_that_is_not_a_video_is_a_clear_error(tmp_path):
    bad = tmp_path / "x.ts"
    bad.write_bytes(b"not a video at all" * 100)
    with VideoStream(resolve_video(str(bad)), W, H, wait_s=5) as s:
        with pytest.raises(SequenceFormatError, match="x.ts"):
            s.first_frame()
