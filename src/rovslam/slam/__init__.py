"""SLAM core: augmented-state EKF (1)-(4), visibility gate (5) and new-landmark test (6)."""

from rovslam.slam.ekf import ConsistencyReport, EkfSlam, UpdateResult
from rovslam.slam.observation import landmark_from_mn, observation_noise_px2, observe_mn, pixels_to_mn

__all__ = [
    "ConsistencyReport",
    "EkfSlam",
    "UpdateResult",
    "landmark_from_mn",
    "observation_noise_px2",
    "observe_mn",
    "pixels_to_mn",
]
