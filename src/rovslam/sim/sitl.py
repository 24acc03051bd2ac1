"""The simulator as an ArduSub vehicle on the network: camera stream, autopilot telemetry, truth on disk.

:class:`SitlVehicle` flies a scenario preset in real time (or ``pace`` times slower) and behaves
like a BlueROV2 with ArduSub and BlueOS: it streams the camera as H.264 (MPEG-TS over UDP, or
RTP with its SDP file), sends HEARTBEAT, ATTITUDE, DISTANCE_SENSOR / RANGEFINDER and
SYSTEM_TIME, and records what a navigation sensor sends it. It is what ``rovslam sitl`` runs,
and the harness of the ``live`` tests::

    vehicle = SitlVehicle(SitlConfig("portofino-short", Path("truth"), video="udp://127.0.0.1:5600",
                                     mavlink="udpout:127.0.0.1:14550", duration_s=10.0))
    vehicle.start()
    vehicle.wait()          # or vehicle.stop()

The stream's axis: frame k is presented at its capture time ``t_k`` (seconds from the first
frame) and sent at wall time ``start + pace * t_k``; every ``time_boot_ms`` is ``1000 t_k``.
ATTITUDE goes out at each frame's time, before the frame, and between frames at 10 Hz or more
(the readings interpolated). The files of the output folder, written as the dive goes:

- ``groundtruth.csv``: the true state at each frame's time (what ``rovslam eval`` reads);
- ``camera.toml``: the camera and lasers (``rovslam live --camera``);
- ``received.csv``: the messages received (:mod:`rovslam.sim.sitl_mavlink`);
- ``stream.sdp``: with ``rtp``, the SDP of the stream;
- ``sitl.json`` at the end: frames sent, late frames, messages in and out.
"""

from __future__ import annotations

import csv
import json
import math
import queue
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from rovslam.errors import SimulationError
from rovslam.sim.sitl_frames import FrameSource, SitlFrame

if TYPE_CHECKING:
    from rovslam.sim.sitl_mavlink import MavlinkLink
    from rovslam.sim.sitl_video import VideoOut

__all__ = ["SitlConfig", "SitlVehicle", "write_camera_file"]

MIN_ATTITUDE_RATE_HZ = 10.0  # ArduSub's default ATTITUDE rate to a GCS
_QUEUE_FRAMES = 3  # frames rendered ahead of their time


@dataclass(frozen=True)
class SitlConfig:
    """What ``rovslam sitl`` is given. ``from_seq``: stream that sequence folder instead of rendering ``scenario``."""

    scenario: str | None
    out: Path
    video: str = "udp://127.0.0.1:5600"
    mavlink: str = "udpout:127.0.0.1:14550"
    seed: int = 0
    duration_s: float | None = None  # None: the preset's dive, or the whole sequence
    from_seq: Path | None = None
    rtp: bool = False
    pace: float = 1.0  # wall seconds per stream second (> 1: slower than real time)
    mode: str = "ALT_HOLD"  # the ArduSub mode the heartbeat reports
    crf: int = 20  # H.264 quality of the stream
    wait_for_peer_s: float = 0.0  # > 0: hold the first frame until another component's HEARTBEAT (at most this long)
    follow_guided: bool = False  # fly the setpoints of a GUIDED mission (rovslam.sim.sitl_guided)
    pilot_guided_s: float | None = None  # with follow_guided: arm and switch to GUIDED at this stream time

    def __post_init__(self) -> None:
        if not (isinstance(self.pace, (int, float)) and math.isfinite(self.pace) and self.pace > 0):
            raise SimulationError(f"--pace must be a positive factor (1 real time, 2 half speed), got {self.pace}")
        if isinstance(self.crf, bool) or not isinstance(self.crf, int) or not 0 <= self.crf <= 51:
            raise SimulationError(f"--crf must be a whole number from 0 (lossless) to 51, got {self.crf}")
        if not (isinstance(self.wait_for_peer_s, (int, float)) and 0 <= self.wait_for_peer_s < math.inf):
            raise SimulationError(f"--wait-for-peer-s must be a number of seconds >= 0, got {self.wait_for_peer_s}")
        if self.scenario is None and self.from_seq is None:
            raise SimulationError("give --scenario NAME (a preset, rovslam simulate --list) or --from SEQUENCE")


