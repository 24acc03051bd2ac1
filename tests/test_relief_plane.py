"""The seabed is not a plane: the laser spots' local plane, the relief off it, and what they feed.

* the plane fit of the spots recovers a known slope and measures the relief off the plane;
* the plane's depth at a pixel (``plane_depth_m``) over a synthetic slope;
* the relief off the plane averaged over frames (``PlaneAverage``);
* the relief as a consider parameter of a landmark observation (3): it widens the innovation.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from synth import paper_camera, paper_lasers

from rovslam.camera import pixels_to_ground
from rovslam.config import LaserConfig, RunConfig
from rovslam.pipeline.depth import PlaneAverage
from rovslam.pipeline.geometry import plane_depth_m
from rovslam.pipeline.update import landmark_depth
from rovslam.slam import EkfSlam
from rovslam.slam.observation import pixels_to_mn
from rovslam.vision.laser import AltitudeEstimate, fuse_altitude

CAM = paper_camera()
LASERS = paper_lasers()
F_PX = CAM.focal_px


def _plane_points(z0: float, tan_a: float, tan_b: float, heights_m=(0.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """The four paper spots' (4, 3) level-frame points on ``z = z0 + tan_a x + tan_b y`` plus a height each."""
    xy = np.array([las.origin_m[:2] for las in LASERS])
    z = z0 + tan_a * xy[:, 0] + tan_b * xy[:, 1] - np.asarray(heights_m)
    return np.column_stack([xy, z])


def test_the_spots_plane_recovers_a_known_slope_and_no_relief_on_a_plane():
    tan_a, tan_b = math.tan(math.radians(12.0)), math.tan(math.radians(-7.0))
    pts = _plane_points(1.31, tan_a, tan_b)
    est = fuse_altitude(pts[:, 2], np.full(4, 1e-4), None, 1.31, LaserConfig(), points_level_m=pts)
    assert est.altitude_m == pytest.approx(1.31, abs=1e-9)
    assert np.degrees(est.slope_rad) == pytest.approx([12.0, -7.0], abs=1e-6)
    assert est.relief_var_m2 == pytest.approx(0.0, abs=1e-12)


def test_the_relief_off_the_plane_is_measured():
    # One spot 1 cm above the plane the other three hold: with four spots the residuals are +-d/4 each,
    # their sum of squares d^2 / 4 over one degree of freedom.
    pts = _plane_points(1.31, 0.1, 0.0, heights_m=(0.01, 0.0, 0.0, 0.0))
    sig = np.full(4, 1e-4)
    est = fuse_altitude(pts[:, 2], sig, None, 1.31, LaserConfig(), points_level_m=pts)
    assert est.relief_var_m2 == pytest.approx(0.01**2 / 4 - 4 * 1e-8 / 4, rel=1e-6)  # less the noise's share
    # The spots' centroid noise alone explains residuals of its size: nothing left for the relief.
    noisy = fuse_altitude(pts[:, 2], np.full(4, 0.02), None, 1.31, LaserConfig(), points_level_m=pts)
    assert noisy.relief_var_m2 == 0.0
    # Three spots: a plane, no residual, no relief measured.
    three = fuse_altitude(pts[:3, 2], sig[:3], None, 1.31, LaserConfig(), points_level_m=pts[:3])
    assert three.slope_rad is not None and math.isnan(three.relief_var_m2)


def test_the_planes_depth_at_a_pixel_over_a_synthetic_slope():
    """Over a 15 x -10 degree slope the plane's depth at any pixel is the true one (to 1e-9); the one
    depth below the camera is up to 8 % off at the image's corners."""
    z0, tan_a, tan_b = 1.31, math.tan(math.radians(15.0)), math.tan(math.radians(-10.0))
    uv = np.array([[0.0, 0.0], [359.0, 0.0], [0.0, 271.0], [359.0, 271.0], [179.5, 135.5], [60.0, 200.0]])
    mn = pixels_to_mn(CAM, uv, z0)
    depth = plane_depth_m(z0, (math.atan(tan_a), math.atan(tan_b)), mn, F_PX)
    # The truth: the pixel's ray (offset g per metre of depth) cut by the plane.
    g1 = pixels_to_ground(CAM, uv, 1.0)
    truth = z0 / (1.0 - tan_a * g1[:, 0] - tan_b * g1[:, 1])
    assert np.max(np.abs(depth / truth - 1.0)) < 1e-9
    assert np.max(np.abs(z0 / truth - 1.0)) > 0.05  # what one depth for the whole image would be off
    assert np.array_equal(plane_depth_m(z0, None, mn, F_PX), np.full(len(mn), z0))


def test_the_planes_depth_from_noisy_spots_beats_one_depth_over_a_slope():
    """Spots with 3 mm of depth noise over a 10 degree slope, the slope averaged over 1 s of frames at 5 Hz: the depth
    at the image's corners within 0.2 % of the truth (median; 0.11 % measured), where the one depth below the camera
    is 2.2 % off."""
    rng = np.random.default_rng(5)
    z0, tan_a = 1.31, math.tan(math.radians(10.0))
    avg = PlaneAverage(relief_tau_s=2.0, slope_tau_s=1.0)
    corners = np.array([[0.0, 0.0], [359.0, 271.0]])
    mn = pixels_to_mn(CAM, corners, z0)
    g1 = pixels_to_ground(CAM, corners, 1.0)
    truth = z0 / (1.0 - tan_a * g1[:, 0])
    errs, flat = [], []
    for k in range(40):
        pts = _plane_points(z0, tan_a, 0.0)
        pts[:, 2] += rng.normal(0.0, 0.003, 4)
        est = fuse_altitude(pts[:, 2], np.full(4, 0.003), None, 1.31, LaserConfig(), points_level_m=pts)
        _, slope = avg.add(0.2 * k, est)
        if k >= 10:
            errs.extend(np.abs(plane_depth_m(z0, slope, mn, F_PX) / truth - 1.0))
            flat.extend(np.abs(z0 / truth - 1.0))
    assert np.median(errs) < 0.002 and np.max(errs) < 0.006
    assert np.median(flat) > 0.02


