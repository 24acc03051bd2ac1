"""Sequence format v1: write, read back, and typed errors naming the file, row or key."""

import os

import fuzz_corpus as fc
import numpy as np
import pytest

from rovslam.camera import Camera, LaserPointer
from rovslam.errors import ImageReadError, SequenceFormatError
from rovslam.io import SequenceInfo, SequenceWriter, open_sequence, read_groundtruth
from rovslam.io.sequence import read_image

CAM = Camera(64, 48, 100.0, 100.0, 31.5, 23.5)
INFO = SequenceInfo(
    "unit",
    CAM,
    (LaserPointer((0.05, 0.05, 0.0)), LaserPointer((-0.05, 0.05, 0.0), (0.0, 0.1, 1.0))),
    1.31,
    {"scenario": "unit", "seed": 3},
)


def write_seq(folder, n=5, fmt="png", attitude=True):
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8) for _ in range(n)]
    with SequenceWriter(folder, INFO, image_format=fmt, with_attitude=attitude) as w:
        for k, img in enumerate(images):
            w.write_frame(
                0.2 * k,
                img,
                0.1 * k,
                None if k == 2 else 1.3 + 0.01 * k,
                0.01 * k if attitude else None,
                -0.02 * k if attitude else None,
                truth=(0.01 * k, -0.02 * k, 1.31, 0.1 * k),
            )
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
    lines[3] = "0.1" + lines[3][lines[3].index(",") :]
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
    p.write_text("\n".join(line for line in p.read_text().splitlines() if not line.startswith("fx_px")))
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


# --------------------------------------------------------------------------- issue 15: paths, encodings, 16-bit images


def _outside(tmp_path):
    out = tmp_path / "outside"
    out.mkdir()
    (out / "secret.png").write_bytes(fc.encode(fc.seabed_frames(1)[0], ".png"))
    return out


