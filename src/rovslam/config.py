"""Configuration: one frozen dataclass per pipeline stage, defaults = the paper's figures.

A run is configured by :class:`RunConfig`, which groups the stage configurations. It is
read from and written to TOML with one table per stage::

    [speed_templates]
    size_px = 16
    max_count = 8

Unknown tables or keys are rejected with a :class:`~rovslam.errors.ConfigError` that names
the key and the file. Values are converted to the field's type (an int where an int is
expected, a tuple for sequences).

Ownership: each stage's module reads only its own dataclass.
"""

from __future__ import annotations

import dataclasses
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rovslam.errors import ConfigError


@dataclass(frozen=True)
class BandpassConfig:
    """2-D band-pass filter of Misu et al. (difference of Gaussians) before the local variance.

    The filter works on the template channel scaled to 0..255 (8-bit intensity units); the
    local variance thresholds of :class:`SpeedTemplateConfig` and
    :class:`LandmarkTemplateConfig` are variances of the filtered image in those units
    squared, computed over a window the size of the template (population variance). The
    filter is G(sigma_fine) - G(sigma_coarse) with unit-sum Gaussians: DC gain 0, peak gain
    0.78 (wavelength 14.6 px) for the defaults, no other rescaling. For scale: white sensor
    noise of 3 grey levels gives a local variance of about 0.6 after the default filter.
    The same band-passed image is the tracking image the templates are cut from and
    correlated on (see rovslam.vision.tracking).
    """

    sigma_fine_px: float = 1.0  # removes wavelengths shorter than ~2*pi*sigma_fine (noise)
    sigma_coarse_px: float = 4.0  # removes wavelengths longer than ~2*pi*sigma_coarse (illumination)
    channel: str = "green"  # "grey" | "green" | "blue"; red is reserved for the lasers
    despeckle_px: int = 7  # >= 2: remove bright specks (marine snow) narrower than this first; 0: off (paper)


@dataclass(frozen=True)
class SpeedTemplateConfig:
    """Small templates ("tokens") tracked between consecutive frames for the speed."""

    size_px: int = 16  # paper: 16x16
    max_count: int = 8  # paper: at most 8 per frame
    min_local_variance: float = 4.0  # lower than the landmarks' (std 2 grey levels, ~7x noise)
    search_radius_px: int = 8  # around the position predicted from the last speed
    border_px: int = 4  # extra margin from the image border
    min_spacing_px: int = 40  # least distance between two tokens (u or v); 16 = just non-overlapping


@dataclass(frozen=True)
class LandmarkTemplateConfig:
    """Large templates used as SLAM landmarks."""

    size_px: int = 32  # paper: 32x32
    min_local_variance: float = 12.3  # paper: 12.3
    search_margin_px: int = 6  # search window beyond the 3-sigma predicted uncertainty
    max_search_radius_px: int = 60
    border_px: int = 8
    inhibit_margin_px: int = 4  # speed templates keep this far from landmark templates


@dataclass(frozen=True)
class TrackerConfig:
    """Normalised-correlation matching (OpenCV TM_CCOEFF_NORMED)."""

    min_correlation: float = 0.89  # paper: 0.89
    max_second_peak_ratio: float = 0.98  # reject if the 2nd peak >= ratio * 1st (ambiguous)
    second_peak_exclusion_px: int = 3  # the 2nd peak is sought outside this radius of the 1st
    subpixel: str = "parabolic"  # "parabolic" | "gaussian" (2-D fit on the 3x3 peak) | "none"
    global_search: bool = True  # phase correlation prior when tracks are lost
    global_search_radius_px: int = 12  # search radius around the phase-correlation prior
    min_global_confidence: float = 0.08  # phase-correlation peak response below this: no prior
    min_tracked_fraction: float = 0.5  # fewer tracked with the prediction -> global search


@dataclass(frozen=True)
class LaserConfig:
    """Laser spot detection in the red channel and triangulation."""

    min_red_excess: float = 60.0  # red - max(green, blue), 8-bit units
    min_spot_area_px: int = 3
    max_spot_area_px: int = 400
    search_radius_px: float = 40.0  # around the spot predicted from the last altitude
    inhibit_radius_px: int = 14  # templates keep this far from a spot centre
    max_relative_disagreement: float = 0.05  # a spot whose altitude differs more is an outlier
    spot_sigma_px: float = 0.3  # centroid noise used for the altitude variance
    sonar_sigma_m: float = 0.05
    fixed_altitude_sigma_m: float = 0.10
    min_altitude_m: float = 0.05  # triangulated depths outside this range are rejected
    max_altitude_m: float = 30.0


