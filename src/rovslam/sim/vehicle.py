"""The vehicle: a way-point grid, a way-point follower in a drifting current, altitude and attitude, sensors.

Model (world frame, metres, seconds). The ROV controls its velocity through the water
``w`` with an acceleration limit; over the ground it moves at ``w + c`` where ``c`` is a
slowly varying current (a mean plus an Ornstein-Uhlenbeck wander). The guidance asks for
a ground velocity along the current leg (cruise speed, slowing down before the way-point
so it can stop with the acceleration limit) plus a cross-track correction; it compensates
the current with a lagged estimate of it, so a change of current pushes the vehicle
sideways until the cross-track term brings it back. Heading is held constant, or turns
(rate-limited) to face each long leg. Altitude is a set point with slow swings and
control noise; roll and pitch are small random motions.

Waves and the tether (all off by default): an irregular swell (three sinusoids around
``wave_period_s`` with random phases) adds surge and sway velocity, yaw and heave that the
controller does not anticipate; the tether adds random velocity jerks (an
Ornstein-Uhlenbeck process with a short correlation time).

Sensors: a compass (true heading + noise + bias + slow drift), a sonar altimeter (true
altitude + noise), an attitude sensor (true roll / pitch + small noise + slow drift). Every random draw comes from
generators seeded by the seed and a fixed stream number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.signal import lfilter

from rovslam.errors import SimulationError

_STREAM_TRAJECTORY = 11
_STREAM_SENSORS = 12


@dataclass(frozen=True)
class GridPattern:
    """A two-dimensional way-point grid, flown again and again with shifted offsets.

    Repetition ``r`` flies lanes along x (north) when ``r`` is even and along y (east) when
    odd (a cross-hatch; only along x if ``cross_hatch`` is False), boustrophedon, over
    ``[-half_x, half_x] x [-half_y, half_y]`` shifted by ``offsets_m[r % len(offsets_m)]``,
    starting from the corner nearest to where the previous pass ended.
    """

    half_size_m: tuple[float, float] = (0.35, 0.35)
    lane_spacing_m: float = 0.175
    cross_hatch: bool = True
    offsets_m: tuple[tuple[float, float], ...] = (
        (0.0, 0.0),
        (0.0, 0.0),
        (0.0875, 0.0875),
        (0.0875, 0.0875),
        (-0.04375, 0.04375),
        (-0.04375, 0.04375),
        (0.04375, -0.0875),
        (0.04375, -0.0875),
    )

    def __post_init__(self) -> None:
        if min(self.half_size_m) <= 0 or self.lane_spacing_m <= 0:
            raise SimulationError(
                f"GridPattern needs positive half_size_m and lane_spacing_m, got {self.half_size_m}, "
                f"{self.lane_spacing_m}"
            )
        if not self.offsets_m:
            raise SimulationError("GridPattern.offsets_m needs at least one (x, y) offset")

    def repetition(self, r: int, start_near: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Way-points of repetition ``r``: ``(K, 2)`` world (x, y) metres.

        Of the four ways to fly the lanes (which end first, which way the first lane goes),
        the one starting closest to ``start_near`` (where the previous pass ended) is taken.
        """
        hx, hy = self.half_size_m
        along_x = (r % 2 == 0) or not self.cross_hatch
        h_lane, h_cross = (hx, hy) if along_x else (hy, hx)
        n_lanes = int(math.floor(2.0 * h_cross / self.lane_spacing_m + 1e-9)) + 1
        offset = np.asarray(self.offsets_m[r % len(self.offsets_m)], dtype=np.float64)
        best = None
        for cross in (
            -h_cross + self.lane_spacing_m * np.arange(n_lanes),
            h_cross - self.lane_spacing_m * np.arange(n_lanes),
        ):
            for first in (-h_lane, h_lane):
                pts = []
                for k, c in enumerate(cross):
                    a = first if k % 2 == 0 else -first
                    pts += [(a, c), (-a, c)]
                wp = np.array(pts, dtype=np.float64)
                wp = (wp if along_x else wp[:, ::-1]) + offset
                d = float(np.hypot(*(wp[0] - start_near)))
                if best is None or d < best[0] - 1e-12:
                    best = (d, wp)
        return best[1]  # type: ignore[index]


