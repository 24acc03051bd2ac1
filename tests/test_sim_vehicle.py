"""Vehicle simulation: grid way-points, speeds and accelerations, revisits, altitude, attitude, sensors."""

from __future__ import annotations

import numpy as np
import pytest

from rovslam.camera import footprint_m
from rovslam.errors import SimulationError
from rovslam.sim import (
    PORTOFINO_CAMERA,
    SCENARIOS,
    GridPattern,
    NavSensorParams,
    VehicleParams,
    read_sensors,
    simulate_trajectory,
)


@pytest.fixture(scope="module")
def portofino():
    sc = SCENARIOS["portofino"]
    return simulate_trajectory(sc.vehicle, sc.grid, 3000, sc.frame_rate_hz, seed=0)


@pytest.fixture(scope="module")
def rough():
    sc = SCENARIOS["rough-turns"]
    return simulate_trajectory(sc.vehicle, sc.grid, 3000, sc.frame_rate_hz, seed=0)


def test_grid_is_a_cross_hatch_with_shifted_repeats():
    g = GridPattern()
    a, b, c = g.repetition(0), g.repetition(1), g.repetition(2)
    assert np.all(np.abs(np.diff(a[::2, 1])) > 0.1)  # lanes along x: y steps between lanes
    np.testing.assert_allclose(a[0::2, 1], a[1::2, 1])  # each lane at constant y
    np.testing.assert_allclose(b[0::2, 0], b[1::2, 0])  # then lanes along y at constant x
    assert np.ptp(a[:, 0]) == pytest.approx(0.7) and np.ptp(a[:, 1]) == pytest.approx(0.7)
    assert np.min(np.abs(c[:, 0] - a[:, 0][:, None])) > 0.0  # shifted offsets on a later pass


def test_trajectory_starts_at_the_origin_and_follows_the_grid(portofino):
    tr = portofino
    assert (tr.x_m[0], tr.y_m[0], tr.t_s[0]) == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(np.diff(tr.t_s), 0.2)
    assert np.abs(tr.x_m).max() < 0.35 + 0.0875 + 0.08
    assert np.abs(tr.y_m).max() < 0.35 + 0.0875 + 0.08
    speed = np.hypot(tr.surge_mps, tr.sway_mps)
    assert speed.max() < 0.15  # survey speed: up to about 0.15 m/s
    assert 0.04 < speed.mean() < 0.11
    assert np.percentile(speed, 5) < 0.04  # slows down at the way-points
    # Ground speed from positions matches the recorded speed.
    v_fd = np.hypot(np.diff(tr.x_m), np.diff(tr.y_m)) / 0.2
    assert np.median(np.abs(v_fd - speed[:-1])) < 0.005


def test_acceleration_limit(portofino):
    tr = portofino
    c, s = np.cos(tr.heading_rad), np.sin(tr.heading_rad)
    vx, vy = c * tr.surge_mps - s * tr.sway_mps, s * tr.surge_mps + c * tr.sway_mps
    acc = np.hypot(np.diff(vx), np.diff(vy)) / 0.2
    assert acc.max() < 0.03 * 1.1 + 0.002  # thrust limit plus the slow current changes


def test_constant_heading_and_controlled_altitude(portofino):
    tr = portofino
    assert np.abs(tr.heading_rad).max() < np.deg2rad(1.0)
    assert tr.altitude_m.mean() == pytest.approx(1.31, abs=0.005)
    assert np.abs(tr.altitude_m - 1.31).max() < 0.03  # +-1 cm control noise, rarely more
    assert np.all(tr.roll_rad == 0) and np.all(tr.pitch_rad == 0)


def test_returns_over_the_start_area_in_the_first_two_minutes(portofino):
    along, across = footprint_m(PORTOFINO_CAMERA, 1.31)
    x, y = portofino.x_m[:600], portofino.y_m[:600]
    # The start point is in the central 75 % of the image.
    in_view = (np.abs(x) < 0.375 * along) & (np.abs(y) < 0.375 * across)
    returns = np.sum(np.diff(in_view.astype(int)) == 1)
    assert returns >= 3


def test_current_pushes_the_vehicle_off_its_lanes(portofino):
    """Cross-track deviation of a few millimetres to centimetres, corrected by the controller."""
    g = GridPattern()
    lanes_y = g.repetition(0)[::2, 1]
    tr = portofino
    # Frames while flying the first x-lanes, away from their ends.
    k = np.arange(len(tr))
    sel = (k > 100) & (k < 350) & (np.abs(tr.x_m) < 0.2) & (np.abs(tr.surge_mps) > 0.05)
    dev = np.min(np.abs(tr.y_m[sel][:, None] - lanes_y[None, :]), axis=1)
    assert 0.001 < np.median(dev) < 0.03
    assert dev.max() < 0.06


