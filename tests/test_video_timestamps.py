"""Video time stamps that lie: every decodable frame kept, times monotonic, the repair said once.

The videos are written here with PyAV: H.264 without B-frames (one frame a packet), each frame a
vertical bar one column further right than the last, so a frame's place in the dive is read
from its image. The packets are then muxed with the presentation times a test wants: permuted
(a muxer that wrote decode times), repeated, irregular (a variable frame rate), or none at all
(a raw H.264 stream).
"""

from __future__ import annotations

import fractions
from pathlib import Path

import numpy as np
import pytest

from rovslam.io.video import open_video

W_PX, H_PX, RATE_HZ, STEP_MS = 64, 48, 20, 50
MS = fractions.Fraction(1, 1000)


def _bar(i: int) -> np.ndarray:
    img = np.zeros((H_PX, W_PX, 3), np.uint8)
    img[:, 4 + 2 * i : 6 + 2 * i] = 255
    return img


def _bar_column(img: np.ndarray) -> int:
    return int(np.argmax(img[:, :, 1].mean(axis=0)) - 4) // 2


def _write(path: Path, pts_ms: list[int] | None, fmt: str | None = None) -> Path:
    """A video of ``len(pts_ms)`` frames (bar i in frame i) whose packets carry ``pts_ms``; None: no stamps."""
    import av

    n = len(pts_ms) if pts_ms is not None else 24
    with av.open(str(path), "w", format=fmt) as c:
        s = c.add_stream("libx264", rate=RATE_HZ)
        s.width, s.height, s.pix_fmt = W_PX, H_PX, "yuv420p"
        s.codec_context.options = {"bf": "0", "g": "4"}
        s.time_base = MS
        packets = []
        for i in range(n):
            f = av.VideoFrame.from_ndarray(_bar(i), format="rgb24")
            f.pts, f.time_base = i * STEP_MS, MS
            packets += s.encode(f)
        packets += s.encode(None)
        assert len(packets) == n
        lowest = min(pts_ms) if pts_ms is not None else 0
        for i, p in enumerate(packets):
            if pts_ms is None:
                continue
            p.time_base = MS
            p.pts = pts_ms[i]
            p.dts = lowest - 10 * STEP_MS + i  # increasing and never after its pts
        if pts_ms is None:
            return path
        for p in packets:
            c.mux(p)
    return path


def _raw_h264(path: Path, n: int) -> Path:
    """An elementary H.264 stream: no container, no time stamps."""
    import av

    with av.open(str(path), "w", format="h264") as c:
        s = c.add_stream("libx264", rate=RATE_HZ)
        s.width, s.height, s.pix_fmt = W_PX, H_PX, "yuv420p"
        s.codec_context.options = {"bf": "0"}
        for i in range(n):
            f = av.VideoFrame.from_ndarray(_bar(i), format="rgb24")
            f.pts = i
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode(None):
            c.mux(p)
    return path


def _camera(tmp_path: Path) -> Path:
    cam = tmp_path / "camera.toml"
    cam.write_text(
        f"[camera]\nwidth_px = {W_PX}\nheight_px = {H_PX}\nfx_px = 60.0\nfy_px = 60.0\n"
        f"cx_px = {W_PX / 2}\ncy_px = {H_PX / 2}\n\n[vehicle]\naltitude_m = 1.0\n"
    )
    return cam


def _frames(video: Path, cam: Path):
    src = open_video(video, cam)
    frames = list(src.frames())
    return src, [f.t_s for f in frames], [_bar_column(f.image) for f in frames]


@pytest.mark.parametrize("fmt", ["matroska", "mpegts", "mp4"])
def test_time_stamps_out_of_order_keep_every_frame_with_its_own_time(tmp_path, fmt):
    # The broken clip's pattern: every third frame's stamp swapped back two places.
    true_ms = [i * STEP_MS for i in range(30)]
    pts = list(true_ms)
    for i in range(3, 30, 3):
        pts[i - 2], pts[i - 1], pts[i] = true_ms[i - 1], true_ms[i], true_ms[i - 2]
    src, t_s, bars = _frames(
        _write(tmp_path / f"perm.{'mkv' if fmt == 'matroska' else fmt}", pts, fmt), _camera(tmp_path)
    )
    assert bars == list(range(30))  # all kept, in the decoder's order
    np.testing.assert_allclose(t_s, np.array(true_ms) / 1000.0, atol=1e-6)  # each frame its own time
    assert src.left_out == 0
    reorder = [w for w in src.warnings if "out of order" in w]
    assert len(reorder) == 1 and "27 frames" in reorder[0], src.warnings


def test_repeated_time_stamps_are_kept_one_period_apart(tmp_path):
    pts = [i * STEP_MS for i in range(20)]
    pts[7] = pts[6]  # a repeated stamp
    pts[12] = pts[11]
    src, t_s, bars = _frames(_write(tmp_path / "rep.mkv", pts, "matroska"), _camera(tmp_path))
    assert bars == list(range(20))
    assert np.all(np.diff(t_s) > 0)
    assert t_s[7] == pytest.approx(t_s[6] + 1.0 / RATE_HZ)
    assert [w for w in src.warnings if "repeat" in w] == [w for w in src.warnings if "2 frames repeat" in w]
    assert len([w for w in src.warnings if "repeat" in w]) == 1
    assert src.left_out == 0


def test_a_variable_frame_rate_keeps_its_time_stamps(tmp_path):
    rng = np.random.default_rng(3)
    pts = np.concatenate([[0], np.cumsum(rng.integers(20, 120, size=24))]).tolist()
    src, t_s, bars = _frames(_write(tmp_path / "vfr.mkv", pts, "matroska"), _camera(tmp_path))
    assert bars == list(range(25))
    np.testing.assert_allclose(t_s, np.array(pts) / 1000.0, atol=1e-6)
    assert src.warnings == []


def test_a_stream_without_time_stamps_is_timed_by_its_rate(tmp_path):
    src, t_s, bars = _frames(_raw_h264(tmp_path / "raw.h264", 18), _camera(tmp_path))
    assert bars == list(range(18))
    import av

    with av.open(str(tmp_path / "raw.h264")) as c:  # a raw stream's rate is FFmpeg's guess (25 Hz here)
        s = c.streams.video[0]
        rate_hz = float(s.average_rate or s.guessed_rate)
    np.testing.assert_allclose(np.diff(t_s), 1.0 / rate_hz, rtol=1e-6)
    assert t_s[0] == 0.0
    assert len(src.warnings) == 1 and "no time stamp" in src.warnings[0] and f"{rate_hz:g} Hz" in src.warnings[0]


def test_a_clean_video_says_nothing(tmp_path):
    pts = [i * STEP_MS for i in range(15)]
    src, t_s, bars = _frames(_write(tmp_path / "ok.mkv", pts, "matroska"), _camera(tmp_path))
    assert bars == list(range(15))
    np.testing.assert_allclose(t_s, np.array(pts) / 1000.0, atol=1e-6)
    assert src.warnings == []
