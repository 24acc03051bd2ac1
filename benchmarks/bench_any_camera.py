"""Frames per second of the per-frame loop on an HD camera, from memory, one core.

Run: ``python benchmarks/bench_any_camera.py [--frames 40] [--repeats 3]``. Simulates
``hd-survey`` (1920x1080, seeded) and ``portofino`` (360x272) into a temporary folder, decodes
every frame into memory first, then times :meth:`SlamPipeline.process` over the frames (no
decoding, no result files), with OpenCV on one thread:

* ``360x272 (paper)``: the paper's camera, processed as it is (the reference);
* ``1920x1080 scale 1``: the HD frames processed at full resolution (the baseline, what
  rovslam did before ``[processing]``);
* ``1920x1080 auto``: the HD frames at the automatic processing scale (480x270).

Prints the median time per frame over ``--repeats`` runs, frames per second, and the ratios
against the full-resolution baseline and the paper's camera. Two clocks: the process's CPU
time (one thread: the time one core is busy; what other jobs on a shared machine do not
change much) and the wall time.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402

from rovslam.config import ProcessingConfig, RunConfig  # noqa: E402
from rovslam.io.sequence import open_sequence  # noqa: E402
from rovslam.pipeline import SlamPipeline  # noqa: E402
from rovslam.sim import simulate  # noqa: E402


def _median_s_per_frame(seq_dir: Path, frames: list, config: RunConfig, repeats: int) -> tuple[float, float, str]:
    """(CPU s per frame, wall s per frame, processed size): medians over ``repeats`` runs."""
    info = open_sequence(seq_dir).info
    cpu, wall = [], []
    shape = ""
    for _ in range(repeats):
        pipe = SlamPipeline(info, config)
        shape = f"{pipe.camera.width_px}x{pipe.camera.height_px}"
        c0, t0 = time.process_time(), time.perf_counter()
        for f in frames:
            pipe.process(f)
        cpu.append((time.process_time() - c0) / len(frames))
        wall.append((time.perf_counter() - t0) / len(frames))
    return statistics.median(cpu), statistics.median(wall), shape


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for name, scenario, config in [
            ("360x272 (paper)", "portofino", RunConfig()),
            ("1920x1080 scale 1", "hd-survey", RunConfig(processing=ProcessingConfig(scale=1.0))),
            ("1920x1080 auto", "hd-survey", RunConfig()),
        ]:
            seq = Path(tmp) / scenario
            if not seq.exists():
                simulate(scenario, seq, frames=args.frames, seed=0)
            frames = list(open_sequence(seq).frames())
            cpu, wall, shape = _median_s_per_frame(seq, frames, config, args.repeats)
            rows.append((name, shape, cpu, wall))
    print(f"{args.frames} frames from memory, one thread, median of {args.repeats} runs")
    print(f"{'camera / processing':<22}{'processed':>11}{'CPU ms':>9}{'CPU fps':>9}{'wall ms':>9}{'wall fps':>9}")
    for name, shape, cpu, wall in rows:
        print(f"{name:<22}{shape:>11}{1000 * cpu:>9.2f}{1 / cpu:>9.1f}{1000 * wall:>9.2f}{1 / wall:>9.1f}")
    paper, full, auto = (r[2] for r in rows)
    print(
        f"CPU time: HD auto is {full / auto:.1f}x faster than HD at full resolution and takes "
        f"{auto / paper:.2f}x the paper camera's time per frame"
    )


if __name__ == "__main__":
    main()
