"""Check that a speed-only change left every result of ``rovslam run`` bit-identical.

Run: ``python -m benchmarks.check_identical --against SRC`` where SRC is the ``src`` folder of
the build to compare with, e.g.::

    git archive <before> src | tar -x -C /tmp/before
    python -m benchmarks.check_identical --against /tmp/before/src

Both builds run the same simulated sequence (seed 0) and every result file is compared byte for
byte (``summary.json`` without its timing fields, and it and ``config.toml`` on the keys both
builds write). Exits 1 and names the files that differ. The sequence is a case of
:mod:`benchmarks._harness`:

* ``--resolution 360x272`` (default): ``portofino-short``, 600 frames, PNG;
* ``--resolution 1920x1080``: the same survey through the HD camera, 120 frames, JPEG (the vision
  runs at the processing scale, the laser spots in the full frame);

``--frames`` sets another length, ``--texture photo`` uses the real seabed photo.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._harness import Case, sequence_folder  # noqa: E402

TIMING_KEYS = {"wall_time_s", "frames_per_second"}
CASES = {"360x272": ("png", 600), "1920x1080": ("jpg", 120)}  # resolution: image files, frames


def _run(seq: Path, out: Path, src: Path | None) -> None:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    subprocess.run([sys.executable, "-m", "rovslam", "run", str(seq), "--out", str(out), "-q"], check=True, env=env)


def _summary(path: Path) -> dict:
    data = json.loads(path.read_text())
    return {k: v for k, v in data.items() if k not in TIMING_KEYS}


def _same_on_common_keys(a: object, b: object, where: str, one_sided: list[str]) -> bool:
    """Whether two parsed documents agree on every key both have; keys in one only go to ``one_sided``."""
    if isinstance(a, dict) and isinstance(b, dict):
        one_sided.extend(f"{where}{k}" for k in sorted(a.keys() ^ b.keys()))
        return all([_same_on_common_keys(a[k], b[k], f"{where}{k}.", one_sided) for k in sorted(a.keys() & b.keys())])
    return a == b


def compare(a: Path, b: Path) -> list[str]:
    """Relative paths of the files that differ (or exist on one side only).

    ``summary.json`` and ``config.toml`` are compared on the keys both builds write: a new
    record or a new configuration key (at a default that changes nothing) is named, not a difference.
    """
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file()}
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file()}
    bad = sorted(str(p) + " (only in one)" for p in files_a ^ files_b)
    for rel in sorted(files_a & files_b):
        if rel.name in ("summary.json", "config.toml"):
            load = _summary if rel.name == "summary.json" else (lambda p: tomllib.loads(p.read_text()))
            one_sided: list[str] = []
            same = _same_on_common_keys(load(a / rel), load(b / rel), "", one_sided)
            if one_sided:
                print(f"{rel}: keys in one build only, not compared: {', '.join(one_sided)}")
        else:
            same = filecmp.cmp(a / rel, b / rel, shallow=False)
        if not same:
            bad.append(str(rel))
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--against", type=Path, required=True, metavar="SRC")
    ap.add_argument("--resolution", choices=tuple(CASES), default="360x272")
    ap.add_argument("--frames", type=int, default=None, help="default: 600 at 360x272, 120 at 1920x1080")
    ap.add_argument("--texture", choices=("sim", "photo"), default="sim")
    args = ap.parse_args()
    image_format, default_frames = CASES[args.resolution]
    frames = default_frames if args.frames is None else args.frames
    seq = sequence_folder(Case(args.resolution, args.texture, image_format, frames))
    with tempfile.TemporaryDirectory() as tmp:
        this, other = Path(tmp) / "this", Path(tmp) / "against"
        _run(seq, this, None)
        _run(seq, other, args.against.resolve())
        bad = compare(this, other)
        n = sum(1 for p in this.rglob("*") if p.is_file())
    if bad:
        print(f"results differ from {args.against}: {', '.join(bad)}")
        return 1
    print(
        f"all {n} result files bit-identical to those of {args.against} "
        f"({args.resolution}, {frames} frames, {args.texture} seabed)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
