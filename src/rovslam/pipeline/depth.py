"""Step 1's image depth Z over time, and what the relief under the measured points adds to its error.

:class:`DepthModel` (one per :class:`~rovslam.pipeline.SlamPipeline`) filters the altimeter's
readings over time (:class:`rovslam.sensor.altitude.AltitudeFilter`), holds the filter's prediction
through a frame without a reading, widens Z's sigma by the relief when the EKF holds no
altitude offset, and gives the offset ``b``'s process over each step. The relief's height
spread comes from the speed tokens' parallax (:attr:`rovslam.sensor.odometry.SpeedEstimator.relief_var`).
:class:`PlaneAverage` averages the laser spots' plane over frames: the relief off it (the spots'
residuals), which widens each altitude reading before the filter (``[laser] relief_altitude_gain``)
and each landmark observation (``[slam] landmark_relief_gain``, :func:`rovslam.pipeline.update.landmark_depth`),
and its slope (``[laser] plane_depth``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rovslam.config import RunConfig
from rovslam.sensor.altitude import AltitudeFilter
from rovslam.sensor.odometry import SpeedEstimator
from rovslam.slam import EkfSlam
from rovslam.slam.motion import altitude_offset_sigma_m, ou_sum_as_one
from rovslam.vision.laser import SOURCE_FIXED, SOURCE_HELD, AltitudeEstimate

__all__ = ["DepthModel", "PlaneAverage"]


class PlaneAverage:
    """The laser spots' plane averaged over time: the relief off it (m^2) and its slope (rad).

    Each frame with a plane (four or more spots for the relief, three for the slope) moves the
    averages towards its own by ``1 - exp(-dt / tau)``; a frame without one leaves them as they
    are. One frame's relief has one degree of freedom (four spots, a plane of three parameters):
    its average over a few seconds is what is carried.

    Args:
        relief_tau_s: averaging time of the relief off the plane.
        slope_tau_s: averaging time of the slope (the slope is clipped to ``max_slope_rad`` on output).
        max_slope_rad: the largest slope returned, per axis.
    """

    def __init__(self, relief_tau_s: float, slope_tau_s: float, max_slope_rad: float = 0.3) -> None:
        self.relief_tau_s = float(relief_tau_s)
        self.slope_tau_s = float(slope_tau_s)
        self.max_slope_rad = float(max_slope_rad)
        self.relief_var_m2 = float("nan")
        self._tan = np.full(2, np.nan)  # averaged tangents of the slope (forward, starboard)
        self._t_relief_s: float | None = None
        self._t_slope_s: float | None = None

    def add(self, t_s: float, alt: AltitudeEstimate) -> tuple[float, tuple[float, float] | None]:
        """Fold in the frame at ``t_s``; returns ``(relief_var_m2, slope_rad or None)`` averaged so far."""
        if math.isfinite(alt.relief_var_m2):
            if self._t_relief_s is None or not math.isfinite(self.relief_var_m2):
                self.relief_var_m2 = float(alt.relief_var_m2)
            else:
                a = 1.0 - math.exp(-max(t_s - self._t_relief_s, 0.0) / self.relief_tau_s)
                self.relief_var_m2 += a * (float(alt.relief_var_m2) - self.relief_var_m2)
            self._t_relief_s = t_s
        if alt.slope_rad is not None and all(math.isfinite(v) for v in alt.slope_rad):
            tan = np.tan(np.asarray(alt.slope_rad, dtype=np.float64))
            if self._t_slope_s is None:
                self._tan = tan
            else:
                a = 1.0 - math.exp(-max(t_s - self._t_slope_s, 0.0) / self.slope_tau_s)
                self._tan = self._tan + a * (tan - self._tan)
            self._t_slope_s = t_s
        if not np.all(np.isfinite(self._tan)):
            return self.relief_var_m2, None
        lim = self.max_slope_rad
        slope = np.clip(np.arctan(self._tan), -lim, lim)
        return self.relief_var_m2, (float(slope[0]), float(slope[1]))


class DepthModel:
    """The altimeter's readings filtered over time, and the errors the relief adds to them (reads the others' state)."""

    def __init__(self, config: RunConfig, altitude: AltitudeFilter, speed: SpeedEstimator, ekf: EkfSlam) -> None:
        self.config = config
        self.altitude = altitude
        self.speed = speed
        self.ekf = ekf
        self.plane = PlaneAverage(
            config.laser.relief_tau_s, config.laser.plane_slope_tau_s, config.laser.max_plane_slope_rad
        )

    def filtered(self, t_s: float, alt: AltitudeEstimate) -> AltitudeEstimate:
        """The reading of the frame at ``t_s`` filtered over time (held when there was none).

        The returned estimate carries the spots' plane averaged over time: ``relief_var_m2`` the relief
        off it (``[laser] relief_tau_s``; NaN before any plane), ``slope_rad`` its slope
        (``plane_slope_tau_s``, clipped to ``max_plane_slope_rad``; None before any plane). The reading's
        sigma is widened by ``relief_altitude_gain`` times that relief's sigma before the filter.
        """
        relief_var, slope = self.plane.add(t_s, alt)
        if alt.source == SOURCE_FIXED:
            return dataclasses.replace(self.held(t_s, alt), relief_var_m2=relief_var, slope_rad=slope)
        laser = self.config.laser
        sigma_in = alt.sigma_m
        if laser.relief_altitude_gain > 0.0 and alt.source.startswith("laser") and math.isfinite(relief_var):
            sigma_in = math.hypot(sigma_in, laser.relief_altitude_gain * math.sqrt(relief_var))
        z, sigma = self.altitude.update(t_s, alt.altitude_m, sigma_in)
        return dataclasses.replace(
            alt,
            altitude_m=z,
            sigma_m=self.with_terrain_sigma_m(z, sigma, alt),
            relief_var_m2=relief_var,
            slope_rad=slope,
        )

    def with_terrain_sigma_m(self, altitude_m: float, sigma_m: float, alt: AltitudeEstimate) -> float:
        """The filtered altitude's sigma, widened by the relief without the filter's altitude-offset state b:
        over relief the lasers (or the sonar) range to the seabed under their few points, not to the mean
        seabed; that spread is Z's error too."""
        if self.ekf.altitude_bias_sigma_m != 0.0:
            return sigma_m
        return math.sqrt(sigma_m * sigma_m + self.terrain_sigma_m(altitude_m, alt) ** 2)

    def held(self, t_s: float, assumed: AltitudeEstimate) -> AltitudeEstimate:
        """A frame with no laser spot and no sonar reading: the altitude filter's prediction, while it is surer.

        Between two readings the vehicle's altitude is what the filter predicts, its sigma growing
        with the vertical acceleration; the assumed altitude (``[vehicle] altitude_m``, else the
        paper's) takes over only before the first reading or once the prediction is less sure than
        it (``[laser] fixed_altitude_sigma_m``).
        """
        pred = self.altitude.predict(t_s)
        if pred is None or not pred[1] < assumed.sigma_m:
            return assumed
        z, sigma = pred
        return dataclasses.replace(
            assumed, altitude_m=z, sigma_m=self.with_terrain_sigma_m(z, sigma, assumed), source=SOURCE_HELD
        )

    def terrain_sigma_m(self, altitude_m: float, alt: AltitudeEstimate) -> float:
        """How far the relief under the altimeter's points strays from the mean seabed (from the tokens' parallax)."""
        samples = max(alt.n_spots, 1) if alt.source.startswith("laser") else 1
        return self.relief_sigma_m(altitude_m, samples)

    def relief_sigma_m(self, altitude_m: float, samples: int = 1) -> float:
        """The relief's height spread at depth Z from the tokens' parallax, over ``samples`` independent points (m)."""
        return self.config.odometry.relief_scale_gain * altitude_m * math.sqrt(self.speed.relief_var / samples)

    def seabed_offset_sigma_m(self, altitude_m: float) -> float:
        """The seabed offset s's stationary sigma over this step: the relief under the laser spots (m).

        The relief's height spread from the tokens' parallax (:meth:`relief_sigma_m`, one point: the
        spots, a few centimetres apart, stand on the same relief): a flat seabed keeps s at 0;
        ``[slam] seabed_offset_sigma_m`` caps it.
        """
        return min(self.relief_sigma_m(altitude_m), self.config.slam.seabed_offset_sigma_m)

    def bias_process(self, altitude_m: float, alt: AltitudeEstimate) -> tuple[float, float]:
        """The altitude offset ``b``'s stationary sigma (m) and correlation time (s) over this step.

        The tokens' speed is measured at the altitude Z, but the tokens stand on the relief: their
        depth strays from Z by about one token's relative height spread (the tokens of one frame stand
        on the same relief features, so their mean does not average it away), a scale error of the
        speed that lasts while the same relief is under the camera. ``b`` carries it beside the
        altimeter's lasting error: their sum, two Ornstein-Uhlenbeck processes (the altimeter's:
        ``[slam] altitude_bias_sigma_m`` and the laser rig's share ``altitude_scale_sigma`` of Z in
        quadrature, :func:`~rovslam.slam.motion.altitude_offset_sigma_m`, with ``altitude_bias_tau_s``;
        the relief's: sigma ``gain Z sigma_s`` from the tokens' parallax with
        ``altitude_bias_relief_tau_s``), held as one with
        the same variance and the same integrated autocovariance (so the same long-run drift).
        """
        slam = self.config.slam
        # the altimeter's lasting error at this depth: its offset and the laser rig's share of Z
        lasting = altitude_offset_sigma_m(slam.altitude_bias_sigma_m, slam.altitude_scale_sigma, altitude_m)
        if not slam.altitude_bias_relief:  # the altimeter's lasting error, or the relief under its spots if larger
            if self.ekf.layout.s is not None:  # the relief under the spots is the seabed offset s's
                return lasting, slam.altitude_bias_tau_s
            return max(lasting, self.terrain_sigma_m(altitude_m, alt)), slam.altitude_bias_tau_s
        relief = self.relief_sigma_m(altitude_m)  # one token's spread: the tokens share their relief features
        return ou_sum_as_one(lasting, slam.altitude_bias_tau_s, relief, slam.altitude_bias_relief_tau_s)
