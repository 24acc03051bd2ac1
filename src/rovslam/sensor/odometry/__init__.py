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
its covariance with the gap. The hypothesis search and the rigid (similarity) fit are in
:mod:`rovslam.sensor.odometry.rigid`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rovslam.averages import DecayingMean
from rovslam.camera import Camera, pixels_to_ground, rot2
from rovslam.config import OdometryConfig
from rovslam.errors import InvalidArgumentError, InvalidMeasurementError, finite_scalar
from rovslam.sensor.odometry.rigid import (
    _CHI2_2DOF_99,
    _MAX_HYPOTHESES,  # noqa: F401 (the tests read it from here)
    _best_hypothesis,
    _floor_eigenvalues,
    _rigid_fit,
    _RigidFit,
    _rival_consensus,
    relief_sample,
)

__all__ = ["SpeedMeasurement", "SpeedEstimator", "speed_from_tokens"]

# Time over which the relief's height spread under the tokens is averaged (it changes over metres).
RELIEF_TAU_S = 5.0
ACCEL_TAU_S = 30.0
"""Seconds over which :class:`SpeedEstimator` averages the accelerations its speeds show."""
TOKEN_NOISE_TAU_S = 10.0
"""Seconds over which :class:`SpeedEstimator` pools the tokens' residual scatter (``token_var_px2``)."""


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
    dpsi_rad: float = 0.0  # heading change used (the tokens' turn with the compass as a weak prior)
    dpsi_sigma_rad: float = float("inf")  # its standard deviation (inf: nothing measured it)
    relief_sample: float = float("nan")  # this frame's relief variance sample (:func:`relief_sample`)
    token_var_px2: float = float("nan")  # this step's per-axis token residual variance after the fit, pixels^2
    token_dof: float = 0.0  # its degrees of freedom
    source: str = "tokens"  # what measured it: "tokens", or "features" (the feature motion, rovslam.pipeline.assist)

    @property
    def speed_mps(self) -> np.ndarray:
        """(2,) [surge, sway]."""
        return np.array([self.surge_mps, self.sway_mps])


