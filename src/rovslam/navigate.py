"""``rovslam navigate``: a closed-loop mission in the simulator, written as a results folder (the edge to disk).

``OUT/`` gets what ``rovslam run`` writes (``trajectory.csv`` with ``dr_x_m, dr_y_m``,
``trajectory.tum``, ``observations.csv``, ``landmarks.csv`` and templates, ``config.toml``,
``summary.json``) and:

``OUT/groundtruth.csv``  the simulated vehicle's true state per frame (``rovslam eval`` reads it)
``OUT/navigation.csv``   per frame: the goal, the estimate steered by, the command, the current estimate, the truth
``OUT/arrivals.csv``     per point: ``name,x_m,y_m,arrival_t_s,est_err_m,true_err_m,hold_rms_true_m`` (and more)
``OUT/navigation.png``   true and estimated paths with the points, and the arrival errors

Rows are written as the run goes; Ctrl-C (or SIGTERM, SIGHUP) finishes the frame in hand
and closes every file complete, ``summary.json`` saying ``"interrupted"``.
"""

from __future__ import annotations

import csv
import io
import math
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovslam import __version__
from rovslam.config import RunConfig, to_dict
from rovslam.core import Goal
from rovslam.errors import InvalidArgumentError, OutputError
from rovslam.io.result_folder import prepare_output_folder
from rovslam.io.results import ResultWriter, atomic_write_text, output_errors
from rovslam.nav.closed_loop import ARRIVAL_COLUMNS, ArrivalBook, ClosedLoop, LoopStep
from rovslam.nav.estimate import check_estimator
from rovslam.nav.guidance import GuidanceConfig
from rovslam.runner import StopRequest

__all__ = ["NAVIGATION_COLUMNS", "NavigateSummary", "navigate", "navigation_row"]

NAVIGATION_COLUMNS = (
    "t_s",
    "phase",
    "goal",
    "target_x_m",
    "target_y_m",
    "nav_x_m",
    "nav_y_m",
    "nav_var_x_m2",
    "nav_cov_xy_m2",
    "nav_var_y_m2",
    "cmd_surge_mps",
    "cmd_sway_mps",
    "cmd_yaw_rate_radps",
    "current_x_mps",
    "current_y_mps",
    "true_x_m",
    "true_y_m",
    "true_heading_rad",
    "true_current_x_mps",
    "true_current_y_mps",
)


def navigation_row(
    t_s: float,
    phase: str,
    goal_index: int,
    target_xy_m: Any,
    est: Any,
    command: Any,
    current_mps: Any,
    truth: tuple[float, ...] = (math.nan,) * 5,
) -> tuple[Any, ...]:
    """One row of ``navigation.csv`` (:data:`NAVIGATION_COLUMNS`): ``target_xy_m`` ``(2,)`` or None, ``est`` the
    estimate steered by (``xy_m`` ``(2,)``, ``cov_m2`` ``(2, 2)``), ``current_mps`` ``(2,)``, ``truth`` the true
    x, y, heading and current (NaN where there is no truth: a live run)."""
    tgt = target_xy_m if target_xy_m is not None else (math.nan, math.nan)
    return (
        t_s,
        phase,
        goal_index,
        float(tgt[0]),
        float(tgt[1]),
        float(est.xy_m[0]),
        float(est.xy_m[1]),
        float(est.cov_m2[0, 0]),
        float(est.cov_m2[0, 1]),
        float(est.cov_m2[1, 1]),
        command.surge_mps,
        command.sway_mps,
        command.yaw_rate_radps,
        float(current_mps[0]),
        float(current_mps[1]),
        *truth,
    )


GROUNDTRUTH_COLUMNS = ("t_s", "x_m", "y_m", "altitude_m", "heading_rad")
FLUSH_EVERY = 50


@dataclass(frozen=True)
class NavigateSummary:
    """What :func:`navigate` did."""

    frames: int
    arrivals: list[dict]
    status: str  # "complete" | "interrupted" | "timeout"
    wall_s: float
    out_dir: Path
    landmarks: int
    signal: str | None = None
    signum: int | None = None

    @property
    def exit_code(self) -> int:
        return 128 + self.signum if self.signum is not None else 0


def _f(v) -> str:
    return (
        ""
        if v is None or (isinstance(v, float) and math.isnan(v))
        else (f"{v:.9g}" if isinstance(v, float) else str(v))
    )


