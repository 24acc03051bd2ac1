"""The paper's whole trial (13,275 frames, 44 min 15 s): about 2 minutes, so marked slow.

Run with ``make test-all`` or ``pytest -m slow``. The figures are the issue's aims for the
full `portofino` trial (ATE RMSE under 1 cm, dead reckoning at least 10 times worse, the
truth inside the 2-sigma ellipse in at least 90 % of frames, landmark 0 seen on many passages),
bounded at the measured figures. Its fast version in the default suite is
``test_pipeline.py::test_portofino_short_meets_the_papers_accuracy``: the first 600 frames of the
same trial (``portofino-short`` is ``portofino`` cut at 2 minutes; the same seed), with its own
measured bounds.
"""

import pytest

from rovslam.eval import evaluate
from rovslam.io.run_results import read_results
from rovslam.io.sequence import read_groundtruth
from rovslam.runner import run_sequence
from rovslam.sim import simulate


@pytest.mark.slow
def test_full_portofino_trial(tmp_path):
    simulate("portofino", tmp_path / "seq", seed=0)
    summary = run_sequence(tmp_path / "seq", tmp_path / "out")
    assert summary.frames == 13275 and not summary.skipped
    f = evaluate(read_results(tmp_path / "out"), read_groundtruth(tmp_path / "seq" / "groundtruth.csv"))
    # Measured (README's worked example: `rovslam simulate --scenario portofino` seed 0, `rovslam run`,
    # `rovslam eval`, at 33f487a, whose src differs from this test's build in viz/mosaic.py alone):
    # ATE RMSE 0.072 cm, dead reckoning 3.591 cm (50 times), 100 % inside 2-sigma, landmark 0 on 74
    # passages. The ATE is bounded at 2.5 times its figure and above a third of it (about 0 would mean
    # the evaluation compared the estimate with itself); the passages at 74 / 2.5.
    assert 0.00024 < f.slam.ate_rmse_m < 0.0018
    assert f.dead_reckoning.ate_rmse_m >= 10.0 * f.slam.ate_rmse_m
    assert f.consistency.coverage_2sigma >= 0.90
    assert len(f.table1_landmark0) >= 30
