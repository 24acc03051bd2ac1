"""The holes a systematic bad-input sweep of the CLI found, one test per class of defect.

Each of these inputs used to end in an internal error (exit 1), a hang, a silently empty result or a
message that did not say where the problem was; each must now give one line naming the file, key
or topic, and exit code 2 (or the reader's typed error).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import threading
from pathlib import Path

import fuzz_corpus as fc
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.config import RunConfig, SpeedTemplateConfig
from rovslam.errors import ConfigError, ImageReadError, ResultsFormatError, SequenceFormatError


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A small valid sequence (8 frames, 128x96) and the results of its run."""
    from rovslam.runner import run_sequence

    root = tmp_path_factory.mktemp("sweep")
    seq = fc.write_sequence(root / "seq")
    run_sequence(seq, root / "results")
    return seq, root / "results"


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def refused(argv: list[str], needle: str) -> str:
    """Run the CLI in-process: exit 2, one line ``rovslam: error: ...`` holding ``needle``, nothing on stdout."""
    res = CliRunner().invoke(app, argv)
    assert res.exit_code == 2, (res.exit_code, res.stdout, res.stderr, res.exception)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error: "), res.stderr
    assert needle in lines[0], lines[0]
    assert res.stdout.strip() == ""
    return lines[0]


def _done_within(fn, seconds: float = 10.0):
    """``fn()``'s exception (or None), failing the test if it has not returned after ``seconds``."""
    out: dict[str, BaseException | None] = {}

    def target() -> None:
        try:
            fn()
            out["exc"] = None
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["exc"] = exc

    th = threading.Thread(target=target, daemon=True)
    th.start()
    th.join(seconds)
    assert "exc" in out, f"still blocked after {seconds} s"
    return out["exc"]


# ------------------------------------------------------------------ summary.json of a results folder


def test_summary_nested_thousands_deep_is_one_line(base, tmp_path):
    """JSON nested 100,000 deep made json.loads raise RecursionError: exit 1, 'internal error'."""
    seq, results = base
    res = _copy(results, tmp_path / "res")
    (res / "summary.json").write_text("[" * 100_000 + "]" * 100_000)
    refused(["eval", str(res), "-g", str(seq / "groundtruth.csv")], "summary.json: JSON nested too deep")


@pytest.mark.parametrize(
    "key, value", [("software", "x"), ("sources", [1, 2]), ("sequence", 5), ("camera_file", {"a": 1})]
)
def test_summary_key_of_the_wrong_type_is_named(base, tmp_path, key, value):
    """A summary.json whose 'software' was a string crashed the report (AttributeError, exit 1)."""
    _, results = base
    res = _copy(results, tmp_path / "res")
    summary = json.loads((res / "summary.json").read_text())
    summary[key] = value
    (res / "summary.json").write_text(json.dumps(summary))
    line = refused(["report", str(res), "--no-mosaic", "-q"], f"summary.json: key '{key}' must be")
    assert "--overwrite" in line


def test_a_valid_summary_still_reads(base):
    from rovslam.io.run_results import read_results

    assert read_results(base[1]).summary["software"]["name"] == "rovslam"


# ------------------------------------------------------------------ other files of a results folder


def test_tokens_csv_that_is_not_utf8_is_named(base, tmp_path):
    """report read tokens.csv with a bare open(): a damaged file was a UnicodeDecodeError (exit 1)."""
    from rovslam.viz.runinfo import read_tokens

    res = _copy(base[1], tmp_path / "res")
    assert sorted(read_tokens(res)) == list(range(1, 8))  # the run's own file: tokens from frame 1 on
    (res / "tokens.csv").write_bytes(b"frame,u_px,v_px\n1,\xe9,2\n")
    with pytest.raises(ResultsFormatError, match=r"tokens\.csv, line 2: not UTF-8"):
        read_tokens(res)


@pytest.mark.parametrize(
    "damage, needle",
    [
        (lambda p: p.write_bytes(bytes(range(256)) * 4), "measurements.csv, line 2: not UTF-8"),
        (lambda p: p.write_text(p.read_text() + "1," + "9" * 200_000 + "\n"), "not a readable CSV line"),
    ],
)
def test_damaged_measurement_file_stops_smooth_with_one_line(base, tmp_path, damage, needle):
    """smooth read measurements.csv with read_text(): binary bytes were a UnicodeDecodeError (exit 1)."""
    res = _copy(base[1], tmp_path / "res")
    damage(res / "measurements.csv")
    refused(["smooth", str(res), "-q"], needle)


# ------------------------------------------------------------------ mosaic


@pytest.mark.parametrize("name, needle", [("", "is a folder"), ("m.txt", "give a file name ending in .png")])
def test_mosaic_out_that_cannot_be_a_png_is_refused_before_the_work(base, tmp_path, name, needle):
    """--out a folder or a .txt name went to cv2.imwrite: cv2.error, exit 1."""
    seq, results = base
    out = tmp_path / name if name else tmp_path
    refused(["mosaic", str(results), "--seq", str(seq), "--out", str(out), "-q"], needle)
    assert not (tmp_path / "m.txt").exists()


