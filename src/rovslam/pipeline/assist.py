"""Step 5 when the tokens are weak: the feature motion between the two frames gates, seeds and stands in for them.

When the tokens' consensus is weak (fewer than ``[odometry] feature_assist_inliers`` agree, or
none), the seabed's global motion between the previous and the current frame is measured from
point features (:func:`rovslam.vision.features.feature_motion`: a similarity, with a covariance
from its inliers' residuals). From it, as pure functions:

* :func:`predicted_tokens`: where each previous token should be now (and how sure that is): the
  search windows are centred there, so that motions far beyond the search radius are found;
* :func:`beyond_reach`: whether it moved the seabed beyond the windows the tokens were searched
  in (only then are weak tokens taken for a large motion: tokens that failed where the motion was
  within reach failed for another reason, turbid water or a bland seabed, and stay as they are);
* :func:`token_gate`: which tracked tokens agree with it (the others are refused);
* :func:`turn_agrees`: whether its turn agrees with the compass (a frame that is not the next view
  of the same seabed, a glitch, must not be taken as a motion);
* :func:`feature_speed`: the motion itself as the step's speed, with its covariance, where the
  tokens still fail.

The similarity is fitted in ideal (undistorted) pixels of the processed camera; the tokens live
in its distorted pixels, so points go through the lens model both ways.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from rovslam.camera import Camera, distort_pixels, undistort_pixels
from rovslam.sensor.odometry import SpeedMeasurement, speed_from_tokens
from rovslam.vision.features import FeatureMotion, similarity_design

__all__ = ["beyond_reach", "feature_speed", "is_weak", "predicted_tokens", "reduced_grey", "token_gate", "turn_agrees"]

# Finite-difference steps of the similarity's parameters [a, b, tx_px, ty_px] for the speed's Jacobian.
_PARAM_STEPS = np.array([1e-4, 1e-4, 0.5, 0.5])
# The feature motion's turn may differ from the compass's by this beyond their sigmas (tilt changes, the lens).
_TURN_SLACK_RAD = math.radians(2.0)


def is_weak(speed: SpeedMeasurement, min_inliers: int) -> bool:
    """Whether a token speed is too weak to stand alone: none, or fewer than ``min_inliers`` tokens agree (0: never)."""
    return min_inliers > 0 and (not speed.ok or speed.n_inliers < min_inliers)


def reduced_grey(image: np.ndarray, camera: Camera) -> np.ndarray:
    """``(H', W') uint8``: the frame's ``(H, W[, 3]) uint8`` image as grey at the processed camera's size."""
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if grey.shape != camera.shape:
        grey = cv2.resize(grey, (camera.width_px, camera.height_px), interpolation=cv2.INTER_AREA)
    return grey


def predicted_tokens(camera: Camera, motion: FeatureMotion, uv_prev_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where ``(N, 2)`` previous-frame pixels (distorted) are now: ``(N, 2)`` px and ``(N, 2, 2)`` px^2.

    Through the lens model: undistort, apply the similarity, distort again. The covariance is that
    of the similarity at the ideal point (:func:`rovslam.vision.features.point_motion_px`).
    """
    uv = np.asarray(uv_prev_px, dtype=np.float64).reshape(-1, 2)
    ideal = undistort_pixels(camera, uv)
    jac = similarity_design(ideal).reshape(len(uv), 2, 4)  # per point: [[u, -v, 1, 0], [v, u, 0, 1]]
    moved = np.einsum("nij,j->ni", jac, motion.params)
    cov = np.einsum("nij,jk,nlk->nil", jac, motion.cov_params, jac)
    return distort_pixels(camera, moved), cov


def beyond_reach(
    camera: Camera,
    motion: FeatureMotion,
    uv_prev_px: np.ndarray,
    windows: list[tuple[np.ndarray, float]],
) -> bool:
    """Whether the feature motion puts most of the ``(N, 2)`` previous tokens outside every search window.

    ``windows``: the searches the tokens had, each ``((N, 2) centre shifts px, radius px)``: a
    square window per token around its previous centre plus the shift. True when more than half
    of the tokens' predicted shifts (:func:`predicted_tokens`) fall outside all of them.
    """
    uv = np.asarray(uv_prev_px, dtype=np.float64).reshape(-1, 2)
    if len(uv) == 0:
        return False
    pred, _ = predicted_tokens(camera, motion, uv)
    shift = pred - uv
    outside = np.all(np.isfinite(shift), axis=1)
    for centres, radius in windows:
        outside &= np.max(np.abs(shift - centres), axis=1) > radius
    return float(np.mean(outside)) > 0.5


