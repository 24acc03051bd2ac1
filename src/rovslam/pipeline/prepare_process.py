"""A sequence folder's frames read and prepared in a second process, ahead of the loop.

:func:`prepared_in_process` is :func:`rovslam.pipeline.prepare.prepared_frames` for a sequence
folder, with the reading and the :class:`~rovslam.pipeline.prepare.FramePreparer` in a process of
their own rather than a thread: the loop's Python and the preparation's no longer take turns at
one interpreter lock (360x272 PNG frames on two cores: the loop's own thread cost a third more
beside a preparing thread).

* The process is a fresh interpreter (``python -c``, this process's ``sys.path``): no lock of
  this process's threads is copied into it, and no script of the caller's is imported again. It
  needs about a second to import; meanwhile the first frames are read and prepared on a thread,
  as without it, then the rest of the folder is handed over from the next frame. It is in a process group
  of its own: a Ctrl-C at the terminal reaches the loop, which stops it.
* Each prepared frame comes back through one of :data:`SLOTS` slots of a shared memory file
  (the image, the tracking image, the bright structures, the local variance and the reduced
  image), a file in ``/dev/shm`` removed as soon as it is made (both processes hold it open);
  the loop copies each frame out and counts in the file the frames it has taken, which frees
  their slots. Only the frame's small fields travel through a pipe.
* The loop takes each piece only where it is what it would make itself, as with a thread: the
  results are the same, bit for bit.
* A source's error is raised in the loop, after the frames before it; a process that dies
  leaves the rest of the folder to a thread, as before it started; closing the generator stops
  the process after the frame it is reading.
"""

from __future__ import annotations

import contextlib
import dataclasses
import mmap
import os
import pickle
import select
import struct
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Generator, Iterator
from typing import Any

import numpy as np

from rovslam.core import Frame
from rovslam.errors import RovslamError
from rovslam.io.sequence import Sequence
from rovslam.pipeline.prepare import AHEAD_FRAMES, FramePreparer, PreparedFrame, prepared_frames
from rovslam.vision.scale import ProcessingScale

__all__ = ["MIN_FRAMES", "SHARED_PREFIX", "SLOTS", "START_INLINE", "prepared_in_process", "serve"]

# Frames in flight: the ones prepared ahead plus the one the loop is copying out.
SLOTS = AHEAD_FRAMES + 1
# Fewer frames than this are read in the loop's process: a second process would start as they end.
MIN_FRAMES = 600
# Whether the first frames are read and prepared on a thread while the process starts (False: the loop
# waits for the process, as the tests do, so that every frame comes from it).
START_INLINE = True
_START_S = 60.0  # how long the loop waits for the process when it does not start inline
_ALIGN = 64
SHARED_PREFIX = "rovslam-frames-"  # the shared file's name in /dev/shm, for the moment between making and removing it
# The file's first _ALIGN bytes: the loop's word to the process.
_REMOVING = 0  # byte: whether the loop takes the sunlight out now
_STOP = 1  # byte: stop now
_TAKEN = 8  # uint64: how many of the process's frames the loop has taken (their slots are free again)
_WAIT_S = 0.0005  # how often a process ahead of the loop looks whether a slot is free
_ARRAYS = ("image", "track_img", "bright", "variance", "small")
_JOIN_S = 5.0


