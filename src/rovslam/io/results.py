"""Result files of ``rovslam run`` (DESIGN.md, end): written as the run goes, readable at any time.

``OUT/trajectory.csv``   one row per frame: estimate, covariance, altitude, speed, counts, dead reckoning
``OUT/trajectory.tum``   TUM format ``t x y z qx qy qz qw`` (z = altitude, quaternion from the heading)
``OUT/observations.csv`` one row per landmark observation (re-observations and initialisations)
``OUT/landmarks.csv``    final landmark map: id, position, 2x2 covariance, first time, observation count
``OUT/landmarks/<id>.png`` the landmark templates
``OUT/summary.json``     configuration, software version, counts, skipped frames, timing
``OUT/tokens.csv``       the speed tokens tracked in each frame (their pixels), for the report's gallery
``OUT/revisits/<id>/<frame>.png`` the image around a landmark at its initialisation and at each revisit

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


TOKEN_COLUMNS = ("t_s", "frame", "u_px", "v_px")
REVISIT_CROP_PX = 64  # side of the saved crop around a landmark match (twice the paper's template)
REVISIT_GAP_S = 2.0  # a landmark seen again after a gap this long starts a new passage (a revisit)


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


class GalleryWriter:
    """What the report's revisit gallery needs, saved as the run goes.

    ``OUT/tokens.csv``: one row per tracked speed token per frame (``t_s,frame,u_px,v_px``).
    ``OUT/revisits/<id>/<frame>.png``: a ``REVISIT_CROP_PX`` square RGB crop of the frame
    around the landmark at its initialisation and at the first accepted observation of each
    later passage (after a gap of more than ``REVISIT_GAP_S``), so the gallery works even
    when the sequence is gone.
    """

    def __init__(self, out_dir: str | Path, flush_every: int = 50):
        self.out = Path(out_dir)
        self._fh = (self.out / "tokens.csv").open("w", newline="", encoding="utf-8")
        self._w = csv.writer(self._fh, lineterminator="\n")
        self._w.writerow(TOKEN_COLUMNS)
        self._last_seen: dict[int, float] = {}
        self.flush_every = max(1, flush_every)
        self._n = 0

    def write_frame(self, image: np.ndarray | None, r: Any) -> None:
        """Record one frame: ``image`` (H, W, 3) uint8 RGB (None when unreadable), ``r`` its FrameResult."""
        t = _f(r.t_s)
        for u, v in np.asarray(getattr(r, "token_uv_px", np.zeros((0, 2)))).reshape(-1, 2):
            self._w.writerow([t, r.index, _f(u), _f(v)])
        for ob in r.observations:
            if not ob.accepted:
                continue
            last = self._last_seen.get(ob.landmark_id, -math.inf)
            self._last_seen[ob.landmark_id] = r.t_s
            if image is not None and (ob.kind == "init" or r.t_s - last > REVISIT_GAP_S):
                self._save_crop(image, ob.landmark_id, r.index, ob.uv_px)
        self._n += 1
        if self._n % self.flush_every == 0:
            self._fh.flush()

    def _save_crop(self, image: np.ndarray, landmark_id: int, frame: int, uv_px: np.ndarray) -> None:
        import cv2

        n = REVISIT_CROP_PX
        crop = cv2.getRectSubPix(np.ascontiguousarray(image), (n, n), (float(uv_px[0]), float(uv_px[1])))
        folder = self.out / "revisits" / str(int(landmark_id))
        folder.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(folder / f"{int(frame)}.png"), cv2.cvtColor(crop, cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        self._fh.close()


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
