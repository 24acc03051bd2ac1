"""What the whole-pipeline benchmarks share: the benchmark cases, their simulated sequences
(made once and cached), in-memory and replayed sources, one-core pinning and the machine.

The sequences are simulated with ``rovslam.sim`` (seed 0) into ``$ROVSLAM_BENCH_CACHE``
(default ``<tmp>/rovslam-bench``), under a key that includes a hash of the simulator's source,
so a changed simulator writes new ones. Cases:

* ``360x272``: the paper's camera (``portofino-short``: 360x272, f = 1075 px, 5 Hz);
* ``1920x1080``: the same survey rendered by the same simulator through an HD camera
  (1920x1080, f = 4800 px: a 52 x 29 cm footprint at 1.31 m; 25 frames/s, 0.2 m/s; the camera
  of the ``hd-survey`` preset of the simulator branch, rendered here without its relief and lamps);
* texture ``sim``: the procedural seabed; ``photo``: the real rocky-seabed photomosaic
  ``chamber3/seabed.jpg``, found by ``rovslam.data``, at 1.0 mm/px (``rovslam simulate --texture``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PHOTO_MM_PER_PX = 1.0
CACHE = Path(os.environ.get("ROVSLAM_BENCH_CACHE", Path(tempfile.gettempdir()) / "rovslam-bench"))
RESULTS = ROOT / "benchmarks" / "results"
TRIAL_FRAMES = 13275  # the paper's Portofino trial


@dataclass(frozen=True)
class Case:
    """One benchmark input: resolution, seabed texture, image files and length."""

    resolution: str  # "360x272" | "1920x1080"
    texture: str  # "sim" | "photo"
    image_format: str  # "png" | "jpg"
    frames: int

    @property
    def name(self) -> str:
        return f"{self.resolution} {self.texture} {self.image_format} x{self.frames}"


def _sim_hash() -> str:
    h = hashlib.sha256()
    for p in sorted((ROOT / "src" / "rovslam" / "sim").glob("*.py")):
        h.update(p.read_bytes())
    return h.hexdigest()[:10]


def _hd_scenario():
    """The portofino survey through the HD camera, registered as the scenario ``bench-hd``."""
    from rovslam.camera import Camera
    from rovslam.sim import SCENARIOS

    if "bench-hd" not in SCENARIOS:
        base = SCENARIOS["portofino-short"]
        cam = Camera(width_px=1920, height_px=1080, fx_px=4800.0, fy_px=4800.0, cx_px=959.5, cy_px=539.5)
        vehicle = dataclasses.replace(base.vehicle, cruise_speed_mps=0.2, accel_limit_mps2=0.05, substeps=1)
        SCENARIOS["bench-hd"] = dataclasses.replace(
            base,
            name="bench-hd",
            camera=cam,
            frame_rate_hz=25.0,
            vehicle=vehicle,
            description="portofino-short through a 1920x1080 camera, f = 4800 px, 25 frames/s, 0.2 m/s",
        )
    return "bench-hd"


def _photo() -> Path:
    """The real seabed photo, found by :mod:`rovslam.data` (``ROVSLAM_DATA``, its cache, the shared data folder)."""
    from rovslam.data import file_path
    from rovslam.errors import DataNotFoundError

    try:
        return file_path("chamber3", "seabed.jpg")
    except DataNotFoundError as exc:
        raise SystemExit(f"benchmark: the real seabed photo is missing: {exc}") from None


def sequence_folder(case: Case, log=print) -> Path:
    """The simulated sequence of ``case`` (simulated on first use, then reused from the cache)."""
    from rovslam.sim import simulate

    scenario = "portofino-short" if case.resolution == "360x272" else _hd_scenario()
    key = f"{scenario}-{case.texture}-{case.image_format}-{case.frames}-{_sim_hash()}"
    folder = CACHE / key
    if (folder / ".complete").is_file():
        return folder
    photo = _photo() if case.texture == "photo" else None
    shutil.rmtree(folder, ignore_errors=True)
    folder.parent.mkdir(parents=True, exist_ok=True)
    log(f"simulating {case.name} into {folder} (once; cached)", flush=True)
    texture = dict(texture_path=photo, texture_mm_per_px=PHOTO_MM_PER_PX) if photo is not None else {}
    simulate(scenario, folder, frames=case.frames, seed=0, image_format=case.image_format, **texture)
    (folder / ".complete").write_text("ok\n")
    return folder


class MemorySource:
    """A sequence decoded beforehand: ``frames()`` hands out the same decoded frames (no I/O)."""

    def __init__(self, seq: Any) -> None:
        self.info = seq.info
        self.description = getattr(seq, "description", "")  # builds before the input descriptions (--against) have none
        self.path = seq.folder
        self.warnings: list[str] = []
        self.left_out = 0
        self._frames = list(seq.frames(prefetch=0))

    def __len__(self) -> int:
        return len(self._frames)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Any]:
        yield from self._frames[start:stop]


class ReplaySource:
    """A sequence flown ``times`` times, forth and back in turn, times and indices continuing.

    Odd passes read the frames in reverse order (the vehicle flies the survey backwards), so the
    images stay continuous from one pass to the next: a dive ``times`` as long over the same area.
    """

    def __init__(self, seq: Any, times: int) -> None:
        self.seq, self.times = seq, int(times)
        self.info = seq.info
        self.description = getattr(seq, "description", "")  # builds before the input descriptions (--against) have none
        self.path = seq.folder
        self.warnings: list[str] = []
        self.left_out = 0
        rows = seq.rows
        self._t0, self._t1 = rows[0].t_s, rows[-1].t_s
        self._dt = rows[1].t_s - rows[0].t_s if len(rows) > 1 else 1.0

    def __len__(self) -> int:
        return len(self.seq) * self.times

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Any]:
        n = len(self.seq)
        stop = len(self) if stop is None else min(stop, len(self))
        period = self._t1 - self._t0 + self._dt
        for k in range(self.times):
            if k * n >= stop:
                return
            backwards = k % 2 == 1
            passed = self.seq.frames() if not backwards else self._backwards()
            for j, f in enumerate(passed):
                index = k * n + j
                if index >= stop:
                    break
                if index >= start:
                    t = (self._t1 - f.t_s if backwards else f.t_s - self._t0) + k * period + self._t0
                    yield dataclasses.replace(f, index=index, t_s=t)

    def _backwards(self) -> Iterator[Any]:
        for j in range(len(self.seq) - 1, -1, -1):  # one frame at a time: nothing held
            yield from self.seq.frames(j, j + 1, prefetch=0)


@contextmanager
def source_override(source: Any) -> Iterator[None]:
    """Make :func:`rovslam.runner.run_sequence` run ``source`` whatever path it is given."""
    import rovslam.runner as runner

    original = runner.open_source
    runner.open_source = lambda path, camera_file=None, options=None: source
    try:
        yield
    finally:
        runner.open_source = original


def pin_one_core() -> int:
    """Pin this process (and the threads it starts from now on) to one CPU; returns it."""
    cpu = max(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu


def machine() -> dict[str, Any]:
    """The machine and the software the figures were measured with."""
    import cv2
    import numpy as np

    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "memory_gib": round(mem_gib, 1),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "opencv": cv2.__version__,
        "load_average": os.getloadavg(),
        "platform": platform.platform(),
    }


def write_json(name: str, data: dict[str, Any], path: Path | None = None) -> Path:
    """Write ``data`` to ``path`` (default ``benchmarks/results/NAME.json``) and return the path."""
    out = path or RESULTS / f"{name}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=2) + "\n")
    return out
