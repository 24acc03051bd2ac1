"""Scenario presets and :func:`simulate`, which writes a whole sequence folder (format v1).

Presets:

* ``portofino`` - the paper's trial: 360x272 colour images, f = 1075 px (footprint about
  44 cm x 33 cm at 1.31 m), 5 Hz, 13,275 frames (44 min 15 s), constant heading, a
  cross-hatched way-point grid of 0.7 m x 0.7 m with lanes 17.5 cm apart flown at up to
  0.12 m/s (it passes over the start area four times in the first two minutes), four red
  lasers parallel to the optical axis at the corners of a 10 cm square, clear water.
* ``portofino-short`` - its first 600 frames (2 minutes), for tests.
* ``rough-turns`` - the same grid and site, harder: the heading turns to follow each lane
  (rate-limited turns at the grid corners), altitude swings of +-10 cm, roll and pitch of
  about 1 degree (attitude sensor columns written), turbid water with marine snow, a
  noisier compass. ``rough-turns-short``: its first 600 frames.

Determinism: the trajectory, the sensors, the seabed, the marine snow and every frame's
noise come from generators keyed by the seed (and the frame index), so a seed gives
byte-identical images, and a frame does not depend on which frames were rendered before.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from rovslam.camera import Camera, LaserPointer
from rovslam.errors import SimulationError
from rovslam.sim.render import LaserSpotParams, Pose, SensorParams, renderer_for
from rovslam.sim.texture import TextureParams
from rovslam.sim.vehicle import (
    GridPattern,
    NavSensorParams,
    Trajectory,
    VehicleParams,
    read_sensors,
    simulate_trajectory,
)
from rovslam.sim.water import WaterParams
from rovslam.sim.world import World

_STREAM_FRAMES = 13

PORTOFINO_CAMERA = Camera(width_px=360, height_px=272, fx_px=1075.0, fy_px=1075.0, cx_px=179.5, cy_px=135.5)
PAPER_LASERS = tuple(
    LaserPointer((sx * 0.05, sy * 0.05, 0.0)) for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1))
)


@dataclass(frozen=True)
class Scenario:
    """Everything a simulated survey needs besides the seed."""

    name: str
    description: str
    n_frames: int
    frame_rate_hz: float = 5.0
    camera: Camera = PORTOFINO_CAMERA
    lasers: tuple[LaserPointer, ...] = PAPER_LASERS
    texture: TextureParams = field(default_factory=TextureParams)
    water: WaterParams = field(default_factory=WaterParams)
    sensor: SensorParams = field(default_factory=SensorParams)
    spots: LaserSpotParams = field(default_factory=LaserSpotParams)
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    grid: GridPattern = field(default_factory=GridPattern)
    nav: NavSensorParams = field(default_factory=NavSensorParams)

    @property
    def tilted(self) -> bool:
        """Whether the vehicle rolls and pitches (then frames.csv gets roll_rad, pitch_rad)."""
        return self.vehicle.attitude_sigma_rad > 0


_PORTOFINO = Scenario(
    name="portofino",
    description="the paper's Portofino trial: 44 min 15 s grid survey at 1.31 m, constant heading, clear water",
    n_frames=13275,
)
_ROUGH = Scenario(
    name="rough-turns",
    description="harder: heading turns at the grid corners, +-10 cm altitude swings, ~1 deg roll/pitch, "
    "turbid water with marine snow",
    n_frames=13275,
    water=WaterParams.turbid(),
    vehicle=VehicleParams(
        heading_mode="legs",
        altitude_swing_m=0.10,
        altitude_noise_m=0.01,
        attitude_sigma_rad=float(np.deg2rad(1.0)),
        current_mean_mps=0.012,
        current_wander_mps=0.007,
    ),
    nav=NavSensorParams(compass_sigma_rad=float(np.deg2rad(0.5)), compass_drift_rad=float(np.deg2rad(0.5)),
                        sonar_sigma_m=0.03),
)

SCENARIOS: dict[str, Scenario] = {
    "portofino": _PORTOFINO,
    "portofino-short": replace(_PORTOFINO, name="portofino-short", n_frames=600,
                               description="the first 2 minutes (600 frames) of portofino, for tests"),
    "rough-turns": _ROUGH,
    "rough-turns-short": replace(_ROUGH, name="rough-turns-short", n_frames=600,
                                 description="the first 2 minutes (600 frames) of rough-turns, for tests"),
}


@dataclass(frozen=True)
class SimulationSummary:
    """What :func:`simulate` wrote."""

    scenario: str
    out_dir: Path
    frames: int
    seed: int
    image_format: str
    duration_s: float  # simulated time covered
    path_length_m: float
    x_range_m: tuple[float, float]
    y_range_m: tuple[float, float]
    altitude_range_m: tuple[float, float]
    wall_time_s: float


def frame_pose(traj: Trajectory, k: int) -> Pose:
    """The true camera pose of frame ``k``."""
    return Pose(
        float(traj.x_m[k]), float(traj.y_m[k]), float(traj.altitude_m[k]), float(traj.heading_rad[k]),
        float(traj.roll_rad[k]), float(traj.pitch_rad[k]),
    )


def frame_rng(seed: int, k: int) -> np.random.Generator:
    """The generator of frame ``k``'s sensor noise and laser speckle."""
    return np.random.default_rng([seed, _STREAM_FRAMES, k])


