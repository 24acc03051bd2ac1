"""Points-of-interest files: what they hold, and a bad row as one line naming file, line and column (exit 2)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.errors import PoiFormatError
from rovslam.io.poi import read_poi_csv

runner = CliRunner()


def write(tmp_path, text, name="poi.csv"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_points_in_the_map_frame_and_landmark_points_in_one_file(tmp_path):
    p = write(tmp_path, "name,x_m,y_m,landmark_id,hold_s\nrock,0.4,-0.2,,15\nstart,,,0,\n\ncrack,-0.35,0.1,,\n")
    goals = read_poi_csv(p)
    assert [g.name for g in goals] == ["rock", "start", "crack"]
    np.testing.assert_array_equal(goals[0].xy_m, [0.4, -0.2])
    assert goals[0].hold_s == 15.0 and goals[0].landmark_id is None and goals[0].kind == "poi"
    assert goals[1].xy_m is None and goals[1].landmark_id == 0 and goals[1].hold_s is None
    assert goals[2].hold_s is None


def test_the_two_short_forms(tmp_path):
    assert read_poi_csv(write(tmp_path, "name,x_m,y_m\na,1,2\n"))[0].xy_m.tolist() == [1.0, 2.0]
    assert read_poi_csv(write(tmp_path, "name,landmark_id\nback,12\n", "b.csv"))[0].landmark_id == 12


@pytest.mark.parametrize(
    "text,needle",
    [
        ("name,x_m,y_m\na,1,2\nb,one,2\n", "line 3: column 'x_m' is not a number: 'one'"),
        ("name,x_m,y_m\na,1,\n", "line 2: column 'y_m' is empty"),
        ("name,x_m,y_m\na,1,nan\n", "line 2: column 'y_m' is not finite"),
        ("name,x_m,y_m\na,1,2\na,3,4\n", "line 3, column 'name': 'a' is already the name of the point on line 2"),
        ("name,x_m,y_m\n,1,2\n", "line 2, column 'name': empty"),
        ("name,x_m,y_m,hold_s\na,1,2,-5\n", "line 2, column 'hold_s': -5 s is negative"),
        ("name,x_m,y_m\na,1,2000\n", "line 2, column 'y_m': 2000 m is more than 1000 m"),
        ("name,landmark_id\na,2.5\n", "line 2, column 'landmark_id': not a whole number: '2.5'"),
        ("name,landmark_id\na,-1\n", "line 2, column 'landmark_id': -1 is negative"),
        ("name,landmark_id\na,\n", "line 2, column 'landmark_id': empty"),
        ("name,x_m,y_m,landmark_id\na,1,2,3\n", "line 2: both x_m,y_m and landmark_id"),
        ("name,x_m\na,1\n", "only one of x_m, y_m"),
        ("name,hold_s\na,1\n", "needs x_m,y_m or landmark_id"),
        ("x_m,y_m\n1,2\n", "missing column(s) name"),
        ("name,x_m,y_m\n", "no point of interest"),
        ("name,x_m,y_m\na,1,2,3\n", "line 2: 4 fields, the header has 3"),
    ],
)
def test_a_bad_row_is_named(tmp_path, text, needle):
    p = write(tmp_path, text)
    with pytest.raises(PoiFormatError) as err:
        read_poi_csv(p)
    assert str(p) in str(err.value) and needle in str(err.value)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(PoiFormatError, match="missing"):
        read_poi_csv(tmp_path / "nope.csv")


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--poi", "BAD", "--scenario", "portofino"], "line 3: column 'x_m' is not a number"),
        (["--poi", "GOOD", "--scenario", "atlantis"], "unknown preset 'atlantis'"),
        (
            ["--poi", "GOOD", "--scenario", "portofino", "--estimator", "gps"],
            "estimator must be one of slam, dead-reckoning",
        ),
        (
            ["--poi", "GOOD", "--scenario", "portofino", "--survey-s", "-1"],
            "--survey-s must be a number of seconds >= 0",
        ),
        (
            ["--poi", "GOOD", "--scenario", "portofino", "--approach-gain-per-s", "0"],
            "--approach-gain-per-s must be a number > 0 (per second), got 0.0",
        ),
        (
            ["--poi", "GOOD", "--scenario", "portofino", "--approach-gain-per-s", "inf"],
            "--approach-gain-per-s must be a number > 0 (per second), got inf",
        ),
    ],
)
def test_navigate_refuses_bad_input_in_one_line_with_exit_2(tmp_path, args, needle):
    good = write(tmp_path, "name,x_m,y_m\na,0.1,0\n", "good.csv")
    bad = write(tmp_path, "name,x_m,y_m\na,0.1,0\nb,[oops],0\n", "bad.csv")
    args = ["navigate", *[{"BAD": str(bad), "GOOD": str(good)}.get(a, a) for a in args], "--out", str(tmp_path / "o")]
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error:") and needle in lines[0], res.output
    assert not (tmp_path / "o").exists()
