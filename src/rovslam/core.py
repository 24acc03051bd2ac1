"""The records every layer shares: a frame, a sequence's description, a ground truth, a goal.

They are plain frozen dataclasses with no behaviour beyond their shape, so the numerical core
(the pipeline, the filter), the inputs (:mod:`rovslam.io`) and the navigation
(:mod:`rovslam.nav`) all import them from here and none of them imports another for them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rovslam.camera import Camera, LaserPointer

__all__ = ["Frame", "GroundTruth", "Goal", "SequenceInfo"]


@dataclass(frozen=True)
class SequenceInfo:
    """What ``sequence.toml`` holds."""

    name: str
    camera: Camera
    lasers: tuple[LaserPointer, ...] = ()
    fixed_altitude_m: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    bit_depth: int | None = None  # [camera] bit_depth: significant bits of 16-bit image files (None: 16)


@dataclass(frozen=True)
class Frame:
    """One timestamped frame from any source (sequence folder, video, bag).

    ``image`` is ``(H, W, 3) uint8`` RGB, or ``None`` when it could not be read (``error``
    then says why). Attitude is 0 when the source gives none (level camera, as the paper).
    """

    index: int
    t_s: float
    image: np.ndarray | None
    heading_rad: float
    sonar_altitude_m: float | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    has_attitude: bool = False
    source: str = ""
    error: str | None = None


@dataclass(frozen=True)
class GroundTruth:
    """``groundtruth.csv`` as arrays, each ``(N,)`` float64."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    altitude_m: np.ndarray
    heading_rad: np.ndarray
    relief_m: np.ndarray | None = None  # (N,) when the file has the optional relief_m column

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def xy_m(self) -> np.ndarray:
        """(N, 2) true positions."""
        return np.column_stack([self.x_m, self.y_m])


@dataclass(frozen=True)
class Goal:
    """A place to go: a survey way-point (passed through) or a point of interest (arrive, then hold)."""

    name: str
    xy_m: np.ndarray | None  # (2,) map frame; None: resolved from the map (``landmark_id``)
    kind: str = "poi"  # "poi" | "survey"
    hold_s: float | None = None  # None: the guidance's hold_s
    landmark_id: int | None = None
