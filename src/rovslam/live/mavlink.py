"""The MAVLink link to the autopilot (pymavlink, MAVLink 2, dialect ardupilotmega).

rovslam speaks as a companion component, like a DVL's BlueOS extension: component id 197
(MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY) of the vehicle's own system, its HEARTBEAT at 1 Hz
(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID). In: the vehicle's HEARTBEAT, ATTITUDE,
DISTANCE_SENSOR facing down (orientation 25) and RANGEFINDER; when no ATTITUDE comes, they are
requested (MAV_CMD_SET_MESSAGE_INTERVAL). Packets that do not parse (garbage, a bad checksum,
an unknown message) are ignored and counted.
"""

from __future__ import annotations

import os
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

from rovslam.errors import InvalidArgumentError, RovslamError
from rovslam.live.telemetry import Telemetry

COMPONENT_ID = 197  # MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
MAV_CMD_SET_MESSAGE_INTERVAL = 511
ORIENTATION_DOWN = 25
MESSAGES_OUT = ("VISION_POSITION_DELTA", "VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE", "DISTANCE_SENSOR")
SHORT_NAMES = {
    "delta": "VISION_POSITION_DELTA",
    "position": "VISION_POSITION_ESTIMATE",
    "speed": "VISION_SPEED_ESTIMATE",
    "distance": "DISTANCE_SENSOR",
}
REQUESTED = ((30, 20.0), (132, 10.0), (173, 10.0))  # ATTITUDE, DISTANCE_SENSOR, RANGEFINDER (message id, Hz)
REQUEST_AFTER_S = 2.0
EARLY_KEPT = 200  # telemetry messages kept per system until its HEARTBEAT (ATTITUDE comes 10-50 times a second)
CONNECTION_FORMS = "udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT or /dev/ttyACM0,115200"


class VehicleNotFoundError(RovslamError):
    """No vehicle's HEARTBEAT arrived in time."""


def parse_mavlink_out(text: str | None) -> tuple[str, ...]:
    """``--mavlink-out``: names separated by commas (``delta,position,speed,distance``, the full message
    names, ``all`` or ``none``) -> the message names to send."""
    if text is None or text.strip().lower() == "all":
        return MESSAGES_OUT
    out: list[str] = []
    for word in (w.strip() for w in text.split(",")):
        if not word or word.lower() == "none":
            continue
        name = SHORT_NAMES.get(word.lower(), word.upper())
        if name not in MESSAGES_OUT:
            raise InvalidArgumentError(
                f"--mavlink-out: {word!r} is not a message rovslam sends; give some of "
                f"{', '.join(SHORT_NAMES)} (or {', '.join(MESSAGES_OUT)}), all or none, separated by commas."
            )
        out.append(name)
    return tuple(dict.fromkeys(out))


def open_connection(connection: str) -> Any:
    """A pymavlink connection (MAVLink 2, ardupilotmega, robust parsing); a refused string: InvalidArgumentError."""
    os.environ.setdefault("MAVLINK20", "1")  # the VISION_* covariance and reset_counter are MAVLink 2 extensions
    from pymavlink import mavutil

    try:
        return mavutil.mavlink_connection(
            connection,
            dialect="ardupilotmega",
            source_system=1,
            source_component=COMPONENT_ID,
            robust_parsing=True,
            autoreconnect=True,
        )
    except Exception as exc:  # pymavlink raises what its transport raises (OSError, serial's, ValueError)
        raise InvalidArgumentError(
            f"--mavlink {connection}: pymavlink cannot open it ({type(exc).__name__}: {str(exc).strip() or 'refused'}); "
            f"give {CONNECTION_FORMS}."
        ) from None


