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

The harder presets, as hard as the real seabed (each 3 to 10 minutes of dive):

* ``portofino-relief`` - the paper's trial camera, site and grid over about 12 cm of relief
  (sand ripples, stones, boulders, a ledge) lit by two lamps on the vehicle, cast shadows.
* ``photo-survey`` - a grid survey over the real ``chamber3`` seabed photomosaic (about
  1 mm/px, kept on the photo with a margin), constant heading, relief derived from the photo.
* ``photo-turns`` - the same with heading turns at the lane ends, yaw oscillation, tilt.
* ``hd-survey`` - an HD camera (1920x1080, 25 frames/s, focal scaled for a 52 x 29 cm
  footprint, finer than the 0.5 mm texture), rolling shutter, lens blur, relief, lamps.
* ``still-camera`` - a 1024x768 still camera at 1.5 Hz from 2 m, about 55 % overlap, 0.4 m/s.
* ``turbid-relief`` - turbid water, marine snow, relief, lamps, H.264 artefacts, noisy compass.
* ``coral-repetitive`` - textures that fool correlation: a hexagonal coral lattice at token
  scale, fine regular ripples, gravel, many look-alike burrows, shells and urchins,
  low-contrast mud, faint laser spots that bleed into the green channel.
* ``swell`` - 2 m altitude swinging by +-30 cm, surge, sway, yaw and heave from the swell,
  tether jerks, lanes at 0.45 m/s, shallow-water sunlight caustics.

Determinism: the trajectory, the sensors, the seabed, the marine snow and every frame's
noise come from generators keyed by the seed (and the frame index), so a seed gives
byte-identical images, and a frame does not depend on which frames were rendered before.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from rovslam.camera import Camera, LaserPointer
from rovslam.errors import SimulationError
from rovslam.sim.calibration import CalibrationErrors, DrawnCalibration, draw_calibration, recorded_lasers
from rovslam.sim.codec import H264Params
from rovslam.sim.lighting import CausticParams, Lamp, LightingParams
from rovslam.sim.relief import PhotoReliefParams, ReliefParams, scaled_relief
from rovslam.sim.render import LaserSpotParams, Pose, SensorParams, renderer_for
from rovslam.sim.texture import TextureParams
from rovslam.sim.vehicle import (
    GridPattern,
    NavReadings,
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
PAPER_LASERS = tuple(LaserPointer((sx * 0.05, sy * 0.05, 0.0)) for sx, sy in ((1, 1), (1, -1), (-1, -1), (-1, 1)))


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
    relief: ReliefParams | PhotoReliefParams | None = None  # None: a flat seabed
    lighting: LightingParams | None = None  # None: the lamp cone fixed to the image
    seabed_photo: str | None = None  # a photo in the shared data folder instead of the procedural texture
    photo_mm_per_px: float = 1.0
    h264: H264Params | None = None  # an H.264 round trip of every frame
    image_format: str = "png"  # the default of simulate(image_format=None)

    @property
    def tilted(self) -> bool:
        """Whether the vehicle rolls and pitches (then frames.csv gets roll_rad, pitch_rad)."""
        return self.vehicle.attitude_sigma_rad > 0

    @property
    def recorded_camera(self) -> Camera:
        """The camera as ``sequence.toml`` describes it: with the sensor's rolling-shutter readout time."""
        return replace(self.camera, readout_s=float(self.sensor.readout_s))

    @property
    def duration_s(self) -> float:
        """Dive time of the full preset."""
        return (self.n_frames - 1) / self.frame_rate_hz

    def summary_line(self) -> str:
        """One line: camera, rate, length, then the description (``rovslam simulate --list``)."""
        cam = self.camera
        return (
            f"{cam.width_px}x{cam.height_px} {self.frame_rate_hz:g} Hz, {self.n_frames} frames "
            f"({self.duration_s / 60.0:.1f} min): {self.description}"
        )


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
    nav=NavSensorParams(
        compass_sigma_rad=float(np.deg2rad(0.5)), compass_drift_rad=float(np.deg2rad(0.5)), sonar_sigma_m=0.03
    ),
)


