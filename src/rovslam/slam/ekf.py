"""Augmented-state EKF-SLAM: state ``[x, y, (eps,) X1, Y1, ..., XN, YN]`` (metres, world frame).

``eps`` (radians, present when ``heading_bias_sigma_rad > 0``) is the slow error of the heading
input, beyond the paper: the true heading is ``psi - eps``, ``eps`` an Ornstein-Uhlenbeck
process. A compass drifts with the vehicle's own magnetic field; while it drifts, landmarks
mapped under one error and seen again under another turn the map. With ``eps`` in the state
the re-observations estimate the change; its absolute value (a rotation of the whole map)
stays unobservable and its variance says so.

* Prediction (1), (2) (:mod:`rovslam.slam.motion`): ``[x, y] += R(psi) [u, v] dt``; the speed covariance Q is projected
  through ``R(psi) dt``, an optional heading noise through ``dR/dpsi [u, v] dt``; landmarks
  are static with an optional process noise per step.
* Update (3) (:mod:`rovslam.slam.observation`): ``[m, n] = f/Z R(psi)^T (X_i - x)``. H is non-zero only in the vehicle's and the
  landmark's columns, so the Joseph-form covariance update
  ``P' = (I - K H) P (I - K H)^T + K R K^T = P - K M^T - M K^T + K S K^T`` (``M = P H^T``)
  is a rank-4 correction ``P -= [K W] [W K]^T`` with ``W = M - K S / 2``, applied in place
  with one BLAS ``dgemm``: O(N^2) memory traffic, no dense (2N+2)^3 product, no inverse
  bigger than 2x2. An innovation (chi-square) test rejects matches inconsistent with the
  prediction before anything changes.
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
from rovslam.slam.motion import motion_jacobians, motion_step_m
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
    """

    def __init__(
        self,
        config: SlamConfig = SlamConfig(),
        initial_xy_m=(0.0, 0.0),
        initial_cov_m2=None,
        initial_capacity: int = 16,
    ):
        self.config = config  # validated when it was built (rovslam.config)
        xy = _vector2("initial_xy_m", initial_xy_m)
        if initial_cov_m2 is None:
            cov = np.eye(2) * config.initial_position_sigma_m**2
        else:
            cov = _cov2("initial_cov_m2", initial_cov_m2)
        self._v = 3 if config.heading_bias_sigma_rad > 0 else 2  # vehicle block: x, y (, eps)
        self._n = self._v
        self._alloc(self._v + 2 * max(int(initial_capacity), 1))
        self._x[:2] = xy
        self._P[:2, :2] = cov
        if self._v == 3:
            self._P[2, 2] = config.heading_bias_sigma_rad**2

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
        """2 + 2N, or 3 + 2N with the heading-bias state."""
        return self._n

    @property
    def n_landmarks(self) -> int:
        return (self._n - self._v) // 2

    @property
    def heading_bias_rad(self) -> float:
        """Estimated slow heading error eps (true heading = input - eps); 0 without the state."""
        return float(self._x[2]) if self._v == 3 else 0.0

    @property
    def heading_bias_sigma_rad(self) -> float:
        return float(np.sqrt(max(self._P[2, 2], 0.0))) if self._v == 3 else 0.0

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
        return self._v + 2 * k

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
        return self._x[self._v : self._n].reshape(-1, 2).copy()

    def landmarks_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) the landmarks' diagonal covariance blocks (O(N))."""
        r = np.arange(self._v, self._n, 2)
        p = self._P
        out = np.empty((len(r), 2, 2))
        out[:, 0, 0] = p[r, r]
        out[:, 0, 1] = p[r, r + 1]
        out[:, 1, 0] = p[r + 1, r]
        out[:, 1, 1] = p[r + 1, r + 1]
        return out

    def vehicle_landmark_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) cross-covariances ``C_i = cov(x, X_i)`` (vehicle rows, landmark columns)."""
        return self._P[0:2, self._v : self._n].reshape(2, -1, 2).transpose(1, 0, 2).copy()

    # ------------------------------------------------------------------ (1), (2)
    def predict(
        self,
        surge_mps: float,
        sway_mps: float,
        speed_cov_mps2,
        heading_rad: float,
        dt_s: float,
        heading_sigma_rad: float | None = None,
    ) -> None:
        """Prediction by (1) and (2) with the measured body speed and heading as inputs.

        Args:
            surge_mps, sway_mps: body-frame speed over the ground.
            speed_cov_mps2: (2, 2) its covariance Q.
            heading_rad: heading psi over the step.
            dt_s: real time step (> 0).
            heading_sigma_rad: heading noise; default ``config.heading_sigma_rad``.

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

        theta = self.map_heading_rad(psi)
        speed = np.array([u, v])
        g, j = motion_jacobians(speed, theta, dt)  # d(position) / d(speed), d(position) / d(psi)
        self._x[:2] += motion_step_m(speed, theta, dt)  # (1)
        n = self._n
        if self._v == 3:
            # F = I except d(position)/d(eps) = -j: P <- F P F^T as two O(N) rank-1 steps.
            p = self._P
            p[0:2, :n] -= np.outer(j, p[2, :n])
            p[:n, 0:2] -= np.outer(p[:n, 2], j)
            a = np.exp(-dt / self.config.heading_bias_tau_s)  # eps: Ornstein-Uhlenbeck
            self._x[2] *= a
            p[2, :n] *= a
            p[:n, 2] *= a
            p[2, 2] += self.config.heading_bias_sigma_rad**2 * (1.0 - a * a)
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
    def _observation_terms(self, k: int, psi: float, z: float, f: float):
        """h (2,) by (3), the non-zero columns of H (2, 4 or 5), their state indices, of landmark row k."""
        theta = self.map_heading_rad(psi)
        h = observe_mn(self._x[k : k + 2], self._x[:2], theta, z, f)[0]
        a, j_psi = observation_jacobians(h, theta, z, f)
        if self._v == 3:  # d h / d eps = -d h / d psi
            return h, np.hstack([-a, -j_psi.T, a]), np.array([0, 1, 2, k, k + 1])
        return h, np.hstack([-a, a]), np.array([0, 1, k, k + 1])

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
        h, hs, idx = self._observation_terms(k, psi, z, f)
        s = self._innovation_cov(hs, idx, observation_noise_px2(h, sp, z, sz, sh))
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
        idx = np.asarray(ids, dtype=np.intp).reshape(-1)
        for i in idx:
            self._index(i)
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, _, _ = self._noise_args(pixel_sigma_px, 0.0, 0.0)
        offset = _vector2("vehicle_offset_m", vehicle_offset_m)
        theta = self.map_heading_rad(psi)
        rows = self._v + 2 * idx  # (K,) first state row of each landmark
        h = observe_mn(self._x[np.stack([rows, rows + 1], axis=1)], self._x[:2] + offset, theta, z, f)
        a, j_psi = observation_jacobians(h, theta, z, f)
        p = self._P
        c = p[0:2][:, np.stack([rows, rows + 1], axis=1)].transpose(1, 0, 2)  # (K, 2, 2) cov(x, X_i)
        p_ll = p[rows[:, None, None] + np.arange(2)[None, :, None], rows[:, None, None] + np.arange(2)[None, None, :]]
        cov_d = p_ll + p[0:2, 0:2] - c - np.swapaxes(c, 1, 2)  # cov(X_i - x)
        s = a @ cov_d @ a.T
        if self._v == 3:  # d h / d eps = -J_psi
            e = -j_psi  # (K, 2)
            q = (p[2, np.stack([rows, rows + 1], axis=1)] - p[2, 0:2]) @ a.T  # (K, 2) A (cov(eps, X_i) - cov(eps, x))
            s = s + e[:, :, None] * q[:, None, :] + q[:, :, None] * e[:, None, :] + p[2, 2] * e[:, :, None] * e[:, None, :]
        s = s + np.eye(2) * sp**2
        return h, 0.5 * (s + np.swapaxes(s, 1, 2))

    def _innovation_cov(self, hs: np.ndarray, idx: np.ndarray, r_m: np.ndarray) -> np.ndarray:
        p = self._P[np.ix_(idx, idx)]
        s = hs @ p @ hs.T + r_m
        return 0.5 * (s + s.T)

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
    ) -> UpdateResult:
        """Kalman update with one observation (3) of landmark i.

        Args:
            i: landmark id.
            mn_px: (2,) observed level-equivalent [m, n] (see :func:`rovslam.slam.observation.pixels_to_mn`).
            heading_rad, altitude_m, focal_px: psi, Z, f of (3).
            pixel_sigma_px: template localisation noise; default ``config.pixel_sigma_px``.
            altitude_sigma_m: sigma of Z, enters R_m as ``mn * sigma_Z / Z``.
            heading_sigma_rad: heading noise, enters R_m; default ``config.heading_sigma_rad``.

        Returns:
            :class:`UpdateResult`; ``accepted=False`` (state untouched) when the NIS exceeds
            ``config.innovation_gate``.

        Raises:
            InvalidMeasurementError: NaN/inf or invalid input, unknown id; the state is unchanged.
            FilterInconsistencyError: the covariance lost positive semi-definiteness.
        """
        k = self._index(i)
        mn = _vector2("mn_px", mn_px)
        psi = _finite("heading_rad", heading_rad)
        z = _finite("altitude_m", altitude_m, positive=True)
        f = _finite("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)

        n = self._n
        h, hs, idx = self._observation_terms(k, psi, z, f)
        r_m = observation_noise_px2(h, sp, z, sz, sh)
        rows = self._P[idx, :n]  # (4 or 5, n) = P[:, idx]^T (P symmetric), contiguous
        s = hs @ rows[:, idx] @ hs.T + r_m
        s = 0.5 * (s + s.T)
        det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
        if not (det > 0.0 and s[0, 0] > 0.0):
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: innovation covariance of landmark {i} is not positive definite "
                f"(S = {s.tolist()}); the covariance has lost positive semi-definiteness"
            )
        s_inv = np.array([[s[1, 1], -s[0, 1]], [-s[1, 0], s[0, 0]]]) / det
        nu = mn - h
        nis = float(nu @ s_inv @ nu)
        if nis > self.config.innovation_gate:
            return UpdateResult(
                False, nis, nu, f"innovation test: NIS {nis:.1f} > {self.config.innovation_gate:g}", s
            )

        m = rows.T @ hs.T  # (n, 2) M = P H^T
        gain = m @ s_inv  # (n, 2) K
        self._x[:n] += gain @ nu  # (3) state update
        # Joseph form, rank 4: P -= K W^T + W K^T, W = M - K S / 2.
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
        self._check_blocks(idx, f"update of landmark {i}")
        return UpdateResult(True, nis, nu, "", s)

    def _symmetrise_rows(self, idx: np.ndarray) -> None:
        """Cheap O(N) symmetrisation of the rows/columns the next update reads."""
        n = self._n
        avg = 0.5 * (self._P[idx, :n] + self._P[:n, idx].T)
        self._P[idx, :n] = avg
        self._P[:n, idx] = avg.T

    def _check_blocks(self, idx: np.ndarray, where: str) -> None:
        """Cheap health check: every variance >= 0, the touched 2x2 blocks PSD."""
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
        for r in (idx[0], idx[-2]):  # the vehicle's and the landmark's 2x2 blocks
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

        ``X = x + Z/f R(psi) [m, n]``. With ``config.augmentation == "full"`` the new rows carry
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

        self._reserve(2)
        n = self._n
        theta = self.map_heading_rad(psi)
        g, j_psi = landmark_jacobians(mn, theta, z, f)  # d X / d [m, n], d X / d psi
        r_m = observation_noise_px2(mn, sp, z, sz, sh)
        p = self._P
        self._x[n : n + 2] = landmark_from_mn(mn, self._x[:2], theta, z, f)[0]  # (4)
        # cov(X, .) = cov(x, .) [+ d X / d eps cov(eps, .)]: the rows of J = [I (, je)].
        cross = p[0:2, :n].copy()
        if self._v == 3:
            je = -j_psi[0]  # d X / d eps = -d X / d psi
            cross += np.outer(je, p[2, :n])
            block = cross[:, 0:2] + np.outer(cross[:, 2], je) + g @ r_m @ g.T
        else:
            block = cross[:, 0:2] + g @ r_m @ g.T
        if self.config.augmentation == "full":
            p[n : n + 2, :n] = cross
            p[:n, n : n + 2] = cross.T
        else:
            p[n : n + 2, :n] = 0.0
            p[:n, n : n + 2] = 0.0
        p[n : n + 2, n : n + 2] = 0.5 * (block + block.T)
        self._n = n + 2
        return (n - self._v) // 2

    # ------------------------------------------------------------------ (5), (6)
    def _gate_inputs(self):
        cross = self.vehicle_landmark_cov_m2() if self.config.gate_covariance == "relative" else None
        return self._x[self._v : self._n].reshape(-1, 2), self.landmarks_cov_m2(), self._x[:2], self._P[:2, :2], cross

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
        return f"EkfSlam(vehicle=({x:.3f}, {y:.3f}) m, landmarks={self.n_landmarks}, capacity={(self._cap - self._v) // 2})"
