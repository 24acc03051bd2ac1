"""``rovslam import``: any input (video, image folder, ROS bag, with its navigation) written as a sequence folder.

The frames are written as lossless PNG (or JPEG) with their times and the navigation's values at
those times in ``frames.csv`` (``heading_rad`` ``nan`` where there was no heading,
``sonar_altitude_m`` empty where there was no altitude, ``roll_rad``/``pitch_rad`` when the input
has an attitude). ``sequence.toml`` holds the camera (a bag's CameraInfo included), the laser rig,
``[vehicle]`` and, in ``[metadata]``, where the input and its heading and altitude came from, so
that a run of the imported sequence reports the same sources as a run of the input.
A frame that cannot be decoded is not written (counted in :attr:`ImportSummary.warnings`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rovslam.errors import ImageReadError, OutputError
from rovslam.io.sequence import SequenceWriter
from rovslam.io.source import SourceDescription


@dataclass
class ImportSummary:
    """What ``import`` wrote: frames written, frames not written (unreadable) and the source's notes."""

    out: Path
    frames: int = 0
    unreadable: int = 0
    warnings: list[str] = field(default_factory=list)
    stopped: bool = False


def check_import_folder(out: Path) -> None:
    """Refuse an output that is a file, or a folder that already holds something."""
    from rovslam.io.output import check_output_folder

    check_output_folder(out, "--out")  # a file, a device, a FIFO, a link to nothing: not a folder
    if out.is_dir() and any(os.scandir(out)):
        raise OutputError(f"{out}: exists and is not empty; give a new or empty folder for the sequence.")
    if out.parent.exists() and not out.parent.is_dir():
        raise OutputError(f"{out}: the folder {out.parent} is a file; give another place for the sequence.")


def import_metadata(description: SourceDescription, inputs: dict[str, Any]) -> dict[str, Any]:
    """The ``[metadata]`` keys of an imported sequence: where it came from, and its heading and altitude."""
    meta: dict[str, Any] = {
        "generator": "rovslam import",
        "imported_from": description.path,
        "imported_kind": description.kind,
    }
    for key in ("heading_input", "heading_detail", "altitude_input", "altitude_detail", "attitude_detail"):
        value = getattr(description, key)
        if value:
            meta[key] = value
    if inputs:
        meta["import_options"] = {k: v for k, v in inputs.items() if v is not None}
    return meta


def import_source(
    source: Any,
    out: str | Path,
    description: SourceDescription,
    inputs: dict[str, Any] | None = None,
    image_format: str = "png",
    max_frames: int | None = None,
    on_frame: Callable[[int, int], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> ImportSummary:
    """Write ``source`` (see :mod:`rovslam.io.source`) as a sequence folder ``out``; returns what was written.

    ``on_frame(done, total)`` reports progress; ``should_stop()`` ends the import early (a signal):
    the frames written so far form a complete, readable sequence.
    """
    out_dir = Path(out)
    check_import_folder(out_dir)
    info = source.info
    meta = {**info.metadata, **import_metadata(description, inputs or {})}
    info = dataclasses.replace(info, metadata=meta)
    summary = ImportSummary(out_dir)
    total = len(source) if max_frames is None else min(len(source) or max_frames, max_frames)
    frames = source.frames(stop=max_frames)
    try:
        with SequenceWriter(
            out_dir,
            info,
            image_format=image_format,
            with_attitude=description.attitude_detail is not None,
            with_groundtruth=False,
        ) as writer:
            for frame in frames:
                if frame.image is None:
                    summary.unreadable += 1
                    if len(summary.warnings) < 20:
                        summary.warnings.append(f"not written: {frame.error}")
                else:
                    att = frame.has_attitude
                    writer.write_frame(
                        frame.t_s,
                        frame.image,
                        frame.heading_rad if math.isfinite(frame.heading_rad) else math.nan,
                        frame.sonar_altitude_m,
                        frame.roll_rad if att else None,
                        frame.pitch_rad if att else None,
                    )
                    summary.frames += 1
                if on_frame is not None:
                    on_frame(summary.frames + summary.unreadable, total)
                if should_stop is not None and should_stop():
                    summary.stopped = True
                    break
    finally:
        frames.close()
    summary.warnings += list(getattr(source, "warnings", []))
    if summary.frames == 0:
        raise ImageReadError(
            f"{description.path}: no frame could be decoded, so {out_dir} holds no usable sequence"
            + (f" (first: {summary.warnings[0]})." if summary.warnings else ".")
        )
    return summary
