"""Peak memory of ``rovslam run`` over the full portofino trial and over a dive ten times as long.

Run: ``python -m benchmarks memory`` (``--frames 3000`` for a shorter trial, ``--times 1 10``
for the lengths, ``--format jpg`` to keep the sequence small). The trial (13,275 frames of the
simulated portofino survey, seed 0) is simulated once and cached (``benchmarks/_harness.py``).
Each length runs in a fresh process: ``rovslam run`` (``run_sequence``, result files written)
over a source that reads the sequence ``times`` times in a row, times and frame indices
continuing. Every tenth of the run the process records its resident memory (``/proc/self/statm``),
its peak so far (``getrusage`` ``ru_maxrss``), the landmarks and the bytes the map holds (the EKF's
state and covariance buffers and the landmark templates). The parent also reads the child's peak
with ``getrusage(RUSAGE_CHILDREN)``. "Flat apart from the map" means: resident memory minus the
map's bytes does not grow with the length of the dive.

Writes ``benchmarks/results/memory.json`` (``--json PATH``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import TRIAL_FRAMES, Case, machine, sequence_folder, write_json  # noqa: E402

MIB = 2**20


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _map_bytes(pipe) -> int:
    ekf = pipe.ekf
    n = sum(getattr(ekf, a).nbytes for a in ("_x", "_P", "_vpad") if hasattr(ekf, a))
    for rec in pipe.landmarks:
        n += rec.patch.nbytes + (rec.patch_wide.nbytes if getattr(rec, "patch_wide", None) is not None else 0)
    return n


def worker(spec: dict) -> dict:
    import rovslam.runner as runner
    from benchmarks._harness import ReplaySource, source_override
    from rovslam.io.sequence import open_sequence

    seq = open_sequence(spec["folder"])
    src = ReplaySource(seq, spec["times"])
    total = len(src)
    step = max(1, total // 10)
    samples: list[dict] = []
    holder: dict = {}
    pipe_init = runner.SlamPipeline.__init__

    def keep(self, *a, **k):  # the run's pipeline, to read its map size
        pipe_init(self, *a, **k)
        holder["pipe"] = self

    def on_frame(res) -> None:
        if (res.index + 1) % step == 0 or res.index + 1 == total:
            samples.append(
                {
                    "frame": res.index + 1,
                    "rss_mib": _rss_bytes() / MIB,
                    "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                    "landmarks": res.n_landmarks,
                    "map_mib": _map_bytes(holder["pipe"]) / MIB,
                }
            )

    runner.SlamPipeline.__init__ = keep
    t0, c0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp, source_override(src):
        s = runner.run_sequence(spec["folder"], Path(tmp) / "out", on_frame=on_frame)
    return {
        "frames": s.frames,
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "samples": samples,
        "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def _spawn(spec: dict) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_memory", "--worker", json.dumps(spec)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    if proc.returncode != 0:
        raise SystemExit(f"memory worker failed ({spec})")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    out["child_peak_mib"] = after / 1024 if after > before else None  # the largest child so far
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--frames", type=int, default=TRIAL_FRAMES, help="frames of the trial (default: the whole trial)")
    ap.add_argument("--times", type=int, nargs="+", default=[1, 10], help="lengths, in trials read in a row")
    ap.add_argument("--format", choices=("png", "jpg"), default="png")
    ap.add_argument("--json", type=Path, default=None, help="default benchmarks/results/memory.json")
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))))
        return 0
    folder = sequence_folder(Case("360x272", "sim", args.format, args.frames))
    results = {"machine": machine(), "trial_frames": args.frames, "format": args.format, "runs": {}}
    for times in args.times:
        print(f"running {times} x {args.frames} frames ...", flush=True)
        results["runs"][str(times)] = _spawn({"folder": str(folder), "times": times})
    print(f"\npeak memory of rovslam run (360x272, {args.format}); RSS and map sampled every tenth of the run")
    head = f"{'length':>16}{'wall s':>9}{'CPU s':>8}{'peak MiB':>10}{'landmarks':>11}{'map MiB':>9}{'RSS - map, MiB at 10 % ... 100 % of the run':>50}"
    print(head)
    print("-" * len(head))
    for times, r in results["runs"].items():
        last = r["samples"][-1]
        flat = " ".join(f"{s['rss_mib'] - s['map_mib']:.0f}" for s in r["samples"])
        print(
            f"{times + ' x ' + str(args.frames):>16}{r['wall_s']:9.0f}{r.get('cpu_s', float('nan')):8.0f}{r['peak_mib']:10.0f}{last['landmarks']:11d}"
            f"{last['map_mib']:9.1f}   {flat}"
        )
    path = write_json("memory", results, args.json)
    print(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
