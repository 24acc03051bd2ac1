"""The ``rovslam live`` command (typer only at import; PyAV, pymavlink and the pipeline inside)."""

from __future__ import annotations

from pathlib import Path

import typer

# The command's options (kept here so that its signature reads as a list of names).
_VIDEO_OPT = typer.Option(
    ...,
    "--video",
    help="udp://HOST:PORT (MPEG-TS), an .sdp file or rtp://HOST:PORT (RTP H.264, "
    "BlueOS: port 5600), rtsp://..., /dev/videoN, or a video file (with --realtime).",
)
_CAMERA_OPT = typer.Option(..., "--camera", help="Camera file of the vehicle's camera and lasers (CAMERA.toml).")
_MAVLINK_OPT = typer.Option(
    ...,
    "--mavlink",
    help="pymavlink connection: udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT, /dev/ttyACM0,115200.",
)
_OUT_OPT = typer.Option(..., "--out", "-o", help="Folder for the results (new or empty), written as the dive goes.")
_CONFIG_OPT = typer.Option(None, "--config", "-c", help="TOML configuration (defaults: the paper's).")
_RECORD_OPT = typer.Option(
    False,
    "--record",
    help="Also write the processed frames with their telemetry as "
    "OUT/sequence (rovslam run OUT/sequence reproduces the trajectory).",
)
_DURATION_S_OPT = typer.Option(None, "--duration-s", help="End the run this many seconds (wall clock) after it starts.")
_VIEWER_OPT = typer.Option(False, "--viewer", help="Show the run live in the rerun viewer.")
_QUIET_OPT = typer.Option(False, "--quiet", "-q", help="No status line (events are still said).")
_MAVLINK_OUT_OPT = typer.Option(
    None,
    "--mavlink-out",
    help="Messages to send, separated by commas: delta, position, speed, distance (default all), or none.",
)
_REALTIME_OPT = typer.Option(False, "--realtime", help="Play a video file at its own frame rate.")
_EVERY_FRAME_OPT = typer.Option(
    False, "--every-frame", help="Process every frame, none dropped, however late (tests, replays; not for a vehicle)."
)
_WAIT_S_OPT = typer.Option(30.0, "--wait-s", help="How long to wait for the video to start.")
_HEARTBEAT_TIMEOUT_S_OPT = typer.Option(
    30.0, "--heartbeat-timeout-s", help="How long to wait for the vehicle's HEARTBEAT."
)
_VIDEO_DELAY_S_OPT = typer.Option(
    0.0,
    "--video-delay-s",
    help="The camera's delay from capture to sending "
    "(its encoder): the telemetry is taken this much before a frame's arrival.",
)
_POI_OPT = typer.Option(
    None,
    "--poi",
    help="Points of interest to go to (CSV of rovslam navigate: "
    "name,x_m,y_m[,hold_s] or name,landmark_id[,hold_s]); without --guide a dry run.",
)
_APPROACH_GAIN_OPT = typer.Option(
    None,
    "--approach-gain-per-s",
    help="How hard --guide steers back to a point: the desired speed per metre off it "
    "(default 0.2; 0.3 holds closer and arrives sooner on a rough sea, see docs/navigation.md).",
)
_GUIDE_OPT = typer.Option(
    False, "--guide", help="Send the velocity setpoints to the autopilot (only while it is armed and in GUIDED)."
)
_SURVEY_S_OPT = typer.Option(0.0, "--survey-s", help="With --poi: a lawnmower survey this long first (s).")
_HOLD_S_OPT = typer.Option(10.0, "--hold-s", help="With --poi: station keeping at each point (s).")
_ESTIMATOR_OPT = typer.Option("slam", "--estimator", help="With --poi: what to steer by, slam or dead-reckoning.")
_GUIDE_PACE_OPT = typer.Option(
    1.0,
    "--guide-pace",
    help="With --poi: the vehicle's clock runs this many times "
    "slower than the wall (rovslam sitl --pace): the stop delays are stretched.",
)


