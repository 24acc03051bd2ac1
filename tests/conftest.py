"""Shared pytest hooks: one closing line counting the tests skipped for sample data."""

from __future__ import annotations

import collections
import re

from datasets import SKIP_PREFIX


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    skipped = terminalreporter.stats.get("skipped", [])
    names: collections.Counter[str] = collections.Counter()
    for report in skipped:
        text = str(getattr(report, "longrepr", ""))
        if SKIP_PREFIX in text:
            m = re.search(r"dataset '([^']+)'", text)
            names[m.group(1) if m else "?"] += 1
    if names:
        which = ", ".join(f"{n} ({k})" for n, k in sorted(names.items()))
        terminalreporter.write_line(
            f"{sum(names.values())} tests skipped for sample data not on this machine: {which}; "
            "set ROVSLAM_DATA to the folder that holds them (docs/data.md)."
        )
