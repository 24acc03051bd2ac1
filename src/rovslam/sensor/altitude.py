"""The image depth Z over time: each frame's laser / sonar altitude, filtered (beyond the paper).

The paper triangulates Z in every frame and uses it as it is. One frame's altitude is noisy
(a sonar reads to a few centimetres, a faint laser spot to a few millimetres), and the speed
estimator maps the previous frame's tokens at the previous Z and the current ones at the
current Z: a 3 cm difference between two readings of a vehicle that did not move vertically
is a 2 % zoom, which moves a token 150 px from the image centre by 3 px and breaks the
consensus of the tokens. The vehicle's altitude changes smoothly, so a constant-velocity
Kalman filter (state ``[Z, dZ/dt]``, white vertical acceleration ``accel_sigma_mps2``) fuses
the readings over time; its estimate, and its standard deviation, are what the loop uses.

An assumed constant altitude (no laser, no sonar) is not a measurement: it passes through
unfiltered, its uncertainty never shrinking.
"""

from __future__ import annotations

import math

import numpy as np

from rovslam.errors import finite_scalar

__all__ = ["AltitudeFilter"]


class AltitudeFilter:
    """Constant-velocity Kalman filter of the altitude, one update per frame.

    Args:
        accel_sigma_mps2: standard deviation of the vertical acceleration (white); 0 makes the
            filter a plain running mean of a constant altitude, large values follow each reading.
    """

    def __init__(self, accel_sigma_mps2: float):
        self.accel_sigma_mps2 = float(accel_sigma_mps2)
        self._t_s: float | None = None
        self._x = np.zeros(2)  # [Z, dZ/dt]
        self._p = np.zeros((2, 2))

    @property
    def started(self) -> bool:
        return self._t_s is not None

    def reset(self) -> None:
        self._t_s = None

    def _predict(self, t_s: float) -> None:
        dt = t_s - self._t_s  # type: ignore[operator]
        if dt <= 0.0:
            return
        f = np.array([[1.0, dt], [0.0, 1.0]])
        q = self.accel_sigma_mps2**2 * np.array([[dt**4 / 4.0, dt**3 / 2.0], [dt**3 / 2.0, dt**2]])
        self._x = f @ self._x
        self._p = f @ self._p @ f.T + q
        self._t_s = t_s

    def update(self, t_s: float, altitude_m: float, sigma_m: float) -> tuple[float, float]:
        """Fuse this frame's reading; returns the filtered ``(altitude_m, sigma_m)``."""
        t = finite_scalar("t_s", t_s)
        z = finite_scalar("altitude_m", altitude_m, positive=True)
        r = finite_scalar("altitude sigma_m", sigma_m, positive=True) ** 2
        if self._t_s is None:
            self._x = np.array([z, 0.0])
            # The vertical speed is unknown at the start: a few cm/s.
            self._p = np.diag([r, 0.05**2])
            self._t_s = t
            return z, math.sqrt(r)
        self._predict(t)
        s = self._p[0, 0] + r
        k = self._p[:, 0] / s
        innov = z - self._x[0]
        self._x = self._x + k * innov
        self._p = self._p - np.outer(k, self._p[0, :])
        self._p = 0.5 * (self._p + self._p.T)
        return float(self._x[0]), math.sqrt(max(float(self._p[0, 0]), 0.0))

    def predict(self, t_s: float) -> tuple[float, float] | None:
        """The altitude expected at ``t_s`` without a reading (a skipped frame), or None before the first one."""
        if self._t_s is None:
            return None
        self._predict(finite_scalar("t_s", t_s))
        return float(self._x[0]), math.sqrt(max(float(self._p[0, 0]), 0.0))
