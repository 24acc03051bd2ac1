"""The EKF's state vector: which optional states it holds, where, their process noise, and read access.

Layout (:class:`StateLayout`, built once from the configuration)::

    [x, y, (eps,) (b,) (wx, wy,) X1, Y1, (h1,) ..., XN, YN, (hN)]

the vehicle block (``vehicle_dim`` rows: the position, then the optional heading error ``eps``,
altitude offset ``b`` and world-frame speed error ``w``), then N landmark blocks of
``landmark_dim`` rows (the position, then the optional height ``h``). :mod:`rovslam.slam.ekf` says
what each state means.

:class:`SlamState` holds the mean and covariance in preallocated buffers whose capacity doubles
when full (augmenting costs O(N) plus an amortised copy on growth, never a reallocation per
landmark) and reads them: the vehicle, the biases, each landmark, the depth of a landmark under
the camera. Landmark ids are 0..N-1 in order of creation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.config import SlamConfig
from rovslam.errors import FilterInconsistencyError, InvalidMeasurementError

__all__ = ["SlamState", "StateLayout"]


@dataclass(frozen=True)
class StateLayout:
    """Which optional states the filter holds, their rows, and their process noise.

    Attributes:
        eps: row of the heading input's slow error (radians); None without it.
        b: row of the measured altitude's offset (metres); None without it.
        s: row of the seabed level under the laser spots relative to the start's (metres, learned); None without it.
        w: first of the two rows of the world-frame speed error (m/s); None without it.
        vehicle_dim: rows of the vehicle block: 2 (+1 with eps, +1 with b, +1 with s, +2 with w).
        landmark_dim: rows of a landmark block: 2, or 3 with the landmark heights.
        heading_bias_sigma_rad, heading_bias_tau_s: eps's Ornstein-Uhlenbeck process.
        altitude_bias_sigma_m, altitude_bias_tau_s: b's, unless a step gives its own.
        speed_bias_tau_s: w's correlation time (its sigma comes with each step).
        landmark_process_sigma_m: (2)'s landmark process noise per step (0: static).
        altitude_bias_consider: b is carried, never learned (a Schmidt consider state).
        landmark_height_sigma_m: a new landmark's height prior.
        seabed_offset_sigma_m, seabed_offset_tau_s: s's Ornstein-Uhlenbeck process.
    """

    eps: int | None
    b: int | None
    w: int | None
    vehicle_dim: int
    landmark_dim: int
    heading_bias_sigma_rad: float
    heading_bias_tau_s: float
    altitude_bias_sigma_m: float
    altitude_bias_tau_s: float
    speed_bias_tau_s: float
    landmark_process_sigma_m: float
    altitude_bias_consider: bool
    landmark_height_sigma_m: float
    s: int | None = None
    seabed_offset_sigma_m: float = 0.0
    seabed_offset_tau_s: float = 5.0

    @classmethod
    def from_config(cls, config: SlamConfig) -> StateLayout:
        """The layout a configuration asks for (a sigma > 0 puts its state in)."""
        eps = 2 if config.heading_bias_sigma_rad > 0 else None
        b = (2 + (eps is not None)) if config.altitude_bias_sigma_m > 0 else None
        # s needs the landmark heights: a new landmark's height starts at s
        with_s = config.seabed_offset_sigma_m > 0 and config.landmark_height_sigma_m > 0
        s = (2 + (eps is not None) + (b is not None)) if with_s else None
        w = (2 + (eps is not None) + (b is not None) + (s is not None)) if config.speed_bias_sigma_mps > 0 else None
        return cls(
            eps=eps,
            b=b,
            w=w,
            s=s,
            seabed_offset_sigma_m=config.seabed_offset_sigma_m,
            seabed_offset_tau_s=config.seabed_offset_tau_s,
            vehicle_dim=2 + (eps is not None) + (b is not None) + (s is not None) + 2 * (w is not None),
            landmark_dim=3 if config.landmark_height_sigma_m > 0 else 2,
            heading_bias_sigma_rad=config.heading_bias_sigma_rad,
            heading_bias_tau_s=config.heading_bias_tau_s,
            altitude_bias_sigma_m=config.altitude_bias_sigma_m,
            altitude_bias_tau_s=config.altitude_bias_tau_s,
            speed_bias_tau_s=config.speed_bias_tau_s,
            landmark_process_sigma_m=config.landmark_process_sigma_m,
            altitude_bias_consider=config.altitude_bias_consider,
            landmark_height_sigma_m=config.landmark_height_sigma_m,
        )

    @property
    def has_landmark_heights(self) -> bool:
        return self.landmark_dim == 3

    def landmark_row(self, k: int) -> int:
        """First state row of landmark k."""
        return self.vehicle_dim + self.landmark_dim * k

    def landmark_rows(self, rows: np.ndarray) -> np.ndarray:
        """(K, landmark_dim) every state row of the landmarks whose first rows are (K,) ``rows``."""
        return rows[:, None] + np.arange(self.landmark_dim)[None, :]

    def new_landmark_jacobian(self, j_psi: np.ndarray, g: np.ndarray, mn_px: np.ndarray, depth_m: float) -> np.ndarray:
        """(2, vehicle_dim) derivative of a new landmark (4) with respect to the vehicle block.

        ``[I (, d X / d eps = -d X / d psi) (, d X / d b = R [m, n] / f)]``; ``j_psi`` (1, 2) and
        ``g`` (2, 2) are :func:`rovslam.slam.observation.landmark_jacobians` at ``depth_m``.
        """
        jv = np.zeros((2, self.vehicle_dim))
        jv[:, :2] = np.eye(2)
        if self.eps is not None:
            jv[:, self.eps] = -j_psi[0]
        if self.b is not None:
            jv[:, self.b] = (g @ mn_px) / depth_m
        return jv


class SlamState:
    """The filter's mean and covariance under a :class:`StateLayout`, with read access to every part.

    Args:
        layout: the state's layout.
        capacity: landmarks the buffers hold before their first growth.
    """

    _x: np.ndarray  # (cap,) the mean; entries >= state_dim unused
    _P: np.ndarray  # (cap, cap) the covariance; rows and columns >= state_dim unused
    _cap: int
    _vpad: np.ndarray  # (cap, 4) work array of the update

    def __init__(self, layout: StateLayout, capacity: int):
        self.layout = layout
        self._n = layout.vehicle_dim
        self._alloc(layout.vehicle_dim + layout.landmark_dim * max(int(capacity), 1))

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

    def _append_landmark(
        self, xy_m: np.ndarray, jv: np.ndarray, noise_m2: np.ndarray, jh: np.ndarray | None, full: bool
    ) -> int:
        """Append a landmark block; returns its id.

        ``cov(X, .) = jv cov(vehicle, .)`` (``jv`` (2, vehicle_dim)) plus ``noise_m2`` (2, 2), the
        observation's share; ``full``: with the cross-covariances, else the diagonal block alone.
        With the heights, ``h = 0`` with variance ``landmark_height_sigma_m^2``, independent of the
        rest, and X moves with it by ``jh`` (2,) = d X / d h; with the seabed offset s, ``h = s + e``,
        ``e`` of that variance (the seabed under the camera now), and X moves with ``e``.
        """
        lay = self.layout
        lm, v = lay.landmark_dim, lay.vehicle_dim
        self._reserve(lm)
        n = self._n
        p = self._P
        self._x[n : n + 2] = xy_m
        cross = jv @ p[:v, :n]
        block = cross[:, :v] @ jv.T + noise_m2
        if full:
            p[n : n + 2, :n] = cross
            p[:n, n : n + 2] = cross.T
        else:
            p[n : n + 2, :n] = 0.0
            p[:n, n : n + 2] = 0.0
        if jh is not None:  # the height h = e, e its own prior, or h = s + e (the seabed under the spots now)
            var_h = lay.landmark_height_sigma_m**2
            block = block + var_h * np.outer(jh, jh)
            s = lay.s
            self._x[n + 2] = 0.0 if s is None else self._x[s]
            p[n + 2, :n] = 0.0 if s is None else p[s, :n]
            p[:n, n + 2] = 0.0 if s is None else p[:n, s]
            p[n : n + 2, n + 2] = p[n + 2, n : n + 2] = var_h * jh if s is None else cross[:, s] + var_h * jh
            p[n + 2, n + 2] = var_h if s is None else p[s, s] + var_h
        p[n : n + 2, n : n + 2] = 0.5 * (block + block.T)
        self._n = n + lm
        return (n - v) // lm

    # ------------------------------------------------------------------ the whole state
    @property
    def state_dim(self) -> int:
        """2 (+1 with eps, +1 with b, +1 with s, +2 with w) + 2N (3N with the landmark heights)."""
        return self._n

    @property
    def n_landmarks(self) -> int:
        return (self._n - self.layout.vehicle_dim) // self.layout.landmark_dim

    @property
    def has_landmark_heights(self) -> bool:
        return self.layout.has_landmark_heights

    @property
    def landmark_ids(self) -> list[int]:
        return list(range(self.n_landmarks))

    @property
    def state_m(self) -> np.ndarray:
        """(state_dim,) full state (copy)."""
        return self._x[: self._n].copy()

    @property
    def covariance_m2(self) -> np.ndarray:
        """(state_dim, state_dim) full covariance (copy; O(N^2))."""
        return self._P[: self._n, : self._n].copy()

    # ------------------------------------------------------------------ the vehicle block
    @property
    def vehicle_xy_m(self) -> np.ndarray:
        """(2,) vehicle position (copy)."""
        return self._x[:2].copy()

    @property
    def vehicle_cov_m2(self) -> np.ndarray:
        """(2, 2) vehicle position covariance (copy)."""
        return self._P[:2, :2].copy()

    def _value(self, row: int | None) -> float:
        return float(self._x[row]) if row is not None else 0.0

    def _sigma(self, row: int | None) -> float:
        return float(np.sqrt(max(self._P[row, row], 0.0))) if row is not None else 0.0

    @property
    def heading_bias_rad(self) -> float:
        """Estimated slow heading error eps (true heading = input - eps); 0 without the state."""
        return self._value(self.layout.eps)

    @property
    def heading_bias_sigma_rad(self) -> float:
        return self._sigma(self.layout.eps)

    @property
    def altitude_bias_m(self) -> float:
        """Estimated offset b of the measured altitude from the seabed datum (true depth = Z + b); 0 without the state."""
        return self._value(self.layout.b)

    @property
    def altitude_bias_sigma_m(self) -> float:
        return self._sigma(self.layout.b)

    @property
    def seabed_offset_m(self) -> float:
        """Estimated seabed level under the laser spots relative to the start's (s); 0 without the state."""
        return self._value(self.layout.s)

    def landmark_depth_m(self, i: int, z: float) -> float:
        """Landmark i's depth under a camera at measured altitude z: ``Z + b + s - h``."""
        return self._depth(self._index(i), float(z))

    @property
    def speed_bias_mps(self) -> np.ndarray:
        """(2,) estimated world-frame speed error w (true step = measured step + w dt); zeros without the state."""
        w = self.layout.w
        return self._x[w : w + 2].copy() if w is not None else np.zeros(2)

    @property
    def speed_bias_cov_mps2(self) -> np.ndarray:
        """(2, 2) its covariance; zeros without the state."""
        w = self.layout.w
        return self._P[w : w + 2, w : w + 2].copy() if w is not None else np.zeros((2, 2))

    def map_heading_rad(self, heading_rad: float) -> float:
        """The heading the filter believes for a heading input: ``psi - eps`` (the input without its slow bias)."""
        return float(heading_rad) - self.heading_bias_rad

    # ------------------------------------------------------------------ landmarks
    def _index(self, i) -> int:
        """First state row of landmark id ``i``, the id checked."""
        try:
            k = int(i)
        except (TypeError, ValueError):
            raise InvalidMeasurementError(f"landmark id must be an integer, got {i!r}") from None
        if not 0 <= k < self.n_landmarks:
            raise InvalidMeasurementError(
                f"no landmark {k}: the map holds ids 0..{self.n_landmarks - 1}"
                if self.n_landmarks
                else f"no landmark {k}: the map is empty; augment() first"
            )
        return self.layout.landmark_row(k)

    def _depth(self, k: int, z: float) -> float:
        """Depth of the landmark at state row k under a camera at measured altitude z: ``Z + b + s - h``."""
        heights = self.layout.has_landmark_heights
        depth = z + self.altitude_bias_m + self.seabed_offset_m - (float(self._x[k + 2]) if heights else 0.0)
        if not heights and self.layout.b is None and self.layout.s is None:
            return z
        if not depth > 0.05 * z:
            raise FilterInconsistencyError(
                f"FILTER INCONSISTENT: landmark at state row {k} is estimated {self._x[k + 2]:.3f} m high, "
                f"above the camera's altitude {z:.3f} m"
            )
        return depth

    def landmark_height_m(self, i: int) -> float:
        """Landmark i's height above the seabed Z refers to: the start's with the seabed offset s (0 without the height state)."""
        r = self._index(i)
        return float(self._x[r + 2]) if self.layout.has_landmark_heights else 0.0

    def landmark_height_sigma_m(self, i: int) -> float:
        r = self._index(i)
        return float(np.sqrt(max(self._P[r + 2, r + 2], 0.0))) if self.layout.has_landmark_heights else 0.0

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
        lay = self.layout
        return self._x[lay.vehicle_dim : self._n].reshape(-1, lay.landmark_dim)[:, :2].copy()

    def landmarks_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) the landmarks' diagonal covariance blocks (O(N))."""
        r = np.arange(self.layout.vehicle_dim, self._n, self.layout.landmark_dim)
        p = self._P
        out = np.empty((len(r), 2, 2))
        out[:, 0, 0] = p[r, r]
        out[:, 0, 1] = p[r, r + 1]
        out[:, 1, 0] = p[r + 1, r]
        out[:, 1, 1] = p[r + 1, r + 1]
        return out

    def vehicle_landmark_cov_m2(self) -> np.ndarray:
        """(N, 2, 2) cross-covariances ``C_i = cov(x, X_i)`` (vehicle rows, landmark columns)."""
        lay = self.layout
        return (
            self._P[0:2, lay.vehicle_dim : self._n].reshape(2, -1, lay.landmark_dim)[:, :, :2].transpose(1, 0, 2).copy()
        )

    def __repr__(self) -> str:
        x, y = self._x[:2]
        lay = self.layout
        return (
            f"{type(self).__name__}(vehicle=({x:.3f}, {y:.3f}) m, landmarks={self.n_landmarks}, "
            f"capacity={(self._cap - lay.vehicle_dim) // lay.landmark_dim})"
        )
