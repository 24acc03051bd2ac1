"""Augmented-state EKF-SLAM: state ``[x, y, (eps,) (b,) (wx, wy,) X1, Y1, (h1,) ..., XN, YN, (hN)]`` (metres, world frame).

``eps`` (radians, present when ``heading_bias_sigma_rad > 0``) is the slow error of the heading
input, beyond the paper: the true heading is ``psi - eps``, ``eps`` an Ornstein-Uhlenbeck
process. A compass drifts with the vehicle's own magnetic field; while it drifts, landmarks
mapped under one error and seen again under another turn the map. With ``eps`` in the state
the re-observations estimate the change; its absolute value (a rotation of the whole map)
stays unobservable and its variance says so.

``h_i`` (metres, present when ``landmark_height_sigma_m > 0``) is landmark i's height above
the seabed the altitude Z refers to, beyond the paper, whose (3) assumes a flat seabed: a
landmark on a 5 cm stone seen from 1.31 m moves 4 % faster across the image than the plane
says, so seen again from another place in the image it is 1 to 7 px off. Its depth is then
``Z - h_i`` in (3) and (4); the parallax of its re-observations estimates ``h_i``.

``b`` (metres, present when ``altitude_bias_sigma_m > 0``) is the offset of the measured
altitude from the seabed level the heights refer to: the lasers range to the relief under
their few spots, which differs from the mean seabed by a few centimetres and changes as the
relief passes (an Ornstein-Uhlenbeck process of correlation time ``altitude_bias_tau_s``, or the
one the caller gives per step: with ``[slam] altitude_bias_relief`` the pipeline adds the relief
under the tokens, which decorrelates within seconds, :func:`rovslam.slam.motion.ou_sum_as_one`). The
true depth of landmark i is ``Z + b - h_i``, and the tokens' speed, measured at depth Z, is
really ``(Z + b) / Z`` times larger: one state ties the odometry's scale and every landmark's
depth together, so their errors, correlated from frame to frame, are not averaged as if white.
A scale error is invisible to the images (the odometry and every landmark's depth scale
together), so by default (``altitude_bias_consider``) ``b`` is a *consider* state (Schmidt-Kalman):
the updates never change it (the rows of the gain for ``b`` are zero; the Joseph form stays
exact), and its variance, never learned away, keeps the altimeter's persistent error (a laser
spot centroid held half a pixel off by a video codec's blocks is a 1 % scale for minutes,
``altitude_bias_tau_s`` = 30 s) in the vehicle's and the landmarks' covariance. Learned, it
was pulled by the relief's parallax to wrong values with a shrinking variance; with the earlier
1 s correlation, the filter averaged a persistent error over many frames as if it were white.
Its stationary sigma, given per step by the pipeline, is the altimeter's offset and the laser rig's
share of the depth in quadrature (``[slam] altitude_bias_sigma_m``, ``altitude_scale_sigma``: a rig
whose baseline is off by 0.76 % reads 1 cm long at 1.31 m, 1.5 cm at 2 m).

``w = [wx, wy]`` (m/s, world frame, present when ``speed_bias_sigma_mps > 0``) is a slow error of
the measured speed that moves with the world, not with the vehicle: sunlight caustics drifting
over the seabed drag a few per cent of their speed into the tokens even after the wide opening
took most of the light out (-1.5 to -1.7 mm/s of surge on the swell preset, 0.5 m of drift over 5
minutes). The true step is ``R(psi) [u, v] dt + w dt``; ``w`` is an Ornstein-Uhlenbeck process
whose stationary sigma the caller gives per step (the pipeline: ``speed_bias_sigma_mps`` while the
sunlight is being taken out, else 0, so ``w`` fades; without it ``w`` stays 0 with no variance);
when that sigma rises, ``w``'s variance rises at once. The landmarks tracked from frame to frame
estimate it; observations do not depend on it.

* Prediction (1), (2) (:mod:`rovslam.slam.motion`): ``[x, y] += R(psi) [u, v] dt``; the speed covariance Q is projected
  through ``R(psi) dt``, an optional heading noise through ``dR/dpsi [u, v] dt``; landmarks
  are static with an optional process noise per step.
* Update (3) (:mod:`rovslam.slam.observation`): ``[m, n] = f/(Z - h_i) R(psi)^T (X_i - x)``. H is non-zero only in the vehicle's and the
  landmark's columns, so the Joseph-form covariance update
  ``P' = (I - K H) P (I - K H)^T + K R K^T = P - K M^T - M K^T + K S K^T`` (``M = P H^T``)
  is a rank-4 correction ``P -= [K W] [W K]^T`` with ``W = M - K S / 2``, applied in place
  with one BLAS ``dgemm``: O(N^2) memory traffic, no dense (2N+2)^3 product, no inverse
  bigger than 2x2. An innovation (chi-square) test rejects matches inconsistent with the
  prediction before anything changes. A tentative landmark's update may move only the
  landmark (``landmark_only``: the gain's other rows are zero; the Joseph form stays exact).
  Landmarks seen in the same frame are checked together first (:meth:`EkfSlam.joint_nis`).
* Augmentation (4): full cross-covariances (``augmentation = "full"``) or the paper's
  diagonal block ``P_Xi = P_x + (Z/f)^2 R R_m R^T`` with no cross terms (``"paper"``).
* Gate (5) and new-landmark test (6): :mod:`rovslam.slam.gating`, vectorised over landmarks.

Storage: state and covariance live in preallocated buffers whose capacity doubles when full,
so augmenting costs O(N) (plus an amortised copy on growth), never a reallocation per
landmark. Landmark ids are 0..N-1 in order of creation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.blas import dgemm

from rovslam.config import SlamConfig
from rovslam.errors import FilterInconsistencyError, InvalidMeasurementError, finite_scalar
from rovslam.slam import gating
from rovslam.slam.motion import altitude_offset_sigma_m, motion_jacobians, motion_step_m
from rovslam.slam.observation import (
    landmark_from_mn,
    landmark_jacobians,
    observation_jacobians,
    observation_noise_px2,
    observe_mn,
)

__all__ = ["EkfSlam", "UpdateResult", "ConsistencyReport"]

# Relative tolerance of the covariance health checks (negative variance, asymmetry).
_PSD_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class UpdateResult:
    """Outcome of one landmark observation.

    Attributes:
        accepted: False when the innovation test rejected it (the state is then untouched).
        nis: normalised innovation squared ``nu^T S^-1 nu`` (chi-square, 2 dof).
        innovation_px: (2,) ``[m, n]_measured - [m, n]_predicted``.
        reason: "" when accepted, else why.
        innovation_cov_px2: (2, 2) S.
    """

    accepted: bool
    nis: float
    innovation_px: np.ndarray
    reason: str
    innovation_cov_px2: np.ndarray


@dataclass(frozen=True)
class ConsistencyReport:
    """Figures of a full covariance check (:meth:`EkfSlam.check_consistency`)."""

    state_dim: int
    max_asymmetry: float  # max |P - P^T| before symmetrisation
    min_eigenvalue: float
    max_eigenvalue: float
    min_diagonal: float


def _finite(name: str, value, *, positive: bool = False, nonnegative: bool = False) -> float:
    return finite_scalar(
        name, value, positive=positive, nonnegative=nonnegative,
        nan_hint="the filter state; drop this measurement or fix the sensor input (the state is unchanged)",
        suffix=" (the state is unchanged)",
    )


def _vector2(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (2,):
        a = a.reshape(-1)
        if a.shape != (2,):
            raise InvalidMeasurementError(f"{name} must hold 2 numbers, got shape {np.shape(value)}")
    if not np.all(np.isfinite(a)):
        raise InvalidMeasurementError(
            f"{name} = {a.tolist()} has a NaN or infinite value; drop this measurement (the state is unchanged)"
        )
    return a


def _cov2(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (2, 2):
        raise InvalidMeasurementError(f"{name} must be a (2, 2) covariance, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidMeasurementError(
            f"{name} has a NaN or infinite entry: {a.tolist()}; the state is unchanged"
        )
    scale = max(abs(a[0, 0]), abs(a[1, 1]), 1e-300)
    if abs(a[0, 1] - a[1, 0]) > 1e-9 * scale:
        raise InvalidMeasurementError(f"{name} must be symmetric, got {a.tolist()}")
    if a[0, 0] < 0 or a[1, 1] < 0 or a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0] < -1e-12 * scale * scale:
        raise InvalidMeasurementError(
            f"{name} must be positive semi-definite (non-negative variances, |cov| <= sigma_x sigma_y), "
            f"got {a.tolist()}"
        )
    return 0.5 * (a + a.T)


class EkfSlam:
    """EKF-SLAM over the vehicle position and N point landmarks (equations (1)-(6)).

    Args:
        config: noise figures, gates and the augmentation form.
        initial_xy_m: (2,) initial vehicle position.
        initial_cov_m2: (2, 2) its covariance; default ``initial_position_sigma_m^2 I``.
        initial_capacity: landmarks the buffers hold before their first growth.
        initial_altitude_m: the depth expected at the start: ``b``'s first variance is its sigma there
            (``altitude_bias_sigma_m`` with ``altitude_scale_sigma``'s share of it); None: the offset's alone.
    """

    def __init__(
        self,
        config: SlamConfig = SlamConfig(),
        initial_xy_m=(0.0, 0.0),
        initial_cov_m2=None,
        initial_capacity: int = 16,
        initial_altitude_m: float | None = None,
    ):
        self.config = config  # validated when it was built (rovslam.config)
        xy = _vector2("initial_xy_m", initial_xy_m)
        z0 = None if initial_altitude_m is None else _finite("initial_altitude_m", initial_altitude_m, positive=True)
        if initial_cov_m2 is None:
            cov = np.eye(2) * config.initial_position_sigma_m**2
        else:
            cov = _cov2("initial_cov_m2", initial_cov_m2)
        self._eps = 2 if config.heading_bias_sigma_rad > 0 else None  # state row of eps
        self._b = (2 + (self._eps is not None)) if config.altitude_bias_sigma_m > 0 else None  # state row of b
        self._w = (2 + (self._eps is not None) + (self._b is not None)) if config.speed_bias_sigma_mps > 0 else None
        self._v = 2 + (self._eps is not None) + (self._b is not None) + 2 * (self._w is not None)  # x, y (, eps) (, b) (, w)
        self._lm = 3 if config.landmark_height_sigma_m > 0 else 2  # landmark block: X, Y (, h)
        self._n = self._v
        self._alloc(self._v + self._lm * max(int(initial_capacity), 1))
        self._x[:2] = xy
        self._P[:2, :2] = cov
        if self._eps is not None:
            self._P[self._eps, self._eps] = config.heading_bias_sigma_rad**2
        if self._b is not None:
            sb = config.altitude_bias_sigma_m if z0 is None else altitude_offset_sigma_m(
                config.altitude_bias_sigma_m, config.altitude_scale_sigma, z0)
            self._P[self._b, self._b] = sb**2
        self._w_sigma_mps = 0.0  # the speed error's stationary sigma over the last step (0: none yet)

    # ------------------------------------------------------------------ storage
    def _alloc(self, cap: int) -> None:
        """(Re)allocate buffers of ``cap`` state entries, keeping the current state."""
        n = self._n
        x = np.zeros(cap)
        p = np.zeros((cap, cap))
        if hasattr(self, "_x"):
            x[:n] = self._x[:n]
            p[:n, :n] = self._P[:n, :n]
        self._x, self._P, self._cap = x, p, cap
        # Work array of the rank-4 update, Fortran order for BLAS; rows >= n stay zero.
        self._vpad = np.zeros((cap, 4), order="F")

    def _reserve(self, extra: int) -> None:
        if self._n + extra > self._cap:
            self._alloc(max(2 * self._cap, self._n + extra))

    # ------------------------------------------------------------------ accessors
    @property
    def state_dim(self) -> int:
        """2 (+1 with eps, +1 with b, +2 with w) + 2N (3N with the landmark heights)."""
        return self._n

    @property
    def n_landmarks(self) -> int:
        return (self._n - self._v) // self._lm

    @property
    def has_landmark_heights(self) -> bool:
        return self._lm == 3

    @property
    def heading_bias_rad(self) -> float:
        """Estimated slow heading error eps (true heading = input - eps); 0 without the state."""
        return float(self._x[self._eps]) if self._eps is not None else 0.0

    @property
    def heading_bias_sigma_rad(self) -> float:
        return float(np.sqrt(max(self._P[self._eps, self._eps], 0.0))) if self._eps is not None else 0.0

    @property
    def altitude_bias_m(self) -> float:
        """Estimated offset b of the measured altitude from the seabed datum (true depth = Z + b); 0 without the state."""
        return float(self._x[self._b]) if self._b is not None else 0.0

    @property
    def altitude_bias_sigma_m(self) -> float:
        return float(np.sqrt(max(self._P[self._b, self._b], 0.0))) if self._b is not None else 0.0

    @property
    def speed_bias_mps(self) -> np.ndarray:
        """(2,) estimated world-frame speed error w (true step = measured step + w dt); zeros without the state."""
        return self._x[self._w : self._w + 2].copy() if self._w is not None else np.zeros(2)

    @property
    def speed_bias_cov_mps2(self) -> np.ndarray:
        """(2, 2) its covariance; zeros without the state."""
        return self._P[self._w : self._w + 2, self._w : self._w + 2].copy() if self._w is not None else np.zeros((2, 2))

    def map_heading_rad(self, heading_rad: float) -> float:
        """The heading the filter believes for a heading input: ``psi - eps`` (the input without its slow bias)."""
        return float(heading_rad) - self.heading_bias_rad

    def inflate_vehicle_covariance(self, cov_m2) -> None:
        """Add a (2, 2) PSD covariance to the vehicle position block (an uncertainty the filter was not told of).

        At the first frame this is the start's uncertainty (e.g. the AHRS tilt offset); the
        whole covariance stays positive semi-definite.
        """
        self._P[:2, :2] += _cov2("added vehicle covariance", cov_m2)

    @property
    def landmark_ids(self) -> list[int]:
        return list(range(self.n_landmarks))

    @property
    def vehicle_xy_m(self) -> np.ndarray:
        """(2,) vehicle position (copy)."""
        return self._x[:2].copy()

    @property
    def vehicle_cov_m2(self) -> np.ndarray:
        """(2, 2) vehicle position covariance (copy)."""
        return self._P[:2, :2].copy()

    @property
    def state_m(self) -> np.ndarray:
        """(state_dim,) full state (copy)."""
        return self._x[: self._n].copy()

    @property
    def covariance_m2(self) -> np.ndarray:
        """(state_dim, state_dim) full covariance (copy; O(N^2))."""
        return self._P[: self._n, : self._n].copy()

    def _index(self, i) -> int:
        try:
            k = int(i)
        except (TypeError, ValueError):
            raise InvalidMeasurementError(f"landmark id must be an integer, got {i!r}") from None
        if not 0 <= k < self.n_landmarks:
            raise InvalidMeasurementError(
                f"no landmark {k}: the map holds ids 0..{self.n_landmarks - 1}" if self.n_landmarks
                else f"no landmark {k}: the map is empty; augment() first"
            )
        return self._v + self._lm * k

    def landmark_height_m(self, i: int) -> float:
        """Landmark i's height above the seabed Z refers to (0 without the height state)."""
        r = self._index(i)
        return float(self._x[r + 2]) if self._lm == 3 else 0.0

    def landmark_height_sigma_m(self, i: int) -> float:
        r = self._index(i)
        return float(np.sqrt(max(self._P[r + 2, r + 2], 0.0))) if self._lm == 3 else 0.0

    def landmark_xy_m(self, i: int) -> np.ndarray:
        """(2,) position of landmark i."""
        r = self._index(i)
        return self._x[r : r + 2].copy()

    def landmark_cov_m2(self, i: int) -> np.ndarray:
        """(2, 2) covariance of landmark i."""
        r = self._index(i)
        return self._P[r : r + 2, r : r + 2].copy()

    def landmarks_xy_m(self) -> np.ndarray:
        """(N, 2) all landmark positions."""
        return self._x[self._v : self._n].reshape(-1, self._lm)[:, :2].copy()

    def landmarks_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) the landmarks' diagonal covariance blocks (O(N))."""
        r = np.arange(self._v, self._n, self._lm)
        p = self._P
        out = np.empty((len(r), 2, 2))
        out[:, 0, 0] = p[r, r]
        out[:, 0, 1] = p[r, r + 1]
        out[:, 1, 0] = p[r + 1, r]
        out[:, 1, 1] = p[r + 1, r + 1]
        return out

    def vehicle_landmark_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) cross-covariances ``C_i = cov(x, X_i)`` (vehicle rows, landmark columns)."""
        return self._P[0:2, self._v : self._n].reshape(2, -1, self._lm)[:, :, :2].transpose(1, 0, 2).copy()

    # ------------------------------------------------------------------ (1), (2)
    def predict(
        self,
        surge_mps: float,
        sway_mps: float,
        speed_cov_mps2,
        heading_rad: float,
        dt_s: float,
        heading_sigma_rad: float | None = None,
        altitude_m: float | None = None,
        altitude_bias_sigma_m: float | None = None,
        heading_walk_var_rad2: float | None = None,
        speed_bias_sigma_mps: float = 0.0,
        altitude_bias_tau_s: float | None = None,
    ) -> None:
        """Prediction by (1) and (2) with the measured body speed and heading as inputs.

        Args:
            surge_mps, sway_mps: body-frame speed over the ground.
            speed_cov_mps2: (2, 2) its covariance Q.
            heading_rad: heading psi over the step.
            dt_s: real time step (> 0).
            heading_sigma_rad: heading noise; default ``config.heading_sigma_rad``.
            altitude_m: the altitude Z the speed was measured at; with the altitude-bias state the
                step is scaled by ``(Z + b) / Z``. None: no such coupling.
            altitude_bias_sigma_m: the bias's stationary sigma over this step (the relief under
                the lasers may be rougher here); default ``config.altitude_bias_sigma_m``.
            heading_walk_var_rad2: a heading input integrated from turns, without a compass: the
                variance it gained over this step. ``eps`` is then a random walk (no decay towards
                0) driven by it, instead of the compass's Ornstein-Uhlenbeck drift. None: a compass.
            speed_bias_sigma_mps: the stationary sigma of the speed error ``w`` over this step: the
                odometry is dragged only while something moves over the seabed (the pipeline gives
                ``config.speed_bias_sigma_mps`` while it takes sunlight out); 0 (the default) lets ``w`` fade.
            altitude_bias_tau_s: the bias's correlation time over this step (the relief's part of it
                decorrelates faster than the altimeter's offset); default ``config.altitude_bias_tau_s``.

        Raises:
            InvalidMeasurementError: NaN/inf or invalid input; the state is unchanged.
        """
        u = _finite("surge_mps", surge_mps)
        v = _finite("sway_mps", sway_mps)
        q = _cov2("speed_cov_mps2", speed_cov_mps2)
        psi = _finite("heading_rad", heading_rad)
        dt = _finite("dt_s", dt_s, positive=True)
        s_psi = self.config.heading_sigma_rad if heading_sigma_rad is None else heading_sigma_rad
        s_psi = _finite("heading_sigma_rad", s_psi, nonnegative=True)

        z = None if altitude_m is None else _finite("altitude_m", altitude_m, positive=True)
        sb = self.config.altitude_bias_sigma_m if altitude_bias_sigma_m is None else altitude_bias_sigma_m
        sb = _finite("altitude_bias_sigma_m", sb, nonnegative=True)
        tb = self.config.altitude_bias_tau_s if altitude_bias_tau_s is None else altitude_bias_tau_s
        tb = _finite("altitude_bias_tau_s", tb, positive=True)
        walk = None if heading_walk_var_rad2 is None else _finite("heading_walk_var_rad2", heading_walk_var_rad2,
                                                                  nonnegative=True)
        sw = _finite("speed_bias_sigma_mps", speed_bias_sigma_mps, nonnegative=True)

        theta = self.map_heading_rad(psi)
        speed = np.array([u, v])
        scale = 1.0 if (self._b is None or z is None) else (z + self.altitude_bias_m) / z  # the true depth's share
        g, j = motion_jacobians(speed * scale, theta, dt)  # d(position) / d(speed), d(position) / d(psi)
        g = g * scale
        step = motion_step_m(speed * scale, theta, dt)
        self._x[:2] += step  # (1)
        n = self._n
        w = self._w
        if w is not None:  # the odometry's slow world-frame error: the true step is the measured one + w dt
            self._x[:2] += self._x[w : w + 2] * dt
        p = self._P
        # F = I except d(position)/d(eps) = -j, d(position)/d(b) = step / (Z + b) and d(position)/d(w) = dt I:
        # P <- F P F^T.
        cols, coef = [], []
        if self._eps is not None:
            cols.append(self._eps)
            coef.append(-j)
        if self._b is not None and z is not None:
            cols.append(self._b)
            coef.append(step / (z * scale))
        if w is not None:
            cols += [w, w + 1]
            coef += [np.array([dt, 0.0]), np.array([0.0, dt])]
        if cols:
            e = np.column_stack(coef)  # (2, k)
            p[0:2, :n] += e @ p[cols, :n]
            p[:n, 0:2] += p[:n, cols] @ e.T
        if w is not None:
            if sw > self._w_sigma_mps:  # a drag appeared (or grew): its variance at once, as a fresh unknown
                rise = sw**2 - self._w_sigma_mps**2
                p[w, w] += rise
                p[w + 1, w + 1] += rise
            self._w_sigma_mps = sw
        for row, tau, sigma in ((self._eps, self.config.heading_bias_tau_s, self.config.heading_bias_sigma_rad),
                                (self._b, tb, sb),
                                (w, self.config.speed_bias_tau_s, sw),
                                (None if w is None else w + 1, self.config.speed_bias_tau_s, sw)):
            if row is None:
                continue
            if row == self._eps and walk is not None:  # an integrated heading: its error walks, never decays
                p[row, row] += walk
                continue
            a = np.exp(-dt / tau)  # Ornstein-Uhlenbeck
            self._x[row] *= a
            p[row, :n] *= a
            p[:n, row] *= a
            p[row, row] += sigma**2 * (1.0 - a * a)
        add = g @ q @ g.T
        if s_psi > 0.0:
            add += s_psi**2 * np.outer(j, j)
        self._P[:2, :2] += 0.5 * (add + add.T)
        s_l = self.config.landmark_process_sigma_m
        v0 = self._v
        if s_l > 0.0 and self._n > v0:  # (2): static landmarks, optional process noise
            diag = self._P.reshape(-1)[v0 * (self._cap + 1) : self._n * (self._cap + 1) : self._cap + 1]
            diag += s_l**2

    # ------------------------------------------------------------------ (3)
    def _depth(self, k: int, z: float) -> float:
        """Depth of the landmark at state row k under a camera at measured altitude z: ``Z + b - h``."""
        depth = z + self.altitude_bias_m - (float(self._x[k + 2]) if self._lm == 3 else 0.0)
        if self._lm == 2 and self._b is None:
            return z
        if not depth > 0.05 * z:
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: landmark at state row {k} is estimated {self._x[k + 2]:.3f} m high, "
                f"above the camera's altitude {z:.3f} m"
            )
        return depth

    def _observation_terms(self, k: int, psi: float, z: float, f: float):
        """h (2,) by (3), the non-zero columns of H (2, 4 to 6), their state indices, and the depth, of landmark row k."""
        theta = self.map_heading_rad(psi)
        depth = self._depth(k, z)
        h = observe_mn(self._x[k : k + 2], self._x[:2], theta, depth, f)[0]
        a, j_psi = observation_jacobians(h, theta, depth, f)
        # d h / d eps = -d h / d psi; d h / d b = -h / depth; d h / d h_i = h / depth.
        cols = ([-a] + ([-j_psi.T] if self._eps is not None else []) + ([-h[:, None] / depth] if self._b is not None else [])
                + ([np.zeros((2, 2))] if self._w is not None else []) + [a] + ([h[:, None] / depth] if self._lm == 3 else []))
        idx = list(range(self._v)) + list(range(k, k + self._lm))
        return h, np.hstack(cols), np.array(idx), depth

    def _noise_args(self, pixel_sigma_px, altitude_sigma_m, heading_sigma_rad):
        sp = self.config.pixel_sigma_px if pixel_sigma_px is None else pixel_sigma_px
        sp = _finite("pixel_sigma_px", sp, positive=True)
        sz = _finite("altitude_sigma_m", altitude_sigma_m, nonnegative=True)
        sh = self.config.heading_sigma_rad if heading_sigma_rad is None else heading_sigma_rad
        sh = _finite("heading_sigma_rad", sh, nonnegative=True)
        return sp, sz, sh

    def predict_observation(
        self,
        i: int,
        heading_rad: float,
        altitude_m: float,
        focal_px: float,
        pixel_sigma_px: float | None = None,
        altitude_sigma_m: float = 0.0,
        heading_sigma_rad: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predicted [m, n] of landmark i by (3) and its innovation covariance S (2, 2) px^2."""
        k = self._index(i)
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)
        h, hs, idx, depth = self._observation_terms(k, psi, z, f)
        s = self._innovation_cov(hs, idx, observation_noise_px2(h, sp, depth, sz, sh))
        return h, s

    def predict_observations(
        self,
        ids: np.ndarray,
        heading_rad: float,
        altitude_m: float,
        focal_px: float,
        vehicle_offset_m=(0.0, 0.0),
        pixel_sigma_px: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(3) for several landmarks at once, with the vehicle moved by ``vehicle_offset_m``.

        This is the landmark search of the loop: it comes before this frame's speed is known,
        so the pipeline moves the vehicle by the last speed. Returns the predicted [m, n]
        (K, 2) and the innovation covariances S (K, 2, 2) with the pixel noise only, in O(K).
        """
        ids = np.asarray(ids, dtype=np.intp).reshape(-1)
        rows = np.array([self._index(i) for i in ids], dtype=np.intp).reshape(-1)  # (K,) first state row
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, _, _ = self._noise_args(pixel_sigma_px, 0.0, 0.0)
        offset = _vector2("vehicle_offset_m", vehicle_offset_m)
        theta = self.map_heading_rad(psi)
        depth = np.array([self._depth(int(r), z) for r in rows]) if len(rows) else np.zeros(0)
        lm_rows = rows[:, None] + np.arange(self._lm)[None, :]  # (K, lm)
        x = self._x
        h = observe_mn(x[lm_rows[:, :2]], x[:2] + offset, theta, depth[:, None], f)  # (3), one depth per landmark
        a, j_psi = observation_jacobians(h, theta, depth[:, None, None], f)  # (K, 2, 2), (K, 2)
        # H_v (K, 2, v) and H_l (K, 2, lm), as in _observation_terms.
        hv = ([-a] + ([-j_psi[:, :, None]] if self._eps is not None else [])
              + ([-(h / depth[:, None])[:, :, None]] if self._b is not None else [])
              + ([np.zeros((len(h), 2, 2))] if self._w is not None else []))
        hl = [a] + ([(h / depth[:, None])[:, :, None]] if self._lm == 3 else [])
        hv_m, hl_m = np.concatenate(hv, axis=2), np.concatenate(hl, axis=2)
        p = self._P
        v = self._v
        p_vv = p[:v, :v]
        p_vl = p[:v][:, lm_rows].transpose(1, 0, 2)  # (K, v, lm)
        p_ll = p[lm_rows[:, :, None], lm_rows[:, None, :]]  # (K, lm, lm)
        cross = hv_m @ p_vl @ np.swapaxes(hl_m, 1, 2)
        s = hv_m @ p_vv @ np.swapaxes(hv_m, 1, 2) + cross + np.swapaxes(cross, 1, 2) + hl_m @ p_ll @ np.swapaxes(hl_m, 1, 2)
        s = s + np.eye(2) * sp**2
        return h, 0.5 * (s + np.swapaxes(s, 1, 2))

    def _innovation_cov(self, hs: np.ndarray, idx: np.ndarray, r_m: np.ndarray) -> np.ndarray:
        p = self._P[np.ix_(idx, idx)]
        s = hs @ p @ hs.T + r_m
        return 0.5 * (s + s.T)

    def _innovation(self, i, mn_px, heading_rad, altitude_m, focal_px, pixel_sigma_px, altitude_sigma_m,
                    heading_sigma_rad):
        """(nu (2,), H columns, state indices, R_m) of one observation, its inputs checked."""
        k = self._index(i)
        mn = _vector2("mn_px", mn_px)
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)
        h, hs, idx, depth = self._observation_terms(k, psi, z, f)
        return mn - h, hs, idx, observation_noise_px2(h, sp, depth, sz, sh), k

    def update(
        self,
        i: int,
        mn_px,
        heading_rad: float,
        altitude_m: float,
        focal_px: float,
        pixel_sigma_px: float | None = None,
        altitude_sigma_m: float = 0.0,
        heading_sigma_rad: float | None = None,
        landmark_only: bool = False,
        gate: float | None = None,
    ) -> UpdateResult:
        """Kalman update with one observation (3) of landmark i.

        Args:
            i: landmark id.
            mn_px: (2,) observed level-equivalent [m, n] (see :func:`rovslam.slam.observation.pixels_to_mn`).
            heading_rad, altitude_m, focal_px: psi, Z, f of (3) (the filter subtracts the
                landmark's height from Z).
            pixel_sigma_px: template localisation noise; default ``config.pixel_sigma_px``.
            altitude_sigma_m: sigma of Z, enters R_m as ``mn * sigma_Z / (Z - h)``.
            heading_sigma_rad: heading noise, enters R_m; default ``config.heading_sigma_rad``.
            landmark_only: update only landmark i's own entries (a tentative landmark: it
                learns where it is, and its height, without moving the vehicle or the map).
            gate: the innovation test's threshold; default ``config.innovation_gate``
                (``inf``: no test, e.g. a re-admission after a recovery).

        Returns:
            :class:`UpdateResult`; ``accepted=False`` (state untouched) when the NIS exceeds
            the gate.

        Raises:
            InvalidMeasurementError: NaN/inf or invalid input, unknown id; the state is unchanged.
            FilterInconsistencyError: the covariance lost positive semi-definiteness.
        """
        nu, hs, idx, r_m, k = self._innovation(i, mn_px, heading_rad, altitude_m, focal_px, pixel_sigma_px,
                                               altitude_sigma_m, heading_sigma_rad)
        n = self._n
        rows = self._P[idx, :n]  # (v + lm, n) = P[:, idx]^T (P symmetric), contiguous
        s = hs @ rows[:, idx] @ hs.T + r_m
        s = 0.5 * (s + s.T)
        det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
        if not (det > 0.0 and s[0, 0] > 0.0):
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: innovation covariance of landmark {i} is not positive definite "
                f"(S = {s.tolist()}); the covariance has lost positive semi-definiteness"
            )
        s_inv = np.array([[s[1, 1], -s[0, 1]], [-s[1, 0], s[0, 0]]]) / det
        nis = float(nu @ s_inv @ nu)
        limit = self.config.innovation_gate if gate is None else float(gate)
        if nis > limit:
            return UpdateResult(False, nis, nu, f"innovation test: NIS {nis:.1f} > {limit:g}", s)

        m = rows.T @ hs.T  # (n, 2) M = P H^T
        gain = m @ s_inv  # (n, 2) K
        if landmark_only:  # any K keeps the Joseph form exact: zero the rows outside the landmark
            keep = np.zeros(n, dtype=bool)
            keep[k : k + self._lm] = True
            gain[~keep] = 0.0
        if self._b is not None and self.config.altitude_bias_consider:  # a consider state: carried, never learned
            gain[self._b] = 0.0
        self._x[:n] += gain @ nu  # (3) state update
        # Joseph form, rank 4: P -= K W^T + W K^T, W = M - K S / 2 (valid for any gain K).
        w = m - 0.5 * (gain @ s)
        u4 = np.empty((n, 4), order="F")
        u4[:, :2] = gain
        u4[:, 2:] = w
        vpad = self._vpad
        vpad[:n, :2] = w
        vpad[:n, 2:] = gain
        block_t = self._P[:n, :].T  # (cap, n) Fortran-contiguous view of the used rows
        out = dgemm(-1.0, vpad, u4, beta=1.0, c=block_t, trans_b=1, overwrite_c=1)
        if out is not block_t:  # BLAS wrapper made a copy (should not happen): write back
            block_t[...] = out
        self._symmetrise_rows(idx)
        self._check_blocks(k, f"update of landmark {i}")
        return UpdateResult(True, nis, nu, "", s)

    def joint_nis(self, observations) -> tuple[float, np.ndarray]:
        """Joint compatibility of several landmarks seen in the same frame.

        ``observations``: a sequence of ``(i, mn_px, heading_rad, altitude_m, focal_px,
        pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)``. The innovations share the
        vehicle's error, so they are tested together: returns the joint NIS
        ``nu^T S^-1 nu`` (chi-square with 2K degrees of freedom) and (K,) each observation's
        share of it (``nu_j^T (S^-1 nu)_j``), which points at the one that does not fit.
        """
        terms = [self._innovation(*ob) for ob in observations]
        if not terms:
            return 0.0, np.zeros(0)
        idx = np.unique(np.concatenate([t[2] for t in terms]))
        col = {int(c): j for j, c in enumerate(idx)}
        h_full = np.zeros((2 * len(terms), len(idx)))
        r_full = np.zeros((2 * len(terms), 2 * len(terms)))
        nu = np.concatenate([t[0] for t in terms])
        for j, (_, hs, ix, r_m, _) in enumerate(terms):
            h_full[2 * j : 2 * j + 2, [col[int(c)] for c in ix]] = hs
            r_full[2 * j : 2 * j + 2, 2 * j : 2 * j + 2] = r_m
        s = h_full @ self._P[np.ix_(idx, idx)] @ h_full.T + r_full
        w = np.linalg.solve(0.5 * (s + s.T), nu)
        share = (nu * w).reshape(-1, 2).sum(axis=1)
        return float(nu @ w), share

    def _symmetrise_rows(self, idx: np.ndarray) -> None:
        """Cheap O(N) symmetrisation of the rows/columns the next update reads."""
        n = self._n
        avg = 0.5 * (self._P[idx, :n] + self._P[:n, idx].T)
        self._P[idx, :n] = avg
        self._P[:n, idx] = avg.T

    def _check_blocks(self, k: int, where: str) -> None:
        """Cheap health check: every variance >= 0, the vehicle's and landmark row k's 2x2 blocks PSD."""
        n = self._n
        diag = np.diagonal(self._P)[:n]
        dmax = float(np.max(diag))
        tol = _PSD_RTOL * max(dmax, 1e-30)
        dmin = float(np.min(diag))
        if not (np.isfinite(dmin) and np.isfinite(dmax)) or dmin < -tol:
            j = int(np.argmin(diag)) if np.isfinite(dmin) else int(np.flatnonzero(~np.isfinite(diag))[0])
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT after {where}: variance of state entry {j} is {diag[j]:.3e} "
                f"(negative or not finite); the covariance is no longer positive semi-definite. "
                "Check the noise figures (Q, pixel sigma) and the inputs fed to the filter."
            )
        for r in (0, k):  # the vehicle's and the landmark's 2x2 blocks
            b = self._P[r : r + 2, r : r + 2]
            if b[0, 0] * b[1, 1] - b[0, 1] * b[1, 0] < -tol * tol:
                raise FilterInconsistencyError(
                    f"FILTER INCONSISTENT after {where}: the 2x2 covariance block at state {r} "
                    f"is not positive semi-definite: {b.tolist()}"
                )

    # ------------------------------------------------------------------ (4)
    def augment(
        self,
        mn_px,
        heading_rad: float,
        altitude_m: float,
        focal_px: float,
        pixel_sigma_px: float | None = None,
        altitude_sigma_m: float = 0.0,
        heading_sigma_rad: float | None = None,
    ) -> int:
        """Add a landmark observed at [m, n] by (4); returns its id.

        ``X = x + Z/f R(psi) [m, n]`` (with a landmark height state, ``h = 0`` with variance
        ``landmark_height_sigma_m^2``, and X moves with h). With ``config.augmentation == "full"`` the new rows carry
        the cross-covariances ``cov(X, .) = cov(x, .)`` with the vehicle and the whole map
        (the correct form); with ``"paper"`` only the diagonal block
        ``P_X = P_x + (Z/f)^2 R R_m R^T`` is set and the cross terms are zero.

        Raises:
            InvalidMeasurementError: NaN/inf or invalid input; the state is unchanged.
        """
        mn = _vector2("mn_px", mn_px)
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)

        lm = self._lm
        self._reserve(lm)
        n = self._n
        theta = self.map_heading_rad(psi)
        depth = z + self.altitude_bias_m  # the new landmark's height starts at 0
        g, j_psi = landmark_jacobians(mn, theta, depth, f)  # d X / d [m, n], d X / d psi
        r_m = observation_noise_px2(mn, sp, depth, sz, sh)
        p = self._P
        self._x[n : n + 2] = landmark_from_mn(mn, self._x[:2], theta, depth, f)[0]  # (4)
        # cov(X, .) = J cov(vehicle, .), J = [I (, d X / d eps = -d X / d psi) (, d X / d b = R [m, n] / f)].
        v = self._v
        jv = np.zeros((2, v))
        jv[:, :2] = np.eye(2)
        if self._eps is not None:
            jv[:, self._eps] = -j_psi[0]
        if self._b is not None:
            jv[:, self._b] = (g @ mn) / depth
        cross = jv @ p[:v, :n]
        block = cross[:, :v] @ jv.T + g @ r_m @ g.T
        if self.config.augmentation == "full":
            p[n : n + 2, :n] = cross
            p[:n, n : n + 2] = cross.T
        else:
            p[n : n + 2, :n] = 0.0
            p[:n, n : n + 2] = 0.0
        if lm == 3:  # the height: a prior of zero, independent of the rest; X moves with it by -R [m, n] / f
            var_h = self.config.landmark_height_sigma_m**2
            jh = -(g @ mn) / depth  # d X / d h
            block = block + var_h * np.outer(jh, jh)
            self._x[n + 2] = 0.0
            p[n + 2, : n + 2] = 0.0
            p[: n + 2, n + 2] = 0.0
            p[n : n + 2, n + 2] = p[n + 2, n : n + 2] = var_h * jh
            p[n + 2, n + 2] = var_h
        p[n : n + 2, n : n + 2] = 0.5 * (block + block.T)
        self._n = n + lm
        return (n - self._v) // lm

    # ------------------------------------------------------------------ (5), (6)
    def _gate_inputs(self):
        cross = self.vehicle_landmark_cov_m2() if self.config.gate_covariance == "relative" else None
        return self.landmarks_xy_m(), self.landmarks_cov_m2(), self._x[:2], self._P[:2, :2], cross

    def _footprint(self, heading_rad, altitude_m, focal_px, width_px, height_px) -> np.ndarray:
        """D of (5) at the map heading, the inputs checked."""
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        w = _finite("width_px", width_px, positive=True)
        hgt = _finite("height_px", height_px, positive=True)
        return gating.footprint_matrix_m2(self.map_heading_rad(psi), z, f, w, hgt)

    def visibility_statistics(
        self, heading_rad: float, altitude_m: float, focal_px: float, width_px: float, height_px: float
    ) -> np.ndarray:
        """(N,) left-hand side of (5) for every landmark."""
        d_fp = self._footprint(heading_rad, altitude_m, focal_px, width_px, height_px)
        if self.n_landmarks == 0:
            return np.zeros(0)
        xy, cov, vxy, vcov, cross = self._gate_inputs()
        return gating.visibility_statistics(xy, cov, vxy, vcov, d_fp, cross)

    def visible_landmarks(
        self, heading_rad: float, altitude_m: float, focal_px: float, width_px: float, height_px: float
    ) -> np.ndarray:
        """Ids (int array) of the landmarks that pass the visibility gate (5)."""
        d_fp = self._footprint(heading_rad, altitude_m, focal_px, width_px, height_px)
        if self.n_landmarks == 0:
            return np.zeros(0, dtype=np.intp)
        xy, cov, vxy, vcov, cross = self._gate_inputs()
        return np.flatnonzero(gating.visibility_gate(xy, cov, vxy, vcov, d_fp, self.config.visibility_lambda, cross))

    def new_landmark_statistics(self) -> np.ndarray:
        """(N,) left-hand side of (6) for every landmark."""
        if self.n_landmarks == 0:
            return np.zeros(0)
        xy, cov, vxy, vcov, cross = self._gate_inputs()
        spacing = gating.spacing_matrix_m2(self.config.new_landmark_spacing_m, self.config.new_landmark_mu)
        return gating.new_landmark_statistics(xy, cov, vxy, vcov, spacing, cross)

    def may_add_landmark(self) -> bool:
        """Test (6) against every landmark: True when the vehicle is far enough from all (or none exist)."""
        xy, cov, vxy, vcov, cross = self._gate_inputs()
        spacing = gating.spacing_matrix_m2(self.config.new_landmark_spacing_m, self.config.new_landmark_mu)
        return gating.new_landmark_test(xy, cov, vxy, vcov, spacing, self.config.new_landmark_mu, cross)

    # ------------------------------------------------------------------ health
    def check_consistency(self, repair: bool = True) -> ConsistencyReport:
        """Full O(N^3) covariance check: symmetry and positive semi-definiteness.

        Symmetrises the whole covariance when ``repair`` (the per-update symmetrisation only
        touches the updated rows). Raises :class:`FilterInconsistencyError` with a loud message
        when an eigenvalue is negative beyond rounding or an entry is not finite.
        """
        n = self._n
        p = self._P[:n, :n]
        if not np.all(np.isfinite(p)):
            raise FilterInconsistencyError(
                "FILTER INCONSISTENT: the covariance holds NaN or infinite entries; "
                "a bad input reached the filter"
            )
        asym = float(np.max(np.abs(p - p.T))) if n else 0.0
        sym = 0.5 * (p + p.T)
        if repair:
            p[...] = sym
        eig = np.linalg.eigvalsh(sym)
        emin, emax = float(eig[0]), float(eig[-1])
        report = ConsistencyReport(n, asym, emin, emax, float(np.min(np.diagonal(sym))))
        tol = _PSD_RTOL * max(emax, 1e-30) * max(n, 1)
        if emin < -tol or asym > tol:
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: covariance of dimension {n} has min eigenvalue {emin:.3e} "
                f"(max {emax:.3e}) and asymmetry {asym:.3e}; it is no longer a valid covariance. "
                f"Check the noise figures and the inputs fed to the filter. {report}"
            )
        return report

    def __repr__(self) -> str:
        x, y = self._x[:2]
        return f"EkfSlam(vehicle=({x:.3f}, {y:.3f}) m, landmarks={self.n_landmarks}, capacity={(self._cap - self._v) // self._lm})"
