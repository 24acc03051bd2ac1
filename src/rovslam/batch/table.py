"""The tables of a batch: ``matrix.csv`` (one row per cell) and ``matrix.md`` (median and worst per scenario).

Pure functions on the cell rows (dicts, as :func:`rovslam.batch.cell.run_cell` returns them),
plus the two writers.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

MATRIX_COLUMNS = (
    "cell",
    "group",
    "scenario",
    "seed",
    "config",
    "status",
    "error",
    "frames",
    "duration_s",
    "distance_m",
    "skipped_frames",
    "landmarks",
    "landmarks_found",
    "ate_rmse_m",
    "ate_max_m",
    "final_error_m",
    "final_error_pct",
    "ate_heading_aligned_rmse_m",
    "heading_offset_rad",
    "coverage_2sigma",
    "nees_mean",
    "max_error_jump_sigma",
    "max_error_jump_t_s",
    "max_error_jump_before_sigma",
    "max_error_jump_before_t_s",
    "speed_nees_mean",
    "speed_coverage_2sigma",
    "altitude_error_median_pct",
    "dr_ate_rmse_m",
    "dr_ate_max_m",
    "dr_final_error_m",
    "dr_final_error_pct",
    "pc_ate_rmse_m",
    "pc_ate_max_m",
    "pc_final_error_m",
    "pc_final_error_pct",
    "dr_over_slam",
    "pc_over_slam",
    "frames_per_s",
    "frames_per_cpu_s",
    "simulate_s",
    "run_s",
    "eval_s",
    "wall_s",
    "simulate_cpu_s",
    "run_cpu_s",
    "eval_cpu_s",
)


@dataclass(frozen=True)
class Figure:
    """One column of the summary: a cell figure, how to print it, and which end of it is worse."""

    key: str
    label: str
    scale: float
    digits: int
    worst: str  # "max": larger is worse; "min": smaller is worse


SUMMARY_FIGURES = (
    Figure("ate_rmse_m", "ATE RMSE [cm]", 100, 2, "max"),
    Figure("ate_max_m", "max error [cm]", 100, 2, "max"),
    Figure("final_error_m", "final error [cm]", 100, 2, "max"),
    Figure("final_error_pct", "final error / distance [%]", 1, 2, "max"),
    Figure("coverage_2sigma", "inside 2-sigma [%]", 100, 1, "min"),
    Figure("nees_mean", "mean NEES", 1, 2, "max"),
    Figure("max_error_jump_sigma", "max error jump [sigma]", 1, 1, "max"),
    Figure("max_error_jump_before_sigma", "max error jump [sigma before]", 1, 1, "max"),
    Figure("speed_nees_mean", "speed NEES", 1, 2, "max"),
    Figure("altitude_error_median_pct", "altitude error, median [%]", 1, 2, "max"),
    Figure("ate_heading_aligned_rmse_m", "ATE, heading aligned [cm]", 100, 2, "max"),
    Figure("sm_ate_rmse_m", "smoothed ATE [cm]", 100, 2, "max"),
    Figure("sm_ate_heading_aligned_rmse_m", "smoothed ATE, heading aligned [cm]", 100, 2, "max"),
    Figure("sm_coverage_2sigma", "smoothed inside 2-sigma [%]", 100, 1, "min"),
    Figure("landmarks", "landmarks", 1, 0, "min"),
    Figure("landmarks_found", "landmark found in view [%]", 100, 0, "min"),
    Figure("frames_per_cpu_s", "frames/s (1 core)", 1, 0, "min"),
    Figure("dr_ate_rmse_m", "dead reckoning ATE [cm]", 100, 2, "max"),
    Figure("pc_ate_rmse_m", "phase correlation ATE [cm]", 100, 2, "max"),
    Figure("dr_over_slam", "DR / SLAM", 1, 1, "min"),
    Figure("pc_over_slam", "PC / SLAM", 1, 1, "min"),
)


@dataclass(frozen=True)
class GroupSummary:
    """Median and worst over the seeds of one scenario (or one sequence)."""

    group: str
    cells: int
    ok: int
    median: dict[str, float | None]
    worst: dict[str, float | None]
    worst_cell: str | None  # the cell with the largest ATE RMSE


def _number(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def summarise(rows: Sequence[dict[str, Any]], groups: Sequence[str] | None = None) -> list[GroupSummary]:
    """One :class:`GroupSummary` per group (in ``groups`` order, default first appearance).

    Failed and pending cells are counted in ``cells``, not in the figures.
    """
    import numpy as np

    order = list(groups) if groups is not None else list(dict.fromkeys(r["group"] for r in rows))
    out = []
    for g in order:
        cells = [r for r in rows if r["group"] == g]
        ok = [r for r in cells if r.get("status") == "ok"]
        median: dict[str, float | None] = {}
        worst: dict[str, float | None] = {}
        for f in SUMMARY_FIGURES:
            vals = [v for v in (_number(r.get(f.key)) for r in ok) if v is not None]
            median[f.key] = float(np.median(vals)) if vals else None
            worst[f.key] = (max(vals) if f.worst == "max" else min(vals)) if vals else None
        ranked = [r for r in ok if _number(r.get("ate_rmse_m")) is not None]
        worst_cell = max(ranked, key=lambda r: _number(r["ate_rmse_m"]))["cell"] if ranked else None  # type: ignore[arg-type,return-value]
        out.append(GroupSummary(g, len(cells), len(ok), median, worst, worst_cell))
    return out


def format_figure(value: float | None, figure: Figure) -> str:
    return "n/a" if value is None else f"{value * figure.scale:.{figure.digits}f}"


def matrix_markdown(title: str, rows: Sequence[dict[str, Any]], groups: Sequence[str] | None = None) -> str:
    """``matrix.md``: per scenario, ``median / worst`` of every summary figure; then the failed cells."""
    summaries = summarise(rows, groups)
    head = ["scenario", "cells ok"] + [f.label for f in SUMMARY_FIGURES] + ["worst cell"]
    lines = [
        f"# rovslam batch: {title}",
        "",
        "Each figure is `median / worst` over the seeds of a scenario (worst: the largest error, NEES",
        "and error jump; the smallest 2-sigma coverage, landmark count, frames/s and baseline/SLAM ratio).",
        "",
        "| " + " | ".join(head) + " |",
        "| --- | ---: |" + " ---: |" * len(SUMMARY_FIGURES) + " --- |",
    ]
    for s in summaries:
        cols = [s.group, f"{s.ok}/{s.cells}"]
        cols += [f"{format_figure(s.median[f.key], f)} / {format_figure(s.worst[f.key], f)}" for f in SUMMARY_FIGURES]
        cols.append(s.worst_cell or "")
        lines.append("| " + " | ".join(cols) + " |")
    failed = [r for r in rows if r.get("status") == "failed"]
    if failed:
        lines += ["", "## Failed cells", "", "| cell | error |", "| --- | --- |"]
        lines += [f"| {r['cell']} | {str(r.get('error', '')).replace('|', '/')} |" for r in failed]
    pending = [r["cell"] for r in rows if r.get("status") == "pending"]
    if pending:
        lines += ["", f"Not run yet (the batch was interrupted): {', '.join(pending)}."]
    lines += [
        "",
        "ATE: RMS of the position error over the frames; final error / distance: the last frame's error",
        "over the distance travelled; max error jump: max over frames of sqrt(de^T P^-1 de), de the change",
        "of the error since the previous frame, P the reported position covariance (after the jump; [sigma",
        "before]: the larger of the ellipses before and after it, so a correction that removes an error the",
        "ellipse before held is not counted as a jump, and a pull to a wrong place still is); DR: rovslam's own",
        "dead reckoning; PC: frame-to-frame phase correlation scaled by the altitude, turned by the compass;",
        "frames/s (1 core): frames per CPU second of `rovslam run` (matrix.csv also has the wall-clock rate).",
        "",
    ]
    return "\n".join(lines)


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else ""
    return str(value)


def write_tables(
    out_dir: Path, title: str, rows: Sequence[dict[str, Any]], groups: Sequence[str] | None = None
) -> None:
    """Write ``matrix.csv`` and ``matrix.md`` in ``out_dir`` (each atomically: a reader never sees half a table)."""
    import io

    from rovslam.io.output import atomic_write_text

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(MATRIX_COLUMNS)
    for r in rows:
        w.writerow([_cell(r.get(c)) for c in MATRIX_COLUMNS])
    atomic_write_text(out_dir / "matrix.csv", buf.getvalue(), "matrix.csv")  # never into a device or a FIFO
    atomic_write_text(out_dir / "matrix.md", matrix_markdown(title, rows, groups), "matrix.md")