def token_gate(
    camera: Camera,
    motion: FeatureMotion,
    uv_prev_px: np.ndarray,
    uv_curr_px: np.ndarray,
    token_sigma_px: float,
    sigmas: float,
) -> np.ndarray:
    """``(N,) bool``: the tracked tokens ``(N, 2)`` -> ``(N, 2)`` px within ``sigmas`` of the feature motion's prediction.

    The distance is a Mahalanobis one under the prediction's covariance plus ``token_sigma_px^2 I``
    (the token's own error, with what the similarity misses: relief, the lens). A lost track (NaN) is out.
    """
    pred, cov = predicted_tokens(camera, motion, uv_prev_px)
    res = np.asarray(uv_curr_px, dtype=np.float64).reshape(-1, 2) - pred
    tot = cov + np.eye(2) * token_sigma_px**2
    keep = np.zeros(len(res), dtype=bool)
    for i, (r, c) in enumerate(zip(res, tot)):
        if np.all(np.isfinite(r)):
            keep[i] = float(r @ np.linalg.solve(c, r)) <= sigmas**2
    return keep


def turn_agrees(
    motion: FeatureMotion, dpsi_rad: tuple[float, ...], dpsi_sigma_rad: float | None, sigmas: float
) -> bool:
    """Whether the feature motion's turn agrees with one of the heading changes ``dpsi_rad`` the compass gives.

    The seabed turns the other way on the image (a level camera looking down: ``theta = -dpsi``).
    Allowed: ``sigmas`` times both standard deviations, plus ``_TURN_SLACK_RAD`` (tilt changes, the
    lens). No compass (``dpsi_sigma_rad`` None or infinite): nothing to check against.
    """
    if dpsi_sigma_rad is None or not math.isfinite(dpsi_sigma_rad):
        return True
    sigma = math.hypot(dpsi_sigma_rad, motion.rotation_sigma_rad)
    gaps = [abs(math.remainder(motion.rotation_rad + d, math.tau)) for d in dpsi_rad]
    return min(gaps) <= sigmas * sigma + _TURN_SLACK_RAD


def _grid(camera: Camera, n: int = 5, share: float = 0.6) -> np.ndarray:
    """``(n*n, 2)`` ideal pixels on a grid over the middle ``share`` of the image."""
    u = camera.cx_px + share * 0.5 * camera.width_px * np.linspace(-1.0, 1.0, n)
    v = camera.cy_px + share * 0.5 * camera.height_px * np.linspace(-1.0, 1.0, n)
    uu, vv = np.meshgrid(u, v)
    return np.column_stack([uu.ravel(), vv.ravel()])


def _speed_of(camera: Camera, params: np.ndarray, grid: np.ndarray, step: dict[str, Any]) -> SpeedMeasurement:
    """The speed of the grid's points moved by the similarity ``params`` (:func:`speed_from_tokens`, exact points)."""
    jac = similarity_design(grid).reshape(len(grid), 2, 4)
    moved = np.einsum("nij,j->ni", jac, params)
    return speed_from_tokens(camera, distort_pixels(camera, grid), distort_pixels(camera, moved), **step)


def feature_speed(camera: Camera, motion: FeatureMotion, n_tokens: int, step: dict[str, Any]) -> SpeedMeasurement:
    """The feature motion as the step's speed: ``ok`` with ``source="features"``, or not ok with the reason.

    ``step``: the keyword arguments of :func:`speed_from_tokens` beyond the camera and the token
    arrays (altitudes, ``dt_s``, the turn prior, attitudes, ``config``...). A grid of points moved
    exactly by the similarity gives the speed through the same geometry as the tokens (tilt, lens,
    altitudes); its covariance is the one those exact points leave (the floors, the altitude's scale
    error) plus ``J C J^T``, ``C`` the similarity's covariance and ``J`` the speed's derivative in
    its parameters (finite differences). ``n_tokens``: the tokens given (the mask's length; none is
    counted as an inlier).
    """
    grid = _grid(camera)
    base = _speed_of(camera, motion.params, grid, step)
    mask = np.zeros(n_tokens, dtype=bool)
    mask.setflags(write=False)
    if not base.ok:
        return dataclasses.replace(base, n_tokens=n_tokens, inlier_mask=mask, reason=f"features: {base.reason}")
    jac = np.zeros((2, 4))
    for j, h in enumerate(_PARAM_STEPS):
        moved = _speed_of(camera, motion.params + h * np.eye(4)[j], grid, step)
        if not moved.ok:
            return dataclasses.replace(
                base, ok=False, n_tokens=n_tokens, n_inliers=0, inlier_mask=mask, reason="features: unstable speed"
            )
        jac[:, j] = (moved.speed_mps - base.speed_mps) / h
    cov = np.asarray(base.cov_mps2) + jac @ motion.cov_params @ jac.T
    cov = 0.5 * (cov + cov.T)
    cov.setflags(write=False)
    dpsi_sigma = max(base.dpsi_sigma_rad, motion.rotation_sigma_rad) if math.isfinite(base.dpsi_sigma_rad) else math.inf
    return dataclasses.replace(
        base,
        cov_mps2=cov,
        n_tokens=n_tokens,
        n_inliers=0,
        inlier_mask=mask,
        dpsi_sigma_rad=dpsi_sigma,
        relief_sample=float("nan"),
        token_var_px2=float("nan"),
        token_dof=0.0,
        source="features",
    )
