"""The bad-input defects of the CLI audit (D1 to D9): each one a refusal or a note, never a traceback."""

from __future__ import annotations

import csv
import errno
import json
import os
import shutil
from pathlib import Path

import pytest
from cli_output import one_error_line
from typer.testing import CliRunner

from rovslam.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    """A 60-frame simulated dive and its run (6 landmarks): (sequence folder, results folder)."""
    root = tmp_path_factory.mktemp("audit")
    res = runner.invoke(
        app, ["simulate", "--scenario", "portofino-short", "--frames", "60", "--out", str(root / "seq"), "-q"]
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["run", str(root / "seq"), "--out", str(root / "out"), "-q"])
    assert res.exit_code == 0, res.output
    return root / "seq", root / "out"


# --------------------------------------------------------------------------- D3: a full disk names the file


class _FullDisk:
    """A text file that takes ``budget`` characters, then fails like a full disk on every write, flush and close."""

    def __init__(self, fh, budget: int):
        self.fh, self.budget = fh, budget

    def _full(self):
        return OSError(errno.ENOSPC, "No space left on device")

    def write(self, text: str) -> int:
        if len(text) > self.budget:
            self.budget = -1
            raise self._full()
        self.budget -= len(text)
        return self.fh.write(text)

    def flush(self) -> None:
        if self.budget < 0:
            raise self._full()
        self.fh.flush()

    def close(self) -> None:
        self.fh.close()
        if self.budget < 0 or self.at_close:
            raise self._full()

    at_close = False


@pytest.mark.parametrize("at_close", [False, True], ids=["while-writing", "at-close"])
def test_a_full_disk_while_writing_tokens_names_the_file_and_finishes_the_others(dive, tmp_path, monkeypatch, at_close):
    import rovslam.io.results as results

    init = results.GalleryWriter.__init__

    def full_after_a_while(self, out_dir, flush_every=50):
        init(self, out_dir, flush_every)
        self._fh = _FullDisk(self._fh, 10**9 if at_close else 5_000)  # tokens.csv of this dive: 12 kB
        self._fh.at_close = at_close
        self._w = csv.writer(self._fh, lineterminator="\n")

    monkeypatch.setattr(results.GalleryWriter, "__init__", full_after_a_while)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(dive[0]), "--out", str(out), "-q"])
    one_error_line(res, str(out / "tokens.csv"), "the disk is full")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "tokens.csv" in summary["reason"]
    n = summary["frames_processed"]
    assert n == 60 if at_close else 0 < n < 60
    rows = (out / "trajectory.csv").read_text().splitlines()
    # every processed frame is there (and the one in hand when tokens.csv failed), each row complete
    assert 1 + n <= len(rows) <= 2 + n and rows[-1].count(",") == rows[0].count(",")
    assert len((out / "trajectory.tum").read_text().splitlines()) == len(rows)
    assert (out / "landmarks.csv").read_text().startswith("id,x_m,y_m")


def test_a_revisit_crop_opencv_cannot_write_names_the_file(dive, tmp_path, monkeypatch):
    import rovslam.io.output as output

    real = output._write_all

    def full_for_crops(fd, data):  # the disk is full when a revisit crop is written (crops are written whole)
        if "/revisits/" in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd, data)

    monkeypatch.setattr(output, "_write_all", full_for_crops)
    out = tmp_path / "o"
    res = runner.invoke(app, ["run", str(dive[0]), "--out", str(out), "-q"])
    line = one_error_line(res, str(out / "revisits"), ".png: cannot write the revisit crop", "free space")
    assert "choose another --out" in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "revisit crop" in summary["reason"]
    assert 1 + summary["frames_processed"] <= len((out / "trajectory.csv").read_text().splitlines())


# --------------------------------------------------------------------------- D2: an interrupted batch keeps finished cells


