"""Normalised-correlation template tracking and the global (phase-correlation) motion prior.

Tracking (paper, section 2): a template is searched for in a neighbourhood of its predicted
location by the normalised correlation coefficient, and "token tracking fails when the
correlation gets lower than a suitable threshold" (0.89 in the experiments of section 4).

The correlation is OpenCV's ``TM_CCOEFF_NORMED``. For a template ``T`` of ``w x h`` pixels and
the image ``I``, at the top-left offset ``(x, y)``::

    T'(x', y') = T(x', y') - mean(T)
    I'(x + x', y + y') = I(x + x', y + y') - mean of I over the w x h window at (x, y)
    R(x, y) = sum_{x', y'} T'(x', y') I'(x + x', y + y')
              / sqrt( sum_{x', y'} T'(x', y')^2 * sum_{x', y'} I'(x + x', y + y')^2 )

``R`` lies in [-1, 1] and is invariant to gain and offset changes of the window. It is
computed only over the search window, never the whole image.

Which image: the pipeline tracks on the band-passed template channel
(:func:`rovslam.vision.filters.bandpass`), the same image the templates were cut from.
On turbid, unevenly lit footage the band-pass removes the haze and vignetting gradients
that otherwise dominate a 16x16 window, which gives a sharp correlation peak and a
sub-pixel estimate that does not drift with the lighting. The functions here work on any
float32 image; extraction and tracking must simply use the same one.

Expected failures are return values: a :class:`Match` with ``ok=False`` and the reason.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from rovslam.averages import median0
from rovslam.config import SpeedTemplateConfig, TrackerConfig
from rovslam.errors import InvalidArgumentError
from rovslam.vision.filters import local_variance
from rovslam.vision.templates import (
    Template,
    extract_templates,
    second_peak,
    window_inhibited,
)

# Reasons of a failed match (Match.reason).
REASON_OUTSIDE = "search window outside the image"
REASON_FLAT = "template has no contrast"
REASON_LOW = "correlation below threshold"
REASON_BORDER = "peak on the search window border"
REASON_AMBIGUOUS = "ambiguous: second peak almost as high"
REASON_INHIBITED = "match overlaps inhibited pixels"
REASON_NOT_FINITE = "correlation not finite"


@dataclass(frozen=True, eq=False)
class Match:
    """Result of :func:`match_template`.

    Attributes
    ----------
    ok: True when the match is accepted.
    uv_px: ``(2,) float64`` template centre (u, v) in the image, sub-pixel (centre =
        top-left + (size - 1) / 2); the best candidate even when ``ok`` is False, NaN when
        there is none.
    score: the correlation coefficient at the integer peak (NaN when none).
    reason: ``""`` when ok, otherwise why the match was refused (``REASON_*``).
    second_score: the highest other local maximum of the correlation surface farther than
        ``second_peak_exclusion_px`` from the peak (-1 when there is none).
    """

    ok: bool
    uv_px: np.ndarray
    score: float
    reason: str
    second_score: float = -1.0


def _fail(reason: str, uv: np.ndarray | None = None, score: float = float("nan"), second: float = -1.0) -> Match:
    return Match(False, np.full(2, np.nan) if uv is None else uv, score, reason, second)


def _subpixel_offset(c3: np.ndarray, method: str) -> np.ndarray:
    """Sub-pixel offset ``(du, dv)`` in [-0.5, 0.5] of the peak of a ``(3, 3)`` neighbourhood.

    Least-squares fit of the paraboloid ``a + g . x + x^T H x / 2`` to the nine samples
    (closed form: mean first and second differences over the rows / columns, and the
    mixed difference of the corners), peak at ``-H^-1 g``. The cross term matters: with
    separate 1-D parabolas along u and v the error on an oblique, elongated correlation
    peak is about three times larger. ``"gaussian"`` fits the paraboloid to the logarithm
    (a Gaussian peak) when all nine samples are positive, else falls back to the parabola.
    """
    return np.array(_subpixel_du_dv(c3, method))


def _subpixel_du_dv(c3: np.ndarray, method: str) -> tuple[float, float]:
    """:func:`_subpixel_offset` as two Python floats."""
    if method == "none":
        return 0.0, 0.0
    # Plain Python floats: nine numbers, far cheaper than NumPy reductions on a 3x3 array.
    (a, b, c), (d, e, f), (g, h, i) = c3.tolist()
    if method == "gaussian" and min(a, b, c, d, e, f, g, h, i) > 0.0:
        a, b, c, d, e, f, g, h, i = (math.log(x) for x in (a, b, c, d, e, f, g, h, i))
    g_u = ((c + f + i) - (a + d + g)) / 6.0
    g_v = ((g + h + i) - (a + b + c)) / 6.0
    h_uu = ((a + d + g) - 2.0 * (b + e + h) + (c + f + i)) / 3.0
    h_vv = ((a + b + c) - 2.0 * (d + e + f) + (g + h + i)) / 3.0
    h_uv = 0.25 * (i - g - c + a)
    det = h_uu * h_vv - h_uv * h_uv
    if h_uu < 0.0 and det > 0.0:
        du = -(h_vv * g_u - h_uv * g_v) / det
        dv = -(h_uu * g_v - h_uv * g_u) / det
    else:
        # Not a maximum-shaped neighbourhood: 1-D parabolas through the centre row / column.
        den_u, den_v = d - 2.0 * e + f, b - 2.0 * e + h
        du = 0.5 * (d - f) / den_u if den_u < 0.0 else 0.0
        dv = 0.5 * (b - h) / den_v if den_v < 0.0 else 0.0
    return min(0.5, max(-0.5, du)), min(0.5, max(-0.5, dv))


def match_template(
    track_img: np.ndarray,
    patch: np.ndarray,
    predicted_uv_px: np.ndarray,
    search_radius_px: int,
    config: TrackerConfig,
) -> Match:
    """Find ``patch`` near its predicted centre by normalised correlation (TM_CCOEFF_NORMED).

    The template's top-left corner is tried at every integer offset within
    ``search_radius_px`` (Chebyshev) of the rounded predicted corner; the window is clipped
    to the image. The match is accepted when

    * the peak correlation is ``>= config.min_correlation`` (paper: 0.89),
    * the peak is not on the border of the (clipped) search window, where the true
      maximum may lie outside it,
    * no other local maximum farther than ``config.second_peak_exclusion_px`` reaches
      ``config.max_second_peak_ratio`` times the peak (ambiguous texture).

    The peak is refined to sub-pixel precision by a 2-D paraboloid (or Gaussian) fitted to
    the 3x3 correlation values around it (``config.subpixel``, see :func:`_subpixel_offset`).

    Parameters
    ----------
    track_img: ``(H, W) float32`` image to search (same kind the patch was cut from).
    patch: ``(s, s) float32`` template (any ``h x w`` works).
    predicted_uv_px: ``(2,)`` predicted centre (u, v).
    search_radius_px: whole number >= 1.
    config: correlation threshold, ambiguity test, sub-pixel method.

    Returns
    -------
    :class:`Match`; a lost track is ``ok=False`` with the reason, never an exception.
    """
    img = np.asarray(track_img)
    tpl = np.asarray(patch)
    if img.ndim != 2 or tpl.ndim != 2:
        raise InvalidArgumentError(f"match_template needs 2-D image and patch, got {img.shape} and {tpl.shape}")
    if int(search_radius_px) != search_radius_px or search_radius_px < 1:
        raise InvalidArgumentError(f"search radius must be a whole number >= 1 px, got {search_radius_px}")
    pred = np.asarray(predicted_uv_px, dtype=np.float64).reshape(-1)
    if pred.shape != (2,):
        raise InvalidArgumentError(f"predicted_uv_px must be 2 numbers (u, v), got shape {pred.shape}")
    pu_pred, pv_pred = pred.tolist()
    if not (math.isfinite(pu_pred) and math.isfinite(pv_pred)):
        return _fail(REASON_OUTSIDE)
    if img.dtype != np.float32:
        img = img.astype(np.float32)
    if tpl.dtype != np.float32:
        tpl = tpl.astype(np.float32)

    th, tw = tpl.shape
    ih, iw = img.shape
    r = int(search_radius_px)
    # Rounded predicted top-left corner; the window spans corners tl0 - r .. tl0 + r.
    tl_u = round(pu_pred - 0.5 * (tw - 1))  # half to even, as np.rint
    tl_v = round(pv_pred - 0.5 * (th - 1))
    u0, u1 = max(0, tl_u - r), min(iw, tl_u + r + tw)
    v0, v1 = max(0, tl_v - r), min(ih, tl_v + r + th)
    if u1 - u0 < tw + 2 or v1 - v0 < th + 2:
        # Fewer than 3 candidate corners along an axis: no interior peak possible.
        return _fail(REASON_OUTSIDE)
    if float(cv2.meanStdDev(tpl)[1][0, 0]) <= 1e-6:
        return _fail(REASON_FLAT)

    corr = cv2.matchTemplate(img[v0:v1, u0:u1], tpl, cv2.TM_CCOEFF_NORMED)
    _, best, _, (pu, pv) = cv2.minMaxLoc(corr)
    if not math.isfinite(best):
        return _fail(REASON_NOT_FINITE)
    rh, rw = corr.shape
    cu, cv = u0 + pu + 0.5 * (tw - 1), v0 + pv + 0.5 * (th - 1)  # the integer peak's centre
    if best < config.min_correlation:
        return _fail(REASON_LOW, np.array([cu, cv]), float(best))
    if pu == 0 or pv == 0 or pu == rw - 1 or pv == rh - 1:
        return _fail(REASON_BORDER, np.array([cu, cv]), float(best))

    # Ambiguity: highest other local maximum outside the exclusion zone.
    second = second_peak(corr, pu, pv, int(config.second_peak_exclusion_px))
    if second >= config.max_second_peak_ratio * best:
        return _fail(REASON_AMBIGUOUS, np.array([cu, cv]), float(best), second)

    du, dv = _subpixel_du_dv(corr[pv - 1 : pv + 2, pu - 1 : pu + 2], config.subpixel)
    return Match(True, np.array([cu + du, cv + dv]), float(best), "", second)


@lru_cache(maxsize=4)
def _hanning(shape_hw: tuple[int, int]) -> np.ndarray:
    win = cv2.createHanningWindow((shape_hw[1], shape_hw[0]), cv2.CV_32F)
    win.setflags(write=False)
    return win


def global_shift(prev: np.ndarray, curr: np.ndarray) -> tuple[np.ndarray, float]:
    """Whole-image translation by phase correlation: the motion prior when no prediction is usable.

    Finds ``shift`` such that ``curr(p) ~ prev(p - shift)`` (the content moved by ``shift``)
    from the normalised cross-power spectrum, with a Hann window against the image-border
    discontinuity (OpenCV ``phaseCorrelate``, sub-pixel by a 5x5 centroid). Feed it the
    band-passed images: haze, vignetting and a fixed lighting pattern would otherwise pull
    the peak towards zero shift. Any shift up to about a third of the image in each axis is
    found on textured seabed.

    Parameters
    ----------
    prev, curr: ``(H, W) float32`` images of the same shape.

    Returns
    -------
    ``(shift_uv_px (2,) float64, confidence)``; the confidence is OpenCV's peak response (the
    normalised phase correlation summed over the 5x5 pixels around the peak). Measured on
    band-passed 360x272 / 384x288 frames: 0.4-0.8 on the turbid Sparus video, about 1 for a
    small shift and 0.3 for a shift of a third of the image on the synthetic seabed, below
    0.05 for unrelated images, 0 for featureless ones. Below
    :attr:`~rovslam.config.TrackerConfig.min_global_confidence` the shift means nothing.
    """
    a = np.asarray(prev)
    b = np.asarray(curr)
    if a.ndim != 2 or a.shape != b.shape:
        raise InvalidArgumentError(
            f"global_shift needs two (H, W) images of the same shape, got {a.shape} and {b.shape}"
        )
    a = a.astype(np.float32, copy=False)
    b = b.astype(np.float32, copy=False)
    (du, dv), response = cv2.phaseCorrelate(a, b, _hanning(a.shape))
    return np.array([du, dv], dtype=np.float64), float(response)


def reduce_for_shift(img: np.ndarray) -> np.ndarray:
    """``(H', W') float32`` the ``(H, W)`` image reduced to :func:`global_scale` (itself at scale 1)."""
    return reduce_image(img.astype(np.float32, copy=False), global_scale(img.shape))


def shift_between(
    prev_small: np.ndarray, small: np.ndarray, shape_hw: tuple[int, int]
) -> tuple[np.ndarray | None, float]:
    """``(shift (2,) in full-image px or None, confidence)``: :func:`global_shift` of two images reduced by
    :func:`reduce_for_shift` from ``shape_hw`` images; ``(None, nan)`` when their shapes differ."""
    if small.shape != prev_small.shape:
        return None, float("nan")
    scale = global_scale(shape_hw)
    g_small, g_conf = global_shift(prev_small, small)
    return g_small / scale, g_conf


def global_scale(shape_hw: tuple[int, int]) -> float:
    """The power-of-two reduction at which :func:`global_shift` runs: the smaller side stays >= 128 px.

    Phase correlation only has to bring the tokens within their search radius, and at half the
    resolution of a 360x272 frame it costs a fifteenth (0.2 ms instead of 3.5 ms).
    """
    scale = 1.0
    while min(shape_hw) * scale / 2.0 >= 128:
        scale /= 2.0
    return scale


def reduce_image(img: np.ndarray, scale: float) -> np.ndarray:
    """``(H, W) float32`` image reduced by ``scale`` (area average), itself when ``scale == 1``."""
    if scale >= 1.0:
        return np.asarray(img, dtype=np.float32)
    h, w = img.shape
    return cv2.resize(img, (max(1, int(round(w * scale))), max(1, int(round(h * scale)))), interpolation=cv2.INTER_AREA)


@dataclass(frozen=True, eq=False)
class TokenTracks:
    """Speed tokens of the previous frame found again in the current one (paper step 5).

    Attributes
    ----------
    uv_prev_px: ``(K, 2)`` centres in the previous frame of the K tracked tokens.
    uv_curr_px: ``(K, 2)`` their sub-pixel centres in the current frame.
    scores: ``(K,)`` correlation coefficients.
    n_given: number of tokens that were searched for.
    used_global_search: True when the matches come from the phase-correlation prior.
    reasons: one entry per token searched for, in extraction order: ``""`` when tracked,
        else why it was lost (``REASON_*``).
    global_shift_uv_px: the phase-correlation shift when it was computed, else None.
    global_confidence: its confidence (NaN when not computed).
    """

    uv_prev_px: np.ndarray
    uv_curr_px: np.ndarray
    scores: np.ndarray
    n_given: int
    used_global_search: bool
    reasons: tuple[str, ...]
    global_shift_uv_px: np.ndarray | None = None
    global_confidence: float = float("nan")

    @property
    def n_tracked(self) -> int:
        return int(len(self.scores))

    @property
    def displacements_uv_px(self) -> np.ndarray:
        """``(K, 2)`` image motion of each tracked token, current - previous."""
        return self.uv_curr_px - self.uv_prev_px


def _match_all(
    img: np.ndarray,
    tokens: Sequence[Template],
    shift_uv_px: np.ndarray,
    radius_px: int,
    config: TrackerConfig,
    inhibit: np.ndarray | None,
) -> list[Match]:
    matches = []
    shifts = np.broadcast_to(shift_uv_px, (len(tokens), 2))  # one common (2,) or per token (N, 2)
    for tok, shift in zip(tokens, shifts):  # at most max_count (8) tokens; one small OpenCV call each
        m = match_template(img, tok.patch, tok.centre_uv_px + shift, radius_px, config)
        if m.ok and inhibit is not None and window_inhibited(inhibit, m.uv_px, tok.patch.shape):
            m = Match(False, m.uv_px, m.score, REASON_INHIBITED, m.second_score)
        matches.append(m)
    return matches


class TokenTracker:
    """The speed tokens of the previous frame: track them (step 5), extract fresh ones (step 8).

    The only state is the last extracted tokens and the tracking image they were cut from
    (needed by the phase-correlation fallback). The work is done by the pure functions
    :func:`~rovslam.vision.templates.extract_templates`, :func:`match_template` and
    :func:`global_shift`.

    Typical per-frame use (tracking image = band-passed template channel)::

        tracks = tracker.track(track_img, predicted_shift_uv_px, inhibit)
        ...                       # speed from tracks.displacements_uv_px
        tracker.extract(track_img, local_var_16, inhibit)
    """

    def __init__(self, speed_config: SpeedTemplateConfig, tracker_config: TrackerConfig) -> None:
        self.speed_config = speed_config
        self.tracker_config = tracker_config
        self._tokens: list[Template] = []
        self._prev_img: np.ndarray | None = None
        self._prev_small: np.ndarray | None = None  # the previous image reduced for the global shift
        self._prev_inhibit: np.ndarray | None = None  # the previous frame's forbidden pixels
        self._last_shift: np.ndarray | None = None  # median motion of the last tracked tokens (u, v) px
        self._prior_for: np.ndarray | None = None  # the image the cached global shift was measured on
        self._prior: tuple[np.ndarray | None, float] = (None, float("nan"))
        # (image given to track, its reduction): extract reuses it for the same image (computed once a frame)
        self._reduced: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def tokens(self) -> tuple[Template, ...]:
        """The tokens the next :meth:`track` will search for."""
        return tuple(self._tokens)

    def reset(self) -> None:
        """Forget the tokens and the previous image (e.g. after a gap in the video)."""
        self._tokens = []
        self._prev_img = None
        self._prev_small = None
        self._prev_inhibit = None
        self._last_shift = None
        self._prior_for = None
        self._prior = (None, float("nan"))
        self._reduced = None

    def extract(
        self,
        track_img: np.ndarray,
        local_var: np.ndarray,
        inhibit: np.ndarray | None = None,
        expected_shift_uv_px: np.ndarray | None = None,
    ) -> int:
        """Extract fresh tokens for the next frame (paper step 8); returns how many.

        Where the seabed will still be seen: with a large expected motion (more than the search
        radius), windows that it would carry out of the next frame are not chosen (a band
        :func:`leaving_mask` wide on the side the content leaves), unless that leaves fewer
        tokens than choosing anywhere.

        Parameters
        ----------
        track_img: ``(H, W) float32`` tracking image of the current frame.
        local_var: ``(H, W) float32`` local variance over the speed template size.
        inhibit: ``(H, W) bool`` forbidden pixels (laser spots, landmark templates).
        expected_shift_uv_px: ``(2,)`` content motion expected to the next frame; None: the
            median motion of the tokens tracked in this frame, when there were some.
        """
        img = np.array(track_img, dtype=np.float32)  # own copy: the caller may reuse its buffer
        shift = self._last_shift if expected_shift_uv_px is None else np.asarray(expected_shift_uv_px, np.float64)
        self._tokens = self._choose(img, local_var, inhibit, shift, _NEXT_SHIFT_SLACK)
        self._prev_img = img
        self._prev_small = None
        if self.tracker_config.global_search:
            reduced, self._reduced = self._reduced, None
            self._prev_small = (
                reduced[1]
                if reduced is not None and reduced[0] is track_img
                else (reduce_image(img, global_scale(img.shape)))
            )
        self._prev_inhibit = None if inhibit is None else np.array(inhibit, dtype=bool)
        self._prior_for = None
        return len(self._tokens)

    def _choose(
        self,
        img: np.ndarray,
        local_var: np.ndarray,
        inhibit: np.ndarray | None,
        shift_uv_px: np.ndarray | None,
        slack: float,
    ) -> list[Template]:
        """The tokens of ``img``, away from the band a large ``shift_uv_px`` carries out of the next frame."""
        cfg = self.speed_config

        def choose(mask: np.ndarray | None) -> list[Template]:
            return extract_templates(
                img,
                local_var,
                cfg.size_px,
                cfg.max_count,
                cfg.min_local_variance,
                cfg.border_px,
                mask,
                cfg.min_spacing_px,
                cfg.max_self_similarity if cfg.max_self_similarity < 1.0 else None,
                cfg.search_radius_px + 2,
            )

        if shift_uv_px is None or not _large_motion(shift_uv_px, cfg.search_radius_px):
            return choose(inhibit)
        leaving = leaving_mask(img.shape, shift_uv_px, cfg.border_px + 2.0 + slack * float(np.max(np.abs(shift_uv_px))))
        staying = choose(leaving if inhibit is None else leaving | inhibit)
        if len(staying) >= min(cfg.max_count, _MIN_STAYING_TOKENS):
            return staying
        anywhere = choose(inhibit)
        return staying if len(staying) >= len(anywhere) else anywhere

    def motion_prior(self, track_img: np.ndarray) -> tuple[np.ndarray | None, float]:
        """``(shift (2,) or None, confidence)``: the whole-image motion since the last extraction.

        Phase correlation of the reduced images (:func:`global_shift`), measured once per
        image (:meth:`track` reuses it); None when there is no previous image or the global
        search is off.
        """
        img = np.asarray(track_img)
        if self._prior_for is img:
            return self._prior
        prior: tuple[np.ndarray | None, float] = (None, float("nan"))
        if self.tracker_config.global_search and self._prev_small is not None:
            offered = self._reduced
            # offered with a prior not taken (made against another previous image): its reduction still holds
            small = offered[1] if offered is not None and offered[0] is track_img else reduce_for_shift(img)
            if small is not img:  # a new array (at scale 1 it is the image): the same frame's extract() reuses it
                self._reduced = (track_img, small)
            prior = shift_between(self._prev_small, small, img.shape)
        self._prior_for, self._prior = img, prior
        return prior

    def offer_prior(
        self,
        track_img: np.ndarray,
        small: np.ndarray,
        prev_small: np.ndarray | None,
        prior: tuple[np.ndarray | None, float],
    ) -> None:
        """Take :meth:`motion_prior`'s work for ``track_img`` done elsewhere (ahead, on another thread).

        ``small`` is ``reduce_for_shift(track_img)``; ``prior`` is :func:`shift_between` of
        ``prev_small`` and ``small``. The prior is taken only when ``prev_small`` is this tracker's
        previous reduced image itself (the same object), so the result is what :meth:`motion_prior`
        would compute; otherwise it is computed there as before.
        """
        if not self.tracker_config.global_search:
            return
        if small is not track_img:
            self._reduced = (track_img, small)
        if self._prev_small is not None and prev_small is self._prev_small:
            self._prior_for, self._prior = np.asarray(track_img), prior

    def reselect_for_motion(self, shift_uv_px: np.ndarray) -> bool:
        """Choose the previous frame's tokens again where the seabed stays in view after ``shift_uv_px``.

        Tokens are chosen before the next frame's motion is known; after a large motion (the
        first pair, a gap, a still camera, a pair moving a third of the image) many of them
        leave the image. When the motion (predicted or measured by :meth:`motion_prior`) is
        larger than the search radius and carries a token's window out of the image, the
        tokens are chosen again in the previous tracking image, away from the band that leaves
        (and from its inhibited pixels). Returns True when the tokens changed (the per-token
        predictions must then be recomputed).
        """
        shift = np.asarray(shift_uv_px, dtype=np.float64).reshape(-1)
        if (
            self._prev_img is None
            or not self._tokens
            or shift.shape != (2,)
            or not np.all(np.isfinite(shift))
            or not _large_motion(shift, self.speed_config.search_radius_px)
        ):
            return False
        h, w = self._prev_img.shape
        half = 0.5 * (self.speed_config.size_px - 1)
        centres = np.array([t.centre_uv_px for t in self._tokens]) + shift
        stay = np.all((centres >= half + 1.0) & (centres <= np.array([w - 2.0 - half, h - 2.0 - half])), axis=1)
        n_stay = int(np.count_nonzero(stay))
        if n_stay == len(self._tokens):
            return False
        size = self.speed_config.size_px
        fresh = self._choose(
            self._prev_img, local_variance(self._prev_img, size), self._prev_inhibit, shift, _PRIOR_SHIFT_SLACK
        )
        if len(fresh) <= n_stay:
            return False
        self._tokens = fresh
        return True

    def track(
        self,
        track_img: np.ndarray,
        predicted_shift_uv_px: np.ndarray | None,
        inhibit: np.ndarray | None = None,
        rotation_offsets_uv_px: np.ndarray | None = None,
    ) -> TokenTracks:
        """Find the previous frame's tokens in ``track_img``.

        Each token is searched within ``search_radius_px`` of its previous centre plus
        ``predicted_shift_uv_px`` (image motion predicted from the last speed). When there is
        no prediction (first pair, after a loss), or fewer than ``min_tracked_fraction`` of
        the tokens are found with it, the whole-image shift is measured by phase correlation
        against the previous frame (:func:`global_shift`) and, if its confidence reaches
        ``min_global_confidence``, the tokens are searched again within
        ``global_search_radius_px`` of that prior; the pass that tracks more tokens is kept.
        With no prediction and no usable global shift, zero motion is assumed. A match whose
        window covers an inhibited pixel is refused.

        Parameters
        ----------
        track_img: ``(H, W) float32`` tracking image of the current frame.
        predicted_shift_uv_px: ``(2,)`` predicted content motion (u, v) in pixels, or None.
        inhibit: ``(H, W) bool`` forbidden pixels, or None.
        rotation_offsets_uv_px: ``(N, 2)`` per-token motion expected besides the common shift
            (a heading change turns the image about the principal point, a tilt change shifts
            it), added to the predicted shift or to zero motion; with the global shift only its
            differential (offsets minus their mean) is added. None for none. With a 3 degree
            turn per frame a token 150 px from the centre moves 8 px more than the centre does.

        Returns
        -------
        :class:`TokenTracks` (possibly with zero tracks; never raises for a lost track).
        """
        img = _checked_image(track_img, inhibit)
        tokens = self._tokens
        n = len(tokens)
        if n == 0 or self._prev_img is None:
            return _empty_tracks(n)
        if self._prev_img.shape != img.shape:
            raise InvalidArgumentError(
                f"frame size changed from {self._prev_img.shape} to {img.shape}; call reset() first"
            )
        rot = _checked_offsets(rotation_offsets_uv_px, n)
        pred = _checked_prediction(predicted_shift_uv_px)
        # The whole-image shift, every frame (at reduced resolution: cheap): a second opinion on
        # the motion, which breaks the chain of a wrong speed predicting the next wrong match.
        g_shift, g_conf = self.motion_prior(track_img)
        matches, used_global = self._search(img, pred, rot, g_shift, g_conf, inhibit)

        ok = np.array([m.ok for m in matches], dtype=bool)
        uv_prev = np.array([t.centre_uv_px for t in tokens], dtype=np.float64).reshape(-1, 2)[ok]
        uv_curr = np.array([m.uv_px for m in matches], dtype=np.float64).reshape(-1, 2)[ok]
        self._last_shift = median0(uv_curr - uv_prev) if len(uv_curr) >= 2 else None
        scores = np.array([m.score for m in matches], dtype=np.float64)[ok]
        return TokenTracks(uv_prev, uv_curr, scores, n, used_global, tuple(m.reason for m in matches), g_shift, g_conf)

    def _search(
        self,
        img: np.ndarray,
        pred: np.ndarray | None,
        rot: np.ndarray,
        g_shift: np.ndarray | None,
        g_conf: float,
        inhibit: np.ndarray | None,
    ) -> tuple[list[Match], bool]:
        """``(one match per token, whether they come from the global shift)``: the passes of :meth:`track`.

        Around the prediction ``pred`` (2,) first; around the whole-image shift ``g_shift`` when it
        is confident and disagrees with the prediction or the prediction found too few tokens
        (the pass whose tokens move together more wins); around a weak ``g_shift`` when enough
        tokens confirm it; else around zero motion. ``rot`` (N, 2) are the per-token offsets.
        """
        tokens, cfg = self._tokens, self.tracker_config
        n = len(tokens)
        need = max(1, int(np.ceil(cfg.min_tracked_fraction * n)))
        global_ok = g_shift is not None and g_conf >= cfg.min_global_confidence
        matches: list[Match] | None = None
        n_ok, coherent = 0, 0
        if pred is not None:
            matches = _match_all(img, tokens, pred + rot, self.speed_config.search_radius_px, cfg, inhibit)
            n_ok, coherent = sum(m.ok for m in matches), _coherent(matches, tokens, rot)
        used_global = False
        disagree = pred is None or (global_ok and float(np.max(np.abs(pred - g_shift))) > _PRIOR_DISAGREEMENT_PX)
        if global_ok and (disagree or n_ok < need):
            # Phase correlation measures the mean image motion: keep only the offsets' differential.
            g_off = rot - rot.mean(axis=0)
            g_matches = _match_all(img, tokens, g_shift + g_off, cfg.global_search_radius_px, cfg, inhibit)
            g_coherent = _coherent(g_matches, tokens, g_off)
            if (
                matches is None
                or g_coherent > coherent
                or (g_coherent == coherent and sum(m.ok for m in g_matches) > n_ok)
            ):
                matches, used_global = g_matches, True
        if g_shift is not None and not global_ok and (matches is None or n_ok < need):
            # A weak phase-correlation peak (large motion, little overlap, low contrast) is still the
            # motion when the tokens confirm it: enough of them found around it, moving together.
            g_off = rot - rot.mean(axis=0)
            g_matches = _match_all(img, tokens, g_shift + g_off, cfg.global_search_radius_px, cfg, inhibit)
            g_coherent = _coherent(g_matches, tokens, g_off)
            if g_coherent >= min(n, max(need, _MIN_CONFIRMING_TOKENS)) and g_coherent > coherent:
                matches, used_global = g_matches, True
        if matches is None:
            # No prediction and no usable global shift: assume no motion.
            matches = _match_all(img, tokens, rot, self.speed_config.search_radius_px, cfg, inhibit)
        return matches, used_global


def _checked_image(track_img: np.ndarray, inhibit: np.ndarray | None) -> np.ndarray:
    """The ``(H, W)`` tracking image as float32, or InvalidArgumentError (it or ``inhibit`` of the wrong shape)."""
    img = np.asarray(track_img)
    if img.ndim != 2:
        raise InvalidArgumentError(f"track_img must be (H, W), got shape {img.shape}")
    img = img.astype(np.float32, copy=False)
    if inhibit is not None and (inhibit.shape != img.shape or inhibit.dtype != np.bool_):
        raise InvalidArgumentError(
            f"inhibit must be an (H, W) bool mask of shape {img.shape}, got {inhibit.shape} {inhibit.dtype}"
        )
    return img


def _checked_offsets(rotation_offsets_uv_px: np.ndarray | None, n: int) -> np.ndarray:
    """The ``(n, 2)`` per-token offsets (zeros for None), or InvalidArgumentError."""
    rot = np.zeros((n, 2))
    if rotation_offsets_uv_px is not None:
        rot = np.asarray(rotation_offsets_uv_px, dtype=np.float64)
        if rot.shape != (n, 2) or not np.all(np.isfinite(rot)):
            raise InvalidArgumentError(
                f"rotation_offsets_uv_px must be ({n}, 2) finite pixels (one row per token), got {rot.shape}"
            )
    return rot


def _checked_prediction(predicted_shift_uv_px: np.ndarray | None) -> np.ndarray | None:
    """The ``(2,)`` predicted shift (None stays None), or InvalidArgumentError."""
    if predicted_shift_uv_px is None:
        return None
    pred = np.asarray(predicted_shift_uv_px, dtype=np.float64).reshape(-1)
    if pred.shape != (2,) or not np.all(np.isfinite(pred)):
        raise InvalidArgumentError(
            f"predicted_shift_uv_px must be 2 finite numbers (u, v) or None, got {predicted_shift_uv_px!r}"
        )
    return pred


# The motion predicted from the last speed and the whole-image shift disagree beyond this: both
# are tried and the one the tokens agree with more is kept.
_PRIOR_DISAGREEMENT_PX = 2.0
# A phase-correlation shift below the confidence threshold is accepted when at least this many
# tokens (and at least min_tracked_fraction of them) are found around it, moving together.
_MIN_CONFIRMING_TOKENS = 3
# Tokens chosen away from the band the motion carries out of view: the band is widened by this
# fraction of the motion (the next frame's motion is a guess: 25 %; a measured prior: 10 %).
_NEXT_SHIFT_SLACK = 0.25
_PRIOR_SHIFT_SLACK = 0.1
# Fewer tokens than this where the seabed stays: choose anywhere instead, if that gives more.
_MIN_STAYING_TOKENS = 4


def _large_motion(shift_uv_px: np.ndarray, search_radius_px: int) -> bool:
    """Whether a content motion is larger than the token search radius (tokens near the border then leave)."""
    values = np.asarray(shift_uv_px, dtype=np.float64).reshape(-1).tolist()
    return all(math.isfinite(x) for x in values) and max(abs(x) for x in values) > search_radius_px


def leaving_mask(shape_hw: tuple[int, int], shift_uv_px: np.ndarray, margin_px: float) -> np.ndarray:
    """``(H, W) bool``: the pixels a content motion ``shift_uv_px`` carries out of the next frame (with a margin).

    Pixel ``(u, v)`` is True when ``u + du`` or ``v + dv`` falls within ``margin_px`` of the
    image border or beyond: a template touching it cannot be found in the next frame.
    """
    h, w = int(shape_hw[0]), int(shape_hw[1])
    du, dv = (float(x) for x in np.asarray(shift_uv_px, dtype=np.float64).reshape(2))
    m = float(margin_px)
    mask = np.zeros((h, w), dtype=bool)
    u = np.arange(w) + du
    v = np.arange(h) + dv
    mask[:, (u < m) | (u > w - 1 - m)] = True
    mask[(v < m) | (v > h - 1 - m), :] = True
    return mask


def _coherent(matches: list[Match], tokens: Sequence[Template], offsets_uv_px: np.ndarray) -> int:
    """How many accepted matches move together: within 1.5 px of their median displacement (offsets removed)."""
    ok = [i for i, m in enumerate(matches) if m.ok]
    if not ok:
        return 0
    # (K, 2) displacements, offsets removed: stacked once, then the same subtractions element by element
    d = np.array([matches[i].uv_px for i in ok]) - np.array([tokens[i].centre_uv_px for i in ok]) - offsets_uv_px[ok]
    dev = np.max(np.abs(d - median0(d)), axis=1)
    return int(np.count_nonzero(dev <= 1.5))


def _empty_tracks(n_given: int) -> TokenTracks:
    return TokenTracks(
        np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), n_given, False, ("no previous frame",) * n_given
    )