def _estimate(relief_var_m2: float, slope=None) -> AltitudeEstimate:
    return AltitudeEstimate(1.31, 0.002, "laser", np.zeros((0, 2)), 4, slope_rad=slope, relief_var_m2=relief_var_m2)


def test_the_relief_is_averaged_over_frames_and_a_frame_without_a_plane_keeps_it():
    avg = PlaneAverage(relief_tau_s=2.0, slope_tau_s=1.0, max_slope_rad=0.2)
    var, slope = avg.add(0.0, _estimate(1e-4, (0.5, -0.05)))
    assert var == pytest.approx(1e-4) and slope == pytest.approx((0.2, -0.05))  # clipped to 0.2 rad
    var, _ = avg.add(2.0, _estimate(0.0))  # one time constant later: 1 - 1/e of the way
    assert var == pytest.approx(1e-4 * math.exp(-1.0), rel=1e-9)
    assert avg.add(2.2, _estimate(float("nan")))[0] == pytest.approx(var)  # no plane: kept


def test_the_relief_off_the_plane_widens_a_landmark_observation():
    """The consider parameter: 1 cm of relief off the plane (gain 1) turns Z's 2 mm sigma into 10.2 mm, and the
    innovation covariance of a landmark 150 px off the image centre grows by (150 x 0.0102 / 1.31)^2 - ... px^2."""
    on = RunConfig(slam=dataclasses.replace(RunConfig().slam, landmark_relief_gain=1.0))
    off = RunConfig(slam=dataclasses.replace(RunConfig().slam, landmark_relief_gain=0.0))
    alt = _estimate(0.01**2)
    mn = np.array([150.0, 0.0])
    depth_on, sigma_on = landmark_depth(on, alt, mn, F_PX)
    depth_off, sigma_off = landmark_depth(off, alt, mn, F_PX)
    assert depth_on == depth_off == 1.31
    assert sigma_off == 0.002 and sigma_on == pytest.approx(math.hypot(0.002, 0.01))
    ekf = EkfSlam(RunConfig().slam)
    i = ekf.augment(mn, 0.0, 1.31, F_PX, altitude_sigma_m=0.002)
    _, s_off = ekf.predict_observation(i, 0.0, 1.31, F_PX, altitude_sigma_m=sigma_off)
    _, s_on = ekf.predict_observation(i, 0.0, 1.31, F_PX, altitude_sigma_m=sigma_on)
    depth = 1.31 + ekf.altitude_bias_m
    added = 150.0**2 * (sigma_on**2 - sigma_off**2) / depth**2
    assert s_on[0, 0] - s_off[0, 0] == pytest.approx(added, rel=1e-9)
    assert added > 1.2  # more than a pixel of sigma along m
    assert s_on[1, 1] == pytest.approx(s_off[1, 1])


def test_a_landmark_depth_from_the_plane_at_its_pixel():
    cfg = RunConfig(laser=dataclasses.replace(RunConfig().laser, plane_depth=True))
    slope = (math.radians(10.0), 0.0)
    mn = np.array([120.0, -40.0])
    depth, _ = landmark_depth(cfg, _estimate(float("nan"), slope), mn, F_PX)
    assert depth == pytest.approx(1.31 / (1.0 - math.tan(slope[0]) * 120.0 / F_PX), rel=1e-12)
    assert depth > 1.31 * 1.019  # 2 % deeper 120 px forward on a 10 degree slope


def _depth_model(gain: float):
    from rovslam.pipeline.depth import DepthModel
    from rovslam.sensor.altitude import AltitudeFilter
    from rovslam.sensor.odometry import SpeedEstimator

    cfg = RunConfig(laser=dataclasses.replace(RunConfig().laser, relief_altitude_gain=gain))
    return DepthModel(
        cfg, AltitudeFilter(cfg.laser.altitude_accel_sigma_mps2), SpeedEstimator(cfg.odometry), EkfSlam(cfg.slam)
    )


def test_the_relief_off_the_plane_widens_the_altitude_reading_before_the_filter():
    """Readings that step by 2 cm over 5 mm of relief off the spots' plane: with the gain 3 the filter
    follows 40 % of the step at the first frame (75 % without), and its sigma is 9.6 mm (1.7 mm without)."""
    followed, sigma = {}, {}
    for gain in (0.0, 3.0):
        model = _depth_model(gain)
        for k in range(21):
            z = 1.31 if k < 20 else 1.33
            reading = AltitudeEstimate(z, 0.002, "laser", np.zeros((0, 2)), 4, relief_var_m2=0.005**2)
            out = model.filtered(0.2 * k, reading)
            assert out.relief_var_m2 == pytest.approx(0.005**2)
            if k == 15:
                sigma[gain] = out.sigma_m
        followed[gain] = (out.altitude_m - 1.31) / 0.02
    assert followed[0.0] == pytest.approx(0.75, abs=0.02) and followed[3.0] == pytest.approx(0.40, abs=0.02)
    assert sigma[0.0] == pytest.approx(0.0017, abs=2e-4) and sigma[3.0] == pytest.approx(0.0096, abs=5e-4)
