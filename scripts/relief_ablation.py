"""What holds rovslam's accuracy over a relief: one dive, its inputs made exact one at a time.

One dive (``--scenario``, ``--seed``, ``--frames``) is simulated three times: as the preset makes
it, without its lamps (the lamp cone fixed to the image: no cast shadows) and over a flat seabed
(the same texture, trajectory and sensors). Each is run by ``rovslam run``'s own
:func:`rovslam.runner.run_sequence`, as it is and with its odometry made exact:

* ``true speed``: every step's surge and sway replaced by the true body speed over the step
  (:func:`rovslam.eval.true_body_speed_mps`), inside the loop, where the tokens' speed enters the
  filter; the Q, the turn and the inliers the tokens reported are kept;
* ``true heading``: the compass column of ``frames.csv`` replaced by the true heading, the run
  told it is exact (0.001 degree of noise, no deviation, no drift, no drift state);
* ``both``: dead reckoning exact.

Prints the table (SLAM ATE, truth inside the 2-sigma ellipse, the frame-to-frame phase
correlation's ATE on the runs as simulated) and writes ``OUT/table.md`` and ``OUT/rows.json``;
each run's folder stays in ``OUT/`` for ``rovslam eval`` and ``rovslam report``.

    python scripts/relief_ablation.py --out relief-ablation       # portofino-relief, seed 4, 1000 frames (about 5 CPU minutes)
    python scripts/relief_ablation.py --out quick --frames 300 --seed 1 --only as-simulated flat
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

DIVES = {  # the dive's variant: the preset's fields replaced (none: as the preset makes it)
    "as-simulated": {},
    "no-lamps": {"lighting": None},
    "flat": {"relief": None},
}
ODOMETRY = ("as is", "true speed", "true heading", "both")
RUNS = [  # (dive, odometry) in the table's order
    ("as-simulated", "as is"),
    ("as-simulated", "true speed"),
    ("as-simulated", "true heading"),
    ("as-simulated", "both"),
    ("no-lamps", "as is"),
    ("no-lamps", "both"),
    ("flat", "as is"),
    ("flat", "both"),
]


def simulate_dive(out: Path, scenario: str, seed: int, frames: int, dive: str) -> Path:
    """The dive's sequence folder (simulated once; a second call reuses it)."""
    from rovslam.sim import SCENARIOS, simulate

    seq = out / f"seq-{dive}"
    if (seq / "groundtruth.csv").is_file() and (seq / ".complete").is_file():
        return seq
    name = scenario if not DIVES[dive] else f"{scenario}-{dive}"
    if DIVES[dive]:
        SCENARIOS[name] = dataclasses.replace(SCENARIOS[scenario], name=name, **DIVES[dive])
    try:
        simulate(name, seq, frames=frames, seed=seed)
    finally:
        if DIVES[dive]:
            del SCENARIOS[name]
    (seq / ".complete").write_text("ok\n")
    return seq