@pytest.mark.parametrize(
    "image,needle",
    [
        (
            "../outside/secret.png",
            "line 4: column 'image': path '../outside/secret.png' leads outside the sequence folder",
        ),
        ("images/../../outside/secret.png", "leads outside"),
        ("ABS", "is absolute"),
        ("/etc/passwd", "line 4: column 'image': path '/etc/passwd' is absolute"),
    ],
)
def test_image_paths_must_stay_inside_the_folder(tmp_path, image, needle):
    outside = _outside(tmp_path)
    write_seq(tmp_path / "s")
    lines = (tmp_path / "s" / "frames.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[1] = str(outside / "secret.png") if image == "ABS" else image
    lines[3] = ",".join(cells)
    (tmp_path / "s" / "frames.csv").write_text("\n".join(lines) + "\n")
    with fc.recording_opens() as opened, pytest.raises(SequenceFormatError, match=needle.replace("(", r"\(")):
        open_sequence(tmp_path / "s")
    assert not fc.opened_outside(opened, tmp_path / "s", tmp_path)


def test_symbolic_links_out_of_the_folder_are_refused(tmp_path):
    outside = _outside(tmp_path)
    write_seq(tmp_path / "s")
    img = tmp_path / "s" / "images" / "000001.png"
    img.unlink()
    img.symlink_to(outside / "secret.png")
    with pytest.raises(SequenceFormatError, match=r"line 3: column 'image': path 'images/000001.png' leads outside"):
        open_sequence(tmp_path / "s")
    img.unlink()
    img.symlink_to("000000.png")  # a link that stays inside is fine
    assert len(open_sequence(tmp_path / "s")) == 5
    (tmp_path / "s" / "groundtruth.csv").unlink()
    (tmp_path / "s" / "groundtruth.csv").symlink_to(outside / "secret.png")
    with pytest.raises(SequenceFormatError, match="groundtruth.csv: path 'groundtruth.csv' leads outside"):
        open_sequence(tmp_path / "s")


def test_an_image_swapped_for_a_link_after_opening_is_not_read(tmp_path):
    outside = _outside(tmp_path)
    write_seq(tmp_path / "s")
    seq = open_sequence(tmp_path / "s")
    img = tmp_path / "s" / "images" / "000002.png"
    img.unlink()
    img.symlink_to(outside / "secret.png")
    with fc.recording_opens() as opened:
        frames = list(seq.frames())
    assert frames[2].image is None and "leads outside" in frames[2].error
    assert all(f.image is not None for k, f in enumerate(frames) if k != 2)
    assert not fc.opened_outside(opened, tmp_path / "s", tmp_path)


def test_utf8_bom_and_crlf_are_read_other_encodings_named(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "frames.csv"
    p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes().replace(b"\n", b"\r\n"))
    g = tmp_path / "s" / "groundtruth.csv"
    g.write_bytes(b"\xef\xbb\xbf" + g.read_bytes())
    seq = open_sequence(tmp_path / "s")
    assert len(seq) == 5 and seq.rows[4].t_s == pytest.approx(0.8)
    assert len(seq.groundtruth) == 5
    p.write_bytes(p.read_bytes().replace(b"images/000003", b"images/\xe9\xe9\xe9003"))
    at = p.read_bytes().index(b"\xe9")  # the offset in the file, BOM included
    with pytest.raises(SequenceFormatError, match=rf"frames.csv, line 5: not UTF-8 text \(byte 0xe9 at offset {at}\)"):
        open_sequence(tmp_path / "s")
    p.write_bytes("t_s,image,heading_rad,sonar_altitude_m\n".encode("utf-16"))
    with pytest.raises(SequenceFormatError, match="UTF-16 text; rovslam reads UTF-8"):
        open_sequence(tmp_path / "s")


def test_nan_heading_means_no_compass(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "frames.csv"
    lines = p.read_text().splitlines()
    lines[1:] = [",".join(c if j != 2 else "nan" for j, c in enumerate(ln.split(","))) for ln in lines[1:]]
    p.write_text("\n".join(lines) + "\n")
    frames = list(open_sequence(tmp_path / "s").frames())
    assert all(np.isnan(f.heading_rad) for f in frames)
    lines[2] = lines[2].replace("nan", "", 1)
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(SequenceFormatError, match="line 3: column 'heading_rad' is empty; write nan"):
        open_sequence(tmp_path / "s")


def test_16_bit_images_are_scaled_to_8_bits(tmp_path):
    import cv2

    values = np.array([[0, 257, 32896, 65535], [1000, 4095, 2048, 65535]], np.uint16)
    grey16 = np.repeat(np.repeat(values, 12, axis=0), 16, axis=1)  # (24, 64)
    cam = Camera(64, 24, 100.0, 100.0, 31.5, 11.5)
    for suffix in (".png", ".tif"):
        path = tmp_path / f"g{suffix}"
        cv2.imwrite(str(path), grey16)
        img = read_image(path, cam)
        assert img.dtype == np.uint8 and img.shape == (24, 64, 3)
        np.testing.assert_array_equal(img[::12, ::16, 0], [[0, 1, 128, 255], [4, 16, 8, 255]])
        # 12 significant bits ([camera] bit_depth = 12): 4095 is white, above saturates.
        img12 = read_image(path, cam, bit_depth=12)
        np.testing.assert_array_equal(img12[::12, ::16, 1], [[0, 16, 255, 255], [62, 255, 128, 255]])
    rgb16 = np.dstack([grey16, grey16 // 2, grey16 // 4])  # BGR on disk
    cv2.imwrite(str(tmp_path / "c.png"), rgb16)
    img = read_image(tmp_path / "c.png", cam)
    np.testing.assert_array_equal(img[12, 63], [64, 127, 255])  # RGB order, each channel scaled
    cv2.imwrite(str(tmp_path / "f.tif"), grey16.astype(np.float32))
    with pytest.raises(ImageReadError, match="float32 pixels; rovslam reads 8- or 16-bit"):
        read_image(tmp_path / "f.tif", cam)


def test_bit_depth_round_trips_and_is_validated(tmp_path):
    from dataclasses import replace

    info = replace(INFO, bit_depth=12)
    with SequenceWriter(tmp_path / "s", info) as w:
        w.write_frame(0.0, np.zeros((48, 64, 3), np.uint8), 0.0)
    assert open_sequence(tmp_path / "s").info.bit_depth == 12
    p = tmp_path / "s" / "sequence.toml"
    p.write_text(p.read_text().replace("bit_depth = 12", "bit_depth = 7"))
    with pytest.raises(SequenceFormatError, match="camera.bit_depth must be a whole number of bits from 8 to 16"):
        open_sequence(tmp_path / "s")


def test_a_png_claiming_a_huge_size_is_refused_before_decoding(tmp_path, monkeypatch):
    import cv2

    data = bytearray(fc.encode(np.zeros((48, 64, 3), np.uint8), ".png"))
    data[16:24] = (60000).to_bytes(4, "big") * 2
    (tmp_path / "b.png").write_bytes(bytes(data))
    monkeypatch.setattr(cv2, "imdecode", lambda *a: pytest.fail("decoded a 60000x60000 image"))
    with pytest.raises(ImageReadError, match="image is 60000x60000 px but sequence.toml says 64x48"):
        read_image(tmp_path / "b.png", CAM)


@pytest.mark.parametrize(
    "edit,needle",
    [
        (("fx_px = 100.0", "fx_px = 0.001"), "focal lengths must be finite, from 1 to 1e\\+06 px"),
        (("cx_px = 31.5", "cx_px = 500.0"), "principal point"),
        (("width_px = 64", "width_px = 100000"), "size must be 1 to 65535 px"),
    ],
)
def test_physically_impossible_cameras_are_refused(tmp_path, edit, needle):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "sequence.toml"
    assert edit[0] in p.read_text()
    p.write_text(p.read_text().replace(*edit))
    with pytest.raises(SequenceFormatError, match=r"sequence.toml: \[camera\]: camera " + needle):
        open_sequence(tmp_path / "s")


def test_rows_must_have_one_value_per_column_and_attitude_in_range(tmp_path):
    write_seq(tmp_path / "s")
    p = tmp_path / "s" / "frames.csv"
    text = p.read_text()
    lines = text.splitlines()
    p.write_text("\n".join(lines[:2] + [lines[2] + ",7"] + lines[3:]) + "\n")
    with pytest.raises(SequenceFormatError, match="line 3: 7 fields, the header has 6"):
        open_sequence(tmp_path / "s")
    cells = lines[3].split(",")
    cells[4] = "1.7"  # roll_rad beyond pi/2
    p.write_text("\n".join(lines[:3] + [",".join(cells)] + lines[4:]) + "\n")
    with pytest.raises(SequenceFormatError, match="line 4: column 'roll_rad' is 1.7 rad, beyond"):
        open_sequence(tmp_path / "s")
    assert os.path.isfile(p)


def _seq_with_angles(folder, heading, roll=None):
    n = len(heading)
    rng = np.random.default_rng(1)
    with SequenceWriter(folder, INFO, with_attitude=roll is not None) as w:
        for k in range(n):
            w.write_frame(
                0.2 * k,
                rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8),
                heading[k],
                1.3,
                None if roll is None else roll[k],
                None if roll is None else 0.0,
            )
    return open_sequence(folder)


def test_angles_that_look_like_degrees_are_warned_of_not_refused(tmp_path):
    rng = np.random.default_rng(7)
    survey_rad = np.deg2rad(90.0 + np.cumsum(rng.normal(0.0, 0.3, 40)))  # a compass at 5 Hz: 0.3 deg a reading
    assert _seq_with_angles(tmp_path / "rad", survey_rad).warnings == []
    seq = _seq_with_angles(tmp_path / "deg", np.rad2deg(survey_rad))  # the same column in degrees
    assert len(seq) == 40 and len(seq.warnings) == 1
    assert "heading_rad changes by" in seq.warnings[0] and "is the column in degrees?" in seq.warnings[0]
    assert str(tmp_path / "deg" / "frames.csv") in seq.warnings[0]
    # a fast turn (12 degrees a frame, one third of the dive) is not mistaken for degrees
    turn_rad = np.concatenate([np.zeros(27), np.deg2rad(12.0) * np.arange(1, 14)])
    assert _seq_with_angles(tmp_path / "turn", turn_rad).warnings == []
    # roll in degrees (1.2 "rad", inside the +-pi/2 that is refused) is warned of; 3 degrees of real roll is not
    roll_deg = np.full(40, 1.2)
    assert _seq_with_angles(tmp_path / "r_rad", survey_rad, np.deg2rad(roll_deg)).warnings == []
    w = _seq_with_angles(tmp_path / "r_deg", survey_rad, roll_deg).warnings
    assert len(w) == 1 and "roll_rad is 1.20 rad (69 degrees)" in w[0]


def test_a_jpeg_is_read_as_stored_in_rgb_order_its_exif_orientation_ignored(tmp_path):
    import struct

    import cv2

    rng = np.random.default_rng(7)
    cam = Camera(64, 48, 100.0, 100.0, 31.5, 23.5)
    bgr = rng.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
    bgr[:, :32] = (20, 60, 200)  # a red half: the channel order shows
    ok, buf = cv2.imencode(".jpg", bgr)
    # An EXIF orientation of 6 (turn 90 degrees): a viewer turns the image, the pixels on file stay as they are.
    exif = b"Exif\x00\x00MM\x00\x2a\x00\x00\x00\x08\x00\x01\x01\x12\x00\x03\x00\x00\x00\x01\x00\x06\x00\x00\x00\x00\x00\x00"
    data = buf[:2].tobytes() + b"\xff\xe1" + struct.pack(">H", len(exif) + 2) + exif + buf[2:].tobytes()
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape == (64, 48, 3)  # the tag is read
    (tmp_path / "c.jpg").write_bytes(data)
    img = read_image(tmp_path / "c.jpg", cam)
    stored = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8
    np.testing.assert_array_equal(img, stored[:, :, ::-1])  # the stored pixels, RGB
    assert img[10, 5, 0] > 150 and img[10, 5, 2] < 80  # red is channel 0
    ok, gbuf = cv2.imencode(".jpg", bgr[:, :, 1])
    (tmp_path / "g.jpg").write_bytes(gbuf.tobytes())
    grey = read_image(tmp_path / "g.jpg", cam)
    g = cv2.imdecode(gbuf, cv2.IMREAD_UNCHANGED)
    assert g.ndim == 2
    np.testing.assert_array_equal(grey, np.dstack([g, g, g]))  # grey replicated
