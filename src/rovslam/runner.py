"""Run the pipeline over a sequence and write the result files (the edge between core and disk).

How a run ends (``summary.json`` ``status``, and what :func:`run_sequence` does):

* ``"complete"``: every frame processed; returns the :class:`RunSummary`.
* ``"interrupted"``: SIGINT (Ctrl-C), SIGTERM (a scheduler, ``kill``) or SIGHUP (the terminal
  closed) all end a run the same way: the frame in hand is finished and written, every file is
  closed complete and readable, ``summary.json`` says ``"interrupted": true`` and the signal's
  name; further signals are ignored while this happens. Returns the summary (``signal`` set);
  the CLI exits with 128 + the signal number (130 for Ctrl-C).
* ``"unusable"``: fewer than ``[run] min_usable_fraction`` of the frames were usable, or an estimate
  left the plausible range (a position farther than ``[run] max_distance_m`` from the start, or not
  finite: the filter diverged). Such an estimate is never written; the files hold what came
  before it. Raises :class:`~rovslam.errors.UnusableRunError` once the files are written.
* ``"failed"``: an output error (full disk, read-only folder) or an input error found
  mid-run. Raises it (an :class:`~rovslam.errors.OutputError` for output problems) once
  whatever can still be written is: the streamed files cut back to their last complete row,
  then (in the space held back from the start) ``summary.json`` saying why, ``landmarks.csv``.

While a run goes, ``summary.json`` says ``"status": "running"``: a folder left in that state
was cut off by something no program can catch (SIGKILL, power loss).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovslam import __version__
from rovslam.config import RunConfig, to_dict
from rovslam.core import Frame
from rovslam.errors import (
    ConfigError,
    InvalidArgumentError,
    OutputError,
    SequenceFormatError,
    UnusableRunError,
)
from rovslam.io.camera_file import CAMERA_TABLES
from rovslam.io.results import GalleryWriter, ResultWriter, describe_os_error, prepare_output_folder
from rovslam.io.sequence import Sequence, open_sequence
from rovslam.io.source import InputOptions, SourceDescription, option_flag
from rovslam.pipeline import FrameResult, SlamPipeline, prepare_process
from rovslam.pipeline.prepare import PreparedFrame, prepared_frames
from rovslam.process import keep_freed_memory, opencv_threads, usable_cores
from rovslam.tallies import MapTally, SourceTally, TimeGaps
from rovslam.vision.scale import processing_scale

STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")


@dataclass(frozen=True)
class RunSummary:
    frames: int
    total_frames: int
    skipped: list[tuple[int, float, str]]
    landmarks: int
    wall_s: float
    interrupted: bool
    out_dir: Path
    signal: str | None = None  # "SIGINT", "SIGTERM" or "SIGHUP" when interrupted by one
    signum: int | None = None
    status: str = "complete"  # "complete" | "interrupted" | "unusable" | "failed"
    reason: str | None = None
    sonar_rejected: list[tuple[int, float, str]] = field(default_factory=list)
    warnings: list[str] = field(
        default_factory=list
    )  # what the source left out (a damaged video), a map that was not used

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else float("inf")

    @property
    def exit_code(self) -> int:
        """The shell convention for the way the run ended: 0, or 128 + the signal number."""
        return 128 + self.signum if self.signum is not None else 0


class StopRequest:
    """While active, SIGINT, SIGTERM and SIGHUP set :attr:`signum` instead of ending the process.

    The first signal is kept; later ones are ignored, so a second Ctrl-C while the files are
    being finalised cannot cut them short. Outside the main thread (where Python cannot install
    handlers) nothing is installed and a run stops only on KeyboardInterrupt.
    """

    def __init__(self) -> None:
        self.signum: int | None = None
        self.ignore_after = False  # True: leave the signals ignored on exit (a process about to end)
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            for name in STOP_SIGNALS:
                sig = getattr(signal, name, None)
                if sig is not None:
                    self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, _frame: object = None) -> None:
        if self.signum is None:
            self.signum = int(signum)

    def request(self, signum: int) -> None:
        """Record a stop as if ``signum`` had arrived (a KeyboardInterrupt raised by a callback)."""
        self._handle(signum)

    @property
    def name(self) -> str | None:
        return None if self.signum is None else signal.Signals(self.signum).name

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._previous.items():
            signal.signal(sig, signal.SIG_IGN if self.ignore_after else old if old is not None else signal.SIG_DFL)


def open_source(path: str | Path, camera_file: str | Path | None = None, options: InputOptions | None = None):
    """Any input of ``rovslam run`` as a source of frames (anything with ``.info``, ``.frames()``, ``.description``).

    A sequence folder; a video, an image folder or a ROS bag with its camera file
    (``options.camera_file``, or ``camera_file``); a NAV.csv attached to a video or an image folder.
    Options that do not apply to the input are refused (one line naming them).
    """
    from rovslam.io.bag import bag_location, open_bag

    opts = options or InputOptions()
    if camera_file is not None and opts.camera_file is None:
        opts = dataclasses.replace(opts, camera_file=Path(camera_file))
    p = Path(path)
    if not p.exists():
        raise SequenceFormatError(f"{p}: not found. Give a sequence folder, a video, a ROS bag or a folder of images.")
    bag = bag_location(p)
    if bag is not None:
        _refuse_options(p, bag[1], opts, fps=True, times=True, nav=True)
        return open_bag(bag[0], _camera_file(p, bag[1], opts), opts)
    if p.is_dir():
        from rovslam.io.folder import ImageFolderSource, is_image_folder

        if (p / "sequence.toml").exists() or (p / "frames.csv").exists():
            _refuse_options(
                p,
                "a sequence folder (its times and navigation are in frames.csv)",
                opts,
                bag=True,
                fps=True,
                times=True,
                nav=True,
            )
            return open_sequence(p)
        _refuse_options(p, "a folder that is not a ROS bag", opts, bag=True)
        if not is_image_folder(p):
            raise SequenceFormatError(
                f"{p}: no sequence.toml, frames.csv or image files (PNG, JPEG, TIFF) in this folder: it is not a sequence "
                "folder, a folder of images or a ROS 2 bag (metadata.yaml)."
            )
        missing = [
            flag
            for flag, absent in (
                ("--camera CAMERA.toml", opts.camera_file is None),
                ("--fps F or --times FILE", opts.fps is None and opts.times_file is None),
            )
            if absent
        ]
        if missing:
            raise SequenceFormatError(
                f"{p}: a folder of images without sequence.toml and frames.csv runs with --camera CAMERA.toml "
                f"({CAMERA_TABLES}) and --fps F or --times FILE (README, 'Your own dive'); missing: "
                f"{' and '.join(missing)}. Or make it a sequence folder (docs/formats.md, 'Sequence folder (format v1)')."
            )
        src = ImageFolderSource(p, _camera_file(p, "image folder", opts), opts.fps, opts.times_file)
        return _with_navigation(src, opts, src.span_s, "image folder")
    from rovslam.io.video import VIDEO_SUFFIXES, VideoSource, is_video

    _refuse_options(p, "a file that is not a ROS bag (.bag, or a ROS 2 folder)", opts, bag=True, fps=True, times=True)
    if p.suffix.lower() not in VIDEO_SUFFIXES and not is_video(p):
        raise SequenceFormatError(
            f"{p}: neither a sequence folder, a ROS bag, a folder of images nor a video FFmpeg can read "
            f"({', '.join(VIDEO_SUFFIXES)}, ...)."
        )
    cam = _camera_file(p, "video", opts)
    src = VideoSource(p, cam.info)  # type: ignore[assignment]
    return _with_navigation(src, opts, src.span_s, "video", cam)


def _camera_file(path: Path, kind: str, opts: InputOptions):
    from rovslam.io.camera_file import read_camera_file

    if opts.camera_file is None:
        raise SequenceFormatError(f"{path}: a {kind} needs --camera CAMERA.toml, a camera file with {CAMERA_TABLES}.")
    return read_camera_file(opts.camera_file, name=path.stem or path.name)


def _with_navigation(src: Any, opts: InputOptions, span_s: tuple[float, float] | None, what: str, camera: Any = None):
    """``src`` with the NAV.csv of ``opts`` attached (or ``src`` itself without one)."""
    if opts.nav_file is None:
        if opts.nav_map or opts.nav_time_offset_s is not None:
            raise SequenceFormatError(
                "--nav-map and --nav-time-offset describe a navigation log: give it with --nav NAV.csv."
            )
        return src
    from rovslam.io.nav import NavigatedSource, nav_mapping, read_nav_csv

    cam = camera if camera is not None else src.camera_file
    mapping = nav_mapping(cam.nav, f"{cam.path}: [nav]", opts.nav_map, opts.nav_time_offset_s)
    return NavigatedSource(src, read_nav_csv(opts.nav_file, mapping), span_s, what)


def _refuse_options(
    path: Path,
    kind: str,
    opts: InputOptions,
    *,
    bag: bool = False,
    fps: bool = False,
    times: bool = False,
    nav: bool = False,
) -> None:
    """Refuse the options that do not apply to ``path`` (``kind`` says what it is)."""
    given = [option_flag(k) for k in opts.bag_options] if bag else []
    given += ["--fps"] if fps and opts.fps is not None else []
    given += ["--times"] if times and opts.times_file is not None else []
    given += [option_flag(k) for k in opts.nav_options] if nav else []
    if given:
        raise SequenceFormatError(
            f"{path}: {', '.join(given)} cannot be used with {kind}: the topic options apply to a ROS bag, --fps and "
            "--times to a folder of images, --nav to a video or a folder of images (a bag's navigation comes from its "
            "topics: --heading-topic, --altitude-topic, --attitude-topic)."
        )


def check_run_arguments(max_frames: int | None, min_usable_fraction: float, max_distance_m: float) -> None:
    """Refuse limits that would silently change the answer (``max_frames`` 0 or negative, ...)."""
    if max_frames is not None and (isinstance(max_frames, bool) or not isinstance(max_frames, int) or max_frames < 1):
        raise InvalidArgumentError(f"max_frames must be a whole number >= 1 (or None for all), got {max_frames!r}")
    if not (isinstance(min_usable_fraction, (int, float)) and 0.0 <= min_usable_fraction <= 1.0):
        raise InvalidArgumentError(f"min_usable_fraction must be from 0 to 1, got {min_usable_fraction!r}")
    if not (isinstance(max_distance_m, (int, float)) and math.isfinite(max_distance_m) and max_distance_m > 0):
        raise InvalidArgumentError(f"max_distance_m must be a positive number of metres, got {max_distance_m!r}")


def check_source_against_config(info: Any, config: RunConfig, fallback_altitude_m: float, where: str) -> None:
    """Refuse a source whose fallback altitude or image size the configuration cannot work with.

    ``fallback_altitude_m``: the altitude used when neither lasers nor sonar give one
    (``[vehicle] altitude_m``, or the pipeline's default).
    """
    lo, hi = config.laser.min_altitude_m, config.laser.max_altitude_m
    if not lo <= fallback_altitude_m <= hi:
        given = (
            "vehicle.altitude_m"
            if info.fixed_altitude_m is not None
            else "the default altitude (no [vehicle] altitude_m)"
        )
        raise SequenceFormatError(
            f"{where}: {given} = {fallback_altitude_m:g} m is outside the plausible altitude range [{lo:g}, {hi:g}] m "
            "(laser.min_altitude_m, laser.max_altitude_m of the configuration)."
        )
    cam = info.camera
    lm = config.landmark_templates
    need = lm.size_px + 2 * lm.border_px + 2
    if min(cam.width_px, cam.height_px) < need:
        raise SequenceFormatError(
            f"{where}: images of {cam.width_px}x{cam.height_px} px are too small: a landmark template "
            f"({lm.size_px} px) with its border ({lm.border_px} px) needs at least {need}x{need} px."
        )
    processed = processing_scale(cam, config.processing, fallback_altitude_m).camera
    for table, size_px in (("speed_templates", config.speed_templates.size_px), ("landmark_templates", lm.size_px)):
        if size_px > min(processed.width_px, processed.height_px):
            raise ConfigError(
                f"[{table}] size_px = {size_px} of the configuration: a template larger than the images of {where} "
                f"({processed.width_px}x{processed.height_px} px as processed); give a smaller size_px "
                "in the configuration (the paper's: 16 for speed, 32 for landmarks)."
            )


def implausible_result(res: FrameResult, max_distance_m: float) -> str | None:
    """Why a frame's estimate cannot be right, or None.

    Not finite, farther than ``max_distance_m`` from the start (estimate or dead reckoning), or
    with a 1-sigma position uncertainty beyond ``max_distance_m``.
    """
    values = (
        res.t_s,
        res.x_m,
        res.y_m,
        res.altitude_m,
        res.heading_rad,
        res.dr_x_m,
        res.dr_y_m,
        *(float(v) for v in res.cov_xy_m2.ravel()),
    )
    if not all(math.isfinite(v) for v in values):
        return "the estimate is not finite (NaN or infinite): the filter diverged"
    for label, x, y in (("position", res.x_m, res.y_m), ("dead-reckoning position", res.dr_x_m, res.dr_y_m)):
        d = math.hypot(x, y)
        if d > max_distance_m:
            return (
                f"{label} ({x:.4g}, {y:.4g}) m is {d:.4g} m from the start, beyond max_distance_m = {max_distance_m:g} m: "
                "the estimate diverged (check the focal length, altitudes and time stamps) or, for a longer dive, "
                "raise --max-distance-m"
            )
    sigma_m = math.sqrt(max(res.cov_xy_m2[0, 0], res.cov_xy_m2[1, 1], 0.0))
    if sigma_m > max_distance_m:
        return (
            f"the position uncertainty (1 sigma {sigma_m:.4g} m) exceeds max_distance_m = {max_distance_m:g} m: "
            f"the estimate says nothing (a time gap of {res.dt_s:.4g} s before this frame?)"
        )
    return None


def run_sequence(
    sequence_dir: str | Path | Any,  # or an opened source (rovslam live)
    out_dir: str | Path,
    config: RunConfig = RunConfig(),
    max_frames: int | None = None,
    on_frame: Callable[[FrameResult], None] | None = None,
    camera_file: str | Path | None = None,
    on_start: Callable[[int], None] | None = None,
    on_frame_image: Callable[[Frame, FrameResult, Callable[[], list[dict]]], None] | None = None,
    *,
    overwrite: bool = False,
    min_usable_fraction: float | None = None,
    max_distance_m: float | None = None,
    inputs: InputOptions | None = None,
    read_ahead: bool | None = None,
) -> RunSummary:
    """Run SLAM on a sequence folder (or video) and write ``out_dir``; see the module notes for how it ends.

    ``on_start`` is called once with the number of frames to process (0: unknown, a stream);
    ``on_frame`` with each result record (progress bars, live viewers).
    ``on_frame_image(frame, result, landmark_rows)`` also gets the decoded frame and a function
    returning the current map as landmarks.csv rows (the live viewer; called only when given).
    ``overwrite``: replace an earlier run's results in ``out_dir`` (never files rovslam did not write).
    ``inputs``: how to open an input that is not a sequence folder (camera file, NAV.csv, topics, times).
    ``read_ahead``: prepare the frames ahead of the loop, on a thread or in a process (:mod:`~rovslam.pipeline.prepare`,
    :mod:`~rovslam.pipeline.prepare_process`; the same results, sooner); None: when the
    process may use two cores or more and the source allows it (a live stream does not: its newest
    frame is the one to process).
    """
    min_usable_fraction = config.run.min_usable_fraction if min_usable_fraction is None else min_usable_fraction
    max_distance_m = config.run.max_distance_m if max_distance_m is None else max_distance_m
    check_run_arguments(max_frames, min_usable_fraction, max_distance_m)
    keep_freed_memory()
    with StopRequest() as stop, opencv_threads(1):
        opts = inputs or InputOptions()
        if camera_file is not None and opts.camera_file is None:
            opts = dataclasses.replace(opts, camera_file=Path(camera_file))
        given = hasattr(sequence_dir, "frames")  # an opened source (rovslam live's stream) instead of a path
        seq: Any = sequence_dir if given else open_source(sequence_dir, options=opts)
        path = Path(seq.path if given else sequence_dir)
        pipe = SlamPipeline(seq.info, config)
        cam = opts.camera_file
        where = str(cam if cam is not None and not isinstance(seq, Sequence) else path / "sequence.toml")
        check_source_against_config(seq.info, config, pipe.altimeter_fallback, where)
        out = prepare_output_folder(out_dir, overwrite)
        writer = ResultWriter(out)
        try:
            run = _Run(seq, pipe, writer, GalleryWriter(out), out, config, stop, min_usable_fraction, max_distance_m)
        except OutputError as exc:  # a disk full from the start: the folder still says why
            writer.abandon(str(exc))
            raise
        run.summary_base["sequence"] = str(path if given else path.resolve())
        run.summary_base.update(getattr(seq, "summary_blocks", {}))  # a source's own blocks (live: filled as it goes)
        run.summary_base["camera_file"] = str(Path(cam).resolve()) if cam is not None else None
        run.summary_base["inputs"] = opts.to_dict()
        run.fallback_detail = _fallback_detail(seq.info, where, pipe.altimeter_fallback)
        run.rig_note = _rig_note(seq.info, config, where)
        if read_ahead is None:
            read_ahead = usable_cores() >= 2 and getattr(seq, "read_ahead", True)
        run.read_ahead = bool(read_ahead)
        return run.execute(max_frames, on_frame, on_start, on_frame_image)


def _fallback_detail(info: Any, where: str, altitude_m: float) -> str:
    """Where the altitude assumed without laser and sonar comes from."""
    if info.fixed_altitude_m is not None:
        return f"{altitude_m:g} m, [vehicle] altitude_m of {where}"
    return f"{altitude_m:g} m, [laser] assumed_altitude_m of the configuration (no [vehicle] altitude_m in {where})"


def _rig_note(info: Any, config: RunConfig, where: str) -> str:
    """A warning for the pointers whose spot never falls inside the image ("" if none)."""
    from rovslam.vision.laser import lasers_never_in_view

    lost = lasers_never_in_view(info.camera, info.lasers, config.laser.min_altitude_m, config.laser.max_altitude_m)
    if not lost:
        return ""
    names = ", ".join(f"#{i + 1} (origin_m {list(info.lasers[i].origin_m)})" for i in lost)
    return (
        f"the spot of [[laser]] {names} of {where} never falls inside the image at any altitude from "
        f"{config.laser.min_altitude_m:g} to {config.laser.max_altitude_m:g} m, so it gives no altitude: origin_m "
        "is in metres (forward, starboard, down from the camera centre) and direction along the beam; check both"
    )


class _Run:
    """One run's loop and its finalisation (kept apart so that every way out writes the same files)."""

    def __init__(
        self,
        seq: Any,
        pipe: SlamPipeline,
        writer: ResultWriter,
        gallery: GalleryWriter,
        out: Path,
        config: RunConfig,
        stop: StopRequest,
        min_usable_fraction: float,
        max_distance_m: float,
    ) -> None:
        self.seq, self.pipe, self.writer, self.out, self.config, self.stop = seq, pipe, writer, out, config, stop
        self.gallery = gallery
        from rovslam.io.measurements import MeasurementWriter

        self.measurements = MeasurementWriter(out)  # what `rovslam smooth` rebuilds the problem from
        self.min_usable_fraction = float(min_usable_fraction)
        self.max_distance_m = float(max_distance_m)
        self.n = 0
        self.total = len(seq)
        self.read_ahead = False  # frames prepared ahead (rovslam.pipeline.prepare, prepare_process)
        self.sonar_rejected: list[tuple[int, float, str]] = []
        self.status = "running"
        self.reason: str | None = None
        self.fallback_detail = ""
        self.rig_note = ""
        self.tally: SourceTally | None = None
        self.map_use = MapTally()
        self.time_gaps = TimeGaps()
        self.summary_base: dict[str, Any] = {
            "software": {"name": "rovslam", "version": __version__},
            "sequence_name": seq.info.name,
            "frames_in_sequence": len(seq),
        }

    @property
    def sources(self) -> SourceTally:
        if self.tally is None:
            self.tally = SourceTally(describe_source(self.seq), self.fallback_detail, self.rig_note)
        return self.tally

    def execute(self, max_frames: int | None, on_frame: Any, on_start: Any, on_frame_image: Any = None) -> RunSummary:
        from rovslam.vision.laser import sonar_reading_problem

        seq, pipe, writer = self.seq, self.pipe, self.writer
        error: BaseException | None = None
        t0 = time.perf_counter()
        frames = None
        try:
            writer.write_config(self.config)
            writer.write_summary(self._summary(0.0))
            self.total = len(seq) if max_frames is None else (min(len(seq), max_frames) if len(seq) else max_frames)
            if on_start is not None:
                on_start(self.total)
            frames = self._frames(max_frames)
            for frame, prepared in frames:
                if self.stop.signum is not None:
                    break
                res = pipe.process(frame, prepared)
                problem = implausible_result(res, self.max_distance_m)
                if problem is not None:
                    self.status, self.reason = "unusable", f"frame {res.index} (t={res.t_s:g} s): {problem}"
                    break
                writer.write_frame(res)
                self.measurements.write(res.measurements)  # type: ignore[arg-type]
                self.sources.add(frame, res)
                self.map_use.add(res)
                self.time_gaps.add(frame)
                self.gallery.write_frame(frame.image, res)
                if res.new_landmark_id is not None:
                    writer.write_landmark_template(res.new_landmark_id, pipe.landmarks[res.new_landmark_id].patch)
                sonar_problem = sonar_reading_problem(frame.sonar_altitude_m, self.config.laser)
                if sonar_problem is not None and res.skipped_reason is None:
                    self.sonar_rejected.append((frame.index, frame.t_s, sonar_problem))
                self.n += 1
                if on_frame is not None:
                    on_frame(res)
                if on_frame_image is not None:
                    on_frame_image(frame, res, pipe.landmark_rows)
                if self.stop.signum is not None:
                    break
        except KeyboardInterrupt:
            self.stop.request(signal.SIGINT)
        except OSError as exc:
            error = OutputError(f"{self.out}: cannot write: {describe_os_error(exc)}.")
        except BaseException as exc:  # an input error found mid-run, or a bug: the files still get finished
            error = exc
        finally:
            if frames is not None:
                frames.close()
        wall = time.perf_counter() - t0
        if error is not None:
            self.status, self.reason = "failed", str(error) or type(error).__name__
        elif self.stop.signum is not None:
            self.status = "interrupted"
        elif self.status == "running":
            self.status, self.reason = self._usable_verdict()
        error = self._finish(wall, error)
        if error is not None:
            raise error
        summary = self._run_summary(wall)
        if self.status == "unusable":
            unusable = UnusableRunError(f"{str(self.reason).rstrip('.')}; see {self.out / 'summary.json'}")
            unusable.summary = summary  # type: ignore[attr-defined]
            raise unusable
        return summary

    def _frames(self, max_frames: int | None) -> Generator[tuple[Frame, PreparedFrame | None], None, None]:
        """The frames with what was prepared of them ahead (none without read-ahead): a long sequence folder
        processed at its own size in a second process (:mod:`rovslam.pipeline.prepare_process`), any other
        source on a second thread (:mod:`rovslam.pipeline.prepare`; larger frames' decoding and reduction
        outweigh the loop, docs/performance.md)."""
        if (
            self.read_ahead
            and type(self.seq) is Sequence
            and self.pipe.scale.identity
            and self.total >= prepare_process.MIN_FRAMES
        ):
            return prepare_process.prepared_in_process(self.seq, max_frames, self.pipe.preparer())
        return prepared_frames(self._source_frames(max_frames), self.pipe.preparer(), self.read_ahead)

    def _source_frames(self, max_frames: int | None) -> Iterator[Frame]:
        """The source's frames. Read ahead, a sequence folder whose frames are processed at their own size
        is decoded by the read-ahead thread itself rather than by a thread of its own: one hand-off fewer
        (360x272 PNG on 2 cores: 8 to 11 % more frames/s); larger frames keep their decoding thread, which
        then shares the decoding with the preparation (1920x1080 JPEG: 6 % more, where decoding in the
        read-ahead thread is 5 % slower)."""
        if self.read_ahead and isinstance(self.seq, Sequence) and self.pipe.scale.identity:
            return self.seq.frames(stop=max_frames, prefetch=0)
        return self.seq.frames(stop=max_frames)

    def _usable_verdict(self) -> tuple[str, str | None]:
        usable = self.n - len(self.pipe.skipped)
        if self.n == 0:
            return "unusable", "no frame was read"
        if usable == 0 or usable < self.min_usable_fraction * self.n:
            kinds: dict[str, int] = {}
            for _, _, r in self.pipe.skipped:
                kinds[_reason_kind(r)] = kinds.get(_reason_kind(r), 0) + 1
            top = max(kinds, key=lambda k: kinds[k])
            return "unusable", (
                f"only {usable} of {self.n} frames were usable (fewer than min_usable_fraction = "
                f"{self.min_usable_fraction:g}); most skipped frames ({kinds[top]}): {top}"
            )
        return "complete", None

    def _finish(self, wall: float, error: BaseException | None) -> BaseException | None:
        """Close every file, then write landmarks.csv and summary.json; the first error wins."""
        writer = self.writer
        # Each in its own try, the trajectory first: one file that cannot be closed or written loses no other.
        for step in (
            lambda quiet=error is not None: writer.close(quiet=quiet),
            self.measurements.close,
            self.gallery.close,
            writer.release_reserve,  # the disk space held back, for what follows
            lambda: self.status == "failed" and writer.write_summary(self._summary(wall), compact=True),  # type: ignore[func-returns-value]
            lambda: writer.write_landmarks(self.pipe.landmark_rows()),
            lambda: writer.salvage(self._summary(wall)),
        ):  # rows a full disk kept out, if room is left
            try:
                step()
            except OutputError as exc:
                if error is None:
                    error = exc
                    self.status, self.reason = "failed", str(exc)
        if self.pipe.smoother is not None and self.n and error is None:
            try:  # the iSAM2 back end: the best estimate of the whole dive given all of it
                write_smoothed_result(self.out, self.pipe.smoother.smoothed(), self.pipe.config)
            except OSError as exc:
                error = OutputError(f"{self.out}: cannot write the smoothed results: {describe_os_error(exc)}.")
                self.status, self.reason = "failed", str(error)
        try:
            writer.write_summary(self._summary(wall))
        except OutputError as exc:
            error = error or exc
            if self.status != "failed":
                self.status, self.reason = "failed", str(exc)
            with contextlib.suppress(OutputError):  # the small summary fits where the whole one did not
                writer.write_summary(self._summary(wall), compact=True)
        return error

    def _summary(self, wall: float) -> dict[str, Any]:
        pipe = self.pipe
        return {
            **self.summary_base,
            "status": self.status,
            "complete": self.status == "complete",
            "interrupted": self.status == "interrupted",
            "signal": self.stop.name if self.status == "interrupted" else None,
            "reason": self.reason,
            "frames_processed": self.n,
            "frames_usable": self.n - len(pipe.skipped),
            "min_usable_fraction": self.min_usable_fraction,
            "max_distance_m": self.max_distance_m,
            "skipped_frames": [{"index": i, "t_s": t, "reason": r} for i, t, r in pipe.skipped],
            "sonar_rejected_frames": [{"index": i, "t_s": t, "reason": r} for i, t, r in self.sonar_rejected],
            "source": self.sources.description.to_dict(),
            "sources": self.sources.summary(),
            "source_warnings": list(getattr(self.seq, "warnings", [])),
            "map_use": {**self.map_use.summary(), "warnings": self.map_use.warnings()},
            "time_gaps": {"gaps": self.time_gaps.gaps(), "warnings": self.time_gaps.warnings()},
            **pipe.light_summaries(),
            "altitude_bias": pipe.altitude_bias_summary(),
            "compass": {**pipe.heading.compass_summary(), "warnings": pipe.heading.compass_warnings()},
            "source_frames_left_out": int(getattr(self.seq, "left_out", 0)),
            "landmarks": pipe.ekf.n_landmarks,
            "processing": {
                "scale": pipe.scale.scale,
                "width_px": pipe.camera.width_px,
                "height_px": pipe.camera.height_px,
            },
            "recoveries": [
                {
                    "frame": e.frame,
                    "t_s": e.t_s,
                    "offset_m": list(e.offset_m),
                    "landmarks": list(e.landmarks),
                    "cause": e.cause,
                }
                for e in pipe.recovery.events
            ],
            "wall_time_s": wall,
            "frames_per_second": self.n / wall if wall > 0 else None,
            "config": to_dict(self.config),
        }

    def _run_summary(self, wall: float) -> RunSummary:
        interrupted = self.status == "interrupted"
        return RunSummary(
            self.n,
            self.total,
            list(self.pipe.skipped),
            self.pipe.ekf.n_landmarks,
            wall,
            interrupted,
            self.out,
            signal=self.stop.name if interrupted else None,
            signum=self.stop.signum if interrupted else None,
            status=self.status,
            reason=self.reason,
            sonar_rejected=list(self.sonar_rejected),
            warnings=(
                list(getattr(self.seq, "warnings", []))
                + self.pipe.sunlight_warnings()
                + self.pipe.heading.compass_warnings()
                + self.map_use.warnings()
                + self.time_gaps.warnings()
                + ([self.rig_note] if self.rig_note else [])
            ),
        )


def describe_source(source: Any) -> SourceDescription:
    """The :class:`SourceDescription` of any source (a source without one: a stream of unknown origin)."""
    d = getattr(source, "description", None)
    return d if isinstance(d, SourceDescription) else SourceDescription("frames", str(getattr(source, "path", "")))


def _reason_kind(reason: str) -> str:
    """A skip reason without the file it names ("/x/images/1.png: not a readable ..." -> "not a readable ...")."""
    head, sep, rest = reason.partition(": ")
    return rest if sep and ("/" in head or "\\" in head or "#" in head) else reason


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
    relief_gain: float = float("nan")  # SmoothedResult.relief_gain


def write_smoothed_result(out_dir: Path, res, config=None) -> None:
    """Write a :class:`~rovslam.slam.smoother.SmoothedResult` as the smoothed trajectory and map files.

    The covariances written are the graph's plus the apparent frame's errors
    (:mod:`rovslam.slam.apparent`): the tilt each frame's AHRS left and the heading error the
    whole dive shares, as the online estimate's, and the altimeter's lasting error
    (``[slam] altitude_bias_sigma_m`` and ``altitude_scale_sigma``), which the graph, unlike the EKF, does not hold: a scale
    of the whole dive. ``config``: the run's :class:`~rovslam.config.RunConfig` (default: the
    defaults). The landmarks take the last frame's tilt and scale terms.
    """
    from rovslam.io.results import write_smoothed
    from rovslam.slam.apparent import apparent_frame_cov_m2, apparent_sigmas
    from rovslam.slam.motion import altitude_offset_sigma_m

    rot, altitude_sigma_m, altitude_scale = apparent_sigmas(RunConfig() if config is None else config, graph=True)
    n = len(res.t_s)
    tilt = np.zeros(n) if res.attitude_sigma_rad is None else res.attitude_sigma_rad
    compass = np.zeros(n, dtype=bool) if res.has_compass is None else res.has_compass
    scale = altitude_offset_sigma_m(altitude_sigma_m, altitude_scale, res.altitude_m) / res.altitude_m
    cov = res.cov_xy_m2 + apparent_frame_cov_m2(res.xy_m, res.altitude_m, tilt, np.where(compass, rot, 0.0), scale)
    lcov = res.landmarks_cov_m2
    if n and len(lcov):
        lcov = lcov + apparent_frame_cov_m2(
            res.landmarks_xy_m, res.altitude_m[-1], tilt[-1], rot if compass[-1] else 0.0, scale[-1]
        )
    rows = [
        {
            "id": int(i),
            "x_m": float(xy[0]),
            "y_m": float(xy[1]),
            "var_x_m2": float(c[0, 0]),
            "cov_xy_m2": float(c[0, 1]),
            "var_y_m2": float(c[1, 1]),
            "first_t_s": float(t),
            "observations": int(n),
            "downweighted": int(d),
            "height_m": float(h),
        }
        for i, xy, c, t, n, d, h in zip(
            res.landmark_ids,
            res.landmarks_xy_m,
            lcov,
            res.landmark_first_t_s,
            res.landmark_observations,
            res.landmark_downweighted,
            np.zeros(len(res.landmark_ids)) if res.landmark_height_m is None else res.landmark_height_m,
        )
    ]
    write_smoothed(out_dir, res.t_s, res.xy_m, cov, res.heading_rad, res.altitude_m, rows)


def run_config_for(out_dir: str | Path):
    """The :class:`~rovslam.config.RunConfig` a run wrote to its ``config.toml`` (the defaults when there is none)."""
    from rovslam.config import load_config

    path = Path(out_dir) / "config.toml"
    return load_config(path) if path.is_file() else RunConfig()


def smoother_config_for_run(out_dir: str | Path):
    """The ``[smoother]`` table of the run's ``config.toml`` (the defaults when there is none)."""
    return run_config_for(out_dir).smoother


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
    from rovslam.slam.smoother import Isam2Smoother

    out = Path(out_dir)
    frames = read_measurements(out)
    if not frames:
        raise ResultsFormatError(f"{out}: the measurement files hold no frame; nothing to smooth.")
    run_config = run_config_for(out)
    smoother = Isam2Smoother(config if config is not None else run_config.smoother)
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
    write_smoothed_result(out, res, dataclasses.replace(run_config, smoother=smoother.config))
    return SmoothSummary(
        frames=len(frames),
        landmarks=len(res.landmark_ids),
        observations=int(res.landmark_observations.sum()),
        downweighted=int(res.landmark_downweighted.sum()),
        online_s=t1 - t0,
        final_s=t2 - t1,
        out_dir=out,
        relief_gain=res.relief_gain,
    )