def prepared_in_process(
    seq: Sequence, stop: int | None, preparer: FramePreparer
) -> Generator[tuple[Frame, PreparedFrame | None], None, None]:
    """``(frame, prepared)`` for each frame of ``seq`` up to ``stop``, prepared in a second process.

    Until the process is ready the frames come from this process, prepared on a thread
    (:func:`~rovslam.pipeline.prepare.prepared_frames`); then from the process, each with its
    :class:`~rovslam.pipeline.prepare.PreparedFrame` (None where its preparation failed). The
    process reads ``preparer.removing()`` as this generator last saw it, a few frames behind.
    """
    worker = _Worker.start(seq, preparer)
    # Meanwhile a thread prepares the frames, as without the process (what it read ahead is read again there).
    inline = prepared_frames(seq.frames(stop=stop, prefetch=0), preparer, True)
    position = 0
    try:
        if worker is not None and not START_INLINE:
            worker.ready(_START_S)
        while worker is None or not worker.ready():
            item = next(inline, None)
            if item is None:
                return
            position += 1
            yield item
        inline.close()
        for item in worker.frames(position, stop):
            position += 1
            yield item
        if worker.died:  # what the process did not deliver, read and prepared here as before it started
            inline = prepared_frames(seq.frames(start=position, stop=stop, prefetch=0), preparer, True)
            yield from inline
    finally:
        inline.close()
        if worker is not None:
            worker.close()


def _slot_bytes(seq: Sequence, scale: ProcessingScale) -> int:
    """Room for one frame: the ``(H, W, 3) uint8`` image and four ``(H', W') float32`` images."""
    full, proc = seq.info.camera, scale.camera
    return _aligned(full.width_px * full.height_px * 3) + 4 * _aligned(proc.width_px * proc.height_px * 4)


