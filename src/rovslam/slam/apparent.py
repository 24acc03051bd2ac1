"""Errors of the frame an estimate lives in, which no image can see (beyond the paper).

Both back ends estimate the vehicle and the map in an *apparent* frame: the one the images,
the compass and the AHRS define together. Three errors move that whole frame against the world,
and only the reported covariance can carry them, because no measurement of a run can reduce
them:

* the AHRS's tilt error: a camera tilted by b sees every seabed point shifted by about
  ``Z b``, so the odometry and the landmarks place the vehicle at ``x - R b``; covariance
  ``(Z sigma_tilt)^2 I``;
* the compass's lasting error (its deviation, and its slow drift when the filter does not hold
  the drift in its state): a heading error delta that every frame shares turns the whole
  estimate about the start (the origin) by delta, moving a point at x by ``delta J x``,
  ``J = [[0, -1], [1, 0]]``; covariance ``sigma_rot^2 (J x)(J x)^T``. A drift that changes
  during the dive is seen again by the landmarks and can be estimated (``[slam]
  heading_bias_sigma_rad``); its value at the start, and any constant part, cannot: a turned
  world gives the same images;
* the altimeter's lasting error, for a back end that does not hold it in its state (the
  smoother; the EKF carries it as its consider state ``b``): an altitude read ``Z (1 + s)``
  scales the odometry and every landmark's depth together, so the whole estimate is scaled by
  ``1 + s`` about the start, moving a point at x by ``s x``; covariance ``sigma_s^2 x x^T``
  (a scaled world gives the same images).
"""

from __future__ import annotations

import math

import numpy as np

from rovslam.config import OdometryConfig, RunConfig

__all__ = ["apparent_frame_cov_m2", "apparent_sigmas", "shared_heading_sigma_rad"]


def shared_heading_sigma_rad(odometry: OdometryConfig, drift_estimated: bool) -> float:
    """Sigma of the heading error every frame of the estimate shares, for frames with a compass.

    The compass's constant error (``compass_offset_sigma_rad``) always; its slow drift too
    (``compass_drift_sigma_rad``) when the back end does not estimate the drift in its state.
    0 when the compass is used as it is (``compass_sigma_rad = 0``, the paper).
    """
    if odometry.compass_sigma_rad == 0:
        return 0.0
    return math.hypot(odometry.compass_offset_sigma_rad, 0.0 if drift_estimated else odometry.compass_drift_sigma_rad)


def apparent_sigmas(config: RunConfig, graph: bool) -> tuple[float, float, float]:
    """``(heading_rad, altitude_m, altitude_scale)``: what a back end's estimate shares and does not hold.

    The sigma of the heading error the whole estimate shares (frames with a compass), and of
    the altimeter's lasting error, its offset (metres) and the laser rig's share of the depth
    (relative; :func:`rovslam.slam.motion.altitude_offset_sigma_m` combines them): the EKF
    (``graph`` False) holds that one in its state ``b`` (both 0 here), the iSAM2 graph (``graph``
    True) does not. As for the EKF's ``b``, the share counts only with an offset sigma > 0
    (``altitude_bias_sigma_m = 0``: no lasting altitude error). Each back end's own drift model
    decides whether the compass drift is shared.
    """
    drift_estimated = (config.smoother if graph else config.slam).heading_bias_sigma_rad > 0
    heading = shared_heading_sigma_rad(config.odometry, drift_estimated)
    slam = config.slam
    if not graph or slam.altitude_bias_sigma_m == 0:
        return heading, (slam.altitude_bias_sigma_m if graph else 0.0), 0.0
    return heading, slam.altitude_bias_sigma_m, slam.altitude_scale_sigma


def apparent_frame_cov_m2(xy_m, depth_m, tilt_sigma_rad, rotation_sigma_rad, scale_sigma=0.0) -> np.ndarray:
    """Covariance the apparent frame adds to a position estimate.

    Args:
        xy_m: (2,) or (N, 2) estimated positions, world frame, metres (the start at the origin).
        depth_m: () or (N,) the image depth Z at each position, metres.
        tilt_sigma_rad: () or (N,) the AHRS's roll / pitch accuracy (0: no AHRS, no tilt term).
        rotation_sigma_rad: () or (N,) sigma of the heading error shared by the whole estimate.
        scale_sigma: () or (N,) relative sigma of a scale error shared by the whole estimate
            (the altimeter's lasting error over the depth; 0 when the back end holds it).

    Returns:
        (2, 2) or (N, 2, 2) covariance to add to the estimate's own, metres squared.
    """
    xy = np.asarray(xy_m, dtype=np.float64)
    single = xy.ndim == 1
    if xy.shape == (2,) and all(np.ndim(a) == 0 for a in (depth_m, tilt_sigma_rad, rotation_sigma_rad, scale_sigma)):
        return _one_cov_m2(xy, depth_m, tilt_sigma_rad, rotation_sigma_rad, scale_sigma)
    xy = np.atleast_2d(xy)
    n = xy.shape[0]
    tilt_var = (
        np.broadcast_to(np.asarray(depth_m, dtype=np.float64), (n,))
        * np.broadcast_to(np.asarray(tilt_sigma_rad, dtype=np.float64), (n,))
    ) ** 2
    rot_var = np.broadcast_to(np.asarray(rotation_sigma_rad, dtype=np.float64), (n,)) ** 2
    jx = np.stack([-xy[:, 1], xy[:, 0]], axis=1)  # J x
    scale_var = np.broadcast_to(np.asarray(scale_sigma, dtype=np.float64), (n,)) ** 2
    cov = (
        rot_var[:, None, None] * jx[:, :, None] * jx[:, None, :]
        + scale_var[:, None, None] * xy[:, :, None] * xy[:, None, :]
    )
    cov[:, 0, 0] += tilt_var
    cov[:, 1, 1] += tilt_var
    return cov[0] if single else cov


def _one_cov_m2(xy_m: np.ndarray, depth_m, tilt_sigma_rad, rotation_sigma_rad, scale_sigma) -> np.ndarray:
    """:func:`apparent_frame_cov_m2` of one (2,) position and scalar sigmas, on Python floats.

    The same operations in the same order as the array form (a square as a product, as NumPy's
    ``** 2``), hence the same bits, at a tenth of the cost of the broadcasting.
    """
    x, y = xy_m.tolist()
    tilt = float(depth_m) * float(tilt_sigma_rad)
    tilt_var = tilt * tilt
    rot = float(rotation_sigma_rad)
    rot_var = rot * rot
    scale = float(scale_sigma)
    scale_var = scale * scale
    jx, jy = -y, x  # J x
    c00 = (rot_var * jx) * jx + (scale_var * x) * x
    c01 = (rot_var * jx) * jy + (scale_var * x) * y
    c10 = (rot_var * jy) * jx + (scale_var * y) * x
    c11 = (rot_var * jy) * jy + (scale_var * y) * y
    return np.array([[c00 + tilt_var, c01], [c10, c11 + tilt_var]])
