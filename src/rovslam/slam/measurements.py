"""The per-frame measurements both SLAM back ends consume (the EKF and the iSAM2 smoother).

One :class:`FrameMeasurements` per frame holds everything the pipeline measured, in plain
numbers, before any back end used it: the body speed from the tokens with its covariance,
the heading input, the raw compass reading, the turn the tokens measured, the image depth,
and the landmark observations of equation (3) as level-equivalent ``[m, n]`` pixels with
their noise R_m. The EKF (:class:`rovslam.slam.EkfSlam`) and the smoother
(:class:`rovslam.slam.smoother.Isam2Smoother`) read the same records; written to disk
(:mod:`rovslam.io.measurements`) they let ``rovslam smooth`` rebuild the whole problem of a
finished run.

Conventions (DESIGN.md): world x north, y east (metres); heading psi from x towards y
(radians); body x forward (surge u), y starboard (sway v). Record k describes the step from
frame k-1 to frame k: its speed was measured between the two frames and, by (1), moves the
vehicle by ``R(psi_{k-1}) [u, v] dt_k`` where ``psi_{k-1}`` is the heading of record k-1; its
landmark observations were made at frame k under ``psi_k``.

Every value is checked on construction; a bad one raises
:class:`~rovslam.errors.InvalidMeasurementError` naming the field and the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from rovslam.errors import InvalidMeasurementError

__all__ = ["LandmarkMeasurement", "FrameMeasurements", "LANDMARK_KINDS"]

LANDMARK_KINDS = ("init", "track")

# Relative tolerance of the covariance checks (asymmetry, negative determinant).
_COV_RTOL = 1e-9


def _where(index) -> str:
    return f"frame {index}" if index is not None else "measurement"


def _scalar(
    name: str, value, where: str, *, allow_nan: bool = False, positive: bool = False, nonnegative: bool = False
) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidMeasurementError(f"{where}: {name} must be a number, got {value!r}") from None
    if math.isnan(v):
        if allow_nan:
            return v
        raise InvalidMeasurementError(f"{where}: {name} is NaN; give a measured value (or drop the frame)")
    if math.isinf(v):
        raise InvalidMeasurementError(
            f"{where}: {name} is {v}; give a finite value (NaN when it was not measured)"
            if allow_nan
            else f"{where}: {name} is {v}; give a finite value"
        )
    if positive and v <= 0.0:
        raise InvalidMeasurementError(f"{where}: {name} must be > 0, got {v}")
    if nonnegative and v < 0.0:
        raise InvalidMeasurementError(f"{where}: {name} must be >= 0, got {v}")
    return v


def _frozen_array(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)  # own copy
    a.flags.writeable = False
    return a


def _vector2(name: str, value, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidMeasurementError(f"{where}: {name} must hold 2 numbers, got {value!r}") from None
    if a.shape != (2,):
        raise InvalidMeasurementError(f"{where}: {name} must have shape (2,), got {a.shape}")
    u, v = a.tolist()
    if not (math.isfinite(u) and math.isfinite(v)):
        raise InvalidMeasurementError(f"{where}: {name} = {a.tolist()} has a NaN or infinite value")
    return _frozen_array(a)


def _cov2(name: str, value, where: str, *, definite: bool = False) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidMeasurementError(f"{where}: {name} must be a (2, 2) covariance, got {value!r}") from None
    if a.shape != (2, 2):
        raise InvalidMeasurementError(f"{where}: {name} must be a (2, 2) covariance, got shape {a.shape}")
    (a00, a01), (a10, a11) = a.tolist()  # Python floats: the checks cost a tenth of NumPy scalar ones
    if not (math.isfinite(a00) and math.isfinite(a01) and math.isfinite(a10) and math.isfinite(a11)):
        raise InvalidMeasurementError(f"{where}: {name} has a NaN or infinite entry: {a.tolist()}")
    scale = max(abs(a00), abs(a11), 1e-300)
    if abs(a01 - a10) > _COV_RTOL * scale:
        raise InvalidMeasurementError(f"{where}: {name} must be symmetric, got {a.tolist()}")
    # sigma_x sigma_y as a product of square roots: no underflow for tiny variances.
    bound = math.sqrt(max(a00, 0.0)) * math.sqrt(max(a11, 0.0))
    if a00 < 0 or a11 < 0 or abs(a01) > bound + _COV_RTOL * scale:
        raise InvalidMeasurementError(
            f"{where}: {name} must be positive semi-definite (variances >= 0, |cov| <= sigma_x sigma_y), "
            f"got {a.tolist()}"
        )
    if definite and (a00 <= 0 or a11 <= 0 or abs(a01) >= bound * (1.0 - 1e-12)):
        raise InvalidMeasurementError(
            f"{where}: {name} must be positive definite (a measurement with zero noise cannot be weighed), "
            f"got {a.tolist()}"
        )
    return _frozen_array(0.5 * (a + a.T))


def _same(a, b) -> bool:
    """Equality for the fields of these records: arrays element-wise, NaN equal to NaN."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.shape(a) == np.shape(b) and bool(np.array_equal(a, b, equal_nan=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


