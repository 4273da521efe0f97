"""The censored lognormal beside the Weibull: its likelihood against scipy's, its fit on Nelson's
fans against scipy's censored fit, and its parameters recovered from simulated lives."""
import math

import numpy as np
import pytest
from scipy import stats

from analyses.service_life_lognormal import lognormal_fit, lognormal_loglik_many
from tests.analyses.test_service_life import fans


def test_lognormal_loglik_is_the_censored_normal_of_the_log_lives():
    life, failed = np.array([1.0, 2.0, 3.5, 5.0]), np.array([True, False, True, True])
    many = lognormal_loglik_many([0.5, 1.2], [2.0, 3.0], life, failed)
    for got, (sg, md) in zip(many, [(0.5, 2.0), (1.2, 3.0)]):
        want = (stats.lognorm.logpdf(life[failed], sg, scale=md).sum()
                + stats.lognorm.logsf(life[~failed], sg, scale=md).sum())
        assert got == pytest.approx(want)
    assert lognormal_loglik_many(-1.0, 3.0, life, failed) == -np.inf


def test_lognormal_fit_matches_scipys_censored_fit_on_nelsons_fans():
    life, failed = fans()
    fit = lognormal_fit(life, failed)
    s, _, md = stats.lognorm.fit(stats.CensoredData.right_censored(life, ~failed), floc=0)
    assert (fit.sigma, fit.median) == pytest.approx((s, md), rel=1e-4)
    assert fit.loglik == pytest.approx(float(lognormal_loglik_many(s, md, life, failed)), abs=1e-6)


def test_lognormal_fit_recovers_its_parameters_and_needs_two_failures():
    rng = np.random.default_rng(11)
    t = np.exp(math.log(500.0) + 0.4 * rng.standard_normal(2000))
    end = rng.uniform(300.0, 900.0, t.size)
    fit = lognormal_fit(np.minimum(t, end), t <= end)
    assert fit.ok and fit.median == pytest.approx(500.0, rel=0.03) and fit.sigma == pytest.approx(0.4, rel=0.06)
    one = lognormal_fit([10.0, 20.0, 30.0], [True, False, False])
    assert not one.ok and "too few failures" in one.note
