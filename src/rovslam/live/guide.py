"""Navigation to points of interest through the autopilot: ``rovslam live --poi POI.csv [--guide]``.

The guidance law and the mission are those of ``rovslam navigate`` (:class:`rovslam.nav.guidance.Mission`,
:class:`~rovslam.nav.guidance.GuidanceConfig`), fed by the live estimate of every processed frame.
The command goes to ArduSub as SET_POSITION_TARGET_LOCAL_NED in ``MAV_FRAME_BODY_NED`` (vx
forward, vy starboard, m/s, the autopilot turns them by its own heading), ``type_mask``
:data:`VELOCITY_ONLY_MASK` (position, acceleration and yaw ignored: only vx, vy, vz = 0 and
the yaw rate are used), ``time_boot_ms`` the stream time of the frame it answers.

Without ``--guide`` nothing is sent to the autopilot but the mission's STATUSTEXT: the
commands are computed and logged (a dry run). With ``--guide`` a setpoint goes out only while

* the vehicle is armed and in GUIDED (ArduSub custom_mode 4), read from its HEARTBEAT;
* an estimate came less than ``0.5 s`` ago (video and filter alive);
* the vehicle's telemetry (ATTITUDE, HEARTBEAT) is not silent for more than ``0.5 s`` / ``3 s``;
* the 2-sigma ellipse is within ``GuidanceConfig.stop_ellipse_m``.

When one of these fails the guide stops: one zero-velocity setpoint at once (from a watchdog
thread checking every 50 ms, so within 0.2 s) if the vehicle is still armed in GUIDED, none
if the pilot left GUIDED or disarmed, then nothing until every condition holds again. Limits
are stretched by ``pace`` for a simulator run slower than real time (``rovslam sitl --pace``).
When the run ends while steering, a last zero-velocity setpoint is sent.

Files in OUT: ``navigation.csv`` and ``arrivals.csv`` (the columns of ``rovslam navigate``; the
true columns empty: ``rovslam sitl`` records the truth), ``setpoints.csv`` (every command,
sent or not, with why), ``guide.json`` at the end.
"""

from __future__ import annotations

import csv
import io
import json
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from rovslam.core import Goal
from rovslam.errors import InvalidArgumentError
from rovslam.nav.closed_loop import (
    ARRIVAL_COLUMNS,
    ArrivalBook,
    survey_around,
)
from rovslam.nav.dynamics import Command
from rovslam.nav.estimate import DeadReckoningCovariance, check_estimator, nav_estimate
from rovslam.nav.guidance import Arrival, GuidanceConfig, HoldEnd, Mission, ellipse_semi_major_m, saturate
from rovslam.navigate import NAVIGATION_COLUMNS, navigation_row

__all__ = ["GUIDED_MODE", "VELOCITY_ONLY_MASK", "Guide", "GuideOptions"]

GUIDED_MODE = 4  # ArduSub custom_mode
MAV_FRAME_BODY_NED = 8
# POSITION_TARGET_TYPEMASK: ignore x, y, z (1, 2, 4), ax, ay, az (64, 128, 256) and yaw (1024): velocity and yaw rate
VELOCITY_ONLY_MASK = 1 | 2 | 4 | 64 | 128 | 256 | 1024
ARMED_FLAG = 128  # MAV_MODE_FLAG_SAFETY_ARMED
LOST_S = 0.5  # video / estimate / telemetry silent longer than this: stop
HEARTBEAT_LOST_S = 3.0
WATCH_EVERY_S = 0.05
SETPOINT_COLUMNS = ("wall_s", "t_s", "vx_mps", "vy_mps", "yaw_rate_radps", "sent", "reason")


