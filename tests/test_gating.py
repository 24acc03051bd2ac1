"""Visibility gate (5) and new-landmark test (6): footprint matrix D, spacing matrix L, vectorisation."""

import numpy as np
import pytest

from rovslam.config import SlamConfig
from rovslam.slam import EkfSlam, MotionInput
from rovslam.slam.gating import (
    footprint_matrix_m2,
    mahalanobis_sq_2d,
    new_landmark_statistics,
    new_landmark_test,
    offset_covariances_m2,
    spacing_matrix_m2,
    visibility_gate,
    visibility_statistics,
)

Z, F, W, H = 1.31, 1075.0, 360, 272
HALF_H_M = Z / F * H / 2  # 0.16573 m: half the along-track footprint
HALF_W_M = Z / F * W / 2  # 0.21935 m: half the across-track footprint
TINY = np.eye(2) * 1e-10


def test_footprint_matrix_numbers():
    d0 = footprint_matrix_m2(0.0, Z, F, W, H)
    np.testing.assert_allclose(d0, np.diag([HALF_H_M**2, HALF_W_M**2]), rtol=1e-12)
    assert HALF_H_M == pytest.approx(0.165730, abs=1e-6) and HALF_W_M == pytest.approx(0.219349, abs=1e-6)
    # Heading east (90 deg): the along-track axis is world y.
    d90 = footprint_matrix_m2(np.pi / 2, Z, F, W, H)
    np.testing.assert_allclose(d90, np.diag([HALF_W_M**2, HALF_H_M**2]), atol=1e-15)
    # Symmetric and positive definite at any heading.
    d = footprint_matrix_m2(0.7, Z, F, W, H)
    np.testing.assert_allclose(d, d.T)
    assert np.all(np.linalg.eigvalsh(d) > 0)
    np.testing.assert_allclose(spacing_matrix_m2(0.1), np.eye(2) * 0.01)
    np.testing.assert_allclose(spacing_matrix_m2(0.1, 4.0), np.eye(2) * 0.0025)


def test_mahalanobis_matches_a_solve_loop():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 2))
    a = rng.normal(size=(50, 2, 2))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(2)
    ref = np.array([di @ np.linalg.solve(ci, di) for di, ci in zip(d, cov)])
    np.testing.assert_allclose(mahalanobis_sq_2d(d, cov), ref, rtol=1e-10)
    # One shared covariance broadcasts; a singular covariance gives inf (or 0 at zero offset).
    np.testing.assert_allclose(mahalanobis_sq_2d(d[:3], np.eye(2) * 4.0), np.sum(d[:3] ** 2, 1) / 4.0)
    q = mahalanobis_sq_2d(np.array([[1.0, 0.0], [0.0, 0.0]]), np.zeros((2, 2, 2)))
    assert q[0] == np.inf and q[1] == 0.0


@pytest.mark.parametrize("heading", [0.0, 0.5, np.pi / 2, -2.0])
def test_gate_keeps_just_inside_and_drops_well_outside(heading):
    r = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]])
    vehicle = np.array([3.0, -1.0])
    # Body-frame offsets: just inside the image edge forward, starboard and in a corner;
    # and well outside (5 half-footprints ahead, 4 to port).
    body = np.array(
        [
            [0.95 * HALF_H_M, 0.0],
            [0.0, -0.95 * HALF_W_M],
            [0.6 * HALF_H_M, 0.6 * HALF_W_M],
            [5.0 * HALF_H_M, 0.0],
            [0.0, -4.0 * HALF_W_M],
        ]
    )
    xy = vehicle + body @ r.T
    cov = np.broadcast_to(TINY, (5, 2, 2))
    fp = footprint_matrix_m2(heading, Z, F, W, H)
    stats = visibility_statistics(xy, cov, vehicle, TINY, fp)
    np.testing.assert_allclose(stats, [0.9025, 0.9025, 0.72, 25.0, 16.0], rtol=1e-6)
    keep = visibility_gate(xy, cov, vehicle, TINY, fp, SlamConfig().visibility_lambda)
    np.testing.assert_array_equal(keep, [True, True, True, False, False])


def test_gate_widens_with_uncertainty():
    vehicle = np.zeros(2)
    xy = np.array([[5.0 * HALF_H_M, 0.0]])
    fp = footprint_matrix_m2(0.0, Z, F, W, H)
    lam = SlamConfig().visibility_lambda
    assert not visibility_gate(xy, TINY[None], vehicle, TINY, fp, lam)[0]
    # A vehicle uncertain by 30 cm may well be over it.
    assert visibility_gate(xy, TINY[None], vehicle, np.eye(2) * 0.3**2, fp, lam)[0]


