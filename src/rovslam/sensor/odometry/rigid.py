"""The rigid (or similarity) motion of matched seabed points: the consensus search and the fit.

The operations :func:`rovslam.sensor.odometry.speed_from_tokens` is made of, on level-frame seabed
offsets ``a`` (previous frame) and ``b`` (current frame), ``(M, 2)`` metres each, related by
``a ~ s R(theta) b + d``:

* :func:`_best_hypothesis` scores hypotheses (single tokens, the median, token pairs) by
  truncated residuals and the compass prior (MSAC, MAP);
* :func:`_rigid_fit` is the least-squares fit on the inliers, with the covariance of ``d``;
* :func:`_rival_consensus` finds a second group agreeing on another motion;
* :func:`relief_sample` is one frame's sample of the relief under the tokens.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from rovslam.averages import median0
from rovslam.camera import drot2, rot2, wrap_angle

# At most this many single-token hypotheses are scored (plus the median); the pairwise
# residual table is then at most 65 x N, whatever N.
_MAX_HYPOTHESES = 64


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


def _rigid_fit(
    a: np.ndarray,
    b: np.ndarray,
    theta0: float,
    prior_rad: float,
    prior_var: float,
    joint: bool,
    sigma0_m: float,
    noise_prior_var_m2: float = 0.0,
    noise_prior_dof: float = 0.0,
    scale_var: float = 0.0,
    along_rel: float = 0.0,
) -> _RigidFit:
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

    With ``along_rel > 0`` (the relief's parallax spread per metre of motion, relative) the turn
    weighs each token's residual along the motion ``d`` by ``w = 1 / (1 + (along_rel |d| /
    sigma0_m)^2)`` and across it by 1 (:func:`_parallax_weight`): relief moves a token along the
    motion only, a turn across it too (:func:`_fit_turn`). The turn's information is then the weighted
    spread less what the zoom takes of it (:func:`_weighted_spread`), over the residual variance in
    the same metric (the along-motion residuals it discounts are the relief's, not token noise).
    """
    m = len(a)
    theta = float(theta0)
    a_bar = a.mean(axis=0)
    b_bar = b.mean(axis=0)
    ac, bc = a - a_bar, b - b_bar
    weight = None
    if joint:
        theta, weight = _fit_turn(ac, bc, a_bar, b_bar, theta, along_rel, sigma0_m)
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
        turn_spread, turn_var = spread, resid_var
        if weight is not None:
            # the residual variance in the weighted metric: trace(W scatter) / 2 (resid_var when W = I)
            turn_spread, turn_var = _weighted_spread(bc, theta, weight), 0.5 * float(np.sum(weight * scatter))
        info_theta = turn_spread / max(pooled(scatter, turn_var)[1], sigma0_m**2)
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


def _fit_turn(
    ac: np.ndarray,
    bc: np.ndarray,
    a_bar: np.ndarray,
    b_bar: np.ndarray,
    theta0: float,
    along_rel: float,
    sigma0_m: float,
) -> tuple[float, np.ndarray | None]:
    """The turn of the centred (M, 2) ``bc`` onto ``ac`` and the (2, 2) weight it was fitted under (None: unweighted).

    The least-squares rotation from ``theta0``; with ``along_rel > 0`` and a step that moves, the turn
    of the weighted similarity under :func:`_parallax_weight` of the step ``a_bar - R b_bar``, the zoom
    free (:func:`_weighted_similarity_turn`): under that weight the turn and the zoom are no longer
    orthogonal (a zoom moves a token across the motion by its position across it), and a turn fitted
    alone would read a zoom as a turn.
    """
    theta = _least_squares_turn(ac, bc, theta0)
    weight = None
    if along_rel > 0.0:
        weight = _parallax_weight(a_bar - rot2(theta) @ b_bar, along_rel, sigma0_m)
        if weight is not None:
            theta = _weighted_similarity_turn(ac, bc, weight)
    return theta, weight


def _least_squares_turn(ac: np.ndarray, bc: np.ndarray, theta_rad: float) -> float:
    """The rotation best taking the centred ``bc`` onto the centred ``ac`` ((M, 2) each): Gauss-Newton from ``theta_rad``."""
    theta = theta_rad
    for _ in range(3):
        c, jb = _turn_jacobian(bc, theta)
        den = float(np.sum(jb * jb))
        if den <= 0.0:
            break
        step = float(np.sum(jb * (ac - c))) / den
        theta += step
        if abs(step) < 1e-12:
            break
    return theta


def _parallax_weight(d_m: np.ndarray, along_rel: float, sigma0_m: float) -> np.ndarray | None:
    """(2, 2) weight ``n n^T + w u u^T`` of a token's residual, ``u`` along the motion ``d_m`` (2,), ``n`` across it.

    ``w = 1 / (1 + (along_rel |d| / sigma0_m)^2)``: the relief's parallax (a spread ``along_rel |d|`` along
    the motion) against one token's noise. None when the step does not move.
    """
    norm = math.hypot(float(d_m[0]), float(d_m[1]))
    if norm <= 0.0 or sigma0_m <= 0.0:
        return None
    u = np.asarray(d_m, dtype=np.float64) / norm
    w = 1.0 / (1.0 + (along_rel * norm / sigma0_m) ** 2)
    return np.eye(2) - (1.0 - w) * np.outer(u, u)