# ------------------------------------------------------------------ as hard as the real seabed
# (the ledge's face, 5 cm over 2.5 cm, is steep enough for the lamps to cast a shadow below it)
_RELIEF_12CM = ReliefParams(
    ripple_height_m=0.005, stone_height_ratio=0.6, ledge_height_m=0.05, ledge_width_m=0.025, undulation_m=0.008
)
_BOULDERS = TextureParams(boulder_density_per_m2=1.5, boulder_radius_mm=70.0)
_DEG = float(np.deg2rad(1.0))
# Coarser textures for the 2 m altitude presets (pixels of 0.8 to 2 mm): a canvas (at most 4096
# texels) then holds the whole survey; the chunk cache holds 100 chunks (80 MB), all a canvas spans.
_MM_TEXTURE = TextureParams(texel_mm=1.0, cache_chunks=100)
_SWELL_TEXTURE = TextureParams(texel_mm=1.25, cache_chunks=100)
# The photo is 2.29 m (east) x 2.13 m (north) at 1 mm/px: lanes within +-0.65 m north, +-0.7 m east
# keep the footprint (half-diagonal 0.28 m at 1.31 m) and the cross-track error on it, with ~5 cm to spare.
_PHOTO_GRID = GridPattern(
    half_size_m=(0.55, 0.6),
    lane_spacing_m=0.2,
    offsets_m=(
        (0.0, 0.0),
        (0.0, 0.0),
        (0.1, 0.1),
        (0.1, 0.1),
        (-0.05, 0.05),
        (-0.05, 0.05),
        (0.05, -0.1),
        (0.05, -0.1),
    ),
)
_PHOTO_SURVEY = Scenario(
    name="photo-survey",
    description="grid survey over the real chamber3 seabed photomosaic (1 mm/px), constant heading, relief "
    "derived from the photo (8 cm), lamps on the vehicle",
    n_frames=1500,
    seabed_photo="chamber3/seabed.jpg",
    relief=PhotoReliefParams(relief_m=0.08),
    lighting=LightingParams(),
    grid=_PHOTO_GRID,
    vehicle=VehicleParams(cruise_speed_mps=0.15, accel_limit_mps2=0.04),
)
HD_CAMERA = Camera(width_px=1920, height_px=1080, fx_px=4800.0, fy_px=4800.0, cx_px=959.5, cy_px=539.5)
STILL_CAMERA = Camera(width_px=1024, height_px=768, fx_px=2560.0, fy_px=2560.0, cx_px=511.5, cy_px=383.5)
_STILL_LAMPS = LightingParams(
    lamps=(Lamp((0.15, -0.35, 0.02), (0.0, 0.15, 1.0), 0.7), Lamp((0.15, 0.35, 0.02), (0.0, -0.15, 1.0), 0.7)),
    reference_altitude_m=2.0,
)

