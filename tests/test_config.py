"""Configuration: the paper's defaults, TOML round trip, unknown keys rejected with the key and file."""

import dataclasses

import pytest

from rovslam.config import BandpassConfig, RunConfig, load_config, save_config
from rovslam.errors import ConfigError


def test_defaults_are_the_papers_figures():
    c = RunConfig()
    assert c.speed_templates.size_px == 16
    assert c.speed_templates.max_count == 8
    assert c.landmark_templates.size_px == 32
    assert c.landmark_templates.min_local_variance == 12.3
    assert c.tracker.min_correlation == 0.89


def test_toml_round_trip(tmp_path):
    c = dataclasses.replace(RunConfig(), tracker=dataclasses.replace(RunConfig().tracker, min_correlation=0.8))
    path = tmp_path / "c.toml"
    save_config(c, path)
    assert load_config(path) == c


def test_partial_file_keeps_defaults(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[speed_templates]\nmax_count = 5\n")
    c = load_config(path)
    assert c.speed_templates.max_count == 5
    assert c.speed_templates.size_px == 16


@pytest.mark.parametrize(
    "text,needle",
    [
        ("[tracker]\nmin_corelation = 0.9\n", "tracker.min_corelation"),
        ("[trackr]\nmin_correlation = 0.9\n", "trackr"),
        ("[speed_templates]\nmax_count = 'eight'\n", "speed_templates.max_count"),
        ("[speed_templates\n", "not valid TOML"),
    ],
)
def test_bad_files_name_the_key_and_the_file(tmp_path, text, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    assert needle in str(exc.value)
    assert "bad.toml" in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize(
    "text,needles",
    [
        ('[slam]\naugmentation = "ful"\n', ["[slam] augmentation = 'ful'", "'full', 'paper'"]),
        ('[bandpass]\nchannel = "red"\n', ["[bandpass] channel", "'grey', 'green', 'blue'"]),
        ('[tracker]\nsubpixel = "cubic"\n', ["[tracker] subpixel", "'parabolic'"]),
        ("[speed_templates]\nmin_spacing_px = -40\n", ["[speed_templates] min_spacing_px = -40", ">= 0"]),
        ("[bandpass]\ndespeckle_px = -3\n", ["[bandpass] despeckle_px = -3", ">= 0"]),
        ("[bandpass]\ndespeckle_px = 1\n", ["despeckle_px = 1", "0 (off) or >= 2"]),
        ("[bandpass]\nsunlight_px = 1\n", ["sunlight_px = 1", "0 (off) or >= 2"]),
        ("[bandpass]\nsunlight_px = -31\n", ["[bandpass] sunlight_px = -31", ">= 0"]),
        ("[bandpass]\nsunlight_px = 100001\n", ["[bandpass] sunlight_px = 100001", "<= 255"]),
        ("[bandpass]\ndespeckle_px = 100001\n", ["[bandpass] despeckle_px = 100001", "<= 255"]),
        ("[bandpass]\nsigma_fine_px = 0\n", ["[bandpass] sigma_fine_px = 0.0", "> 0"]),
        ("[bandpass]\nsigma_fine_px = 5.0\n", ["sigma_coarse_px = 4.0", "larger than sigma_fine_px"]),
        ("[tracker]\nmin_correlation = -1\n", ["[tracker] min_correlation = -1.0", "> 0 and <= 1"]),
        ("[tracker]\nmin_tracked_fraction = 2\n", ["min_tracked_fraction = 2.0", "<= 1"]),
        ("[laser]\nmin_altitude_m = 3.0\nmax_altitude_m = 2.0\n", ["max_altitude_m = 2.0", "min_altitude_m"]),
        ("[laser]\nassumed_altitude_m = -1.0\n", ["assumed_altitude_m = -1.0", "> 0"]),
        ("[odometry]\nmax_speed_mps = nan\n", ["max_speed_mps = nan", "finite"]),
        ("[slam]\nheading_bias_tau_s = 0\n", ["heading_bias_tau_s = 0.0", "> 0"]),
        ("[slam]\ninnovation_gate = inf\n", ["innovation_gate = inf", "finite"]),
        ("[tracker]\nglobal_search = 1\n", ["tracker.global_search", "true or false"]),
    ],
)
def test_every_value_is_checked_when_the_file_is_loaded(tmp_path, text, needles):
    path = tmp_path / "my.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_config(path)
    message = str(exc.value)
    assert message.startswith(f"{path}: ")
    for needle in needles:
        assert needle in message


def test_every_numeric_field_declares_its_range():
    """A new configuration value must say what it allows (so a bad file is refused at load)."""
    import typing

    for stage in dataclasses.fields(RunConfig):
        cls = stage.type if isinstance(stage.type, type) else typing.get_type_hints(RunConfig)[stage.name]
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] in (int, float):
                assert any(f.metadata.get(k) is not None for k in ("gt", "ge", "le")), f"{cls.__name__}.{f.name}"


def _numeric_fields():
    import typing

    for stage in dataclasses.fields(RunConfig):
        cls = typing.get_type_hints(RunConfig)[stage.name]
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] in (int, float):
                yield cls, f, hints[f.name]


def test_no_setting_takes_a_huge_number_nor_an_angle_beyond_half_a_turn():
    """1e308 in any setting was an OverflowError deep in the filter ("internal error") for 21 of
    them, and a band-pass sigma of 1e6 px ran for minutes: every number is bounded at load."""
    for cls, f, tp in _numeric_fields():
        huge = 10**12 if tp is int else 1e308
        with pytest.raises(ConfigError, match=f"{f.name} = .*out of range"):
            dataclasses.replace(cls(), **{f.name: huge})
        if f.name.endswith("_rad"):
            with pytest.raises(ConfigError, match="give radians, not degrees"):
                dataclasses.replace(cls(), **{f.name: 5.0})
    with pytest.raises(ConfigError, match="<= 100"):
        BandpassConfig(sigma_coarse_px=1e6)


def test_bom_is_accepted_and_other_encodings_are_named(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf[speed_templates]\nmax_count = 5\n")
    assert load_config(path).speed_templates.max_count == 5
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b"# caf\xe9\n[speed_templates]\nmax_count = 5\n")
    with pytest.raises(ConfigError, match=r"latin.toml: line 1: not UTF-8"):
        load_config(latin)


def test_save_is_atomic_and_leaves_no_temporary_file(tmp_path):
    path = tmp_path / "c.toml"
    save_config(RunConfig(), path)
    save_config(RunConfig(), path)
    assert [p.name for p in tmp_path.iterdir()] == ["c.toml"]
    assert load_config(path) == RunConfig()
