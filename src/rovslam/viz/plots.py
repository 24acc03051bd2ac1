"""The paper's figures from a run's result files (matplotlib, Agg; no screen needed).

* ``altitude_speed.png``  Fig. 2: altitude (titled with where it came from), surge and sway, heading.
* ``position.png``        Fig. 3: x and y against time, the +-2 sigma bounds drawn at a scale where
                          they can be seen (error against the truth, or the 2-sigma width itself),
                          and the identifiers of the tracked landmarks along the time axis.
* ``map.png``             Fig. 4: path and landmark map, 2-sigma ellipses magnified by a stated
                          factor, labels that never overlap, the true and dead-reckoning paths.

Every ``plot_*`` function takes the :class:`~rovslam.io.run_results.RunResults` of a run (and the truth,
aligned with its rows, when known), writes one PNG and returns its path; a ``*_figure`` one returns the figure.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rovslam.io.run_results import RunResults
from rovslam.viz.labels import label_points
from rovslam.viz.runinfo import SourceShare, altitude_sources

DPI = 110
_SOURCE_COLOURS = {
    "laser": "tab:red",
    "laser+sonar": "tab:purple",
    "sonar": "tab:blue",
    "fixed": "tab:gray",
    "held": "tab:orange",
    "none": "k",
}


def pyplot():
    """matplotlib.pyplot on the Agg backend (imported lazily: heavy)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    """Save ``fig`` as ``path`` (its format from the suffix), whole or not at all (never into a device or FIFO)."""
    import io

    from rovslam.io.output import atomic_write_bytes

    buf = io.BytesIO()
    try:
        fig.savefig(buf, dpi=DPI, format=Path(path).suffix.lstrip(".").lower() or "png")
    finally:
        pyplot().close(fig)
    atomic_write_bytes(path, buf.getvalue(), "the figure")
    return path


def sigma_m(res: RunResults) -> np.ndarray:
    """(N, 2) standard deviations of x and y (m)."""
    t = res.trajectory
    return np.sqrt(np.maximum(np.stack([t["var_x_m2"], t["var_y_m2"]], axis=1), 0.0))


def altitude_words(res: RunResults, altitude: SourceShare) -> tuple[str, bool]:
    """(how the altitude was obtained, in words for Fig. 2's title and caption; True when assumed).

    Follows ``summary.json`` ``sources.altitude.source`` (what the run wrote), else the share of
    frames per source of trajectory.csv.
    """
    sources = res.summary.get("sources")
    part = sources.get("altitude") if isinstance(sources, dict) else None
    src = part.get("source") if isinstance(part, dict) else None
    names = [str(src)] if isinstance(src, str) and src.strip() else list(altitude.fractions)
    tokens = {t for n in names for t in n.lower().replace(",", "+").replace(" ", "+").split("+") if t}
    assumed = altitude.assumed or bool(tokens & {"assumed", "fixed", "none", "unknown", "constant"})
    words = [w for key, w in _ALTITUDE_WORDS if key in tokens]
    if assumed:
        measured = [w for key, w in _ALTITUDE_WORDS if any(key in n for n in altitude.fractions)]
        return ("ASSUMED, not measured" + (f"; partly {' and '.join(measured)}" if measured else "")), True
    return (" and ".join(words) if words else ", ".join(names)), False


_ALTITUDE_WORDS = (
    ("laser", "laser triangulation"),
    ("sonar", "sonar altimeter"),
    ("navigation", "navigation log"),
    ("held", "held between readings"),
)


def altitude_speed_title(res: RunResults, altitude: SourceShare) -> str:
    """Fig. 2's title, naming where the altitude came from (never "laser" on a run without one)."""
    words, _ = altitude_words(res, altitude)
    return f"Fig. 2  Altitude ({words}), horizontal speed (optical correlation) and heading"


def plot_altitude_speed(res: RunResults, path: Path, altitude: SourceShare | None = None) -> Path:
    """Fig. 2 written as a PNG (:func:`altitude_speed_figure`)."""
    return save_figure(altitude_speed_figure(res, altitude), path)


