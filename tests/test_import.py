"""`rovslam import` (rovslam.io.importer): any input as a sequence folder, with its navigation in frames.csv."""

from __future__ import annotations

import math

import fuzz_corpus as fc
import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.errors import OutputError
from rovslam.io.importer import import_source
from rovslam.io.sequence import open_sequence
from rovslam.io.source import InputOptions
from rovslam.runner import describe_source, open_source


@pytest.fixture
def video(tmp_path):
    v = fc.write_video(tmp_path / "dive.mkv", n=12)
    cam = tmp_path / "cam.toml"
    cam.write_text(fc.CAMERA_FILE + fc.NAV_MAP)
    nav = tmp_path / "nav.csv"
    nav.write_text(fc.nav_csv_text())
    return v, cam, nav


def test_import_writes_the_navigation_at_each_frame(video, tmp_path):
    v, cam, nav = video
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(v),
            "--camera",
            str(cam),
            "--nav",
            str(nav),
            "--nav-time-offset",
            repr(fc.NAV_OFFSET_S),
            "--out",
            str(tmp_path / "seq"),
            "-q",
        ],
    )
    assert res.exit_code == 0, res.stderr
    s = open_sequence(tmp_path / "seq")
    assert len(s) == 12
    t = np.array([r.t_s for r in s.rows])
    np.testing.assert_allclose(t, 0.2 * np.arange(12), atol=1e-9)
    # The log: heading 10 + 10 t degrees, altitude 1.3 + 0.01 t m (10 Hz), interpolated at each frame.
    np.testing.assert_allclose([math.degrees(r.heading_rad) for r in s.rows], 10 + 10 * t, atol=1e-9)
    np.testing.assert_allclose([r.sonar_altitude_m for r in s.rows], 1.3 + 0.01 * t, atol=1e-9)
    assert s.info.metadata["heading_input"] == "navigation" and s.info.metadata["imported_kind"] == "video"
    assert s.info.camera.fx_px == 200.0
    first = s.frames(prefetch=0)
    img = next(first).image
    first.close()
    src = open_source(v, options=InputOptions(camera_file=cam))
    assert np.array_equal(img, next(src.frames()).image)  # PNG: the decoded video frame, losslessly


def test_an_import_stopped_early_is_a_readable_sequence(video, tmp_path):
    v, cam, _ = video
    src = open_source(v, options=InputOptions(camera_file=cam))
    calls = []
    summary = import_source(
        src,
        tmp_path / "seq",
        describe_source(src),
        should_stop=lambda: len(calls) >= 4,
        on_frame=lambda done, total: calls.append((done, total)),
    )
    assert summary.stopped and summary.frames == 4
    assert calls[0] == (1, 12)
    s = open_sequence(tmp_path / "seq")
    assert len(s) == 4 and all(f.image is not None for f in s.frames())
    assert all(math.isnan(r.heading_rad) for r in s.rows)  # no navigation: no compass, written as nan


def test_unreadable_frames_are_not_written(tmp_path):
    folder = fc.write_image_folder(tmp_path / "imgs", n=6)
    (folder / "frame3.png").write_bytes(b"\x89PNG broken")
    cam = tmp_path / "cam.toml"
    cam.write_text(fc.CAMERA_FILE)
    src = open_source(folder, options=InputOptions(camera_file=cam, fps=2.0))
    summary = import_source(src, tmp_path / "seq", describe_source(src), image_format="jpg")
    assert (summary.frames, summary.unreadable) == (5, 1) and "frame3.png" in summary.warnings[0]
    s = open_sequence(tmp_path / "seq")
    assert [r.t_s for r in s.rows] == [0.0, 0.5, 1.5, 2.0, 2.5] and s.rows[0].image.endswith(".jpg")


def test_import_refuses_a_folder_that_holds_something(video, tmp_path):
    v, cam, _ = video
    out = tmp_path / "seq"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    src = open_source(v, options=InputOptions(camera_file=cam))
    with pytest.raises(OutputError, match="exists and is not empty"):
        import_source(src, out, describe_source(src))
    assert (out / "notes.txt").read_text() == "mine"


def test_a_video_without_camera_file_says_what_one_holds(video, tmp_path):
    v, _, _ = video
    res = CliRunner().invoke(app, ["run", str(v), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    assert res.stderr.strip() == (
        f"rovslam: error: {v}: a video needs --camera CAMERA.toml, a camera file with [camera] "
        "(width_px, height_px, fx_px, fy_px, cx_px, cy_px), optional [[laser]], [vehicle] "
        "altitude_m and [nav]."
    )
