"""Where rovslam writes: output paths checked once, files written so that a failure leaves them whole.

Every output path of every command goes through :func:`check_output_file` (a file) or
:func:`check_output_folder` (a folder) where it enters:

* a path that exists and is not a regular file (a folder where a file is expected, a device
  node such as ``/dev/null`` or ``/dev/full``, a FIFO, a socket) is refused with one line
  (:class:`~rovslam.errors.OutputError`); rovslam never writes into it nor renames over it;
* a symbolic link is resolved, and its target checked the same way: a link to a regular file
  is written through (the link stays, the file it names is replaced), a link to anything else
  is refused, and so is a link to nothing (a dangling link).

:func:`atomic_write_bytes` writes a whole file (a temporary file beside the target, fsync,
rename), checking the target again just before the rename. :class:`StreamFile` appends rows
and, when a write fails (a full disk, a quota), cuts the file back to its last complete row.
:class:`SpaceReserve` holds a little disk space for the end of a run, so that a disk that
fills mid-run still leaves room for ``summary.json`` saying ``"failed"`` and the landmark map.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path

from rovslam.errors import OutputError

_KINDS = (
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISDIR, "a folder"),
)


def file_kind(mode: int) -> str:
    """What an ``st_mode`` is, in words ("a regular file", "a FIFO (named pipe)", ...)."""
    if stat.S_ISREG(mode):
        return "a regular file"
    for test, name in _KINDS:
        if test(mode):
            return name
    return "not a regular file"


def describe_os_error(exc: OSError) -> str:
    """A short human reason for an OSError, with a hint for the common output problems."""
    hints = {
        errno.ENOSPC: "the disk is full; free space or choose another --out",
        errno.EDQUOT: "the disk quota is exceeded; free space or choose another --out",
        errno.EROFS: "the file system is read-only; choose another --out",
        errno.EACCES: "permission denied; choose a folder you can write to",
        errno.EPERM: "operation not permitted; choose a folder you can write to",
        errno.ENOTDIR: "a parent of this path is a file, not a folder",
        errno.EISDIR: "this is a folder; give a file name",
        errno.ENOENT: "the folder does not exist",
    }
    reason = exc.strerror or str(exc) or type(exc).__name__
    hint = hints.get(exc.errno or -1)
    return f"{reason} ({hint})" if hint else reason


@contextlib.contextmanager
def output_errors(path: Path, action: str = "cannot write") -> Iterator[None]:
    """Turn an OSError raised inside the block into an :class:`OutputError` naming ``path``."""
    try:
        yield
    except OSError as exc:
        raise OutputError(f"{path}: {action}: {describe_os_error(exc)}.") from None


def _lstat(path: Path) -> os.stat_result | None:
    try:
        return os.lstat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise OutputError(f"{path}: cannot be checked as an output: {describe_os_error(exc)}.") from None


def _resolve_link(path: Path, what: str) -> Path:
    """The final target of the symbolic link ``path``, or OutputError for a link to nothing."""
    target = Path(os.path.realpath(path))
    if _lstat(target) is None:
        raise OutputError(
            f"{path}: is a symbolic link to {target}, which does not exist; rovslam does not create "
            f"files through a dangling link: give {what} the real path."
        )
    return target


def check_output_file(
    path: str | Path, what: str = "the output", *, parent_must_exist: bool = True, example: str = "FILE"
) -> Path:
    """The path to write the file ``path`` at, or :class:`OutputError` saying why it cannot be one.

    Refused: a folder, a device, a FIFO, a socket (an existing path that is not a regular
    file), a link to one of those or to nothing, and (``parent_must_exist``) a path whose folder
    does not exist. A symbolic link to a regular file is resolved: the returned path is its
    target. ``what`` names the output in the message (e.g. "--json"), ``example`` a file name to suggest
    inside a folder given instead of a file.
    """
    p = Path(path)
    st = _lstat(p)
    if st is not None and stat.S_ISLNK(st.st_mode):
        target = _resolve_link(p, what)
        st, shown = os.stat(target), f"{p} (a link to {target})"
        p = target
    else:
        shown = str(p)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{shown}: is a folder; {what} needs a file name (e.g. {Path(path) / example}).")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputError(
            f"{shown}: is {file_kind(st.st_mode)}, not a regular file; rovslam never writes into or "
            f"replaces one; give {what} the path of a regular file."
        )
    if parent_must_exist:
        parent = p.parent
        if not parent.is_dir():
            state = "is not a folder" if parent.exists() else "does not exist"
            raise OutputError(f"{shown}: the folder {parent} {state}; create it or choose another place for {what}.")
    return p


def check_output_folder(path: str | Path, what: str = "--out") -> Path:
    """``path`` when it is a folder or does not exist yet; :class:`OutputError` for anything else.

    A symbolic link is resolved and its target checked the same way (a link to nothing is refused).
    """
    p = Path(path)
    st = _lstat(p)
    shown = str(p)
    if st is not None and stat.S_ISLNK(st.st_mode):
        target = _resolve_link(p, what)
        st, shown = os.stat(target), f"{p} (a link to {target})"
    if st is not None and not stat.S_ISDIR(st.st_mode):
        kind = "a file" if stat.S_ISREG(st.st_mode) else file_kind(st.st_mode)
        raise OutputError(f"{shown}: exists and is {kind}, not a folder; give {what} a new or empty folder.")
    return p


def _write_all(fd: int, data: bytes | memoryview) -> int:
    """os.write until every byte of ``data`` is written; returns the count (an OSError carries on up)."""
    view, done = memoryview(data), 0
    while done < len(view):
        n = os.write(fd, view[done:])
        if n <= 0:  # never seen, but a zero-byte write would loop for ever
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        done += n
    return done


def atomic_write_bytes(path: str | Path, data: bytes, what: str = "the output") -> Path:
    """Write ``data`` to ``path`` atomically: a temporary file beside it, fsync, then rename. Returns the path written.

    The target is checked first (:func:`check_output_file`: never a device, FIFO, socket or
    folder; a link is written through to its regular file) and again just before the rename.
    Readers see the old file or the new one, never a part. On any error the temporary file is
    removed and :class:`OutputError` names ``path``.
    """
    target = check_output_file(path, what)
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
    with output_errors(Path(path)):
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
            try:
                _write_all(fd, data)
                os.fsync(fd)
            finally:
                os.close(fd)
            check_output_file(target, what)  # a special file put there meanwhile is not renamed over either
            os.replace(tmp, target)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
    return target


def atomic_write_text(path: str | Path, text: str, what: str = "the output") -> Path:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    return atomic_write_bytes(path, text.encode("utf-8"), what)


class StreamFile:
    """A new file written row by row: each ``write`` call is one complete row (what ``csv.writer`` does).

    Rows are kept in memory until :meth:`flush` (or until ``max_pending_bytes`` of them wait).
    When a write fails (full disk, quota) the file is cut back to its last complete row, the
    rows not written stay pending, and :class:`OutputError` names the file: the file never
    ends in half a row. Created with ``O_EXCL`` (``exclusive``): never writes through a file or link
    that is there; else an existing regular file is emptied (anything else refused, see
    :func:`check_output_file`).
    """

    def __init__(self, path: str | Path, max_pending_bytes: int = 1 << 20, exclusive: bool = True):
        self.path = Path(path)
        flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
        if exclusive:
            flags |= os.O_EXCL
        else:
            flags |= os.O_TRUNC
            check_output_file(self.path)
        with output_errors(self.path, "cannot create"):
            self._fd: int | None = os.open(self.path, flags, 0o666)
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self.size_bytes = 0  # bytes of complete rows in the file
        self.rows = 0  # complete rows in the file
        self.max_pending_bytes = int(max_pending_bytes)

    def write(self, text: str) -> int:
        data = text.encode("utf-8")
        self._pending.append(data)
        self._pending_bytes += len(data)
        if self._pending_bytes >= self.max_pending_bytes:
            self.flush()
        return len(text)

    def flush(self, max_bytes: int | None = None, max_rows: int | None = None) -> None:
        """Write the pending rows; on an error, cut the file back to its last complete row and raise OutputError.

        ``max_bytes``: write only the first rows that fit in that many bytes; ``max_rows``: only as many as
        leave the file with at most that many complete rows (the others stay pending).
        """
        if not self._pending or self._fd is None:
            return
        if max_bytes is not None or max_rows is not None:
            room = len(self._pending) if max_rows is None else max(0, max_rows - self.rows)
            budget = math.inf if max_bytes is None else max_bytes
            rows = size = 0
            for row in self._pending[:room]:
                if size + len(row) > budget:
                    break
                size += len(row)
                rows += 1
            head, tail = self._pending[:rows], self._pending[rows:]
            self._pending = head
            try:
                self.flush()
            finally:
                self._pending = self._pending + tail
                self._pending_bytes = sum(len(r) for r in self._pending)
            return
        data = b"".join(self._pending)
        done = 0
        try:
            view = memoryview(data)
            while done < len(view):
                n = os.write(self._fd, view[done:])
                if n <= 0:
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += n
        except OSError as exc:
            self._settle(done)
            raise OutputError(f"{self.path}: cannot write: {describe_os_error(exc)}.") from None
        self._settle(done)

    def _settle(self, done: int) -> None:
        """Count the rows wholly inside the ``done`` bytes just written; cut off the part of the next one."""
        whole = rows = 0
        for row in self._pending:
            if whole + len(row) > done:
                break
            whole += len(row)
            rows += 1
        if whole < done and self._fd is not None:  # half a row reached the disk: take it back
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self.size_bytes + whole)
                os.lseek(self._fd, self.size_bytes + whole, os.SEEK_SET)
        self.size_bytes += whole
        self.rows += rows
        self._pending = self._pending[rows:]
        self._pending_bytes = sum(len(r) for r in self._pending)

    def close(self, quiet: bool = False) -> None:
        """Flush and close; ``quiet``: after an error, close without writing the rows still pending."""
        if self._fd is None:
            return
        try:
            if not quiet:
                self.flush()
        finally:
            fd, self._fd = self._fd, None
            self._pending, self._pending_bytes = [], 0
            with contextlib.suppress(OSError):
                os.close(fd)

    @property
    def closed(self) -> bool:
        return self._fd is None


RESERVE_NAME = ".rovslam-reserve"
RESERVE_SIZES_BYTES = (256 * 1024, 128 * 1024, 64 * 1024, 32 * 1024, 16 * 1024)


class SpaceReserve:
    """A hidden file in an output folder that holds disk space for the last writes of a run.

    Created with the largest of ``sizes_bytes`` no larger than a quarter of the free space
    (else the largest that fits; none when even the smallest does not: the run then fails on
    its first rows). :meth:`release` deletes it, which frees its space for ``summary.json``
    and ``landmarks.csv`` when the disk filled mid-run.
    """

    def __init__(self, folder: str | Path, sizes_bytes: tuple[int, ...] = RESERVE_SIZES_BYTES):
        self.path = Path(folder) / RESERVE_NAME
        self.size_bytes = 0
        try:
            st = os.statvfs(folder)
            quarter = st.f_bavail * st.f_frsize // 4
        except (OSError, AttributeError):
            quarter = max(sizes_bytes)
        sizes = sorted(sizes_bytes, reverse=True)
        first = next((i for i, size in enumerate(sizes) if size <= quarter), len(sizes) - 1)
        for size in sizes[first:]:
            if self._try(size):
                self.size_bytes = size
                break

    def _try(self, size: int) -> bool:
        try:
            fd = os.open(
                self.path,
                os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0),
                0o600,
            )
        except OSError:
            return False
        try:
            try:
                os.posix_fallocate(fd, 0, size)
            except (AttributeError, OSError) as exc:
                if isinstance(exc, OSError) and exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):
                    raise
                _write_all(fd, bytes(size))  # a file system without fallocate: real blocks, written
            return True
        except OSError:
            os.close(fd)
            fd = -1
            with contextlib.suppress(OSError):
                os.unlink(self.path)
            return False
        finally:
            if fd >= 0:
                os.close(fd)

    def release(self) -> None:
        """Delete the reserve (its space is free at once); a second call does nothing."""
        if self.size_bytes or self.path.exists():
            with contextlib.suppress(OSError):
                os.unlink(self.path)
        self.size_bytes = 0
