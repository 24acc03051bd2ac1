"""The inputs that enter the EKF, checked where they enter: scalars, [m, n] pairs, 2x2 covariances, and
the inputs of one prediction step (:class:`MotionInput`).

Every check raises :class:`rovslam.errors.InvalidMeasurementError` saying what was wrong, before the
filter's state is touched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovslam.errors import InvalidMeasurementError, finite_scalar

__all__ = ["MotionInput", "checked_cov2", "checked_scalar", "checked_vector2"]


def checked_scalar(name: str, value, *, positive: bool = False, nonnegative: bool = False) -> float:
    """``value`` as a finite float (> 0 with ``positive``, >= 0 with ``nonnegative``)."""
    return finite_scalar(
        name,
        value,
        positive=positive,
        nonnegative=nonnegative,
        nan_hint="the filter state; drop this measurement or fix the sensor input (the state is unchanged)",
        suffix=" (the state is unchanged)",
    )


def checked_vector2(name: str, value) -> np.ndarray:
    """``value`` as a finite (2,) float64 array."""
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


def checked_cov2(name: str, value) -> np.ndarray:
    """``value`` as a finite, symmetric, positive semi-definite (2, 2) covariance (symmetrised)."""
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (2, 2):
        raise InvalidMeasurementError(f"{name} must be a (2, 2) covariance, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidMeasurementError(f"{name} has a NaN or infinite entry: {a.tolist()}; the state is unchanged")
    scale = max(abs(a[0, 0]), abs(a[1, 1]), 1e-300)
    if abs(a[0, 1] - a[1, 0]) > 1e-9 * scale:
        raise InvalidMeasurementError(f"{name} must be symmetric, got {a.tolist()}")
    if a[0, 0] < 0 or a[1, 1] < 0 or a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0] < -1e-12 * scale * scale:
        raise InvalidMeasurementError(
            f"{name} must be positive semi-definite (non-negative variances, |cov| <= sigma_x sigma_y), "
            f"got {a.tolist()}"
        )
    return 0.5 * (a + a.T)


@dataclass(frozen=True, eq=False)
class MotionInput:
    """The inputs of one prediction (1), (2): the measured body speed and heading over one step.

    Checked when built (:class:`rovslam.errors.InvalidMeasurementError` for a NaN, an infinite
    value, a bad shape or range), so a filter never sees a bad one. None takes the
    filter's configured value.

    Attributes:
        surge_mps, sway_mps: body-frame speed over the ground.
        speed_cov_mps2: (2, 2) its covariance Q (stored symmetrised).
        heading_rad: heading psi over the step.
        dt_s: real time step (> 0).
        heading_sigma_rad: heading noise; None: ``config.heading_sigma_rad``.
        altitude_m: the altitude Z the speed was measured at; with the altitude-bias state the
            step is scaled by ``(Z + b) / Z``. None: no such coupling.
        altitude_bias_sigma_m: the bias's stationary sigma over this step (the relief under
            the lasers may be rougher here); None: ``config.altitude_bias_sigma_m``.
        heading_walk_var_rad2: a heading input integrated from turns, without a compass: the
            variance it gained over this step. ``eps`` is then a random walk (no decay towards
            0) driven by it, instead of the compass's Ornstein-Uhlenbeck drift. None: a compass.
        speed_bias_sigma_mps: the stationary sigma of the speed error ``w`` over this step: the
            odometry is dragged only while something moves over the seabed (the pipeline gives
            ``config.speed_bias_sigma_mps`` while it takes sunlight out); 0 lets ``w`` fade.
        altitude_bias_tau_s: the bias's correlation time over this step (the relief's part of it
            decorrelates faster than the altimeter's offset); None: ``config.altitude_bias_tau_s``.
        seabed_offset_sigma_m: the seabed offset s's stationary sigma over this step (the relief under
            the laser spots); None: ``config.seabed_offset_sigma_m``.
    """

    surge_mps: float
    sway_mps: float
    speed_cov_mps2: np.ndarray
    heading_rad: float
    dt_s: float
    heading_sigma_rad: float | None = None
    altitude_m: float | None = None
    altitude_bias_sigma_m: float | None = None
    heading_walk_var_rad2: float | None = None
    speed_bias_sigma_mps: float = 0.0
    altitude_bias_tau_s: float | None = None
    seabed_offset_sigma_m: float | None = None

    def __post_init__(self) -> None:
        checks: tuple[tuple[str, dict[str, bool] | None], ...] = (
            ("surge_mps", {}),
            ("sway_mps", {}),
            ("speed_cov_mps2", None),
            ("heading_rad", {}),
            ("dt_s", {"positive": True}),
            ("heading_sigma_rad", {"nonnegative": True}),
            ("altitude_m", {"positive": True}),
            ("altitude_bias_sigma_m", {"nonnegative": True}),
            ("altitude_bias_tau_s", {"positive": True}),
            ("seabed_offset_sigma_m", {"nonnegative": True}),
            ("heading_walk_var_rad2", {"nonnegative": True}),
            ("speed_bias_sigma_mps", {"nonnegative": True}),
        )
        for name, kind in checks:  # in this order: the first bad input is the one named
            value = getattr(self, name)
            if kind is None:
                object.__setattr__(self, name, checked_cov2(name, value))
            elif value is not None:
                object.__setattr__(self, name, checked_scalar(name, value, **kind))
