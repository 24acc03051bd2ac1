"""A simple ROV for the closed loop: first-order surge, sway and yaw response, a current, altitude control.

Model (world frame x north, y east; body frame x forward, y starboard; seconds, metres):

* the velocity through the water in the body frame ``w = [u, v]`` follows the commanded one
  with time constants ``surge_tau_s``, ``sway_tau_s`` (thrusters and added mass), limited
  to ``max_speed_mps``; the yaw rate follows its command with ``yaw_tau_s``;
* over the ground the vehicle moves at ``R(psi) w + c``, ``c`` a current: a mean (its
  direction drawn from the seed) plus an Ornstein-Uhlenbeck wander per component;
* the heading integrates the yaw rate plus a small random yaw disturbance;
* the altitude controller holds ``altitude_m`` above the mean seabed with a first-order
  response and a residual Ornstein-Uhlenbeck error; roll and pitch are small random motions.

:func:`step_vehicle` is the pure step; :class:`SimulatedVehicle` holds the random processes.
Nothing here is seen by the controller: it gets only what the pipeline estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rovslam.camera import rot2
from rovslam.errors import InvalidArgumentError

__all__ = ["Command", "DynamicsParams", "SimulatedVehicle", "VehicleState", "step_vehicle"]

_STREAM_DYNAMICS = 21


@dataclass(frozen=True)
class Command:
    """What the controller asks: body-frame velocity through the water and a yaw rate."""

    surge_mps: float = 0.0
    sway_mps: float = 0.0
    yaw_rate_radps: float = 0.0


@dataclass(frozen=True)
class DynamicsParams:
    """Response, limits and disturbances of the simulated vehicle."""

    surge_tau_s: float = 1.0
    sway_tau_s: float = 1.5
    yaw_tau_s: float = 0.7
    max_speed_mps: float = 0.3  # through the water, each body axis
    max_yaw_rate_radps: float = 0.4
    current_mean_mps: float = 0.008
    current_wander_mps: float = 0.005  # OU standard deviation of each component
    current_tau_s: float = 150.0
    yaw_disturbance_rad: float = 0.0015  # OU standard deviation of a heading error the vehicle does not control
    yaw_disturbance_tau_s: float = 20.0
    altitude_m: float = 1.31  # altitude set point above the mean seabed
    altitude_tau_s: float = 4.0
    altitude_noise_m: float = 0.006  # residual error of the altitude control (OU standard deviation)
    altitude_noise_tau_s: float = 6.0
    attitude_sigma_rad: float = 0.0  # roll and pitch (OU standard deviation)
    attitude_tau_s: float = 3.0
    substeps: int = 4  # integration steps per frame

    def __post_init__(self) -> None:
        for name in (
            "surge_tau_s",
            "sway_tau_s",
            "yaw_tau_s",
            "max_speed_mps",
            "max_yaw_rate_radps",
            "current_tau_s",
            "yaw_disturbance_tau_s",
            "altitude_m",
            "altitude_tau_s",
            "altitude_noise_tau_s",
            "attitude_tau_s",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidArgumentError(f"DynamicsParams.{name} must be a finite number > 0, got {v!r}")
        for name in (
            "current_mean_mps",
            "current_wander_mps",
            "yaw_disturbance_rad",
            "altitude_noise_m",
            "attitude_sigma_rad",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidArgumentError(f"DynamicsParams.{name} must be a finite number >= 0, got {v!r}")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise InvalidArgumentError(f"DynamicsParams.substeps must be a whole number >= 1, got {self.substeps!r}")

    @classmethod
    def from_vehicle(cls, vehicle) -> DynamicsParams:
        """The disturbances of a simulator preset's :class:`~rovslam.sim.vehicle.VehicleParams` (same current, noise)."""
        return cls(
            current_mean_mps=vehicle.current_mean_mps,
            current_wander_mps=vehicle.current_wander_mps,
            current_tau_s=vehicle.current_tau_s,
            yaw_disturbance_rad=vehicle.heading_wander_rad,
            yaw_disturbance_tau_s=vehicle.heading_wander_tau_s,
            altitude_m=vehicle.altitude_m,
            altitude_noise_m=vehicle.altitude_noise_m,
            altitude_noise_tau_s=vehicle.altitude_noise_tau_s,
            attitude_sigma_rad=vehicle.attitude_sigma_rad,
            attitude_tau_s=vehicle.attitude_tau_s,
        )


@dataclass(frozen=True)
class VehicleState:
    """The true state (the simulator's; never shown to the controller)."""

    t_s: float
    x_m: float
    y_m: float
    heading_rad: float  # controlled heading (the disturbance is added to give the true one)
    u_water_mps: float = 0.0
    v_water_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    altitude_m: float = 1.31

    def ground_velocity_mps(self, current_mps: np.ndarray) -> np.ndarray:
        """(2,) world velocity over the ground in a current ``current_mps`` (2,)."""
        return rot2(self.heading_rad) @ np.array([self.u_water_mps, self.v_water_mps]) + current_mps


def _first_order(value: float, target: float, tau_s: float, dt_s: float) -> float:
    """Exact step of ``dx/dt = (target - x) / tau`` over ``dt_s`` with ``target`` held."""
    return target + (value - target) * math.exp(-dt_s / tau_s)


def _clip(v: float, limit: float) -> float:
    return max(-limit, min(limit, v))