def _aligned(n: int) -> int:
    return -(-int(n) // _ALIGN) * _ALIGN


class _Worker:
    """The preparing process, the shared memory file of its slots and its two pipes (commands in, frames out).

    The file's first :data:`_ALIGN` bytes are the loop's word to it (whether the sunlight is being
    taken out, stop, how many frames it has taken); the :data:`SLOTS` slots follow.
    """

    def __init__(
        self, proc: subprocess.Popen, buf: mmap.mmap, slot_bytes: int, commands, results, removing: Callable[[], bool]
    ) -> None:
        self.proc, self.buf, self.slot_bytes = proc, buf, slot_bytes
        self.commands, self.results = commands, results  # binary files of the two pipes
        self.removing = removing  # whether the loop takes the sunlight out now
        self.died = False
        self._ready = False
        self._handing: threading.Thread | None = None  # the thread writing the sequence to the process

    @classmethod
    def start(cls, seq: Sequence, preparer: FramePreparer) -> _Worker | None:
        """The process, started; None when it cannot be (the frames are then read in this process)."""
        if not hasattr(os, "posix_fallocate"):  # not Linux: the thread does it
            return None
        slot_bytes = _slot_bytes(seq, preparer.scale)
        size = _ALIGN + SLOTS * slot_bytes
        buf = None
        fds: list[int] = []
        try:
            memory, name = tempfile.mkstemp(prefix=SHARED_PREFIX, dir=_shared_dir())
            fds.append(memory)
            os.unlink(name)  # the two processes share it by its descriptor: nothing is left behind, whatever happens
            # Reserved now: a full /dev/shm fails here (the frames are then read in the loop), not as a SIGBUS later.
            os.posix_fallocate(memory, 0, size)
            buf = mmap.mmap(memory, size)
            commands_r, commands_w = os.pipe()
            results_r, results_w = os.pipe()
            fds += [commands_r, commands_w, results_r, results_w]
            env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
            proc = subprocess.Popen(
                [sys.executable, "-c", _SERVE, str(commands_r), str(results_w), str(memory), str(slot_bytes)],
                pass_fds=(commands_r, results_w, memory),
                stdin=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,  # what goes wrong there comes back through the pipe, or the loop reads on
                env=env,
                process_group=0,  # a Ctrl-C at the terminal is the loop's to handle, not this process's
            )
            for fd in (commands_r, results_w, memory):
                os.close(fd)
            commands, results = os.fdopen(commands_w, "wb"), os.fdopen(results_r, "rb")
            worker = cls(proc, buf, slot_bytes, commands, results, preparer.removing)
            # The sequence goes to the process on a thread: it reads it once it has imported (a second),
            # and a long folder's rows fill the pipe; meanwhile the first frames are read and prepared on a thread.
            data = pickle.dumps((seq, preparer.config, preparer.scale, preparer.opening_px), pickle.HIGHEST_PROTOCOL)
            worker._handing = threading.Thread(target=_write_all, args=(commands_w, data), name="rovslam-hand-over")
            worker._handing.start()
        except (OSError, ValueError, pickle.PicklingError):
            for fd in fds:
                with contextlib.suppress(OSError):
                    os.close(fd)
            if buf is not None:
                buf.close()
            return None
        return worker

    def _send(self, message: Any) -> None:
        pickle.dump(message, self.commands, pickle.HIGHEST_PROTOCOL)
        self.commands.flush()

    def ready(self, timeout_s: float = 0.0) -> bool:
        """Whether the process has started and mapped the slots (it then waits for :meth:`frames`)."""
        if not self._ready and select.select([self.results], [], [], timeout_s)[0]:
            with contextlib.suppress(EOFError, OSError, pickle.UnpicklingError):
                pickle.load(self.results)  # ("ready",)
            self._ready = True  # or it died starting: frames() finds that out and leaves the rest to a thread
        return self._ready

    def frames(self, start: int, stop: int | None) -> Iterator[tuple[Frame, PreparedFrame | None]]:
        """The frames from position ``start``, prepared; sets :attr:`died` if the process ends early."""
        if self._handing is not None:
            self._handing.join()  # it has read the sequence (it said it is ready): at once
        try:
            self._send(("start", start, stop))
        except OSError:
            self.died = True
            return
        last_small: np.ndarray | None = None
        taken = 0
        while True:
            self.buf[_REMOVING] = bool(self.removing())
            try:
                message = pickle.load(self.results)
            except (EOFError, OSError, pickle.UnpicklingError):
                self.died = True
                return
            if message[0] == "end":
                return
            if message[0] == "error":
                raise message[1]
            frame, prepared = self._unpack(message, last_small)
            taken += 1
            struct.pack_into("<Q", self.buf, _TAKEN, taken)  # its slot is free again
            last_small = None if prepared is None else prepared.small
            yield frame, prepared

    def _unpack(self, message: tuple, last_small: np.ndarray | None) -> tuple[Frame, PreparedFrame | None]:
        _, slot, frame, prepared, placed = message
        base = _ALIGN + slot * self.slot_bytes
        arrays = {}
        for key, where, shape, dtype in placed:
            if where is None:  # it did not fit in the slot: the array itself came in the message, as its shape
                arrays[key] = shape
            else:
                n = int(np.prod(shape))
                arrays[key] = np.frombuffer(self.buf, dtype, n, base + where).reshape(shape).copy()
        frame = dataclasses.replace(frame, image=arrays.get("image"))
        if prepared is None:
            return frame, None
        without_bright, reason, prior, prev_is_last = prepared
        made = PreparedFrame(
            frame.image,
            without_bright,
            arrays.get("track_img"),
            arrays.get("bright"),
            reason,
            arrays.get("variance"),
            arrays.get("small"),
            last_small if prev_is_last else None,
            prior if prev_is_last else (None, float("nan")),
        )
        return frame, made

    def close(self) -> None:
        """Stop the process (after the frame it is reading) and free its memory."""
        self.buf[_STOP] = 1
        if self._handing is not None and self._handing.is_alive():
            self.proc.kill()  # it never read the sequence: its pipe breaks, and the thread ends
            self._handing.join()
        with contextlib.suppress(OSError, ValueError):
            self._send(None)
        for f in (self.commands, self.results):
            with contextlib.suppress(OSError):
                f.close()
        try:
            self.proc.wait(_JOIN_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.buf.close()


def _write_all(fd: int, data: bytes) -> None:
    """Write ``data`` to the pipe ``fd`` whole, or until the process at its other end has gone."""
    view = memoryview(data)
    with contextlib.suppress(OSError):
        while view:
            view = view[os.write(fd, view) :]


def _shared_dir() -> str | None:
    """Where the slots' file lies: memory (``/dev/shm``) where there is one, else the temporary folder."""
    shm = "/dev/shm"
    return shm if os.path.isdir(shm) and os.access(shm, os.W_OK) else None


# ----------------------------------------------------------------------------- the process's side

_SERVE = "import sys; from rovslam.pipeline.prepare_process import serve; serve(*sys.argv[1:])"


def serve(commands_fd: str, results_fd: str, memory_fd: str, slot_bytes: str) -> None:
    """The preparing process: map the slots, say so, then prepare from the position it is given."""
    size = int(slot_bytes)
    buf = mmap.mmap(int(memory_fd), _ALIGN + SLOTS * size)
    os.close(int(memory_fd))
    commands, results = os.fdopen(int(commands_fd), "rb"), os.fdopen(int(results_fd), "wb")

    def send(message: Any) -> None:
        pickle.dump(message, results, pickle.HIGHEST_PROTOCOL)
        results.flush()

    try:
        seq, config, scale, opening_px = pickle.load(commands)
        send(("ready",))
        command = pickle.load(commands)
        if command is not None:
            _, start, stop = command
            _prepare(
                seq.frames(start=start, stop=stop, prefetch=0),
                FramePreparer(config, scale, opening_px, lambda: bool(buf[_REMOVING])),
                buf,
                size,
                commands,
                send,
            )
    except (EOFError, BrokenPipeError):
        pass  # the loop has gone
    except Exception as exc:  # the source's error, raised in the loop
        with contextlib.suppress(OSError):
            send(("error", _portable(exc)))
    finally:
        for f in (commands, results):
            with contextlib.suppress(OSError):  # a half-sent frame to a loop that has gone
                f.close()


def _prepare(
    frames: Iterator[Frame], preparer: FramePreparer, buf: mmap.mmap, size: int, commands, send: Callable[[Any], None]
) -> None:
    """Prepare each frame into the next slot, once the loop has taken the frame that was in it; stop when it says so."""
    sent_small: np.ndarray | None = None
    for sent, frame in enumerate(frames):
        try:
            prepared = preparer(frame)
        except Exception:  # the loop makes it again and says what is wrong
            prepared = None
        while sent - struct.unpack_from("<Q", buf, _TAKEN)[0] >= SLOTS:  # every slot holds a frame not yet taken
            if buf[_STOP] or select.select([commands], [], [], _WAIT_S)[0]:
                return  # told to stop, or the loop has gone
        send(_pack(frame, prepared, sent_small, buf, sent % SLOTS, size))
        sent_small = None if prepared is None else prepared.small
    send(("end",))


def _pack(
    frame: Frame, prepared: PreparedFrame | None, sent_small: np.ndarray | None, buf: mmap.mmap, slot: int, size: int
) -> tuple:
    """The message of one frame: its arrays written to ``slot`` (those that fit), the rest in the message."""
    arrays = {"image": frame.image}
    if prepared is not None:
        arrays.update(
            track_img=prepared.track_img, bright=prepared.bright, variance=prepared.variance, small=prepared.small
        )
    placed: list[tuple[Any, ...]] = []
    offset = 0
    for key in _ARRAYS:
        a = arrays.get(key)
        if a is None:
            continue
        a = np.ascontiguousarray(a)
        if offset + a.nbytes <= size:
            np.frombuffer(buf, a.dtype, a.size, _ALIGN + slot * size + offset)[:] = a.reshape(-1)
            placed.append((key, offset, a.shape, a.dtype.str))
            offset += _aligned(a.nbytes)
        else:
            placed.append((key, None, a, None))
    meta = None
    if prepared is not None:
        prev_is_last = prepared.prev_small is not None and prepared.prev_small is sent_small
        meta = (prepared.without_bright, prepared.reason, prepared.prior, prev_is_last)
    return ("frame", slot, dataclasses.replace(frame, image=None), meta, placed)


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a :class:`RovslamError` with its type and message."""
    try:
        return pickle.loads(pickle.dumps(exc))
    except Exception:
        return RovslamError(f"{type(exc).__name__}: {exc}")