def live(
    video: str = _VIDEO_OPT,
    camera: Path = _CAMERA_OPT,
    mavlink: str = _MAVLINK_OPT,
    out: Path = _OUT_OPT,
    config: Path | None = _CONFIG_OPT,
    record: bool = _RECORD_OPT,
    duration_s: float | None = _DURATION_S_OPT,
    viewer: bool = _VIEWER_OPT,
    quiet: bool = _QUIET_OPT,
    mavlink_out: str | None = _MAVLINK_OUT_OPT,
    realtime: bool = _REALTIME_OPT,
    every_frame: bool = _EVERY_FRAME_OPT,
    wait_s: float = _WAIT_S_OPT,
    heartbeat_timeout_s: float = _HEARTBEAT_TIMEOUT_S_OPT,
    video_delay_s: float = _VIDEO_DELAY_S_OPT,
    poi: Path | None = _POI_OPT,
    guide: bool = _GUIDE_OPT,
    survey_s: float = _SURVEY_S_OPT,
    hold_s: float = _HOLD_S_OPT,
    estimator: str = _ESTIMATOR_OPT,
    guide_pace: float = _GUIDE_PACE_OPT,
    approach_gain_per_s: float | None = _APPROACH_GAIN_OPT,
) -> None:
    """Live on the vehicle: the camera stream and the autopilot's telemetry in, a position with covariance out
    to the autopilot over MAVLink (like a DVL), the results folder of `rovslam run` written as the dive goes."""
    import sys
    import time

    from rovslam.config import RunConfig, load_config
    from rovslam.errors import InvalidArgumentError
    from rovslam.live.mavlink import parse_mavlink_out
    from rovslam.live.session import LiveOptions, run_live

    for name, value in (
        ("--duration-s", duration_s),
        ("--wait-s", wait_s),
        ("--heartbeat-timeout-s", heartbeat_timeout_s),
    ):
        if value is not None and not (value > 0 and value != float("inf")):
            raise InvalidArgumentError(f"{name} must be a positive number of seconds, got {value}")
    if not 0.0 <= video_delay_s < 10.0:
        raise InvalidArgumentError(f"--video-delay-s must be from 0 to 10 s, got {video_delay_s}")
    cfg = load_config(config) if config is not None else RunConfig()
    opts = LiveOptions(
        video=video,
        camera_file=camera,
        mavlink=mavlink,
        out=out,
        config=cfg,
        record=record,
        duration_s=duration_s,
        every_frame=every_frame,
        realtime=realtime,
        mavlink_out=parse_mavlink_out(mavlink_out),
        wait_s=wait_s,
        heartbeat_timeout_s=heartbeat_timeout_s,
        video_delay_s=video_delay_s,
        guide=_guide_options(poi, guide, survey_s, hold_s, estimator, guide_pace, approach_gain_per_s),
    )

    def say(text: str) -> None:
        typer.echo(f"live: {text}", err=True)

    last = [0.0]

    def status(line: str) -> None:
        now = time.monotonic()
        if now - last[0] >= 5.0:
            last[0] = now
            typer.echo(f"live: {line}", err=True)

    viewer_obj = None
    if viewer:
        from rovslam.viz.viewer import RerunViewer, display_available

        spawn = display_available()
        viewer_obj = RerunViewer(spawn=spawn, save_path=None if spawn else out / "run.rrd")
    try:
        summary, block = run_live(opts, say, on_frame_image=viewer_obj, status=None if quiet else status)
    finally:
        if viewer_obj is not None:
            viewer_obj.close()
    lat = block.get("latency_ms", {})
    p50 = "-" if lat.get("p50") is None else f"{lat['p50']:.0f}"
    p99 = "-" if lat.get("p99") is None else f"{lat['p99']:.0f}"
    line = (
        f"{block.get('frames_received', 0)} frames received, {block.get('frames_processed', 0)} processed, "
        f"{block.get('frames_dropped', 0)} dropped; {block.get('positions_sent', 0)} positions sent; latency p50 "
        f"{p50} ms, p99 {p99} ms; {summary.landmarks} landmarks -> {out}"
    )
    for note in summary.warnings:
        typer.echo(f"warning: {note}", err=True)
    if summary.interrupted:
        typer.echo(
            f"rovslam: stopped by {summary.signal}: {line}; every file written is complete and readable", err=True
        )
        sys.stdout.flush()
        raise typer.Exit(summary.exit_code)
    typer.echo(line)


def _guide_options(
    poi: Path | None,
    guide: bool,
    survey_s: float,
    hold_s: float,
    estimator: str,
    pace: float,
    approach_gain_per_s: float | None = None,
):
    """The :class:`rovslam.live.guide.GuideOptions` of ``--poi`` (None without it)."""
    from rovslam.errors import InvalidArgumentError

    if poi is None:
        if guide:
            raise InvalidArgumentError("--guide needs --poi POI.csv (the points to go to)")
        if approach_gain_per_s is not None:
            raise InvalidArgumentError("--approach-gain-per-s needs --poi POI.csv (it steers to the points)")
        return None
    from rovslam.io.poi import read_poi_csv
    from rovslam.live.guide import GuideOptions
    from rovslam.nav.guidance import guidance_config

    guidance = guidance_config(hold_s, approach_gain_per_s) if approach_gain_per_s is not None else None
    return GuideOptions(
        tuple(read_poi_csv(poi)),
        guide=guide,
        survey_s=survey_s,
        hold_s=hold_s,
        estimator=estimator,
        pace=pace,
        guidance=guidance,
    )
