"""How a run ends when it is stopped (issue 15): SIGINT, SIGTERM and SIGHUP, in a real process.

Each test starts ``rovslam run`` on a 300-frame 360x272 dive, waits until the first rows are
on disk (no clock involved), sends the signal(s) and checks that every file is complete and
readable, that ``summary.json`` names the signal, and the exit code is 128 + the signal number.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import fuzz_corpus as fc
import numpy as np
import pytest

from rovslam.io.run_results import read_results


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    return fc.write_sequence(tmp_path_factory.mktemp("stops") / "seq", n=300, size=(360, 272))


def _start(dive, out):
    return subprocess.Popen(
        [sys.executable, "-m", "rovslam", "run", str(dive), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _wait_for_rows(proc, out, timeout_s=300.0):
    """Block until trajectory.csv holds at least one data row (the run is mid-way), or fail."""
    path = out / "trajectory.csv"
    deadline = time.monotonic() + timeout_s  # a guard against a hung test only, not a measurement
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the run ended before it could be stopped: {proc.communicate()}"
        if path.is_file() and path.read_bytes().count(b"\n") >= 2:
            return
        time.sleep(0.01)
    pytest.fail("no rows written")


def _check_stopped(proc, out, signame):
    stdout, stderr = proc.communicate(timeout=300)
    signum = getattr(signal, signame)
    assert proc.returncode == 128 + signum, stderr
    assert "Traceback" not in stderr and stdout == ""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"rovslam: stopped by {signame}: "), stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == signame and summary["status"] == "interrupted"
    res = read_results(out)
    n = summary["frames_processed"]
    assert 0 < n < 300
    # Every row of every file is complete: nothing of the frames processed is lost or cut.
    assert len(res.t_s) == n and (out / "trajectory.csv").read_bytes().endswith(b"\n")
    assert len(np.loadtxt(out / "trajectory.tum")) == n
    assert len(res.landmarks["id"]) == summary["landmarks"]
    for lid in res.landmarks["id"].astype(int):
        assert (out / "landmarks" / f"{lid}.png").stat().st_size > 0
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    assert (out / "config.toml").read_text().count("[") >= 7


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_a_signal_ends_the_run_with_every_file_complete(dive, tmp_path, signame):
    out = tmp_path / "out"
    proc = _start(dive, out)
    _wait_for_rows(proc, out)
    os.kill(proc.pid, getattr(signal, signame))
    _check_stopped(proc, out, signame)


def test_a_second_ctrl_c_while_finishing_changes_nothing(dive, tmp_path):
    out = tmp_path / "out"
    proc = _start(dive, out)
    _wait_for_rows(proc, out)
    os.kill(proc.pid, signal.SIGINT)
    for _ in range(3):  # impatient presses while the files are being finished
        time.sleep(0.02)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGINT)
    _check_stopped(proc, out, "SIGINT")