def step_vehicle(
    state: VehicleState,
    command: Command,
    current_mps: np.ndarray,
    altitude_target_m: float,
    dt_s: float,
    params: DynamicsParams,
) -> VehicleState:
    """One integration step of the model over ``dt_s``: the command saturated, the responses, the current."""
    p = params
    u = _first_order(state.u_water_mps, _clip(command.surge_mps, p.max_speed_mps), p.surge_tau_s, dt_s)
    v = _first_order(state.v_water_mps, _clip(command.sway_mps, p.max_speed_mps), p.sway_tau_s, dt_s)
    r = _first_order(state.yaw_rate_radps, _clip(command.yaw_rate_radps, p.max_yaw_rate_radps), p.yaw_tau_s, dt_s)
    # Trapezoidal position step with the mean water velocity and heading over the step.
    psi_mid = state.heading_rad + 0.5 * (state.yaw_rate_radps + r) * 0.5 * dt_s
    w_mid = 0.5 * np.array([state.u_water_mps + u, state.v_water_mps + v])
    vel = rot2(psi_mid) @ w_mid + np.asarray(current_mps, dtype=np.float64)
    psi = state.heading_rad + 0.5 * (state.yaw_rate_radps + r) * dt_s
    return VehicleState(
        t_s=state.t_s + dt_s,
        x_m=state.x_m + float(vel[0]) * dt_s,
        y_m=state.y_m + float(vel[1]) * dt_s,
        heading_rad=(psi + math.pi) % (2.0 * math.pi) - math.pi,
        u_water_mps=u,
        v_water_mps=v,
        yaw_rate_radps=r,
        altitude_m=_first_order(state.altitude_m, altitude_target_m, p.altitude_tau_s, dt_s),
    )


class _OU:
    def __init__(self, rng: np.random.Generator, sigma: float, tau_s: float) -> None:
        self.rng, self.sigma, self.tau_s = rng, sigma, tau_s
        self.value = sigma * float(rng.standard_normal()) if sigma > 0 else 0.0

    def step(self, dt_s: float) -> float:
        if self.sigma > 0:
            phi = math.exp(-dt_s / self.tau_s)
            self.value = phi * self.value + self.sigma * math.sqrt(1 - phi * phi) * float(self.rng.standard_normal())
        return self.value


class SimulatedVehicle:
    """The simulated ROV: :func:`step_vehicle` with the current, yaw, altitude and attitude disturbances.

    Starts at rest at the origin at ``heading_rad``, at the altitude set point.
    :meth:`advance` applies a command for one frame period and returns the new state;
    :meth:`true_state` gives what the renderer needs (true heading, ground speeds, attitude).
    """

    def __init__(self, params: DynamicsParams, seed: int, heading_rad: float = 0.0) -> None:
        def rng(k: int) -> np.random.Generator:
            return np.random.default_rng([int(seed), _STREAM_DYNAMICS, k])

        self.params = p = params
        direction = rng(0).uniform(0.0, 2.0 * math.pi)
        self._current_mean = p.current_mean_mps * np.array([math.cos(direction), math.sin(direction)])
        self._cx, self._cy = (
            _OU(rng(1), p.current_wander_mps, p.current_tau_s),
            _OU(rng(2), p.current_wander_mps, p.current_tau_s),
        )
        self._yaw = _OU(rng(3), p.yaw_disturbance_rad, p.yaw_disturbance_tau_s)
        self._alt = _OU(rng(4), p.altitude_noise_m, p.altitude_noise_tau_s)
        self._roll, self._pitch = (
            _OU(rng(5), p.attitude_sigma_rad, p.attitude_tau_s),
            _OU(rng(6), p.attitude_sigma_rad, p.attitude_tau_s),
        )
        self.state = VehicleState(0.0, 0.0, 0.0, float(heading_rad), altitude_m=p.altitude_m + self._alt.value)

    @property
    def current_mps(self) -> np.ndarray:
        """(2,) the current now (world frame)."""
        return self._current_mean + np.array([self._cx.value, self._cy.value])

    def advance(self, command: Command, dt_s: float) -> VehicleState:
        """Apply ``command`` for ``dt_s`` (in ``params.substeps`` steps); the new state."""
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise InvalidArgumentError(f"dt_s must be a finite number of seconds > 0, got {dt_s!r}")
        p = self.params
        h = dt_s / p.substeps
        for _ in range(p.substeps):
            self._cx.step(h)
            self._cy.step(h)
            target = p.altitude_m + self._alt.step(h)
            self.state = step_vehicle(self.state, command, self.current_mps, target, h, p)
        self._yaw.step(dt_s)
        self._roll.step(dt_s)
        self._pitch.step(dt_s)
        return self.state

    def true_state(self):
        """The state as the renderer takes it (:class:`rovslam.sim.live.TrueState`): true heading, ground speeds."""
        from rovslam.sim.live import TrueState

        s = self.state
        psi = (s.heading_rad + self._yaw.value + math.pi) % (2.0 * math.pi) - math.pi
        vel = s.ground_velocity_mps(self.current_mps)
        body = rot2(psi).T @ vel
        return TrueState(
            t_s=s.t_s,
            x_m=s.x_m,
            y_m=s.y_m,
            altitude_m=s.altitude_m,
            heading_rad=psi,
            roll_rad=self._roll.value,
            pitch_rad=self._pitch.value,
            surge_mps=float(body[0]),
            sway_mps=float(body[1]),
            yaw_rate_radps=s.yaw_rate_radps,
        )
