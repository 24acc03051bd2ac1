"""The ``rovslam`` command. Parses, calls the library, prints. Heavy imports stay inside commands.

Exit codes: 0 success; 2 bad input, an unusable run or an unusable output place (one line on
stderr naming the problem, never a traceback); 128 + the signal number when a run is stopped
by SIGINT (130), SIGTERM (143) or SIGHUP (129), its files complete; 1 an internal error (a
bug: one line, the traceback with ``ROVSLAM_TRACEBACK=1``). Messages are printed as plain
text, never interpreted as rich markup (``[camera]`` stays as it is).
"""

from __future__ import annotations

import math
import os
import re
import sys
from pathlib import Path
from typing import NoReturn, Optional

import typer

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Vision-based SLAM for ROVs: laser altimeter, optical-correlation speed, EKF landmark map.",
    pretty_exceptions_enable=False,
)


def _error_line(message: str, prefix: str = "rovslam: error: ") -> None:
    """Print ``prefix`` + ``message`` on one line of stderr, the message as plain text (no markup)."""
    from rich.console import Console
    from rich.text import Text

    line = re.sub(r"\s*[\r\n]+\s*", " ", str(message)).strip()
    try:
        Console(stderr=True, highlight=False, soft_wrap=True).print(Text.assemble((prefix, "bold red"), line))
    except OSError:  # stderr gone (a closed terminal): nothing left to tell
        pass


def _fail(message: str, code: int = 2) -> NoReturn:
    _error_line(message)
    raise typer.Exit(code)


def _guard(fn):
    """Turn every error into one line on stderr and an exit code: 2 for bad input, 1 for a bug."""
    import functools

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from rovslam.errors import RovslamError

        try:
            return fn(*args, **kwargs)
        except (typer.Exit, typer.Abort, typer.TyperException):
            raise
        except RovslamError as exc:
            _fail(str(exc))
        except KeyboardInterrupt:
            _fail("interrupted", 130)
        except OSError as exc:
            from rovslam.io.results import describe_os_error

            where = f"{exc.filename}: " if exc.filename else ""
            _fail(f"{where}{describe_os_error(exc)}")
        except Exception as exc:
            if os.environ.get("ROVSLAM_TRACEBACK"):
                raise
            _fail(
                f"internal error ({type(exc).__name__}: {exc}). This is a bug: please report it with the command "
                "line; ROVSLAM_TRACEBACK=1 shows the traceback.",
                1,
            )

    return wrapper


def _version(value: bool) -> None:
    if value:
        from rovslam import __version__

        typer.echo(f"rovslam {__version__}")
        raise typer.Exit()


@app.callback()
def _main_options(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """Vision-based SLAM for ROVs: laser altimeter, optical-correlation speed, EKF landmark map."""


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
    calibration_errors: bool = typer.Option(
        False, "--calibration-errors",
        help="Draw the seed's lasting sensor errors (compass deviation 0.5 deg, laser-rig baseline 0.76 %, sonar offset "
             "1 cm, one sigma) and record them in sequence.toml; default: exact sensors."),
    list_scenarios: bool = typer.Option(False, "--list", help="List the scenarios and exit."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar."),
) -> None:
    """Simulate an ROV dive over a seabed and write a sequence folder with exact ground truth."""
    from rovslam.errors import SimulationError
    from rovslam.sim import SCENARIOS, CalibrationErrors, simulate as run_sim

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
            calibration=CalibrationErrors() if calibration_errors else None,
        )
    typer.echo(f"wrote {out} ({_describe(summary)})")
    d = summary.calibration
    if d is not None:
        typer.echo(f"calibration errors of seed {seed}: compass {math.degrees(d.compass_deviation_rad):+.2f} deg, "
                   f"laser rig {100 * d.laser_baseline_error:+.2f} %, sonar {100 * d.sonar_offset_m:+.2f} cm "
                   "(sequence.toml [metadata])")


def _h(text: str) -> str:
    """Help text shown as written: rich would take ``[camera]`` for markup and drop it."""
    return text.replace("[", "\\[")