class _RecordEq:
    """``==`` field by field with :func:`_same` (frozen dataclasses holding arrays)."""

    def __eq__(self, other) -> bool:
        if type(other) is not type(self):
            return NotImplemented
        return all(_same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))  # type: ignore[arg-type]

    __hash__ = None  # type: ignore[assignment]  # holds arrays: not hashable


@dataclass(frozen=True, eq=False)
class LandmarkMeasurement(_RecordEq):
    """One landmark observation of equation (3) in one frame.

    Attributes:
        landmark_id: the landmark's id (0, 1, ... in order of creation).
        kind: ``"init"`` when this observation created the landmark (initialisation (4)),
            ``"track"`` when an existing landmark was found again.
        mn_px: (2,) level-equivalent ``[m, n]`` of (3), pixels: m forward, n starboard
            (:func:`rovslam.slam.pixels_to_mn`).
        noise_px2: (2, 2) R_m, pixels squared: the template localisation and the altitude
            error (``observation_noise_px2(mn, pixel_sigma, Z, altitude_sigma)``), without
            the heading term: each back end adds the heading uncertainty in its own way.
        accepted_by_online: False when the online back end (the EKF's innovation test)
            rejected it; the smoother may still use it, under its robust loss.
    """

    landmark_id: int
    kind: str
    mn_px: np.ndarray
    noise_px2: np.ndarray
    accepted_by_online: bool = True

    def __post_init__(self) -> None:
        where = f"landmark observation {self.landmark_id!r}"
        lid = self.landmark_id
        if isinstance(lid, (bool, np.bool_)) or not isinstance(lid, (int, np.integer)) or lid < 0:
            raise InvalidMeasurementError(f"{where}: landmark_id must be an integer >= 0, got {lid!r}")
        object.__setattr__(self, "landmark_id", int(lid))
        if self.kind not in LANDMARK_KINDS:
            raise InvalidMeasurementError(f"{where}: kind must be 'init' or 'track', got {self.kind!r}")
        object.__setattr__(self, "mn_px", _vector2("mn_px", self.mn_px, where))
        object.__setattr__(self, "noise_px2", _cov2("noise_px2", self.noise_px2, where, definite=True))
        if not isinstance(self.accepted_by_online, (bool, np.bool_)):
            raise InvalidMeasurementError(
                f"{where}: accepted_by_online must be True or False, got {self.accepted_by_online!r}"
            )
        object.__setattr__(self, "accepted_by_online", bool(self.accepted_by_online))


