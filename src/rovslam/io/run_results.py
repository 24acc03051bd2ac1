"""The result files of a run (:mod:`rovslam.io.results` lists them) read back, validated.

:func:`read_results` reads a ``rovslam run --out`` folder, complete or interrupted (a last line
cut short by a crash is dropped), into a :class:`RunResults`; it raises
:class:`~rovslam.errors.ResultsFormatError` naming the file, line and column of what is wrong.
:func:`read_summary` reads ``summary.json`` alone, :func:`failure_of_run` says why a run failed.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import ResultsFormatError
from rovslam.io.results import (
    LANDMARK_COLUMNS,
    OBSERVATION_COLUMNS,
    SMOOTHED_TRAJECTORY_COLUMNS,
    TRAJECTORY_COLUMNS,
)
from rovslam.io.source import TOKENS_ONLY
from rovslam.io.text import float_cell, not_a_file, read_csv_table, read_text


@dataclass(frozen=True)
class RunResults:
    """The result files of a run, read back as arrays (columns of trajectory.csv by name)."""

    folder: Path
    trajectory: dict[str, np.ndarray]
    observations: dict[str, np.ndarray]
    landmarks: dict[str, np.ndarray]
    summary: dict[str, Any]
    smoothed: dict[str, np.ndarray] | None = None  # trajectory_smoothed.csv, when the run was smoothed

    @property
    def t_s(self) -> np.ndarray:
        return self.trajectory["t_s"]

    @property
    def smoothed_xy_m(self) -> np.ndarray | None:
        """(N, 2) the smoothed positions, or None."""
        s = self.smoothed
        return None if s is None else np.column_stack([s["x_m"], s["y_m"]])

    @property
    def smoothed_cov_m2(self) -> np.ndarray | None:
        """(N, 2, 2) the smoothed marginal position covariances, or None."""
        return None if self.smoothed is None else _cov_table(self.smoothed)

    @property
    def xy_m(self) -> np.ndarray:
        return np.column_stack([self.trajectory["x_m"], self.trajectory["y_m"]])

    @property
    def without_compass(self) -> bool:
        """Whether no frame had a compass: the run's frame is then its first heading, not north."""
        heading = (self.summary.get("sources") or {}).get("heading") or {}
        frames = heading.get("frames") if isinstance(heading, dict) else None
        return isinstance(frames, dict) and set(frames) == {TOKENS_ONLY}

    @property
    def cov_m2(self) -> np.ndarray:
        """(N, 2, 2) position covariances."""
        return _cov_table(self.trajectory)

    @property
    def speed_cov_mps2(self) -> np.ndarray | None:
        """(N, 2, 2) covariances Q of the measured (surge, sway); None when trajectory.csv has no such columns."""
        names = ("var_surge_mps2", "cov_surge_sway_mps2", "var_sway_mps2")
        # numbers only: an optional column holding text (a damaged file) is read as absent
        t = self.trajectory
        return _cov_table(t, names) if all(n in t and t[n].dtype.kind == "f" for n in names) else None

    @property
    def dr_xy_m(self) -> np.ndarray:
        return np.column_stack([self.trajectory["dr_x_m"], self.trajectory["dr_y_m"]])


def _cov_table(
    t: dict[str, np.ndarray], names: tuple[str, str, str] = ("var_x_m2", "cov_xy_m2", "var_y_m2")
) -> np.ndarray:
    """(N, 2, 2) covariances from the ``(var_a, cov_ab, var_b)`` columns ``names`` of a table."""
    var_a, cov_ab, var_b = (t[n] for n in names)
    c = np.empty((len(t["t_s"]), 2, 2))
    c[:, 0, 0], c[:, 0, 1], c[:, 1, 0], c[:, 1, 1] = var_a, cov_ab, cov_ab, var_b
    return c


