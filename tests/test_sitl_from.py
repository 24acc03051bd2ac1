"""`rovslam sitl --from SEQ`, `--rtp`, `--pace`, the command's bad input and its stop on SIGTERM, on loopback.

A small sequence folder written here (flat grey frames whose level says their index, times
from 100 s) is streamed: the receiver gets those frames at their own times, shifted to start at
0, and the truth is the folder's on the same axis. Every wait is a deadline for a failure.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from _sitl_peers import MavlinkPeer, VideoReader, free_udp_port, wait_udp_bound

from rovslam.camera import Camera
from rovslam.core import SequenceInfo
from rovslam.io.sequence import SequenceWriter, read_groundtruth

RATE_HZ, N, T0_S = 10.0, 8, 100.0
W, H = 160, 120
DEADLINE_S = 120.0


def _level(k: int) -> int:
    return 40 + 20 * k


def _image(k: int) -> np.ndarray:
    """Frame k: grey level :func:`_level` plus seeded noise (an H.264 frame of a few kilobytes, as a seabed's)."""
    noise = np.random.default_rng(k).normal(0.0, 8.0, (H, W, 3))
    return np.clip(_level(k) + noise, 0, 255).astype(np.uint8)


def _write_sequence(folder: Path, n: int = N) -> Path:
    cam = Camera(width_px=W, height_px=H, fx_px=300.0, fy_px=300.0, cx_px=63.5, cy_px=47.5)
    info = SequenceInfo(name="flat greys", camera=cam, metadata={"frame_rate_hz": RATE_HZ})
    with SequenceWriter(folder, info, with_groundtruth=True) as w:
        for k in range(n):
            w.write_frame(
                T0_S + k / RATE_HZ,
                _image(k),
                heading_rad=0.01 * k,
                sonar_altitude_m=1.3 + 0.001 * k,
                truth=(0.01 * k, -0.02 * k, 1.3, 0.005 * k),
            )
    return folder


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    return _write_sequence(tmp_path_factory.mktemp("from") / "seq")


def _vehicle(seq: Path, out: Path, video: str, mav_port: int, **kw):
    from rovslam.sim.sitl import SitlConfig, SitlVehicle

    return SitlVehicle(SitlConfig(None, out, video=video, mavlink=f"udpout:127.0.0.1:{mav_port}", from_seq=seq, **kw))


def test_from_streams_the_folders_frames_at_their_times(seq, tmp_path):
    video_port, mav_port = free_udp_port(), free_udp_port()
    peer = MavlinkPeer(mav_port, DEADLINE_S)
    reader = VideoReader(f"udp://127.0.0.1:{video_port}", N, DEADLINE_S)
    peer.start()
    reader.start()
    assert wait_udp_bound(video_port, DEADLINE_S)  # (a frame sent before the receiver binds is lost, as on any UDP)
    vehicle = _vehicle(seq, tmp_path / "truth", f"udp://127.0.0.1:{video_port}", mav_port, pace=1.5)
    try:
        vehicle.start()
        assert vehicle.wait(DEADLINE_S)
        reader.join(DEADLINE_S)
    finally:
        summary = vehicle.stop()
        peer.close()
    assert (summary["frames_sent"], summary["complete"]) == (N, True)
    frames = reader.frames
    assert len(frames) == N, reader.error
    np.testing.assert_allclose([t for t, _ in frames], np.arange(N) / RATE_HZ, atol=1e-4)
    for k, (_, img) in enumerate(frames):
        assert img.shape == (H, W, 3)
        assert abs(float(img.mean()) - _level(k)) < 2.0  # frame k is the folder's frame k
    gt = read_groundtruth(tmp_path / "truth" / "groundtruth.csv")
    np.testing.assert_allclose(gt.t_s, np.arange(N) / RATE_HZ, atol=1e-9)  # the stream's axis
    np.testing.assert_allclose(gt.x_m, 0.01 * np.arange(N))
    att = {m.time_boot_ms: m.yaw for m in peer.of("ATTITUDE")}
    assert att[300] == pytest.approx(0.03, abs=1e-7)  # frame 3's compass reading at its time
    ds = [m for m in peer.of("DISTANCE_SENSOR") if m.time_boot_ms == 600]
    assert ds and ds[0].current_distance == 131


def test_pace_slows_the_dive_but_not_its_clock(seq, tmp_path):
    """--pace 3: frames go out 3 frame periods apart (never sooner), presented at their capture times."""
    pace = 3.0
    vehicle = _vehicle(
        seq, tmp_path / "truth", f"udp://127.0.0.1:{free_udp_port()}", free_udp_port(), pace=pace, duration_s=0.3
    )
    try:
        vehicle.start()
        assert vehicle.wait(DEADLINE_S)
    finally:
        vehicle.stop()
    sent = np.array(vehicle.sent_monotonic_s)
    assert len(sent) == 4
    assert np.all(np.diff(sent) >= pace / RATE_HZ - 0.005)  # a lower bound: scheduling can only be late
    gt = read_groundtruth(tmp_path / "truth" / "groundtruth.csv")
    np.testing.assert_allclose(gt.t_s, np.arange(4) / RATE_HZ, atol=1e-9)


def test_the_dive_can_wait_for_the_companions_heartbeat(seq, tmp_path):
    """wait_for_peer_s: no frame goes out before a HEARTBEAT from another component has arrived."""
    mav_port = free_udp_port()
    peer = MavlinkPeer(mav_port, DEADLINE_S)
    peer.start()
    vehicle = _vehicle(
        seq, tmp_path / "truth", f"udp://127.0.0.1:{free_udp_port()}", mav_port, wait_for_peer_s=DEADLINE_S
    )
    try:
        vehicle.start()
        assert _wait_for(lambda: bool(peer.of("HEARTBEAT")) and bool(peer.conn.clients))
        time.sleep(0.5)
        assert vehicle.frames_sent == 0  # holding
        t_sent = time.monotonic()
        peer.conn.mav.heartbeat_send(18, 8, 0, 0, 4)  # an onboard controller, no autopilot, active
        assert vehicle.wait(DEADLINE_S)
    finally:
        summary = vehicle.stop()
        peer.close()
    assert summary["peer_heartbeat_before_first_frame"] and summary["frames_sent"] == N
    assert vehicle.sent_monotonic_s[0] >= t_sent


def _wait_for(predicate, deadline_s: float = DEADLINE_S) -> bool:
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return bool(predicate())


def test_rtp_stream_opens_through_its_sdp(seq, tmp_path):
    """--rtp: H.264 over RTP with OUT/stream.sdp, opened as BlueOS's stream is (protocol_whitelist=file,udp,rtp).

    The dive waits for the receiver: it opens the SDP that sitl wrote, binds the port, then a companion's
    HEARTBEAT starts the dive (wait_for_peer_s).
    """
    video_port, mav_port = free_udp_port(), free_udp_port()
    out = tmp_path / "truth"
    peer = MavlinkPeer(mav_port, DEADLINE_S)
    peer.start()
    vehicle = _vehicle(seq, out, f"udp://127.0.0.1:{video_port}", mav_port, rtp=True, wait_for_peer_s=DEADLINE_S)
    reader = None
    try:
        vehicle.start()
        sdp = (out / "stream.sdp").read_text()
        assert f"m=video {video_port} RTP/AVP 96" in sdp and "a=rtpmap:96 H264/90000" in sdp
        reader = VideoReader(
            str(out / "stream.sdp"),
            N,
            DEADLINE_S,
            fmt="sdp",
            options={"protocol_whitelist": "file,udp,rtp", "probesize": "4096", "analyzeduration": "0"},
        )
        reader.start()
        assert wait_udp_bound(video_port, DEADLINE_S)
        assert _wait_for(lambda: bool(peer.of("HEARTBEAT")) and bool(peer.conn.clients))
        peer.conn.mav.heartbeat_send(18, 8, 0, 0, 4)
        assert vehicle.wait(DEADLINE_S)
        reader.join(DEADLINE_S)
    finally:
        vehicle.stop()
        peer.close()
    frames = reader.frames
    assert len(frames) >= N - 1, reader.error  # (FFmpeg's H.264 parser holds the last until the stream goes on)
    assert frames[0][0] is None  # RTP: the first frame's time is unknown; the others count from it
    times = np.array([t for t, _ in frames[1:]])
    # The frames' spacing is the stream's clock, exactly. Their common offset is not: FFmpeg's RTP receiver
    # shifts every time by the first RTCP sender report's RTP timestamp, which its sender takes from its
    # wall clock (rtpenc.c rtcp_send_sr, rtpdec.c rtcp_ts_offset), so a send a millisecond late moves them
    # all by that millisecond (seen once on a loaded 2-core machine: 0.099, 0.199, ... s).
    np.testing.assert_allclose(np.diff(times), 1.0 / RATE_HZ, atol=1e-4)
    assert abs(times[0] - 1.0 / RATE_HZ) < 0.01, times
    for k, (_, img) in enumerate(frames):
        assert img.shape == (H, W, 3) and abs(float(img.mean()) - _level(k)) < 2.0


def test_each_frame_is_received_before_the_next_is_sent():
    """No frame waits in the sender or the demuxer for the next one: frame k+1 goes out only once k is decoded."""
    from rovslam.sim.sitl_video import VideoOut

    port = free_udp_port()
    reader = VideoReader(f"udp://127.0.0.1:{port}", N, DEADLINE_S)
    reader.start()
    assert wait_udp_bound(port, DEADLINE_S)
    video = VideoOut(f"udp://127.0.0.1:{port}", W, H, RATE_HZ)
    try:
        for k in range(N):
            video.send(_image(k), k / RATE_HZ)
            end = time.monotonic() + 30.0
            while len(reader.frames) < k + 1 and time.monotonic() < end and reader.is_alive():
                time.sleep(0.01)
            assert len(reader.frames) == k + 1, f"frame {k} not decoded before frame {k + 1} was sent"
    finally:
        video.close()
        reader.join(DEADLINE_S)
    assert [round(t * RATE_HZ) for t, _ in reader.frames] == list(range(N))


def test_every_mpegts_frame_carries_its_length_even_a_busy_one():
    """A frame of more than 64 KiB could carry no PES length (and would wait in the demuxer for the next): the
    encoder's buffer keeps each below; here noise that would code to far more at this quality."""
    import socket

    from rovslam.sim.sitl_video import MAX_FRAME_BYTES, VideoOut

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    noise = np.random.default_rng(5).normal(100.0, 40.0, (480, 640, 3))
    video = VideoOut(f"udp://127.0.0.1:{rx.getsockname()[1]}", 640, 480, RATE_HZ)
    data = b""
    try:
        for k in range(4):
            video.send(np.clip(np.roll(noise, 7 * k, axis=1), 0, 255).astype(np.uint8), k / RATE_HZ)
            while True:  # on loopback a datagram is in the receiver's buffer when sendto returns
                try:
                    data += rx.recv(65536)
                except BlockingIOError:
                    break
    finally:
        video.close()
        rx.close()
    lengths = _pes_lengths(data)
    assert len(lengths) == 4 and all(0 < n <= MAX_FRAME_BYTES + 100 for n in lengths), lengths
    assert video.bytes > 4 * 40_000  # (busy frames: the cap is what kept them small)


def _pes_lengths(ts: bytes) -> list[int]:
    """PES_packet_length of each PES starting in an MPEG-TS byte string (video PID 0x100)."""
    out = []
    for i in range(0, len(ts) - 187, 188):
        pk = ts[i : i + 188]
        if pk[1] & 0x40 and ((pk[1] & 0x1F) << 8 | pk[2]) == 0x100:
            off = 4 + (1 + pk[4] if (pk[3] >> 4) & 2 else 0)
            if pk[off : off + 3] == b"\x00\x00\x01":
                out.append(int.from_bytes(pk[off + 4 : off + 6], "big"))
    return out


# --------------------------------------------------------------------------- the command


def _rovslam(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "rovslam", "sitl", *args], capture_output=True, text=True, timeout=DEADLINE_S, **kw
    )


