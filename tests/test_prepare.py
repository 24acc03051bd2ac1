"""Frames prepared ahead of the loop on a second thread: the same results, the source's errors and
an early stop handled as without it (rovslam.pipeline.prepare)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import rovslam.pipeline.loop as loop
from rovslam.core import Frame
from rovslam.errors import SequenceFormatError
from rovslam.pipeline.prepare import AHEAD_FRAMES, prepared_frames
from rovslam.runner import run_sequence
from rovslam.sim import simulate


def _frames(n: int, fail_at: int | None = None, closed: list | None = None):
    try:
        for k in range(n):
            if k == fail_at:
                raise SequenceFormatError(f"frame {k}: cannot decode")
            yield Frame(index=k, t_s=0.1 * k, image=np.full((8, 8, 3), k, np.uint8), heading_rad=0.0)
    finally:
        if closed is not None:
            closed.append(True)


def test_frames_come_in_order_each_with_its_preparation():
    seen = []
    out = list(prepared_frames(_frames(20), lambda f: (seen.append(threading.current_thread().name), f.index)[1], True))
    assert [f.index for f, _ in out] == list(range(20))
    assert [p for _, p in out] == list(range(20))
    assert set(seen) == {"rovslam-prepare"}  # made on the other thread
    assert [p for _, p in prepared_frames(_frames(3), lambda f: 1 / 0, False)] == [None, None, None]  # not asked


def test_a_failed_preparation_leaves_the_frame_to_the_loop():
    def prepare(f):
        if f.index == 2:
            raise ValueError("bad image")
        return f.index

    out = list(prepared_frames(_frames(4), prepare, True))
    assert [(f.index, p) for f, p in out] == [(0, 0), (1, 1), (2, None), (3, 3)]


def test_the_sources_error_comes_after_the_frames_before_it():
    got = []
    with pytest.raises(SequenceFormatError, match="frame 5: cannot decode"):
        for f, _ in prepared_frames(_frames(10, fail_at=5), lambda f: None, True):
            got.append(f.index)
    assert got == [0, 1, 2, 3, 4]


def test_stopping_early_stops_the_thread_and_closes_the_source():
    closed: list = []
    before = {t.name for t in threading.enumerate()}
    gen = prepared_frames(_frames(1000, closed=closed), lambda f: None, True)
    assert next(gen)[0].index == 0
    gen.close()
    assert closed == [True]
    assert "rovslam-prepare" not in {t.name for t in threading.enumerate()} - before
    # it never read more than the frames it may hold ahead (and the one it was putting)
    closed2: list = []
    read: list = []
    gen2 = prepared_frames(_frames(1000, closed=closed2), lambda f: read.append(f.index), True)
    next(gen2)
    for _ in range(100):
        if len(read) >= AHEAD_FRAMES + 1:
            break
        threading.Event().wait(0.01)
    gen2.close()
    assert AHEAD_FRAMES <= len(read) <= AHEAD_FRAMES + 2 and closed2 == [True]


@pytest.fixture(scope="module")
def swell(tmp_path_factory):
    """The swell preset's first 12 s: the sunlight is taken out part of the way (both paths of the loop)."""
    root = tmp_path_factory.mktemp("ahead")
    simulate("swell", root / "seq", frames=120, seed=0)
    return root


def counting_tracking_images(monkeypatch) -> list:
    """The loop's tracking images counted: the list returned grows by one at each it makes."""
    made_in_loop: list = []
    original = loop.tracking_image

    def counted(*args, **kwargs):
        made_in_loop.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(loop, "tracking_image", counted)
    return made_in_loop


def test_read_ahead_gives_the_same_results_bit_for_bit(swell, monkeypatch):
    made_in_loop = counting_tracking_images(monkeypatch)
    run_sequence(swell / "seq", swell / "inline", read_ahead=False)
    inline_calls = len(made_in_loop)
    made_in_loop.clear()
    run_sequence(swell / "seq", swell / "ahead", read_ahead=True)
    # Without read-ahead the loop makes every tracking image (120), and again when the sunlight is taken
    # out or left in again; with it, only those where the sunlight changed between the preparation and
    # the loop (the preparation reads whether it is taken out a few frames ahead). Measured: 121 and 5.
    assert inline_calls > 120  # the sunlight was taken out
    assert len(made_in_loop) <= 0.2 * inline_calls
    for name in ("trajectory.csv", "landmarks.csv", "tokens.csv", "observations.csv", "landmark_measurements.csv"):
        assert (swell / "inline" / name).read_bytes() == (swell / "ahead" / name).read_bytes(), name


def test_a_video_read_ahead_gives_the_same_results(swell, tmp_path):
    """A video is decoded as it is read: read ahead, the decoding moves to the other thread too."""
    import av

    from rovslam.io.sequence import open_sequence
    from rovslam.io.source import InputOptions
    from rovslam.sim.sitl import write_camera_file

    seq = open_sequence(swell / "seq")
    video = tmp_path / "dive.mp4"
    with av.open(str(video), "w") as c:
        st = c.add_stream("libx264", rate=5)
        st.width, st.height, st.pix_fmt = seq.info.camera.width_px, seq.info.camera.height_px, "yuv420p"
        for f in seq.frames(stop=60, prefetch=0):
            for pkt in st.encode(av.VideoFrame.from_ndarray(f.image, format="rgb24")):
                c.mux(pkt)
        for pkt in st.encode():
            c.mux(pkt)
    camera = tmp_path / "camera.toml"
    write_camera_file(camera, seq.info)
    opts = InputOptions(camera_file=camera)
    seen = []
    for ahead in (False, True):
        s = run_sequence(video, tmp_path / f"out{ahead}", inputs=opts, read_ahead=ahead)
        seen.append(s.frames)
    assert seen == [60, 60]
    for name in ("trajectory.csv", "landmarks.csv", "measurements.csv", "landmark_measurements.csv"):
        assert (tmp_path / "outFalse" / name).read_bytes() == (tmp_path / "outTrue" / name).read_bytes(), name
