"""Result files of ``rovslam run`` (DESIGN.md, end): written as the run goes, readable at any time.

``OUT/trajectory.csv``   one row per frame: estimate, covariance, altitude, speed, counts, dead reckoning
``OUT/trajectory.tum``   TUM format ``t x y z qx qy qz qw`` (z = altitude, quaternion from the heading)
``OUT/observations.csv`` one row per landmark observation (re-observations and initialisations)
``OUT/landmarks.csv``    final landmark map: id, position, 2x2 covariance, first time, observation count
``OUT/landmarks/<id>.png`` the landmark templates
``OUT/summary.json``     status, configuration, software version, counts, skipped frames, timing
``OUT/config.toml``      the configuration of the run
``OUT/tokens.csv``       the speed tokens tracked in each frame (their pixels), for the report's gallery
``OUT/revisits/<id>/<frame>.png`` the image around a landmark at its initialisation and at each revisit

Rows are flushed every ``flush_every`` frames and at close, so an interrupted run leaves
complete lines only (a reader drops a last line cut short by a crash). ``landmarks.csv``,
``summary.json``, ``config.toml``, the landmark PNGs and ``eval.json`` are written atomically
(:func:`atomic_write_bytes`: a temporary file in the same folder, fsync, rename), so they are
either the old or the new file, never half of one. ``summary.json`` is written first with
``"status": "running"`` and last with the outcome.

Every write error (read-only folder, full disk) becomes an :class:`~rovslam.errors.OutputError`
naming the file. :func:`~rovslam.io.result_folder.prepare_output_folder` readies the folder first
(it refuses one that holds an earlier run or files rovslam did not write);
:func:`~rovslam.io.run_results.read_results` reads the files back, validated.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from rovslam.errors import OutputError
from rovslam.io.output import (  # atomic_write_*, describe_os_error, output_errors: imported from here too
    SpaceReserve,
    StreamFile,
    atomic_write_bytes,
    atomic_write_text,
    check_output_folder,
    describe_os_error,
    output_errors,
)
from rovslam.io.result_folder import prepare_output_folder as prepare_output_folder  # imported from here too

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
# Written since the consistency work; readers do not require them (older runs lack them).
OBSERVATION_EXTRA_COLUMNS = ("reason", "tentative")
TRAJECTORY_EXTRA_COLUMNS = (
    "var_surge_mps2",
    "cov_surge_sway_mps2",
    "var_sway_mps2",
    "tokens_inliers",
    "recovery",
    "speed_source",
)
LANDMARK_EXTRA_COLUMNS = ("height_m", "height_sigma_m", "self_similarity", "confirmed", "rejected")
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


# --------------------------------------------------------------------------- writing safely


def json_text(data: Any) -> str:
    """Strict JSON (no NaN / Infinity, which JSON does not allow): non-finite numbers become null."""
    return json.dumps(_finite_or_null(data), indent=2, default=_json_default, allow_nan=False)


def _finite_or_null(o: Any) -> Any:
    if isinstance(o, float) or isinstance(o, np.floating):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _finite_or_null(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite_or_null(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite_or_null(o.tolist())
    return o


class ResultWriter:
    """Streams the per-frame results of a run into ``out_dir`` (which :func:`prepare_output_folder` readied).

    Every write error is an :class:`OutputError` naming the file.
    """

    def __init__(self, out_dir: str | Path, flush_every: int = 50):
        self.out = check_output_folder(out_dir, "--out")
        # Disk space held for the last writes: a disk that fills mid-run still takes the "failed" summary.
        self.reserve = SpaceReserve(self.out) if self.out.is_dir() else None
        self._paths = {k: self.out / f"{k}" for k in ("trajectory.csv", "trajectory.tum", "observations.csv")}
        self._fhs: dict[str, StreamFile] = {}
        self._unwritten: dict[str, StreamFile] = {}  # files whose last flush failed (a full disk): see salvage
        with output_errors(self.out / "landmarks", "cannot create the folder"):
            (self.out / "landmarks").mkdir(parents=True, exist_ok=True)
        try:
            for name, path in self._paths.items():
                # O_EXCL: never write through a file (or link) that appeared since the folder was prepared.
                self._fhs[name] = StreamFile(path)
            self._traj = csv.writer(self._fhs["trajectory.csv"], lineterminator="\n")
            self._obs = csv.writer(self._fhs["observations.csv"], lineterminator="\n")
            self._traj.writerow(TRAJECTORY_COLUMNS + TRAJECTORY_EXTRA_COLUMNS)
            self._fhs["trajectory.tum"].write("# t x y z qx qy qz qw  (rovslam: z = altitude, heading about z)\n")
            self._obs.writerow(OBSERVATION_COLUMNS + OBSERVATION_EXTRA_COLUMNS)
            self.flush()  # the headers on disk at once: a run that fails at its first frame leaves readable files
        except OutputError as exc:
            self.abandon(str(exc))
            raise
        except BaseException:
            self.close(quiet=True)
            raise
        self.flush_every = max(1, flush_every)
        self._n = 0

    @property
    def frames_written(self) -> int:
        """Rows of trajectory.csv on disk, complete (the header not counted)."""
        fh = self._fhs.get("trajectory.csv") or self._unwritten.get("trajectory.csv")
        return max(0, fh.rows - 1) if fh is not None else self._frames_written

    _frames_written = 0

    def write_frame(self, r: Any) -> None:
        """Append one :class:`rovslam.pipeline.FrameResult`."""
        cov = r.cov_xy_m2
        name = "trajectory.csv"
        try:  # one try for the three files (an OSError names the one being written)
            self._traj.writerow(
                [
                    _f(r.t_s),
                    _f(r.x_m),
                    _f(r.y_m),
                    _f(cov[0, 0]),
                    _f(cov[0, 1]),
                    _f(cov[1, 1]),
                    _f(r.altitude_m),
                    _f(r.surge_mps),
                    _f(r.sway_mps),
                    r.tokens_tracked,
                    r.landmarks_tracked,
                    _f(r.heading_rad),
                    _f(r.altitude_sigma_m),
                    r.altitude_source,
                    int(r.speed_ok),
                    _f(r.dr_x_m),
                    _f(r.dr_y_m),
                    int(r.skipped_reason is not None),
                    _f(r.speed_cov_mps2[0, 0]),
                    _f(r.speed_cov_mps2[0, 1]),
                    _f(r.speed_cov_mps2[1, 1]),
                    r.tokens_inliers,
                    int(getattr(r, "recovery", None) is not None),
                    getattr(r, "speed_source", ""),
                ]
            )
            name = "trajectory.tum"
            q = heading_quaternion(r.heading_rad)
            self._fhs[name].write(" ".join(_f(v) for v in (r.t_s, r.x_m, r.y_m, r.altitude_m, *q)) + "\n")
            name = "observations.csv"
            if r.observations:
                self._obs.writerows(
                    [
                        _f(r.t_s),
                        r.index,
                        ob.landmark_id,
                        ob.kind,
                        _f(ob.uv_px[0]),
                        _f(ob.uv_px[1]),
                        _f(ob.score),
                        _f(ob.nis),
                        int(ob.accepted),
                        getattr(ob, "reason", ""),
                        int(getattr(ob, "tentative", False)),
                    ]
                    for ob in r.observations
                )
        except OSError as exc:  # a row too long for the memory buffer, written at once
            raise OutputError(f"{self._paths[name]}: cannot write: {describe_os_error(exc)}.") from None
        self._n += 1
        if self._n % self.flush_every == 0:
            self.flush()

    def write_landmark_template(self, landmark_id: int, patch: np.ndarray) -> None:
        """Save a landmark template as an 8-bit PNG (contrast-stretched for viewing)."""
        import cv2

        p = np.asarray(patch, dtype=np.float32)
        lo, hi = float(p.min()), float(p.max())
        img = np.zeros(p.shape, np.uint8) if hi <= lo else ((p - lo) * (255.0 / (hi - lo))).astype(np.uint8)
        path = self.out / "landmarks" / f"{landmark_id}.png"
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise OutputError(f"{path}: OpenCV could not encode the landmark template.")
        atomic_write_bytes(path, buf.tobytes())

    def write_landmarks(self, rows: list[dict[str, Any]]) -> None:
        """(Re)write landmarks.csv atomically from dicts with the LANDMARK_COLUMNS keys (and the extra ones present)."""
        extra = tuple(c for c in LANDMARK_EXTRA_COLUMNS if rows and c in rows[0])
        cols = LANDMARK_COLUMNS + extra
        lines = [",".join(cols)]
        for row in rows:
            lines.append(",".join(str(row[c]) if isinstance(row[c], (int, str)) else _f(row[c]) for c in cols))
        atomic_write_text(self.out / "landmarks.csv", "\n".join(lines) + "\n")

    def write_summary(self, summary: dict[str, Any], compact: bool = False) -> None:
        """(Re)write summary.json atomically (strict JSON: a non-finite number becomes null).

        A failed run's summary also says how many trajectory rows reached the disk
        (``frames_written``). ``compact``: :func:`compact_summary` of it (a few kilobytes, to fit
        in the space a full disk has left).
        """
        if summary.get("status") != "running":  # the last summary: the space held back is for it
            self.release_reserve()
        if summary.get("status") == "failed":
            summary = {**summary, "frames_written": self.frames_written}
        path = self.out / "summary.json"
        if not compact:
            atomic_write_text(path, json_text(summary) + "\n")
            return
        try:
            atomic_write_text(path, json_text(compact_summary(summary)) + "\n")
        except OutputError:  # not even that: the few keys that say what happened (a few hundred bytes)
            atomic_write_text(path, json_text(compact_summary(summary, minimal=True)) + "\n")

    def write_config(self, config: Any) -> None:
        """Write config.toml atomically (every key, so the file documents the run)."""
        import tomli_w

        from rovslam.config import to_dict

        atomic_write_text(self.out / "config.toml", tomli_w.dumps(to_dict(config)))

    def flush(self) -> None:
        """Write the rows kept in memory (each file keeps whole rows only: see :class:`StreamFile`)."""
        for fh in self._fhs.values():
            fh.flush()

    def release_reserve(self) -> None:
        """Free the disk space held for the last writes (:class:`SpaceReserve`)."""
        reserve = getattr(self, "reserve", None)
        if reserve is not None:
            reserve.release()

    def abandon(self, reason: str) -> None:
        """A run that failed before it started (a full disk): close what is open, free the reserve, and leave a
        small ``summary.json`` saying ``"failed"`` and why, if the disk takes it."""
        self.close(quiet=True)
        for fh in self._unwritten.values():
            fh.close(quiet=True)
        self.release_reserve()
        from rovslam import __version__

        with contextlib.suppress(OutputError):
            self.write_summary(
                {
                    "software": {"name": "rovslam", "version": __version__},
                    "status": "failed",
                    "complete": False,
                    "interrupted": False,
                    "reason": reason,
                    "frames_processed": 0,
                }
            )

    def close(self, quiet: bool = False) -> None:
        """Flush and close the streamed files; ``quiet``: after an error, close without raising.

        A file that cannot be written whole is cut back to its last complete row.
        """
        fhs, self._fhs = self._fhs, {}
        traj = fhs.get("trajectory.csv")
        first: OutputError | None = None
        self._unwritten = {}
        for name, fh in fhs.items():  # trajectory.csv first: trajectory.tum never holds a frame it does not
            try:
                fh.flush(max_rows=self._tum_rows(name, traj))
            except OutputError as exc:
                first = first or exc
                self._unwritten[name] = fh  # its rows kept in memory: see salvage
                continue
            fh.close(quiet=True)
        if traj is not None:
            self._frames_written = max(0, traj.rows - 1)
        if first is not None and not quiet:
            raise first

    def _tum_rows(self, name: str, traj: StreamFile | None) -> int | None:
        """The most rows ``name`` may hold: trajectory.tum no more than trajectory.csv (one header each)."""
        if name != "trajectory.tum":
            return None
        return traj.rows if traj is not None else 1 + self._frames_written

    def salvage(self, summary: dict[str, Any]) -> None:
        """After a full disk: write what it now takes of the rows a failed flush kept in memory (whole rows only),
        leaving room for twice ``summary`` (the summary.json to write next) and 16 KiB; then close those files."""
        unwritten, self._unwritten = self._unwritten, {}
        keep_free = 2 * len(json_text(summary)) + 16 * 1024
        traj = unwritten.get("trajectory.csv")
        for name, fh in unwritten.items():  # trajectory.csv first, as in close
            try:
                st = os.statvfs(self.out)
                fh.flush(max_bytes=max(0, st.f_bavail * st.f_frsize - keep_free), max_rows=self._tum_rows(name, traj))
            except (OSError, OutputError):
                pass  # the disk took no more: the rows on disk stay whole
            finally:
                fh.close(quiet=True)
                if name == "trajectory.csv":
                    self._frames_written = max(0, fh.rows - 1)


_COMPACT_LIST_ITEMS = 20


_MINIMAL_KEYS = (
    "software",
    "sequence",
    "sequence_name",
    "frames_in_sequence",
    "status",
    "complete",
    "interrupted",
    "signal",
    "reason",
    "frames_processed",
    "frames_usable",
    "frames_written",
    "landmarks",
)


def compact_summary(summary: dict[str, Any], minimal: bool = False) -> dict[str, Any]:
    """``summary`` made small: its per-frame lists cut to their first ``_COMPACT_LIST_ITEMS`` items (with the full
    count beside them) and the configuration left out (config.toml holds it); everything else as it is.
    ``minimal``: only the keys that say what happened (``_MINIMAL_KEYS``)."""
    out: dict[str, Any] = {}
    for key, value in summary.items():
        if key == "config" or (minimal and key not in _MINIMAL_KEYS):
            continue
        if isinstance(value, list) and len(value) > _COMPACT_LIST_ITEMS:
            out[key] = value[:_COMPACT_LIST_ITEMS]
            out[f"{key}_count"] = len(value)
        else:
            out[key] = value
    out["compact"] = True  # written small, on a full disk
    return out


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
        self._path = self.out / "tokens.csv"
        self._fh = StreamFile(self._path)
        self._w = csv.writer(self._fh, lineterminator="\n")
        self._w.writerow(TOKEN_COLUMNS)
        self._last_seen: dict[int, float] = {}
        self.flush_every = max(1, flush_every)
        self._n = 0

    def write_frame(self, image: np.ndarray | None, r: Any) -> None:
        """Record one frame: ``image`` (H, W, 3) uint8 RGB (None when unreadable), ``r`` its FrameResult."""
        t = _f(r.t_s)
        uv = (
            np.asarray(getattr(r, "token_uv_px", np.zeros((0, 2)))).reshape(-1, 2).tolist()
        )  # Python floats: faster to format
        if uv:
            with output_errors(self._path):
                self._w.writerows([t, r.index, _f(u), _f(v)] for u, v in uv)
        for ob in r.observations:
            if not ob.accepted:
                continue
            last = self._last_seen.get(ob.landmark_id, -math.inf)
            self._last_seen[ob.landmark_id] = r.t_s
            if image is not None and (ob.kind == "init" or r.t_s - last > REVISIT_GAP_S):
                self._save_crop(image, ob.landmark_id, r.index, ob.uv_px)
        self._n += 1
        if self._n % self.flush_every == 0:
            with output_errors(self._path):
                self._fh.flush()

    def _save_crop(self, image: np.ndarray, landmark_id: int, frame: int, uv_px: np.ndarray) -> None:
        import cv2

        n = REVISIT_CROP_PX
        crop = cv2.getRectSubPix(np.ascontiguousarray(image), (n, n), (float(uv_px[0]), float(uv_px[1])))
        folder = self.out / "revisits" / str(int(landmark_id))
        with output_errors(folder, "cannot create the folder"):
            folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{int(frame)}.png"
        ok, buf = cv2.imencode(".png", cv2.cvtColor(crop, cv2.COLOR_RGB2BGR))
        if not ok:
            raise OutputError(f"{path}: OpenCV could not encode the revisit crop.")
        try:
            atomic_write_bytes(path, buf.tobytes())  # whole or not at all: a full disk leaves no half PNG
        except OutputError as exc:
            why = str(exc).split(": ", 2)[-1].rstrip(".") if ": cannot write: " in str(exc) else str(exc)
            raise OutputError(f"{path}: cannot write the revisit crop: {why}.") from None

    def close(self) -> None:
        """Flush and close tokens.csv; an error names it (the file is closed all the same, whole rows only)."""
        try:
            with output_errors(self._path):
                self._fh.flush()
                self._fh.close()
        finally:
            with contextlib.suppress(OSError, ValueError, OutputError):
                self._fh.close()  # a StreamFile closes (dropping what it could not write) even when its flush failed


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o)}")


# ---------------------------------------------------------------------------------------------
# Smoothed results (``rovslam smooth``, the smoothing back end): the best estimate of the whole
# dive given all of it, beside the online (causal) trajectory.

SMOOTHED_TRAJECTORY_COLUMNS = ("t_s", "x_m", "y_m", "var_x_m2", "cov_xy_m2", "var_y_m2", "heading_rad")
SMOOTHED_LANDMARK_COLUMNS = LANDMARK_COLUMNS[:-1] + ("downweighted", "height_m")


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
    atomic_write_text(out / "trajectory_smoothed.tum", "\n".join(rows) + "\n")
    atomic_write_text(out / "trajectory_smoothed.csv", "\n".join(csv_rows) + "\n")
    lm = [",".join(SMOOTHED_LANDMARK_COLUMNS)]
    for row in landmark_rows:
        lm.append(
            ",".join(
                str(row[c]) if isinstance(row[c], (int, np.integer)) else _f(row[c]) for c in SMOOTHED_LANDMARK_COLUMNS
            )
        )
    atomic_write_text(out / "landmarks_smoothed.csv", "\n".join(lm) + "\n")
