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

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rovslam.averages import DecayingMean, median0
from rovslam.camera import Camera, drot2, pixels_to_ground, rot2, wrap_angle
from rovslam.config import OdometryConfig
from rovslam.errors import InvalidArgumentError, InvalidMeasurementError, finite_scalar

__all__ = ["SpeedMeasurement", "SpeedEstimator", "speed_from_tokens"]

# Time over which the relief's height spread under the tokens is averaged (it changes over metres).
RELIEF_TAU_S = 5.0
ACCEL_TAU_S = 30.0
"""Seconds over which :class:`SpeedEstimator` averages the accelerations its speeds show."""
TOKEN_NOISE_TAU_S = 10.0
"""Seconds over which :class:`SpeedEstimator` pools the tokens' residual scatter (``token_var_px2``)."""

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
    dpsi_rad: float = 0.0  # heading change used (the tokens' turn with the compass as a weak prior)
    dpsi_sigma_rad: float = float("inf")  # its standard deviation (inf: nothing measured it)
    relief_sample: float = float("nan")  # this frame's relief variance sample (:func:`relief_sample`)
    token_var_px2: float = float("nan")  # this step's per-axis token residual variance after the fit, pixels^2
    token_dof: float = 0.0  # its degrees of freedom

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
    altitude_samples: int = 1,
    relief_var: float = 0.0,
    attitude_noise_rad: float = 0.0,
    token_var_px2: float = 0.0,
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
            estimate it alone; the measurement returns this frame's sample.
        attitude_noise_rad: reading-to-reading noise of the roll and pitch given: an error
            ``e`` in one frame's attitude moves all its seabed points by ``Z e``, the same for
            every token (so their scatter cannot show it).
        token_var_px2: the tokens' residual variance (pixels^2, per axis) over recent steps, as
            pooled by :class:`SpeedEstimator`; it counts as ``config.token_noise_prior_dof``
            degrees of freedom in this step's noise when larger than what this step's tokens
            show (0: each step alone).

    Returns:
        A :class:`SpeedMeasurement`; ``ok=False`` (zero speed, covariance
        ``initial_speed_sigma_mps**2 I``) when there are too few tokens or no consensus.

    Raises:
        InvalidMeasurementError: NaN/infinite/non-positive altitude, time step or attitude.
        InvalidArgumentError: token arrays of the wrong shape.
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

    # Each pixel onto the seabed through the (tilted) camera: a = g_prev, b = g_curr, and the
    # mirrored motion a = R(dpsi) b + d, d the displacement in the level frame of the previous step (1).
    a_all = pixels_to_ground(camera, uv0, z_prev, roll0, pitch0)
    b_all = pixels_to_ground(camera, uv1, z_curr, roll1, pitch1)
    valid = np.all(np.isfinite(a_all), axis=1) & np.all(np.isfinite(b_all), axis=1)
    n_valid = int(valid.sum())
    if n_valid < config.min_inliers:
        return _failure(n_tokens, "too few tokens" if n_valid else "no tokens", config)
    a, b = a_all[valid], b_all[valid]
    px_per_m = camera.focal_px / (0.5 * (z_prev + z_curr))
    joint = dpsi_sigma_rad is not None and n_valid >= 2
    prior_var = float(dpsi_sigma_rad) ** 2 if joint else 0.0
    sigma0 = config.token_sigma_px / px_per_m  # one token's displacement noise, metres (the floor)
    pool_var = _scalar("token_var_px2", token_var_px2, nonnegative=True) / px_per_m**2
    if config.token_noise_prior_dof <= 0:
        pool_var = 0.0
    thr = config.outlier_threshold_px / px_per_m
    # Each frame's altitude is measured on its own: an error in their ratio zooms one frame against the
    # other about the nadir, moving off-centre tokens (over relief the lasers' step-to-step noise is 2 to 3
    # times their sigma). The tokens see that zoom far better than the lasers: a similarity fit, the
    # measured ratio its prior.
    scale_var = 2.0 * (sigma_z / (0.5 * (z_prev + z_curr))) ** 2 if config.token_scale else 0.0

    # Consensus: rigid hypotheses (similarities with token_scale) scored by truncated residuals and the
    # compass prior (MSAC, MAP).
    theta, d, support = _best_hypothesis(a, b, dpsi, prior_var, thr, sigma0, joint, scale_var)
    inl = support
    fit = None
    for _ in range(3):  # refit on the inliers; the threshold follows the residuals they show
        if int(inl.sum()) < config.min_inliers:
            break
        fit = _rigid_fit(a[inl], b[inl], theta, dpsi, prior_var, joint, sigma0, pool_var, config.token_noise_prior_dof,
                         scale_var)
        theta, d = fit.theta_rad, fit.d_m
        res = a - fit.scale * (b @ rot2(theta).T) - d
        r2 = np.einsum("mj,mj->m", res, res)
        # the dive's pooled scatter keeps a step whose few tokens happen to agree from gating out its own inliers
        sigma = math.sqrt(max(fit.residual_var_m2, pool_var, sigma0**2))
        gate = min(thr, max(_CHI2_2DOF_99 ** 0.5 * sigma, 3.0 * sigma0))
        new = r2 <= gate**2
        if np.array_equal(new, inl):
            break
        inl = new
    n_inl = int(inl.sum())
    if fit is None or n_inl < config.min_inliers:
        return _failure(n_tokens, "no consensus", config)
    # Two groups with equal support: refuse rather than pick one.
    rival = _rival_consensus(a[~inl], b[~inl], theta, dpsi, prior_var, thr, sigma0, joint, scale_var)
    if rival is not None and rival[1] >= n_inl:
        return _failure(n_tokens, "ambiguous consensus", config)

    # d is in the previous frame's scale (its altitude); the fitted zoom splits the ratio's error between both
    speed = d * (0.5 * (1.0 + fit.scale)) / dt
    if float(np.hypot(speed[0], speed[1])) > config.max_speed_mps:
        return _failure(n_tokens, "implausible speed", config)
    # The tokens' scatter shows their independent errors; an error they all share (block artefacts of
    # a compressed video, a lighting change, interpolation bias) it cannot show: a floor per step.
    cov = fit.cov_d_m2 / dt**2 + np.eye(2) * (config.common_sigma_px / px_per_m / dt) ** 2
    # Relief parallax: the tokens and the altitude see the seabed at different heights.
    n_altitude = max(int(altitude_samples), 1)
    cov = cov + config.relief_scale_gain**2 * max(relief_var, 0.0) * (1.0 / n_inl + 1.0 / n_altitude) * np.outer(
        speed, speed
    )
    cov = cov + (sigma_z / (0.5 * (z_prev + z_curr))) ** 2 * np.outer(speed, speed)  # altitude: a scale error
    att = _scalar("attitude_noise_rad", attitude_noise_rad, nonnegative=True)
    cov = cov + np.eye(2) * (att**2 * (z_prev**2 + z_curr**2) / dt**2)  # each frame's tilt error shifts it all
    if 2 * n_inl < n_valid:  # a minority consensus is not trusted like a majority
        cov = cov * (n_valid / n_inl) ** 2
    if rival is not None:  # another group agrees on another motion: the covariance says so
        gap = (d - rival[0]) / dt
        cov = cov + rival[1] / (n_inl + rival[1]) * np.outer(gap, gap)
    cov = _floor_eigenvalues(cov, config.min_speed_sigma_mps**2)
    cov.setflags(write=False)

    mask = np.zeros(n_tokens, dtype=bool)
    mask[np.flatnonzero(valid)[inl]] = True
    mask.setflags(write=False)
    theta_sigma = math.sqrt(fit.theta_var_rad2) if joint else math.inf
    return SpeedMeasurement(
        True, float(speed[0]), float(speed[1]), cov, n_tokens, n_inl, mask, "",
        float(theta if joint else dpsi), theta_sigma, relief_sample(a[inl], b[inl], theta, d, fit.scale),
        fit.residual_var_m2 * px_per_m**2, fit.residual_dof,
    )


