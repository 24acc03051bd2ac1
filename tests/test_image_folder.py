"""A plain folder of images (rovslam.io.folder): natural order, --fps, --times, and bad folders as one line."""

from __future__ import annotations

import os
import re
from pathlib import Path

import fuzz_corpus as fc
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.io.camera_file import read_camera_file
from rovslam.io.folder import ImageFolderSource, natural_key

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "dive"
    d.mkdir()
    for k, img in enumerate(fc.seabed_frames(12)):
        (d / f"img{k + 1}.png").write_bytes(fc.encode(img, ".png"))
    (d / "notes.txt").write_text("not an image")
    cam = tmp_path / "cam.toml"
    cam.write_text(fc.CAMERA_TOML.replace('format = "rovslam-sequence/1"\n', ""))
    return d, cam


def test_natural_order():
    names = ["f10.png", "f2.png", "F1.png", "f2b.png", "g.png"]
    assert sorted(names, key=natural_key) == ["F1.png", "f2.png", "f2b.png", "f10.png", "g.png"]


def test_fps_orders_images_naturally_and_times_them(folder):
    d, cam = folder
    src = ImageFolderSource(d, read_camera_file(cam), fps=4.0)
    frames = list(src.frames())
    assert [Path(f.source).name for f in frames] == [f"img{k}.png" for k in range(1, 13)]
    assert [f.t_s for f in frames] == [k / 4.0 for k in range(12)]
    assert all(f.image is not None and f.image.shape == (fc.H, fc.W, 3) for f in frames)


def test_times_file_chooses_and_times_the_images(folder, tmp_path):
    d, cam = folder
    times = tmp_path / "times.csv"
    times.write_text("image,t_s\nimg3.png,0.9\nimg1.png,0.1\nimg2.png,0.5\n")
    src = ImageFolderSource(d, read_camera_file(cam), times_file=times)
    assert src.names == ["img1.png", "img2.png", "img3.png"] and src.times_s == [0.1, 0.5, 0.9]
    assert src.warnings == [f"9 image file(s) of {d} are not listed in {times}: left out."]


def test_a_folder_of_images_runs_end_to_end(folder, tmp_path):
    d, cam = folder
    res = CliRunner().invoke(
        app, ["run", str(d), "--camera", str(cam), "--fps", "5", "--out", str(tmp_path / "o"), "-q"]
    )
    assert res.exit_code == 0, res.stderr
    import json

    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["sources"]["input"]["kind"] == "image folder" and s["frames_processed"] == 12
    assert s["sources"]["heading"]["frames"] == {"tokens only (no compass)": 12}


def _error(args: list[str]) -> str:
    res = CliRunner().invoke(app, [str(a) for a in args])
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("rovslam: error: "), res.stderr
    return lines[0]


def test_bad_image_folders(folder, tmp_path):
    d, cam = folder
    out = ["--out", tmp_path / "o", "-q"]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no sequence.toml, frames.csv or image files" in _error(["run", empty, *out])
    line = _error(["run", d, *out])
    assert "a folder of images without sequence.toml and frames.csv runs with --camera CAMERA.toml ([camera]" in line
    assert "(README, 'Your own dive')" in line
    assert "missing: --camera CAMERA.toml and --fps F or --times FILE." in line
    assert "missing: --fps F or --times FILE." in _error(["run", d, "--camera", cam, *out])
    assert "missing: --camera CAMERA.toml." in _error(["run", d, "--fps", "5", *out])
    assert "give --fps or --times, one of the two, not both" in _error(
        ["run", d, "--camera", cam, "--fps", "5", "--times", tmp_path / "t.csv", *out]
    )
    assert "--fps must be a frame rate" in _error(["run", d, "--camera", cam, "--fps", "0", *out])
    times = tmp_path / "t.csv"
    times.write_text("image,t_s\nimg1.png,0\nimg99.png,1\n")
    assert "t.csv, line 3: image file 'img99.png' not found" in _error(
        ["run", d, "--camera", cam, "--times", times, *out]
    )
    (tmp_path / "bait.png").write_bytes((d / "img1.png").read_bytes())
    times.write_text("image,t_s\nimg1.png,0\n../bait.png,1\n")
    assert "line 3: column 'image': path '../bait.png' leads outside" in _error(
        ["run", d, "--camera", cam, "--times", times, *out]
    )
    times.write_text("image,t_s\nimg1.png,0\n/etc/passwd,1\n")
    assert "line 3: column 'image': path '/etc/passwd' is absolute" in _error(
        ["run", d, "--camera", cam, "--times", times, *out]
    )
    times.write_text("image,t_s\nimg1.png,0\nimg2.png,0\n")
    assert "repeats another image's time" in _error(["run", d, "--camera", cam, "--times", times, *out])
    assert "--image-topic cannot be used" in _error(
        ["run", d, "--camera", cam, "--fps", "5", "--image-topic", "/x", *out]
    )


def test_an_image_linking_outside_the_folder_is_refused(folder, tmp_path):
    d, cam = folder
    bait = tmp_path / "bait.png"
    bait.write_bytes((d / "img1.png").read_bytes())
    (d / "img5.png").unlink()
    os.symlink(bait, d / "img5.png")
    assert "image 'img5.png': path 'img5.png' leads outside" in _error(
        ["run", d, "--camera", cam, "--fps", "5", "--out", tmp_path / "o", "-q"]
    )


def test_every_readme_section_an_error_names_exists():
    """An error that sends the user to a section (``README, 'X'`` or ``docs/PAGE.md, 'X'``) names one that exists."""
    named = set()
    for path in (ROOT / "src" / "rovslam").rglob("*.py"):
        named |= set(re.findall(r"(README|docs/[\w-]+\.md), '([^']+)'", path.read_text(encoding="utf-8")))
    assert named, "no error names a README section"
    missing = set()
    for doc, section in named:
        text = (ROOT / ("README.md" if doc == "README" else doc)).read_text(encoding="utf-8")
        headings = {re.sub(r"[`*]", "", h).strip() for h in re.findall(r"^#+ (.+)$", text, flags=re.M)}
        if not any(h.startswith(section) for h in headings):
            missing.add((doc, section))
    assert not missing, f"errors point at sections that do not exist: {missing}"