@dataclass(frozen=True, eq=False)
class FrameMeasurements(_RecordEq):
    """Everything measured in one frame, as both back ends consume it.

    Attributes:
        index: frame index in the sequence (>= 0, increasing along a run).
        t_s: frame time, seconds.
        dt_s: ``t_s`` minus the previous frame's time (0 for the first frame), seconds.
        speed_mps: (2,) body speed over the ground ``[surge u, sway v]`` over the step from
            the previous frame, m/s (the held speed when the tokens failed).
        speed_cov_mps2: (2, 2) its covariance Q, (m/s)^2; positive definite when ``dt_s > 0``.
        speed_ok: True when the tokens measured the speed in this frame (False: held speed,
            grown covariance).
        heading_rad: the heading input of the online filter at this frame (the compass
            smoothed with the token turns, rovslam's convention), radians.
        heading_sigma_rad: white-noise standard deviation of ``heading_rad``.
        compass_rad: the raw compass reading at this frame, radians; NaN without a compass.
        compass_sigma_rad: the compass's white-noise standard deviation (its slow drift is a
            model parameter of each back end), radians.
        heading_step_rad: the turn the tokens measured from the previous frame to this one,
            radians; NaN when not measured.
        heading_step_sigma_rad: its standard deviation; NaN when not measured.
        altitude_m: image depth Z (> 0), metres.
        altitude_sigma_m: its standard deviation, metres; NaN when not measured (a skipped frame).
        focal_px: focal length f of (3), pixels.
        landmarks: the landmark observations made in this frame (ids unique within the frame).
        attitude_sigma_rad: the accuracy of the roll and pitch this frame was levelled with
            (0: no AHRS); the tilt error it leaves shifts the apparent frame
            (:mod:`rovslam.slam.apparent`), radians.
    """

    index: int
    t_s: float
    dt_s: float
    speed_mps: np.ndarray
    speed_cov_mps2: np.ndarray
    speed_ok: bool
    heading_rad: float
    heading_sigma_rad: float
    compass_rad: float
    compass_sigma_rad: float
    heading_step_rad: float
    heading_step_sigma_rad: float
    altitude_m: float
    altitude_sigma_m: float
    focal_px: float
    landmarks: tuple[LandmarkMeasurement, ...] = ()
    attitude_sigma_rad: float = 0.0

    def __post_init__(self) -> None:
        idx = self.index
        if isinstance(idx, (bool, np.bool_)) or not isinstance(idx, (int, np.integer)) or idx < 0:
            raise InvalidMeasurementError(f"frame measurement: index must be an integer >= 0, got {idx!r}")
        object.__setattr__(self, "index", int(idx))
        where = _where(self.index)
        put = object.__setattr__
        put(self, "t_s", _scalar("t_s", self.t_s, where))
        put(self, "dt_s", _scalar("dt_s", self.dt_s, where, nonnegative=True))
        put(self, "speed_mps", _vector2("speed_mps", self.speed_mps, where))
        put(self, "speed_cov_mps2", _cov2("speed_cov_mps2", self.speed_cov_mps2, where, definite=self.dt_s > 0))
        if not isinstance(self.speed_ok, (bool, np.bool_)):
            raise InvalidMeasurementError(f"{where}: speed_ok must be True or False, got {self.speed_ok!r}")
        put(self, "speed_ok", bool(self.speed_ok))
        put(self, "heading_rad", _scalar("heading_rad", self.heading_rad, where))
        put(self, "heading_sigma_rad", _scalar("heading_sigma_rad", self.heading_sigma_rad, where, nonnegative=True))
        put(self, "compass_rad", _scalar("compass_rad", self.compass_rad, where, allow_nan=True))
        put(self, "compass_sigma_rad", _scalar("compass_sigma_rad", self.compass_sigma_rad, where, nonnegative=True))
        step = _scalar("heading_step_rad", self.heading_step_rad, where, allow_nan=True)
        step_sigma = _scalar("heading_step_sigma_rad", self.heading_step_sigma_rad, where, allow_nan=True)
        if math.isnan(step) != math.isnan(step_sigma):
            raise InvalidMeasurementError(
                f"{where}: heading_step_rad and heading_step_sigma_rad must both be NaN (turn not measured) "
                f"or both be numbers, got {step} and {step_sigma}"
            )
        if not math.isnan(step_sigma) and step_sigma <= 0.0:
            raise InvalidMeasurementError(f"{where}: heading_step_sigma_rad must be > 0, got {step_sigma}")
        put(self, "heading_step_rad", step)
        put(self, "heading_step_sigma_rad", step_sigma)
        put(self, "altitude_m", _scalar("altitude_m", self.altitude_m, where, positive=True))
        sz = _scalar("altitude_sigma_m", self.altitude_sigma_m, where, allow_nan=True, nonnegative=True)
        put(self, "altitude_sigma_m", sz)
        put(self, "focal_px", _scalar("focal_px", self.focal_px, where, positive=True))
        put(self, "attitude_sigma_rad", _scalar("attitude_sigma_rad", self.attitude_sigma_rad, where, nonnegative=True))
        try:
            obs = tuple(self.landmarks)
        except TypeError:
            raise InvalidMeasurementError(
                f"{where}: landmarks must be a sequence of LandmarkMeasurement, got {self.landmarks!r}"
            ) from None
        seen: set[int] = set()
        for ob in obs:
            if not isinstance(ob, LandmarkMeasurement):
                raise InvalidMeasurementError(f"{where}: landmarks must hold LandmarkMeasurement, got {ob!r}")
            if ob.landmark_id in seen:
                raise InvalidMeasurementError(
                    f"{where}: landmark {ob.landmark_id} is observed twice in one frame; keep one observation"
                )
            seen.add(ob.landmark_id)
        put(self, "landmarks", obs)

    @property
    def has_compass(self) -> bool:
        return not math.isnan(self.compass_rad)

    @property
    def has_heading_step(self) -> bool:
        return not math.isnan(self.heading_step_rad)
