"""The presets of issue 9: reproducible per seed, readable, runnable, and each as hard as it says."""

from __future__ import annotations

import os
import subprocess
import sys

import datasets
import numpy as np
import pytest
from synth import photo_available
from test_sim_presets_frozen import folder_digest

from rovslam.camera import pixels_to_ground, rot2
from rovslam.core import SequenceInfo
from rovslam.errors import SimulationError
from rovslam.io.sequence import SequenceWriter, open_sequence, read_groundtruth
from rovslam.sim import SCENARIOS, simulate, simulate_trajectory
from rovslam.sim import scenarios as scenarios_module

NEW_PRESETS = (
    "portofino-relief",
    "photo-survey",
    "photo-turns",
    "hd-survey",
    "still-camera",
    "turbid-relief",
    "coral-repetitive",
    "swell",
)
PHOTO = {"photo-survey", "photo-turns"}


def _skip_without_photo(name: str) -> None:
    if name in PHOTO and not photo_available():
        datasets.skip_unless("chamber3")


def test_every_new_preset_is_listed_with_a_dive_of_3_to_10_minutes():
    for name in NEW_PRESETS:
        sc = SCENARIOS[name]
        assert sc.name == name
        assert 180.0 <= sc.duration_s + 1.0 / sc.frame_rate_hz <= 600.0, name
        assert "\n" not in sc.summary_line()
    out = subprocess.run(
        [sys.executable, "-m", "rovslam", "simulate", "--list"], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert len(out) == len(SCENARIOS)
    for name in NEW_PRESETS:
        (line,) = [ln for ln in out if ln.split()[0] == name]
        assert "min)" in line and "Hz" in line


@pytest.mark.parametrize("name", NEW_PRESETS)
def test_new_presets_are_byte_identical_per_seed_and_read_back(tmp_path, name):
    _skip_without_photo(name)
    frames = 2 if name == "hd-survey" else 3
    simulate(name, tmp_path / "a", frames=frames, seed=7)
    simulate(name, tmp_path / "b", frames=frames, seed=7)
    simulate(name, tmp_path / "c", frames=frames, seed=8)
    assert folder_digest(tmp_path / "a") == folder_digest(tmp_path / "b")
    assert folder_digest(tmp_path / "a") != folder_digest(tmp_path / "c")
    seq = open_sequence(tmp_path / "a")
    sc = SCENARIOS[name]
    assert len(seq) == frames and seq.info.camera == sc.recorded_camera  # with its rolling-shutter readout
    images = [f.image for f in seq.frames()]
    assert all(im is not None and im.shape == (sc.camera.height_px, sc.camera.width_px, 3) for im in images)
    assert seq.rows[0].image.endswith(sc.image_format)
    gt = read_groundtruth(tmp_path / "a" / "groundtruth.csv")
    assert gt.relief_m is not None and len(gt.relief_m) == frames  # every new preset has relief
    # altitude_m is above the mean plane; the sonar sees the relief (first echo, +- its noise).
    sonar = np.array([r.sonar_altitude_m for r in seq.rows])
    assert np.all(np.abs(sonar - (gt.altitude_m - gt.relief_m)) < 5 * sc.nav.sonar_sigma_m + 0.03)


@pytest.mark.parametrize("name", NEW_PRESETS)
def test_rovslam_runs_the_first_50_frames_of_each_preset(tmp_path, name):
    from rovslam.runner import run_sequence

    _skip_without_photo(name)
    simulate(name, tmp_path / "seq", frames=50, seed=0)
    summary = run_sequence(tmp_path / "seq", tmp_path / "out", max_frames=50)
    assert summary.frames == 50 and not summary.interrupted
    assert (tmp_path / "out" / "trajectory.csv").is_file()


def test_a_longer_run_starts_with_the_frames_of_a_shorter_one_h264_included(tmp_path):
    simulate("turbid-relief", tmp_path / "long", frames=5, seed=3)
    simulate("turbid-relief", tmp_path / "short", frames=3, seed=3)
    for k in range(3):
        name = f"images/{k:06d}.png"
        assert (tmp_path / "long" / name).read_bytes() == (tmp_path / "short" / name).read_bytes()


@pytest.mark.parametrize("name", sorted(PHOTO))
def test_photo_surveys_keep_the_footprint_on_the_photo(name):
    _skip_without_photo(name)
    sc = SCENARIOS[name]
    cam = sc.camera
    half_north, half_east = 2128 * 0.5e-3 * sc.photo_mm_per_px, 2288 * 0.5e-3 * sc.photo_mm_per_px
    corners = np.array(
        [[0, 0], [cam.width_px - 1, 0], [0, cam.height_px - 1], [cam.width_px - 1, cam.height_px - 1]], dtype=float
    )
    for seed in (0, 1, 2):
        traj = simulate_trajectory(sc.vehicle, sc.grid, sc.n_frames, sc.frame_rate_hz, seed)
        worst = 0.0
        for k in range(0, len(traj), 5):
            # the largest footprint: rays down to 5 cm below the mean plane (the relief's lowest)
            ground = pixels_to_ground(cam, corners, traj.altitude_m[k] + 0.05, traj.roll_rad[k], traj.pitch_rad[k])
            xy = ground @ rot2(traj.heading_rad[k]).T + [traj.x_m[k], traj.y_m[k]]
            worst = max(
                worst, float(np.max(np.abs(xy[:, 0]) / half_north)), float(np.max(np.abs(xy[:, 1]) / half_east))
            )
        assert worst < 0.97, (seed, worst)  # at least 3 % of the photo to spare on every side


def test_a_missing_photo_names_where_it_looked_and_the_variable(tmp_path, monkeypatch):
    from rovslam import data

    monkeypatch.setattr(data, "_seed_folders", lambda: [])  # no shared data beside the checkout
    monkeypatch.setenv("ROVSLAM_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(SimulationError) as info:
        simulate("photo-survey", tmp_path / "out", frames=2)
    msg = str(info.value)
    assert str(tmp_path / "nowhere" / "chamber3" / "seabed.jpg") in msg
    assert "ROVSLAM_DATA" in msg
    assert not (tmp_path / "out").exists()


def test_the_photo_is_found_through_the_environment_variable(tmp_path, monkeypatch):
    datasets.skip_unless("chamber3")
    from rovslam import data

    real = scenarios_module.shared_data_file("chamber3/seabed.jpg")
    (tmp_path / "data" / "chamber3").mkdir(parents=True)
    os.symlink(real, tmp_path / "data" / "chamber3" / "seabed.jpg")
    monkeypatch.setattr(data, "_seed_folders", lambda: [])
    monkeypatch.setenv("ROVSLAM_DATA", str(tmp_path / "data"))
    assert scenarios_module.shared_data_file("chamber3/seabed.jpg") == tmp_path / "data" / "chamber3" / "seabed.jpg"


def test_groundtruth_relief_column_is_optional(tmp_path):
    cam = SCENARIOS["portofino"].camera
    img = np.zeros((cam.height_px, cam.width_px, 3), np.uint8)
    for with_relief in (False, True):
        out = tmp_path / str(with_relief)
        with SequenceWriter(out, SequenceInfo("t", cam), with_relief=with_relief) as w:
            for k in range(3):
                truth = (0.1 * k, 0.0, 1.3, 0.0) + ((0.01 * k,) if with_relief else ())
                w.write_frame(0.2 * k, img, 0.0, 1.3, truth=truth)
        gt = read_groundtruth(out / "groundtruth.csv")
        np.testing.assert_allclose(gt.x_m, [0.0, 0.1, 0.2])
        if with_relief:
            np.testing.assert_allclose(gt.relief_m, [0.0, 0.01, 0.02])
        else:
            assert gt.relief_m is None
    with SequenceWriter(tmp_path / "bad", SequenceInfo("t", cam), with_relief=True) as w:
        with pytest.raises(Exception, match="relief_m"):
            w.write_frame(0.0, img, 0.0, 1.3, truth=(0.0, 0.0, 1.3, 0.0))
