"""Outputs: special files are never written into nor renamed over, a full disk leaves a consistent folder,
and bad input to a batch cell is that cell's one-line error.

As root (CI runs as root) nothing here touches the machine's /dev/null or /dev/full: the device
nodes are made in the test's own folder (``os.mknod``), and the small disks are tmpfs mounts
made and unmounted by the tests (skipped, saying why, where mounting is not permitted).
"""

from __future__ import annotations

import csv
import errno
import json
import os
import shutil
import socket
import stat
import subprocess
from pathlib import Path

import pytest
from cli_output import one_error_line
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.errors import NavigationError, OutputError

runner = CliRunner()


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    """A 40-frame simulated dive and its run: (sequence folder, results folder)."""
    root = tmp_path_factory.mktemp("outputs")
    res = runner.invoke(
        app, ["simulate", "--scenario", "portofino-short", "--frames", "40", "--out", str(root / "seq"), "-q"]
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["run", str(root / "seq"), "--out", str(root / "out"), "-q"])
    assert res.exit_code == 0, res.output
    return root / "seq", root / "out"


# --------------------------------------------------------------------------- special files as outputs


def _make(kind: str, path: Path) -> None:
    """Put a special file of ``kind`` at ``path`` (skip the test where the system does not allow it)."""
    if kind == "device":  # a copy of /dev/null's node, made here: never the machine's own
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
        except (PermissionError, OSError) as exc:
            pytest.skip(f"cannot make a device node here ({exc.strerror}): needs root")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        if len(str(path)) > 100:
            pytest.skip("the test folder's path is too long for a Unix socket name")
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.bind(str(path))
        s.close()
    elif kind == "link-to-fifo":
        os.mkfifo(path.with_name(path.name + ".pipe"))
        os.symlink(path.with_name(path.name + ".pipe"), path)
    elif kind == "dangling-link":
        os.symlink(path.with_name("nowhere" + path.suffix), path)
    else:
        raise AssertionError(kind)


def _snapshot(path: Path) -> tuple[int, int]:
    st = os.lstat(path)
    return st.st_ino, stat.S_IFMT(st.st_mode)


def _assert_untouched(path: Path, before: tuple[int, int]) -> None:
    """The special file is still there, the same node (not replaced by a regular file), and no temporary file is left."""
    assert _snapshot(path) == before
    assert not [p.name for p in path.parent.iterdir() if p.name.endswith(".tmp")]


KINDS = ["device", "fifo", "socket", "link-to-fifo", "dangling-link"]
NEEDLE = {
    "device": "is a character device, not a regular file",
    "fifo": "is a FIFO (named pipe), not a regular file",
    "socket": "is a socket, not a regular file",
    "link-to-fifo": "is a FIFO (named pipe), not a regular file",
    "dangling-link": "is a symbolic link to",
}


@pytest.mark.parametrize("kind", KINDS)
def test_eval_json_that_is_a_special_file_is_refused_and_left_alone(dive, tmp_path, kind):
    seq, out = dive
    target = tmp_path / "figures.json"
    _make(kind, target)
    before = _snapshot(target)
    res = runner.invoke(app, ["eval", str(out), "-g", str(seq / "groundtruth.csv"), "--json", str(target)])
    one_error_line(res, str(target), NEEDLE[kind])
    assert "wrote" not in res.output
    _assert_untouched(target, before)


@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_eval_default_json_that_is_a_special_file_is_refused(dive, tmp_path, kind):
    seq, out = dive
    res_dir = tmp_path / "res"
    shutil.copytree(out, res_dir)
    (res_dir / "eval.json").unlink(missing_ok=True)
    _make(kind, res_dir / "eval.json")
    before = _snapshot(res_dir / "eval.json")
    res = runner.invoke(app, ["eval", str(res_dir), "-g", str(seq / "groundtruth.csv")])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert NEEDLE[kind] in res.output.splitlines()[-1]
    _assert_untouched(res_dir / "eval.json", before)


@pytest.mark.parametrize("kind", KINDS)
def test_config_overwrite_onto_a_special_file_is_refused(tmp_path, kind):
    target = tmp_path / "c.toml"
    _make(kind, target)
    before = _snapshot(target)
    one_error_line(runner.invoke(app, ["config", str(target), "--overwrite"]), str(target), NEEDLE[kind])
    _assert_untouched(target, before)


