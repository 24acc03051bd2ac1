"""``rovslam batch``: a robustness matrix on Dask, one cell per scenario and seed, resumable."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.display import CellProgress, print_matrix
from rovslam.cli.errors import guard


@app.command()
@guard
def batch(
    matrix: Path = typer.Argument(
        ..., help="Matrix file (TOML): scenarios x seeds and/or sequences with ground truth."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the cells and the tables (matrix.csv, matrix.md)."),
    scheduler: str | None = typer.Option(
        None, "--scheduler", help="Address of an existing Dask scheduler (default: a local cluster)."
    ),
    workers: int | None = typer.Option(None, "--workers", "-w", help="Local cluster size (default: one per core)."),
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
    with CellProgress(quiet) as progress:
        report = run_matrix(m, out, scheduler, workers, keep_sequences, on_start=progress.start, on_cell=progress.cell)
    if report.reused and not report.computed and not report.interrupted:
        typer.echo(f"all {len(report.reused)} cells were finished already (delete DIR/cells/<cell> to run one again)")
    elif report.reused:
        typer.echo(f"kept {len(report.reused)} finished cells; ran {len(report.computed)} on {where}")
    print_matrix(report.rows, m.groups)
    typer.echo(f"wrote {out / 'matrix.csv'} and {out / 'matrix.md'}")
    if report.interrupted:
        typer.echo("interrupted: the finished cells are kept; run the same command again to resume", err=True)
        raise typer.Exit(130)
    if report.failed:
        typer.echo(
            f"{len(report.failed)} of {len(report.rows)} cells failed (see {out / 'cells'}/<cell>/error.log)", err=True
        )
        raise typer.Exit(report.exit_code)  # 2: every failed cell had bad input; 1: a bug