_NEW: tuple[Scenario, ...] = (
    Scenario(
        name="portofino-relief",
        description="the paper's trial camera, site and grid over ~12 cm of relief (ripples, stones, boulders, "
        "a ledge), two lamps on the vehicle with cast shadows",
        n_frames=1500,
        texture=_BOULDERS,
        relief=_RELIEF_12CM,
        lighting=LightingParams(shadow_samples=3),
    ),
    _PHOTO_SURVEY,
    replace(
        _PHOTO_SURVEY,
        name="photo-turns",
        description="photo-survey with heading turns at the lane ends, +-3 deg yaw oscillation, 0.5 deg tilt, "
        "0.4 deg compass noise",
        vehicle=VehicleParams(
            cruise_speed_mps=0.15,
            accel_limit_mps2=0.04,
            heading_mode="legs",
            wave_yaw_rad=3.0 * _DEG,
            wave_period_s=8.0,
            attitude_sigma_rad=0.5 * _DEG,
        ),
        nav=NavSensorParams(compass_sigma_rad=0.4 * _DEG, compass_drift_rad=0.5 * _DEG),
    ),
    Scenario(
        name="hd-survey",
        description="HD camera 1920x1080 at 25 fps (52x29 cm footprint, pixels finer than the texture), rolling "
        "shutter, lens blur, 12 cm relief, lamps, 0.2 m/s, JPEG frames",
        n_frames=4500,
        frame_rate_hz=25.0,
        camera=HD_CAMERA,
        texture=_BOULDERS,
        relief=_RELIEF_12CM,
        lighting=LightingParams(),
        sensor=SensorParams(exposure_s=0.006, psf_sigma_px=1.3, readout_s=0.02),
        vehicle=VehicleParams(cruise_speed_mps=0.2, accel_limit_mps2=0.05, substeps=1),
        image_format="jpg",
    ),
    Scenario(
        name="still-camera",
        description="1024x768 still camera at 1.5 Hz from 2 m (80x60 cm footprint, ~55 % overlap), 0.4 m/s, "
        "strobes, relief, JPEG frames",
        n_frames=450,
        frame_rate_hz=1.5,
        camera=STILL_CAMERA,
        texture=_MM_TEXTURE,
        relief=ReliefParams(ripple_height_m=0.005, stone_height_ratio=0.6, undulation_m=0.01),
        lighting=_STILL_LAMPS,
        sensor=SensorParams(exposure_s=0.002),
        vehicle=VehicleParams(
            altitude_m=2.0, cruise_speed_mps=0.4, accel_limit_mps2=0.1, waypoint_tolerance_m=0.05, substeps=12
        ),
        grid=GridPattern(
            half_size_m=(1.2, 1.2),
            lane_spacing_m=0.4,
            offsets_m=((0.0, 0.0), (0.0, 0.0), (0.2, 0.2), (0.2, 0.2), (-0.1, 0.1), (-0.1, 0.1)),
        ),
        image_format="jpg",
    ),
    Scenario(
        name="turbid-relief",
        description="turbid water with marine snow over 8 cm of relief, lamps, H.264 artefacts (CRF 30), "
        "0.5 deg compass noise with 1 deg drift",
        n_frames=1500,
        texture=_BOULDERS,
        relief=ReliefParams(
            ripple_height_m=0.004, stone_height_ratio=0.5, ledge_height_m=0.03, ledge_width_m=0.03, undulation_m=0.006
        ),
        lighting=LightingParams(),
        water=WaterParams.turbid(),
        h264=H264Params(crf=30),
        nav=NavSensorParams(compass_sigma_rad=0.5 * _DEG, compass_drift_rad=1.0 * _DEG, sonar_sigma_m=0.03),
    ),
    Scenario(
        name="coral-repetitive",
        description="textures that fool correlation: coral lattice at token scale, fine regular ripples, gravel, "
        "look-alike burrows, shells and urchins, low-contrast mud; faint laser spots bleeding into green",
        n_frames=1500,
        texture=TextureParams(
            coral_cover=0.35,
            fine_ripple_strength=0.12,
            pebble_density_per_m2=1500.0,
            gravel_patchiness=0.3,
            burrow_density_per_m2=60.0,
            shell_density_per_m2=300.0,
            urchin_density_per_m2=20.0,
            mud_cover=0.25,
        ),
        relief=ReliefParams(ripple_height_m=0.003, stone_height_ratio=0.5),
        lighting=LightingParams(),
        spots=LaserSpotParams(
            peak_dn=260.0, halo_fraction=0.08, halo_sigma_px=4.0, crosstalk_green=0.25, crosstalk_blue=0.05
        ),
    ),
    Scenario(
        name="swell",
        description="2 m altitude swinging +-30 cm, swell surge/sway/yaw/heave and tether jerks, 0.45 m/s, "
        "1.5 deg roll/pitch, shallow-water caustics, relief, lamps",
        n_frames=1500,
        texture=_SWELL_TEXTURE,
        relief=ReliefParams(ripple_height_m=0.005, stone_height_ratio=0.6, undulation_m=0.01),
        lighting=LightingParams(reference_altitude_m=2.0, caustics=CausticParams(strength=0.2)),
        vehicle=VehicleParams(
            altitude_m=2.0,
            altitude_swing_m=0.3,
            altitude_swing_period_s=40.0,
            cruise_speed_mps=0.45,
            accel_limit_mps2=0.2,
            waypoint_tolerance_m=0.04,
            wave_surge_mps=0.12,
            wave_sway_mps=0.08,
            wave_yaw_rad=3.0 * _DEG,
            wave_heave_m=0.04,
            wave_period_s=7.0,
            tether_jerk_mps=0.03,
            attitude_sigma_rad=1.5 * _DEG,
            current_mean_mps=0.02,
            current_wander_mps=0.01,
        ),
        grid=GridPattern(
            half_size_m=(1.0, 1.0), lane_spacing_m=0.3, offsets_m=((0.0, 0.0), (0.0, 0.0), (0.15, 0.15), (0.15, 0.15))
        ),
        nav=NavSensorParams(compass_sigma_rad=0.5 * _DEG, compass_drift_rad=0.5 * _DEG),
    ),
)

