"""The altimeter's lasting error: an offset and the laser rig's share of the depth (``[slam] altitude_scale_sigma``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from rovslam.config import RunConfig, SlamConfig
from rovslam.core import SequenceInfo
from rovslam.errors import ConfigError, InvalidMeasurementError
from rovslam.pipeline import SlamPipeline
from rovslam.sim import PAPER_LASERS, PORTOFINO_CAMERA
from rovslam.slam.ekf import EkfSlam
from rovslam.slam.motion import altitude_offset_sigma_m


def test_offset_and_share_add_in_quadrature():
    assert altitude_offset_sigma_m(0.01, 0.0076, 1.31) == pytest.approx(math.hypot(0.01, 0.009956), rel=1e-12)
    z = np.array([0.5, 1.31, 2.0, 4.0])
    np.testing.assert_allclose(altitude_offset_sigma_m(0.01, 0.0076, z), np.hypot(0.01, 0.0076 * z), rtol=1e-15)
    assert altitude_offset_sigma_m(0.0, 0.01, 3.0) == pytest.approx(0.03, rel=1e-15)  # the rig alone: 1 % of Z
    # no share: the offset itself, bit for bit, at any depth (the filter of before)
    assert altitude_offset_sigma_m(0.0123, 0.0, 2.7) == 0.0123
    np.testing.assert_array_equal(altitude_offset_sigma_m(0.0123, 0.0, z), np.full(4, 0.0123))


def test_the_filter_starts_with_the_sigma_at_the_expected_depth():
    cfg = SlamConfig()
    assert EkfSlam(cfg).altitude_bias_sigma_m == pytest.approx(cfg.altitude_bias_sigma_m, rel=1e-12)
    at_2m = EkfSlam(cfg, initial_altitude_m=2.0).altitude_bias_sigma_m
    assert at_2m == pytest.approx(math.hypot(cfg.altitude_bias_sigma_m, cfg.altitude_scale_sigma * 2.0), rel=1e-12)
    off = SlamConfig(altitude_bias_sigma_m=0.0)  # no b: the share has nothing to widen
    assert EkfSlam(off, initial_altitude_m=2.0).altitude_bias_sigma_m == 0.0
    with pytest.raises(InvalidMeasurementError, match="initial_altitude_m"):
        EkfSlam(cfg, initial_altitude_m=-1.0)


def test_the_pipeline_widens_b_with_the_depth():
    """Held at 1.31 m and at 2.6 m the stationary sigma of b is the offset and the rig's share in quadrature."""
    info = SequenceInfo(name="t", camera=PORTOFINO_CAMERA, lasers=PAPER_LASERS)
    cfg = RunConfig()  # no relief prior: the relief under the spots would be the larger sigma before any token
    pipe = SlamPipeline(
        info, dataclasses.replace(cfg, odometry=dataclasses.replace(cfg.odometry, relief_prior_sigma=0.0))
    )
    assert pipe.ekf.altitude_bias_sigma_m == pytest.approx(math.hypot(0.01, 0.0076 * pipe.altimeter_fallback))

    class _Alt:  # what _altitude_bias_process reads of an altitude estimate (a flat seabed: no relief)
        source, n_spots = "laser", 4

    for z in (1.31, 2.6):
        sigma, tau = pipe._altitude_bias_process(z, _Alt())
        assert sigma == pytest.approx(math.hypot(0.01, 0.0076 * z), rel=1e-12)
        assert tau == RunConfig().slam.altitude_bias_tau_s


@pytest.mark.parametrize("value", [-0.01, 0.2, math.nan])
def test_a_bad_share_is_refused_at_load(value):
    with pytest.raises(ConfigError, match="altitude_scale_sigma"):
        SlamConfig(altitude_scale_sigma=value)
