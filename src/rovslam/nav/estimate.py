"""The estimate the controller steers by, from each frame's pipeline result: SLAM or dead reckoning.

* ``slam``: the filter's position and its (2, 2) covariance (landmark updates included);
* ``dead-reckoning``: the same pipeline's speed integrated with the heading and no landmark
  update (``FrameResult.dr_x_m, dr_y_m``, what ``trajectory.csv`` holds as ``dr_x_m, dr_y_m``),
  with its covariance propagated here by the Jacobians of (1): ``P += G Q G^T + j j^T sigma_psi^2``.

Both carry the measured ground velocity (the pipeline's surge and sway turned by the heading),
which the guidance uses to estimate the current.
"""

from __future__ import annotations

import numpy as np

from rovslam.camera import rot2
from rovslam.errors import InvalidArgumentError
from rovslam.nav.guidance import NavEstimate
from rovslam.pipeline import FrameResult
from rovslam.slam.motion import motion_jacobians

__all__ = ["ESTIMATORS", "DeadReckoningCovariance", "check_estimator", "nav_estimate"]

ESTIMATORS = ("slam", "dead-reckoning")


def check_estimator(estimator: str) -> str:
    """``estimator`` if it is one of :data:`ESTIMATORS`, else InvalidArgumentError."""
    if estimator not in ESTIMATORS:
        raise InvalidArgumentError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    return estimator


class DeadReckoningCovariance:
    """The covariance of the dead-reckoning position, propagated frame by frame (starts at 0, the origin known)."""

    def __init__(self) -> None:
        self.cov_m2 = np.zeros((2, 2))

    def update(self, res: FrameResult) -> np.ndarray:
        """Add this frame's step: speed covariance through ``G = R dt``, heading noise through ``j = dR/dpsi v dt``."""
        if res.dt_s > 0:
            meas = res.measurements
            psi = meas.heading_rad if meas is not None else res.heading_rad
            sigma_psi = meas.heading_sigma_rad if meas is not None else 0.0
            g, j = motion_jacobians(np.array([res.surge_mps, res.sway_mps]), psi, res.dt_s)
            self.cov_m2 = self.cov_m2 + g @ res.speed_cov_mps2 @ g.T + np.outer(j, j) * sigma_psi**2
        return self.cov_m2


def nav_estimate(res: FrameResult, estimator: str, dr: DeadReckoningCovariance | None = None) -> NavEstimate:
    """The :class:`~rovslam.nav.guidance.NavEstimate` of one frame's result for ``estimator``."""
    velocity = rot2(res.heading_rad) @ np.array([res.surge_mps, res.sway_mps]) if res.speed_ok else None
    if estimator == "slam":
        xy, cov = np.array([res.x_m, res.y_m]), np.asarray(res.cov_xy_m2, dtype=np.float64)
    elif estimator == "dead-reckoning":
        if dr is None:
            raise InvalidArgumentError("the dead-reckoning estimate needs its DeadReckoningCovariance")
        xy, cov = np.array([res.dr_x_m, res.dr_y_m]), dr.update(res).copy()
    else:
        check_estimator(estimator)
    return NavEstimate(res.t_s, xy, cov, float(res.heading_rad), velocity)
