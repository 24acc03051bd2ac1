"""Calibration errors drawn per seed: the same dive with a compass deviation, a laser-rig error, a sonar offset."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.batch import load_matrix
from rovslam.camera import ground_to_pixels
from rovslam.cli import app
from rovslam.errors import ConfigError, SimulationError
from rovslam.io.sequence import open_sequence
from rovslam.sim import PAPER_LASERS, PORTOFINO_CAMERA, CalibrationErrors, DrawnCalibration, draw_calibration, simulate
from rovslam.sim.calibration import recorded_lasers
from rovslam.vision.laser import triangulate_spots


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    root = tmp_path_factory.mktemp("calib")
    simulate("portofino-short", root / "exact", frames=8, seed=3)
    simulate("portofino-short", root / "drawn", frames=8, seed=3, calibration=CalibrationErrors())
    return root / "exact", root / "drawn", draw_calibration(CalibrationErrors(), 3)


def test_the_dive_differs_by_the_drawn_errors_alone(pair):
    exact, drawn, cal = pair
    a, b = _files(exact), _files(drawn)
    assert a.keys() == b.keys()
    same = {k for k in a if a[k] == b[k]}
    assert same == set(a) - {"sequence.toml", "frames.csv"}  # images and ground truth untouched
    sa, sb = open_sequence(exact), open_sequence(drawn)
    dh = np.array([rb.heading_rad - ra.heading_rad for ra, rb in zip(sa.rows, sb.rows)])
    dh = (dh + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(dh, cal.compass_deviation_rad, atol=1e-12)
    ds = np.array([rb.sonar_altitude_m - ra.sonar_altitude_m for ra, rb in zip(sa.rows, sb.rows)])
    np.testing.assert_allclose(ds, cal.sonar_offset_m, atol=0.0011)  # readings rounded to the millimetre
    for la, lb in zip(sa.info.lasers, sb.info.lasers):
        np.testing.assert_allclose(
            np.array(lb.origin_m[:2]) / np.array(la.origin_m[:2]), 1 + cal.laser_baseline_error, rtol=1e-12
        )
        assert lb.origin_m[2] == la.origin_m[2] and lb.direction == la.direction
    meta = sb.info.metadata
    assert meta["calibration_compass_deviation_deg"] == pytest.approx(math.degrees(cal.compass_deviation_rad), abs=1e-4)
    assert meta["calibration_laser_baseline_error"] == pytest.approx(cal.laser_baseline_error, abs=1e-6)
    assert "calibration_compass_deviation_deg" not in sa.info.metadata


@pytest.mark.parametrize("altitude_m", [0.8, 1.31, 2.5])
def test_the_recorded_rig_scales_the_lasers_altitude_by_one_plus_the_error(altitude_m):
    cal = draw_calibration(CalibrationErrors(laser_baseline_sigma=0.02), 11)
    assert abs(cal.laser_baseline_error) > 1e-3
    # the true spots: each parallel pointer's seabed point seen by the camera at this altitude
    ground = np.array([[lp.origin_m[0], lp.origin_m[1]] for lp in PAPER_LASERS])
    spots = ground_to_pixels(PORTOFINO_CAMERA, ground, altitude_m)
    z_true = triangulate_spots(PORTOFINO_CAMERA, PAPER_LASERS, spots)
    z_recorded = triangulate_spots(PORTOFINO_CAMERA, recorded_lasers(PAPER_LASERS, cal), spots)
    np.testing.assert_allclose(z_true, altitude_m, rtol=1e-9)
    np.testing.assert_allclose(z_recorded / z_true, 1 + cal.laser_baseline_error, rtol=1e-9)


def test_draws_are_zero_mean_with_the_given_sigmas():
    errors = CalibrationErrors(compass_deviation_sigma_rad=0.01, laser_baseline_sigma=0.005, sonar_offset_sigma_m=0.02)
    draws = np.array(
        [
            [d.compass_deviation_rad, d.laser_baseline_error, d.sonar_offset_m]
            for d in (draw_calibration(errors, s) for s in range(3000))
        ]
    )
    np.testing.assert_allclose(draws.std(axis=0), [0.01, 0.005, 0.02], rtol=0.06)
    assert np.all(np.abs(draws.mean(axis=0)) < 3 * np.array([0.01, 0.005, 0.02]) / math.sqrt(3000))
    assert abs(np.corrcoef(draws.T)[0, 1]) < 0.06  # independent
    assert draw_calibration(errors, 7) == draw_calibration(errors, 7)
    zero = draw_calibration(CalibrationErrors(0.0, 0.0, 0.0), 7)
    assert (zero.compass_deviation_rad, zero.laser_baseline_error, zero.sonar_offset_m) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"compass_deviation_sigma_rad": -0.1},
        {"laser_baseline_sigma": math.nan},
        {"sonar_offset_sigma_m": math.inf},
        {"laser_baseline_sigma": 0.5},
    ],
)
def test_bad_sigmas_are_refused(kwargs):
    with pytest.raises(SimulationError, match=next(iter(kwargs))):
        CalibrationErrors(**kwargs)


def test_bad_seed_and_calibration_are_refused(tmp_path):
    with pytest.raises(SimulationError, match="seed"):
        draw_calibration(CalibrationErrors(), -1)
    with pytest.raises(SimulationError, match="CalibrationErrors, a DrawnCalibration or None"):
        simulate("portofino-short", tmp_path / "x", frames=2, calibration=0.5)  # type: ignore[arg-type]
    assert not (tmp_path / "x").exists()


def test_cli_flag_records_the_errors(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "simulate",
            "--scenario",
            "portofino-short",
            "--frames",
            "2",
            "--seed",
            "4",
            "--out",
            str(tmp_path / "s"),
            "-q",
            "--calibration-errors",
        ],
    )
    assert res.exit_code == 0, res.output
    meta = open_sequence(tmp_path / "s").info.metadata
    cal = draw_calibration(CalibrationErrors(), 4)
    assert meta["calibration_sonar_offset_m"] == pytest.approx(cal.sonar_offset_m, abs=1e-5)
    assert (
        f"compass {math.degrees(cal.compass_deviation_rad):+.2f} deg, laser rig "
        f"{100 * cal.laser_baseline_error:+.2f} %, sonar {100 * cal.sonar_offset_m:+.2f} cm"
    ) in res.output


def test_matrix_key(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(
        'seeds = [1]\n[[scenario]]\nname = "portofino-short"\nframes = 5\ncalibration_errors = true\n'
        '[[scenario]]\nname = "portofino-short"\nlabel = "exact"\nframes = 5\n'
    )
    cells = load_matrix(p).cells
    assert [c.calibration_errors for c in cells] == [True, False]
    p.write_text('[[scenario]]\nname = "portofino-short"\ncalibration_errors = "yes"\n')
    with pytest.raises(ConfigError, match="calibration_errors must be true or false"):
        load_matrix(p)


def test_given_errors_are_used_as_they_are(tmp_path):
    given = DrawnCalibration(compass_deviation_rad=0.02, laser_baseline_error=-0.015, sonar_offset_m=0.0)
    simulate("portofino-short", tmp_path / "s", frames=2, seed=1, calibration=given)
    meta = open_sequence(tmp_path / "s").info.metadata
    assert meta["calibration_laser_baseline_error"] == -0.015
    assert meta["calibration_compass_deviation_deg"] == pytest.approx(math.degrees(0.02), abs=1e-4)
    with pytest.raises(SimulationError, match="laser_baseline_error"):
        DrawnCalibration(0.0, 0.7, 0.0)
    with pytest.raises(SimulationError, match="sonar_offset_m"):
        DrawnCalibration(0.0, 0.0, math.nan)
