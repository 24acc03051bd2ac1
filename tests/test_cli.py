"""The `rovslam` command as a user runs it: exit codes, one-line errors, files written."""

from __future__ import annotations

import errno
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import fuzz_corpus as fc
import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def tiny_seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    res = runner.invoke(
        app, ["simulate", "--scenario", "portofino-short", "--frames", "60", "--out", str(root / "seq"), "--quiet"]
    )
    assert res.exit_code == 0, res.output
    return root


def test_run_eval_report_and_config(tiny_seq, tmp_path):
    out = tmp_path / "out"
    res = runner.invoke(app, ["run", str(tiny_seq / "seq"), "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    assert "60/60 frames" in res.output
    res = runner.invoke(app, ["eval", str(out), "--groundtruth", str(tiny_seq / "seq" / "groundtruth.csv")])
    assert res.exit_code == 0, res.output
    figures = json.loads((out / "eval.json").read_text())
    assert figures["frames"] == 60 and figures["slam"]["ate_rmse_m"] < 0.01
    res = runner.invoke(app, ["report", str(out), "--groundtruth", str(tiny_seq / "seq" / "groundtruth.csv")])
    assert res.exit_code == 0, res.output
    for name in ("index.html", "map.png", "position.png", "altitude_speed.png"):
        assert (out / "report" / name).stat().st_size > 1000
    res = runner.invoke(app, ["config", str(tmp_path / "c.toml")])
    assert res.exit_code == 0 and "min_correlation = 0.89" in (tmp_path / "c.toml").read_text()


def test_eval_names_a_bad_groundtruth_once(tiny_seq, tmp_path):
    out = tmp_path / "out"
    assert runner.invoke(app, ["run", str(tiny_seq / "seq"), "--out", str(out), "--quiet"]).exit_code == 0
    bad = tmp_path / "truth.csv"
    bad.write_text("hello\n1,2\n")
    res = runner.invoke(app, ["eval", str(out), "--groundtruth", str(bad)])
    assert res.exit_code == 2, res.output
    assert res.output.count(str(bad)) == 1, res.output
    assert "header is missing column(s) t_s, x_m" in res.output
    short = tmp_path / "short.csv"  # times that do not cover the run: evaluate's error, named here
    rows = (tiny_seq / "seq" / "groundtruth.csv").read_text().splitlines()[:4]
    short.write_text("\n".join(rows) + "\n")
    res = runner.invoke(app, ["eval", str(out), "--groundtruth", str(short)])
    assert res.exit_code == 2, res.output
    assert str(short) in res.output


@pytest.mark.parametrize(
    "args,needle",
    [
        (["run", "/no/such/folder", "--out", "OUT"], "not found"),
        (["eval", "/no/such/out", "--groundtruth", "gt.csv"], "not a folder"),
        (["simulate", "--scenario", "atlantis", "--out", "OUT"], "unknown scenario"),
    ],
)
def test_user_mistakes_are_one_line_and_exit_2(tmp_path, args, needle):
    args = [a.replace("OUT", str(tmp_path / "o")) for a in args]
    res = runner.invoke(app, args)
    assert res.exit_code == 2
    assert needle in res.output
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error:")


def test_bad_config_names_the_key(tiny_seq, tmp_path):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[tracker]\nmin_corelation = 0.9\n")
    res = runner.invoke(app, ["run", str(tiny_seq / "seq"), "--out", str(tmp_path / "o"), "-c", str(cfg)])
    assert res.exit_code == 2 and "tracker.min_corelation" in res.output and "bad.toml" in res.output


# --------------------------------------------------------------------------- issue 15: errors, outputs, limits


@pytest.fixture
def small_seq(tmp_path):
    return fc.write_sequence(tmp_path / "seq")


def _one_error_line(res, needle):
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 2, res.stderr
    assert len(lines) == 1 and lines[0].startswith("rovslam: error: "), res.stderr
    assert needle in lines[0], lines[0]
    assert "Traceback" not in res.output
    return lines[0]


def _no_tmp(folder: Path) -> None:
    assert not [p for p in folder.rglob("*") if p.name.endswith(".tmp")]


def test_version():
    from rovslam import __version__

    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.stdout.strip() == f"rovslam {__version__}"


def test_messages_keep_their_brackets(small_seq, tmp_path):
    """Rich markup must not eat '[camera]' or a folder called '[bold]x[/bold]'."""
    fc.replace_in(small_seq / "sequence.toml", "[camera]", "[metadata]")
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "o")])
    _one_error_line(res, "missing [camera] table (width_px")
    res = runner.invoke(app, ["run", str(tmp_path / "[red]dive[/red]"), "--out", str(tmp_path / "o")])
    _one_error_line(res, "[red]dive[/red]: not found")