def test_an_interrupted_batch_tables_hold_a_cell_finished_but_not_gathered(tmp_path, monkeypatch):
    import rovslam.batch as batch
    from rovslam.batch import load_matrix, run_matrix

    class Closable:
        def close(self):
            pass

    monkeypatch.setattr(batch, "_connect", lambda scheduler, workers: (Closable(), None))

    def interrupted(client, todo, cells_dir, keep, rows, report, on_cell, save):
        # the worker wrote the first cell's result.json; Ctrl-C came before the client gathered it
        done = {**batch.pending_row(todo[0]), "status": "ok", "ate_rmse_m": 0.02}
        (cells_dir / todo[0].cell_id).mkdir(parents=True)
        (cells_dir / todo[0].cell_id / "result.json").write_text(json.dumps({"row": done, "evaluation": {}}))
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "_run_cells", interrupted)
    m = tmp_path / "m.toml"
    m.write_text('seeds = [0, 1, 2]\n[[scenario]]\nname = "portofino-short"\nframes = 5\n')
    report = run_matrix(load_matrix(m), tmp_path / "o")
    assert report.interrupted and report.computed == ["portofino-short_s0"]
    assert [r["status"] for r in report.rows] == ["ok", "pending", "pending"]
    with open(tmp_path / "o" / "matrix.csv", newline="") as fh:
        table = {r["cell"]: r for r in csv.DictReader(fh)}
    assert table["portofino-short_s0"]["status"] == "ok" and float(table["portofino-short_s0"]["ate_rmse_m"]) == 0.02
    assert table["portofino-short_s1"]["status"] == "pending"
    md = (tmp_path / "o" / "matrix.md").read_text()
    assert "| portofino-short | 1/3 |" in md
    assert "Not run yet (the batch was interrupted): portofino-short_s1, portofino-short_s2." in md


# --------------------------------------------------------------------------- D4: unknown frames.csv columns


def _add_columns(seq: Path, names: str, value: str) -> None:
    p = seq / "frames.csv"
    lines = p.read_text().splitlines()
    p.write_text("\n".join([lines[0] + "," + names] + [x + "," + value for x in lines[1:]]) + "\n")


@pytest.mark.parametrize(
    "names,value",
    [
        ("roll_deg,pitch_deg", "5,0"),
        ("rol_rad,pich_rad", "0.2,0.2"),
        ("roll_rad,pich_rad", "0.2,0.2"),
        ("heading_deg", "12"),
        ("sonar_alt_m", "1.3"),
    ],
)
def test_unknown_frames_columns_are_refused_with_the_known_ones_listed(tmp_path, names, value):
    import shutil

    import fuzz_corpus as fc

    seq = fc.write_sequence(tmp_path / "seq")
    _add_columns(seq, names, value)
    res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "-q"])
    unknown = [n for n in names.split(",") if n not in ("roll_rad", "pitch_rad")]
    one_error_line(
        res, str(seq / "frames.csv"), *(f"'{n}'" for n in unknown), "optional roll_rad,pitch_rad", "rename or remove"
    )
    assert not (tmp_path / "o").exists()
    shutil.rmtree(seq)


def test_other_extra_frames_columns_are_ignored_as_before(tmp_path):
    import fuzz_corpus as fc

    from rovslam.io.sequence import open_sequence

    seq = fc.write_sequence(tmp_path / "seq")
    _add_columns(seq, "depth_m,lat,lon,temperature_c", "12.5,44.3,9.2,14.0")
    assert len(open_sequence(seq)) > 0 and not open_sequence(seq).has_attitude


def test_every_sequence_rovslam_writes_is_still_read(tmp_path):
    import fuzz_corpus as fc

    from rovslam.io.sequence import open_sequence
    from rovslam.sim import simulate

    simulate("portofino-short", tmp_path / "level", frames=3, seed=0)
    simulate("swell", tmp_path / "tilted", frames=3, seed=0)  # writes roll_rad, pitch_rad
    assert open_sequence(tmp_path / "tilted").has_attitude
    assert len(open_sequence(tmp_path / "level")) == 3
    seq = fc.write_sequence(tmp_path / "with_att")
    _add_columns(seq, "roll_rad,pitch_rad", "0.01,-0.02")
    assert open_sequence(seq).rows[0].roll_rad == 0.01


# --------------------------------------------------------------------------- D6, D7: damaged results folders


def _copy_run(out: Path, dest: Path) -> Path:
    import shutil

    shutil.copytree(out, dest)
    return dest


def test_a_cut_trajectory_of_a_complete_run_is_refused(dive, tmp_path):
    r = _copy_run(dive[1], tmp_path / "r")
    (r / "trajectory.csv").write_bytes((dive[1] / "trajectory.csv").read_bytes()[:3000])
    res = runner.invoke(app, ["eval", str(r), "-g", str(dive[0] / "groundtruth.csv")])
    one_error_line(
        res,
        str(r / "trajectory.csv"),
        "rows, but summary.json says the run (complete) processed 60 frames",
        "cut short",
        "--overwrite",
    )


