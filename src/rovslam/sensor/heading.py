"""The heading inputs of the loop: the compass, smoothed with the turn the speed tokens measure.

The paper flew at constant heading and used the compass as it is. A compass reading has white
noise (0.2 to 0.5 degree), so its frame-to-frame difference is mostly noise at 5 Hz and above,
and every degree of heading error turns each token 150 px from the image centre by 2.6 px.
Two objects hold all heading state of a run:

* :class:`HeadingFilter`, a one-state Kalman filter: predict ``psi += dpsi`` with the rotation
  the tokens measured, update with the compass reading. It learns the compass's white noise, and
  how much faster the tokens' summed turn errs than their per-step sigmas say (over relief they
  are correlated from step to step), from the compass itself. Without a compass (a bare video)
  the heading is the integrated token rotation from 0 at the first frame.
* :class:`HeadingTracker`, what the per-frame loop talks to: :meth:`HeadingTracker.prior`
  before the tokens are tracked (the previous heading and the compass step, which predict where
  the tokens went), :meth:`HeadingTracker.update` once the speed estimator has measured the turn,
  :meth:`HeadingTracker.skip` for an unusable frame.

The slow compass error (magnetic disturbance, drift) is not removed here: it is a state of the
filter (``[slam] heading_bias_sigma_rad``, :class:`rovslam.slam.EkfSlam`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from rovslam.averages import DecayingMean
from rovslam.camera import wrap_angle
from rovslam.config import OdometryConfig, SlamConfig
from rovslam.errors import finite_scalar

__all__ = ["HeadingEstimate", "HeadingFilter", "HeadingPrior", "HeadingTracker"]

# Prior standard deviation of one step's heading change when no compass is given.
NO_COMPASS_STEP_SIGMA_RAD = 0.2
# The compass's white noise is learned from the heading filter's innovations, averaged over about
# this many readings (20 s at 5 Hz: the estimate's own scatter is then about 15 % of the variance),
# and used once this many readings were averaged.
COMPASS_NOISE_READINGS = 100
COMPASS_NOISE_MIN_READINGS = 20
# The run's warnings say so when the compass is this many times noisier than configured.
COMPASS_NOISIER_WARNING = 1.5
# The tokens' turn noise scale is learned over about this many steps (5 minutes at 5 Hz; a window ends
# at each), and used once this many windows were averaged (:meth:`HeadingFilter.turn_noise_scale`).
TURN_NOISE_WINDOWS = 1500
TURN_NOISE_MIN_WINDOWS = 50


class HeadingFilter:
    """Heading from the compass, smoothed with the tokens' measured heading changes (beyond the paper).

    Predict ``psi += dpsi`` (the fused rotation of :func:`rovslam.sensor.odometry.speed_from_tokens`,
    variance ``dpsi_sigma^2``), update with the compass reading (variance ``compass_sigma^2``).
    Without token rotations it follows the compass.

    The compass's white noise is also learned from the innovations ``y`` of the steps the tokens
    measured (``E[y^2] = P_pred + r``, averaged over about :data:`COMPASS_NOISE_READINGS`
    readings); with ``learn_noise`` the update uses it when it is larger than ``compass_sigma_rad``
    (a compass noisier than its datasheet; never smaller than configured).

    The tokens' turns are checked against the compass too, over windows of ``turn_window_steps``
    steps (:meth:`turn_noise_scale`): each step's ``dpsi_sigma`` comes from that step's tokens
    alone, but over relief the same seabed stays under the tokens for several frames and their
    turn errors are correlated (the real-photo seabed: 0.3 to 0.4 from one step to the next, up to
    5 steps apart), so the integrated turn drifts faster than the sigmas say, and a heading
    smoothed with them is surer than it is right. With ``learn_turn_noise`` the predicted variance
    of a step is ``dpsi_sigma^2`` times the scale the windows show (never less than 1).
    """

    def __init__(
        self,
        compass_sigma_rad: float,
        learn_noise: bool = False,
        gate_sigmas: float = 0.0,
        gate_max_readings: int = 0,
        learn_turn_noise: bool = False,
        turn_window_steps: int = 25,
    ):
        self.compass_sigma_rad = float(compass_sigma_rad)
        self.learn_turn_noise = bool(learn_turn_noise)
        self.turn_window_steps = int(turn_window_steps)
        # (compass reading before the step, dpsi, dpsi_sigma^2) of the last measured steps
        self._window: deque[tuple[float, float, float]] = deque(maxlen=self.turn_window_steps)
        self._last_compass_rad: float | None = None  # the last reading the filter took
        self._turn_sq = DecayingMean()  # over the windows: (compass change - summed turns)^2
        self._turn_claimed = DecayingMean()  # ... and the summed turn variances
        self._step_sq = DecayingMean()  # the same over one step: (compass step - turn)^2
        self._step_claimed = DecayingMean()  # ... and the turn's variance
        self.learn_noise = bool(learn_noise)
        self.gate_sigmas = float(gate_sigmas)
        self.gate_max_readings = int(gate_max_readings)
        self.heading_rad: float | None = None
        self.var_rad2 = 0.0
        self.refused_readings = 0  # compass readings refused as glitches (:meth:`_glitch`)
        self.refused_last = False  # whether the last update refused its reading
        self._refused_in_row = 0
        self._resync = False  # the gate's limit was reached: the next update takes the compass as it is
        self._noise = DecayingMean()  # the compass variance the innovations show, over ~COMPASS_NOISE_READINGS

    @property
    def sigma_rad(self) -> float:
        return math.sqrt(self.var_rad2)

    @property
    def learned_compass_sigma_rad(self) -> float | None:
        """The compass's white noise its readings show (None before :data:`COMPASS_NOISE_MIN_READINGS`)."""
        if self._noise.count < COMPASS_NOISE_MIN_READINGS:
            return None
        return math.sqrt(max(self._noise.mean(), 0.0))

    def _white_compass_var_rad2(self) -> float:
        """``r`` from single steps: ``E[(compass step - turn)^2] = dpsi_sigma^2 + 2 r``.

        A turn's error is small beside a compass's, so this holds whatever the turns' correlation;
        the innovations' ``E[y^2] = P_pred + r`` (:attr:`learned_compass_sigma_rad`) does not:
        ``P_pred`` holds the turn noise scale, and ``r`` learned so falls as the scale rises (0.42
        -> 0.32 degree against the simulator's 0.40 on the real-photo survey with turns, where this
        gives 0.39). The filter's update keeps the innovations' value: it is used only above the
        configured noise, where it errs large, on the safe side.
        """
        return max(0.5 * (self._step_sq.mean() - self._step_claimed.mean()), 0.0)

    @property
    def compass_var_rad2(self) -> float:
        """The compass variance the update uses: the configured one, or the learned one when larger."""
        r = self.compass_sigma_rad**2
        learned = self.learned_compass_sigma_rad if self.learn_noise else None
        return r if learned is None else max(r, learned**2)

    def _learn_noise(self, innovation_rad: float, predicted_var_rad2: float, compass_var_rad2: float) -> None:
        """One innovation of a measured step: ``E[y^2] = P_pred + r``, so ``y^2 - P_pred`` estimates ``r``.

        ``y^2`` is capped at 9 times its expected value (a 3-sigma reading), so that one glitch of
        the compass does not count as noise for the next hundred readings.
        """
        y2 = min(innovation_rad**2, 9.0 * (predicted_var_rad2 + compass_var_rad2))
        a = 1.0 / COMPASS_NOISE_READINGS
        self._noise.add(y2 - predicted_var_rad2, a, 1.0 - a)

    @property
    def turn_noise_scale(self) -> float:
        """How much faster the tokens' summed turn error grows than their per-step variances say (>= 1).

        Over a window of W measured steps the compass change less the summed turns is the
        summed turn error plus two compass readings' noise: ``E[e^2] = s sum(dpsi_sigma^2) + 2 r``
        (the compass's drift over the window is left in: it errs towards a larger ``s``), with
        ``r`` from single steps (:meth:`_white_compass_var_rad2`; from the filter's innovations
        ``r`` would fall as ``s`` rose, and ``s`` went to 11).

        Where the compass is much noisier than the summed turns, ``E[e^2] - 2 r`` is a small
        difference of two large averages: on a 1 degree compass over 60 s the scale swung between
        1 and 11, and the truth left the ellipse (87 % inside 2-sigma, 93 % before). So the excess
        ``d = E[e^2] - 2 r - sum(dpsi_sigma^2)`` is shrunk by ``d^2 / (d^2 + se^2)``, ``se`` its
        standard error (``E[e^2]`` counted as ``n / W`` independent windows of a chi-square, sd
        ``E[e^2] sqrt(2 W / n)``, and ``2 r`` as ``n`` single steps): a noisy compass or a short
        dive leaves the sigmas nearly as measured, a clear excess is taken almost whole. 1 until
        :data:`TURN_NOISE_MIN_WINDOWS` windows were averaged, or without ``learn_turn_noise``.
        """
        if not self.learn_turn_noise or self._turn_sq.count < TURN_NOISE_MIN_WINDOWS:
            return 1.0
        claimed = self._turn_claimed.mean()
        if not claimed > 0:
            return 1.0
        sq, two_r = self._turn_sq.mean(), 2.0 * self._white_compass_var_rad2()
        windows = min(self._turn_sq.count, TURN_NOISE_WINDOWS) / self.turn_window_steps
        steps = min(self._step_sq.count, TURN_NOISE_WINDOWS)
        se = math.hypot(sq * math.sqrt(2.0 / windows), two_r * math.sqrt(2.0 / steps))
        excess = sq - two_r - claimed
        if excess <= 0.0:
            return 1.0
        return 1.0 + excess * excess / (excess * excess + se * se) * excess / claimed

    def _learn_turn_noise(
        self, previous_compass_rad: float | None, compass_rad: float, dpsi_rad: float, dpsi_var_rad2: float
    ) -> None:
        """One measured step whose reading was taken (``previous_compass_rad``: the step's first reading,
        None when it was not taken): one single-step sample; slide the window, add its sample when full."""
        if previous_compass_rad is None:
            self._forget_window()
            return
        # One step: capped at 9 times its expected value (a 3-sigma reading), as the innovations are
        e1 = wrap_angle(compass_rad - previous_compass_rad - dpsi_rad)
        e1_sq = min(e1 * e1, 9.0 * (dpsi_var_rad2 + 2.0 * self.compass_var_rad2))
        a = 1.0 / TURN_NOISE_WINDOWS
        self._step_sq.add(e1_sq, a, 1.0 - a)
        self._step_claimed.add(dpsi_var_rad2, a, 1.0 - a)
        self._window.append((previous_compass_rad, dpsi_rad, dpsi_var_rad2))
        if len(self._window) < self.turn_window_steps:
            return
        e = wrap_angle(compass_rad - self._window[0][0] - sum(d for _, d, _ in self._window))
        self._turn_sq.add(e * e, a, 1.0 - a)
        self._turn_claimed.add(sum(v for _, _, v in self._window), a, 1.0 - a)

    def _forget_window(self) -> None:
        """A step the tokens did not measure, or a reading not taken: the next window starts after it."""
        self._window.clear()

    def _beyond_gate(self, innovation_rad: float, innovation_var_rad2: float) -> bool:
        """Whether an innovation lies farther than ``gate_sigmas`` of its standard deviation (0: no gate)."""
        return self.gate_sigmas > 0 and innovation_rad**2 > self.gate_sigmas**2 * innovation_var_rad2

    def implausible(self, compass_rad: float, unmeasured_sigma_rad: float) -> bool:
        """Whether a reading lies beyond the gate around the last heading, held through a turn of
        ``unmeasured_sigma_rad`` (what the vehicle can turn in the step) when nothing measured it."""
        if self.heading_rad is None:
            return False
        held_var = self.var_rad2 + float(unmeasured_sigma_rad) ** 2
        return self._beyond_gate(wrap_angle(compass_rad - self.heading_rad), held_var + self.compass_var_rad2)

    def _glitch(self, beyond_gate: bool) -> bool:
        """Whether to refuse a reading as a glitch: beyond the gate (a magnetic spike, a corrupt log
        line: one reading 1 rad off took the real-photo survey from 99.3 to 81.7 % inside 2-sigma).
        At most ``gate_max_readings`` in a row are refused; then the compass is believed again, as
        it is (its error really changed)."""
        if not beyond_gate:
            self._refused_in_row = 0
            return False
        if self._refused_in_row >= self.gate_max_readings:
            self._refused_in_row = 0
            self._resync = True
            return False
        self._refused_in_row += 1
        self.refused_readings += 1
        self.refused_last = True
        return True

    def update(
        self,
        compass_rad: float,
        dpsi_rad: float | None = None,
        dpsi_sigma_rad: float = math.inf,
        unmeasured_sigma_rad: float = NO_COMPASS_STEP_SIGMA_RAD,
    ) -> float:
        """One step: the compass reading of this frame and the measured change since the last one.

        A NaN compass (a video without navigation) leaves the tokens alone: the heading is
        then their integrated rotation from 0 at the first frame, its variance growing (by
        ``unmeasured_sigma_rad`` squared over a step whose turn nothing measured).
        """
        measured = dpsi_rad is not None and math.isfinite(dpsi_sigma_rad)
        self.refused_last = False
        last_compass, self._last_compass_rad = self._last_compass_rad, None  # set again if this reading is taken
        if compass_rad is None or not math.isfinite(compass_rad):
            if self.heading_rad is None:
                self.heading_rad, self.var_rad2 = 0.0, 0.0
            elif measured:
                self.heading_rad = wrap_angle(self.heading_rad + float(dpsi_rad))  # type: ignore[arg-type]
                self.var_rad2 += float(dpsi_sigma_rad) ** 2
            else:  # nothing measured the turn of this step
                self.var_rad2 += float(unmeasured_sigma_rad) ** 2
            return self.heading_rad
        c = finite_scalar("heading_rad", compass_rad)
        r = self.compass_var_rad2
        if self.heading_rad is None or r == 0.0:
            self.heading_rad, self.var_rad2, self._last_compass_rad = c, r, c
            return c
        if measured:
            psi = self.heading_rad + float(dpsi_rad)  # type: ignore[arg-type]
            var = self.var_rad2 + self.turn_noise_scale * float(dpsi_sigma_rad) ** 2
        else:
            self._forget_window()
            if self._glitch(self.implausible(c, unmeasured_sigma_rad)):
                self.var_rad2 += float(unmeasured_sigma_rad) ** 2  # a glitch, and no turn measured: the heading is held
                return self.heading_rad
            psi, var = c, r  # nothing but the compass bridges this step
        innovation = wrap_angle(c - psi)
        if measured and self._glitch(self._beyond_gate(innovation, var + r)):
            self.heading_rad, self.var_rad2 = wrap_angle(psi), var  # the tokens' turn alone bridges this step
            return self.heading_rad
        if self._resync:  # refused gate_max_readings times in a row: the compass moved, follow it
            self._resync = False
            self._forget_window()
            self.heading_rad, self.var_rad2, self._last_compass_rad = c, r, c
            return c
        if measured:  # learned always (for the run's warnings), used only when learn_noise
            self._learn_noise(innovation, var, r)
            if self.learn_turn_noise:
                self._learn_turn_noise(last_compass, c, float(dpsi_rad), float(dpsi_sigma_rad) ** 2)  # type: ignore[arg-type]
        self._last_compass_rad = c
        k = var / (var + r)
        self.heading_rad = wrap_angle(psi + k * innovation)
        self.var_rad2 = (1.0 - k) * var
        return self.heading_rad


