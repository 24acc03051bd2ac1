"""Configuration: one frozen dataclass per pipeline stage, defaults = the paper's figures.

A run is configured by :class:`RunConfig`, which groups the stage configurations. It is
read from and written to TOML with one table per stage::

    [speed_templates]
    size_px = 16
    max_count = 8

Every value is checked when the configuration is built (so when the file is loaded): its
type, its range (declared beside the field with :func:`_num`) and, for choices, the allowed
values (``Literal`` types). Unknown tables or keys are rejected. Each error is a
:class:`~rovslam.errors.ConfigError` naming the file, the key, the value and what is allowed.

Ownership: each stage's module reads only its own dataclass.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Literal

from rovslam.errors import ConfigError, parse_toml

Channel = Literal["grey", "green", "blue"]
Subpixel = Literal["parabolic", "gaussian", "none"]
Augmentation = Literal["full", "paper"]
GateCovariance = Literal["relative", "paper"]
Backend = Literal["ekf", "isam2"]
SpeedBiasWhen = Literal["sunlight", "always"]
Auto = Literal["auto"]


def _num(default: float | int, *, gt: float | None = None, ge: float | None = None, le: float | None = None):
    """A numeric field with its allowed range (checked at construction): ``gt`` / ``ge`` below, ``le`` above."""
    return field(default=default, metadata={"gt": gt, "ge": ge, "le": le})


class _Checked:
    """Mixin: check every field's type, range and choice after construction (frozen dataclasses)."""

    TABLE: ClassVar[str] = ""

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            _check_value(self.TABLE, f.name, getattr(self, f.name), hints[f.name], f.metadata)
        self._check_relations()

    def _check_relations(self) -> None:
        """Constraints between fields (overridden where there are some)."""

    def _fail(self, key: str, message: str) -> typing.NoReturn:
        raise ConfigError(f"[{self.TABLE}] {key} = {getattr(self, key)!r}: {message}")