def _scalar(name: str, value: float, *, positive: bool = False, nonnegative: bool = False) -> float:
    """A finite float, or InvalidMeasurementError saying what was wrong."""
    return finite_scalar(
        name,
        value,
        positive=positive,
        nonnegative=nonnegative,
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
    altitude_samples: int = 1,
    relief_var: float = 0.0,
    attitude_noise_rad: float = 0.0,
    token_var_px2: float = 0.0,
    turn_relief_var: float | None = None,
) -> SpeedMeasurement:
    """Surge and sway (and the turn) from token displacements between two consecutive frames.

    Args:
        camera: the camera (intrinsics, distortion, yaw offset).
        uv_prev_px: (N, 2) token centres in the previous frame (distorted pixels).
        uv_curr_px: (N, 2) where the same tokens were found in the current frame. A row with
            a NaN (a lost track) is not used and is reported as an outlier.
        altitude_prev_m, altitude_curr_m: image depth Z of each frame, > 0.
        dt_s: real time between the two frames (> 0); dropped frames make it longer.
        dpsi_rad: heading change psi_curr - psi_prev from the compass (a prior).
        altitude_sigma_m: standard deviation of Z (scale error of the speed).
        attitude_prev_rad, attitude_curr_rad: (roll, pitch) of each frame; (0, 0) assumes a
            level camera, as the paper does.
        config: thresholds, token noise and floors.
        dpsi_sigma_rad: standard deviation of ``dpsi_rad`` (a compass difference: mostly
            noise at 5 Hz and above). When given, the turn is estimated with the translation
            from the tokens (a joint rigid fit) and ``dpsi_rad`` is only a weak prior; None uses
            ``dpsi_rad`` as it is (the paper's constant-heading case).
        altitude_samples: how many seabed points the altitude came from (laser spots used, 1
            for a sonar or an assumed value): the relief under them and under the tokens differ.
        relief_var: relative variance of the seabed heights under the tokens (``sigma_s^2``
            of :func:`relief_sample`), as averaged over recent frames by
            :class:`SpeedEstimator`; 0 for a flat seabed. One frame's tokens are too few to
            estimate it alone; the measurement returns this frame's sample. It widens the speed's
            covariance and, with ``config.relief_turn_gain``, sets how much the turn fit
            discounts the tokens' displacements along the motion.
        attitude_noise_rad: reading-to-reading noise of the roll and pitch given: an error
            ``e`` in one frame's attitude moves all its seabed points by ``Z e``, the same for
            every token (so their scatter cannot show it).
        token_var_px2: the tokens' residual variance (pixels^2, per axis) over recent steps, as
            pooled by :class:`SpeedEstimator`; it counts as ``config.token_noise_prior_dof``
            degrees of freedom in this step's noise when larger than what this step's tokens
            show (0: each step alone).
        turn_relief_var: the relief the turn fit discounts (``config.relief_turn_gain``), when not
            ``relief_var``: :class:`SpeedEstimator` gives the share of it its frames measured, not its
            prior (None: ``relief_var``).

    Returns:
        A :class:`SpeedMeasurement`; ``ok=False`` (zero speed, covariance
        ``initial_speed_sigma_mps**2 I``) when there are too few tokens or no consensus.

    Raises:
        InvalidMeasurementError: NaN/infinite/non-positive altitude, time step or attitude.
        InvalidArgumentError: token arrays of the wrong shape.
    """
    step = _checked_step(
        altitude_prev_m,
        altitude_curr_m,
        dt_s,
        dpsi_rad,
        altitude_sigma_m,
        attitude_prev_rad,
        attitude_curr_rad,
        uv_prev_px,
        uv_curr_px,
        token_var_px2,
        attitude_noise_rad,
    )
    n_tokens = step.uv_prev_px.shape[0]
    turn_relief = relief_var if turn_relief_var is None else turn_relief_var
    found = _token_consensus(camera, step, dpsi_sigma_rad, config, turn_relief)
    if isinstance(found, str):
        return _failure(n_tokens, found, config)
    # d is in the previous frame's scale (its altitude); the fitted zoom splits the ratio's error between both
    speed = found.d_m * (0.5 * (1.0 + found.fit.scale)) / step.dt_s
    if float(np.hypot(speed[0], speed[1])) > config.max_speed_mps:
        return _failure(n_tokens, "implausible speed", config)
    cov = _speed_covariance(found, speed, step, config, relief_var, altitude_samples)
    return _measurement(found, speed, cov, step)


@dataclass(frozen=True, eq=False)
class _Step:
    """One step's checked inputs (see :func:`speed_from_tokens`); token arrays ``(N, 2)`` pixels."""

    z_prev_m: float
    z_curr_m: float
    dt_s: float
    dpsi_rad: float
    sigma_z_m: float
    attitude_prev_rad: tuple[float, float]
    attitude_curr_rad: tuple[float, float]
    uv_prev_px: np.ndarray
    uv_curr_px: np.ndarray
    token_var_px2: float
    attitude_noise_rad: float


def _checked_step(
    altitude_prev_m,
    altitude_curr_m,
    dt_s,
    dpsi_rad,
    altitude_sigma_m,
    attitude_prev_rad,
    attitude_curr_rad,
    uv_prev_px,
    uv_curr_px,
    token_var_px2,
    attitude_noise_rad,
) -> _Step:
    """The inputs of :func:`speed_from_tokens` as numbers and arrays, or the error saying what is wrong."""
    z_prev = _scalar("altitude_prev_m", altitude_prev_m, positive=True)
    z_curr = _scalar("altitude_curr_m", altitude_curr_m, positive=True)
    dt = _scalar("dt_s", dt_s, positive=True)
    dpsi = _scalar("dpsi_rad", dpsi_rad)
    sigma_z = _scalar("altitude_sigma_m", altitude_sigma_m, nonnegative=True)
    att0 = _attitude("attitude_prev_rad", attitude_prev_rad)
    att1 = _attitude("attitude_curr_rad", attitude_curr_rad)
    uv0 = _token_array("uv_prev_px", uv_prev_px)
    uv1 = _token_array("uv_curr_px", uv_curr_px)
    if uv0.shape != uv1.shape:
        raise InvalidArgumentError(
            f"uv_prev_px and uv_curr_px must hold the same tokens, got shapes {uv0.shape} and {uv1.shape}"
        )
    token_var = _scalar("token_var_px2", token_var_px2, nonnegative=True)
    att_noise = _scalar("attitude_noise_rad", attitude_noise_rad, nonnegative=True)
    return _Step(z_prev, z_curr, dt, dpsi, sigma_z, att0, att1, uv0, uv1, token_var, att_noise)


