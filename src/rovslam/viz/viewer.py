"""Live viewer of a run with rerun-sdk: what the filter sees and believes, frame by frame.

Entities (timelines ``frame`` and ``time``):

* ``camera/image``          the frame (JPEG-encoded to keep the recording small)
* ``camera/lasers``         laser spots used for the altitude
* ``camera/tokens``         the tracked 16x16 speed tokens
* ``camera/landmarks``      the 32x32 landmark templates matched (or initialised), with their ids
* ``map/path``              the estimated path (east right, north up)
* ``map/vehicle``           the vehicle and ``map/vehicle_ellipse`` its 2-sigma ellipse
* ``map/landmarks``         the landmark map and ``map/landmark_ellipses`` their 2-sigma ellipses
                            (both ellipses magnified ``ellipse_scale`` times, said in ``map/legend``)
* ``series/altitude_m``, ``series/surge_mps``, ``series/sway_mps``, ``series/heading_deg``,
  ``series/correlation``, ``series/nis``, ``series/tokens_tracked``

rerun is imported only when a viewer is made: a run without ``--viewer`` / ``--save-rrd``
never loads it and pays nothing.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from rovslam.viz.plots import ellipse_points

ENTITY_PATHS = (
    "camera/image",
    "camera/lasers",
    "camera/tokens",
    "camera/landmarks",
    "map/path",
    "map/vehicle",
    "map/vehicle_ellipse",
    "map/landmarks",
    "map/landmark_ellipses",
    "series/altitude_m",
    "series/surge_mps",
    "series/sway_mps",
    "series/heading_deg",
    "series/correlation",
    "series/nis",
    "series/tokens_tracked",
)
TOKEN_PX = 16
LANDMARK_PX = 32


def display_available() -> bool:
    """Whether a viewer window can open here (a desktop session, or X / Wayland on Linux)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _map_xy(xy_m: np.ndarray) -> np.ndarray:
    """World (x north, y east) -> rerun 2-D view coordinates (east right, north up: y flipped)."""
    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    return np.column_stack([xy[:, 1], -xy[:, 0]])


