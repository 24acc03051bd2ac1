"""The sample data the tests use, found only through :mod:`rovslam.data` (never by a path of their own).

A test that needs a dataset is marked ``@needs("sparus")``; on a machine without it the test is
skipped with a reason that starts with :data:`SKIP_PREFIX`, names the dataset and says how to
get it, and ``conftest.py`` counts those skips in one line at the end of the run.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rovslam import data

SKIP_PREFIX = "needs data:"


def skip_reason(name: str) -> str:
    return (
        f"{SKIP_PREFIX} dataset '{name}' is not on this machine; set {data.DATA_ENV} to a folder holding "
        f"{name}/ (the project's shared data), see docs/data.md"
    )


def needs(name: str) -> pytest.MarkDecorator:
    """Skip the test unless dataset ``name`` can be had without a download."""
    return pytest.mark.skipif(not data.available(name), reason=skip_reason(name))


def folder(name: str) -> Path:
    """The dataset's folder when it is available; else where it would be (tests marked ``needs`` skip)."""
    if data.available(name):
        return data.path(name, download=False)
    return data.data_folder() / name


def skip_unless(name: str) -> None:
    """Inside a test: skip it (with the counted reason) unless dataset ``name`` is available."""
    if not data.available(name):
        pytest.skip(skip_reason(name))