def _turn_jacobian(bc: np.ndarray, theta_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R b, d(R b)/d theta)``, (M, 2) each, of the centred (M, 2) ``bc``."""
    c = bc @ rot2(theta_rad).T  # R b (centred)
    return c, np.column_stack([-c[:, 1], c[:, 0]])  # d(R b)/d theta = J R b


def _weighted_spread(bc: np.ndarray, theta_rad: float, weight: np.ndarray) -> float:
    """The turn's information times the noise variance under a (2, 2) ``weight``, the zoom free: ``sum jb^T W jb``
    over the centred (M, 2) ``bc``, less ``(sum jb^T W c)^2 / sum c^T W c`` (``c = R b``, the zoom's Jacobian);
    with ``W = I`` the two are orthogonal and it is their spread ``sum |b|^2``."""
    c, jb = _turn_jacobian(bc, theta_rad)
    wjb = jb @ weight
    info = float(np.sum(wjb * jb))
    zoom_info = float(np.sum((c @ weight) * c))
    if zoom_info > 0.0:
        info -= float(np.sum(wjb * c)) ** 2 / zoom_info
    return max(info, 0.0)


def _weighted_similarity_turn(ac: np.ndarray, bc: np.ndarray, weight: np.ndarray) -> float:
    """The turn of the weighted least-squares similarity ``ac ~ s R(theta) bc`` of the centred (M, 2) points, the
    zoom ``s`` free: linear in ``x = (s cos theta, s sin theta)``, ``sum B^T W B x = sum B^T W a`` with
    ``B = [[bx, -by], [by, bx]]`` each token's. A turn fitted alone under a weight that is not isotropic reads
    a zoom as a turn wherever the tokens' positions along and across the motion are correlated."""
    bx, by = bc[:, 0], bc[:, 1]
    wxx, wxy, wyy = float(weight[0, 0]), float(weight[0, 1]), float(weight[1, 1])
    m00 = float(np.sum(wxx * bx * bx + 2.0 * wxy * bx * by + wyy * by * by))
    m11 = float(np.sum(wxx * by * by - 2.0 * wxy * bx * by + wyy * bx * bx))
    m01 = float(np.sum((wyy - wxx) * bx * by + wxy * (bx * bx - by * by)))
    wa = ac @ weight
    v0 = float(np.sum(bx * wa[:, 0] + by * wa[:, 1]))
    v1 = float(np.sum(bx * wa[:, 1] - by * wa[:, 0]))
    det = m00 * m11 - m01 * m01
    if not det > 0.0:
        return math.atan2(v1, v0)  # too few points to tell the turn from the zoom: the plain rotation
    return math.atan2(m00 * v1 - m01 * v0, m11 * v0 - m01 * v1)


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
        th, d_pairs, zoom = _pair_hypotheses(a, b, prior_rad, thr, joint, scale_var)
        thetas.append(th)
        if zoom is not None:
            zooms.append(zoom)
        ds.append(d_pairs)
    thetas_a = np.concatenate(thetas)
    ds_a = np.concatenate(ds)
    zooms_a = np.concatenate(zooms) if scale_var > 0.0 else None
    score, r2 = _hypothesis_scores(a, b, thetas_a, ds_a, zooms_a, prior_rad, prior_var, thr, sigma0, joint, scale_var)
    k = int(np.argmin(score))
    return float(thetas_a[k]), ds_a[k], r2[k] <= thr**2


def _pair_hypotheses(a, b, prior_rad, thr, joint, scale_var):
    """``(theta (K,), d (K, 2), zoom (K,) or None)``: the motion fixed by every long enough token pair.

    A pair's baseline must be at least a quarter of the tokens' extent and 8 thresholds long
    (at most ``_MAX_HYPOTHESES`` pairs, the longest). In ``joint`` mode the pair fixes the turn,
    else the turn is the prior's; with ``scale_var > 0`` it also fixes the zoom (None without).
    """
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
    moved = np.matmul(rots, mid_b[:, :, None])[:, :, 0]
    zoom = None
    if scale_var > 0.0:
        if joint:  # the similarity through the pair
            zoom = np.sqrt(np.einsum("kj,kj->k", da[keep], da[keep]) / base2[keep])
        else:  # the least-squares zoom at the prior's turn
            zoom = np.einsum("kj,kj->k", da[keep], db[keep] @ rot2(prior_rad).T) / base2[keep]
        moved = moved * zoom[:, None]
    return th, 0.5 * (a[ii] + a[jj]) - moved, zoom


def _hypothesis_scores(a, b, thetas, ds, zooms, prior_rad, prior_var, thr, sigma0, joint, scale_var):
    """``(score (K,), r2 (K, M))``: each hypothesis's MSAC score (plus its priors) and squared residuals."""
    c, s = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
    rb = np.stack([c * b[None, :, 0] - s * b[None, :, 1], s * b[None, :, 0] + c * b[None, :, 1]], axis=-1)
    if scale_var > 0.0:
        rb = rb * zooms[:, None, None]
    r = a[None] - rb - ds[:, None, :]  # (K, M, 2)
    r2 = np.einsum("kmj,kmj->km", r, r)
    score = np.minimum(r2, thr**2).sum(axis=1) / sigma0**2
    if joint and prior_var > 0:
        score = score + wrap_angle(thetas - prior_rad) ** 2 / prior_var
    if scale_var > 0.0:
        score = score + (zooms - 1.0) ** 2 / scale_var
    return score, r2


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
