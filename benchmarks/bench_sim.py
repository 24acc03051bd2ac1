"""Benchmark of the seabed simulator: per-frame rendering of every preset, and writing whole dives.

Run: ``python benchmarks/bench_sim.py`` (a few minutes; ``--frames 100`` for a quick run,
``--presets portofino swell`` for some, ``--full`` to also write the complete 13,275-frame
``portofino`` trial and time it). Prints, per frame, medians over ``--repeats`` runs of the
wall time and of the CPU time of the process (all its threads: what a frame costs a
shared machine, and steadier than the wall time when other work runs beside it):

* ``render``: :meth:`FrameRenderer.render` alone (seabed and relief windows already
  built), for each preset, over its first ``--frames`` frames (a fifth of them for the
  1920x1080 ``hd-survey``), with the ratio to ``render portofino`` (the baseline, measured
  in the same run, as every ratio here);
* ``write const``: the sequence writer storing a constant image (the I/O floor of the format);
* ``simulate``: :func:`rovslam.sim.simulate` end to end (trajectory, seabed and relief
  generation, rendering, H.264 where the preset has it, encoding, CSVs) over the same
  frames, and that CPU rate extrapolated to the preset's whole dive (``dive s``): an upper
  bound, since a longer dive spreads the seabed generation over more frames.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rovslam.core import SequenceInfo
from rovslam.io.sequence import SequenceWriter
from rovslam.sim import SCENARIOS, frame_pose, frame_rng, renderer_for, simulate, simulate_trajectory
from rovslam.sim.scenarios import build_world, survey_area_m

TRIAL_FRAMES = SCENARIOS["portofino"].n_frames
DEFAULT_PRESETS = (
    "portofino",
    "rough-turns",
    "portofino-relief",
    "photo-survey",
    "photo-turns",
    "hd-survey",
    "still-camera",
    "turbid-relief",
    "coral-repetitive",
    "swell",
)


def _parse() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=300, help="frames per timed run (hd-survey: a fifth)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per row (median reported)")
    ap.add_argument("--presets", nargs="*", default=list(DEFAULT_PRESETS), help="presets to time")
    ap.add_argument("--full", action="store_true", help="also write the whole portofino trial once")
    return ap.parse_args()


def _frames_for(name: str, n: int) -> int:
    return max(5, n // 5) if SCENARIOS[name].camera.width_px > 1200 else n


class _Clock:
    """Wall and CPU seconds elapsed since construction."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), time.process_time()

    def per(self, n: int) -> tuple[float, float]:
        return (time.perf_counter() - self.wall) / n, (time.process_time() - self.cpu) / n


def _median(runs: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def bench_render(name: str, n: int) -> tuple[float, float]:
    """(wall, CPU) seconds per frame of rendering alone over the first n frames of a preset."""
    sc = SCENARIOS[name]
    traj = simulate_trajectory(sc.vehicle, sc.grid, n, sc.frame_rate_hz, seed=0)
    world, _ = build_world(sc, 0, grow_m=float(np.max(np.hypot(traj.x_m, traj.y_m))) + 0.05)
    world.area_m = survey_area_m(sc, traj)  # as simulate does
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots, sc.lighting)

    def frame(k: int) -> np.ndarray:
        return renderer.render(
            world,
            frame_pose(traj, k),
            sc.lasers,
            frame_rng(0, k),
            velocity_mps=(traj.surge_mps[k], traj.sway_mps[k]),
            t_s=traj.t_s[k],
        )

    for k in range(0, n, max(1, n // 10)):  # build the windows the run will use
        frame(k)
    clock = _Clock()
    for k in range(n):
        frame(k)
    return clock.per(n)


def bench_write(image: np.ndarray, n: int, root: Path) -> tuple[float, float]:
    """(wall, CPU) seconds per frame for the sequence writer storing ``image`` n times."""
    sc = SCENARIOS["portofino"]
    out = root / "write"
    shutil.rmtree(out, ignore_errors=True)
    info = SequenceInfo(name="bench", camera=sc.camera, lasers=sc.lasers)
    clock = _Clock()
    with SequenceWriter(out, info) as w:
        for k in range(n):
            w.write_frame(0.2 * k, image, 0.0, 1.31, truth=(0.0, 0.0, 1.31, 0.0))
    return clock.per(n)


def bench_simulate(name: str, n: int, root: Path) -> tuple[float, float]:
    out = root / "sim"
    shutil.rmtree(out, ignore_errors=True)
    clock = _Clock()
    simulate(name, out, frames=n, seed=0)
    return clock.per(n)


def main() -> None:
    args = _parse()
    root = Path(tempfile.mkdtemp(prefix="rovslam-bench-sim-"))
    try:
        rows: list[tuple[str, int, tuple[float, float], float | None]] = []  # label, frames, s/frame, dive s
        names = ["portofino"] + [p for p in args.presets if p != "portofino"]
        for name in names:
            n = _frames_for(name, args.frames)
            rows.append((f"render {name}", n, _median([bench_render(name, n) for _ in range(args.repeats)]), None))
        sc = SCENARIOS["portofino"]
        const = np.full((sc.camera.height_px, sc.camera.width_px, 3), 100, np.uint8)
        rows.append(
            (
                "write const",
                args.frames,
                _median([bench_write(const, args.frames, root) for _ in range(args.repeats)]),
                None,
            )
        )
        for name in names:
            n = _frames_for(name, args.frames)
            sec = _median([bench_simulate(name, n, root) for _ in range(args.repeats)])
            rows.append((f"simulate {name}", n, sec, sec[1] * SCENARIOS[name].n_frames))
        base = rows[0][2]
        print(f"median of {args.repeats} runs; ratios to 'render portofino'; dive s: CPU for the whole preset")
        print(f"{'':28s} {'frames':>6s} {'wall ms':>8s} {'x base':>7s} {'CPU ms':>8s} {'x base':>7s} {'dive s':>7s}")
        for label, n, (wall, cpu), dive in rows:
            print(
                f"{label:28s} {n:6d} {wall * 1e3:8.2f} {wall / base[0]:7.2f} {cpu * 1e3:8.2f} {cpu / base[1]:7.2f} "
                f"{'' if dive is None else f'{dive:7.0f}'}"
            )
        if args.full:
            out = root / "full"
            t0 = time.perf_counter()
            summary = simulate("portofino", out, seed=0)
            wall = time.perf_counter() - t0
            size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
            print(
                f"portofino trial written: {summary.frames} frames in {wall:.1f} s "
                f"({wall / summary.frames * 1e3:.2f} ms/frame, {size_mb:.0f} MB)"
            )
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