_IN = "Inputs: video, image folder, navigation log (README, 'Real dives in')"
_BAG = "Inputs: ROS bags (ROS 1 .bag, ROS 2 sqlite3 or MCAP folder)"
_CAMERA_OPT = typer.Option(None, "--camera", help=_h("Camera file of a video, image folder or bag: [camera], optional [[laser]], "
                           "[vehicle] altitude_m and [nav] (the columns of --nav)."), rich_help_panel=_IN)
_NAV_OPT = typer.Option(None, "--nav", help="Navigation log (CSV): heading or a quaternion, roll, pitch, altitude by time, "
                        "interpolated to each frame.", rich_help_panel=_IN)
_NAV_OFFSET_OPT = typer.Option(None, "--nav-time-offset", help=_h("The navigation clock's time at the first frame (s): a row at "
                               "time T belongs to the frame at T - S (overrides [nav] time_offset_s)."), rich_help_panel=_IN)
_NAV_MAP_OPT = typer.Option(None, "--nav-map", help=_h("KEY=VALUE of the [nav] table, e.g. time=ts, heading=hdg, angle_unit=deg, "
                            "altitude=alt_m, quaternion=qx,qy,qz,qw (repeatable; overrides the camera file)."), rich_help_panel=_IN)
_FPS_OPT = typer.Option(None, "--fps", help="Frame rate of a folder of images (frame k at k / F s).", rich_help_panel=_IN)
_TIMES_OPT = typer.Option(None, "--times", help="CSV image,t_s giving the time of each image of a folder.", rich_help_panel=_IN)
_IMAGE_TOPIC_OPT = typer.Option(None, "--image-topic", help="sensor_msgs/Image or CompressedImage topic.", rich_help_panel=_BAG)
_HEADING_TOPIC_OPT = typer.Option(None, "--heading-topic", help="sensor_msgs/Imu, nav_msgs/Odometry or std_msgs/Float64 topic.",
                                  rich_help_panel=_BAG)
_ALTITUDE_TOPIC_OPT = typer.Option(None, "--altitude-topic", help="sensor_msgs/Range or std_msgs/Float64 (m) topic.",
                                   rich_help_panel=_BAG)
_ATTITUDE_TOPIC_OPT = typer.Option(None, "--attitude-topic", help="sensor_msgs/Imu or nav_msgs/Odometry topic for roll and pitch.",
                                   rich_help_panel=_BAG)
_CAMERA_INFO_OPT = typer.Option(None, "--camera-info-topic", help=_h("sensor_msgs/CameraInfo topic (replaces [camera]'s K and "
                                "distortion)."), rich_help_panel=_BAG)
_HEADING_CONV_OPT = typer.Option("enu", "--heading-convention", help="Orientation topics: enu (ROS, REP 103) or ned.",
                                 rich_help_panel=_BAG)
_HEADING_DEG_OPT = typer.Option(False, "--heading-degrees", help="A std_msgs/Float64 heading topic is in degrees.",
                                rich_help_panel=_BAG)


_INPUT_PARAMS = {  # name -> (type, option): the input options of `run` and `import`
    "camera": (Optional[Path], _CAMERA_OPT),
    "nav": (Optional[Path], _NAV_OPT),
    "nav_time_offset": (Optional[float], _NAV_OFFSET_OPT),
    "nav_map": (Optional[list[str]], _NAV_MAP_OPT),
    "fps": (Optional[float], _FPS_OPT),
    "times": (Optional[Path], _TIMES_OPT),
    "image_topic": (Optional[str], _IMAGE_TOPIC_OPT),
    "heading_topic": (Optional[str], _HEADING_TOPIC_OPT),
    "altitude_topic": (Optional[str], _ALTITUDE_TOPIC_OPT),
    "attitude_topic": (Optional[str], _ATTITUDE_TOPIC_OPT),
    "camera_info_topic": (Optional[str], _CAMERA_INFO_OPT),
    "heading_convention": (str, _HEADING_CONV_OPT),
    "heading_degrees": (bool, _HEADING_DEG_OPT),
}


