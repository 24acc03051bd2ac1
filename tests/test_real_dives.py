"""Issue 12, inputs: the same dive as a sequence folder, a ROS 1 / ROS 2 bag, a video with its NAV.csv, an image
folder, and back through ``rovslam import``, gives the same trajectory; the real Sparus video with its own log.

Tolerances: a bag stores the images losslessly and stamps in integer nanoseconds; its headings go
through a quaternion and back (1e-16 rad). The trajectories then agree to the 1e-9 m that
trajectory.csv is written with (asserted: 1e-8 m). The video is written with a lossless codec
(FFV1 in Matroska, libx264rgb at crf 0 in MP4) and its NAV.csv on a UNIX clock (1.4e9 s: its
times are known to 2.4e-7 s in float64, so the rows fall a fraction of a microsecond off the
frames): the 2 mm RMS of the issue is asserted, and the run in fact matches to 1e-6 m.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import datasets
import numpy as np
import pytest
from rosbag_writer import sequence_to_bag
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.io.run_results import read_results
from rovslam.io.sequence import open_sequence

ROOT = Path(__file__).resolve().parents[1]
SPARUS = datasets.folder("sparus")
needs_sparus = datasets.needs("sparus")
N_FRAMES = 60
SAME_M = 1e-8


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    """A short simulated dive (lasers, sonar, a compass, roll and pitch) and its sequence-folder run."""
    from rovslam.runner import run_sequence
    from rovslam.sim import simulate

    d = tmp_path_factory.mktemp("dive")
    simulate("rough-turns-short", d / "seq", frames=N_FRAMES, seed=3)
    camera = d / "camera.toml"
    text = (d / "seq" / "sequence.toml").read_text()
    camera.write_text(text.split("[metadata]")[0].replace('format = "rovslam-sequence/1"\n', ""))  # a camera file
    run_sequence(d / "seq", d / "ref")
    return d


def _run(args: list[str]) -> None:
    res = CliRunner().invoke(app, ["run", *map(str, args), "--quiet"])
    assert res.exit_code == 0, res.stderr


def _same_path(out: Path, ref: Path, tol_m: float = SAME_M) -> dict:
    a, b = read_results(out), read_results(ref)
    assert len(a.t_s) == len(b.t_s) == N_FRAMES
    np.testing.assert_allclose(a.t_s, b.t_s, atol=1e-8)
    err = np.abs(a.xy_m - b.xy_m).max()
    assert err <= tol_m, f"max position difference {err} m"
    assert np.abs(a.dr_xy_m - b.dr_xy_m).max() <= tol_m
    assert list(a.trajectory["altitude_source"]) == list(b.trajectory["altitude_source"])
    return a.summary


@pytest.mark.parametrize("flavour, name", [("ros1", "dive.bag"), ("sqlite3", "bag_sqlite"), ("mcap", "bag_mcap")])
def test_a_bag_gives_the_sequence_folders_trajectory(dive, flavour, name):
    bag = dive / name
    topics = sequence_to_bag(dive / "seq", bag, flavour, heading="imu", altitude="range", attitude=True)
    out = dive / f"out_{flavour}"
    _run(
        [
            bag,
            "--camera",
            dive / "camera.toml",
            "--image-topic",
            topics["image"],
            "--heading-topic",
            topics["heading"],
            "--altitude-topic",
            topics["altitude"],
            "--attitude-topic",
            topics["heading"],
            "--out",
            out,
        ]
    )
    summary = _same_path(out, dive / "ref")
    src = summary["sources"]
    assert (
        src["input"]["kind"]
        == {"ros1": "ROS 1 bag", "sqlite3": "ROS 2 bag (sqlite3)", "mcap": "ROS 2 bag (MCAP)"}[flavour]
    )
    assert src["heading"]["frames"] == {"navigation": N_FRAMES}
    assert "/nav/heading (sensor_msgs/msg/Imu orientation, ENU)" in src["heading"]["detail"]
    assert src["altitude"]["frames"] == {"laser+sonar": N_FRAMES}  # a sensor_msgs/Range is a sonar
    assert src["attitude"]["source"] == "given" and src["warnings"] == []


def test_a_bag_imported_as_a_sequence_runs_the_same(dive):
    bag = dive / "import.bag"
    topics = sequence_to_bag(dive / "seq", bag, "ros1", heading="odometry", altitude="float64", attitude=True)
    seq = dive / "imported"
    res = CliRunner().invoke(
        app,
        [
            "import",
            str(bag),
            "--camera",
            str(dive / "camera.toml"),
            "--image-topic",
            topics["image"],
            "--heading-topic",
            topics["heading"],
            "--altitude-topic",
            topics["altitude"],
            "--attitude-topic",
            topics["heading"],
            "--out",
            str(seq),
            "-q",
        ],
    )
    assert res.exit_code == 0, res.stderr
    assert f"wrote {seq} ({N_FRAMES} frames)" in res.stdout
    s = open_sequence(seq)
    ref = open_sequence(dive / "seq")
    assert [r.t_s for r in s.rows] == pytest.approx([r.t_s for r in ref.rows], abs=1e-9)
    np.testing.assert_allclose([r.sonar_altitude_m for r in s.rows], [r.sonar_altitude_m for r in ref.rows], atol=1e-12)
    np.testing.assert_allclose([r.roll_rad for r in s.rows], [r.roll_rad for r in ref.rows], atol=1e-12)
    assert s.info.metadata["heading_input"] == "navigation" and s.info.metadata["altitude_input"] == "navigation"
    _run([seq, "--out", dive / "imported_run"])
    summary = _same_path(dive / "imported_run", dive / "ref")
    # The imported sequence still says where its heading and altitude came from.
    assert summary["sources"]["heading"]["frames"] == {"navigation": N_FRAMES}
    assert summary["sources"]["altitude"]["frames"] == {"laser+navigation": N_FRAMES}


def _write_video(seq: Path, path: Path, codec: str, pix_fmt: str) -> None:
    import av

    options = {"crf": "0"} if codec == "libx264rgb" else {}
    with av.open(str(path), "w") as c:
        st = c.add_stream(codec, rate=5, options=options)
        st.width, st.height, st.pix_fmt = 360, 272, pix_fmt
        for f in open_sequence(seq).frames(prefetch=0):
            for p in st.encode(av.VideoFrame.from_ndarray(f.image, format="rgb24")):
                c.mux(p)
        for p in st.encode():
            c.mux(p)


def _nav_csv(seq: Path, path: Path, offset_s: float) -> None:
    """The sequence's compass, sonar and attitude as a 10 Hz log in degrees on another clock."""
    rows = open_sequence(seq).rows
    lines = ["unix_time,hdg_deg,alt,roll_deg,pitch_deg"]
    for r, n in zip(rows, rows[1:] + [None]):
        lines.append(
            f"{offset_s + r.t_s!r},{math.degrees(r.heading_rad)!r},{r.sonar_altitude_m!r},"
            f"{math.degrees(r.roll_rad)!r},{math.degrees(r.pitch_rad)!r}"
        )
        if n is not None:  # a row half-way, interpolated on the shorter arc
            dh = math.atan2(math.sin(n.heading_rad - r.heading_rad), math.cos(n.heading_rad - r.heading_rad))
            lines.append(
                f"{offset_s + (r.t_s + n.t_s) / 2!r},{math.degrees(r.heading_rad + dh / 2)!r},"
                f"{(r.sonar_altitude_m + n.sonar_altitude_m) / 2!r},{math.degrees((r.roll_rad + n.roll_rad) / 2)!r},"
                f"{math.degrees((r.pitch_rad + n.pitch_rad) / 2)!r}"
            )
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("codec, pix_fmt, suffix", [("ffv1", "bgr0", ".mkv"), ("libx264rgb", "rgb24", ".mp4")])
def test_a_video_with_its_nav_csv_gives_the_sequence_folders_trajectory(dive, codec, pix_fmt, suffix):
    video = dive / f"dive_{codec}{suffix}"
    _write_video(dive / "seq", video, codec, pix_fmt)
    offset = 1_372_687_208.617628827
    nav = dive / "nav.csv"
    _nav_csv(dive / "seq", nav, offset)
    cam = dive / f"camera_{codec}.toml"
    cam.write_text(
        (dive / "camera.toml").read_text()
        + '\n[nav]\ntime = "unix_time"\nheading = "hdg_deg"\naltitude = "alt"\nroll = "roll_deg"\npitch = "pitch_deg"\n'
    )
    out = dive / f"video_{codec}"
    _run([video, "--camera", cam, "--nav", nav, "--nav-time-offset", repr(offset), "--out", out])
    a, b = read_results(out), read_results(dive / "ref")
    rms_m = float(np.sqrt(np.mean(np.sum((a.xy_m - b.xy_m) ** 2, axis=1))))
    assert rms_m < 0.002
    _same_path(out, dive / "ref", tol_m=1e-6)
    src = a.summary["sources"]
    assert src["heading"]["frames"] == {"navigation": N_FRAMES} and "hdg_deg (deg" in src["heading"]["detail"]
    assert src["altitude"]["frames"] == {"laser+navigation": N_FRAMES}
    assert a.summary["inputs"]["nav_time_offset"] == offset


