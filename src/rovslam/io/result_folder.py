"""The ``--out`` folder of a run: which of its files are rovslam's, and readying it for new results.

:func:`prepare_output_folder` refuses an ``--out`` that holds an earlier run (unless ``overwrite``,
which deletes only rovslam's own result files: ``RESULT_FILES`` and ``RESULT_DIRS``) or files
rovslam did not write. Every error is an :class:`~rovslam.errors.OutputError` naming the folder.
"""

from __future__ import annotations

import re
from pathlib import Path

from rovslam.errors import OutputError
from rovslam.io.output import RESERVE_NAME, check_output_folder, output_errors

# Everything rovslam writes into a results folder (run, eval, report), so --overwrite knows what
# it may delete. Other writers of the folder add their names here.
RESULT_FILES = frozenset(
    {
        "trajectory.csv",
        "trajectory.tum",
        "observations.csv",
        "landmarks.csv",
        "summary.json",
        "config.toml",
        "eval.json",
        "tokens.csv",
        "run.rrd",
        "mosaic.png",
        "mosaic.pgw",
        "mosaic_truth.png",
        "mosaic_truth.pgw",
        "measurements.csv",
        "landmark_measurements.csv",
        "trajectory_smoothed.tum",
        "trajectory_smoothed.csv",
        "landmarks_smoothed.csv",
        # rovslam navigate
        "groundtruth.csv",
        "navigation.csv",
        "arrivals.csv",
        "navigation.png",
        RESERVE_NAME,
    }
)
# Folders rovslam writes, with the pattern of their files' paths relative to the folder.
RESULT_DIRS = {
    "landmarks": re.compile(r"\d+\.png"),
    "report": re.compile(r"[\w.-]+\.(png|html|json|svg|csv|pgw|jpg)"),
    "revisits": re.compile(r"\d+/\d+\.png"),
}
_TMP = re.compile(r"\.(?P<atomic>.+)\.[0-9a-f]{8}\.tmp|(?P<legacy>.+)\.tmp")


def _is_ours(name: str, pattern: re.Pattern[str] | None = None) -> bool:
    """Whether ``name`` is a result file rovslam writes (or one of its temporary files)."""
    head, _, leaf = name.rpartition("/")
    m = _TMP.fullmatch(leaf)
    for n in (leaf, m and (m["atomic"] or m["legacy"])):
        if n and (pattern.fullmatch(f"{head}/{n}" if head else n) if pattern is not None else n in RESULT_FILES):
            return True
    return False


def classify_output_folder(out: Path) -> tuple[list[Path], list[str]]:
    """(rovslam's own result entries, deepest first, names of the other entries) of an existing folder."""
    ours: list[Path] = []
    foreign: list[str] = []
    with output_errors(out, "cannot list"):
        for entry in sorted(out.iterdir()):
            name = entry.name
            pattern = RESULT_DIRS.get(name)
            if pattern is not None and entry.is_dir() and not entry.is_symlink():
                inside = sorted(entry.rglob("*"), key=lambda q: (-len(q.parts), str(q)))  # children before folders
                for child in inside:
                    rel = child.relative_to(entry).as_posix()
                    if child.is_dir() and not child.is_symlink():
                        ours.append(child)  # deleted only when nothing foreign is anywhere in the folder
                    elif (child.is_file() or child.is_symlink()) and _is_ours(rel, pattern):
                        ours.append(child)
                    else:
                        foreign.append(f"{name}/{rel}")
                ours.append(entry)
            elif (entry.is_file() or entry.is_symlink()) and _is_ours(name):
                ours.append(entry)
            else:
                foreign.append(name)
    return ours, foreign


def prepare_output_folder(out: str | Path, overwrite: bool = False) -> Path:
    """Make ``out`` ready for a run's results, or raise :class:`OutputError` saying why not.

    A new or empty folder is used as it is. A folder holding an earlier run's results is refused
    unless ``overwrite``, which deletes those files first (only names rovslam writes: see
    ``RESULT_FILES`` and ``RESULT_DIRS``). A folder holding anything else is always refused: rovslam
    never deletes or mixes in files it did not write.
    """
    out = check_output_folder(out, "--out")
    if not out.exists():
        with output_errors(out, "cannot create the folder"):
            out.mkdir(parents=True)
        return out
    ours, foreign = classify_output_folder(out)
    if foreign:
        shown = ", ".join(foreign[:4]) + (f" and {len(foreign) - 4} more" if len(foreign) > 4 else "")
        raise OutputError(
            f"{out}: holds files rovslam did not write ({shown}); give --out a new or empty folder "
            "(--overwrite only ever deletes rovslam's own result files)."
        )
    if ours and not overwrite:
        shown = ", ".join(p.name for p in ours if p.parent == out)
        raise OutputError(
            f"{out}: holds the results of an earlier run ({shown}); add --overwrite to replace them, or choose another --out."
        )
    for entry in ours:  # children come before their folder
        with output_errors(entry, "cannot delete"):
            if entry.is_dir() and not entry.is_symlink():
                entry.rmdir()
            else:
                entry.unlink()
    return out
