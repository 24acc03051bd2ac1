"""The measurement files of a run: every frame's :class:`~rovslam.slam.measurements.FrameMeasurements`.

Written as the run goes, so that ``rovslam smooth OUT`` can rebuild the whole problem of any
run (EKF runs included) without the images:

``OUT/measurements.csv``           one row per frame (``MEASUREMENT_COLUMNS``)
``OUT/landmark_measurements.csv``  one row per landmark observation (``LANDMARK_MEASUREMENT_COLUMNS``),
                                   keyed by ``frame``

Numbers are written as Python's shortest exact representation (``repr``), so a record read
back equals the one written, bit for bit; NaN is ``nan`` (an empty cell also reads as NaN);
booleans are ``0`` / ``1``. ``observations`` in measurements.csv counts the frame's rows in
landmark_measurements.csv. A frame's observations are written before its row and the
observation file is flushed first, so an interrupted run leaves, at worst, a torn last line
or observations of frames whose row never reached the disk: the reader drops those (the
tail of an interrupted run) and rejects anything else that does not add up with a
:class:`~rovslam.errors.ResultsFormatError` naming the file, the line and the column.
"""

from __future__ import annotations

import contextlib
import csv
import math
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from rovslam.errors import InvalidMeasurementError, ResultsFormatError, SequenceFormatError
from rovslam.io.output import StreamFile
from rovslam.io.text import read_text
from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement

__all__ = [
    "MEASUREMENTS_FILE",
    "LANDMARK_MEASUREMENTS_FILE",
    "MEASUREMENT_COLUMNS",
    "LANDMARK_MEASUREMENT_COLUMNS",
    "MeasurementWriter",
    "read_measurements",
    "write_measurements",
    "has_measurements",
]

MEASUREMENTS_FILE = "measurements.csv"
LANDMARK_MEASUREMENTS_FILE = "landmark_measurements.csv"

MEASUREMENT_COLUMNS = (
    "frame",
    "t_s",
    "dt_s",
    "surge_mps",
    "sway_mps",
    "var_surge_mps2",
    "cov_surge_sway_mps2",
    "var_sway_mps2",
    "speed_ok",
    "heading_rad",
    "heading_sigma_rad",
    "compass_rad",
    "compass_sigma_rad",
    "heading_step_rad",
    "heading_step_sigma_rad",
    "altitude_m",
    "altitude_sigma_m",
    "focal_px",
    "observations",
    "attitude_sigma_rad",
)
# Columns a run by an earlier rovslam did not write, and the value read in their place.
_OPTIONAL_COLUMNS = {"attitude_sigma_rad": 0.0}
LANDMARK_MEASUREMENT_COLUMNS = (
    "frame",
    "landmark_id",
    "kind",
    "m_px",
    "n_px",
    "var_m_px2",
    "cov_mn_px2",
    "var_n_px2",
    "accepted_by_online",
)

_NO_MEASUREMENTS_HINT = (
    "this run was made by a rovslam version that does not write measurements; "
    "run the sequence again with this version (rovslam run SEQ --out OUT)"
)


def _num(v: float) -> str:
    return repr(float(v))


