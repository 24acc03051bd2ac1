"""The run says when its map stopped correcting the odometry (landmarks in view, not found again).

On the ``swell`` preset, with the sunlight left in (``[bandpass] sunlight_px = 0``), the caustics
change every landmark's appearance between frames: landmarks are found again in about a tenth of
the frames that have one in view, against 66 to 98 % on every other preset of the robustness
matrix (tests/test_sunlight.py runs that dive).
"""

from __future__ import annotations

from types import SimpleNamespace

from rovslam.tallies import MAP_USE_MIN_FOUND, MAP_USE_MIN_FRAMES, MapTally


def _res(visible: int, tracked: int, skipped: str | None = None) -> SimpleNamespace:
    return SimpleNamespace(landmarks_visible=visible, landmarks_tracked=tracked, skipped_reason=skipped)


def test_tally_counts_frames_with_a_landmark_in_view_and_found():
    tally = MapTally()
    for k in range(100):
        tally.add(_res(2, 1 if k % 10 == 0 else 0))  # found in 10 of 100
    tally.add(_res(0, 0))  # nothing in view: not counted
    tally.add(_res(3, 3, skipped="no image"))  # a skipped frame: not counted
    assert tally.summary() == {
        "frames_with_landmark_in_view": 100,
        "frames_with_landmark_found": 10,
        "found_fraction": 0.1,
    }
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
