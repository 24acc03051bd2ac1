"""The live run: :func:`rovslam.runner.run_sequence` fed by the stream, its results sent over MAVLink.

:class:`LiveSource` is a source of frames as ``run_sequence`` takes one: each frame taken from the
stream gets the telemetry interpolated to its time. :class:`LiveOutput` is the ``on_frame``
callback: for every frame the loop processed and did not refuse it sends the messages, measures
the latency from the frame's arrival, and records the frame (``--record``). The results folder is
the one of ``rovslam run``, written as the dive goes; ``summary.json`` gets a ``live`` block.
"""

from __future__ import annotations

import dataclasses
import signal
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame, SequenceInfo
from rovslam.io.source import SourceDescription
from rovslam.live import messages as msgs
from rovslam.live.stream import BLIND_S, StreamFrame, VideoStream
from rovslam.live.telemetry import Telemetry

BRIDGE_S = 1.0  # a video gap longer than this (stream time) is not bridged: the estimate's reset_counter goes up
STATUS_EVERY_S = 10.0
# The latency of a frame sent, in three stages (summary.json's live block, latency_stages_ms):
# arrival -> decoded, decoded -> taken by the loop, taken -> its messages sent.
LATENCY_STAGES = ("decoding", "waiting", "processing")
SETTLE_WAIT_S = 3.0  # at most this long for the first frames' burst to end


@dataclass(frozen=True)
class LiveOptions:
    """What ``rovslam live`` was given."""

    video: str
    camera_file: Path
    mavlink: str
    out: Path
    config: RunConfig = field(default_factory=RunConfig)
    record: bool = False
    duration_s: float | None = None
    every_frame: bool = False
    realtime: bool = False
    mavlink_out: tuple[str, ...] | None = None  # the messages to send (None: all)
    wait_s: float = 30.0
    heartbeat_timeout_s: float = 30.0
    overwrite: bool = False
    video_delay_s: float = 0.0  # capture to arrival beyond what is measured (a camera's encoder, a sender's buffer)
    guide: Any = None  # a rovslam.live.guide.GuideOptions: the mission to the points of interest (--poi)


def stop_requested() -> bool:
    """True once the run's :class:`rovslam.runner.StopRequest` (the SIGINT handler it installed) caught a signal.

    The source waits for frames that may never come (a stalled stream): it asks here between waits,
    so that Ctrl-C or SIGTERM end a blind run too.
    """
    owner = getattr(signal.getsignal(signal.SIGINT), "__self__", None)
    return getattr(owner, "signum", None) is not None


def percentiles_ms(latencies_s: list[float]) -> dict[str, float | None]:
    """p50, p95, p99 and max of latencies in seconds, as milliseconds (None without any)."""
    if not latencies_s:
        return {"p50": None, "p95": None, "p99": None, "max": None, "count": 0}
    a = np.asarray(latencies_s) * 1000.0
    p50, p95, p99 = (float(v) for v in np.percentile(a, [50, 95, 99]))
    return {"p50": p50, "p95": p95, "p99": p99, "max": float(a.max()), "count": int(a.size)}


