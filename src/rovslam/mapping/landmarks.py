"""Landmark templates beside the filter state: what the map keeps of each landmark's appearance.

The filter (:mod:`rovslam.slam`) holds a landmark's position; this module holds its 32x32
template (steps 3 and 7 of the loop), a wider patch cut with it so that the template can be
re-oriented when the vehicle comes back at another heading (beyond the paper, which flew at
constant heading), and the counts the map reports.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from rovslam.camera import wrap_angle
from rovslam.vision.templates import Template

__all__ = ["LandmarkRecord", "most_distinctive", "oriented_patch", "wide_patch_size_px"]

# Landmark templates are re-oriented when the heading differs from the one they were cut at
# by more than this.
ROTATE_TEMPLATE_RAD = math.radians(0.5)


@dataclass
class LandmarkRecord:
    """A landmark's template and its history (the map's bookkeeping beside the filter state)."""

    id: int
    patch: np.ndarray  # (S, S) float32, the template as cut
    local_variance: float
    first_t_s: float
    first_frame: int
    heading_rad: float = 0.0  # map heading when the template was cut
    patch_wide: np.ndarray | None = None  # (W, W) float32, W > S sqrt(2): rotated on re-observation
    observations: int = 0
    rejected: int = 0
    last_seen_t_s: float = math.nan
    self_similarity: float = math.nan  # the template's highest other autocorrelation peak when it was chosen
    confirmed: bool = False  # seen again consistently: its observations correct the vehicle
    dead: bool = False  # refused while tentative: never searched again

    def observed(self, accepted: bool, t_s: float, confirm_after: int) -> None:
        """Count one observation; a tentative landmark is confirmed after ``confirm_after`` consistent ones."""
        if accepted:
            self.observations += 1
            self.last_seen_t_s = t_s
            if not self.confirmed and self.observations > confirm_after:  # the first one is its initialisation
                self.confirmed = True
        else:
            self.rejected += 1
            if not self.confirmed and self.rejected >= 2:
                self.dead = True

    @classmethod
    def cut(
        cls, landmark_id: int, track_img: np.ndarray, template: Template, heading_rad: float, t_s: float, frame: int
    ) -> LandmarkRecord:
        """A new landmark (step 7) from ``template`` found in the ``(H, W) float32`` tracking image."""
        size = template.patch.shape[0]
        wide = wide_patch_size_px(size)
        centre = tuple(float(c) for c in template.centre_uv_px)
        return cls(
            landmark_id,
            template.patch,
            float(template.local_variance),
            t_s,
            frame,
            heading_rad=heading_rad,
            patch_wide=cv2.getRectSubPix(track_img, (wide, wide), centre),
            observations=1,
            last_seen_t_s=t_s,
            self_similarity=float(template.self_similarity),
        )


def wide_patch_size_px(size_px: int) -> int:
    """Side of the patch that still covers a ``size_px`` template turned by any angle (same parity)."""
    wide = int(math.ceil(size_px * math.sqrt(2.0))) + 2
    return wide + (wide - size_px) % 2


def oriented_patch(record: LandmarkRecord, heading_rad: float) -> np.ndarray:
    """(S, S) float32: the landmark template as the camera sees it at map heading ``heading_rad``."""
    dpsi = wrap_angle(heading_rad - record.heading_rad)
    if abs(dpsi) < ROTATE_TEMPLATE_RAD or record.patch_wide is None:
        return record.patch
    n = record.patch_wide.shape[0]
    c = (n - 1) / 2.0
    # The seabed turns by -dpsi in the (m, n) frame, i.e. by +dpsi in OpenCV's (u, v-down) angle.
    rot = cv2.getRotationMatrix2D((c, c), math.degrees(dpsi), 1.0)
    turned = cv2.warpAffine(record.patch_wide, rot, (n, n), flags=cv2.INTER_LINEAR)
    k = (n - record.patch.shape[0]) // 2
    return turned[k : k + record.patch.shape[0], k : k + record.patch.shape[1]]


def most_distinctive(candidates: list[Template]) -> Template | None:
    """The candidate to make a landmark: strong (local variance) and unlike its neighbourhood.

    Scored ``local_variance * (1 - self_similarity)``: of two equally contrasted windows, the
    one whose autocorrelation has the lower second peak is the safer to recognise again.
    """
    if not candidates:
        return None

    def score(t: Template) -> float:
        ss = t.self_similarity if math.isfinite(t.self_similarity) else 0.0
        return t.local_variance * (1.0 - max(ss, 0.0))

    return max(candidates, key=score)
