"""What seeing a run costs: the run with the viewer off and on, the report and the mosaic.

Run: ``python benchmarks/bench_viz.py [--frames 300] [--repeats 3]``. Simulates a portofino
sequence once (seeded), then times, over ``--repeats`` runs (medians):

* ``results only`` (the baseline, measured in the same run): the per-frame loop writing the
  result files of ``rovslam run`` without the gallery's ``tokens.csv`` and revisit crops;
* ``run, viewer off``: ``run_sequence`` as ``rovslam run`` calls it (gallery files written,
  no viewer): the issue's limit is 1.2x the baseline;
* ``run, --save-rrd``: the same with the rerun viewer logging to an ``.rrd`` file;
* ``mosaic``: ``rovslam mosaic`` of the run (every frame, native scale);
* ``report``: ``rovslam report`` with the truth (figures, gallery, two mosaics).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from rovslam.io.results import ResultWriter
from rovslam.io.sequence import open_sequence
from rovslam.pipeline import SlamPipeline
from rovslam.runner import run_sequence
from rovslam.sim import simulate


def results_only(seq: Path, out: Path) -> None:
    s = open_sequence(seq)
    pipe = SlamPipeline(s.info)
    writer = ResultWriter(out)
    for frame in s.frames():
        res = pipe.process(frame)
        writer.write_frame(res)
        if res.new_landmark_id is not None:
            writer.write_landmark_template(res.new_landmark_id, pipe.landmarks[res.new_landmark_id].patch)
    writer.write_landmarks(pipe.landmark_rows())
    writer.close()


def _time(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from rovslam.viz.mosaic import mosaic_of_run
    from rovslam.viz.report import write_report
    from rovslam.viz.viewer import RerunViewer

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        seq = root / "seq"
        simulate("portofino", seq, frames=args.frames, seed=0)
        t = {k: [] for k in ("results only", "run, viewer off", "run, --save-rrd", "mosaic", "report")}
        for r in range(args.repeats):
            t["results only"].append(_time(lambda r=r: results_only(seq, root / f"base{r}")))
            t["run, viewer off"].append(_time(lambda r=r: run_sequence(seq, root / f"off{r}")))

            def with_viewer(r=r):
                v = RerunViewer(save_path=root / f"on{r}.rrd")
                run_sequence(seq, root / f"on{r}", on_frame_image=v)
                v.close()

            t["run, --save-rrd"].append(_time(with_viewer))
            t["mosaic"].append(_time(lambda r=r: mosaic_of_run(root / f"off{r}")))
            t["report"].append(_time(lambda r=r: write_report(root / f"off{r}", seq / "groundtruth.csv")))
    med = {k: statistics.median(v) for k, v in t.items()}
    n = args.frames
    base = med["results only"]
    print(f"portofino, {n} frames, median of {args.repeats} runs")
    print(f"{'stage':<18}{'wall s':>9}{'ms/frame':>10}{'x baseline':>12}")
    for k, v in med.items():
        print(f"{k:<18}{v:>9.2f}{1000 * v / n:>10.2f}{v / base:>12.2f}")


if __name__ == "__main__":
    main()