class LiveSource:
    """The stream as a source of :func:`rovslam.runner.run_sequence` (``info``, ``frames()``, ``description``).

    ``summary_blocks["live"]`` is the dict ``summary.json`` shows as its ``live`` block; it is
    filled in place as the run goes and when the frames end.
    """

    # Not read ahead of the loop: the newest frame is the one to process (its latency), and
    # ``current`` must stay the frame being processed.
    read_ahead = False

    def __init__(
        self,
        stream: VideoStream,
        telemetry: Telemetry,
        info: SequenceInfo,
        given: str,
        deadline_s: float | None,
        say: Callable[[str], None],
        video_delay_s: float = 0.0,
    ) -> None:
        self.stream, self.telemetry, self.info, self.path, self.say = stream, telemetry, info, given, say
        self.video_delay_s = float(video_delay_s)
        self.deadline_s = deadline_s
        self.warnings: list[str] = []
        self.left_out = 0
        self.groundtruth_path = None
        self.current: tuple[Frame, StreamFrame, float] | None = None  # (frame, stream frame, local time)
        self.taken_s: float | None = None  # when the loop took the newest frame from the stream (monotonic)
        self.offset_s: float | None = None  # local clock - stream time (its smallest: the delay's floor)
        self.blind: list[dict[str, float]] = []
        self.no_attitude = 0
        self.no_altitude = 0
        self.block: dict[str, Any] = {}
        self.summary_blocks = {"live": self.block}
        self.finish: Callable[[], None] = lambda: None

    def __len__(self) -> int:
        return 0  # a stream: unknown

    @property
    def description(self) -> SourceDescription:
        return SourceDescription(
            "live stream",
            self.path,
            altitude_input="sonar",
            altitude_detail="MAVLink DISTANCE_SENSOR (downward) or RANGEFINDER",
            heading_input="compass",
            heading_detail="MAVLink ATTITUDE yaw",
            attitude_detail="MAVLink ATTITUDE roll, pitch",
        )

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        index = 0
        try:
            while stop is None or index < stop:
                sf = self._next()
                if sf is None:
                    return
                yield self._frame(index, sf)
                index += 1
        finally:
            self.finish()

    def _next(self) -> StreamFrame | None:
        """The next frame to process; None at the end (duration, a signal, the stream's end)."""
        blind_since: float | None = None
        while True:
            if stop_requested() or (self.deadline_s is not None and time.monotonic() >= self.deadline_s):
                return None
            sf = self.stream.take(0.1)
            now = time.monotonic()
            if sf is not None:
                self.taken_s = now
                prev = self.current[1].delivered_s if self.current is not None else None
                if prev is not None and sf.delivered_s - prev > BLIND_S:  # said as it began, or only now (a late loop)
                    self.blind.append({"after_t_s": self._last_t_s(), "blind_s": sf.delivered_s - prev})
                    self.say(
                        f"video: back at t = {sf.t_s:.2f} s after {sf.delivered_s - prev:.1f} s without a frame"
                        + ("" if blind_since is not None else " (blind: no position was sent in between)")
                    )
                return sf
            if self.stream.finished:
                if self.stream.error is not None:
                    from rovslam.errors import SequenceFormatError

                    raise SequenceFormatError(self.stream.error)
                return None
            last = self.current[1].delivered_s if self.current is not None else None
            if blind_since is None and last is not None and now - last > BLIND_S:
                blind_since = now
                self.say(
                    f"video: no frame for {BLIND_S:g} s after t = {self._last_t_s():.2f} s: blind, no position "
                    "is sent until it returns"
                )

    def _last_t_s(self) -> float:
        return self.current[0].t_s if self.current is not None else 0.0

    def _frame(self, index: int, sf: StreamFrame) -> Frame:
        if index == 0:  # the first frames come in a burst (the stream's probe): wait for the clock to settle
            self.stream.settled.wait(SETTLE_WAIT_S)
        d = sf.arrival_s - sf.t_s
        self.offset_s = d if self.offset_s is None else min(self.offset_s, d)
        floor = self.stream.floor_s
        # when it was captured, on the local clock: the smallest delay seen over every packet so far
        t_local = sf.pts_s + floor if sf.pts_s is not None and floor is not None else sf.t_s + self.offset_s
        t_local -= self.video_delay_s
        att = self.telemetry.wait_attitude(t_local)
        alt = self.telemetry.altitude_at(t_local)
        had = self.current is not None and self.current[0].has_attitude
        if att is None:
            self.no_attitude += 1
            if had or index == 0:
                self.say(
                    f"telemetry: no ATTITUDE at t = {sf.t_s:.2f} s: the heading is the tokens' turn until it returns"
                )
        elif self.current is not None and not had:
            self.say(f"telemetry: ATTITUDE back at t = {sf.t_s:.2f} s")
        self.no_altitude += alt is None
        frame = Frame(
            index=index,
            t_s=sf.t_s,
            image=sf.image,
            heading_rad=float("nan") if att is None else att[2],
            sonar_altitude_m=alt,
            roll_rad=0.0 if att is None else att[0],
            pitch_rad=0.0 if att is None else att[1],
            has_attitude=att is not None,
            source=f"{self.path}#{sf.number}",
        )
        self.current = (frame, sf, t_local)
        return frame