SCENARIOS: dict[str, Scenario] = {
    "portofino": _PORTOFINO,
    "portofino-short": replace(
        _PORTOFINO,
        name="portofino-short",
        n_frames=600,
        description="the first 2 minutes (600 frames) of portofino, for tests",
    ),
    "rough-turns": _ROUGH,
    "rough-turns-short": replace(
        _ROUGH,
        name="rough-turns-short",
        n_frames=600,
        description="the first 2 minutes (600 frames) of rough-turns, for tests",
    ),
    **{sc.name: sc for sc in _NEW},
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
    calibration: DrawnCalibration | None = None  # the lasting sensor errors the dive was given (None: exact sensors)


def frame_pose(traj: Trajectory, k: int) -> Pose:
    """The true camera pose of frame ``k``."""
    return Pose(
        float(traj.x_m[k]),
        float(traj.y_m[k]),
        float(traj.altitude_m[k]),
        float(traj.heading_rad[k]),
        float(traj.roll_rad[k]),
        float(traj.pitch_rad[k]),
    )


def frame_rng(seed: int, k: int) -> np.random.Generator:
    """The generator of frame ``k``'s sensor noise and laser speckle."""
    return np.random.default_rng([seed, _STREAM_FRAMES, k])


def shared_data_file(relative: str) -> Path:
    """A file of the sample data (e.g. ``chamber3/seabed.jpg``: dataset ``chamber3``, file ``seabed.jpg``).

    Found by :func:`rovslam.data.file_path` (``$ROVSLAM_DATA``, the user cache, the project's shared
    data); the path returned is absolute. A missing file raises SimulationError saying how to get it.
    """
    from rovslam import data
    from rovslam.errors import DataNotFoundError

    name, _, file = relative.partition("/")
    try:
        return data.file_path(name, file)
    except DataNotFoundError as exc:
        raise SimulationError(f"the seabed photo {relative} was not found: {exc}") from None


MAX_FRAMES = 1_000_000  # one simulated dive: 55 hours at 5 Hz (its trajectory arrays alone are 0.4 GB)


def _check_args(scenario, frames, seed, image_format, texture_path, texture_mm_per_px) -> tuple[Scenario, int, str]:
    if not isinstance(scenario, str) or scenario not in SCENARIOS:
        raise SimulationError(f"unknown scenario {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[scenario]
    n = sc.n_frames if frames is None else frames
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise SimulationError(f"frames must be a whole number >= 1, got {frames!r}")
    if n > MAX_FRAMES:
        raise SimulationError(
            f"frames must be at most {MAX_FRAMES:,} (55 hours at 5 Hz), got {frames!r}; "
            "simulate a long campaign as several dives"
        )
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"seed must be a whole number >= 0, got {seed!r}")
    fmt = {"png": "png", "jpg": "jpg", "jpeg": "jpg"}.get(
        str(sc.image_format if image_format is None else image_format).lower()
    )
    if fmt is None:
        raise SimulationError(f"image format must be png or jpg, got {image_format!r}")
    if (texture_path is None) != (texture_mm_per_px is None):
        raise SimulationError("give --texture IMAGE and --texture-mm-per-px S together (the image and its scale)")
    if texture_mm_per_px is not None and not (np.isfinite(texture_mm_per_px) and texture_mm_per_px > 0):
        raise SimulationError(f"texture scale must be a positive number of mm per pixel, got {texture_mm_per_px!r}")
    return sc, int(n), fmt


def build_world(
    sc: Scenario,
    seed: int,
    grow_m: float = 0.25,
    texture_path: Path | None = None,
    texture_mm_per_px: float | None = None,
) -> tuple[World, str]:
    """The world of a scenario (seabed, relief, water seed) and a note on its texture for the metadata.

    ``texture_path`` replaces the scenario's seabed by that image; on a scenario with relief,
    the relief is then derived from the image (:func:`~rovslam.sim.relief.relief_from_photo`).
    """
    photo, mm = None, None
    if texture_path is not None:
        photo, mm = Path(texture_path), float(texture_mm_per_px)  # type: ignore[arg-type]
    elif sc.seabed_photo is not None:
        photo, mm = shared_data_file(sc.seabed_photo), sc.photo_mm_per_px
    if photo is None:
        return World.procedural(int(seed), sc.texture, relief=sc.relief, grow_m=grow_m), "procedural"
    params = None
    if sc.relief is not None:
        params = sc.relief if isinstance(sc.relief, PhotoReliefParams) else PhotoReliefParams()
    seabed, relief = _photo_seabed(str(photo.resolve()), photo.stat().st_mtime_ns, mm, params)
    return World(seabed, seed=int(seed), grow_m=grow_m, relief=relief), f"{photo.name} at {mm} mm/px"


@lru_cache(maxsize=2)
def _photo_seabed(path: str, mtime_ns: int, mm_per_px: float, relief: PhotoReliefParams | None):
    """(ImageSeabed, its relief or None), shared in a process (the relief takes a second or two to derive)."""
    from rovslam.sim.relief import relief_from_photo
    from rovslam.sim.texture import ImageSeabed

    seabed = ImageSeabed.from_file(path, mm_per_px)
    return seabed, None if relief is None else relief_from_photo(seabed, relief)


def survey_area_m(sc: Scenario, traj: Trajectory, margin_m: float = 0.05) -> tuple[float, float, float, float]:
    """(north min, north max, east min, east max) of the seabed the camera can see along ``traj``.

    The camera's footprint radius at the highest altitude (plus the deepest relief a preset
    has, 0.1 m, and the largest tilt) around every position, and ``margin_m``.
    """
    cam = sc.camera
    half_diag = float(
        np.hypot(
            max(cam.cx_px, cam.width_px - cam.cx_px) / cam.fx_px, max(cam.cy_px, cam.height_px - cam.cy_px) / cam.fy_px
        )
    )
    tilt = float(np.max(np.abs(np.concatenate([traj.roll_rad, traj.pitch_rad])), initial=0.0))
    reach = (float(np.max(traj.altitude_m)) + 0.1) * np.tan(np.arctan(half_diag) + tilt) + margin_m
    return (
        float(traj.x_m.min()) - reach,
        float(traj.x_m.max()) + reach,
        float(traj.y_m.min()) - reach,
        float(traj.y_m.max()) + reach,
    )


def _yaw_rate_radps(traj: Trajectory) -> np.ndarray:
    """(N,) heading rate from the true headings (for the rolling shutter)."""
    if len(traj) < 2:
        return np.zeros(len(traj))
    return np.gradient(np.unwrap(traj.heading_rad), traj.t_s)


def simulate(
    scenario: str,
    out_dir: Path,
    frames: int | None = None,
    seed: int = 0,
    image_format: str | None = None,
    texture_path: Path | None = None,
    texture_mm_per_px: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    calibration: CalibrationErrors | DrawnCalibration | None = None,
    relief_scale: float = 1.0,
) -> SimulationSummary:
    """Simulate scenario ``scenario`` and write the sequence folder ``out_dir`` (format v1).

    ``frames`` overrides the scenario's length (the first ``frames`` frames of the same
    survey). ``image_format`` (png or jpg) defaults to the scenario's. ``texture_path`` /
    ``texture_mm_per_px`` replace the seabed by an image at that scale.
    ``progress(done, total)`` is called after every frame. Bad arguments (and a missing
    seabed photo) raise :class:`~rovslam.errors.SimulationError` before anything is written.
    On a scenario with relief, ``groundtruth.csv`` gets a ``relief_m`` column (the relief
    height under the camera; ``altitude_m`` stays the altitude above the mean seabed plane)
    and the sonar reads the range to the relief under its beam.
    ``calibration``: lasting sensor errors (compass deviation, laser-rig baseline, sonar offset;
    :mod:`rovslam.sim.calibration`), drawn for the seed from a :class:`CalibrationErrors` or given
    as a :class:`DrawnCalibration`, recorded in ``[metadata]``; None: exact sensors.
    ``relief_scale`` multiplies every height of the scenario's relief (0: a flat seabed;
    :func:`~rovslam.sim.relief.scaled_relief`), recorded in ``[metadata]``.
    """
    from rovslam.core import SequenceInfo
    from rovslam.io.sequence import SequenceWriter
    from rovslam.sim.codec import H264RoundTrip

    t_start = time.perf_counter()
    sc, n, fmt = _check_args(scenario, frames, seed, image_format, texture_path, texture_mm_per_px)
    if relief_scale != 1.0:
        sc = replace(sc, relief=scaled_relief(sc.relief, relief_scale))
    drawn = _drawn_calibration(calibration, int(seed))
    out = Path(out_dir)
    from rovslam.io.output import check_output_folder

    check_output_folder(out, "--out")  # a file, a device, a FIFO: "not a folder" (OutputError)
    if out.exists() and any(out.iterdir()):
        raise SimulationError(f"output folder {out} already exists and is not empty; give a new folder")
    traj = simulate_trajectory(sc.vehicle, sc.grid, n, sc.frame_rate_hz, int(seed))
    # Size the first canvas to the whole survey, so it is built once (the path is known).
    grow_m = min(1.0, float(np.max(np.hypot(traj.x_m, traj.y_m)))) + 0.05
    world, texture_note = build_world(sc, int(seed), grow_m, texture_path, texture_mm_per_px)
    world.area_m = survey_area_m(sc, traj)
    relief_m, sonar_m = _relief_under_vehicle(sc, world, traj)
    nav_params, lasers_recorded = sc.nav, sc.lasers
    if drawn is not None:
        nav_params = replace(
            sc.nav,
            compass_bias_rad=sc.nav.compass_bias_rad + drawn.compass_deviation_rad,
            sonar_offset_m=sc.nav.sonar_offset_m + drawn.sonar_offset_m,
        )
        lasers_recorded = recorded_lasers(sc.lasers, drawn)
    nav = read_sensors(traj, nav_params, int(seed), sonar_range_m=sonar_m)
    info = SequenceInfo(
        name=f"rovslam simulate {sc.name} (seed {int(seed)})",
        camera=sc.recorded_camera,
        lasers=lasers_recorded,
        metadata=_metadata(sc, int(seed), n, texture_note, world, drawn, relief_scale),
    )
    codec = (
        None if sc.h264 is None else H264RoundTrip(sc.camera.width_px, sc.camera.height_px, sc.frame_rate_hz, sc.h264)
    )
    with SequenceWriter(
        out, info, image_format=fmt, with_attitude=sc.tilted, with_groundtruth=True, with_relief=relief_m is not None
    ) as writer:
        _write_frames(writer, sc, world, traj, nav, relief_m, int(seed), codec, progress)
    if codec is not None:
        codec.close()
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
        calibration=drawn,
    )