@pytest.mark.parametrize("value", ["0", "-1"])
def test_max_frames_must_be_positive(small_seq, tmp_path, value):
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "o"), "--max-frames", value])
    _one_error_line(res, f"--max-frames must be a whole number of frames >= 1, got {value}")
    assert not (tmp_path / "o").exists()


def test_max_frames_processes_exactly_n(small_seq, tmp_path):
    from rovslam.io.run_results import read_results

    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "o"), "--max-frames", "3", "-q"])
    assert res.exit_code == 0 and "3/3 frames" in res.stdout
    assert len(read_results(tmp_path / "o").t_s) == 3


def test_existing_results_are_refused_then_replaced_with_overwrite(small_seq, tmp_path):
    from rovslam.io.run_results import read_results

    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"]).exit_code == 0
    (out / "landmarks" / "99.png").write_bytes(b"an old run's template")
    (out / "eval.json").write_text("{}")
    before = (out / "trajectory.csv").read_bytes()
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q", "--max-frames", "4"])
    _one_error_line(res, "holds the results of an earlier run")
    assert (out / "trajectory.csv").read_bytes() == before and (out / "eval.json").exists()  # untouched
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q", "--max-frames", "4", "--overwrite"])
    assert res.exit_code == 0, res.stderr
    # Nothing of the old run is mixed in: its extra landmark and its evaluation are gone.
    assert not (out / "landmarks" / "99.png").exists() and not (out / "eval.json").exists()
    assert len(read_results(out).t_s) == 4


def test_overwrite_never_deletes_files_rovslam_did_not_write(small_seq, tmp_path):
    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"]).exit_code == 0
    (out / "notes.txt").write_text("my notes")
    (out / "landmarks" / "sketch.jpg").write_bytes(b"mine")
    names = sorted(p.relative_to(out) for p in out.rglob("*"))
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q", "--overwrite"])
    _one_error_line(res, "holds files rovslam did not write (landmarks/sketch.jpg, notes.txt)")
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == names  # nothing deleted
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(small_seq), "-q", "--overwrite"])
    _one_error_line(res, "holds files rovslam did not write (frames.csv")


def test_a_dive_with_no_usable_frame_fails_and_says_why(small_seq, tmp_path):
    import cv2

    for p in (small_seq / "images").iterdir():
        cv2.imwrite(str(p), np.zeros((fc.H, fc.W, 3), np.uint8))
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"])
    line = _one_error_line(res, "only 0 of 8 frames were usable")
    assert "no texture" in line and "summary.json" in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "unusable" and summary["complete"] is False
    assert summary["frames_usable"] == 0 and len(summary["skipped_frames"]) == 8
    assert summary["reason"].startswith("only 0 of 8 frames were usable")


def test_a_diverging_estimate_is_never_written(small_seq, tmp_path):
    """A last frame 1e12 s later: its position uncertainty is absurd, so the row is refused."""
    from rovslam.io.run_results import read_results

    fc.set_cell(small_seq / "frames.csv", fc.N_FRAMES, "t_s", "1e12")
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"])
    _one_error_line(res, f"frame {fc.N_FRAMES - 1} (t=1e+12 s): the position uncertainty")
    r = read_results(out)
    assert r.summary["status"] == "unusable" and len(r.t_s) == fc.N_FRAMES - 1
    assert float(np.max(r.trajectory["var_x_m2"])) < 1.0


