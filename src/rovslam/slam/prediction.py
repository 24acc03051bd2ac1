"""The EKF's prediction (1), (2) as steps over the mean ``x`` and covariance ``P`` buffers, in place.

``x`` (cap,) and ``P`` (cap, cap) are the filter's buffers, of which the first ``n`` rows are used;
``layout`` (:class:`rovslam.slam.state.StateLayout`) says where the optional states are. In order
(:meth:`rovslam.slam.ekf.EkfSlam.predict`):

1. :func:`motion_terms`: the step's inputs resolved against the configuration, the displacement
   (1) and its Jacobians at the current estimate;
2. :func:`move_vehicle`: the mean;
3. :func:`couple_vehicle`: ``P <- F P F^T`` with F = I but the vehicle's derivatives with
   respect to eps, b and w;
4. :func:`drive_biases`: the optional states' own process (Ornstein-Uhlenbeck, or a random walk
   for an integrated heading);
5. :func:`add_process_noise`: the speed's and heading's noise on the vehicle, (2)'s on the landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.config import SlamConfig
from rovslam.slam.inputs import MotionInput
from rovslam.slam.motion import motion_jacobians, motion_step_m
from rovslam.slam.state import StateLayout

__all__ = ["MotionTerms", "add_process_noise", "couple_vehicle", "drive_biases", "motion_terms", "move_vehicle"]


@dataclass(frozen=True, eq=False)
class MotionTerms:
    """One prediction step's inputs, resolved, and its linearisation at the current estimate.

    Attributes:
        dt_s: the time step.
        altitude_m: Z the speed was measured at (None: no altitude coupling).
        scale: ``(Z + b) / Z`` with the altitude-offset state and Z, else 1.
        step_m: (2,) the vehicle's displacement (1), the speed scaled.
        g: (2, 2) d(position) / d(speed), the scale included.
        j: (2,) d(position) / d(psi).
        speed_cov_mps2: (2, 2) Q.
        heading_sigma_rad, altitude_bias_sigma_m, altitude_bias_tau_s, heading_walk_var_rad2,
        speed_bias_sigma_mps, seabed_offset_sigma_m: as :class:`rovslam.slam.inputs.MotionInput`, the defaults
        resolved.
    """

    dt_s: float
    altitude_m: float | None
    scale: float
    step_m: np.ndarray
    g: np.ndarray
    j: np.ndarray
    speed_cov_mps2: np.ndarray
    heading_sigma_rad: float
    altitude_bias_sigma_m: float
    altitude_bias_tau_s: float
    heading_walk_var_rad2: float | None
    speed_bias_sigma_mps: float
    seabed_offset_sigma_m: float = 0.0


def motion_terms(
    motion: MotionInput, config: SlamConfig, layout: StateLayout, heading_bias_rad: float, altitude_bias_m: float
) -> MotionTerms:
    """Resolve ``motion``'s defaults against ``config`` and linearise (1) at the estimated eps and b."""
    s_psi = float(config.heading_sigma_rad) if motion.heading_sigma_rad is None else motion.heading_sigma_rad
    sb = float(config.altitude_bias_sigma_m) if motion.altitude_bias_sigma_m is None else motion.altitude_bias_sigma_m
    tb = float(config.altitude_bias_tau_s) if motion.altitude_bias_tau_s is None else motion.altitude_bias_tau_s
    z = motion.altitude_m
    theta = float(motion.heading_rad) - heading_bias_rad  # the map heading
    speed = np.array([motion.surge_mps, motion.sway_mps])
    scale = 1.0 if (layout.b is None or z is None) else (z + altitude_bias_m) / z  # the true depth's share
    g, j = motion_jacobians(speed * scale, theta, motion.dt_s)  # d(position) / d(speed), d(position) / d(psi)
    step = motion_step_m(speed * scale, theta, motion.dt_s)
    return MotionTerms(
        dt_s=motion.dt_s,
        altitude_m=z,
        scale=scale,
        step_m=step,
        g=g * scale,
        j=j,
        speed_cov_mps2=motion.speed_cov_mps2,
        heading_sigma_rad=s_psi,
        altitude_bias_sigma_m=sb,
        altitude_bias_tau_s=tb,
        heading_walk_var_rad2=motion.heading_walk_var_rad2,
        speed_bias_sigma_mps=motion.speed_bias_sigma_mps,
        seabed_offset_sigma_m=(
            float(config.seabed_offset_sigma_m)
            if motion.seabed_offset_sigma_m is None
            else motion.seabed_offset_sigma_m
        ),
    )


