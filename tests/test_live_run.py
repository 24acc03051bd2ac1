"""``rovslam live`` end to end on loopback, against a MAVLink vehicle built to the message definitions.

Every run processes every frame (``--every-frame``), so nothing here depends on the machine's
speed; every wait has a deadline and every process a timeout.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time

import numpy as np
import pytest
from live_peer import Vehicle, finish, free_udp_port, make_dive, rows, start_live

YAW_RATE = 0.02  # rad/s, the yaw the vehicle reports turns at this rate


@pytest.fixture(scope="module")
def dive(tmp_path_factory):
    root = tmp_path_factory.getbasetemp() / "live_dive"
    root.mkdir(exist_ok=True)
    return make_dive(root)


# --------------------------------------------------------------------------- a whole run, its messages checked


@pytest.fixture(scope="module")
def run(dive, tmp_path_factory):
    seq, video, camera = dive
    tmp = tmp_path_factory.mktemp("live_run")
    port = free_udp_port()
    vehicle = Vehicle(port, yaw_rad=lambda t: 0.3 + YAW_RATE * t, garbage=10)
    try:
        p = start_live(
            [
                "--video",
                str(video),
                "--camera",
                str(camera),
                "--mavlink",
                f"udpin:127.0.0.1:{port}",
                "--out",
                str(tmp / "out"),
                "--realtime",
                "--every-frame",
                "--record",
                "--heartbeat-timeout-s",
                "60",
                "--wait-s",
                "60",
            ],
            tmp,
        )
        rc, out, err = finish(p, tmp)
        time.sleep(0.5)  # the last datagrams
    finally:
        vehicle.close()
    return {"rc": rc, "out": out, "err": err, "dir": tmp / "out", "vehicle": vehicle, "tmp": tmp, "seq": seq}


def test_live_finds_the_vehicle_and_processes_every_frame(run):
    assert run["rc"] == 0, run["err"]
    assert "vehicle: system 1, component 1 (MAV_TYPE_SUBMARINE, MAV_AUTOPILOT_ARDUPILOTMEGA)" in run["err"]
    s = json.loads((run["dir"] / "summary.json").read_text())
    live = s["live"]
    assert s["status"] == "complete"
    assert live["frames_received"] == live["frames_processed"] == 40 and live["frames_dropped"] == 0
    assert live["latency_ms"]["count"] == 40 - live["frames_refused"] and live["latency_ms"]["p50"] > 0
    assert 0 < live["cpu_ms_per_frame"] < 1000  # the process's CPU a frame while it streamed
    stages = live["latency_stages_ms"]  # arrival -> decoded -> taken by the loop -> sent
    assert sorted(stages) == ["decoding", "processing", "waiting"]
    assert all(stages[n]["count"] == live["latency_ms"]["count"] for n in stages)
    assert stages["decoding"]["p50"] >= 0 and stages["waiting"]["p50"] >= 0 and stages["processing"]["p50"] > 0
    # each frame's stages add up to its latency: the largest of each is at most the largest latency
    assert max(stages[n]["max"] for n in stages) <= live["latency_ms"]["max"] + 1e-6
    assert stages["processing"]["p50"] <= live["latency_ms"]["p50"] + 1e-6
    assert live["messages_in"]["ATTITUDE"] > 40 and live["messages_in"]["DISTANCE_SENSOR"] > 20
    assert live["frames_without_attitude"] == 0 and live["frames_without_altitude"] == 0
    assert live["video_gaps"] == [] and live["reset_counter"] == 0


def test_live_speaks_as_the_visual_odometry_component(run):
    hb = [m for m in run["vehicle"].of_type("HEARTBEAT")]
    assert hb and all((m.get_srcSystem(), m.get_srcComponent(), m.type, m.autopilot) == (1, 197, 18, 8) for m in hb)


def test_garbage_packets_are_ignored_and_counted(run):
    live = json.loads((run["dir"] / "summary.json").read_text())["live"]
    assert live["bad_packets_in"] >= 5  # ten malformed packets sent (a few may swallow the next good one)
    assert run["rc"] == 0


def test_position_estimates_are_the_filters_trajectory(run):
    traj = [r for r in rows(run["dir"] / "trajectory.csv") if r["skipped"] == "0"]
    pos = run["vehicle"].of_type("VISION_POSITION_ESTIMATE")
    assert len(pos) == len(traj) == 40
    last, row = pos[-1], traj[-1]
    assert abs(last.x - float(row["x_m"])) < 1e-3 and abs(last.y - float(row["y_m"])) < 1e-3 and last.z == 0.0
    for m, r in zip(pos, traj):  # the filter's 2x2 in the x, y corner of the 6x6 upper triangle (float32)
        assert m.covariance[0] == pytest.approx(float(r["var_x_m2"]), rel=1e-6)
        assert m.covariance[1] == pytest.approx(float(r["cov_xy_m2"]), rel=1e-6, abs=1e-12)
        assert m.covariance[6] == pytest.approx(float(r["var_y_m2"]), rel=1e-6)
        assert m.yaw == pytest.approx(math.remainder(float(r["heading_rad"]), 2 * math.pi), abs=1e-6)
        assert m.reset_counter == 0
    assert all(b.usec > a.usec for a, b in zip(pos, pos[1:]))


def test_speed_delta_and_distance_messages(run):
    traj = [r for r in rows(run["dir"] / "trajectory.csv") if r["skipped"] == "0"]
    by_t = {round(float(r["t_s"]), 6): r for r in traj}
    pos = run["vehicle"].of_type("VISION_POSITION_ESTIMATE")
    t_of_usec = {m.usec: float(t) for m, t in zip(pos, by_t)}
    speeds = run["vehicle"].of_type("VISION_SPEED_ESTIMATE")
    assert len(speeds) == sum(r["speed_ok"] == "1" for r in traj)
    for m in speeds:
        r = by_t[round(t_of_usec[m.usec], 6)]
        psi, u, v = float(r["heading_rad"]), float(r["surge_mps"]), float(r["sway_mps"])
        assert m.x == pytest.approx(u * math.cos(psi) - v * math.sin(psi), abs=1e-5)
        assert m.y == pytest.approx(u * math.sin(psi) + v * math.cos(psi), abs=1e-5)
        assert len(m.covariance) == 9 and m.covariance[0] > 0
    deltas = run["vehicle"].of_type("VISION_POSITION_DELTA")
    assert len(deltas) == 39
    for m in deltas:  # the body-frame step's length is the step between consecutive estimates
        k = [p.usec for p in pos].index(m.time_usec)
        a, b = traj[k - 1], traj[k]
        step = math.hypot(float(b["x_m"]) - float(a["x_m"]), float(b["y_m"]) - float(a["y_m"]))
        assert math.hypot(*m.position_delta[:2]) == pytest.approx(step, abs=1e-5)
        assert m.time_delta_usec == round((float(b["t_s"]) - float(a["t_s"])) * 1e6)
        assert 0 <= m.confidence <= 100
    dist = run["vehicle"].of_type("DISTANCE_SENSOR")
    lasers = [r for r in traj if r["altitude_source"].startswith("laser")]
    assert len(dist) == len(lasers) > 0
    for m, r in zip(dist, lasers):
        assert m.orientation == 25 and m.current_distance == round(100 * float(r["altitude_m"]))
        assert m.covariance == min(254, round((100 * float(r["altitude_sigma_m"])) ** 2))


def test_telemetry_is_interpolated_to_the_frames_and_recorded(run):
    frames = rows(run["dir"] / "sequence" / "frames.csv")
    assert len(frames) == 40
    t = np.array([float(f["t_s"]) for f in frames])
    h = np.array([float(f["heading_rad"]) for f in frames])
    assert np.all(np.isfinite(h)) and np.all(np.diff(h) > 0), (h, (run["tmp"] / "live.err").read_text())
    assert (h[-1] - h[0]) / (t[-1] - t[0]) == pytest.approx(YAW_RATE, rel=0.15)
    assert all(
        float(f["roll_rad"]) == pytest.approx(0.01) and float(f["pitch_rad"]) == pytest.approx(-0.02) for f in frames
    )
    assert all(float(f["sonar_altitude_m"]) == 1.5 for f in frames)


def test_the_recorded_sequence_reproduces_the_live_trajectory(run):
    out2 = run["tmp"] / "rerun"
    p = subprocess.run(
        [sys.executable, "-m", "rovslam", "run", str(run["dir"] / "sequence"), "--out", str(out2), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    assert (out2 / "trajectory.csv").read_bytes() == (run["dir"] / "trajectory.csv").read_bytes()


# --------------------------------------------------------------------------- faults


def test_a_vehicle_that_never_answers_is_a_clear_error(dive, tmp_path):
    _, video, camera = dive
    port = free_udp_port()
    t0 = time.monotonic()
    p = start_live(
        [
            "--video",
            str(video),
            "--camera",
            str(camera),
            "--mavlink",
            f"udpin:127.0.0.1:{port}",
            "--out",
            str(tmp_path / "out"),
            "--heartbeat-timeout-s",
            "2",
        ],
        tmp_path,
    )
    rc, _, err = finish(p, tmp_path, timeout_s=120)
    assert rc == 2
    lines = [line for line in err.splitlines() if "error" in line]
    assert len(lines) == 1 and "no vehicle HEARTBEAT in 2 s" in lines[0] and "Traceback" not in err
    assert time.monotonic() - t0 < 110


@pytest.mark.parametrize("case", ["url", "connection", "camera", "never-starts"])
def test_bad_input_is_one_line_and_exit_2(dive, tmp_path, case):
    _, video, camera = dive
    port = free_udp_port()
    args = {"video": str(video), "camera": str(camera), "mavlink": f"udpin:127.0.0.1:{port}"}
    expect = ""
    if case == "url":
        args["video"], expect = str(tmp_path / "missing.ts"), "missing.ts: not found"
    elif case == "connection":
        args["mavlink"], expect = "udpin:127.0.0.1:notaport", "pymavlink cannot open it"
    elif case == "camera":
        small = tmp_path / "camera.toml"
        small.write_text(camera.read_text().replace("width_px = 360", "width_px = 320"))
        args["camera"], expect = str(small), "360x272 px but the camera file says 320x272"
    else:
        args["video"], expect = f"udp://127.0.0.1:{free_udp_port()}", "no video after 2 s"
    vehicle = Vehicle(port) if case in ("camera", "never-starts") else None
    try:
        p = start_live(
            [
                "--video",
                args["video"],
                "--camera",
                args["camera"],
                "--mavlink",
                args["mavlink"],
                "--out",
                str(tmp_path / "out"),
                "--heartbeat-timeout-s",
                "60",
                "--wait-s",
                "2",
            ],
            tmp_path,
        )
        rc, _, err = finish(p, tmp_path, timeout_s=120)
    finally:
        if vehicle is not None:
            vehicle.close()
    lines = [line for line in err.splitlines() if line.startswith("rovslam: error")]
    assert rc == 2 and len(lines) == 1 and expect in lines[0] and "Traceback" not in err, err
