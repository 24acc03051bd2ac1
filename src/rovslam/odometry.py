"""Motion-from-tokens speed estimator: surge and sway from speed-template displacements.

A speed template ("token") is a small seabed patch seen at pixel ``uv_prev`` in frame k and
found again at ``uv_curr`` in frame k+1. Each pixel is mapped onto the seabed through the
(possibly tilted, distorted, yaw-offset) camera with :func:`rovslam.camera.pixels_to_ground`,
giving level-frame offsets ``g`` (forward, starboard) in metres. A fixed seabed point P
satisfies ``P = pos_k + R(psi_k) g_prev = pos_k+1 + R(psi_k+1) g_curr``, so the displacement
of the vehicle over the step, in the level frame of step k, is::

    d = g_prev - R(dpsi) g_curr,    dpsi = psi_k+1 - psi_k

(the seabed moves opposite to the vehicle: "mirrored motion") and ``[u, v] = d / dt`` is
exactly the input of the prediction (1) of the filter.

The estimate is robust to wrong matches: every token's displacement and the component-wise
median are hypotheses, the one with the best truncated-residual (MSAC) score wins, the
inliers (residual within ``outlier_threshold_px``) are averaged and re-selected once. Its
covariance Q (the Q(k) of equation (1)) combines the inlier spread (standard error of the
mean, each token's variance floored at ``token_sigma_px``), the altitude uncertainty (a
scale error: ``speed * sigma_Z / Z``) and a floor ``min_speed_sigma_mps``.

:func:`speed_from_tokens` is the pure operation; :class:`SpeedEstimator` is the thin
stateful wrapper that holds the last good speed when a frame gives no usable tokens and grows
its covariance with the gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.camera import Camera, pixels_to_ground, rot2, wrap_angle
from rovslam.config import OdometryConfig
from rovslam.errors import InvalidArgumentError, InvalidMeasurementError, finite_scalar

__all__ = ["SpeedMeasurement", "SpeedEstimator", "speed_from_tokens"]

# At most this many single-token hypotheses are scored (plus the median); the pairwise
# residual table is then at most 65 x N, whatever N.
_MAX_HYPOTHESES = 64


@dataclass(frozen=True, eq=False)
class SpeedMeasurement:
    """Surge and sway over one frame step, body (level) frame, with the covariance Q of (1).

    Attributes:
        ok: False when the tokens gave no usable speed; the values are then the held last
            speed (:class:`SpeedEstimator`) or zero (:func:`speed_from_tokens`).
        surge_mps, sway_mps: body-frame speed over the ground (forward, starboard).
        cov_mps2: (2, 2) covariance Q of (surge, sway).
        n_tokens: tokens given.
        n_inliers: tokens that agree with the consensus (0 when not ok).
        inlier_mask: (n_tokens,) bool, True for the tokens used.
        reason: "" when ok, else why ("no tokens", "too few tokens", "no consensus",
            "ambiguous consensus", "implausible speed" (above ``max_speed_mps``),
            "implausible acceleration").
    """

    ok: bool
    surge_mps: float
    sway_mps: float
    cov_mps2: np.ndarray
    n_tokens: int
    n_inliers: int
    inlier_mask: np.ndarray
    reason: str
    dpsi_rad: float = 0.0  # heading change used (compass difference fused with the tokens' rotation)
    dpsi_sigma_rad: float = float("inf")  # its standard deviation (inf: nothing measured it)

    @property
    def speed_mps(self) -> np.ndarray:
        """(2,) [surge, sway]."""
        return np.array([self.surge_mps, self.sway_mps])


def _scalar(name: str, value: float, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite float, or InvalidMeasurementError saying what was wrong."""
    return finite_scalar(
        name, value, positive=positive, nonnegative=nonnegative,
        nan_hint="the speed estimate; check the sensor reading or drop the frame",
    )


def _attitude(name: str, value) -> tuple[float, float]:
    try:
        roll, pitch = value
    except (TypeError, ValueError):
        raise InvalidMeasurementError(f"{name} must be a pair (roll_rad, pitch_rad), got {value!r}") from None
    return (_scalar(f"{name} roll", roll), _scalar(f"{name} pitch", pitch))


