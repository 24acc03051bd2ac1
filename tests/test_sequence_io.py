"""Sequence format v1: write, read back, and typed errors naming the file, row or key."""

import numpy as np
import pytest

from rovslam.camera import Camera, LaserPointer
from rovslam.errors import SequenceFormatError
from rovslam.io import SequenceInfo, SequenceWriter, open_sequence, read_groundtruth

CAM = Camera(64, 48, 100.0, 100.0, 31.5, 23.5)
INFO = SequenceInfo(
    "unit", CAM, (LaserPointer((0.05, 0.05, 0.0)), LaserPointer((-0.05, 0.05, 0.0), (0.0, 0.1, 1.0))), 1.31,
    {"scenario": "unit", "seed": 3},
)


def write_seq(folder, n=5, fmt="png", attitude=True):
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8) for _ in range(n)]
    with SequenceWriter(folder, INFO, image_format=fmt, with_attitude=attitude) as w:
        for k, img in enumerate(images):
            w.write_frame(0.2 * k, img, 0.1 * k, None if k == 2 else 1.3 + 0.01 * k,
                          0.01 * k if attitude else None, -0.02 * k if attitude else None,
                          truth=(0.01 * k, -0.02 * k, 1.31, 0.1 * k))
    return images


def test_round_trip_keeps_every_column(tmp_path):
    images = write_seq(tmp_path / "s")
    seq = open_sequence(tmp_path / "s")
    assert seq.info == INFO
    assert len(seq) == 5 and seq.has_attitude
    frames = list(seq.frames())
    for k, f in enumerate(frames):
        assert f.index == k and f.t_s == pytest.approx(0.2 * k, abs=0)
        assert f.heading_rad == 0.1 * k
        assert f.sonar_altitude_m == (None if k == 2 else 1.3 + 0.01 * k)
        assert f.roll_rad == 0.01 * k and f.pitch_rad == -0.02 * k
        np.testing.assert_array_equal(f.image, images[k])  # PNG is lossless
    gt = seq.groundtruth
    np.testing.assert_array_equal(gt.x_m, [0.01 * k for k in range(5)])
    np.testing.assert_array_equal(gt.heading_rad, [0.1 * k for k in range(5)])


def test_jpeg_and_no_attitude(tmp_path):
    write_seq(tmp_path / "s", fmt="jpg", attitude=False)
    seq = open_sequence(tmp_path / "s")
    assert not seq.has_attitude
    f = next(seq.frames())
    assert f.image.shape == (48, 64, 3) and f.roll_rad == 0.0 and not f.has_attitude


def test_missing_image_names_the_row(tmp_path):
    write_seq(tmp_path / "s")
    (tmp_path / "s" / "images" / "000003.png").unlink()
    with pytest.raises(SequenceFormatError, match=r"frames.csv, line 5: image file 'images/000003.png' not found"):
        open_sequence(tmp_path / "s")


def test_non_monotonic_time_names_the_row(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "frames.csv"
    lines = p.read_text().splitlines()
    lines[3] = "0.1" + lines[3][lines[3].index(","):]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match="line 4.*strictly increasing"):
        open_sequence(tmp_path / "s")


def test_header_without_required_column(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "frames.csv"
    p.write_text(p.read_text().replace("heading_rad", "heading", 1))
    with pytest.raises(SequenceFormatError, match="missing column.*heading_rad"):
        open_sequence(tmp_path / "s")


def test_camera_without_focal_length(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "sequence.toml"
    p.write_text("\n".join(l for l in p.read_text().splitlines() if not l.startswith("fx_px")))
    with pytest.raises(SequenceFormatError, match=r"sequence.toml: \[camera\] is missing key 'fx_px'"):
        open_sequence(tmp_path / "s")


def test_unknown_key_and_wrong_format(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "sequence.toml"
    text = p.read_text()
    p.write_text(text.replace("fy_px", "fyy_px"))
    with pytest.raises(SequenceFormatError, match="camera.fyy_px"):
        open_sequence(tmp_path / "s")
    p.write_text(text.replace("rovslam-sequence/1", "rovslam-sequence/9"))
    with pytest.raises(SequenceFormatError, match="format"):
        open_sequence(tmp_path / "s")


def test_corrupt_image_is_a_frame_error_not_an_exception(tmp_path):
    write_seq(tmp_path / "s")
    (tmp_path / "s" / "images" / "000002.png").write_bytes(b"not a png at all")
    frames = list(open_sequence(tmp_path / "s").frames())
    assert frames[2].image is None and "not a readable" in frames[2].error
    assert all(f.image is not None for k, f in enumerate(frames) if k != 2)


def test_groundtruth_bad_number(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "groundtruth.csv"
    lines = p.read_text().splitlines()
    lines[2] = lines[2].replace(lines[2].split(",")[1], "abc", 1)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match="line 3: column 'x_m' is not a number"):
        read_groundtruth(p)


def test_not_a_folder(tmp_path):
    with pytest.raises(SequenceFormatError, match="not a folder"):
        open_sequence(tmp_path / "missing")
