"""analyses.numerics_spline: scipy.interpolate.CubicSpline's values to the bit (uniform and uneven grids,
extrapolation, NaN), and what a not-a-knot cubic spline must do (a cubic exactly, data points hit)."""
import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from analyses.numerics_spline import NotAKnotSpline


def test_gives_scipys_bits():
    rng = np.random.default_rng(2)
    for trial in range(60):
        n = int(rng.integers(4, 2000))
        x = np.arange(n) if trial % 3 == 0 else np.cumsum(rng.uniform(0.01, 2.0, size=n))
        y = rng.normal(size=n) if trial % 5 == 0 else np.cumsum(rng.normal(size=n)) * 10 ** rng.uniform(-6, 3)
        xq = np.concatenate([rng.uniform(x[0] - 2, x[-1] + 2, size=300), x, x + 0.37, [np.nan]])
        assert np.array_equal(NotAKnotSpline(x, y)(xq), CubicSpline(x, y)(xq), equal_nan=True)


def test_reproduces_a_cubic_and_passes_through_the_data():
    x = np.array([0.0, 0.5, 1.7, 2.0, 3.1, 4.0])
    cubic = lambda t: 0.3 * t ** 3 - t ** 2 + 2.0 * t - 5.0  # noqa: E731
    s = NotAKnotSpline(x, cubic(x))
    t = np.linspace(-1.0, 5.0, 61)  # extrapolated too: the end pieces are the cubic
    assert np.allclose(s(t), cubic(t), rtol=0, atol=1e-12)
    y = np.sin(x)
    assert np.allclose(NotAKnotSpline(x, y)(x), y, rtol=0, atol=1e-15)


def test_refuses_what_it_cannot_fit():
    with pytest.raises(ValueError):
        NotAKnotSpline([0.0, 1.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        NotAKnotSpline([0.0, 1.0, 1.0, 2.0], [1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError):
        NotAKnotSpline([0.0, 1.0, 2.0, 3.0], [1.0, np.nan, 3.0, 4.0])