def test_new_landmark_test_refuses_within_the_spacing():
    cfg = SlamConfig()
    mu = cfg.new_landmark_mu
    spacing = spacing_matrix_m2(cfg.new_landmark_spacing_m, mu)  # 15 cm
    vehicle = np.array([1.0, 1.0])
    near = vehicle + np.array([[0.06, 0.06]])  # 8.5 cm away: within the 15 cm spacing
    far = vehicle + np.array([[0.8, -0.3]])
    cov = TINY[None]
    # d^T L^-1 d = 0.0072 / (0.0225 / 13.82)
    assert new_landmark_statistics(near, cov, vehicle, TINY, spacing)[0] == pytest.approx(
        0.0072 / 0.0225 * mu, rel=1e-6
    )
    assert not new_landmark_test(near, cov, vehicle, TINY, spacing, mu)
    assert new_landmark_test(far, cov, vehicle, TINY, spacing, mu)
    # One near landmark among many far ones is enough to refuse.
    both = np.vstack([far, near])
    assert not new_landmark_test(both, np.repeat(cov, 2, 0), vehicle, TINY, spacing, mu)
    assert new_landmark_test(np.zeros((0, 2)), np.zeros((0, 2, 2)), vehicle, TINY, spacing, mu)
    # With a certain filter the minimum spacing is exactly new_landmark_spacing_m.
    edge = cfg.new_landmark_spacing_m
    assert not new_landmark_test(vehicle + [[0.99 * edge, 0.0]], cov, vehicle, TINY, spacing, mu)
    assert new_landmark_test(vehicle + [[1.01 * edge, 0.0]], cov, vehicle, TINY, spacing, mu)


def test_relative_covariance_uses_the_cross_terms():
    # Vehicle and landmark both uncertain by 20 cm but 99 % correlated: their offset is known to ~3 cm.
    p = np.eye(2) * 0.04
    c = 0.99 * p
    rel = offset_covariances_m2(p[None], p, c[None])[0]
    np.testing.assert_allclose(rel, np.eye(2) * 0.04 * 0.02)
    paper = offset_covariances_m2(p[None], p)[0]
    np.testing.assert_allclose(paper, np.eye(2) * 0.08)
    xy = np.array([[0.3, 0.0]])
    spacing = spacing_matrix_m2(0.1)
    s_rel = new_landmark_statistics(xy, p[None], np.zeros(2), p, spacing, c[None])[0]
    s_paper = new_landmark_statistics(xy, p[None], np.zeros(2), p, spacing)[0]
    assert s_rel == pytest.approx(0.09 / 0.0108, rel=1e-9)  # 8.33
    assert s_paper == pytest.approx(0.09 / 0.09, rel=1e-9)  # 1.0: the paper's form stalls the map


def test_ekf_gate_and_new_landmark_test():
    ekf = EkfSlam(
        SlamConfig(
            pixel_sigma_px=0.5,
            new_landmark_spacing_m=0.372,
            landmark_height_sigma_m=0.0,
            altitude_bias_sigma_m=0.0,
            speed_bias_sigma_mps=0.0,
        )
    )
    assert ekf.may_add_landmark()  # no landmarks yet
    assert ekf.visible_landmarks(0.0, Z, F, W, H).size == 0
    # Landmark 0 just inside the image edge ahead (m = 0.95 * H/2), landmark 1 far ahead.
    ekf.augment([0.95 * H / 2, 0.0], 0.0, Z, F)
    assert not ekf.may_add_landmark()  # 0.157 m away < 0.372 m
    ekf.augment([6.0 * H / 2, 0.0], 0.0, Z, F)
    np.testing.assert_array_equal(ekf.visible_landmarks(0.0, Z, F, W, H), [0])
    stats = ekf.visibility_statistics(0.0, Z, F, W, H)
    assert stats[0] == pytest.approx(0.9025, rel=1e-3) and stats[1] == pytest.approx(36.0, rel=1e-3)
    # Fly 0.7 m forward (negligible speed noise): landmark 1 (0.994 m ahead of the start) is now
    # 0.294 m ahead, inside the gate; landmark 0 is 0.543 m = 3.27 half-footprints behind,
    # beyond sqrt(lambda) = 3.03: outside.
    ekf.predict(MotionInput(0.1, 0.0, np.eye(2) * 1e-12, 0.0, 7.0))
    np.testing.assert_array_equal(ekf.visible_landmarks(0.0, Z, F, W, H), [1])
    assert not ekf.may_add_landmark()  # landmark 1 is within 0.372 m
    ekf.predict(MotionInput(0.0, 0.1, np.eye(2) * 1e-12, 0.0, 5.0))  # 0.5 m to starboard: far from both
    assert ekf.may_add_landmark()


def test_gate_is_vectorised_over_thousands_of_landmarks():
    rng = np.random.default_rng(1)
    n = 5000
    xy = rng.uniform(-5, 5, (n, 2))
    a = rng.normal(size=(n, 2, 2)) * 0.01
    cov = a @ np.swapaxes(a, 1, 2)
    fp = footprint_matrix_m2(0.3, Z, F, W, H)
    stats = visibility_statistics(xy, cov, np.zeros(2), TINY, fp)
    ref = np.array([x @ np.linalg.solve(c + TINY + fp, x) for x, c in zip(xy[:100], cov[:100])])
    np.testing.assert_allclose(stats[:100], ref, rtol=1e-9)
    assert stats.shape == (n,)
