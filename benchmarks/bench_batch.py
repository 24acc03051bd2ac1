"""Cost of a robustness-matrix cell, and the projected wall time of a whole matrix on N cores.

Run: ``python benchmarks/bench_batch.py [--matrix matrices/default.toml] [--cores 2] [--frames 200]``.

For every scenario of the matrix, one cell is run in this process as a Dask worker runs it
(:func:`rovslam.batch.cell.run_cell`: simulate -> run -> eval with the phase-correlation
baseline, OpenCV on one thread) at ``--frames`` and at a quarter of that, ``--repeats`` times
each; the medians of their CPU times split each stage into a fixed part (seabed canvas) and a
part per frame. The baseline, measured in the same run: decoding the cell's images alone
(the I/O floor every stage pays).

Projection: a cell costs fixed + frames x per-frame CPU seconds; cells are placed longest
first on the least-loaded of ``--cores`` one-thread workers (as ``rovslam batch`` submits
them); the wall time is that of the busiest worker. CPU time, not wall time, is measured,
so a machine shared with other work still gives the figure of a quiet one.

Scenarios missing from the build measured are measured on a stand-in, and the table says which:
a 1920x1080, 25 frames/s variant of ``portofino`` for names with ``hd``, a 1.5 frames/s
variant for names with ``still``, otherwise ``portofino`` itself (360x272, 5 frames/s).
"""

from __future__ import annotations

import argparse
import heapq
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2

from rovslam.batch import load_matrix
from rovslam.batch.cell import run_cell
from rovslam.batch.matrix import CellSpec
from rovslam.camera import Camera
from rovslam.io.sequence import open_sequence
from rovslam.sim import SCENARIOS

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("simulate", "run", "eval")


def _stand_in(name: str):
    """The scenario to measure for ``name``: itself, or a stand-in when the build measured lacks it."""
    if name in SCENARIOS:
        return SCENARIOS[name], ""
    base = SCENARIOS["portofino"]
    if "hd" in name:
        s = 1920 / 360
        cam = Camera(1920, 1080, base.camera.fx_px * s, base.camera.fy_px * s, 959.5, 539.5)
        return replace(
            base, name="stand-in-hd", camera=cam, frame_rate_hz=25.0
        ), "stand-in: portofino at 1920x1080, 25 Hz"
    if "still" in name:
        return replace(base, name="stand-in-still", frame_rate_hz=1.5), "stand-in: portofino at 1.5 Hz"
    return base, "stand-in: portofino (360x272, 5 Hz)"


def _cell_cpu_s(scenario: str, frames: int, repeats: int, image_format: str) -> tuple[dict[str, float], float]:
    """Median CPU seconds per stage of a cell, and the median decode-only CPU seconds of its images."""
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:  # warm-up: imports and the renderer's tables, once per worker
        run_cell(CellSpec("w", "w", scenario=scenario, seed=99, frames=2, image_format=image_format), tmp)
    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    decode = []
    for r in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            spec = CellSpec("c", "c", scenario=scenario, seed=r, frames=frames, image_format=image_format)
            row = run_cell(spec, tmp, keep_sequence=True)
            if row["status"] != "ok":
                raise SystemExit(f"{scenario}: the cell failed: {row['error']}")
            for s in STAGES:
                per_stage[s].append(row[f"{s}_cpu_s"])
            c0 = time.process_time()
            for _ in open_sequence(Path(tmp) / "c" / "sequence").frames(prefetch=0):
                pass
            decode.append(time.process_time() - c0)
    return {s: statistics.median(v) for s, v in per_stage.items()}, statistics.median(decode)


def _project(costs_s: list[float], cores: int) -> float:
    """Wall time of cells of ``costs_s`` CPU seconds placed longest first on ``cores`` workers."""
    load = [0.0] * cores
    heapq.heapify(load)
    for c in sorted(costs_s, reverse=True):
        heapq.heappush(load, heapq.heappop(load) + c)
    return max(load)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--matrix", type=Path, default=ROOT / "matrices" / "default.toml")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--frames", type=int, default=200, help="frames of the longer timed cell")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    stand_ins = {}
    with open(args.matrix, "rb") as fh:
        import tomllib

        names = [e["name"] for e in tomllib.load(fh).get("scenario", [])]
    for name in names:
        sc, note = _stand_in(name)
        SCENARIOS.setdefault(sc.name, sc)  # this process only: lets the stand-ins be simulated by name
        stand_ins[name] = (sc, note)
    matrix = load_matrix(args.matrix, {n: sc for n, (sc, _) in stand_ins.items()} | dict(SCENARIOS))
    n_long, n_short = args.frames, max(2, args.frames // 4)
    measured: dict[str, tuple[float, float, dict, float]] = {}
    print(
        f"{matrix.name}: {len(matrix.cells)} cells; CPU seconds, medians of {args.repeats} cells of "
        f"{n_short} and {n_long} frames"
    )
    print(
        f"{'scenario':<18}{'frames':>7}{'fixed s':>9}{'sim ms/f':>10}{'run ms/f':>10}{'eval ms/f':>10}"
        f"{'decode ms/f':>12}{'cell s':>8}  measured on"
    )
    cell_costs = []
    for group in matrix.groups:
        cells = [c for c in matrix.cells if c.group == group]
        if cells[0].scenario is None:
            print(f"{group:<18} a recorded sequence: not estimated")
            continue
        sc, note = stand_ins[cells[0].scenario]
        key = (sc.name, cells[0].image_format)
        if key not in measured:
            short, _ = _cell_cpu_s(key[0], n_short, args.repeats, key[1])
            long, dec = _cell_cpu_s(key[0], n_long, args.repeats, key[1])
            per = {s: max(0.0, (long[s] - short[s]) / (n_long - n_short)) for s in STAGES}
            fixed = sum(long[s] - per[s] * n_long for s in STAGES)
            measured[key] = (fixed, sum(per.values()), per, dec / n_long)
        fixed, per_frame, per, dec = measured[key]
        frames = cells[0].frames or sc.n_frames
        cost = fixed + per_frame * frames
        cell_costs += [cost] * len(cells)
        print(
            f"{group:<18}{frames:>7}{fixed:>9.1f}{1e3 * per['simulate']:>10.1f}{1e3 * per['run']:>10.1f}"
            f"{1e3 * per['eval']:>10.1f}{1e3 * dec:>12.1f}{cost:>8.0f}  {note or 'itself'}, {cells[0].image_format}"
        )
    total = sum(cell_costs)
    wall = _project(cell_costs, args.cores)
    print(
        f"total {total / 3600:.2f} CPU hours; projected wall time on {args.cores} cores: {wall / 3600:.2f} h "
        f"({wall / 60:.0f} min), the busiest worker {100 * wall * args.cores / total:.0f} % of the mean"
    )


if __name__ == "__main__":
    main()