def _check_value(table: str, key: str, value: Any, tp: Any, meta: typing.Mapping[str, Any]) -> None:
    where = f"[{table}] {key} = {value!r}"
    if typing.get_origin(tp) in (typing.Union, types.UnionType):  # e.g. float | "auto": the first that fits
        options = typing.get_args(tp)
        errors = []
        for option in options:
            try:
                _check_value(table, key, value, option, meta)
                return
            except ConfigError as exc:
                errors.append(exc)
        if isinstance(value, str):
            allowed = [repr(a) for o in options if typing.get_origin(o) is Literal for a in typing.get_args(o)]
            raise ConfigError(f"{where}: must be a number or one of {', '.join(allowed)}")
        raise errors[0]
    if typing.get_origin(tp) is Literal:
        allowed = typing.get_args(tp)  # type: ignore[assignment]
        if value not in allowed:
            raise ConfigError(f"{where}: must be one of {', '.join(repr(a) for a in allowed)}")
        return
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: must be true or false")
        return
    if tp in (int, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or (tp is int and not isinstance(value, int)):
            raise ConfigError(f"{where}: must be a {'whole number' if tp is int else 'number'}")
        if not math.isfinite(value):
            raise ConfigError(f"{where}: must be a finite number")
        gt, ge, le = meta.get("gt"), meta.get("ge"), meta.get("le")
        if (
            (gt is not None and not value > gt)
            or (ge is not None and not value >= ge)
            or (le is not None and not value <= le)
        ):
            parts = [
                f"> {gt:g}" if gt is not None else "",
                f">= {ge:g}" if ge is not None else "",
                f"<= {le:g}" if le is not None else "",
            ]
            raise ConfigError(f"{where}: out of range, must be {' and '.join(p for p in parts if p)}")
        if le is None:  # no setting needs a huge number: one is a typo (an exponent), and would overflow the maths
            if key.endswith("_rad") and abs(value) > math.pi:
                raise ConfigError(
                    f"{where}: out of range, an angle in radians must be within +-{math.pi:.4f} "
                    "(half a turn); give radians, not degrees"
                )
            if abs(value) > MAX_SETTING:
                raise ConfigError(
                    f"{where}: out of range, must be within +-{MAX_SETTING:g} (no setting needs "
                    "a larger number: check the exponent)"
                )


MAX_OPENING_PX = 255  # widest bright-structure opening (despeckle_px, sunlight_px)
MAX_SETTING = 1e6  # the largest magnitude of a number setting without a bound of its own
MAX_BLUR_SIGMA_PX = 100.0  # widest band-pass Gaussian (a 1e6 px sigma made a kernel that ran for minutes)


@dataclass(frozen=True)
class BandpassConfig(_Checked):
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

    TABLE: ClassVar[str] = "bandpass"
    # removes wavelengths shorter than ~2*pi*sigma_fine (noise)
    sigma_fine_px: float = _num(1.0, gt=0, le=MAX_BLUR_SIGMA_PX)
    # removes wavelengths longer than ~2*pi*sigma_coarse (illumination)
    sigma_coarse_px: float = _num(4.0, gt=0, le=MAX_BLUR_SIGMA_PX)
    channel: Channel = "green"  # red is reserved for the lasers
    # >= 2: remove bright specks (marine snow) narrower than this first; 0: off (paper). At most
    # MAX_OPENING_PX: a disc kernel's memory grows with its square (100001 px asked for 10 GB).
    despeckle_px: int = _num(7, ge=0, le=MAX_OPENING_PX)
    # While bright structures around the speed tokens do not move with them (sunlight caustics:
    # rovslam.sensor.sunlight), those narrower than this are removed (31 px: 6 cm at 500 px/m); 0 or
    # not above despeckle_px: never.
    sunlight_px: int = _num(31, ge=0, le=MAX_OPENING_PX)
    # A frame whose band-passed standard deviation is below this (a dark or low-contrast camera) is
    # scaled up to it before the local-variance thresholds, as a camera's gain would; 0: off (paper).
    # Correlation does not see the gain; the matrix presets' frames all lie above 2.0.
    min_contrast_std: float = _num(1.7, ge=0)

    def _check_relations(self) -> None:
        if self.sigma_coarse_px <= self.sigma_fine_px:
            self._fail("sigma_coarse_px", f"must be larger than sigma_fine_px = {self.sigma_fine_px!r}")
        if self.despeckle_px == 1:
            self._fail("despeckle_px", "must be 0 (off) or >= 2 px")
        if self.sunlight_px == 1:
            self._fail("sunlight_px", "must be 0 (off) or >= 2 px")


@dataclass(frozen=True)
class ProcessingConfig(_Checked):
    """The resolution the vision runs at: any camera is brought near the paper's pixels (:mod:`rovslam.vision.scale`).

    Every pixel figure of the other tables (band-pass sigmas, template sizes, search radii,
    inhibition radii, thresholds in pixels) is in *processing* pixels. The frame is reduced
    by ``scale`` (area average) before the template channel is filtered; the laser spots are
    found in the full frame with their pixel figures divided by ``scale``; every pixel the
    results report (laser spots, tokens, landmark observations) is converted back to the
    full-resolution image, with the intrinsics scaled to match (distortion is in normalised
    coordinates: unchanged).

    * ``scale = "auto"`` (default): the largest reduction that keeps the image's long side at
      most ``max_side_px`` and its ground resolution at the expected altitude (``[vehicle]
      altitude_m``, else ``[laser] assumed_altitude_m``) at least ``min_px_per_m``; never
      enlarged. The paper's 360x272 camera and the Sparus 384x288 are processed as they are;
      1920x1080 at 0.25 (480x270).
    * ``scale = 0.5`` (a number in (0, 1]): that reduction whatever the camera.
    """

    TABLE: ClassVar[str] = "processing"
    scale: float | Auto = "auto"  # "auto" (see above) or a fixed reduction in (0, 1] (1: full resolution)
    max_side_px: int = _num(480, ge=64)  # auto: the long side of the processed image at most this
    min_px_per_m: float = _num(500.0, ge=0)  # auto: ground pixels per metre kept at least (0: no limit)

    def _check_relations(self) -> None:
        if not isinstance(self.scale, str) and not 0.0 < self.scale <= 1.0:
            self._fail("scale", 'must be "auto" or a number in (0, 1] (a reduction; 1 = full resolution)')


@dataclass(frozen=True)
class SpeedTemplateConfig(_Checked):
    """Small templates ("tokens") tracked between consecutive frames for the speed."""

    TABLE: ClassVar[str] = "speed_templates"
    size_px: int = _num(16, ge=4)  # paper: 16x16
    max_count: int = _num(8, ge=1)  # paper: at most 8 per frame
    min_local_variance: float = _num(4.0, ge=0)  # lower than the landmarks' (std 2 grey levels, ~7x noise)
    search_radius_px: int = _num(8, ge=1)  # around the position predicted from the last speed
    border_px: int = _num(4, ge=0)  # extra margin from the image border
    min_spacing_px: int = _num(40, ge=0)  # least distance between two tokens (u or v); 16 = just non-overlapping
    max_self_similarity: float = _num(0.9, gt=0, le=1)  # a token that looks like its neighbours is not chosen (1: off)


@dataclass(frozen=True)
class LandmarkTemplateConfig(_Checked):
    """Large templates used as SLAM landmarks."""

    TABLE: ClassVar[str] = "landmark_templates"
    size_px: int = _num(32, ge=4)  # paper: 32x32
    min_local_variance: float = _num(12.3, ge=0)  # paper: 12.3
    search_margin_px: int = _num(6, ge=0)  # search window beyond the 3-sigma predicted uncertainty
    max_search_radius_px: int = _num(60, ge=1)  # the search window around the prediction never wider than this
    border_px: int = _num(8, ge=0)  # a new landmark template keeps this far from the image border
    inhibit_margin_px: int = _num(4, ge=0)  # speed templates keep this far from landmark templates


@dataclass(frozen=True)
class AssociationConfig(_Checked):
    """Which landmark matches the filter believes (beyond the paper, which takes every match in its gate).

    * Unambiguous landmarks: a candidate template whose autocorrelation within
      ``similarity_radius_px`` has another peak above ``max_self_similarity`` is never made
      a landmark; among the ``candidates`` strongest, the most distinctive is taken.
    * Tentative landmarks: a new landmark corrects only itself (its position and height)
      until it has been seen consistently ``confirm_observations`` times.
    * Joint compatibility: the landmarks matched in one frame are tested together (their
      innovations share the vehicle's error); the one that does not fit is refused.
    * Recovery: correct-looking matches (correlation >= ``strong_correlation``) refused by the
      innovation test ``recovery_after_frames`` frames in a row, telling the same vehicle
      offset, mean the filter is wrong, not the matches: the vehicle covariance is inflated
      by that offset and they are admitted. Expected landmarks not found for
      ``wide_search_after_frames`` frames are searched for within ``wide_search_radius_px``.
    """

    TABLE: ClassVar[str] = "association"
    max_self_similarity: float = _num(0.8, gt=0, le=1)  # 1: no test (the paper)
    similarity_radius_px: int = _num(24, ge=1)  # radius of the candidate's autocorrelation searched for a second peak
    candidates: int = _num(5, ge=1)  # strongest candidate templates among which the most distinctive is chosen
    confirm_observations: int = _num(3, ge=0)  # 0: a landmark corrects the vehicle from its first re-observation
    joint_compatibility: bool = True  # test a frame's landmark matches together (false: each on its own, the paper)
    joint_quantile: float = _num(0.999, gt=0, le=1)  # chi-square quantile of the joint test (2K dof)
    recovery: bool = True  # admit strong matches refused frame after frame, inflating the vehicle covariance
    strong_correlation: float = _num(0.95, gt=0, le=1)  # a refused match this well correlated counts as evidence
    recovery_after_frames: int = _num(3, ge=1)  # frames in a row of such refusals before the recovery
    recovery_min_landmarks: int = _num(2, ge=1)  # different landmarks that must speak against the estimate
    recovery_memory_s: float = _num(10.0, ge=0)  # how long a refused match's told offset counts as evidence
    recovery_offset_agreement_m: float = _num(0.01, gt=0)  # the refused matches' vehicle offsets agree within this
    # a confirmed landmark expected but not found this many frames: wide search
    wide_search_after_frames: int = _num(5, ge=1)
    wide_search_radius_px: int = _num(150, ge=1)  # radius of that wide search


@dataclass(frozen=True)
class TrackerConfig(_Checked):
    """Normalised-correlation matching (OpenCV TM_CCOEFF_NORMED)."""

    TABLE: ClassVar[str] = "tracker"
    min_correlation: float = _num(0.89, gt=0, le=1)  # paper: 0.89
    max_second_peak_ratio: float = _num(0.98, gt=0)  # reject if the 2nd peak >= ratio * 1st (ambiguous)
    second_peak_exclusion_px: int = _num(3, ge=0)  # the 2nd peak is sought outside this radius of the 1st
    subpixel: Subpixel = "parabolic"  # 2-D fit on the 3x3 peak ("gaussian": of its logarithm)
    global_search: bool = True  # phase correlation prior when tracks are lost
    global_search_radius_px: int = _num(12, ge=1)  # search radius around the phase-correlation prior
    min_global_confidence: float = _num(0.08, ge=0)  # phase-correlation peak response below this: no prior
    min_tracked_fraction: float = _num(0.5, ge=0, le=1)  # fewer tracked with the prediction -> global search


@dataclass(frozen=True)
class LaserConfig(_Checked):
    """Laser spot detection in the red channel, triangulation, and the altitude fallbacks."""

    TABLE: ClassVar[str] = "laser"
    min_red_excess: float = _num(60.0, ge=0, le=255)  # red - max(green, blue), 8-bit units
    min_spot_area_px: int = _num(3, ge=1)  # a red blob smaller than this is noise, not a laser spot
    max_spot_area_px: int = _num(400, ge=1)  # a red blob larger than this is a red object, not a laser spot
    search_radius_px: float = _num(40.0, gt=0)  # around the spot predicted from the last altitude
    inhibit_radius_px: int = _num(14, ge=0)  # templates keep this far from a spot centre
    max_relative_disagreement: float = _num(0.05, gt=0)  # a spot whose altitude differs more is an outlier
    spot_sigma_px: float = _num(0.3, gt=0)  # centroid noise used for the altitude variance
    # a spot's centre weighs its red beyond the threshold this far (plus its radius) around the blob:
    # a codec's lopsided smear moved the thresholded centroid (0: the thresholded pixels only, before);
    # at most 100 px: a fade wider than that is not a spot's, and the disc it dilates by must fit in memory
    spot_skirt_px: float = _num(3.0, ge=0, le=100.0)
    # a spot missed by min_red_excess is searched this close to its prediction, its blob at 30 % of its peak,
    # when the peak reaches faint_red_excess (0: no faint spots, as before)
    faint_red_excess: float = _num(20.0, ge=0, le=255)
    faint_search_radius_px: float = _num(8.0, gt=0)  # a faint spot is looked for this close to its predicted pixel
    sonar_sigma_m: float = _num(0.05, gt=0)  # one-sigma error of a sonar (altimeter) reading
    fixed_altitude_sigma_m: float = _num(0.10, gt=0)  # one-sigma error of an assumed altitude (no laser, no sonar)
    min_altitude_m: float = _num(0.05, gt=0)  # altitudes (laser or sonar) outside this range are rejected
    max_altitude_m: float = _num(30.0, gt=0)  # altitudes (laser or sonar) above this are rejected
    assumed_altitude_m: float = _num(1.31, gt=0)  # no laser, no sonar, no [vehicle] altitude_m: the paper's 1.31 m
    # vertical acceleration of the altitude filter (rovslam.sensor.altitude)
    altitude_accel_sigma_mps2: float = _num(0.05, gt=0)
    # the relief off the laser spots' plane (four or more spots: their residuals from the plane fit) is averaged
    # over this time, seconds (rovslam.pipeline.depth)
    relief_tau_s: float = _num(2.0, gt=0)
    # that relief's sigma times this widens each altitude reading's sigma in quadrature before the altitude filter:
    # the filter then averages the relief under the spots (3: 10 % less ATE over the relief presets, 23 % on the
    # real-photo survey, docs/consistency.md; 0: the spots' centroid noise alone, as before)
    relief_altitude_gain: float = _num(3.0, ge=0)
    # true: each landmark's image depth is the spots' plane at its pixel (its slope averaged over plane_slope_tau_s,
    # at most max_plane_slope_rad), not the one depth below the camera
    plane_depth: bool = False
    plane_slope_tau_s: float = _num(1.0, gt=0)  # averaging time of the spots' plane's slope, seconds
    max_plane_slope_rad: float = _num(0.3, ge=0)  # a steeper averaged slope is clipped to this

    def _check_relations(self) -> None:
        if self.max_spot_area_px < self.min_spot_area_px:
            self._fail("max_spot_area_px", f"must be >= min_spot_area_px = {self.min_spot_area_px}")
        if self.max_altitude_m <= self.min_altitude_m:
            self._fail("max_altitude_m", f"must be larger than min_altitude_m = {self.min_altitude_m!r}")


@dataclass(frozen=True)
class OdometryConfig(_Checked):
    """Motion-from-tokens speed estimator and the heading inputs."""

    TABLE: ClassVar[str] = "odometry"
    outlier_threshold_px: float = _num(1.0, gt=0)  # residual beyond which a token is an outlier
    min_inliers: int = _num(2, ge=1)  # fewer tokens agreeing than this: no speed measured this frame
    min_speed_sigma_mps: float = _num(0.0005, gt=0)  # floor of the speed standard deviation
    token_sigma_px: float = _num(0.15, gt=0)  # one token's displacement noise (floor)
    # the dive's recent token scatter counts as this many degrees of freedom in each step's noise (0: each step
    # alone)
    token_noise_prior_dof: float = _num(4.0, ge=0)
    # true: the zoom between the two frames from the tokens (a similarity fit), the measured altitudes'
    # ratio its prior (the lasers' step-to-step noise over relief zooms one frame against the next); false:
    # the rigid fit. With relief_turn_gain below (docs/consistency.md, "The zoom between frames")
    token_scale: bool = True
    # the turn fit discounts each token's displacement along the motion, where the relief's parallax moves it
    # (the seabed nearer on one side of the image reads as a turn): that axis weighs
    # 1 / (1 + (gain sigma_s |d| / sigma_token)^2), sigma_s the relief's spread the frames measured under the
    # tokens (0: both axes alike; docs/consistency.md, "The relief's parallax in the turn fit")
    relief_turn_gain: float = _num(2.5, ge=0)
    common_sigma_px: float = _num(0.15, ge=0)  # an error all tokens of a step share (compression, lighting): not / n
    gap_speed_sigma_mps: float = _num(0.02, ge=0)  # landmark search: the speed may change by this per second
    # a held speed's error grows by at least this per second (a manoeuvre), by more when the dive's
    # speeds have shown harder accelerations (swell: SpeedEstimator.accel_sigma_mps2)
    held_speed_drift_mps2: float = _num(0.1, ge=0)
    initial_speed_sigma_mps: float = _num(0.2, gt=0)  # speed sigma held before the first good measurement
    # > 0: a speed changing faster than this (+3 sigma) is a wrong consensus (0: off)
    max_accel_mps2: float = _num(0.0, ge=0)
    max_speed_mps: float = _num(3.0, gt=0)  # a measured speed above this is not a vehicle's: refused
    survey_speed_mps: float = _num(0.15, gt=0)  # speed bound for the landmark search before any speed is measured
    # relief parallax scale error: x its one-step estimate (step correlation)
    relief_scale_gain: float = _num(2.0, ge=0)
    # relief height spread / altitude assumed before the tokens measured it
    relief_prior_sigma: float = _num(0.02, ge=0)
    # ... its share fades as exp(-seconds measured / this) (0: no prior, start as flat)
    relief_prior_s: float = _num(2.0, ge=0)
    compass_sigma_rad: float = _num(0.0087, ge=0)  # compass white noise (0.5 deg); 0 uses the compass as it is (paper)
    # how fast the vehicle may turn (14 deg/s): without a compass, a step whose turn the tokens missed adds this
    # times the step to the heading's error; with one, it bounds a plausible reading (compass_gate_sigmas)
    unmeasured_turn_rate_sigma_radps: float = _num(0.25, gt=0)
    # a compass reading farther than this many sigmas from the heading the tokens' turn predicts is a glitch,
    # refused (0: off); after compass_gate_max_readings refused in a row the compass is believed again
    compass_gate_sigmas: float = _num(6.0, ge=0)
    compass_gate_max_readings: int = _num(10, ge=0)  # see compass_gate_sigmas above
    compass_sigma_learned: bool = True  # the compass noise its readings show is used when above compass_sigma_rad
    # slow compass error no smoothing removes (magnetic disturbance, 1 deg)
    compass_drift_sigma_rad: float = _num(0.0175, ge=0)
    # the tokens' turn errors are correlated from step to step over relief: the variance of their sum over
    # turn_noise_window_steps steps, checked against the compass, scales each step's (never below 1; false: as measured)
    turn_noise_learned: bool = True
    turn_noise_window_steps: int = _num(25, ge=2)  # see turn_noise_learned above
    # the compass's constant error (deviation, 0.5 deg calibrated): turns the whole estimate
    compass_offset_sigma_rad: float = _num(0.0087, ge=0)
    attitude_sigma_rad: float = _num(0.0035, ge=0)  # AHRS roll / pitch accuracy (0.2 deg), when frames.csv has them
    # AHRS reading-to-reading noise (0.01 deg): moves each frame's seabed
    attitude_noise_sigma_rad: float = _num(0.0002, ge=0)
    # fewer tokens agreeing than this (or no speed): the motion between the two frames is measured from point
    # features too; where it moved most tokens beyond the windows they were searched in (a large motion: a
    # third of the image, a turn, a zoom), it seeds the token search, gates the tokens, and is the speed where
    # they still fail (rovslam.pipeline.assist); within reach, the weak tokens stay as they are. 0: never
    feature_assist_inliers: int = _num(3, ge=0)
    feature_gate_sigmas: float = _num(3.0, gt=0)  # a token farther than this from the feature motion is refused


@dataclass(frozen=True)
class SlamConfig(_Checked):
    """Augmented-state EKF, visibility gate (5) and new-landmark test (6)."""

    TABLE: ClassVar[str] = "slam"
    initial_position_sigma_m: float = _num(0.0, ge=0)  # the trajectory starts at the origin, known
    pixel_sigma_px: float = _num(0.5, gt=0)  # landmark observation noise nu_m, nu_n
    heading_sigma_rad: float = _num(0.0, ge=0)  # compass noise propagated through d/dpsi
    landmark_process_sigma_m: float = _num(0.0, ge=0)  # (2) process noise per step
    visibility_lambda: float = _num(9.21, gt=0)  # (5): chi-square 2 dof, 99 %
    new_landmark_mu: float = _num(13.82, gt=0)  # (6): chi-square 2 dof, 99.9 %
    new_landmark_spacing_m: float = _num(0.15, ge=0)  # L = (spacing^2 / mu) I: minimum distance between landmarks
    innovation_gate: float = _num(13.82, gt=0)  # chi-square 2 dof, 99.9 %
    augmentation: Augmentation = "full"  # "full" (correct cross-covariances) | "paper" ((4) diagonal block)
    gate_covariance: GateCovariance = "relative"  # (5), (6): "relative" (P_Xi + P_x - C - C^T) | "paper" (P_Xi + P_x)
    # > 0: estimate the slow compass error in the state (1 deg; 0: paper)
    heading_bias_sigma_rad: float = _num(0.0175, ge=0)
    heading_bias_tau_s: float = _num(120.0, gt=0)  # its correlation time (Ornstein-Uhlenbeck)
    backend: Backend = "ekf"  # the online estimate: "ekf" (the paper's) or "isam2" (GTSAM, [smoother])
    # > 0: each landmark's height in the state, this prior (0: flat seabed, the paper)
    landmark_height_sigma_m: float = _num(0.03, ge=0)
    # > 0: a landmark's height off the laser spots' plane as a consider parameter: this times the relief off that plane
    # ([laser] relief_tau_s) widens the landmark observation's altitude sigma in (3), (4) in quadrature (0: off; 3: 1
    # to 3 % less ATE over the relief presets, docs/consistency.md)
    landmark_relief_gain: float = _num(3.0, ge=0)
    # > 0: the measured altitude's offset from the seabed datum in the state
    altitude_bias_sigma_m: float = _num(0.01, ge=0)
    # its correlation time (the altimeter's lasting offset: its calibration, a codec's spot)
    altitude_bias_tau_s: float = _num(30.0, gt=0)
    # the laser rig's lasting share of the altitude (its baseline's calibration: 0.76 %, 1 cm at 1.31 m); with
    # altitude_bias_sigma_m > 0, b's sigma at depth Z is hypot(altitude_bias_sigma_m, altitude_scale_sigma Z) (0: an offset alone)
    altitude_scale_sigma: float = _num(0.0076, ge=0, le=0.1)
    # true: the relief under the tokens adds to b (sigma from the tokens' parallax, [odometry] relief_scale_gain), with
    # this correlation time. Off by default: through b it also widens the landmarks' depths, and on one HD dive a
    # revisit then pulled the estimate 8 mm off (docs/method.md); false: b is the altimeter's offset, widened only by the
    # relief under the laser spots
    altitude_bias_relief: bool = False
    altitude_bias_relief_tau_s: float = _num(5.0, gt=0)  # correlation time of that relief term
    # b a consider state (Schmidt): its uncertainty carried, never learned (False: learned)
    altitude_bias_consider: bool = True
    # > 0 (with landmark_height_sigma_m > 0): the seabed level under the laser spots, relative to the start's, in the
    # state and learned from the landmarks (s): the altitude Z ranges to the relief under the spots, so a landmark's
    # depth is Z + b + s - h with h its height above the start's seabed; s's stationary sigma over each step is the
    # relief from the tokens' parallax, capped at this (0: off, h is above the seabed under the spots at each frame;
    # b then also carries that relief)
    seabed_offset_sigma_m: float = _num(0.02, ge=0)
    seabed_offset_tau_s: float = _num(5.0, gt=0)  # its correlation time (the relief passing under the spots)
    # > 0: the odometry's slow world-frame speed error w in the state, while sunlight drags the tokens (0: none)
    speed_bias_sigma_mps: float = _num(0.002, ge=0)
    speed_bias_tau_s: float = _num(60.0, gt=0)  # its correlation time (Ornstein-Uhlenbeck)
    # "sunlight": while it is taken out | "always" (slow caustics the watch misses)
    speed_bias_when: SpeedBiasWhen = "sunlight"


RobustLoss = Literal["huber", "cauchy", "none"]
ROBUST_LOSSES = typing.get_args(RobustLoss)


@dataclass(frozen=True)
class SmootherConfig(_Checked):
    """The smoothing back end (GTSAM iSAM2, :mod:`rovslam.slam.smoother`): noise model and solver.

    Attributes:
        robust: loss on the landmark factors: "huber", "cauchy" or "none" (least squares).
        robust_k: its threshold, in whitened sigmas of the observation noise.
        use_rejected: also use the observations the online filter rejected (under the
            robust loss); False drops them.
        relinearize_threshold: iSAM2 relinearises a variable whose update exceeds this
            (metres, radians).
        relinearize_skip: iSAM2 checks for relinearisation every this many updates.
        wildfire_threshold: iSAM2 stops propagating an update down the tree where the
            change falls below this (metres, radians): the older poses' online estimates may
            lag by that much until the final smoothing.
        partial_relinearization_check: check for relinearisation only the part of the tree
            an update touched (instead of every variable at every check).
        initial_position_sigma_m: prior on the first position (0: known, taken as 1e-6 m).
        initial_heading_sigma_rad: prior on the first heading without a compass (0: the map
            frame is the first heading, taken as 1e-6 rad).
        loose_turn_sigma_rad: sigma of a step's turn when the tokens did not measure it.
        heading_bias_sigma_rad: stationary sigma of the slow compass error (0: no drift model;
            the default is the EKF's ``[slam] heading_bias_sigma_rad``).
        heading_bias_tau_s: its correlation time (Ornstein-Uhlenbeck, as the EKF's).
        bias_block_s: duration over which the drift is held constant (one variable per block).
        final_max_iterations: Levenberg-Marquardt iterations of the final smoothing
            (0: the iSAM2 estimate as it is).
        relief_rounds: rounds of the relief step in the final smoothing (0: the paper's flat
            seabed, every landmark at the laser altitude's depth): each round solves the landmarks'
            heights and the seabed under the spots given the poses (:mod:`rovslam.slam.heights`),
            then smooths again with those depths; the rounds stop early once no depth moves by
            more than 0.01 mm.
        relief_min_gain: the relief rounds' result is kept when it takes at least this share of
            the landmark factors' misfit (squared whitened residuals, over the observations it
            explains) away, else the flat seabed's is: with their priors the heights and the seabed
            offset also fit the pixel noise of a flat seabed (18 to 23 % of the misfit on the
            synthetic surveys of tests/test_smoother.py, whose path they then make 14 % worse),
            while relief gives 46 to 92 % (46 to 84 % on the simulated dives).
        landmark_height_sigma_m: a landmark's height off the seabed under the camera at its first
            frame (the relief rounds' prior; the EKF's ``[slam]`` figure and default).
        seabed_offset_sigma_m: the stationary sigma of the seabed under the spots relative to the
            start's (the relief rounds' prior; the EKF's ``[slam]`` figure and default).
        seabed_offset_tau_s: its correlation time (the EKF's ``[slam]`` figure and default).
    """

    TABLE: ClassVar[str] = "smoother"
    robust: RobustLoss = "huber"
    robust_k: float = _num(3.0, gt=0)
    use_rejected: bool = True
    relinearize_threshold: float = _num(0.01, gt=0)
    relinearize_skip: int = _num(10, ge=1)
    wildfire_threshold: float = _num(0.001, gt=0)
    partial_relinearization_check: bool = False
    initial_position_sigma_m: float = _num(0.0, ge=0)
    initial_heading_sigma_rad: float = _num(0.0, ge=0)
    loose_turn_sigma_rad: float = _num(0.2, gt=0)
    heading_bias_sigma_rad: float = _num(0.0175, ge=0)  # the EKF's compass model ([slam]): 1 deg
    heading_bias_tau_s: float = _num(120.0, gt=0)
    bias_block_s: float = _num(5.0, gt=0)
    final_max_iterations: int = _num(10, ge=0)
    relief_rounds: int = _num(8, ge=0)
    relief_min_gain: float = _num(0.3, ge=0, le=1)
    landmark_height_sigma_m: float = _num(0.03, gt=0)  # the EKF's [slam] defaults
    seabed_offset_sigma_m: float = _num(0.02, gt=0)
    seabed_offset_tau_s: float = _num(5.0, gt=0)


@dataclass(frozen=True)
class RunLimitsConfig(_Checked):
    """When a run is refused as a whole (exit 2) rather than written as if it had worked."""

    TABLE: ClassVar[str] = "run"
    min_usable_fraction: float = _num(0.5, ge=0, le=1)  # fewer usable frames than this fraction: the run failed
    max_distance_m: float = _num(1000.0, gt=0)  # an estimate farther than this from the start has diverged


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs besides the sequence."""

    bandpass: BandpassConfig = field(default_factory=BandpassConfig)
    processing: ProcessingConfig = field(default_factory=ProcessingConfig)
    speed_templates: SpeedTemplateConfig = field(default_factory=SpeedTemplateConfig)
    landmark_templates: LandmarkTemplateConfig = field(default_factory=LandmarkTemplateConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    association: AssociationConfig = field(default_factory=AssociationConfig)
    laser: LaserConfig = field(default_factory=LaserConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    slam: SlamConfig = field(default_factory=SlamConfig)
    smoother: SmootherConfig = field(default_factory=SmootherConfig)
    run: RunLimitsConfig = field(default_factory=RunLimitsConfig)


def _convert(value: Any, tp: Any, where: str) -> Any:
    """Convert a TOML value to the dataclass field type ``tp`` or raise ConfigError."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        return value  # checked against the allowed values by the dataclass
    if origin in (typing.Union, types.UnionType):  # a number or a word ("auto"): numbers become floats
        if float in typing.get_args(tp) and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value  # checked by the dataclass
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
                f"{source}: unknown key '{where}'. Known keys here: {known}. Fix the spelling or remove the key."
            )
        tp = hints[key]
        if dataclasses.is_dataclass(tp):
            kwargs[key] = from_dict(tp, value, source, where)  # type: ignore[arg-type]
        else:
            kwargs[key] = _convert(value, tp, f"{source}: {where}")
    try:
        obj = cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
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
        what = "is not a regular file (a folder, a device or a pipe)" if p.exists() else "configuration file not found"
        raise ConfigError(f"{p}: {what}. Give the path of a TOML file.")
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot be read ({exc.strerror or exc}).") from None
    try:
        text = raw.decode("utf-8-sig")  # a UTF-8 byte-order mark is accepted
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(f"{p}: line {line}: not UTF-8 text (byte {exc.start}); save the file as UTF-8.") from None
    try:
        data = parse_toml(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return from_dict(RunConfig, data, str(p))


def save_config(config: RunConfig, path: str | Path) -> None:
    """Write ``config`` as TOML (every key, so the file documents the run)."""
    import os
    import tempfile

    import tomli_w

    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:  # written whole, then renamed: never half a file
            fh.write(tomli_w.dumps(to_dict(config)))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
