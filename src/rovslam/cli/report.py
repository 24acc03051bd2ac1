"""``rovslam report`` (the HTML report of a run) and ``rovslam mosaic`` (its frames laid on the seabed)."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import check_sequence_of_run
from rovslam.cli.display import ProgressBar
from rovslam.cli.errors import guard


@app.command()
@guard
def report(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Path | None = typer.Option(None, "--groundtruth", "-g", help="groundtruth.csv, if known."),
    seq: Path | None = typer.Option(
        None, "--seq", help="The run's sequence folder or video, if it moved (default: the one summary.json names)."
    ),
    camera: Path | None = typer.Option(
        None, "--camera", help="Camera file of a video run (default: the one summary.json names)."
    ),
    landmarks: str | None = typer.Option(
        None,
        "--landmarks",
        help="Landmark ids for Figures 5 and 6, e.g. 0,3,7 (default: 0 and the two most revisited).",
    ),
    mosaic: bool = typer.Option(
        True, "--mosaic/--no-mosaic", help="Include the seabed mosaic (estimate, and truth when given)."
    ),
    mosaic_every: int | None = typer.Option(
        None, "--mosaic-every", help="Lay every k-th frame in the mosaic (default: about 1,500 frames)."
    ),
    open_browser: bool = typer.Option(False, "--open", help="Open the report in the web browser."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """One self-contained HTML report: Figures 2 to 6, Table 1, the mosaic and the configuration."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.viz.report import write_report

    if mosaic_every is not None and mosaic_every < 1:
        raise InvalidArgumentError(f"--mosaic-every must be a whole number >= 1, got {mosaic_every}")
    check_sequence_of_run(results, seq, "--seq")
    with ProgressBar(quiet, "mosaic") as bar:
        path = write_report(
            results,
            groundtruth,
            seq=seq,
            landmarks=_landmark_ids(landmarks),
            mosaic=mosaic,
            mosaic_every=mosaic_every,
            progress=(lambda d, n: bar(d, n)) if bar else None,
            camera_file=camera,
        )
    typer.echo(f"wrote {path}")
    if open_browser:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())


@app.command(name="mosaic")
@guard
def mosaic_cmd(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    seq: Path | None = typer.Option(None, "--seq", help="The run's sequence folder or video, if it moved."),
    camera: Path | None = typer.Option(
        None, "--camera", help="Camera file of a video run (default: the one summary.json names)."
    ),
    mm_per_px: float | None = typer.Option(
        None, "--mm-per-px", help="Mosaic scale (default: the camera's ground resolution)."
    ),
    every: int = typer.Option(1, "--every", help="Lay every k-th frame."),
    groundtruth: Path | None = typer.Option(
        None, "--groundtruth", "-g", help="Lay the frames by this groundtruth.csv instead of the estimate."
    ),
    out_png: Path | None = typer.Option(
        None, "--out", "-o", help="PNG to write (default OUT/mosaic.png, OUT/mosaic_truth.png with --groundtruth)."
    ),
    overlay: bool = typer.Option(True, "--overlay/--no-overlay", help="Draw the path and the landmarks."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Lay the frames on the seabed by their poses: a north-up PNG with scale bar, north arrow and world file (.pgw)."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.viz.mosaic import mosaic_of_run

    if every < 1:
        raise InvalidArgumentError(f"--every must be a whole number >= 1, got {every}")
    if mm_per_px is not None and not (mm_per_px > 0):
        raise InvalidArgumentError(f"--mm-per-px must be a positive number, got {mm_per_px}")
    check_sequence_of_run(results, seq, "--seq")
    with ProgressBar(quiet, "mosaic") as bar:
        m = mosaic_of_run(
            results,
            out_png,
            seq=seq,
            mm_per_px=mm_per_px,
            every=every,
            groundtruth=groundtruth,
            overlay=overlay,
            progress=(lambda d, n: bar(d, n)) if bar else None,
            camera_file=camera,
        )
    g = m.mosaic.grid
    typer.echo(
        f"wrote {m.png} ({g.width_px}x{g.height_px} px, {g.mm_per_px:g} mm/px, {m.mosaic.frames_used} frames) "
        f"and {m.world_file}"
    )


def _landmark_ids(text: str | None) -> list[int] | None:
    """The ids of ``--landmarks 0,3,7``, each once in the order given; None when not given."""
    if text is None:
        return None
    from rovslam.errors import InvalidArgumentError

    try:
        ids = [int(t) for t in text.replace(" ", "").split(",") if t]
    except ValueError:
        raise InvalidArgumentError(
            f"--landmarks takes landmark ids separated by commas (e.g. 0,3,7), got {text!r}"
        ) from None
    if not ids or min(ids) < 0:
        raise InvalidArgumentError(f"--landmarks takes landmark ids >= 0 separated by commas, got {text!r}")
    return list(dict.fromkeys(ids))  # each once, in the order given: an id repeated is one figure
