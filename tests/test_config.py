"""Configuration: the paper's defaults, TOML round trip, unknown keys rejected with the key and file."""

import dataclasses

import pytest

from rovslam.config import RunConfig, load_config, save_config
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