@pytest.mark.parametrize("kind", ["device", "fifo", "dangling-link"])
def test_mosaic_out_that_is_a_special_file_is_refused_before_the_work(dive, tmp_path, kind):
    _, out = dive
    target = tmp_path / "m.png"
    _make(kind, target)
    before = _snapshot(target)
    one_error_line(runner.invoke(app, ["mosaic", str(out), "--out", str(target), "-q"]), str(target), NEEDLE[kind])
    _assert_untouched(target, before)


def test_mosaic_world_file_that_is_a_fifo_is_refused(dive, tmp_path):
    _, out = dive
    _make("fifo", tmp_path / "m.pgw")
    before = _snapshot(tmp_path / "m.pgw")
    one_error_line(
        runner.invoke(app, ["mosaic", str(out), "--out", str(tmp_path / "m.png"), "-q"]), "m.pgw", NEEDLE["fifo"]
    )
    _assert_untouched(tmp_path / "m.pgw", before)
    assert not (tmp_path / "m.png").exists()


@pytest.mark.parametrize("where", ["report", "report/index.html", "report/map.png"])
def test_report_files_that_are_special_files_are_refused(dive, tmp_path, where):
    _, out = dive
    res_dir = tmp_path / "res"
    shutil.copytree(out, res_dir)
    shutil.rmtree(res_dir / "report", ignore_errors=True)
    if where != "report":
        (res_dir / "report").mkdir()
    _make("fifo", res_dir / where)
    before = _snapshot(res_dir / where)
    res = runner.invoke(app, ["report", str(res_dir), "--no-mosaic", "-q"])
    one_error_line(res, str(res_dir / where), "FIFO (named pipe)")
    _assert_untouched(res_dir / where, before)


def test_smooth_output_that_is_a_fifo_is_refused(dive, tmp_path):
    _, out = dive
    res_dir = tmp_path / "res"
    shutil.copytree(out, res_dir)
    target = res_dir / "trajectory_smoothed.csv"
    target.unlink(missing_ok=True)
    _make("fifo", target)
    before = _snapshot(target)
    one_error_line(runner.invoke(app, ["smooth", str(res_dir), "-q"]), str(target), NEEDLE["fifo"])
    _assert_untouched(target, before)


@pytest.mark.parametrize("kind", ["device", "fifo", "socket", "dangling-link"])
@pytest.mark.parametrize("command", ["run", "simulate", "import", "batch", "navigate"])
def test_out_folder_that_is_a_special_file_is_refused(dive, tmp_path, kind, command):
    seq, _ = dive
    target = tmp_path / "o"
    _make(kind, target)
    before = _snapshot(target)
    matrix = tmp_path / "m.toml"
    matrix.write_text(f'name = "t"\n[[sequence]]\nname = "d"\npath = "{seq}"\n')
    poi = tmp_path / "poi.csv"
    poi.write_text("name,x_m,y_m\na,0.1,0.1\n")
    args = {
        "run": ["run", str(seq), "--out", str(target), "-q"],
        "simulate": ["simulate", "--frames", "5", "--out", str(target), "-q"],
        "import": ["import", str(seq / "images"), "--fps", "10", "--out", str(target), "-q"],
        "batch": ["batch", str(matrix), "--out", str(target), "-q"],
        "navigate": ["navigate", "--scenario", "portofino-short", "--poi", str(poi), "--out", str(target), "-q"],
    }[command]
    needle = "is a symbolic link to" if kind == "dangling-link" else "not a folder"
    one_error_line(runner.invoke(app, args), str(target), needle)
    _assert_untouched(target, before)


@pytest.mark.parametrize("kind", ["device", "fifo"])
def test_save_rrd_that_is_a_special_file_is_refused(dive, tmp_path, kind):
    seq, _ = dive
    target = tmp_path / "live.rrd"
    _make(kind, target)
    before = _snapshot(target)
    res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "--save-rrd", str(target), "-q"])
    one_error_line(res, str(target), NEEDLE[kind])
    _assert_untouched(target, before)
    assert not (tmp_path / "o").exists()  # refused before the run