@dataclass(frozen=True)
class OdometryConfig:
    """Motion-from-tokens speed estimator."""

    outlier_threshold_px: float = 1.0  # residual beyond which a token is an outlier
    min_inliers: int = 2
    min_speed_sigma_mps: float = 0.0005  # floor of the speed standard deviation
    token_sigma_px: float = 0.15  # one token's displacement noise
    gap_speed_sigma_mps: float = 0.02  # added per second without tokens
    initial_speed_sigma_mps: float = 0.2  # speed sigma held before the first good measurement
    max_accel_mps2: float = 0.0  # > 0: a speed changing faster than this (+3 sigma) is a wrong consensus (0: off)
    compass_sigma_rad: float = 0.0087  # compass white noise (0.5 deg); 0 uses the compass as it is (the paper)
    compass_drift_sigma_rad: float = 0.0087  # slow compass error no smoothing removes (magnetic disturbance)
    attitude_sigma_rad: float = 0.0035  # AHRS roll / pitch accuracy (0.2 deg, a typical spec), when frames.csv has them


@dataclass(frozen=True)
class SlamConfig:
    """Augmented-state EKF, visibility gate (5) and new-landmark test (6)."""

    initial_position_sigma_m: float = 0.0  # the trajectory starts at the origin, known
    pixel_sigma_px: float = 0.5  # landmark observation noise nu_m, nu_n
    heading_sigma_rad: float = 0.0  # compass noise propagated through d/dpsi
    landmark_process_sigma_m: float = 0.0  # eq. (2) process noise per step
    visibility_lambda: float = 9.21  # eq. (5): chi-square 2 dof, 99 %
    new_landmark_mu: float = 13.82  # eq. (6): chi-square 2 dof, 99.9 %
    new_landmark_spacing_m: float = 0.15  # L = (spacing^2 / mu) I: minimum distance between landmarks
    innovation_gate: float = 13.82  # chi-square 2 dof, 99.9 %
    augmentation: str = "full"  # "full" (correct cross-covariances) | "paper" (eq. 4 diagonal block)
    gate_covariance: str = "relative"  # (5), (6): "relative" (P_Xi + P_x - C - C^T) | "paper" (P_Xi + P_x)
    heading_bias_sigma_rad: float = 0.0087  # > 0: estimate the slow compass error in the state (0: paper)
    heading_bias_tau_s: float = 120.0  # its correlation time (Ornstein-Uhlenbeck)


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs besides the sequence."""

    bandpass: BandpassConfig = field(default_factory=BandpassConfig)
    speed_templates: SpeedTemplateConfig = field(default_factory=SpeedTemplateConfig)
    landmark_templates: LandmarkTemplateConfig = field(default_factory=LandmarkTemplateConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Convert a TOML value to the dataclass field type ``tp`` or raise ConfigError."""
    origin = typing.get_origin(tp)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{where}: expected a whole number, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(tp)
        inner = args[0] if args else float
        return tuple(_convert(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    return value


def from_dict(cls: type, data: dict[str, Any], source: str = "<dict>", prefix: str = "") -> Any:
    """Build dataclass ``cls`` from a (nested) dict, rejecting unknown keys."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: [{prefix or cls.__name__}] must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        where = f"{prefix}.{key}" if prefix else key
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(
                f"{source}: unknown key '{where}'. Known keys here: {known}. "
                "Fix the spelling or remove the key."
            )
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            kwargs[key] = from_dict(tp, value, source, where)
        else:
            kwargs[key] = _convert(value, tp, f"{source}: {where}")
    try:
        obj = cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: invalid [{prefix or cls.__name__}]: {exc}") from None
    return obj


def to_dict(obj: Any) -> dict[str, Any]:
    """Dataclass -> plain dict with lists instead of tuples (TOML/JSON friendly)."""

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        return v

    return plain(obj)


def load_config(path: str | Path) -> RunConfig:
    """Read a :class:`RunConfig` from a TOML file; missing keys keep the paper's defaults."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: configuration file not found. Give the path of a TOML file.")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return from_dict(RunConfig, data, str(p))


def save_config(config: RunConfig, path: str | Path) -> None:
    """Write ``config`` as TOML (every key, so the file documents the run)."""
    import tomli_w

    Path(path).write_text(tomli_w.dumps(to_dict(config)), encoding="utf-8")