# chi-square quantile (2 dof, 99 %): the inlier gate is sqrt(9.21) = 3.03 residual sigmas.
_CHI2_2DOF_99 = 9.21


@dataclass(frozen=True)
class _RigidFit:
    """Least-squares ``a ~ R(theta) b + d`` (a Gauss-Newton solution with the compass prior)."""

    theta_rad: float
    d_m: np.ndarray  # (2,)
    theta_var_rad2: float  # variance of the turn (0 when it was fixed)
    cov_d_m2: np.ndarray  # (2, 2) covariance of d
    residual_var_m2: float  # per-axis residual variance of this step's tokens (floored later)
    residual_dof: float  # its degrees of freedom, both axes: 2 (m - p)
    scale: float = 1.0  # the zoom ``s`` of ``a ~ s R(theta) b + d`` (1: rigid)


def _rigid_fit(a: np.ndarray, b: np.ndarray, theta0: float, prior_rad: float, prior_var: float,
               joint: bool, sigma0_m: float, noise_prior_var_m2: float = 0.0, noise_prior_dof: float = 0.0,
               scale_var: float = 0.0) -> _RigidFit:
    """Rotation and translation from (M, 2) matched points, the rotation fixed when not ``joint``.

    The turn is the least-squares rotation of the centred points (Gauss-Newton from
    ``theta0``), then fused with the compass prior by precision (MAP). The translation's
    covariance comes from the residuals: their 2x2 scatter (anisotropic: relief parallax lies
    along the motion) over the degrees of freedom left, each eigenvalue floored at one token's
    noise ``sigma0_m^2``, divided by the number of points; plus what the turn's uncertainty
    moves ``d = mean(a) - R mean(b)`` by.

    A few tokens show their noise poorly (two tokens leave one degree of freedom): with
    ``noise_prior_dof > 0`` the per-axis noise variance is the pooled estimate
    ``(dof s^2 + dof0 s0^2) / (dof + dof0)`` of this step's ``s^2`` and the dive's recent
    ``noise_prior_var_m2`` (:attr:`SpeedEstimator.token_var_px2`), when that is larger than
    ``s^2`` alone (it never makes a step's tokens look better than they are).

    With ``scale_var > 0`` the fit is a similarity ``a ~ s R b + d``: the least-squares zoom of the
    centred points (the rotation is the same as the rigid one's), fused with the prior ``s = 1``
    of variance ``scale_var`` by precision. Its variance moves ``d`` along ``R mean(b)``, and the
    share of it the tokens decided costs half a degree of freedom per axis.
    """
    m = len(a)
    theta = float(theta0)
    a_bar = a.mean(axis=0)
    b_bar = b.mean(axis=0)
    ac, bc = a - a_bar, b - b_bar
    if joint:
        for _ in range(3):
            c = bc @ rot2(theta).T  # R b (centred)
            jb = np.column_stack([-c[:, 1], c[:, 0]])  # d(R b)/d theta = J R b
            den = float(np.sum(jb * jb))
            if den <= 0.0:
                break
            step = float(np.sum(jb * (ac - c))) / den
            theta += step
            if abs(step) < 1e-12:
                break
    p = 1.5 if joint else 1.0  # parameters per axis: (d, theta) or d

    dof_axis = max(m - p, 0.5)

    def residuals(th: float, zoom: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
        dd = a_bar - zoom * (rot2(th) @ b_bar)
        res = a - zoom * (b @ rot2(th).T) - dd
        sc = res.T @ res / dof_axis  # (2, 2)
        return dd, sc, float(np.trace(sc)) / 2.0

    def pooled(sc: np.ndarray, var: float) -> tuple[np.ndarray, float]:
        """The scatter and per-axis variance raised towards the dive's recent token noise, if larger."""
        if noise_prior_dof <= 0.0 or noise_prior_var_m2 <= var:
            return sc, var
        dof = 2.0 * dof_axis
        raised = (dof * var + noise_prior_dof * noise_prior_var_m2) / (dof + noise_prior_dof)
        return sc + (raised - var) * np.eye(2), raised

    spread = float(np.sum(bc * bc))
    zoom, zoom_var = 1.0, 0.0
    if scale_var > 0.0 and spread > 0.0:
        zoom_ls = float(np.sum((bc @ rot2(theta).T) * ac)) / spread
        info_zoom = spread / max(pooled(*residuals(theta, zoom_ls)[1:])[1], sigma0_m**2)
        zoom_var = 1.0 / (info_zoom + 1.0 / scale_var)
        w_zoom = info_zoom * zoom_var  # the tokens' share of the zoom (the prior's: 1 - w)
        zoom = 1.0 + w_zoom * (zoom_ls - 1.0)
        dof_axis = max(m - p - 0.5 * w_zoom, 0.5)
    d, scatter, resid_var = residuals(theta, zoom)
    theta_var = 0.0
    if joint:
        info_theta = spread / max(pooled(scatter, resid_var)[1], sigma0_m**2)
        if prior_var > 0.0:
            w = info_theta / (info_theta + 1.0 / prior_var)
            theta = prior_rad + wrap_angle(theta - prior_rad) * w
            d, scatter, resid_var = residuals(theta, zoom)
            theta_var = 1.0 / (info_theta + 1.0 / prior_var)
        else:
            theta_var = 1.0 / info_theta if info_theta > 0 else math.inf
    cov_d = _floor_eigenvalues(pooled(scatter, resid_var)[0], sigma0_m**2) / m
    if joint and math.isfinite(theta_var):
        jrb = zoom * (drot2(theta) @ b_bar)  # d d / d theta = -s dR/dtheta mean(b)
        cov_d = cov_d + theta_var * np.outer(jrb, jrb)
    if zoom_var > 0.0:
        rb = rot2(theta) @ b_bar  # d d / d s = -R mean(b)
        cov_d = cov_d + zoom_var * np.outer(rb, rb)
    return _RigidFit(theta, d, theta_var, cov_d, resid_var, 2.0 * dof_axis, zoom)


@lru_cache(maxsize=64)
def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.triu_indices(n, 1)``, computed once per token count (read-only)."""
    i, j = np.triu_indices(n, 1)
    i.setflags(write=False)
    j.setflags(write=False)
    return i, j


def _best_hypothesis(a, b, prior_rad, prior_var, thr, sigma0, joint, scale_var=0.0):
    """(theta, d, inlier mask) of the best rigid hypothesis: MSAC residuals plus the compass prior.

    Hypotheses: the prior turn with the median and with every single-token translation; in
    ``joint`` mode also the rigid motion of every token pair whose baseline is long enough to
    fix the turn (at least a quarter of the tokens' extent, and 8 thresholds). Each is scored
    by ``sum(min(r^2, thr^2)) / sigma0^2 + (theta - prior)^2 / prior_var``. With ``scale_var > 0``
    a pair's hypothesis is the similarity it fixes (its zoom ``s = |da| / |db|``; at the prior's
    turn when not ``joint``), scored by ``(s - 1)^2 / scale_var`` more: a zoom between the frames
    does not split the consensus.
    """
    if len(a) > _MAX_HYPOTHESES:
        pick = np.linspace(0, len(a) - 1, _MAX_HYPOTHESES).astype(np.intp)
    else:
        pick = np.arange(len(a))
    rb_prior = b @ rot2(prior_rad).T
    singles = a[pick] - rb_prior[pick]
    thetas = [np.full(1 + len(singles), prior_rad)]
    ds = [median0(a - rb_prior)[None], singles]
    zooms = [np.ones(1 + len(singles))]
    if (joint or scale_var > 0.0) and len(a) >= 2:
        i, j = _pairs(len(a))
        da, db = a[i] - a[j], b[i] - b[j]
        base2 = np.einsum("kj,kj->k", db, db)
        extent2 = float(np.max(base2))
        keep = base2 >= max((8.0 * thr) ** 2, extent2 / 16.0)
        if np.any(keep) and len(keep) > _MAX_HYPOTHESES:
            keep &= base2 >= np.sort(base2)[-_MAX_HYPOTHESES]
        if joint:
            th = np.arctan2(da[keep, 1], da[keep, 0]) - np.arctan2(db[keep, 1], db[keep, 0])
            th = prior_rad + wrap_angle(th - prior_rad)
        else:  # the turn is the prior's: a pair fixes only the zoom
            th = np.full(int(np.count_nonzero(keep)), float(prior_rad))
        ii, jj = i[keep], j[keep]
        # Each pair's translation mid(a) - R(t) mid(b); a stacked matmul gives R(t) @ v bit for bit.
        c, s = np.cos(th), np.sin(th)
        rots = np.empty((len(th), 2, 2))
        rots[:, 0, 0], rots[:, 0, 1], rots[:, 1, 0], rots[:, 1, 1] = c, -s, s, c
        mid_b = 0.5 * (b[ii] + b[jj])
        thetas.append(th)
        moved = np.matmul(rots, mid_b[:, :, None])[:, :, 0]
        if scale_var > 0.0:
            if joint:  # the similarity through the pair
                zoom = np.sqrt(np.einsum("kj,kj->k", da[keep], da[keep]) / base2[keep])
            else:  # the least-squares zoom at the prior's turn
                zoom = np.einsum("kj,kj->k", da[keep], db[keep] @ rot2(prior_rad).T) / base2[keep]
            zooms.append(zoom)
            moved = moved * zoom[:, None]
        ds.append(0.5 * (a[ii] + a[jj]) - moved)
    thetas_a = np.concatenate(thetas)
    ds_a = np.concatenate(ds)
    c, s = np.cos(thetas_a)[:, None], np.sin(thetas_a)[:, None]
    rb = np.stack([c * b[None, :, 0] - s * b[None, :, 1], s * b[None, :, 0] + c * b[None, :, 1]], axis=-1)
    if scale_var > 0.0:
        zooms_a = np.concatenate(zooms)
        rb = rb * zooms_a[:, None, None]
    r = a[None] - rb - ds_a[:, None, :]  # (K, M, 2)
    r2 = np.einsum("kmj,kmj->km", r, r)
    score = np.minimum(r2, thr**2).sum(axis=1) / sigma0**2
    if joint and prior_var > 0:
        score = score + wrap_angle(thetas_a - prior_rad) ** 2 / prior_var
    if scale_var > 0.0:
        score = score + (zooms_a - 1.0) ** 2 / scale_var
    k = int(np.argmin(score))
    return float(thetas_a[k]), ds_a[k], r2[k] <= thr**2


def _rival_consensus(a, b, theta, prior_rad, prior_var, thr, sigma0, joint, scale_var=0.0):
    """The best consensus among the outliers: ``(d (2,), support)`` when at least two agree, else None."""
    if len(a) < 2:
        return None
    _, d, support = _best_hypothesis(a, b, prior_rad, prior_var, thr, sigma0, joint, scale_var)
    n = int(support.sum())
    return (d, n) if n >= 2 else None


def relief_sample(a_m: np.ndarray, b_m: np.ndarray, theta_rad: float, d_m: np.ndarray, scale: float = 1.0) -> float:
    """One frame's sample of the relative variance of the seabed heights under the tokens (NaN: none).

    Over relief each token moves as its own depth says, ``d_i = d Z / Z_i``: the relief spreads
    the tokens' displacements along the motion only, while matching noise spreads them in every
    direction. So the along-motion residual variance less the across-motion one, over ``|d|^2``,
    estimates ``sigma_s^2`` without bias (it may be negative for one frame; averages are not).
    The mean depth of n tokens and the depth the altitude was measured at (m points) then
    differ by ``sigma_s^2 (1/n + 1/m)`` in relative variance: a scale error of the speed.
    """
    n = len(a_m)
    dd = float(d_m @ d_m)
    if n < 3 or dd <= 0.0:
        return math.nan
    res = a_m - scale * (b_m @ rot2(theta_rad).T) - d_m  # (n, 2) residuals of the fit (``scale``: its zoom)
    along = res @ d_m
    across = res @ np.array([-d_m[1], d_m[0]])
    return float(np.mean(along**2) - np.mean(across**2)) / (dd * dd) * n / (n - 1.5)


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
        data = max(self._relief.mean(), 0.0)
        cfg = self.config
        if cfg.relief_prior_s <= 0.0 or cfg.relief_prior_sigma <= 0.0:
            return data
        prior = math.exp(-self._relief_seen_s / cfg.relief_prior_s)  # the prior's share: 1 at the start
        return prior * cfg.relief_prior_sigma**2 + (1.0 - prior) * data

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
            camera, uv_prev_px, uv_curr_px, altitude_prev_m, altitude_curr_m, dt_s, dpsi_rad,
            altitude_sigma_m, attitude_prev_rad, attitude_curr_rad, self.config, dpsi_sigma_rad, altitude_samples,
            self.relief_var, attitude_noise_rad, self.token_var_px2,
        )
        if m.ok:
            self._learn_relief(m.relief_sample, float(dt_s), float(np.sum((m.speed_mps * dt_s) ** 2)))
            self._learn_token_noise(m, float(dt_s))
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
