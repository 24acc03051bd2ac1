"""What the smoother can gain over the online estimate: its ATE with the errors no image measures taken out.

Two errors of a simulated dive are shared by the online and the smoothed path and observed by
nothing but their priors:

* the AHRS's tilt error: the camera sees the seabed under it, the vehicle is ``Z tan(tilt)`` away
  (2 to 5 mm at 1.3 m for the simulator's 0.1 degree drift), and only the AHRS says how far;
* the compass's mean error over the dive: the landmarks measure how the compass error changes, not
  its level, which turns the whole map about the start.

For each simulated matrix cell (a ``rovslam batch`` folder whose matrix has ``smooth = true``,
or any with the runs' ``measurements.csv``), this smooths the run again with the current code,
rebuilds the truth and the AHRS readings from the scenario and seed (the simulator is
deterministic), and prints smoothed / online ATE as it is, with the AHRS term removed from both,
with the smoother also given the true heading, and for the shapes alone (each path aligned to the
truth by the rotation and shift that fit it best).

    python scripts/smoother_floor.py matrix-smooth --scenario photo-turns

Cells simulated with calibration errors (``calibration = true``) are not supported: their
sensors are drawn for the seed as well, which this does not rebuild.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

import numpy as np

from rovslam.eval.metrics import trajectory_errors
from rovslam.io.measurements import read_measurements
from rovslam.runner import run_config_for
from rovslam.sim.scenarios import SCENARIOS
from rovslam.sim.vehicle import read_sensors, simulate_trajectory
from rovslam.slam.smoother import Isam2Smoother


def _ate_mm(path_m: np.ndarray, truth_m: np.ndarray) -> float:
    """``rovslam eval``'s ATE RMSE of an (N, 2) path against the truth, in millimetres."""
    return trajectory_errors(path_m, truth_m).ate_rmse_m * 1000.0


def _shape_ate_mm(path_m: np.ndarray, truth_m: np.ndarray) -> float:
    """ATE after the rotation and shift that best align the path to the truth (its shape's error)."""
    p, q = path_m - path_m.mean(axis=0), truth_m - truth_m.mean(axis=0)
    u, _, vt = np.linalg.svd(q.T @ p)
    r = u @ np.diag([1.0, np.linalg.det(u @ vt)]) @ vt
    return _ate_mm(p @ r.T, q)


def _smooth(frames, config) -> np.ndarray:
    smoother = Isam2Smoother(config)
    for meas in frames:
        smoother.add_frame(meas)
    return smoother.smoothed().xy_m


def _tilt_offset_m(traj, nav) -> np.ndarray:
    """(N, 2) world-frame offset of the vehicle from where the AHRS's tilt error puts it (``Z`` times the error)."""
    d_pitch, d_roll = nav.pitch_rad - traj.pitch_rad, nav.roll_rad - traj.roll_rad
    body = np.c_[-traj.altitude_m * d_pitch, traj.altitude_m * d_roll]
    c, s = np.cos(traj.heading_rad), np.sin(traj.heading_rad)
    return np.c_[c * body[:, 0] - s * body[:, 1], s * body[:, 0] + c * body[:, 1]]


def cell_figures(cell: Path) -> dict[str, float]:
    """One cell's ATEs [mm]: online, smoothed, smoothed with the true heading, and the AHRS term."""
    run = cell / "run"
    row = json.loads((cell / "result.json").read_text(encoding="utf-8"))["row"]
    frames = read_measurements(run)
    sc = SCENARIOS[row["scenario"]]
    traj = simulate_trajectory(sc.vehicle, sc.grid, len(frames), sc.frame_rate_hz, int(row["seed"]))
    nav = read_sensors(traj, sc.nav, int(row["seed"]))
    truth = np.c_[traj.x_m - traj.x_m[0], traj.y_m - traj.y_m[0]]
    online = np.loadtxt(run / "trajectory.csv", delimiter=",", skiprows=1, usecols=(1, 2)).reshape(-1, 2)
    config = run_config_for(run).smoother
    smoothed = _smooth(frames, config)
    exact = [
        dataclasses.replace(f, compass_rad=float(traj.heading_rad[k]), compass_sigma_rad=1e-4)
        for k, f in enumerate(frames)
    ]
    true_heading = _smooth(exact, dataclasses.replace(config, heading_bias_sigma_rad=0.0))
    tilt = _tilt_offset_m(traj, nav)
    return {
        "online": _ate_mm(online, truth),
        "smoothed": _ate_mm(smoothed, truth),
        "online_no_tilt": _ate_mm(online - tilt, truth),
        "smoothed_no_tilt": _ate_mm(smoothed - tilt, truth),
        "true_heading_no_tilt": _ate_mm(true_heading - tilt, truth),
        "tilt_term": _ate_mm(tilt, np.zeros_like(tilt)),
        "online_shape": _shape_ate_mm(online, truth),
        "smoothed_shape": _shape_ate_mm(smoothed, truth),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("matrix", type=Path, help="a rovslam batch --out folder")
    parser.add_argument("--scenario", default=None, help="only this scenario's cells")
    args = parser.parse_args(argv)
    cells = sorted(
        p.parent for p in args.matrix.glob("cells/*/result.json") if (p.parent / "run" / "measurements.csv").is_file()
    )
    if args.scenario:
        cells = [c for c in cells if c.name.rsplit("_s", 1)[0] == args.scenario]
    if not cells:
        print(f"no cell with a run's measurements.csv under {args.matrix}/cells", file=sys.stderr)
        return 2
    print(
        "| cell | online [mm] | smoothed [mm] | ratio | AHRS term [mm] | ratio, AHRS term out "
        "| ratio, also true heading | ratio of the shapes |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    ratios: dict[str, list[float]] = {"raw": [], "no_tilt": [], "floor": [], "shape": []}
    for cell in cells:
        f = cell_figures(cell)
        r = (
            f["smoothed"] / f["online"],
            f["smoothed_no_tilt"] / f["online_no_tilt"],
            f["true_heading_no_tilt"] / f["online_no_tilt"],
            f["smoothed_shape"] / f["online_shape"],
        )
        for key, value in zip(ratios, r):
            ratios[key].append(value)
        print(
            f"| {cell.name} | {f['online']:.2f} | {f['smoothed']:.2f} | {r[0]:.2f} | {f['tilt_term']:.2f} | {r[1]:.2f} | {r[2]:.2f} | {r[3]:.2f} |"
        )
    med = {k: statistics.median(v) for k, v in ratios.items()}
    print(f"| median | | | {med['raw']:.3f} | | {med['no_tilt']:.3f} | {med['floor']:.3f} | {med['shape']:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
