"""Result files of ``rovslam run`` (DESIGN.md, end): written as the run goes, readable at any time.

``OUT/trajectory.csv``   one row per frame: estimate, covariance, altitude, speed, counts, dead reckoning
``OUT/trajectory.tum``   TUM format ``t x y z qx qy qz qw`` (z = altitude, quaternion from the heading)
``OUT/observations.csv`` one row per landmark observation (re-observations and initialisations)
``OUT/landmarks.csv``    final landmark map: id, position, 2x2 covariance, first time, observation count
``OUT/landmarks/<id>.png`` the landmark templates
``OUT/summary.json``     configuration, software version, counts, skipped frames, timing

Rows are flushed every ``flush_every`` frames and at close, so an interrupted run leaves
complete lines only; landmarks.csv and summary.json are rewritten at close.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import SequenceFormatError

TRAJECTORY_COLUMNS = (
    "t_s",
    "x_m",
    "y_m",
    "var_x_m2",
    "cov_xy_m2",
    "var_y_m2",
    "altitude_m",
    "surge_mps",
    "sway_mps",
    "tokens_tracked",
    "landmarks_tracked",
    "heading_rad",
    "altitude_sigma_m",
    "altitude_source",
    "speed_ok",
    "dr_x_m",
    "dr_y_m",
    "skipped",
)
OBSERVATION_COLUMNS = ("t_s", "frame", "landmark_id", "kind", "u_px", "v_px", "score", "nis", "accepted")
LANDMARK_COLUMNS = (
    "id",
    "x_m",
    "y_m",
    "var_x_m2",
    "cov_xy_m2",
    "var_y_m2",
    "first_t_s",
    "observations",
    "local_variance",
)


def heading_quaternion(heading_rad: float) -> tuple[float, float, float, float]:
    """(qx, qy, qz, qw) of a rotation by ``heading_rad`` about z (world z down, as in DESIGN.md)."""
    return (0.0, 0.0, math.sin(heading_rad / 2.0), math.cos(heading_rad / 2.0))


def _f(v: float) -> str:
    return f"{v:.9g}"


class ResultWriter:
    """Streams the per-frame results of a run into ``out_dir``."""

    def __init__(self, out_dir: str | Path, flush_every: int = 50):
        self.out = Path(out_dir)
        if self.out.exists() and not self.out.is_dir():
            raise SequenceFormatError(f"{self.out}: exists and is not a folder; choose another --out.")
        (self.out / "landmarks").mkdir(parents=True, exist_ok=True)
        self._traj_fh = (self.out / "trajectory.csv").open("w", newline="", encoding="utf-8")
        self._traj = csv.writer(self._traj_fh, lineterminator="\n")
        self._traj.writerow(TRAJECTORY_COLUMNS)
        self._tum_fh = (self.out / "trajectory.tum").open("w", encoding="utf-8")
        self._tum_fh.write("# t x y z qx qy qz qw  (rovslam: z = altitude, heading about z)\n")
        self._obs_fh = (self.out / "observations.csv").open("w", newline="", encoding="utf-8")
        self._obs = csv.writer(self._obs_fh, lineterminator="\n")
        self._obs.writerow(OBSERVATION_COLUMNS)
        self.flush_every = max(1, flush_every)
        self._n = 0

    def write_frame(self, r: Any) -> None:
        """Append one :class:`rovslam.pipeline.FrameResult`."""
        cov = r.cov_xy_m2
        self._traj.writerow(
            [
                _f(r.t_s), _f(r.x_m), _f(r.y_m), _f(cov[0, 0]), _f(cov[0, 1]), _f(cov[1, 1]),
                _f(r.altitude_m), _f(r.surge_mps), _f(r.sway_mps), r.tokens_tracked, r.landmarks_tracked,
                _f(r.heading_rad), _f(r.altitude_sigma_m), r.altitude_source, int(r.speed_ok),
                _f(r.dr_x_m), _f(r.dr_y_m), int(r.skipped_reason is not None),
            ]
        )
        q = heading_quaternion(r.heading_rad)
        self._tum_fh.write(" ".join(_f(v) for v in (r.t_s, r.x_m, r.y_m, r.altitude_m, *q)) + "\n")
        for ob in r.observations:
            self._obs.writerow(
                [_f(r.t_s), r.index, ob.landmark_id, ob.kind, _f(ob.uv_px[0]), _f(ob.uv_px[1]),
                 _f(ob.score), _f(ob.nis), int(ob.accepted)]
            )
        self._n += 1
        if self._n % self.flush_every == 0:
            self.flush()

    def write_landmark_template(self, landmark_id: int, patch: np.ndarray) -> None:
        """Save a landmark template as an 8-bit PNG (contrast-stretched for viewing)."""
        import cv2

        p = np.asarray(patch, dtype=np.float32)
        lo, hi = float(p.min()), float(p.max())
        img = np.zeros(p.shape, np.uint8) if hi <= lo else ((p - lo) * (255.0 / (hi - lo))).astype(np.uint8)
        cv2.imwrite(str(self.out / "landmarks" / f"{landmark_id}.png"), img)

    def write_landmarks(self, rows: list[dict[str, Any]]) -> None:
        """(Re)write landmarks.csv atomically from dicts with the LANDMARK_COLUMNS keys."""
        tmp = self.out / "landmarks.csv.tmp"
        with tmp.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(LANDMARK_COLUMNS)
            for row in rows:
                w.writerow([row[c] if isinstance(row[c], (int, str)) else _f(row[c]) for c in LANDMARK_COLUMNS])
        tmp.replace(self.out / "landmarks.csv")

    def write_summary(self, summary: dict[str, Any]) -> None:
        tmp = self.out / "summary.json.tmp"
        tmp.write_text(json.dumps(summary, indent=2, default=_json_default), encoding="utf-8")
        tmp.replace(self.out / "summary.json")

    def flush(self) -> None:
        for fh in (self._traj_fh, self._tum_fh, self._obs_fh):
            fh.flush()

    def close(self) -> None:
        for fh in (self._traj_fh, self._tum_fh, self._obs_fh):
            fh.close()


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


@dataclass(frozen=True)
class RunResults:
    """The result files of a run, read back as arrays (columns of trajectory.csv by name)."""

    folder: Path
    trajectory: dict[str, np.ndarray]
    observations: dict[str, np.ndarray]
    landmarks: dict[str, np.ndarray]
    summary: dict[str, Any]

    @property
    def t_s(self) -> np.ndarray:
        return self.trajectory["t_s"]

    @property
    def xy_m(self) -> np.ndarray:
        return np.column_stack([self.trajectory["x_m"], self.trajectory["y_m"]])

    @property
    def cov_m2(self) -> np.ndarray:
        """(N, 2, 2) position covariances."""
        t = self.trajectory
        c = np.empty((len(t["t_s"]), 2, 2))
        c[:, 0, 0], c[:, 0, 1], c[:, 1, 0], c[:, 1, 1] = t["var_x_m2"], t["cov_xy_m2"], t["cov_xy_m2"], t["var_y_m2"]
        return c

    @property
    def dr_xy_m(self) -> np.ndarray:
        return np.column_stack([self.trajectory["dr_x_m"], self.trajectory["dr_y_m"]])


def _read_table(path: Path, text_columns: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise SequenceFormatError(f"{path}: missing. Is this the --out folder of a `rovslam run`?")
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise SequenceFormatError(f"{path}: empty file.")
        rows = [r for r in reader if len(r) == len(header)]  # a torn last line is dropped
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        col = [r[j] for r in rows]
        if name in text_columns:
            out[name] = np.asarray(col, dtype=object)
            continue
        try:
            out[name] = np.asarray([float(v) if v != "" else np.nan for v in col], dtype=np.float64)
        except ValueError:
            out[name] = np.asarray(col, dtype=object)
    return out


def read_results(out_dir: str | Path) -> RunResults:
    """Read the files of a ``rovslam run --out`` folder (complete or interrupted)."""
    out = Path(out_dir)
    if not out.is_dir():
        raise SequenceFormatError(f"{out}: not a folder. Give the --out folder of a `rovslam run`.")
    traj = _read_table(out / "trajectory.csv", ("altitude_source",))
    obs_path = out / "observations.csv"
    obs = _read_table(obs_path, ("kind",)) if obs_path.is_file() else {}
    lm_path = out / "landmarks.csv"
    lms = _read_table(lm_path) if lm_path.is_file() else {}
    summ_path = out / "summary.json"
    summary = json.loads(summ_path.read_text(encoding="utf-8")) if summ_path.is_file() else {}
    return RunResults(out, traj, obs, lms, summary)


# ---------------------------------------------------------------------------------------------
# Smoothed results (``rovslam smooth``, the smoothing back end): the best estimate of the whole
# dive given all of it, beside the online (causal) trajectory.

SMOOTHED_TRAJECTORY_COLUMNS = ("t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "heading_rad")
SMOOTHED_LANDMARK_COLUMNS = LANDMARK_COLUMNS[:-1] + ("downweighted",)


def _replace_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)


def write_smoothed(
    out_dir: str | Path,
    t_s: np.ndarray,
    xy_m: np.ndarray,
    cov_xy_m2: np.ndarray,
    heading_rad: np.ndarray,
    altitude_m: np.ndarray,
    landmark_rows: list[dict[str, Any]],
) -> None:
    """Write ``trajectory_smoothed.tum``, ``trajectory_smoothed.csv`` and ``landmarks_smoothed.csv``.

    Args:
        t_s, heading_rad, altitude_m: (N,) per pose; xy_m: (N, 2); cov_xy_m2: (N, 2, 2).
        landmark_rows: dicts with the ``SMOOTHED_LANDMARK_COLUMNS`` keys.

    Each file is written whole and then renamed over the old one: an interruption leaves the
    previous version, never half a file.
    """
    out = Path(out_dir)
    rows = ["# t x y z qx qy qz qw  (rovslam smoothed: z = altitude, heading about z)"]
    csv_rows = [",".join(SMOOTHED_TRAJECTORY_COLUMNS)]
    for t, (x, y), c, psi, z in zip(t_s, xy_m, cov_xy_m2, heading_rad, altitude_m):
        rows.append(" ".join(_f(v) for v in (t, x, y, z, *heading_quaternion(float(psi)))))
        csv_rows.append(",".join(_f(v) for v in (t, x, y, c[0, 0], c[0, 1], c[1, 1], psi)))
    _replace_atomically(out / "trajectory_smoothed.tum", "\n".join(rows) + "\n")
    _replace_atomically(out / "trajectory_smoothed.csv", "\n".join(csv_rows) + "\n")
    lm = [",".join(SMOOTHED_LANDMARK_COLUMNS)]
    for row in landmark_rows:
        lm.append(",".join(str(row[c]) if isinstance(row[c], (int, np.integer)) else _f(row[c])
                           for c in SMOOTHED_LANDMARK_COLUMNS))
    _replace_atomically(out / "landmarks_smoothed.csv", "\n".join(lm) + "\n")
