"""``rovslam sitl``: the simulator as an ArduSub vehicle on the network (the command; the work is in :mod:`rovslam.sim.sitl`).

Only typer is imported here at module level; the simulator, PyAV and pymavlink load when the
command runs.
"""

from pathlib import Path

import typer

from rovslam.cli import app
from rovslam.cli.errors import guard

__all__ = ["sitl"]


# The command's options (kept here so that its signature reads as a list of names).
_SCENARIO_OPT = typer.Option(None, "--scenario", help="Simulator preset to fly (rovslam simulate --list).")
_OUT_OPT = typer.Option(
    ..., "--out", "-o", help="Folder for the truth: groundtruth.csv, camera.toml, received.csv (new or empty)."
)
_SEED_OPT = typer.Option(0, help="Random seed of the seabed, the path and the sensors (as rovslam simulate).")
_VIDEO_OPT = typer.Option(
    "udp://127.0.0.1:5600",
    "--video",
    help="Where to stream the camera: udp://HOST:PORT "
    "(H.264 in MPEG-TS; with --rtp: H.264 over RTP and OUT/stream.sdp, as BlueOS).",
)
_MAVLINK_OPT = typer.Option(
    "udpout:127.0.0.1:14550",
    "--mavlink",
    help="pymavlink connection string of the "
    "autopilot link (udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT, /dev/ttyX,BAUD).",
)
_DURATION_S_OPT = typer.Option(
    None, "--duration-s", help="Dive time to stream (s); default: the preset's dive, or the whole --from sequence."
)
_FROM_SEQ_OPT = typer.Option(
    None,
    "--from",
    help="Stream this sequence folder (rovslam simulate writes one) at its own frame times instead of rendering live.",
)
_RTP_OPT = typer.Option(False, "--rtp", help="H.264 over RTP (BlueOS's default on UDP 5600) with its SDP file.")
_PACE_OPT = typer.Option(
    1.0,
    "--pace",
    help="Wall seconds per dive second: 1 real time, 2 half speed (the "
    "stream's presentation times stay the capture times).",
)
_MODE_OPT = typer.Option(
    "ALT_HOLD", "--mode", help="ArduSub mode the heartbeat reports (MANUAL, STABILIZE, ALT_HOLD, POSHOLD, GUIDED, ...)."
)
_LINGER_S_OPT = typer.Option(
    2.0,
    "--linger-s",
    help="After the last frame, keep receiving this long (the answers to the last frames) before closing.",
)
_CRF_OPT = typer.Option(
    20,
    "--crf",
    help="H.264 quality of the stream (x264 CRF: lower is better; MPEG-TS frames are kept under 60 kB whatever it is).",
)
_WAIT_FOR_PEER_S_OPT = typer.Option(
    0.0,
    "--wait-for-peer-s",
    help="Hold the first frame until a companion's HEARTBEAT arrives (at most this long; 0: start at once).",
)
_QUIET_OPT = typer.Option(False, "--quiet", "-q", help="No progress lines.")
_FOLLOW_GUIDED_OPT = typer.Option(
    False,
    "--follow-guided",
    help="Obey SET_MODE, arm/disarm and velocity "
    "setpoints (GUIDED) and fly them; STATUSTEXT with the true position in "
    "OUT/events.csv. Starts disarmed.",
)
_PILOT_GUIDED_S_OPT = typer.Option(
    None,
    "--pilot-guided-s",
    help="With --follow-guided: the pilot arms and switches to GUIDED this many seconds into the dive.",
)


