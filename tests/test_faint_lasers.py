"""Faint laser spots are found, and the altitude is held between readings, not replaced by an assumed one.

The coral preset's lasers are faint and bleed into green: the detector's ``min_red_excess`` found a
spot in 22 % of the frames of its seed-0 dive. Without an altimeter every other frame then took the
assumed altitude: right only because the preset flies at the paper's 1.31 m. With the assumed
altitude 1.8 m (a dive flown lower than configured) the 2-minute dive ended 13 cm off, 4.2 % of
its frames inside 2-sigma; found near their prediction (:func:`rovslam.vision.laser.find_faint_spots`)
the spots give the altitude in 99 % of the frames and the dive 0.9 mm.
"""

from __future__ import annotations

import csv
import json
import shutil

import cv2
import numpy as np
import pytest

from rovslam.config import LaserConfig, RunConfig
from rovslam.eval.metrics import evaluate_run
from rovslam.io.sequence import decode_image
from rovslam.runner import run_sequence
from rovslam.sim import simulate

ASSUMED_WRONG = LaserConfig(assumed_altitude_m=1.8)  # the preset flies at 1.31 m


@pytest.fixture(scope="module")
def coral_without_altimeter(tmp_path_factory):
    """150 frames of the coral preset (seed 0), the sonar column emptied."""
    seq = tmp_path_factory.mktemp("faint") / "seq"
    simulate("coral-repetitive", seq, frames=150, seed=0)
    rows = list(csv.DictReader(open(seq / "frames.csv")))
    for r in rows:
        r["sonar_altitude_m"] = ""
    with open(seq / "frames.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return seq


def _sources(run) -> list[str]:
    return [r["altitude_source"] for r in csv.DictReader(open(run / "trajectory.csv"))]


def test_faint_spots_give_the_altitude_without_an_altimeter(coral_without_altimeter, tmp_path):
    seq = coral_without_altimeter
    run_sequence(seq, tmp_path / "run", RunConfig(laser=ASSUMED_WRONG))
    ev = evaluate_run(tmp_path / "run", seq / "groundtruth.csv")
    src = _sources(tmp_path / "run")
    assert src.count("laser") >= 0.9 * len(src) and "fixed" not in src
    # Measured: ATE RMSE 0.042 cm (100 % inside 2-sigma), by this test's dive and run then evaluate_run;
    # bound at 2.6 times that, and above a third of it.
    assert 0.00014 < ev.slam.ate_rmse_m < 0.0011
    assert ev.consistency.coverage_2sigma >= 0.95
    # control: the bright spots alone leave most frames to the assumed altitude
    off = RunConfig(laser=LaserConfig(assumed_altitude_m=1.8, faint_red_excess=0.0))
    run_sequence(seq, tmp_path / "off", off)
    ev_off = evaluate_run(tmp_path / "off", seq / "groundtruth.csv")
    assert _sources(tmp_path / "off").count("laser") < 0.5 * len(src)
    assert ev_off.slam.ate_rmse_m > 5 * ev.slam.ate_rmse_m  # measured: 0.38 mm, 100 % inside -> 17 mm, 62 %


def test_frames_without_a_spot_hold_the_filtered_altitude(coral_without_altimeter, tmp_path):
    seq = tmp_path / "seq"
    shutil.copytree(coral_without_altimeter, seq)
    rows = list(csv.DictReader(open(seq / "frames.csv")))
    gap = range(60, 66)  # 1.2 s without a laser (the light blocked, a dark patch)
    for k in gap:
        path = seq / rows[k]["image"]
        rgb = decode_image(path.read_bytes(), str(path))
        rgb[..., 0] = np.minimum(rgb[..., 0], np.maximum(rgb[..., 1], rgb[..., 2]))  # no red dominance left
        cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    run_sequence(seq, tmp_path / "run", RunConfig(laser=ASSUMED_WRONG))
    traj = list(csv.DictReader(open(tmp_path / "run" / "trajectory.csv")))
    truth = list(csv.DictReader(open(seq / "groundtruth.csv")))
    for k in gap:
        assert traj[k]["altitude_source"] == "held"
        err = float(traj[k]["altitude_m"]) - float(truth[k]["altitude_m"])
        assert abs(err) < 3 * float(traj[k]["altitude_sigma_m"]) and abs(err) < 0.01, (k, err)
    assert float(traj[gap[-1]]["altitude_sigma_m"]) > float(traj[gap[0]]["altitude_sigma_m"])  # it grows
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["sources"]["altitude"]["frames"]["held between readings"] == len(gap)
