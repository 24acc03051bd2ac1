"""The original presets stay byte-identical per seed while the simulator grows (issue 9).

The digests were recorded with the simulator as it was before relief, vehicle lamps, photo
seabeds, codecs and waves were added (commit 687490c). They cover the sequence files written
by ``simulate`` (decoded pixels, so a change of PNG compression does not matter; the CSVs
and sequence.toml as bytes), and frames rendered later in a survey (turns, tilt, marine
snow), together with the trajectory and sensor readings behind them.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from rovslam.sim import (
    SCENARIOS,
    World,
    frame_pose,
    frame_rng,
    read_sensors,
    renderer_for,
    simulate,
    simulate_trajectory,
)

SEQUENCE_DIGESTS = {
    ("portofino", 0): "bb339c03505efa1a110fefacfccdeda7ce9bc68655b33e8eb9548d855cfa10d3",
    ("portofino-short", 1): "19b95c6da4f4740ddada6005384abea36d5228b7197b97438f4c0462a69cabca",
    ("rough-turns", 2): "f51b395b6684b96a2b080d3b0096e44f4a7147fd8ed3e9d50c05e1472bfba1a5",
    ("rough-turns-short", 3): "130627faaeafbf74bd489d745d0c2bd3778c96043e40475d12cbc4e9a934b951",
}
LATER_FRAME_DIGESTS = {
    "portofino": "80e354ae6ad9a5c5df9fbc470e82b43761249ff08d42dd7cccd2279a324a7f04",
    "rough-turns": "1c9820634732a3f17d81aa81428429c41e3a3a0f9f869c34066d800069804e09",
}


def folder_digest(folder: Path) -> str:
    """SHA-256 over every file's relative name and content (PNG images as decoded pixels)."""
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if not p.is_file():
            continue
        h.update(str(p.relative_to(folder)).encode())
        if p.suffix == ".png":
            h.update(cv2.imread(str(p), cv2.IMREAD_UNCHANGED).tobytes())
        else:
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.mark.parametrize("name, seed", sorted(SEQUENCE_DIGESTS))
def test_original_preset_sequences_are_unchanged(tmp_path, name, seed):
    simulate(name, tmp_path / "s", frames=3, seed=seed)
    assert folder_digest(tmp_path / "s") == SEQUENCE_DIGESTS[(name, seed)]


@pytest.mark.parametrize("name", sorted(LATER_FRAME_DIGESTS))
def test_original_preset_frames_later_in_the_survey_are_unchanged(name):
    sc = SCENARIOS[name]
    traj = simulate_trajectory(sc.vehicle, sc.grid, 400, sc.frame_rate_hz, 4)
    nav = read_sensors(traj, sc.nav, 4)
    world = World.procedural(4, sc.texture)
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots)
    h = hashlib.sha256()
    for arr in (traj.x_m, traj.y_m, traj.altitude_m, traj.heading_rad, nav.heading_rad, nav.sonar_altitude_m):
        h.update(np.ascontiguousarray(arr).tobytes())
    for k in (150, 399):
        img = renderer.render(
            world,
            frame_pose(traj, k),
            sc.lasers,
            frame_rng(4, k),
            velocity_mps=(float(traj.surge_mps[k]), float(traj.sway_mps[k])),
            t_s=float(traj.t_s[k]),
        )
        h.update(img.tobytes())
    assert h.hexdigest() == LATER_FRAME_DIGESTS[name]
