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


class ImageReadError(RovslamError):
    """An image file is missing, unreadable or of an unsupported shape / type."""


class InvalidMeasurementError(RovslamError, ValueError):
    """A measurement (speed, heading, altitude, pixel) is NaN, infinite or out of range."""


class FilterInconsistencyError(RovslamError):
    """The filter covariance lost symmetry or positive semi-definiteness beyond repair."""


class SimulationError(RovslamError):
    """A simulation request is invalid (unknown scenario, bad frame count, bad texture)."""
