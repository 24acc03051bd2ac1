"""``rovslam sitl --follow-guided``: the simulated vehicle obeys an autopilot's commands and velocity setpoints.

:class:`GuidedFollower` plays ArduSub's side of a guided mission:

* SET_MODE and COMMAND_LONG (MAV_CMD_DO_SET_MODE 176, MAV_CMD_COMPONENT_ARM_DISARM 400) are
  answered with COMMAND_ACK (accepted for the modes of :data:`~rovslam.sim.sitl_mavlink.ARDUSUB_MODES`,
  e.g. GUIDED 4 and MANUAL 19; denied otherwise); the HEARTBEAT reports the mode and the armed flag
  (sent at once after a change);
* SET_POSITION_TARGET_LOCAL_NED with its velocity (MAV_FRAME_BODY_NED: vx forward, vy starboard;
  MAV_FRAME_LOCAL_NED: north, east, turned into the body frame by the true heading) and yaw rate
  is flown, while armed and in GUIDED, through :mod:`rovslam.nav.dynamics` (the model of
  ``rovslam navigate``, with the preset's current); a setpoint older than 3 s (ArduSub's guided
  timeout), a mode other than GUIDED or a disarmed vehicle: zero velocity (station keeping,
  drifting with the current);
* each frame is rendered from the true state (:class:`~rovslam.sim.live.LiveSimulator`, as
  :class:`~rovslam.nav.closed_loop.ClosedLoop` does) half a frame period after the previous one
  went out, or as soon as the setpoint answering it (its ``time_boot_ms``) arrives;
* every STATUSTEXT is a row of ``TRUTH/events.csv``: ``t_s,text,x_true_m,y_true_m`` (the true
  position when it arrived);
* ``pilot_guided_s``: the simulated pilot arms and switches to GUIDED at that stream time.
"""

from __future__ import annotations

import csv
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import SimulationError
from rovslam.sim.sitl_frames import FrameSource, SitlFrame

__all__ = ["EVENT_COLUMNS", "GuidedFollower", "read_events"]

