"""``rovslam live --poi [--guide]``: the setpoints to the autopilot and every safety stop.

A small in-process peer stands for the vehicle: the guide's link records what it would send,
HEARTBEATs go through the link's listeners as the real receiver calls them, frames' results are
fed at 10 Hz. Every stop is checked with the wall times of the messages: a zero-velocity
setpoint within 0.2 s of the moment the rule is broken (or none at all when the pilot left
GUIDED or disarmed), then no setpoint until the rule holds again.
"""

from __future__ import annotations

import csv
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rovslam.core import Goal
from rovslam.live.guide import (
    GUIDED_MODE,
    LOST_S,
    VELOCITY_ONLY_MASK,
    Guide,
    GuideOptions,
)
from rovslam.nav.guidance import GuidanceConfig

MANUAL = 19
PERIOD_S = 0.1
SLACK_S = 0.2  # the stop's allowance


class FakeTelemetry:
    def __init__(self) -> None:
        self.last_s = time.monotonic()
        self.alive = True

    def silent_for_s(self, now: float) -> float | None:
        if self.alive:
            self.last_s = now
        return now - self.last_s


class FakeLink:
    """What the guide needs of :class:`rovslam.live.mavlink.MavlinkLink`; every send recorded with its time."""

    def __init__(self) -> None:
        self.listeners: list = []
        self.vehicle = {"system": 1, "component": 1}
        self.telemetry = FakeTelemetry()
        self.sent: list[tuple[float, str, dict]] = []
        self.lock = threading.Lock()
        self.time_boot_ms = 0

    def send(self, kind: str, fields: dict) -> None:
        with self.lock:
            self.sent.append((time.monotonic(), kind, dict(fields)))

    def heartbeat(self, armed: bool, mode: int) -> None:
        msg = SimpleNamespace(
            get_srcSystem=lambda: 1,
            get_srcComponent=lambda: 1,
            autopilot=3,
            base_mode=(128 if armed else 0) | 1,
            custom_mode=mode,
        )
        for listener in self.listeners:
            listener("HEARTBEAT", msg, time.monotonic())

    def setpoints(self, after_s: float = 0.0) -> list[tuple[float, dict]]:
        with self.lock:
            return [(t, f) for t, k, f in self.sent if k == "SET_POSITION_TARGET_LOCAL_NED" and t >= after_s]

    def texts(self) -> list[str]:
        with self.lock:
            return [f["text"].decode() for _, k, f in self.sent if k == "STATUSTEXT"]


def result(t_s: float, xy=(0.0, 0.0), sigma_m: float = 0.002, heading_rad: float = 0.0):
    """A frame's result as the pipeline gives it (what the guide reads of it)."""
    return SimpleNamespace(
        t_s=t_s,
        dt_s=PERIOD_S,
        x_m=xy[0],
        y_m=xy[1],
        cov_xy_m2=np.eye(2) * sigma_m**2,
        heading_rad=heading_rad,
        surge_mps=0.0,
        sway_mps=0.0,
        speed_ok=True,
        skipped_reason=None,
    )


class Feeder:
    """Frames' results at 10 Hz from a thread (``pause`` stops them: a stalled video), and a heartbeat at 1 Hz."""

    def __init__(self, guide: Guide, link: FakeLink, xy=(0.0, 0.0)) -> None:
        self.guide, self.link, self.xy = guide, link, xy
        self.sigma_m = 0.002
        self.armed, self.mode = True, GUIDED_MODE
        self.running = threading.Event()
        self.running.set()
        self.stop = threading.Event()
        self.k = 0
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        next_beat = 0.0
        while not self.stop.wait(PERIOD_S):
            if time.monotonic() >= next_beat:
                next_beat = time.monotonic() + 1.0
                self.link.heartbeat(self.armed, self.mode)
            if self.running.is_set():
                self.guide.on_frame(result(self.k * PERIOD_S, self.xy, self.sigma_m))
                self.k += 1

    def __enter__(self) -> Feeder:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(5.0)
        self.guide.close()


def make(
    tmp_path: Path, guide: bool = True, cfg: GuidanceConfig | None = None, pois=(Goal("rock", np.array([0.5, 0.2])),)
) -> tuple[Guide, FakeLink, list[str]]:
    link, said = FakeLink(), []
    g = Guide(GuideOptions(tuple(pois), guide=guide, hold_s=1.0, guidance=cfg), link, tmp_path, said.append)
    return g, link, said


