"""DecayingMean: the exponentially weighted mean that starts from nothing; median0: NumPy's median, faster."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from rovslam.averages import DecayingMean, median0


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


# ---------------------------------------------------------------- median0: np.median(axis=0), bit for bit
@settings(max_examples=300, deadline=None)
@given(
    hnp.arrays(
        st.sampled_from([np.float64, np.float32]),
        st.one_of(st.tuples(st.integers(1, 40)), st.tuples(st.integers(1, 40), st.integers(1, 3))),
        elements=st.floats(-1e6, 1e6, width=32),
    )
)
def test_median0_is_numpys_median_bit_for_bit(values):
    expected = np.median(values, axis=0)
    got = median0(values)
    assert np.asarray(got).dtype == np.asarray(expected).dtype and np.shape(got) == np.shape(expected)
    assert np.array_equal(got, expected)


def test_median0_of_even_count_is_the_mean_of_the_middle_two_and_integers_give_float():
    assert median0(np.array([4.0, 1.0, 3.0, 2.0])) == 2.5
    assert median0(np.array([[1.0, 10.0], [3.0, 30.0], [2.0, 20.0]])).tolist() == [2.0, 20.0]
    m = median0(np.array([1, 2], dtype=np.uint8))
    assert m == 1.5 and np.asarray(m).dtype == np.float64


def test_median0_leaves_nan_and_empty_to_numpy():
    assert np.isnan(median0(np.array([1.0, np.nan, 3.0])))
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        assert np.isnan(median0(np.zeros(0)))
