"""The text files every input reads: UTF-8 text, CSV tables with a checked header, numbers and
times in their cells, and paths that must stay inside a folder.

Each function raises the typed error it is given (:class:`~rovslam.errors.SequenceFormatError`
by default), naming the file, line and column, so every reader of a text input (sequence folders,
navigation logs, points of interest, results) says what is wrong the same way.
"""

from __future__ import annotations

import csv
import io
import math
import os
import stat
from pathlib import Path

from rovslam.errors import RovslamError, SequenceFormatError

__all__ = [
    "MAX_TEXT_BYTES",
    "MAX_TIME_S",
    "float_cell",
    "inside_folder",
    "is_number",
    "not_a_file",
    "read_csv_table",
    "read_text",
    "time_cell",
]

MAX_TEXT_BYTES = 512 * 2**20  # a frames.csv of a million frames is ~80 MB


def read_text(path: Path, error: type[RovslamError] = SequenceFormatError) -> str:
    """The text of a UTF-8 file (a UTF-8 byte-order mark is accepted), or ``error`` naming the line.

    A file that is not UTF-8 (Latin-1, UTF-16 from a spreadsheet, binary) is refused with the
    line and byte offset of the first bad byte: guessing an encoding could misread numbers.
    """
    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):  # a pipe would block the read for ever, a device never end
            raise error(f"{path}: {not_a_file(path)}.")
        size = st.st_size
        if size > MAX_TEXT_BYTES:
            raise error(
                f"{path}: {size} bytes, more than the {MAX_TEXT_BYTES // 2**20} MiB a text file of rovslam may hold."
            )
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc}).") from None
    bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
    try:
        return data[bom:].decode("utf-8")
    except UnicodeDecodeError as exc:
        if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
            raise error(f"{path}: UTF-16 text; rovslam reads UTF-8. Save the file as UTF-8 (CSV UTF-8).") from None
        at = bom + exc.start
        line = data.count(b"\n", 0, at) + 1
        raise error(
            f"{path}, line {line}: not UTF-8 text (byte 0x{data[at]:02x} at offset {at}). Save the file as UTF-8."
        ) from None


def read_csv_table(
    path: Path,
    required: tuple[str, ...],
    error: type[RovslamError] = SequenceFormatError,
    *,
    drop_torn_last_line: bool = False,
) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """Read a UTF-8 CSV whose header holds ``required``: (header, [(line number, row dict)]).

    Every row must have as many fields as the header; blank lines are ignored. With
    ``drop_torn_last_line`` a last line without its newline (a write cut short) is dropped.
    Raises ``error`` naming the file and line.
    """
    if not path.is_file():
        raise error(f"{path}: {not_a_file(path)}.")
    text = read_text(path, error)
    if drop_torn_last_line and text and not text.endswith("\n") and "\n" in text:
        text = text[: text.rindex("\n") + 1]
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = [h.strip() for h in next(reader, [])]
        if not any(header):
            raise error(f"{path}: empty file; the first line must be the header {','.join(required)}.")
        if not set(required) & set(header) and is_number(header[0]):
            raise error(
                f"{path}, line 1: holds values ({','.join(header)[:60]}), not the header; "
                f"add the header line {','.join(required)} above the first row."
            )
        dup = sorted({h for h in header if header.count(h) > 1})
        if dup:
            raise error(f"{path}: header names column(s) {', '.join(dup)} more than once.")
        missing = [c for c in required if c not in header]
        if missing:
            read = ",".join(header)
            sep = next(
                (f" It is separated by {n}: use commas." for c, n in ((";", "';'"), ("\t", "tabs")) if c in read), ""
            )
            case = (
                " Column names are lower case." if not sep and any(c.lower() in read.lower() for c in missing) else ""
            )
            raise error(
                f"{path}: header is missing column(s) {', '.join(missing)}. "
                f"The header must start with: {','.join(required)}; it reads {read[:80]!r}.{sep}{case}"
            )
        rows = []
        for fields in reader:
            if not fields or (len(fields) == 1 and not fields[0].strip()):
                continue
            if len(fields) != len(header):
                raise error(
                    f"{path}, line {reader.line_num}: {len(fields)} fields, the header has {len(header)}; "
                    "every row needs one value per column (empty for a missing optional value)."
                )
            rows.append((reader.line_num, dict(zip(header, fields, strict=True))))
    except csv.Error as exc:
        raise error(f"{path}, line {reader.line_num}: not a readable CSV line ({exc}).") from None
    return header, rows


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def not_a_file(path: Path) -> str:
    """Why ``path`` (which is not a regular file) cannot be read: missing, a folder, or a special file."""
    if path.is_dir():
        return "is a folder, not a file"
    if path.exists():
        return "is not a regular file (a pipe, socket or device)"
    return "missing"


def float_cell(
    row: dict[str, str],
    key: str,
    where: str,
    *,
    optional: bool = False,
    allow_nan: bool = False,
    error: type[RovslamError] = SequenceFormatError,
) -> float | None:
    """The number in column ``key`` of a CSV row; empty gives None when ``optional``, NaN only when ``allow_nan``."""
    text = (row.get(key) or "").strip()
    if text == "":
        if optional:
            return None
        raise error(f"{where}: column '{key}' is empty; it needs a number.")
    try:
        v = float(text)
    except ValueError:
        raise error(f"{where}: column '{key}' is not a number: {text!r}.") from None
    if math.isnan(v) and allow_nan:
        return v
    if not math.isfinite(v):
        raise error(f"{where}: column '{key}' is not finite: {text!r}.")
    return v


MAX_TIME_S = 1e12  # |t_s| above this is no clock's (31,700 years; UNIX times are 1.7e9): its steps would overflow


def time_cell(row: dict[str, str], where: str, key: str = "t_s") -> float:
    """The time in column ``key`` (seconds): a finite number of at most :data:`MAX_TIME_S` in size."""
    t = float(float_cell(row, key, where))  # type: ignore[arg-type]
    if abs(t) > MAX_TIME_S:
        raise SequenceFormatError(
            f"{where}: column '{key}' = {t:g} s is no clock's time (more than {MAX_TIME_S:g} s "
            "from 0); give times in seconds (UNIX times or from the start of the dive)."
        )
    return t


def inside_folder(root: Path, relative: str, where: str) -> Path:
    """``root / relative`` with every link resolved, or SequenceFormatError when it is not inside ``root``.

    ``root`` must already be resolved (``os.path.realpath``). Absolute paths, ``..`` that climbs
    out and symbolic links to elsewhere are all refused; nothing is opened.
    """
    if "\x00" in relative:
        raise SequenceFormatError(f"{where}: path {relative!r} holds a NUL character.")
    if os.path.isabs(relative) or relative.startswith(("/", "\\")) or (len(relative) > 1 and relative[1] == ":"):
        raise SequenceFormatError(
            f"{where}: path '{relative}' is absolute; image paths must be relative to the sequence folder "
            f"({root}) and stay inside it."
        )
    resolved = Path(os.path.realpath(root / relative))
    if not resolved.is_relative_to(root):
        raise SequenceFormatError(
            f"{where}: path '{relative}' leads outside the sequence folder {root} (to {resolved}); "
            "keep every file of a sequence inside its folder (copy it in rather than linking it)."
        )
    return resolved
