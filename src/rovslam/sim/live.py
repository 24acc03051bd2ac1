"""A simulated camera and navigation sensors that can be flown anywhere, one frame at a time.

:func:`simulate` writes a whole dive whose path is known in advance. A closed loop (the
vehicle steered by what the pipeline estimates, :mod:`rovslam.nav.closed_loop`) needs the
opposite: the next pose is known only once the last frame has been processed.
:class:`LiveSimulator` renders the frame of any true state of the vehicle and reads its
sensors (compass, sonar over the relief, AHRS) with the preset's noise, as
:class:`rovslam.io.sequence.Frame` records the pipeline consumes directly.

The sensor errors are the ones of :func:`~rovslam.sim.vehicle.read_sensors`, stepped one
reading at a time: white noise plus a constant bias plus a slow Ornstein-Uhlenbeck drift
(compass), white plus drift (roll, pitch), white (sonar, on the first echo under its beam).
Every random draw comes from generators keyed by the seed (streams of their own), so a
seed and the same sequence of states give the same frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from rovslam.core import Frame, SequenceInfo
from rovslam.errors import SimulationError
from rovslam.sim.relief import ReliefParams
from rovslam.sim.render import Pose, renderer_for
from rovslam.sim.scenarios import SCENARIOS, Scenario, build_world, frame_rng
from rovslam.sim.vehicle import NavSensorParams

__all__ = ["LiveSensors", "LiveSimulator", "TrueState"]

_STREAM_LIVE_SENSORS = 14


@dataclass(frozen=True)
class TrueState:
    """The true state of the vehicle at a frame (world frame; ground speeds in the level body frame)."""

    t_s: float
    x_m: float
    y_m: float
    altitude_m: float  # above the mean seabed plane
    heading_rad: float
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    surge_mps: float = 0.0  # ground velocity along the heading
    sway_mps: float = 0.0  # ground velocity to starboard
    yaw_rate_radps: float = 0.0

    @property
    def pose(self) -> Pose:
        return Pose(self.x_m, self.y_m, self.altitude_m, self.heading_rad, self.roll_rad, self.pitch_rad)


class _OrnsteinUhlenbeck:
    """One stationary OU process stepped sample by sample (standard deviation ``sigma``, time ``tau_s``)."""

    def __init__(self, rng: np.random.Generator, sigma: float, tau_s: float) -> None:
        self.rng, self.sigma, self.tau_s = rng, float(sigma), float(tau_s)
        self.value = self.sigma * float(rng.standard_normal()) if self.sigma > 0 else 0.0

    def step(self, dt_s: float) -> float:
        if self.sigma > 0 and dt_s > 0:
            phi = math.exp(-dt_s / self.tau_s)
            self.value = phi * self.value + self.sigma * math.sqrt(1.0 - phi * phi) * float(self.rng.standard_normal())
        return self.value


class LiveSensors:
    """Compass, sonar and AHRS readings of :class:`~rovslam.sim.vehicle.NavSensorParams`, one reading at a time."""

    def __init__(self, params: NavSensorParams, seed: int) -> None:
        def rng(sensor: int) -> np.random.Generator:
            return np.random.default_rng([int(seed), _STREAM_LIVE_SENSORS, sensor])

        p = self.params = params
        self._white = rng(0)
        self._compass_drift = _OrnsteinUhlenbeck(rng(1), p.compass_drift_rad, p.compass_drift_tau_s)
        self._roll_drift = _OrnsteinUhlenbeck(rng(2), p.attitude_drift_rad, p.attitude_drift_tau_s)
        self._pitch_drift = _OrnsteinUhlenbeck(rng(3), p.attitude_drift_rad, p.attitude_drift_tau_s)
        self._t_s: float | None = None

    def read(self, state: TrueState, sonar_range_m: float) -> tuple[float, float | None, float, float]:
        """(compass heading, sonar altitude or None, roll, pitch) readings at ``state`` (radians, metres)."""
        p = self.params
        dt = 0.0 if self._t_s is None else state.t_s - self._t_s
        self._t_s = state.t_s
        w = self._white.standard_normal(4)
        heading = state.heading_rad + p.compass_bias_rad + p.compass_sigma_rad * w[0] + self._compass_drift.step(dt)
        heading = (heading + math.pi) % (2.0 * math.pi) - math.pi
        sonar = round(sonar_range_m + p.sonar_sigma_m * float(w[1]), 3) if p.sonar else None
        roll = state.roll_rad + p.attitude_sigma_rad * w[2] + self._roll_drift.step(dt)
        pitch = state.pitch_rad + p.attitude_sigma_rad * w[3] + self._pitch_drift.step(dt)
        return float(heading), sonar, float(roll), float(pitch)


def _caching(sc: Scenario, area_m: tuple[float, float, float, float] | None) -> Scenario:
    """``sc`` with chunk caches that hold the whole ``area_m`` (a cache only: the seabed is the same texel for texel)."""
    if area_m is None:
        return sc
    span_m = max(area_m[1] - area_m[0], area_m[3] - area_m[2])

    def chunks(params) -> int:
        side = math.ceil(span_m / (params.texel_mm * 1e-3) / params.chunk_texels) + 2
        return max(params.cache_chunks, side * side)

    changes = {"texture": replace(sc.texture, cache_chunks=chunks(sc.texture))}
    if isinstance(sc.relief, ReliefParams):
        changes["relief"] = replace(sc.relief, cache_chunks=chunks(sc.relief))  # type: ignore[assignment]
    return replace(sc, **changes)  # type: ignore[arg-type]


class LiveSimulator:
    """The camera, lasers and navigation sensors of a scenario preset over its seabed, for any true state.

    ``area_m`` (north min, north max, east min, east max): where the vehicle is expected to
    fly (a canvas covering it is built once); None: canvases grow as frames need them.
    """

    def __init__(
        self, scenario: str | Scenario, seed: int = 0, area_m: tuple[float, float, float, float] | None = None
    ) -> None:
        if isinstance(scenario, str):
            if scenario not in SCENARIOS:
                raise SimulationError(f"unknown scenario {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
            scenario = SCENARIOS[scenario]
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise SimulationError(f"seed must be a whole number >= 0, got {seed!r}")
        sc = self.scenario = scenario
        self.seed = int(seed)
        grow_m = 0.25 if area_m is None else max(abs(v) for v in area_m) + 0.05
        self.world, texture_note = build_world(_caching(sc, area_m), self.seed, min(grow_m, 1.5))
        self.world.area_m = area_m
        if area_m is not None:  # one canvas for the whole area (a closed loop wanders: no rebuilds as it goes)
            span_m = max(area_m[1] - area_m[0], area_m[3] - area_m[2])
            self.world.max_canvas_texels = max(self.world.max_canvas_texels, int(span_m / self.world.texel_m) + 512)
        self.renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots, sc.lighting)
        self.sensors = LiveSensors(sc.nav, self.seed)
        self._codec = None
        if sc.h264 is not None:
            from rovslam.sim.codec import H264RoundTrip

            self._codec = H264RoundTrip(sc.camera.width_px, sc.camera.height_px, sc.frame_rate_hz, sc.h264)
        self.info = SequenceInfo(
            name=f"rovslam closed loop {sc.name} (seed {self.seed})",
            camera=sc.recorded_camera,
            lasers=sc.lasers,
            metadata={
                "generator": "rovslam.sim.live",
                "scenario": sc.name,
                "seed": self.seed,
                "frame_rate_hz": float(sc.frame_rate_hz),
                "texture": texture_note,
                "nominal_altitude_m": float(sc.vehicle.altitude_m),
            },
        )

    @property
    def frame_period_s(self) -> float:
        return 1.0 / self.scenario.frame_rate_hz

    def relief_height_m(self, x_m: float, y_m: float) -> float:
        """Height of the seabed above its mean plane at a world point (0 on a flat seabed)."""
        if self.world.relief is None:
            return 0.0
        from rovslam.sim.relief import heights_at

        return float(heights_at(self.world.relief, np.array([x_m]), np.array([y_m]))[0])

    def sonar_range_m(self, state: TrueState) -> float:
        """What the altimeter's first echo sees from ``state`` (the altitude above a flat seabed)."""
        if self.world.relief is None:
            return float(state.altitude_m)
        from rovslam.sim.relief import sonar_first_return_m

        return float(
            sonar_first_return_m(
                self.world.relief,
                np.array([state.x_m]),
                np.array([state.y_m]),
                np.array([state.altitude_m]),
                self.scenario.nav.sonar_beam_half_angle_rad,
            )[0]
        )

    def render(self, k: int, state: TrueState) -> np.ndarray:
        """Frame ``k``'s image seen from ``state``: ``(H, W, 3) uint8`` RGB (motion blur, rolling shutter included)."""
        if self.world.relief is not None and state.altitude_m - self.world.relief.height_range_m[1] < 0.05:
            raise SimulationError(f"frame {k}: the vehicle at altitude {state.altitude_m:.3f} m touches the relief")
        image = self.renderer.render(
            self.world,
            state.pose,
            self.scenario.lasers,
            frame_rng(self.seed, k),
            velocity_mps=(state.surge_mps, state.sway_mps),
            t_s=state.t_s,
            yaw_rate_radps=state.yaw_rate_radps,
        )
        return image if self._codec is None else self._codec.push(image)

    def capture(self, k: int, state: TrueState) -> Frame:
        """Frame ``k`` at ``state``: the image and the sensor readings, as the pipeline reads a sequence's frame."""
        image = self.render(k, state)
        heading, sonar, roll, pitch = self.sensors.read(state, self.sonar_range_m(state))
        tilted = self.scenario.tilted
        return Frame(
            index=k,
            t_s=float(state.t_s),
            image=image,
            heading_rad=heading,
            sonar_altitude_m=sonar,
            roll_rad=roll if tilted else 0.0,
            pitch_rad=pitch if tilted else 0.0,
            has_attitude=tilted,
            source=f"live:{k}",
        )

    def close(self) -> None:
        if self._codec is not None:
            self._codec.close()
            self._codec = None