class MavlinkLink:
    """The receiver and heartbeat threads, the message counts, and the sends (thread-safe)."""

    def __init__(self, connection: str, telemetry: Telemetry, say: Callable[[str], None] = lambda s: None) -> None:
        self.connection = connection
        self.telemetry = telemetry
        self.say = say
        self.conn = open_connection(connection)
        self.counts_in: Counter[str] = Counter()
        self.counts_out: Counter[str] = Counter()
        self.bad_packets = 0
        self.vehicle: dict[str, int] | None = None
        self.requests = 0
        self.listeners: list[Callable[[str, Any, float], None]] = []  # called with every message (rovslam.live.guide)
        self._found = threading.Event()
        self._early: dict[int, deque] = {}  # system -> its latest telemetry received before its HEARTBEAT
        self._stop = threading.Event()
        self._send_lock = threading.Lock()
        self._t0 = time.monotonic()
        self._rx = threading.Thread(target=self._receive, name="rovslam-mavlink-rx", daemon=True)
        self._hb = threading.Thread(target=self._heartbeat, name="rovslam-mavlink-hb", daemon=True)
        self._rx.start()

    # ------------------------------------------------------------------ vehicle

    def wait_vehicle(self, timeout_s: float) -> dict[str, int]:
        """Wait for the vehicle's HEARTBEAT; start the heartbeat. Raises :class:`VehicleNotFoundError`."""
        if not self._found.wait(timeout_s):
            raise VehicleNotFoundError(
                f"--mavlink {self.connection}: no vehicle HEARTBEAT in {timeout_s:g} s (received: "
                f"{self._describe_in()}); check the connection string and that the autopilot (or BlueOS's "
                "MAVLink router) sends to it, or give a longer --heartbeat-timeout-s."
            )
        assert self.vehicle is not None
        self.conn.mav.srcSystem = self.vehicle["system"]
        self._hb.start()
        return self.vehicle

    def _describe_in(self) -> str:
        parts = [f"{n} {k}" for k, n in sorted(self.counts_in.items())]
        if self.bad_packets:
            parts.append(f"{self.bad_packets} packets that are not MAVLink")
        return ", ".join(parts) or "nothing"

    @property
    def time_boot_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000)

    # ------------------------------------------------------------------ threads

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.2)
            except Exception:  # a malformed packet pymavlink could not even report as BAD_DATA
                self.bad_packets += 1
                continue
            if msg is None:
                continue
            kind = msg.get_type()
            if kind in ("BAD_DATA", "UNKNOWN") or kind.startswith("UNKNOWN_"):
                self.bad_packets += 1
                continue
            self.counts_in[kind] += 1
            try:
                self._handle(kind, msg, time.monotonic())
                for listener in self.listeners:
                    listener(kind, msg, time.monotonic())
            except (AttributeError, TypeError, ValueError):
                self.bad_packets += 1

    def _handle(self, kind: str, msg: Any, now: float) -> None:
        sysid = msg.get_srcSystem()
        if kind == "HEARTBEAT":
            if (
                self.vehicle is None
                and msg.autopilot != MAV_AUTOPILOT_INVALID
                and msg.type not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER)
            ):
                self.vehicle = {
                    "system": int(sysid),
                    "component": int(msg.get_srcComponent()),
                    "type": int(msg.type),
                    "autopilot": int(msg.autopilot),
                }
                for kind_, msg_, now_ in self._early.pop(int(sysid), ()):  # its telemetry before its heartbeat
                    self._telemetry(kind_, msg_, now_)
                self._early.clear()
                self._found.set()
            return
        if self.vehicle is None:
            self._early.setdefault(int(sysid), deque(maxlen=EARLY_KEPT)).append((kind, msg, now))
            return
        if sysid == self.vehicle["system"]:
            self._telemetry(kind, msg, now)

    def _telemetry(self, kind: str, msg: Any, now: float) -> None:
        if kind == "ATTITUDE":
            self.telemetry.add_attitude(
                msg.time_boot_ms / 1000.0,
                float(msg.roll),
                float(msg.pitch),
                float(msg.yaw),
                now,
                (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed)),
            )
        elif kind == "DISTANCE_SENSOR" and msg.orientation == ORIENTATION_DOWN:
            d_cm = int(msg.current_distance)
            if msg.min_distance <= d_cm <= msg.max_distance and d_cm > 0:
                self.telemetry.add_altitude(msg.time_boot_ms / 1000.0, d_cm / 100.0, now)
        elif kind == "RANGEFINDER" and float(msg.distance) > 0:
            self.telemetry.add_altitude(None, float(msg.distance), now)

    def _heartbeat(self) -> None:
        next_request = time.monotonic() + REQUEST_AFTER_S
        while not self._stop.is_set():
            self._send(
                "HEARTBEAT",
                lambda mav: mav.heartbeat_send(
                    MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE
                ),
            )
            now = time.monotonic()
            silent = self.telemetry.silent_for_s(now)
            if now >= next_request and self.requests < 3 and (silent is None or silent > REQUEST_AFTER_S):
                self.request_telemetry()
                next_request = now + 5.0
            self._stop.wait(1.0)

    def request_telemetry(self) -> None:
        """Ask the autopilot for ATTITUDE, DISTANCE_SENSOR and RANGEFINDER (MAV_CMD_SET_MESSAGE_INTERVAL)."""
        assert self.vehicle is not None
        target = self.vehicle["system"]
        for msg_id, hz in REQUESTED:
            self._send(
                "COMMAND_LONG",
                lambda mav, m=msg_id, h=hz: mav.command_long_send(  # type: ignore[misc]
                    target, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0, m, 1e6 / h, 0, 0, 0, 0, 0
                ),
            )
        self.requests += 1
        if self.requests == 1:
            self.say(
                f"no ATTITUDE from system {target} for {REQUEST_AFTER_S:g} s: requested ATTITUDE, DISTANCE_SENSOR "
                "and RANGEFINDER (MAV_CMD_SET_MESSAGE_INTERVAL)"
            )

    # ------------------------------------------------------------------ sending

    def _send(self, kind: str, call: Callable[[Any], None]) -> None:
        with self._send_lock:
            try:
                call(self.conn.mav)
            except OSError:
                return  # the peer is not there (yet): a UDP send that failed is a lost datagram
            self.counts_out[kind] += 1

    def send(self, kind: str, fields: dict) -> None:
        """Send one message given by name and field values (``kind`` in :data:`MESSAGES_OUT`)."""
        fn = getattr(self.conn.mav, kind.lower() + "_send")
        self._send(kind, lambda mav: fn(**fields))

    def summary(self) -> dict[str, Any]:
        return {
            "vehicle": self.vehicle,
            "messages_in": dict(sorted(self.counts_in.items())),
            "messages_out": dict(sorted(self.counts_out.items())),
            "bad_packets_in": self.bad_packets,
            "telemetry_requests": self.requests,
        }

    def close(self) -> None:
        self._stop.set()
        for th in (self._rx, self._hb):
            if th.is_alive():
                th.join(2.0)
        try:
            self.conn.close()
        except OSError:
            pass