def _check_args(scenario, frames, seed, image_format, texture_path, texture_mm_per_px) -> tuple[Scenario, int, str]:
    if not isinstance(scenario, str) or scenario not in SCENARIOS:
        raise SimulationError(f"unknown scenario {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[scenario]
    n = sc.n_frames if frames is None else frames
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise SimulationError(f"frames must be a whole number >= 1, got {frames!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"seed must be a whole number >= 0, got {seed!r}")
    fmt = {"png": "png", "jpg": "jpg", "jpeg": "jpg"}.get(str(image_format).lower())
    if fmt is None:
        raise SimulationError(f"image format must be png or jpg, got {image_format!r}")
    if (texture_path is None) != (texture_mm_per_px is None):
        raise SimulationError("give --texture IMAGE and --texture-mm-per-px S together (the image and its scale)")
    if texture_mm_per_px is not None and not (np.isfinite(texture_mm_per_px) and texture_mm_per_px > 0):
        raise SimulationError(f"texture scale must be a positive number of mm per pixel, got {texture_mm_per_px!r}")
    return sc, int(n), fmt


def simulate(
    scenario: str,
    out_dir: Path,
    frames: int | None = None,
    seed: int = 0,
    image_format: str = "png",
    texture_path: Path | None = None,
    texture_mm_per_px: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SimulationSummary:
    """Simulate scenario ``scenario`` and write the sequence folder ``out_dir`` (format v1).

    ``frames`` overrides the scenario's length (the first ``frames`` frames of the same
    survey). ``texture_path`` / ``texture_mm_per_px`` replace the procedural seabed by an
    image at that scale. ``progress(done, total)`` is called after every frame. Bad
    arguments raise :class:`~rovslam.errors.SimulationError` before anything is written.
    """
    from rovslam.io.sequence import SequenceInfo, SequenceWriter

    t_start = time.perf_counter()
    sc, n, fmt = _check_args(scenario, frames, seed, image_format, texture_path, texture_mm_per_px)
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SimulationError(f"output folder {out} already exists and is not empty; give a new folder")
    traj = simulate_trajectory(sc.vehicle, sc.grid, n, sc.frame_rate_hz, int(seed))
    # Size the first canvas to the whole survey, so it is built once (the path is known).
    grow_m = min(1.0, float(np.max(np.hypot(traj.x_m, traj.y_m)))) + 0.05
    if texture_path is not None:
        world = World.from_image(texture_path, float(texture_mm_per_px), seed=int(seed), grow_m=grow_m)
        texture_note = f"{Path(texture_path).name} at {float(texture_mm_per_px)} mm/px"
    else:
        world = World.procedural(int(seed), sc.texture, grow_m=grow_m)
        texture_note = "procedural"
    nav = read_sensors(traj, sc.nav, int(seed))
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots)
    info = SequenceInfo(
        name=f"rovslam simulate {sc.name} (seed {int(seed)})",
        camera=sc.camera,
        lasers=sc.lasers,
        metadata={
            "generator": "rovslam.sim",
            "scenario": sc.name,
            "seed": int(seed),
            "frames": n,
            "frame_rate_hz": float(sc.frame_rate_hz),
            "texture": texture_note,
            "nominal_altitude_m": float(sc.vehicle.altitude_m),
        },
    )
    tilted = sc.tilted
    with SequenceWriter(out, info, image_format=fmt, with_attitude=tilted, with_groundtruth=True) as writer:
        for k in range(n):
            pose = frame_pose(traj, k)
            image = renderer.render(
                world, pose, sc.lasers, frame_rng(int(seed), k),
                velocity_mps=(float(traj.surge_mps[k]), float(traj.sway_mps[k])), t_s=float(traj.t_s[k]),
            )
            writer.write_frame(
                float(traj.t_s[k]),
                image,
                heading_rad=float(nav.heading_rad[k]),
                sonar_altitude_m=None if nav.sonar_altitude_m is None else float(nav.sonar_altitude_m[k]),
                roll_rad=float(nav.roll_rad[k]) if tilted else None,
                pitch_rad=float(nav.pitch_rad[k]) if tilted else None,
                truth=(pose.x_m, pose.y_m, pose.altitude_m, pose.heading_rad),
            )
            if progress is not None:
                progress(k + 1, n)
    return SimulationSummary(
        scenario=sc.name,
        out_dir=out,
        frames=n,
        seed=int(seed),
        image_format=fmt,
        duration_s=float(traj.t_s[-1]),
        path_length_m=traj.path_length_m,
        x_range_m=(float(traj.x_m.min()), float(traj.x_m.max())),
        y_range_m=(float(traj.y_m.min()), float(traj.y_m.max())),
        altitude_range_m=(float(traj.altitude_m.min()), float(traj.altitude_m.max())),
        wall_time_s=time.perf_counter() - t_start,
    )