def wait_until(predicate, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def test_dry_run_logs_the_commands_and_sends_no_setpoint(tmp_path):
    g, link, said = make(tmp_path, guide=False)
    with Feeder(g, link):
        time.sleep(1.0)
    assert link.setpoints() == []
    rows = list(csv.DictReader((tmp_path / "setpoints.csv").open()))
    assert len(rows) >= 7 and all(r["sent"] == "0" and r["reason"] == "dry run" for r in rows)
    assert float(rows[-1]["vx_mps"]) > 0.05  # towards the point (north), as it would be sent
    assert any("dry run" in s for s in said) and any("mission" in t for t in link.texts())
    assert (tmp_path / "navigation.csv").exists() and (tmp_path / "guide.json").exists()


def test_setpoints_carry_velocity_and_yaw_rate_only_within_the_limits(tmp_path):
    cfg = GuidanceConfig(
        max_speed_mps=0.12, cruise_speed_mps=0.12, max_yaw_rate_radps=0.05, heading_rad=2.0, hold_s=1.0
    )
    g, link, _ = make(tmp_path, cfg=cfg, pois=(Goal("far", np.array([5.0, -3.0])),))
    with Feeder(g, link):
        assert wait_until(lambda: len(link.setpoints()) >= 10)
    sps = [f for _, f in link.setpoints()]
    assert all(f["type_mask"] == VELOCITY_ONLY_MASK and f["coordinate_frame"] == 8 for f in sps)
    assert VELOCITY_ONLY_MASK & (8 | 16 | 32 | 2048) == 0 and VELOCITY_ONLY_MASK & (1 | 2 | 4 | 64 | 128 | 256 | 1024)
    speeds = [np.hypot(f["vx"], f["vy"]) for f in sps]
    assert max(speeds) <= 0.12 + 1e-9 and max(speeds) > 0.11
    assert max(abs(f["yaw_rate"]) for f in sps) == pytest.approx(0.05)
    assert all(f["vz"] == 0 and f["target_system"] == 1 for f in sps)


def test_never_a_setpoint_while_disarmed(tmp_path):
    g, link, _ = make(tmp_path)
    with Feeder(g, link) as feed:
        feed.armed = False
        time.sleep(1.5)
        assert link.setpoints() == []
        feed.armed = True
        assert wait_until(lambda: len(link.setpoints()) >= 3)
        feed.armed = False
        link.heartbeat(False, GUIDED_MODE)  # the pilot disarms
        t_off = time.monotonic()
        time.sleep(1.0)
    assert link.setpoints(t_off + 0.05) == []
    assert any("disarmed" in t for t in link.texts())


def test_leaving_guided_mid_transit_stops_the_setpoints_until_guided_again(tmp_path):
    g, link, _ = make(tmp_path)
    with Feeder(g, link) as feed:
        assert wait_until(lambda: len(link.setpoints()) >= 5)
        feed.mode = MANUAL
        link.heartbeat(True, MANUAL)  # the pilot switches to MANUAL on the joystick
        t_off = time.monotonic()
        time.sleep(1.5)
        during = link.setpoints(t_off + 0.05)
        feed.mode = GUIDED_MODE
        link.heartbeat(True, GUIDED_MODE)
        t_on = time.monotonic()
        assert wait_until(lambda: len(link.setpoints(t_on)) >= 3)
    assert during == []  # no setpoint at all outside GUIDED (not even a zero one: the pilot has the vehicle)
    assert any("not in GUIDED" in t for t in link.texts()) and any("resumed" in t for t in link.texts())
    assert (
        np.hypot(link.setpoints(t_on)[0][1]["vx"], link.setpoints(t_on)[0][1]["vy"]) > 0.05
    )  # (the last: the end's stop)


def _zero_then_silence(link: FakeLink, t_break: float, quiet_s: float) -> None:
    """After ``t_break`` (the rule broken): setpoints only until LOST_S, then one zero setpoint within LOST_S + 0.2 s,
    then none for ``quiet_s``."""
    time.sleep(LOST_S + SLACK_S + quiet_s)
    after = link.setpoints(t_break + 0.001)
    zeros = [(t, f) for t, f in after if f["vx"] == 0 and f["vy"] == 0 and f["yaw_rate"] == 0]
    assert len(zeros) == 1, [(round(t - t_break, 3), f["vx"]) for t, f in after]
    t_zero = zeros[0][0]
    assert t_zero - t_break <= LOST_S + SLACK_S, t_zero - t_break
    assert all(t < t_break + LOST_S for t, f in after if t < t_zero)
    assert link.setpoints(t_zero + 0.001) == []


def test_video_stall_sends_zero_then_nothing_and_resumes(tmp_path):
    g, link, _ = make(tmp_path)
    with Feeder(g, link) as feed:
        assert wait_until(lambda: len(link.setpoints()) >= 5)
        feed.running.clear()  # no frame: the video stalled
        t_break = link.setpoints()[-1][0]
        _zero_then_silence(link, t_break, 1.0)
        feed.running.set()
        t_on = time.monotonic()
        assert wait_until(lambda: len(link.setpoints(t_on)) >= 3)
    assert any("no estimate" in t for t in link.texts())


def test_ellipse_too_wide_stops_and_resumes_when_it_shrinks(tmp_path):
    cfg = GuidanceConfig(stop_ellipse_m=0.05, hold_s=1.0)
    g, link, _ = make(tmp_path, cfg=cfg)
    with Feeder(g, link) as feed:
        assert wait_until(lambda: len(link.setpoints()) >= 5)
        feed.sigma_m = 0.03  # 2-sigma 60 mm > 50 mm
        t_set = time.monotonic()
        assert wait_until(lambda: any(f["vx"] == 0 for _, f in link.setpoints(t_set)), 1.0)
        t_zero = next(t for t, f in link.setpoints(t_set) if f["vx"] == 0)
        time.sleep(1.0)
        assert len(link.setpoints(t_zero + 0.001)) == 0
        assert t_zero - t_set <= PERIOD_S + SLACK_S
        feed.sigma_m = 0.002
        t_on = time.monotonic()
        assert wait_until(lambda: len(link.setpoints(t_on)) >= 3)
    assert any("ellipse" in t for t in link.texts())


def test_telemetry_loss_sends_zero_then_nothing(tmp_path):
    g, link, _ = make(tmp_path)
    with Feeder(g, link):
        assert wait_until(lambda: len(link.setpoints()) >= 5)
        link.telemetry.alive = False  # ATTITUDE stops (frames still come)
        t_break = time.monotonic()
        _zero_then_silence(link, t_break, 1.0)
        link.telemetry.alive = True
        t_on = time.monotonic()
        assert wait_until(lambda: len(link.setpoints(t_on)) >= 3)
    assert any("telemetry lost" in t for t in link.texts())


def test_arrival_is_announced_with_the_name_and_written(tmp_path):
    cfg = GuidanceConfig(settle_s=0.3, hold_s=0.5)
    g, link, _ = make(tmp_path, cfg=cfg, pois=(Goal("red rock", np.array([0.0, 0.001])),))
    with Feeder(g, link):
        assert wait_until(lambda: any("mission done" in t for t in link.texts()), 5.0)
    arrived = [t for t in link.texts() if "arrived" in t]
    assert len(arrived) == 1 and "red rock" in arrived[0] and "2sig 4mm" in arrived[0]
    assert any("holding red rock" in t for t in link.texts())
    rows = list(csv.DictReader((tmp_path / "arrivals.csv").open()))
    assert rows[0]["name"] == "red rock" and float(rows[0]["est_err_m"]) == pytest.approx(0.001)


def _live_cli(tmp_path, *extra):
    import subprocess
    import sys

    return subprocess.run(
        [
            sys.executable,
            "-m",
            "rovslam",
            "live",
            "--video",
            "udp://127.0.0.1:9",
            "--camera",
            str(tmp_path / "cam.toml"),
            "--mavlink",
            "udpin:127.0.0.1:9",
            "--out",
            str(tmp_path / "o"),
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_guide_without_poi_and_a_bad_poi_file_are_one_line_errors(tmp_path):
    p = _live_cli(tmp_path, "--guide")
    assert p.returncode == 2 and "--guide needs --poi" in p.stderr and "Traceback" not in p.stderr
    bad = tmp_path / "poi.csv"
    bad.write_text("name,x_m,y_m\nrock,0.1,\n", encoding="utf-8")
    p = _live_cli(tmp_path, "--poi", str(bad), "--guide")
    assert p.returncode == 2 and "poi.csv, line 2" in p.stderr and "Traceback" not in p.stderr
    p = _live_cli(tmp_path, "--approach-gain-per-s", "0.3")
    assert p.returncode == 2 and "--approach-gain-per-s needs --poi" in p.stderr and "Traceback" not in p.stderr
    good = tmp_path / "good.csv"
    good.write_text("name,x_m,y_m\nrock,0.1,0\n", encoding="utf-8")
    p = _live_cli(tmp_path, "--poi", str(good), "--guide", "--approach-gain-per-s", "-1")
    assert (
        p.returncode == 2 and "--approach-gain-per-s must be a number > 0" in p.stderr and "Traceback" not in p.stderr
    )


def test_the_end_of_the_run_while_steering_sends_a_last_zero_setpoint(tmp_path):
    g, link, _ = make(tmp_path)
    with Feeder(g, link):
        assert wait_until(lambda: len(link.setpoints()) >= 3)
    last = link.setpoints()[-1][1]
    assert last["vx"] == 0 and last["vy"] == 0 and last["yaw_rate"] == 0
    assert "guiding ended: stopped" in link.texts()