def test_a_missing_landmarks_file_is_refused_when_the_run_mapped_some(dive, tmp_path):
    r = _copy_run(dive[1], tmp_path / "r")
    (r / "landmarks.csv").unlink()
    for args in (["eval", str(r), "-g", str(dive[0] / "groundtruth.csv")], ["report", str(r), "-q"]):
        res = runner.invoke(app, args)
        one_error_line(
            res,
            str(r / "landmarks.csv"),
            "missing, but summary.json says the run mapped 6 landmarks",
            "copy the file back",
        )


def test_eval_of_an_interrupted_run_says_it_was_partial(dive, tmp_path):
    r = _copy_run(dive[1], tmp_path / "r")
    lines = (r / "trajectory.csv").read_text().splitlines()
    (r / "trajectory.csv").write_text("\n".join(lines[:31]) + "\n")  # 30 frames, as an interrupted run leaves them
    summary = json.loads((r / "summary.json").read_text())
    summary.update(status="interrupted", complete=False, interrupted=True, signal="SIGINT", frames_processed=30)
    (r / "summary.json").write_text(json.dumps(summary))
    res = runner.invoke(app, ["eval", str(r), "-g", str(dive[0] / "groundtruth.csv")])
    assert res.exit_code == 0, res.output
    assert (
        "note: the run was interrupted by SIGINT after 30 of 60 frames: these figures cover those 30 frames only"
        in " ".join(res.output.split())
    )  # rich wraps the line at the terminal's width
    figures = json.loads((r / "eval.json").read_text())
    assert figures["frames"] == 30 and "interrupted by SIGINT after 30 of 60 frames" in figures["partial_run"]


# --------------------------------------------------------------------------- D5: another dive's sequence


@pytest.fixture(scope="module")
def other_dive(tmp_path_factory):
    root = tmp_path_factory.mktemp("other")
    res = runner.invoke(
        app,
        [
            "simulate",
            "--scenario",
            "rough-turns-short",
            "--frames",
            "60",
            "--seed",
            "1",
            "--out",
            str(root / "seq"),
            "-q",
        ],
    )
    assert res.exit_code == 0, res.output
    return root / "seq"


def _fewer_frames(seq: Path, dest: Path, n: int) -> Path:
    import shutil

    shutil.copytree(seq, dest)
    lines = (dest / "frames.csv").read_text().splitlines()
    (dest / "frames.csv").write_text("\n".join(lines[: n + 1]) + "\n")
    return dest


@pytest.mark.parametrize("command", ["mosaic", "report", "eval"])
def test_another_dives_sequence_is_refused_naming_both(dive, other_dive, tmp_path, command):
    seq, out = dive
    option = "--sequence" if command == "eval" else "--seq"
    args = {
        "mosaic": ["mosaic", str(out), "--seq", str(other_dive), "--out", str(tmp_path / "m.png"), "-q"],
        "report": ["report", str(out), "--seq", str(other_dive), "-q"],
        "eval": [
            "eval",
            str(out),
            "-g",
            str(seq / "groundtruth.csv"),
            "-s",
            str(other_dive),
            "--json",
            str(tmp_path / "e.json"),
        ],
    }[command]
    one_error_line(
        runner.invoke(app, args),
        f"{option} {other_dive}: not the sequence of the run in {out}",
        "named 'rovslam simulate rough-turns-short (seed 1)'",
        "the run's sequence 'rovslam simulate portofino-short (seed 0)'",
        f"summary.json names {seq}",
        "give that run's own sequence folder",
    )
    assert not (tmp_path / "m.png").exists() and not (tmp_path / "e.json").exists()
    short = _fewer_frames(seq, tmp_path / "short", 40)  # the same dive's name, 40 of its 60 frames
    line = one_error_line(
        runner.invoke(app, [a if a != str(other_dive) else str(short) for a in args]),
        "it has 40 frames, the run's sequence 60",
    )
    assert "named" not in line


def test_the_runs_sequence_moved_elsewhere_is_accepted(dive, tmp_path):
    import shutil

    seq, out = dive
    moved = shutil.copytree(seq, tmp_path / "moved")
    res = runner.invoke(app, ["mosaic", str(out), "--seq", str(moved), "--out", str(tmp_path / "m.png"), "-q"])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "m.png").stat().st_size > 1000


