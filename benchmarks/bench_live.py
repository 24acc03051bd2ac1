"""Latency, CPU and dropped frames of ``rovslam live`` fed by ``rovslam sitl`` on loopback, in real time.

Run: ``python benchmarks/bench_live.py [--seconds 60] [--cases 360x272,1920x1080]``
(``--quick``: 10 s). For each case a dive rendered beforehand (simulated once with seed 0 and
cached, as the other benchmarks' sequences) is streamed by ``rovslam sitl --from`` in real time:

* ``360x272 10 Hz``: the paper's camera and survey (``portofino-short``) at 10 frames/s;
* ``1920x1080 25 Hz``: the same survey through the HD camera of the benchmarks (``bench-hd``).

``rovslam live`` receives the H.264 MPEG-TS stream (``udp://127.0.0.1:PORT``) and the vehicle's
MAVLink (``udpin:127.0.0.1:PORT``), pinned to one core (``sitl`` on another), and runs for the
dive plus a margin. Printed per case, from live's ``OUT/summary.json`` ``live`` block and the
process's own CPU time (``os.wait4``): frames sent / received / processed / dropped, latency
from a frame's arrival to its messages sent (p50, p99, max, ms) and its three stages (decoding,
waiting for the loop, processing: p50 and p99), CPU seconds of ``live`` (with its
start-up) and per frame, the CPU a frame while it streamed (``live``'s ``cpu_ms_per_frame``: every
thread, from the first processed frame to the last), and the targets: p99 below one frame period, no frame dropped; and the frames ``sitl``
sent late (over half a period: its reading, decoding and encoding did not keep up, so the figures
of that case are not of a steady stream). Figures also go to
``benchmarks/results/live.json``. Wall-clock figures: run it on a machine doing nothing else.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from benchmarks._harness import CACHE, Case, _hd_scenario, _sim_hash, machine, write_json  # noqa: E402

CASES = {"360x272": (10.0, "png"), "1920x1080": (25.0, "jpg")}
MARGIN_S = 30.0  # live runs this much longer than the dive (its start, the stream's wait)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _scenario(resolution: str, rate_hz: float) -> str:
    """The preset of a case, registered in this process (``bench-10hz``: portofino-short at 10 frames/s)."""
    from rovslam.sim import SCENARIOS

    if resolution == "1920x1080":
        return _hd_scenario()
    if "bench-10hz" not in SCENARIOS:
        base = SCENARIOS["portofino-short"]
        SCENARIOS["bench-10hz"] = dataclasses.replace(
            base, name="bench-10hz", frame_rate_hz=rate_hz, description="portofino-short at 10 frames/s"
        )
    return "bench-10hz"


def _sequence(resolution: str, seconds: float) -> Path:
    """The case's dive, simulated once into the benchmark cache."""
    from rovslam.sim import simulate

    rate, fmt = CASES[resolution]
    case = Case(resolution, "sim", fmt, int(round(seconds * rate)) + 1)
    scenario = _scenario(resolution, rate)
    folder = CACHE / f"live-{scenario}-{case.frames}-{_sim_hash()}"
    if not (folder / ".complete").is_file():
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
        folder.parent.mkdir(parents=True, exist_ok=True)
        print(f"simulating {case.frames} frames of {scenario} into {folder} (once; cached)", flush=True)
        simulate(scenario, folder, frames=case.frames, seed=0, image_format=fmt)
        (folder / ".complete").write_text("ok\n")
    return folder


def _pinned(cpu: int):
    return lambda: os.sched_setaffinity(0, {cpu})


def _run_case(resolution: str, seconds: float, work: Path) -> dict:
    rate, _ = CASES[resolution]
    seq = _sequence(resolution, seconds)
    video, mav = _free_port(), _free_port()
    truth, out = work / f"truth-{resolution}", work / f"live-{resolution}"
    cpus = sorted(os.sched_getaffinity(0))
    live_cpu, sitl_cpu = cpus[-1], cpus[0]
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    live_log = (work / f"live-{resolution}.log").open("w")
    live = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rovslam",
            "live",
            "--video",
            f"udp://127.0.0.1:{video}",
            "--camera",
            str(seq / "sequence.toml"),
            "--mavlink",
            f"udpin:127.0.0.1:{mav}",
            "--out",
            str(out),
            "--duration-s",
            str(seconds + MARGIN_S),
            "--quiet",
        ],
        env=env,
        preexec_fn=_pinned(live_cpu),
        stdout=subprocess.DEVNULL,
        stderr=live_log,
    )
    sitl = subprocess.run(  # the dive starts when live's first HEARTBEAT arrives
        [
            sys.executable,
            "-m",
            "rovslam",
            "sitl",
            "--from",
            str(seq),
            "--out",
            str(truth),
            "--duration-s",
            str(seconds),
            "--video",
            f"udp://127.0.0.1:{video}",
            "--mavlink",
            f"udpout:127.0.0.1:{mav}",
            "--wait-for-peer-s",
            str(MARGIN_S),
            "--quiet",
        ],
        env=env,
        preexec_fn=_pinned(sitl_cpu),
        capture_output=True,
        text=True,
        timeout=seconds * 5 + 600,
    )
    _, status, usage = os.wait4(live.pid, 0)
    live.returncode = os.waitstatus_to_exitcode(status)
    live_log.close()
    err = (work / f"live-{resolution}.log").read_text()
    row: dict = {
        "case": f"{resolution} {rate:g} Hz",
        "seconds": seconds,
        "live_exit": live.returncode,
        "sitl_exit": sitl.returncode,
        "live_cpu_s": usage.ru_utime + usage.ru_stime,
    }
    if sitl.returncode != 0:
        row["error"] = f"sitl: {sitl.stderr.strip()[-300:]}"
    return _figures(row, out, truth, err, rate)


