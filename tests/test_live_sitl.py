"""Acceptance: ``rovslam sitl`` (the simulated vehicle) and ``rovslam live`` on loopback, 60 s of a preset.

The live run's accuracy matches the offline ``rovslam run`` of the same dive (the difference is
the H.264 coding), the messages the vehicle received are the filter's, and ``--record`` then
``rovslam run`` gives the same trajectory. ``--every-frame``: the result does not depend on the
machine's speed; the vehicle streams a dive rendered beforehand (``--from``) in real time, as
H.264 in MPEG-TS over UDP.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from live_peer import finish, free_udp_port, rows, start_live

FRAMES = 301  # 60 s at 5 frames/s
CRF = 12  # the stream's H.264 quality (a BlueOS stream's bitrate is set to the camera's use)
PRESET = "rough-turns-short"  # turns, altitude swings, roll and pitch, turbid water: an ATE of millimetres


def wait_for(predicate, timeout_s: float, step_s: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step_s)
    return False


@pytest.mark.slow
def test_sitl_and_live_on_loopback_match_the_offline_run(tmp_path):
    from rovslam.eval import evaluate_run
    from rovslam.runner import run_sequence
    from rovslam.sim.scenarios import simulate
    from rovslam.sim.sitl import SitlConfig, SitlVehicle
    from rovslam.sim.sitl_mavlink import read_received

    seq = tmp_path / "seq"
    simulate(PRESET, seq, frames=FRAMES, seed=0)
    run_sequence(seq, tmp_path / "offline")
    offline = evaluate_run(tmp_path / "offline", seq / "groundtruth.csv")

    camera = tmp_path / "camera.toml"
    shutil.copy(seq / "sequence.toml", camera)
    vport, mport = free_udp_port(), free_udp_port()
    out, truth = tmp_path / "out", tmp_path / "truth"
    p = start_live(
        [
            "--video",
            f"udp://127.0.0.1:{vport}",
            "--camera",
            str(camera),
            "--mavlink",
            f"udpin:127.0.0.1:{mport}",
            "--out",
            str(out),
            "--every-frame",
            "--record",
            "--quiet",
            "--heartbeat-timeout-s",
            "120",
            "--wait-s",
            "120",
        ],
        tmp_path,
    )
    vehicle = None
    try:
        assert wait_for(lambda: "waiting for a vehicle" in (tmp_path / "live.err").read_text(), 120)
        time.sleep(0.5)  # the video socket is bound
        vehicle = SitlVehicle(
            SitlConfig(
                None,
                truth,
                video=f"udp://127.0.0.1:{vport}",
                crf=CRF,
                mavlink=f"udpout:127.0.0.1:{mport}",
                from_seq=seq,
            )
        ).start()
        assert vehicle.wait(240)

        state = {"n": -1, "since": time.monotonic()}

        def settled() -> bool:  # no new message for 3 s: all processed
            n = sum(1 for _ in (truth / "received.csv").open()) if (truth / "received.csv").exists() else 0
            if n != state["n"]:
                state["n"], state["since"] = n, time.monotonic()
            return time.monotonic() - state["since"] > 3.0

        assert wait_for(settled, 240, 0.2)
        p.send_signal(signal.SIGTERM)
        rc, _, err = finish(p, tmp_path, timeout_s=120)
    finally:
        if p.poll() is None:
            p.kill()
        if vehicle is not None:
            vehicle.stop()
    assert rc == 128 + signal.SIGTERM, err
    live = json.loads((out / "summary.json").read_text())["live"]
    # every frame but the last one or two: FFmpeg hands a frame out when the next ones begin, and none follows
    assert FRAMES - 2 <= live["frames_received"] == live["frames_processed"] and live["frames_dropped"] == 0

    # the same frames give the same estimate: the frames live received (--record), run offline
    ev = evaluate_run(out, truth / "groundtruth.csv")
    assert ev.frames == live["frames_processed"]
    run_sequence(out / "sequence", tmp_path / "replay")
    replay = evaluate_run(tmp_path / "replay", truth / "groundtruth.csv")
    print(
        f"\nATE: live {ev.slam.ate_rmse_m * 1000:.3f} mm, its frames offline {replay.slam.ate_rmse_m * 1000:.3f} mm, "
        f"the lossless frames offline {offline.slam.ate_rmse_m * 1000:.3f} mm"
    )
    assert ev.slam.ate_rmse_m == pytest.approx(replay.slam.ate_rmse_m, rel=1e-6)
    # accuracy: the stream's H.264 costs at most 10 % of the offline run's ATE over the lossless frames (its loss may
    # fall either way: 2.88 mm live against 3.27 mm offline on this dive since the zoom between frames is on), the
    # truth inside 2-sigma as often
    assert ev.slam.ate_rmse_m <= 1.10 * offline.slam.ate_rmse_m, (ev.slam.ate_rmse_m, offline.slam.ate_rmse_m)
    assert ev.consistency.coverage_2sigma >= offline.consistency.coverage_2sigma - 0.05

    # what the vehicle received is the filter's
    traj = [r for r in rows(out / "trajectory.csv") if r["skipped"] == "0"]
    pos = [r for r in read_received(truth / "received.csv") if r["type"] == "VISION_POSITION_ESTIMATE"]
    assert len(pos) == len(traj)
    assert abs(pos[-1]["x"] - float(traj[-1]["x_m"])) < 1e-3 and abs(pos[-1]["y"] - float(traj[-1]["y_m"])) < 1e-3
    for m, r in zip(pos, traj):
        cov = m["covariance"]
        assert cov[0] == pytest.approx(float(r["var_x_m2"]), rel=1e-6)
        assert cov[1] == pytest.approx(float(r["cov_xy_m2"]), rel=1e-6, abs=1e-12)
        assert cov[6] == pytest.approx(float(r["var_y_m2"]), rel=1e-6)

    # --record, then rovslam run: the same trajectory
    rerun = subprocess.run(
        [sys.executable, "-m", "rovslam", "run", str(out / "sequence"), "--out", str(tmp_path / "rerun"), "--quiet"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert (tmp_path / "rerun" / "trajectory.csv").read_bytes() == (out / "trajectory.csv").read_bytes()
    Path(tmp_path / "figures.json").write_text(
        json.dumps(
            {
                "live_ate_m": ev.slam.ate_rmse_m,
                "offline_ate_m": offline.slam.ate_rmse_m,
                "live_2sigma": ev.consistency.coverage_2sigma,
                "offline_2sigma": offline.consistency.coverage_2sigma,
                "latency_ms": live["latency_ms"],
            }
        )
    )