# Columns that must hold finite numbers (the others may be nan, e.g. altitude_sigma_m of a skipped frame).
_FINITE = {
    "trajectory.csv": ("t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "dr_x_m", "dr_y_m"),
    "observations.csv": ("t_s", "frame", "landmark_id"),
    "landmarks.csv": ("id", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2"),
    "trajectory_smoothed.csv": ("t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2"),
}


def _read_table(
    path: Path, required: tuple[str, ...], text_columns: tuple[str, ...] = ()
) -> tuple[dict[str, np.ndarray], list[int]]:
    """A results CSV as columns: required ones validated (numbers, finite where needed), others lenient.

    Returns the columns and the line number of each row.
    """
    if not path.is_file():
        raise ResultsFormatError(f"{path}: {not_a_file(path)}. Is this the --out folder of a `rovslam run`?")
    header, rows = read_csv_table(path, required, ResultsFormatError, drop_torn_last_line=True)
    finite = _FINITE.get(path.name, ())
    out: dict[str, np.ndarray] = {}
    for name in header:
        if name in text_columns:
            out[name] = np.asarray([row[name] for _, row in rows], dtype=object)
        elif name in required:
            out[name] = np.asarray(
                [
                    math.nan if v is None else v
                    for v in (
                        float_cell(
                            row,
                            name,
                            f"{path}, line {line}",
                            optional=name not in finite,
                            allow_nan=name not in finite,
                            error=ResultsFormatError,
                        )
                        for line, row in rows
                    )
                ],
                dtype=np.float64,
            )
        else:  # a column added by a newer rovslam: numbers if they all are, else text
            col = [row[name] for _, row in rows]
            try:
                out[name] = np.asarray([float(v) if v.strip() != "" else math.nan for v in col], dtype=np.float64)
            except ValueError:
                out[name] = np.asarray(col, dtype=object)
    return out, [line for line, _ in rows]


def _check_time(path: Path, table: dict[str, np.ndarray], lines: list[int], strict: bool) -> None:
    t = table["t_s"]
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0 if strict else step < 0)
    if len(bad):
        k = int(bad[0]) + 1
        raise ResultsFormatError(
            f"{path}, line {lines[k]}: t_s={t[k]} is not after the row before it (t_s={t[k - 1]}); "
            "the file was edited or two runs were mixed."
        )


def read_summary(path: Path) -> dict[str, Any]:
    """``summary.json`` as a dict ({} when absent), or ResultsFormatError naming the problem."""
    if not path.is_file():
        return {}
    try:
        summary = json.loads(read_text(path, ResultsFormatError))
    except json.JSONDecodeError as exc:
        raise ResultsFormatError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); "
            "it was cut short or edited. Run again with --overwrite to rewrite it."
        ) from None
    except RecursionError:  # arrays or objects nested thousands deep: not a file rovslam wrote
        raise ResultsFormatError(
            f"{path}: JSON nested too deep to read; it is not the summary rovslam writes. "
            "Run again with --overwrite to rewrite it."
        ) from None
    if not isinstance(summary, dict):
        raise ResultsFormatError(f"{path}: must hold a JSON object, got {type(summary).__name__}.")
    for key, kind in _SUMMARY_TYPES.items():
        value = summary.get(key)
        if value is not None and not isinstance(value, kind):
            what = "a JSON object" if kind is dict else "a string"
            raise ResultsFormatError(
                f"{path}: key '{key}' must be {what} or null, got {json.dumps(value)[:60]}; the file was edited. "
                "Run again with --overwrite to rewrite it."
            )
    return summary


def check_sequence_of_run(results_dir: Path, seq: Path, option: str) -> None:
    """SequenceFormatError when the sequence folder ``seq`` (given with ``option``) is clearly not the one the
    run read: another name or frame count than its summary.json records. A video, or a summary without them, passes."""
    from rovslam.errors import SequenceFormatError
    from rovslam.io.sequence import open_sequence

    summary = read_summary(Path(results_dir) / "summary.json")
    if not (Path(seq) / "sequence.toml").is_file():
        return
    s = open_sequence(seq, check_images=False)
    name, frames = summary.get("sequence_name"), summary.get("frames_in_sequence")
    differ = []
    if isinstance(name, str) and name != s.info.name:
        differ.append(f"it is named {s.info.name!r}, the run's sequence {name!r}")
    if isinstance(frames, int) and frames != len(s):
        differ.append(f"it has {len(s)} frames, the run's sequence {frames}")
    if differ:
        raise SequenceFormatError(
            f"{option} {seq}: not the sequence of the run in {results_dir} ({'; '.join(differ)}; summary.json names "
            f"{summary.get('sequence')}); give that run's own sequence folder."
        )


