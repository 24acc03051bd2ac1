"""The README's worked examples of "Real dives in": one dive as a ROS 2 bag, a video with its NAV.csv and a
folder of JPEG images, and the real Sparus AUV video with its own log; each run with the CLI, each path plotted.

Run: ``python docs/make_input_examples.py [--keep DIR]`` (about a minute). It simulates 60 s of the
``rough-turns`` dive (turns, altitude swings, roll and pitch, turbid water), writes it in the
three formats (the bag with ``tests/rosbag_writer.py``, the video with PyAV, H.264 at crf 18,
i.e. lossy), runs ``rovslam run`` on each exactly as the README shows, and writes
``docs/img/input_*.png``: the estimated path, dead reckoning and the truth (the navigation's
positions for Sparus), north up. The figures it prints are those quoted in the README.
"""

from __future__ import annotations

import argparse
import math
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
SPARUS = ROOT / ".." / "shared" / "data" / "sparus"
sys.path.insert(0, str(ROOT / "tests"))


def sh(cmd: str, cwd: Path) -> None:
    print(f"$ {cmd}")
    subprocess.run(shlex.split(cmd), cwd=cwd, check=True)


def make_inputs(w: Path) -> None:
    import av
    import cv2
    from rosbag_writer import sequence_to_bag

    from rovslam.io.sequence import open_sequence

    sh("rovslam simulate --scenario rough-turns-short --frames 300 --out dive -q", w)
    seq = open_sequence(w / "dive")
    text = (w / "dive" / "sequence.toml").read_text()
    (w / "camera.toml").write_text(text.split("[metadata]")[0].replace('format = "rovslam-sequence/1"\n', ""))
    # ROS 2 bag (MCAP): images, an Imu heading with roll and pitch, a sonar Range.
    sequence_to_bag(w / "dive", w / "dive_bag", "mcap", heading="imu", altitude="range", attitude=True)
    # A video (H.264, lossy) and a 10 Hz NAV.csv on the UNIX clock, in degrees.
    with av.open(str(w / "dive.mp4"), "w") as c:
        st = c.add_stream("libx264", rate=5, options={"crf": "18"})
        st.width, st.height, st.pix_fmt = seq.info.camera.width_px, seq.info.camera.height_px, "yuv420p"
        for f in seq.frames(prefetch=0):
            for p in st.encode(av.VideoFrame.from_ndarray(f.image, format="rgb24")):
                c.mux(p)
        for p in st.encode():
            c.mux(p)
    t0 = 1_717_000_000.0
    rows = seq.rows
    lines = ["unix_time,heading_deg,altitude,roll_deg,pitch_deg"]
    for r, n in zip(rows, rows[1:] + [rows[-1]]):
        for a in (0.0, 0.5) if n is not r else (0.0,):
            dh = math.atan2(math.sin(n.heading_rad - r.heading_rad), math.cos(n.heading_rad - r.heading_rad))
            lines.append(
                f"{t0 + r.t_s + a * (n.t_s - r.t_s):.3f},{math.degrees(r.heading_rad + a * dh):.3f},"
                f"{r.sonar_altitude_m + a * (n.sonar_altitude_m - r.sonar_altitude_m):.3f},"
                f"{math.degrees(r.roll_rad):.3f},{math.degrees(r.pitch_rad):.3f}"
            )
    (w / "dive_nav.csv").write_text("\n".join(lines) + "\n")
    (w / "camera_nav.toml").write_text(
        (w / "camera.toml").read_text() + '\n[nav]\ntime = "unix_time"\n'
        'heading = "heading_deg"\naltitude = "altitude"\nroll = "roll_deg"\npitch = "pitch_deg"\n'
    )
    # A folder of JPEG images, nothing else.
    (w / "jpegs").mkdir()
    for k, f in enumerate(seq.frames(prefetch=0)):
        cv2.imwrite(
            str(w / "jpegs" / f"IMG_{k + 1}.jpg"),
            cv2.cvtColor(f.image, cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_JPEG_QUALITY, 92],
        )


OFFSET = "1717000000.0"
COMMANDS = {
    "bag": "rovslam run dive_bag --camera camera.toml --image-topic /camera/image --heading-topic /nav/heading "
    "--attitude-topic /nav/heading --altitude-topic /nav/altitude --out out_bag -q",
    "video_nav": f"rovslam run dive.mp4 --camera camera_nav.toml --nav dive_nav.csv --nav-time-offset {OFFSET} --out out_video -q",
    "folder": "rovslam run jpegs --camera camera.toml --fps 5 --out out_folder -q",
    "folder_nav": f"rovslam run jpegs --camera camera_nav.toml --fps 5 --nav dive_nav.csv --nav-time-offset {OFFSET} "
    "--out out_folder_nav -q",
    "import": "rovslam import dive_bag --camera camera.toml --image-topic /camera/image --heading-topic /nav/heading "
    "--attitude-topic /nav/heading --altitude-topic /nav/altitude --out imported -q",
    "imported": "rovslam run imported --out out_imported -q",
    "sparus": f"rovslam run {SPARUS / 'sparus_snippet.mp4'} --camera {ROOT / 'examples' / 'sparus-camera.toml'} "
    f"--nav {SPARUS / 'sparus_snippet.csv'} --out out_sparus -q",
}