def _figures(row: dict, out: Path, truth: Path, live_stderr: str, rate_hz: float) -> dict:
    """``row`` with the figures of live's ``OUT/summary.json`` ``live`` block and sitl's ``sitl.json``."""
    summary_path = out / "summary.json"
    if not summary_path.is_file():
        row.setdefault(
            "error", f"live wrote no summary.json (exit {row.get('live_exit')}): {live_stderr.strip()[-300:]}"
        )
        return row
    block = json.loads(summary_path.read_text()).get("live", {})
    sitl_json = json.loads((truth / "sitl.json").read_text()) if (truth / "sitl.json").is_file() else {}
    lat = block.get("latency_ms", {})
    row.update(
        frames_sent=sitl_json.get("frames_sent"),
        sitl_late_frames=sitl_json.get("late_frames"),
        frames_received=block.get("frames_received"),
        frames_processed=block.get("frames_processed"),
        frames_dropped=block.get("frames_dropped"),
        latency_p50_ms=lat.get("p50"),
        latency_p99_ms=lat.get("p99"),
        latency_max_ms=lat.get("max"),
    )
    for stage, figures in block.get("latency_stages_ms", {}).items():  # arrival -> decoded -> taken -> sent
        row[f"{stage}_p50_ms"], row[f"{stage}_p99_ms"] = figures.get("p50"), figures.get("p99")
    processed = row["frames_processed"] or 0
    row["live_cpu_ms_per_frame"] = 1e3 * row["live_cpu_s"] / processed if processed else None
    row["streaming_cpu_ms_per_frame"] = block.get("cpu_ms_per_frame")  # first to last frame: no start-up, no wait
    row["target_p99_below_period"] = row["latency_p99_ms"] is not None and row["latency_p99_ms"] < 1e3 / rate_hz
    row["target_no_drop"] = row["frames_dropped"] == 0
    return row


def _fmt(v, digits: int = 1) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}" if isinstance(v, float) else str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="10 s per case")
    ap.add_argument("--cases", default=",".join(CASES))
    args, _ = ap.parse_known_args()  # (python -m benchmarks passes every script the same options)
    seconds = 10.0 if args.quick else args.seconds
    rows = []
    with tempfile.TemporaryDirectory(prefix="rovslam-bench-live-") as tmp:
        for resolution in args.cases.split(","):
            print(f"{resolution}: sitl --from + live, {seconds:g} s on loopback ...", flush=True)
            rows.append(_run_case(resolution.strip(), seconds, Path(tmp)))
    head = (
        "case",
        "sent",
        "late",
        "recv",
        "proc",
        "drop",
        "p50 ms",
        "p99 ms",
        "max ms",
        "live CPU s",
        "CPU ms/frame",
        "streaming CPU ms/frame",
        "p99<period",
        "no drop",
    )
    print(" | ".join(head))
    for r in rows:
        if "error" in r and r.get("frames_processed") is None:
            print(f"{r['case']}: {r['error']}")
            continue
        print(
            " | ".join(
                [
                    r["case"],
                    _fmt(r["frames_sent"]),
                    _fmt(r["sitl_late_frames"]),
                    _fmt(r["frames_received"]),
                    _fmt(r["frames_processed"]),
                    _fmt(r["frames_dropped"]),
                    _fmt(r["latency_p50_ms"]),
                    _fmt(r["latency_p99_ms"]),
                    _fmt(r["latency_max_ms"]),
                    _fmt(r["live_cpu_s"]),
                    _fmt(r["live_cpu_ms_per_frame"]),
                    _fmt(r.get("streaming_cpu_ms_per_frame")),
                    "yes" if r["target_p99_below_period"] else "NO",
                    "yes" if r["target_no_drop"] else "NO",
                ]
            )
        )
    print(
        "latency by stage, p50 / p99 ms: decoding (arrival -> decoded), waiting (-> the loop takes it), processing (-> sent)"
    )
    from rovslam.live.session import LATENCY_STAGES

    for r in rows:
        stages = [f"{s} {_fmt(r.get(f'{s}_p50_ms'))} / {_fmt(r.get(f'{s}_p99_ms'))}" for s in LATENCY_STAGES]
        print(f"{r['case']}: " + ", ".join(stages))
    print(f"results: {write_json('live', {'machine': machine(), 'rows': rows})}")


if __name__ == "__main__":
    main()
