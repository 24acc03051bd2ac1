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
    image_format: Optional[str] = typer.Option(None, "--format", help="png or jpg (default: the scenario's)."),
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
            typer.echo(f"{name:18s} {sc.summary_line()}")
        return
    if image_format is not None and image_format not in ("png", "jpg"):
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
) -> None:
    """Compare a run with the ground truth: ATE, drift, dead reckoning, 2-sigma coverage, NEES, Table 1."""
    path = json_out or (results / "eval.json")
    _evaluate(results, groundtruth, path)
    typer.echo(f"wrote {path}")


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


def _evaluate(results: Path, groundtruth: Path, json_path: Path) -> None:
    """Evaluate a run against the truth, write the figures as JSON and print them as tables."""
    from rovslam.eval import evaluate
    from rovslam.io.results import read_results
    from rovslam.io.sequence import read_groundtruth

    figures = evaluate(read_results(results), read_groundtruth(groundtruth))
    json_path.write_text(json.dumps(figures, indent=2), encoding="utf-8")
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


def _print_eval(f: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    t = Table(title=f"rovslam eval: {f['frames']} frames, {f['duration_s']:.0f} s, {f['landmarks']} landmarks")
    t.add_column("figure")
    t.add_column("SLAM", justify="right")
    t.add_column("dead reckoning", justify="right")
    s, d = f["slam"], f["dead_reckoning"]
    for key, label, scale, unit in [
        ("ate_rmse_m", "ATE RMSE", 100, "cm"),
        ("ate_median_m", "ATE median", 100, "cm"),
        ("ate_max_m", "ATE max", 100, "cm"),
        ("final_error_m", "final error", 100, "cm"),
        ("relative_error_m_per_m", f"drift per {s['segment_m']:.0f} m", 100, "cm/m"),
        ("final_error_pct", "final error / distance", 1, "%"),
    ]:
        t.add_row(label, f"{s[key] * scale:.3f} {unit}", f"{d[key] * scale:.3f} {unit}")
    t.add_row("distance travelled", f"{s['distance_m']:.2f} m", "")
    c = f["consistency"]
    t.add_row("inside 2-sigma ellipse", f"{100 * c['coverage_2sigma']:.1f} %", "")
    t.add_row("NEES mean (2 dof)", f"{c['nees_mean']:.2f}", "")
    t.add_row("skipped frames", str(f["skipped_frames"]), "")
    console.print(t)
    if f["table1_landmark0"]:
        t1 = Table(title="Table 1: vehicle position while tracking landmark 0 (displacement since its initialisation)")
        for col in ("time [s]", "x est [m]", "y est [m]", "x true [m]", "y true [m]"):
            t1.add_column(col, justify="right")
        rows = f["table1_landmark0"]
        for r in rows[:12]:
            t1.add_row(f"{r['t_s']:.1f}", f"{r['x_est_m']:.3f}", f"{r['y_est_m']:.3f}", f"{r['x_gt_m']:.3f}", f"{r['y_gt_m']:.3f}")
        console.print(t1)
        if len(rows) > 12:
            console.print(f"({len(rows) - 12} more passages over landmark 0 in eval.json)")


def main() -> None:
    app()


if __name__ == "__main__":
    main()
