"""Whole-pipeline speed of ``rovslam run`` : frames/s, the baseline, the stages, the profile.

Run: ``python -m benchmarks pipeline`` (``--quick`` for a short look; ``--cases 360-sim-png``
for one case; ``--profile`` adds a pyinstrument profile of two runs). Prints the tables and
writes everything to ``benchmarks/results/pipeline.json`` (``--json PATH``).

Cases (``benchmarks/_harness.py``): 360x272 and 1920x1080 frames of the simulated portofino
survey, on the procedural seabed (``sim``) and on the real seabed photo (``photo``), read from
memory (decoded beforehand), from PNG or from JPEG files. Each measurement runs in a fresh
process; ``1 core`` means that process is pinned to one CPU (OpenCV's threads and the decoding
thread included), ``2 cores`` that it may use both. Figures are medians over ``--repeats`` runs.

* ``rovslam run``: :func:`rovslam.runner.run_sequence` as ``rovslam run`` calls it (result files
  written, the progress bar drawn on a pseudo-terminal); from memory, the same with a source that
  hands out the decoded frames;
* ``baseline`` (same frames, same process kind): decoding each file with OpenCV (``cv2.imread``,
  grey, float32) and ``cv2.phaseCorrelate`` of each consecutive pair; from memory, the phase
  correlation alone. ``ratio`` = ``rovslam run`` time / baseline time;
* ``decode``: ``cv2.imread`` alone;
* ``stages``: one instrumented run (one core, decoding in the main thread) split into the stages
  of the loop by timers wrapped around the library's step methods (``benchmarks/_stages.py``);
  the stages add up to the run's wall time, ``loop and glue`` being what no timer covers.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import TRIAL_FRAMES, Case, machine, sequence_folder, write_json  # noqa: E402

CASES = {
    "360-sim-mem": Case("360x272", "sim", "png", 600),
    "360-sim-png": Case("360x272", "sim", "png", 600),
    "360-sim-jpg": Case("360x272", "sim", "jpg", 600),
    "360-photo-mem": Case("360x272", "photo", "png", 600),
    "360-photo-png": Case("360x272", "photo", "png", 600),
    "360-photo-jpg": Case("360x272", "photo", "jpg", 600),
    "hd-sim-mem": Case("1920x1080", "sim", "jpg", 120),
    "hd-sim-jpg": Case("1920x1080", "sim", "jpg", 120),
    "hd-photo-mem": Case("1920x1080", "photo", "jpg", 120),
    "hd-photo-jpg": Case("1920x1080", "photo", "jpg", 120),
}
STAGE_CASES = ("360-sim-png", "360-photo-png", "hd-sim-jpg")
PROFILE_CASES = ("360-sim-mem", "hd-sim-mem")


# ----------------------------------------------------------------------------- worker side


def _bar_factory():
    """The progress bar of ``rovslam run`` (drawn on this process's stderr)."""
    try:
        from rovslam.cli.display import ProgressBar, slam_callbacks
    except ImportError:  # an --against build from before the CLI package: one module
        from rovslam.cli import _progress as ProgressBar  # noqa: N813
        from rovslam.cli import _slam_callbacks as slam_callbacks

    return ProgressBar, slam_callbacks


def _run_once(source_path: Path, memory, out: Path, wrap_callbacks=None, max_frames: int | None = None) -> int:
    from benchmarks._harness import source_override
    from rovslam.runner import run_sequence

    progress, callbacks = _bar_factory()
    with progress(False, "SLAM", extra=True) as bar:
        cbs = callbacks(bar)
        if wrap_callbacks is not None:
            cbs = {k: wrap_callbacks(f) for k, f in cbs.items()}
        if memory is not None:
            with source_override(memory):
                s = run_sequence(source_path, out, max_frames=max_frames, **cbs)
        else:
            s = run_sequence(source_path, out, max_frames=max_frames, **cbs)
    return s.frames


def _baseline_once(paths: list[Path] | None, grey: list | None) -> int:
    import cv2
    import numpy as np

    prev = None
    n = 0
    if grey is not None:
        for g in grey:
            if prev is not None:
                cv2.phaseCorrelate(prev, g)
            prev, n = g, n + 1
        return n
    for p in paths:
        g = np.float32(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
        if prev is not None:
            cv2.phaseCorrelate(prev, g)
        prev, n = g, n + 1
    return n


def _decode_once(paths: list[Path]) -> int:
    import cv2

    for p in paths:
        cv2.imread(str(p), cv2.IMREAD_COLOR)
    return len(paths)


def _timed(fn, repeats: int) -> dict:
    walls, cpus, frames = [], [], 0
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        frames = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return {
        "frames": frames,
        "wall_s": walls,
        "cpu_s": cpus,
        "median_wall_s": statistics.median(walls),
        "median_cpu_s": statistics.median(cpus),
    }


def worker(spec: dict) -> dict:
    from benchmarks._harness import MemorySource, pin_one_core

    if spec["cores"] == 1:
        pin_one_core()
    from rovslam.io.sequence import open_sequence

    folder = Path(spec["folder"])
    memory = spec["source"] == "mem"
    seq = open_sequence(folder)
    paths = [folder / r.image for r in seq.rows]
    mode, repeats = spec["mode"], spec["repeats"]
    tmp = Path(tempfile.mkdtemp(prefix="rovslam-bench-"))
    runs = iter(range(10**6))
    if mode in ("run", "stages", "profile"):
        mem = MemorySource(seq) if memory else None
        _run_once(folder, mem, tmp / "warm", max_frames=5)  # imports and first-use caches, untimed
        if mode == "run":
            return _timed(lambda: _run_once(folder, mem, tmp / f"o{next(runs)}"), repeats)
        if mode == "stages":
            return _stages(folder, mem, tmp)
        return _profile(folder, mem, tmp, spec.get("top", 15))
    if mode == "baseline":
        if memory:
            import cv2
            import numpy as np

            grey = [np.float32(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in paths]
            return _timed(lambda: _baseline_once(None, grey), repeats)
        return _timed(lambda: _baseline_once(paths, None), repeats)
    if mode == "decode":
        return _timed(lambda: _decode_once(paths), repeats)
    raise SystemExit(f"unknown mode {mode}")


def _stages(folder: Path, memory, tmp: Path) -> dict:
    import functools

    from benchmarks._stages import PROGRESS, StageClock
    from rovslam.io.sequence import Sequence

    frames_orig = Sequence.frames

    @functools.wraps(frames_orig)
    def frames_in_main_thread(self, start=0, stop=None, prefetch=4):
        return frames_orig(self, start, stop, prefetch=0)

    clock = StageClock()
    Sequence.frames = frames_in_main_thread
    clock.install()
    try:
        n, total = clock.timed_total(
            lambda: _run_once(folder, memory, tmp / "stages", lambda f: clock.wrap(PROGRESS, f, "progress callback"))
        )
    finally:
        clock.uninstall()
        Sequence.frames = frames_orig
    st = clock.result(total, n)
    return {
        "frames": n,
        "total_s": total,
        "glue_share": st.glue_share,
        "uncalled": st.uncalled,
        "stages": [{"stage": lb, "ms_per_frame": ms, "share": sh, "calls": c} for lb, ms, sh, c in st.table()],
    }


def _profile(folder: Path, memory, tmp: Path, top: int) -> dict:
    from collections import defaultdict

    from pyinstrument import Profiler

    prof = Profiler(interval=0.0005)
    prof.start()
    n = _run_once(folder, memory, tmp / "profile")
    session = prof.stop()
    root = session.root_frame()
    self_s: dict[str, float] = defaultdict(float)

    def walk(f) -> None:
        real = [c for c in f.children if not c.identifier.startswith("[")]
        self_s[f"{f.function} ({f.file_path_short}:{f.line_no})"] += f.time - sum(c.time for c in real)
        for c in real:
            walk(c)

    walk(root)
    total = root.time
    rows = sorted(self_s.items(), key=lambda kv: -kv[1])[:top]
    html = tmp / "profile.html"
    html.write_text(prof.output_html())
    return {
        "frames": n,
        "total_s": total,
        "html": str(html),
        "hotspots": [{"function": k, "self_s": v, "share": v / total, "ms_per_frame": 1e3 * v / n} for k, v in rows],
    }


# ----------------------------------------------------------------------------- driver side


def _spawn(spec: dict, src: Path | None = None) -> dict:
    """Run one measurement in a fresh process (stderr on a pseudo-terminal, as a user's run).

    ``src``: the ``src`` folder of another build of rovslam to measure instead of the installed one.
    """
    import pty

    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(src)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    master, slave = pty.openpty()
    tail = bytearray()  # the last of what the worker wrote on its terminal (a traceback, when it fails)
    drained = threading.Thread(target=_drain, args=(master, tail), daemon=True)
    drained.start()
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "benchmarks.bench_pipeline", "--worker", json.dumps(spec)],
            stdout=subprocess.PIPE,
            stderr=slave,
            text=True,
            cwd=Path(__file__).resolve().parents[1],
            env=env,
        )
    finally:
        os.close(slave)
    if proc.returncode != 0:
        drained.join(timeout=2.0)
        err = tail.decode("utf-8", "replace").replace("\r", "")
        raise SystemExit(f"benchmark worker failed ({spec}); its output:\n{proc.stdout}{err}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _drain(fd: int, tail: bytearray) -> None:
    """Read a pseudo-terminal until it closes, keeping its last 8 KiB in ``tail``."""
    try:
        while chunk := os.read(fd, 65536):
            tail.extend(chunk)
            del tail[:-8192]
    except OSError:
        pass
    finally:
        os.close(fd)


def _fps(r: dict) -> float:
    return r["frames"] / r["median_wall_s"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--cases", nargs="+", choices=sorted(CASES), default=None, help="default: all")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="one repeat, half the frames, no stages")
    ap.add_argument("--no-stages", action="store_true")
    ap.add_argument("--profile", action="store_true", help="also profile the 360x272 and HD runs from memory")
    ap.add_argument(
        "--against",
        type=Path,
        default=None,
        metavar="SRC",
        help="also measure the build whose package is in SRC (e.g. `git archive REV src | tar -x -C /tmp/old` "
        "then --against /tmp/old/src), each measurement right after the same one of the build measured",
    )
    ap.add_argument("--json", type=Path, default=None, help="default benchmarks/results/pipeline.json")
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(json.loads(args.worker))))
        return 0

    if args.profile:
        import importlib.util

        if importlib.util.find_spec("pyinstrument") is None:
            raise SystemExit(
                "--profile needs pyinstrument: .venv/bin/pip install -e '.[bench]' (make bench installs it)"
            )
    names = args.cases or list(CASES)
    repeats = 1 if args.quick else args.repeats
    info = machine()
    print(
        f"machine: {info['cpu']}, {info['cores']} cores, {info['memory_gib']} GiB; Python {info['python']}, "
        f"NumPy {info['numpy']}, OpenCV {info['opencv']}; load average {info['load_average'][0]:.1f}",
        flush=True,
    )
    builds = {"this": None} | ({"against": args.against.resolve()} if args.against else {})
    results: dict = {
        "machine": info,
        "repeats": repeats,
        "builds": {k: str(v or "installed") for k, v in builds.items()},
        "cases": {b: {} for b in builds},
    }
    for name in names:
        case = CASES[name]
        if args.quick:
            case = Case(case.resolution, case.texture, case.image_format, case.frames // 2)
        folder = sequence_folder(case)
        src = "mem" if name.endswith("-mem") else "file"
        base = {"folder": str(folder), "source": src, "repeats": repeats}
        for b in builds:
            results["cases"][b][name] = {"case": case.name, "source": "memory" if src == "mem" else case.image_format}
        print(f"{name}: ", end="", flush=True)
        for mode, cores in (("run", 1), ("run", 2), ("baseline", 1), ("baseline", 2)) + (
            (("decode", 1),) if src == "file" else ()
        ):
            for b, path in builds.items():
                if mode != "run" and b != "this":
                    continue  # the baselines do not depend on the build
                r = results["cases"][b][name][f"{mode}@{cores}"] = _spawn({**base, "mode": mode, "cores": cores}, path)
                print(f"{mode}@{cores}{'' if b == 'this' else ' (against)'} {_fps(r):.0f} fps  ", end="", flush=True)
        print()
        for b in builds:
            if b != "this":
                results["cases"][b][name].update(
                    {k: v for k, v in results["cases"]["this"][name].items() if "@" in k and not k.startswith("run")}
                )
    for b in builds:
        _print_speed(results["cases"][b], f" ({b} build: {results['builds'][b]})" if len(builds) > 1 else "")
    if len(builds) > 1:
        _print_speedup(results["cases"])
    if not (args.quick or args.no_stages):
        results["stages"] = {b: {} for b in builds}
        for name in STAGE_CASES:
            if name in names:
                spec = {
                    "folder": str(sequence_folder(CASES[name])),
                    "source": "file",
                    "repeats": 1,
                    "mode": "stages",
                    "cores": 1,
                }
                for b, path in builds.items():
                    results["stages"][b][name] = _spawn(spec, path)
        for b in builds:
            _print_stages(results["stages"][b], f" ({b} build)" if len(builds) > 1 else "")
    if args.profile:
        results["profile"] = {}
        for name in PROFILE_CASES:
            if name in names:
                spec = {
                    "folder": str(sequence_folder(CASES[name])),
                    "source": "mem",
                    "repeats": 1,
                    "mode": "profile",
                    "cores": 1,
                }
                results["profile"][name] = _spawn(spec)
        _print_profile(results["profile"])
    path = write_json("pipeline", results, args.json)
    print(f"\nwrote {path}")
    return 0


def _print_speedup(cases: dict) -> None:
    print("\nspeed-up of the build measured over the --against build (rovslam run, frames/s)")
    print(f"{'case':<16}{'1 core':>22}{'2 cores':>22}")
    for name, r in cases["this"].items():
        o = cases["against"][name]
        cells = [f"{_fps(o[k]):6.0f} -> {_fps(r[k]):5.0f} x{_fps(r[k]) / _fps(o[k]):4.2f}" for k in ("run@1", "run@2")]
        print(f"{name:<16}{cells[0]:>22}{cells[1]:>22}")


def _print_speed(cases: dict, title: str = "") -> None:
    print(
        f"\nframes/s (median){title}; ratio = rovslam run time / baseline time (decode + phaseCorrelate; from memory: "
        "phaseCorrelate alone), each on the same number of cores"
    )
    head = (
        f"{'case':<16}{'source':>7}{'run 1c':>8}{'run 2c':>8}{'base 1c':>9}{'base 2c':>9}{'decode':>8}"
        f"{'ratio 1c':>9}{'ratio 2c':>9}{'run 2c / base 1c':>18}{'CPU ms/fr':>10}"
    )
    print(head)
    print("-" * len(head))
    for name, r in cases.items():
        run1, run2, b1, b2 = (r[k] for k in ("run@1", "run@2", "baseline@1", "baseline@2"))
        dec = f"{_fps(r['decode@1']):8.0f}" if "decode@1" in r else f"{'-':>8}"
        cpu_ms = 1e3 * run1["median_cpu_s"] / run1["frames"]
        print(
            f"{name:<16}{r['source']:>7}{_fps(run1):8.0f}{_fps(run2):8.0f}{_fps(b1):9.0f}{_fps(b2):9.0f}{dec}"
            f"{run1['median_wall_s'] / b1['median_wall_s']:9.2f}{run2['median_wall_s'] / b2['median_wall_s']:9.2f}"
            f"{run2['median_wall_s'] / b1['median_wall_s']:18.2f}{cpu_ms:10.2f}"
        )
    for name in ("360-sim-png", "360-photo-png"):
        if name in cases:
            r = cases[name]
            per = {k: r[k]["median_wall_s"] / r[k]["frames"] for k in ("run@1", "run@2")}
            print(
                f"full trial ({TRIAL_FRAMES} frames) from PNG, projected from {name}: "
                f"{TRIAL_FRAMES * per['run@2']:.0f} s (2 cores), {TRIAL_FRAMES * per['run@1']:.0f} s (1 core)"
            )


def _print_stages(stages: dict, title: str = "") -> None:
    for name, st in stages.items():
        print(
            f"\nstages of {name}{title} (one core, decoding in the main thread): {st['frames']} frames, "
            f"{1e3 * st['total_s'] / st['frames']:.2f} ms per frame measured"
        )
        print(f"{'stage':<38}{'ms/frame':>10}{'share':>8}{'calls':>8}")
        for row in st["stages"]:
            print(f"{row['stage']:<38}{row['ms_per_frame']:10.3f}{100 * row['share']:7.1f}%{row['calls']:8d}")
        named = 1.0 - st["glue_share"]
        print(
            f"named stages cover {100 * named:.1f} % of the measured frame time "
            f"({'within' if st['glue_share'] <= 0.10 else 'NOT within'} 10 %)"
        )
        if st["uncalled"]:
            print(f"never called in this run: {', '.join(st['uncalled'])}")


def _print_profile(profiles: dict) -> None:
    for name, p in profiles.items():
        print(
            f"\nprofile of {name} (pyinstrument, one core): {p['frames']} frames, "
            f"{1e3 * p['total_s'] / p['frames']:.2f} ms per frame under the profiler; HTML: {p['html']}"
        )
        print(f"{'self time in':<70}{'ms/frame':>10}{'share':>8}")
        for h in p["hotspots"]:
            print(f"{h['function'][:69]:<70}{h['ms_per_frame']:10.3f}{100 * h['share']:7.1f}%")


if __name__ == "__main__":
    sys.exit(main())