def test_rough_preset_turns_swings_and_tilts(rough):
    tr = rough
    heading_deg = np.rad2deg(np.unwrap(tr.heading_rad))
    assert np.ptp(heading_deg) > 170  # turns at the grid corners
    rate = np.abs(np.diff(np.unwrap(tr.heading_rad))) / 0.2
    assert rate.max() < 0.25 + 0.02  # yaw-rate limit (plus the control wander)
    assert np.ptp(tr.altitude_m) > 0.15 and np.abs(tr.altitude_m - 1.31).max() < 0.16
    for a in (tr.roll_rad, tr.pitch_rad):
        assert np.deg2rad(0.5) < a.std() < np.deg2rad(1.5)
    # Mostly surge along the lanes once turned.
    moving = np.hypot(tr.surge_mps, tr.sway_mps) > 0.05
    assert np.median(np.abs(tr.surge_mps[moving])) > 3 * np.median(np.abs(tr.sway_mps[moving]))


def test_sensor_noise_levels(rough):
    nav = NavSensorParams(
        compass_sigma_rad=0.005,
        compass_bias_rad=0.01,
        compass_drift_rad=0.0,
        sonar_sigma_m=0.02,
        attitude_sigma_rad=0.002,
        attitude_drift_rad=0.0,
    )
    r = read_sensors(rough, nav, seed=3)
    err = np.angle(np.exp(1j * (r.heading_rad - rough.heading_rad)))
    assert err.mean() == pytest.approx(0.01, abs=0.0005)
    assert err.std() == pytest.approx(0.005, rel=0.1)
    assert np.std(r.sonar_altitude_m - rough.altitude_m) == pytest.approx(0.02, rel=0.1)
    assert np.std(r.roll_rad - rough.roll_rad) == pytest.approx(0.002, rel=0.1)
    no_sonar = read_sensors(rough, NavSensorParams(sonar=False), seed=3)
    assert no_sonar.sonar_altitude_m is None
    # Default: a slow compass drift (0.3 deg, 2 min) on top of 0.3 deg of white noise.
    d = read_sensors(rough, NavSensorParams(), seed=3)
    err = np.angle(np.exp(1j * (d.heading_rad - rough.heading_rad)))
    smooth = np.convolve(err, np.ones(50) / 50, mode="valid")  # 10 s means: the drift remains
    assert np.deg2rad(0.05) < smooth.std() < np.deg2rad(0.6)
    assert np.std(np.diff(d.roll_rad - rough.roll_rad)) < np.deg2rad(0.03)  # smooth AHRS output


def test_same_seed_same_trajectory():
    sc = SCENARIOS["portofino"]
    a = simulate_trajectory(sc.vehicle, sc.grid, 200, 5.0, seed=8)
    b = simulate_trajectory(sc.vehicle, sc.grid, 200, 5.0, seed=8)
    c = simulate_trajectory(sc.vehicle, sc.grid, 200, 5.0, seed=9)
    np.testing.assert_array_equal(a.x_m, b.x_m)
    np.testing.assert_array_equal(a.altitude_m, b.altitude_m)
    assert np.abs(a.x_m - c.x_m).max() > 1e-4
    # A longer run starts with the same frames.
    d = simulate_trajectory(sc.vehicle, sc.grid, 400, 5.0, seed=8)
    for name in ("x_m", "y_m", "altitude_m", "heading_rad", "surge_mps"):
        np.testing.assert_array_equal(getattr(a, name), getattr(d, name)[:200])
    nav_a, nav_d = read_sensors(a, NavSensorParams(), 8), read_sensors(d, NavSensorParams(), 8)
    np.testing.assert_array_equal(nav_a.heading_rad, nav_d.heading_rad[:200])


def test_bad_vehicle_parameters():
    with pytest.raises(SimulationError, match="heading_mode"):
        VehicleParams(heading_mode="spin")
    with pytest.raises(SimulationError, match="seabed"):
        VehicleParams(altitude_m=0.4, altitude_swing_m=0.3)
    with pytest.raises(SimulationError, match="n_frames"):
        simulate_trajectory(VehicleParams(), GridPattern(), 0, 5.0, 0)
