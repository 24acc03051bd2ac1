"""Guidance and control to points of interest, from the online estimate only.

The law (world frame x north, y east; body frame x forward, y starboard):

* **way-point law**: the desired ground velocity points at the goal with speed
  ``min(cruise_speed_mps, approach_gain_per_s * distance)`` (a proportional approach that
  slows down on arrival), or at least ``min_transit_speed_mps`` on a survey way-point the
  vehicle passes through;
* **integral action**: within ``integral_radius_m`` of a point of interest an integral of the
  position error (gain ``integral_gain_per_s2``, clamped to ``integral_limit_mps``) removes
  the offset the current estimate leaves;
* **current compensation**: the controller estimates the current as the low-passed
  difference between the ground velocity the pipeline measures and the water velocity it
  believes it commanded (a first-order model of its own thrusters), and subtracts it; without
  it a proportional law stops ``current / gain`` short of the point (1.6 cm for 8 mm/s);
* **speed limits**: the water-relative command is saturated as a vector to
  ``max_speed_mps`` (the direction kept), the yaw rate to ``max_yaw_rate_radps``;
* **heading**: held at a reference (the first heading estimate, unless given) by a
  proportional yaw-rate law;
* **arrival** at a point of interest: the estimated position within ``arrival_radius_m``
  (for ``settle_s`` in a row: passing through the circle is not arriving) AND the 2-sigma ellipse's semi-major axis under ``max_ellipse_m``. Within the radius but
  with a wider ellipse the vehicle keeps station there and waits (landmark updates shrink
  the ellipse) for at most ``ellipse_wait_s`` from the first time it came within the radius; then it declares the arrival anyway, flagged
  as not confident (a dead-reckoning vehicle, whose ellipse only grows, always ends so);
* **station keeping**: after the arrival the same law holds the point for the point's
  ``hold_s``; then the next point.

:func:`waypoint_velocity`, :func:`body_command`, :func:`saturate`, :func:`ellipse_semi_major_m`
and :func:`arrival_state` are pure; :class:`Mission` is the state machine over the goals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rovslam.camera import rot2
from rovslam.core import Goal
from rovslam.errors import InvalidArgumentError
from rovslam.nav.dynamics import Command

__all__ = [
    "Arrival",
    "Goal",
    "GuidanceConfig",
    "HoldEnd",
    "Mission",
    "NavEstimate",
    "arrival_state",
    "guidance_config",
    "body_command",
    "ellipse_semi_major_m",
    "saturate",
    "waypoint_velocity",
]


@dataclass(frozen=True)
class GuidanceConfig:
    """Gains, limits and the arrival rule of the guidance."""

    cruise_speed_mps: float = 0.10
    approach_gain_per_s: float = 0.2
    min_transit_speed_mps: float = 0.03  # survey way-points: never slower than this before passing
    max_speed_mps: float = 0.2  # water-relative command, vector norm
    max_yaw_rate_radps: float = 0.2
    yaw_gain_per_s: float = 0.5
    heading_rad: float | None = None  # held heading (None: the first estimate)
    arrival_radius_m: float = 0.005
    settle_s: float = 2.0  # the estimate stays within the radius this long before the arrival
    integral_gain_per_s2: float = (
        0.01  # integral action near a point of interest (removes what the current estimate misses)
    )
    integral_radius_m: float = 0.01  # ... within this distance of the point
    integral_limit_mps: float = 0.005
    max_ellipse_m: float = 0.015  # 2-sigma semi-major axis of the position estimate
    stop_ellipse_m: float = 0.10  # a vehicle steered through its autopilot stops while the 2-sigma ellipse is wider
    ellipse_wait_s: float = 15.0
    hold_s: float = 10.0
    waypoint_radius_m: float = 0.03  # survey way-points are passed within this
    goal_timeout_s: float = 300.0  # a goal not reached after this long is abandoned
    current_tau_s: float = 10.0  # low-pass time of the current estimate
    thruster_tau_s: tuple[float, float] = (1.0, 1.5)  # the controller's model of its surge / sway response

    def __post_init__(self) -> None:
        for name in (
            "cruise_speed_mps",
            "approach_gain_per_s",
            "max_speed_mps",
            "max_yaw_rate_radps",
            "yaw_gain_per_s",
            "arrival_radius_m",
            "max_ellipse_m",
            "stop_ellipse_m",
            "waypoint_radius_m",
            "goal_timeout_s",
            "current_tau_s",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidArgumentError(f"GuidanceConfig.{name} must be a finite number > 0, got {v!r}")
        for name in (
            "min_transit_speed_mps",
            "ellipse_wait_s",
            "hold_s",
            "settle_s",
            "integral_gain_per_s2",
            "integral_radius_m",
            "integral_limit_mps",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidArgumentError(f"GuidanceConfig.{name} must be a finite number >= 0, got {v!r}")
        if self.cruise_speed_mps > self.max_speed_mps:
            raise InvalidArgumentError(
                f"GuidanceConfig.cruise_speed_mps ({self.cruise_speed_mps}) exceeds max_speed_mps ({self.max_speed_mps})"
            )


def guidance_config(hold_s: float, approach_gain_per_s: float | None = None) -> GuidanceConfig:
    """The :class:`GuidanceConfig` of the commands' ``--hold-s`` and ``--approach-gain-per-s`` (None: its default).

    A larger gain holds the vehicle closer to a point and arrives sooner where the current estimate
    lags a changing current; docs/navigation.md ("The approach gain") has the measured trade-off.
    """
    if approach_gain_per_s is None:
        return GuidanceConfig(hold_s=float(hold_s))
    g = approach_gain_per_s
    if isinstance(g, bool) or not (isinstance(g, (int, float)) and math.isfinite(g) and g > 0):
        raise InvalidArgumentError(f"--approach-gain-per-s must be a number > 0 (per second), got {g!r}")
    return GuidanceConfig(hold_s=float(hold_s), approach_gain_per_s=float(g))


@dataclass(frozen=True)
class NavEstimate:
    """What the controller knows after a frame: the estimate it steers by (map frame)."""

    t_s: float
    xy_m: np.ndarray  # (2,)
    cov_m2: np.ndarray  # (2, 2)
    heading_rad: float
    ground_velocity_mps: np.ndarray | None = None  # (2,) world frame, measured (None: no measurement this frame)


@dataclass(frozen=True)
class Arrival:
    """A point of interest reached (by the estimate)."""

    goal_index: int
    name: str
    t_s: float
    target_xy_m: np.ndarray  # (2,)
    est_xy_m: np.ndarray  # (2,)
    ellipse_m: float  # 2-sigma semi-major axis at arrival
    confident: bool  # False: declared after ellipse_wait_s with the ellipse still too wide


@dataclass(frozen=True)
class HoldEnd:
    """Station keeping over a point of interest finished (or the goal was abandoned: ``reached`` False)."""

    goal_index: int
    name: str
    t_s: float
    reached: bool = True
    reason: str = ""


# ---------------------------------------------------------------------------------------------- pure functions
def saturate(vec: np.ndarray, limit: float) -> np.ndarray:
    """``vec`` (2,) scaled down to norm ``limit`` when longer (its direction kept)."""
    v = np.asarray(vec, dtype=np.float64)
    n = float(np.hypot(v[0], v[1]))
    return v * (limit / n) if n > limit else v


def waypoint_velocity(
    est_xy_m: np.ndarray, target_xy_m: np.ndarray, cfg: GuidanceConfig, pass_through: bool = False
) -> np.ndarray:
    """(2,) desired ground velocity (world): towards the target at ``min(cruise, gain * distance)``.

    ``pass_through`` (a survey way-point): at least ``min_transit_speed_mps`` until it is passed.
    """
    d = np.asarray(target_xy_m, dtype=np.float64) - np.asarray(est_xy_m, dtype=np.float64)
    dist = float(np.hypot(d[0], d[1]))
    if dist < 1e-12:
        return np.zeros(2)
    speed = min(cfg.cruise_speed_mps, cfg.approach_gain_per_s * dist)
    if pass_through:
        speed = max(speed, min(cfg.min_transit_speed_mps, cfg.cruise_speed_mps))
    return d / dist * speed


def body_command(
    ground_velocity_mps: np.ndarray,
    current_mps: np.ndarray,
    heading_rad: float,
    heading_ref_rad: float,
    cfg: GuidanceConfig,
) -> Command:
    """The command for a desired ground velocity: water velocity = ground - current, in the body frame, saturated.

    Yaw rate: ``yaw_gain_per_s`` times the wrapped heading error, saturated to ``max_yaw_rate_radps``.
    """
    water = saturate(
        np.asarray(ground_velocity_mps, dtype=np.float64) - np.asarray(current_mps, dtype=np.float64), cfg.max_speed_mps
    )
    body = rot2(heading_rad).T @ water
    err = (heading_ref_rad - heading_rad + math.pi) % (2.0 * math.pi) - math.pi
    r = max(-cfg.max_yaw_rate_radps, min(cfg.max_yaw_rate_radps, cfg.yaw_gain_per_s * err))
    return Command(float(body[0]), float(body[1]), float(r))


def ellipse_semi_major_m(cov_m2: np.ndarray, n_sigma: float = 2.0) -> float:
    """Semi-major axis of the ``n_sigma`` ellipse of a (2, 2) covariance, metres."""
    c = np.asarray(cov_m2, dtype=np.float64)
    return n_sigma * math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (c + c.T))[-1]), 0.0))


def arrival_state(est_xy_m: np.ndarray, cov_m2: np.ndarray, target_xy_m: np.ndarray, cfg: GuidanceConfig) -> str:
    """``"arrived"`` (within the radius, ellipse small enough), ``"uncertain"`` (within, ellipse too wide) or ``"away"``."""
    d = np.asarray(target_xy_m, dtype=np.float64) - np.asarray(est_xy_m, dtype=np.float64)
    if float(np.hypot(d[0], d[1])) > cfg.arrival_radius_m:
        return "away"
    return "arrived" if ellipse_semi_major_m(cov_m2) <= cfg.max_ellipse_m else "uncertain"


# ---------------------------------------------------------------------------------------------- the state machine
@dataclass
class _Progress:
    index: int = 0
    phase: str = "transit"  # "transit" | "hold" | "done"
    started_s: float | None = None  # when the current goal started
    within_s: float | None = None  # when the estimate first came within the radius
    settled_s: float | None = None  # since when it has stayed within the radius
    hold_until_s: float | None = None
    integral_mps: np.ndarray = field(default_factory=lambda: np.zeros(2))  # integral term of the approach law
    events: list = field(default_factory=list)


class Mission:
    """Goals in order, each reached by the estimate, and the command of every frame.

    Survey goals (passed through) still ahead at ``survey_until_s`` are dropped (a survey of
    a given duration). ``resolve(landmark_id)`` gives a landmark's (2,) map position (None when not in the map);
    it is called at every frame of a landmark goal, so the point follows the map as it
    improves. :meth:`update` takes a :class:`NavEstimate` and returns the command and the
    events (:class:`Arrival`, :class:`HoldEnd`) of this frame.
    """

    def __init__(
        self,
        goals: list[Goal],
        cfg: GuidanceConfig = GuidanceConfig(),
        resolve=None,
        survey_until_s: float | None = None,
    ) -> None:
        self.goals = list(goals)
        self.survey_until_s = survey_until_s  # survey way-points left at this time are dropped
        self.cfg = cfg
        self.resolve = resolve
        self.p = _Progress()
        self.heading_ref_rad = cfg.heading_rad
        self.current_mps = np.zeros(2)
        self._water_mps = np.zeros(2)  # the controller's model of its water velocity (body frame)
        self._water_mean_mps = np.zeros(2)  # ... its mean over the last frame period
        self._last_cmd: Command | None = None
        self.target_xy_m: np.ndarray | None = None

    @property
    def done(self) -> bool:
        return self.p.index >= len(self.goals)

    @property
    def phase(self) -> str:
        return "done" if self.done else self.p.phase

    @property
    def goal(self) -> Goal | None:
        return None if self.done else self.goals[self.p.index]

    def _target(self, goal: Goal) -> np.ndarray | None:
        if goal.landmark_id is None:
            return np.asarray(goal.xy_m, dtype=np.float64)
        return None if self.resolve is None else self.resolve(goal.landmark_id)

    def _observe_current(self, est: NavEstimate, dt_s: float) -> None:
        """Current estimate: measured ground velocity minus the modelled water velocity, low-passed.

        The pipeline's speed is the mean over the last frame period, so it is compared with the
        model's mean water velocity over the same period.
        """
        if est.ground_velocity_mps is None or dt_s <= 0:
            return
        water_world = rot2(est.heading_rad) @ self._water_mean_mps
        a = min(1.0, dt_s / self.cfg.current_tau_s)
        self.current_mps = self.current_mps + a * (np.asarray(est.ground_velocity_mps) - water_world - self.current_mps)

    def _model_thrusters(self, cmd: Command, dt_s: float) -> None:
        """The water velocity the controller believes it has after ``cmd`` held for ``dt_s`` (first order), and its mean."""
        tau = np.array(self.cfg.thruster_tau_s, dtype=np.float64)
        target = np.array([cmd.surge_mps, cmd.sway_mps])
        decay = np.exp(-dt_s / tau)
        self._water_mean_mps = target + (self._water_mps - target) * (tau / dt_s) * (1.0 - decay)
        self._water_mps = target + (self._water_mps - target) * decay

    def _integral(self, error_m: np.ndarray, dt_s: float) -> np.ndarray:
        """Integral term of the law near a point of interest: ``ki * integral(error)``, clamped; 0 farther away."""
        cfg = self.cfg
        if float(np.hypot(*error_m)) > cfg.integral_radius_m:
            return self.p.integral_mps
        if dt_s > 0:
            self.p.integral_mps = saturate(
                self.p.integral_mps + cfg.integral_gain_per_s2 * error_m * dt_s, cfg.integral_limit_mps
            )
        return self.p.integral_mps

    def _next(self, t_s: float, events: list, reached: bool = True, reason: str = "") -> None:
        goal = self.goals[self.p.index]
        if goal.kind == "poi":
            events.append(HoldEnd(self.p.index, goal.name, t_s, reached, reason))
        self.p = _Progress(index=self.p.index + 1, started_s=t_s)

    def update(self, est: NavEstimate, dt_s: float) -> tuple[Command, list]:
        """The command for the frame period after ``est`` (``dt_s``: the time since the last update)."""
        cfg = self.cfg
        if self.heading_ref_rad is None:
            self.heading_ref_rad = float(est.heading_rad)
        if self._last_cmd is not None and dt_s > 0:
            self._model_thrusters(self._last_cmd, dt_s)
        self._observe_current(est, dt_s)
        events: list = []
        t = est.t_s
        while not self.done:
            goal = self.goals[self.p.index]
            if self.p.started_s is None:
                self.p.started_s = t
            target = self._target(goal)
            if target is None:
                self._next(t, events, False, f"landmark {goal.landmark_id} is not in the map")
                continue
            self.target_xy_m = target
            if self.p.phase == "transit" and t - self.p.started_s > cfg.goal_timeout_s:
                self._next(t, events, False, f"not reached within {cfg.goal_timeout_s:g} s")
                continue
            if goal.kind == "survey":
                d = target - est.xy_m
                late = self.survey_until_s is not None and t >= self.survey_until_s
                if late or float(np.hypot(*d)) <= cfg.waypoint_radius_m:
                    self._next(t, events)
                    continue
                vel = waypoint_velocity(est.xy_m, target, cfg, pass_through=True)
                break
            if self.p.phase == "transit":
                state = arrival_state(est.xy_m, est.cov_m2, target, cfg)
                if state == "away":
                    self.p.settled_s = None
                else:
                    if self.p.within_s is None:  # the ellipse wait runs from the first time within the radius
                        self.p.within_s = t
                    if self.p.settled_s is None:
                        self.p.settled_s = t
                    settled = t - self.p.settled_s >= cfg.settle_s - 1e-9
                    if settled and (state == "arrived" or t - self.p.within_s >= cfg.ellipse_wait_s):
                        hold = cfg.hold_s if goal.hold_s is None else goal.hold_s
                        events.append(
                            Arrival(
                                self.p.index,
                                goal.name,
                                t,
                                target.copy(),
                                np.array(est.xy_m, dtype=float),
                                ellipse_semi_major_m(est.cov_m2),
                                state == "arrived",
                            )
                        )
                        self.p.phase, self.p.hold_until_s = "hold", t + hold
            if self.p.phase == "hold" and t >= self.p.hold_until_s:  # type: ignore[operator]
                self._next(t, events)
                continue
            vel = waypoint_velocity(est.xy_m, target, cfg) + self._integral(target - est.xy_m, dt_s)
            break
        else:
            vel = np.zeros(2)
            self.target_xy_m = None
        cmd = body_command(vel, self.current_mps, est.heading_rad, self.heading_ref_rad, cfg)
        self._last_cmd = cmd
        return cmd, events