def test_a_symlink_to_a_regular_file_is_written_through_and_stays_a_link(dive, tmp_path):
    seq, out = dive
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    res = runner.invoke(app, ["eval", str(out), "-g", str(seq / "groundtruth.csv"), "--json", str(link)])
    assert res.exit_code == 0, res.output
    assert link.is_symlink() and os.readlink(link) == str(real)
    figures = json.loads(real.read_text())
    assert figures["frames"] == 40


def test_a_symlink_to_a_folder_as_out_is_used_as_that_folder(dive, tmp_path):
    seq, _ = dive
    (tmp_path / "real").mkdir()
    (tmp_path / "o").symlink_to(tmp_path / "real")
    res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "--max-frames", "5", "-q"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "o").is_symlink()
    assert len((tmp_path / "real" / "trajectory.csv").read_text().splitlines()) == 6


def test_a_regular_file_as_simulate_out_is_not_a_folder(tmp_path):
    target = tmp_path / "f"
    target.write_text("mine")
    line = one_error_line(
        runner.invoke(app, ["simulate", "--frames", "5", "--out", str(target), "-q"]),
        str(target),
        "is a file, not a folder",
    )
    assert "not empty" not in line
    assert target.read_text() == "mine"


def test_batch_tables_that_are_fifos_are_refused(tmp_path, monkeypatch):
    from rovslam.batch import load_matrix, run_matrix

    matrix = tmp_path / "m.toml"
    matrix.write_text('name = "t"\n[[sequence]]\nname = "d"\npath = "nowhere"\n')
    out = tmp_path / "b"
    out.mkdir()
    _make("fifo", out / "matrix.csv")
    before = _snapshot(out / "matrix.csv")

    class Closable:
        def close(self):
            pass

    from rovslam import batch

    monkeypatch.setattr(batch, "_connect", lambda scheduler, workers: (Closable(), None))
    with pytest.raises(OutputError, match="matrix.csv: is a FIFO"):
        run_matrix(load_matrix(matrix), out)
    _assert_untouched(out / "matrix.csv", before)


# --------------------------------------------------------------------------- a full disk


def _check_consistent(out: Path) -> dict:
    """What a run stopped by a full disk must leave: whole rows, no reserve or temporary file, a "failed" summary."""
    names = {p.name for p in out.iterdir()}
    assert ".rovslam-reserve" not in names and not [n for n in names if n.endswith(".tmp")], names
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed", summary
    assert "No space left on device" in summary["reason"] and "the disk is full" in summary["reason"]
    for name in ("trajectory.csv", "observations.csv", "tokens.csv", "measurements.csv", "landmark_measurements.csv"):
        path = out / name
        if not path.exists():
            continue
        text = path.read_text()
        assert text == "" or text.endswith("\n"), (name, text[-80:])  # never half a row
        rows = list(csv.reader(text.splitlines()))
        if rows:
            assert all(len(r) == len(rows[0]) for r in rows), name
    traj = (out / "trajectory.csv").read_text().splitlines()
    assert len(traj) == 1 + summary["frames_written"]
    assert len((out / "trajectory.tum").read_text().splitlines()) <= len(traj)
    for png in (out / "landmarks").glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return summary


def _check_eval_tells_the_reason(seq: Path, out: Path, summary: dict) -> None:
    res = runner.invoke(
        app, ["eval", str(out), "-g", str(seq / "groundtruth.csv"), "--json", str(out.parent / "e.json")]
    )
    text = " ".join(res.output.split())
    assert "killed or a power loss" not in text
    if summary["frames_written"] == 0:
        one_error_line(res, "the run wrote no frame; it failed:", "No space left on device")
    else:
        assert res.exit_code == 0, res.output
        assert "the run was stopped by an error (" in text and "No space left on device" in text
        partial = json.loads((out.parent / "e.json").read_text())["partial_run"]
        assert "No space left on device" in partial


@pytest.fixture
def small_disk(tmp_path):
    """A function mounting a tmpfs of the size given at a new folder (unmounted afterwards)."""
    mounts: list[Path] = []

    def mount(size: str) -> Path:
        where = tmp_path / f"disk{len(mounts)}"
        where.mkdir()
        try:
            done = subprocess.run(
                ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                check=False,
                capture_output=True,
                text=True,
                timeout=30,
            )
        except (OSError, subprocess.TimeoutExpired) as exc:
            pytest.skip(f"cannot run mount: {exc}")
        if done.returncode != 0:
            pytest.skip(f"mounting a tmpfs is not permitted here (needs root): {done.stderr.strip()}")
        mounts.append(where)
        return where

    yield mount
    for where in mounts:
        subprocess.run(["umount", str(where)], check=False, capture_output=True, timeout=30)