class MeasurementWriter:
    """Appends each frame's measurements to ``out_dir`` as the run goes.

    Args:
        out_dir: the run's output folder (created if missing).
        flush_every: frames between flushes (and at :meth:`close`).
    """

    def __init__(self, out_dir: str | Path, flush_every: int = 50):
        self.out = Path(out_dir)
        if self.out.exists() and not self.out.is_dir():
            raise SequenceFormatError(f"{self.out}: exists and is not a folder; choose another --out.")
        self.out.mkdir(parents=True, exist_ok=True)
        self._obs_fh = StreamFile(self.out / LANDMARK_MEASUREMENTS_FILE, exclusive=False)  # whole rows only
        self._obs = csv.writer(self._obs_fh, lineterminator="\n")
        self._obs.writerow(LANDMARK_MEASUREMENT_COLUMNS)
        self._frames_fh = StreamFile(self.out / MEASUREMENTS_FILE, exclusive=False)
        self._frames = csv.writer(self._frames_fh, lineterminator="\n")
        self._frames.writerow(MEASUREMENT_COLUMNS)
        self.flush_every = max(1, int(flush_every))
        self._n = 0
        self.flush()

    def write(self, meas: FrameMeasurements) -> None:
        """Append one frame: its observations first, then its row."""
        if not isinstance(meas, FrameMeasurements):
            raise InvalidMeasurementError(
                f"MeasurementWriter.write takes a FrameMeasurements, got {type(meas).__name__}"
            )
        for ob in meas.landmarks:
            r = ob.noise_px2
            self._obs.writerow(
                [
                    meas.index,
                    ob.landmark_id,
                    ob.kind,
                    _num(ob.mn_px[0]),
                    _num(ob.mn_px[1]),
                    _num(r[0, 0]),
                    _num(r[0, 1]),
                    _num(r[1, 1]),
                    int(ob.accepted_by_online),
                ]
            )
        q = meas.speed_cov_mps2
        self._frames.writerow(
            [
                meas.index,
                _num(meas.t_s),
                _num(meas.dt_s),
                _num(meas.speed_mps[0]),
                _num(meas.speed_mps[1]),
                _num(q[0, 0]),
                _num(q[0, 1]),
                _num(q[1, 1]),
                int(meas.speed_ok),
                _num(meas.heading_rad),
                _num(meas.heading_sigma_rad),
                _num(meas.compass_rad),
                _num(meas.compass_sigma_rad),
                _num(meas.heading_step_rad),
                _num(meas.heading_step_sigma_rad),
                _num(meas.altitude_m),
                _num(meas.altitude_sigma_m),
                _num(meas.focal_px),
                len(meas.landmarks),
                _num(meas.attitude_sigma_rad),
            ]
        )
        self._n += 1
        if self._n % self.flush_every == 0:
            self.flush()

    def flush(self) -> None:
        """Observations first: a frame row on disk always has its observations before it."""
        from rovslam.io.results import output_errors

        with output_errors(self.out / LANDMARK_MEASUREMENTS_FILE):
            self._obs_fh.flush()
        with output_errors(self.out / MEASUREMENTS_FILE):
            self._frames_fh.flush()

    def close(self) -> None:
        """Flush and close both files (closed even when the flush fails: the error names the file)."""
        if not self._frames_fh.closed:
            try:
                self.flush()
            finally:
                for fh in (self._obs_fh, self._frames_fh):
                    with contextlib.suppress(OSError, ValueError):
                        fh.close(quiet=True)

    def __enter__(self) -> MeasurementWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def has_measurements(out_dir: str | Path) -> bool:
    """Whether ``out_dir`` holds the measurement files of a run."""
    out = Path(out_dir)
    return (out / MEASUREMENTS_FILE).is_file() and (out / LANDMARK_MEASUREMENTS_FILE).is_file()


