"""The running averages the loop learns a dive's statistics with (token noise, relief, accelerations,
compass noise, the sunlight's moving share).

Each is an exponentially weighted mean that starts from nothing: the sum of the weighted samples
over the sum of their weights, both decayed at every step. Started so, the first samples count at
their value, where an average started from 0 would be pulled towards 0 for as many steps as it
remembers.

:func:`median0` is the median over the first axis of the few values one step has (tokens, pairs),
exactly as ``np.median(values, axis=0)`` gives it at a fifth of its overhead.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DecayingMean", "median0"]


def median0(values) -> np.ndarray:
    """``np.median(values, axis=0)``, bit for bit (dtype and shape too), for ``(N,)`` or ``(N, k)`` values.

    One or two partitions instead of NumPy's general path (about 12 us against 40 to 60 us on
    eight tokens). Integers give float64, as NumPy's; any NaN, or no value, is left to NumPy.
    """
    a = np.asarray(values)
    if a.dtype.kind != "f":
        a = a.astype(np.float64)
    n = a.shape[0] if a.ndim else 0
    if n == 0 or np.isnan(a).any():
        return np.median(a, axis=0)
    k = n // 2
    if n % 2:
        return np.partition(a, k, axis=0)[k]
    part = np.partition(a, (k - 1, k), axis=0)
    return (part[k - 1] + part[k]) / 2  # NumPy's mean of the two middle values: their sum over 2


class DecayingMean:
    """``sum_k w_k c^(n-k) x_k / sum_k w_k c^(n-k)``: each :meth:`add` keeps ``c`` of what was there.

    With ``keep = 1 - a`` and ``weight = a`` it is the exponential average ``m += a (x - m)``
    divided by the weight ``1 - (1 - a)^n`` it has given the n samples; with ``keep = exp(-dt /
    tau)`` a time-weighted average over about ``tau`` seconds.
    """

    __slots__ = ("num", "den", "count")

    def __init__(self) -> None:
        self.num = 0.0  # the decayed sum of weighted samples
        self.den = 0.0  # the decayed sum of their weights
        self.count = 0  # samples added

    def add(self, value: float, weight: float, keep: float) -> None:
        """Decay what was there by ``keep`` (0..1), then add ``value`` with ``weight`` (>= 0)."""
        self.num = keep * self.num + weight * value
        self.den = keep * self.den + weight
        self.count += 1

    def mean(self, empty: float = 0.0) -> float:
        """The average, or ``empty`` before any weight."""
        return self.num / self.den if self.den > 0 else empty