def _with_inputs(fn):
    """Give a command the input options of `run` (camera file, navigation log, times, topics) as one
    ``inputs: InputOptions`` argument, checked; the command's own signature names it last."""
    import functools
    import inspect

    sig = inspect.signature(fn)
    own = [prm for prm in sig.parameters.values() if prm.name != "inputs"]
    added = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=opt, annotation=kind)
             for name, (kind, opt) in _INPUT_PARAMS.items()]

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        values = {name: kwargs.pop(name) for name in _INPUT_PARAMS}
        return fn(*args, inputs=_input_options(**values), **kwargs)

    wrapper.__signature__ = sig.replace(parameters=[*own, *added])  # type: ignore[attr-defined]
    return wrapper


def _input_options(camera, nav, nav_time_offset, nav_map, fps, times, image_topic, heading_topic, altitude_topic,
                   attitude_topic, camera_info_topic, heading_convention, heading_degrees):
    """The input options as one :class:`rovslam.io.source.InputOptions`, checked."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.io.source import InputOptions

    pairs = []
    for item in nav_map or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise InvalidArgumentError(f"--nav-map takes KEY=VALUE (a key of the [nav] table), got {item!r}")
        pairs.append((key.strip(), value))
    if heading_convention not in ("enu", "ned"):
        raise InvalidArgumentError(f"--heading-convention must be enu or ned, got {heading_convention!r}")
    if nav_time_offset is not None and nav_time_offset != nav_time_offset:
        raise InvalidArgumentError("--nav-time-offset must be a number of seconds, got nan")
    return InputOptions(
        camera_file=camera, nav_file=nav, nav_map=tuple(pairs), nav_time_offset_s=nav_time_offset, fps=fps,
        times_file=times, image_topic=image_topic, heading_topic=heading_topic, altitude_topic=altitude_topic,
        attitude_topic=attitude_topic, camera_info_topic=camera_info_topic, heading_convention=heading_convention,
        heading_degrees=heading_degrees,
    )


@app.command()
@_guard
@_with_inputs
def run(
    sequence: Path = typer.Argument(..., help="Sequence folder (format v1), a video, a folder of images or a ROS bag."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the results (new or empty, or see --overwrite)."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="TOML configuration (defaults: the paper's)."),
    max_frames: Optional[int] = typer.Option(None, help="Process only the first N frames (N >= 1)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the results of an earlier run in --out (only rovslam's own files)."),
    min_usable_fraction: Optional[float] = typer.Option(
        None, help=_h("Fail (exit 2) when fewer than this fraction of the frames were usable (0 to 1; default [run] of the config, 0.5).")
    ),
    max_distance_m: Optional[float] = typer.Option(
        None, help=_h("Fail (exit 2) when the estimate goes farther than this from the start: it diverged (default [run], 1000 m).")
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
    viewer: bool = typer.Option(False, "--viewer", help="Show the run live in the rerun viewer (saved to OUT/run.rrd without a display)."),
    save_rrd: Optional[Path] = typer.Option(None, "--save-rrd", help="Save the live view as a rerun recording (.rrd)."),
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
    cfg = _load_config(config) if config is not None else RunConfig()
    min_usable_fraction = cfg.run.min_usable_fraction if min_usable_fraction is None else min_usable_fraction
    max_distance_m = cfg.run.max_distance_m if max_distance_m is None else max_distance_m
    _quiet_native_logs()
    live = _live_viewer(viewer, save_rrd, out) if viewer or save_rrd is not None else None
    try:
        # The outer StopRequest catches a signal that comes after the run's own handlers are gone; once a
        # run was stopped, the process ignores further signals until it exits (nothing can be cut short).
        with StopRequest() as late, _progress(quiet, "SLAM", extra=True) as bar:
            summary = run_sequence(
                sequence, out, cfg, max_frames=max_frames, inputs=inputs, overwrite=overwrite,
                min_usable_fraction=min_usable_fraction, max_distance_m=max_distance_m, on_frame_image=live,
                **_slam_callbacks(bar),
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
        _error_line(f"{msg}; every file written is complete and readable", f"rovslam: stopped by {summary.signal}: ")
        raise typer.Exit(summary.exit_code)
    _report_run(summary)
    typer.echo(msg)
    if late.signum is not None:  # a signal just as the run completed: the files are whole, the exit says it
        raise typer.Exit(128 + late.signum)


@app.command(name="import")
@_guard
@_with_inputs
def import_cmd(
    source: Path = typer.Argument(..., help="A video, a folder of images or a ROS bag (with the options that open it)."),
    out: Path = typer.Option(..., "--out", "-o", help="Sequence folder to write (new or empty)."),
    image_format: str = typer.Option("png", "--format", help="png (lossless) or jpg."),
    max_frames: Optional[int] = typer.Option(None, help="Import only the first N frames (N >= 1)."),
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
    _quiet_native_logs()
    src = open_source(source, options=inputs)
    with StopRequest() as stop, _progress(quiet, "import") as bar:
        summary = import_source(src, out, describe_source(src), inputs.to_dict(), image_format, max_frames,
                                on_frame=(lambda d, n: bar(d, n or None)) if bar else None,
                                should_stop=lambda: stop.signum is not None)
        stop.ignore_after = summary.stopped
    for note in summary.warnings:
        typer.echo(f"warning: {note}", err=True)
    msg = f"wrote {out} ({summary.frames} frames" + (f", {summary.unreadable} unreadable left out" if summary.unreadable else "") + ")"
    if summary.stopped:
        _error_line(f"{msg}; the frames written form a readable sequence", f"rovslam: stopped by {stop.name}: ")
        raise typer.Exit(128 + int(stop.signum))
    typer.echo(msg)


@app.command()
@_guard
def topics(
    bag: Path = typer.Argument(..., help="A ROS 1 .bag file or a ROS 2 bag folder (sqlite3 or MCAP, with metadata.yaml)."),
) -> None:
    """List a bag's topics: type, message count, mean rate, and the `rovslam run` option that takes each."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from rovslam.io.bag import list_topics

    kind, path, rows = list_topics(bag)
    t = Table(title=escape(f"{path} ({kind})"))
    widths = {"topic": max([5] + [len(r.topic) for r in rows]), "type": max([4] + [len(r.msgtype) for r in rows])}
    for col, just in (("topic", "left"), ("type", "left"), ("messages", "right"), ("rate [Hz]", "right"),
                      ("option of rovslam run", "left")):
        t.add_column(escape(col), justify=just, overflow="fold", min_width=widths.get(col))  # type: ignore[arg-type]
    for r in rows:
        rate = f"{r.rate_hz:.2f}" if r.rate_hz is not None else "-"
        t.add_row(escape(r.topic), escape(r.msgtype), str(r.count), rate, r.role)
    Console(highlight=False).print(t)


