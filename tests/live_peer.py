"""Test helpers of ``rovslam live``: a short simulated dive as an MPEG-TS video, and a MAVLink vehicle.

:class:`Vehicle` plays an ArduSub autopilot on loopback with pymavlink, built to the message
definitions: HEARTBEAT (submarine, ArduPilot), ATTITUDE and DISTANCE_SENSOR (downward), sent
from ``udpout`` to ``live``'s ``udpin``; it decodes and keeps every message ``live`` sends back.
Every thread stops by itself (a deadline) and every socket read has a timeout.
"""

from __future__ import annotations

import csv
import fractions
import math
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MAVLINK20", "1")

FPS = 10


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def make_dive(root: Path, frames: int = 40, seed: int = 0) -> tuple[Path, Path, Path]:
    """(sequence folder, MPEG-TS video of it at its frame times, camera file) of a short simulated dive."""
    from rovslam.sim.scenarios import simulate

    seq = root / "seq"
    if not (seq / "frames.csv").exists():
        simulate("portofino-short", seq, frames=frames, seed=seed)
    video = root / "dive.ts"
    if not video.exists():
        write_ts(seq, video)
    camera = root / "camera.toml"
    camera.write_text((seq / "sequence.toml").read_text(encoding="utf-8"), encoding="utf-8")
    return seq, video, camera


