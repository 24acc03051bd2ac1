"""``rovslam eval --reference features``: a run's frame pairs checked against the feature motion, no ground truth.

A short simulated dive: its token motions agree with the feature motions (>= 95 % of the pairs).
The same dive with one bad frame (frame 30 replaced by a turned view of another part of the
seabed: the tokens lose it and the run holds its speed through a large motion): the two pairs
around that frame are the worst listed, with their frame numbers.
"""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from rovslam.errors import InvalidArgumentError
from rovslam.eval.feature_reference import compare_pair, feature_reference, token_motion_px

BAD_FRAME = 30


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    from rovslam.runner import run_sequence
    from rovslam.sim import simulate

    root = tmp_path_factory.mktemp("feature_reference")
    simulate("portofino-short", root / "seq", frames=60, seed=0)
    run_sequence(root / "seq", root / "out")
    return root


@pytest.fixture(scope="module")
def bad_dive(dive):
    """A copy of the dive whose frame 30 shows another part of the seabed (frame 45), turned by 35 degrees."""
    import cv2

    from rovslam.runner import run_sequence

    root = dive / "bad"
    shutil.copytree(dive / "seq", root / "seq")
    image = cv2.imread(str(dive / "seq" / "images" / "000045.png"))
    h, w = image.shape[:2]
    turn = cv2.getRotationMatrix2D(((w - 1) / 2, (h - 1) / 2), 35.0, 1.0)
    bad = cv2.warpAffine(image, turn, (w, h), borderMode=cv2.BORDER_REFLECT)
    cv2.imwrite(str(root / "seq" / "images" / f"{BAD_FRAME:06d}.png"), bad)
    run_sequence(root / "seq", root / "out")
    return root


def test_simulated_dive_agrees_with_the_features(dive):
    ref = feature_reference(dive / "out")
    d = ref.to_dict()
    assert d["pairs"] == 59 and d["compared"] >= 55, d
    assert d["agree_share"] >= 0.95, d
    assert [p.frame - p.frame_prev for p in ref.pairs] == [1] * 59
    moving = [p for p in ref.compared if np.linalg.norm(p.token_px) > 3.0]
    assert len(moving) >= 20  # the dive moves several pixels a frame: the agreement is not about zeros
    assert np.median([p.relative for p in moving]) < 0.05


def test_injected_bad_pair_is_listed_among_the_worst(bad_dive):
    d = feature_reference(bad_dive / "out").to_dict()
    worst = {(row["frame_prev"], row["frame"]): row for row in d["worst"]}
    assert (BAD_FRAME - 1, BAD_FRAME) in worst or (BAD_FRAME, BAD_FRAME + 1) in worst, d["worst"]
    first = d["worst"][0]
    assert BAD_FRAME in (first["frame_prev"], first["frame"]) and not first["agrees"], first
    assert first["relative"] > 1.0  # the features saw a motion several times the one the run used


def test_cli_writes_feature_reference_without_ground_truth(dive, tmp_path):
    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.runner import run_sequence

    run_sequence(dive / "seq", tmp_path / "run", max_frames=12)  # a short run keeps the test short
    res = CliRunner().invoke(app, ["eval", str(tmp_path / "run"), "--reference", "features"])
    assert res.exit_code == 0, res.output
    assert "11 of 11 frame pairs compared" in res.output
    d = json.loads((tmp_path / "run" / "eval.json").read_text())["feature_reference"]
    assert d["agree_share"] >= 0.9 and len(d["worst"]) == 5


def test_cli_needs_a_ground_truth_or_a_reference(dive):
    from typer.testing import CliRunner

    from rovslam.cli import app

    res = CliRunner().invoke(app, ["eval", str(dive / "out")])
    assert res.exit_code == 2
    assert "--groundtruth" in res.output and "--reference features" in res.output
    assert "Traceback" not in res.output
    res = CliRunner().invoke(app, ["eval", str(dive / "out"), "--reference", "phase"])
    assert res.exit_code == 2 and "unknown reference" in res.output


def test_token_motion_in_pixels():
    from rovslam.camera import Camera

    cam = Camera(width_px=360, height_px=272, fx_px=1000.0, fy_px=1000.0, cx_px=179.5, cy_px=135.5)
    # 0.1 m forward in 0.2 s at 2 m: the point now under the centre was 50 px above it (v smaller).
    px, cov = token_motion_px(np.array([0.5, 0.0]), np.diag([1e-4, 4e-4]), 0.2, 2.0, cam)
    np.testing.assert_allclose(px, [0.0, -50.0], atol=1e-12)
    np.testing.assert_allclose(np.diag(cov), [4e-4 * 0.04 * 250000, 1e-4 * 0.04 * 250000])
    px, _ = token_motion_px(np.array([0.0, 0.5]), np.zeros((2, 2)), 0.2, 2.0, cam)  # starboard: to the right
    np.testing.assert_allclose(px, [50.0, 0.0], atol=1e-12)
    with pytest.raises(InvalidArgumentError):
        token_motion_px(np.array([0.5, 0.0]), np.zeros((2, 2)), 0.0, 2.0, cam)


def test_compare_pair():
    rel, maha = compare_pair(np.array([10.0, 0.0]), np.eye(2), np.array([11.0, 0.0]), np.eye(2) * 0.25)
    assert rel == pytest.approx(0.1) and maha == pytest.approx(1.0 / math.sqrt(1.25))


def test_a_speed_from_the_features_is_not_compared_with_them(dive, tmp_path):
    """A frame whose speed the run took from the feature motion would check the method against itself:
    left out and counted (``speed_source = features`` in trajectory.csv)."""
    import csv

    out = tmp_path / "out"
    shutil.copytree(dive / "out", out)
    path = out / "trajectory.csv"
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["speed_source"] for r in rows[1:]} <= {"tokens", ""} and rows[10]["speed_source"] == "tokens"
    rows[10]["speed_source"] = "features"
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    d = feature_reference(out).to_dict()
    assert d["not_compared"].get("speed from the feature motion") == 1, d["not_compared"]
    assert [10 - 1, 10, "speed from the feature motion"] in d["not_compared_pairs"], d["not_compared_pairs"]