def _quiet_native_logs() -> None:
    """Silence OpenCV's own stderr log (a damaged PNG is reported once, in rovslam's words)."""
    import cv2.utils.logging as cv_log

    cv_log.setLogLevel(cv_log.LOG_LEVEL_SILENT)


def _report_run(summary) -> None:
    """Skipped frames, rejected sonar readings and damaged-source notes on stderr (a few, then a count)."""
    for label, items in (("skipped frame", summary.skipped), ("sonar reading rejected, frame", summary.sonar_rejected)):
        for idx, t, reason in items[:10]:
            typer.echo(f"{label} {idx} (t={t:.2f} s): {reason}", err=True)
        if len(items) > 10:
            typer.echo(f"... and {len(items) - 10} more ({label.split(',')[0]}s: see summary.json)", err=True)
    for note in summary.warnings:
        typer.echo(f"warning: {note}", err=True)


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
    if json_out is not None:
        _check_output_file(json_out, "--json")
    path = json_out or (results / "eval.json")
    _check_sequence_of_run(results, sequence, "--sequence")
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
    from rovslam.runner import StopRequest, run_sequence
    from rovslam.sim import simulate as run_sim
    from rovslam.viz.report import write_report

    seq, res = out / "sequence", out / "results"
    if _same_simulation(seq, scenario, frames, seed):
        typer.echo(f"reusing the simulated sequence in {seq}")
    else:
        if seq.exists():
            import shutil

            from rovslam.errors import OutputError

            if not _is_simulated_sequence(seq):
                raise OutputError(f"{seq}: exists and is not a sequence rovslam simulated; give the demo another --out.")
            shutil.rmtree(seq)  # the demo's own folder, from another scenario or seed
        with _progress(quiet, "simulating") as bar:
            run_sim(scenario, seq, frames=frames, seed=seed, progress=bar)
    _quiet_native_logs()
    with StopRequest() as late, _progress(quiet, "SLAM", extra=True) as bar:
        summary = run_sequence(seq, res, overwrite=True, **_slam_callbacks(bar))
        late.ignore_after = summary.interrupted
    if summary.interrupted:
        _fail(f"stopped by {summary.signal}; partial results are in {res}", summary.exit_code)
    _evaluate(res, seq / "groundtruth.csv", res / "eval.json", seq)
    report = write_report(res, seq / "groundtruth.csv")
    typer.echo(f"{summary.frames} frames at {summary.fps:.0f} frames/s; results in {res}")
    typer.echo(f"report: {report}")