def test_one_frame_run_evaluates_to_strict_json(small_seq, tmp_path):
    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q", "--max-frames", "1"]).exit_code == 0
    res = runner.invoke(app, ["eval", str(out), "-g", str(small_seq / "groundtruth.csv")])
    assert res.exit_code in (0, 2), res.output
    if res.exit_code == 0:  # JSON has no NaN: a figure that cannot be computed is null
        json.loads((out / "eval.json").read_text(), parse_constant=lambda c: pytest.fail(f"eval.json holds {c}"))
    else:
        _one_error_line(res, "")


def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_disk_full_during_a_run(small_seq, tmp_path, monkeypatch):
    from rovslam.io.results import ResultWriter
    from rovslam.io.run_results import read_summary

    real = ResultWriter.write_frame
    calls = []

    def write_frame(self, r):
        calls.append(r.index)
        if len(calls) > 3:
            _enospc()
        real(self, r)

    monkeypatch.setattr(ResultWriter, "write_frame", write_frame)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"])
    _one_error_line(res, "No space left on device (the disk is full; free space or choose another --out)")
    summary = read_summary(out / "summary.json")
    assert summary["status"] == "failed" and "No space left" in summary["reason"] and not summary["complete"]
    assert summary["frames_processed"] == 3
    _no_tmp(out)


def test_disk_full_for_every_write(small_seq, tmp_path, monkeypatch):
    """Nothing can be written: no summary at all (so nothing looks complete), no temporary file."""
    import rovslam.io.results as results

    monkeypatch.setattr(results.os, "fsync", _enospc)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"])
    _one_error_line(res, "config.toml: cannot write: No space left on device")
    assert not (out / "summary.json").exists() and not (out / "config.toml").exists()
    _no_tmp(out)


def test_disk_full_at_the_end_leaves_a_running_summary(small_seq, tmp_path, monkeypatch):
    """The final summary cannot be written: the one that stays says "running", never "complete"."""
    import rovslam.io.results as results

    real, calls = os.fsync, []

    def fsync(fd):
        calls.append(fd)
        if len(calls) > 2:  # config.toml and the first summary.json succeed
            _enospc()
        real(fd)

    monkeypatch.setattr(results.os, "fsync", fsync)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"])
    _one_error_line(res, "No space left on device")
    assert json.loads((out / "summary.json").read_text())["status"] == "running"
    _no_tmp(out)


def test_disk_full_writing_eval_json(small_seq, tmp_path, monkeypatch):
    import rovslam.io.results as results

    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"]).exit_code == 0
    monkeypatch.setattr(results.os, "fsync", _enospc)
    res = runner.invoke(app, ["eval", str(out), "-g", str(small_seq / "groundtruth.csv")])
    _one_error_line(res, "eval.json: cannot write: No space left on device")
    assert not (out / "eval.json").exists()
    _no_tmp(out)


def test_output_folder_that_cannot_be_created(small_seq, tmp_path, monkeypatch):
    """A read-only place (simulated: the tests may run as root, who can write anywhere)."""
    real = Path.mkdir

    def mkdir(self, *a, **k):
        if self.is_relative_to(tmp_path / "ro"):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return real(self, *a, **k)

    monkeypatch.setattr(Path, "mkdir", mkdir)
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "ro" / "o"), "-q"])
    _one_error_line(
        res, "cannot create the folder: Permission denied (permission denied; choose a folder you can write to)"
    )


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder(small_seq, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        res = runner.invoke(app, ["run", str(small_seq), "--out", str(ro / "o"), "-q"])
        _one_error_line(res, "Permission denied")
    finally:
        ro.chmod(0o700)


def test_parent_is_a_file_and_json_is_a_folder(small_seq, tmp_path):
    (tmp_path / "f").write_text("x")
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "f" / "o"), "-q"])
    _one_error_line(res, "a parent of this path is a file")
    out = tmp_path / "o"
    assert runner.invoke(app, ["run", str(small_seq), "--out", str(out), "-q"]).exit_code == 0
    res = runner.invoke(app, ["eval", str(out), "-g", str(small_seq / "groundtruth.csv"), "--json", str(tmp_path)])
    _one_error_line(res, "is a folder; --json needs a file name")