@dataclass(frozen=True)
class HeadingPrior:
    """The heading known before this frame's tokens are tracked.

    Attributes:
        compass_rad: this frame's compass reading (NaN without a compass).
        previous_rad: the filtered heading of the previous frame: the heading of the
            prediction (1) over the step that ends at this frame.
        step_rad: compass difference since the previous frame (0 without a compass).
        step_sigma_rad: prior standard deviation of ``step_rad`` for the token rotation
            consensus; None when the compass is used as it is (``compass_sigma_rad = 0``).
    """

    compass_rad: float
    previous_rad: float
    step_rad: float
    step_sigma_rad: float | None

    @property
    def has_compass(self) -> bool:
        return math.isfinite(self.compass_rad)

    @property
    def predicted_rad(self) -> float:
        """This frame's heading before the tokens measure the turn (not wrapped)."""
        return self.previous_rad + self.step_rad


@dataclass(frozen=True)
class HeadingEstimate:
    """This frame's heading after the tokens measured the turn.

    Attributes:
        heading_rad: the heading input of (1) and (3) (compass convention; the filter removes
            its slow bias).
        sigma_rad: its white-noise standard deviation as told to the filter's prediction
            (None: the filter's configured ``heading_sigma_rad``).
        observation_sigma_rad: the heading noise told to the landmark observations (3), (4):
            ``sigma_rad``, plus the compass drift when the filter holds no bias state (a
            landmark seen again minutes later was mapped under another drift).
        walk_var_rad2: without a compass, when the filter holds the heading error ``eps``:
            the variance the integrated heading gained over this step. Its error is then a
            random walk, the same error for every later step, not white noise: ``eps`` carries
            it (the landmarks seen again estimate it) and ``sigma_rad`` stays for the records.
            None otherwise.
    """

    heading_rad: float
    sigma_rad: float | None
    observation_sigma_rad: float | None
    walk_var_rad2: float | None = None