# Sizes at which the 40-frame run's disk fills at different files: before the first frame (a file's
# header, summary.json), at a landmark template, mid-stream, at the end (landmarks.csv, summary.json).
@pytest.mark.parametrize("size", ["24k", "40k", "56k", "80k", "100k", "120k"])
def test_a_run_on_a_small_disk_leaves_a_consistent_folder(dive, small_disk, size):
    seq, _ = dive
    out = small_disk(size) / "out"
    res = runner.invoke(app, ["run", str(seq), "--out", str(out), "-q"])
    one_error_line(res, "No space left on device", "the disk is full")
    summary = _check_consistent(out)
    if summary["frames_written"]:
        assert (out / "landmarks.csv").read_text().startswith("id,x_m,y_m")
    _check_eval_tells_the_reason(seq, out, summary)


class _FakeDisk:
    """os.write / posix_fallocate for files under ``root`` as on a disk of ``capacity`` bytes (for a non-root run).

    The bytes in use are the sizes of the files under ``root``: deleting one frees its space, as on a real disk.
    """

    def __init__(self, root: Path, capacity: int):
        self.root, self.capacity = str(root), capacity
        self.real_write, self.real_fallocate, self.real_statvfs = os.write, os.posix_fallocate, os.statvfs
        self.full_writes = 0

    def _under(self, fd: int) -> bool:
        try:
            return os.readlink(f"/proc/self/fd/{fd}").startswith(self.root)
        except OSError:
            return False

    def _used(self) -> int:
        return sum(os.lstat(os.path.join(d, f)).st_size for d, _, files in os.walk(self.root) for f in files)

    def write(self, fd: int, data) -> int:
        if not self._under(fd):
            return self.real_write(fd, data)
        room = self.capacity - self._used()
        if room <= 0:
            self.full_writes += 1
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.real_write(fd, bytes(data[:room]))  # a short write, as a disk that fills mid-way does

    def statvfs(self, path):
        st = self.real_statvfs(path)
        if not str(path).startswith(self.root):
            return st
        return type(
            "statvfs", (), {"f_bavail": max(0, self.capacity - self._used()), "f_frsize": 1, "f_bsize": st.f_bsize}
        )()

    def fallocate(self, fd: int, offset: int, length: int) -> None:
        if self._under(fd) and self._used() + length > self.capacity:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.real_fallocate(fd, offset, length)


@pytest.mark.parametrize("capacity", [3_000, 9_000, 30_000, 45_000, 60_000, 75_000, 90_000])
def test_a_run_on_a_fake_full_disk_leaves_a_consistent_folder(dive, tmp_path, monkeypatch, capacity):
    seq, _ = dive
    disk = _FakeDisk(tmp_path / "disk", capacity)
    (tmp_path / "disk").mkdir()
    monkeypatch.setattr(os, "write", disk.write)
    monkeypatch.setattr(os, "posix_fallocate", disk.fallocate)
    monkeypatch.setattr(os, "statvfs", disk.statvfs)
    out = tmp_path / "disk" / "out"
    res = runner.invoke(app, ["run", str(seq), "--out", str(out), "-q"])
    monkeypatch.undo()
    assert disk.full_writes > 0
    one_error_line(res, "No space left on device", "the disk is full")
    summary = _check_consistent(out)
    _check_eval_tells_the_reason(seq, out, summary)


def test_a_half_written_row_is_cut_back_to_the_last_whole_one(tmp_path, monkeypatch):
    from rovslam.io.output import StreamFile

    f = StreamFile(tmp_path / "t.csv")
    f.write("a,b\n")
    f.flush()
    for i in range(5):
        f.write(f"{i},{i * i}\n")
    real = os.write
    calls = []

    def short_then_full(fd, data):
        calls.append(len(data))
        if len(calls) == 1:
            return real(fd, bytes(data[:9]))  # "0,0\n1,1\n2" reaches the disk
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "write", short_then_full)
    with pytest.raises(OutputError, match=r"t\.csv: cannot write: No space left on device"):
        f.flush()
    monkeypatch.undo()
    assert (tmp_path / "t.csv").read_text() == "a,b\n0,0\n1,1\n"
    assert f.rows == 3
    f.flush()  # the space came back: the rows kept in memory follow, whole
    f.close()
    assert (tmp_path / "t.csv").read_text() == "a,b\n0,0\n1,1\n2,4\n3,9\n4,16\n"


