"""``rovslam sitl --follow-guided``: the simulated vehicle obeys arm / mode commands and flies velocity setpoints.

A small pymavlink ground station on loopback arms the vehicle, switches it to GUIDED, sends
velocity setpoints, then switches to MANUAL while still sending: the true path (groundtruth.csv)
moves at the commanded speed in GUIDED and stops (drifting with the current) after the switch.
STATUSTEXT messages land in events.csv with the true position. The stream is paced 2x slower
than real time and the checks are on the stream's time axis (independent of the machine's speed).
"""

from __future__ import annotations

import csv
import time

import numpy as np
from _sitl_peers import free_udp_port, mavutil

from rovslam.sim.sitl import SitlConfig, SitlVehicle
from rovslam.sim.sitl_guided import read_events

PRESET = "portofino-short"


def _ground_truth(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.array([[float(r["t_s"]), float(r["x_m"]), float(r["y_m"])] for r in rows])


def _wait(conn, kind: str, timeout_s: float, cond=lambda m: True):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        m = conn.recv_match(type=kind, blocking=True, timeout=0.2)
        if m is not None and cond(m):
            return m
    return None


def _speed(gt: np.ndarray, t0: float, t1: float) -> float:
    sel = gt[(gt[:, 0] >= t0) & (gt[:, 0] <= t1)]
    return float(np.hypot(*(sel[-1, 1:] - sel[0, 1:])) / (sel[-1, 0] - sel[0, 0]))


def test_follow_guided_arms_flies_the_setpoints_and_stops_on_manual(tmp_path):
    mu = mavutil()
    port = free_udp_port()
    gcs = mu.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    truth = tmp_path / "truth"
    vehicle = SitlVehicle(
        SitlConfig(
            PRESET,
            truth,
            video=f"udp://127.0.0.1:{free_udp_port()}",
            mavlink=f"udpout:127.0.0.1:{port}",
            duration_s=16.0,
            pace=2.0,
            follow_guided=True,
            wait_for_peer_s=60.0,
        )
    )
    m = mu.mavlink
    try:
        vehicle.start()
        hb = _wait(gcs, "HEARTBEAT", 60)
        assert hb is not None and not hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED  # starts disarmed
        gcs.mav.heartbeat_send(m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert vehicle.wait_streaming(120)
        gcs.mav.command_long_send(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = _wait(gcs, "COMMAND_ACK", 10, lambda a: a.command == m.MAV_CMD_COMPONENT_ARM_DISARM)
        assert ack is not None and ack.result == m.MAV_RESULT_ACCEPTED
        gcs.mav.set_mode_send(1, m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
        ack = _wait(gcs, "COMMAND_ACK", 10, lambda a: a.command == 11)
        assert ack is not None and ack.result == m.MAV_RESULT_ACCEPTED
        hb = _wait(gcs, "HEARTBEAT", 10, lambda h: h.custom_mode == 4)
        assert hb is not None and hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED
        gcs.mav.statustext_send(6, b"guided now")

        def setpoints(seconds_stream: float) -> None:
            end = time.monotonic() + 2.0 * seconds_stream
            while time.monotonic() < end:
                gcs.mav.set_position_target_local_ned_send(0, 1, 1, 8, 1479, 0, 0, 0, 0.1, 0.0, 0, 0, 0, 0, 0, 0)
                time.sleep(0.1)

        setpoints(5.0)
        gcs.mav.command_long_send(1, 1, m.MAV_CMD_DO_SET_MODE, 0, 1, 19, 0, 0, 0, 0, 0)  # MANUAL
        ack = _wait(gcs, "COMMAND_ACK", 10, lambda a: a.command == m.MAV_CMD_DO_SET_MODE)
        assert ack is not None and ack.result == m.MAV_RESULT_ACCEPTED
        gcs.mav.statustext_send(6, b"manual now, arrived nowhere")
        setpoints(5.0)  # ignored outside GUIDED
        assert vehicle.wait(120)
    finally:
        vehicle.stop()
        gcs.close()
    gt = _ground_truth(truth / "groundtruth.csv")
    events = read_events(truth / "events.csv")
    assert [e["text"] for e in events] == ["guided now", "manual now, arrived nowhere"]
    t_guided, t_manual = events[0]["t_s"], events[1]["t_s"]
    # The current of the preset (about 1 cm/s) adds to or takes from the commanded 10 cm/s.
    assert 0.07 < _speed(gt, t_guided + 2.0, t_manual) < 0.13
    assert _speed(gt, t_manual + 4.0, t_manual + 6.0) < 0.025
    i = int(np.argmin(np.abs(gt[:, 0] - t_manual)))
    assert np.hypot(events[1]["x_true_m"] - gt[i, 1], events[1]["y_true_m"] - gt[i, 2]) < 0.03
    assert vehicle.follower is not None and vehicle.follower.setpoints_flown > 0


def test_pilot_guided_s_arms_and_switches_to_guided(tmp_path):
    mu = mavutil()
    port = free_udp_port()
    gcs = mu.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255, source_component=190)
    vehicle = SitlVehicle(
        SitlConfig(
            PRESET,
            tmp_path / "t",
            video=f"udp://127.0.0.1:{free_udp_port()}",
            mavlink=f"udpout:127.0.0.1:{port}",
            duration_s=3.0,
            pace=2.0,
            follow_guided=True,
            pilot_guided_s=1.0,
        )
    )
    try:
        vehicle.start()
        first = _wait(gcs, "HEARTBEAT", 60)
        later = _wait(gcs, "HEARTBEAT", 120, lambda h: h.custom_mode == 4)
        assert vehicle.wait(120)
    finally:
        vehicle.stop()
        gcs.close()
    assert first is not None and not first.base_mode & 128 and first.custom_mode == 2  # ALT_HOLD, disarmed
    assert later is not None and later.base_mode & 128
