"""Issue 15 as a test: hostile and careless inputs give a right answer or one clear line, never a
traceback, and nothing outside the dive folder is read.

* The corpus of :mod:`fuzz_corpus` (broken sequences, configurations, videos, results folders,
  output places), each case through the real CLI, with an audit hook on ``open``.
* Hypothesis on the parsers (frames.csv, groundtruth.csv, sequence.toml, results files): a
  parser returns validated data or raises its typed error, nothing else.
* A few error cases in a real subprocess, so that native libraries' own stderr output counts.
* Marked slow: seeded byte-level mutations of every file of a sequence and of a results folder.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import fuzz_corpus as fc
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rovslam.errors import ResultsFormatError, SequenceFormatError

CASES = fc.all_cases()


@pytest.fixture(scope="module")
def shared(tmp_path_factory):
    return fc.build_shared(tmp_path_factory.mktemp("corpus"))


def test_the_corpus_covers_every_class_of_fault():
    groups = {c.group for c in CASES}
    assert groups == {"sequence", "config", "video", "results", "output", "navigation", "folder", "bag"}
    assert len(CASES) >= 175
    assert len({c.id for c in CASES}) == len(CASES)  # one folder per case
    assert sum(c.expect == "error" for c in CASES) >= 120 and sum(c.expect == "ok" for c in CASES) >= 40


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_corpus_case(case, shared):
    outcome = fc.run_case(case, shared)
    assert not outcome.problems, (case.id, outcome.problems, outcome.stderr)


def test_the_audit_hook_sees_a_read_outside(shared, tmp_path):
    """The check itself can fail: reading a bait file outside the case folder is caught."""
    with fc.recording_opens() as opened:
        (shared.outside / "bait.png").read_bytes()
        Path("/etc/passwd").read_bytes() if Path("/etc/passwd").is_file() else None
    bad = fc.opened_outside(opened, tmp_path, shared.root)
    assert str(shared.outside / "bait.png") in bad


def test_sonar_readings_outside_the_range_are_dropped_and_recorded(shared, tmp_path):
    from typer.testing import CliRunner

    from rovslam.cli import app
    from rovslam.io.run_results import read_results

    seq = tmp_path / "seq"
    shutil.copytree(shared.base_seq, seq)
    fc.set_cell(seq / "frames.csv", 3, "sonar_altitude_m", "1e6")
    fc.set_cell(seq / "frames.csv", 5, "sonar_altitude_m", "-2")
    res = CliRunner().invoke(app, ["run", str(seq), "--out", str(tmp_path / "out"), "-q"])
    assert res.exit_code == 0, res.stderr
    r = read_results(tmp_path / "out")
    rejected = r.summary["sonar_rejected_frames"]
    assert [x["index"] for x in rejected] == [2, 4]
    assert "1e+06 m outside the plausible range [0.05, 30] m" in rejected[0]["reason"]
    assert "sonar reading rejected, frame 2" in res.stderr
    # The rejected frames hold the altitude filtered from the readings before (not the assumed one);
    # the others use the sonar (1.3 m).
    src = list(r.trajectory["altitude_source"])
    assert src[2] == src[4] == "held" and src[1] == src[3] == "sonar"
    np.testing.assert_allclose(r.trajectory["altitude_m"], 1.3)


@pytest.mark.parametrize("name", sorted(fc.RANGE_CONFIGS))
def test_impossible_configuration_values_are_refused(name, shared):
    case = fc.config_case(name, fc.RANGE_CONFIGS[name], "error")
    outcome = fc.run_case(case, shared)
    assert not outcome.problems, outcome.problems


@pytest.mark.parametrize("name", ["sequence-images-all-bomb", "video-truncated-mp4"])
def test_one_line_from_a_real_process(name, shared, tmp_path):
    """In a real process, native libraries (OpenCV, FFmpeg) could add their own stderr lines."""
    case = next(c for c in CASES if c.id == name)
    d = tmp_path / name
    d.mkdir()
    argv = case.build(d, shared)
    proc = subprocess.run(
        [sys.executable, "-m", "rovslam", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "COLUMNS": "80"},
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("rovslam: error: ") and case.needle in lines[0], proc.stderr
    assert proc.stdout == ""


# --------------------------------------------------------------------------- hypothesis on the parsers

CELLS = st.one_of(
    st.sampled_from(
        [
            "0",
            "0.2",
            "-1",
            "1e6",
            "nan",
            "NaN",
            "inf",
            "-inf",
            "",
            " ",
            "1,3",
            "abc",
            '"0.4"',
            "1e309",
            "images/000001.png",
            "../outside/bait.png",
            "/etc/passwd",
            "images",
            "images/../images/000002.png",
            "images/\x00.png",
            "0x10",
            "1_000",
            "\ufeff0",
        ]
    ),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(max_size=6),
)


def _csv_text(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(",".join(r) for r in [header, *rows]) + "\n"


@st.composite
def frames_csv(draw):
    header = draw(
        st.one_of(
            st.just(["t_s", "image", "heading_rad", "sonar_altitude_m"]),
            st.just(["t_s", "image", "heading_rad", "sonar_altitude_m", "roll_rad", "pitch_rad"]),
            st.lists(st.sampled_from(["t_s", "image", "heading_rad", "sonar_altitude_m", "roll_rad", "x"]), max_size=6),
        )
    )
    n = draw(st.integers(0, 6))
    rows = [
        [
            draw(CELLS)
            for _ in range(draw(st.sampled_from([len(header), len(header), max(len(header) - 1, 0), len(header) + 1])))
        ]
        for _ in range(n)
    ]
    text = _csv_text(header, rows)
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "utf-16"]))
    return text.encode(encoding, errors="replace")


@pytest.fixture(scope="module")
def parser_folder(tmp_path_factory, shared):
    root = tmp_path_factory.mktemp("parsers")
    seq = fc.write_sequence(root / "seq", n=3)
    return seq


def _assert_inside(seq_folder: Path, image: str) -> None:
    real = Path(os.path.realpath(seq_folder / image))
    assert real.is_relative_to(os.path.realpath(seq_folder)), image


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=frames_csv())
def test_frames_csv_parser(data, parser_folder, shared):
    from rovslam.io.sequence import read_frames_csv

    path = parser_folder / "frames.csv"
    path.write_bytes(data)
    with fc.recording_opens() as opened:
        try:
            rows = read_frames_csv(path, parser_folder)
        except SequenceFormatError as exc:
            assert "frames.csv" in str(exc)
            rows = None
    assert not fc.opened_outside(opened, parser_folder, shared.root)
    if rows is not None:
        t = [r.t_s for r in rows]
        assert len(rows) >= 1 and all(math.isfinite(x) for x in t) and all(b > a for a, b in zip(t, t[1:]))
        for r in rows:
            _assert_inside(parser_folder, r.image)
            assert (parser_folder / r.image).is_file()
            assert not math.isinf(r.heading_rad)
            assert r.sonar_altitude_m is None or math.isfinite(r.sonar_altitude_m)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    rows=st.lists(st.lists(CELLS, min_size=5, max_size=5), max_size=5),
    header=st.sampled_from([["t_s", "x_m", "y_m", "altitude_m", "heading_rad"], ["t_s", "x_m", "y_m"]]),
    bom=st.booleans(),
)
def test_groundtruth_parser(rows, header, bom, parser_folder):
    from rovslam.io.sequence import read_groundtruth

    path = parser_folder / "gt_fuzz.csv"
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + _csv_text(header, rows).encode("utf-8", errors="replace"))
    try:
        gt = read_groundtruth(path)
    except SequenceFormatError as exc:
        assert "gt_fuzz.csv" in str(exc)
        return
    assert len(gt) >= 1 and np.all(np.isfinite(gt.xy_m)) and np.all(np.diff(gt.t_s) > 0)


TOML_VALUES = st.one_of(
    st.integers(-(10**6), 10**12),
    st.floats(allow_nan=True),
    st.text(max_size=5),
    st.booleans(),
    st.lists(st.floats(allow_nan=False, width=32), max_size=9),
)


@st.composite
def sequence_toml(draw):
    cam = {"width_px": 128, "height_px": 96, "fx_px": 200.0, "fy_px": 200.0, "cx_px": 63.5, "cy_px": 47.5}
    for key in draw(
        st.lists(st.sampled_from(sorted(cam) + ["distortion", "yaw_offset_rad", "bit_depth", "foo"]), max_size=3)
    ):
        cam[key] = draw(TOML_VALUES)
    for key in draw(st.lists(st.sampled_from(sorted(cam)), max_size=2)):
        cam.pop(key, None)
    data = {"format": draw(st.sampled_from(["rovslam-sequence/1", "rovslam-sequence/1", "v2"])), "camera": cam}
    if draw(st.booleans()):
        data["laser"] = [
            {"origin_m": draw(st.lists(TOML_VALUES, max_size=4)), "direction": draw(st.lists(TOML_VALUES, max_size=4))}
        ]
    if draw(st.booleans()):
        data["vehicle"] = {"altitude_m": draw(TOML_VALUES)}
    return data


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=sequence_toml(), garbage=st.one_of(st.none(), st.binary(max_size=60)))
def test_sequence_toml_parser(data, garbage, parser_folder):
    import tomli_w

    from rovslam.io.sequence import parse_sequence_toml

    path = parser_folder / "fuzz.toml"
    try:
        text = tomli_w.dumps(data).encode()
    except (TypeError, ValueError):  # a value TOML cannot hold
        return
    path.write_bytes(text if garbage is None else garbage)
    try:
        info = parse_sequence_toml(path)
    except SequenceFormatError as exc:
        assert "fuzz.toml" in str(exc)
        return
    cam = info.camera
    assert 1.0 <= cam.fx_px <= 1e6 and 1.0 <= cam.fy_px <= 1e6
    assert 0 <= cam.cx_px <= cam.width_px and 0 <= cam.cy_px <= cam.height_px
    assert info.fixed_altitude_m is None or info.fixed_altitude_m > 0


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    column=st.sampled_from(["t_s", "x_m", "var_x_m2", "altitude_m", "skipped", "altitude_source"]),
    line=st.integers(1, 8),
    value=CELLS,
    cut=st.integers(0, 400),
    summary=st.one_of(st.none(), st.binary(max_size=40), st.sampled_from([b"{}", b"[]", b"null", b'{"a": NaN}'])),
)
def test_results_reader(column, line, value, cut, summary, shared, tmp_path_factory):
    from rovslam.io.run_results import read_results

    res = tmp_path_factory.mktemp("res")
    shutil.copytree(shared.base_results, res, dirs_exist_ok=True)
    fc.set_cell(res / "trajectory.csv", line, column, value.replace(",", ";").replace("\n", " ").replace("\r", " "))
    data = (res / "trajectory.csv").read_bytes()
    (res / "trajectory.csv").write_bytes(data[: len(data) - cut])
    if summary is not None:
        (res / "summary.json").write_bytes(summary)
    try:
        r = read_results(res)
    except ResultsFormatError as exc:
        assert str(res) in str(exc)
        return
    for col in ("t_s", "x_m", "y_m", "var_x_m2", "var_y_m2", "cov_xy_m2", "dr_x_m", "dr_y_m"):
        assert np.all(np.isfinite(r.trajectory[col])), col
    assert np.all(np.diff(r.t_s) > 0) and isinstance(r.summary, dict)


# --------------------------------------------------------------------------- the bigger corpus (slow)


def _mutants(data: bytes, rng: np.random.Generator, k: int) -> list[bytes]:
    out = []
    for _ in range(k):
        b = bytearray(data)
        how = rng.integers(4)
        if how == 0 and b:  # flip bytes
            for i in rng.integers(0, len(b), size=rng.integers(1, 8)):
                b[i] = int(rng.integers(256))
        elif how == 1:  # cut
            b = b[: int(rng.integers(0, len(b) + 1))]
        elif how == 2 and b:  # duplicate a slice
            i, j = sorted(rng.integers(0, len(b), size=2))
            b[i:i] = b[i:j]
        else:  # insert special bytes
            i = int(rng.integers(0, len(b) + 1))
            b[i:i] = rng.choice([b"\x00", b"\xff\xfe", b",", b"\n", b"nan", b"../", b"\xef\xbb\xbf", b'"'])
        out.append(bytes(b))
    return out


@pytest.mark.slow
def test_byte_mutations_of_every_file(shared, tmp_path):
    """Seeded mutants of sequence.toml, frames.csv, an image, groundtruth.csv and every results file."""
    rng = np.random.default_rng(15)
    targets = [
        ("seq", "sequence.toml"),
        ("seq", "frames.csv"),
        ("seq", "images/000002.png"),
        ("seq", "groundtruth.csv"),
        ("res", "trajectory.csv"),
        ("res", "summary.json"),
        ("res", "landmarks.csv"),
        ("res", "observations.csv"),
    ]
    failures, outcomes = [], {0: 0, 2: 0}
    for kind, rel in targets:
        base = shared.base_seq if kind == "seq" else shared.base_results
        for m, data in enumerate(_mutants((base / rel).read_bytes(), rng, 60)):

            def build(d, sh, kind=kind, rel=rel, data=data, base=base):
                folder = d / kind
                shutil.copytree(base, folder)
                (folder / rel).write_bytes(data)
                if kind == "seq":
                    return ["run", str(folder), "--out", str(d / "out"), "-q"]
                return ["eval", str(folder), "-g", str(sh.base_seq / "groundtruth.csv"), "--json", str(d / "e.json")]

            case = fc.Case(f"{kind}-{rel.replace('/', '_')}-{m}", "mutant", build, "either")
            outcome = fc.run_case(case, shared)
            outcomes[outcome.exit_code] = outcomes.get(outcome.exit_code, 0) + 1
            if outcome.problems:
                failures.append((case.id, outcome.problems))
    print("mutants by exit code:", outcomes)
    assert not failures, failures[:5]
