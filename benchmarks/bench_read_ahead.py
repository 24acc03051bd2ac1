"""What preparing the frames on a second core gains: ``rovslam run`` with and without read-ahead, paired.

Run: ``python benchmarks/bench_read_ahead.py [--pairs 6]`` (``python -m benchmarks read_ahead``).
:func:`rovslam.runner.run_sequence` reads ahead (``read_ahead=None``) when the process may use two
cores or more: a thread decodes the frames (when the source decodes as it is read: videos, image
folders, bags; a sequence folder processed at its own size) and prepares each
(:mod:`rovslam.pipeline.prepare`) while the loop runs; a sequence folder of 600 frames or more
processed at its own size is read and prepared in a second process instead
(:mod:`rovslam.pipeline.prepare_process`). This script runs the same input with
``read_ahead=True`` and ``False`` in turn, in one process (so that both meet the same machine),
``--pairs`` times, the order alternating, and prints the median frames/s of each and the median of
the per-pair ratios, with how many pairs read-ahead won. The inputs, made once and kept under the
benchmarks' temporary folder:

* ``360x272 PNG folder``: the benchmarks' simulated survey (600 frames, ``benchmarks/_harness.py``),
  read in a second process; ``... on a thread``: the same on a thread, as shorter folders are;
  ``... 3,000 frames``: the survey flown for 5 minutes (the process's start is a smaller share);
* ``360x272 H.264``: the same frames as an MP4 video (libx264, CRF 18) with its camera file;
* ``1920x1080 H.264``: the HD survey's frames (120) as an MP4 video.

Results are bit-identical either way (``tests/test_prepare.py``); only the time differs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import Case, machine, sequence_folder  # noqa: E402

try:
    from rovslam.pipeline.prepare_process import MIN_FRAMES as _MIN_FRAMES
except ImportError:  # a build from before the second process
    _MIN_FRAMES = 10**9

# name: (case, video frame rate or None for the folder itself, read ahead on a thread even where a process would)
INPUTS = {
    "360x272 PNG folder": (Case("360x272", "sim", "png", 600), None, False),
    "  ... on a thread": (Case("360x272", "sim", "png", 600), None, True),
    "  ... 3,000 frames": (Case("360x272", "sim", "png", 3000), None, False),
    "360x272 H.264": (Case("360x272", "sim", "png", 600), 10, False),
    "1920x1080 H.264": (Case("1920x1080", "sim", "jpg", 120), 25, False),
}


def _video(seq: Path, fps: int) -> tuple[Path, Path]:
    """``(video.mp4, camera.toml)`` made from a sequence folder's images (once; kept beside it)."""
    import av

    from rovslam.io.sequence import open_sequence
    from rovslam.sim.sitl import write_camera_file

    mp4, cam = seq.with_name(seq.name + ".mp4"), seq.with_name(seq.name + "-camera.toml")
    if not (mp4.is_file() and cam.is_file()):
        source = open_sequence(seq)
        part = mp4.with_suffix(".part.mp4")
        with av.open(str(part), "w") as c:
            st = c.add_stream("libx264", rate=fps)
            st.width, st.height, st.pix_fmt = source.info.camera.width_px, source.info.camera.height_px, "yuv420p"
            st.options = {"crf": "18", "preset": "veryfast"}
            for f in source.frames(prefetch=0):
                for pkt in st.encode(av.VideoFrame.from_ndarray(f.image, format="rgb24")):
                    c.mux(pkt)
            for pkt in st.encode():
                c.mux(pkt)
        part.replace(mp4)
        write_camera_file(cam, source.info)
    return mp4, cam


def _pairs(path: Path, camera: Path | None, pairs: int, tmp: Path, thread: bool) -> dict:
    import rovslam.pipeline.prepare_process as process
    from rovslam.io.source import InputOptions
    from rovslam.runner import run_sequence

    process.MIN_FRAMES = 10**9 if thread else _MIN_FRAMES

    opts = InputOptions(camera_file=camera) if camera is not None else None

    def fps(ahead: bool) -> float:
        t0 = time.perf_counter()
        s = run_sequence(path, tmp / f"out-{ahead}", inputs=opts, read_ahead=ahead, overwrite=True)
        return s.frames / (time.perf_counter() - t0)

    fps(False)  # imports and first-use caches, untimed
    with_, without, ratios = [], [], []
    for i in range(pairs):
        got = {ahead: fps(ahead) for ahead in ((True, False) if i % 2 else (False, True))}
        with_.append(got[True])
        without.append(got[False])
        ratios.append(got[True] / got[False])
    return {
        "with": statistics.median(with_),
        "without": statistics.median(without),
        "ratio": statistics.median(ratios),
        "won": sum(r > 1.0 for r in ratios),
        "pairs": pairs,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--quick", action="store_true", help="3 pairs")
    args, _ = ap.parse_known_args()
    pairs = 3 if args.quick else args.pairs
    m = machine()
    print(f"machine: {m['cpu']}, {m['cores']} cores; load average {m['load_average'][0]:.1f}")
    print(f"{'input':<22}{'read-ahead':>12}{'without':>10}{'ratio':>8}  pairs won")
    with tempfile.TemporaryDirectory(prefix="rovslam-bench-ahead-") as tmp:
        for name, (case, fps, thread) in INPUTS.items():
            seq = sequence_folder(case, log=lambda *a, **k: None)
            path, camera = (seq, None) if fps is None else _video(seq, fps)
            r = _pairs(path, camera, pairs, Path(tmp), thread)
            print(
                f"{name:<22}{r['with']:>12.1f}{r['without']:>10.1f}{r['ratio']:>8.3f}  {r['won']}/{r['pairs']}",
                flush=True,
            )
    print("frames/s: medians over the pairs; ratio: median of each pair's read-ahead / without (wall clock)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
