"""Step 6's prediction of the loop: the filter's prediction (1), (2) and the dead reckoning reported beside it.

:class:`Prediction` (one per :class:`~rovslam.pipeline.SlamPipeline`, sharing its filter and its
sunlight monitor) moves the filter with the frame's speed (the measured one, or the held one
over an unusable frame), adds the same step to the dead reckoning, keeps the last good speed
(the landmark search and the token predictions of the next frame start from it), and tallies
what ``summary.json`` says of the speed error w and of the altitude offset ``b``.
"""

from __future__ import annotations

from array import array

import numpy as np

from rovslam.config import RunConfig
from rovslam.pipeline import records
from rovslam.sensor.heading import HeadingEstimate, HeadingPrior
from rovslam.sensor.odometry import SpeedMeasurement
from rovslam.sensor.sunlight import SunlightMonitor
from rovslam.slam import EkfSlam, MotionInput
from rovslam.slam.motion import motion_step_m

__all__ = ["Prediction"]


class Prediction:
    """The filter's prediction (1), (2) over each step, the dead reckoning beside it and the last good speed."""

    def __init__(self, config: RunConfig, ekf: EkfSlam, sunlight: SunlightMonitor | None) -> None:
        self.config = config
        self.ekf = ekf
        self.sunlight = sunlight  # the sunlight watch's monitor (None: no watch)
        self.drag_frames = 0  # predictions that drove the filter's speed error w
        self.drag_sum_mps = np.zeros(2)  # w summed over them, and its sigma
        self.drag_sigma_sum_mps = np.zeros(2)
        self.altitude_bias_sigmas_m = array("d")  # b's process sigma of each prediction (summary.json; 8 bytes each)
        self.last_speed_mps: np.ndarray | None = None  # (surge, sway) of the last good step
        self.dr_m = np.zeros(2)  # the dead reckoning, (2,) metres

    def measured(
        self,
        speed: SpeedMeasurement,
        prior: HeadingPrior,
        heading: HeadingEstimate,
        dt_s: float,
        altitude_m: float,
        altitude_bias: tuple[float, float],
        seabed_offset_sigma_m: float | None = None,
    ) -> None:
        """Step 6: prediction (1), (2) with the speed the tokens measured.

        ``altitude_bias``: the offset ``b``'s stationary sigma (m) and correlation time (s) over
        the step (:meth:`rovslam.pipeline.depth.DepthModel.bias_process`); ``seabed_offset_sigma_m``: the
        seabed offset s's (:meth:`~rovslam.pipeline.depth.DepthModel.seabed_offset_sigma_m`; None: the
        configured one).
        """
        bias_sigma, bias_tau = altitude_bias
        self.altitude_bias_sigmas_m.append(bias_sigma)
        walk = heading.walk_var_rad2  # without a compass: the integrated heading's error is eps's random walk
        self.predict(
            speed,
            prior.previous_rad,
            dt_s,
            heading.sigma_rad if walk is None else 0.0,
            altitude_m,
            bias_sigma,
            walk,
            bias_tau,
            seabed_offset_sigma_m,
        )

    def speed_bias_sigma_mps(self) -> float:
        """The odometry's slow speed error: sunlight caustics drifting over the seabed drag the tokens."""
        cfg = self.config.slam
        seen = cfg.speed_bias_when == "always" or (self.sunlight is not None and self.sunlight.active)
        return cfg.speed_bias_sigma_mps if seen else 0.0

    def predict(
        self,
        speed: SpeedMeasurement,
        heading_rad: float,
        dt_s: float,
        heading_sigma_rad: float | None,
        altitude_m: float | None = None,
        altitude_bias_sigma_m: float | None = None,
        heading_walk_var_rad2: float | None = None,
        altitude_bias_tau_s: float | None = None,
        seabed_offset_sigma_m: float | None = None,
    ) -> None:
        """Prediction (1) of the filter and of the dead reckoning reported beside it."""
        drag_sigma = self.speed_bias_sigma_mps()
        self.ekf.predict(
            MotionInput(
                speed.surge_mps,
                speed.sway_mps,
                speed.cov_mps2,
                heading_rad,
                dt_s,
                heading_sigma_rad,
                altitude_m,
                altitude_bias_sigma_m,
                heading_walk_var_rad2,
                drag_sigma,
                altitude_bias_tau_s,
                seabed_offset_sigma_m,
            )
        )
        if drag_sigma > 0.0:
            self.drag_frames += 1
            self.drag_sum_mps += self.ekf.speed_bias_mps
            self.drag_sigma_sum_mps += np.sqrt(np.maximum(np.diag(self.ekf.speed_bias_cov_mps2), 0.0))
        self.dr_m += motion_step_m(speed.speed_mps, heading_rad, dt_s)
        if speed.ok:
            self.last_speed_mps = speed.speed_mps

    # ------------------------------------------------------------------ summary.json
    def speed_bias_summary(self) -> dict:
        """What ``summary.json`` says of the speed error w (:func:`rovslam.pipeline.records.speed_bias_summary`)."""
        return records.speed_bias_summary(self.drag_frames, self.drag_sum_mps, self.drag_sigma_sum_mps)

    def altitude_bias_summary(self) -> dict:
        """What ``summary.json`` says of the altitude offset ``b`` (:func:`rovslam.pipeline.records.altitude_bias_summary`)."""
        return records.altitude_bias_summary(self.altitude_bias_sigmas_m)

    def drag(self) -> tuple[int, np.ndarray, np.ndarray]:
        """``(frames, (2,) sum, (2,) sigma sum)`` of the speed error w over the predictions that drove it."""
        return self.drag_frames, self.drag_sum_mps, self.drag_sigma_sum_mps
