"""Tests of analyses.numerics: scipy's Savitzky-Golay derivative, Brent root and second-order
Butterworth zero-phase filter, bounded scalar minimiser, Student t and Welch test, bit for bit."""
import math

import numpy as np
import pytest

from analyses.numerics import (two_sided_z, brentq, chi2_ppf, chi2_sf, fminbound, norm_isf, norm_pdf, norm_sf, savgol_derivative, student_t_ppf,
                               student_t_sf, welch_t_test_p)


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


def test_fminbound_takes_scipys_steps():
    import scipy.optimize

    rng = np.random.default_rng(274)
    for i in range(300):
        c, w = rng.uniform(-5, 5), rng.uniform(0.1, 3)
        lo, hi = c - w * rng.uniform(0.1, 2), c + w * rng.uniform(0.1, 2)
        k = int(rng.integers(2, 5)) if i % 2 else rng.integers(2, 5)  # a numpy exponent: f sees scipy's types

        def f(z, c=c, k=k):
            return float(abs(z - c) ** k + 0.1 * math.sin(5 * z))
        xatol = 1e-3 * (hi - lo) + 1e-12 if i % 3 else 1e-9
        expected = scipy.optimize.minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": xatol}).x
        assert fminbound(f, lo, hi, xatol) == expected
    # a parabola's minimum, and a minimum at a bound
    assert fminbound(lambda z: (z - 1.25) ** 2, -3.0, 4.0, 1e-10) == pytest.approx(1.25, abs=1e-8)
    assert fminbound(lambda z: z, 0.0, 1.0, 1e-9) == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError):
        fminbound(lambda z: z, 1.0, 0.0)


