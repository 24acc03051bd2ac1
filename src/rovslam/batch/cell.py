"""One cell of the matrix, as a Dask task: simulate -> run -> eval -> baselines, in ``DIR/cells/<cell>/``.

A cell is done when ``result.json`` exists; it is written last and atomically, so a cell
interrupted half-way is started again from scratch on the next ``rovslam batch``. A failing
cell returns a row with ``status = "failed"`` and leaves its error in ``error.log``: for bad input (a
:class:`~rovslam.errors.RovslamError`: a sequence with no ground truth, a full disk) the one line
the table shows; for anything else (a bug) the traceback.

Folder of a cell::

    cells/<cell>/sequence/     the simulated dive (deleted after the cell unless --keep-sequences)
    cells/<cell>/run/          the `rovslam run` outputs, with eval.json
    cells/<cell>/result.json   {"row": the matrix.csv row, "evaluation": eval.json's figures}
    cells/<cell>/error.log     the error of a failed cell (one line; a traceback only for a bug)
"""

from __future__ import annotations

import json
import shutil
import time
import traceback
from pathlib import Path
from typing import Any

from rovslam.batch.matrix import CellSpec
from rovslam.errors import RovslamError, SequenceFormatError
from rovslam.io.output import atomic_write_text

RESULT_FILE = "result.json"
ERROR_FILE = "error.log"


