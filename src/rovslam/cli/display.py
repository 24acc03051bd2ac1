"""What the commands print besides their one-line results: progress bars, tables, help text.

:class:`ProgressBar` (a run, a simulation, a mosaic: frames per second, landmarks, tokens) and
:class:`CellProgress` (a batch) draw on stderr and turn themselves off when the terminal goes;
:func:`print_eval` and :func:`print_matrix` print the figures as rich tables. rich is imported
only when something is drawn.
"""

from __future__ import annotations


def plain_help(text: str) -> str:
    """Help text shown as written: rich would take ``[camera]`` for markup and drop it."""
    return text.replace("[", "\\[")


def quiet_native_logs() -> None:
    """Silence OpenCV's own stderr log (a damaged PNG is reported once, in rovslam's words)."""
    import cv2.utils.logging as cv_log

    cv_log.setLogLevel(cv_log.LOG_LEVEL_SILENT)


def slam_callbacks(bar) -> dict:
    """``on_start`` / ``on_frame`` of :func:`rovslam.runner.run_sequence` feeding a progress bar (or nothing)."""
    if bar is None:
        return {}
    return {
        "on_start": lambda n: bar(0, n or None),
        "on_frame": lambda r: bar(r.index + 1, None, landmarks=r.n_landmarks, tokens=r.tokens_tracked),
    }


class ProgressBar:
    """A rich progress bar as a callable ``bar(done, total, **fields)``; None when quiet."""

    def __init__(self, quiet: bool, label: str, extra: bool = False):
        self.quiet = quiet
        self.label = label
        self.extra = extra
        self._p = None

    def __enter__(self):
        if self.quiet:
            return None
        started = False

        def lazy(done: int, total: int | None = None, **fields) -> None:
            # The bar appears with the first progress report, so an input error comes alone.
            # A display that fails (a closed terminal) turns the bar off; it never fails the run.
            nonlocal started
            try:
                if not started:
                    started = True
                    self._start()
                if self._p is not None:
                    self._bar(done, total, **fields)
            except OSError:
                self._p = None

        return lazy

    def _start(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        cols = [
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[fps]:>6.0f} frames/s"),
        ]
        if self.extra:
            cols.append(TextColumn("landmarks {task.fields[landmarks]}  tokens {task.fields[tokens]}"))
        cols.append(TimeRemainingColumn())
        progress = Progress(*cols, console=Console(stderr=True), transient=False)
        progress.start()
        self._p = progress  # type: ignore[assignment]
        self._task = self._p.add_task(self.label, total=None, fps=0.0, landmarks=0, tokens=0)  # type: ignore[attr-defined]
        import time

        self._t0 = time.perf_counter()
        self._last = 0.0
        self._total: int | None = None
        self._final: tuple | None = None

        def bar(done: int, total: int | None = None, **fields) -> None:
            now = time.perf_counter()
            self._final = (done, fields)
            if now - self._last < 0.1 and total is None and done != self._total:
                return
            self._last = now
            fps = done / (now - self._t0) if now > self._t0 else 0.0
            kw = {"completed": done, "fps": fps, **fields}
            if total is not None:
                kw["total"] = total
                self._total = total
            self._p.update(self._task, **kw)  # type: ignore[attr-defined]

        self._bar = bar

    def __exit__(self, *exc) -> None:
        if self._p is not None:
            try:
                if self._final is not None:  # the last update may have been throttled
                    done, fields = self._final
                    self._last = 0.0
                    self._p.update(self._task, completed=done, **fields)
                self._p.stop()
            except OSError:  # the terminal is gone: nothing left to show
                pass


