"""The figure of a navigation run (``rovslam navigate``): true and estimated paths with the points of interest."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rovslam.viz.plots import pyplot, save_figure

__all__ = ["plot_navigation"]


def plot_navigation(
    path: Path,
    true_xy_m: np.ndarray,
    est_xy_m: np.ndarray,
    poi_xy_m: np.ndarray,
    poi_names: list[str],
    nav_start: int,
    arrivals: list[dict],
    estimator: str,
) -> Path:
    """Plan view (east right, north up): true path, estimated path, the points and each arrival's true error.

    ``true_xy_m``, ``est_xy_m``: (N, 2) per frame; ``nav_start``: the first frame after the
    survey (the survey is drawn faint); ``poi_xy_m`` (K, 2) with NaN for a landmark point
    never resolved; ``arrivals``: the arrivals.csv rows.
    """
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 6.2), gridspec_kw={"width_ratios": [1.4, 1]})
    t, e = np.asarray(true_xy_m), np.asarray(est_xy_m)
    if nav_start > 0:
        ax.plot(t[: nav_start + 1, 1], t[: nav_start + 1, 0], color="0.8", lw=0.6, label="survey (true)")
    ax.plot(t[nav_start:, 1], t[nav_start:, 0], color="k", lw=1.0, label="true path")
    ax.plot(e[nav_start:, 1], e[nav_start:, 0], color="tab:blue", lw=0.8, ls="--", label=f"estimate ({estimator})")
    pts = np.asarray(poi_xy_m, dtype=np.float64).reshape(-1, 2)
    ax.scatter(pts[:, 1], pts[:, 0], marker="x", s=70, color="tab:red", zorder=5, label="points of interest")
    for name, p in zip(poi_names, pts):
        if np.all(np.isfinite(p)):
            ax.annotate(name, (p[1], p[0]), textcoords="offset points", xytext=(6, 6), fontsize=8, color="tab:red")
    ax.set_xlabel("east y (m)")
    ax.set_ylabel("north x (m)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("paths and points of interest")
    names = [r["name"] for r in arrivals]
    true_mm = [1e3 * float(r["true_err_m"]) for r in arrivals]
    hold_mm = [1e3 * float(r["hold_rms_true_m"]) for r in arrivals]
    est_mm = [1e3 * float(r["est_err_m"]) for r in arrivals]
    x = np.arange(len(names))
    bx.bar(x - 0.27, est_mm, 0.27, label="estimate to point at arrival", color="tab:blue")
    bx.bar(x, true_mm, 0.27, label="truth to point at arrival", color="k")
    bx.bar(x + 0.27, hold_mm, 0.27, label="truth to point, RMS while holding", color="0.6")
    bx.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    bx.set_ylabel("mm")
    finite = [v for v in true_mm if math.isfinite(v)]
    mean = f"mean true error {np.mean(finite):.1f} mm" if finite else "no arrival"
    bx.set_title(f"arrivals: {mean}")
    bx.grid(alpha=0.3, axis="y")
    bx.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, Path(path))
