"""Sunlight caustics: light that does not move with the seabed, noticed and taken out of the image.

In shallow water the sun draws a bright network of lines on the seabed (caustics), a few
centimetres wide, that drifts and flickers with the waves. It is light *added* to the seabed's,
never taken away, and it does not move with the seabed. A landmark template that holds a piece
of it is not found again a few frames later, and a speed token that holds some is pulled toward
the light's motion. On the robustness matrix's ``swell`` preset (caustics drifting at 5.8 cm/s)
the landmarks in view were found again in 10 % of the frames that had one, against 66 to 98 % on
every other preset, and the surge came out 3.6 mm/s slow: 56 to 62 cm of error after 5 minutes.

The cure is a grey-level opening wider than the lines (``[bandpass] sunlight_px``, 31 px, 6 cm
at 500 px/m, :func:`rovslam.vision.filters.remove_specks`): it removes bright structures the
octagon does not fit in and keeps the dark ones (stones, holes, shadows) and larger bright areas.
It is not applied where there is no sunlight: on a seabed whose texture has bright specks it
removes texture the tokens need (always on, it cost 5 to 15 % of ATE on single 5-minute dives of
the presets without caustics).

What tells the sunlight from the seabed's own bright specks is motion. The bright structures
between the two widths, ``B = open(I, despeckle_px) - open(I, sunlight_px)``, are compared around
each speed token where it was in the previous frame and where it was found in this one
(:func:`moving_light_share`): the seabed's own specks moved with the token, the sunlight did not.
The comparison spans at least 0.15 s (:class:`BrightHistory`: at 10 Hz the frame 2 back, the tokens
carried back through the frame between), as at the 5 Hz the thresholds were measured at.
:class:`SunlightMonitor` smooths that share over about 10 frames and switches the wide opening
on above ``SUNLIGHT_ON_SHARE`` and off below ``SUNLIGHT_OFF_SHARE``, from the third frame with a
share on. The average is divided by the weight it has given the frames so far, so the first
frames count at their value: started from 0, it needed 18 to 24 frames to cross the threshold,
and the error made meanwhile (3 to 4 cm in 5 s on the swell preset, tokens dragged by the
light at 0.3 m/s) stayed in every landmark mapped then. Measured over 5-minute dives (windows
of the consensus's tokens, turn and scale followed): median per-frame share 0.033 to 0.064
under the simulator's caustics (slow, fast, small cells), the smoothed share never falling
below 0.021 once on; 0.006 to 0.012 on the presets without them (real-photo survey and turns,
relief, turbid), the smoothed share at most 0.028; 0.017 on the real Sparus video.

The share is the median over every token, one with no bright structure around it counting 0: the
sunlight is a network over the whole seabed, around every token, while marine snow and the seabed's
lamp-lit specks are around a few. A median over the lit tokens alone trapped the watch: once the wide
opening is on, the tokens are cut from an image without the bright specks, fewer of them sit on any
(over marine snow, 54 % of them against 78 %), those that do are mostly on the snow, and their
median rose from 0.018 to 0.026 a frame. On the 44-minute ``rough-turns`` trial, which has no
sunlight, the smoothed share once crossed 0.03 and never again fell below 0.015: the seabed's own
bright specks were taken out of its last 9,062 frames (ATE 0.419 cm against 0.371 cm). Counted over
every token, its share is 0.014 a frame (median), its smoothed share at most 0.027, and the watch
never switches on; the swell's caustics, around every token, give the same 0.072 as before and are
taken out from the same frame. The share can only have fallen, frame by frame, from what the
median over the lit tokens gave: the figures above were measured that way.

Each frame's share enters the average as the median of it and the two frames before
(``SUNLIGHT_MEDIAN_FRAMES``; of the first two, the smaller), or as itself when that is smaller:
one frame is not the light, and the average is never above the plain one, so the watch never
switches on where it did not (the first frames of the real Sparus video decimated by 3 measured
0.033, 0.030, 0.022: their median, 0.030, would have switched it on). A vehicle holding station over the
real-photo seabed under its lamps (a guided mission's point) measured 0.014 to 0.023 a frame,
the average 0.02, until one frame's share of 0.199 (a consensus of three tokens on a glitch)
lifted it over 0.03; the wide opening then took the lamp-lit specks out of every image, the
landmarks cut before were never found again, and the average, at 0.018 with the vehicle still,
stayed above ``SUNLIGHT_OFF_SHARE``: the map was lost for the rest of the mission. Caustics give
a share above 0.03 frame after frame, so the median delays their detection by one frame.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from rovslam.averages import DecayingMean, median0

SUNLIGHT_ON_SHARE = 0.03  # the smoothed moving share above which the sunlight is taken out
SUNLIGHT_OFF_SHARE = 0.015  # ... and below which it is left in again
SUNLIGHT_SMOOTHING = 0.1  # exponential smoothing per frame (about 10 frames)
SUNLIGHT_MIN_FRAMES = 3  # frames with a share before the first decision
SUNLIGHT_MEDIAN_FRAMES = (
    3  # a frame's share enters as at most the median of the last this many (one frame is not the light)
)
MIN_BRIGHT_RMS = 10.0  # grey levels: a token window with fainter bright structures says nothing
# The light is compared over at least this much time (3/4 of it, for timestamps that jitter), whatever
# the frame rate: the shares and thresholds above were measured between frames 0.2 s apart, and
# caustics move half as far between frames at 10 Hz (the swell at 10 Hz: never seen, 40 cm of error).
SUNLIGHT_BASELINE_S = 0.2


def moving_light_share(
    bright_prev: np.ndarray,
    bright_curr: np.ndarray,
    uv_prev_px: np.ndarray,
    uv_curr_px: np.ndarray,
    size_px: int = 16,
) -> float:
    """How much of the bright structures around the tokens did not move with them.

    Args:
        bright_prev, bright_curr: ``(H, W) float32`` bright structures of the previous and the
            current frame (the two openings' difference).
        uv_prev_px, uv_curr_px: ``(N, 2)`` token centres in the previous frame and where they
            were found in this one (rows with a NaN are left out).
        size_px: side of the compared windows.

    Returns:
        The median over the tokens of ``sum (Bc - Bp)^2 / sum (Bc^2 + Bp^2)`` over each token's
        windows (0 when the bright structures moved with the seabed, about 1 when they are
        unrelated); a token whose windows' RMS stays below ``MIN_BRIGHT_RMS`` has no bright
        structure around it, so none that moved: it counts 0. NaN without a token.
    """
    p, q = _finite_pairs(uv_prev_px, uv_curr_px)
    if len(p) == 0:
        return float("nan")
    # Each window follows its token with the frame's turn and scale (a vehicle turning or climbing
    # turns and scales the seabed's specks too): the similarity that best maps the tokens, in least squares.
    half = (size_px - 1) / 2.0
    g = np.arange(size_px, dtype=np.float64) - half
    off = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)  # (S*S, 2) window offsets (u, v)
    a = _similarity(p, q)
    wa = _windows(bright_prev, p, off)
    wb = _windows(bright_curr, q, off @ a.T)
    total = np.sum(wa * wa, axis=1) + np.sum(wb * wb, axis=1)
    lit = total >= 2.0 * size_px * size_px * MIN_BRIGHT_RMS**2  # fainter: no bright structure, none moved
    shares = np.zeros(len(p))
    shares[lit] = np.sum((wb - wa) ** 2, axis=1)[lit] / total[lit]
    # The median over the tokens: one token matched wrongly (or half out of the frame) is not the light.
    return float(median0(shares))


def _similarity(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(2, 2)`` ``s R`` of the similarity ``q - mean(q) = s R (p - mean(p))`` (identity for one point).

    Least squares, then again without the pairs it leaves more than 2 px (or three times the
    median residual) out: a wrong match must not turn the other windows.
    """
    a = _similarity_lsq(p, q)
    if len(p) < 3:
        return a
    res = np.hypot(*((q - q.mean(axis=0)) - (p - p.mean(axis=0)) @ a.T).T)
    good = res <= max(2.0, 3.0 * float(median0(res)))
    return _similarity_lsq(p[good], q[good]) if 2 <= good.sum() < len(p) else a


def _similarity_lsq(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    if len(p) < 2:
        return np.eye(2)
    pc, qc = p - p.mean(axis=0), q - q.mean(axis=0)
    den = float(np.sum(pc * pc))
    if den <= 0.0:
        return np.eye(2)
    c = float(np.sum(pc * qc)) / den  # s cos
    s_ = float(np.sum(pc[:, 0] * qc[:, 1] - pc[:, 1] * qc[:, 0])) / den  # s sin
    return np.array([[c, -s_], [s_, c]])


def _windows(img: np.ndarray, centres: np.ndarray, off: np.ndarray) -> np.ndarray:
    """``(N, S*S) float32``: ``img`` sampled (bilinear, border replicated) at each centre plus the offsets."""
    pts = (centres[:, None, :] + off[None, :, :]).astype(np.float32)  # (N, S*S, 2)
    out = cv2.remap(
        img,
        np.ascontiguousarray(pts[..., 0]),
        np.ascontiguousarray(pts[..., 1]),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.astype(np.float32, copy=False)


class BrightHistory:
    """The bright structures of the last frames and how each frame's tokens moved, so that the watch
    compares the light over :data:`SUNLIGHT_BASELINE_S` whatever the frame rate.

    :meth:`push` adds a frame; :meth:`baseline` gives the bright structures of the newest frame at
    least 3/4 of the baseline older than the current one (or the oldest frame the tokens' motion
    links to it) and where the current frame's tokens were in it.
    """

    def __init__(self, baseline_s: float = SUNLIGHT_BASELINE_S, max_frames: int = 12):
        self.baseline_s = float(baseline_s)
        # (t_s, (H, W) bright, (p, q): its tokens in the frame before it and in it, finite rows only)
        self._frames: deque = deque(maxlen=max_frames)

    def push(self, t_s: float, bright: np.ndarray, uv_prev_px: np.ndarray, uv_curr_px: np.ndarray) -> None:
        """Add a frame with its tokens' positions in the frame before it and in it (``(N, 2)``, NaN rows left out)."""
        self._frames.append((float(t_s), bright, _finite_pairs(uv_prev_px, uv_curr_px)))

    def baseline(self, t_s: float, uv_prev_px: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """``(bright, uv)``: an earlier frame's bright structures and where the tokens were in it.

        ``uv_prev_px`` ``(N, 2)``: the current frame's tokens in the newest pushed frame (their
        previous positions). None before the first frame.
        """
        if not self._frames:
            return None
        uv = np.asarray(uv_prev_px, dtype=float).reshape(-1, 2)
        i = len(self._frames) - 1
        while t_s - self._frames[i][0] < 0.75 * self.baseline_s and i > 0:
            link = _similarity_transform(*self._frames[i][2])  # only when the frames are nearer than that
            if link is None:
                break
            a, t = link
            uv = (uv - t) @ np.linalg.inv(a).T  # back into the frame before
            i -= 1
        return self._frames[i][1], uv


def _finite_pairs(uv_prev_px, uv_curr_px) -> tuple[np.ndarray, np.ndarray]:
    """The ``(N, 2)`` rows of two point lists where both are finite (a lost token is a NaN row)."""
    p = np.asarray(uv_prev_px, dtype=float).reshape(-1, 2)
    q = np.asarray(uv_curr_px, dtype=float).reshape(-1, 2)
    ok = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(q), axis=1)
    return p[ok], q[ok]


def _similarity_transform(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(A, t)`` with ``q = A p + t`` (A a scaled rotation, :func:`_similarity`) from finite point pairs, or None
    from fewer than 2."""
    if len(p) < 2:
        return None
    a = _similarity(p, q)
    if not abs(np.linalg.det(a)) > 1e-6:
        return None
    return a, q.mean(axis=0) - a @ p.mean(axis=0)


@dataclass(frozen=True)
class SunlightEvent:
    """The frame from which the pipeline took the sunlight out (``removed``) or left it in again."""

    frame: int
    t_s: float
    removed: bool
    share: float  # the smoothed moving share that decided


class SunlightMonitor:
    """The moving share smoothed over frames, and whether the sunlight is being taken out.

    :meth:`observe` takes one frame's :func:`moving_light_share` and returns True when
    :attr:`active` changed. :attr:`share` is the exponential average divided by the weight it
    has given the frames so far (``1 - (1 - smoothing)^frames``): the mean of the first frames,
    then the usual average.
    """

    def __init__(
        self,
        on_share: float = SUNLIGHT_ON_SHARE,
        off_share: float = SUNLIGHT_OFF_SHARE,
        smoothing: float = SUNLIGHT_SMOOTHING,
    ):
        if not (0.0 < off_share < on_share and 0.0 < smoothing <= 1.0):
            raise ValueError(
                f"need 0 < off_share < on_share and smoothing in (0, 1]; got {off_share}, {on_share}, {smoothing}"
            )
        self.on_share, self.off_share = float(on_share), float(off_share)
        self.smoothing = float(smoothing)
        self.share = 0.0
        self.active = False
        self._mean = DecayingMean()  # the exponential average over its own weight
        self._recent: deque[float] = deque(maxlen=SUNLIGHT_MEDIAN_FRAMES)  # the last frames' shares

    @property
    def frames(self) -> int:
        """Frames with a share so far."""
        return self._mean.count

    def observe(self, share: float) -> bool:
        """Fold one frame in (a NaN share changes nothing); True when :attr:`active` flipped."""
        if not np.isfinite(share):
            return False
        self._recent.append(float(share))
        lower_median = sorted(self._recent)[(len(self._recent) - 1) // 2]  # of two frames, the smaller
        # never more than the frame's own share: the average is never above what it was without the median
        self._mean.add(min(float(share), lower_median), self.smoothing, 1.0 - self.smoothing)
        self.share = self._mean.mean()  # the first frames' mean, not pulled towards 0
        if self.frames < SUNLIGHT_MIN_FRAMES:
            return False
        if not self.active and self.share > self.on_share:
            self.active = True
            return True
        if self.active and self.share < self.off_share:
            self.active = False
            return True
        return False