# --------------------------------------------------------------------------- D8: a ground truth not at the origin


def test_a_ground_truth_in_other_coordinates_is_shifted_to_the_runs_origin_with_a_note(dive, tmp_path):
    seq, out = dive
    moved = tmp_path / "gt_utm.csv"  # the same truth in UTM-like coordinates: 500 km east, 4.9e6 m north
    with open(seq / "groundtruth.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    with open(moved, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(
            {**r, "x_m": repr(float(r["x_m"]) + 4_900_000.0), "y_m": repr(float(r["y_m"]) + 500_000.5)} for r in rows
        )
    res = runner.invoke(app, ["eval", str(out), "-g", str(seq / "groundtruth.csv"), "--json", str(tmp_path / "a.json")])
    assert res.exit_code == 0, res.output
    assert "shifted" not in res.output
    res = runner.invoke(app, ["eval", str(out), "-g", str(moved), "--json", str(tmp_path / "b.json")])
    assert res.exit_code == 0, res.output
    assert (
        "note: the ground truth at the run's first frame is at x = 4900000.000 m, y = 500000.500 m, not at the "
        "origin where the run starts: it was shifted by (-4900000.000, -500000.500) m to start there"
    ) in " ".join(res.output.split())
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    assert b["groundtruth_shift_m"] == [-4_900_000.0, -500_000.5] and a["groundtruth_shift_m"] == [0.0, 0.0]
    assert a["slam"]["ate_rmse_m"] < 0.01
    assert b["slam"]["ate_rmse_m"] == pytest.approx(a["slam"]["ate_rmse_m"], abs=1e-6)  # not 4.9e6 m
    assert b["consistency"]["coverage_2sigma"] == a["consistency"]["coverage_2sigma"]


# --------------------------------------------------------------------------- D1: Ctrl-C during the start-up imports


def test_ctrl_c_while_the_cli_is_imported_exits_130_without_a_traceback(monkeypatch, capsys):
    import builtins
    import sys
    import tomllib

    import rovslam.__main__ as entry
    import rovslam.cli as cli

    with open(Path(__file__).parents[1] / "pyproject.toml", "rb") as fh:
        assert tomllib.load(fh)["project"]["scripts"]["rovslam"] == "rovslam.__main__:main"
    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name == "rovslam.cli":
            raise KeyboardInterrupt  # Ctrl-C while typer and rich load
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "rovslam.cli", raising=False)
    monkeypatch.setattr(builtins, "__import__", interrupted)
    with pytest.raises(SystemExit) as stop:
        entry.main()
    assert stop.value.code == 130
    monkeypatch.setattr(builtins, "__import__", real_import)
    monkeypatch.setitem(sys.modules, "rovslam.cli", cli)  # the module the other tests use, not a second copy
    out = capsys.readouterr()
    assert out.out == "" and out.err == ""
    monkeypatch.setattr(sys, "argv", ["rovslam", "--version"])
    with pytest.raises(SystemExit) as done:
        entry.main()
    assert done.value.code == 0 and capsys.readouterr().out.startswith("rovslam 0.")


# --------------------------------------------------------------------------- D9: messages that said the wrong thing


@pytest.fixture
def image_folder(tmp_path):
    import fuzz_corpus as fc

    folder = fc.write_image_folder(tmp_path / "imgs")
    (tmp_path / "cam.toml").write_text(fc.CAMERA_FILE)
    return folder, tmp_path / "cam.toml"


def _run_folder(folder, cam, out, *extra):
    return runner.invoke(app, ["run", str(folder), "--camera", str(cam), "--out", str(out), "-q", *extra])


def test_d9a_a_times_file_with_only_a_header_is_named(image_folder, tmp_path):
    times = tmp_path / "t.csv"
    times.write_text("image,t_s\n")
    one_error_line(
        _run_folder(*image_folder, tmp_path / "o", "--times", str(times)),
        f"{times}: lists no images (only a header)",
        "add one row image,t_s per image",
    )


@pytest.mark.parametrize("fps", ["0", "-5"])
def test_d9i_fps_must_be_above_zero(image_folder, tmp_path, fps):
    one_error_line(_run_folder(*image_folder, tmp_path / "o", "--fps", fps), "above 0 and at most 10000")


