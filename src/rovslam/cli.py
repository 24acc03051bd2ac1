"""The ``rovslam`` command. Parses, calls the library, prints. Heavy imports stay inside commands.

Exit codes: 0 success, 2 bad input (one-line message, no traceback), 130 interrupted.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Vision-based SLAM for ROVs: laser altimeter, optical-correlation speed, EKF landmark map.",
    pretty_exceptions_enable=False,
)


def _fail(message: str, code: int = 2) -> None:
    from rich.console import Console

    Console(stderr=True).print(f"[bold red]rovslam: error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _guard(fn):
    """Turn rovslam's typed input errors into a one-line message and exit code 2."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from rovslam.errors import RovslamError

        try:
            return fn(*args, **kwargs)
        except RovslamError as exc:
            _fail(str(exc))

    return wrapper


@app.command()
@_guard
def simulate(
    scenario: str = typer.Option("portofino-short", help="Scenario preset (see --list)."),
    out: Path = typer.Option(Path("sim-seq"), "--out", "-o", help="Sequence folder to write."),
    frames: Optional[int] = typer.Option(None, help="Number of frames (default: the scenario's)."),
    seed: int = typer.Option(0, help="Random seed; the same seed writes byte-identical files."),
    image_format: str = typer.Option("png", "--format", help="png or jpg."),
    texture: Optional[Path] = typer.Option(None, help="Seabed photo/orthomosaic to use instead of the procedural texture."),
    texture_mm_per_px: Optional[float] = typer.Option(None, help="Scale of --texture (millimetres per pixel)."),
    list_scenarios: bool = typer.Option(False, "--list", help="List the scenarios and exit."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate an ROV dive over a seabed and write a sequence folder with exact ground truth."""
    from rovslam.errors import SimulationError
    from rovslam.sim import SCENARIOS, simulate as run_sim

    if list_scenarios:
        for name, sc in SCENARIOS.items():
            typer.echo(f"{name:20s} {getattr(sc, 'description', '')}")
        return
    if image_format not in ("png", "jpg"):
        raise SimulationError(f"--format must be png or jpg, got {image_format!r}")
    if frames is not None and frames <= 0:
        raise SimulationError(f"--frames must be a positive number of frames, got {frames}")
    with _progress(quiet, "simulating") as bar:
        summary = run_sim(
            scenario, out, frames=frames, seed=seed, image_format=image_format, texture_path=texture,
            texture_mm_per_px=texture_mm_per_px, progress=bar,
        )
    typer.echo(f"wrote {out} ({_describe(summary)})")


@app.command()
@_guard
def run(
    sequence: Path = typer.Argument(..., help="Sequence folder (format v1: sequence.toml, frames.csv, images/) or a video file."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the results."),
    camera: Optional[Path] = typer.Option(None, "--camera", help="Camera file for a video input (sequence.toml syntax)."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="TOML configuration (defaults: the paper's)."),
    max_frames: Optional[int] = typer.Option(None, help="Process only the first N frames."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Run vision-based SLAM on a sequence: trajectory with covariance, landmark map, summary."""
    from rovslam.config import RunConfig, load_config
    from rovslam.runner import run_sequence

    cfg = load_config(config) if config is not None else RunConfig()
    with _progress(quiet, "SLAM", extra=True) as bar:
        summary = run_sequence(sequence, out, cfg, max_frames=max_frames, camera_file=camera, **_slam_callbacks(bar))
    msg = (
        f"{summary.frames}/{summary.total_frames} frames, {summary.landmarks} landmarks, "
        f"{len(summary.skipped)} skipped, {summary.fps:.0f} frames/s -> {out}"
    )
    for idx, t, reason in summary.skipped[:10]:
        typer.echo(f"skipped frame {idx} (t={t:.2f} s): {reason}", err=True)
    if len(summary.skipped) > 10:
        typer.echo(f"... and {len(summary.skipped) - 10} more skipped frames (see summary.json)", err=True)
    if summary.interrupted:
        typer.echo(f"interrupted: {msg}; the files written so far are complete and readable", err=True)
        raise typer.Exit(130)
    typer.echo(msg)


@app.command(name="eval")
@_guard
def eval_cmd(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Path = typer.Option(..., "--groundtruth", "-g", help="groundtruth.csv of the sequence."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Where to write the figures (default OUT/eval.json)."),
    sequence: Optional[Path] = typer.Option(
        None, "--sequence", "-s", help="The sequence that was run: adds the frame-to-frame phase-correlation baseline."
    ),
) -> None:
    """Compare a run with the ground truth: ATE, drift, dead reckoning, 2-sigma coverage, NEES, error jumps, Table 1."""
    path = json_out or (results / "eval.json")
    _evaluate(results, groundtruth, path, sequence)
    typer.echo(f"wrote {path}")


@app.command()
@_guard
def batch(
    matrix: Path = typer.Argument(..., help="Matrix file (TOML): scenarios x seeds and/or sequences with ground truth."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the cells and the tables (matrix.csv, matrix.md)."),
    scheduler: Optional[str] = typer.Option(
        None, "--scheduler", help="Address of an existing Dask scheduler (default: a local cluster)."
    ),
    workers: Optional[int] = typer.Option(None, "--workers", "-w", help="Local cluster size (default: one per core)."),
    keep_sequences: bool = typer.Option(False, "--keep-sequences", help="Keep each cell's simulated images."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Run a robustness matrix on Dask: simulate, run, eval and baselines per cell; resumes; one table."""
    from rovslam.batch import default_workers, load_matrix, run_matrix
    from rovslam.errors import ClusterError

    if scheduler is not None and workers is not None:
        raise ClusterError("--workers sizes the local cluster; with --scheduler the cluster is yours to size")
    if workers is not None and workers < 1:
        raise ClusterError(f"--workers must be at least 1, got {workers}")
    m = load_matrix(matrix)
    where = scheduler or f"a local cluster of {workers or default_workers()} workers"
    with _cell_progress(quiet) as progress:
        report = run_matrix(m, out, scheduler, workers, keep_sequences, on_start=progress.start, on_cell=progress.cell)
    if report.reused and not report.computed and not report.interrupted:
        typer.echo(f"all {len(report.reused)} cells were finished already (delete DIR/cells/<cell> to run one again)")
    elif report.reused:
        typer.echo(f"kept {len(report.reused)} finished cells; ran {len(report.computed)} on {where}")
    _print_matrix(report.rows, m.groups)
    typer.echo(f"wrote {out / 'matrix.csv'} and {out / 'matrix.md'}")
    if report.interrupted:
        typer.echo("interrupted: the finished cells are kept; run the same command again to resume", err=True)
        raise typer.Exit(130)
    if report.failed:
        typer.echo(f"{len(report.failed)} of {len(report.rows)} cells failed (see {out / 'cells'}/<cell>/error.log)", err=True)
        raise typer.Exit(1)


@app.command()
@_guard
def demo(
    out: Path = typer.Option(Path("rovslam-demo"), "--out", "-o", help="Folder for everything the demo writes."),
    scenario: str = typer.Option("portofino-short", help="Scenario to simulate."),
    frames: Optional[int] = typer.Option(None, help="Number of frames (default: the scenario's)."),
    seed: int = typer.Option(0, help="Simulation seed."),
    quiet: bool = typer.Option(False, "--quiet", "-q"),
) -> None:
    """Simulate the paper's trial, run SLAM, evaluate and write the report, in one go."""
    from rovslam.runner import run_sequence
    from rovslam.sim import simulate as run_sim
    from rovslam.viz.report import write_report

    seq, res = out / "sequence", out / "results"
    if _same_simulation(seq, scenario, frames, seed):
        typer.echo(f"reusing the simulated sequence in {seq}")
    else:
        if seq.exists():
            import shutil

            shutil.rmtree(seq)  # the demo's own folder, from another scenario or seed
        with _progress(quiet, "simulating") as bar:
            run_sim(scenario, seq, frames=frames, seed=seed, progress=bar)
    with _progress(quiet, "SLAM", extra=True) as bar:
        summary = run_sequence(seq, res, **_slam_callbacks(bar))
    if summary.interrupted:
        _fail("interrupted; partial results are in " + str(res), 130)
    _evaluate(res, seq / "groundtruth.csv", res / "eval.json")
    report = write_report(res, seq / "groundtruth.csv")
    typer.echo(f"{summary.frames} frames at {summary.fps:.0f} frames/s; results in {res}")
    typer.echo(f"report: {report}")


@app.command()
@_guard
def report(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Optional[Path] = typer.Option(None, "--groundtruth", "-g", help="groundtruth.csv, if known."),
) -> None:
    """Write the paper's figures (altitude and speed, position with bounds, path and map) and an HTML report."""
    from rovslam.viz.report import write_report

    typer.echo(f"wrote {write_report(results, groundtruth)}")


@app.command(name="config")
@_guard
def config_cmd(out: Path = typer.Argument(..., help="TOML file to write with every default.")) -> None:
    """Write the default configuration (the paper's values) to a TOML file to edit."""
    from rovslam.config import RunConfig, save_config

    save_config(RunConfig(), out)
    typer.echo(f"wrote {out}")


def _same_simulation(seq: Path, scenario: str, frames: Optional[int], seed: int) -> bool:
    """Whether ``seq`` is a complete simulation of this scenario, length and seed (the demo reuses it)."""
    from rovslam.errors import RovslamError
    from rovslam.io.sequence import open_sequence

    if not (seq / "sequence.toml").is_file():
        return False
    try:
        s = open_sequence(seq)
    except RovslamError:
        return False
    from rovslam.sim import SCENARIOS

    if scenario not in SCENARIOS:
        return False
    want = frames if frames is not None else SCENARIOS[scenario].n_frames
    meta = s.info.metadata
    return meta.get("scenario") == scenario and meta.get("seed") == seed and len(s) == want == meta.get("frames")


def _slam_callbacks(bar) -> dict:
    """``on_start`` / ``on_frame`` of :func:`rovslam.runner.run_sequence` feeding a progress bar (or nothing)."""
    if bar is None:
        return {}
    return {
        "on_start": lambda n: bar(0, n or None),
        "on_frame": lambda r: bar(r.index + 1, None, landmarks=r.n_landmarks, tokens=r.tokens_tracked),
    }


def _evaluate(results: Path, groundtruth: Path, json_path: Path, sequence: Optional[Path] = None) -> None:
    """Evaluate a run against the truth, write the figures as JSON and print them as tables."""
    from rovslam.eval import evaluate_run

    figures = evaluate_run(results, groundtruth, sequence)
    json_path.write_text(json.dumps(figures.to_dict(), indent=2), encoding="utf-8")
    _print_eval(figures)


def _describe(summary) -> str:
    frames = getattr(summary, "frames", None)
    wall = getattr(summary, "wall_s", None)
    parts = []
    if frames is not None:
        parts.append(f"{frames} frames")
    if wall:
        parts.append(f"{wall:.1f} s")
    return ", ".join(parts) or "done"


class _progress:
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

        def lazy(done: int, total: Optional[int] = None, **fields) -> None:
            # The bar appears with the first progress report, so an input error comes alone.
            nonlocal started
            if not started:
                started = True
                self._start()
            self._bar(done, total, **fields)

        return lazy

    def _start(self) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        cols = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[fps]:>6.0f} frames/s")]
        if self.extra:
            cols.append(TextColumn("landmarks {task.fields[landmarks]}  tokens {task.fields[tokens]}"))
        cols.append(TimeRemainingColumn())
        self._p = Progress(*cols, console=Console(stderr=True), transient=False)
        self._p.start()
        self._task = self._p.add_task(self.label, total=None, fps=0.0, landmarks=0, tokens=0)
        import time

        self._t0 = time.perf_counter()
        self._last = 0.0
        self._total: Optional[int] = None
        self._final: Optional[tuple] = None

        def bar(done: int, total: Optional[int] = None, **fields) -> None:
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
            self._p.update(self._task, **kw)

        self._bar = bar

    def __exit__(self, *exc) -> None:
        if self._p is not None:
            if self._final is not None:  # the last update may have been throttled
                done, fields = self._final
                self._last = 0.0
                self._p.update(self._task, completed=done, **fields)
            self._p.stop()


def _print_eval(f) -> None:
    """Print an :class:`rovslam.eval.Evaluation` as tables; an undefined figure says n/a, and why below."""
    from rich.console import Console
    from rich.table import Table

    console = Console()
    t = Table(title=f"rovslam eval: {f.frames} frames, {f.duration_s:.0f} s, {f.landmarks} landmarks")
    t.add_column("figure")
    runs = [("SLAM", f.slam), ("dead reckoning", f.dead_reckoning)]
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
    ]:
        t.add_row(label, *(_fig(getattr(e, key), scale, unit, 3) for _, e in runs))
    pad = [""] * (len(runs) - 1)
    t.add_row("distance travelled", f"{f.slam.distance_m:.2f} m", *pad)
    c = f.consistency
    t.add_row("inside 2-sigma ellipse", f"{100 * c.coverage_2sigma:.1f} %", *pad)
    t.add_row("NEES mean (2 dof)", f"{c.nees_mean:.2f}", *pad)
    jump = _fig(c.max_error_jump_sigma, 1, "sigma", 2)
    if c.max_error_jump_t_s is not None:
        jump += f" at {c.max_error_jump_t_s:.1f} s"
    t.add_row("largest error jump", jump, *pad)
    t.add_row("skipped frames", str(f.skipped_frames), *pad)
    console.print(t)
    for note in f.notes:
        console.print(f"n/a: {note}", markup=False, highlight=False)
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


def _fig(value: Optional[float], scale: float, unit: str, digits: int) -> str:
    """A figure for the tables: ``n/a`` when undefined (too short a run)."""
    return "n/a" if value is None else f"{value * scale:.{digits}f} {unit}"


class _cell_progress:
    """Progress of a batch: a bar of cells and one line per finished cell (failures with their error)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self._p = None

    def __enter__(self) -> "_cell_progress":
        return self

    def start(self, done: int, total: int) -> None:
        if self.quiet:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self._p = Progress(TextColumn("[bold]cells"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                           console=Console(stderr=True))
        self._p.start()
        self._task = self._p.add_task("cells", total=total, completed=done)

    def cell(self, row: dict) -> None:
        if self._p is None:
            return
        if row.get("status") == "ok":
            line = (f"ok      {row['cell']}: ATE {100 * row['ate_rmse_m']:.2f} cm, {row['frames']} frames, "
                    f"{row['wall_s']:.0f} s")
        else:
            line = f"FAILED  {row['cell']}: {row.get('error', '')}"
        self._p.console.print(line, markup=False, highlight=False)
        self._p.advance(self._task)

    def __exit__(self, *exc) -> None:
        if self._p is not None:
            self._p.stop()


def _print_matrix(rows: list, groups) -> None:
    """The per-scenario summary of a batch (median / worst over seeds), as in matrix.md."""
    from rich.console import Console
    from rich.table import Table

    from rovslam.batch import SUMMARY_FIGURES, summarise
    from rovslam.batch.table import format_figure

    short = {"ate_rmse_m": "ATE cm", "final_error_pct": "final % dist", "coverage_2sigma": "in 2-sigma %",
             "max_error_jump_sigma": "jump sigma", "dr_ate_rmse_m": "DR ATE cm", "pc_ate_rmse_m": "PC ATE cm"}
    figures = [f for f in SUMMARY_FIGURES if f.key in short]
    t = Table(title="median / worst over seeds (all figures in matrix.md)")
    t.add_column("scenario", no_wrap=True)
    t.add_column("ok", justify="right")
    for f in figures:
        t.add_column(short[f.key], justify="right")
    for s in summarise(rows, groups):
        t.add_row(s.group, f"{s.ok}/{s.cells}",
                  *(f"{format_figure(s.median[f.key], f)} / {format_figure(s.worst[f.key], f)}" for f in figures))
    Console().print(t)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
