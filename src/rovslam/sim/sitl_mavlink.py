"""The simulated vehicle's MAVLink side: an ArduSub autopilot's telemetry out, a sensor's messages in.

Out (system 1, component 1, dialect ardupilotmega, MAVLink 2): HEARTBEAT at 1 Hz (a submarine
run by ArduPilot, armed, in the mode given), SYSTEM_TIME at 1 Hz, and what :class:`MavlinkLink`'s
``send_*`` methods are called with: ATTITUDE, DISTANCE_SENSOR (downward) and RANGEFINDER.
Every ``time_boot_ms`` is on the stream's axis: 1000 x the presentation time of the video
(seconds from the first frame).

In: every VISION_POSITION_DELTA, VISION_POSITION_ESTIMATE, VISION_SPEED_ESTIMATE,
DISTANCE_SENSOR and STATUSTEXT from another system or component is a row of ``received.csv``
(:data:`RECEIVED_COLUMNS`; arrays as JSON lists), with its arrival time. SET_MESSAGE_INTERVAL
and REQUEST_MESSAGE commands are acknowledged (accepted), other commands refused as
unsupported; REQUEST_DATA_STREAM is taken without reply, as ArduSub does. Bytes that are no
MAVLink are counted and dropped.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rovslam.errors import SimulationError

__all__ = ["ARDUSUB_MODES", "MavlinkLink", "RECEIVED_COLUMNS", "RECORDED_TYPES", "check_connection", "read_received"]

ARDUSUB_MODES = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "CIRCLE": 7,
    "SURFACE": 9,
    "POSHOLD": 16,
    "MANUAL": 19,
}
RECORDED_TYPES = (
    "VISION_POSITION_DELTA",
    "VISION_POSITION_ESTIMATE",
    "VISION_SPEED_ESTIMATE",
    "DISTANCE_SENSOR",
    "STATUSTEXT",
)
# arrival_s: seconds on the stream's axis when the message arrived (empty before the first frame);
# unix_time_s: the wall clock then. The other columns are the message's fields (empty where it has none).
RECEIVED_COLUMNS = (
    "arrival_s",
    "unix_time_s",
    "type",
    "src_system",
    "src_component",
    "time_usec",
    "time_boot_ms",
    "x",
    "y",
    "z",
    "roll",
    "pitch",
    "yaw",
    "covariance",
    "reset_counter",
    "time_delta_usec",
    "angle_delta",
    "position_delta",
    "confidence",
    "current_distance",
    "min_distance",
    "max_distance",
    "sensor_type",
    "sensor_id",
    "orientation",
    "signal_quality",
    "severity",
    "text",
)
_RENAME = {"usec": "time_usec", "type": "sensor_type", "id": "sensor_id"}
_ARRAY_COLUMNS = ("covariance", "angle_delta", "position_delta")
_CONNECTION_FORMS = "udpin:HOST:PORT, udpout:HOST:PORT, udp:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or a serial device /dev/ttyX[,BAUD]"
OWN_SYSTEM, OWN_COMPONENT = 1, 1
MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE = 511, 512


def check_connection(connection: str) -> tuple[str, int | None]:
    """(pymavlink device, baud or None) of a ``--mavlink`` connection string, or SimulationError naming the forms."""
    text = str(connection).strip()
    m = re.fullmatch(r"(udpin|udpout|udp|tcp|tcpin):([^:\s]+):(\d{1,5})", text)
    if m:
        if not 0 < int(m.group(3)) < 65536:
            raise SimulationError(f"--mavlink {connection!r}: port {m.group(3)} is not 1 to 65535")
        return text, None
    m = re.fullmatch(r"(/dev/[^,\s]+|COM\d+)(?:,(\d+))?", text)
    if m:
        if text.startswith("/dev/") and not Path(m.group(1)).exists():
            raise SimulationError(f"--mavlink {connection!r}: no serial device {m.group(1)}")
        return m.group(1), int(m.group(2) or 115200)
    raise SimulationError(f"--mavlink {connection!r}: not a connection string; give {_CONNECTION_FORMS}")


def _mavutil():
    """pymavlink's mavutil with the ardupilotmega dialect in MAVLink 2 (its extension fields: covariance, reset_counter)."""
    os.environ.setdefault("MAVLINK20", "1")
    from pymavlink import mavutil

    if getattr(mavutil.mavlink, "WIRE_PROTOCOL_VERSION", "1.0") != "2.0" or mavutil.current_dialect != "ardupilotmega":
        os.environ["MAVLINK20"] = "1"
        mavutil.set_dialect("ardupilotmega")
    return mavutil


