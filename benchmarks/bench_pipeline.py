"""End-to-end frames per second of `rovslam run` on a simulated portofino sequence.

Run: ``python benchmarks/bench_pipeline.py [--frames 600] [--repeats 3]``. Simulates the
sequence once (seeded) into a temporary folder, then times, over ``--repeats`` runs:

* ``decode only`` (the baseline, measured in the same run): reading and decoding every PNG;
* ``pipeline``: the whole per-frame loop with the result files written.

Prints median wall time, frames per second and the ratio pipeline / decode.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from rovslam.io.sequence import open_sequence
from rovslam.runner import run_sequence
from rovslam.sim import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scenario", default="portofino")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        seq = Path(tmp) / "seq"
        simulate(args.scenario, seq, frames=args.frames, seed=0)
        decode, full = [], []
        for r in range(args.repeats):
            t0 = time.perf_counter()
            for _ in open_sequence(seq).frames():
                pass
            decode.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            run_sequence(seq, Path(tmp) / f"out{r}")
            full.append(time.perf_counter() - t0)
    d, f = statistics.median(decode), statistics.median(full)
    n = args.frames
    print(f"{args.scenario}, {n} frames, median of {args.repeats} runs")
    print(f"{'stage':<14}{'wall s':>10}{'ms/frame':>10}{'frames/s':>10}")
    print(f"{'decode only':<14}{d:>10.2f}{1000 * d / n:>10.2f}{n / d:>10.0f}")
    print(f"{'pipeline':<14}{f:>10.2f}{1000 * f / n:>10.2f}{n / f:>10.0f}")
    print(f"pipeline / decode = {f / d:.1f}x; full trial (13,275 frames) projected: {13275 * f / n:.0f} s")


if __name__ == "__main__":
    main()
