"""A frame's work that depends on the frame alone, done ahead of the loop on a second core.

:class:`FramePreparer` makes for each frame what the loop would otherwise make first thing:
the tracking image (:func:`rovslam.pipeline.image.tracking_image`, the sunlight taken out or not
as the loop did last), its local variance over the speed template size (step 8) and its reduction
with the phase correlation against the previous frame's (the tokens' motion prior,
:meth:`rovslam.vision.tracking.TokenTracker.motion_prior`). None of it reads the loop's state.

:func:`prepared_frames` runs a preparer on another thread a few frames ahead of the loop, when
the process may use two cores or more; OpenCV releases Python's lock while it filters, so the
two threads work at once. The loop takes each piece only where it is what it would have made
itself (the same image object, the sunlight taken out or not as it is now, the same previous
reduced image) and makes it again otherwise: the results are the same, bit for bit, with or
without it.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from rovslam.config import RunConfig
from rovslam.core import Frame
from rovslam.pipeline.image import tracking_image
from rovslam.vision.filters import local_variance
from rovslam.vision.scale import ProcessingScale
from rovslam.vision.tracking import reduce_for_shift, shift_between

__all__ = ["FramePreparer", "PreparedFrame", "prepared_frames"]

# Frames prepared ahead of the loop: enough to absorb one slow frame, few enough to hold little memory.
AHEAD_FRAMES = 3


@dataclass(frozen=True, eq=False)
class PreparedFrame:
    """What :class:`FramePreparer` made of one frame.

    ``image``: the frame's image object it was made from; ``without_bright``: whether the sunlight
    was taken out; ``track_img``, ``bright``, ``reason``: :func:`~rovslam.pipeline.image.tracking_image`
    (``track_img`` ``(H', W') float32`` or None); ``variance``: ``(H', W') float32`` local variance of
    ``track_img`` over the speed template size; ``small``: ``track_img`` reduced for the phase
    correlation (None when the global search is off); ``prev_small``: the previous prepared
    frame's ``small``; ``prior``: ``(shift (2,) px or None, confidence)`` between the two.
    """

    image: np.ndarray
    without_bright: bool
    track_img: np.ndarray | None
    bright: np.ndarray | None
    reason: str | None
    variance: np.ndarray | None = None
    small: np.ndarray | None = None
    prev_small: np.ndarray | None = None
    prior: tuple[np.ndarray | None, float] = (None, float("nan"))


class FramePreparer:
    """Prepares the frames of one run in order (it keeps the previous frame's reduced image).

    ``removing()`` says whether the loop takes the sunlight out now (read as each frame is
    prepared: a few frames ahead, the loop mostly still does the same).
    """

    def __init__(
        self, config: RunConfig, scale: ProcessingScale, opening_px: int, removing: Callable[[], bool]
    ) -> None:
        self.config, self.scale, self.opening_px, self.removing = config, scale, int(opening_px), removing
        self._prev_small: np.ndarray | None = None

    def __call__(self, frame: Frame) -> PreparedFrame | None:
        """The frame's :class:`PreparedFrame`; None for a frame without an image."""
        if frame.image is None or frame.error is not None:
            self._prev_small = None
            return None
        without = bool(self.removing())
        img, bright, reason = tracking_image(frame.image, self.config.bandpass, self.scale, self.opening_px, without)
        if img is None:
            self._prev_small = None
            return PreparedFrame(frame.image, without, None, bright, reason)
        variance = local_variance(img, self.config.speed_templates.size_px)
        small = prev = None
        prior: tuple[np.ndarray | None, float] = (None, float("nan"))
        if self.config.tracker.global_search:
            small, prev = reduce_for_shift(img), self._prev_small
            if prev is not None:
                prior = shift_between(prev, small, img.shape)
        self._prev_small = small
        return PreparedFrame(frame.image, without, img, bright, reason, variance, small, prev, prior)


_END = object()


class _Failed:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


def prepared_frames(
    frames: Iterator[Frame], preparer: Callable[[Frame], PreparedFrame | None], ahead: bool
) -> Generator[tuple[Frame, PreparedFrame | None], None, None]:
    """``(frame, prepared)`` for each of ``frames``: prepared on another thread when ``ahead``, else None.

    With ``ahead``, a thread reads the frames and prepares each, :data:`AHEAD_FRAMES` ahead of
    the caller. A frame whose preparation fails comes with None (the loop meets the problem
    itself, where it always has); an error of the source is raised here, in the caller's thread,
    after the frames before it. Closing this generator stops the thread after the frame it is
    reading and closes ``frames``.
    """
    if not ahead:
        try:
            for frame in frames:
                yield frame, None
        finally:
            _close(frames)
        return
    items: queue.Queue[Any] = queue.Queue(maxsize=AHEAD_FRAMES)
    stop = threading.Event()

    def put(item: Any) -> bool:
        while not stop.is_set():
            try:
                items.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for frame in frames:
                try:
                    prepared = preparer(frame)
                except Exception:  # the loop makes it again and says what is wrong
                    prepared = None
                if not put((frame, prepared)):
                    return
            put(_END)
        except BaseException as exc:  # the source's error, raised in the caller's thread
            put(_Failed(exc))
        finally:
            _close(frames)

    thread = threading.Thread(target=work, name="rovslam-prepare", daemon=True)
    thread.start()
    try:
        while True:
            item = items.get()
            if item is _END:
                return
            if isinstance(item, _Failed):
                raise item.exc
            yield item
    finally:
        stop.set()
        thread.join()


def _close(frames: Iterator[Frame]) -> None:
    close = getattr(frames, "close", None)
    if close is not None:
        close()