# The keys of summary.json that eval, report and mosaic read, and their JSON types (null allowed).
_SUMMARY_TYPES: dict[str, type] = {
    "software": dict,
    "source": dict,
    "sources": dict,
    "map_use": dict,
    "config": dict,
    "inputs": dict,
    "sequence": str,
    "camera_file": str,
    "sequence_name": str,
    "heading_source": str,
    "altitude_source": str,
}


def read_results(out_dir: str | Path) -> RunResults:
    """Read the files of a ``rovslam run --out`` folder (complete or interrupted), validated.

    Raises :class:`ResultsFormatError` naming the file, line and column of a missing file,
    missing column, text where a number belongs, time going backwards or an empty trajectory.
    """
    out = Path(out_dir)
    if not out.is_dir():
        raise ResultsFormatError(f"{out}: not a folder. Give the --out folder of a `rovslam run`.")
    traj_path = out / "trajectory.csv"
    traj, lines = _read_table(traj_path, TRAJECTORY_COLUMNS, ("altitude_source", "speed_source"))
    if len(traj["t_s"]) == 0:
        failed = failure_of_run(read_summary(out / "summary.json"))
        raise ResultsFormatError(
            f"{traj_path}: no rows (only a header): the run wrote no frame"
            + (f"; it failed: {failed}" if failed else ".")
        )
    _check_time(traj_path, traj, lines, strict=True)
    obs: dict[str, np.ndarray] = {}
    obs_path = out / "observations.csv"
    if obs_path.is_file():
        obs, lines = _read_table(obs_path, OBSERVATION_COLUMNS, ("kind", "reason"))
        _check_time(obs_path, obs, lines, strict=False)
    lm_path = out / "landmarks.csv"
    lms = _read_table(lm_path, LANDMARK_COLUMNS)[0] if lm_path.is_file() else {}
    summary = read_summary(out / "summary.json")
    _check_against_summary(out, len(traj["t_s"]), lm_path.is_file(), summary)
    smoothed = None
    sm_path = out / "trajectory_smoothed.csv"
    if sm_path.is_file():
        smoothed, lines = _read_table(sm_path, SMOOTHED_TRAJECTORY_COLUMNS)
        _check_time(sm_path, smoothed, lines, strict=True)
    return RunResults(out, traj, obs, lms, summary, smoothed)


def failure_of_run(summary: dict[str, Any]) -> str | None:
    """Why a run failed, as its summary.json says (``"status": "failed"``), or None (not failed, or no reason given)."""
    if summary.get("status") != "failed":
        return None
    reason = summary.get("reason")
    return " ".join(reason.split()).rstrip(".") if isinstance(reason, str) and reason.strip() else "no reason recorded"


# Statuses whose files were all closed complete: trajectory.csv holds a row for every frame processed.
_CLOSED_STATUSES = ("complete", "interrupted", "unusable")


def _check_against_summary(out: Path, rows: int, has_landmarks_file: bool, summary: dict[str, Any]) -> None:
    """ResultsFormatError when trajectory.csv is shorter, or landmarks.csv missing, against what summary.json says."""
    status, processed, landmarks = summary.get("status"), summary.get("frames_processed"), summary.get("landmarks")
    rerun = "run `rovslam run` again with --overwrite to rewrite the results"
    if status in _CLOSED_STATUSES and isinstance(processed, int) and rows < processed:
        raise ResultsFormatError(
            f"{out / 'trajectory.csv'}: {rows} rows, but summary.json says the run ({status}) processed {processed} "
            f"frames; the file was cut short (copied while written, or edited). Copy it again, or {rerun}."
        )
    # A failed run (a full disk) may not have written landmarks.csv: it is then read as no map.
    if status != "failed" and not has_landmarks_file and isinstance(landmarks, int) and landmarks > 0:
        raise ResultsFormatError(
            f"{out / 'landmarks.csv'}: missing, but summary.json says the run mapped {landmarks} landmarks; "
            f"copy the file back, or {rerun}."
        )