class _NavFiles:
    """navigation.csv and groundtruth.csv, streamed; arrivals.csv rewritten whole (atomically) as rows complete."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self._n = 0
        self._fhs = {}
        self._w = {}
        for name, cols in (("navigation.csv", NAVIGATION_COLUMNS), ("groundtruth.csv", GROUNDTRUTH_COLUMNS)):
            with output_errors(out / name, "cannot create"):
                fh = (out / name).open("x", newline="", encoding="utf-8")
                self._fhs[name] = fh
                self._w[name] = csv.writer(fh, lineterminator="\n")
                self._w[name].writerow(cols)
        self.write_arrivals([])

    def write_step(self, s: LoopStep) -> None:
        n, tr = s.nav, s.truth
        truth = (tr.x_m, tr.y_m, tr.heading_rad, float(s.current_true_mps[0]), float(s.current_true_mps[1]))
        row = navigation_row(tr.t_s, n.phase, n.goal_index, n.target_xy_m, n.estimate, n.command, n.current_mps, truth)
        with output_errors(self.out / "navigation.csv"):
            self._w["navigation.csv"].writerow([_f(v) for v in row])
        with output_errors(self.out / "groundtruth.csv"):
            self._w["groundtruth.csv"].writerow(
                [_f(v) for v in (tr.t_s, tr.x_m, tr.y_m, tr.altitude_m, tr.heading_rad)]
            )
        self._n += 1
        if self._n % FLUSH_EVERY == 0:  # as ResultWriter: complete lines on disk as the run goes
            for name, fh in self._fhs.items():
                with output_errors(self.out / name):
                    fh.flush()

    def write_arrivals(self, rows: list[dict]) -> None:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(ARRIVAL_COLUMNS)
        for r in rows:
            w.writerow([_f(r.get(c)) for c in ARRIVAL_COLUMNS])
        atomic_write_text(self.out / "arrivals.csv", buf.getvalue())

    def close(self) -> None:
        for name, fh in self._fhs.items():
            with output_errors(self.out / name):
                fh.close()


def navigate(
    scenario: str,
    pois: list[Goal],
    out_dir: str | Path,
    estimator: str = "slam",
    survey_s: float = 0.0,
    hold_s: float = 10.0,
    seed: int = 0,
    config: RunConfig = RunConfig(),
    guidance: GuidanceConfig | None = None,
    max_s: float | None = None,
    overwrite: bool = False,
    on_start: Callable[[float], None] | None = None,
    on_step: Callable[[LoopStep, int], None] | None = None,
    plot: bool = True,
) -> NavigateSummary:
    """Fly the mission in closed loop and write ``out_dir`` (see the module notes).

    ``on_start(expected_s)`` is called once with a rough duration (survey plus points);
    ``on_step(step, arrivals_done)`` after every frame.
    """
    _check_mission(estimator, pois, hold_s)
    gcfg = guidance if guidance is not None else GuidanceConfig(hold_s=float(hold_s))
    with StopRequest() as stop:
        out = prepare_output_folder(out_dir, overwrite)
        loop = ClosedLoop(scenario, pois, estimator, seed, survey_s, gcfg, config=config, max_s=max_s)
        writer = ResultWriter(out)
        files = _NavFiles(out)
        book = ArrivalBook(pois)
        base = {
            "software": {"name": "rovslam", "version": __version__},
            "command": "navigate",
            "scenario": scenario,
            "seed": int(seed),
            "estimator": estimator,
            "survey_s": float(survey_s),
            "hold_s": float(hold_s),
            "guidance": {k: getattr(gcfg, k) for k in gcfg.__dataclass_fields__},
            "config": to_dict(config),
        }
        writer.write_config(config)
        writer.write_summary({**base, "status": "running"})
        t0 = time.perf_counter()
        if on_start is not None:
            on_start(survey_s + sum(60.0 + (hold_s if p.hold_s is None else p.hold_s) for p in pois))
        flight = _fly(loop, writer, files, book, stop, on_step)
        wall = time.perf_counter() - t0
        error = flight.error
        status = _status(error, stop, book, pois)
        try:
            _finish_files(out, writer, files, book, loop, flight, pois, estimator, plot)
        except OutputError as exc:
            error = error or exc
            status = "failed"
        interrupted = status == "interrupted"
        summary = {
            **base,
            "status": status,
            "complete": status == "complete",
            "interrupted": interrupted,
            "signal": stop.name if interrupted else None,
            "reason": None if error is None else str(error) or type(error).__name__,
            "frames_processed": flight.n,
            "landmarks": flight.landmarks,
            "wall_time_s": wall,
            "arrivals": book.table(),
            "navigation_start_frame": flight.nav_start,
            **loop.navigator.pipeline.light_summaries(),  # as `rovslam run` writes them
        }
        writer.write_summary(summary)
        if error is not None:
            raise error
        return NavigateSummary(
            flight.n,
            book.table(),
            status,
            wall,
            out,
            flight.landmarks,
            signal=stop.name if interrupted else None,
            signum=stop.signum if interrupted else None,
        )


def _check_mission(estimator: str, pois: list[Goal], hold_s: float) -> None:
    """InvalidArgumentError for an unknown estimator, no point to visit or a bad hold time."""
    check_estimator(estimator)
    if not pois:
        raise InvalidArgumentError("no point of interest to visit")
    if not (isinstance(hold_s, (int, float)) and math.isfinite(hold_s) and hold_s >= 0):
        raise InvalidArgumentError(f"--hold-s must be a number of seconds >= 0, got {hold_s!r}")


@dataclass
class _Flight:
    """What the closed loop flew: the paths (true and estimated), the frame counts, the error that stopped it."""

    true_xy: list = field(default_factory=list)
    est_xy: list = field(default_factory=list)
    nav_start: int | None = None  # the first frame flown towards a point
    n: int = 0  # frames flown
    landmarks: int = 0
    error: BaseException | None = None  # an output error, or a bug (the files still get finished)


def _fly(
    loop: ClosedLoop,
    writer: ResultWriter,
    files: _NavFiles,
    book: ArrivalBook,
    stop: StopRequest,
    on_step: Callable[[LoopStep, int], None] | None,
) -> _Flight:
    """Run the loop to its end (or a stop request, or an error), writing every frame's rows as it goes."""
    pipe = loop.navigator.pipeline
    flight = _Flight()
    steps = None
    try:
        steps = iter(loop)
        for step in steps:
            res = step.nav.result
            writer.write_frame(res)
            files.write_step(step)
            if res.new_landmark_id is not None:
                writer.write_landmark_template(res.new_landmark_id, pipe.landmarks[res.new_landmark_id].patch)
            if book.feed(step):
                files.write_arrivals(book.table())
            flight.true_xy.append((step.truth.x_m, step.truth.y_m))
            flight.est_xy.append(tuple(step.nav.estimate.xy_m))
            if flight.nav_start is None and not step.surveying:
                flight.nav_start = flight.n
            flight.n += 1
            flight.landmarks = res.n_landmarks
            if on_step is not None:
                on_step(step, len(book.table()))
            if stop.signum is not None:
                break
    except KeyboardInterrupt:
        stop.request(signal.SIGINT)
    except BaseException as exc:  # an output error, or a bug: the files still get finished
        flight.error = exc
    finally:
        if steps is not None:
            steps.close()  # type: ignore[attr-defined]
    return flight