class CellProgress:
    """Progress of a batch: a bar of cells and one line per finished cell (failures with their error)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self._p = None

    def __enter__(self) -> CellProgress:
        return self

    def start(self, done: int, total: int) -> None:
        if self.quiet:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self._p = Progress(  # type: ignore[assignment]
            TextColumn("[bold]cells"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=Console(stderr=True),
        )
        self._p.start()  # type: ignore[attr-defined]
        self._task = self._p.add_task("cells", total=total, completed=done)  # type: ignore[attr-defined]

    def cell(self, row: dict) -> None:
        if self._p is None:
            return
        if row.get("status") == "ok":
            line = (
                f"ok      {row['cell']}: ATE {100 * row['ate_rmse_m']:.2f} cm, {row['frames']} frames, "
                f"{row['wall_s']:.0f} s"
            )
        else:
            line = f"FAILED  {row['cell']}: {row.get('error', '')}"
        self._p.console.print(line, markup=False, highlight=False)
        self._p.advance(self._task)

    def __exit__(self, *exc) -> None:
        if self._p is not None:
            self._p.stop()


def print_eval(f) -> None:
    """Print an :class:`rovslam.eval.Evaluation` as tables; an undefined figure says n/a, and why below."""
    import math

    from rich.console import Console
    from rich.table import Table

    console = Console()
    t = Table(title=f"rovslam eval: {f.frames} frames, {f.duration_s:.0f} s, {f.landmarks} landmarks")
    t.add_column("figure")
    runs = [("SLAM", f.slam)]
    if f.smoothed is not None:
        runs.append(("SLAM smoothed", f.smoothed))
    runs.append(("dead reckoning", f.dead_reckoning))
    if f.phase_correlation is not None:
        runs.append(("phase correlation", f.phase_correlation))
    for name, _ in runs:
        t.add_column(name, justify="right")
    for key, label, scale, unit in [
        ("ate_rmse_m", "ATE RMSE", 100, "cm"),
        ("ate_median_m", "ATE median", 100, "cm"),
        ("ate_max_m", "ATE max", 100, "cm"),
        ("final_error_m", "final error", 100, "cm"),
        ("relative_error_m_per_m", f"drift per {f.slam.segment_m:g} m", 100, "cm/m"),
        ("final_error_pct", "final error / distance", 1, "%"),
        ("ate_heading_aligned_rmse_m", "ATE RMSE, heading aligned", 100, "cm"),
        ("heading_offset_rad", "... the turn taken out", 180 / math.pi, "deg"),
    ]:
        t.add_row(label, *(_fig(getattr(e, key), scale, unit, 3) for _, e in runs))
    cons = [f.consistency] + ([f.smoothed_consistency] if f.smoothed is not None else [])
    pad = [""] * (len(runs) - len(cons))

    def jump(value: float | None, t_s: float | None) -> str:
        return _fig(value, 1, "sigma", 2) + (f" at {t_s:.1f} s" if t_s is not None else "")

    t.add_row("distance travelled", f"{f.slam.distance_m:.2f} m", *[""] * (len(runs) - 1))
    t.add_row("inside 2-sigma ellipse", *(f"{100 * c.coverage_2sigma:.1f} %" for c in cons), *pad)
    t.add_row("NEES mean (2 dof)", *(f"{c.nees_mean:.2f}" for c in cons), *pad)
    t.add_row("largest error jump", *(jump(c.max_error_jump_sigma, c.max_error_jump_t_s) for c in cons), *pad)
    t.add_row(
        "... in sigmas of the ellipse before",
        *(jump(c.max_error_jump_before_sigma, c.max_error_jump_before_t_s) for c in cons),
        *pad,
    )
    if f.speed is not None:
        sp = f.speed
        t.add_row(
            "speed NEES mean (2 dof, per step)", f"{sp.nees_mean:.2f} over {sp.steps} steps", *[""] * (len(runs) - 1)
        )
        t.add_row(
            "speed error / claimed sigma (RMS)",
            " ".join(f"{1e3 * e:.2f}/{1e3 * s:.2f}" for e, s in zip(sp.rms_error_mps, sp.rms_sigma_mps)) + " mm/s",
            *[""] * (len(runs) - 1),
        )
    if f.altitude is not None:
        a = f.altitude
        t.add_row(
            "altitude error" + (" (seabed below)" if a.truth != "altitude_m" else ""),
            f"median {a.median_error_pct:.2f} %, p95 {a.p95_error_pct:.2f} %, mean {a.mean_error_pct:+.2f} %",
            *[""] * (len(runs) - 1),
        )
    t.add_row("skipped frames", str(f.skipped_frames), *[""] * (len(runs) - 1))
    console.print(t)
    for note in f.notes:
        console.print(f"n/a: {note}", markup=False, highlight=False)
    if f.groundtruth_shift_m != (0.0, 0.0):
        dx, dy = f.groundtruth_shift_m
        console.print(
            f"note: the ground truth at the run's first frame is at x = {-dx:.3f} m, y = {-dy:.3f} m, not at the "
            f"origin where the run starts: it was shifted by ({dx:+.3f}, {dy:+.3f}) m to start there",
            markup=False,
            highlight=False,
        )
    if f.partial_run is not None:
        console.print(f"note: {f.partial_run}", markup=False, highlight=False)
    if f.run_frame_turn_rad != 0.0:
        console.print(
            f"note: no compass in this run: its frame is its first heading; the ground truth was turned "
            f"by {math.degrees(f.run_frame_turn_rad):+.2f} deg into it",
            markup=False,
            highlight=False,
        )
    if f.table1_landmark0:
        t1 = Table(title="Table 1: vehicle position while tracking landmark 0 (displacement since its initialisation)")
        for col in ("time [s]", "x est [m]", "y est [m]", "x true [m]", "y true [m]"):
            t1.add_column(col, justify="right")
        rows = f.table1_landmark0
        for r in rows[:12]:
            t1.add_row(f"{r.t_s:.1f}", f"{r.x_est_m:.3f}", f"{r.y_est_m:.3f}", f"{r.x_gt_m:.3f}", f"{r.y_gt_m:.3f}")
        console.print(t1)
        if len(rows) > 12:
            console.print(f"({len(rows) - 12} more passages over landmark 0 in eval.json)")


def _fig(value: float | None, scale: float, unit: str, digits: int) -> str:
    """A figure for the tables: ``n/a`` when undefined (too short a run)."""
    return "n/a" if value is None else f"{value * scale:.{digits}f} {unit}"


def print_matrix(rows: list, groups) -> None:
    """The per-scenario summary of a batch (median / worst over seeds), as in matrix.md."""
    from rich.console import Console
    from rich.table import Table

    from rovslam.batch import SUMMARY_FIGURES, summarise
    from rovslam.batch.table import format_figure

    short = {
        "ate_rmse_m": "ATE cm",
        "final_error_pct": "final % dist",
        "coverage_2sigma": "in 2-sigma %",
        "max_error_jump_sigma": "jump sigma",
        "dr_ate_rmse_m": "DR ATE cm",
        "pc_ate_rmse_m": "PC ATE cm",
    }
    figures = [f for f in SUMMARY_FIGURES if f.key in short]
    t = Table(title="median / worst over seeds (all figures in matrix.md)")
    t.add_column("scenario", no_wrap=True)
    t.add_column("ok", justify="right")
    for f in figures:
        t.add_column(short[f.key], justify="right")
    for s in summarise(rows, groups):
        t.add_row(
            s.group,
            f"{s.ok}/{s.cells}",
            *(f"{format_figure(s.median[f.key], f)} / {format_figure(s.worst[f.key], f)}" for f in figures),
        )
    Console().print(t)