@dataclass(frozen=True)
class VehicleParams:
    """Way-point following, current, altitude and attitude of the ROV."""

    cruise_speed_mps: float = 0.12
    min_speed_mps: float = 0.008  # speed kept when arriving at a way-point
    accel_limit_mps2: float = 0.03
    waypoint_tolerance_m: float = 0.02
    cross_track_gain_per_s: float = 0.5
    heading_mode: str = "constant"  # "constant" | "legs": turn to face every leg >= turn_min_leg_m
    heading_rad: float = 0.0  # held heading ("constant"); offset added to the leg direction ("legs")
    turn_min_leg_m: float = 0.3
    yaw_rate_limit_radps: float = 0.25
    yaw_gain_per_s: float = 0.8
    heading_wander_rad: float = 0.0015  # heading-control error, OU standard deviation
    heading_wander_tau_s: float = 20.0
    current_mean_mps: float = 0.008
    current_wander_mps: float = 0.005  # OU standard deviation of each current component
    current_tau_s: float = 150.0
    current_estimate_tau_s: float = 40.0  # lag of the controller's current compensation
    altitude_m: float = 1.31
    altitude_noise_m: float = 0.006  # control noise, OU standard deviation
    altitude_noise_tau_s: float = 6.0
    altitude_swing_m: float = 0.0  # amplitude of slow altitude swings
    altitude_swing_period_s: float = 55.0
    attitude_sigma_rad: float = 0.0  # roll and pitch, OU standard deviation
    attitude_tau_s: float = 3.0
    substeps: int = 4  # control steps per frame
    wave_period_s: float = 7.0  # dominant period of the swell
    wave_surge_mps: float = 0.0  # amplitude of the swell's surge velocity
    wave_sway_mps: float = 0.0
    wave_yaw_rad: float = 0.0  # amplitude of the yaw oscillation
    wave_heave_m: float = 0.0  # amplitude of the altitude oscillation
    tether_jerk_mps: float = 0.0  # OU standard deviation of the tether's pull (each horizontal component)
    tether_tau_s: float = 2.5

    def __post_init__(self) -> None:
        if self.heading_mode not in ("constant", "legs"):
            raise SimulationError(f"VehicleParams.heading_mode must be 'constant' or 'legs', got {self.heading_mode!r}")
        for name in (
            "cruise_speed_mps",
            "accel_limit_mps2",
            "waypoint_tolerance_m",
            "altitude_m",
            "yaw_rate_limit_radps",
            "current_tau_s",
            "current_estimate_tau_s",
            "altitude_noise_tau_s",
            "attitude_tau_s",
            "heading_wander_tau_s",
            "altitude_swing_period_s",
            "wave_period_s",
            "tether_tau_s",
        ):
            if not (getattr(self, name) > 0):
                raise SimulationError(f"VehicleParams.{name} must be > 0, got {getattr(self, name)}")
        for name in ("wave_surge_mps", "wave_sway_mps", "wave_yaw_rad", "wave_heave_m", "tether_jerk_mps"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise SimulationError(f"VehicleParams.{name} must be a finite number >= 0, got {getattr(self, name)}")
        if self.altitude_swing_m + 1.5 * self.wave_heave_m + 4 * self.altitude_noise_m >= self.altitude_m - 0.2:
            raise SimulationError(
                f"VehicleParams: altitude swings ({self.altitude_swing_m} m), heave and noise would reach the seabed "
                f"from {self.altitude_m} m; lower them"
            )

    @property
    def has_waves(self) -> bool:
        """Whether the swell or the tether move the vehicle."""
        return self.wave_surge_mps > 0 or self.wave_sway_mps > 0 or self.wave_yaw_rad > 0 or self.tether_jerk_mps > 0
        if self.substeps < 1:
            raise SimulationError(f"VehicleParams.substeps must be >= 1, got {self.substeps}")


@dataclass(frozen=True)
class NavSensorParams:
    """Navigation sensors written to frames.csv.

    Each error is white noise plus a slowly varying part (Ornstein-Uhlenbeck: standard
    deviation ``*_drift_rad``, correlation time ``*_drift_tau_s``): a compass is disturbed by
    the vehicle's own magnetic field, an AHRS's tilt drifts with its filter; their output
    at 5 Hz is smooth, so the white part is small.
    """

    compass_sigma_rad: float = float(np.deg2rad(0.3))  # white
    compass_bias_rad: float = 0.0  # constant
    compass_drift_rad: float = float(np.deg2rad(0.3))
    compass_drift_tau_s: float = 120.0
    sonar: bool = True  # write sonar_altitude_m (else the column is empty)
    sonar_sigma_m: float = 0.025
    sonar_offset_m: float = 0.0  # constant (a calibration error: rovslam.sim.calibration)
    sonar_beam_half_angle_rad: float = float(np.deg2rad(3.0))  # over relief: the first echo within this cone
    attitude_sigma_rad: float = float(np.deg2rad(0.01))  # AHRS roll / pitch, white
    attitude_drift_rad: float = float(np.deg2rad(0.1))
    attitude_drift_tau_s: float = 60.0

    def __post_init__(self) -> None:
        for name in (
            "compass_sigma_rad",
            "compass_drift_rad",
            "sonar_sigma_m",
            "attitude_sigma_rad",
            "attitude_drift_rad",
        ):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise SimulationError(f"NavSensorParams.{name} must be a finite number >= 0, got {getattr(self, name)}")
        for name in ("compass_bias_rad", "sonar_offset_m"):
            if not np.isfinite(getattr(self, name)):
                raise SimulationError(f"NavSensorParams.{name} must be a finite number, got {getattr(self, name)}")
        if not (self.compass_drift_tau_s > 0 and self.attitude_drift_tau_s > 0):
            raise SimulationError("NavSensorParams drift correlation times must be > 0 s")


@dataclass(frozen=True)
class Trajectory:
    """True vehicle state at each frame, ``(N,)`` float64 arrays (world frame, level-frame speeds)."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    altitude_m: np.ndarray
    heading_rad: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    surge_mps: np.ndarray  # ground velocity along the heading
    sway_mps: np.ndarray  # ground velocity to starboard

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def path_length_m(self) -> float:
        return float(np.sum(np.hypot(np.diff(self.x_m), np.diff(self.y_m))))


@dataclass(frozen=True)
class NavReadings:
    """Sensor readings at each frame: ``(N,)`` arrays; ``sonar_altitude_m`` None without a sonar."""

    heading_rad: np.ndarray
    sonar_altitude_m: np.ndarray | None
    roll_rad: np.ndarray
    pitch_rad: np.ndarray


def ou_process(rng: np.random.Generator, n: int, dt_s: float, tau_s: float, sigma: float) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck samples ``(n,)``: correlation time ``tau_s``, standard deviation ``sigma``."""
    if sigma == 0 or n == 0:
        return np.zeros(n)
    phi = math.exp(-dt_s / tau_s)
    w = rng.standard_normal(n)
    w[0] /= math.sqrt(1.0 - phi * phi)  # start in the stationary distribution
    return lfilter([sigma * math.sqrt(1.0 - phi * phi)], [1.0, -phi], w)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def swell(rng: np.random.Generator, t_s: np.ndarray, period_s: float) -> np.ndarray:
    """An irregular unit swell at times ``t_s``: three sinusoids at 0.8, 1 and 1.3 x ``period_s``, random phases.

    Amplitudes 0.35, 1, 0.5 (the dominant one has amplitude 1).
    """
    out = np.zeros(len(t_s))
    for scale, amp in ((0.8, 0.35), (1.0, 1.0), (1.3, 0.5)):
        out += amp * np.sin(2.0 * np.pi * t_s / (scale * period_s) + rng.uniform(0.0, 2.0 * np.pi))
    return out


def simulate_trajectory(
    vehicle: VehicleParams, grid: GridPattern, n_frames: int, frame_rate_hz: float, seed: int
) -> Trajectory:
    """Fly the grid from (0, 0) for ``n_frames`` frames; the first frame is at the origin, t = 0."""
    if n_frames < 1:
        raise SimulationError(f"n_frames must be >= 1, got {n_frames}")
    if not frame_rate_hz > 0:
        raise SimulationError(f"frame_rate_hz must be > 0, got {frame_rate_hz}")
    v = vehicle
    dt_frame = 1.0 / frame_rate_hz
    dt = dt_frame / v.substeps
    n_steps = (n_frames - 1) * v.substeps + 1
    dist = _disturbances(v, seed, n_steps, dt)
    out = _fly_grid(v, grid, n_frames, dt, dist)
    t = np.arange(n_frames) * dt_frame
    alt, roll, pitch = _altitude_and_attitude(v, seed, t, dt_frame)
    return Trajectory(
        t_s=t,
        x_m=out[:, 0],
        y_m=out[:, 1],
        altitude_m=alt,
        heading_rad=out[:, 2],
        roll_rad=roll,
        pitch_rad=pitch,
        surge_mps=out[:, 3],
        sway_mps=out[:, 4],
    )


def _trajectory_rng(seed: int, process: int) -> np.random.Generator:
    """The generator of one random process of the trajectory: a longer run starts with the same frames."""
    return np.random.default_rng([seed, _STREAM_TRAJECTORY, process])


@dataclass(frozen=True)
class _Disturbances:
    """What pushes the vehicle, per control step: ``(n_steps,)`` arrays (the waves None without them)."""

    current_x_mps: np.ndarray  # the current over the ground, world north
    current_y_mps: np.ndarray  # east
    wander_rad: np.ndarray  # the heading's control wander (plus the swell's yaw)
    wave_u_mps: np.ndarray | None  # swell and tether, body-frame surge
    wave_v_mps: np.ndarray | None  # sway


def _disturbances(v: VehicleParams, seed: int, n_steps: int, dt: float) -> _Disturbances:
    """The current, the heading wander and (with ``v.has_waves``) the swell and the tether, per control step."""
    rng = partial(_trajectory_rng, seed)
    cur_dir = rng(0).uniform(0.0, 2.0 * math.pi)
    cur_x = v.current_mean_mps * math.cos(cur_dir) + ou_process(
        rng(1), n_steps, dt, v.current_tau_s, v.current_wander_mps
    )
    cur_y = v.current_mean_mps * math.sin(cur_dir) + ou_process(
        rng(2), n_steps, dt, v.current_tau_s, v.current_wander_mps
    )
    wander = ou_process(rng(3), n_steps, dt, v.heading_wander_tau_s, v.heading_wander_rad)
    wave_u = wave_v = None
    if v.has_waves:  # swell and tether, body-frame velocity (surge, sway) and yaw per control step
        t_steps = np.arange(n_steps) * dt
        wave_u = v.wave_surge_mps * swell(rng(8), t_steps, v.wave_period_s) + ou_process(
            rng(11), n_steps, dt, v.tether_tau_s, v.tether_jerk_mps
        )
        wave_v = v.wave_sway_mps * swell(rng(9), t_steps, v.wave_period_s) + ou_process(
            rng(12), n_steps, dt, v.tether_tau_s, v.tether_jerk_mps
        )
        wander = wander + v.wave_yaw_rad * swell(rng(10), t_steps, v.wave_period_s)
    return _Disturbances(cur_x, cur_y, wander, wave_u, wave_v)


def _leg(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> tuple[float, float, float, float]:
    """``(ex, ey, length, remaining)``: the unit direction of the leg a -> b, its length, and how far
    along it the way-point b still is from the position p (negative once passed)."""
    ex, ey = bx - ax, by - ay
    leg = math.hypot(ex, ey)
    ex, ey = (ex / leg, ey / leg) if leg > 1e-9 else (0.0, 0.0)
    return ex, ey, leg, (bx - px) * ex + (by - py) * ey


def _fly_grid(v: VehicleParams, grid: GridPattern, n_frames: int, dt: float, dist: _Disturbances) -> np.ndarray:
    """``(n_frames, 6)``: (x, y, heading, surge, sway, 0) at every frame, from the way-point follower.

    Every control step: the next leg when the way-point is reached, the rate-limited heading,
    the guidance (along-track speed profile and cross-track correction over the ground), the
    accel-limited thrust against the estimated current, and the motion over the ground.
    """
    sub = v.substeps
    cur_x, cur_y, wander = dist.current_x_mps, dist.current_y_mps, dist.wander_rad
    wave_u, wave_v = dist.wave_u_mps, dist.wave_v_mps
    reps = 0
    waypoints = grid.repetition(0)
    wp_i = 0
    ax, ay = 0.0, 0.0  # start of the current leg
    bx, by = float(waypoints[0, 0]), float(waypoints[0, 1])
    px, py, wx, wy = 0.0, 0.0, 0.0, 0.0
    chx, chy = float(cur_x[0]), float(cur_y[0])  # controller's current estimate
    psi_cmd = v.heading_rad
    if v.heading_mode == "legs" and math.hypot(bx, by) >= v.turn_min_leg_m:
        psi_cmd = _wrap(math.atan2(by, bx) + v.heading_rad)
    psi = psi_cmd
    a_step = v.accel_limit_mps2 * dt
    out = np.empty((n_frames, 6))
    n_steps = (n_frames - 1) * sub + 1
    for i in range(n_steps):
        # Advance to the next leg when the way-point is reached (or passed).
        ex, ey, leg, remaining = _leg(ax, ay, bx, by, px, py)
        if math.hypot(bx - px, by - py) < v.waypoint_tolerance_m or remaining < 0.0:
            ax, ay = bx, by
            wp_i += 1
            if wp_i == len(waypoints):
                reps += 1
                waypoints, wp_i = grid.repetition(reps, start_near=(ax, ay)), 0
            bx, by = float(waypoints[wp_i, 0]), float(waypoints[wp_i, 1])
            ex, ey, leg, remaining = _leg(ax, ay, bx, by, px, py)
            if v.heading_mode == "legs" and leg >= v.turn_min_leg_m:
                psi_cmd = math.atan2(ey, ex) + v.heading_rad
        # Heading: rate-limited turn towards the command, plus the control wander.
        err = _wrap(psi_cmd - psi)
        psi = _wrap(psi + max(-v.yaw_rate_limit_radps, min(v.yaw_rate_limit_radps, v.yaw_gain_per_s * err)) * dt)
        psi_true = _wrap(psi + float(wander[i]))
        aligned = abs(err) < 0.05
        # Guidance: along-track speed profile + cross-track correction, over the ground.
        # (braking at half the limit, to arrive within the tolerance at about min_speed_mps)
        brake = math.sqrt(v.accel_limit_mps2 * max(remaining - 0.5 * v.waypoint_tolerance_m, 0.0))
        along = min(v.cruise_speed_mps, brake + v.min_speed_mps) if aligned else 0.0
        rx, ry = px - ax, py - ay
        s = rx * ex + ry * ey
        ctx, cty = rx - s * ex, ry - s * ey
        gx = along * ex - v.cross_track_gain_per_s * ctx
        gy = along * ey - v.cross_track_gain_per_s * cty
        # Thrust: water-relative velocity towards (guidance - estimated current), accel-limited.
        dwx, dwy = gx - chx - wx, gy - chy - wy
        dn = math.hypot(dwx, dwy)
        if dn > a_step:
            dwx, dwy = dwx * a_step / dn, dwy * a_step / dn
        wx, wy = wx + dwx, wy + dwy
        cx, cy = float(cur_x[i]), float(cur_y[i])
        vx, vy = wx + cx, wy + cy
        if v.has_waves:
            cw, sw = math.cos(psi_true), math.sin(psi_true)
            vx += cw * float(wave_u[i]) - sw * float(wave_v[i])  # type: ignore[index]
            vy += sw * float(wave_u[i]) + cw * float(wave_v[i])  # type: ignore[index]
        if i % sub == 0:
            k = i // sub
            c, sn = math.cos(psi_true), math.sin(psi_true)
            out[k] = (px, py, psi_true, c * vx + sn * vy, -sn * vx + c * vy, 0.0)
        px, py = px + vx * dt, py + vy * dt
        chx += (cx - chx) * dt / v.current_estimate_tau_s
        chy += (cy - chy) * dt / v.current_estimate_tau_s
    return out


def _altitude_and_attitude(
    v: VehicleParams, seed: int, t: np.ndarray, dt_frame: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(altitude, roll, pitch)`` at the frame times ``t`` ``(N,)``: set point, slow swing, control noise, heave."""
    n_frames = len(t)
    rng = partial(_trajectory_rng, seed)
    alt = (
        v.altitude_m
        + v.altitude_swing_m * np.sin(2.0 * np.pi * t / v.altitude_swing_period_s + rng(4).uniform(0, 2 * np.pi))
        + ou_process(rng(5), n_frames, dt_frame, v.altitude_noise_tau_s, v.altitude_noise_m)
    )
    if v.wave_heave_m > 0:
        alt = alt + v.wave_heave_m * swell(rng(13), t, v.wave_period_s)
    roll = ou_process(rng(6), n_frames, dt_frame, v.attitude_tau_s, v.attitude_sigma_rad)
    pitch = ou_process(rng(7), n_frames, dt_frame, v.attitude_tau_s, v.attitude_sigma_rad)
    return alt, roll, pitch


def read_sensors(
    traj: Trajectory, params: NavSensorParams, seed: int, sonar_range_m: np.ndarray | None = None
) -> NavReadings:
    """Compass, sonar and attitude readings for a trajectory (noise from the seed's sensor streams).

    ``sonar_range_m`` (N,) is what the altimeter sees over a relief (see
    :func:`rovslam.sim.relief.sonar_first_return_m`); None: the altitude above the flat seabed.
    """
    n = len(traj)
    dt = float(traj.t_s[1] - traj.t_s[0]) if n > 1 else 1.0

    def rng(sensor: int) -> np.random.Generator:
        # One generator per error process, so a longer run starts with the same readings.
        return np.random.default_rng([seed, _STREAM_SENSORS, sensor])

    p = params
    heading = (
        traj.heading_rad
        + p.compass_bias_rad
        + p.compass_sigma_rad * rng(0).standard_normal(n)
        + ou_process(rng(4), n, dt, p.compass_drift_tau_s, p.compass_drift_rad)
    )
    heading = (heading + np.pi) % (2.0 * np.pi) - np.pi
    true_range = traj.altitude_m if sonar_range_m is None else np.asarray(sonar_range_m, dtype=np.float64)
    if p.sonar_offset_m != 0.0:  # (only then: the presets' readings stay bit for bit)
        true_range = true_range + p.sonar_offset_m
    sonar = np.round(true_range + p.sonar_sigma_m * rng(1).standard_normal(n), 3) if p.sonar else None
    roll = (
        traj.roll_rad
        + p.attitude_sigma_rad * rng(2).standard_normal(n)
        + ou_process(rng(5), n, dt, p.attitude_drift_tau_s, p.attitude_drift_rad)
    )
    pitch = (
        traj.pitch_rad
        + p.attitude_sigma_rad * rng(3).standard_normal(n)
        + ou_process(rng(6), n, dt, p.attitude_drift_tau_s, p.attitude_drift_rad)
    )
    return NavReadings(heading, sonar, roll, pitch)