BAD = [
    (["--scenario", "no-such-preset"], "unknown preset 'no-such-preset'"),
    (["--scenario", "portofino-short", "--video", "http://127.0.0.1:5600"], "the scheme must be udp or rtp"),
    (["--scenario", "portofino-short", "--video", "udp://127.0.0.1"], "needs a host and a port"),
    (["--scenario", "portofino-short", "--mavlink", "udpout:127.0.0.1"], "not a connection string"),
    (["--scenario", "portofino-short", "--mavlink", "/dev/no-such-tty,57600"], "no serial device"),
    (["--scenario", "portofino-short", "--pace", "0"], "--pace must be a positive factor"),
    (["--scenario", "portofino-short", "--mode", "HOVER"], "--mode 'HOVER'"),
    ([], "give --scenario NAME"),
    (["--scenario", "portofino-short", "--crf", "60"], "--crf must be a whole number"),
]


@pytest.mark.parametrize("case", [0, 1, 3])  # (each command line loads the simulator: a few seconds)
def test_bad_input_is_one_line_and_exit_2(tmp_path, case):
    args, says = BAD[case]
    r = _rovslam(*args, "--out", str(tmp_path / "truth"))
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "truth").exists()


@pytest.mark.parametrize("args, says", BAD)
def test_bad_input_is_refused_before_anything_is_written(tmp_path, args, says):
    """The same checks through the command's function (in this process): SimulationError, nothing written."""
    import typer

    from rovslam.cli.sitl import sitl
    from rovslam.errors import SimulationError

    opts = dict(
        scenario=None,
        seed=0,
        video="udp://127.0.0.1:5600",
        mavlink="udpout:127.0.0.1:14550",
        duration_s=None,
        from_seq=None,
        rtp=False,
        pace=1.0,
        mode="ALT_HOLD",
        crf=20,
        wait_for_peer_s=0.0,
        quiet=True,
    )
    names = {
        "--scenario": "scenario",
        "--video": "video",
        "--mavlink": "mavlink",
        "--pace": "pace",
        "--mode": "mode",
        "--crf": "crf",
    }
    for flag, value in zip(args[::2], args[1::2], strict=True):
        opts[names[flag]] = float(value) if flag == "--pace" else int(value) if flag == "--crf" else value
    with pytest.raises((SimulationError, typer.Exit)) as err:
        sitl(out=tmp_path / "truth", **opts)
    assert says in str(err.value)
    assert not (tmp_path / "truth").exists()


