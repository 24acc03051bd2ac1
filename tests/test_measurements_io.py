"""The measurement records both back ends consume: validation, and their files written and read back exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from synth import crosshatch_track, landmark_field, survey_measurements

from rovslam.errors import InvalidMeasurementError, ResultsFormatError
from rovslam.io.measurements import (
    LANDMARK_MEASUREMENTS_FILE,
    MEASUREMENTS_FILE,
    MeasurementWriter,
    has_measurements,
    read_measurements,
    write_measurements,
)
from rovslam.slam.measurements import FrameMeasurements, LandmarkMeasurement


def frame(index=1, **changes):
    """A valid frame with two observations; ``changes`` override fields."""
    fields = dict(
        index=index,
        t_s=0.2 * index,
        dt_s=0.2,
        speed_mps=[0.1, -0.01],
        speed_cov_mps2=[[4e-6, 1e-7], [1e-7, 9e-6]],
        speed_ok=True,
        heading_rad=0.4,
        heading_sigma_rad=0.003,
        compass_rad=0.41,
        compass_sigma_rad=0.0087,
        heading_step_rad=0.001,
        heading_step_sigma_rad=0.002,
        altitude_m=1.31,
        altitude_sigma_m=0.01,
        focal_px=1075.0,
        landmarks=(
            LandmarkMeasurement(3, "track", [12.5, -40.25], [[0.25, 0.01], [0.01, 0.3]], accepted_by_online=False),
            LandmarkMeasurement(4, "init", [-3.0, 7.0], np.eye(2) * 0.25),
        ),
    )
    fields.update(changes)
    return FrameMeasurements(**fields)


@pytest.fixture(scope="module")
def survey():
    xy, psi = crosshatch_track(120)
    return survey_measurements(3, xy, psi, landmark_field(3, xy))


# ---------------------------------------------------------------- the records
def test_records_hold_frozen_float_copies_and_compare_nan_equal():
    src = np.array([0.1, -0.01])
    f = frame(speed_mps=src, compass_rad=float("nan"), heading_step_rad=np.nan, heading_step_sigma_rad=np.nan)
    src[0] = 5.0  # the record keeps its own copy
    assert f.speed_mps[0] == 0.1 and f.speed_mps.dtype == np.float64
    with pytest.raises(ValueError):
        f.speed_mps[0] = 1.0  # read-only
    assert not f.has_compass and not f.has_heading_step and frame().has_compass and frame().has_heading_step
    same = frame(compass_rad=float("nan"), heading_step_rad=np.nan, heading_step_sigma_rad=np.nan)
    assert f == same  # NaN equals NaN field by field
    assert f != frame() and frame() != frame(index=2)
    assert isinstance(f.index, int) and f.landmarks[0].noise_px2.shape == (2, 2)


@pytest.mark.parametrize(
    "changes,needle",
    [
        (dict(index=-1), "index"),
        (dict(index=1.5), "index"),
        (dict(t_s=np.nan), "t_s is NaN"),
        (dict(dt_s=-0.2), "dt_s must be >= 0"),
        (dict(speed_mps=[0.1]), "shape (2,)"),
        (dict(speed_mps=[0.1, np.inf]), "NaN or infinite"),
        (dict(speed_cov_mps2=[[1e-6, 0.0], [0.0, 0.0]]), "positive definite"),
        (dict(speed_cov_mps2=[[1e-6, 1e-5], [1e-5, 1e-6]]), "semi-definite"),
        (dict(speed_cov_mps2=[[1e-6, 1e-7], [0.0, 1e-6]]), "symmetric"),
        (dict(speed_ok=1), "speed_ok"),
        (dict(heading_rad=np.inf), "heading_rad"),
        (dict(compass_rad=np.inf), "compass_rad"),
        (dict(heading_sigma_rad=-0.1), "heading_sigma_rad"),
        (dict(heading_step_rad=np.nan), "both be NaN"),
        (dict(heading_step_sigma_rad=0.0), "heading_step_sigma_rad must be > 0"),
        (dict(altitude_m=0.0), "altitude_m must be > 0"),
        (dict(focal_px=np.nan), "focal_px"),
        (dict(attitude_sigma_rad=-0.001), "attitude_sigma_rad must be >= 0"),
        (dict(landmarks=(LandmarkMeasurement(1, "track", [1.0, 2.0], np.eye(2)),) * 2), "observed twice"),
        (dict(landmarks=("not an observation",)), "LandmarkMeasurement"),
    ],
)
def test_bad_frame_values_raise_a_typed_error_naming_the_field(changes, needle):
    with pytest.raises(InvalidMeasurementError, match="frame 1|frame measurement") as err:
        frame(**changes)
    assert needle in str(err.value)


@pytest.mark.parametrize(
    "args,needle",
    [
        ((-1, "track", [1.0, 2.0], np.eye(2)), "landmark_id"),
        ((1, "seen", [1.0, 2.0], np.eye(2)), "kind"),
        ((1, "track", [1.0, np.nan], np.eye(2)), "mn_px"),
        ((1, "track", [1.0, 2.0], np.zeros((2, 2))), "positive definite"),
        ((1, "track", [1.0, 2.0], np.eye(3)), "(2, 2)"),
    ],
)
def test_bad_observations_raise_a_typed_error(args, needle):
    with pytest.raises(InvalidMeasurementError) as err:
        LandmarkMeasurement(*args)
    assert needle in str(err.value)


def test_the_first_frame_may_have_no_speed_covariance():
    f = frame(index=0, t_s=0.0, dt_s=0.0, speed_mps=[0.0, 0.0], speed_cov_mps2=np.zeros((2, 2)), landmarks=())
    assert f.dt_s == 0.0 and np.all(f.speed_cov_mps2 == 0)


# ---------------------------------------------------------------- the files
def test_a_survey_round_trips_exactly(tmp_path, survey):
    frames = list(survey.frames)
    frames[5] = frame(
        index=5,
        t_s=1.0,
        compass_rad=np.nan,
        heading_step_rad=np.nan,
        heading_step_sigma_rad=np.nan,
        altitude_sigma_m=np.nan,
        speed_ok=False,
    )
    assert not has_measurements(tmp_path)
    write_measurements(tmp_path, frames)
    assert has_measurements(tmp_path)
    back = read_measurements(tmp_path)
    assert len(back) == 120 and sum(len(f.landmarks) for f in back) > 50
    assert back == frames  # bit for bit, NaN fields included
    header = (tmp_path / MEASUREMENTS_FILE).read_text().splitlines()[0]
    assert header.startswith("frame,t_s,dt_s,surge_mps,sway_mps")


def test_the_ahrs_accuracy_round_trips_and_an_earlier_run_without_it_reads_as_none(tmp_path, survey):
    frames = [
        frame(index=k, t_s=0.2 * k, attitude_sigma_rad=0.0035 if k % 2 else 0.0, landmarks=()) for k in range(1, 5)
    ]
    write_measurements(tmp_path, frames)
    back = read_measurements(tmp_path)
    assert [f.attitude_sigma_rad for f in back] == [0.0035, 0.0, 0.0035, 0.0]
    # A run by an earlier rovslam: the same file without the column (it had no such value).
    path = tmp_path / MEASUREMENTS_FILE
    lines = path.read_text().splitlines()
    assert lines[0].endswith(",attitude_sigma_rad")
    path.write_text("\n".join(line.rsplit(",", 1)[0] for line in lines) + "\n")
    old = read_measurements(tmp_path)
    assert [f.attitude_sigma_rad for f in old] == [0.0] * 4
    assert [f.t_s for f in old] == [f.t_s for f in frames]


@settings(max_examples=40, deadline=None)
@given(
    values=st.lists(
        st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_subnormal=True), min_size=6, max_size=6
    ),
    tiny=st.floats(min_value=1e-300, max_value=1e-3),
)
def test_any_finite_numbers_round_trip_exactly(tmp_path_factory, values, tiny):
    out = tmp_path_factory.mktemp("rt")
    f = frame(
        t_s=values[0],
        speed_mps=values[1:3],
        heading_rad=values[3],
        compass_rad=values[4],
        speed_cov_mps2=np.eye(2) * tiny,
        landmarks=(LandmarkMeasurement(7, "track", values[4:6], np.eye(2) * tiny),),
    )
    write_measurements(out, [f])
    assert read_measurements(out) == [f]


def test_an_interrupted_run_reads_up_to_its_last_complete_frame(tmp_path, survey):
    frames = list(survey.frames[:40])
    with MeasurementWriter(tmp_path, flush_every=7) as writer:
        for f in frames:
            writer.write(f)
    meas, obs = tmp_path / MEASUREMENTS_FILE, tmp_path / LANDMARK_MEASUREMENTS_FILE
    text = meas.read_text()
    meas.write_text(text[: len(text) - 25])  # a torn last line
    back = read_measurements(tmp_path)
    assert back == frames[:39]
    # The frame rows reached the disk but not the observations of the last frames.
    meas.write_text(text)
    last_with_obs = max(i for i, f in enumerate(frames) if f.landmarks)
    kept = [
        line
        for line in obs.read_text().splitlines()
        if not line.split(",")[0].isdigit() or int(line.split(",")[0]) < frames[last_with_obs].index
    ]
    obs.write_text("\n".join(kept) + "\n")
    back = read_measurements(tmp_path)
    assert back == frames[:last_with_obs]


def test_bad_files_name_the_file_line_and_column(tmp_path, survey):
    with pytest.raises(ResultsFormatError, match="not the --out folder of a `rovslam run`"):
        read_measurements(tmp_path)  # no run here (audit D9 g: it was told it came from an old rovslam)
    with pytest.raises(ResultsFormatError, match="not a folder"):
        read_measurements(tmp_path / "nowhere")
    write_measurements(tmp_path, survey.frames[:20])
    meas = tmp_path / MEASUREMENTS_FILE
    good = meas.read_text()
    lines = good.splitlines()

    cells = lines[4].split(",")
    cells[3] = "fast"  # surge_mps
    meas.write_text("\n".join(lines[:4] + [",".join(cells)] + lines[5:]) + "\n")
    with pytest.raises(ResultsFormatError, match=r"measurements.csv, line 5, column surge_mps: 'fast' is not a number"):
        read_measurements(tmp_path)

    cells = lines[6].split(",")
    cells[15] = "-1.0"  # altitude_m
    meas.write_text("\n".join(lines[:6] + [",".join(cells)] + lines[7:]) + "\n")
    with pytest.raises(ResultsFormatError, match=r"line 7: frame 5: altitude_m must be > 0"):
        read_measurements(tmp_path)

    meas.write_text("\n".join([lines[0].replace(",focal_px", "")] + lines[1:]) + "\n")
    with pytest.raises(ResultsFormatError, match="line 1: missing column"):
        read_measurements(tmp_path)

    meas.write_text("\n".join(lines[:3] + lines[4:5] + lines[3:4] + lines[5:]) + "\n")
    with pytest.raises(ResultsFormatError, match="column frame: frame 2 after frame 3"):
        read_measurements(tmp_path)

    # A frame in the middle that lost an observation: the files do not belong together.
    meas.write_text(good)
    obs = tmp_path / LANDMARK_MEASUREMENTS_FILE
    obs_lines = obs.read_text().splitlines()
    obs.write_text("\n".join(obs_lines[:2] + obs_lines[3:]) + "\n")
    with pytest.raises(ResultsFormatError, match="do not belong together"):
        read_measurements(tmp_path)

    obs.write_text(
        "\n".join(
            obs_lines[:1] + [obs_lines[1].replace(",track,", ",seen,").replace(",init,", ",seen,")] + obs_lines[2:]
        )
        + "\n"
    )
    with pytest.raises(ResultsFormatError, match="landmark_measurements.csv, line 2: .*kind must be 'init' or 'track'"):
        read_measurements(tmp_path)


def test_the_writer_rejects_what_is_not_a_record(tmp_path):
    with MeasurementWriter(tmp_path) as writer, pytest.raises(InvalidMeasurementError):
        writer.write({"index": 0})
    assert read_measurements(tmp_path) == []  # the headers alone: a run stopped before its first frame
