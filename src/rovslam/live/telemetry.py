"""The autopilot's telemetry by time: attitude and altitude samples interpolated (or moved on by the rates) to a frame's time.

Pure bookkeeping (no sockets): :mod:`rovslam.live.mavlink` feeds it, the live source reads it.
Look-ups are at local monotonic times (seconds). A vehicle's own time stamps (``time_boot_ms``)
are put on that clock by :class:`ClockMap`: the smallest ``arrival - sent`` seen so far is the
offset (the one-way delay's floor), so the jitter of the network does not move the samples.
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from typing import Any

ATTITUDE_HOLD_S = 0.3  # a frame this far past the newest attitude sample still gets it (held)
ALTITUDE_HOLD_S = 1.0  # the sonar reports slower than the AHRS
TELEMETRY_GAP_S = 1.0  # no attitude for this long: a telemetry gap
LATE_WAIT_S = 0.5  # a frame waits at most this long for the attitude sample after it (then the last one is held)
SNAP_S = 0.01  # a sample this close to a frame's time is the frame's
EXTRAPOLATE_S = 0.1  # a frame this far past the newest attitude sample gets it moved on by its rates, without waiting
KEEP_S = 300.0  # samples kept: a loop that lags (every frame processed) still finds its frames'


class ClockMap:
    """Maps a sender's clock (seconds) to the local clock; restarts when the sender's clock jumps back."""

    def __init__(self) -> None:
        self.offset_s: float | None = None
        self._last_remote_s: float | None = None

    def local_s(self, remote_s: float, arrival_s: float) -> float:
        if self._last_remote_s is not None and remote_s < self._last_remote_s - 1.0:
            self.offset_s = None  # the vehicle rebooted
        self._last_remote_s = remote_s
        d = arrival_s - remote_s
        self.offset_s = d if self.offset_s is None else min(self.offset_s, d)
        return remote_s + self.offset_s


class TimeSeries:
    """Samples of a few values by time; ``at(t)`` interpolates linearly (angles: unwrap them first).

    ``hold_s``: a time past the newest sample by at most this gets the newest; farther, None.
    """

    def __init__(self, hold_s: float, keep_s: float = KEEP_S) -> None:
        self.hold_s = float(hold_s)
        self.keep_s = float(keep_s)
        self.t_s: list[float] = []
        self.values: list[tuple[float, ...]] = []

    def add(self, t_s: float, values: tuple[float, ...]) -> None:
        if not all(math.isfinite(v) for v in (t_s, *values)):
            return
        if self.t_s and t_s <= self.t_s[-1]:
            if t_s < self.t_s[-1] - 1.0:  # the clock restarted: start again
                self.t_s.clear()
                self.values.clear()
            else:
                return
        self.t_s.append(float(t_s))
        self.values.append(tuple(float(v) for v in values))
        if self.t_s[0] < t_s - self.keep_s:
            cut = bisect.bisect_left(self.t_s, t_s - self.keep_s)
            del self.t_s[:cut], self.values[:cut]

    @property
    def last(self) -> tuple[float, ...] | None:
        return self.values[-1] if self.values else None

    def at(self, t_s: float) -> tuple[float, ...] | None:
        """The values at ``t_s`` (interpolated, or held within ``hold_s`` of the nearest end); None without.

        A sample within :data:`SNAP_S` of ``t_s`` is taken as it is: an autopilot that samples with the
        camera gives the frame's own reading, which the clock maps' few milliseconds of error would
        otherwise blend with its neighbour's.
        """
        ts = self.t_s
        if not ts:
            return None
        k = bisect.bisect_left(ts, t_s)
        near = min((j for j in (k - 1, k) if 0 <= j < len(ts)), key=lambda j: abs(ts[j] - t_s))
        if abs(ts[near] - t_s) <= SNAP_S:
            return self.values[near]
        if t_s >= ts[-1]:
            return self.values[-1] if t_s - ts[-1] <= self.hold_s else None
        if t_s <= ts[0]:
            return self.values[0] if ts[0] - t_s <= self.hold_s else None
        k = bisect.bisect_right(ts, t_s)
        t0, t1 = ts[k - 1], ts[k]
        if t1 - t0 > 2 * self.hold_s + TELEMETRY_GAP_S:  # inside a gap: nothing to interpolate between
            return None
        w = (t_s - t0) / (t1 - t0)
        return tuple(a + w * (b - a) for a, b in zip(self.values[k - 1], self.values[k]))


def unwrap_to(angle_rad: float, previous_rad: float | None) -> float:
    """``angle_rad`` plus the whole turns that bring it nearest ``previous_rad``."""
    if previous_rad is None:
        return float(angle_rad)
    return float(angle_rad + 2 * math.pi * round((previous_rad - angle_rad) / (2 * math.pi)))


class Telemetry:
    """Attitude (roll, pitch, unwrapped yaw) and altitude samples, thread-safe; gaps and counts.

    Samples are kept on the vehicle's clock (``remote_s``: its ``time_boot_ms``) and looked up at
    a local time through the :class:`ClockMap` as it stands at the look-up: a receiver thread that
    was late for a while (the GIL, a loaded machine) moves no sample. An altitude without a time
    stamp (RANGEFINDER) is kept on the local clock at its arrival.
    """

    def __init__(self) -> None:
        self._lock = threading.Condition()
        self.clock = ClockMap()
        self.attitude = TimeSeries(ATTITUDE_HOLD_S)
        self.altitude = TimeSeries(ALTITUDE_HOLD_S)
        self.altitude_local = TimeSeries(ALTITUDE_HOLD_S)
        self.gaps: list[dict[str, float]] = []
        self._last_attitude_arrival_s: float | None = None
        self.first_attitude_s: float | None = None

    def add_attitude(
        self,
        remote_s: float,
        roll_rad: float,
        pitch_rad: float,
        yaw_rad: float,
        arrival_s: float,
        rates_rad_s: tuple[float, float, float] | None = None,
    ) -> None:
        """An ATTITUDE sample; ``rates_rad_s``: its (roll, pitch, yaw) rates (None: unknown, taken as 0)."""
        rates = (0.0, 0.0, 0.0) if rates_rad_s is None else tuple(float(r) for r in rates_rad_s)
        if not all(math.isfinite(r) for r in rates):
            rates = (0.0, 0.0, 0.0)
        with self._lock:
            self.clock.local_s(remote_s, arrival_s)
            prev = self.attitude.last
            yaw = unwrap_to(yaw_rad, prev[2] if prev else None)
            self.attitude.add(remote_s, (roll_rad, pitch_rad, yaw, *rates))
            last = self._last_attitude_arrival_s
            if last is not None and arrival_s - last > TELEMETRY_GAP_S:
                self.gaps.append({"what": "ATTITUDE", "gap_s": arrival_s - last, "ended_at_s": arrival_s})  # type: ignore[dict-item]
            if self.first_attitude_s is None:
                self.first_attitude_s = arrival_s
            self._last_attitude_arrival_s = arrival_s
            self._lock.notify_all()

    def add_altitude(self, remote_s: float | None, altitude_m: float, arrival_s: float) -> None:
        """An altitude reading; ``remote_s`` None: no time stamp (kept at its arrival)."""
        with self._lock:
            if remote_s is None:
                self.altitude_local.add(arrival_s, (altitude_m,))
            else:
                self.clock.local_s(remote_s, arrival_s)
                self.altitude.add(remote_s, (altitude_m,))

    def _remote(self, t_s: float) -> float | None:
        return None if self.clock.offset_s is None else t_s - self.clock.offset_s

    def attitude_at(self, t_s: float) -> tuple[float, float, float] | None:
        """(roll, pitch, yaw) in radians at local time ``t_s``, yaw unwrapped; None when no sample is near.

        Past the newest sample (by more than :data:`SNAP_S`), its angles are moved on by its rates over
        at most :data:`EXTRAPOLATE_S`, then held (up to ``ATTITUDE_HOLD_S``). The rates are the body's
        (the gyros'): the angles' own rates up to the tilt's second order, a few hundredths of a degree
        over 0.1 s at 10 degrees of roll and 20 degrees/s of turn.
        """
        with self._lock:
            r = self._remote(t_s)
            v = None if r is None else self.attitude.at(r)
            if v is None:
                return None
            past_s = r - self.attitude.t_s[-1]  # type: ignore[operator]
        if past_s > SNAP_S:
            dt = min(past_s, EXTRAPOLATE_S)
            return (v[0] + v[3] * dt, v[1] + v[4] * dt, v[2] + v[5] * dt)
        return (v[0], v[1], v[2])

    def wait_attitude(
        self, t_s: float, late_s: float = LATE_WAIT_S, now=time.monotonic
    ) -> tuple[float, float, float] | None:
        """:meth:`attitude_at` once a sample within :data:`EXTRAPOLATE_S` before ``t_s`` (or after it) is in.

        A frame whose time is a little past the newest sample (the camera's frames and the autopilot's
        ATTITUDE are not sent together) takes that sample moved on by its rates, without waiting for
        the next one: waiting would add up to a telemetry period to the frame's latency. Farther past
        (the receiving thread fell behind), it waits up to ``late_s`` for a sample, never while the
        attitude is silent."""
        start = now()
        with self._lock:
            while True:
                r = self._remote(t_s)
                ts = self.attitude.t_s
                if r is None or (ts and ts[-1] >= r - EXTRAPOLATE_S):
                    break
                last = self._last_attitude_arrival_s
                waited = now() - start
                if last is None or now() - last > TELEMETRY_GAP_S or waited >= late_s:
                    break
                self._lock.wait(late_s - waited)
        return self.attitude_at(t_s)

    def altitude_at(self, t_s: float) -> float | None:
        with self._lock:
            r = self._remote(t_s)
            v = None if r is None else self.altitude.at(r)
            if v is None:
                v = self.altitude_local.at(t_s)
        return None if v is None else v[0]

    def silent_for_s(self, now_s: float) -> float | None:
        """Seconds since the last attitude sample arrived (None: none ever)."""
        with self._lock:
            last = self._last_attitude_arrival_s
        return None if last is None else now_s - last

    def summary(self, now_s: float) -> dict[str, Any]:
        with self._lock:
            gaps = list(self.gaps)
            last = self._last_attitude_arrival_s
        if last is not None and now_s - last > TELEMETRY_GAP_S:  # still silent at the end
            gaps.append({"what": "ATTITUDE", "gap_s": now_s - last, "ended_at_s": None})  # type: ignore[dict-item]
        return {"telemetry_gaps": gaps}
