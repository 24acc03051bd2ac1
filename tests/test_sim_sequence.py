"""`simulate`: sequence folders that read back intact, byte-identical per seed; bad arguments rejected."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from rovslam.errors import SimulationError
from rovslam.io.sequence import open_sequence
from rovslam.sim import SCENARIOS, frame_pose, frame_rng, renderer_for, simulate, simulate_trajectory
from rovslam.sim.world import World


@pytest.fixture(scope="module")
def rough_seq(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "rough"
    summary = simulate("rough-turns-short", out, frames=6, seed=5)
    return out, summary


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_writes_byte_identical_files(tmp_path):
    simulate("portofino-short", tmp_path / "a", frames=4, seed=3)
    simulate("portofino-short", tmp_path / "b", frames=4, seed=3)
    simulate("portofino-short", tmp_path / "c", frames=4, seed=4)
    a, b, c = _files(tmp_path / "a"), _files(tmp_path / "b"), _files(tmp_path / "c")
    assert len(a) == 4 + 3  # images + sequence.toml, frames.csv, groundtruth.csv
    assert a == b
    assert a["images/000001.png"] != c["images/000001.png"]


def test_short_preset_is_the_start_of_the_full_trial(tmp_path):
    simulate("portofino", tmp_path / "full", frames=3, seed=2)
    simulate("portofino-short", tmp_path / "short", frames=3, seed=2)
    full, short = _files(tmp_path / "full"), _files(tmp_path / "short")
    for name in ("images/000000.png", "images/000002.png", "frames.csv", "groundtruth.csv"):
        assert full[name] == short[name]


def test_sequence_reads_back_with_all_columns(rough_seq):
    out, summary = rough_seq
    sc = SCENARIOS["rough-turns-short"]
    seq = open_sequence(out)
    assert len(seq) == summary.frames == 6
    assert seq.info.camera == sc.camera
    assert seq.info.lasers == sc.lasers
    assert seq.info.metadata["scenario"] == "rough-turns-short"
    assert seq.info.metadata["seed"] == 5
    assert seq.has_attitude  # the rough preset tilts: roll_rad, pitch_rad written
    traj = simulate_trajectory(sc.vehicle, sc.grid, 6, sc.frame_rate_hz, 5)
    gt = seq.groundtruth
    assert (gt.x_m[0], gt.y_m[0]) == (0.0, 0.0)
    np.testing.assert_allclose(gt.x_m, traj.x_m, atol=1e-12)
    np.testing.assert_allclose(gt.altitude_m, traj.altitude_m, atol=1e-12)
    np.testing.assert_allclose(gt.heading_rad, traj.heading_rad, atol=1e-12)
    world = World.procedural(5, sc.texture)
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots)
    for k, frame in enumerate(seq.frames()):
        assert frame.t_s == pytest.approx(0.2 * k)
        assert frame.image.shape == (272, 360, 3) and frame.image.dtype == np.uint8
        nav = sc.nav
        compass_tol = 5 * (nav.compass_sigma_rad + nav.compass_drift_rad)
        assert abs(np.angle(np.exp(1j * (frame.heading_rad - traj.heading_rad[k])))) < compass_tol
        assert abs(frame.sonar_altitude_m - traj.altitude_m[k]) < 5 * nav.sonar_sigma_m
        tilt_tol = 5 * (nav.attitude_sigma_rad + nav.attitude_drift_rad)
        assert abs(frame.roll_rad - traj.roll_rad[k]) < tilt_tol
        assert abs(frame.pitch_rad - traj.pitch_rad[k]) < tilt_tol
        if k in (0, 5):  # PNG is lossless: the image is the pure render of that frame's pose and noise
            expect = renderer.render(
                world,
                frame_pose(traj, k),
                sc.lasers,
                frame_rng(5, k),
                velocity_mps=(traj.surge_mps[k], traj.sway_mps[k]),
                t_s=traj.t_s[k],
            )
            np.testing.assert_array_equal(frame.image, expect)


def test_level_scenario_has_no_attitude_columns_and_jpeg_works(tmp_path):
    simulate("portofino-short", tmp_path / "s", frames=3, seed=1, image_format="jpg")
    seq = open_sequence(tmp_path / "s")
    assert not seq.has_attitude
    assert seq.rows[0].image.endswith(".jpg")
    assert all(r.sonar_altitude_m is not None for r in seq.rows)
    assert (tmp_path / "s" / "frames.csv").read_text().splitlines()[0] == "t_s,image,heading_rad,sonar_altitude_m"


def test_image_texture_option(tmp_path):
    rng = np.random.default_rng(0)
    photo = cv2.GaussianBlur((rng.random((300, 400, 3)) * 255).astype(np.uint8), (0, 0), 2.0)
    cv2.imwrite(str(tmp_path / "mosaic.png"), photo)
    summary = simulate(
        "portofino-short", tmp_path / "s", frames=2, seed=1, texture_path=tmp_path / "mosaic.png", texture_mm_per_px=2.0
    )
    seq = open_sequence(tmp_path / "s")
    assert "mosaic.png" in seq.info.metadata["texture"]
    assert summary.frames == 2
    # The photo is 0.8 m x 0.6 m: the first frame at the origin shows it without mirroring seams.
    img = next(seq.frames()).image
    assert img.std() > 3


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"scenario": "atlantis"}, "unknown scenario"),
        ({"frames": 0}, "frames"),
        ({"frames": -3}, "frames"),
        ({"seed": -1}, "seed"),
        ({"image_format": "bmp"}, "png or jpg"),
        ({"texture_path": Path("x.png")}, "together"),
        ({"texture_mm_per_px": 1.0}, "together"),
    ],
)
def test_bad_arguments_raise_simulation_error(tmp_path, kwargs, message):
    args = {"scenario": "portofino-short", "out_dir": tmp_path / "s", "frames": 2} | kwargs
    with pytest.raises(SimulationError, match=message):
        simulate(**args)
    assert not (tmp_path / "s").exists()  # nothing written


def test_texture_that_is_not_an_image_and_non_empty_output(tmp_path):
    (tmp_path / "notes.txt").write_text("not an image")
    with pytest.raises(SimulationError, match="not an image"):
        simulate(
            "portofino-short", tmp_path / "s", frames=2, texture_path=tmp_path / "notes.txt", texture_mm_per_px=1.0
        )
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "old.txt").write_text("x")
    with pytest.raises(SimulationError, match="not empty"):
        simulate("portofino-short", tmp_path / "full", frames=2)


def test_progress_callback(tmp_path):
    calls = []
    simulate("portofino-short", tmp_path / "s", frames=3, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


@pytest.mark.parametrize(
    "extra",
    [["--scenario", "atlantis"], ["--frames", "0"], ["--texture", "NOTES", "--texture-mm-per-px", "1"]],
)
def test_cli_bad_arguments_give_one_line_and_exit_code_2(tmp_path, extra):
    notes = tmp_path / "notes.txt"
    notes.write_text("not an image")
    args = [a.replace("NOTES", str(notes)) for a in extra]
    res = subprocess.run(
        [sys.executable, "-m", "rovslam", "simulate", "--out", str(tmp_path / "s"), "--quiet", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "error" in lines[0]
    assert "Traceback" not in res.stderr