# --------------------------------------------------------------------------- batch: bad input is the cell's one line


def _spec(tmp_path: Path, seq: Path):
    from rovslam.batch.matrix import CellSpec

    return CellSpec("d", "d", sequence_path=str(seq), groundtruth_path=str(seq / "groundtruth.csv"))


def test_a_cell_whose_sequence_has_no_ground_truth_is_its_one_line_not_a_traceback(dive, tmp_path):
    from rovslam.batch.cell import run_cell

    seq = tmp_path / "seq"
    shutil.copytree(dive[0], seq)
    (seq / "groundtruth.csv").unlink()
    row = run_cell(_spec(tmp_path, seq), str(tmp_path / "cells"))
    assert row["status"] == "failed" and row["failure"] == "input"
    assert row["error"].startswith("SequenceFormatError: ") and "ground truth not found" in row["error"]
    log = (tmp_path / "cells" / "d" / "error.log").read_text()
    assert log == row["error"] + "\n" and "Traceback" not in log


def test_a_cell_that_hits_a_bug_keeps_its_traceback(dive, tmp_path, monkeypatch):
    from rovslam.batch import cell

    def bug(*a):
        raise ZeroDivisionError("division by zero")

    monkeypatch.setattr(cell, "_run", bug)
    row = cell.run_cell(_spec(tmp_path, dive[0]), str(tmp_path / "cells"))
    assert row["failure"] == "internal"
    assert "Traceback" in (tmp_path / "cells" / "d" / "error.log").read_text()


class _Future:
    def __init__(self, fn, *args):
        self.fn, self.args = fn, args

    def result(self):
        return self.fn(*self.args)


class _Client:
    def submit(self, fn, *args, **kwargs):
        return _Future(fn, *args)

    def close(self):
        pass


@pytest.mark.parametrize("bug", [False, True], ids=["bad-input", "bug"])
def test_batch_exit_code_two_for_cells_with_bad_input_one_for_a_bug(dive, tmp_path, monkeypatch, bug):
    import dask.distributed

    from rovslam import batch
    from rovslam.batch import cell

    seq = tmp_path / "no-truth"
    shutil.copytree(dive[0], seq)
    (seq / "groundtruth.csv").unlink()
    matrix = tmp_path / "m.toml"
    matrix.write_text(
        f'name = "t"\n[[sequence]]\nname = "d"\npath = "{seq}"\n[[sequence]]\nname = "gone"\n'
        f'path = "{tmp_path / "gone"}"\n'
    )
    monkeypatch.setattr(batch, "_connect", lambda scheduler, workers: (_Client(), None))
    monkeypatch.setattr(dask.distributed, "as_completed", lambda futures: list(futures))
    if bug:
        real = cell._run

        def sometimes_a_bug(spec, cell_dir, keep):
            if spec.cell_id == "gone":
                raise ZeroDivisionError("division by zero")
            return real(spec, cell_dir, keep)

        monkeypatch.setattr(cell, "_run", sometimes_a_bug)
    out = tmp_path / "b"
    res = runner.invoke(app, ["batch", str(matrix), "--out", str(out), "-q"])
    assert res.exit_code == (1 if bug else 2), res.output
    assert "2 of 2 cells failed" in res.output and "Traceback" not in res.output
    with (out / "matrix.csv").open() as fh:
        table = {r["cell"]: r for r in csv.DictReader(fh)}
    assert table["d"]["status"] == "failed" and table["d"]["error"].startswith("SequenceFormatError: ")
    assert "ground truth not found" in table["d"]["error"]
    assert "Traceback" not in (out / "cells" / "d" / "error.log").read_text()
    gone_log = (out / "cells" / "gone" / "error.log").read_text()
    assert ("Traceback" in gone_log) == bug


# --------------------------------------------------------------------------- wordings


