"""What a run counts frame by frame for ``summary.json``, and the warnings it draws from the counts.

* :class:`MapTally`: how often the landmarks expected in view were found again (``map_use``);
* :class:`TimeGaps`: frame intervals far longer than the dive's usual one (``time_gaps``);
* :class:`SourceTally`: where each frame's altitude and heading came from (``sources``).

:func:`rovslam.runner.run_sequence` keeps one of each over a run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from rovslam.core import Frame
from rovslam.io.source import ASSUMED_ALTITUDE, HELD_ALTITUDE, TOKENS_ONLY, SourceDescription
from rovslam.pipeline import FrameResult

__all__ = [
    "MAP_USE_MIN_FOUND",
    "MAP_USE_MIN_FRAMES",
    "TIME_GAP_MIN_S",
    "TIME_GAP_RATIO",
    "MapTally",
    "SourceTally",
    "TimeGaps",
]

# The map corrects the odometry only where its landmarks are found again: below this share of the
# frames with a landmark in view, over at least MAP_USE_MIN_FRAMES such frames, the run says so.
MAP_USE_MIN_FOUND = 0.25
MAP_USE_MIN_FRAMES = 50


class MapTally:
    """How often the landmarks expected in view were found again (``summary.json`` ``map_use``).

    A frame counts as "in view" when some landmark passed the visibility gate (5) and as "found"
    when at least one landmark match was accepted. A seabed whose appearance changes between
    passes (moving sunlight caustics, turbidity, a scene that moves) makes the landmarks
    unrecognisable: the map then stops correcting the odometry's drift, and the run warns.
    """

    def __init__(self) -> None:
        self.in_view = 0
        self.found = 0

    def add(self, res: FrameResult) -> None:
        if res.skipped_reason is None and res.landmarks_visible > 0:
            self.in_view += 1
            self.found += res.landmarks_tracked > 0

    def warnings(self) -> list[str]:
        if self.in_view < MAP_USE_MIN_FRAMES or self.found >= MAP_USE_MIN_FOUND * self.in_view:
            return []
        return [
            f"landmarks were found again in only {self.found} of the {self.in_view} frames that had one in view "
            f"({100.0 * self.found / self.in_view:.0f} %): the map corrects little of the odometry's drift, and the "
            "position's error may outgrow its covariance. Common causes: a seabed whose appearance changes "
            "between passes (moving sunlight caustics in shallow water, turbidity, moving weed), or too little "
            "texture for [landmark_templates] min_local_variance"
        ]

    def summary(self) -> dict[str, Any]:
        return {
            "frames_with_landmark_in_view": self.in_view,
            "frames_with_landmark_found": self.found,
            "found_fraction": self.found / self.in_view if self.in_view else None,
        }


# A frame interval longer than this many times the dive's median (and than TIME_GAP_MIN_S) is a gap.
TIME_GAP_RATIO = 10.0
TIME_GAP_MIN_S = 1.0


class TimeGaps:
    """Frame intervals far longer than the dive's usual one (``summary.json`` ``time_gaps``).

    Across a gap the filter predicts with the held speed and grows its covariance with the gap's
    length; when the frames on either side were in fact consecutive (a clock jump, a concatenated
    log), the speed measured across it is the image motion divided by the wrong interval.
    """

    def __init__(self) -> None:
        self._prev_t_s: float | None = None
        self._dt_s: list[float] = []
        self._where: list[tuple[int, float]] = []  # (frame index, t_s) after each interval

    def add(self, frame: Frame) -> None:
        if self._prev_t_s is not None and math.isfinite(frame.t_s):
            self._dt_s.append(frame.t_s - self._prev_t_s)
            self._where.append((frame.index, frame.t_s))
        self._prev_t_s = frame.t_s

    def gaps(self) -> list[dict[str, float]]:
        if len(self._dt_s) < 2:
            return []
        dt = np.asarray(self._dt_s)
        limit = max(TIME_GAP_MIN_S, TIME_GAP_RATIO * float(np.median(dt)))
        return [{"frame": i, "t_s": t, "gap_s": float(g)} for g, (i, t) in zip(dt, self._where) if g > limit]

    def warnings(self) -> list[str]:
        gaps = self.gaps()
        if not gaps:
            return []
        big = max(gaps, key=lambda g: g["gap_s"])
        return [
            f"{len(gaps)} gap(s) in the frame times, the longest {big['gap_s']:g} s before frame {big['frame']} "
            f"(t = {big['t_s']:g} s), against a usual {float(np.median(self._dt_s)):g} s: the position's uncertainty "
            "grows across a gap; if the frames on either side are consecutive, the times (frames.csv t_s, the "
            "bag's stamps) are wrong and the speed across the gap is too small"
        ]


class SourceTally:
    """Counts, frame by frame, where the altitude and the heading came from (``summary.json`` ``sources``).

    Altitude: "laser", "sonar", "navigation" (what the source's altitude input is), "laser+sonar" /
    "laser+navigation" (fused), or "assumed constant"; heading: "compass", "navigation" or
    "tokens only (no compass)". Skipped frames are not counted.
    """

    def __init__(self, description: SourceDescription, fallback_detail: str = "", rig_note: str = "") -> None:
        self.description = description
        self.fallback_detail = fallback_detail
        self.rig_note = rig_note  # pointers whose spot is never inside the image ("" if none)
        self.altitude: dict[str, int] = {}
        self.heading: dict[str, int] = {}

    def add(self, frame: Frame, res: FrameResult) -> None:
        if res.skipped_reason is not None:
            return
        alt_input = self.description.altitude_input or "sonar"
        alt = {
            "laser": "laser",
            "laser+sonar": f"laser+{alt_input}",
            "sonar": alt_input,
            "fixed": ASSUMED_ALTITUDE,
            "held": HELD_ALTITUDE,
        }.get(res.altitude_source, res.altitude_source)
        self.altitude[alt] = self.altitude.get(alt, 0) + 1
        has_heading = math.isfinite(frame.heading_rad) and self.description.heading_input is not None
        head = (self.description.heading_input or "compass") if has_heading else TOKENS_ONLY
        self.heading[head] = self.heading.get(head, 0) + 1

    def summary(self) -> dict[str, Any]:
        d = self.description

        def part(counts: dict[str, int], details: dict[str, str]) -> dict[str, Any]:
            main = max(counts, key=lambda k: counts[k]) if counts else None
            return {
                "source": main,
                "frames": dict(counts),
                "detail": "; ".join(f"{k}: {details[k]}" for k in counts if details.get(k)),
            }

        alt_details = {
            "laser": "laser spots of the camera file's [[laser]] rig",
            ASSUMED_ALTITUDE: self.fallback_detail,
            HELD_ALTITUDE: "no laser spot and no altimeter reading in the frame: the altitude filter's "
            "prediction from the readings before (its sigma growing)",
        }
        if d.altitude_input:
            alt_details[d.altitude_input] = d.altitude_detail
            alt_details[f"laser+{d.altitude_input}"] = f"laser spots fused with {d.altitude_detail}"
        head_details = {TOKENS_ONLY: "the turn the speed tokens measure, integrated from 0 at the first frame"}
        if d.heading_input:
            head_details[d.heading_input] = d.heading_detail
        warnings = []
        n_alt = sum(self.altitude.values())
        if self.altitude.get(ASSUMED_ALTITUDE):
            warnings.append(
                f"altitude assumed constant ({self.fallback_detail}) in {self.altitude[ASSUMED_ALTITUDE]} of "
                f"{n_alt} frames: speeds and positions there scale with that value"
            )
        if self.rig_note:
            warnings.append(self.rig_note)
        if self.heading.get(TOKENS_ONLY):
            warnings.append(
                f"no compass in {self.heading[TOKENS_ONLY]} of {sum(self.heading.values())} frames: the "
                "heading there is the integrated turn of the speed tokens, which drifts"
            )
        return {
            "input": {"kind": d.kind, "path": d.path},
            "altitude": part(self.altitude, alt_details),
            "heading": part(self.heading, head_details),
            "attitude": {
                "source": "given" if d.attitude_detail else "none (level camera assumed)",
                "detail": d.attitude_detail or "",
            },
            "warnings": warnings,
        }
