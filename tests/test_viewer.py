"""The live viewer: a short run saves an .rrd that rerun reads back, with the expected entities and values."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from rovslam.cli import app
from rovslam.io.run_results import read_results
from rovslam.runner import run_sequence
from rovslam.sim import simulate
from rovslam.viz.viewer import ENTITY_PATHS, RerunViewer, entity_paths_in, scalar_series

N = 25


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    root = tmp_path_factory.mktemp("viewer")
    simulate("portofino-short", root / "seq", frames=N, seed=1)
    return root / "seq"


def test_a_short_run_saves_an_rrd_that_rerun_reads_back(seq, tmp_path):
    rrd = tmp_path / "live.rrd"
    viewer = RerunViewer(save_path=rrd, map_every=5)
    run_sequence(seq, tmp_path / "out", on_frame_image=viewer)
    viewer.close()
    counts = entity_paths_in(rrd)
    assert set(ENTITY_PATHS) <= set(counts), set(ENTITY_PATHS) - set(counts)
    for path in ("camera/image", "camera/lasers", "camera/tokens", "map/vehicle", "series/altitude_m"):
        assert counts[path] == N, (path, counts[path])
    assert counts["map/path"] >= N // 5
    res = read_results(tmp_path / "out")
    frames, alt = scalar_series(rrd, "series/altitude_m")
    assert np.array_equal(frames, np.arange(N))
    np.testing.assert_allclose(alt, res.trajectory["altitude_m"], rtol=1e-7)
    _, heading = scalar_series(rrd, "series/heading_deg")
    np.testing.assert_allclose(heading, np.degrees(res.trajectory["heading_rad"]), rtol=1e-6, atol=1e-9)
    # rerun's own command-line tool accepts the file
    rerun_cli = [sys.executable, "-m", "rerun", "rrd", "verify", str(rrd)]
    assert subprocess.run(rerun_cli, capture_output=True, timeout=120).returncode == 0


def test_viewer_without_a_display_saves_the_recording_and_says_so(seq, tmp_path, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["run", str(seq), "--out", str(out), "--quiet", "--viewer", "--max-frames", "8"])
    assert res.exit_code == 0, res.output
    assert "no display" in res.output and (out / "run.rrd").is_file()
    assert entity_paths_in(out / "run.rrd")["camera/image"] == 8


def test_no_viewer_means_rerun_is_never_imported(seq, tmp_path):
    code = (
        "import sys; from rovslam.runner import run_sequence; "
        f"run_sequence({str(seq)!r}, {str(tmp_path / 'o')!r}, max_frames=3); "
        "print('rerun' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "False", out.stderr