def read_result(cell_dir: Path) -> dict[str, Any] | None:
    """The matrix row of a finished cell, or None when the cell is not done (or its file is unreadable)."""
    path = cell_dir / RESULT_FILE
    try:
        return json.loads(path.read_text(encoding="utf-8"))["row"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def run_cell(
    spec: CellSpec, cells_dir: str, keep_sequence: bool = False, opencv_threads: int | None = 1
) -> dict[str, Any]:
    """Run one cell and return its matrix row (``status`` ``ok`` or ``failed``). Never raises for a bad cell.

    ``opencv_threads``: OpenCV's thread count inside this worker (1: one core per worker, as
    the local cluster is sized); None leaves it alone.
    """
    cell_dir = Path(cells_dir) / spec.cell_id
    done = read_result(cell_dir)
    if done is not None:
        return done
    if opencv_threads is not None:
        import cv2

        cv2.setNumThreads(opencv_threads)
    t0 = time.perf_counter()
    try:
        if cell_dir.exists():
            shutil.rmtree(cell_dir)  # an interrupted attempt: start clean
        cell_dir.mkdir(parents=True)
        row = _run(spec, cell_dir, keep_sequence)
    except Exception as exc:  # a cell never takes the others down: its error goes to the table
        row = failed_row(spec, exc, time.perf_counter() - t0)
        # Bad input is its one line, as the table and `rovslam run` say it; only a bug gets a traceback.
        log = f"{row['error']}\n" if isinstance(exc, RovslamError) else traceback.format_exc()
        try:
            cell_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(cell_dir / ERROR_FILE, log, "the cell's error.log")
        except (OSError, RovslamError):  # the disk that failed the cell may not take its log either
            pass
        return row
    return row


def failed_row(spec: CellSpec, exc: BaseException, wall_s: float = float("nan")) -> dict[str, Any]:
    """The matrix row of a cell that raised ``exc`` (its message on one line)."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    return {
        **_spec_columns(spec),
        "status": "failed",
        "error": f"{type(exc).__name__}: {message}",
        "wall_s": wall_s,
        "failure": "input" if isinstance(exc, RovslamError) else "internal",
    }


def pending_row(spec: CellSpec) -> dict[str, Any]:
    """The matrix row of a cell not run yet (an interrupted batch)."""
    return {**_spec_columns(spec), "status": "pending", "error": ""}


def _spec_columns(spec: CellSpec) -> dict[str, Any]:
    return {
        "cell": spec.cell_id,
        "group": spec.group,
        "scenario": spec.scenario or "",
        "seed": spec.seed,
        "config": spec.config_path or "",
    }


def _run(spec: CellSpec, cell_dir: Path, keep_sequence: bool) -> dict[str, Any]:
    from rovslam.eval import evaluate_run
    from rovslam.runner import run_sequence

    t0, c0 = time.perf_counter(), time.process_time()
    if spec.simulated:
        from rovslam.sim import CalibrationErrors, simulate

        seq = cell_dir / "sequence"
        simulate(
            spec.scenario,  # type: ignore[arg-type]
            seq,
            frames=spec.frames,
            seed=spec.seed,  # type: ignore[arg-type]
            image_format=spec.image_format,
            calibration=CalibrationErrors() if spec.calibration_errors else None,
            relief_scale=spec.relief_scale,
        )
        groundtruth = seq / "groundtruth.csv"
        max_frames = None
    else:
        seq, groundtruth, max_frames = Path(spec.sequence_path), Path(spec.groundtruth_path), spec.frames  # type: ignore[arg-type]
        if not seq.exists():
            raise SequenceFormatError(f"{seq}: sequence not found (a [[sequence]] path is relative to the matrix file)")
        if not groundtruth.is_file():
            raise SequenceFormatError(
                f"{groundtruth}: ground truth not found; a matrix cell needs one (key groundtruth)"
            )
    t1, c1 = time.perf_counter(), time.process_time()
    run_dir = cell_dir / "run"
    # No read-ahead thread: the matrix's workers fill the cores, and its frames/s stay one core's.
    summary = run_sequence(seq, run_dir, spec.config, max_frames=max_frames, read_ahead=False)
    if summary.interrupted:
        raise RuntimeError(f"the run was interrupted after {summary.frames} frames")
    t2, c2 = time.perf_counter(), time.process_time()
    if spec.smooth and not (run_dir / "trajectory_smoothed.csv").is_file():
        from rovslam.runner import smooth_run

        smooth_run(run_dir)
    t2s, c2s = time.perf_counter(), time.process_time()
    ev = evaluate_run(run_dir, groundtruth, seq)
    figures = ev.to_dict()
    atomic_write_text(run_dir / "eval.json", json.dumps(figures, indent=2), "the cell's eval.json")
    t3, c3 = time.perf_counter(), time.process_time()
    row = {
        **_spec_columns(spec),
        "status": "ok",
        "error": "",
        **cell_figures(ev),
        "landmarks_found": _landmarks_found(run_dir),
        "frames_per_s": summary.fps,  # wall clock, as `rovslam run` reports it: depends on the machine's load
        "frames_per_cpu_s": summary.frames / (c2 - c1) if c2 > c1 else None,  # per second of one core
        "simulate_s": t1 - t0,
        "run_s": t2 - t1,
        "smooth_s": t2s - t2,
        "eval_s": t3 - t2s,
        "wall_s": t3 - t0,
        # CPU seconds of this worker process (all its threads): the cost of the cell on a quiet core.
        "simulate_cpu_s": c1 - c0,
        "run_cpu_s": c2 - c1,
        "smooth_cpu_s": c2s - c2,
        "eval_cpu_s": c3 - c2s,
    }
    _write_atomic(cell_dir / RESULT_FILE, {"row": row, "evaluation": figures})
    if spec.simulated and not keep_sequence:
        shutil.rmtree(seq, ignore_errors=True)
    return row


def _landmarks_found(run_dir: Path) -> float | None:
    """Share of the frames with a landmark in view where one was found again (``summary.json`` ``map_use``)."""
    try:
        value = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))["map_use"]["found_fraction"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return float(value) if isinstance(value, (int, float)) else None


def cell_figures(ev) -> dict[str, Any]:
    """The matrix.csv figures of an :class:`rovslam.eval.Evaluation` (None where undefined)."""
    row: dict[str, Any] = {
        "frames": ev.frames,
        "duration_s": ev.duration_s,
        "distance_m": ev.slam.distance_m,
        "skipped_frames": ev.skipped_frames,
        "landmarks": ev.landmarks,
        "coverage_2sigma": ev.consistency.coverage_2sigma,
        "nees_mean": ev.consistency.nees_mean,
        "max_error_jump_sigma": ev.consistency.max_error_jump_sigma,
        "max_error_jump_t_s": ev.consistency.max_error_jump_t_s,
        "max_error_jump_before_sigma": ev.consistency.max_error_jump_before_sigma,
        "max_error_jump_before_t_s": ev.consistency.max_error_jump_before_t_s,
        "ate_heading_aligned_rmse_m": ev.slam.ate_heading_aligned_rmse_m,
        "heading_offset_rad": ev.slam.heading_offset_rad,
    }
    for prefix, e in (("", ev.slam), ("dr_", ev.dead_reckoning), ("pc_", ev.phase_correlation)):
        for key in ("ate_rmse_m", "ate_max_m", "final_error_m", "final_error_pct"):
            row[prefix + key] = None if e is None else getattr(e, key)
    sm, smc = ev.smoothed, ev.smoothed_consistency
    for key in ("ate_rmse_m", "ate_max_m", "final_error_m", "ate_heading_aligned_rmse_m", "heading_offset_rad"):
        row["sm_" + key] = None if sm is None else getattr(sm, key)
    row["sm_coverage_2sigma"] = None if smc is None else smc.coverage_2sigma
    row["sm_nees_mean"] = None if smc is None else smc.nees_mean
    row["speed_nees_mean"] = None if ev.speed is None else ev.speed.nees_mean
    row["speed_coverage_2sigma"] = None if ev.speed is None else ev.speed.coverage_2sigma
    row["altitude_error_median_pct"] = None if ev.altitude is None else ev.altitude.median_error_pct
    row["dr_over_slam"] = ev.dead_reckoning_over_slam_rmse
    row["pc_over_slam"] = ev.phase_correlation_over_slam_rmse
    return row


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    from rovslam.eval.metrics import finite_or_none

    atomic_write_text(path, json.dumps(finite_or_none(data), indent=2, allow_nan=False), "the cell's result.json")