class _Table:
    """Rows of one CSV file with its header checked; cells read with file / line / column in errors."""

    def __init__(self, path: Path, columns: tuple[str, ...], optional: dict[str, float] | None = None):
        self.path = path
        if not path.is_file():
            if not any((path.parent / n).is_file() for n in ("trajectory.csv", "summary.json")):
                raise ResultsFormatError(
                    f"{path.parent}: not the --out folder of a `rovslam run` (no trajectory.csv, no summary.json); give a run's folder."
                )
            raise ResultsFormatError(f"{path}: missing; {_NO_MEASUREMENTS_HINT}.")
        text = read_text(path, ResultsFormatError)  # not UTF-8 (a damaged file): one line naming it
        self.torn = bool(text) and not text.endswith("\n")  # an interrupted write
        reader = csv.reader(text.splitlines())
        try:
            header = next(reader, None)
            if header is None:
                raise ResultsFormatError(
                    f"{path}: empty file (no header line): it was cut short (the run killed at its start, or a full "
                    "disk); run the sequence again (rovslam run SEQ --out OUT --overwrite)."
                )
            self.absent = {c: v for c, v in (optional or {}).items() if c not in header}
            missing = [c for c in columns if c not in header and c not in self.absent]
            if missing:
                raise ResultsFormatError(
                    f"{path}, line 1: missing column(s) {', '.join(missing)}; expected the header {','.join(columns)}"
                )
            self.col = {c: header.index(c) for c in columns if c not in self.absent}
            self.width = len(header)
            self.rows = [(i + 2, r) for i, r in enumerate(reader)]  # (line number, cells)
        except csv.Error as exc:  # e.g. a field beyond the csv module's size limit
            raise ResultsFormatError(
                f"{path}, line {reader.line_num}: not a readable CSV line ({exc}); the file is damaged: "
                "re-run the sequence to write it again"
            ) from None
        if self.torn and self.rows:
            self.rows.pop()  # rows end with a newline: this is the torn last line of an interrupted run

    def where(self, line: int, column: str | None = None) -> str:
        return f"{self.path}, line {line}" + (f", column {column}" if column else "")

    def check_width(self, line: int, cells: list[str]) -> None:
        if len(cells) != self.width:
            raise ResultsFormatError(
                f"{self.where(line)}: {len(cells)} fields, the header has {self.width}; "
                "the file is damaged: re-run the sequence to write it again"
            )

    def number(self, line: int, cells: list[str], column: str) -> float:
        if column in self.absent:
            return self.absent[column]
        cell = cells[self.col[column]].strip()
        if cell == "":
            return math.nan
        try:
            return float(cell)
        except ValueError:
            raise ResultsFormatError(f"{self.where(line, column)}: {cell!r} is not a number") from None

    def integer(self, line: int, cells: list[str], column: str) -> int:
        cell = cells[self.col[column]].strip()
        try:
            v = int(cell)
        except ValueError:
            raise ResultsFormatError(f"{self.where(line, column)}: {cell!r} is not an integer") from None
        if v < 0:
            raise ResultsFormatError(f"{self.where(line, column)}: {v} must be >= 0")
        return v

    def flag(self, line: int, cells: list[str], column: str) -> bool:
        cell = cells[self.col[column]].strip()
        if cell not in ("0", "1"):
            raise ResultsFormatError(f"{self.where(line, column)}: {cell!r} must be 0 or 1")
        return cell == "1"

    def text(self, line: int, cells: list[str], column: str) -> str:
        return cells[self.col[column]].strip()


def _read_observations(table: _Table) -> dict[int, list[tuple[int, LandmarkMeasurement]]]:
    by_frame: dict[int, list[tuple[int, LandmarkMeasurement]]] = {}
    last = -1
    for line, cells in table.rows:
        table.check_width(line, cells)
        frame = table.integer(line, cells, "frame")
        if frame < last:
            raise ResultsFormatError(
                f"{table.where(line, 'frame')}: frame {frame} after frame {last}; rows must be in frame order"
            )
        last = frame
        f = {c: table.number(line, cells, c) for c in ("m_px", "n_px", "var_m_px2", "cov_mn_px2", "var_n_px2")}
        try:
            ob = LandmarkMeasurement(
                landmark_id=table.integer(line, cells, "landmark_id"),
                kind=table.text(line, cells, "kind"),
                mn_px=np.array([f["m_px"], f["n_px"]]),
                noise_px2=np.array([[f["var_m_px2"], f["cov_mn_px2"]], [f["cov_mn_px2"], f["var_n_px2"]]]),
                accepted_by_online=table.flag(line, cells, "accepted_by_online"),
            )
        except InvalidMeasurementError as exc:
            raise ResultsFormatError(f"{table.where(line)}: {exc}") from None
        by_frame.setdefault(frame, []).append((line, ob))
    return by_frame


