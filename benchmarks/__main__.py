"""Run every benchmark script in this folder, one after the other, and print their tables.

Usage: ``python -m benchmarks [NAME ...]`` (names without ``bench_`` / ``.py``; default: all).
Each script prints medians over repeated runs and ratios against a baseline measured in
the same run.
"""

import subprocess
import sys
from pathlib import Path

here = Path(__file__).parent
wanted = set(sys.argv[1:])
scripts = sorted(p for p in here.glob("bench_*.py") if not wanted or p.stem[len("bench_"):] in wanted)
status = 0
for script in scripts:
    print(f"\n=== {script.stem} ===", flush=True)
    status |= subprocess.call([sys.executable, str(script)])
sys.exit(status)
