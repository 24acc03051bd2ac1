"""What the report says about a run, computed from its result files (pure functions on arrays).

Kept here, beside the plots, so the report depends on the result files only (``trajectory.csv``,
``observations.csv``, ``landmarks.csv``, ``summary.json``, ``tokens.csv``), not on the shape of
the evaluator's output: an ``eval.json`` is read when present, defensively.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import ResultsFormatError
from rovslam.io.run_results import RunResults
from rovslam.io.text import read_text

# Altitude sources written by the laser altimeter (rovslam.vision.laser): measured or assumed.
MEASURED_ALTITUDE = ("laser", "laser+sonar", "sonar", "held")  # held: predicted from the readings between them
ASSUMED_ALTITUDE = ("fixed", "none")


@dataclass(frozen=True)
class SourceShare:
    """Where a quantity came from, as the fraction of frames per source."""

    fractions: dict[str, float]
    assumed: bool  # True when any frame used an assumed value
    label: str  # e.g. "laser+sonar (100 %)" or "ASSUMED constant 1.80 m (100 %)"


def _summary_sources(res: RunResults, key: str) -> dict[str, Any] | None:
    """``summary.json`` ``sources[key]`` as a run writes it (frames per source, detail), or None."""
    sources = res.summary.get("sources")
    part = sources.get(key) if isinstance(sources, dict) else None
    frames = part.get("frames") if isinstance(part, dict) else None
    if not isinstance(frames, dict) or not frames or not all(isinstance(v, int) and v >= 0 for v in frames.values()):
        return None
    if sum(frames.values()) == 0:
        return None
    return part


def _share_from_summary(part: dict[str, Any], assumed_names: tuple[str, ...]) -> SourceShare:
    frames = {str(k): int(v) for k, v in part["frames"].items()}
    n = sum(frames.values())
    fr = {k: v / n for k, v in frames.items()}
    labels = [f"{name} ({100 * f:.0f} %)" for name, f in sorted(fr.items(), key=lambda kv: -kv[1])]
    return SourceShare(fr, any(k in assumed_names for k in fr), ", ".join(labels))


def altitude_sources(res: RunResults) -> SourceShare:
    """Share of frames per altitude source (``altitude_source`` of trajectory.csv, or summary.json).

    The altimeter calls every altitude input "sonar"; a run whose ``summary.json`` says its source's
    altitude came from a navigation log (``source.altitude_input``) is labelled so.
    """
    col = res.trajectory.get("altitude_source")
    source = res.summary.get("source")
    nav = isinstance(source, dict) and source.get("altitude_input") == "navigation"
    if nav and col is not None:
        col = np.char.replace(np.asarray(col, dtype=str), "sonar", "navigation")
    if col is None or len(col) == 0:
        src = res.summary.get("altitude_source")
        fr = {str(src): 1.0} if src else {"unknown": 1.0}
    else:
        names, counts = np.unique(np.asarray(col, dtype=str), return_counts=True)
        fr = {str(n): float(c) / len(col) for n, c in zip(names, counts)}
    assumed = any(k in ASSUMED_ALTITUDE or k == "unknown" for k in fr)
    alt = res.trajectory.get("altitude_m")
    parts = []
    for name, f in sorted(fr.items(), key=lambda kv: -kv[1]):
        if name == "fixed" and alt is not None and len(alt):
            fixed = np.asarray(alt)[np.asarray(col, dtype=str) == "fixed"] if col is not None else alt
            parts.append(f"ASSUMED constant {np.nanmedian(fixed):.2f} m ({100 * f:.0f} %)")
        elif name == "none":
            parts.append(f"held over skipped frames ({100 * f:.0f} %)")
        elif name == "held":
            parts.append(f"held between readings ({100 * f:.0f} %)")
        else:
            parts.append(f"{name} ({100 * f:.0f} %)")
    return SourceShare(fr, assumed, ", ".join(parts))


def heading_source(res: RunResults, sequence: Path | None) -> SourceShare:
    """Whether the heading came from a compass (frames.csv ``heading_rad``) or from the tokens alone.

    Uses ``summary.json`` ``heading_source`` when the run wrote one; otherwise looks at the
    sequence: a video, or a frames.csv whose headings are NaN, has no compass.
    """
    part = _summary_sources(res, "heading")
    if part is not None:
        return _share_from_summary(part, ("tokens only (no compass)",))
    given = res.summary.get("heading_source")
    if isinstance(given, str) and given:
        tokens_only = "token" in given
        return SourceShare(
            {given: 1.0}, tokens_only, given + (" (no compass: integrated turn, drifts)" if tokens_only else "")
        )
    if sequence is None or not sequence.exists():
        return SourceShare({"unknown": 1.0}, True, "unknown (sequence not found)")
    if sequence.is_file():
        return SourceShare({"tokens": 1.0}, True, "speed tokens only (video, no compass: integrated turn, drifts)")
    frames_csv = sequence / "frames.csv"
    try:
        with frames_csv.open(newline="", encoding="utf-8") as fh:
            vals = [row.get("heading_rad", "") for row in csv.DictReader(fh)]
        finite = np.isfinite([float(v) if v.strip() else math.nan for v in vals])
    except (OSError, ValueError):
        return SourceShare({"unknown": 1.0}, True, f"unknown ({frames_csv} unreadable)")
    share = float(np.mean(finite)) if len(finite) else 0.0
    if share == 1.0:
        return SourceShare({"compass": 1.0}, False, "compass, smoothed with the token rotation (100 %)")
    return SourceShare(
        {"compass": share, "tokens": 1.0 - share},
        True,
        f"compass ({100 * share:.0f} %), speed tokens only ({100 * (1 - share):.0f} %, no compass)",
    )


def passages(res: RunResults, landmark_id: int, gap_s: float = 2.0) -> list[int]:
    """Rows of observations.csv that start a passage over ``landmark_id``: its initialisation,
    then the first accepted observation after a gap longer than ``gap_s`` (the paper's revisits)."""
    obs = res.observations
    if not obs or len(obs.get("landmark_id", [])) == 0:
        return []
    rows = np.nonzero((obs["landmark_id"] == landmark_id) & (obs["accepted"] > 0))[0]
    out: list[int] = []
    last_t = -math.inf
    for r in rows:
        t = float(obs["t_s"][r])
        if t - last_t > gap_s or not out:
            out.append(int(r))
        last_t = t
    return out


def most_revisited(res: RunResults, k: int = 2, exclude: tuple[int, ...] = (0,)) -> list[int]:
    """The ``k`` landmarks with the most passages (ties: the older first), ``exclude`` left out."""
    lm = res.landmarks
    if not lm or len(lm.get("id", [])) == 0:
        return []
    ids = [int(i) for i in lm["id"] if int(i) not in exclude]
    counts = {i: len(passages(res, i)) for i in ids}
    return sorted(ids, key=lambda i: (-counts[i], i))[:k]


def truth_at(res: RunResults, gt_t_s: np.ndarray, gt_xy_m: np.ndarray, tol_s: float = 1e-3) -> np.ndarray | None:
    """(N, 2) true positions at the trajectory times, or None when the clocks do not match."""
    t = res.t_s
    if len(t) == 0 or len(gt_t_s) == 0:
        return None
    k = np.clip(np.searchsorted(gt_t_s, t - tol_s), 0, len(gt_t_s) - 1)
    if np.any(np.abs(gt_t_s[k] - t) > tol_s):
        return None
    return gt_xy_m[k]


def accuracy(res: RunResults, truth_xy_m: np.ndarray) -> dict[str, float]:
    """ATE RMSE of SLAM and dead reckoning (m), the 2-sigma coverage (fraction of frames) and the
    mean NEES (e^T P^-1 e over the frames, 2 degrees of freedom: 2 for a consistent filter)."""
    err = res.xy_m - truth_xy_m
    dr = res.dr_xy_m - truth_xy_m
    cov = res.cov_m2 + 1e-12 * np.eye(2)
    d2 = np.einsum("ni,nij,nj->n", err, np.linalg.inv(cov), err)
    return {
        "ate_rmse_m": float(np.sqrt(np.mean(np.sum(err**2, axis=1)))),
        "dr_ate_rmse_m": float(np.sqrt(np.mean(np.sum(dr**2, axis=1)))),
        "coverage_2sigma": float(np.mean(d2 <= 4.0)),
        "nees_mean": float(np.mean(d2)),
    }


def distance_m(xy_m: np.ndarray) -> float:
    """Length of an (N, 2) path."""
    return float(np.sum(np.linalg.norm(np.diff(xy_m, axis=0), axis=1))) if len(xy_m) > 1 else 0.0


def read_eval_json(path: Path) -> dict[str, Any]:
    """``eval.json`` as a dict (empty when missing or unreadable: the report computes its own figures)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):  # RecursionError: nested thousands deep, not rovslam's
        return {}
    return data if isinstance(data, dict) else {}


def read_tokens(out_dir: Path) -> dict[int, np.ndarray]:
    """``OUT/tokens.csv`` as {frame index: (K, 2) token pixels}; empty when the run wrote none."""
    path = out_dir / "tokens.csv"
    out: dict[int, list[tuple[float, float]]] = {}
    if not path.is_file():
        return {}
    text = read_text(path, ResultsFormatError)  # not UTF-8 (a damaged file): one line naming it
    try:
        for row in csv.DictReader(io.StringIO(text, newline="")):
            try:
                out.setdefault(int(row["frame"]), []).append((float(row["u_px"]), float(row["v_px"])))
            except (KeyError, TypeError, ValueError):
                continue  # a torn last line of an interrupted run
    except csv.Error as exc:
        raise ResultsFormatError(
            f"{path}: not a readable CSV file ({exc}); run again with --overwrite to rewrite it."
        ) from None
    return {k: np.asarray(v) for k, v in out.items()}