def _ground_offsets(camera: Camera, step: _Step) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)``, ``(N, 2)`` each: every token's seabed offset (forward, starboard) in each frame, metres.

    Each pixel onto the seabed through the (tilted) camera: a = g_prev, b = g_curr, and the
    mirrored motion a = R(dpsi) b + d, d the displacement in the level frame of the previous step
    (1). A lost track (NaN) gives a NaN row.
    """
    roll0, pitch0 = step.attitude_prev_rad
    roll1, pitch1 = step.attitude_curr_rad
    a_all = pixels_to_ground(camera, step.uv_prev_px, step.z_prev_m, roll0, pitch0)
    b_all = pixels_to_ground(camera, step.uv_curr_px, step.z_curr_m, roll1, pitch1)
    return a_all, b_all


@dataclass(frozen=True)
class _FitScales:
    """The step's image scale and the fit's noises and thresholds, in metres on the seabed."""

    px_per_m: float
    joint: bool  # the turn is estimated with the translation (the compass a weak prior)
    prior_var_rad2: float  # the compass turn's variance (0 when not joint)
    sigma0_m: float  # one token's displacement noise (the floor)
    pool_var_m2: float  # the dive's pooled token noise (0: each step alone)
    threshold_m: float  # the outlier threshold
    scale_var: float  # the zoom prior's variance (0: a rigid fit)
    along_rel: float = 0.0  # the relief's parallax spread per metre of motion the turn fit discounts (0: none)


def _fit_scales(
    camera: Camera,
    step: _Step,
    n_valid: int,
    dpsi_sigma_rad: float | None,
    config: OdometryConfig,
    relief_var: float = 0.0,
) -> _FitScales:
    """The pixel quantities of ``config`` at this step's altitude, and whether the turn is fitted."""
    px_per_m = camera.focal_px / (0.5 * (step.z_prev_m + step.z_curr_m))
    joint = dpsi_sigma_rad is not None and n_valid >= 2
    prior_var = float(dpsi_sigma_rad) ** 2 if joint else 0.0  # type: ignore[arg-type]
    sigma0 = config.token_sigma_px / px_per_m  # one token's displacement noise, metres (the floor)
    pool_var = step.token_var_px2 / px_per_m**2
    if config.token_noise_prior_dof <= 0:
        pool_var = 0.0
    thr = config.outlier_threshold_px / px_per_m
    # Each frame's altitude is measured on its own: an error in their ratio zooms one frame against the
    # other about the nadir, moving off-centre tokens (over relief the lasers' step-to-step noise is 2 to 3
    # times their sigma). The tokens see that zoom far better than the lasers: a similarity fit, the
    # measured ratio its prior.
    scale_var = 2.0 * (step.sigma_z_m / (0.5 * (step.z_prev_m + step.z_curr_m))) ** 2 if config.token_scale else 0.0
    along_rel = config.relief_turn_gain * math.sqrt(max(relief_var, 0.0)) if joint else 0.0
    return _FitScales(px_per_m, joint, prior_var, sigma0, pool_var, thr, scale_var, along_rel)