def test_an_image_folder_with_times_and_nav(dive):
    folder = dive / "plain"
    folder.mkdir()
    rows = open_sequence(dive / "seq").rows
    # Names that sort wrongly as text (f10 before f2): the times file orders them.
    times = ["image,t_s"]
    for k, r in enumerate(rows):
        name = f"f{k}.png"
        shutil.copy(dive / "seq" / r.image, folder / name)
        times.append(f"{name},{r.t_s!r}")
    (dive / "times.csv").write_text("\n".join(times[:1] + times[:0:-1]) + "\n")  # rows in any order
    _nav_csv(dive / "seq", dive / "nav_folder.csv", 0.0)
    out = dive / "folder_out"
    _run(
        [
            folder,
            "--camera",
            dive / "camera.toml",
            "--times",
            dive / "times.csv",
            "--nav",
            dive / "nav_folder.csv",
            "--nav-map",
            "time=unix_time",
            "--nav-map",
            "heading=hdg_deg",
            "--nav-map",
            "altitude=alt",
            "--nav-map",
            "roll=roll_deg",
            "--nav-map",
            "pitch=pitch_deg",
            "--out",
            out,
        ]
    )
    summary = _same_path(out, dive / "ref")
    assert summary["sources"]["input"]["kind"] == "image folder"
    # --fps: natural order (f2 before f10), frame k at k / fps
    out2 = dive / "folder_fps"
    _run(
        [
            folder,
            "--camera",
            dive / "camera.toml",
            "--fps",
            "5",
            "--nav",
            dive / "nav_folder.csv",
            "--nav-map",
            "time=unix_time",
            "--nav-map",
            "heading=hdg_deg",
            "--nav-map",
            "altitude=alt",
            "--nav-map",
            "roll=roll_deg",
            "--nav-map",
            "pitch=pitch_deg",
            "--out",
            out2,
        ]
    )
    _same_path(out2, dive / "ref", tol_m=1e-6)  # k / 5 vs the simulator's 0.2 k: the last digit of t_s


