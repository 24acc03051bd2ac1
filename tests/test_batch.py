"""`rovslam batch`: the matrix file, the tables, and a small matrix through Dask's local cluster."""

from __future__ import annotations

import csv

import pytest
from typer.testing import CliRunner

from rovslam.batch import load_matrix, run_matrix, summarise
from rovslam.batch.table import matrix_markdown
from rovslam.cli import app
from rovslam.errors import ConfigError


def _matrix(tmp_path, text, name="m.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


# --------------------------------------------------------------------------- the matrix file


def test_matrix_cells_seeds_frames_and_relative_paths(tmp_path):
    (tmp_path / "fast.toml").write_text("[tracker]\nmin_correlation = 0.8\n")
    p = _matrix(
        tmp_path,
        """
name = "demo"
seeds = 3
[[scenario]]
name = "portofino-short"
frames = 120
[[scenario]]
name = "rough-turns-short"
duration_s = 30.0
format = "jpg"
seeds = [7]
config = "fast.toml"
label = "rough-fast"
[[sequence]]
name = "my-dive"
path = "dives/d1"
frames = 50
""",
    )
    m = load_matrix(p)
    assert m.name == "demo"
    assert [c.cell_id for c in m.cells] == [
        "portofino-short_s0",
        "portofino-short_s1",
        "portofino-short_s2",
        "rough-fast_s7",
        "my-dive",
    ]
    assert m.groups == ("portofino-short", "rough-fast", "my-dive")
    assert m.cells[0].frames == 120 and m.cells[0].config.tracker.min_correlation == 0.89
    rough = m.cells[3]
    assert rough.scenario == "rough-turns-short" and rough.frames == 150  # 30 s at 5 Hz
    assert rough.image_format == "jpg" and m.cells[0].image_format == "png"
    assert rough.config.tracker.min_correlation == 0.8 and rough.config_path == str(tmp_path / "fast.toml")
    seq = m.cells[4]
    assert not seq.simulated and seq.frames == 50
    assert seq.sequence_path == str(tmp_path / "dives" / "d1")
    assert seq.groundtruth_path == str(tmp_path / "dives" / "d1" / "groundtruth.csv")


@pytest.mark.parametrize(
    "text,needle",
    [
        ('[[scenario]]\nname = "atlantis"\n', "unknown scenario 'atlantis'; known: portofino, portofino-short"),
        ('[[scenario]]\nname = "portofino-short"\nframe = 10\n', "[[scenario]] #1: unknown key 'frame'"),
        ('[[scenario]]\nname = "portofino-short"\nframes = 0\n', "frames: must be a whole number >= 1"),
        ('[[scenario]]\nname = "portofino-short"\nformat = "tiff"\n', 'format must be "png" or "jpg"'),
        ('[[scenario]]\nname = "portofino-short"\nframes = 5\nduration_s = 3\n', "frames or duration_s, not both"),
        # 1e308 s was an OverflowError ("internal error"); 1e12 frames asked 149 GiB in the worker
        (
            '[[scenario]]\nname = "portofino-short"\nduration_s = 1e308\n',
            "inf frames to simulate, more than the 1,000,000",
        ),
        ('[[scenario]]\nname = "portofino-short"\nframes = 1000000000000\n', "1e+12 frames to simulate"),
        ('[[scenario]]\nname = "portofino-short"\nduration_s = 1e9\n', "give a shorter duration_s"),
        ('seeds = [1, 1]\n[[scenario]]\nname = "portofino-short"\n', "a seed appears twice"),
        ('seeds = [-1]\n[[scenario]]\nname = "portofino-short"\n', "list of whole numbers >= 0"),
        ('[[scenario]]\nname = "portofino-short"\n[[scenario]]\nname = "portofino-short"\n', "appears twice"),
        ('[[scenario]]\nname = "portofino-short"\nconfig = "nope.toml"\n', "nope.toml: configuration file not found"),
        ('[[sequence]]\nname = "a b"\npath = "x"\n', "a folder name"),
        ('[[scenario]]\nname = "portofino-short"\nrelief_scale = 2\n', "relief_scale: this scenario has a flat seabed"),
        ('[[scenario]]\nname = "portofino-relief"\nrelief_scale = "deep"\n', "relief_scale must be a number >= 0"),
        ('[[scenario]]\nname = "portofino-relief"\nrelief_scale = 3\n', "use a scale of at most 1.67"),
        ('name = "empty"\n', "no cells"),
        ("[[scenario]\n", "not valid TOML"),
    ],
)
def test_matrix_mistakes_name_the_file_entry_and_key(tmp_path, text, needle):
    p = _matrix(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_matrix(p)
    assert needle in str(info.value) and str(p.name) in str(info.value)


def test_cli_unknown_scenario_is_one_line_exit_2(tmp_path):
    p = _matrix(tmp_path, '[[scenario]]\nname = "atlantis"\n')
    res = CliRunner().invoke(app, ["batch", str(p), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "unknown scenario 'atlantis'; known: portofino," in lines[0]
    assert "rough-turns-short" in lines[0]
    assert not (tmp_path / "o").exists()  # nothing ran


def test_a_scenario_entry_scales_its_relief(tmp_path):
    p = _matrix(
        tmp_path,
        '[[scenario]]\nname = "portofino-relief"\nlabel = "flat"\nframes = 5\nrelief_scale = 0\n'
        '[[scenario]]\nname = "portofino-relief"\nframes = 5\n',
    )
    flat, base = load_matrix(p).cells
    assert (flat.cell_id, flat.relief_scale) == ("flat_s0", 0.0) and base.relief_scale == 1.0


def test_shipped_matrices_load():
    from pathlib import Path

    smoke = load_matrix(Path(__file__).parents[1] / "matrices" / "smoke.toml")
    relief = load_matrix(Path(__file__).parents[1] / "matrices" / "relief.toml")
    assert {c.relief_scale for c in relief.cells} == {0.0, 1.0, 1.5, 1.6}
    assert len(smoke.cells) == 4 and {c.frames for c in smoke.cells} == {250}
    # The default matrix names the hard presets; every one of them at 10 seeds, 3 to 10 minutes.
    import tomllib

    default = tomllib.loads((Path(__file__).parents[1] / "matrices" / "default.toml").read_text())
    assert default["seeds"] == 10 and len(default["scenario"]) >= 6
    assert all(180 <= s["duration_s"] <= 600 for s in default["scenario"])


# --------------------------------------------------------------------------- the tables


def _row(group, seed, ate_cm, coverage, status="ok"):
    return {
        "cell": f"{group}_s{seed}",
        "group": group,
        "status": status,
        "error": "" if status == "ok" else "boom",
        "ate_rmse_m": ate_cm / 100,
        "coverage_2sigma": coverage,
        "pc_over_slam": 10.0 / ate_cm,
        "final_error_pct": None,
    }


def test_summary_is_median_and_worst_over_seeds():
    rows = [
        _row("a", 0, 1.0, 0.9),
        _row("a", 1, 3.0, 0.5),
        _row("a", 2, 2.0, 0.7),
        _row("a", 3, 99.0, 0, "failed"),
        _row("b", 0, 0.5, 1.0),
    ]
    a, b = summarise(rows)
    assert (a.group, a.cells, a.ok) == ("a", 4, 3)
    assert a.median["ate_rmse_m"] == pytest.approx(0.02) and a.worst["ate_rmse_m"] == pytest.approx(0.03)
    assert a.median["coverage_2sigma"] == pytest.approx(0.7) and a.worst["coverage_2sigma"] == pytest.approx(0.5)
    assert a.worst["pc_over_slam"] == pytest.approx(10.0 / 3.0)  # the baseline closest to SLAM
    assert a.worst_cell == "a_s1"
    assert a.median["final_error_pct"] is None and a.median["landmarks"] is None  # not computed: n/a
    assert b.ok == 1 and b.median["ate_rmse_m"] == b.worst["ate_rmse_m"]
    md = matrix_markdown("t", rows)
    assert "| a | 3/4 | 2.00 / 3.00 |" in md
    assert "| a_s3 | boom |" in md and "n/a / n/a" in md


# --------------------------------------------------------------------------- through Dask


def test_matrix_runs_on_a_local_dask_cluster_resumes_and_survives_a_failing_cell(tmp_path):
    p = _matrix(
        tmp_path,
        """
seeds = [0, 1]
[[scenario]]
name = "portofino-short"
frames = 60
[[sequence]]
name = "missing"
path = "no/such/sequence"
""",
    )
    out = tmp_path / "batch"
    seen = []
    report = run_matrix(load_matrix(p), out, workers=2, on_cell=seen.append)
    assert sorted(report.computed) == ["missing", "portofino-short_s0", "portofino-short_s1"]
    assert report.reused == [] and not report.interrupted
    assert sorted(r["cell"] for r in seen) == sorted(report.computed)
    ok = {r["cell"]: r for r in report.rows if r["status"] == "ok"}
    assert set(ok) == {"portofino-short_s0", "portofino-short_s1"}
    for r in ok.values():
        assert r["frames"] == 60 and 0 < r["ate_rmse_m"] < 0.01
        assert r["pc_ate_rmse_m"] > 0 and r["dr_ate_rmse_m"] > 0 and r["max_error_jump_sigma"] > 0
        assert (
            0 < r["max_error_jump_before_sigma"] <= r["max_error_jump_sigma"] * (1 + 1e-9)
        )  # the ellipse before is never smaller
        assert 0.5 < r["landmarks_found"] <= 1.0  # the paper's seabed: landmarks in view are found again
    (bad,) = report.failed
    assert bad["cell"] == "missing" and "not found" in bad["error"]
    assert "no/such/sequence" in (out / "cells" / "missing" / "error.log").read_text()
    cell0 = out / "cells" / "portofino-short_s0"
    assert (cell0 / "run" / "eval.json").is_file() and not (cell0 / "sequence").exists()  # images deleted
    with (out / "matrix.csv").open() as fh:
        table = list(csv.DictReader(fh))
    assert [t["cell"] for t in table] == ["portofino-short_s0", "portofino-short_s1", "missing"]
    assert table[2]["status"] == "failed" and table[2]["ate_rmse_m"] == ""
    md = (out / "matrix.md").read_text()
    assert "| portofino-short | 2/2 |" in md and "| missing | 0/1 |" in md and "## Failed cells" in md

    # Again, through the CLI: the finished cells are kept, only the failed one runs again.
    done = [out / "cells" / f"portofino-short_s{s}" / "result.json" for s in (0, 1)]
    mtimes = [d.stat().st_mtime_ns for d in done]
    res = CliRunner().invoke(app, ["batch", str(p), "--out", str(out), "--workers", "1", "--quiet"])
    # A cell failed on bad input (its sequence is missing): exit 2, the tables are written all the same
    assert res.exit_code == 2, res.output
    assert "Traceback" not in (out / "cells" / "missing" / "error.log").read_text()
    assert "kept 2 finished cells; ran 1 on a local cluster of 1 workers" in res.output
    assert "1 of 3 cells failed" in res.output
    assert [d.stat().st_mtime_ns for d in done] == mtimes  # not recomputed
    assert "| portofino-short | 2/2 |" in (out / "matrix.md").read_text()


def test_local_workers_keep_glibcs_adaptive_malloc():
    from rovslam.batch import worker_environ

    env = worker_environ()
    assert "MALLOC_TRIM_THRESHOLD_" not in env  # 2-3x the CPU of a cell when set (see worker_environ)
    assert env.get("OMP_NUM_THREADS") in (1, "1")  # Dask's one-thread settings are kept


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--scheduler", "nonsense"], "--scheduler nonsense: no Dask scheduler answered"),
        (["--workers", "0"], "--workers must be at least 1"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "with --scheduler the cluster is yours to size"),
    ],
)
def test_cli_cluster_mistakes_are_one_line_exit_2(tmp_path, args, needle):
    p = _matrix(tmp_path, '[[scenario]]\nname = "portofino-short"\nframes = 5\n')
    res = CliRunner().invoke(app, ["batch", str(p), "--out", str(tmp_path / "o"), *args])
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and needle in lines[0]
    assert not (tmp_path / "o").exists()


def test_an_interrupted_batch_keeps_tables_with_the_cells_not_run_as_pending(tmp_path, monkeypatch):
    import rovslam.batch as batch

    class Closable:
        closed = False

        def close(self):
            self.closed = True

    client, cluster = Closable(), Closable()
    monkeypatch.setattr(batch, "_connect", lambda scheduler, workers: (client, cluster))

    def interrupted(client, todo, cells_dir, keep, rows, report, on_cell, save):
        rows[todo[0].cell_id] = {**batch.pending_row(todo[0]), "status": "ok", "ate_rmse_m": 0.01}
        report.computed.append(todo[0].cell_id)
        save()
        raise KeyboardInterrupt  # Ctrl-C while the second cell runs

    monkeypatch.setattr(batch, "_run_cells", interrupted)
    p = _matrix(tmp_path, 'seeds = [0, 1]\n[[scenario]]\nname = "portofino-short"\nframes = 5\n')
    report = run_matrix(load_matrix(p), tmp_path / "o")
    assert report.interrupted and report.computed == ["portofino-short_s0"] and report.failed == []
    assert [r["status"] for r in report.rows] == ["ok", "pending"]
    assert client.closed and cluster.closed
    md = (tmp_path / "o" / "matrix.md").read_text()
    assert "| portofino-short | 1/2 | 1.00 / 1.00 |" in md
    assert "Not run yet (the batch was interrupted): portofino-short_s1." in md
