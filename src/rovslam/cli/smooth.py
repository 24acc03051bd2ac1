"""``rovslam smooth``: a finished run smoothed in a factor graph (GTSAM iSAM2), the whole path given all of it."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.display import ProgressBar
from rovslam.cli.errors import guard


@app.command()
@guard
def smooth(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run` (any back end)."),
    robust: str = typer.Option("huber", help="Loss on the landmark observations: huber, cauchy or none."),
    robust_k: float = typer.Option(3.0, help="Its threshold, in sigmas of the observation noise."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Smooth a finished run: its measurements in a factor graph (GTSAM iSAM2), the whole path given all of it.

    Writes OUT/trajectory_smoothed.tum, OUT/trajectory_smoothed.csv (with each pose's marginal
    covariance) and OUT/landmarks_smoothed.csv from OUT/measurements.csv and
    OUT/landmark_measurements.csv.
    """
    import dataclasses

    from rovslam.runner import smooth_run, smoother_config_for_run

    cfg = dataclasses.replace(smoother_config_for_run(results), robust=robust, robust_k=robust_k)
    try:
        with ProgressBar(quiet, "smoothing") as bar:
            callbacks = {} if bar is None else {"on_start": lambda n: bar(0, n), "on_frame": lambda n: bar(n, None)}
            summary = smooth_run(results, cfg, **callbacks)
    except KeyboardInterrupt:
        typer.echo("interrupted: nothing written (the measurement files are untouched)", err=True)
        raise typer.Exit(130) from None
    if summary.relief_gain == summary.relief_gain:  # not NaN: the relief rounds were tried
        kept = summary.relief_gain >= cfg.relief_min_gain
        typer.echo(
            f"relief: the landmarks' heights took {100 * summary.relief_gain:.0f} % of their misfit away; "
            + ("kept" if kept else f"under {100 * cfg.relief_min_gain:.0f} %, the flat seabed's result kept")
        )
    typer.echo(
        f"{summary.frames} frames, {summary.landmarks} landmarks, {summary.observations} observations "
        f"({summary.downweighted} down-weighted); incremental pass {summary.online_s:.1f} s, "
        f"final smoothing {summary.final_s:.1f} s -> {results}/trajectory_smoothed.csv"
    )
