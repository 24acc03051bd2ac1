"""The paper's figures from a run's result files (matplotlib, Agg; no screen needed).

* ``altitude_speed.png``  Fig. 2: altitude and surge / sway speed measured by the LTOC sensor.
* ``position.png``        Fig. 3: estimated x and y with +-2 sigma bounds and the tracked landmark ids
                          (and the truth, when given).
* ``map.png``             Fig. 4: estimated path and landmark positions with 2-sigma ellipses
                          (and the true path / dead reckoning).
* ``errors.png``          position error against the truth with the filter's +-2 sigma bounds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rovslam.io.results import RunResults


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_altitude_speed(res: RunResults, path: Path) -> Path:
    plt = _plt()
    t = res.trajectory
    fig, ax = plt.subplots(3, 1, figsize=(9, 6.5), sharex=True)
    ax[0].plot(t["t_s"], t["altitude_m"], lw=0.8)
    ax[0].set_ylabel("altitude Z [m]")
    ax[1].plot(t["t_s"], t["surge_mps"], lw=0.6)
    ax[1].set_ylabel("surge u [m/s]")
    ax[2].plot(t["t_s"], t["sway_mps"], lw=0.6, color="tab:orange")
    ax[2].set_ylabel("sway v [m/s]")
    ax[2].set_xlabel("time [s]")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("Altitude and horizontal speed from the laser-triangulation optical-correlation sensor")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_position(res: RunResults, path: Path, gt_xy_m: np.ndarray | None = None) -> Path:
    plt = _plt()
    t = res.t_s
    xy = res.xy_m
    sd = np.sqrt(np.maximum(np.stack([res.trajectory["var_x_m2"], res.trajectory["var_y_m2"]], 1), 0))
    fig, ax = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for k, name in enumerate(("x (north)", "y (east)")):
        ax[k].plot(t, xy[:, k], lw=0.8, label="estimate")
        ax[k].fill_between(t, xy[:, k] - 2 * sd[:, k], xy[:, k] + 2 * sd[:, k], alpha=0.25, label="+-2 sigma")
        if gt_xy_m is not None:
            ax[k].plot(t, gt_xy_m[:, k], lw=0.6, color="k", ls="--", label="truth")
        ax[k].set_ylabel(f"{name} [m]")
        ax[k].grid(alpha=0.3)
    ax[0].legend(loc="upper right", fontsize=8)
    obs = res.observations
    if obs and len(obs.get("t_s", [])):
        ok = obs["accepted"] > 0
        ax[2].scatter(obs["t_s"][ok], obs["landmark_id"][ok], s=2, c="tab:green")
    ax[2].set_ylabel("tracked landmark id")
    ax[2].set_xlabel("time [s]")
    ax[2].grid(alpha=0.3)
    fig.suptitle("Estimated position and tracked landmarks")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _ellipse(ax, centre, cov, **kw) -> None:
    w, v = np.linalg.eigh(cov)
    w = np.sqrt(np.maximum(w, 0)) * 2.0
    a = np.linspace(0, 2 * np.pi, 40)
    pts = centre + (v @ (np.stack([np.cos(a), np.sin(a)]) * w[:, None])).T
    ax.plot(pts[:, 1], pts[:, 0], **kw)


def plot_map(res: RunResults, path: Path, gt_xy_m: np.ndarray | None = None) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.5, 7))
    xy = res.xy_m
    if gt_xy_m is not None:
        ax.plot(gt_xy_m[:, 1], gt_xy_m[:, 0], color="k", lw=0.6, ls="--", label="truth")
    ax.plot(res.dr_xy_m[:, 1], res.dr_xy_m[:, 0], color="tab:gray", lw=0.6, alpha=0.8, label="dead reckoning")
    ax.plot(xy[:, 1], xy[:, 0], lw=0.8, label="SLAM estimate")
    lm = res.landmarks
    if lm and len(lm.get("id", [])):
        ax.scatter(lm["y_m"], lm["x_m"], marker="+", color="tab:red", s=40, label="landmarks")
        for k in range(len(lm["id"])):
            cov = np.array([[lm["var_x_m2"][k], lm["cov_xy_m2"][k]], [lm["cov_xy_m2"][k], lm["var_y_m2"][k]]])
            _ellipse(ax, np.array([lm["x_m"][k], lm["y_m"][k]]), cov, color="tab:red", lw=0.4)
            if len(lm["id"]) <= 60:
                ax.annotate(str(int(lm["id"][k])), (lm["y_m"][k], lm["x_m"][k]), fontsize=7, color="tab:red")
    ax.set_xlabel("y east [m]")
    ax.set_ylabel("x north [m]")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title("Estimated path and landmark map (2-sigma ellipses)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_errors(res: RunResults, path: Path, gt_xy_m: np.ndarray) -> Path:
    plt = _plt()
    t = res.t_s
    err = res.xy_m - gt_xy_m
    dr_err = res.dr_xy_m - gt_xy_m
    sd = np.sqrt(np.maximum(np.stack([res.trajectory["var_x_m2"], res.trajectory["var_y_m2"]], 1), 0))
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for k, name in enumerate(("x", "y")):
        ax[k].fill_between(t, -200 * sd[:, k], 200 * sd[:, k], alpha=0.25, label="+-2 sigma")
        ax[k].plot(t, 100 * err[:, k], lw=0.7, label="SLAM error")
        ax[k].plot(t, 100 * dr_err[:, k], lw=0.6, color="tab:gray", alpha=0.7, label="dead reckoning error")
        ax[k].set_ylabel(f"{name} error [cm]")
        ax[k].grid(alpha=0.3)
    ax[0].legend(loc="upper left", fontsize=8)
    ax[1].set_xlabel("time [s]")
    fig.suptitle("Position error against the ground truth")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
