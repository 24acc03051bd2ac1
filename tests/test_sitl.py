"""`rovslam sitl` on loopback: a preset flown as an ArduSub vehicle, seen by a MAVLink peer and a video receiver.

One dive of portofino-short (2 s, 11 frames) is flown once for the module; the peers check
what a companion computer would get: HEARTBEAT of a submarine run by ArduPilot, ATTITUDE equal to
the preset's compass / AHRS readings (those ``rovslam simulate`` writes for the seed) and within
their noise of the truth, DISTANCE_SENSOR downward from the sonar, H.264 frames with their
capture times as presentation times; and what the vehicle records: the messages sent to it,
the truth along the preset's path and its camera file. Nothing here depends on the machine's
speed: every wait is a deadline for a failure, never a measurement.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
from _sitl_peers import MavlinkPeer, VideoReader, free_udp_port, wait_udp_bound

from rovslam.sim.scenarios import SCENARIOS
from rovslam.sim.vehicle import read_sensors, simulate_trajectory

SCENARIO, SEED, DURATION_S = "portofino-short", 3, 2.0
N_FRAMES = 11  # 2 s at 5 Hz, both ends
DEADLINE_S = 180.0  # a failure's bound (the first frame builds the seabed: seconds on a loaded machine)


def _wait_for(predicate, deadline_s: float = 30.0) -> bool:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def _send_to_vehicle(peer: MavlinkPeer) -> None:
    """What a navigation sensor sends an autopilot, plus a command, a stream request and garbage."""
    mav = peer.conn.mav
    cov = [float(i) * 0.01 for i in range(21)]
    mav.vision_position_delta_send(1_000_000, 200_000, [0.001, 0.002, 0.003], [0.01, 0.02, 0.0], 87.5)
    mav.vision_position_estimate_send(1_200_000, 0.25, -0.5, 1.31, 0.0, 0.0, 0.1, cov, 3)
    mav.vision_speed_estimate_send(1_200_000, 0.1, 0.02, 0.0, [0.0001] * 9, 3)
    mav.distance_sensor_send(1200, 20, 1000, 131, 0, 2, 25, 4)
    mav.statustext_send(6, b"rovslam live: tracking")
    mav.command_long_send(1, 1, 511, 0, 30, 100000, 0, 0, 0, 0, 0)  # SET_MESSAGE_INTERVAL ATTITUDE 10 Hz
    mav.request_data_stream_send(1, 1, 0, 10, 1)
    sock, addr = peer.conn.port, peer.vehicle_address()
    sock.sendto(b"this is not mavlink at all", addr)
    sock.sendto(bytes([0xFE, 9]) + bytes(15), addr)  # a MAVLink 1 frame with a wrong checksum
    mav.statustext_send(4, b"after the garbage")


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    from rovslam.sim.sitl import SitlConfig, SitlVehicle

    out = tmp_path_factory.mktemp("sitl") / "truth"
    video_port, mav_port = free_udp_port(), free_udp_port()
    peer = MavlinkPeer(mav_port, DEADLINE_S)
    reader = VideoReader(f"udp://127.0.0.1:{video_port}", N_FRAMES, DEADLINE_S)
    peer.start()
    reader.start()
    assert wait_udp_bound(video_port, DEADLINE_S)
    vehicle = SitlVehicle(SitlConfig(SCENARIO, out, video=f"udp://127.0.0.1:{video_port}",
                                     mavlink=f"udpout:127.0.0.1:{mav_port}", seed=SEED, duration_s=DURATION_S))
    vehicle.start()
    try:
        assert vehicle.wait_streaming(DEADLINE_S), "the first frame was never sent"
        assert _wait_for(lambda: bool(peer.of("HEARTBEAT")) and peer.conn.clients, DEADLINE_S)
        _send_to_vehicle(peer)
        assert vehicle.wait(DEADLINE_S), "the dive did not end"
        reader.join(DEADLINE_S)
        _wait_for(lambda: vehicle.link.counts_in["STATUSTEXT"] >= 2 and vehicle.link.bad_packets >= 1, 10.0)
        _wait_for(lambda: bool(peer.of("COMMAND_ACK")), 10.0)
    finally:
        summary = vehicle.stop()
        peer.close()
    sc = SCENARIOS[SCENARIO]
    traj = simulate_trajectory(sc.vehicle, sc.grid, N_FRAMES, sc.frame_rate_hz, SEED)
    nav = read_sensors(traj, sc.nav, SEED)
    return {"out": out, "peer": peer, "reader": reader, "summary": summary, "traj": traj, "nav": nav, "sc": sc}


def test_the_dive_is_flown_whole(dive):
    s = dive["summary"]
    assert (s["frames_planned"], s["frames_sent"], s["complete"], s["error"]) == (N_FRAMES, N_FRAMES, True, None)
    assert (dive["out"] / "sitl.json").is_file()


def test_heartbeat_is_an_ardusub_submarine(dive):
    beats = dive["peer"].of("HEARTBEAT")
    assert len(beats) >= 2
    hb = beats[0]
    assert (hb.type, hb.autopilot, hb.custom_mode, hb.system_status) == (12, 3, 2, 4)  # submarine, ArduPilot, ALT_HOLD
    assert hb.base_mode & 1 and hb.base_mode & 128  # custom mode, armed
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)


def test_attitude_is_the_presets_compass_and_ahrs_within_their_noise(dive):
    att = {m.time_boot_ms: m for m in dive["peer"].of("ATTITUDE")}
    traj, nav, sc = dive["traj"], dive["nav"], dive["sc"]
    at_frames = [k for k in range(N_FRAMES) if 200 * k in att]
    assert len(at_frames) >= N_FRAMES - 1  # loopback UDP: at most a stray loss
    sigma = math.hypot(sc.nav.compass_sigma_rad, sc.nav.compass_drift_rad)
    for k in at_frames:
        m = att[200 * k]
        assert m.yaw == pytest.approx(float(nav.heading_rad[k]), abs=1e-6)  # the reading rovslam simulate writes
        assert abs(m.yaw - float(traj.heading_rad[k])) < 5 * sigma  # and within its noise of the truth
        assert (m.roll, m.pitch) == (0.0, 0.0)  # a level preset records no attitude
    between = [t for t in att if t % 200 == 100]  # 10 Hz: one reading between frames, interpolated
    assert len(between) >= N_FRAMES - 3
    for t in between:
        k = t // 200
        expected = 0.5 * (float(nav.heading_rad[k]) + float(nav.heading_rad[k + 1]))
        assert att[t].yaw == pytest.approx(expected, abs=1e-6)


def test_distance_sensor_is_the_downward_sonar(dive):
    nav = dive["nav"]
    ds = {m.time_boot_ms: m for m in dive["peer"].of("DISTANCE_SENSOR")}
    assert len(ds) >= N_FRAMES - 1
    for t, m in ds.items():
        assert m.orientation == 25 and m.type == 1  # downward, ultrasound
        assert m.current_distance == round(100 * float(nav.sonar_altitude_m[t // 200]))
        assert m.covariance == round((100 * dive["sc"].nav.sonar_sigma_m) ** 2)
    ranges = [m.distance for m in dive["peer"].of("RANGEFINDER")]
    assert min(ranges) > 1.0 and max(ranges) < 1.6  # metres, at about 1.31 m
    assert dive["peer"].of("SYSTEM_TIME")


def test_video_frames_arrive_with_capture_times_at_the_presets_size(dive):
    reader = dive["reader"]
    frames = reader.frames
    assert len(frames) >= N_FRAMES - 1, reader.error  # a receiver that joined at once
    times = [t for t, _ in frames]
    assert times[0] == pytest.approx(0.0, abs=1e-6)
    steps = np.diff(times)
    assert np.all(steps > 0)
    assert np.allclose(steps / 0.2, np.round(steps / 0.2), atol=1e-4)  # frame times on the 5 Hz grid
    assert all(img.shape == (272, 360, 3) for _, img in frames)


def test_messages_sent_to_the_vehicle_land_in_received_csv(dive):
    from rovslam.sim.sitl_mavlink import read_received

    rows = read_received(dive["out"] / "received.csv")
    by_type = {}
    for r in rows:
        by_type.setdefault(r["type"], []).append(r)
    assert set(by_type) == {"VISION_POSITION_DELTA", "VISION_POSITION_ESTIMATE", "VISION_SPEED_ESTIMATE",
                            "DISTANCE_SENSOR", "STATUSTEXT"}
    est = by_type["VISION_POSITION_ESTIMATE"][0]
    assert (est["x"], est["y"], est["reset_counter"], est["time_usec"]) == (0.25, -0.5, 3, 1_200_000)
    assert est["covariance"] == pytest.approx([i * 0.01 for i in range(21)], abs=1e-7)  # float32 on the wire
    assert (est["src_system"], est["src_component"]) == (1, 197)
    assert est["arrival_s"] >= 0.0
    delta = by_type["VISION_POSITION_DELTA"][0]
    assert delta["position_delta"] == pytest.approx([0.01, 0.02, 0.0], abs=1e-7)
    assert (delta["time_delta_usec"], delta["confidence"]) == (200_000, 87.5)
    assert by_type["VISION_SPEED_ESTIMATE"][0]["covariance"] == pytest.approx([0.0001] * 9, rel=1e-6)
    dist = by_type["DISTANCE_SENSOR"][0]
    assert (dist["current_distance"], dist["orientation"], dist["sensor_id"], dist["covariance"]) == (131, 25, 2, 4)
    assert [r["text"] for r in by_type["STATUSTEXT"]] == ["rovslam live: tracking", "after the garbage"]
    link = dive["summary"]["mavlink"]
    assert link["bad_packets"] >= 1  # the garbage: counted, dropped
    assert link["messages_in"]["COMMAND_LONG"] == 1 and link["messages_in"]["REQUEST_DATA_STREAM"] == 1


def test_set_message_interval_is_acknowledged(dive):
    acks = dive["peer"].of("COMMAND_ACK")
    assert [(a.command, a.result) for a in acks] == [(511, 0)]  # accepted


def test_groundtruth_is_the_presets_path_on_the_stream_axis(dive):
    from rovslam.io.sequence import read_groundtruth

    gt = read_groundtruth(dive["out"] / "groundtruth.csv")
    traj = dive["traj"]
    assert len(gt) == N_FRAMES
    np.testing.assert_allclose(gt.t_s, 0.2 * np.arange(N_FRAMES), atol=1e-12)
    for a, b in ((gt.x_m, traj.x_m), (gt.y_m, traj.y_m), (gt.altitude_m, traj.altitude_m),
                 (gt.heading_rad, traj.heading_rad)):
        np.testing.assert_array_equal(a, b)


def test_camera_file_is_the_presets_camera_and_lasers(dive):
    from rovslam.io.camera_file import read_camera_file

    cf = read_camera_file(dive["out"] / "camera.toml")
    sc = dive["sc"]
    assert cf.info.camera == sc.recorded_camera
    assert cf.info.lasers == sc.lasers
    assert cf.info.metadata["frame_rate_hz"] == 5.0


def test_sitl_renders_what_simulate_writes(dive, tmp_path):
    """The streamed images are the preset's (the frames rovslam simulate writes for the seed), before H.264."""
    from rovslam.io.sequence import open_sequence
    from rovslam.sim import simulate
    from rovslam.sim.sitl_frames import preset_frames

    simulate(SCENARIO, tmp_path / "seq", frames=3, seed=SEED)
    seq = open_sequence(tmp_path / "seq")
    src = preset_frames(SCENARIO, SEED, duration_s=0.4)
    for ours, theirs in zip(src.frames, seq.frames(prefetch=0), strict=True):
        assert np.array_equal(ours.image, theirs.image)
        assert (ours.heading_rad, ours.sonar_altitude_m) == (theirs.heading_rad, theirs.sonar_altitude_m)