def test_a_fifo_in_images_is_not_a_regular_file_not_missing(dive, tmp_path):
    seq = tmp_path / "seq"
    shutil.copytree(dive[0], seq)
    first = min((seq / "images").iterdir())
    first.unlink()
    os.mkfifo(first)
    line = one_error_line(
        runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "-q"]), first.name, "is not a regular file"
    )
    assert "not found" not in line


def test_a_fifo_listed_in_a_times_file_is_not_a_regular_file(dive, tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    images = sorted((dive[0] / "images").iterdir())[:3]
    for p in images[:2]:
        shutil.copy(p, folder / p.name)
    os.mkfifo(folder / images[2].name)
    times = tmp_path / "times.csv"
    times.write_text("image,t_s\n" + "".join(f"{p.name},{0.1 * k}\n" for k, p in enumerate(images)))
    camera = Path(__file__).resolve().parents[1] / "examples" / "sparus-camera.toml"
    line = one_error_line(
        runner.invoke(
            app,
            ["run", str(folder), "--camera", str(camera), "--times", str(times), "--out", str(tmp_path / "o"), "-q"],
        ),
        images[2].name,
        "is not a regular file",
    )
    assert "not found" not in line


def test_a_navigation_log_range_is_its_own_first_and_last_times(tmp_path):
    from rovslam.io.nav import read_nav_csv

    p = tmp_path / "NAV.csv"
    p.write_text("t_s,heading_rad\n" + "".join(f"{1000 + k},0.1\n" for k in range(9)))  # 1000.0 to 1008.0 s
    nav = read_nav_csv(p)
    with pytest.raises(NavigationError) as exc:
        nav.check_overlap((0.0, 20.0), "video", "")
    assert "from 1000.000 to 1008.000 s" in str(exc.value)
    assert "999.5" not in str(exc.value) and "1008.5" not in str(exc.value)


def _plain_frame(k: int):
    from types import SimpleNamespace

    import numpy as np

    return SimpleNamespace(
        index=k,
        t_s=0.2 * k,
        x_m=0.01 * k,
        y_m=0.0,
        cov_xy_m2=np.eye(2) * 1e-6,
        altitude_m=1.31,
        surge_mps=0.05,
        sway_mps=0.0,
        tokens_tracked=8,
        landmarks_tracked=1,
        heading_rad=0.1,
        altitude_sigma_m=0.003,
        altitude_source="laser",
        speed_ok=True,
        dr_x_m=0.01 * k,
        dr_y_m=0.0,
        skipped_reason=None,
        speed_cov_mps2=np.eye(2) * 1e-8,
        tokens_inliers=8,
        recovery=None,
        speed_source="tokens",
        observations=(),
    )


@pytest.mark.parametrize("csv_takes_rows", [0, 1, 3])
def test_trajectory_tum_never_holds_a_frame_trajectory_csv_lost_to_a_full_disk(tmp_path, monkeypatch, csv_takes_rows):
    # The disk fills while trajectory.csv is written (it takes only the first rows) but still takes the
    # shorter TUM rows: before, trajectory.tum could then hold frames trajectory.csv did not (seen once at one
    # disk size in tests/test_outputs_safety.py's fake full disk, where the byte counts fell that way).
    from rovslam.io.results import ResultWriter

    out = tmp_path / "out"
    out.mkdir()
    writer = ResultWriter(out, flush_every=1000)
    for k in range(6):
        writer.write_frame(_plain_frame(k))
    csv_fd = writer._fhs["trajectory.csv"]._fd
    fits = sum(len(row) for row in writer._fhs["trajectory.csv"]._pending[:csv_takes_rows])
    real_write = os.write
    taken = {"bytes": 0}

    def full_for_the_csv(fd, data):
        if fd != csv_fd:
            return real_write(fd, data)
        room = fits - taken["bytes"]
        if room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = real_write(fd, bytes(data[: min(len(data), room + 7)]))  # and a few bytes of the next row
        taken["bytes"] += n
        return n

    monkeypatch.setattr(os, "write", full_for_the_csv)
    writer.close(quiet=True)
    monkeypatch.undo()
    csv_rows = (out / "trajectory.csv").read_text().splitlines()
    tum_rows = (out / "trajectory.tum").read_text().splitlines()
    assert len(csv_rows) == 1 + csv_takes_rows  # the header, then whole rows only
    assert len(tum_rows) == len(csv_rows)  # the same frames, no more