EVENT_COLUMNS = ("t_s", "text", "x_true_m", "y_true_m")
MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM = 176, 400
MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_NED = 1, 8
SETPOINT_TIMEOUT_S = 3.0
GUIDED = 4
ANSWER_WAIT = 0.5  # of a frame period: the longest wait for the answer to the last frame before rendering the next


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """The rows of ``events.csv`` (numbers as float)."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        return [
            {
                "t_s": float(r["t_s"]),
                "text": r["text"],
                "x_true_m": float(r["x_true_m"]),
                "y_true_m": float(r["y_true_m"]),
            }
            for r in csv.DictReader(fh)
        ]


class GuidedFollower:
    """The vehicle's state, its commands, and the frames rendered from it (``source``), for ``SitlVehicle``."""

    def __init__(
        self, scenario: str, seed: int, duration_s: float | None, out: Path, pilot_guided_s: float | None = None
    ) -> None:
        from rovslam.core import Goal
        from rovslam.nav.closed_loop import mission_area_m
        from rovslam.nav.dynamics import DynamicsParams, SimulatedVehicle
        from rovslam.sim.live import LiveSimulator
        from rovslam.sim.scenarios import SCENARIOS

        if scenario not in SCENARIOS:
            raise SimulationError(f"--scenario: unknown preset {scenario!r}; choose one of: {', '.join(SCENARIOS)}")
        if pilot_guided_s is not None and not (math.isfinite(pilot_guided_s) and pilot_guided_s >= 0):
            raise SimulationError(f"--pilot-guided-s must be a number of seconds >= 0, got {pilot_guided_s}")
        sc = self.scenario = SCENARIOS[scenario]
        hx, hy = sc.grid.half_size_m
        corners = [Goal("c", np.array([sx * (hx + 0.3), sy * (hy + 0.3)])) for sx in (-1, 1) for sy in (-1, 1)]
        self.sim = LiveSimulator(sc, int(seed), area_m=mission_area_m(sc, corners))
        self.vehicle = SimulatedVehicle(
            DynamicsParams.from_vehicle(sc.vehicle), int(seed), heading_rad=sc.vehicle.heading_rad
        )
        d = sc.duration_s if duration_s is None else float(duration_s)
        if not (d >= 0 and math.isfinite(d)):
            raise SimulationError(f"--duration-s must be a number of seconds >= 0, got {duration_s}")
        self.n_frames = max(1, int(math.floor(d * sc.frame_rate_hz + 1e-9)) + 1)
        self.pilot_guided_s = pilot_guided_s
        self.out = Path(out)
        self.armed = False
        self.custom_mode: int | None = None  # None: the link's
        self.link: Any = None
        self.clock: Callable[[], float | None] = lambda: None
        self.stopped: Callable[[], bool] = lambda: False
        self._lock = threading.Lock()
        self._answer = threading.Event()
        self._setpoint: tuple[float, float, float, int, float] | None = None  # vx, vy, r (body), answered ms, when (s)
        self._waiting_ms = -1
        self.truth_xy_m = (0.0, 0.0)
        self.setpoints = 0
        self.setpoints_flown = 0
        self._events_fh: Any = None

    # ------------------------------------------------------------------ wiring
    def attach(self, link: Any, clock: Callable[[], float | None], stopped: Callable[[], bool]) -> None:
        """Take the vehicle's MAVLink link (its handler, mode and armed flag), the stream clock and the stop flag."""
        self.link, self.clock, self.stopped = link, clock, stopped
        if self.custom_mode is not None:
            link.custom_mode = self.custom_mode
        link.armed = self.armed
        link.handler = self.handle
        self.out.mkdir(parents=True, exist_ok=True)
        self._events_fh = (self.out / "events.csv").open("w", newline="", encoding="utf-8")
        self._events = csv.writer(self._events_fh, lineterminator="\n")
        self._events.writerow(EVENT_COLUMNS)
        self._events_fh.flush()

    def stats(self) -> dict[str, Any]:
        """What ``sitl.json`` says of the guided flight."""
        return {
            "armed": self.armed,
            "custom_mode": None if self.link is None else self.link.custom_mode,
            "setpoints_received": self.setpoints,
            "frames_flown_on_a_setpoint": self.setpoints_flown,
        }

    def close(self) -> None:
        if self._events_fh is not None and not self._events_fh.closed:
            self._events_fh.close()

    def _set(self, armed: bool | None = None, mode: int | None = None) -> None:
        link = self.link
        if armed is not None:
            self.armed = link.armed = bool(armed)
        if mode is not None:
            link.custom_mode = int(mode)
        if mode is not None and mode != GUIDED or armed is False:
            self._setpoint = None  # leaving GUIDED (or disarming) stops at once
        link.send_heartbeat()

    @property
    def guided(self) -> bool:
        return self.armed and self.link is not None and self.link.custom_mode == GUIDED

    # ------------------------------------------------------------------ messages
    def handle(self, msg: Any, name: str) -> bool:
        """A message from another component: True when answered here (the link's own answer is skipped)."""
        from rovslam.sim.sitl_mavlink import ARDUSUB_MODES

        link, m = self.link, self.link._m
        if name == "STATUSTEXT":
            t = self.clock()
            text = msg.text.decode("utf-8", "replace") if isinstance(msg.text, bytes) else str(msg.text)
            with self._lock:
                x, y = self.truth_xy_m
            self._events.writerow([f"{t or 0.0:.3f}", text.rstrip("\x00"), repr(x), repr(y)])
            self._events_fh.flush()
            return False
        if name == "SET_MODE":
            ok = int(msg.custom_mode) in ARDUSUB_MODES.values()
            with self._lock:
                if ok:
                    self._set(mode=int(msg.custom_mode))
            link._send(
                "COMMAND_ACK",
                11,
                m.MAV_RESULT_ACCEPTED if ok else m.MAV_RESULT_DENIED,
                0,
                0,
                msg.get_srcSystem(),
                msg.get_srcComponent(),
            )
            return True
        if name == "COMMAND_LONG" and msg.command in (MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM):
            with self._lock:
                if msg.command == MAV_CMD_COMPONENT_ARM_DISARM:
                    ok = msg.param1 in (0.0, 1.0)
                    if ok:
                        self._set(armed=msg.param1 == 1.0)
                else:
                    ok = int(msg.param2) in ARDUSUB_MODES.values()
                    if ok:
                        self._set(mode=int(msg.param2))
            link._send(
                "COMMAND_ACK",
                msg.command,
                m.MAV_RESULT_ACCEPTED if ok else m.MAV_RESULT_DENIED,
                0,
                0,
                msg.get_srcSystem(),
                msg.get_srcComponent(),
            )
            return True
        if name == "SET_POSITION_TARGET_LOCAL_NED":
            self._setpoint_in(msg)
            return True
        return False

    def _setpoint_in(self, msg: Any) -> None:
        self.setpoints += 1
        with self._lock:
            if not self.guided or msg.coordinate_frame not in (MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_NED):
                return
            vx, vy = float(msg.vx), float(msg.vy)
            if msg.type_mask & 8:  # velocity ignored: a stop
                vx = vy = 0.0
            if msg.coordinate_frame == MAV_FRAME_LOCAL_NED:
                psi = self.vehicle.state.heading_rad
                c, s = math.cos(psi), math.sin(psi)
                vx, vy = c * vx + s * vy, -s * vx + c * vy
            r = 0.0 if msg.type_mask & 2048 else float(msg.yaw_rate)
            self._setpoint = (vx, vy, r, int(msg.time_boot_ms), self.clock() or 0.0)
            if int(msg.time_boot_ms) >= self._waiting_ms:
                self._answer.set()

    def command(self, t_s: float):
        """The velocity command flown now: the setpoint while armed in GUIDED and fresh, else zero (station keeping)."""
        from rovslam.nav.dynamics import Command

        with self._lock:
            sp = self._setpoint
            if sp is None or not self.guided or t_s - sp[4] > SETPOINT_TIMEOUT_S:
                return Command()
            self.setpoints_flown += 1
            return Command(sp[0], sp[1], sp[2])

    # ------------------------------------------------------------------ frames
    def source(self) -> FrameSource:
        """The frames, each rendered from the state the commands have led to."""
        sc = self.sim.scenario
        return FrameSource(
            self.sim.info,
            float(sc.frame_rate_hz),
            float(sc.nav.sonar_sigma_m),
            self.n_frames,
            self.sim.world.relief is not None,
            self._frames(),
        )

    def _wait_for_answer(self, t_prev_s: float, dt_s: float) -> None:
        """Until frame ``t_prev_s`` is out and its setpoint came (or half a period passed, or the dive stops)."""
        with self._lock:
            self._waiting_ms = round(1000.0 * t_prev_s)
            self._answer.clear()
        while not self.stopped():
            t = self.clock()
            if t is not None and t >= t_prev_s:
                break
            time.sleep(0.005)
        while not self.stopped():
            t = self.clock()
            if (t is not None and t >= t_prev_s + ANSWER_WAIT * dt_s) or self._answer.wait(0.005):
                return

    def _pilot(self, t_s: float) -> None:
        if self.pilot_guided_s is not None and t_s >= self.pilot_guided_s and self.link is not None:
            self.pilot_guided_s = None
            with self._lock:
                self._set(armed=True, mode=GUIDED)

    def _frames(self) -> Iterator[SitlFrame]:
        dt = self.sim.frame_period_s
        try:
            for k in range(self.n_frames):
                if k > 0:
                    self._wait_for_answer((k - 1) * dt, dt)
                    self._pilot(k * dt)
                    self.vehicle.advance(self.command(k * dt), dt)
                truth = replace(self.vehicle.true_state(), t_s=k * dt)
                with self._lock:
                    self.truth_xy_m = (truth.x_m, truth.y_m)
                f = self.sim.capture(k, truth)
                assert f.image is not None  # (a rendered frame always has its image)
                gt: tuple[float, ...] = (truth.x_m, truth.y_m, truth.altitude_m, truth.heading_rad)
                if self.sim.world.relief is not None:
                    gt += (self.sim.relief_height_m(truth.x_m, truth.y_m),)
                yield SitlFrame(
                    k,
                    k * dt,
                    f.image,
                    float(f.heading_rad),
                    f.sonar_altitude_m,
                    float(f.roll_rad),
                    float(f.pitch_rad),
                    gt,
                )
        finally:
            self.sim.close()
