"""Evaluation maths on hand-made trajectories with known answers."""

import numpy as np
import pytest

from rovslam.errors import SequenceFormatError
from rovslam.eval.metrics import align_by_time, consistency, nees, trajectory_errors


def test_ate_of_a_constant_offset():
    gt = np.column_stack([np.linspace(0, 3, 301), np.zeros(301)])
    est = gt + np.array([0.03, -0.04])  # 5 cm everywhere
    e = trajectory_errors(est, gt, segment_m=1.0)
    assert e.ate_rmse_m == pytest.approx(0.05)
    assert e.ate_max_m == pytest.approx(0.05)
    assert e.final_error_m == pytest.approx(0.05)
    assert e.distance_m == pytest.approx(3.0)
    assert e.relative_error_m_per_m == pytest.approx(0.0, abs=1e-12)  # no drift, only an offset


def test_relative_error_of_a_scale_error():
    gt = np.column_stack([np.linspace(0, 3, 301), np.zeros(301)])
    est = gt * 1.02  # 2 % scale error: 2 cm per metre
    e = trajectory_errors(est, gt, segment_m=1.0)
    assert e.relative_error_m_per_m == pytest.approx(0.02, rel=1e-6)
    assert e.relative_error_pct == pytest.approx(2.0, rel=1e-6)
    assert e.final_error_pct == pytest.approx(2.0, rel=1e-6)


def test_consistency_of_a_matched_gaussian():
    rng = np.random.default_rng(7)
    cov = np.array([[4e-4, 1e-4], [1e-4, 1e-4]])
    err = rng.multivariate_normal([0, 0], cov, size=20000)
    c = consistency(err, np.broadcast_to(cov, (20000, 2, 2)))
    assert c.nees_mean == pytest.approx(2.0, rel=0.05)
    assert c.coverage_2sigma == pytest.approx(1 - np.exp(-2.0), abs=0.01)  # 86.5 % in 2-D
    assert c.nees_in_95_interval == pytest.approx(0.95, abs=0.01)


def test_nees_of_an_overconfident_filter_is_large():
    err = np.full((10, 2), 0.01)
    assert np.all(nees(err, np.broadcast_to(np.eye(2) * 1e-6, (10, 2, 2))) > 100)


def test_align_by_time_rejects_foreign_ground_truth():
    t = np.arange(10) * 0.2
    np.testing.assert_array_equal(align_by_time(t[2:5], t), [2, 3, 4])
    with pytest.raises(SequenceFormatError, match="no row at t_s"):
        align_by_time(np.array([0.1]), t)
