"""SLAM core: augmented-state EKF (1)-(4), visibility gate (5) and new-landmark test (6)."""

from rovslam.slam.ekf import ConsistencyReport, EkfSlam, UpdateResult
from rovslam.slam.inputs import MotionInput
from rovslam.slam.motion import motion_jacobians, motion_step_m
from rovslam.slam.observation import (
    landmark_from_mn,
    landmark_jacobians,
    observation_jacobians,
    observation_noise_px2,
    observe_mn,
    pixels_to_mn,
)
from rovslam.slam.state import StateLayout

__all__ = [
    "ConsistencyReport",
    "EkfSlam",
    "MotionInput",
    "StateLayout",
    "UpdateResult",
    "landmark_from_mn",
    "landmark_jacobians",
    "motion_jacobians",
    "motion_step_m",
    "observation_jacobians",
    "observation_noise_px2",
    "observe_mn",
    "pixels_to_mn",
]
