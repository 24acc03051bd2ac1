"""Run benchmark scripts of this folder, one after the other, and print their tables.

Usage: ``python -m benchmarks [NAME ...] [-- OPTIONS]`` (names without ``bench_`` / ``.py``;
default: all; options after ``--``, or any argument starting with ``-``, go to every script
run, e.g. ``python -m benchmarks pipeline --quick``). Each script prints medians over
repeated runs and ratios against a baseline measured in the same run; ``pipeline`` and
``memory`` also write ``benchmarks/results/NAME.json`` (``live``: ``live.json``, its latency and dropped frames).
"""

import subprocess
import sys
from pathlib import Path

here = Path(__file__).parent
args = [a for a in sys.argv[1:] if a != "--"]
wanted = {a for a in args if not a.startswith("-") and (here / f"bench_{a}.py").is_file()}
passed = [a for a in args if a not in wanted]
scripts = sorted(p for p in here.glob("bench_*.py") if not wanted or p.stem[len("bench_"):] in wanted)
status = 0
for script in scripts:
    print(f"\n=== {script.stem} ===", flush=True)
    status |= subprocess.call([sys.executable, str(script), *passed], cwd=here.parent)
sys.exit(status)