def altitude_speed_figure(res: RunResults, altitude: SourceShare | None = None):
    """Fig. 2: altitude with its source, surge and sway speed, heading; all against time."""
    plt = pyplot()
    tr = res.trajectory
    t = res.t_s
    altitude = altitude or altitude_sources(res)
    fig, ax = plt.subplots(4, 1, figsize=(9, 8.2), sharex=True)
    src = np.asarray(tr.get("altitude_source", np.full(len(t), "unknown")), dtype=str)
    for name in np.unique(src):
        z = np.where(src == name, tr["altitude_m"], np.nan)
        label = "ASSUMED (fixed, not measured)" if name == "fixed" else name
        ax[0].plot(t, z, lw=0.9, color=_SOURCE_COLOURS.get(name, "tab:green"), label=label)
    if "altitude_sigma_m" in tr:
        s = np.nan_to_num(tr["altitude_sigma_m"], nan=0.0)
        ax[0].fill_between(
            t,
            tr["altitude_m"] - 2 * s,
            tr["altitude_m"] + 2 * s,
            color="tab:purple",
            alpha=0.2,
            lw=0,
            label="+-2 sigma",
        )
    title = "Altitude Z: " + altitude.label
    ax[0].set_title(title, fontsize=10, color="tab:red" if altitude.assumed else "k", loc="left")
    ax[0].set_ylabel("altitude Z [m]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, tr["surge_mps"], lw=0.6)
    ax[1].set_ylabel("surge u [m/s]")
    ax[2].plot(t, tr["sway_mps"], lw=0.6, color="tab:orange")
    ax[2].set_ylabel("sway v [m/s]")
    if "speed_ok" in tr:
        bad = tr["speed_ok"] < 0.5
        if np.any(bad[1:]):
            for a, key in ((ax[1], "surge_mps"), (ax[2], "sway_mps")):
                a.plot(t[bad], tr[key][bad], ".", ms=3, color="tab:red", label="not measured (held)")
            ax[1].legend(loc="upper right", fontsize=8)
    if "heading_rad" in tr:
        ax[3].plot(t, np.degrees(np.unwrap(tr["heading_rad"])), lw=0.8, color="tab:green")
    ax[3].set_ylabel("heading [deg]")
    ax[3].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(altitude_speed_title(res, altitude))
    fig.tight_layout()
    return fig


# Colours of the refused matches, by the reason observations.csv records (others: REFUSED_OTHER).
REFUSED_COLOURS = {
    "innovation test": "tab:red",
    "joint compatibility": "tab:orange",
    "laser spot inside the template": "tab:gray",
}
REFUSED_OTHER = "tab:purple"


def refusal_groups(reasons: np.ndarray, accepted: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """``(reason, (N,) bool mask)`` of the refused matches, one group per recorded reason, most frequent first."""
    reasons = np.asarray(reasons, dtype=str)
    refused = ~(np.asarray(accepted) > 0)
    names, counts = np.unique(reasons[refused], return_counts=True)
    return [(str(r), refused & (reasons == r)) for r, _ in sorted(zip(names, counts), key=lambda rc: -rc[1])]


def _landmark_track_panel(ax, res: RunResults) -> None:
    """Tracked landmark identifiers against time (accepted observations; initialisations ringed;
    refused matches crossed, one colour per reason: a laser spot on the template is not the filter
    disagreeing)."""
    obs = res.observations
    if obs and len(obs.get("t_s", [])):
        ok = obs["accepted"] > 0
        ax.scatter(obs["t_s"][ok], obs["landmark_id"][ok], s=3, c="tab:green", label="tracked")
        kind = np.asarray(obs.get("kind", np.array([], dtype=object)), dtype=str)
        init = kind == "init"
        if np.any(init):
            ax.scatter(
                obs["t_s"][init],
                obs["landmark_id"][init],
                s=22,
                facecolors="none",
                edgecolors="k",
                lw=0.7,
                label="initialised",
            )
        reasons = obs.get("reason", np.full(len(ok), "refused", dtype=object))
        for reason, sel in refusal_groups(reasons, obs["accepted"]):
            ax.scatter(
                obs["t_s"][sel],
                obs["landmark_id"][sel],
                s=10,
                marker="x",
                lw=0.7,
                c=REFUSED_COLOURS.get(reason, REFUSED_OTHER),
                label=f"refused: {reason or 'refused'}",
            )
        ax.legend(loc="best", fontsize=7, ncol=3)
        top = int(np.nanmax(obs["landmark_id"])) if len(obs["landmark_id"]) else 0
        ax.set_ylim(-0.8, top + 1.2)
        from matplotlib.ticker import MaxNLocator

        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    else:
        ax.text(0.5, 0.5, "no landmark observed", transform=ax.transAxes, ha="center")
    ax.set_ylabel("landmark id")


BAND_THIN_FRACTION = 0.01  # a +-2 sigma band narrower than this share of the y-range is not seen


def band_too_thin(
    low: np.ndarray, high: np.ndarray, curves: list[np.ndarray], frac: float = BAND_THIN_FRACTION
) -> bool:
    """True when a band (N,) ``low`` .. ``high`` is too thin to see on axes that also show ``curves``
    (each (N,)): its median width is below ``frac`` of the y-range the band and curves span."""
    values = np.concatenate([np.ravel(v) for v in (low, high, *curves)])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return False
    span = float(values.max() - values.min())
    width = np.asarray(high, float) - np.asarray(low, float)
    width = width[np.isfinite(width)]
    median = float(np.median(width)) if width.size else 0.0
    return span > 0 and median < frac * span


def plot_position(res: RunResults, path: Path, gt_xy_m: np.ndarray | None = None) -> Path:
    """Fig. 3 written as a PNG (:func:`position_figure`)."""
    return save_figure(position_figure(res, gt_xy_m), path)


def _error_panels(ax, res: RunResults, gt_xy_m: np.ndarray, sd: np.ndarray) -> None:
    """The x and y error against the truth (cm) inside the +-2 sigma band, one panel each."""
    t = res.t_s
    err = res.xy_m - gt_xy_m
    for k, name in enumerate(("x", "y")):
        a = ax[k]
        a.fill_between(t, -200 * sd[:, k], 200 * sd[:, k], color="tab:blue", alpha=0.25, lw=0, label="+-2 sigma")
        a.plot(t, 100 * err[:, k], lw=0.8, color="tab:red", label="estimate - truth")
        a.axhline(0, color="k", lw=0.4)
        a.set_ylabel(f"{name} error [cm]")
        inside = float(np.mean(np.abs(err[:, k]) <= 2 * sd[:, k] + 1e-12)) * 100
        a.set_title(f"{name} error inside +-2 sigma in {inside:.1f} % of frames", fontsize=9, loc="left")
    ax[0].legend(loc="best", fontsize=7, ncol=2)


def position_figure(res: RunResults, gt_xy_m: np.ndarray | None = None):
    """Fig. 3: x and y against time with their bounds, and the tracked landmark identifiers.

    The +-2 sigma band is often millimetres wide on a plot metres high; the panels below show it
    in centimetres: the error against the truth inside +-2 sigma when the truth is known, the
    2-sigma half-width of x and y otherwise. The legend of the top panel sits above it, over no curve.
    """
    plt = pyplot()
    t = res.t_s
    xy = res.xy_m
    sd = sigma_m(res)
    n_rows = 5 if gt_xy_m is not None else 4
    ratios = [1.2, 1.2, 1, 1, 1.1] if gt_xy_m is not None else [1.2, 1.2, 1, 1.1]
    fig, ax = plt.subplots(
        n_rows, 1, figsize=(9, 2.0 * n_rows + 0.8), sharex=True, gridspec_kw={"height_ratios": ratios}
    )
    for k, name in enumerate(("x (north)", "y (east)")):
        low, high = xy[:, k] - 2 * sd[:, k], xy[:, k] + 2 * sd[:, k]
        curves = [xy[:, k]] + ([gt_xy_m[:, k]] if gt_xy_m is not None else [])
        thin = band_too_thin(low, high, curves)
        label = "+-2 sigma (see below, too thin here)" if thin else "+-2 sigma"
        ax[k].fill_between(t, low, high, color="tab:blue", alpha=0.3, lw=0, label=label)
        ax[k].plot(t, xy[:, k], lw=0.8, color="tab:blue", label="estimate")
        if gt_xy_m is not None:
            ax[k].plot(t, gt_xy_m[:, k], lw=0.7, color="k", ls="--", label="truth")
        ax[k].set_ylabel(f"{name} [m]")
    ax[0].legend(loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=7, ncol=3, frameon=False, borderaxespad=0.2)
    if gt_xy_m is not None:
        _error_panels(ax[2:4], res, gt_xy_m, sd)
    else:
        a = ax[2]
        a.plot(t, 200 * sd[:, 0], lw=0.9, label="2 sigma x")
        a.plot(t, 200 * sd[:, 1], lw=0.9, label="2 sigma y")
        a.set_ylabel("2 sigma [cm]")
        a.set_ylim(bottom=0)
        a.set_title("bound half-width (no ground truth given: the error itself is unknown)", fontsize=9, loc="left")
        a.legend(loc="best", fontsize=7)
    _landmark_track_panel(ax[-1], res)
    ax[-1].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("Fig. 3  Estimated position with its +-2 sigma bounds and the tracked SLAM landmarks")
    fig.tight_layout()
    return fig


def ellipse_points(
    centre: np.ndarray, cov: np.ndarray, n_sigma: float = 2.0, scale: float = 1.0, n: int = 48
) -> np.ndarray:
    """(n, 2) points of the ``n_sigma`` ellipse of ``cov`` (2, 2) around ``centre`` (2,), magnified by ``scale``."""
    w, v = np.linalg.eigh(np.asarray(cov, dtype=float))
    r = np.sqrt(np.maximum(w, 0.0)) * n_sigma * scale
    a = np.linspace(0, 2 * np.pi, n)
    return np.asarray(centre, dtype=float) + (v @ (np.stack([np.cos(a), np.sin(a)]) * r[:, None])).T


def nice_scale(want: float) -> int:
    """The 1-2-5 number nearest below ``want`` (at least 1): an ellipse magnification to state."""
    if not math.isfinite(want) or want <= 1:
        return 1
    e = 10 ** math.floor(math.log10(want))
    for m in (5, 2, 1):
        if m * e <= want:
            return int(m * e)
    return 1


def plot_map(res: RunResults, path: Path, gt_xy_m: np.ndarray | None = None) -> Path:
    """Fig. 4: the path and the landmark map, north up.

    The 2-sigma ellipses are magnified by a stated 1-2-5 factor so the median one is about
    3 % of the plot's size, and drawn at true scale too when that is visible. Landmark
    labels are placed by :func:`rovslam.viz.labels.label_points` and never overlap.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.5, 7), dpi=DPI)
    xy = res.xy_m
    if gt_xy_m is not None:
        ax.plot(gt_xy_m[:, 1], gt_xy_m[:, 0], color="k", lw=0.7, ls="--", label="truth")
    if "dr_x_m" in res.trajectory:
        ax.plot(res.dr_xy_m[:, 1], res.dr_xy_m[:, 0], color="tab:gray", lw=0.6, alpha=0.8, label="dead reckoning")
    ax.plot(xy[:, 1], xy[:, 0], lw=0.8, color="tab:blue", label="SLAM estimate")
    ax.plot(xy[0, 1], xy[0, 0], "o", color="tab:blue", ms=5)
    lm = res.landmarks
    n_lm = len(lm.get("id", [])) if lm else 0
    pts = np.zeros((0, 2))
    if n_lm:
        pts = np.column_stack([lm["y_m"], lm["x_m"]])  # plotted (east, north)
        covs = np.empty((n_lm, 2, 2))
        covs[:, 0, 0], covs[:, 1, 1] = lm["var_x_m2"], lm["var_y_m2"]
        covs[:, 0, 1] = covs[:, 1, 0] = lm["cov_xy_m2"]
        all_pts = np.vstack([pts, xy[:, ::-1]])
        extent = float(np.max(np.ptp(all_pts, axis=0))) or 1.0
        semi = 2.0 * np.sqrt(np.maximum(np.linalg.eigvalsh(covs)[:, 1], 0.0))
        med = float(np.median(semi)) if np.any(semi > 0) else 0.0
        scale = nice_scale(0.03 * extent / med) if med > 0 else 1
        for k in range(n_lm):
            e = ellipse_points(np.array([lm["x_m"][k], lm["y_m"][k]]), covs[k], 2.0, scale)
            ax.plot(
                e[:, 1],
                e[:, 0],
                color="tab:red",
                lw=0.8,
                zorder=4,
                label=f"2-sigma ellipses x{scale} (magnified {scale} times)" if k == 0 else None,
            )
            if scale > 1:
                e1 = ellipse_points(np.array([lm["x_m"][k], lm["y_m"][k]]), covs[k], 2.0, 1.0)
                ax.fill(
                    e1[:, 1],
                    e1[:, 0],
                    color="tab:red",
                    alpha=0.6,
                    lw=0,
                    label="2-sigma ellipses, true scale" if k == 0 else None,
                )
        ax.scatter(pts[:, 0], pts[:, 1], marker="+", color="tab:red", s=36, lw=0.9, label="landmarks", zorder=4)
        # the vehicle's final 2-sigma ellipse at the same magnification
        e = ellipse_points(xy[-1], res.cov_m2[-1], 2.0, scale)
        ax.plot(e[:, 1], e[:, 0], color="tab:blue", lw=0.7, label=f"final vehicle 2-sigma x{scale}")
    if res.without_compass:  # the run's frame: x along its first heading, y to starboard of it
        ax.set_xlabel("y, starboard of the first heading [m]")
        ax.set_ylabel("x, along the first heading (no compass) [m]")
    else:
        ax.set_xlabel("y east [m]")
        ax.set_ylabel("x north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=7, framealpha=0.85, bbox_to_anchor=(1.01, 1.0))
    ax.set_title("Fig. 4  Estimated path and SLAM landmark map", fontsize=11)
    fig.tight_layout()
    if n_lm:
        ax.margins(0.08)
        ax.autoscale_view()
        fig.canvas.draw()  # final limits before labels are placed in pixels
        order = np.argsort(lm["id"])
        label_points(
            ax,
            pts[order],
            [str(int(lm["id"][k])) for k in order],
            fontsize=7,
            color="darkred",
            zorder=5,
            bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.75},
        )
    return save_figure(fig, path)
