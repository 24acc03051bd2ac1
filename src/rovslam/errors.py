"""Typed exceptions for bad input. Expected failures (a lost track) are return values, not these.

Every message says what was wrong, where (file, row, key) and how to fix it.
"""

from __future__ import annotations


class RovslamError(Exception):
    """Base class of every error rovslam raises for bad input or a bad environment."""


class ConfigError(RovslamError):
    """A configuration file or value is invalid (unknown key, wrong type, out of range)."""


class SequenceFormatError(RovslamError):
    """A sequence folder does not follow the rovslam sequence format v1."""


class NavigationError(RovslamError):
    """A navigation log (NAV.csv, its ``[nav]`` mapping, a bag's heading / altitude / attitude topic) that
    cannot be used: a missing column, an unknown unit or convention, a bad row, times that miss the frames."""


class BagError(RovslamError):
    """A ROS bag that cannot be read, or a topic that is missing or of a type rovslam does not read."""


class ImageReadError(RovslamError):
    """An image file is missing, unreadable or of an unsupported shape / type."""


class InvalidArgumentError(RovslamError, ValueError):
    """A function was called with an array of the wrong shape or type (a programming error at a stage boundary)."""


class ResultsFormatError(RovslamError):
    """A results folder (what ``rovslam run`` writes) is missing a file, a column, or holds unreadable values."""


class OutputError(RovslamError):
    """An output place cannot be used: read-only, full disk, a file where a folder is needed, or
    a folder holding an earlier run's results (``--overwrite``) or files rovslam did not write."""


class UnusableRunError(RovslamError):
    """A run ended but its result cannot be trusted: too few usable frames, or an estimate outside
    the plausible range (diverged). The files are written and ``summary.json`` says why."""


class InvalidMeasurementError(RovslamError, ValueError):
    """A measurement (speed, heading, altitude, pixel) is NaN, infinite or out of range."""


class FilterInconsistencyError(RovslamError):
    """The filter covariance lost symmetry or positive semi-definiteness beyond repair."""


class ClusterError(RovslamError):
    """A Dask cluster for ``rovslam batch`` cannot be reached, or is asked for in a way that cannot be."""


class PoiFormatError(RovslamError):
    """A points-of-interest file (``rovslam navigate --poi``): a missing column, a bad or duplicate row."""


class SimulationError(RovslamError):
    """A simulation request is invalid (unknown scenario, bad frame count, bad texture)."""


class DataNotFoundError(RovslamError):
    """A sample dataset (:mod:`rovslam.data`) is not on this machine and cannot be fetched."""


def finite_scalar(
    name: str, value: object, *, positive: bool = False, nonnegative: bool = False, nan_hint: str = "", suffix: str = ""
) -> float:
    """``value`` as a finite float, or :class:`InvalidMeasurementError` saying what was wrong.

    ``nan_hint`` completes the message for a NaN / infinite value ("a NaN ... cannot enter
    <nan_hint>"); ``suffix`` is appended to the range messages.
    """
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InvalidMeasurementError(f"{name} must be a number, got {value!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise InvalidMeasurementError(f"{name} is {v}: a NaN or infinite value cannot enter {nan_hint}")
    if positive and v <= 0.0:
        raise InvalidMeasurementError(f"{name} must be > 0, got {v}{suffix}")
    if nonnegative and v < 0.0:
        raise InvalidMeasurementError(f"{name} must be >= 0, got {v}{suffix}")
    return v


def parse_toml(text: str) -> dict:
    """``tomllib.loads(text)``; arrays or tables nested past Python's recursion limit are a ``TOMLDecodeError`` too.

    (tomllib parses nested arrays recursively: a file of a few thousand ``[`` would otherwise
    end in a RecursionError, an internal error, instead of the caller's bad-file message.)
    """
    import tomllib

    try:
        return tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError(
            "arrays or inline tables nested too deeply (more than a few hundred levels)"
        ) from None