class LiveOutput:
    """The ``on_frame`` callback: the MAVLink messages of each processed frame, the latency, the record."""

    def __init__(
        self, source: LiveSource, link: Any, sends: tuple[str, ...], config: RunConfig, record_folder: Path | None
    ) -> None:
        self.source, self.link, self.sends, self.config = source, link, sends, config
        self.record_folder = record_folder
        self.recorder: Any = None
        self.prev: msgs.Estimate | None = None
        self.prev_t_s: float | None = None
        self.reset_counter = 0
        self.resets: list[dict[str, Any]] = []
        self.latencies_s: list[float] = []
        # Per frame sent: arrival -> decoded (the decoder's hand-over), decoded -> taken by the loop
        # (waiting for the frame before it), taken -> messages sent (telemetry, the loop, the messages).
        self.stages_s: dict[str, list[float]] = {name: [] for name in LATENCY_STAGES}
        self.processed = 0
        self.refused = 0
        self.positions_sent = 0
        self._t0_wall = time.time()
        self._t0_mono = time.monotonic()
        self.cpu_first_s: float | None = None  # the process's CPU time (every thread) at the first frame
        self.cpu_last_s: float | None = None  # ... and at the newest

    def on_frame(self, res: Any) -> None:
        cur = self.source.current
        if cur is None:
            return
        frame, sf, t_local = cur
        self.processed += 1
        self.cpu_last_s = time.process_time()
        if self.cpu_first_s is None:
            self.cpu_first_s = self.cpu_last_s
        self._record(frame)
        gap_s = None if self.prev_t_s is None else frame.t_s - self.prev_t_s
        self.prev_t_s = frame.t_s
        if res.skipped_reason is not None:  # the loop refused the frame: nothing is sent from it
            self.refused += 1
            return
        reset = False
        if res.recovery is not None or (gap_s is not None and gap_s > BRIDGE_S):
            self.reset_counter += 1
            reset = True
            self.resets.append(
                {
                    "t_s": frame.t_s,
                    "cause": "recovery"
                    if res.recovery is not None
                    else f"video gap of {gap_s:.2f} s (longer than {BRIDGE_S:g} s)",
                }
            )
        e = self._estimate(res, frame)
        usec = int((self._t0_wall + (t_local - self._t0_mono)) * 1e6)
        if "VISION_POSITION_DELTA" in self.sends and self.prev is not None and not reset:
            self.link.send("VISION_POSITION_DELTA", msgs.position_delta(self.prev, e, usec))
        if "VISION_POSITION_ESTIMATE" in self.sends:
            self.link.send("VISION_POSITION_ESTIMATE", msgs.position_estimate(e, usec, self.reset_counter))
            self.positions_sent += 1
        if "VISION_SPEED_ESTIMATE" in self.sends and res.speed_ok:
            self.link.send("VISION_SPEED_ESTIMATE", msgs.speed_estimate(e, usec, self.reset_counter))
        if "DISTANCE_SENSOR" in self.sends and str(res.altitude_source).startswith("laser"):
            lc = self.config.laser
            self.link.send(
                "DISTANCE_SENSOR", msgs.distance_sensor(e, self.link.time_boot_ms, lc.min_altitude_m, lc.max_altitude_m)
            )
        self.prev = e
        now = time.monotonic()
        self.latencies_s.append(now - sf.arrival_s)
        taken = self.source.taken_s if self.source.taken_s is not None else sf.delivered_s
        for name, seconds in zip(LATENCY_STAGES, (sf.delivered_s - sf.arrival_s, taken - sf.delivered_s, now - taken)):
            self.stages_s[name].append(seconds)

    def cpu_ms_per_frame(self) -> float | None:
        """The process's CPU time (every thread: decoding, the loop, the links) from the first processed
        frame to the newest, per frame processed in between; None before two frames."""
        if self.cpu_first_s is None or self.cpu_last_s is None or self.processed < 2:
            return None
        return 1e3 * (self.cpu_last_s - self.cpu_first_s) / (self.processed - 1)

    def _estimate(self, res: Any, frame: Frame) -> msgs.Estimate:
        od = self.config.odometry
        return msgs.Estimate(
            t_s=res.t_s,
            x_m=res.x_m,
            y_m=res.y_m,
            heading_rad=res.heading_rad,
            roll_rad=frame.roll_rad,
            pitch_rad=frame.pitch_rad,
            cov_xy_m2=np.asarray(res.cov_xy_m2, float),
            surge_mps=res.surge_mps,
            sway_mps=res.sway_mps,
            speed_cov_mps2=np.asarray(res.speed_cov_mps2, float),
            speed_ok=bool(res.speed_ok),
            altitude_m=res.altitude_m,
            altitude_sigma_m=res.altitude_sigma_m,
            altitude_source=str(res.altitude_source),
            yaw_sigma_rad=od.compass_sigma_rad,
            attitude_sigma_rad=od.attitude_noise_sigma_rad,
        )

    def _record(self, frame: Frame) -> None:
        if self.record_folder is None or frame.image is None:
            return
        if self.recorder is None:
            from rovslam.io.sequence import SequenceWriter

            info = dataclasses.replace(
                self.source.info,
                metadata={
                    **self.source.info.metadata,
                    "recorded_by": "rovslam live",
                    "video": self.source.path,
                    "heading_detail": "MAVLink ATTITUDE yaw",
                    "altitude_detail": "MAVLink DISTANCE_SENSOR / RANGEFINDER",
                    "attitude_detail": "MAVLink ATTITUDE roll, pitch",
                },
            )
            self.recorder = SequenceWriter(self.record_folder, info, with_attitude=True, with_groundtruth=False)
        self.recorder.write_frame(
            frame.t_s,
            frame.image,
            frame.heading_rad,
            frame.sonar_altitude_m,
            frame.roll_rad if frame.has_attitude else None,
            frame.pitch_rad if frame.has_attitude else None,
        )

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None


