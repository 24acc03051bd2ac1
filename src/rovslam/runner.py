"""Run the pipeline over a sequence and write the result files (the edge between core and disk)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rovslam import __version__
from rovslam.config import RunConfig, save_config, to_dict
from rovslam.io.results import ResultWriter
from rovslam.errors import SequenceFormatError
from rovslam.io.sequence import open_sequence
from rovslam.pipeline import FrameResult, SlamPipeline


@dataclass(frozen=True)
class RunSummary:
    frames: int
    total_frames: int
    skipped: list[tuple[int, float, str]]
    landmarks: int
    wall_s: float
    interrupted: bool
    out_dir: Path

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else float("inf")


def open_source(path: str | Path, camera_file: str | Path | None = None):
    """A sequence folder, or a video file with its camera file: anything with ``.info`` and ``.frames()``."""
    p = Path(path)
    if not p.exists():
        raise SequenceFormatError(f"{p}: not found. Give a sequence folder or a video file.")
    if p.is_dir():
        return open_sequence(p)
    from rovslam.io.video import VIDEO_SUFFIXES, open_video

    if p.suffix.lower() in VIDEO_SUFFIXES:
        if camera_file is None:
            raise SequenceFormatError(
                f"{p}: a video needs --camera FILE.toml (a sequence.toml with [camera], optional [[laser]] "
                "and [vehicle] altitude_m)."
            )
        return open_video(p, camera_file)
    raise SequenceFormatError(
        f"{p}: neither a sequence folder nor a video file ({', '.join(VIDEO_SUFFIXES)})."
    )


def run_sequence(
    sequence_dir: str | Path,
    out_dir: str | Path,
    config: RunConfig = RunConfig(),
    max_frames: int | None = None,
    on_frame: Callable[[FrameResult], None] | None = None,
    camera_file: str | Path | None = None,
    on_start: Callable[[int], None] | None = None,
) -> RunSummary:
    """Run SLAM on a sequence folder (or video) and write ``out_dir``. Ctrl-C keeps what was computed.

    ``on_start`` is called once with the number of frames to process (0: unknown, a stream);
    ``on_frame`` with each result record (progress bars, live viewers).
    """
    seq = open_source(sequence_dir, camera_file)
    pipe = SlamPipeline(seq.info, config)
    out = Path(out_dir)
    writer = ResultWriter(out)
    save_config(config, out / "config.toml")
    total = len(seq) if max_frames is None else (min(len(seq), max_frames) if len(seq) else max_frames)  # 0: unknown
    if on_start is not None:
        on_start(total)
    n = 0
    interrupted = False
    t0 = time.perf_counter()
    try:
        for frame in seq.frames(stop=max_frames):
            res = pipe.process(frame)
            writer.write_frame(res)
            if res.new_landmark_id is not None:
                writer.write_landmark_template(res.new_landmark_id, pipe.landmarks[res.new_landmark_id].patch)
            n += 1
            if on_frame is not None:
                on_frame(res)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        wall = time.perf_counter() - t0
        writer.write_landmarks(pipe.landmark_rows())
        summary = RunSummary(n, total, list(pipe.skipped), pipe.ekf.n_landmarks, wall, interrupted, out)
        writer.write_summary(
            {
                "software": {"name": "rovslam", "version": __version__},
                "sequence": str(Path(sequence_dir).resolve()),
                "sequence_name": seq.info.name,
                "frames_processed": n,
                "frames_in_sequence": len(seq),
                "interrupted": interrupted,
                "skipped_frames": [{"index": i, "t_s": t, "reason": r} for i, t, r in pipe.skipped],
                "landmarks": pipe.ekf.n_landmarks,
                "wall_time_s": wall,
                "frames_per_second": summary.fps,
                "config": to_dict(config),
            }
        )
        writer.close()
    return summary


@dataclass(frozen=True)
class SmoothSummary:
    """What :func:`smooth_run` did."""

    frames: int
    landmarks: int
    observations: int
    downweighted: int  # observations the robust loss down-weighted at the final estimate
    online_s: float  # the incremental (iSAM2) pass over every frame
    final_s: float  # the final polish and the marginal covariances
    out_dir: Path


def smoother_config_for_run(out_dir: str | Path):
    """The smoother's drift model taken from the run's ``config.toml`` (defaults when absent).

    The compass drift the run was told of (``[odometry] compass_drift_sigma_rad``, with the
    correlation time ``[slam] heading_bias_tau_s``) is the one the graph models.
    """
    from rovslam.config import load_config
    from rovslam.slam.smoother import SmootherConfig

    path = Path(out_dir) / "config.toml"
    if not path.is_file():
        return SmootherConfig()
    cfg = load_config(path)
    return SmootherConfig(
        heading_bias_sigma_rad=cfg.odometry.compass_drift_sigma_rad, heading_bias_tau_s=cfg.slam.heading_bias_tau_s
    )


def smooth_run(
    out_dir: str | Path,
    config=None,
    on_start: Callable[[int], None] | None = None,
    on_frame: Callable[[int], None] | None = None,
) -> SmoothSummary:
    """Rebuild the factor graph of a run from its measurement files, smooth it, write the results.

    Reads ``OUT/measurements.csv`` and ``OUT/landmark_measurements.csv``, feeds every frame to
    :class:`rovslam.slam.smoother.Isam2Smoother` and writes ``OUT/trajectory_smoothed.tum``,
    ``OUT/trajectory_smoothed.csv`` and ``OUT/landmarks_smoothed.csv``. ``config`` (a
    :class:`~rovslam.slam.smoother.SmootherConfig`) defaults to :func:`smoother_config_for_run`.
    ``on_start`` gets the frame count, ``on_frame`` the number of frames done.

    Raises:
        ResultsFormatError: no measurement files (a run by an older rovslam) or bad content.
    """
    from rovslam.errors import ResultsFormatError
    from rovslam.io.measurements import read_measurements
    from rovslam.io.results import write_smoothed
    from rovslam.slam.smoother import Isam2Smoother

    out = Path(out_dir)
    frames = read_measurements(out)
    if not frames:
        raise ResultsFormatError(f"{out}: the measurement files hold no frame; nothing to smooth.")
    smoother = Isam2Smoother(config if config is not None else smoother_config_for_run(out))
    if on_start is not None:
        on_start(len(frames))
    t0 = time.perf_counter()
    for n, meas in enumerate(frames, 1):
        smoother.add_frame(meas)
        if on_frame is not None:
            on_frame(n)
    t1 = time.perf_counter()
    res = smoother.smoothed()
    t2 = time.perf_counter()
    rows = [
        {"id": int(i), "x_m": float(xy[0]), "y_m": float(xy[1]), "var_x_m2": float(c[0, 0]), "cov_xy_m2": float(c[0, 1]),
         "var_y_m2": float(c[1, 1]), "first_t_s": float(t), "observations": int(n), "downweighted": int(d)}
        for i, xy, c, t, n, d in zip(res.landmark_ids, res.landmarks_xy_m, res.landmarks_cov_m2,
                                      res.landmark_first_t_s, res.landmark_observations, res.landmark_downweighted)
    ]
    write_smoothed(out, res.t_s, res.xy_m, res.cov_xy_m2, res.heading_rad, res.altitude_m, rows)
    return SmoothSummary(
        frames=len(frames), landmarks=len(rows), observations=int(res.landmark_observations.sum()),
        downweighted=int(res.landmark_downweighted.sum()), online_s=t1 - t0, final_s=t2 - t1, out_dir=out,
    )
