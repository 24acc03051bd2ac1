"""Guidance, control and the vehicle model of rovslam.nav, with numbers (no images)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovslam.core import Goal
from rovslam.errors import InvalidArgumentError
from rovslam.nav import (
    Arrival,
    Command,
    DeadReckoningCovariance,
    DynamicsParams,
    GuidanceConfig,
    HoldEnd,
    Mission,
    NavEstimate,
    VehicleState,
    arrival_state,
    body_command,
    ellipse_semi_major_m,
    saturate,
    step_vehicle,
    waypoint_velocity,
)

SMALL_COV = np.eye(2) * 1e-6  # 2-sigma semi-major axis 2 mm
WIDE_COV = np.eye(2) * 1e-4  # 2 cm


def est(t_s, xy, cov=SMALL_COV, heading=0.0, vel=None):
    return NavEstimate(
        t_s,
        np.asarray(xy, dtype=float),
        np.asarray(cov, dtype=float),
        heading,
        None if vel is None else np.asarray(vel, dtype=float),
    )


# ------------------------------------------------------------------ pure laws
def test_saturate_keeps_the_direction_and_leaves_short_vectors_alone():
    np.testing.assert_allclose(saturate(np.array([0.3, 0.4]), 0.1), [0.06, 0.08], atol=1e-15)
    np.testing.assert_array_equal(saturate(np.array([0.03, -0.04]), 0.1), [0.03, -0.04])


def test_waypoint_law_cruises_far_away_slows_down_near_and_passes_survey_points():
    cfg = GuidanceConfig(cruise_speed_mps=0.1, approach_gain_per_s=0.2, min_transit_speed_mps=0.03)
    far = waypoint_velocity(np.zeros(2), np.array([3.0, 4.0]), cfg)  # 5 m away: cruise, towards the target
    np.testing.assert_allclose(far, [0.06, 0.08], atol=1e-12)
    near = waypoint_velocity(np.zeros(2), np.array([0.0, -0.1]), cfg)  # 10 cm: 0.2/s x 0.1 m = 2 cm/s
    np.testing.assert_allclose(near, [0.0, -0.02], atol=1e-12)
    passing = waypoint_velocity(np.zeros(2), np.array([0.05, 0.0]), cfg, pass_through=True)
    np.testing.assert_allclose(passing, [0.03, 0.0], atol=1e-12)  # 1 cm/s by the gain, 3 cm/s floor
    np.testing.assert_array_equal(waypoint_velocity(np.ones(2), np.ones(2), cfg), [0.0, 0.0])


def test_body_command_turns_into_the_body_frame_compensates_the_current_and_saturates():
    cfg = GuidanceConfig(max_speed_mps=0.2, max_yaw_rate_radps=0.2, yaw_gain_per_s=0.5)
    # Heading east: going north is going to port (negative sway).
    c = body_command(np.array([0.1, 0.0]), np.zeros(2), math.pi / 2, math.pi / 2, cfg)
    assert c.surge_mps == pytest.approx(0.0, abs=1e-12) and c.sway_mps == pytest.approx(-0.1)
    assert c.yaw_rate_radps == 0.0
    # Holding still in a 1 cm/s current from the south: push 1 cm/s south through the water.
    c = body_command(np.zeros(2), np.array([0.01, 0.0]), 0.0, 0.0, cfg)
    assert (c.surge_mps, c.sway_mps) == pytest.approx((-0.01, 0.0))
    # 0.5 m/s asked: saturated to 0.2 m/s, direction kept.
    c = body_command(np.array([0.3, 0.4]), np.zeros(2), 0.0, 0.0, cfg)
    assert (c.surge_mps, c.sway_mps) == pytest.approx((0.12, 0.16))
    # Yaw: 1 rad off -> 0.5 rad/s saturated to 0.2; 0.1 rad -> 0.05; the error is wrapped (-2 degrees).
    assert body_command(np.zeros(2), np.zeros(2), 0.0, 1.0, cfg).yaw_rate_radps == pytest.approx(0.2)
    assert body_command(np.zeros(2), np.zeros(2), 0.0, 0.1, cfg).yaw_rate_radps == pytest.approx(0.05)
    wrapped = body_command(np.zeros(2), np.zeros(2), math.radians(-179), math.radians(179), cfg).yaw_rate_radps
    assert wrapped == pytest.approx(0.5 * math.radians(-2))


def test_ellipse_and_arrival_state():
    assert ellipse_semi_major_m(np.diag([4e-4, 1e-4])) == pytest.approx(0.04)
    assert ellipse_semi_major_m(np.array([[1e-4, 1e-4], [1e-4, 1e-4]])) == pytest.approx(2 * math.sqrt(2e-4))
    cfg = GuidanceConfig(arrival_radius_m=0.005, max_ellipse_m=0.01)
    target = np.array([1.0, 1.0])
    assert arrival_state(np.array([1.004, 1.0]), SMALL_COV, target, cfg) == "arrived"
    assert arrival_state(np.array([1.004, 1.0]), WIDE_COV, target, cfg) == "uncertain"
    assert arrival_state(np.array([1.006, 1.0]), SMALL_COV, target, cfg) == "away"


def test_bad_guidance_values_are_refused():
    with pytest.raises(InvalidArgumentError, match="arrival_radius_m"):
        GuidanceConfig(arrival_radius_m=0.0)
    with pytest.raises(InvalidArgumentError, match="cruise_speed_mps"):
        GuidanceConfig(cruise_speed_mps=0.5, max_speed_mps=0.2)
    with pytest.raises(InvalidArgumentError, match="hold_s"):
        GuidanceConfig(hold_s=-1.0)


# ------------------------------------------------------------------ the mission state machine
def fly(mission, estimates, dt=0.2):
    events = []
    for e in estimates:
        _, ev = mission.update(e, dt)
        events += ev
    return events


def test_arrival_needs_the_settle_time_then_the_hold_lasts_its_time():
    cfg = GuidanceConfig(arrival_radius_m=0.005, settle_s=2.0, hold_s=3.0)
    m = Mission([Goal("a", np.array([1.0, 0.0])), Goal("b", np.array([0.0, 1.0]))], cfg)
    ev = fly(m, [est(0.2 * k, [1.002, 0.0]) for k in range(40)])
    arrivals = [e for e in ev if isinstance(e, Arrival)]
    ends = [e for e in ev if isinstance(e, HoldEnd)]
    assert arrivals[0].name == "a" and arrivals[0].t_s == pytest.approx(2.0) and arrivals[0].confident
    assert ends[0].name == "a" and ends[0].t_s == pytest.approx(5.0) and ends[0].reached
    assert m.goal.name == "b" and m.phase == "transit"


def test_passing_through_the_circle_is_not_arriving():
    cfg = GuidanceConfig(arrival_radius_m=0.005, settle_s=2.0)
    m = Mission([Goal("a", np.array([0.0, 0.0]))], cfg)
    xs = [0.02 - 0.002 * k for k in range(21)]  # 1 cm/s through the point: 1 s inside the radius
    assert not [e for e in fly(m, [est(0.2 * k, [x, 0.0]) for k, x in enumerate(xs)]) if isinstance(e, Arrival)]


def test_a_wide_ellipse_waits_then_arrives_flagged_as_not_confident():
    cfg = GuidanceConfig(arrival_radius_m=0.005, max_ellipse_m=0.01, ellipse_wait_s=4.0, settle_s=1.0, hold_s=1.0)
    m = Mission([Goal("a", np.array([0.0, 0.0]))], cfg)
    ev = fly(m, [est(0.2 * k, [0.001, 0.0], WIDE_COV) for k in range(40)])
    a = [e for e in ev if isinstance(e, Arrival)][0]
    assert a.t_s == pytest.approx(4.0) and not a.confident and a.ellipse_m == pytest.approx(0.02)


def test_survey_points_are_passed_and_dropped_when_the_survey_time_is_over():
    cfg = GuidanceConfig(waypoint_radius_m=0.03)
    goals = [
        Goal("s0", np.array([0.0, 0.02]), kind="survey"),
        Goal("s1", np.array([5.0, 0.0]), kind="survey"),
        Goal("poi", np.array([0.0, 0.0])),
    ]
    m = Mission(goals, cfg, survey_until_s=1.0)
    m.update(est(0.0, [0.0, 0.0]), 0.2)
    assert m.goal.name == "s1"  # s0 passed within 3 cm, no event
    m.update(est(0.8, [0.0, 0.0]), 0.2)
    assert m.goal.name == "s1"
    _, ev = m.update(est(1.0, [0.0, 0.0]), 0.2)
    assert m.goal.name == "poi" and ev == []


def test_landmark_goals_follow_the_map_and_a_missing_landmark_is_skipped():
    where = {3: np.array([0.4, 0.1])}
    m = Mission(
        [Goal("lm9", None, landmark_id=9), Goal("lm3", None, landmark_id=3)],
        GuidanceConfig(),
        resolve=lambda i: where.get(i),
    )
    _, ev = m.update(est(0.0, [0.0, 0.0]), 0.2)
    assert ev == [HoldEnd(0, "lm9", 0.0, False, "landmark 9 is not in the map")]
    np.testing.assert_array_equal(m.target_xy_m, [0.4, 0.1])
    where[3] = np.array([0.41, 0.1])  # the map improved
    m.update(est(0.2, [0.0, 0.0]), 0.2)
    np.testing.assert_array_equal(m.target_xy_m, [0.41, 0.1])


def test_a_goal_not_reached_in_time_is_abandoned():
    m = Mission([Goal("far", np.array([10.0, 0.0]))], GuidanceConfig(goal_timeout_s=5.0))
    ev = fly(m, [est(0.2 * k, [0.0, 0.0]) for k in range(30)])
    assert ev == [HoldEnd(0, "far", pytest.approx(5.2), False, "not reached within 5 s")] and m.done


# ------------------------------------------------------------------ vehicle model and closed loop without images
def test_first_order_response_and_speed_limit():
    p = DynamicsParams(surge_tau_s=1.0, sway_tau_s=2.0, max_speed_mps=0.3)
    s = VehicleState(0.0, 0.0, 0.0, 0.0)
    s1 = step_vehicle(s, Command(0.1, 0.1, 0.0), np.zeros(2), 1.31, 1.0, p)
    assert s1.u_water_mps == pytest.approx(0.1 * (1 - math.exp(-1.0)))
    assert s1.v_water_mps == pytest.approx(0.1 * (1 - math.exp(-0.5)))
    fast = s
    for _ in range(200):
        fast = step_vehicle(fast, Command(1.0, 0.0, 0.0), np.zeros(2), 1.31, 0.1, p)
    assert fast.u_water_mps == pytest.approx(0.3, abs=1e-6)  # saturated
    drift = step_vehicle(s, Command(), np.array([0.01, -0.02]), 1.31, 2.0, p)  # the current alone
    assert (drift.x_m, drift.y_m) == pytest.approx((0.02, -0.04))


def test_guidance_holds_a_point_in_a_current_it_estimates():
    """Perfect position estimate, measured ground speed, a 1.2 cm/s current: the hold ends within 1 mm."""
    p = DynamicsParams(current_mean_mps=0.0, current_wander_mps=0.0)
    current = np.array([0.012, -0.005])
    cfg = GuidanceConfig(hold_s=60.0, settle_s=1.0)
    m = Mission([Goal("a", np.array([0.3, -0.2]))], cfg)
    s = VehicleState(0.0, 0.0, 0.0, 0.0)
    dt, prev = 0.2, np.zeros(2)
    errs = []
    for k in range(1500):
        xy = np.array([s.x_m, s.y_m])
        vel = (xy - prev) / dt if k else None
        prev = xy
        cmd, _ = m.update(est(k * dt, xy, vel=vel), dt)
        if m.phase == "hold":
            errs.append(float(np.hypot(*(xy - [0.3, -0.2]))))
        for _ in range(4):
            s = step_vehicle(s, cmd, current, 1.31, dt / 4, p)
    assert len(errs) > 100
    assert max(errs[-100:]) < 1e-3
    np.testing.assert_allclose(m.current_mps, current, atol=5e-4)


def test_dead_reckoning_covariance_adds_each_step():
    from types import SimpleNamespace

    dr = DeadReckoningCovariance()
    res = SimpleNamespace(
        dt_s=0.2,
        surge_mps=0.1,
        sway_mps=0.0,
        speed_cov_mps2=np.eye(2) * 1e-6,
        heading_rad=0.0,
        measurements=SimpleNamespace(heading_rad=0.0, heading_sigma_rad=0.01),
    )
    for _ in range(10):
        cov = dr.update(res)
    # speed: 10 x 0.2^2 x 1e-6 on both axes; heading: 10 x (0.1 x 0.2 x 0.01)^2 across the track (y)
    np.testing.assert_allclose(cov, np.diag([4e-7, 4e-7 + 10 * (0.02 * 0.01) ** 2]), rtol=1e-12, atol=1e-18)
