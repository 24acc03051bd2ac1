"""Per-stage timing of a whole ``rovslam run``, without touching the library: the pipeline's step
methods, the vision functions it calls, the decoder, the writers and the progress callbacks are
wrapped in timers in the benchmark process (monkeypatching), each timer counting its own time
minus that of the timed calls inside it (exclusive time). What no timer covers (the loop itself,
the glue between steps) is reported as ``loop and glue``, so the stages add up to the run's
measured wall time by construction; the benchmark checks that this remainder stays under 10 %.

Every target is named by its import path. A target that no longer exists (a method renamed or
removed in the library) stops the benchmark with a message naming it and this file, instead of
timing nothing; a target never called during the run is listed as such.
"""

from __future__ import annotations

import functools
import importlib
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

# (label, targets); a target is "module:Attr.path". Order = the order of the table.
STAGES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("decode", ("rovslam.io.sequence:Sequence._load",)),
    (
        "channel and despeckle",
        (
            "rovslam.pipeline.image:despeckled_channels",
            "rovslam.pipeline.image:template_channel_u8",
            "rovslam.vision.scale:ProcessingScale.reduce_channel",
            "rovslam.pipeline.image:remove_specks",
        ),
    ),
    (
        "band-pass (+ texture check)",
        (
            "rovslam.pipeline.image:bandpass",
            "rovslam.pipeline.image:contrast_std",
            "rovslam.pipeline:SlamPipeline._tracking_image",
        ),
    ),
    ("local variance", ("rovslam.pipeline.loop:local_variance", "rovslam.pipeline.search:local_variance")),
    (
        "laser (spots, altitude, inhibition)",
        ("rovslam.pipeline:SlamPipeline._measure_altitude", "rovslam.pipeline:SlamPipeline._inhibit_laser_spots"),
    ),
    (
        "landmark search (gate, match, new)",
        (
            "rovslam.pipeline:SlamPipeline._track_landmarks",
            "rovslam.pipeline:SlamPipeline._choose_new_landmark",
            "rovslam.pipeline:SlamPipeline._inhibit_landmarks",
        ),
    ),
    (
        "token tracking (match, extract)",
        (
            "rovslam.pipeline.speed:SpeedStep.token_predictions",
            "rovslam.vision.tracking:TokenTracker.track",
            "rovslam.pipeline:SlamPipeline._extract_tokens",
        ),
    ),
    (
        "token tracking: phase correlation",
        ("rovslam.vision.tracking:global_shift", "rovslam.vision.tracking:reduce_image"),
    ),
    ("speed estimation", ("rovslam.pipeline:SlamPipeline._measure_speed",)),
    ("sunlight watch", ("rovslam.pipeline:SlamPipeline._watch_sunlight", "rovslam.sensor.sunlight:BrightHistory.push")),
    ("heading", ("rovslam.sensor.heading:HeadingTracker.prior", "rovslam.pipeline:SlamPipeline._fuse_heading")),
    (
        "EKF (predict, update, augment)",
        (
            "rovslam.pipeline:SlamPipeline._predict_and_update",
            "rovslam.pipeline:SlamPipeline._add_landmark",
            "rovslam.pipeline:SlamPipeline._start_filter",
        ),
    ),
    (
        "result records",
        (
            "rovslam.pipeline.records:FrameRecords.measurements",
            "rovslam.pipeline.records:FrameRecords.result",
            "rovslam.pipeline:SlamPipeline._back_end",
            "rovslam.pipeline:SlamPipeline._skip",
        ),
    ),
    (
        "writers (CSV, templates, summary)",
        (
            "rovslam.io.results:ResultWriter.write_frame",
            "rovslam.io.results:ResultWriter.write_landmark_template",
            "rovslam.io.results:GalleryWriter.write_frame",
            "rovslam.io.measurements:MeasurementWriter.write",
            "rovslam.tallies:SourceTally.add",
            "rovslam.runner:_Run._finish",
            "rovslam.io.results:ResultWriter.write_config",
            "rovslam.io.results:ResultWriter.write_summary",
        ),
    ),
)
PROGRESS = "progress display"
GLUE = "loop and glue"
# Targets a run may legitimately never call (no unusable frame, no AHRS, frames at the processing scale).
MAY_BE_UNCALLED = {
    "rovslam.pipeline:SlamPipeline._skip",
    "rovslam.pipeline:SlamPipeline._start_filter",
    "rovslam.pipeline.image:template_channel_u8",
    "rovslam.vision.scale:ProcessingScale.reduce_channel",
    "rovslam.pipeline.image:remove_specks",
    "rovslam.io.results:ResultWriter.write_landmark_template",
}