def _drawn_calibration(calibration: CalibrationErrors | DrawnCalibration | None, seed: int) -> DrawnCalibration | None:
    """The lasting sensor errors of the dive: drawn for ``seed`` from a :class:`CalibrationErrors`, or as given."""
    if calibration is not None and not isinstance(calibration, (CalibrationErrors, DrawnCalibration)):
        raise SimulationError(
            f"calibration must be a CalibrationErrors, a DrawnCalibration or None, got {type(calibration).__name__}"
        )
    return draw_calibration(calibration, seed) if isinstance(calibration, CalibrationErrors) else calibration


def _relief_under_vehicle(sc: Scenario, world: World, traj: Trajectory) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(relief height under the camera, sonar range)``, ``(N,)`` each, or (None, None) on a flat seabed.

    Raises SimulationError when the vehicle would touch the relief.
    """
    from rovslam.sim.relief import heights_at, sonar_first_return_m

    if world.relief is None:
        return None, None
    relief_m = heights_at(world.relief, traj.x_m, traj.y_m)
    sonar_m = sonar_first_return_m(world.relief, traj.x_m, traj.y_m, traj.altitude_m, sc.nav.sonar_beam_half_angle_rad)
    if float(np.min(traj.altitude_m - world.relief.height_range_m[1])) < 0.05:
        raise SimulationError(f"scenario {sc.name}: the vehicle would touch the relief; fly higher")
    return relief_m, sonar_m


def _metadata(
    sc: Scenario,
    seed: int,
    n: int,
    texture_note: str,
    world: World,
    drawn: DrawnCalibration | None,
    relief_scale: float,
) -> dict:
    """The ``[metadata]`` of the sequence: what was simulated, and how."""
    metadata = {
        "generator": "rovslam.sim",
        "scenario": sc.name,
        "seed": seed,
        "frames": n,
        "frame_rate_hz": float(sc.frame_rate_hz),
        "texture": texture_note,
        "nominal_altitude_m": float(sc.vehicle.altitude_m),
    }
    if world.relief is not None:  # (only then: the original presets' files stay as they were)
        lo, hi = world.relief.height_range_m
        metadata["relief"] = f"{type(world.relief).__name__}, heights within [{lo:.3f}, {hi:.3f}] m"
    if relief_scale != 1.0:
        metadata["relief_scale"] = float(relief_scale)
    if drawn is not None:
        metadata.update(drawn.metadata())
    if sc.h264 is not None:
        metadata["compression"] = f"H.264 round trip, CRF {sc.h264.crf}"
    return metadata


def _write_frames(
    writer,
    sc: Scenario,
    world: World,
    traj: Trajectory,
    nav: NavReadings,
    relief_m: np.ndarray | None,
    seed: int,
    codec,
    progress: Callable[[int, int], None] | None,
) -> None:
    """Render every frame of ``traj`` (through ``codec``, an H.264 round trip, when not None) and write it with
    its readings and truth to ``writer`` (a :class:`~rovslam.io.sequence.SequenceWriter`)."""
    n = len(traj)
    renderer = renderer_for(sc.camera, sc.water, sc.sensor, sc.spots, sc.lighting)
    yaw_rate = _yaw_rate_radps(traj) if sc.sensor.readout_s > 0 else np.zeros(n)
    tilted = sc.tilted
    for k in range(n):
        pose = frame_pose(traj, k)
        image = renderer.render(
            world,
            pose,
            sc.lasers,
            frame_rng(seed, k),
            velocity_mps=(float(traj.surge_mps[k]), float(traj.sway_mps[k])),
            t_s=float(traj.t_s[k]),
            yaw_rate_radps=float(yaw_rate[k]),
        )
        if codec is not None:
            image = codec.push(image)
        truth = (pose.x_m, pose.y_m, pose.altitude_m, pose.heading_rad)
        writer.write_frame(
            float(traj.t_s[k]),
            image,
            heading_rad=float(nav.heading_rad[k]),
            sonar_altitude_m=None if nav.sonar_altitude_m is None else float(nav.sonar_altitude_m[k]),
            roll_rad=float(nav.roll_rad[k]) if tilted else None,
            pitch_rad=float(nav.pitch_rad[k]) if tilted else None,
            truth=truth if relief_m is None else truth + (float(relief_m[k]),),
        )
        if progress is not None:
            progress(k + 1, n)