def test_mosaic_of_a_sequence_whose_images_are_gone_is_refused(base, tmp_path):
    """Every image missing gave exit 0 and a blank 'mosaic' of 0 frames."""
    seq, results = base
    moved = _copy(seq, tmp_path / "seq")
    for p in (moved / "images").iterdir():
        p.unlink()
    out = tmp_path / "m.png"
    refused(
        ["mosaic", str(results), "--seq", str(moved), "--out", str(out), "-q"],
        "none of the 8 frames to lay could be read",
    )
    assert not out.exists()


# ------------------------------------------------------------------ CSV files and special files


def test_csv_without_its_header_line_says_so(tmp_path):
    """A groundtruth.csv without header said 'header names column(s) 0.0 more than once'."""
    from rovslam.io.sequence import read_groundtruth

    p = tmp_path / "gt.csv"
    p.write_text("0.0,0,0,1.3,0\n0.2,0,0.01,1.3,0\n0.4,0,0.02,1.3,0\n")
    with pytest.raises(
        SequenceFormatError,
        match=r"gt\.csv, line 1: holds values .* not the header; add the header "
        r"line t_s,x_m,y_m,altitude_m,heading_rad",
    ):
        read_groundtruth(p)


def test_a_folder_given_for_a_csv_file_is_called_a_folder(tmp_path):
    """A folder where groundtruth.csv belongs was reported as 'missing'."""
    from rovslam.io.sequence import read_groundtruth

    (tmp_path / "gt.csv").mkdir()
    with pytest.raises(SequenceFormatError, match=r"gt\.csv: is a folder, not a file"):
        read_groundtruth(tmp_path / "gt.csv")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_a_named_pipe_where_an_image_or_text_belongs_does_not_block(tmp_path):
    """A pipe named frame9.png in an image folder hung `rovslam run` for ever (open() waits for a writer)."""
    from rovslam.io.sequence import read_image
    from rovslam.io.text import read_text

    pipe = tmp_path / "frame9.png"
    os.mkfifo(pipe)
    exc = _done_within(lambda: read_image(pipe))
    assert isinstance(exc, ImageReadError) and "is not a regular file" in str(exc)
    exc = _done_within(lambda: read_text(pipe))
    assert isinstance(exc, SequenceFormatError) and "is not a regular file" in str(exc)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes")
def test_an_image_folder_holding_a_named_pipe_runs(tmp_path):
    folder = fc.write_image_folder(tmp_path / "images")
    os.mkfifo(folder / "frame9.png")
    (tmp_path / "cam.toml").write_text(fc.CAMERA_FILE)
    out = tmp_path / "out"
    res = _done_within(
        lambda: CliRunner().invoke(
            app, ["run", str(folder), "--camera", str(tmp_path / "cam.toml"), "--fps", "5", "--out", str(out), "-q"]
        ),
        60.0,
    )
    assert res is None
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete" and summary["frames_usable"] == 8
    assert "not a regular file" in summary["skipped_frames"][0]["reason"]


# ------------------------------------------------------------------ configuration against the images


@pytest.mark.parametrize("size_px", [100, 100_000, 2**64])
def test_a_template_larger_than_the_image_names_the_configuration_key(base, tmp_path, size_px):
    """[speed_templates] size_px beyond the image failed inside the filters: 'local variance window ... px is
    larger than the image', with neither the key nor the fix."""
    from rovslam.runner import run_sequence

    if size_px > 1e6:  # no setting takes so large a number: refused when the configuration is built
        with pytest.raises(ConfigError, match=rf"\[speed_templates\] size_px = {size_px}: out of range"):
            SpeedTemplateConfig(size_px=size_px)
        return
    cfg = RunConfig(speed_templates=SpeedTemplateConfig(size_px=size_px))
    with pytest.raises(
        ConfigError, match=rf"\[speed_templates\] size_px = {size_px} of the configuration: .*128x96 px"
    ):
        run_sequence(base[0], tmp_path / "out", cfg)
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_a_template_larger_than_the_image_from_a_config_file(base, tmp_path):
    (tmp_path / "c.toml").write_text("[speed_templates]\nsize_px = 200\n")
    refused(
        ["run", str(base[0]), "-c", str(tmp_path / "c.toml"), "--out", str(tmp_path / "out"), "-q"],
        "[speed_templates] size_px = 200 of the configuration",
    )
    (tmp_path / "c.toml").write_text("[speed_templates]\nsize_px = 99999999999999999999\n")
    refused(
        ["run", str(base[0]), "-c", str(tmp_path / "c.toml"), "--out", str(tmp_path / "out"), "-q"],
        "[speed_templates] size_px = 99999999999999999999: out of range",
    )


# ------------------------------------------------------------------ bags


