"""Tests of analyses.numerics_fmin: scipy's Nelder-Mead, weibull_min's censored fit and Brent's
minimiser from a bracket search, bit for bit."""
import subprocess
import sys

import numpy as np
import pytest

from analyses.numerics_fmin import brent_minimize, nelder_mead, weibull_censored_nll, weibull_polish


def _scipy_fit(x, f, k0, s0):
    """What weibull_fit called before: weibull_min.fit on the right-censored lives, or the exception's name."""
    import scipy.stats

    try:
        with np.errstate(all="ignore"):
            k, _, s = scipy.stats.weibull_min.fit(scipy.stats.CensoredData.right_censored(x, ~f), k0, floc=0, scale=s0)
        return k, s
    except Exception as exc:
        return type(exc).__name__


def _mine(x, f, k0, s0):
    try:
        with np.errstate(all="ignore"):
            return weibull_polish(x, f, k0, s0)
    except ValueError as exc:
        return type(exc).__name__


def _censored_lives(rng, n, shape, unit):
    x = rng.weibull(shape, n) * unit
    c = rng.uniform(0, x.max() * 1.2, n)
    f = x <= c
    return np.where(f, x, c), f


def test_weibull_polish_gives_weibull_min_fits_bits():
    """150 samples of every shape and unit, censored or not, started at the profile MLE or off it."""
    from analyses.service_life import _profile_mle

    rng = np.random.default_rng(26)
    compared = plain = 0
    for i in range(150):
        x, f = _censored_lives(rng, int(rng.integers(3, 40)), float(rng.choice([0.5, 1.0, 2.0, 4.0, 10.0])),
                               10 ** rng.uniform(-3, 4))
        if i % 4 == 0:
            x = np.round(x, 1) + 0.1   # ties
        if i % 5 == 0:
            f[:] = True                # no censored life: scipy fits the plain lives
        if f.sum() < 2:
            continue
        try:
            k0, s0 = _profile_mle(x, f)
        except ValueError:   # no shape inside the search's bounds: weibull_fit does not polish
            continue
        if i % 3 == 0:
            k0, s0 = 1.5 * k0, 0.8 * s0
        expected, got = _scipy_fit(x, f, k0, s0), _mine(x, f, k0, s0)
        assert type(got[0]) is type(expected[0]) and (got[0], got[1]) == (expected[0], expected[1])
        compared += 1
        plain += bool(f.all())
    assert compared > 100 and plain > 15


def test_weibull_polish_fails_where_scipy_fails():
    """Lives that overflow when scaled, a zero start shape, a scale start below the lives' range."""
    rng = np.random.default_rng(7)
    outcomes = set()
    for i in range(30):
        x = rng.weibull(2.0, 12) * 10 ** rng.uniform(-300, 300)
        f = rng.random(12) < (1.0 if i % 3 == 0 else 0.5)
        k0, s0 = 10 ** rng.uniform(-3, 3), x.max() * 10 ** rng.uniform(-5, 5)
        if i % 5 == 0:
            s0 = 1e-320
        if i % 7 == 0:
            k0 = 0.0
        expected, got = _scipy_fit(x, f, k0, s0), _mine(x, f, k0, s0)
        if isinstance(expected, str):
            assert got == expected == "ValueError"
        else:
            assert (got[0], got[1]) == (expected[0], expected[1]) or (np.isnan(got).all() and np.isnan(expected).all())
        outcomes.add(isinstance(expected, str))
    assert outcomes == {True, False}


@pytest.mark.parametrize("x0", [[-1.2, 1.0], [0.0, 0.0], [10.0, -3.0], [1.0, 2.0, 3.0], [5.0]])
def test_nelder_mead_takes_fmins_steps(x0):
    """Smooth, rugged (the evaluation budget spent) and NaN-valued functions."""
    import scipy.optimize

    funcs = [lambda p: float((p[0] - 3) ** 2 + 100 * (p[-1] - p[0] ** 2) ** 2 + np.sum(p[1:-1] ** 2)),
             lambda p: float(np.sum(np.sin(1e3 * p) * np.cos(37.0 * p)) + 1e-3 * np.sum(p ** 2)),
             lambda p: float("nan") if p[0] > 1.0 else float(np.sum((p - 0.5) ** 2))]
    for func in funcs:
        assert np.array_equal(nelder_mead(func, x0), scipy.optimize.fmin(func, x0, disp=0), equal_nan=True)