def _cell(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return json.dumps([float(v) for v in value])
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, float):
        return repr(value)
    return str(value).rstrip("\x00") if isinstance(value, str) else str(value)


def read_received(path: str | Path) -> list[dict[str, Any]]:
    """The rows of ``received.csv``: numbers as float (int for counters), arrays as lists, empty cells dropped."""
    out = []
    with Path(path).open(newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            rec: dict[str, Any] = {}
            for key, value in row.items():
                if value in ("", None):
                    continue
                if key in ("type", "text"):
                    rec[key] = value
                elif key in _ARRAY_COLUMNS:
                    rec[key] = json.loads(value)
                else:
                    number = float(value)
                    rec[key] = (
                        int(number) if number.is_integer() and key not in ("x", "y", "z", "arrival_s") else number
                    )
            out.append(rec)
    return out


class MavlinkLink:
    """One MAVLink connection as an ArduSub vehicle: heartbeat and receiving in a thread, telemetry sent on call.

    ``stream_time_s()``: the stream's clock now (seconds from the first frame), or None before it.
    """

    def __init__(
        self,
        connection: str,
        received_csv: Path,
        stream_time_s: Callable[[], float | None],
        mode: str = "ALT_HOLD",
        sonar_max_m: float = 50.0,
    ) -> None:
        if mode not in ARDUSUB_MODES:
            raise SimulationError(f"unknown ArduSub mode {mode!r}; choose one of: {', '.join(ARDUSUB_MODES)}")
        device, baud = check_connection(connection)
        mavutil = _mavutil()
        try:
            self._conn = mavutil.mavlink_connection(
                device,
                baud=baud or 115200,
                source_system=OWN_SYSTEM,
                source_component=OWN_COMPONENT,
                autoreconnect=True,
            )
        except (OSError, ValueError) as exc:
            raise SimulationError(f"--mavlink {connection!r}: cannot open it ({exc})") from None
        self._mav = self._conn.mav
        self._m = mavutil.mavlink
        self.connection = connection
        self.custom_mode = ARDUSUB_MODES[mode]
        self.armed = True
        self.handler: Callable[[Any, str], bool] | None = None  # answers first when set (rovslam.sim.sitl_guided)
        self.sonar_max_m = float(sonar_max_m)
        self._clock = stream_time_s
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._fh = Path(received_csv).open("w", newline="", encoding="utf-8")
        self._csv = csv.DictWriter(self._fh, RECEIVED_COLUMNS, lineterminator="\n")
        self._csv.writeheader()
        self._fh.flush()
        self.counts_in: Counter[str] = Counter()
        self.counts_out: Counter[str] = Counter()
        self.bad_packets = 0
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ out
    def _send(self, name: str, *args: Any) -> None:
        with self._lock:
            try:
                getattr(self._mav, f"{name.lower()}_send")(*args)
            except OSError:  # nobody listening (an ICMP refusal): the next message tries again
                return
            self.counts_out[name] += 1

    def _time_boot_ms(self, t_s: float) -> int:
        return max(0, int(round(1000.0 * t_s)))

    def send_heartbeat(self) -> None:
        m = self._m
        base = (
            m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | (m.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
            | m.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
            | m.MAV_MODE_FLAG_STABILIZE_ENABLED
        )
        self._send(
            "HEARTBEAT",
            m.MAV_TYPE_SUBMARINE,
            m.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            self.custom_mode,
            m.MAV_STATE_ACTIVE,
            3,
        )

    def send_attitude(
        self,
        t_s: float,
        roll_rad: float,
        pitch_rad: float,
        yaw_rad: float,
        rates_radps: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """ATTITUDE at ``t_s`` (stream seconds): roll, pitch, yaw (NED, within +-pi) in rad, body rates in rad/s."""
        yaw = (float(yaw_rad) + math.pi) % (2.0 * math.pi) - math.pi
        self._send(
            "ATTITUDE", self._time_boot_ms(t_s), float(roll_rad), float(pitch_rad), yaw, *map(float, rates_radps)
        )

    def send_sonar(self, t_s: float, altitude_m: float, sigma_m: float) -> None:
        """DISTANCE_SENSOR (ultrasound, downward, cm, covariance in cm^2) and RANGEFINDER (m) of one sonar reading."""
        m = self._m
        cm = int(round(100.0 * min(max(float(altitude_m), 0.0), self.sonar_max_m)))
        var_cm2 = min(254, int(round((100.0 * sigma_m) ** 2)))
        self._send(
            "DISTANCE_SENSOR",
            self._time_boot_ms(t_s),
            20,
            int(100 * self.sonar_max_m),
            cm,
            m.MAV_DISTANCE_SENSOR_ULTRASOUND,
            1,
            m.MAV_SENSOR_ROTATION_PITCH_270,
            var_cm2,
        )
        self._send("RANGEFINDER", float(altitude_m), 0.0)

    def send_system_time(self, t_s: float) -> None:
        self._send("SYSTEM_TIME", int(time.time() * 1e6), self._time_boot_ms(t_s))

    # ------------------------------------------------------------------ in
    def _record(self, msg: Any, name: str) -> None:
        t = self._clock()
        row: dict[str, str] = {
            "arrival_s": "" if t is None else f"{t:.6f}",
            "unix_time_s": f"{time.time():.6f}",
            "type": name,
            "src_system": str(msg.get_srcSystem()),
            "src_component": str(msg.get_srcComponent()),
        }
        for field in msg.get_fieldnames():
            if field in ("id", "type") and name != "DISTANCE_SENSOR":  # (a STATUSTEXT's id is its chunk sequence)
                continue
            key = _RENAME.get(field, field)
            if key in RECEIVED_COLUMNS and key not in row:
                row[key] = _cell(getattr(msg, field))
        self._csv.writerow(row)
        self._fh.flush()

    def _answer(self, msg: Any, name: str) -> None:
        if name == "COMMAND_LONG" and msg.target_system in (0, OWN_SYSTEM):
            m = self._m
            ok = msg.command in (MAV_CMD_SET_MESSAGE_INTERVAL, MAV_CMD_REQUEST_MESSAGE)
            result = m.MAV_RESULT_ACCEPTED if ok else m.MAV_RESULT_UNSUPPORTED
            self._send("COMMAND_ACK", msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def poll(self, timeout_s: float) -> None:
        """Receive for up to ``timeout_s``: record, answer, count (garbage dropped)."""
        try:
            msg = self._conn.recv_match(blocking=True, timeout=timeout_s)
        except (OSError, ValueError, TypeError, IndexError, KeyError, UnicodeDecodeError) as exc:  # a malformed packet
            del exc
            self.bad_packets += 1
            return
        while msg is not None:
            name = msg.get_type()
            if name == "BAD_DATA" or name.startswith("UNKNOWN"):
                self.bad_packets += 1
            elif (msg.get_srcSystem(), msg.get_srcComponent()) != (OWN_SYSTEM, OWN_COMPONENT):
                self.counts_in[name] += 1
                if name in RECORDED_TYPES:
                    self._record(msg, name)
                if self.handler is None or not self.handler(msg, name):
                    self._answer(msg, name)
            try:
                msg = self._conn.recv_match(blocking=False)
            except (OSError, ValueError, TypeError, IndexError, KeyError, UnicodeDecodeError):
                self.bad_packets += 1
                return

    def _run(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                next_beat = now + 1.0
                self.send_heartbeat()
                t = self._clock()
                if t is not None:
                    self.send_system_time(t)
            self.poll(min(0.1, max(0.0, next_beat - time.monotonic())))

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="rovslam-sitl-mavlink", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread, close the connection and the file (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if not self._fh.closed:
            self._fh.close()
            with self._lock:
                self._conn.close()

    def stats(self) -> dict[str, Any]:
        return {
            "connection": self.connection,
            "messages_in": dict(sorted(self.counts_in.items())),
            "messages_out": dict(sorted(self.counts_out.items())),
            "bad_packets": self.bad_packets,
        }
