"""The figures of closed-loop navigation to points of interest, slam against dead reckoning.

For each preset, seed and estimator: a survey of ``--survey-s`` seconds, then ``--points``
points spread over a ``--span-m`` square centred on the start (a seeded, shuffled grid of
positions), each held ``--hold-s`` seconds; ``rovslam.navigate.navigate`` writes each run to
``OUT/<preset>-s<seed>-<estimator>/``. Prints the table (mean and worst true arrival error,
mean hold RMS, points reached) and writes it to ``OUT/table.md``; every finished run is also
appended to ``OUT/runs.jsonl`` (a second call skips the runs already there).

    python scripts/nav_closing_note.py --out nav-note                      # the closing note (long)
    python scripts/nav_closing_note.py --out nav-quick --survey-s 120 --seeds 1 --presets portofino-relief
    python scripts/nav_closing_note.py --out nav-note --table-only            # the table of the runs done so far
"""

from __future__ import annotations

import argparse
import json
import math
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np


def points(n: int, span_m: float, seed: int) -> list[tuple[str, float, float]]:
    """``n`` points over a ``span_m`` square: a jittered grid, shuffled by the seed."""
    rng = np.random.default_rng([seed, 16])
    side = math.ceil(math.sqrt(n))
    cells = [(i, j) for i in range(side) for j in range(side)]
    rng.shuffle(cells)
    half = span_m / 2.0
    step = span_m / side
    out = []
    for k, (i, j) in enumerate(cells[:n]):
        x = -half + (i + 0.5) * step + rng.uniform(-0.25, 0.25) * step
        y = -half + (j + 0.5) * step + rng.uniform(-0.25, 0.25) * step
        out.append((f"p{k}", float(np.clip(x, -half, half)), float(np.clip(y, -half, half))))
    return out


def one_run(args: tuple) -> dict:
    preset, seed, estimator, survey_s, hold_s, n_points, span_m, out = args
    from rovslam.core import Goal
    from rovslam.navigate import navigate

    pois = [Goal(name, np.array([x, y])) for name, x, y in points(n_points, span_m, seed)]
    folder = Path(out) / f"{preset}-s{seed}-{estimator}"
    s = navigate(preset, pois, folder, estimator, survey_s, hold_s, seed, overwrite=True, plot=True)
    rows = s.arrivals
    reached = [r for r in rows if r["reached"]]
    return {
        "preset": preset,
        "seed": seed,
        "estimator": estimator,
        "survey_s": survey_s,
        "frames": s.frames,
        "landmarks": s.landmarks,
        "wall_s": s.wall_s,
        "points": len(pois),
        "reached": len(reached),
        "true_err_m": [r["true_err_m"] for r in reached],
        "est_err_m": [r["est_err_m"] for r in reached],
        "hold_rms_true_m": [r["hold_rms_true_m"] for r in reached],
        "status": s.status,
    }


def table(runs: list[dict]) -> str:
    lines = [
        "| preset | estimator | seeds | points reached | mean true arrival error | worst | mean hold RMS (true) | "
        "mean / slam's |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    slam_mean = {
        p: np.mean([e for r in runs if r["preset"] == p and r["estimator"] == "slam" for e in r["true_err_m"]])
        for p in {r["preset"] for r in runs if r["estimator"] == "slam" and r["true_err_m"]}
    }
    keys = sorted({(r["preset"], r["estimator"]) for r in runs}, key=lambda k: (k[0], k[1] != "slam"))
    for preset, est in keys:
        rs = [r for r in runs if r["preset"] == preset and r["estimator"] == est]
        errs = [e for r in rs for e in r["true_err_m"]]
        holds = [h for r in rs for h in r["hold_rms_true_m"] if h == h]
        seeds = ",".join(str(r["seed"]) for r in sorted(rs, key=lambda r: r["seed"]))
        ratio = f"{np.mean(errs) / slam_mean[preset]:.1f}" if preset in slam_mean and errs else ""
        lines.append(
            f"| {preset} | {est} | {seeds} | {sum(r['reached'] for r in rs)}/{sum(r['points'] for r in rs)} | "
            f"{1e3 * np.mean(errs):.1f} mm | {1e3 * np.max(errs):.1f} mm | {1e3 * np.mean(holds):.1f} mm | "
            f"{ratio} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--presets", nargs="+", default=["portofino-relief", "photo-survey"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--estimators", nargs="+", default=["slam", "dead-reckoning"])
    ap.add_argument("--survey-s", type=float, default=1200.0)
    ap.add_argument("--hold-s", type=float, default=10.0)
    ap.add_argument("--points", type=int, default=10)
    ap.add_argument("--span-m", type=float, default=2.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--table-only", action="store_true", help="only tabulate the runs already in OUT/runs.jsonl")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    log = a.out / "runs.jsonl"
    done = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    have = {(r["preset"], r["seed"], r["estimator"], r["survey_s"]) for r in done}
    todo = [
        (p, s, e, a.survey_s, a.hold_s, a.points, a.span_m, str(a.out))
        for s in a.seeds
        for p in a.presets
        for e in a.estimators
        if (p, s, e, a.survey_s) not in have and not a.table_only
    ]
    with ProcessPoolExecutor(max_workers=a.workers) as pool:
        for res in pool.map(one_run, todo):
            done.append(res)
            with log.open("a") as fh:
                fh.write(json.dumps(res) + "\n")
            print(
                res["preset"],
                res["seed"],
                res["estimator"],
                f"{res['reached']}/{res['points']}",
                f"mean {1e3 * np.mean(res['true_err_m']):.1f} mm" if res["true_err_m"] else "",
                flush=True,
            )
    text = table([r for r in done if r["survey_s"] == a.survey_s])
    (a.out / "table.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