def live_block(source: LiveSource, output: LiveOutput, link: Any, opts: LiveOptions) -> dict[str, Any]:
    """The ``live`` block of ``summary.json``."""
    stream = source.stream
    gaps = [{**g, "bridged": g["stream_gap_s"] <= BRIDGE_S} for g in stream.gaps]
    return {
        "video": opts.video,
        "mavlink": opts.mavlink,
        "every_frame": opts.every_frame,
        "realtime": opts.realtime,
        "messages_sent": list(output.sends),
        "frames_received": stream.received,
        "frames_processed": output.processed,
        "frames_dropped": stream.received - stream.taken,
        "frames_refused": output.refused,
        "positions_sent": output.positions_sent,
        "frames_without_attitude": source.no_attitude,
        "frames_without_altitude": source.no_altitude,
        "latency_ms": percentiles_ms(output.latencies_s),
        "latency_stages_ms": {name: percentiles_ms(v) for name, v in output.stages_s.items()},
        "cpu_ms_per_frame": output.cpu_ms_per_frame(),
        **link.summary(),
        **source.telemetry.summary(time.monotonic()),
        "video_gaps": gaps,
        "blind": list(source.blind),
        "blind_limit_s": BLIND_S,
        "bridge_limit_s": BRIDGE_S,
        "resets": list(output.resets),
        "reset_counter": output.reset_counter,
        "recorded_sequence": str(output.record_folder) if output.record_folder is not None else None,
    }


