"""``rovslam run`` (SLAM on a sequence, video, image folder or bag), ``rovslam import`` (any of those as a
sequence folder) and ``rovslam topics`` (what a bag holds)."""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.checks import load_config
from rovslam.cli.display import ProgressBar, plain_help, quiet_native_logs, slam_callbacks
from rovslam.cli.errors import error_line, guard
from rovslam.cli.inputs import with_inputs


@app.command()
@guard
@with_inputs
def run(
    sequence: Path = typer.Argument(..., help="Sequence folder (format v1), a video, a folder of images or a ROS bag."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the results (new or empty, or see --overwrite)."),
    config: Path | None = typer.Option(None, "--config", "-c", help="TOML configuration (defaults: the paper's)."),
    max_frames: int | None = typer.Option(None, help="Process only the first N frames (N >= 1)."),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Replace the results of an earlier run in --out (only rovslam's own files)."
    ),
    min_usable_fraction: float | None = typer.Option(
        None,
        help=plain_help(
            "Fail (exit 2) when fewer than this fraction of the frames were usable (0 to 1; "
            "default [run] of the config, 0.5)."
        ),
    ),
    max_distance_m: float | None = typer.Option(
        None,
        help=plain_help(
            "Fail (exit 2) when the estimate goes farther than this from the start: it diverged "
            "(default [run], 1000 m)."
        ),
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
    viewer: bool = typer.Option(
        False, "--viewer", help="Show the run live in the rerun viewer (saved to OUT/run.rrd without a display)."
    ),
    save_rrd: Path | None = typer.Option(None, "--save-rrd", help="Save the live view as a rerun recording (.rrd)."),
    inputs=None,
) -> None:
    """Run vision-based SLAM on a sequence folder, a video, a ROS bag or a folder of images: trajectory with
    covariance, landmark map, summary (with where the altitude and the heading came from)."""
    from rovslam.config import RunConfig
    from rovslam.errors import InvalidArgumentError
    from rovslam.runner import StopRequest, run_sequence

    if max_frames is not None and max_frames < 1:
        raise InvalidArgumentError(f"--max-frames must be a whole number of frames >= 1, got {max_frames}")
    if min_usable_fraction is not None and not 0.0 <= min_usable_fraction <= 1.0:
        raise InvalidArgumentError(f"--min-usable-fraction must be from 0 to 1, got {min_usable_fraction}")
    if max_distance_m is not None and not (max_distance_m > 0 and max_distance_m != float("inf")):
        raise InvalidArgumentError(f"--max-distance-m must be a positive number of metres, got {max_distance_m}")
    cfg = load_config(config) if config is not None else RunConfig()
    min_usable_fraction = cfg.run.min_usable_fraction if min_usable_fraction is None else min_usable_fraction
    max_distance_m = cfg.run.max_distance_m if max_distance_m is None else max_distance_m
    quiet_native_logs()
    live = _live_viewer(viewer, save_rrd, out) if viewer or save_rrd is not None else None
    try:
        # The outer StopRequest catches a signal that comes after the run's own handlers are gone; once a
        # run was stopped, the process ignores further signals until it exits (nothing can be cut short).
        with StopRequest() as late, ProgressBar(quiet, "SLAM", extra=True) as bar:
            summary = run_sequence(
                sequence,
                out,
                cfg,
                max_frames=max_frames,
                inputs=inputs,
                overwrite=overwrite,
                min_usable_fraction=min_usable_fraction,
                max_distance_m=max_distance_m,
                on_frame_image=live,
                **slam_callbacks(bar),
            )
            late.ignore_after = summary.interrupted
    finally:
        if live is not None:
            live.close()
            if live.save_path is not None and live.started:
                typer.echo(f"live view saved to {live.save_path} (open it with: rerun {live.save_path})", err=True)
    msg = (
        f"{summary.frames}/{summary.total_frames} frames, {summary.landmarks} landmarks, "
        f"{len(summary.skipped)} skipped, {summary.fps:.0f} frames/s -> {out}"
    )
    if summary.interrupted:
        error_line(f"{msg}; every file written is complete and readable", f"rovslam: stopped by {summary.signal}: ")
        raise typer.Exit(summary.exit_code)
    _report_run(summary)
    typer.echo(msg)
    if late.signum is not None:  # a signal just as the run completed: the files are whole, the exit says it
        raise typer.Exit(128 + late.signum)


@app.command(name="import")
@guard
@with_inputs
def import_cmd(
    source: Path = typer.Argument(
        ..., help="A video, a folder of images or a ROS bag (with the options that open it)."
    ),
    out: Path = typer.Option(..., "--out", "-o", help="Sequence folder to write (new or empty)."),
    image_format: str = typer.Option("png", "--format", help="png (lossless) or jpg."),
    max_frames: int | None = typer.Option(None, help="Import only the first N frames (N >= 1)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
    inputs=None,
) -> None:
    """Write a video, an image folder or a ROS bag, with its navigation, as a sequence folder (format v1)."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.io.importer import check_import_folder, import_source
    from rovslam.runner import StopRequest, describe_source, open_source

    if image_format not in ("png", "jpg"):
        raise InvalidArgumentError(f"--format must be png or jpg, got {image_format!r}")
    if max_frames is not None and max_frames < 1:
        raise InvalidArgumentError(f"--max-frames must be a whole number of frames >= 1, got {max_frames}")
    check_import_folder(out)
    quiet_native_logs()
    src = open_source(source, options=inputs)
    with StopRequest() as stop, ProgressBar(quiet, "import") as bar:
        summary = import_source(
            src,
            out,
            describe_source(src),
            inputs.to_dict(),
            image_format,
            max_frames,
            on_frame=(lambda d, n: bar(d, n or None)) if bar else None,
            should_stop=lambda: stop.signum is not None,
        )
        stop.ignore_after = summary.stopped
    for note in summary.warnings:
        typer.echo(f"warning: {note}", err=True)
    msg = (
        f"wrote {out} ({summary.frames} frames"
        + (f", {summary.unreadable} unreadable left out" if summary.unreadable else "")
        + ")"
    )
    if summary.stopped:
        error_line(f"{msg}; the frames written form a readable sequence", f"rovslam: stopped by {stop.name}: ")
        raise typer.Exit(128 + int(stop.signum))  # type: ignore[arg-type]
    typer.echo(msg)


@app.command()
@guard
def topics(
    bag: Path = typer.Argument(
        ..., help="A ROS 1 .bag file or a ROS 2 bag folder (sqlite3 or MCAP, with metadata.yaml)."
    ),
) -> None:
    """List a bag's topics: type, message count, mean rate, and the `rovslam run` option that takes each."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from rovslam.io.bag import list_topics

    kind, path, rows = list_topics(bag)
    t = Table(title=escape(f"{path} ({kind})"))
    widths = {"topic": max([5] + [len(r.topic) for r in rows]), "type": max([4] + [len(r.msgtype) for r in rows])}
    for col, just in (
        ("topic", "left"),
        ("type", "left"),
        ("messages", "right"),
        ("rate [Hz]", "right"),
        ("option of rovslam run", "left"),
    ):
        t.add_column(escape(col), justify=just, overflow="fold", min_width=widths.get(col))  # type: ignore[arg-type]
    for r in rows:
        rate = f"{r.rate_hz:.2f}" if r.rate_hz is not None else "-"
        t.add_row(escape(r.topic), escape(r.msgtype), str(r.count), rate, r.role)
    Console(highlight=False).print(t)


def _report_run(summary) -> None:
    """Skipped frames, rejected sonar readings and damaged-source notes on stderr (a few, then a count)."""
    for label, items in (("skipped frame", summary.skipped), ("sonar reading rejected, frame", summary.sonar_rejected)):
        for idx, t, reason in items[:10]:
            typer.echo(f"{label} {idx} (t={t:.2f} s): {reason}", err=True)
        if len(items) > 10:
            typer.echo(f"... and {len(items) - 10} more ({label.split(',')[0]}s: see summary.json)", err=True)
    for note in summary.warnings:
        typer.echo(f"warning: {note}", err=True)
    note = assumed_altitude_note(summary.out_dir / "summary.json")
    if note:
        typer.echo(note, err=True)


def assumed_altitude_note(summary_json: Path) -> str | None:
    """One line when frames ran on an assumed altitude (no laser spot, no altimeter): the scale is a guess."""
    import json

    try:
        altitude = json.loads(summary_json.read_text(encoding="utf-8"))["sources"]["altitude"]
        frames = {str(k): int(v) for k, v in altitude["frames"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    assumed = sum(n for source, n in frames.items() if source.startswith(("assumed", "fixed")))
    if not assumed:
        return None
    detail = str(altitude.get("detail", "")).removeprefix("assumed constant: ")
    return (
        f"altitude: assumed on {assumed} of {sum(frames.values())} frames ({detail}): no laser spot and no "
        "altimeter, so the path's scale is only as good as that assumption"
    )


def _live_viewer(spawn: bool, save_rrd: Path | None, out: Path):
    """The rerun live viewer of `run --viewer / --save-rrd` (rerun is imported only here)."""
    from rovslam.viz.viewer import RerunViewer, display_available

    if save_rrd is not None:
        from rovslam.io.output import check_output_file

        check_output_file(save_rrd, "--save-rrd", parent_must_exist=False, example="run.rrd")
    if spawn and not display_available():
        typer.echo("no display found for the viewer: saving the live view instead", err=True)
        spawn = False
        save_rrd = save_rrd or out / "run.rrd"
    return RerunViewer(spawn=spawn, save_path=save_rrd)