def test_student_t_and_welch_give_scipys_bits():
    import warnings

    import scipy.stats

    rng = np.random.default_rng(401)
    for i in range(300):
        q, x = rng.uniform(0.5, 0.9999), rng.normal() * 3
        df = [rng.uniform(0.5, 100), np.inf, 3, 1][i % 4]
        assert student_t_ppf(q, df) == scipy.stats.t.ppf(q, df)
        assert student_t_sf(x, df) == scipy.stats.t.sf(x, df)
        a = rng.normal(10, rng.uniform(0.01, 3), rng.integers(2, 30))
        b = rng.normal(10.5, rng.uniform(0.01, 3), rng.integers(2, 30)) if i % 7 else np.full(3, 4.0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert welch_t_test_p(a, b) == scipy.stats.ttest_ind(a, b, equal_var=False).pvalue
    # hand-checked: t(1) is Cauchy, t(inf) normal; equal samples' means differ by nothing
    assert student_t_ppf(0.75, 1) == pytest.approx(1.0, rel=1e-12)
    assert student_t_sf(0.0, 7) == 0.5 and student_t_sf(math.inf, 3) == 0.0 and student_t_sf(-math.inf, 3) == 1.0
    assert student_t_ppf(0.975, np.inf) == pytest.approx(1.959963984540054, rel=1e-12)
    assert math.isnan(student_t_ppf(0.9, 0.0)) and math.isnan(student_t_sf(math.nan, 3))
    assert welch_t_test_p([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]) == 1.0
    assert math.isnan(welch_t_test_p([], [1.0, 2.0]))


def test_chi2_sf_and_ppf_give_scipys_bits():
    import scipy.stats

    rng = np.random.default_rng(402)
    for i in range(400):
        df = [1, 2, rng.uniform(0.5, 30)][i % 3]
        x, q = rng.exponential(4.0), rng.uniform(1e-6, 1 - 1e-6)
        assert chi2_sf(x, df) == scipy.stats.chi2.sf(x, df)
        assert chi2_ppf(q, df) == scipy.stats.chi2.ppf(q, df)
    assert chi2_sf(0.0, 1) == scipy.stats.chi2.sf(0.0, 1) == 1.0
    assert chi2_ppf(0.0, 1) == 0.0 and chi2_ppf(1.0, 1) == np.inf
    assert np.isnan(chi2_sf(np.nan, 1)) and np.isnan(chi2_ppf(1.5, 1)) and np.isnan(chi2_sf(1.0, 0))


def test_a_life_effect_is_computed_without_importing_scipy_stats_or_optimize():
    """life_effect (common or separate shapes) reaches scipy only through scipy.special: a rebuild whose
    decision or remaining-life stage re-runs does not pay scipy.stats' import for it (issue 26)."""
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "from analyses.life_effect import life_effect\n"
            "rng = np.random.default_rng(3)\n"
            "x = np.concatenate([1000 * rng.weibull(1.2, 15), 1500 * rng.weibull(3.5, 15)])\n"
            "e = life_effect(np.minimum(x, 2500), x <= 2500, np.repeat([0, 1], 15))\n"
            "print(e.model.replace(' ', '_'), np.isfinite(e.life_ratio_lower), "
            "sorted({m.split('.')[1] for m in sys.modules if m.startswith('scipy.')} & {'stats', 'optimize'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["separate_shapes", "True", "[]"]


def test_the_normal_helpers_give_scipy_stats_bits():
    import scipy.stats

    rng = np.random.default_rng(403)
    x = np.concatenate([rng.normal(0, 4, 500), [0.0, -0.0, np.inf, -np.inf, np.nan, 38.0, -38.0]])
    q = np.concatenate([rng.uniform(0, 1, 500), [0.0, 1.0, 1e-300, 0.5, np.nan, 1.5, -0.1]])
    np.testing.assert_array_equal(norm_sf(x), scipy.stats.norm.sf(x))
    np.testing.assert_array_equal(norm_pdf(x), scipy.stats.norm.pdf(x))
    np.testing.assert_array_equal(norm_isf(q), scipy.stats.norm.isf(q))
    for v, p in zip(x[:50], q[:50]):  # scalars come back as numpy scalars, as scipy's do
        assert norm_sf(v) == scipy.stats.norm.sf(v) and type(norm_sf(v)) is type(scipy.stats.norm.sf(v))
        assert norm_isf(p) == scipy.stats.norm.isf(p) and norm_pdf(v) == scipy.stats.norm.pdf(v)


def test_a_sequential_design_is_computed_without_importing_scipy_stats_or_optimize():
    """The spending functions and the designs (analyses.sequential*) reach scipy through scipy.special
    only: the remaining-life stage's sensitivity verdict, re-run on a leakage change, pays no scipy.stats."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from analyses.sequential import max_information\n"
            "from analyses.sequential_boundaries import efficacy_boundaries\n"
            "import numpy as np\n"
            "c = efficacy_boundaries(np.arange(1, 21) / 20, 0.05, 'obrien-fleming')\n"
            "m = max_information(1.5, 0.05, 0.8, 'pocock', 2.0)\n"
            "print(round(float(c[-1]), 3), m.failures > 0, "
            "sorted({m.split('.')[1] for m in sys.modules if m.startswith('scipy.')} & {'stats', 'optimize'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out[1:] == ["True", "[]"] and 2.0 < float(out[0]) < 2.3  # the last O'Brien-Fleming-type boundary: a little above 1.96


def test_two_sided_z_is_ndtri_bit_for_bit():
    """The constants of the usual confidences are scipy's ``ndtri`` exactly, and any other
    confidence is computed by it (the findings' uncertainties keep their bits)."""
    from scipy.special import ndtri

    usual = {0.8: 1.2815515655446004, 0.9: 1.6448536269514722, 0.95: 1.959963984540054, 0.99: 2.5758293035489004}
    for conf, z in usual.items():
        assert z == float(ndtri(0.5 + conf / 2)), conf
        assert two_sided_z(conf) == z
    for conf in (0.5, 0.68, 0.85, 0.9000001, 0.975, 0.999):
        assert two_sided_z(conf) == float(ndtri(0.5 + conf / 2))