def test_a_used_output_folder_is_refused(seq, tmp_path):
    (tmp_path / "truth").mkdir()
    (tmp_path / "truth" / "old.csv").write_text("x\n")
    r = _rovslam("--from", str(seq), "--out", str(tmp_path / "truth"))
    assert r.returncode == 2 and "not an empty folder" in r.stderr


def test_sigterm_ends_the_dive_with_its_files_complete(seq, tmp_path):
    out = tmp_path / "truth"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "rovslam",
            "sitl",
            "--from",
            str(seq),
            "--out",
            str(out),
            "--pace",
            "50",
            "--video",
            f"udp://127.0.0.1:{free_udp_port()}",
            "--mavlink",
            f"udpout:127.0.0.1:{free_udp_port()}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ),
    )
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    try:
        end = time.monotonic() + DEADLINE_S
        while not any("streaming" in x for x in lines) and time.monotonic() < end and proc.poll() is None:
            time.sleep(0.05)
        assert any("streaming" in x for x in lines), lines
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "stopped by SIGTERM" in err and len(err.strip().splitlines()) == 1
    gt = read_groundtruth(out / "groundtruth.csv")
    assert 1 <= len(gt) < N  # what was flown, every row whole
    assert (out / "sitl.json").is_file() and (out / "received.csv").read_text().startswith("arrival_s,")
