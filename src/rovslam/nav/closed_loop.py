"""The closed loop in the simulator: the vehicle flies where the estimate steers it, frames rendered on the fly.

Each frame period: the simulated vehicle's true state (:class:`~rovslam.nav.dynamics.SimulatedVehicle`)
is rendered by the preset's camera with its compass, sonar and AHRS readings
(:class:`~rovslam.sim.live.LiveSimulator`); the :class:`~rovslam.nav.api.Navigator` processes that
frame like any other and returns a command; the vehicle applies it for one frame period.
The only path from the truth to the controller is the rendered image and the noisy sensors.

A mission is an optional survey (a cross-hatched lawnmower of the preset's grid, widened
to cover the points of interest, flown for ``survey_s`` seconds through pass-through
way-points) and then the points of interest in order. :class:`ArrivalBook` compares what
the controller believed at each arrival with the truth (``arrivals.csv``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Goal
from rovslam.errors import InvalidArgumentError, SimulationError
from rovslam.nav.api import Navigator, NavStep
from rovslam.nav.dynamics import DynamicsParams, SimulatedVehicle
from rovslam.nav.guidance import Arrival, GuidanceConfig, HoldEnd
from rovslam.sim.live import LiveSimulator, TrueState
from rovslam.sim.scenarios import SCENARIOS, Scenario
from rovslam.sim.vehicle import GridPattern

__all__ = [
    "ARRIVAL_COLUMNS",
    "ArrivalBook",
    "ClosedLoop",
    "LoopStep",
    "mission_area_m",
    "survey_around",
    "survey_goals",
    "survey_grid",
]

ARRIVAL_COLUMNS = (
    "name",
    "x_m",
    "y_m",
    "arrival_t_s",
    "est_err_m",
    "true_err_m",
    "hold_rms_true_m",
    "landmark_id",
    "confident",
    "reached",
    "ellipse_m",
    "note",
)


@dataclass(frozen=True)
class LoopStep:
    """One frame of the closed loop: the truth it was rendered from and what the navigator made of it."""

    k: int
    truth: TrueState
    nav: NavStep
    current_true_mps: np.ndarray  # (2,) the simulated current (truth, for the record only)
    surveying: bool = False  # the frame belongs to the survey


def survey_grid(grid: GridPattern, points_xy_m: np.ndarray) -> GridPattern:
    """The preset's grid, widened (same lanes and offsets) so that it covers ``points_xy_m`` (K, 2) if they lie outside."""
    pts = np.asarray(points_xy_m, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return grid
    hx = max(grid.half_size_m[0], float(np.max(np.abs(pts[:, 0]))))
    hy = max(grid.half_size_m[1], float(np.max(np.abs(pts[:, 1]))))
    return replace(grid, half_size_m=(hx, hy))


def survey_goals(grid: GridPattern, duration_s: float, speed_mps: float) -> list[Goal]:
    """Pass-through way-points of the grid's repetitions, enough for ``duration_s`` at ``speed_mps``."""
    if duration_s <= 0:
        return []
    goals: list[Goal] = []
    length, last, r = 0.0, np.zeros(2), 0
    while length < 1.2 * duration_s * speed_mps + 1.0:
        for p in grid.repetition(r, start_near=(float(last[0]), float(last[1]))):
            length += float(np.hypot(*(p - last)))
            last = p
            goals.append(Goal(f"survey {len(goals)}", p.copy(), kind="survey"))
        r += 1
    return goals


def survey_around(points_xy_m: np.ndarray, duration_s: float, speed_mps: float) -> list[Goal]:
    """The default grid's survey (:class:`GridPattern`), widened to cover ``points_xy_m`` (K, 2): way-points for ``duration_s``."""
    return survey_goals(survey_grid(GridPattern(), points_xy_m), duration_s, speed_mps)


def mission_area_m(sc: Scenario, goals: list[Goal], margin_m: float = 0.15) -> tuple[float, float, float, float]:
    """(north min, north max, east min, east max) the camera may see: the goals, the start and the footprint."""
    pts = np.array([[0.0, 0.0]] + [g.xy_m for g in goals if g.xy_m is not None])
    cam = sc.camera
    half_diag = math.hypot(
        max(cam.cx_px, cam.width_px - cam.cx_px) / cam.fx_px, max(cam.cy_px, cam.height_px - cam.cy_px) / cam.fy_px
    )
    reach = (sc.vehicle.altitude_m + 0.1) * half_diag + margin_m
    return (
        float(pts[:, 0].min()) - reach,
        float(pts[:, 0].max()) + reach,
        float(pts[:, 1].min()) - reach,
        float(pts[:, 1].max()) + reach,
    )


class ClosedLoop:
    """Fly the survey then the points of interest in closed loop; iterating gives one :class:`LoopStep` per frame.

    ``guidance`` defaults to :class:`GuidanceConfig` (the survey flies at the preset's cruise
    speed); ``dynamics`` to the preset's current and altitude disturbances
    (:meth:`DynamicsParams.from_vehicle`). Ends when the mission is done or at ``max_s``.
    ``navigator`` is the :class:`~rovslam.nav.api.Navigator` (its pipeline holds the map).
    """

    def __init__(
        self,
        scenario: str | Scenario,
        pois: list[Goal],
        estimator: str = "slam",
        seed: int = 0,
        survey_s: float = 0.0,
        guidance: GuidanceConfig | None = None,
        dynamics: DynamicsParams | None = None,
        config: RunConfig = RunConfig(),
        max_s: float | None = None,
    ) -> None:
        if isinstance(scenario, str):
            if scenario not in SCENARIOS:
                raise SimulationError(f"unknown scenario {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
            scenario = SCENARIOS[scenario]
        sc = self.scenario = scenario
        if not (isinstance(survey_s, (int, float)) and math.isfinite(survey_s) and survey_s >= 0):
            raise InvalidArgumentError(f"survey_s must be a number of seconds >= 0, got {survey_s!r}")
        self.guidance = guidance if guidance is not None else GuidanceConfig()
        # The survey flies at the preset's speed, the points of interest at the guidance's.
        self.survey_guidance = replace(
            self.guidance, cruise_speed_mps=min(sc.vehicle.cruise_speed_mps, self.guidance.max_speed_mps)
        )
        points = np.array([g.xy_m for g in pois if g.xy_m is not None]).reshape(-1, 2)
        survey = survey_goals(survey_grid(sc.grid, points), survey_s, sc.vehicle.cruise_speed_mps)
        goals = survey + list(pois)
        self.max_s = max_s
        self.sim = LiveSimulator(sc, seed, area_m=mission_area_m(sc, goals))
        self.vehicle = SimulatedVehicle(
            dynamics if dynamics is not None else DynamicsParams.from_vehicle(sc.vehicle),
            seed,
            heading_rad=sc.vehicle.heading_rad,
        )
        self.navigator = Navigator(self.sim.info, goals, estimator, config, self.guidance, survey_until_s=survey_s)

    def __iter__(self) -> Iterator[LoopStep]:
        nav, dt_s = self.navigator, self.sim.frame_period_s
        try:
            k = 0
            while not nav.done and (self.max_s is None or k * dt_s <= self.max_s):
                goal = nav.mission.goal
                surveying = goal is not None and goal.kind == "survey"
                nav.mission.cfg = self.survey_guidance if surveying else self.guidance
                truth = replace(self.vehicle.true_state(), t_s=k * dt_s)
                step = nav.step(self.sim.capture(k, truth))
                yield LoopStep(k, truth, step, self.vehicle.current_mps.copy(), surveying)
                self.vehicle.advance(step.command, dt_s)
                k += 1
        finally:
            self.sim.close()


class ArrivalBook:
    """``arrivals.csv`` rows from the loop's steps: the estimate's and the truth's distance to each point.

    ``est_err_m`` / ``true_err_m``: from the estimated / true position to the point at the
    arrival; ``hold_rms_true_m``: RMS of the true distance over the station keeping.
    A landmark point is the landmark's map position at the arrival.
    """

    def __init__(self, pois: list[Goal]) -> None:
        self.rows: dict[str, dict] = {}
        self._names = [p.name for p in pois]
        self._landmarks = {p.name: p.landmark_id for p in pois}
        self._hold: list[float] | None = None
        self._target: np.ndarray | None = None
        self._current: str | None = None

    def feed(self, step: LoopStep) -> list[dict]:
        """Account one frame; the rows completed in it (a hold ended or a goal was abandoned)."""
        done = []
        true_xy = np.array([step.truth.x_m, step.truth.y_m])
        for ev in step.nav.events:
            if isinstance(ev, Arrival):
                self._current, self._target, self._hold = ev.name, ev.target_xy_m, []
                self.rows[ev.name] = {
                    "name": ev.name,
                    "x_m": float(ev.target_xy_m[0]),
                    "y_m": float(ev.target_xy_m[1]),
                    "arrival_t_s": ev.t_s,
                    "est_err_m": float(np.hypot(*(ev.est_xy_m - ev.target_xy_m))),
                    "true_err_m": float(np.hypot(*(true_xy - ev.target_xy_m))),
                    "hold_rms_true_m": math.nan,
                    "landmark_id": self._landmarks.get(ev.name),
                    "confident": int(ev.confident),
                    "reached": 1,
                    "ellipse_m": ev.ellipse_m,
                    "note": "" if ev.confident else "ellipse still too wide at arrival",
                }
            elif isinstance(ev, HoldEnd) and ev.name in self._names:
                row = self.rows.get(ev.name)
                if row is None or not ev.reached:
                    row = {
                        "name": ev.name,
                        "x_m": math.nan,
                        "y_m": math.nan,
                        "arrival_t_s": math.nan,
                        "est_err_m": math.nan,
                        "true_err_m": math.nan,
                        "hold_rms_true_m": math.nan,
                        "landmark_id": self._landmarks.get(ev.name),
                        "confident": 0,
                        "reached": 0,
                        "ellipse_m": math.nan,
                        "note": ev.reason,
                    }
                    self.rows[ev.name] = row
                elif self._hold:
                    row["hold_rms_true_m"] = math.sqrt(float(np.mean(np.square(self._hold))))
                self._current, self._hold = None, None
                done.append(row)
        if self._hold is not None and self._target is not None:
            self._hold.append(float(np.hypot(*(true_xy - self._target))))
        return done

    def table(self) -> list[dict]:
        """The rows in the points' order (points not reached yet are left out)."""
        return [self.rows[n] for n in self._names if n in self.rows]
