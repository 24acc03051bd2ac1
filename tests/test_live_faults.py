"""``rovslam live`` faults on loopback: the video stalls for 3 s, the telemetry stops, SIGTERM.

One run carries the three (a UDP stream that pauses, a vehicle that stops its ATTITUDE after
eight positions, a SIGTERM once every frame was processed); each test checks one of them.
``--every-frame``: nothing depends on the machine's speed; every wait has a deadline.
"""

from __future__ import annotations

import json
import signal
import time

import pytest
from live_peer import (
    Vehicle,
    finish,
    free_udp_port,
    make_dive,
    rows,
    start_live,
    stream_udp,
)

STOP_AFTER = 15  # frames streamed before the pause
PAUSE_S = 3.0


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    root = tmp_path_factory.getbasetemp() / "live_dive"
    root.mkdir(exist_ok=True)
    seq, _, camera = make_dive(root)
    tmp = tmp_path_factory.mktemp("live_faults")
    video_port, mav_port = free_udp_port(), free_udp_port()
    vehicle = Vehicle(mav_port, yaw_rad=lambda t: 0.3, attitude_stop_after=8)
    sender = None
    try:
        p = start_live(["--video", f"udp://127.0.0.1:{video_port}", "--camera", str(camera), "--mavlink",
                        f"udpin:127.0.0.1:{mav_port}", "--out", str(tmp / "out"), "--every-frame",
                        "--heartbeat-timeout-s", "60", "--wait-s", "60"], tmp)
        deadline = time.monotonic() + 120
        while not vehicle.of_type("HEARTBEAT") and time.monotonic() < deadline and p.poll() is None:
            time.sleep(0.1)  # live is up: stream
        sender = stream_udp(seq, video_port, start_delay_s=1.0, stop_after=STOP_AFTER, pause_s=PAUSE_S)
        sender.join(90)
        last, stable_since = -1, time.monotonic()
        while time.monotonic() < deadline and p.poll() is None:  # every frame processed: no new position for 2 s
            n = len(vehicle.of_type("VISION_POSITION_ESTIMATE"))
            if n != last:
                last, stable_since = n, time.monotonic()
            elif time.monotonic() - stable_since > 2.0:
                break
            time.sleep(0.1)
        p.send_signal(signal.SIGTERM)
        rc, _, err = finish(p, tmp, timeout_s=60)
        time.sleep(0.3)
    finally:
        vehicle.close()
    s = json.loads((tmp / "out" / "summary.json").read_text())
    return {"rc": rc, "err": err, "summary": s, "live": s["live"], "vehicle": vehicle, "dir": tmp / "out"}


def test_sigterm_leaves_complete_files(faulty):
    assert faulty["rc"] == 128 + signal.SIGTERM, faulty["err"]
    s, live = faulty["summary"], faulty["live"]
    assert s["status"] == "interrupted" and s["signal"] == "SIGTERM" and "stopped by SIGTERM" in faulty["err"]
    traj = rows(faulty["dir"] / "trajectory.csv")
    assert len(traj) == s["frames_processed"] == live["frames_processed"] >= 15
    assert live["frames_received"] == live["frames_processed"] + live["frames_dropped"]
    assert (faulty["dir"] / "landmarks.csv").exists()


def test_a_video_stall_sends_no_position_and_resets_the_estimate(faulty):
    live = faulty["live"]
    gaps = live["video_gaps"]  # gaps in the camera's frames (stream time)
    assert len(gaps) == 1 and gaps[0]["stream_gap_s"] > PAUSE_S and not gaps[0]["bridged"]
    assert "without a frame" in faulty["err"]
    assert live["blind"] and max(b["blind_s"] for b in live["blind"]) > 2.0
    pos = sorted(faulty["vehicle"].of_type("VISION_POSITION_ESTIMATE"), key=lambda m: m.usec)
    assert len(pos) == live["positions_sent"] > STOP_AFTER
    steps = [(b.usec - a.usec) / 1e6 for a, b in zip(pos, pos[1:])]
    jumps = [k for k, d in enumerate(steps) if d > 0.5]  # no position from a frame inside the gap
    assert len(jumps) == 1 and steps[jumps[0]] > PAUSE_S
    k = jumps[0]
    assert {m.reset_counter for m in pos[:k + 1]} == {0} and {m.reset_counter for m in pos[k + 1:]} == {1}
    assert live["reset_counter"] == 1 and "video gap" in live["resets"][0]["cause"]
    deltas = faulty["vehicle"].of_type("VISION_POSITION_DELTA")
    assert len(deltas) == len(pos) - 2  # none for the first frame, none across the reset


def test_telemetry_that_stops_leaves_the_heading_to_the_tokens(faulty):
    live, s = faulty["live"], faulty["summary"]
    assert faulty["vehicle"].attitude_stopped_at_s is not None
    assert live["frames_without_attitude"] >= 5
    assert live["telemetry_gaps"] and "no ATTITUDE at t =" in faulty["err"]
    assert s["sources"]["heading"]["frames"].get("tokens only (no compass)", 0) >= 5
    assert live["positions_sent"] == sum(r["skipped"] == "0" for r in rows(faulty["dir"] / "trajectory.csv"))
