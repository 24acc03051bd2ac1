"""Where the loop's time goes, by the library it is in: Python, NumPy's dispatch, NumPy's compute, OpenCV.

Run: ``python benchmarks/profile_libraries.py [--case 360-sim-png] [--rate 500]`` (needs py-spy:
``pip install -e '.[bench]'``, which ``make bench`` does). ``rovslam run`` of one case of
``benchmarks/bench_pipeline.py`` (its sequence folder, made once and cached) runs on one core
(py-spy beside it), decoding in the loop's own process, and py-spy samples it with its native frames. Each sample
inside the loop (:meth:`rovslam.pipeline.SlamPipeline.process`) is counted by its innermost frame:

* ``Python``: the interpreter running rovslam's or a library's Python code;
* ``NumPy dispatch``: inside NumPy's C module but not in one of its compute loops (argument
  parsing, type resolution, array creation, iterators: the cost of a call on a small array);
* ``NumPy compute``: NumPy's inner loops (``DOUBLE_add``, sorts, partitions, ...);
* ``OpenCV``: inside ``cv2`` (its kernels and its bindings);
* ``C library``: ``libc`` (allocation, copies), ``BLAS``, anything else.

Then the functions of rovslam holding the most samples (with what they call). A sample is a
statistical figure: two runs differ by a percent or so.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import pin_one_core, sequence_folder  # noqa: E402
from benchmarks.bench_pipeline import CASES  # noqa: E402

LOOP_FRAME = "SlamPipeline.process ("
_NUMPY_COMPUTE = re.compile(
    r"^(BOOL|BYTE|UBYTE|SHORT|USHORT|INT|UINT|LONG|ULONG|LONGLONG|ULONGLONG|HALF|FLOAT|DOUBLE|CFLOAT|CDOUBLE)_"
    r"|pairwise_sum|sort|partition|select"
)
KINDS = ("Python", "NumPy dispatch", "NumPy compute", "OpenCV", "C library")

_RUN = """
from rovslam.runner import run_sequence
run_sequence({seq!r}, {out!r}, overwrite=True, read_ahead=False)
"""


def kind_of(leaf: str) -> str:
    """The :data:`KINDS` entry of a sample's innermost frame (py-spy's ``name (file:line)`` or ``name (library)``)."""
    name, _, where = leaf.rpartition(" (")
    where = where.rstrip(")")
    if re.search(r"\.py:\d+$", where) or where.startswith("<"):
        return "Python"
    if "_umath" in where:  # numpy/_core/_multiarray_umath
        return "NumPy compute" if _NUMPY_COMPUTE.search(name) else "NumPy dispatch"
    if "cv2" in where:
        return "OpenCV"
    return "C library"


def tally(raw_lines: list[str]) -> tuple[int, collections.Counter, collections.Counter]:
    """``(samples in the loop, samples by kind, samples by innermost rovslam function)`` of py-spy's raw output."""
    total, kinds, funcs = 0, collections.Counter(), collections.Counter()
    for line in raw_lines:
        stack, _, count = line.rstrip().rpartition(" ")
        if not count.isdigit():
            continue
        frames = stack.split(";")
        if not any(LOOP_FRAME in f for f in frames):
            continue
        n = int(count)
        total += n
        kinds[kind_of(frames[-1])] += n
        own = [f for f in frames if "rovslam/" in f]
        if own:
            funcs[own[-1].split(" (")[0] + "  " + own[-1].split("rovslam/")[1].split(":")[0]] += n
    return total, kinds, funcs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", choices=sorted(c for c in CASES if not c.endswith("-mem")), default="360-sim-png")
    ap.add_argument("--rate", type=int, default=500, help="samples a second")
    ap.add_argument("--top", type=int, default=15, help="functions listed")
    args = ap.parse_args()
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).is_file():
        print("py-spy not found: pip install -e '.[bench]' (make bench installs it)", file=sys.stderr)
        return 2
    folder = sequence_folder(CASES[args.case])
    with tempfile.TemporaryDirectory(prefix="rovslam-spy-") as tmp:
        raw = Path(tmp) / "raw.txt"
        code = _RUN.format(seq=str(folder), out=str(Path(tmp) / "out"))
        cmd = [spy, "record", "--native", "--rate", str(args.rate), "--format", "raw", "-o", str(raw), "--"]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        # py-spy and the run on the same core (both inherit this process's): py-spy stops the run for each
        # native stack, and from the other core of a 2-core VM it fell behind, most of its time in the kernel
        pin_one_core()
        done = subprocess.run([*cmd, sys.executable, "-c", code], capture_output=True, text=True, env=env)
        if done.returncode != 0 or not raw.is_file():
            print(f"py-spy failed ({done.returncode}): {done.stderr.strip()[-500:]}", file=sys.stderr)
            return 1
        total, kinds, funcs = tally(raw.read_text().splitlines())
    if total == 0:
        print("no sample inside the loop", file=sys.stderr)
        return 1
    print(f"{args.case}: {total} samples inside the loop (one core, {args.rate} a second)\n")
    print(f"{'where':<16} {'share':>6}")
    for k in KINDS:
        print(f"{k:<16} {100 * kinds[k] / total:5.1f}%")
    print(f"\nthe {args.top} functions of rovslam holding the most samples (with what they call)")
    for name, n in funcs.most_common(args.top):
        print(f"{100 * n / total:5.1f}%  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
