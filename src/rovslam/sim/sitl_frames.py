"""What the simulated vehicle sees and reads, frame by frame: a preset flown now, or a dive rendered before.

:func:`preset_frames` flies a scenario preset's survey (the path of :func:`rovslam.sim.simulate`
for the same seed), renders each frame with :class:`~rovslam.sim.live.LiveSimulator` and reads
the navigation sensors as ``rovslam simulate`` does (the same noise for the same seed), so a
sequence written by ``rovslam simulate`` with that seed holds the same truth, readings and
images. :func:`sequence_frames` reads them from such a folder instead (for presets whose
renderer is slower than their camera). Times are on the stream's axis: seconds from the first frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import SimulationError
from rovslam.io.sequence import SequenceInfo

__all__ = ["FrameSource", "SitlFrame", "preset_frames", "sequence_frames"]


@dataclass(frozen=True)
class SitlFrame:
    """One frame of the dive: the image ``(H, W, 3) uint8``, the readings and the truth at ``t_s``."""

    index: int
    t_s: float  # capture time, seconds from the first frame
    image: np.ndarray
    heading_rad: float  # compass reading
    sonar_altitude_m: float | None
    roll_rad: float  # AHRS readings (0 on a level preset, as its frames.csv has none)
    pitch_rad: float
    truth: tuple[float, ...] | None  # (x_m, y_m, altitude_m, heading_rad[, relief_m]) or None


@dataclass(frozen=True)
class FrameSource:
    """A dive to stream: its camera file, frame rate, sonar noise, frame count and frames (an iterator)."""

    info: SequenceInfo
    frame_rate_hz: float
    sonar_sigma_m: float
    n_frames: int
    with_relief: bool
    frames: Iterator[SitlFrame]


def _count(duration_s: float | None, default_s: float, rate_hz: float, available: int) -> int:
    d = default_s if duration_s is None else float(duration_s)
    if not (d >= 0 and math.isfinite(d)):
        raise SimulationError(f"--duration-s must be a number of seconds >= 0, got {duration_s}")
    return max(1, min(available, int(math.floor(d * rate_hz + 1e-9)) + 1))


def preset_frames(scenario: str, seed: int, duration_s: float | None = None) -> FrameSource:
    """The preset ``scenario`` flown for ``duration_s`` (default: its whole dive), seed ``seed``."""
    from rovslam.sim.live import LiveSimulator, TrueState
    from rovslam.sim.scenarios import SCENARIOS, survey_area_m
    from rovslam.sim.vehicle import read_sensors, simulate_trajectory

    if scenario not in SCENARIOS:
        raise SimulationError(f"--scenario: unknown preset {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"--seed must be a whole number >= 0, got {seed!r}")
    sc = SCENARIOS[scenario]
    n = _count(duration_s, sc.duration_s, sc.frame_rate_hz, 10**6)
    traj = simulate_trajectory(sc.vehicle, sc.grid, n, sc.frame_rate_hz, int(seed))
    sim = LiveSimulator(sc, int(seed), area_m=survey_area_m(sc, traj))
    relief = sim.world.relief
    sonar_range = relief_m = None
    if relief is not None:
        from rovslam.sim.relief import heights_at, sonar_first_return_m

        relief_m = heights_at(relief, traj.x_m, traj.y_m)
        sonar_range = sonar_first_return_m(relief, traj.x_m, traj.y_m, traj.altitude_m, sc.nav.sonar_beam_half_angle_rad)
    nav = read_sensors(traj, sc.nav, int(seed), sonar_range_m=sonar_range)
    yaw_rate = (np.gradient(np.unwrap(traj.heading_rad), traj.t_s) if sc.sensor.readout_s > 0 and n > 1
                else np.zeros(n))
    info = SequenceInfo(name=f"rovslam sitl {sc.name} (seed {int(seed)})", camera=sc.recorded_camera, lasers=sc.lasers,
                        metadata={"generator": "rovslam.sim.sitl", "scenario": sc.name, "seed": int(seed),
                                  "frame_rate_hz": float(sc.frame_rate_hz)})

    def frames() -> Iterator[SitlFrame]:
        try:
            for k in range(n):
                state = TrueState(float(traj.t_s[k]), float(traj.x_m[k]), float(traj.y_m[k]), float(traj.altitude_m[k]),
                                  float(traj.heading_rad[k]), float(traj.roll_rad[k]), float(traj.pitch_rad[k]),
                                  float(traj.surge_mps[k]), float(traj.sway_mps[k]), float(yaw_rate[k]))
                truth = (state.x_m, state.y_m, state.altitude_m, state.heading_rad)
                yield SitlFrame(
                    k, state.t_s, sim.render(k, state), float(nav.heading_rad[k]),
                    None if nav.sonar_altitude_m is None else float(nav.sonar_altitude_m[k]),
                    float(nav.roll_rad[k]) if sc.tilted else 0.0, float(nav.pitch_rad[k]) if sc.tilted else 0.0,
                    truth if relief_m is None else truth + (float(relief_m[k]),))
        finally:
            sim.close()

    return FrameSource(info, float(sc.frame_rate_hz), float(sc.nav.sonar_sigma_m), n, relief_m is not None, frames())


def sequence_frames(folder: Path, duration_s: float | None = None) -> FrameSource:
    """The frames of a sequence folder (``rovslam simulate`` writes them) at their own times, with their truth."""
    from rovslam.io.sequence import open_sequence
    from rovslam.sim.scenarios import SCENARIOS

    seq: Any = open_sequence(folder)  # (mypy reads io.sequence.Sequence as typing.Sequence)
    if len(seq) == 0:
        raise SimulationError(f"--from {folder}: the sequence has no frames")
    t = np.array([r.t_s for r in seq.rows])
    rate = seq.info.metadata.get("frame_rate_hz")
    if not isinstance(rate, (int, float)) or not rate > 0:
        rate = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    n = _count(duration_s, float(t[-1] - t[0]), float(rate), len(seq))
    gt = seq.groundtruth
    if gt is not None and len(gt) != len(seq):
        raise SimulationError(f"--from {folder}: groundtruth.csv has {len(gt)} rows for {len(seq)} frames")
    sc = SCENARIOS.get(str(seq.info.metadata.get("scenario", "")))
    sigma = float(sc.nav.sonar_sigma_m) if sc is not None else 0.025

    def frames() -> Iterator[SitlFrame]:
        for f in seq.frames(0, n):
            if f.image is None:
                raise SimulationError(f"--from {folder}: frame {f.index}: {f.error}")
            truth: tuple[float, ...] | None = None
            if gt is not None:
                k = f.index
                truth = (float(gt.x_m[k]), float(gt.y_m[k]), float(gt.altitude_m[k]), float(gt.heading_rad[k]))
                if gt.relief_m is not None:
                    truth += (float(gt.relief_m[k]),)
            yield SitlFrame(f.index, float(f.t_s - t[0]), f.image, float(f.heading_rad), f.sonar_altitude_m,
                            float(f.roll_rad), float(f.pitch_rad), truth)

    with_relief = gt is not None and gt.relief_m is not None
    return FrameSource(seq.info, float(rate), sigma, n, with_relief, frames())