class RerunViewer:
    """An ``on_frame_image`` callback for :func:`rovslam.runner.run_sequence` logging to rerun.

    ``spawn`` opens the rerun viewer; ``save_path`` writes an ``.rrd`` file (both may be given).
    ``map_every`` frames between map updates (path, landmarks), ``ellipse_scale`` magnifies the
    2-sigma ellipses (millimetres on a metres map).
    """

    def __init__(
        self,
        *,
        spawn: bool = False,
        save_path: str | Path | None = None,
        ellipse_scale: float = 10.0,
        map_every: int = 5,
        jpeg_quality: int = 80,
        application_id: str = "rovslam",
    ):
        import rerun as rr

        self.rr = rr
        self.rec = rr.RecordingStream(application_id)
        self.save_path = Path(save_path) if save_path is not None else None
        self.spawn = spawn
        self.ellipse_scale = float(ellipse_scale)
        self.map_every = max(1, int(map_every))
        self.jpeg_quality = int(jpeg_quality)
        self._path: list[tuple[float, float]] = []
        self._n = 0
        self._started = False

    @property
    def started(self) -> bool:
        """Whether a frame was logged (and so the sinks opened)."""
        return self._started

    def _start(self) -> None:
        """Open the sinks at the first frame (the results folder is ready by then, the .rrd goes into it)."""
        rr = self.rr
        if self.spawn:
            self.rec.spawn(connect=self.save_path is None)
        if self.save_path is not None:
            self.save_path.parent.mkdir(parents=True, exist_ok=True)
            if self.spawn:
                self.rec.set_sinks(rr.GrpcSink(), rr.FileSink(str(self.save_path)))
            else:
                self.rec.save(str(self.save_path))
        self.rec.log(
            "map/legend",
            rr.TextDocument(
                f"Map: east right, north up, metres. Ellipses: 2 sigma, magnified {self.ellipse_scale:g} times."
            ),
            static=True,
        )
        self._started = True

    def __call__(self, frame, res, landmark_rows: Callable[[], list[dict]] | None = None) -> None:
        if not self._started:
            self._start()
        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=int(res.index))
        rec.set_time("time", duration=float(res.t_s))
        self._log_camera(frame, res)
        self._path.append((res.x_m, res.y_m))
        xy = np.array([[res.x_m, res.y_m]])
        rec.log("map/vehicle", rr.Points2D(_map_xy(xy), radii=0.004, colors=(30, 110, 230)))
        rec.log(
            "map/vehicle_ellipse",
            rr.LineStrips2D(
                [_map_xy(ellipse_points(xy[0], res.cov_xy_m2, 2.0, self.ellipse_scale))], colors=(30, 110, 230)
            ),
        )
        if self._n % self.map_every == 0 or res.new_landmark_id is not None:
            self._log_map(landmark_rows)
        scores = [o.score for o in res.observations if o.kind == "track"]
        nis = [o.nis for o in res.observations if o.kind == "track"]
        series = {
            "series/altitude_m": res.altitude_m,
            "series/surge_mps": res.surge_mps,
            "series/sway_mps": res.sway_mps,
            "series/heading_deg": math.degrees(res.heading_rad),
            "series/tokens_tracked": float(res.tokens_tracked),
        }
        if scores:
            series["series/correlation"] = max(scores)
            series["series/nis"] = max(nis)
        for path, value in series.items():
            if math.isfinite(value):
                rec.log(path, rr.Scalars(float(value)))
        self._n += 1

    def _log_camera(self, frame, res) -> None:
        rr, rec = self.rr, self.rec
        img = getattr(frame, "image", None)
        if img is not None:
            import cv2

            ok, buf = cv2.imencode(
                ".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
            )
            if ok:
                rec.log("camera/image", rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))
        rec.log(
            "camera/lasers",
            rr.Points2D(np.asarray(res.laser_spots_uv_px).reshape(-1, 2), radii=4.0, colors=(255, 40, 40)),
        )
        tok = np.asarray(getattr(res, "token_uv_px", np.zeros((0, 2)))).reshape(-1, 2)
        rec.log("camera/tokens", rr.Boxes2D(centers=tok, sizes=np.full((len(tok), 2), TOKEN_PX), colors=(0, 230, 0)))
        obs = list(res.observations)
        rec.log(
            "camera/landmarks",
            rr.Boxes2D(
                centers=np.array([o.uv_px for o in obs]).reshape(-1, 2),
                sizes=np.full((len(obs), 2), LANDMARK_PX),
                labels=[f"L{o.landmark_id}" + (" new" if o.kind == "init" else "") for o in obs],
                colors=[(255, 220, 0) if o.accepted else (255, 60, 60) for o in obs],
            ),
        )

    def _log_map(self, landmark_rows: Callable[[], list[dict]] | None) -> None:
        rr, rec = self.rr, self.rec
        path = np.asarray(self._path)
        step = max(1, len(path) // 5000)
        rec.log("map/path", rr.LineStrips2D([_map_xy(path[::step] if step > 1 else path)], colors=(30, 110, 230)))
        rows = landmark_rows() if landmark_rows is not None else []
        if not rows:
            return
        xy = np.array([[r["x_m"], r["y_m"]] for r in rows])
        rec.log(
            "map/landmarks",
            rr.Points2D(_map_xy(xy), radii=0.005, colors=(220, 30, 30), labels=[str(r["id"]) for r in rows]),
        )
        strips = [
            _map_xy(
                ellipse_points(
                    xy[k],
                    np.array([[r["var_x_m2"], r["cov_xy_m2"]], [r["cov_xy_m2"], r["var_y_m2"]]]),
                    2.0,
                    self.ellipse_scale,
                )
            )
            for k, r in enumerate(rows)
        ]
        rec.log("map/landmark_ellipses", rr.LineStrips2D(strips, colors=(220, 30, 30)))

    def close(self) -> None:
        """Flush and close the recording (the .rrd is complete after this; none is written without a frame)."""
        if not self._started:
            return
        self.rec.flush()
        self.rec.disconnect()


def entity_paths_in(rrd: str | Path) -> dict[str, int]:
    """{entity path: rows logged} of an ``.rrd`` file, read back with rerun's own reader."""
    from rerun.chunk import RrdReader

    counts: dict[str, int] = {}
    for chunk in RrdReader(str(rrd)).stream():
        counts[chunk.entity_path.lstrip("/")] = counts.get(chunk.entity_path.lstrip("/"), 0) + chunk.num_rows
    return counts


def scalar_series(rrd: str | Path, entity_path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(frame (N,), value (N,))`` of a scalar series in an ``.rrd`` file, in frame order."""
    from rerun.chunk import RrdReader

    frames, values = [], []
    for chunk in RrdReader(str(rrd)).stream():
        if chunk.entity_path.lstrip("/") != entity_path:
            continue
        rb = chunk.to_record_batch()
        col = next(n for n in rb.schema.names if n.endswith(":scalars"))
        frames += rb.column("frame").to_pylist()
        values += [v[0] for v in rb.column(col).to_pylist()]
    order = np.argsort(frames, kind="stable")
    return np.asarray(frames)[order], np.asarray(values, dtype=float)[order]