def _live_viewer(spawn: bool, save_rrd: Optional[Path], out: Path):
    """The rerun live viewer of `run --viewer / --save-rrd` (rerun is imported only here)."""
    from rovslam.viz.viewer import RerunViewer, display_available

    if save_rrd is not None and save_rrd.is_dir():
        from rovslam.errors import OutputError

        raise OutputError(f"{save_rrd}: is a folder; --save-rrd needs a file name (e.g. {save_rrd / 'run.rrd'}).")
    if spawn and not display_available():
        typer.echo("no display found for the viewer: saving the live view instead", err=True)
        spawn = False
        save_rrd = save_rrd or out / "run.rrd"
    return RerunViewer(spawn=spawn, save_path=save_rrd)


def _landmark_ids(text: Optional[str]) -> Optional[list[int]]:
    if text is None:
        return None
    from rovslam.errors import InvalidArgumentError

    try:
        ids = [int(t) for t in text.replace(" ", "").split(",") if t]
    except ValueError:
        raise InvalidArgumentError(f"--landmarks takes landmark ids separated by commas (e.g. 0,3,7), got {text!r}") from None
    if not ids or min(ids) < 0:
        raise InvalidArgumentError(f"--landmarks takes landmark ids >= 0 separated by commas, got {text!r}")
    return list(dict.fromkeys(ids))  # each once, in the order given: an id repeated is one figure