def _consensus(
    a: np.ndarray, b: np.ndarray, dpsi_rad: float, sc: _FitScales, config: OdometryConfig
) -> tuple[float, np.ndarray, np.ndarray, _RigidFit | None]:
    """``(theta, d (2,), inlier mask (M,), fit or None)``: the best hypothesis, refitted on its inliers.

    Rigid hypotheses (similarities with ``token_scale``) are scored by truncated residuals and
    the compass prior (MSAC, MAP); the winner's inliers are fitted by least squares and
    re-selected, at most three times, the gate following the residuals they show. ``fit`` is
    None when the inliers were too few to fit.
    """
    theta, d, support = _best_hypothesis(
        a, b, dpsi_rad, sc.prior_var_rad2, sc.threshold_m, sc.sigma0_m, sc.joint, sc.scale_var
    )
    inl = support
    fit = None
    for _ in range(3):  # refit on the inliers; the threshold follows the residuals they show
        if int(inl.sum()) < config.min_inliers:
            break
        fit = _rigid_fit(
            a[inl],
            b[inl],
            theta,
            dpsi_rad,
            sc.prior_var_rad2,
            sc.joint,
            sc.sigma0_m,
            sc.pool_var_m2,
            config.token_noise_prior_dof,
            sc.scale_var,
            sc.along_rel,
        )
        theta, d = fit.theta_rad, fit.d_m
        res = a - fit.scale * (b @ rot2(theta).T) - d
        r2 = np.einsum("mj,mj->m", res, res)
        # the dive's pooled scatter keeps a step whose few tokens happen to agree from gating out its own inliers
        sigma = math.sqrt(max(fit.residual_var_m2, sc.pool_var_m2, sc.sigma0_m**2))
        gate = min(sc.threshold_m, max(_CHI2_2DOF_99**0.5 * sigma, 3.0 * sc.sigma0_m))
        new = r2 <= gate**2
        if np.array_equal(new, inl):
            break
        inl = new
    return theta, d, inl, fit


@dataclass(frozen=True, eq=False)
class _Consensus:
    """The tokens that agree on one motion: the fit on them and what the step's speed is built from.

    ``a``, ``b``: ``(M, 2)`` seabed offsets of the usable tokens (metres); ``valid``: ``(N,)`` which
    tokens given are usable; ``inliers``: ``(M,)`` which usable ones agree.
    """

    a: np.ndarray
    b: np.ndarray
    valid: np.ndarray
    theta_rad: float
    d_m: np.ndarray  # (2,) displacement, the previous frame's level frame
    inliers: np.ndarray
    fit: _RigidFit
    scales: _FitScales
    rival: tuple[np.ndarray, int] | None  # another group's displacement and support, if any

    @property
    def n_valid(self) -> int:
        return self.a.shape[0]

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def _token_consensus(
    camera: Camera, step: _Step, dpsi_sigma_rad: float | None, config: OdometryConfig, relief_var: float = 0.0
) -> _Consensus | str:
    """The tokens' consensus on the step's motion (:func:`_consensus`), or why there is none."""
    if step.uv_prev_px.shape[0] == 0:
        return "no tokens"
    a_all, b_all = _ground_offsets(camera, step)
    valid = np.all(np.isfinite(a_all), axis=1) & np.all(np.isfinite(b_all), axis=1)
    n_valid = int(valid.sum())
    if n_valid < config.min_inliers:
        return "too few tokens" if n_valid else "no tokens"
    a, b = a_all[valid], b_all[valid]
    sc = _fit_scales(camera, step, n_valid, dpsi_sigma_rad, config, relief_var)
    theta, d, inl, fit = _consensus(a, b, step.dpsi_rad, sc, config)
    n_inl = int(inl.sum())
    if fit is None or n_inl < config.min_inliers:
        return "no consensus"
    # Two groups with equal support: refuse rather than pick one.
    rival = _rival_consensus(
        a[~inl], b[~inl], theta, step.dpsi_rad, sc.prior_var_rad2, sc.threshold_m, sc.sigma0_m, sc.joint, sc.scale_var
    )
    if rival is not None and rival[1] >= n_inl:
        return "ambiguous consensus"
    return _Consensus(a, b, valid, theta, d, inl, fit, sc, rival)


def _measurement(found: _Consensus, speed: np.ndarray, cov: np.ndarray, step: _Step) -> SpeedMeasurement:
    """The step's :class:`SpeedMeasurement` from the consensus, its ``(2,)`` speed and ``(2, 2)`` covariance."""
    n_tokens = step.uv_prev_px.shape[0]
    mask = np.zeros(n_tokens, dtype=bool)
    mask[np.flatnonzero(found.valid)[found.inliers]] = True
    mask.setflags(write=False)
    fit, sc, theta, inl = found.fit, found.scales, found.theta_rad, found.inliers
    theta_sigma = math.sqrt(fit.theta_var_rad2) if sc.joint else math.inf
    return SpeedMeasurement(
        True,
        float(speed[0]),
        float(speed[1]),
        cov,
        n_tokens,
        found.n_inliers,
        mask,
        "",
        float(theta if sc.joint else step.dpsi_rad),
        theta_sigma,
        relief_sample(found.a[inl], found.b[inl], theta, found.d_m, fit.scale),
        fit.residual_var_m2 * sc.px_per_m**2,
        fit.residual_dof,
    )