@dataclass(frozen=True)
class GuideOptions:
    """What ``rovslam live --poi`` was given."""

    pois: tuple[Goal, ...]
    guide: bool = False  # False: dry run
    survey_s: float = 0.0
    hold_s: float = 10.0
    estimator: str = "slam"  # or "dead-reckoning" (comparisons)
    pace: float = 1.0  # wall seconds per vehicle second (a simulator run slower than real time)
    guidance: GuidanceConfig | None = None  # None: GuidanceConfig(hold_s=hold_s)

    def __post_init__(self) -> None:
        check_estimator(self.estimator)
        if not self.pois:
            raise InvalidArgumentError("--poi: no point of interest to visit")
        for name, v in (("--survey-s", self.survey_s), ("--hold-s", self.hold_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidArgumentError(f"{name} must be a number of seconds >= 0, got {v!r}")
        if not (isinstance(self.pace, (int, float)) and math.isfinite(self.pace) and self.pace >= 1.0):
            raise InvalidArgumentError(f"--guide-pace must be a factor >= 1 (1: real time), got {self.pace!r}")

    @property
    def config(self) -> GuidanceConfig:
        return self.guidance if self.guidance is not None else GuidanceConfig(hold_s=float(self.hold_s))


def _f(v: Any) -> str:
    return (
        ""
        if v is None or (isinstance(v, float) and math.isnan(v))
        else (f"{v:.9g}" if isinstance(v, float) else str(v))
    )


@dataclass
class _Vehicle:
    """What the vehicle's HEARTBEAT said, and when."""

    armed: bool = False
    custom_mode: int | None = None
    heartbeat_s: float | None = None  # monotonic


@dataclass
class _Counts:
    setpoints_sent: int = 0
    zero_setpoints_sent: int = 0
    commands_logged: int = 0
    statustext_sent: int = 0
    stops: list = field(default_factory=list)


class Guide:
    """The mission on the live estimate, and the setpoints to the autopilot under the safety rules above.

    ``link`` is a :class:`rovslam.live.mavlink.MavlinkLink` (or anything with ``send``, ``listeners``,
    ``vehicle``, ``telemetry``). :meth:`on_frame` is called with each processed frame's result;
    :meth:`close` ends the watchdog and writes ``guide.json``.
    """

    def __init__(self, opts: GuideOptions, link: Any, out: Path, say: Callable[[str], None]) -> None:
        self.opts, self.link, self.out, self.say = opts, link, Path(out), say
        self.cfg = opts.config
        self.pace = float(opts.pace)
        self.vehicle = _Vehicle()
        self.counts = _Counts()
        self.mission: Mission | None = None
        self.book = ArrivalBook(list(opts.pois))
        self._dr = DeadReckoningCovariance()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._estimate_s: float | None = None  # monotonic time of the last estimate
        self._ellipse_m = 0.0
        self._engaged = False  # setpoints are flowing
        self.reason: str | None = "no estimate yet"
        self._surveying = False
        self._files: dict[str, Any] = {}
        self._writers: dict[str, Any] = {}
        self._t0 = time.monotonic()
        link.listeners.append(self._on_message)
        self._watch = threading.Thread(target=self._watchdog, name="rovslam-guide", daemon=True)
        self._watch.start()

    # ------------------------------------------------------------------ the vehicle's state
    def _on_message(self, kind: str, msg: Any, now: float) -> None:
        v = self.link.vehicle
        if kind != "HEARTBEAT" or v is None or msg.get_srcSystem() != v["system"] or msg.autopilot == 8:
            return
        if msg.get_srcComponent() != v["component"]:
            return
        with self._lock:
            self.vehicle.armed = bool(msg.base_mode & ARMED_FLAG)
            self.vehicle.custom_mode = int(msg.custom_mode)
            self.vehicle.heartbeat_s = now
            self._check(now)

    def block_reason(self, now: float) -> str | None:
        """Why no setpoint may go out now (None: they may)."""
        v, lim = self.vehicle, LOST_S * self.pace
        if not self.opts.guide:
            return "dry run"
        if v.heartbeat_s is None or now - v.heartbeat_s > HEARTBEAT_LOST_S * self.pace:
            return "telemetry lost (no HEARTBEAT)"
        silent = self.link.telemetry.silent_for_s(now)
        if silent is None or silent > lim:
            return "telemetry lost (no ATTITUDE)"
        if not v.armed:
            return "disarmed"
        if v.custom_mode != GUIDED_MODE:
            return "not in GUIDED"
        if self._estimate_s is None or now - self._estimate_s > lim:
            return "no estimate (video or filter lost)"
        if self._ellipse_m > self.cfg.stop_ellipse_m:
            return f"2-sigma ellipse {1000 * self._ellipse_m:.0f} mm wider than {1000 * self.cfg.stop_ellipse_m:.0f} mm"
        return None

    def _check(self, now: float) -> None:
        """Stop (one zero setpoint where the vehicle still listens) or resume as the conditions change."""
        reason = self.block_reason(now)
        if reason == self.reason:
            return
        was = self.reason
        self.reason = reason
        if reason is None:
            self._announce("guiding: setpoints resumed" if self.counts.setpoints_sent else "guiding: GUIDED, armed")
            return
        if self._engaged:
            self._engaged = False
            if self.vehicle.armed and self.vehicle.custom_mode == GUIDED_MODE:  # (as last heard, if telemetry is lost)
                self._send_setpoint(Command(), None, zero=True)
            self.counts.stops.append({"wall_s": now - self._t0, "reason": reason})
            self._announce(f"guiding stopped: {reason}")
        elif was is not None and reason not in ("dry run",) and not was.startswith("no estimate yet"):
            self.say(f"guide: waiting: {reason}")

    def _watchdog(self) -> None:
        while not self._stop.wait(WATCH_EVERY_S):
            with self._lock:
                self._check(time.monotonic())

    # ------------------------------------------------------------------ sending
    def _send_setpoint(self, cmd: Command, t_s: float | None, zero: bool = False) -> None:
        v = self.link.vehicle
        if v is None:
            return
        body = saturate(np.array([cmd.surge_mps, cmd.sway_mps]), self.cfg.max_speed_mps)
        r = max(-self.cfg.max_yaw_rate_radps, min(self.cfg.max_yaw_rate_radps, cmd.yaw_rate_radps))
        t_ms = round(1000.0 * t_s) if t_s is not None else self.link.time_boot_ms
        self.link.send(
            "SET_POSITION_TARGET_LOCAL_NED",
            {
                "time_boot_ms": max(0, t_ms),
                "target_system": v["system"],
                "target_component": v["component"],
                "coordinate_frame": MAV_FRAME_BODY_NED,
                "type_mask": VELOCITY_ONLY_MASK,
                "x": 0.0,
                "y": 0.0,
                "z": 0.0,
                "vx": float(body[0]),
                "vy": float(body[1]),
                "vz": 0.0,
                "afx": 0.0,
                "afy": 0.0,
                "afz": 0.0,
                "yaw": 0.0,
                "yaw_rate": float(r),
            },
        )
        self.counts.setpoints_sent += 1
        self.counts.zero_setpoints_sent += int(zero)
        self._log_setpoint(t_s, Command(float(body[0]), float(body[1]), float(r)), True, "stop" if zero else "")

    def _announce(self, text: str) -> None:
        """A mission event: on the console and as STATUSTEXT (at most 50 characters)."""
        self.say(f"guide: {text}")
        v = self.link.vehicle
        if v is None:
            return
        severity = 4 if ("stopped" in text or "abandoned" in text) else 6  # WARNING / INFO
        self.link.send("STATUSTEXT", {"severity": severity, "text": text[:50].encode("ascii", "replace")})
        self.counts.statustext_sent += 1

    # ------------------------------------------------------------------ frames
    def on_frame(self, res: Any) -> None:
        """One processed frame's result: the estimate, the mission, the command (sent when allowed)."""
        if not self._files:
            self._open_files()
        if res.skipped_reason is not None:  # a refused frame gives no estimate
            return
        est = nav_estimate(res, self.opts.estimator, self._dr)
        now = time.monotonic()
        with self._lock:
            self._estimate_s = now
            self._ellipse_m = ellipse_semi_major_m(est.cov_m2)
            self._check(now)
            active = self.reason is None or not self.opts.guide
            events: list = []
            if self.opts.guide and self.reason is not None:
                cmd = Command()
            else:
                cmd, events = self._update(est, res.dt_s)
            if self.opts.guide and self.reason is None:
                self._engaged = True
                self._send_setpoint(cmd, res.t_s)
            else:
                self._log_setpoint(res.t_s, cmd, False, self.reason or "")
        self._events(events)
        self._write_row(res.t_s, est, cmd, "paused" if not active else None)

    def _update(self, est: Any, dt_s: float) -> tuple[Command, list]:
        if self.mission is None:
            pts = np.array([g.xy_m for g in self.opts.pois if g.xy_m is not None]).reshape(-1, 2)
            survey = survey_around(pts, self.opts.survey_s, self.cfg.cruise_speed_mps)
            self.mission = Mission(survey + list(self.opts.pois), self.cfg, None, est.t_s + self.opts.survey_s)
            self._surveying = bool(survey)
            n = len(self.opts.pois)
            self._announce(
                f"mission: {'survey, then ' if survey else ''}{n} point{'s' if n > 1 else ''}"
                + ("" if self.opts.guide else " (dry run)")
            )
        if self.mission.done:
            return Command(), []
        cmd, events = self.mission.update(est, dt_s)
        if self._surveying and (self.mission.goal is None or self.mission.goal.kind != "survey"):
            self._surveying = False
            self._announce(f"survey done at t {est.t_s:.0f} s")
        return cmd, events

    def _events(self, events: list) -> None:
        for ev in events:
            if isinstance(ev, Arrival):
                hold = self.mission.goals[ev.goal_index].hold_s if self.mission is not None else None
                hold = self.cfg.hold_s if hold is None else hold
                self._announce(f"arrived {ev.name[:16]} 2sig {1000 * ev.ellipse_m:.0f}mm")
                self._announce(f"holding {ev.name[:16]} {hold:g}s")
            elif isinstance(ev, HoldEnd) and not ev.reached:
                self._announce(f"abandoned {ev.name[:16]}: {ev.reason}")
        if events:
            step = SimpleNamespace(
                truth=SimpleNamespace(x_m=math.nan, y_m=math.nan), nav=SimpleNamespace(events=events)
            )
            done = self.book.feed(step)  # type: ignore[arg-type]  # a loop step without truth (unknown live)
            if done or any(isinstance(e, Arrival) for e in events):
                self._write_arrivals()
            if self.mission is not None and self.mission.done:
                self._announce("mission done")

    # ------------------------------------------------------------------ files
    def _open_files(self) -> None:
        for name, cols in (("navigation.csv", NAVIGATION_COLUMNS), ("setpoints.csv", SETPOINT_COLUMNS)):
            fh = (self.out / name).open("w", newline="", encoding="utf-8")
            self._files[name] = fh
            self._writers[name] = csv.writer(fh, lineterminator="\n")
            self._writers[name].writerow(cols)
        self._write_arrivals()

    def _log_setpoint(self, t_s: float | None, cmd: Command, sent: bool, reason: str) -> None:
        w = self._writers.get("setpoints.csv")
        self.counts.commands_logged += 1
        if w is not None:
            w.writerow(
                [
                    _f(v)
                    for v in (
                        time.monotonic() - self._t0,
                        t_s,
                        cmd.surge_mps,
                        cmd.sway_mps,
                        cmd.yaw_rate_radps,
                        int(sent),
                        reason,
                    )
                ]
            )
            self._files["setpoints.csv"].flush()

    def _write_row(self, t_s: float, est: Any, cmd: Command, phase: str | None) -> None:
        m = self.mission
        row = navigation_row(
            t_s,
            phase or (m.phase if m is not None else "waiting"),
            m.p.index if m is not None else 0,
            m.target_xy_m if m is not None else None,
            est,
            cmd,
            m.current_mps if m is not None else np.full(2, math.nan),
        )
        self._writers["navigation.csv"].writerow([_f(v) for v in row])
        self._files["navigation.csv"].flush()

    def _write_arrivals(self) -> None:
        from rovslam.io.results import atomic_write_text

        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(ARRIVAL_COLUMNS)
        for r in self.book.table():
            w.writerow([_f(r.get(c)) for c in ARRIVAL_COLUMNS])
        atomic_write_text(self.out / "arrivals.csv", buf.getvalue())

    def summary(self) -> dict[str, Any]:
        c = self.counts
        return {
            "guide": self.opts.guide,
            "estimator": self.opts.estimator,
            "survey_s": self.opts.survey_s,
            "hold_s": self.opts.hold_s,
            "approach_gain_per_s": self.cfg.approach_gain_per_s,
            "pace": self.pace,
            "setpoints_sent": c.setpoints_sent,
            "zero_setpoints_sent": c.zero_setpoints_sent,
            "commands_computed": c.commands_logged,
            "statustext_sent": c.statustext_sent,
            "stops": list(c.stops),
            "arrivals": self.book.table(),
            "mission_done": bool(self.mission is not None and self.mission.done),
            "guidance": {k: getattr(self.cfg, k) for k in self.cfg.__dataclass_fields__},
        }

    def close(self) -> None:
        """Stop the watchdog, close the files, write ``guide.json`` (idempotent)."""
        self._stop.set()
        if self._watch.is_alive():
            self._watch.join(2.0)
        with self._lock:
            if self._engaged:  # the run ends while steering: the vehicle is told to stop
                self._engaged = False
                self._send_setpoint(Command(), None, zero=True)
                self._announce("guiding ended: stopped")
            for fh in self._files.values():
                if not fh.closed:
                    fh.close()
            if self._files:
                self._write_arrivals()
                (self.out / "guide.json").write_text(
                    json.dumps(self.summary(), indent=2, default=float) + "\n", encoding="utf-8"
                )