def move_vehicle(x: np.ndarray, layout: StateLayout, t: MotionTerms) -> None:
    """(1) on the mean; with w, the true step is the measured one + w dt (the odometry's slow world-frame error)."""
    x[:2] += t.step_m
    w = layout.w
    if w is not None:
        x[:2] += x[w : w + 2] * t.dt_s


def couple_vehicle(p: np.ndarray, n: int, layout: StateLayout, t: MotionTerms) -> None:
    """``P <- F P F^T``, F = I except d(position)/d(eps) = -j, d(position)/d(b) = step / (Z + b), d(position)/d(w) = dt I."""
    cols, coef = [], []
    if layout.eps is not None:
        cols.append(layout.eps)
        coef.append(-t.j)
    if layout.b is not None and t.altitude_m is not None:
        cols.append(layout.b)
        coef.append(t.step_m / (t.altitude_m * t.scale))
    w = layout.w
    if w is not None:
        cols += [w, w + 1]
        coef += [np.array([t.dt_s, 0.0]), np.array([0.0, t.dt_s])]
    if cols:
        e = np.column_stack(coef)  # (2, k)
        p[0:2, :n] += e @ p[cols, :n]
        p[:n, 0:2] += p[:n, cols] @ e.T


def drive_biases(
    x: np.ndarray, p: np.ndarray, n: int, layout: StateLayout, t: MotionTerms, speed_bias_sigma_before_mps: float
) -> None:
    """The optional states' process over the step: eps, b, w Ornstein-Uhlenbeck (eps a random walk
    when the heading is integrated from turns).

    ``speed_bias_sigma_before_mps``: w's stationary sigma over the previous step; when this step's
    is larger (a drag appeared or grew), w's variance rises at once, as a fresh unknown.
    """
    w = layout.w
    sw = t.speed_bias_sigma_mps
    if w is not None and sw > speed_bias_sigma_before_mps:
        rise = sw**2 - speed_bias_sigma_before_mps**2
        p[w, w] += rise
        p[w + 1, w + 1] += rise
    for row, tau, sigma in (
        (layout.eps, layout.heading_bias_tau_s, layout.heading_bias_sigma_rad),
        (layout.b, t.altitude_bias_tau_s, t.altitude_bias_sigma_m),
        (layout.s, layout.seabed_offset_tau_s, t.seabed_offset_sigma_m),
        (w, layout.speed_bias_tau_s, sw),
        (None if w is None else w + 1, layout.speed_bias_tau_s, sw),
    ):
        if row is None:
            continue
        if row == layout.eps and t.heading_walk_var_rad2 is not None:  # an integrated heading: walks, never decays
            p[row, row] += t.heading_walk_var_rad2
            continue
        a = np.exp(-t.dt_s / tau)  # Ornstein-Uhlenbeck
        x[row] *= a
        p[row, :n] *= a
        p[:n, row] *= a
        p[row, row] += sigma**2 * (1.0 - a * a)


def add_process_noise(p: np.ndarray, n: int, layout: StateLayout, t: MotionTerms) -> None:
    """The speed's covariance through ``g``, the heading's through ``j`` on the vehicle; (2)'s on each landmark."""
    add = t.g @ t.speed_cov_mps2 @ t.g.T
    if t.heading_sigma_rad > 0.0:
        add += t.heading_sigma_rad**2 * np.outer(t.j, t.j)
    p[:2, :2] += 0.5 * (add + add.T)
    s_l = layout.landmark_process_sigma_m
    v0 = layout.vehicle_dim
    if s_l > 0.0 and n > v0:  # (2): static landmarks, optional process noise
        cap = p.shape[0]
        diag = p.reshape(-1)[v0 * (cap + 1) : n * (cap + 1) : cap + 1]
        diag += s_l**2