def _speed_covariance(
    found: _Consensus, speed: np.ndarray, step: _Step, config: OdometryConfig, relief_var: float, altitude_samples: int
) -> np.ndarray:
    """The ``(2, 2)`` covariance Q of the speed (read-only): the fit's, plus the errors its tokens cannot show."""
    fit, d, rival, sc = found.fit, found.d_m, found.rival, found.scales
    n_inl, n_valid = found.n_inliers, found.n_valid
    z_prev, z_curr, dt = step.z_prev_m, step.z_curr_m, step.dt_s
    # The tokens' scatter shows their independent errors; an error they all share (block artefacts of
    # a compressed video, a lighting change, interpolation bias) it cannot show: a floor per step.
    cov = fit.cov_d_m2 / dt**2 + np.eye(2) * (config.common_sigma_px / sc.px_per_m / dt) ** 2
    # Relief parallax: the tokens and the altitude see the seabed at different heights.
    n_altitude = max(int(altitude_samples), 1)
    cov = cov + config.relief_scale_gain**2 * max(relief_var, 0.0) * (1.0 / n_inl + 1.0 / n_altitude) * np.outer(
        speed, speed
    )
    cov = cov + (step.sigma_z_m / (0.5 * (z_prev + z_curr))) ** 2 * np.outer(speed, speed)  # altitude: a scale error
    att = step.attitude_noise_rad
    cov = cov + np.eye(2) * (att**2 * (z_prev**2 + z_curr**2) / dt**2)  # each frame's tilt error shifts it all
    if 2 * n_inl < n_valid:  # a minority consensus is not trusted like a majority
        cov = cov * (n_valid / n_inl) ** 2
    if rival is not None:  # another group agrees on another motion: the covariance says so
        gap = (d - rival[0]) / dt
        cov = cov + rival[1] / (n_inl + rival[1]) * np.outer(gap, gap)
    cov = _floor_eigenvalues(cov, config.min_speed_sigma_mps**2)
    cov.setflags(write=False)
    return cov


