"""DecayingMean: the exponentially weighted mean that starts from nothing."""

import math

import numpy as np
import pytest

from rovslam.averages import DecayingMean


def test_empty_gives_the_default():
    m = DecayingMean()
    assert m.mean() == 0.0 and m.mean(empty=math.nan) != m.mean(empty=math.nan) and m.count == 0


def test_equal_weights_are_the_exponential_average_over_its_own_weight():
    rng = np.random.default_rng(4)
    x, a = rng.normal(3.0, 1.0, 50), 0.1
    m, ema = DecayingMean(), 0.0
    for k, v in enumerate(x, start=1):
        m.add(v, a, 1.0 - a)
        ema += a * (v - ema)
        assert m.mean() == pytest.approx(ema / (1.0 - (1.0 - a) ** k), rel=1e-12)
    assert m.count == 50
    assert DecayingMean().mean() == 0.0


def test_the_first_sample_counts_at_its_value_and_old_ones_fade():
    m = DecayingMean()
    m.add(5.0, 0.01, 0.99)
    assert m.mean() == pytest.approx(5.0)  # not 0.05, as an average started from 0 would say
    for _ in range(2000):
        m.add(1.0, 0.01, 0.99)
    assert m.mean() == pytest.approx(1.0, abs=1e-6)


def test_weights_count_as_given():
    m = DecayingMean()
    m.add(2.0, 3.0, 1.0)
    m.add(6.0, 1.0, 1.0)
    assert m.mean() == pytest.approx(3.0)  # (3 * 2 + 6) / 4