def test_without_navigation_the_summary_and_report_say_what_was_assumed(dive):
    from rovslam.viz.report import write_report

    video = dive / "bare.mkv"
    _write_video(dive / "seq", video, "ffv1", "bgr0")
    cam = dive / "camera_nolaser.toml"
    cam.write_text((dive / "camera.toml").read_text().split("[[laser]]")[0] + "\n[vehicle]\naltitude_m = 1.31\n")
    out = dive / "bare_out"
    _run([video, "--camera", cam, "--out", out])
    s = json.loads((out / "summary.json").read_text())["sources"]
    assert s["altitude"]["frames"] == {"assumed constant": N_FRAMES}
    assert "1.31 m, [vehicle] altitude_m of" in s["altitude"]["detail"]
    assert s["heading"]["frames"] == {"tokens only (no compass)": N_FRAMES}
    assert (
        len(s["warnings"]) == 2 and "altitude assumed constant" in s["warnings"][0] and "no compass" in s["warnings"][1]
    )
    html = write_report(out, mosaic=False).read_text(encoding="utf-8")
    assert "ASSUMED constant 1.31 m (100 %)" in html and "tokens only (no compass) (100 %)" in html
    assert "Altitude NOT MEASURED" in html


# --------------------------------------------------------------------------- the real Sparus video


@needs_sparus
def test_sparus_video_with_its_own_navigation(tmp_path):
    """Heading change within 1.6 degrees of the navigation's, direction of travel within 15 degrees."""
    import tomllib

    from rovslam.io.nav import nav_mapping, read_nav_csv

    out = tmp_path / "sparus"
    _run(
        [
            SPARUS / "sparus_snippet.mp4",
            "--camera",
            ROOT / "examples" / "sparus-camera.toml",
            "--nav",
            SPARUS / "sparus_snippet.csv",
            "--out",
            out,
        ]
    )
    r = read_results(out)
    assert len(r.t_s) == 22 and r.summary["sources"]["heading"]["frames"] == {"navigation": 22}
    nav = read_nav_csv(
        SPARUS / "sparus_snippet.csv",
        nav_mapping(tomllib.loads((ROOT / "examples" / "sparus-camera.toml").read_text())["nav"]),
    )
    t0, t1 = float(r.t_s[0]), float(r.t_s[-1])
    nav_turn = math.degrees(nav.sample(t1).heading_rad - nav.sample(t0).heading_rad)
    run_turn = math.degrees(r.trajectory["heading_rad"][-1] - r.trajectory["heading_rad"][0])
    # Measured (this run; test body run with the snippet at /work/shared/data/sparus): the run turns -24.14
    # degrees against the log's -23.48 (0.66 apart), and travels at 23.8 degrees against the log's 30.7
    # (6.9 apart); the bounds are 2.4 and 2.2 times those.
    assert abs(run_turn - nav_turn) < 1.6, (run_turn, nav_turn)
    # The log's positions (ENU: x east, y north) at the first and last frame, interpolated.
    import csv

    with (SPARUS / "sparus_snippet.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    ts = np.array([float(x["ts"]) for x in rows]) - 1372687208.617628827
    east = np.interp([t0, t1], ts, [float(x["x"]) for x in rows])
    north = np.interp([t0, t1], ts, [float(x["y"]) for x in rows])
    nav_dir = math.degrees(math.atan2(east[1] - east[0], north[1] - north[0]))
    d = r.xy_m[-1] - r.xy_m[0]  # rovslam: x north, y east
    run_dir = math.degrees(math.atan2(d[1], d[0]))
    assert abs((run_dir - nav_dir + 180) % 360 - 180) < 15.0, (run_dir, nav_dir)
