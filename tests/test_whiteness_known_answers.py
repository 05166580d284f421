"""Bartlett's cumulative periodogram (Fig. 19-20) on sequences with known answers: a
sinusoid at Fourier frequency j0 puts all its power at j0, so C_j is 0 below j0 and 1
from j0 on, and the largest distance to the line j/m is max((j0 - 1)/m, 1 - j0/m)."""
import math

import numpy as np
import pytest

from cosim.algorithms.whiteness import cumulative_periodogram


@pytest.mark.parametrize("n,j0", [(1001, 1), (1001, 137), (1001, 500), (2000, 999)])
def test_single_fourier_frequency(n, j0):
    m = (n - 1) // 2
    t = np.arange(n)
    x = np.cos(2 * math.pi * j0 * t / n + 0.3)
    cp = cumulative_periodogram(x)
    assert cp.curve.size == m
    np.testing.assert_allclose(cp.curve[:j0 - 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(cp.curve[j0 - 1:], 1.0, atol=1e-12)
    assert cp.max_deviation == pytest.approx(max((j0 - 1) / m, 1 - j0 / m), abs=1e-12)


def test_band_is_the_ks_critical_value_for_m_minus_1():
    from scipy import stats
    x = np.random.default_rng(0).normal(size=801)
    cp = cumulative_periodogram(x, confidence=0.95)
    m = 400
    assert cp.band_halfwidth == pytest.approx(stats.kstwo.isf(0.05, m - 1), rel=1e-12)
    assert cp.band_halfwidth == pytest.approx(1.36 / math.sqrt(m), rel=0.03)