class SpeedEstimator:
    """Stateful wrapper of :func:`speed_from_tokens` that bridges frames without tokens.

    When a step gives no usable speed, :meth:`measure` returns ``ok=False`` with the last good
    speed held (see :meth:`hold` for its covariance). Before any good measurement the held
    speed is zero with ``initial_speed_sigma_mps``.
    """

    def __init__(self, config: OdometryConfig = OdometryConfig()):
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the held speed and the relief seen (as at the start of a sequence).

        The relief average starts from a prior (``relief_prior_sigma``) that fades with the
        seconds of measurements (time constant ``relief_prior_s``, :attr:`relief_var`): before the
        tokens have seen the seabed, its relief is not known to be flat, and the first steps' Q
        must not say it is.
        """
        self._last: SpeedMeasurement | None = None
        self._last_dt_s = 0.0  # the step of the last good speed
        self._gap_s = 0.0  # seconds since the last good speed (T)
        self._gap_sum_s2 = 0.0  # sum over the gap's steps of T_k dt_k (S)
        self._relief = DecayingMean()  # relief samples, weighted by |d|^4
        self._relief_seen_s = 0.0  # seconds of relief samples since the start: the prior fades with them
        self._accel = DecayingMean()  # the per-axis acceleration variance, m^2/s^4
        self._token = DecayingMean()  # the tokens' residual variance, px^2, weighted by dof

    @property
    def relief_var(self) -> float:
        """The relief's relative height variance under the tokens, averaged over the last seconds (>= 0)."""
        prior_share, data = self._relief_shares()
        return prior_share * self.config.relief_prior_sigma**2 + (1.0 - prior_share) * data

    @property
    def measured_relief_var(self) -> float:
        """:attr:`relief_var` without its prior's share: the relief the frames measured (0 before any).

        The prior keeps the first steps' Q from calling an unseen seabed flat; the turn fit discounts only
        this (``relief_turn_gain``): a relief assumed, not seen, would throw away most of the turn's
        information along the motion (a weight of 0.02 on the real Sparus video's first step decimated
        by 3, whose tokens then lost their consensus to the compass's turn).
        """
        prior_share, data = self._relief_shares()
        return (1.0 - prior_share) * data

    def _relief_shares(self) -> tuple[float, float]:
        """``(the prior's share, the frames' average)`` of :attr:`relief_var`."""
        data = max(self._relief.mean(), 0.0)
        cfg = self.config
        if cfg.relief_prior_s <= 0.0 or cfg.relief_prior_sigma <= 0.0:
            return 0.0, data
        return math.exp(-self._relief_seen_s / cfg.relief_prior_s), data  # the prior's share: 1 at the start

    def _learn_relief(self, sample: float, dt_s: float, step_m2: float) -> None:
        """Exponential average of :func:`relief_sample` over ``RELIEF_TAU_S`` seconds (bias-corrected at the start).

        Each sample is weighted by its step's ``|d|^4`` (``step_m2`` is ``|d|^2``): the sample is a
        residual variance over ``|d|^4``, so a short step (the start, a hover, a turn on the spot)
        divides matching noise by almost nothing; weighted so, the average is the ratio of the
        summed residual variances to the summed ``|d|^4``, which a short step cannot swing.
        """
        if not (math.isfinite(sample) and step_m2 > 0.0):
            return
        self._relief_seen_s += dt_s
        a = math.exp(-dt_s / RELIEF_TAU_S)
        self._relief.add(sample, (1.0 - a) * step_m2 * step_m2, a)

    @property
    def token_var_px2(self) -> float:
        """The tokens' per-axis residual variance after the fit (pixels^2), pooled over the last
        ``TOKEN_NOISE_TAU_S`` seconds of steps, each weighted by its degrees of freedom (0 before any)."""
        return self._token.mean()

    def _learn_token_noise(self, m: SpeedMeasurement, dt_s: float) -> None:
        if not (math.isfinite(m.token_var_px2) and m.token_dof > 0 and dt_s > 0):
            return
        self._token.add(m.token_var_px2, m.token_dof, math.exp(-dt_s / TOKEN_NOISE_TAU_S))

    @property
    def accel_sigma_mps2(self) -> float:
        """The vehicle's acceleration per axis (RMS over the last ``ACCEL_TAU_S`` seconds) its speeds show (>= 0)."""
        return math.sqrt(self._accel.mean())

    def _learn_acceleration(self, m: SpeedMeasurement, dt_s: float) -> None:
        """Average the speed change since the last good speed, less what their noise explains.

        Only consecutive good speeds are compared (a gap's change is what is being bounded).
        The change over one step is ``a dt`` plus both speeds' errors, so a sample is
        ``(|dv|^2 / 2 - tr(C_prev + C_curr) / 2) / dt^2`` per axis, clipped at 0, averaged
        with weights ``dt`` (bias-corrected at the start, as the relief).
        """
        last = self._last
        if last is None or self._gap_s > 0.0 or not dt_s > 0.0:
            return
        dv = m.speed_mps - last.speed_mps
        noise = 0.5 * float(np.trace(m.cov_mps2 + last.cov_mps2))
        sample = max(0.5 * float(dv @ dv) - noise, 0.0) / dt_s**2
        if not math.isfinite(sample):
            return
        a = math.exp(-dt_s / ACCEL_TAU_S)
        self._accel.add(sample, 1.0 - a, a)

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
        altitude_samples: int = 1,
        attitude_noise_rad: float = 0.0,
    ) -> SpeedMeasurement:
        """Same arguments as :func:`speed_from_tokens` (without ``config`` and ``relief_var``)."""
        m = speed_from_tokens(
            camera,
            uv_prev_px,
            uv_curr_px,
            altitude_prev_m,
            altitude_curr_m,
            dt_s,
            dpsi_rad,
            altitude_sigma_m,
            attitude_prev_rad,
            attitude_curr_rad,
            self.config,
            dpsi_sigma_rad,
            altitude_samples,
            self.relief_var,
            attitude_noise_rad,
            self.token_var_px2,
            self.measured_relief_var,
        )
        return self.take(m, dt_s)

    def take(self, m: SpeedMeasurement, dt_s: float) -> SpeedMeasurement:
        """What :meth:`measure` does with its token measurement: learn from it, then :meth:`accept` it.

        ``m``: a token measurement made with this estimator's averages (:meth:`preview`).
        """
        if m.ok:
            self._learn_relief(m.relief_sample, float(dt_s), float(np.sum((m.speed_mps * dt_s) ** 2)))
            self._learn_token_noise(m, float(dt_s))
        return self.accept(m, dt_s)

    def preview(self, camera: Camera, uv_prev_px: np.ndarray, uv_curr_px: np.ndarray, **step) -> SpeedMeasurement:
        """What :meth:`measure` would measure from the tokens (before the plausibility check), its state unchanged."""
        return speed_from_tokens(
            camera,
            uv_prev_px,
            uv_curr_px,
            config=self.config,
            relief_var=self.relief_var,
            token_var_px2=self.token_var_px2,
            turn_relief_var=self.measured_relief_var,
            **step,
        )

    def accept(self, m: SpeedMeasurement, dt_s: float) -> SpeedMeasurement:
        """An ok measurement becomes the last good speed when plausible; else the held speed (:meth:`hold`).

        :meth:`measure` ends here; a speed measured otherwise (the feature motion) enters here, without
        teaching the token averages.
        """
        if m.ok and self._plausible(m, float(dt_s)):
            self._learn_acceleration(m, float(dt_s))
            self._last, self._last_dt_s = m, float(dt_s)
            self._gap_s = self._gap_sum_s2 = 0.0
            return m
        return self.hold(dt_s, "implausible acceleration" if m.ok else m.reason, m.n_tokens, m.inlier_mask)

    def hold(
        self, dt_s: float, reason: str = "no tokens", n_tokens: int = 0, inlier_mask: np.ndarray | None = None
    ) -> SpeedMeasurement:
        """A step without a usable speed: the last good speed held (``ok=False``).

        The held speed's error is the same in every step of the gap: the last good speed's
        error ``e0`` (covariance ``B``) plus a drift growing with the time ``T_k`` since then
        (``g``, an unknown acceleration ``a``: the vehicle may be manoeuvring, a lane end, or
        rocked by the swell while the tokens fail; ``g`` is ``held_speed_drift_mps2`` or, when
        larger, the acceleration the dive's own speeds have shown, :attr:`accel_sigma_mps2`), so step ``k``
        moves the position by ``(e0 + a T_k) dt_k`` too much. Those errors are correlated, but
        the filter adds each step's Q as if independent, so Q is chosen to give the position,
        after every step, the variance of the correlated sum::

            V(T) = (dt_0 + T)^2 B + g^2 S^2,   S = sum_k T_k dt_k,   Q = (V(T) - V(T_prev)) / dt^2

        ``dt_0`` being the last good step (``e0`` already moved the position once there). With
        equal steps that is ``Q = (2n + 1) B + g^2 dt^2 n^3`` at the n-th step of the gap,
        where an independent Q would give ``B + g^2 dt^2 n^2``: a vehicle slowing down at a lane
        end while the tokens fail is then inside its covariance. Before any good speed, ``B``
        is ``initial_speed_sigma_mps^2 I`` and ``dt_0 = 0``.
        """
        if inlier_mask is None:
            inlier_mask = np.zeros(n_tokens, dtype=bool)
        dt = float(dt_s)
        t_prev, s_prev = self._gap_s, self._gap_sum_s2
        self._gap_s += dt
        self._gap_sum_s2 += self._gap_s * dt
        g2 = max(self.config.held_speed_drift_mps2, self.accel_sigma_mps2) ** 2
        grow = g2 * (self._gap_sum_s2**2 - s_prev**2) / dt**2 if dt > 0 else g2 * self._gap_s**2
        if self._last is None:
            surge = sway = 0.0
            b, dt0 = np.eye(2) * self.config.initial_speed_sigma_mps**2, 0.0
        else:
            surge, sway = self._last.surge_mps, self._last.sway_mps
            b, dt0 = self._last.cov_mps2, self._last_dt_s
        base = b * (((dt0 + self._gap_s) ** 2 - (dt0 + t_prev) ** 2) / dt**2 if dt > 0 else 1.0)
        cov = base + grow * np.eye(2)
        cov.setflags(write=False)
        return SpeedMeasurement(False, surge, sway, cov, n_tokens, 0, inlier_mask, reason)
