"""The image the loop tracks in: the template channel band-passed, without the sunlight while caustics are seen.

:func:`tracking_image` reduces a frame to the processing scale, despeckles and band-passes its
template channel (:mod:`rovslam.vision.filters`) and says when it carries no texture to track.
:class:`SunlightWatch` (one per :class:`~rovslam.pipeline.SlamPipeline`) keeps, frame by frame,
the bright structures narrower than ``[bandpass] sunlight_px`` and decides with
:class:`rovslam.sensor.sunlight.SunlightMonitor` whether they move with the seabed; while they do not
(sunlight caustics), they are taken out of the tracking image.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rovslam.config import BandpassConfig
from rovslam.sensor.sunlight import BrightHistory, SunlightEvent, SunlightMonitor, moving_light_share
from rovslam.vision.filters import bandpass, contrast_std, despeckled_channels, remove_specks, template_channel_u8
from rovslam.vision.scale import ProcessingScale

__all__ = ["MIN_TEXTURE_STD", "SunlightWatch", "tracking_image"]

# A frame whose template channel has less contrast than this (8-bit units, std of the
# band-passed image) carries no texture to track: black, saturated or flat.
MIN_TEXTURE_STD = 0.5


def tracking_image(
    image: np.ndarray,
    cfg: BandpassConfig,
    scale: ProcessingScale,
    wide_px: int,
    without_bright: bool,
) -> tuple[np.ndarray | None, np.ndarray | None, str | None]:
    """``(img, bright, reason)`` of a ``(H, W[, C])`` frame at the processing scale.

    ``img``: the ``(H', W') float32`` band-passed template channel (None when the frame has no
    texture; ``reason`` then says so); ``bright``: the bright structures between the despeckle
    width and ``wide_px`` (None when ``wide_px`` is 0), taken out of ``img`` when ``without_bright``.
    """
    if scale.identity:
        chan, wide = despeckled_channels(image, cfg.channel, cfg.despeckle_px, wide_px)
    else:  # the channel reduced to the processing scale (area average on floats), then despeckled
        chan = remove_specks(scale.reduce_channel(template_channel_u8(image, cfg.channel)), cfg.despeckle_px)
        wide = remove_specks(chan, wide_px) if wide_px else None
    bright = None
    if wide is not None:  # the bright structures between the two widths: the sunlight, if any
        bright = chan - wide
        if without_bright:
            chan = wide
    img = bandpass(chan, cfg.sigma_fine_px, cfg.sigma_coarse_px)
    std = contrast_std(img)
    if std < MIN_TEXTURE_STD:
        return None, bright, "no texture (black, saturated or flat frame)"
    if std < cfg.min_contrast_std:  # dark or low-contrast: lifted as a camera's gain would, for the thresholds
        img *= np.float32(cfg.min_contrast_std / std)
    return img, bright, None


class SunlightWatch:
    """The sunlight over a run: this frame's bright structures, the last frames', and when they were taken out.

    ``monitor`` is None when ``[bandpass] sunlight_px`` does not exceed ``despeckle_px`` (no watch).
    """

    def __init__(self, cfg: BandpassConfig) -> None:
        self.monitor = SunlightMonitor() if cfg.sunlight_px > cfg.despeckle_px else None
        self.opening_px = cfg.sunlight_px if self.monitor is not None else 0  # the wide opening (0: none)
        self.events: list[SunlightEvent] = []
        self.frames_removed = 0
        self.history = BrightHistory()  # (H, W) float32 bright structures of the last frames
        self.bright: np.ndarray | None = None  # ... and of this one

    @property
    def removing(self) -> bool:
        """Whether the sunlight is being taken out of the tracking image."""
        return self.monitor is not None and self.monitor.active

    def changed(self, t_s: float, uv0: np.ndarray, uv1: np.ndarray, size_px: int) -> bool:
        """Did the monitor change its mind at ``t_s``? The bright structures around the ``(N, 2)`` tokens
        (``uv0`` in the previous frame, ``uv1`` in this one) compared with those 0.2 s back
        (:func:`rovslam.sensor.sunlight.moving_light_share` over ``size_px`` windows)."""
        if self.monitor is None or self.bright is None:
            return False
        earlier = self.history.baseline(t_s, uv0)  # over 0.2 s, whatever the frame rate
        if earlier is None:
            return False
        share = moving_light_share(earlier[0], self.bright, earlier[1], uv1, size_px)
        return self.monitor.observe(share)

    def watch(
        self,
        t_s: float,
        frame: int,
        uv0: np.ndarray,
        uv1: np.ndarray,
        size_px: int,
        retrack: Callable[[], tuple[np.ndarray | None, str | None]],
    ) -> np.ndarray | None:
        """After step 6 of the ``frame``-th processed frame: is the sunlight to be taken out (or left in again)?

        ``uv0``, ``uv1``, ``size_px``: as for :meth:`changed`. When the monitor changes its mind,
        ``retrack()`` makes the frame's tracking image again (``(img, reason)``) and it is
        returned, so that steps 7 and 8 cut their templates from it; None when nothing changed,
        or when no texture is left without the sunlight (the change is then undone).
        """
        if not self.changed(t_s, uv0, uv1, size_px):
            return None
        img, reason = retrack()
        if reason is not None:  # no texture left without the sunlight: keep the image as it was
            self.monitor.active = not self.monitor.active  # type: ignore[union-attr]
            return None
        self.events.append(SunlightEvent(frame, t_s, self.monitor.active, self.monitor.share))  # type: ignore[union-attr]
        return img

    def end_frame(self, t_s: float, uv0: np.ndarray, uv1: np.ndarray) -> None:
        """The frame at ``t_s`` is done: keep its bright structures with the consensus's ``(N, 2)`` tokens."""
        if self.bright is not None:
            self.history.push(t_s, self.bright, uv0, uv1)
        self.frames_removed += self.removing