def sitl(
    scenario: str | None = _SCENARIO_OPT,
    out: Path = _OUT_OPT,
    seed: int = _SEED_OPT,
    video: str = _VIDEO_OPT,
    mavlink: str = _MAVLINK_OPT,
    duration_s: float | None = _DURATION_S_OPT,
    from_seq: Path | None = _FROM_SEQ_OPT,
    rtp: bool = _RTP_OPT,
    pace: float = _PACE_OPT,
    mode: str = _MODE_OPT,
    linger_s: float = _LINGER_S_OPT,
    crf: int = _CRF_OPT,
    wait_for_peer_s: float = _WAIT_FOR_PEER_S_OPT,
    quiet: bool = _QUIET_OPT,
    follow_guided: bool = _FOLLOW_GUIDED_OPT,
    pilot_guided_s: float | None = _PILOT_GUIDED_S_OPT,
) -> None:
    """Fly a preset as an ArduSub vehicle: camera stream, MAVLink telemetry, truth on disk, for `rovslam live`.

    Streams the preset's camera as H.264 at its frame rate (each frame's presentation time its
    capture time), sends HEARTBEAT, ATTITUDE, DISTANCE_SENSOR and SYSTEM_TIME as system 1, and
    records the VISION_* / DISTANCE_SENSOR / STATUSTEXT messages it receives. Ctrl-C ends the
    dive with every file complete.
    """
    from rovslam.errors import SimulationError
    from rovslam.runner import StopRequest
    from rovslam.sim.sitl import SitlConfig, SitlVehicle
    from rovslam.sim.sitl_mavlink import ARDUSUB_MODES

    if scenario is not None and from_seq is not None:
        raise SimulationError("give --scenario or --from, not both (a --from sequence knows its preset)")
    if mode.upper() not in ARDUSUB_MODES:
        raise SimulationError(f"--mode {mode!r}: choose one of: {', '.join(ARDUSUB_MODES)}")
    if seed < 0:
        raise SimulationError(f"--seed must be a whole number >= 0, got {seed}")

    def say(text: str) -> None:
        if not quiet:
            typer.echo(text)

    config = SitlConfig(
        scenario,
        out,
        video=video,
        mavlink=mavlink,
        seed=seed,
        duration_s=duration_s,
        from_seq=from_seq,
        rtp=rtp,
        pace=pace,
        mode=mode.upper(),
        wait_for_peer_s=wait_for_peer_s,
        crf=crf,
        follow_guided=follow_guided,
        pilot_guided_s=pilot_guided_s,
    )
    vehicle = SitlVehicle(config)
    src = vehicle.source
    cam = src.info.camera
    with StopRequest() as stop:
        vehicle.start()
        stream = (
            f"{video} as RTP, SDP {out / 'stream.sdp'}" if rtp or video.startswith("rtp:") else f"{video} (MPEG-TS)"
        )
        say(
            f"sitl: {src.info.name}: {src.n_frames} frames {cam.width_px}x{cam.height_px} at "
            f"{src.frame_rate_hz:g} Hz, pace {pace:g}"
        )
        say(f"sitl: video {stream}; MAVLink {mavlink} as system 1 (ArduSub, {mode.upper()}); truth in {out}")
        say("sitl: rendering the first frame..." if from_seq is None else "sitl: reading the first frame...")
        if wait_for_peer_s > 0:
            say(f"sitl: the dive starts when a companion's HEARTBEAT arrives (at most {wait_for_peer_s:g} s)")
        try:
            _watch(vehicle, stop, say, linger_s)
        finally:
            stop.ignore_after = stop.signum is not None
            summary = vehicle.stop()
    link = summary["mavlink"] or {}
    ins = ", ".join(f"{k} {v}" for k, v in link.get("messages_in", {}).items()) or "none"
    line = (
        f"{summary['frames_sent']}/{summary['frames_planned']} frames sent ({summary['late_frames']} late); "
        f"messages in: {ins}; garbage {link.get('bad_packets', 0)} -> {out}"
    )
    if stop.signum is not None:
        typer.echo(f"sitl: stopped by {stop.name}: {line}; every file written is complete", err=True)
        raise typer.Exit(128 + stop.signum)
    say(f"sitl: done: {line}")


app.command(name="sitl")(guard(sitl))  # registered undecorated: tests call sitl() and see its errors


def _watch(vehicle, stop, say, linger_s: float) -> None:
    """Follow the dive (a line every 10 s) until it ends or a signal comes, then keep receiving ``linger_s``."""
    import time

    announced, last_note = False, time.monotonic()
    n = vehicle.source.n_frames
    while stop.signum is None and not vehicle.wait(0.2):
        if not announced and vehicle.frames_sent > 0:
            announced = True
            say("sitl: streaming (Ctrl-C ends the dive, the files complete)")
        if time.monotonic() - last_note >= 10.0:
            last_note = time.monotonic()
            say(
                f"sitl: t = {vehicle.stream_time_s() or 0.0:.1f} s, {vehicle.frames_sent}/{n} frames, "
                f"{sum(vehicle.link.counts_in.values()) if vehicle.link else 0} messages in"
            )
    end = time.monotonic() + max(0.0, linger_s)
    while stop.signum is None and time.monotonic() < end:
        time.sleep(0.05)
