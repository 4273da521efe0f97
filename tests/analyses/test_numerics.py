"""Tests of analyses.numerics: scipy's Savitzky-Golay derivative and Brent root, bit for bit."""
import math

import numpy as np
import pytest

from analyses.numerics import brentq, savgol_derivative


@pytest.mark.parametrize("n, window, dt", [(4000, 21, 1e-3), (700, 5, 1.0), (3001, 101, 2.5e-4), (12, 11, 1e-3)])
def test_savgol_derivative_gives_scipys_bits(n, window, dt):
    import scipy.signal

    rng = np.random.default_rng(n)
    t = np.arange(n) * dt
    for x in (np.cumsum(rng.standard_normal(n)), 0.01 * np.sin(2 * np.pi * 2 * t) + 1e-5 * rng.standard_normal(n)):
        expected = scipy.signal.savgol_filter(x, window, 3, deriv=1, delta=dt)
        assert np.array_equal(savgol_derivative(x, window, dt), expected)
    # a cubic is differentiated exactly, ends included
    x = 2.0 + 3.0 * t - 0.5 * t ** 2 + 0.25 * t ** 3
    np.testing.assert_allclose(savgol_derivative(x, window, dt), 3.0 - t + 0.75 * t ** 2,
                               rtol=1e-9, atol=1e-9 * (1 + np.max(np.abs(t)) ** 2))


@pytest.mark.parametrize("f, a, b", [(lambda x: x ** 3 - 2 * x - 5, 2.0, 3.0), (lambda x: math.cos(x) - x, 0.0, 1.0),
                                     (lambda x: math.exp(x) - 1e3, 0.0, 10.0), (lambda x: np.tanh(50 * (x - 0.7)), 0, 1),
                                     (lambda x: (x - 1.2345) ** 3 + 1e-3 * (x - 1.2345), 0.5, 2.5)])
def test_brentq_takes_scipys_steps(f, a, b):
    import scipy.optimize

    for kw in ({}, {"xtol": 1e-15, "maxiter": 200}):
        assert brentq(f, a, b, **kw) == scipy.optimize.brentq(f, a, b, **kw)
    assert brentq(lambda x: x * x - 2, 0, 2, xtol=1e-15) == pytest.approx(math.sqrt(2), abs=1e-15)
    with pytest.raises(ValueError):
        brentq(lambda x: x * x + 1, -1, 1)
    with pytest.raises(RuntimeError):
        brentq(lambda x: math.tanh(50 * (x - 0.7)), 0, 1, xtol=1e-300, rtol=0.0, maxiter=3)
