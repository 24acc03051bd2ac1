"""Checks of the files and folders a command is given, shared by the commands (typed errors, one line)."""

from __future__ import annotations

from pathlib import Path


def check_output_file(path: Path, what: str) -> None:
    """Refuse an output file path that is a folder, a device, a FIFO, a socket or whose folder does not exist."""
    from rovslam.io.output import check_output_file as check

    check(path, what, example="eval.json")


def load_config(path: Path):
    """:func:`rovslam.config.load_config`, with a folder given to -c told so (it said "not found")."""
    from rovslam.config import load_config as load_toml
    from rovslam.errors import ConfigError

    if path.is_dir():
        raise ConfigError(f"{path}: is a folder; -c needs a TOML file (`rovslam config FILE.toml` writes one to edit).")
    return load_toml(path)


def check_sequence_of_run(results: Path, seq: Path | None, option: str) -> None:
    """Refuse a --seq / --sequence that is clearly another dive's (name or frame count unlike summary.json's)."""
    if seq is not None:
        from rovslam.io.run_results import check_sequence_of_run as check

        check(results, seq, option)