@pytest.mark.parametrize("func, xa, xb", [(lambda m: (m - 1.3) ** 2, 0.0, 1.0), (lambda m: (m - 1.3) ** 2, 5.0, 6.0),
                                         (lambda m: float(np.cosh(3 * (m + 20.0))), -1.0, 2.0),
                                         (lambda m: abs(m - 0.25) ** 0.5, 0.0, 1.0),
                                         (lambda m: -m, 0.0, 1.0),                  # no bracket: scipy's best point
                                         (lambda m: float("nan"), 0.0, 1.0),
                                         (lambda m: float(np.sin(7 * m) + 0.1 * m * m), 2.0, 2.5)])
def test_brent_minimize_gives_minimize_scalars_bits(func, xa, xb):
    import scipy.optimize

    res = scipy.optimize.minimize_scalar(func, bracket=(xa, xb))
    x, fun = brent_minimize(func, xa, xb)
    np.testing.assert_array_equal([x, fun], [res.x, res.fun])


def test_lognormal_fits_import_no_scipy_optimize():
    """lognormal_fit's two searches are scipy's, ported: the remaining-life stage's life models
    import no scipy.optimize (issue 26)."""
    code = ("import sys\n"
            "from analyses.service_life_lognormal import lognormal_fit\n"
            "w = lognormal_fit([10.0, 20.0, 30.0, 40.0, 50.0, 60.0], [True, True, False, True, False, True])\n"
            "print(w.note is None, 'scipy.optimize' in sys.modules, 'scipy.stats' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "False", "False"]


def test_weibull_censored_nll_is_the_censored_likelihood():
    """The negative log-likelihood of failures (density) and suspensions (survival); inf outside;
    a scaled censored life that overflows raises, a plain life that does is a penalty."""
    x_f, x_c = np.array([1.0, 2.0, 3.5]), np.array([4.0, 0.5])
    k, s = 1.7, 3.0
    z_f, z_c = x_f / s, x_c / s
    loglik = np.sum(np.log(k / s) + (k - 1) * np.log(z_f) - z_f ** k) - np.sum(z_c ** k)
    assert weibull_censored_nll(np.array([k, s]), x_f, x_c) == pytest.approx(-loglik, rel=1e-13)
    assert weibull_censored_nll(np.array([-1.0, s]), x_f, x_c) == np.inf
    assert weibull_censored_nll(np.array([k, 0.0]), x_f, x_c) == np.inf
    assert weibull_censored_nll(np.array([k, s]), x_f, None) == pytest.approx(
        -np.sum(np.log(k / s) + (k - 1) * np.log(z_f) - z_f ** k), rel=1e-13)
    with np.errstate(all="ignore"):
        with pytest.raises(ValueError):
            weibull_censored_nll(np.array([k, 1e-320]), np.array([1e300]), x_c)
        assert weibull_censored_nll(np.array([k, 1e-320]), np.array([1e300, 1.0]), None) > 1e5


def test_a_censored_weibull_fit_imports_no_scipy_stats():
    """The remaining-life stage's life models fit censored lives: a rebuild that re-runs it after
    one leakage check imports neither scipy.stats nor scipy.optimize for them (issue 26)."""
    code = ("import sys, numpy as np\n"
            "from analyses.service_life import weibull_fit\n"
            "w = weibull_fit([10.0, 20.0, 30.0, 40.0, 50.0, 60.0], [True, True, False, True, False, True])\n"
            "print(w.ok, sorted({m.split('.')[1] for m in sys.modules if m.startswith('scipy.')} & {'optimize', 'stats'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "[]"]