def _frame_from_row(
    table: _Table, line: int, cells: list[str], obs: tuple[LandmarkMeasurement, ...]
) -> FrameMeasurements:
    v = {c: table.number(line, cells, c) for c in MEASUREMENT_COLUMNS if c not in ("frame", "speed_ok", "observations")}
    q = np.array([[v["var_surge_mps2"], v["cov_surge_sway_mps2"]], [v["cov_surge_sway_mps2"], v["var_sway_mps2"]]])
    try:
        return FrameMeasurements(
            index=table.integer(line, cells, "frame"),
            t_s=v["t_s"],
            dt_s=v["dt_s"],
            speed_mps=np.array([v["surge_mps"], v["sway_mps"]]),
            speed_cov_mps2=q,
            speed_ok=table.flag(line, cells, "speed_ok"),
            heading_rad=v["heading_rad"],
            heading_sigma_rad=v["heading_sigma_rad"],
            compass_rad=v["compass_rad"],
            compass_sigma_rad=v["compass_sigma_rad"],
            heading_step_rad=v["heading_step_rad"],
            heading_step_sigma_rad=v["heading_step_sigma_rad"],
            altitude_m=v["altitude_m"],
            altitude_sigma_m=v["altitude_sigma_m"],
            focal_px=v["focal_px"],
            landmarks=obs,
            attitude_sigma_rad=v["attitude_sigma_rad"],
        )
    except InvalidMeasurementError as exc:
        raise ResultsFormatError(f"{table.where(line)}: {exc}") from None


def read_measurements(out_dir: str | Path) -> list[FrameMeasurements]:
    """Read the measurement files of a run (complete or interrupted), in frame order.

    Raises:
        ResultsFormatError: a file is missing (a run by an older rovslam), a column is
            missing, a cell is not a number, a value is out of range, frames are out of order,
            or the observation counts do not add up (other than at the tail of an interrupted run).
    """
    out = Path(out_dir)
    if not out.is_dir():
        raise ResultsFormatError(f"{out}: not a folder. Give the --out folder of a `rovslam run`.")
    frames_table = _Table(out / MEASUREMENTS_FILE, MEASUREMENT_COLUMNS, _OPTIONAL_COLUMNS)
    obs_table = _Table(out / LANDMARK_MEASUREMENTS_FILE, LANDMARK_MEASUREMENT_COLUMNS)
    by_frame = _read_observations(obs_table)
    last_obs_frame = max(by_frame, default=-1)
    frames: list[FrameMeasurements] = []
    previous = -1
    for line, cells in frames_table.rows:
        frames_table.check_width(line, cells)
        index = frames_table.integer(line, cells, "frame")
        if index <= previous:
            raise ResultsFormatError(
                f"{frames_table.where(line, 'frame')}: frame {index} after frame {previous}; "
                "frames must be in increasing order"
            )
        previous = index
        expected = frames_table.integer(line, cells, "observations")
        found = by_frame.pop(index, [])
        if len(found) != expected:
            if index >= last_obs_frame and len(found) < expected:
                break  # an interrupted run: this frame's observations never reached the disk
            raise ResultsFormatError(
                f"{frames_table.where(line, 'observations')}: frame {index} has {expected} observation(s) but "
                f"{obs_table.path.name} holds {len(found)}; the two files do not belong together"
            )
        frames.append(_frame_from_row(frames_table, line, cells, tuple(ob for _, ob in found)))
    last_frame = frames[-1].index if frames else -1
    for frame, rows in by_frame.items():
        if frame <= last_frame:  # observations of frames that are not there
            raise ResultsFormatError(
                f"{obs_table.where(rows[0][0], 'frame')}: frame {frame} is not in {frames_table.path.name}; "
                "the two files do not belong together"
            )
    return frames


def write_measurements(out_dir: str | Path, frames: Iterable[FrameMeasurements]) -> None:
    """Write a whole list of frames at once (a convenience over :class:`MeasurementWriter`)."""
    with MeasurementWriter(out_dir) as writer:
        for meas in frames:
            writer.write(meas)