@pytest.mark.parametrize("value", [float("inf"), float("nan")])
def test_a_heading_topic_without_a_usable_value_names_the_topic(tmp_path, value):
    """Every std_msgs/Float64 heading non-finite: 'a navigation track needs at least one sample', no bag, no topic."""
    from rosbag_writer import T0_NS, BagWriter

    bag_path = tmp_path / "dive.bag"
    with BagWriter(bag_path, "ros1") as bag:
        for k, img in enumerate(fc.seabed_frames(4)):
            ns = T0_NS + k * 200_000_000
            bag.write("/cam/image", "sensor_msgs/msg/Image", bag.image(ns, img), ns)
            bag.write("/nav/hdg", "std_msgs/msg/Float64", bag.float64(value), ns)
    (tmp_path / "cam.toml").write_text(fc.CAMERA_FILE)
    argv = [
        "run",
        str(bag_path),
        "--camera",
        str(tmp_path / "cam.toml"),
        "--image-topic",
        "/cam/image",
        "--heading-topic",
        "/nav/hdg",
        "--out",
        str(tmp_path / "out"),
        "-q",
    ]
    line = refused(argv, "dive.bag: topic /nav/hdg (std_msgs/msg/Float64) holds no usable heading")
    assert "leave the option out" in line


def test_an_image_folder_that_cannot_be_searched_is_named_as_an_input(base, tmp_path, monkeypatch):
    """A sequence whose images/ could not be searched (chmod) ended in the CLI's output-error text:
    'Permission denied (permission denied; choose a folder you can write to)'. Root reads any folder,
    so the operating system's refusal is played by Path.is_file."""
    from rovslam.io.sequence import open_sequence

    seq = _copy(base[0], tmp_path / "seq")
    real_is_file = Path.is_file

    def is_file(self: Path) -> bool:
        if self.parent.name == "images":
            raise PermissionError(13, "Permission denied", str(self))
        return real_is_file(self)

    monkeypatch.setattr(Path, "is_file", is_file)
    with pytest.raises(
        SequenceFormatError,
        match=r"frames\.csv, line 2: image file 'images/000000\.png' cannot be "
        r"reached \(Permission denied\); give read access",
    ):
        open_sequence(seq)
    line = refused(["run", str(seq), "--out", str(tmp_path / "out"), "-q"], "cannot be reached (Permission denied)")
    assert "write to" not in line


def test_save_rrd_that_is_a_folder_is_refused(base, tmp_path):
    """--save-rrd FOLDER reached rerun: 'internal error (RuntimeError: Failed to create file: Is a directory)'."""
    refused(
        ["run", str(base[0]), "--out", str(tmp_path / "out"), "-q", "--save-rrd", str(tmp_path)],
        "is a folder; --save-rrd needs a file name",
    )
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("seeds", ["1000000000", "[" + ", ".join(map(str, range(10_001))) + "]"], ids=["count", "list"])
def test_a_matrix_with_a_billion_seeds_is_refused_at_once(tmp_path, seeds):
    """seeds = 1000000000 built a list of a billion cells: the batch never started (a hang, then the memory)."""
    from rovslam.batch import load_matrix
    from rovslam.errors import ConfigError

    p = tmp_path / "m.toml"
    p.write_text(f'seeds = {seeds}\n[[scenario]]\nname = "portofino-short"\nframes = 10\n')
    exc = _done_within(lambda: load_matrix(p), 10.0)
    assert isinstance(exc, ConfigError), exc
    assert re.search(r"m\.toml: seeds: (1000000000|10001) seeds, more than the 10000", str(exc)), str(exc)
    p.write_text('seeds = 10000\n[[scenario]]\nname = "portofino-short"\nframes = 10\n')
    assert len(load_matrix(p).cells) == 10_000  # the limit itself is allowed


def test_a_local_cluster_says_nothing_when_dasks_default_port_is_taken():
    """With another Dask cluster on the machine (port 8787 taken), the local cluster of `rovslam batch` added
    'UserWarning: Port 8787 is already in use' to stderr, around the one error line."""
    import socket
    import warnings

    from rovslam.batch import _connect

    holder = socket.socket()
    try:
        holder.bind(("", 8787))
        holder.listen()
    except OSError:
        pass  # taken already: the case itself
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            client, cluster = _connect(None, 1)
            client.close()
            cluster.close()
        assert not [w for w in caught if "8787" in str(w.message)], [str(w.message) for w in caught]
    finally:
        holder.close()


@pytest.mark.parametrize("column", ["x_m", "y_m", "altitude_m"])
def test_ground_truth_beyond_the_earth_is_refused(base, tmp_path, column):
    """x_m = 1e300 ran, and NumPy's 'overflow encountered in multiply' came out on stderr of `rovslam eval`."""
    from rovslam.io.sequence import read_groundtruth

    gt = tmp_path / "gt.csv"
    shutil.copy(base[0] / "groundtruth.csv", gt)
    fc.set_cell(gt, 3, column, "1e300")
    with pytest.raises(
        SequenceFormatError, match=rf"gt\.csv, line 4: column '{column}' is 1e\+300 m, beyond any place"
    ):
        read_groundtruth(gt)
    refused(["eval", str(_copy(base[1], tmp_path / "res")), "-g", str(gt)], "beyond any place on Earth")
    fc.set_cell(gt, 3, column, "5500000.0")  # a UTM northing is a place
    assert read_groundtruth(gt).x_m.shape == (8,)
