"""A sequence folder read and prepared in a second process: the same results bit for bit, the frames
in order whatever happens to the process, nothing left behind (rovslam.pipeline.prepare_process)."""

from __future__ import annotations

import dataclasses
import os
import signal

import numpy as np
import pytest
from test_prepare import counting_tracking_images

import rovslam.pipeline.prepare_process as pp
from rovslam.config import RunConfig
from rovslam.errors import RovslamError
from rovslam.io.sequence import Sequence, open_sequence
from rovslam.pipeline import SlamPipeline
from rovslam.pipeline.prepare import FramePreparer
from rovslam.runner import run_sequence
from rovslam.sim import simulate


@pytest.fixture(scope="module")
def swell(tmp_path_factory):
    """The swell preset's first 12 s: the sunlight is taken out part of the way (both paths of the loop)."""
    root = tmp_path_factory.mktemp("process")
    simulate("swell", root / "seq", frames=120, seed=0)
    return root


@pytest.fixture
def workers(monkeypatch):
    """The processes started, as the test's list; the loop waits for each before its first frame."""
    started = []
    original = pp._Worker.start.__func__

    def start(cls, seq, preparer):
        worker = original(cls, seq, preparer)
        started.append(worker)
        return worker

    monkeypatch.setattr(pp._Worker, "start", classmethod(start))
    monkeypatch.setattr(pp, "START_INLINE", False)
    monkeypatch.setattr(pp, "MIN_FRAMES", 0)
    return started


@pytest.fixture
def shm(tmp_path, monkeypatch):
    """The folder the shared file is made in, this test's own: what is left in it is what a run left."""
    folder = tmp_path / "shm"
    folder.mkdir()
    monkeypatch.setattr(pp, "_shared_dir", lambda: str(folder))
    return folder


def _preparer(seq: Sequence) -> FramePreparer:
    return SlamPipeline(seq.info, RunConfig()).preparer()


def test_a_run_prepared_in_a_process_gives_the_same_results_bit_for_bit(swell, workers, monkeypatch):
    made_in_loop = counting_tracking_images(monkeypatch)
    run_sequence(swell / "seq", swell / "inline", read_ahead=False)
    inline_calls = len(made_in_loop)
    made_in_loop.clear()
    assert workers == []
    run_sequence(swell / "seq", swell / "ahead", read_ahead=True)
    assert len(workers) == 1 and workers[0] is not None and not workers[0].died
    # Without read-ahead the loop makes every tracking image (120) and again when the sunlight is taken
    # out or left in; prepared in the process, only those where the sunlight changed in between.
    assert inline_calls > 120
    assert len(made_in_loop) <= 0.2 * inline_calls
    for name in ("trajectory.csv", "landmarks.csv", "tokens.csv", "observations.csv", "landmark_measurements.csv"):
        assert (swell / "inline" / name).read_bytes() == (swell / "ahead" / name).read_bytes(), name


def test_what_the_process_prepares_is_what_the_loop_would_make(swell, workers):
    seq = open_sequence(swell / "seq")
    here = _preparer(seq)
    out = list(pp.prepared_in_process(seq, 30, _preparer(seq)))
    assert [f.index for f, _ in out] == list(range(30))
    direct = list(seq.frames(stop=30, prefetch=0))
    assert all(p is not None for _, p in out)  # every frame came from the process (it was waited for)
    for (frame, prepared), mine in zip(out, direct):
        assert np.array_equal(frame.image, mine.image)
        assert dataclasses.replace(frame, image=None) == dataclasses.replace(mine, image=None)
        expected = here(mine)
        assert prepared.image is frame.image
        for key in ("track_img", "bright", "variance", "small"):
            a, b = getattr(prepared, key), getattr(expected, key)
            assert a.dtype == b.dtype and np.array_equal(a, b), key
        if frame.index >= 1:  # the previous frame's reduced image: the very object handed out before
            assert prepared.prev_small is out[frame.index - 1][1].small
            assert np.array_equal(prepared.prior[0], expected.prior[0]) and prepared.prior[1] == expected.prior[1]