def test_d9j_fps_and_times_together_are_told_apart_from_neither(image_folder, tmp_path):
    times = tmp_path / "t.csv"
    times.write_text("image,t_s\nframe1.png,0\n")
    one_error_line(
        _run_folder(*image_folder, tmp_path / "o", "--fps", "5", "--times", str(times)),
        "give --fps or --times, one of the two, not both",
    )
    line = one_error_line(_run_folder(*image_folder, tmp_path / "o"), "--fps F or --times FILE")
    assert "not both" not in line


def test_d9b_the_coarser_scale_suggested_is_one_the_mosaic_accepts(dive, tmp_path):
    line = one_error_line(
        runner.invoke(app, ["mosaic", str(dive[1]), "--mm-per-px", "0.0001", "--out", str(tmp_path / "m.png"), "-q"]),
        "give a coarser --mm-per-px",
    )
    suggested = float(line.rsplit("(e.g. ", 1)[1].rstrip(")"))  # was "0.0", itself refused
    side_px = max(int(v) for v in line.split("would be ", 1)[1].split(" px", 1)[0].split("x"))
    assert 0.0001 * side_px / 40_000 < suggested < 0.0001 * side_px / 30_000  # fits, and not much coarser


def test_d9c_a_file_where_the_report_folder_goes_is_named(dive, tmp_path):
    r = _copy_run(dive[1], tmp_path / "r")
    (r / "report").write_text("notes")
    one_error_line(runner.invoke(app, ["report", str(r), "-q"]), f"{r / 'report'}: is a file", "move or delete it")


@pytest.mark.parametrize(
    "header,needle",
    [
        ("t_s;image;heading_rad;sonar_altitude_m", "separated by ';': use commas"),
        ("t_s\timage\theading_rad\tsonar_altitude_m", "separated by tabs: use commas"),
        ("T_S,IMAGE,HEADING_RAD,SONAR_ALTITUDE_M", "Column names are lower case"),
    ],
)
def test_d9d_a_header_of_another_dialect_is_quoted_with_a_hint(tmp_path, header, needle):
    import fuzz_corpus as fc

    seq = fc.write_sequence(tmp_path / "seq")
    lines = (seq / "frames.csv").read_text().splitlines()
    sep = ";" if ";" in header else "\t" if "\t" in header else ","
    (seq / "frames.csv").write_text("\n".join([header] + [x.replace(",", sep) for x in lines[1:]]) + "\n")
    one_error_line(
        runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "-q"]),
        f"{seq / 'frames.csv'}: header is missing column(s)",
        "it reads 'T_S" if "T_S" in header else "it reads 't_s",
        needle,
    )


def test_d9e_a_ground_truth_that_does_not_cover_the_run_is_named(dive, tmp_path):
    gt = tmp_path / "gt.csv"
    gt.write_text("\n".join((dive[0] / "groundtruth.csv").read_text().splitlines()[:30]) + "\n")
    one_error_line(
        runner.invoke(app, ["eval", str(dive[1]), "-g", str(gt), "--json", str(tmp_path / "e.json")]),
        f"{gt}: ground truth has no row at t_s=",
        "give the groundtruth.csv of the sequence that was run",
    )


def test_d9f_an_image_cell_naming_a_folder_says_so(tmp_path):
    import fuzz_corpus as fc

    seq = fc.write_sequence(tmp_path / "seq")
    fc.set_cell(seq / "frames.csv", 3, "image", "images")
    one_error_line(
        runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "o"), "-q"]),
        "line 4: image file 'images' is a folder, not an image file",
    )


def test_d9g_smooth_tells_a_sequence_folder_and_a_cut_file_from_an_old_run(dive, tmp_path):
    one_error_line(
        runner.invoke(app, ["smooth", str(dive[0]), "-q"]),
        f"{dive[0]}: not the --out folder of a `rovslam run` (no trajectory.csv, no summary.json)",
    )
    r = _copy_run(dive[1], tmp_path / "r")
    (r / "measurements.csv").write_bytes(b"")
    one_error_line(
        runner.invoke(app, ["smooth", str(r), "-q"]),
        f"{r / 'measurements.csv'}: empty file",
        "cut short",
        "--overwrite",
    )
    (r / "measurements.csv").unlink()  # a run folder without the file: made by an older rovslam
    one_error_line(runner.invoke(app, ["smooth", str(r), "-q"]), "does not write measurements")