@app.command()
@_guard
def report(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    groundtruth: Optional[Path] = typer.Option(None, "--groundtruth", "-g", help="groundtruth.csv, if known."),
    seq: Optional[Path] = typer.Option(None, "--seq", help="The run's sequence folder or video, if it moved (default: the one summary.json names)."),
    camera: Optional[Path] = typer.Option(None, "--camera", help="Camera file of a video run (default: the one summary.json names)."),
    landmarks: Optional[str] = typer.Option(None, "--landmarks", help="Landmark ids for Figures 5 and 6, e.g. 0,3,7 (default: 0 and the two most revisited)."),
    mosaic: bool = typer.Option(True, "--mosaic/--no-mosaic", help="Include the seabed mosaic (estimate, and truth when given)."),
    mosaic_every: Optional[int] = typer.Option(None, "--mosaic-every", help="Lay every k-th frame in the mosaic (default: about 1,500 frames)."),
    open_browser: bool = typer.Option(False, "--open", help="Open the report in the web browser."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """One self-contained HTML report: Figures 2 to 6, Table 1, the mosaic and the configuration."""
    from rovslam.errors import InvalidArgumentError
    from rovslam.viz.report import write_report

    if mosaic_every is not None and mosaic_every < 1:
        raise InvalidArgumentError(f"--mosaic-every must be a whole number >= 1, got {mosaic_every}")
    _check_sequence_of_run(results, seq, "--seq")
    with _progress(quiet, "mosaic") as bar:
        path = write_report(results, groundtruth, seq=seq, landmarks=_landmark_ids(landmarks), mosaic=mosaic,
                            mosaic_every=mosaic_every, progress=(lambda d, n: bar(d, n)) if bar else None,
                            camera_file=camera)
    typer.echo(f"wrote {path}")
    if open_browser:
        import webbrowser

        webbrowser.open(path.resolve().as_uri())


@app.command(name="mosaic")
@_guard
def mosaic_cmd(
    results: Path = typer.Argument(..., help="The --out folder of `rovslam run`."),
    seq: Optional[Path] = typer.Option(None, "--seq", help="The run's sequence folder or video, if it moved."),
    camera: Optional[Path] = typer.Option(None, "--camera", help="Camera file of a video run (default: the one summary.json names)."),
    mm_per_px: Optional[float] = typer.Option(None, "--mm-per-px", help="Mosaic scale (default: the camera's ground resolution)."),
    every: int = typer.Option(1, "--every", help="Lay every k-th frame."),
    groundtruth: Optional[Path] = typer.Option(None, "--groundtruth", "-g", help="Lay the frames by this groundtruth.csv instead of the estimate."),
    out_png: Optional[Path] = typer.Option(None, "--out", "-o", help="PNG to write (default OUT/mosaic.png, OUT/mosaic_truth.png with --groundtruth)."),
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
    _check_sequence_of_run(results, seq, "--seq")
    with _progress(quiet, "mosaic") as bar:
        m = mosaic_of_run(results, out_png, seq=seq, mm_per_px=mm_per_px, every=every, groundtruth=groundtruth,
                          overlay=overlay, progress=(lambda d, n: bar(d, n)) if bar else None, camera_file=camera)
    g = m.mosaic.grid
    typer.echo(f"wrote {m.png} ({g.width_px}x{g.height_px} px, {g.mm_per_px:g} mm/px, {m.mosaic.frames_used} frames) "
               f"and {m.world_file}")


@app.command(name="config")
@_guard
def config_cmd(
    out: Path = typer.Argument(..., help="TOML file to write with every default."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the file if it exists."),
) -> None:
    """Write the default configuration (the paper's values) to a TOML file to edit."""
    import tomli_w

    from rovslam.config import RunConfig, to_dict
    from rovslam.errors import OutputError
    from rovslam.io.results import atomic_write_text

    _check_output_file(out, "the configuration file")
    if out.exists() and not overwrite:
        raise OutputError(f"{out}: exists; add --overwrite to replace it, or give another name.")
    atomic_write_text(out, tomli_w.dumps(to_dict(RunConfig())))
    typer.echo(f"wrote {out}")


def _check_output_file(path: Path, what: str) -> None:
    """Refuse an output file path that is a folder or whose folder does not exist (one clear line)."""
    from rovslam.errors import OutputError

    if path.is_dir():
        raise OutputError(f"{path}: is a folder; {what} needs a file name (e.g. {path / 'eval.json'}).")
    parent = path.parent
    if not parent.is_dir():
        state = "is not a folder" if parent.exists() else "does not exist"
        raise OutputError(f"{path}: the folder {parent} {state}; create it or choose another place for {what}.")


def _load_config(path: Path):
    """:func:`rovslam.config.load_config`, with a folder given to -c told so (it said "not found")."""
    from rovslam.config import load_config
    from rovslam.errors import ConfigError

    if path.is_dir():
        raise ConfigError(f"{path}: is a folder; -c needs a TOML file (`rovslam config FILE.toml` writes one to edit).")
    return load_config(path)


def _check_sequence_of_run(results: Path, seq: Optional[Path], option: str) -> None:
    """Refuse a --seq / --sequence that is clearly another dive's (name or frame count unlike summary.json's)."""
    if seq is not None:
        from rovslam.io.results import check_sequence_of_run

        check_sequence_of_run(results, seq, option)


def _is_simulated_sequence(seq: Path) -> bool:
    """Whether ``seq`` is a sequence folder rovslam's simulator wrote (so the demo may replace it)."""
    import tomllib

    from rovslam.errors import parse_toml

    try:
        meta = parse_toml((seq / "sequence.toml").read_text(encoding="utf-8")).get("metadata", {})
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return isinstance(meta, dict) and meta.get("generator") == "rovslam.sim"


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
    from rovslam.io.results import atomic_write_text, json_text

    figures = evaluate_run(results, groundtruth, sequence)
    atomic_write_text(json_path, json_text(figures.to_dict()) + "\n")  # strict JSON: a figure that cannot be computed is null
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

        cols = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[fps]:>6.0f} frames/s")]
        if self.extra:
            cols.append(TextColumn("landmarks {task.fields[landmarks]}  tokens {task.fields[tokens]}"))
        cols.append(TimeRemainingColumn())
        progress = Progress(*cols, console=Console(stderr=True), transient=False)
        progress.start()
        self._p = progress
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
            try:
                if self._final is not None:  # the last update may have been throttled
                    done, fields = self._final
                    self._last = 0.0
                    self._p.update(self._task, completed=done, **fields)
                self._p.stop()
            except OSError:  # the terminal is gone: nothing left to show
                pass


def _print_eval(f) -> None:
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
    t.add_row("... in sigmas of the ellipse before",
              *(jump(c.max_error_jump_before_sigma, c.max_error_jump_before_t_s) for c in cons), *pad)
    if f.speed is not None:
        sp = f.speed
        t.add_row("speed NEES mean (2 dof, per step)", f"{sp.nees_mean:.2f} over {sp.steps} steps", *[""] * (len(runs) - 1))
        t.add_row("speed error / claimed sigma (RMS)",
                  " ".join(f"{1e3 * e:.2f}/{1e3 * s:.2f}" for e, s in zip(sp.rms_error_mps, sp.rms_sigma_mps)) + " mm/s",
                  *[""] * (len(runs) - 1))
    t.add_row("skipped frames", str(f.skipped_frames), *[""] * (len(runs) - 1))
    console.print(t)
    for note in f.notes:
        console.print(f"n/a: {note}", markup=False, highlight=False)
    if f.groundtruth_shift_m != (0.0, 0.0):
        dx, dy = f.groundtruth_shift_m
        console.print(f"note: the ground truth's first row is at x = {-dx:.3f} m, y = {-dy:.3f} m, not at the origin where "
                      f"the run starts: it was shifted by ({dx:+.3f}, {dy:+.3f}) m to start there", markup=False, highlight=False)
    if f.partial_run is not None:
        console.print(f"note: {f.partial_run}", markup=False, highlight=False)
    if f.run_frame_turn_rad != 0.0:
        console.print(f"note: no compass in this run: its frame is its first heading; the ground truth was turned "
                      f"by {math.degrees(f.run_frame_turn_rad):+.2f} deg into it", markup=False, highlight=False)
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


@app.command()
@_guard
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
        with _progress(quiet, "smoothing") as bar:
            callbacks = {} if bar is None else {
                "on_start": lambda n: bar(0, n), "on_frame": lambda n: bar(n, None)}
            summary = smooth_run(results, cfg, **callbacks)
    except KeyboardInterrupt:
        typer.echo("interrupted: nothing written (the measurement files are untouched)", err=True)
        raise typer.Exit(130) from None
    typer.echo(
        f"{summary.frames} frames, {summary.landmarks} landmarks, {summary.observations} observations "
        f"({summary.downweighted} down-weighted); incremental pass {summary.online_s:.1f} s, "
        f"final smoothing {summary.final_s:.1f} s -> {results}/trajectory_smoothed.csv"
    )


@app.command()
@_guard
def navigate(
    scenario: str = typer.Option(..., "--scenario", help="Simulator preset (rovslam simulate --list), e.g. portofino-relief."),
    poi: Path = typer.Option(..., "--poi", help="Points of interest, CSV: name,x_m,y_m[,hold_s] or name,landmark_id[,hold_s]."),
    out: Path = typer.Option(..., "--out", "-o", help="Folder for the results (new or empty, or see --overwrite)."),
    estimator: str = typer.Option("slam", help="What the controller steers by: slam or dead-reckoning."),
    survey_s: float = typer.Option(0.0, "--survey-s", help="Fly a lawnmower survey this long first, to build the map (s)."),
    hold_s: float = typer.Option(10.0, "--hold-s", help="Station keeping at each point, unless its hold_s says otherwise (s)."),
    seed: int = typer.Option(0, help="Random seed of the seabed, the current and the sensors."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="TOML configuration of the pipeline."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the results of an earlier run in --out."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress display."),
) -> None:
    """Closed loop in the simulator: survey, then visit the points of interest steered by the online estimate.

    Writes the usual results plus arrivals.csv (true and estimated error at each point),
    navigation.csv, groundtruth.csv and navigation.png. Ctrl-C keeps what is written.
    """
    from rovslam.config import RunConfig
    from rovslam.errors import InvalidArgumentError
    from rovslam.io.poi import read_poi_csv
    from rovslam.nav.estimate import check_estimator
    from rovslam.navigate import navigate as fly
    from rovslam.runner import StopRequest
    from rovslam.sim import SCENARIOS

    if scenario not in SCENARIOS:
        raise InvalidArgumentError(f"--scenario: unknown preset {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
    check_estimator(estimator)
    for name, v in (("--survey-s", survey_s), ("--hold-s", hold_s)):
        if not (v >= 0 and v != float("inf")):
            raise InvalidArgumentError(f"{name} must be a number of seconds >= 0, got {v}")
    if seed < 0:
        raise InvalidArgumentError(f"--seed must be a whole number >= 0, got {seed}")
    pois = read_poi_csv(poi)
    cfg = _load_config(config) if config is not None else RunConfig()
    rate = SCENARIOS[scenario].frame_rate_hz
    _quiet_native_logs()
    with StopRequest() as late, _progress(quiet, f"navigate ({estimator})", extra=True) as bar:
        callbacks = {} if bar is None else {
            "on_start": lambda s: bar(0, int(s * rate)),
            "on_step": lambda st, done: bar(st.k + 1, None, landmarks=st.nav.result.n_landmarks,
                                            tokens=f"{st.nav.result.tokens_tracked}  points {done}/{len(pois)}"),
        }
        summary = fly(scenario, pois, out, estimator, survey_s, hold_s, seed, cfg, overwrite=overwrite, **callbacks)
        late.ignore_after = summary.status == "interrupted"
    rows = summary.arrivals
    errs = [r["true_err_m"] for r in rows if r["reached"]]
    msg = (f"{summary.frames} frames, {summary.landmarks} landmarks, {len(errs)}/{len(pois)} points reached"
           + (f", true arrival error mean {1e3 * sum(errs) / len(errs):.1f} mm, worst {1e3 * max(errs):.1f} mm"
              if errs else "") + f" -> {out}")
    if summary.status == "interrupted":
        _error_line(f"{msg}; every file written is complete and readable", f"rovslam: stopped by {summary.signal}: ")
        raise typer.Exit(summary.exit_code)
    typer.echo(msg)
    if summary.status != "complete":
        _fail(f"not every point was reached (see {out / 'arrivals.csv'})")


app.command(name="live")(_guard(__import__("rovslam.live.command", fromlist=["live"]).live))  # rovslam live (typer only at import)


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


app.command(name="sitl")(_guard(__import__("runpy").run_path(str(Path(__import__("rovslam").__file__).parent / "sim" / "sitl_command.py"))["sitl"]))  # by path: importing rovslam.sim takes seconds


def main() -> None:
    """The console script: like ``app()``, but a command-line usage error is one line too."""
    from typer.main import get_command

    try:
        code = get_command(app).main(prog_name="rovslam", standalone_mode=False)
    except typer.TyperException as exc:
        fmt = getattr(exc, "format_message", None)
        ctx = getattr(exc, "ctx", None)
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        _error_line(f"{fmt() if fmt else exc}{hint}")
        code = getattr(exc, "exit_code", 2)
    except typer.Abort:
        code = 130
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main()