def with_true_heading(seq: Path, out: Path) -> Path:
    """A copy of ``seq`` (its images hard-linked) whose compass reads the true heading."""
    dest = out / f"{seq.name}-true-heading"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "sequence.toml").write_text((seq / "sequence.toml").read_text())
    (dest / "groundtruth.csv").write_text((seq / "groundtruth.csv").read_text())
    (dest / "images").mkdir(exist_ok=True)
    for image in (seq / "images").iterdir():  # hard links: a sequence keeps its files inside its folder
        if not (dest / "images" / image.name).exists():
            try:
                os.link(image, dest / "images" / image.name)
            except OSError:  # another file system
                shutil.copy2(image, dest / "images" / image.name)
    with open(seq / "groundtruth.csv", newline="") as fh:
        truth = [row["heading_rad"] for row in csv.DictReader(fh)]
    with open(seq / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if len(rows) != len(truth):
        raise SystemExit(f"{seq}: frames.csv has {len(rows)} rows, groundtruth.csv {len(truth)}")
    with open(dest / "frames.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows({**row, "heading_rad": heading} for row, heading in zip(rows, truth))
    return dest


def exact_heading_config():
    """The run told its compass is exact: 0.001 degree of white noise, no deviation, no drift, no drift state."""
    from rovslam.config import RunConfig

    cfg = RunConfig()
    odometry = dataclasses.replace(
        cfg.odometry,
        compass_sigma_rad=math.radians(0.001),
        compass_sigma_learned=False,
        compass_offset_sigma_rad=0.0,
        compass_drift_sigma_rad=0.0,
    )
    return dataclasses.replace(cfg, odometry=odometry, slam=dataclasses.replace(cfg.slam, heading_bias_sigma_rad=0.0))


@contextmanager
def true_speed(groundtruth: Path) -> Iterator[None]:
    """Inside this block, the speed the odometry hands the filter is the true body speed of each step.

    :class:`rovslam.sensor.odometry.SpeedEstimator` measures step k (frame k-1 to frame k) while
    :meth:`rovslam.pipeline.SlamPipeline.process` runs frame k; every speed it hands on passes
    through :meth:`~rovslam.sensor.odometry.SpeedEstimator.accept` (the tokens', the feature
    motion's, or the held one), whose result keeps everything reported (Q, turn, inliers, ok) but
    the surge and sway.
    """
    import rovslam.pipeline as pipeline
    import rovslam.sensor.odometry as odometry
    from rovslam.eval import true_body_speed_mps
    from rovslam.io.sequence import read_groundtruth

    gt = read_groundtruth(groundtruth)
    speed = true_body_speed_mps(gt.xy_m, gt.heading_rad, gt.t_s)
    process, accept = pipeline.SlamPipeline.process, odometry.SpeedEstimator.accept
    frame_index = [0]

    def process_frame(self, frame):
        frame_index[0] = frame.index
        return process(self, frame)

    def accept_true(self, *args, **kwargs):
        m = accept(self, *args, **kwargs)
        k = frame_index[0]
        if 1 <= k <= len(speed):
            m = dataclasses.replace(m, surge_mps=float(speed[k - 1, 0]), sway_mps=float(speed[k - 1, 1]))
        return m

    pipeline.SlamPipeline.process, odometry.SpeedEstimator.accept = process_frame, accept_true
    try:
        yield
    finally:
        pipeline.SlamPipeline.process, odometry.SpeedEstimator.accept = process, accept


def run_one(out: Path, seq: Path, dive: str, odometry: str) -> dict:
    from rovslam.config import RunConfig
    from rovslam.eval import evaluate_run
    from rovslam.runner import run_sequence

    name = f"run-{dive}-{odometry.replace(' ', '-')}"
    run_dir = out / name
    source, cfg = seq, RunConfig()
    if odometry in ("true heading", "both"):
        source, cfg = with_true_heading(seq, out), exact_heading_config()
    if odometry in ("true speed", "both"):
        with true_speed(seq / "groundtruth.csv"):
            run_sequence(source, run_dir, cfg, overwrite=True)
    else:
        run_sequence(source, run_dir, cfg, overwrite=True)
    ev = evaluate_run(run_dir, seq / "groundtruth.csv", sequence_dir=seq if odometry == "as is" else None)
    if odometry == "both" and ev.dead_reckoning.final_error_m > 1e-3:
        raise SystemExit(
            f"{name}: dead reckoning with the true speed and heading ends "
            f"{100.0 * ev.dead_reckoning.final_error_m:.2f} cm off: the true speed did not reach the "
            "filter (has the speed's path through the loop changed? see true_speed())"
        )
    pc = ev.phase_correlation
    return {
        "dive": dive,
        "odometry": odometry,
        "run": name,
        "ate_cm": 100.0 * ev.slam.ate_rmse_m,
        "inside_2sigma_pct": 100.0 * ev.consistency.coverage_2sigma,
        "mean_nees": ev.consistency.nees_mean,
        "dead_reckoning_ate_cm": 100.0 * ev.dead_reckoning.ate_rmse_m,
        "final_dead_reckoning_error_cm": 100.0 * ev.dead_reckoning.final_error_m,
        "phase_correlation_ate_cm": None if pc is None else 100.0 * pc.ate_rmse_m,
    }


def table(rows: list[dict], title: str) -> str:
    lines = [
        title,
        "",
        "| dive | odometry | SLAM ATE [cm] | inside 2-sigma [%] | mean NEES | dead reckoning ATE [cm] | phase correlation ATE [cm] |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        pc = "" if r["phase_correlation_ate_cm"] is None else f"{r['phase_correlation_ate_cm']:.3f}"
        lines.append(
            f"| {r['dive']} | {r['odometry']} | {r['ate_cm']:.3f} | {r['inside_2sigma_pct']:.1f} | "
            f"{r['mean_nees']:.2f} | {r['dead_reckoning_ate_cm']:.3f} | {pc} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the dives, the runs and the table")
    ap.add_argument("--scenario", default="portofino-relief")
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--only", nargs="+", choices=sorted(DIVES), help="only these dives")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for dive, odometry in RUNS:
        if args.only and dive not in args.only:
            continue
        seq = simulate_dive(args.out, args.scenario, args.seed, args.frames, dive)
        rows.append(run_one(args.out, seq, dive, odometry))
        r = rows[-1]
        print(
            f"{dive:13s} {odometry:12s} ATE {r['ate_cm']:.3f} cm, {r['inside_2sigma_pct']:.1f} % inside 2-sigma",
            flush=True,
        )
    title = f"{args.scenario}, seed {args.seed}, {args.frames} frames"
    text = table(rows, title)
    (args.out / "table.md").write_text(text)
    (args.out / "rows.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n" + text)


if __name__ == "__main__":
    main()