def test_d9h_a_missing_summary_is_not_called_a_summary_naming_no_sequence(dive, tmp_path):
    r = _copy_run(dive[1], tmp_path / "r")
    (r / "summary.json").unlink()
    one_error_line(
        runner.invoke(app, ["mosaic", str(r), "-q"]),
        f"{r / 'summary.json'} is missing (or empty), so the run's sequence is unknown",
        "--seq",
    )


def test_d9k_a_folder_given_as_configuration_is_called_a_folder(dive, tmp_path):
    one_error_line(
        runner.invoke(app, ["run", str(dive[0]), "-c", str(tmp_path), "--out", str(tmp_path / "o"), "-q"]),
        f"{tmp_path}: is a folder; -c needs a TOML file",
    )


# --------------------------------------------------------------------------- D10: a gap in the frame times


def test_a_gap_in_the_frame_times_is_a_warning_with_its_length(dive, tmp_path):
    seq, _ = dive
    gapped = tmp_path / "seq"
    shutil.copytree(seq, gapped)
    rows = list(csv.DictReader(open(gapped / "frames.csv")))
    for r in rows[30:]:
        r["t_s"] = str(float(r["t_s"]) + 1000.0)  # a clock jump of 1000 s between frames 29 and 30
    with open(gapped / "frames.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    res = runner.invoke(app, ["run", str(gapped), "--out", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 0, res.output
    assert "1 gap(s) in the frame times, the longest 1000.2 s before frame 30" in " ".join(res.output.split())
    gaps = json.loads((tmp_path / "out" / "summary.json").read_text())["time_gaps"]
    assert [(g["frame"], round(g["gap_s"], 3)) for g in gaps["gaps"]] == [(30, 1000.2)]
    # the dive as it was: no gap, no warning
    plain = json.loads((dive[1] / "summary.json").read_text())["time_gaps"]
    assert plain == {"gaps": [], "warnings": []}


# --------------------------------------------------------------------------- D10: a laser pointer out of view


def test_a_laser_whose_spot_is_never_in_the_image_is_named(dive, tmp_path):
    seq, _ = dive
    moved = tmp_path / "seq"
    shutil.copytree(seq, moved)
    toml = (moved / "sequence.toml").read_text()
    first = toml.index("origin_m = [")
    start = toml.index("0.05", first)
    (moved / "sequence.toml").write_text(toml[:start] + "5.0" + toml[start + 4 :])  # 5 m forward: millimetres meant?
    res = runner.invoke(app, ["run", str(moved), "--out", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "the spot of [[laser]] #1 (origin_m [5.0, 0.05, 0.0])" in text and "never falls inside the image" in text
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert any("[[laser]] #1" in w for w in summary["sources"]["warnings"])
    # the rig as simulated: every spot is in view at some altitude, no such warning
    plain = json.loads((dive[1] / "summary.json").read_text())
    assert not any("[[laser]]" in w for w in plain["sources"]["warnings"])


_DEEP = "distortion = " + "[" * 5000 + "]" * 5000 + "\n"  # tomllib recurses once a level


@pytest.mark.parametrize("which", ["sequence", "config", "matrix"])
def test_a_toml_file_nested_thousands_deep_is_a_bad_file_not_an_internal_error(dive, tmp_path, which):
    seq, _ = dive
    if which == "sequence":
        bad = tmp_path / "seq"
        shutil.copytree(seq, bad)
        text = (bad / "sequence.toml").read_text()
        (bad / "sequence.toml").write_text(text.replace("[camera]\n", "[camera]\n" + _DEEP, 1))
        res = runner.invoke(app, ["run", str(bad), "--out", str(tmp_path / "out"), "-q"])
        target = bad / "sequence.toml"
    elif which == "config":
        target = tmp_path / "deep.toml"
        target.write_text("[odometry]\n" + _DEEP)
        res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "out"), "--config", str(target), "-q"])
    else:
        target = tmp_path / "matrix.toml"
        target.write_text(_DEEP)
        res = runner.invoke(app, ["batch", str(target), "--out", str(tmp_path / "out")])
    one_error_line(res, str(target), "not valid TOML", "nested too deeply")


