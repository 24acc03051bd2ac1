"""Seabed simulator: procedural or photographic seabed and relief, ROV trajectory, camera / water / lamps / laser renderer.

Entry points: :func:`simulate` (a whole sequence folder from a scenario preset in
:data:`SCENARIOS`) and :func:`render_frame` (one frame for one pose, a pure function).
"""

from rovslam.sim.calibration import CalibrationErrors, DrawnCalibration, draw_calibration
from rovslam.sim.codec import H264Params, H264RoundTrip
from rovslam.sim.lighting import CausticParams, Lamp, LightingParams
from rovslam.sim.relief import ArrayRelief, PhotoReliefParams, ProceduralRelief, ReliefParams, relief_from_photo
from rovslam.sim.render import FrameRenderer, LaserSpotParams, Pose, SensorParams, render_frame, renderer_for
from rovslam.sim.scenarios import (
    PAPER_LASERS,
    PORTOFINO_CAMERA,
    SCENARIOS,
    Scenario,
    SimulationSummary,
    frame_pose,
    frame_rng,
    shared_data_file,
    simulate,
)
from rovslam.sim.texture import ImageSeabed, ProceduralSeabed, TextureParams, TextureSource
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

__all__ = [
    "ArrayRelief",
    "CalibrationErrors",
    "CausticParams",
    "DrawnCalibration",
    "FrameRenderer",
    "H264Params",
    "H264RoundTrip",
    "Lamp",
    "LightingParams",
    "PhotoReliefParams",
    "ProceduralRelief",
    "ReliefParams",
    "relief_from_photo",
    "shared_data_file",
    "GridPattern",
    "ImageSeabed",
    "LaserSpotParams",
    "NavReadings",
    "NavSensorParams",
    "PAPER_LASERS",
    "PORTOFINO_CAMERA",
    "Pose",
    "ProceduralSeabed",
    "SCENARIOS",
    "Scenario",
    "SensorParams",
    "SimulationSummary",
    "TextureParams",
    "TextureSource",
    "Trajectory",
    "VehicleParams",
    "WaterParams",
    "World",
    "draw_calibration",
    "frame_pose",
    "frame_rng",
    "read_sensors",
    "render_frame",
    "renderer_for",
    "simulate",
    "simulate_trajectory",
]
