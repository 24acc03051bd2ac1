"""Benchmark of the seabed simulator: per-frame rendering, and writing the paper's whole trial.

Run: ``python benchmarks/bench_sim.py`` (about a minute; ``--frames 300`` for a quick run,
``--full`` to also write the complete 13,275-frame ``portofino`` trial and time it).
Prints, per frame, medians over ``--repeats`` runs:

* ``render``: :meth:`FrameRenderer.render` alone (canvas already built), for each preset;
* ``write const``: the baseline, measured in the same run: the sequence writer storing a
  constant image (the I/O floor of the format, no rendering);
* ``write rendered``: the writer storing an already rendered frame (PNG cost of real content);
* ``simulate``: :func:`rovslam.sim.simulate` end to end (trajectory, seabed generation,
  rendering, encoding, CSVs), and its extrapolation to the 13,275 frames of ``portofino``;

with the ratio to the constant-image baseline.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rovslam.io.sequence import SequenceInfo, SequenceWriter
from rovslam.sim import SCENARIOS, World, frame_pose, frame_rng, renderer_for, simulate, simulate_trajectory

TRIAL_FRAMES = SCENARIOS["portofino"].n_frames


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1000, help="frames per timed run")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per row (median reported)")
    ap.add_argument("--full", action="store_true", help="also write the whole portofino trial once")
    return ap.parse_args()


def bench_render(name: str, n: int) -> float:
    """Seconds per frame of rendering alone over the first n frames of a preset."""
    sc = SCENARIOS[name]
    traj = simulate_trajectory(sc.vehicle, sc.grid, n, sc.frame_rate_hz, seed=0)
    world = World.procedural(0, sc.texture, grow_m=float(np.max(np.hypot(traj.x_m, traj.y_m))) + 0.05)
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots)

    def frame(k: int) -> np.ndarray:
        return renderer.render(world, frame_pose(traj, k), sc.lasers, frame_rng(0, k),
                               velocity_mps=(traj.surge_mps[k], traj.sway_mps[k]), t_s=traj.t_s[k])

    frame(0)  # builds the canvas
    t0 = time.perf_counter()
    for k in range(n):
        frame(k)
    return (time.perf_counter() - t0) / n


def bench_write(image: np.ndarray, n: int, root: Path) -> float:
    """Seconds per frame for the sequence writer storing ``image`` n times."""
    sc = SCENARIOS["portofino"]
    out = root / "write"
    shutil.rmtree(out, ignore_errors=True)
    info = SequenceInfo(name="bench", camera=sc.camera, lasers=sc.lasers)
    t0 = time.perf_counter()
    with SequenceWriter(out, info) as w:
        for k in range(n):
            w.write_frame(0.2 * k, image, 0.0, 1.31, truth=(0.0, 0.0, 1.31, 0.0))
    return (time.perf_counter() - t0) / n


def bench_simulate(name: str, n: int, root: Path) -> float:
    out = root / "sim"
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    simulate(name, out, frames=n, seed=0)
    return (time.perf_counter() - t0) / n


def main() -> None:
    args = _parse()
    n = args.frames
    root = Path(tempfile.mkdtemp(prefix="rovslam-bench-sim-"))
    try:
        rows: list[tuple[str, float]] = []
        for name in ("portofino", "rough-turns"):
            rows.append((f"render {name}", statistics.median(bench_render(name, n) for _ in range(args.repeats))))
        sc = SCENARIOS["portofino"]
        const = np.full((sc.camera.height_px, sc.camera.width_px, 3), 100, np.uint8)
        base = statistics.median(bench_write(const, n, root) for _ in range(args.repeats))
        rows.append(("write const (baseline)", base))
        traj = simulate_trajectory(sc.vehicle, sc.grid, 1, 5.0, seed=0)
        rendered = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots).render(
            World.procedural(0, sc.texture), frame_pose(traj, 0), sc.lasers, frame_rng(0, 0))
        rows.append(("write rendered", statistics.median(bench_write(rendered, n, root) for _ in range(args.repeats))))
        for name in ("portofino", "rough-turns"):
            rows.append((f"simulate {name}", statistics.median(bench_simulate(name, n, root)
                                                             for _ in range(args.repeats))))
        print(f"{n} frames per run, median of {args.repeats} runs")
        print(f"{'':26s} {'ms/frame':>9s} {'frames/s':>9s} {'x baseline':>10s}")
        for label, sec in rows:
            print(f"{label:26s} {sec * 1e3:9.2f} {1.0 / sec:9.0f} {sec / base:10.2f}")
        sim = dict(rows)["simulate portofino"]
        print(f"portofino trial ({TRIAL_FRAMES} frames) extrapolated: {sim * TRIAL_FRAMES:.0f} s")
        if args.full:
            out = root / "full"
            t0 = time.perf_counter()
            summary = simulate("portofino", out, seed=0)
            wall = time.perf_counter() - t0
            size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
            print(f"portofino trial written: {summary.frames} frames in {wall:.1f} s "
                  f"({wall / summary.frames * 1e3:.2f} ms/frame, {size_mb:.0f} MB)")
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
