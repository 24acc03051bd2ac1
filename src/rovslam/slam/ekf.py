"""Augmented-state EKF-SLAM: state ``[x, y, (eps,) (b,) (s,) (wx, wy,) X1, Y1, (h1,) ..., XN, YN, (hN)]`` (metres, world frame).

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

``s`` (metres, present when ``seabed_offset_sigma_m > 0``) is the seabed level under the laser
spots relative to the start's, learned from the landmarks. The lasers range to the relief under
their spots, which rises and falls by centimetres as the relief passes under the camera, while a
landmark's height stays where it is: measured from the seabed under the spots at each frame, the
heights would move with the relief, and a landmark seen near the edge of the image from 1.3 m,
with 2 cm of relief under the spots, is 2 to 3 px off. With ``s`` the depth of landmark i is
``Z + b + s - h_i``, ``h_i`` its height above the start's seabed, and a new landmark's height
starts at ``s`` (the seabed under the camera now) with ``landmark_height_sigma_m`` of its own;
its position (4) then does not depend on ``s``. ``s`` is an Ornstein-Uhlenbeck process
(``seabed_offset_sigma_m``, ``seabed_offset_tau_s``: the relief passing under the spots), 0 with
no variance at the start (the start's seabed is the datum). ``b`` then carries the altimeter's
lasting error alone. Over a simulated relief dive (portofino-relief, seed 2) the landmarks'
observations fit a fixed 3-D point to 0.10 px RMS from the true camera heights, and to 0.74 px
from the laser's altitude: that gap is what ``s`` takes out, as far as the landmarks in view
measure it (docs/consistency.md).

``w = [wx, wy]`` (m/s, world frame, present when ``speed_bias_sigma_mps > 0``) is a slow error of
the measured speed that moves with the world, not with the vehicle: sunlight caustics drifting
over the seabed drag a few per cent of their speed into the tokens even after the wide opening
took most of the light out (-1.5 to -1.7 mm/s of surge on the swell preset, 0.5 m of drift over 5
minutes). The true step is ``R(psi) [u, v] dt + w dt``; ``w`` is an Ornstein-Uhlenbeck process
whose stationary sigma the caller gives per step (the pipeline: ``speed_bias_sigma_mps`` while the
sunlight is being taken out, else 0, so ``w`` fades; without it ``w`` stays 0 with no variance);
when that sigma rises, ``w``'s variance rises at once. The landmarks tracked from frame to frame
estimate it; observations do not depend on it.

* Prediction (1), (2) (:mod:`rovslam.slam.motion`, its steps :mod:`rovslam.slam.prediction`, its inputs one
  :class:`rovslam.slam.inputs.MotionInput`): ``[x, y] += R(psi) [u, v] dt``; the speed covariance Q is projected
  through ``R(psi) dt``, an optional heading noise through ``dR/dpsi [u, v] dt``; landmarks
  are static with an optional process noise per step.
* Update (3) (:mod:`rovslam.slam.observation`; the predicted [m, n] and the stacked H of one or many landmarks:
  :func:`rovslam.slam.kalman.observe_landmarks`): ``[m, n] = f/(Z - h_i) R(psi)^T (X_i - x)``. H is non-zero
  only in the vehicle's and the landmark's columns, so the Joseph-form covariance update
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

Storage and layout (:mod:`rovslam.slam.state`): which optional states exist and their rows are a
:class:`~rovslam.slam.state.StateLayout` built once from the configuration; state and covariance live in
preallocated buffers whose capacity doubles when full, so augmenting costs O(N) (plus an
amortised copy on growth), never a reallocation per landmark. Landmark ids are 0..N-1 in order of
creation. Health checks: :mod:`rovslam.slam.health`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.config import SlamConfig
from rovslam.errors import FilterInconsistencyError, InvalidMeasurementError
from rovslam.slam import gating, prediction
from rovslam.slam.health import ConsistencyReport, check_blocks, check_consistency
from rovslam.slam.inputs import (
    MotionInput,
    checked_cov2,
    checked_scalar,
    checked_vector2,
)
from rovslam.slam.kalman import joseph_update, observe_landmarks, symmetrise_rows
from rovslam.slam.motion import altitude_offset_sigma_m
from rovslam.slam.observation import (
    landmark_from_mn,
    landmark_jacobians,
    observation_noise_px2,
)
from rovslam.slam.state import SlamState, StateLayout

__all__ = ["ConsistencyReport", "EkfSlam", "MotionInput", "UpdateResult"]


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


class EkfSlam(SlamState):
    """EKF-SLAM over the vehicle position and N point landmarks (equations (1)-(6)).

    The state's read access (the vehicle, the biases, the landmarks) is :class:`SlamState`'s.

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
        xy = checked_vector2("initial_xy_m", initial_xy_m)
        z0 = (
            None
            if initial_altitude_m is None
            else checked_scalar("initial_altitude_m", initial_altitude_m, positive=True)
        )
        if initial_cov_m2 is None:
            cov = np.eye(2) * config.initial_position_sigma_m**2
        else:
            cov = checked_cov2("initial_cov_m2", initial_cov_m2)
        super().__init__(StateLayout.from_config(config), initial_capacity)
        lay = self.layout
        self._x[:2] = xy
        self._P[:2, :2] = cov
        if lay.eps is not None:
            self._P[lay.eps, lay.eps] = config.heading_bias_sigma_rad**2
        if lay.b is not None:
            sb = (
                config.altitude_bias_sigma_m
                if z0 is None
                else altitude_offset_sigma_m(config.altitude_bias_sigma_m, config.altitude_scale_sigma, z0)
            )
            self._P[lay.b, lay.b] = sb**2
        self._w_sigma_mps = 0.0  # the speed error's stationary sigma over the last step (0: none yet)

    def inflate_vehicle_covariance(self, cov_m2) -> None:
        """Add a (2, 2) PSD covariance to the vehicle position block (an uncertainty the filter was not told of).

        At the first frame this is the start's uncertainty (e.g. the AHRS tilt offset); the
        whole covariance stays positive semi-definite.
        """
        self._P[:2, :2] += checked_cov2("added vehicle covariance", cov_m2)

    # ------------------------------------------------------------------ (1), (2)
    def predict(self, motion: MotionInput) -> None:
        """Prediction by (1) and (2) with the measured body speed and heading of ``motion`` as inputs.

        The inputs were checked when ``motion`` was built (:class:`rovslam.slam.inputs.MotionInput`);
        the steps are :mod:`rovslam.slam.prediction`'s.

        Raises:
            InvalidMeasurementError: ``motion`` is not a :class:`MotionInput`; the state is unchanged.
        """
        if not isinstance(motion, MotionInput):
            raise InvalidMeasurementError(
                f"predict takes a MotionInput (speed, its covariance, heading, dt, ...), got {type(motion).__name__}"
            )
        lay, n, x, p = self.layout, self._n, self._x, self._P
        terms = prediction.motion_terms(motion, self.config, lay, self.heading_bias_rad, self.altitude_bias_m)
        prediction.move_vehicle(x, lay, terms)  # (1)
        prediction.couple_vehicle(p, n, lay, terms)  # P <- F P F^T
        prediction.drive_biases(x, p, n, lay, terms, self._w_sigma_mps)
        if lay.w is not None:
            self._w_sigma_mps = terms.speed_bias_sigma_mps
        prediction.add_process_noise(p, n, lay, terms)  # + G Q G^T, (2)

    # ------------------------------------------------------------------ (3)
    def _observation_terms(self, k: int, psi: float, z: float, f: float):
        """Landmark row k's h (2,) by (3), the non-zero columns of H (2, vehicle_dim + landmark_dim), their
        state indices, and its depth."""
        lay = self.layout
        depth = self._depth(k, z)
        h, hs = observe_landmarks(
            lay, self._x, np.array([k], dtype=np.intp), self._x[:2], self.map_heading_rad(psi), np.array([depth]), f
        )
        idx = np.concatenate([np.arange(lay.vehicle_dim), np.arange(k, k + lay.landmark_dim)])
        return h[0], hs[0], idx, depth

    def _noise_args(self, pixel_sigma_px, altitude_sigma_m, heading_sigma_rad):
        sp = self.config.pixel_sigma_px if pixel_sigma_px is None else pixel_sigma_px
        sp = checked_scalar("pixel_sigma_px", sp, positive=True)
        sz = checked_scalar("altitude_sigma_m", altitude_sigma_m, nonnegative=True)
        sh = self.config.heading_sigma_rad if heading_sigma_rad is None else heading_sigma_rad
        sh = checked_scalar("heading_sigma_rad", sh, nonnegative=True)
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
        psi = checked_scalar("heading_rad", heading_rad)
        z = checked_scalar("altitude_m", altitude_m, positive=True)
        f = checked_scalar("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)
        h, hs, idx, depth = self._observation_terms(k, psi, z, f)
        s = hs @ self._P[np.ix_(idx, idx)] @ hs.T + observation_noise_px2(h, sp, depth, sz, sh)
        return h, 0.5 * (s + s.T)

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
        rows = self._rows(ids)  # (K,) first state row
        psi = checked_scalar("heading_rad", heading_rad)
        z = checked_scalar("altitude_m", altitude_m, positive=True)
        f = checked_scalar("focal_px", focal_px, positive=True)
        sp, _, _ = self._noise_args(pixel_sigma_px, 0.0, 0.0)
        offset = checked_vector2("vehicle_offset_m", vehicle_offset_m)
        lay, x, p = self.layout, self._x, self._P
        depth = self._depths(rows, z)
        h, hh = observe_landmarks(lay, x, rows, x[:2] + offset, self.map_heading_rad(psi), depth, f)
        v = lay.vehicle_dim
        hv_m, hl_m = np.ascontiguousarray(hh[:, :, :v]), np.ascontiguousarray(hh[:, :, v:])  # (K, 2, v), (K, 2, lm)
        lm_rows = lay.landmark_rows(rows)  # (K, lm)
        p_vv = p[:v, :v]
        p_vl = p[:v][:, lm_rows].transpose(1, 0, 2)  # (K, v, lm)
        p_ll = p[lm_rows[:, :, None], lm_rows[:, None, :]]  # (K, lm, lm)
        cross = hv_m @ p_vl @ np.swapaxes(hl_m, 1, 2)
        s = (
            hv_m @ p_vv @ np.swapaxes(hv_m, 1, 2)
            + cross
            + np.swapaxes(cross, 1, 2)
            + hl_m @ p_ll @ np.swapaxes(hl_m, 1, 2)
        )
        s = s + np.eye(2) * sp**2
        return h, 0.5 * (s + np.swapaxes(s, 1, 2))

    def _rows(self, ids: np.ndarray) -> np.ndarray:
        """(K,) first state row of each of the (K,) landmark ids, the ids checked (as :meth:`_index`)."""
        n_lm = self.n_landmarks
        if len(ids) and not (0 <= int(ids.min()) and int(ids.max()) < n_lm):
            for i in ids.tolist():
                self._index(i)  # raises for the first id out of range
        return self.layout.vehicle_dim + self.layout.landmark_dim * ids

    def _depths(self, rows: np.ndarray, z: float) -> np.ndarray:
        """(K,) depths :meth:`_depth` of the landmarks at state ``rows`` (K,), in one array operation."""
        lay = self.layout
        if not lay.has_landmark_heights and lay.b is None and lay.s is None:
            return np.full(len(rows), z)
        above = z + self.altitude_bias_m + self.seabed_offset_m
        depth = above - self._x[rows + 2] if lay.has_landmark_heights else np.full(len(rows), above - 0.0)
        if not np.all(depth > 0.05 * z):
            for r in rows.tolist():
                self._depth(r, z)  # raises for the first landmark above the camera
        return depth

    def _innovation(
        self, i, mn_px, heading_rad, altitude_m, focal_px, pixel_sigma_px, altitude_sigma_m, heading_sigma_rad
    ):
        """(nu (2,), H columns, state indices, R_m, first state row) of one observation, its inputs checked."""
        k = self._index(i)
        mn = checked_vector2("mn_px", mn_px)
        psi = checked_scalar("heading_rad", heading_rad)
        z = checked_scalar("altitude_m", altitude_m, positive=True)
        f = checked_scalar("focal_px", focal_px, positive=True)
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
        nu, hs, idx, r_m, k = self._innovation(
            i, mn_px, heading_rad, altitude_m, focal_px, pixel_sigma_px, altitude_sigma_m, heading_sigma_rad
        )
        n = self._n
        rows = self._P[idx, :n]  # (v + lm, n) = P[:, idx]^T (P symmetric), contiguous
        s, s_inv = self._innovation_cov(hs @ rows[:, idx] @ hs.T + r_m, i)
        nis = float(nu @ s_inv @ nu)
        limit = self.config.innovation_gate if gate is None else float(gate)
        if nis > limit:
            return UpdateResult(False, nis, nu, f"innovation test: NIS {nis:.1f} > {limit:g}", s)
        m = rows.T @ hs.T  # (n, 2) M = P H^T
        gain = self._gain(m @ s_inv, k, landmark_only)  # (n, 2) K
        self._x[:n] += gain @ nu  # (3) state update
        joseph_update(self._P, n, self._vpad, gain, m, s)
        symmetrise_rows(self._P, n, idx)
        check_blocks(self._P, n, k, f"update of landmark {i}")
        return UpdateResult(True, nis, nu, "", s)

    @staticmethod
    def _innovation_cov(s: np.ndarray, i) -> tuple[np.ndarray, np.ndarray]:
        """S (2, 2) symmetrised and its inverse; :class:`FilterInconsistencyError` when S is not positive definite."""
        s = 0.5 * (s + s.T)
        det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
        if not (det > 0.0 and s[0, 0] > 0.0):
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: innovation covariance of landmark {i} is not positive definite "
                f"(S = {s.tolist()}); the covariance has lost positive semi-definiteness"
            )
        return s, np.array([[s[1, 1], -s[0, 1]], [-s[1, 0], s[0, 0]]]) / det

    def _gain(self, gain: np.ndarray, k: int, landmark_only: bool) -> np.ndarray:
        """The gain (n, 2) with the rows that must not learn zeroed (any K keeps the Joseph form exact)."""
        if landmark_only:  # only the landmark at state row k learns
            keep = np.zeros(self._n, dtype=bool)
            keep[k : k + self.layout.landmark_dim] = True
            gain[~keep] = 0.0
        if self.layout.b is not None and self.layout.altitude_bias_consider:  # a consider state: carried, never learned
            gain[self.layout.b] = 0.0
        return gain

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
        mn = checked_vector2("mn_px", mn_px)
        psi = checked_scalar("heading_rad", heading_rad)
        z = checked_scalar("altitude_m", altitude_m, positive=True)
        f = checked_scalar("focal_px", focal_px, positive=True)
        sp, sz, sh = self._noise_args(pixel_sigma_px, altitude_sigma_m, heading_sigma_rad)
        lay = self.layout
        theta = self.map_heading_rad(psi)
        depth = z + self.altitude_bias_m  # the new landmark's height starts at 0
        g, j_psi = landmark_jacobians(mn, theta, depth, f)  # d X / d [m, n], d X / d psi
        r_m = observation_noise_px2(mn, sp, depth, sz, sh)
        xy = landmark_from_mn(mn, self._x[:2], theta, depth, f)[0]  # (4)
        jh = -(g @ mn) / depth if lay.has_landmark_heights else None  # d X / d h
        return self._append_landmark(
            xy,
            lay.new_landmark_jacobian(j_psi, g, mn, depth),
            g @ r_m @ g.T,
            jh,
            full=self.config.augmentation == "full",
        )

    # ------------------------------------------------------------------ (5), (6)
    def _gate_inputs(self):
        cross = self.vehicle_landmark_cov_m2() if self.config.gate_covariance == "relative" else None
        return self.landmarks_xy_m(), self.landmarks_cov_m2(), self._x[:2], self._P[:2, :2], cross

    def _footprint(self, heading_rad, altitude_m, focal_px, width_px, height_px) -> np.ndarray:
        """D of (5) at the map heading, the inputs checked."""
        psi = checked_scalar("heading_rad", heading_rad)
        z = checked_scalar("altitude_m", altitude_m, positive=True)
        f = checked_scalar("focal_px", focal_px, positive=True)
        w = checked_scalar("width_px", width_px, positive=True)
        hgt = checked_scalar("height_px", height_px, positive=True)
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
        """Full O(N^3) covariance check: symmetry and positive semi-definiteness (:func:`rovslam.slam.health.check_consistency`).

        Symmetrises the whole covariance when ``repair`` (the per-update symmetrisation only
        touches the updated rows). Raises :class:`FilterInconsistencyError` with a loud message
        when an eigenvalue is negative beyond rounding or an entry is not finite.
        """
        return check_consistency(self._P, self._n, repair)