def test_a_laser_skirt_no_memory_holds_is_refused_at_load(dive, tmp_path):
    # [laser] spot_skirt_px = 1e6 reached OpenCV as a 2-million-pixel disc (4 TB): an internal error
    seq, _ = dive
    cfg = tmp_path / "skirt.toml"
    cfg.write_text("[laser]\nspot_skirt_px = 1e6\n")
    res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "out"), "--config", str(cfg), "-q"])
    one_error_line(res, str(cfg), "[laser] spot_skirt_px", "<= 100")


def test_a_frame_rate_or_time_no_clock_gives_is_named_not_an_overflow(image_folder, tmp_path):
    # --fps 1e-300 and a times file with t_s = 1e308 overflowed the altitude filter's step (an internal error)
    folder, cam = image_folder
    one_error_line(_run_folder(folder, cam, tmp_path / "a", "--fps", "1e-300"), "--fps 1e-300", "frames per second")
    names = sorted(p.name for p in folder.iterdir())
    times = tmp_path / "times.csv"
    times.write_text(
        "image,t_s\n" + "".join(f"{n},{0 if k == 0 else 1e308 * k / len(names)}\n" for k, n in enumerate(names))
    )
    one_error_line(
        _run_folder(folder, cam, tmp_path / "b", "--times", str(times)), str(times), "line 3", "no clock's time"
    )


def test_simulate_refuses_more_frames_than_a_dive_holds(tmp_path):
    res = runner.invoke(
        app, ["simulate", "--scenario", "portofino-short", "--frames", "10000000000", "--out", str(tmp_path / "s")]
    )
    one_error_line(res, "at most 1,000,000")
    assert not (tmp_path / "s").exists()


def test_mosaic_and_report_of_a_damaged_map_or_summary_still_draw(dive, tmp_path):
    # a landmark at 1e12 m made cv2.drawMarker fail; "software": null in summary.json broke the report
    seq, out = dive
    bad = tmp_path / "out"
    shutil.copytree(out, bad)
    with open(bad / "landmarks.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    rows[0]["x_m"] = "1e12"
    with open(bad / "landmarks.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    summary = json.loads((bad / "summary.json").read_text())
    summary["software"] = None
    (bad / "summary.json").write_text(json.dumps(summary))
    res = runner.invoke(app, ["mosaic", str(bad), "--seq", str(seq)])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["report", str(bad), "--groundtruth", str(seq / "groundtruth.csv"), "--seq", str(seq)])
    assert res.exit_code == 0, res.output
    assert "rovslam ?" in (bad / "report" / "index.html").read_text()


def test_a_landmark_id_given_many_times_is_one_figure():
    from rovslam.cli.report import _landmark_ids

    assert _landmark_ids(",".join(["3", "0"] * 1000)) == [3, 0]


@pytest.mark.parametrize(
    "path,needle", [("/dev/null", "is not a regular file"), ("no-such.toml", "configuration file not found")]
)
def test_a_config_that_is_a_device_is_not_called_missing(dive, tmp_path, path, needle):
    seq, _ = dive
    res = runner.invoke(app, ["run", str(seq), "--out", str(tmp_path / "out"), "--config", path, "-q"])
    one_error_line(res, path, needle)


@pytest.mark.parametrize("z", [1e308, 1e-320])
def test_a_laser_direction_of_extreme_numbers_is_the_same_ray_without_warnings(z):
    """(0, 0, 1e308) is the ray (0, 0, 1): its norm overflowed (1e-320: underflowed), which printed numpy
    warnings and made the rig's spot 'never in view'."""
    import warnings

    import numpy as np

    from rovslam.camera import LaserPointer

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        las = LaserPointer((0.05, 0.05, 0.0), (0.0, 0.0, z))
        assert las.unit_direction.tolist() == [0.0, 0.0, 1.0]
        tilted = LaserPointer((0.05, 0.05, 0.0), (0.1 * z, 0.0, z)).unit_direction
    # 0.1 z is a subnormal number for z = 1e-320: three digits, no more
    assert np.allclose(
        tilted, np.array([0.1, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 1.0]), rtol=1e-15 if z > 1 else 1e-2
    )
    assert LaserPointer((0.0, 0.0, 0.0), (0.0, 0.0, 2.0)).unit_direction.tolist() == [0.0, 0.0, 1.0]
