"""The apparent frame's errors: the AHRS tilt and the heading error the whole estimate shares."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rovslam.camera import rot2
from rovslam.config import OdometryConfig, RunConfig
from rovslam.slam.apparent import apparent_frame_cov_m2, apparent_sigmas, shared_heading_sigma_rad


def test_a_shared_heading_error_turns_the_estimate_about_the_start():
    rng = np.random.default_rng(3)
    xy = np.array([2.0, -1.0])
    sigma = 0.01
    cov = apparent_frame_cov_m2(xy, 1.31, 0.0, sigma)
    # Monte Carlo: the whole estimate turned about the origin by delta ~ N(0, sigma^2).
    deltas = rng.normal(0.0, sigma, 20000)
    moved = np.stack([rot2(d) @ xy - xy for d in deltas])
    np.testing.assert_allclose(cov, np.cov(moved.T), rtol=0.03, atol=1e-9)
    radial = xy / np.linalg.norm(xy)
    assert radial @ cov @ radial == pytest.approx(0.0, abs=1e-18)  # a turn moves nothing along the radius
    tangential = np.array([-radial[1], radial[0]])
    assert tangential @ cov @ tangential == pytest.approx((sigma * np.linalg.norm(xy)) ** 2)
    assert np.all(apparent_frame_cov_m2(np.zeros(2), 1.31, 0.0, sigma) == 0.0)  # the start itself is not moved


def test_a_shared_scale_error_scales_the_estimate_about_the_start():
    xy = np.array([1.5, 0.5])
    cov = apparent_frame_cov_m2(xy, 1.31, 0.0, 0.0, 0.01 / 1.31)
    np.testing.assert_allclose(cov, np.outer(xy, xy) * (0.01 / 1.31) ** 2, rtol=1e-12)
    radial = xy / np.linalg.norm(xy)
    tangential = np.array([-radial[1], radial[0]])
    assert tangential @ cov @ tangential == pytest.approx(0.0, abs=1e-18)  # a scale moves nothing across the radius
    both = apparent_frame_cov_m2(xy, 1.31, 0.0, 0.0087, 0.01 / 1.31)
    assert radial @ both @ radial == pytest.approx((0.01 / 1.31 * np.linalg.norm(xy)) ** 2)
    assert tangential @ both @ tangential == pytest.approx((0.0087 * np.linalg.norm(xy)) ** 2)


def test_the_tilt_offset_is_isotropic_and_scales_with_the_depth():
    cov = apparent_frame_cov_m2(np.array([5.0, 3.0]), 1.31, 0.0035, 0.0)
    np.testing.assert_allclose(cov, np.eye(2) * (1.31 * 0.0035) ** 2, rtol=1e-12)
    both = apparent_frame_cov_m2(np.array([5.0, 3.0]), 1.31, 0.0035, 0.0087)
    np.testing.assert_allclose(both, cov + apparent_frame_cov_m2(np.array([5.0, 3.0]), 1.31, 0.0, 0.0087), rtol=1e-12)


def test_many_positions_at_once_equal_one_at_a_time():
    rng = np.random.default_rng(7)
    xy = rng.normal(0.0, 3.0, (6, 2))
    depth = rng.uniform(1.0, 2.0, 6)
    tilt = np.array([0.0035, 0.0, 0.0035, 0.001, 0.0, 0.002])
    rot = np.array([0.0087, 0.0087, 0.0, 0.01, 0.02, 0.0])
    many = apparent_frame_cov_m2(xy, depth, tilt, rot)
    assert many.shape == (6, 2, 2)
    for k in range(6):
        np.testing.assert_allclose(many[k], apparent_frame_cov_m2(xy[k], depth[k], tilt[k], rot[k]), rtol=1e-12)
        assert np.all(np.linalg.eigvalsh(many[k]) >= -1e-18)


def test_the_drift_counts_only_when_the_back_end_does_not_estimate_it():
    odo = OdometryConfig(compass_offset_sigma_rad=0.0087, compass_drift_sigma_rad=0.0175)
    assert shared_heading_sigma_rad(odo, drift_estimated=True) == 0.0087
    assert shared_heading_sigma_rad(odo, drift_estimated=False) == pytest.approx(math.hypot(0.0087, 0.0175))
    paper = dataclasses.replace(odo, compass_sigma_rad=0.0)  # the compass as it is: no term
    assert shared_heading_sigma_rad(paper, drift_estimated=False) == 0.0


def test_each_back_end_adds_what_it_does_not_hold():
    cfg = RunConfig()
    # The EKF estimates the drift (eps) and holds the altimeter's lasting error (b): the offset alone.
    assert apparent_sigmas(cfg, graph=False) == (cfg.odometry.compass_offset_sigma_rad, 0.0, 0.0)
    # The graph estimates the drift too, but holds no altimeter error: that scales its whole dive.
    assert apparent_sigmas(cfg, graph=True) == (
        cfg.odometry.compass_offset_sigma_rad,
        cfg.slam.altitude_bias_sigma_m,
        cfg.slam.altitude_scale_sigma,
    )
    # no lasting altitude error configured (no b in the EKF): the graph adds no scale either, the rig's share included
    no_b = dataclasses.replace(cfg, slam=dataclasses.replace(cfg.slam, altitude_bias_sigma_m=0.0))
    assert apparent_sigmas(no_b, graph=True) == (cfg.odometry.compass_offset_sigma_rad, 0.0, 0.0)
    no_drift = dataclasses.replace(cfg, slam=dataclasses.replace(cfg.slam, heading_bias_sigma_rad=0.0))
    assert apparent_sigmas(no_drift, graph=False)[0] == pytest.approx(
        math.hypot(cfg.odometry.compass_offset_sigma_rad, cfg.odometry.compass_drift_sigma_rad)
    )
    assert apparent_sigmas(no_drift, graph=True)[0] == cfg.odometry.compass_offset_sigma_rad  # the graph's own model