def test_config_command_does_not_clobber(tmp_path):
    c = tmp_path / "c.toml"
    c.write_text("# my edits\n")
    _one_error_line(runner.invoke(app, ["config", str(c)]), "exists; add --overwrite")
    assert c.read_text() == "# my edits\n"
    assert runner.invoke(app, ["config", str(c), "--overwrite"]).exit_code == 0
    assert "min_correlation = 0.89" in c.read_text()
    _no_tmp(tmp_path)


def test_a_bug_is_one_line_and_exit_1(small_seq, tmp_path, monkeypatch):
    import rovslam.runner

    def boom(*a, **k):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(rovslam.runner, "run_sequence", boom)
    res = runner.invoke(app, ["run", str(small_seq), "--out", str(tmp_path / "o")])
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 1 and len(lines) == 1 and "internal error (ZeroDivisionError" in lines[0]


def test_usage_errors_are_one_line_in_the_console_script(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "rovslam", "run", "--bogus"], capture_output=True, text=True, timeout=120
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("rovslam: error: No such option: --bogus")


def test_help_lists_the_commands_in_the_order_of_the_workflow():
    from typer.testing import CliRunner

    from rovslam.cli import app

    out = CliRunner().invoke(app, ["--help"], env={"COLUMNS": "120"}).output
    commands = [m.group(1) for line in out.splitlines() if (m := re.match(r"^│ ([a-z]+) {2,}\S", line))]
    assert commands == [
        "simulate",
        "run",
        "import",
        "topics",
        "eval",
        "batch",
        "demo",
        "report",
        "mosaic",
        "config",
        "smooth",
        "navigate",
        "live",
        "sitl",
    ]


def test_the_demo_ends_with_the_next_step(tmp_path):
    from typer.testing import CliRunner

    from rovslam.cli import app

    result = CliRunner().invoke(app, ["demo", "--out", str(tmp_path / "d"), "--frames", "40", "-q"])
    assert result.exit_code == 0, result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("next: ") and "rovslam run VIDEO" in last and "rovslam live" in last
    assert (tmp_path / "d" / "results" / "report" / "index.html").is_file()


def test_an_assumed_altitude_is_said_on_the_console(tmp_path):
    import json

    from rovslam.cli.run import assumed_altitude_note

    summary = tmp_path / "summary.json"
    detail = "assumed constant: 1.8 m, [vehicle] altitude_m of cam.toml"
    summary.write_text(
        json.dumps({"sources": {"altitude": {"frames": {"assumed constant": 20, "laser": 2}, "detail": detail}}})
    )
    note = assumed_altitude_note(summary)
    assert note.startswith("altitude: assumed on 20 of 22 frames (1.8 m, [vehicle] altitude_m of cam.toml)")
    summary.write_text(json.dumps({"sources": {"altitude": {"frames": {"laser+sonar": 22}, "detail": "laser"}}}))
    assert assumed_altitude_note(summary) is None
    assert assumed_altitude_note(tmp_path / "missing.json") is None


def test_help_shows_no_type_after_a_flag_and_arguments_in_capitals():
    from typer.testing import CliRunner

    from rovslam.cli import app

    out = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "120"}).output
    usage = next(line for line in out.splitlines() if "Usage:" in line)
    assert usage.split()[-1] == "SEQUENCE" and "{" not in usage
    quiet = next(line for line in out.splitlines() if "--quiet" in line)
    assert "<bool>" not in quiet and "No progress" in quiet
    assert "<int>" in next(line for line in out.splitlines() if "--max-frames" in line)