def _token_array(name: str, uv) -> np.ndarray:
    a = np.asarray(uv, dtype=np.float64)
    if a.size == 0:
        return a.reshape(0, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise InvalidArgumentError(f"{name} must be an (N, 2) array of pixels (u, v), got shape {a.shape}")
    return a


def _floor_eigenvalues(cov: np.ndarray, floor_var: float) -> np.ndarray:
    """(2, 2) symmetric matrix with its eigenvalues raised to at least ``floor_var`` (closed form)."""
    a, c = float(cov[0, 0]), float(cov[1, 1])
    b = 0.5 * float(cov[0, 1] + cov[1, 0])
    mid = 0.5 * (a + c)
    half = float(np.hypot(0.5 * (a - c), b))
    lam1, lam2 = mid + half, mid - half
    if lam2 >= floor_var:
        return np.array([[a, b], [b, c]])
    if lam1 <= floor_var:  # both eigenvalues below the floor
        return np.eye(2) * floor_var
    # Only lam2 is raised: C + (floor - lam2) v2 v2^T with v2 v2^T = (lam1 I - C) / (lam1 - lam2).
    k = (floor_var - lam2) / (lam1 - lam2)
    return np.array([[a + k * (lam1 - a), b - k * b], [b - k * b, c + k * (lam1 - c)]])


def _failure(n_tokens: int, reason: str, config: OdometryConfig) -> SpeedMeasurement:
    mask = np.zeros(n_tokens, dtype=bool)
    mask.setflags(write=False)
    cov = np.eye(2) * config.initial_speed_sigma_mps**2
    cov.setflags(write=False)
    return SpeedMeasurement(False, 0.0, 0.0, cov, n_tokens, 0, mask, reason)


def speed_from_tokens(
    camera: Camera,
    uv_prev_px: np.ndarray,
    uv_curr_px: np.ndarray,
    altitude_prev_m: float,
    altitude_curr_m: float,
    dt_s: float,
    dpsi_rad: float = 0.0,
    altitude_sigma_m: float = 0.0,
    attitude_prev_rad: tuple[float, float] = (0.0, 0.0),
    attitude_curr_rad: tuple[float, float] = (0.0, 0.0),
    config: OdometryConfig = OdometryConfig(),
    dpsi_sigma_rad: float | None = None,
) -> SpeedMeasurement:
    """Surge and sway from token displacements between two consecutive frames.

    Args:
        camera: the camera (intrinsics, distortion, yaw offset).
        uv_prev_px: (N, 2) token centres in the previous frame (distorted pixels).
        uv_curr_px: (N, 2) where the same tokens were found in the current frame. A row with
            a NaN (a lost track) is not used and is reported as an outlier.
        altitude_prev_m, altitude_curr_m: image depth Z of each frame, > 0.
        dt_s: real time between the two frames (> 0); dropped frames make it longer.
        dpsi_rad: heading change psi_curr - psi_prev.
        altitude_sigma_m: standard deviation of Z (scale error of the speed).
        attitude_prev_rad, attitude_curr_rad: (roll, pitch) of each frame; (0, 0) assumes a
            level camera, as the paper does.
        config: thresholds, token noise and floors.
        dpsi_sigma_rad: standard deviation of ``dpsi_rad`` (from differencing a noisy compass).
            When given, the rotation of the inlier tokens about their centroid (a 2-D
            Procrustes fit) is fused with ``dpsi_rad``, variance-weighted: 8 tokens spread over
            the image measure the heading change to a few 1e-4 rad, far better than a compass
            difference, and an error in dpsi moves every off-centre token.

    Returns:
        A :class:`SpeedMeasurement`; ``ok=False`` (zero speed, covariance
        ``initial_speed_sigma_mps**2 I``) when there are too few tokens or no consensus.

    Raises:
        InvalidMeasurementError: NaN/infinite/non-positive altitude, time step or attitude,
            or token arrays of the wrong shape.
    """
    z_prev = _scalar("altitude_prev_m", altitude_prev_m, positive=True)
    z_curr = _scalar("altitude_curr_m", altitude_curr_m, positive=True)
    dt = _scalar("dt_s", dt_s, positive=True)
    dpsi = _scalar("dpsi_rad", dpsi_rad)
    sigma_z = _scalar("altitude_sigma_m", altitude_sigma_m, nonnegative=True)
    roll0, pitch0 = _attitude("attitude_prev_rad", attitude_prev_rad)
    roll1, pitch1 = _attitude("attitude_curr_rad", attitude_curr_rad)
    uv0 = _token_array("uv_prev_px", uv_prev_px)
    uv1 = _token_array("uv_curr_px", uv_curr_px)
    if uv0.shape != uv1.shape:
        raise InvalidArgumentError(
            f"uv_prev_px and uv_curr_px must hold the same tokens, got shapes {uv0.shape} and {uv1.shape}"
        )
    n_tokens = uv0.shape[0]
    if n_tokens == 0:
        return _failure(0, "no tokens", config)

    # Each pixel onto the seabed through the (tilted) camera, then the mirrored motion
    # d = g_prev - R(dpsi) g_curr, expressed in the level frame of the previous step (eq. 1).
    g_prev = pixels_to_ground(camera, uv0, z_prev, roll0, pitch0)
    g_curr = pixels_to_ground(camera, uv1, z_curr, roll1, pitch1)
    d_m = g_prev - g_curr @ rot2(dpsi).T
    valid = np.all(np.isfinite(d_m), axis=1)
    n_valid = int(valid.sum())
    if n_valid < config.min_inliers:
        return _failure(n_tokens, "too few tokens" if n_valid else "no tokens", config)

    z_mean = 0.5 * (z_prev + z_curr)
    px_per_m = camera.focal_px / z_mean
    thr2 = config.outlier_threshold_px**2
    if dpsi_sigma_rad is not None and n_valid >= 3:
        # A noisy compass difference turns every off-centre token by its error (0.007 rad moves a
        # token 150 px from the centre by 1 px): take the heading change from token pairs first.
        dpsi = _rotation_consensus(
            g_prev[valid], g_curr[valid], dpsi, config.outlier_threshold_px / px_per_m, float(dpsi_sigma_rad)
        )
        d_m = g_prev - g_curr @ rot2(dpsi).T
    dv_px = d_m[valid] * px_per_m  # (M, 2) displacements in pixels, for the threshold

    # Consensus: the median and single-token hypotheses, scored by truncated squared residuals.
    if n_valid > _MAX_HYPOTHESES:
        pick = np.linspace(0, n_valid - 1, _MAX_HYPOTHESES).astype(np.intp)
        singles = dv_px[pick]
    else:
        singles = dv_px
    hyps = np.vstack([np.median(dv_px, axis=0), singles])  # (K, 2)
    diff = dv_px[None, :, :] - hyps[:, None, :]
    r2 = np.einsum("kmj,kmj->km", diff, diff)  # (K, M)
    score = np.minimum(r2, thr2).sum(axis=1)
    support = (r2 <= thr2).sum(axis=1)
    best = int(np.argmin(score))
    inl = r2[best] <= thr2
    if int(inl.sum()) >= 1:
        centre = dv_px[inl].sum(axis=0) / np.count_nonzero(inl)
        res = dv_px - centre
        inl = np.einsum("mj,mj->m", res, res) <= thr2  # one re-selection around the mean
    n_inl = int(inl.sum())
    if n_inl < config.min_inliers:
        return _failure(n_tokens, "no consensus", config)
    centre = dv_px[inl].sum(axis=0) / n_inl
    # Two disjoint groups with equal support: refuse rather than pick one at random.
    rivals = (support >= n_inl) & (np.sum((hyps - centre) ** 2, axis=1) > 4.0 * thr2)
    if np.any(rivals):
        return _failure(n_tokens, "ambiguous consensus", config)

    dpsi_sigma = float("inf")
    if dpsi_sigma_rad is not None and n_inl >= 2:
        dpsi, dpsi_sigma = _fuse_rotation(
            g_prev[valid][inl], g_curr[valid][inl], dpsi, float(dpsi_sigma_rad), config.token_sigma_px / px_per_m
        )
        d_m = g_prev - g_curr @ rot2(dpsi).T
        res = d_m[valid] * px_per_m - centre
        inl = np.einsum("mj,mj->m", res, res) <= thr2
        n_inl = int(inl.sum())
        if n_inl < config.min_inliers:
            return _failure(n_tokens, "no consensus", config)
    speeds = d_m[valid][inl] / dt  # (n_inl, 2) m/s, one per inlier token
    speed = speeds.sum(axis=0) / n_inl
    if float(np.hypot(speed[0], speed[1])) > config.max_speed_mps:
        return _failure(n_tokens, "implausible speed", config)
    # Q: standard error of the mean from the inlier spread, each token's variance floored
    # at the a-priori token noise; plus the altitude scale error; plus the floor.
    token_var = (config.token_sigma_px / px_per_m / dt) ** 2
    dev = speeds - speed
    spread = dev.T @ dev / (n_inl - 1) if n_inl >= 2 else np.zeros((2, 2))
    cov = _floor_eigenvalues(spread, token_var) / n_inl
    rel_z = sigma_z / z_mean
    cov = cov + rel_z**2 * np.outer(speed, speed)
    cov = _floor_eigenvalues(cov, config.min_speed_sigma_mps**2)
    cov.setflags(write=False)

    mask = np.zeros(n_tokens, dtype=bool)
    mask[np.flatnonzero(valid)[inl]] = True
    mask.setflags(write=False)
    return SpeedMeasurement(
        True, float(speed[0]), float(speed[1]), cov, n_tokens, n_inl, mask, "", float(dpsi), dpsi_sigma
    )


def _rotation_consensus(
    a_m: np.ndarray, b_m: np.ndarray, dpsi_rad: float, thr_m: float, prior_sigma_rad: float
) -> float:
    """The heading change best supported by the tokens: ``a ~ R(theta) b + d``, (M, 2) each.

    Hypotheses: the prior ``dpsi_rad`` and the rotation of every token pair with a baseline
    of at least eight thresholds; each is scored by the truncated residuals about its median
    translation plus half a threshold squared per prior variance away from ``dpsi_rad`` (a
    Gaussian prior, MAP-style): when a cluster of wrong tokens (a large marine-snow particle
    under three tokens) supports another rotation as well as the seabed does, the rotation
    nearer the compass wins. Returns the winning rotation.
    """
    i, j = np.triu_indices(len(a_m), 1)
    da, db = a_m[i] - a_m[j], b_m[i] - b_m[j]
    keep = np.einsum("kj,kj->k", db, db) > (8.0 * thr_m) ** 2
    th = np.arctan2(da[keep, 1], da[keep, 0]) - np.arctan2(db[keep, 1], db[keep, 0])
    hyps = np.concatenate([[dpsi_rad], dpsi_rad + wrap_angle(th - dpsi_rad)])
    c, s = np.cos(hyps)[:, None], np.sin(hyps)[:, None]
    t = np.stack([a_m[None, :, 0] - (c * b_m[:, 0] - s * b_m[:, 1]),
                  a_m[None, :, 1] - (s * b_m[:, 0] + c * b_m[:, 1])], axis=-1)  # (K, M, 2)
    res = t - np.median(t, axis=1, keepdims=True)
    score = np.minimum(np.einsum("kmj,kmj->km", res, res), thr_m**2).sum(axis=1)
    score += 0.5 * thr_m**2 * ((hyps - dpsi_rad) / prior_sigma_rad) ** 2
    return float(hyps[int(np.argmin(score))])


def _fuse_rotation(
    g_prev_m: np.ndarray, g_curr_m: np.ndarray, dpsi_rad: float, dpsi_sigma_rad: float, token_sigma_m: float
) -> tuple[float, float]:
    """Fuse a prior heading change with the rotation of matched seabed points.

    ``g_prev ~ R(dpsi) g_curr + d`` (both (M, 2)); the least-squares rotation of the centred
    point sets is ``atan2(sum b x a, sum b . a)`` with variance ``2 sigma_g^2 / sum |b|^2``.
    Returns the variance-weighted (dpsi, sigma).
    """
    a = g_prev_m - g_prev_m.mean(axis=0)
    b = g_curr_m - g_curr_m.mean(axis=0)
    spread_m2 = float(np.sum(b * b))
    if spread_m2 <= 0.0:
        return dpsi_rad, dpsi_sigma_rad
    theta = float(np.arctan2(np.sum(b[:, 0] * a[:, 1] - b[:, 1] * a[:, 0]), np.sum(b * a)))
    var_tok = 2.0 * token_sigma_m**2 / spread_m2
    var_prior = dpsi_sigma_rad**2
    # Wrap the token rotation next to the prior so that the weighted mean is meaningful.
    theta = dpsi_rad + wrap_angle(theta - dpsi_rad)
    w = var_prior / (var_prior + var_tok) if np.isfinite(var_prior) else 1.0
    fused = dpsi_rad + w * (theta - dpsi_rad)
    var = var_tok * var_prior / (var_tok + var_prior) if np.isfinite(var_prior) else var_tok
    return float(fused), float(np.sqrt(var))


class SpeedEstimator:
    """Stateful wrapper of :func:`speed_from_tokens` that bridges frames without tokens.

    When a step gives no usable speed, :meth:`measure` returns ``ok=False`` with the last good
    speed and its covariance grown by ``(gap_speed_sigma_mps * gap_s)**2 I``, ``gap_s`` being
    the time since the last good measurement (the real time steps, so dropped frames count).
    Before any good measurement the held speed is zero with ``initial_speed_sigma_mps``.
    """

    def __init__(self, config: OdometryConfig = OdometryConfig()):
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the held speed (as at the start of a sequence)."""
        self._last: SpeedMeasurement | None = None
        self._gap_s = 0.0

    @property
    def last_good(self) -> SpeedMeasurement | None:
        """The last ok measurement, or None."""
        return self._last

    @property
    def gap_s(self) -> float:
        """Seconds since the last ok measurement (0 right after one)."""
        return self._gap_s

    def _plausible(self, m: SpeedMeasurement, dt_s: float) -> bool:
        """Whether the speed change since the last good one is within what the vehicle can do.

        A consensus of a few wrong matches (turbid water, particles) can agree on a wrong
        motion; no ROV changes its speed by 5 cm/s in 0.2 s. Allowed: ``max_accel_mps2`` times
        the time since the last good speed, plus three standard deviations of the change.
        """
        if self._last is None or self.config.max_accel_mps2 <= 0:
            return True
        dv = m.speed_mps - self._last.speed_mps
        sigma = float(np.sqrt(np.trace(m.cov_mps2 + self._last.cov_mps2)))
        return float(np.hypot(*dv)) <= self.config.max_accel_mps2 * (dt_s + self._gap_s) + 3.0 * sigma

    def measure(
        self,
        camera: Camera,
        uv_prev_px: np.ndarray,
        uv_curr_px: np.ndarray,
        altitude_prev_m: float,
        altitude_curr_m: float,
        dt_s: float,
        dpsi_rad: float = 0.0,
        altitude_sigma_m: float = 0.0,
        attitude_prev_rad: tuple[float, float] = (0.0, 0.0),
        attitude_curr_rad: tuple[float, float] = (0.0, 0.0),
        dpsi_sigma_rad: float | None = None,
    ) -> SpeedMeasurement:
        """Same arguments as :func:`speed_from_tokens` (without ``config``)."""
        m = speed_from_tokens(
            camera, uv_prev_px, uv_curr_px, altitude_prev_m, altitude_curr_m, dt_s, dpsi_rad,
            altitude_sigma_m, attitude_prev_rad, attitude_curr_rad, self.config, dpsi_sigma_rad,
        )
        if m.ok and self._plausible(m, float(dt_s)):
            self._last = m
            self._gap_s = 0.0
            return m
        return self.hold(dt_s, "implausible acceleration" if m.ok else m.reason, m.n_tokens, m.inlier_mask)

    def hold(
        self, dt_s: float, reason: str = "no tokens", n_tokens: int = 0, inlier_mask: np.ndarray | None = None
    ) -> SpeedMeasurement:
        """A step without a usable speed: the last good speed, its covariance grown by the gap (``ok=False``)."""
        if inlier_mask is None:
            inlier_mask = np.zeros(n_tokens, dtype=bool)
        self._gap_s += float(dt_s)
        grow = (self.config.gap_speed_sigma_mps * self._gap_s) ** 2
        if self._last is None:
            surge = sway = 0.0
            base = np.eye(2) * self.config.initial_speed_sigma_mps**2
        else:
            surge, sway = self._last.surge_mps, self._last.sway_mps
            base = self._last.cov_mps2
        cov = base + grow * np.eye(2)
        cov.setflags(write=False)
        return SpeedMeasurement(False, surge, sway, cov, n_tokens, 0, inlier_mask, reason)
