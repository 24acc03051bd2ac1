"""The `rovslam` command as a user runs it: exit codes, one-line errors, files written."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from rovslam.cli import app

runner = CliRunner()


@pytest.fixture(scope="module")
def tiny_seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    res = runner.invoke(app, ["simulate", "--scenario", "portofino-short", "--frames", "60", "--out",
                              str(root / "seq"), "--quiet"])
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
    for name in ("index.html", "map.png", "position.png", "altitude_speed.png", "errors.png"):
        assert (out / "report" / name).stat().st_size > 1000
    res = runner.invoke(app, ["config", str(tmp_path / "c.toml")])
    assert res.exit_code == 0 and "min_correlation = 0.89" in (tmp_path / "c.toml").read_text()


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
