"""The run says when its map stopped correcting the odometry (landmarks in view, not found again).

On the ``swell`` preset the sunlight caustics (a bright network drifting over the seabed at
5.8 cm/s) change every landmark's appearance between frames: landmarks are found again in
about a tenth of the frames that have one in view, against 66 to 98 % on every other preset of
the robustness matrix. The same dive rendered without the caustics is the control.
"""

from __future__ import annotations

import dataclasses
import json
from types import SimpleNamespace

import pytest

from rovslam.runner import MAP_USE_MIN_FOUND, MAP_USE_MIN_FRAMES, MapTally, run_sequence
from rovslam.sim import SCENARIOS, simulate


def _res(visible: int, tracked: int, skipped: str | None = None) -> SimpleNamespace:
    return SimpleNamespace(landmarks_visible=visible, landmarks_tracked=tracked, skipped_reason=skipped)


def test_tally_counts_frames_with_a_landmark_in_view_and_found():
    tally = MapTally()
    for k in range(100):
        tally.add(_res(2, 1 if k % 10 == 0 else 0))  # found in 10 of 100
    tally.add(_res(0, 0))  # nothing in view: not counted
    tally.add(_res(3, 3, skipped="no image"))  # a skipped frame: not counted
    assert tally.summary() == {"frames_with_landmark_in_view": 100, "frames_with_landmark_found": 10,
                               "found_fraction": 0.1}
    (warning,) = tally.warnings()
    assert "found again in only 10 of the 100 frames that had one in view (10 %)" in warning
    assert "caustics" in warning


def test_tally_is_quiet_when_the_map_is_used_or_the_run_is_short():
    used = MapTally()
    for k in range(100):
        used.add(_res(1, 1 if k % 4 else 0))  # 75 %
    assert used.warnings() == []
    short = MapTally()
    for _ in range(MAP_USE_MIN_FRAMES - 1):
        short.add(_res(1, 0))
    assert short.warnings() == []
    assert MapTally().summary()["found_fraction"] is None
    border = MapTally()
    for k in range(100):
        border.add(_res(1, 1 if k < MAP_USE_MIN_FOUND * 100 else 0))  # exactly at the threshold: quiet
    assert border.warnings() == []


@pytest.fixture(scope="module")
def swell_pair(tmp_path_factory):
    base = SCENARIOS["swell"]
    SCENARIOS["swell-no-caustics"] = dataclasses.replace(
        base, name="swell-no-caustics", lighting=dataclasses.replace(base.lighting, caustics=None))
    root = tmp_path_factory.mktemp("swell")
    out = {}
    try:
        for name in ("swell", "swell-no-caustics"):
            simulate(name, root / name, frames=120, seed=0)
            run_sequence(root / name, root / f"{name}-run")
            out[name] = json.loads((root / f"{name}-run" / "summary.json").read_text())["map_use"]
    finally:
        del SCENARIOS["swell-no-caustics"]  # the other tests see the presets as they are
    return out


def test_caustics_make_the_landmarks_unrecognisable_and_the_run_says_so(swell_pair):
    lit, control = swell_pair["swell"], swell_pair["swell-no-caustics"]
    assert lit["frames_with_landmark_in_view"] >= 100 and control["frames_with_landmark_in_view"] >= 100
    assert lit["found_fraction"] < 0.15  # measured 0.07
    assert control["found_fraction"] > 0.6  # the same dive without the moving light
    assert len(lit["warnings"]) == 1 and "caustics" in lit["warnings"][0]
    assert control["warnings"] == []