def _status(error: BaseException | None, stop: StopRequest, book: ArrivalBook, pois: list[Goal]) -> str:
    """The run's status: "failed", "interrupted", "complete" (every point reached) or "timeout"."""
    if error is not None:
        return "failed"
    if stop.signum is not None:
        return "interrupted"
    return "complete" if len(book.table()) == len(pois) else "timeout"


def _finish_files(
    out: Path,
    writer: ResultWriter,
    files: _NavFiles,
    book: ArrivalBook,
    loop: ClosedLoop,
    flight: _Flight,
    pois: list[Goal],
    estimator: str,
    plot: bool,
) -> None:
    """Close the streamed files, write the arrivals, the landmarks and the plot (OutputError when one fails)."""
    writer.close(quiet=flight.error is not None)
    files.close()
    files.write_arrivals(book.table())
    writer.write_landmarks(loop.navigator.pipeline.landmark_rows())
    if plot and flight.n:
        from rovslam.viz.navigation import plot_navigation

        pts = np.array([p.xy_m if p.xy_m is not None else _row_xy(book, p.name) for p in pois])
        plot_navigation(
            out / "navigation.png",
            np.array(flight.true_xy),
            np.array(flight.est_xy),
            pts,
            [p.name for p in pois],
            flight.nav_start or 0,
            book.table(),
            estimator,
        )


def _row_xy(book: ArrivalBook, name: str) -> np.ndarray:
    row = book.rows.get(name)
    return np.array([row["x_m"], row["y_m"]]) if row else np.array([math.nan, math.nan])
