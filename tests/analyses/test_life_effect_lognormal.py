"""analyses/life_effect_lognormal.py: the common-sigma lognormal life ratio, checked by hand on complete
lives (closed forms), its score and Hessian against differences, and recovered from censored simulations."""
import math

import numpy as np
import pytest
from scipy import stats

from analyses import life_effect_lognormal as ln
from analyses.service_life_lognormal import lognormal_fit


def _complete(seed=1, n=(10, 12), mu=(0.0, 0.3), sigma=0.5):
    rng = np.random.default_rng(seed)
    y0, y1 = rng.normal(mu[0], sigma, n[0]), rng.normal(mu[1], sigma, n[1])
    return (np.exp(np.r_[y0, y1]), np.ones(sum(n), bool), np.r_[np.zeros(n[0], int), np.ones(n[1], int)], y0, y1)


def test_complete_lives_by_hand():
    # complete normal regression: theta = difference of mean logs, sigma^2 = pooled SS / n,
    # se^2 = sigma^2 (1/n0 + 1/n1), deviance(theta) = n log(1 + (theta - hat)^2 n0 n1 / (n SS))
    x, f, g, y0, y1 = _complete()
    fit = ln.lognormal_effect_fit(x, f, g)
    ss = float(((y0 - y0.mean()) ** 2).sum() + ((y1 - y1.mean()) ** 2).sum())
    assert fit.log_ratio == pytest.approx(y1.mean() - y0.mean(), abs=1e-7)
    assert fit.mu_distance == pytest.approx(y0.mean(), abs=1e-7)
    assert fit.sigma == pytest.approx(math.sqrt(ss / 22), rel=1e-6)
    assert fit.se_log_ratio == pytest.approx(math.sqrt(ss / 22 * (1 / 10 + 1 / 12)), rel=1e-5)
    for trial in (0.3, -0.2):
        d = trial - fit.log_ratio
        assert ln.lognormal_ratio_deviance(x, f, g, math.exp(trial)) == pytest.approx(
            22 * math.log(1 + d * d * 120 / (22 * ss)), rel=1e-6)
    le = ln.lognormal_life_effect(x, f, g, confidence=0.9)
    crit = stats.chi2.ppf(0.9, 1)
    for bound in (le.life_ratio_lower, le.life_ratio_upper):       # the bounds are where the deviance is crit
        assert ln.lognormal_ratio_deviance(x, f, g, bound) == pytest.approx(crit, rel=1e-5)
    assert le.model == ln.LOGNORMAL and le.note is None and math.isnan(le.shape)
    assert le.p_value == pytest.approx(stats.chi2.sf(ln.lognormal_ratio_deviance(x, f, g, 1.0), 1), rel=1e-6)


def test_one_group_each_side_agrees_with_service_lifes_lognormal():
    # at the ratio held at the estimate of the force lives alone, the profile is two one-sample fits with
    # one sigma; with the force lives a copy of the distance lives the ratio is 1 and sigma that sample's
    x, f, _, _, _ = _complete(seed=3, n=(9, 9))
    f[[1, 4]] = False
    life, failed = np.r_[x[:9], x[:9]], np.r_[f[:9], f[:9]]
    fit = ln.lognormal_effect_fit(life, failed, np.r_[np.zeros(9, int), np.ones(9, int)])
    one = lognormal_fit(x[:9], f[:9])
    assert fit.log_ratio == pytest.approx(0.0, abs=1e-6)
    assert fit.sigma == pytest.approx(one.sigma, rel=1e-4)
    assert fit.loglik == pytest.approx(2 * one.loglik, rel=1e-6)


def test_score_and_hessian_match_differences_with_censoring():
    x, f, g, _, _ = _complete(seed=2)
    f[[1, 3, 12, 15]] = False
    groups = ln.split_groups(x, f, g)
    stacked, p, eps = ln._stack(groups), np.array([0.1, 0.2, 0.6]), 1e-6
    score, hess = ln._derivatives(stacked, *p)
    for i in range(3):
        e = eps * np.eye(3)[i]
        assert score[i] == pytest.approx((ln._loglik(groups, *(p + e)) - ln._loglik(groups, *(p - e))) / (2 * eps),
                                         rel=1e-6)
        num = (ln._derivatives(stacked, *(p + e))[0] - ln._derivatives(stacked, *(p - e))[0]) / (2 * eps)
        assert hess[i] == pytest.approx(num, rel=1e-5, abs=1e-6)


def test_recovers_a_known_ratio_from_censored_lives_and_its_interval_covers():
    # 150 simulated types, true ratio 1.6, sigma 0.4, Type I censoring at 1.5x the median (~15 %); the
    # 90 % profile interval holds 1.6 exactly when the deviance there is below chi2(0.9, 1)
    covered, est, crit = 0, [], stats.chi2.ppf(0.9, 1)
    for seed in range(150):
        rng = np.random.default_rng([7, seed])
        g = np.repeat([0, 1], 15)
        life = np.exp(math.log(1000.0) + math.log(1.6) * g + 0.4 * rng.standard_normal(30))
        end = 1500.0 * np.where(g == 1, 1.6, 1.0)
        x, f = np.minimum(life, end), life <= end
        est.append(ln.lognormal_effect_fit(x, f, g).log_ratio)
        covered += ln.lognormal_ratio_deviance(x, f, g, 1.6) < crit
    assert np.mean(est) == pytest.approx(math.log(1.6), abs=0.03)   # its sd over 150: 0.012
    assert 0.84 <= covered / 150 <= 0.96                      # 90 % nominal; binomial sd 2.4 points


def test_too_few_failures_or_no_spread_is_nan_with_a_note():
    x, f, g, _, _ = _complete()
    f[g == 1] = False
    f[np.flatnonzero(g == 1)[0]] = True
    le = ln.lognormal_life_effect(x, f, g)
    assert math.isnan(le.life_ratio) and le.note == "too few failures to tell a lognormal: force 1 < 2"
    assert math.isnan(ln.lognormal_ratio_deviance(x, f, g, 1.0))
    same = ln.lognormal_effect_fit(np.r_[np.full(5, 10.0), np.full(5, 20.0)], np.ones(10, bool), np.repeat([0, 1], 5))
    assert math.isnan(same.log_ratio) and "cannot tell a spread" in same.note
    assert math.isnan(ln.lognormal_life_effect(np.r_[np.full(5, 10.0), np.full(5, 20.0)], np.ones(10, bool),
                                               np.repeat([0, 1], 5)).life_ratio)