def sequence_images(seq: Path) -> list[tuple[float, np.ndarray]]:
    import cv2

    with (seq / "frames.csv").open(encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return [(float(r["t_s"]), cv2.cvtColor(cv2.imread(str(seq / r["image"])), cv2.COLOR_BGR2RGB)) for r in rows]


def encode_frames(
    container,
    images: list[tuple[float, np.ndarray]],
    pace_s: float | None = 0.0,
    stop_after: int | None = None,
    pause_s: float = 0.0,
) -> None:
    """Encode ``images`` (t_s, RGB) as H.264 into ``container``; ``pace_s`` between frames (None: their own times),
    ``pause_s`` after the first ``stop_after`` frames instead."""
    import av

    h, w = images[0][1].shape[:2]
    stream = container.add_stream("libx264", rate=FPS)
    stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
    stream.options = {"crf": "12", "preset": "ultrafast", "tune": "zerolatency", "g": "10"}
    tb = fractions.Fraction(1, 1000)
    stream.codec_context.time_base = tb
    for k, (t_s, img) in enumerate(images):
        frame = av.VideoFrame.from_ndarray(img, format="rgb24")
        frame.pts, frame.time_base = int(round(t_s * 1000)), tb
        if stop_after is not None and k == stop_after:  # a camera that resumes starts with a key frame
            frame.pict_type = av.video.frame.PictureType.I
        for packet in stream.encode(frame):
            container.mux(packet)
        step_s = (images[k + 1][0] - t_s if k + 1 < len(images) else 0.0) if pace_s is None else pace_s
        if step_s:
            time.sleep(pause_s if stop_after is not None and k + 1 == stop_after and pace_s is not None else step_s)
    for packet in stream.encode():
        container.mux(packet)


def write_ts(seq: Path, path: Path) -> None:
    import av

    with av.open(str(path), "w", format="mpegts") as c:
        encode_frames(c, sequence_images(seq))


def stream_udp(
    seq: Path,
    port: int,
    start_delay_s: float = 0.0,
    pace_s: float | None = None,
    stop_after: int | None = None,
    pause_s: float = 0.0,
) -> threading.Thread:
    """A thread streaming the dive as MPEG-TS to udp://127.0.0.1:port (a pause of ``pause_s`` after ``stop_after`` frames)."""
    import av

    images = sequence_images(seq)
    if stop_after is not None and pause_s:  # the camera's clock runs on: the frames of the pause are lost
        t_stop = images[stop_after - 1][0]
        images = images[:stop_after] + [im for im in images[stop_after:] if im[0] > t_stop + pause_s]

    def run() -> None:
        time.sleep(start_delay_s)
        with av.open(f"udp://127.0.0.1:{port}?pkt_size=1316", "w", format="mpegts") as c:
            encode_frames(c, images, pace_s, stop_after, pause_s)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


class Vehicle:
    """An ArduSub-like MAVLink peer: ``udpout`` to ``port``; keeps what it receives in ``received``.

    ``yaw_rad(t)``: the yaw it reports at its time ``t`` (s since it started); ``attitude_until_s``:
    it stops sending ATTITUDE then; ``garbage``: it also sends that many malformed packets;
    ``heartbeat``: False plays a vehicle that never answers; ``attitude_stop_after``: it stops
    sending ATTITUDE once it received that many VISION_POSITION_ESTIMATE. Garbage is sent once
    ``live`` answered (its HEARTBEAT), so that it reaches a bound socket.
    """

    def __init__(
        self,
        port: int,
        *,
        yaw_rad=lambda t: 0.3,
        altitude_m: float = 1.5,
        attitude_until_s: float = 1e9,
        garbage: int = 0,
        heartbeat: bool = True,
        lifetime_s: float = 120.0,
        rate_hz: float = 20.0,
        attitude_stop_after: int | None = None,
    ) -> None:
        from pymavlink import mavutil

        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", dialect="ardupilotmega", source_system=1, source_component=1
        )
        self.port = port
        self.yaw_rad, self.altitude_m = yaw_rad, altitude_m
        self.attitude_until_s, self.garbage, self.heartbeat = attitude_until_s, garbage, heartbeat
        self.rate_hz = rate_hz
        self.attitude_stop_after = attitude_stop_after
        self.attitude_stopped_at_s: float | None = None
        self.received: list = []
        self.sent_attitude = 0
        self._stop = threading.Event()
        self._deadline = time.monotonic() + lifetime_s
        self._t0 = time.monotonic()
        self._threads = [
            threading.Thread(target=self._send_loop, daemon=True),
            threading.Thread(target=self._recv_loop, daemon=True),
        ]
        for th in self._threads:
            th.start()

    def _send_loop(self) -> None:
        mav = self.conn.mav
        k = 0
        garbage_left = self.garbage
        rng = np.random.default_rng(7)
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            t = time.monotonic() - self._t0
            if self.heartbeat and k % int(self.rate_hz) == 0:
                mav.heartbeat_send(12, 3, 0, 0, 4)  # MAV_TYPE_SUBMARINE, MAV_AUTOPILOT_ARDUPILOTMEGA, active
            if (
                self.attitude_stop_after is not None
                and self.attitude_stopped_at_s is None
                and len(self.of_type("VISION_POSITION_ESTIMATE")) >= self.attitude_stop_after
            ):
                self.attitude_stopped_at_s = t
            if self.heartbeat and t < self.attitude_until_s and self.attitude_stopped_at_s is None:
                # the body rates with the angles, as an autopilot's gyros give them (live moves a sample on by them)
                yaw_rate = (self.yaw_rad(t + 1e-3) - self.yaw_rad(t - 1e-3)) / 2e-3
                mav.attitude_send(
                    int(t * 1000), 0.01, -0.02, math.remainder(self.yaw_rad(t), 2 * math.pi), 0.0, 0.0, yaw_rate
                )
                self.sent_attitude += 1
                if k % 2 == 0:
                    mav.distance_sensor_send(int(t * 1000), 20, 5000, int(round(self.altitude_m * 100)), 1, 0, 25, 4)
            if garbage_left > 0 and self.received:
                junk = bytes(rng.integers(0, 256, 40, dtype=np.uint8))
                self.conn.write(b"\xfd" + junk if garbage_left % 2 else b"\xfe\x09" + junk)
                garbage_left -= 1
            k += 1
            self._stop.wait(1.0 / self.rate_hz)

    def _recv_loop(self) -> None:
        while not self._stop.is_set() and time.monotonic() < self._deadline:
            try:
                m = self.conn.recv_match(blocking=True, timeout=0.2)
            except Exception:
                continue
            if m is not None and m.get_type() != "BAD_DATA":
                self.received.append((time.monotonic(), m))

    def of_type(self, kind: str) -> list:
        return [m for _, m in self.received if m.get_type() == kind]

    def close(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(2.0)
        self.conn.close()


def start_live(args: list[str], tmp: Path, name: str = "live") -> subprocess.Popen:
    out, err = (tmp / f"{name}.out").open("w"), (tmp / f"{name}.err").open("w")
    return subprocess.Popen(
        [sys.executable, "-m", "rovslam", "live", *args],
        stdout=out,
        stderr=err,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def finish(p: subprocess.Popen, tmp: Path, name: str = "live", timeout_s: float = 180) -> tuple[int, str, str]:
    try:
        rc = p.wait(timeout_s)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait(10)
        raise
    return rc, (tmp / f"{name}.out").read_text(), (tmp / f"{name}.err").read_text()


def rows(path: Path) -> list[dict]:
    with path.open(encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