class HeadingTracker:
    """All heading state of a run: the previous compass reading, the previous heading, the filter."""

    def __init__(self, odometry: OdometryConfig = OdometryConfig(), slam: SlamConfig = SlamConfig()):
        self.odometry = odometry
        self.slam = slam
        self.filter = HeadingFilter(
            odometry.compass_sigma_rad,
            learn_noise=odometry.compass_sigma_learned,
            gate_sigmas=odometry.compass_gate_sigmas,
            gate_max_readings=odometry.compass_gate_max_readings,
            learn_turn_noise=odometry.turn_noise_learned,
            turn_window_steps=odometry.turn_noise_window_steps,
        )
        self._previous_rad: float | None = None  # filtered heading of the previous frame
        self._previous_compass_rad: float | None = None
        self.has_compass = True  # whether the last frame had a compass reading

    @property
    def previous_rad(self) -> float | None:
        return self._previous_rad

    @property
    def compass_sigma_rad(self) -> float:
        """The compass's white noise as used: configured, or learned from its readings when larger."""
        return math.sqrt(self.filter.compass_var_rad2)

    def compass_summary(self) -> dict:
        """What ``summary.json`` says of the compass noise: configured and learned (degrees; None: not learned)."""
        learned = self.filter.learned_compass_sigma_rad
        return {
            "sigma_configured_deg": math.degrees(self.odometry.compass_sigma_rad),
            "sigma_learned_deg": None if learned is None else math.degrees(learned),
            "sigma_used_deg": math.degrees(self.compass_sigma_rad),
            "learning": self.filter.learn_noise,
            "readings_refused": self.filter.refused_readings,
            "token_turn_noise_scale": self.filter.turn_noise_scale,
        }

    def compass_warnings(self) -> list[str]:
        """One line when the compass was found much noisier than configured, one when readings were refused."""
        out = []
        if self.filter.refused_readings:
            out.append(
                f"{self.filter.refused_readings} compass reading(s) refused as glitches: more than "
                f"{self.odometry.compass_gate_sigmas:g} sigma from the heading the tokens' turn predicts "
                "([odometry] compass_gate_sigmas; 0 keeps every reading)"
            )
        learned, configured = self.filter.learned_compass_sigma_rad, self.odometry.compass_sigma_rad
        if learned is None or configured == 0 or learned < COMPASS_NOISIER_WARNING * configured:
            return out
        return out + [
            f"the compass readings scatter by {math.degrees(learned):.2f} deg against the turns the tokens "
            f"measure, more than the {math.degrees(configured):.2f} deg configured ([odometry] compass_sigma_rad "
            f"= {configured:g}); "
            + (
                "the learned value was used"
                if self.filter.learn_noise
                else f"set compass_sigma_rad = {learned:.4f} or compass_sigma_learned = true"
            )
        ]

    def prior(self, compass_rad: float, dt_s: float | None = None) -> HeadingPrior:
        """The heading before the tokens: previous heading and compass step (first frame: the compass, or 0).

        A reading farther from the last heading than the vehicle can turn in ``dt_s`` (a glitch)
        gives no step: the prior is then 0 within the turn the vehicle can make.
        """
        has_compass = math.isfinite(compass_rad)
        self.has_compass = has_compass
        previous_compass = compass_rad if self._previous_compass_rad is None else self._previous_compass_rad
        if self._previous_rad is None:
            previous = compass_rad if has_compass else 0.0
        else:
            previous = self._previous_rad
        step = wrap_angle(compass_rad - previous_compass) if has_compass and math.isfinite(previous_compass) else 0.0
        sigma_c = self.compass_sigma_rad if has_compass else 0.0
        if sigma_c > 0:
            step_sigma: float | None = math.sqrt(2.0) * sigma_c  # difference of two readings
        else:
            step_sigma = None if has_compass else NO_COMPASS_STEP_SIGMA_RAD
        turn_sigma = self.unmeasured_turn_sigma_rad(dt_s)
        if sigma_c > 0 and self.filter.implausible(compass_rad, turn_sigma):
            step, step_sigma = 0.0, turn_sigma  # a glitch: the tokens alone find this turn
        return HeadingPrior(compass_rad, previous, step, step_sigma)

    def update(
        self, prior: HeadingPrior, dpsi_rad: float | None, dpsi_sigma_rad: float, dt_s: float | None = None
    ) -> HeadingEstimate:
        """Fuse the compass with the turn the tokens measured (``dpsi_rad`` None: not measured).

        ``dt_s``: the step's duration, which bounds an unmeasured turn without a compass
        (:meth:`unmeasured_turn_sigma_rad`).
        """
        var_before = self.filter.var_rad2
        psi = self.filter.update(prior.compass_rad, dpsi_rad, dpsi_sigma_rad, self.unmeasured_turn_sigma_rad(dt_s))
        smoothing = self.odometry.compass_sigma_rad > 0 and prior.has_compass
        sigma = self.filter.sigma_rad if smoothing or not prior.has_compass else None
        if smoothing and self.slam.heading_bias_sigma_rad == 0:
            obs_sigma = math.hypot(sigma, self.odometry.compass_drift_sigma_rad)  # type: ignore[arg-type]
        else:
            obs_sigma = sigma  # type: ignore[assignment]
        walk = self._walk_var_rad2(prior.has_compass, var_before)
        self._remember(psi, prior.compass_rad)
        if walk is not None:
            return HeadingEstimate(psi, sigma, 0.0, walk)  # the whole heading error is eps's
        return HeadingEstimate(psi, sigma, obs_sigma)

    def skip(self, compass_rad: float, dt_s: float | None = None) -> HeadingEstimate:
        """An unusable frame: follow the compass alone (without one, the heading is held and its error grows)."""
        var_before = self.filter.var_rad2
        psi = self.filter.update(compass_rad, unmeasured_sigma_rad=self.unmeasured_turn_sigma_rad(dt_s))
        walk = self._walk_var_rad2(math.isfinite(compass_rad), var_before)
        self._remember(psi, compass_rad)
        return HeadingEstimate(psi, None, None, walk)

    def unmeasured_turn_sigma_rad(self, dt_s: float | None) -> float:
        """Standard deviation of a turn nothing measured over ``dt_s`` seconds, without a compass.

        ``[odometry] unmeasured_turn_rate_sigma_radps`` times the step (at most pi): the vehicle
        turns at most so fast. Before, 0.2 rad a step whatever its length (57 degrees/s at 5 Hz):
        after two such steps the filter's heading error ``eps`` was free to take whatever the next
        landmark's short track suggested, and the bare-video survey with turns went 6 to 16 cm
        wrong outside its ellipse. ``dt_s`` None (or not positive): :data:`NO_COMPASS_STEP_SIGMA_RAD`.
        """
        if dt_s is None or not dt_s > 0:
            return NO_COMPASS_STEP_SIGMA_RAD
        return min(math.pi, self.odometry.unmeasured_turn_rate_sigma_radps * float(dt_s))

    def _walk_var_rad2(self, has_compass: bool, var_before_rad2: float) -> float | None:
        """Without a compass and with ``eps`` in the filter: what this step added to the integrated heading's variance."""
        if has_compass or self.slam.heading_bias_sigma_rad == 0:
            return None
        return max(self.filter.var_rad2 - var_before_rad2, 0.0)

    def _remember(self, heading_rad: float, compass_rad: float) -> None:
        """The step's heading and its compass reading; a refused reading (a glitch) is not the next
        step's reference: the heading stands in for it."""
        self._previous_rad = heading_rad
        self._previous_compass_rad = heading_rad if self.filter.refused_last else compass_rad