def plot(panels: list[tuple[Path, str, np.ndarray | None, str]], png: Path) -> list[dict]:
    """One panel per (results folder, title, reference path, its label); returns each run's figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rovslam.io.run_results import read_results

    fig, axes = plt.subplots(1, len(panels), figsize=(5.2 * len(panels), 4.6), dpi=110, squeeze=False)
    out = []
    for ax, (folder, title, ref_xy, ref_label) in zip(axes[0], panels):
        r = read_results(folder)
        if ref_xy is not None:
            ax.plot(ref_xy[:, 1], ref_xy[:, 0], "k--", lw=0.9, label=ref_label)
        ax.plot(r.dr_xy_m[:, 1], r.dr_xy_m[:, 0], color="tab:gray", lw=0.8, label="dead reckoning")
        ax.plot(r.xy_m[:, 1], r.xy_m[:, 0], color="tab:blue", lw=1.2, label="rovslam")
        ax.plot(r.xy_m[0, 1], r.xy_m[0, 0], "o", color="tab:blue", ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east y [m]")
        ax.set_ylabel("north x [m]")
        src = r.summary["sources"]
        ax.set_title(f"{title}\naltitude: {src['altitude']['source']}, heading: {src['heading']['source']}", fontsize=9)
        ax.legend(fontsize=8, loc="best")
        ax.grid(alpha=0.3)
        figures = {"frames": len(r.t_s), "length_m": float(np.sum(np.linalg.norm(np.diff(r.xy_m, axis=0), axis=1)))}
        if ref_xy is not None and len(ref_xy) == len(r.xy_m):
            figures["ate_rmse_m"] = float(np.sqrt(np.mean(np.sum((r.xy_m - ref_xy) ** 2, axis=1))))
            figures["dr_ate_rmse_m"] = float(np.sqrt(np.mean(np.sum((r.dr_xy_m - ref_xy) ** 2, axis=1))))
        figures["heading_change_deg"] = math.degrees(
            float(r.trajectory["heading_rad"][-1] - r.trajectory["heading_rad"][0])
        )
        out.append(figures)
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)
    return out


def sparus_navigation(t_s: np.ndarray) -> np.ndarray:
    """The Sparus log's positions (ENU) at the run's frame times, as (north, east) from the first."""
    import csv

    with (SPARUS / "sparus_snippet.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    ts = np.array([float(x["ts"]) for x in rows]) - 1372687208.617628827
    east = np.interp(t_s, ts, [float(x["x"]) for x in rows])
    north = np.interp(t_s, ts, [float(x["y"]) for x in rows])
    return np.column_stack([north - north[0], east - east[0]])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--keep", type=Path, help="Work in this folder and keep it (default: a temporary folder).")
    args = ap.parse_args()
    from rovslam.io.run_results import read_results
    from rovslam.io.sequence import read_groundtruth

    with tempfile.TemporaryDirectory() as tmp:
        w = args.keep or Path(tmp)
        w.mkdir(parents=True, exist_ok=True)
        make_inputs(w)
        gt = read_groundtruth(w / "dive" / "groundtruth.csv")
        IMG.mkdir(parents=True, exist_ok=True)
        for name, cmd in COMMANDS.items():
            if name != "sparus" or SPARUS.is_dir():
                sh(cmd, w)
        c, s_ = math.cos(-gt.heading_rad[0]), math.sin(-gt.heading_rad[0])
        turned = gt.xy_m @ np.array([[c, -s_], [s_, c]]).T  # no compass: the path's frame is the first image's
        figures = {
            "bag": plot(
                [(w / "out_bag", "ROS 2 bag (MCAP): Imu + Range topics", gt.xy_m, "truth")], IMG / "input_bag.png"
            ),
            "video_nav": plot(
                [(w / "out_video", "H.264 video + NAV.csv (10 Hz, UNIX clock)", gt.xy_m, "truth")],
                IMG / "input_video_nav.png",
            ),
            "folder": plot(
                [
                    (w / "out_folder", "JPEG folder, --fps 5, nothing else", turned, "truth, turned to heading 0"),
                    (w / "out_folder_nav", "JPEG folder, --fps 5, --nav NAV.csv", gt.xy_m, "truth"),
                ],
                IMG / "input_folder.png",
            ),
        }
        same = np.abs(read_results(w / "out_imported").xy_m - read_results(w / "out_bag").xy_m).max()
        print(f"imported sequence vs the bag: largest position difference {same:.1e} m")
        if SPARUS.is_dir():
            nav = sparus_navigation(read_results(w / "out_sparus").t_s)
            figures["sparus"] = plot(
                [(w / "out_sparus", "Sparus AUV video + its navigation log", nav, "navigation log (positions)")],
                IMG / "input_sparus.png",
            )
        for name, figs in figures.items():
            for f in figs:
                print(name, {k: round(v, 4) if isinstance(v, float) else v for k, v in f.items()})


if __name__ == "__main__":
    main()
