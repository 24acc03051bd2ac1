"""Run the pipeline over a sequence and write the result files (the edge between core and disk)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from rovslam import __version__
from rovslam.config import RunConfig, save_config, to_dict
from rovslam.io.results import GalleryWriter, ResultWriter
from rovslam.errors import SequenceFormatError
from rovslam.io.sequence import Frame, open_sequence
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
    on_frame_image: Callable[[Frame, FrameResult, Callable[[], list[dict]]], None] | None = None,
) -> RunSummary:
    """Run SLAM on a sequence folder (or video) and write ``out_dir``. Ctrl-C keeps what was computed.

    ``on_start`` is called once with the number of frames to process (0: unknown, a stream);
    ``on_frame`` with each result record (progress bars, live viewers).
    ``on_frame_image(frame, result, landmark_rows)`` also gets the decoded frame and a function
    returning the current map as landmarks.csv rows (the live viewer; called only when given).
    """
    seq = open_source(sequence_dir, camera_file)
    pipe = SlamPipeline(seq.info, config)
    out = Path(out_dir)
    writer = ResultWriter(out)
    gallery = GalleryWriter(out)
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
            gallery.write_frame(frame.image, res)
            if res.new_landmark_id is not None:
                writer.write_landmark_template(res.new_landmark_id, pipe.landmarks[res.new_landmark_id].patch)
            n += 1
            if on_frame is not None:
                on_frame(res)
            if on_frame_image is not None:
                on_frame_image(frame, res, pipe.landmark_rows)
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
                "camera_file": str(Path(camera_file).resolve()) if camera_file is not None else None,
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
        gallery.close()
    return summary