def run_live(
    opts: LiveOptions,
    say: Callable[[str], None],
    on_frame_image: Any = None,
    status: Callable[[str], None] | None = None,
) -> Any:
    """Run ``rovslam live``: returns the :class:`rovslam.runner.RunSummary` and the ``live`` block of summary.json."""
    from rovslam.io.camera_file import read_camera_file
    from rovslam.live.mavlink import MavlinkLink, parse_mavlink_out
    from rovslam.live.stream import resolve_video
    from rovslam.runner import run_sequence

    t_start = time.monotonic()
    deadline = None if opts.duration_s is None else t_start + opts.duration_s
    cam = read_camera_file(opts.camera_file, name="live")
    sends = parse_mavlink_out(None) if opts.mavlink_out is None else opts.mavlink_out
    sdp_folder = tempfile.TemporaryDirectory(prefix="rovslam-sdp-")  # an rtp:// stream's SDP file, removed at the end
    try:
        video = resolve_video(opts.video, Path(sdp_folder.name))
    except BaseException:
        sdp_folder.cleanup()
        raise
    telemetry = Telemetry()
    link = MavlinkLink(opts.mavlink, telemetry, say)
    stream: VideoStream | None = None
    output: LiveOutput | None = None
    try:
        cam_info = cam.info
        # A stream is listened to from the start (one that begins with the vehicle loses no first frame); a file is
        # played once the vehicle is there.
        stream = VideoStream(
            video,
            cam_info.camera.width_px,
            cam_info.camera.height_px,
            every_frame=opts.every_frame,
            realtime=opts.realtime,
            wait_s=opts.wait_s,
        )
        if not video.is_file:
            stream.start()
        say(f"waiting for a vehicle's HEARTBEAT on {opts.mavlink} ...")
        v = link.wait_vehicle(opts.heartbeat_timeout_s)
        if video.is_file:
            stream.start()
        say(
            f"vehicle: system {v['system']}, component {v['component']} ({_enum('MAV_TYPE', v['type'])}, "
            f"{_enum('MAV_AUTOPILOT', v['autopilot'])}); sending as system {v['system']}, component 197"
        )
        say(f"waiting for the video on {opts.video} ...")
        first = stream.first_frame()
        say(f"video: {first.image.shape[1]}x{first.image.shape[0]} px")
        source = LiveSource(stream, telemetry, cam_info, opts.video, deadline, say, opts.video_delay_s)
        output = LiveOutput(source, link, sends, opts.config, opts.out / "sequence" if opts.record else None)
        out_ = output
        guide = _guide(opts, link, say)

        def finish() -> None:
            out_.close()
            if guide is not None:
                guide.close()
            source.block.update(live_block(source, out_, link, opts))

        source.finish = finish

        def on_frame(res: Any) -> None:
            out_.on_frame(res)
            if guide is not None:
                guide.on_frame(res)
            if status is not None:
                status(_status_line(source, out_))

        summary = run_sequence(
            source,
            opts.out,
            opts.config,
            on_frame=on_frame,
            camera_file=opts.camera_file,
            on_frame_image=on_frame_image,
            overwrite=opts.overwrite,
        )
        return summary, dict(source.block)
    finally:
        if output is not None:
            output.close()
        if stream is not None:
            stream.close()
        link.close()
        sdp_folder.cleanup()


def _guide(opts: LiveOptions, link: Any, say: Callable[[str], None]) -> Any:
    if opts.guide is None:
        return None
    from rovslam.live.guide import Guide

    return Guide(opts.guide, link, opts.out, say)


def _status_line(source: LiveSource, output: LiveOutput) -> str:
    cur = source.current
    t = cur[0].t_s if cur else 0.0
    lat = percentiles_ms(output.latencies_s[-100:])
    p50 = f"{lat['p50']:.0f} ms" if lat["p50"] is not None else "-"
    return (
        f"t {t:7.1f} s  frames {source.stream.received} in, {output.processed} processed, "
        f"{source.stream.received - source.stream.taken} dropped  positions sent {output.positions_sent}  "
        f"latency p50 {p50}"
    )


def _enum(name: str, value: int) -> str:
    from pymavlink import mavutil

    entry = mavutil.mavlink.enums.get(name, {}).get(value)
    return entry.name if entry is not None else f"{name} {value}"


__all__ = ["LiveOptions", "LiveOutput", "LiveSource", "live_block", "percentiles_ms", "run_live", "stop_requested"]