def write_camera_file(path: Path, info) -> None:
    """``info``'s camera and lasers as a camera file (``rovslam run --camera``, ``rovslam live --camera``)."""
    import tomli_w

    from rovslam.io.sequence import info_to_toml

    data = info_to_toml(info)
    data.pop("format", None)
    path.write_text(tomli_w.dumps(data), encoding="utf-8")


def _interpolate(a: SitlFrame, b: SitlFrame, w: float) -> tuple[float, float, float]:
    """(roll, pitch, heading) readings a fraction ``w`` of the way from frame ``a`` to ``b`` (heading the short way)."""
    dh = (b.heading_rad - a.heading_rad + math.pi) % (2.0 * math.pi) - math.pi
    return (
        a.roll_rad + w * (b.roll_rad - a.roll_rad),
        a.pitch_rad + w * (b.pitch_rad - a.pitch_rad),
        a.heading_rad + w * dh,
    )


class SitlVehicle:
    """The simulated vehicle: :meth:`start` opens the stream and the link and flies in threads; :meth:`stop` ends it.

    Bad input (an unknown preset, a URL or connection string that cannot be used, an output
    folder that is not empty) raises :class:`~rovslam.errors.SimulationError` from the
    constructor, before anything is sent. Errors in the threads end the dive and are raised
    again by :meth:`wait`.
    """

    def __init__(self, config: SitlConfig) -> None:
        from rovslam.sim.sitl_frames import preset_frames, sequence_frames
        from rovslam.sim.sitl_mavlink import check_connection
        from rovslam.sim.sitl_video import parse_video_url

        self.config = c = config
        parse_video_url(c.video, c.rtp)
        check_connection(c.mavlink)
        out = Path(c.out)
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise SimulationError(f"--out {out}: exists and is not an empty folder; give a new folder")
        self.follower: Any = None  # rovslam.sim.sitl_guided.GuidedFollower with --follow-guided
        if c.follow_guided:
            from rovslam.sim.sitl_guided import GuidedFollower

            if c.from_seq is not None:
                raise SimulationError("--follow-guided renders from the vehicle's state: give --scenario, not --from")
            self.follower = GuidedFollower(str(c.scenario), c.seed, c.duration_s, Path(c.out), c.pilot_guided_s)
        self.source: FrameSource = (
            self.follower.source()
            if self.follower is not None
            else sequence_frames(Path(c.from_seq), c.duration_s)
            if c.from_seq is not None
            else preset_frames(str(c.scenario), c.seed, c.duration_s)
        )
        self.out = out
        self._t0: float | None = None  # monotonic time of the first frame
        self._stop = threading.Event()
        self._done = threading.Event()
        self._streaming = threading.Event()  # set when the first frame is sent
        self._error: BaseException | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=1 if c.follow_guided else _QUEUE_FRAMES)
        self._threads: list[threading.Thread] = []
        self.frames_sent = 0
        self.sent_monotonic_s: list[float] = []  # when each frame went out (time.monotonic)
        self.peer_seen = False  # a HEARTBEAT of another component had arrived when the dive began
        self.late_frames = 0  # sent more than half a frame period after their time (a renderer too slow)
        self.link: MavlinkLink | None = None
        self.video: VideoOut | None = None
        self._gt_fh: IO[str] | None = None
        self.started_unix_s: float | None = None

    # ------------------------------------------------------------------ clock
    def stream_time_s(self) -> float | None:
        """Seconds on the stream's axis now (the capture time of a frame sent now), None before the first frame."""
        return None if self._t0 is None else (time.monotonic() - self._t0) / self.config.pace

    def _sleep_until(self, t_s: float) -> bool:
        """Wait until stream time ``t_s``; False if stopped first."""
        assert self._t0 is not None
        delay = self._t0 + t_s * self.config.pace - time.monotonic()
        return not self._stop.wait(delay) if delay > 0 else not self._stop.is_set()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SitlVehicle:
        """Create the output files, open the stream and the link, and start flying (returns at once)."""
        from rovslam.io.sequence import GROUNDTRUTH_COLUMNS, RELIEF_COLUMN
        from rovslam.sim.sitl_mavlink import MavlinkLink
        from rovslam.sim.sitl_video import VideoOut

        c, src = self.config, self.source
        self.out.mkdir(parents=True, exist_ok=True)
        write_camera_file(self.out / "camera.toml", src.info)
        cam = src.info.camera
        video = self.video = VideoOut(
            c.video,
            cam.width_px,
            cam.height_px,
            src.frame_rate_hz,
            rtp=c.rtp,
            sdp_path=self.out / "stream.sdp",
            crf=c.crf,
        )
        try:
            link = self.link = MavlinkLink(c.mavlink, self.out / "received.csv", self.stream_time_s, mode=c.mode)
        except BaseException:
            video.close()
            raise
        if self.follower is not None:
            self.follower.attach(link, self.stream_time_s, self._stop.is_set)
        fh = self._gt_fh = (self.out / "groundtruth.csv").open("w", newline="", encoding="utf-8")
        self._gt = csv.writer(fh, lineterminator="\n")
        self._gt.writerow(GROUNDTRUTH_COLUMNS + ((RELIEF_COLUMN,) if src.with_relief else ()))
        fh.flush()
        self.started_unix_s = time.time()
        link.start()
        for target, name in ((self._produce, "render"), (self._fly, "fly")):
            th = threading.Thread(target=self._guarded(target), name=f"rovslam-sitl-{name}", daemon=True)
            self._threads.append(th)
            th.start()
        return self

    def _guarded(self, fn):
        def run() -> None:
            try:
                fn()
            except BaseException as exc:  # kept for wait(); the dive ends
                if self._error is None:
                    self._error = exc
                self._stop.set()

        return run

    def _produce(self) -> None:
        """Render (or read) the frames ahead of their time; None after the last one."""
        try:
            for frame in self.source.frames:
                if not self._put(frame):
                    return
        finally:
            close = getattr(self.source.frames, "close", None)
            if close is not None:
                close()
        self._put(None)

    def _put(self, item: SitlFrame | None) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _next(self) -> SitlFrame | None:
        while not self._stop.is_set():
            try:
                return self._queue.get(timeout=0.1)
            except queue.Empty:
                continue
        return None

    def _fly(self) -> None:
        """Send each frame and its telemetry at its time; ATTITUDE between frames, interpolated."""
        link = self.link
        assert link is not None
        try:
            rate = self.source.frame_rate_hz
            sub = max(1, math.ceil(MIN_ATTITUDE_RATE_HZ / rate - 1e-9))
            prev: SitlFrame | None = None
            while (frame := self._next()) is not None:
                if prev is None:
                    self._wait_for_peer(link)
                    self._t0 = time.monotonic() - frame.t_s * self.config.pace
                else:
                    gap = frame.t_s - prev.t_s
                    for j in range(1, sub):
                        t = prev.t_s + gap * j / sub
                        if not self._sleep_until(t):
                            return
                        roll, pitch, yaw = _interpolate(prev, frame, j / sub)
                        link.send_attitude(t, roll, pitch, yaw, self._rates(prev, frame))
                if not self._sleep_until(frame.t_s):
                    return
                self._send_frame(frame, prev)
                self._streaming.set()
                prev = frame
        finally:
            self._done.set()
            self._stop.set()

    def _wait_for_peer(self, link: MavlinkLink) -> None:
        """Hold the dive until another component's HEARTBEAT arrives, or ``wait_for_peer_s`` has passed."""
        end = time.monotonic() + self.config.wait_for_peer_s
        while not link.counts_in["HEARTBEAT"] and time.monotonic() < end and not self._stop.wait(0.02):
            pass
        self.peer_seen = bool(link.counts_in["HEARTBEAT"])

    @staticmethod
    def _rates(a: SitlFrame | None, b: SitlFrame) -> tuple[float, float, float]:
        if a is None or b.t_s <= a.t_s:
            return (0.0, 0.0, 0.0)
        dt = b.t_s - a.t_s
        dh = (b.heading_rad - a.heading_rad + math.pi) % (2.0 * math.pi) - math.pi
        return ((b.roll_rad - a.roll_rad) / dt, (b.pitch_rad - a.pitch_rad) / dt, dh / dt)

    def _send_frame(self, frame: SitlFrame, prev: SitlFrame | None) -> None:
        link, video, fh = self.link, self.video, self._gt_fh
        assert link is not None and video is not None and fh is not None
        late_s = (self.stream_time_s() or 0.0) - frame.t_s
        if late_s > 0.5 / self.source.frame_rate_hz:
            self.late_frames += 1
        link.send_attitude(frame.t_s, frame.roll_rad, frame.pitch_rad, frame.heading_rad, self._rates(prev, frame))
        if frame.sonar_altitude_m is not None:
            link.send_sonar(frame.t_s, frame.sonar_altitude_m, self.source.sonar_sigma_m)
        self.sent_monotonic_s.append(time.monotonic())
        video.send(frame.image, frame.t_s)
        if frame.truth is not None:
            self._gt.writerow([repr(float(frame.t_s))] + [repr(float(v)) for v in frame.truth])
            fh.flush()
        self.frames_sent += 1

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the end of the dive (``timeout_s``: at most that long); True if it ended. Re-raises a thread's error."""
        ended = self._done.wait(timeout_s)
        if self._error is not None:
            raise self._error
        return ended

    def wait_streaming(self, timeout_s: float | None = None) -> bool:
        """Wait until the first frame is sent (the first render builds the seabed: seconds); True if it was."""
        while not self._streaming.wait(0.05 if timeout_s is None else min(0.05, timeout_s)):
            if self._done.is_set():
                break
            if timeout_s is not None:
                timeout_s -= 0.05
                if timeout_s <= 0:
                    break
        if self._error is not None:
            raise self._error
        return self._streaming.is_set()

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def stop(self) -> dict[str, Any]:
        """End the dive (if still flying), close the stream, the link and the files; returns what ``sitl.json`` says."""
        self._stop.set()
        for th in self._threads:
            th.join(10.0)
        self._threads = []
        if self.video is not None:
            self.video.close()
        if self.link is not None:
            self.link.close()
        if self.follower is not None:
            self.follower.close()
        if self._gt_fh is not None and not self._gt_fh.closed:
            self._gt_fh.close()
        summary = self.summary()
        if self.started_unix_s is not None:
            (self.out / "sitl.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
        return summary

    def summary(self) -> dict[str, Any]:
        c = self.config
        return {
            "scenario": c.scenario if c.from_seq is None else self.source.info.metadata.get("scenario"),
            "from": None if c.from_seq is None else str(c.from_seq),
            "seed": c.seed,
            "pace": c.pace,
            "video": c.video,
            "rtp": c.rtp,
            "frame_rate_hz": self.source.frame_rate_hz,
            "peer_heartbeat_before_first_frame": self.peer_seen,
            "frames_planned": self.source.n_frames,
            "frames_sent": self.frames_sent,
            "late_frames": self.late_frames,
            "complete": self.frames_sent == self.source.n_frames,
            "video_bytes": 0 if self.video is None else self.video.bytes,
            "mavlink": None if self.link is None else self.link.stats(),
            "error": None if self._error is None else f"{type(self._error).__name__}: {self._error}",
            "guided": None if self.follower is None else self.follower.stats(),
        }

    def __enter__(self) -> SitlVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
