"""The smoothing back end: the paper's measurements in a factor graph, optimised by GTSAM's iSAM2.

Built like GTSAM's Python examples (``Pose2ISAM2Example``, ``PlanarSLAMExample``) from the
plain per-frame records of :mod:`rovslam.slam.measurements`, the same ones the EKF consumes.
Every factor is one of GTSAM's compiled factors (no Python callback: a ``gtsam.CustomFactor``
is handed a copy of all the variables at every evaluation inside iSAM2, which makes each
frame cost O(poses); see docs/method.md, "Smoothing back end").

Variables:

* ``x_k`` (``gtsam.Pose2``): the vehicle at frame k, ``(x, y, psi)`` in the world frame of
  DESIGN.md (x north, y east, psi from x towards y). ``Pose2`` composes exactly as (1):
  ``t_k = t_{k-1} + R(psi_{k-1}) [u, v] dt``.
* ``l_i`` (``gtsam.Point2``): landmark i, ``[X_i, Y_i]``; static, as (2) without process noise.
* ``m_j`` (``gtsam.Pose2``): the compass frame over block j of ``bias_block_s`` seconds. Its
  rotation is minus the slow compass error b_j (the EKF's ``eps``: compass = true heading + b);
  its translation carries nothing and is held at the origin by a prior.

Factors:

* Prior on ``x_0``: the origin (``initial_position_sigma_m``, and with an AHRS the tilt offset
  ``Z sigma_att`` it leaves, as the EKF's start) and, without a compass, the first heading (the
  map frame is then defined by it).
* Odometry, one ``BetweenFactorPose2`` per step: translation ``[u, v] dt`` in the frame of
  ``x_{k-1}``, covariance ``dt^2 Q``; rotation the turn the tokens measured, with its sigma,
  or, when they did not, the change of the heading input with ``loose_turn_sigma_rad``.
* Compass, one per frame with a reading: ``BetweenFactorPose2(m_j, x_k)`` whose rotation
  residual is exactly ``wrap(psi_k + b_j - compass_k)`` (the rotation part of Pose2's Logmap
  is the angle alone); its translation residual gets a sigma of 10 km, i.e. no weight.
  Without the drift model (``heading_bias_sigma_rad = 0``) it is a ``PriorFactorPose2`` on the
  heading alone, the same way. The white noise is inflated by the mean square distance of
  the drift from its block value, ``2 sigma_b^2 (1 - exp(-T / (4 tau)))`` (the bias is held
  constant over a block of T seconds: a documented approximation of the continuous process).
* Compass drift: the block values follow the EKF's Ornstein-Uhlenbeck process exactly,
  ``b_0 ~ N(0, sigma_b^2)``, ``b_{j+1} - a b_j ~ N(0, q)``, ``a = exp(-T / tau)``,
  ``q = sigma_b^2 (1 - a^2)``. Its information is written, exactly, as random-walk links
  ``BetweenFactorPose2(m_j, m_{j+1})`` of information ``a / q`` plus zero-mean priors on each
  block value: ``(1 - a) / q`` at both ends of the chain, ``(1 - a)^2 / q`` inside (a single
  block: ``1 / sigma_b^2``); when a block opens, the prior of the previous last one is
  replaced (iSAM2 removes the old factor).
* Landmarks, one per observation, equation (3) with the image depth known per frame:
  ``[m, n] Z / f = R(psi)^T (X - x)``, i.e. exactly ``Pose2.transformTo(X)`` in metres with
  noise ``(Z/f)^2 R_m``. That is ``gtsam_unstable.DeltaFactor`` (shipped in the gtsam wheel:
  ``pose.transformTo(point) - measured`` with analytic Jacobians), under a robust loss (Huber
  or Cauchy, threshold ``robust_k`` whitened sigmas), so a wrong association is down-weighted
  instead of bending the path. A landmark's first observation creates it at (4),
  ``X = x + Z/f R(psi) [m, n]``.

:meth:`Isam2Smoother.add_frame` adds one frame's factors and runs one iSAM2 update (frame
rate); it returns the newest pose with its marginal covariance. :meth:`Isam2Smoother.smoothed`
polishes the whole graph (Levenberg-Marquardt from the iSAM2 estimate, so the robust weight
of every factor is recomputed at the final estimate) and returns every pose and landmark
with its marginal covariance.

Covariances: GTSAM gives a ``Pose2`` marginal in its tangent space, whose translation is in
the body frame; world-frame position covariances are ``R(psi) Sigma_t R(psi)^T``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rovslam.camera import rot2, wrap_angle
from rovslam.config import ROBUST_LOSSES, SmootherConfig
from rovslam.errors import ConfigError, FilterInconsistencyError, InvalidMeasurementError
from rovslam.slam.heights import (
    ReliefObservations,
    ReliefPriors,
    observation_depths,
    solve_relief,
    whitened_norms,
)
from rovslam.slam.measurements import FrameMeasurements

__all__ = ["SmootherConfig", "Isam2Smoother", "OnlineEstimate", "SmoothedResult", "ROBUST_LOSSES"]

# A zero standard deviation in a prior is taken as this (information 1e12): GTSAM's Gaussian
# models need a finite information matrix, and the marginals stay well conditioned.
_TINY_SIGMA = 1e-6
# Sigma of the residuals that carry no information (metres, radians): information 1e-8.
_FREE_SIGMA = 1e4
# Sigma of the prior holding a compass frame's translation at the origin, metres.
_FRAME_SIGMA_M = 1.0
# The relief rounds stop once no observation's depth moves by more than this (metres).
_RELIEF_TOL_M = 1e-5


@dataclass(frozen=True)
class OnlineEstimate:
    """The newest pose after :meth:`Isam2Smoother.add_frame` (causal: all frames up to this one).

    Attributes:
        index, t_s: the frame.
        xy_m: (2,) position, world frame.
        heading_rad: heading psi (the compass error removed).
        cov_xy_m2: (2, 2) marginal position covariance, world frame.
    """

    index: int
    t_s: float
    xy_m: np.ndarray
    heading_rad: float
    cov_xy_m2: np.ndarray


@dataclass(frozen=True)
class SmoothedResult:
    """Every pose and landmark given all the measurements (:meth:`Isam2Smoother.smoothed`).

    Attributes:
        index: (N,) frame indices; t_s: (N,) frame times.
        xy_m: (N, 2) positions; heading_rad: (N,) headings; altitude_m: (N,) image depths.
        cov_xy_m2: (N, 2, 2) marginal position covariances, world frame (the graph's: without
            the apparent frame's errors, :mod:`rovslam.slam.apparent`).
        landmark_ids: (M,) ids in increasing order.
        landmarks_xy_m: (M, 2) positions; landmarks_cov_m2: (M, 2, 2) marginal covariances.
        landmark_first_t_s: (M,) time of the first observation.
        landmark_observations: (M,) observations in the graph.
        landmark_downweighted: (M,) of them, those whose whitened residual at the estimate
            exceeds ``robust_k`` (what a robust loss down-weights).
        iterations: Levenberg-Marquardt iterations of the final polish.
        attitude_sigma_rad: (N,) each frame's ``FrameMeasurements.attitude_sigma_rad``.
        has_compass: (N,) whether each frame had a compass reading.
        landmark_height_m: (M,) the landmarks' heights above the start's seabed (zeros without
            the relief rounds); seabed_m: (N,) the seabed under the spots, relative to the start's.
        relief_gain: the share of the landmark factors' misfit the relief rounds took away (NaN:
            not tried); below ``relief_min_gain`` their result is set aside for the flat seabed's.
    """

    index: np.ndarray
    t_s: np.ndarray
    xy_m: np.ndarray
    heading_rad: np.ndarray
    altitude_m: np.ndarray
    cov_xy_m2: np.ndarray
    landmark_ids: np.ndarray
    landmarks_xy_m: np.ndarray
    landmarks_cov_m2: np.ndarray
    landmark_first_t_s: np.ndarray
    landmark_observations: np.ndarray
    landmark_downweighted: np.ndarray
    iterations: int = 0
    attitude_sigma_rad: np.ndarray | None = None
    has_compass: np.ndarray | None = None
    landmark_height_m: np.ndarray | None = None
    seabed_m: np.ndarray | None = None
    relief_gain: float = math.nan


@dataclass
class _Landmark:
    first_t_s: float
    # Per observation: pose number, [m, n] / f (2,) and R_m / f^2 (2, 2); times the image depth,
    # they are the measured R^T (X - x) in metres and its noise.
    poses: list = field(default_factory=list)
    ray: list = field(default_factory=list)
    noise: list = field(default_factory=list)


class Isam2Smoother:
    """Incremental smoothing of the paper's measurements with GTSAM's iSAM2.

    Args:
        config: noise model and solver settings.

    Feed one :class:`FrameMeasurements` per frame, in order, to :meth:`add_frame`; ask
    :meth:`smoothed` for the whole path at any time (typically at the end).
    """

    def __init__(self, config: SmootherConfig = SmootherConfig()):
        import gtsam
        import gtsam_unstable

        if not isinstance(config, SmootherConfig):
            raise ConfigError(f"config must be a SmootherConfig, got {type(config).__name__}")
        self.config = config
        self._g = gtsam
        self._delta_factor = gtsam_unstable.DeltaFactor
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(config.relinearize_threshold)
        params.relinearizeSkip = config.relinearize_skip
        params.enablePartialRelinearizationCheck = config.partial_relinearization_check
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(config.wildfire_threshold))
        self._isam = gtsam.ISAM2(params)
        self._index: list[int] = []
        self._t_s: list[float] = []
        self._altitude_m: list[float] = []
        self._attitude_sigma_rad: list[float] = []
        self._has_compass: list[bool] = []
        self._landmarks: dict[int, _Landmark] = {}
        self._prev: FrameMeasurements | None = None
        self._pose: Any = None  # latest gtsam.Pose2 estimate
        self._t0_s = 0.0
        self._robust = self._make_robust()
        # Compass drift: blocks opened so far, the slot of the last block's prior in iSAM2.
        self._use_bias = config.heading_bias_sigma_rad > 0
        self._block = -1
        self._tail_prior_slot: int | None = None
        t, tau, sb = config.bias_block_s, config.heading_bias_tau_s, config.heading_bias_sigma_rad
        self._bias_a = math.exp(-t / tau)
        self._bias_q = sb * sb * (1.0 - self._bias_a**2)
        # Mean square distance of the OU process from its value at the block's middle.
        self._bias_within_var = 2.0 * sb * sb * (1.0 - math.exp(-t / (4.0 * tau)))

    # ------------------------------------------------------------------ keys and models
    def _x(self, k: int) -> int:
        return self._g.symbol("x", k)

    def _l(self, i: int) -> int:
        return self._g.symbol("l", i)

    def _m(self, j: int) -> int:
        return self._g.symbol("m", j)

    def _make_robust(self):
        cfg = self.config
        est = self._g.noiseModel.mEstimator
        if cfg.robust == "huber":
            return est.Huber.Create(cfg.robust_k)
        if cfg.robust == "cauchy":
            return est.Cauchy.Create(cfg.robust_k)
        return None

    def _sigmas(self, s_x: float, s_y: float, s_psi: float):
        return self._g.noiseModel.Diagonal.Sigmas(np.array([s_x, s_y, s_psi]))

    # ------------------------------------------------------------------ accessors
    @property
    def n_poses(self) -> int:
        return len(self._index)

    @property
    def n_landmarks(self) -> int:
        return len(self._landmarks)

    @property
    def landmark_ids(self) -> list[int]:
        return sorted(self._landmarks)

    def _known(self, landmark_id: int) -> int:
        if landmark_id not in self._landmarks:
            raise InvalidMeasurementError(f"no landmark {landmark_id}: the graph holds {self.landmark_ids}")
        return self._l(landmark_id)

    def landmark_xy_m(self, landmark_id: int) -> np.ndarray:
        """(2,) current (online) estimate of a landmark (read from its marginal, see :meth:`_marginal`)."""
        key = self._known(landmark_id)
        delta, _ = self._marginal(key)
        return np.asarray(self._isam.getLinearizationPoint().atPoint2(key), dtype=np.float64) + delta

    def landmark_cov_m2(self, landmark_id: int) -> np.ndarray:
        """(2, 2) current marginal covariance of a landmark."""
        return self._marginal(self._known(landmark_id))[1]

    # ------------------------------------------------------------------ one frame
    def add_frame(self, meas: FrameMeasurements) -> OnlineEstimate:
        """Add one frame's factors, update incrementally, return the newest pose.

        Raises:
            InvalidMeasurementError: a frame out of order, a non-positive time step, a
                landmark initialised twice; the graph is then unchanged.
        """
        g = self._g
        if not isinstance(meas, FrameMeasurements):
            raise InvalidMeasurementError(f"add_frame takes a FrameMeasurements, got {type(meas).__name__}")
        k = len(self._index)
        prev = self._prev
        if prev is not None:
            if meas.index <= prev.index:
                raise InvalidMeasurementError(
                    f"frame {meas.index}: frames must come in increasing order (previous frame {prev.index})"
                )
            if meas.dt_s <= 0.0:
                raise InvalidMeasurementError(
                    f"frame {meas.index}: dt_s must be > 0 after the first frame, got {meas.dt_s}"
                )
        for ob in meas.landmarks:
            if ob.kind == "init" and ob.landmark_id in self._landmarks:
                raise InvalidMeasurementError(
                    f"frame {meas.index}: landmark {ob.landmark_id} is initialised twice "
                    f"(first seen at t = {self._landmarks[ob.landmark_id].first_t_s:.3f} s)"
                )

        graph = g.NonlinearFactorGraph()
        values = g.Values()
        removed: list[int] = []
        xk = self._x(k)
        if prev is None:
            self._t0_s = meas.t_s
            guess = g.Pose2(0.0, 0.0, meas.heading_rad)
            # With an AHRS the start is known only up to its tilt offset (as the EKF's start).
            s_xy = (
                math.hypot(self.config.initial_position_sigma_m, meas.altitude_m * meas.attitude_sigma_rad)
                or _TINY_SIGMA
            )
            # With a compass, the compass and the drift prior fix the heading.
            s_psi = _FREE_SIGMA if meas.has_compass else (self.config.initial_heading_sigma_rad or _TINY_SIGMA)
            graph.add(g.PriorFactorPose2(xk, guess, self._sigmas(s_xy, s_xy, s_psi)))
        else:
            step, noise = self._odometry(prev, meas)
            graph.add(g.BetweenFactorPose2(self._x(k - 1), xk, step, noise))
            guess = self._pose.compose(step)
        values.insert(xk, guess)
        tail_position = None
        if meas.has_compass:
            tail_position = self._add_compass(graph, values, removed, k, meas)
        self._add_landmarks(graph, values, k, guess, meas)

        try:
            result = self._isam.update(graph, values, removed)
        except RuntimeError as exc:  # GTSAM: an indeterminate (ill-posed) linear system
            raise _solver_error(f"the iSAM2 update of frame {meas.index}", exc) from None
        if tail_position is not None:
            self._tail_prior_slot = int(result.getNewFactorsIndices()[tail_position])
        self._index.append(meas.index)
        self._t_s.append(meas.t_s)
        self._altitude_m.append(meas.altitude_m)
        self._attitude_sigma_rad.append(meas.attitude_sigma_rad)
        self._has_compass.append(meas.has_compass)
        self._prev = meas
        self._pose, cov = self._recent_pose(xk)
        r = rot2(self._pose.theta())
        return OnlineEstimate(
            index=meas.index,
            t_s=meas.t_s,
            xy_m=np.array([self._pose.x(), self._pose.y()]),
            heading_rad=float(self._pose.theta()),
            cov_xy_m2=r @ cov[:2, :2] @ r.T,
        )

    def _marginal(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """A variable's update from its linearisation point and its tangent-space marginal covariance.

        ``calculateEstimate`` would first back-substitute the whole tree: every clique holding a
        landmark re-eliminated in this update in its separator, i.e. O(poses) per frame on a
        survey that keeps seeing the same landmarks. The marginal of one variable is read from
        the path between its clique and the root alone (the newest pose, the current drift
        block and the landmarks just seen sit at the top); its mean is the variable's update.
        """
        marginal = self._isam.marginalFactor(key)
        delta = np.asarray(marginal.solve(self._g.VectorValues()).at(key), dtype=np.float64)
        r_inv = np.linalg.inv(np.asarray(marginal.R(), dtype=np.float64))
        return delta, r_inv @ r_inv.T

    def _recent_pose(self, key: int):
        """Estimate (gtsam.Pose2) and (3, 3) tangent covariance of a pose (see :meth:`_marginal`)."""
        delta, cov = self._marginal(key)
        return self._isam.getLinearizationPoint().atPose2(key).retract(delta), cov

    def heading_bias_rad(self) -> float:
        """Current estimate of the slow compass error b (compass = heading + b); 0 without the model."""
        if not self._use_bias or self._block < 0:
            return 0.0
        return -float(self._recent_pose(self._m(self._block))[0].theta())

    def _odometry(self, prev: FrameMeasurements, meas: FrameMeasurements):
        """(1) as a relative pose in the frame of the previous pose, with its 3x3 covariance."""
        g = self._g
        dt = meas.dt_s
        if meas.has_heading_step:
            turn, s_turn = meas.heading_step_rad, meas.heading_step_sigma_rad
        else:
            turn, s_turn = wrap_angle(meas.heading_rad - prev.heading_rad), self.config.loose_turn_sigma_rad
        cov = np.zeros((3, 3))
        cov[:2, :2] = dt * dt * meas.speed_cov_mps2
        cov[2, 2] = s_turn**2
        u, v = meas.speed_mps * dt
        return g.Pose2(float(u), float(v), float(turn)), g.noiseModel.Gaussian.Covariance(cov)

    def _bias_prior(self, j: int, last: bool):
        """Zero-mean prior on block j's drift: the node share of the OU chain's information."""
        a, q = self._bias_a, self._bias_q
        if j == 0:
            info = 1.0 / self.config.heading_bias_sigma_rad**2 if last else (1.0 - a) / q
        else:
            info = (1.0 - a) / q if last else (1.0 - a) ** 2 / q
        return self._g.PriorFactorPose2(
            self._m(j), self._g.Pose2(), self._sigmas(_FRAME_SIGMA_M, _FRAME_SIGMA_M, 1.0 / math.sqrt(info))
        )

    def _add_compass(self, graph, values, removed: list[int], k: int, meas: FrameMeasurements) -> int | None:
        """Compass factor of frame k (and any drift blocks it opens). Returns the graph position
        of the new last block's prior, when one was added."""
        g = self._g
        cfg = self.config
        if not self._use_bias:
            noise = self._sigmas(_FREE_SIGMA, _FREE_SIGMA, meas.compass_sigma_rad or _TINY_SIGMA)
            graph.add(g.PriorFactorPose2(self._x(k), g.Pose2(0.0, 0.0, meas.compass_rad), noise))
            return None
        j = int(math.floor((meas.t_s - self._t0_s) / cfg.bias_block_s + 1e-9))
        tail_position = None
        if j > self._block:  # open the drift blocks up to j (a gap in the compass may skip some)
            if self._block >= 0:  # the old last block is now inside the chain: swap its prior
                removed.append(self._tail_prior_slot)  # type: ignore[arg-type]
                graph.add(self._bias_prior(self._block, last=False))
            link = self._sigmas(_FRAME_SIGMA_M, _FRAME_SIGMA_M, math.sqrt(self._bias_q / self._bias_a))
            for b in range(self._block + 1, j + 1):
                if b > 0:
                    graph.add(g.BetweenFactorPose2(self._m(b - 1), self._m(b), g.Pose2(), link))
                if b == j:
                    tail_position = graph.size()
                graph.add(self._bias_prior(b, last=b == j))
                # The residuals are linear in the drift: any initial value converges in one step.
                values.insert(self._m(b), g.Pose2())
            self._block = j
        noise = self._sigmas(_FREE_SIGMA, _FREE_SIGMA, math.sqrt(meas.compass_sigma_rad**2 + self._bias_within_var))
        graph.add(g.BetweenFactorPose2(self._m(j), self._x(k), g.Pose2(0.0, 0.0, meas.compass_rad), noise))
        return tail_position

    def _add_landmarks(self, graph, values, k: int, pose, meas: FrameMeasurements) -> None:
        scale = meas.altitude_m / meas.focal_px  # metres per pixel of (3)
        for ob in meas.landmarks:
            lm = self._landmarks.get(ob.landmark_id)
            if lm is None:  # (4): X = x + Z/f R(psi) [m, n]
                lm = self._landmarks[ob.landmark_id] = _Landmark(first_t_s=meas.t_s)
                xy = np.array([pose.x(), pose.y()]) + scale * (rot2(pose.theta()) @ ob.mn_px)
                values.insert(self._l(ob.landmark_id), xy)
            elif not ob.accepted_by_online and not self.config.use_rejected:
                continue
            graph.add(self._landmark_factor(k, ob.landmark_id, scale * ob.mn_px, scale * scale * ob.noise_px2))
            lm.poses.append(k)
            lm.ray.append(ob.mn_px / meas.focal_px)
            lm.noise.append(ob.noise_px2 / meas.focal_px**2)

    def _landmark_factor(self, k: int, landmark_id: int, p_m: np.ndarray, cov_m2: np.ndarray):
        """(3) as a factor: R(psi_k)^T (X - x_k) = p_m (metres) with noise cov_m2 (2, 2), under the robust loss."""
        g = self._g
        gauss = g.noiseModel.Gaussian.Covariance(cov_m2)
        model = gauss if self._robust is None else g.noiseModel.Robust.Create(self._robust, gauss)
        return self._delta_factor(self._x(k), self._l(landmark_id), p_m, model)

    # ------------------------------------------------------------------ the whole path
    def smoothed(self) -> SmoothedResult:
        """Every pose and landmark with its marginal covariance, given all frames so far.

        Levenberg-Marquardt from the iSAM2 estimate, then (``relief_rounds``) the relief rounds:
        the landmarks' heights and the seabed under the spots given the poses, the graph again
        with those depths (:mod:`rovslam.slam.heights`).
        """
        g = self._g
        n = len(self._index)
        if n == 0:
            raise InvalidMeasurementError("smoothed(): no frame was added; feed add_frame() first")
        factors = self._isam.getFactorsUnsafe()
        graph = g.NonlinearFactorGraph()
        for i in range(factors.size()):  # iSAM2 leaves empty slots where factors were removed
            if factors.exists(i):
                graph.add(factors.at(i))
        obs = _stacked_observations([self._landmarks[i] for i in self.landmark_ids])
        depth = np.asarray(self._altitude_m)[obs.pose]  # the flat seabed: the laser altitude
        relief = None
        try:
            estimate, iterations = self._polish(graph, self._isam.calculateEstimate())
            gain = math.nan
            if self.config.relief_rounds > 0 and self.config.final_max_iterations > 0 and len(obs.pose):
                trial = self._relief(graph, estimate, obs, depth)
                before = whitened_norms(*self._read(estimate), obs, depth)
                gain = _relief_gain(before, whitened_norms(*self._read(trial[1]), obs, trial[3]), self.config)
                if gain >= self.config.relief_min_gain:  # else the seabed is flat as far as the images tell
                    graph, estimate, relief, depth, more = trial
                    iterations += more
            marginals = g.Marginals(graph, estimate)
        except RuntimeError as exc:
            raise _solver_error("the final smoothing", exc) from None
        xy, psi, lxy = self._read(estimate)
        cov = np.empty((n, 2, 2))
        for k in range(n):
            r = rot2(psi[k])
            cov[k] = r @ np.asarray(marginals.marginalCovariance(self._x(k)))[:2, :2] @ r.T
        ids = np.array(self.landmark_ids, dtype=np.int64)
        m = len(ids)
        lcov = np.empty((m, 2, 2))
        for j, i in enumerate(ids):
            lcov[j] = marginals.marginalCovariance(self._l(int(i)))
        norms = whitened_norms(xy, psi, lxy, obs, depth)
        down = np.bincount(obs.landmark[norms > self.config.robust_k], minlength=m).astype(np.int64)
        return SmoothedResult(
            index=np.array(self._index, dtype=np.int64),
            t_s=np.array(self._t_s),
            xy_m=xy,
            heading_rad=psi,
            altitude_m=np.array(self._altitude_m),
            cov_xy_m2=cov,
            landmark_ids=ids,
            landmarks_xy_m=lxy,
            landmarks_cov_m2=lcov,
            landmark_first_t_s=np.array([self._landmarks[int(i)].first_t_s for i in ids]),
            landmark_observations=np.bincount(obs.landmark, minlength=m).astype(np.int64),
            landmark_downweighted=down,
            iterations=iterations,
            attitude_sigma_rad=np.array(self._attitude_sigma_rad),
            has_compass=np.array(self._has_compass, dtype=bool),
            landmark_height_m=np.zeros(m) if relief is None else relief.height_m,
            seabed_m=np.zeros(n) if relief is None else relief.seabed_m,
            relief_gain=gain,
        )

    def _polish(self, graph, estimate) -> tuple[Any, int]:
        """Levenberg-Marquardt from ``estimate`` (``final_max_iterations``; 0: as it is): the estimate and its iterations."""
        if self.config.final_max_iterations == 0:
            return estimate, 0
        params = self._g.LevenbergMarquardtParams()
        params.setMaxIterations(self.config.final_max_iterations)
        params.setRelativeErrorTol(1e-6)
        params.setAbsoluteErrorTol(1e-9)
        opt = self._g.LevenbergMarquardtOptimizer(graph, estimate, params)
        return opt.optimize(), int(opt.iterations())

    def _read(self, estimate) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 2) positions, (N,) headings and (M, 2) landmark positions (in id order) of an estimate."""
        poses = [estimate.atPose2(self._x(k)) for k in range(len(self._index))]
        xy = np.array([[p.x(), p.y()] for p in poses]).reshape(-1, 2)
        psi = np.array([p.theta() for p in poses])
        lxy = np.array([estimate.atPoint2(self._l(i)) for i in self.landmark_ids], dtype=np.float64).reshape(-1, 2)
        return xy, psi, lxy

    def _relief(self, graph, estimate, obs: ReliefObservations, depth: np.ndarray):
        """The relief rounds: heights and seabed given the poses, then the graph with their depths.

        Returns the last graph, its estimate, the last :class:`ReliefSolution`, the (K,) depths
        and the Levenberg-Marquardt iterations spent.
        """
        g, cfg, ids = self._g, self.config, self.landmark_ids
        kept = [graph.at(i) for i in range(graph.size())]
        kept = [f for f in kept if not any(g.Symbol(key).chr() == ord("l") for key in f.keys())]
        priors = ReliefPriors(cfg.landmark_height_sigma_m, cfg.seabed_offset_sigma_m, cfg.seabed_offset_tau_s)
        t_s, z_m = np.array(self._t_s), np.array(self._altitude_m)
        iterations = 0
        for _ in range(cfg.relief_rounds):
            xy, psi, lxy = self._read(estimate)
            sol = solve_relief(xy, psi, t_s, z_m, lxy, depth, obs, priors, cfg.robust, cfg.robust_k)
            new_depth = observation_depths(z_m, sol.seabed_m, sol.height_m, obs)
            moved_m = float(np.max(np.abs(new_depth - depth)))
            depth = new_depth
            graph = g.NonlinearFactorGraph()
            for f in kept:
                graph.add(f)
            for j in range(len(obs.pose)):
                d = float(depth[j])
                graph.add(
                    self._landmark_factor(int(obs.pose[j]), ids[obs.landmark[j]], obs.ray[j] * d, d * d * obs.noise[j])
                )
            values = g.Values(estimate)
            for j, i in enumerate(ids):
                values.update(self._l(i), sol.landmarks_xy_m[j])
            estimate, more = self._polish(graph, values)
            iterations += more
            if moved_m < _RELIEF_TOL_M:
                break
        return graph, estimate, sol, depth, iterations

    def __repr__(self) -> str:
        return f"Isam2Smoother(poses={self.n_poses}, landmarks={self.n_landmarks}, robust={self.config.robust!r})"


def _relief_gain(before: np.ndarray, after: np.ndarray, config: SmootherConfig) -> float:
    """The share of the landmark factors' misfit (squared whitened residuals, (K,) norms before and after
    the relief rounds) they took away, over the observations the relief explains (within ``robust_k``
    after; all without a robust loss): a wrong association, unexplained either way, would otherwise
    swamp the sum with a cost neither model can lower."""
    used = after <= config.robust_k if config.robust != "none" else np.ones(len(after), dtype=bool)
    return 1.0 - float(np.sum(after[used] ** 2)) / max(float(np.sum(before[used] ** 2)), 1e-300)


def _stacked_observations(recs: list[_Landmark]) -> ReliefObservations:
    """Every landmark observation in the graph, stacked in the order of ``recs`` (landmark-id order)."""
    return ReliefObservations(
        pose=np.array([k for r in recs for k in r.poses], dtype=np.int64),
        landmark=np.repeat(np.arange(len(recs)), [len(r.poses) for r in recs]).astype(np.int64),
        ray=np.array([x for r in recs for x in r.ray], dtype=np.float64).reshape(-1, 2),
        noise=np.array([x for r in recs for x in r.noise], dtype=np.float64).reshape(-1, 2, 2),
        first_pose=np.array([r.poses[0] for r in recs], dtype=np.int64),
    )


def _solver_error(what: str, exc: RuntimeError) -> FilterInconsistencyError:
    """GTSAM's error (several lines) as one line naming what failed and the usual cause."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    detail = " ".join(lines[:2]) if lines else type(exc).__name__
    return FilterInconsistencyError(
        f"SMOOTHER FAILED in {what}: {detail} A variable is not constrained by any measurement, or "
        "a noise figure is zero or far out of scale; check the measurement records."
    )