class MissingTarget(SystemExit):
    pass


def resolve(target: str) -> tuple[Any, str, Any]:
    """``(owner, attribute, current value)`` of ``module:Attr.path``, or :class:`MissingTarget` naming it."""
    mod_name, _, path = target.partition(":")
    try:
        owner: Any = importlib.import_module(mod_name)
    except ImportError as exc:
        raise MissingTarget(f"benchmarks/_stages.py: cannot import {mod_name} for the stage timer ({exc})") from None
    parts = path.split(".")
    for i, part in enumerate(parts):
        if not hasattr(owner, part):
            where = ".".join([mod_name] + parts[:i]) if i else mod_name
            raise MissingTarget(
                f"benchmarks/_stages.py: {where} has no attribute {part!r} (timing target {target}): it was renamed "
                "or removed in the library; update STAGES in benchmarks/_stages.py so every step is timed"
            )
        if i < len(parts) - 1:
            owner = getattr(owner, part)
    attr = parts[-1]
    value = owner.__dict__[attr] if isinstance(owner, type) and attr in owner.__dict__ else getattr(owner, attr)
    if not callable(value):
        raise MissingTarget(f"benchmarks/_stages.py: timing target {target} is not callable any more; update STAGES")
    return owner, attr, value


@dataclass
class StageTimes:
    """Exclusive seconds and call counts per label, over one run."""

    seconds: dict[str, float]
    calls: dict[str, int]
    uncalled: list[str]
    total_s: float
    frames: int

    def table(self) -> list[tuple[str, float, float, int]]:
        """Rows ``(label, ms per frame, share of the total, calls)`` in stage order, glue last."""
        labels = [label for label, _ in STAGES] + [PROGRESS, GLUE]
        return [
            (
                lb,
                1e3 * self.seconds.get(lb, 0.0) / self.frames,
                self.seconds.get(lb, 0.0) / self.total_s,
                self.calls.get(lb, 0),
            )
            for lb in labels
        ]

    @property
    def glue_share(self) -> float:
        return self.seconds.get(GLUE, 0.0) / self.total_s


class StageClock:
    """Installs the timers; ``with clock.installed(): ...`` then ``clock.result(total_s, frames)``."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self.clock = clock
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.target_calls: dict[str, int] = defaultdict(int)
        self._stack: list[float] = []
        self._main = threading.main_thread()
        self._undo: list[tuple[Any, str, Any]] = []

    def wrap(self, label: str, fn: Callable, target: str = "") -> Callable:
        clock, stack, seconds, calls, tcalls, main = (
            self.clock,
            self._stack,
            self.seconds,
            self.calls,
            self.target_calls,
            self._main,
        )

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if threading.current_thread() is not main:
                return fn(*args, **kwargs)
            stack.append(0.0)
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = clock() - t0
                inner = stack.pop()
                seconds[label] += elapsed - inner
                calls[label] += 1
                tcalls[target] += 1
                if stack:
                    stack[-1] += elapsed

        return timed

    def install(self) -> None:
        resolved = [(label, t, *resolve(t)) for label, targets in STAGES for t in targets]  # all checked first
        for label, target, owner, attr, value in resolved:
            self._undo.append((owner, attr, value))
            setattr(owner, attr, self.wrap(label, value, target))

    def uninstall(self) -> None:
        while self._undo:
            owner, attr, value = self._undo.pop()
            setattr(owner, attr, value)

    def timed_total(self, fn: Callable[[], Any]) -> tuple[Any, float]:
        """Run ``fn`` as the outermost timed call; returns its result and its wall time."""
        outer = self.wrap(GLUE, fn)
        t0 = self.clock()
        out = outer()
        return out, self.clock() - t0

    def result(self, total_s: float, frames: int) -> StageTimes:
        uncalled = [
            t for _, targets in STAGES for t in targets if self.target_calls[t] == 0 and t not in MAY_BE_UNCALLED
        ]
        return StageTimes(dict(self.seconds), dict(self.calls), uncalled, total_s, frames)
