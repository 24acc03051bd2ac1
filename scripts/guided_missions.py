"""Guided missions over loopback against ``rovslam navigate``: the true arrival errors, as a table.

For each preset and seed: ``rovslam navigate`` (steered by the online SLAM estimate, and by dead
reckoning) in the simulator, then the same mission flown through the autopilot's interface:
``rovslam sitl --follow-guided`` (the simulated ArduSub vehicle, its pilot selecting GUIDED) and
``rovslam live --poi --guide`` (every frame processed), both as subprocesses on 127.0.0.1. The true
arrival errors of the loopback mission come from ``sitl``'s ``events.csv`` (the true position when
each "arrived" STATUSTEXT came), so they need nothing from the estimator.

    python scripts/guided_missions.py --presets rough-turns photo-turns --seeds 0 1 2 --jobs 3

Each loopback mission runs ``--pace`` times slower than real time (2 by default: about 25 minutes
for a 30 s survey and six points); ``--jobs`` missions run at once. Results go to ``--out``
(``missions.md``, ``missions.csv`` and each run's folders); a finished run is not flown again.
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

POINTS = [
    ("rock", 0.3, 0.3),
    ("anchor", 0.4, 0.0),
    ("crack", 0.3, -0.3),
    ("sponge", -0.3, -0.3),
    ("ledge", -0.4, 0.0),
    ("wreck", -0.3, 0.3),
]


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def rovslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "rovslam", *args]


def navigate_errors(preset: str, seed: int, estimator: str, poi: Path, out: Path, a) -> dict[str, float]:
    """{point: true arrival error (m)} of ``rovslam navigate``."""
    if not (out / "arrivals.csv").exists():
        subprocess.run(
            rovslam(
                "navigate",
                "--scenario",
                preset,
                "--poi",
                str(poi),
                "--out",
                str(out),
                "--estimator",
                estimator,
                "--survey-s",
                str(a.survey_s),
                "--hold-s",
                str(a.hold_s),
                "--seed",
                str(seed),
                "--quiet",
                "--overwrite",
            ),
            check=True,
            stdout=subprocess.DEVNULL,
        )
    with (out / "arrivals.csv").open(newline="", encoding="utf-8") as fh:
        return {r["name"]: float(r["true_err_m"]) for r in csv.DictReader(fh) if r["reached"] == "1"}


def loopback_errors(preset: str, seed: int, poi: Path, root: Path, a) -> dict[str, float]:
    """{point: true arrival error (m)} of ``sitl --follow-guided`` + ``live --poi --guide``."""
    truth, out = root / "truth", root / "out"
    events = truth / "events.csv"
    if not (events.exists() and "mission done" in events.read_text(encoding="utf-8")):
        if root.exists():
            shutil.rmtree(root)  # an interrupted mission is flown again from the start
        vport, mport = free_udp_port(), free_udp_port()
        root.mkdir(parents=True, exist_ok=True)
        with (root / "sitl.log").open("w") as slog, (root / "live.log").open("w") as llog:
            sitl = subprocess.Popen(
                rovslam(
                    "sitl",
                    "--scenario",
                    preset,
                    "--seed",
                    str(seed),
                    "--out",
                    str(truth),
                    "--quiet",
                    "--video",
                    f"udp://127.0.0.1:{vport}",
                    "--mavlink",
                    f"udpout:127.0.0.1:{mport}",
                    "--duration-s",
                    str(a.dive_s),
                    "--pace",
                    str(a.pace),
                    "--follow-guided",
                    "--pilot-guided-s",
                    "1",
                    "--wait-for-peer-s",
                    "120",
                ),
                stdout=slog,
                stderr=subprocess.STDOUT,
            )
            deadline = time.monotonic() + 60.0
            while not (truth / "camera.toml").exists() and time.monotonic() < deadline and sitl.poll() is None:
                time.sleep(0.2)
            live = subprocess.Popen(
                rovslam(
                    "live",
                    "--video",
                    f"udp://127.0.0.1:{vport}",
                    "--camera",
                    str(truth / "camera.toml"),
                    "--mavlink",
                    f"udpin:127.0.0.1:{mport}",
                    "--out",
                    str(out),
                    "--every-frame",
                    "--quiet",
                    "--poi",
                    str(poi),
                    "--guide",
                    "--survey-s",
                    str(a.survey_s),
                    "--hold-s",
                    str(a.hold_s),
                    "--guide-pace",
                    str(a.pace),
                    "--heartbeat-timeout-s",
                    "120",
                    "--wait-s",
                    "200",
                ),
                stdout=llog,
                stderr=subprocess.STDOUT,
            )
            end = time.monotonic() + a.pace * a.dive_s + 240.0
            try:
                while time.monotonic() < end and sitl.poll() is None and live.poll() is None:
                    if events.exists() and "mission done" in events.read_text(encoding="utf-8"):
                        break
                    time.sleep(1.0)
            finally:
                for p in (live, sitl):
                    if p.poll() is None:
                        p.send_signal(signal.SIGINT)
                for p in (live, sitl):
                    try:
                        p.wait(timeout=60)
                    except subprocess.TimeoutExpired:
                        p.kill()
    errors: dict[str, float] = {}
    if events.exists():
        with events.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        for name, x, y in POINTS:
            for r in rows:
                if re.match(rf"arrived {re.escape(name)} ", r["text"]):
                    errors[name] = math.hypot(float(r["x_true_m"]) - x, float(r["y_true_m"]) - y)
                    break
    return errors


def one(preset: str, seed: int, poi: Path, a) -> dict:
    root = a.out / f"{preset}_s{seed}"
    nav = navigate_errors(preset, seed, "slam", poi, root / "navigate", a)
    dr = navigate_errors(preset, seed, "dead-reckoning", poi, root / "dead-reckoning", a)
    live = loopback_errors(preset, seed, poi, root / "loopback", a)
    row = {"preset": preset, "seed": seed}
    for key, errs in (("live", live), ("navigate", nav), ("dr", dr)):
        vals = list(errs.values())
        row[f"{key}_reached"] = len(vals)
        row[f"{key}_mean_mm"] = 1000 * sum(vals) / len(vals) if vals else float("nan")
        row[f"{key}_max_mm"] = 1000 * max(vals) if vals else float("nan")
    print(f"{preset} seed {seed}: {row}", flush=True)
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| preset | seed | loopback: reached, mean / max [mm] | navigate: reached, mean / max [mm] "
        "| dead reckoning: reached, mean / max [mm] | loopback / navigate | dead reckoning / loopback |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    n = len(POINTS)
    for r in rows:
        lines.append(
            f"| {r['preset']} | {r['seed']} "
            + "".join(
                f"| {r[k + '_reached']}/{n}, {r[k + '_mean_mm']:.2f} / {r[k + '_max_mm']:.2f} "
                for k in ("live", "navigate", "dr")
            )
            + f"| {r['live_mean_mm'] / r['navigate_mean_mm']:.2f} | {r['dr_mean_mm'] / r['live_mean_mm']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["rough-turns", "photo-turns"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--survey-s", type=float, default=30.0)
    ap.add_argument("--hold-s", type=float, default=2.0)
    ap.add_argument("--dive-s", type=float, default=900.0, help="sitl's longest dive (s)")
    ap.add_argument("--pace", type=float, default=2.0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("guided-missions"))
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    poi = a.out / "poi.csv"
    poi.write_text("name,x_m,y_m\n" + "".join(f"{n},{x},{y}\n" for n, x, y in POINTS), encoding="utf-8")
    cases = [(p, s) for p in a.presets for s in a.seeds]
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        rows = list(pool.map(lambda c: one(c[0], c[1], poi, a), cases))
    with (a.out / "missions.csv").open("w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    md = table(rows)
    (a.out / "missions.md").write_text(md, encoding="utf-8")
    print(md)


if __name__ == "__main__":
    main()