def test_stopping_early_stops_the_process_and_leaves_no_file(swell, workers, shm):
    seq = open_sequence(swell / "seq")
    gen = pp.prepared_in_process(seq, None, _preparer(seq))
    assert [next(gen)[0].index for _ in range(5)] == [0, 1, 2, 3, 4]
    worker = workers[0]
    assert worker is not None and list(shm.iterdir()) == []  # shared while the process runs, yet no file
    gen.close()
    assert worker.proc.returncode == 0  # it stopped by itself, at once
    assert list(shm.iterdir()) == []


def test_a_process_that_dies_leaves_the_rest_of_the_folder_to_the_loop(swell, workers, shm):
    seq = open_sequence(swell / "seq")
    got = []
    for frame, _ in pp.prepared_in_process(seq, 40, _preparer(seq)):
        got.append(frame.index)
        if frame.index == 10:
            os.kill(workers[0].proc.pid, signal.SIGKILL)
    assert got == list(range(40))
    assert workers[0].died and list(shm.iterdir()) == []


def test_the_sources_error_comes_after_the_frames_before_it(swell, workers, shm):
    seq = open_sequence(swell / "seq")
    rows = list(seq.rows[:20])
    rows[12] = dataclasses.replace(rows[12], image=None)  # a row the folder cannot be read at: a TypeError
    broken = Sequence(seq.folder, seq.info, rows, None)
    got = []
    with pytest.raises(TypeError):
        for frame, _ in pp.prepared_in_process(broken, None, _preparer(seq)):
            got.append(frame.index)
    assert got == list(range(12))
    assert list(shm.iterdir()) == [] and workers[0].proc.returncode is not None


def test_an_error_that_cannot_cross_the_pipe_keeps_its_type_and_message():
    class Odd(Exception):
        def __init__(self, a, b):
            super().__init__(f"{a} and {b}")

    exc = pp._portable(Odd(1, 2))
    assert isinstance(exc, RovslamError) and str(exc) == "Odd: 1 and 2"
    same = pp._portable(ValueError("frame 3"))
    assert type(same) is ValueError and str(same) == "frame 3"


def test_short_runs_and_other_sources_keep_the_thread(swell, monkeypatch):
    started = []
    monkeypatch.setattr(pp._Worker, "start", classmethod(lambda cls, seq, prep: started.append(1)))
    run_sequence(swell / "seq", swell / "short", read_ahead=True, max_frames=20)
    assert started == []  # fewer frames than MIN_FRAMES
    monkeypatch.setattr(pp, "MIN_FRAMES", 10)
    run_sequence(swell / "seq", swell / "long", read_ahead=True, max_frames=20)
    assert started == [1]  # asked for (and, given None, read here: the same 20 frames)
    assert (swell / "long" / "trajectory.csv").read_bytes() == (swell / "short" / "trajectory.csv").read_bytes()


def test_without_room_for_the_shared_file_the_frames_are_prepared_on_a_thread(swell, workers, monkeypatch, tmp_path):
    monkeypatch.setattr(pp, "_shared_dir", lambda: str(tmp_path / "missing"))
    seq = open_sequence(swell / "seq")
    out = list(pp.prepared_in_process(seq, 15, _preparer(seq)))
    assert workers == [None]  # no process was started
    assert [f.index for f, _ in out] == list(range(15))
    assert all(p is not None for _, p in out)  # prepared on a thread, as without the process


def test_the_frames_handed_over_while_the_run_goes_on_give_the_same_results(swell, monkeypatch):
    """Started as a run starts it: the first frames prepared on a thread, the rest by the process from
    wherever the loop is when it is ready (here within the 120 frames or not at all: either way the same)."""
    started = []
    original = pp._Worker.start.__func__
    monkeypatch.setattr(
        pp._Worker, "start", classmethod(lambda cls, s, p: started.append(original(cls, s, p)) or started[-1])
    )
    monkeypatch.setattr(pp, "MIN_FRAMES", 0)
    run_sequence(swell / "seq", swell / "handed", read_ahead=True)
    run_sequence(swell / "seq", swell / "alone", read_ahead=False)
    assert len(started) == 1 and started[0] is not None
    for name in ("trajectory.csv", "landmarks.csv", "tokens.csv", "observations.csv", "landmark_measurements.csv"):
        assert (swell / "alone" / name).read_bytes() == (swell / "handed" / name).read_bytes(), name
