"""What a run sets in its process: freed memory kept for reuse, OpenCV on one thread; the cores it may use.

Both are process-wide (the C allocator's and OpenCV's settings); :func:`rovslam.runner.run_sequence`
applies them around every run (``rovslam run``, ``live``, a matrix cell).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

FREED_MEMORY_KEPT_BYTES = 64 * 2**20
MMAP_THRESHOLD_BYTES = 32 * 2**20  # the largest glibc takes on 64 bits: blocks below it come from its heaps


def keep_freed_memory(pad_bytes: int = FREED_MEMORY_KEPT_BYTES) -> bool:
    """Ask the C allocator (glibc) to keep ``pad_bytes`` of freed memory for reuse; False where it cannot.

    Every frame allocates and frees a few image-sized arrays (OpenCV and NumPy results: 0.4 MB
    each at 360x272, 8 MB at 1920x1080). By default glibc gives freed memory at the top of its
    heap back to the system as soon as 128 KiB of it is free, so the next frame's arrays are
    fresh pages and every first touch is a page fault: about 330 faults per 360x272 frame, a
    tenth of them once the memory is kept (``M_TOP_PAD``). The peak memory of a run does not
    change; between frames up to ``pad_bytes`` stay resident. A no-op off glibc.
    """
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_top_pad, m_mmap_threshold = -2, -3  # <malloc.h>
    kept = bool(mallopt(ctypes.c_int(m_top_pad), ctypes.c_int(int(pad_bytes))))
    # Setting M_TOP_PAD also freezes glibc's mmap threshold where it stands (otherwise raised to the largest
    # block freed). Below this one, live's decoder thread got each 1920x1080 frame as fresh pages, faulting
    # every one on first touch (about 1,600 faults a frame, docs/performance.md).
    return kept and bool(mallopt(ctypes.c_int(m_mmap_threshold), ctypes.c_int(MMAP_THRESHOLD_BYTES)))


@contextlib.contextmanager
def opencv_threads(n: int = 1) -> Iterator[None]:
    """OpenCV's thread count set to ``n`` while the block runs, then set back. Its pool costs more than it
    splits on the loop's small images (a third more CPU a frame on two cores, docs/performance.md); the
    results do not depend on it."""
    import cv2

    before = cv2.getNumThreads()
    cv2.setNumThreads(int(n))
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def usable_cores() -> int:
    """The cores this process may use (its CPU affinity on Linux)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)
