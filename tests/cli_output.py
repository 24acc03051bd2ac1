"""What the tests check of a refused command's output (shared by the bad-input and output-safety tests)."""

from __future__ import annotations


def one_error_line(res, *needles: str) -> str:
    """The single `rovslam: error:` line of a refused command (exit 2, no traceback), holding every needle."""
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error:"), res.output
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]
