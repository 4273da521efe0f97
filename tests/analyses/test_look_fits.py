"""The looks' fits solved together and their repeated confidence intervals by the profile likelihood: each
look's own fit, the ends where the look's deviance reaches its critical value (the same as the bracketed
search, the same as life_effect's interval), NaN where the data do not bound a side, and the coverage of a
known ratio."""
import math

import numpy as np
import pytest
import scipy

from analyses.life_effect import common_shape_fit, life_effect, ratio_deviance
from analyses.life_effect_lognormal import lognormal_effect_fit, lognormal_ratio_deviance
from analyses.look_fits import BARTLETT, bartlett_factor, look_fits, profile_rci


def looks_of(seed, n=20, ratio=1.5, shape=2.0, first=6):
    """(life, failed, group, look, looks): n hoses an adjustment all installed at once, a look at each
    failure from the ``first``-th on, the others censored at that failure's distance."""
    rng = np.random.default_rng(seed)
    x = np.r_[1000.0 * rng.weibull(shape, n), ratio * 1000.0 * rng.weibull(shape, n)]
    g = np.r_[np.zeros(n, int), np.ones(n, int)]
    ends = np.sort(x)[first - 1:]
    parts = [(np.minimum(x, e), x <= e, g, np.full(2 * n, j)) for j, e in enumerate(ends, start=first)]
    life, failed, group, look = (np.concatenate([p[i] for p in parts]) for i in range(4))
    return life, failed, group, look, np.arange(first, first + ends.size)


def test_look_fits_equal_each_looks_own_fit():
    """The vectorised fit of every look is common_shape_fit of that look's hoses (to 1e-12), notes included:
    looks with too few failures, lives of 0 (just installed), and a look without rows."""
    rng = np.random.default_rng(11)
    parts = []
    for look in range(1, 16):
        m = int(rng.integers(0, 30))
        x = rng.weibull(rng.uniform(0.8, 4.0), m) * 50.0 * np.where(np.arange(m) % 2, 1.6, 1.0)
        x[rng.random(m) < 0.1] = 0.0
        parts.append((np.full(m, look), x, rng.random(m) < rng.uniform(0.2, 1.0), np.arange(m) % 2))
    look, x, f, g = (np.concatenate([p[i] for p in parts]) for i in range(4))
    wanted = np.arange(1, 17)                       # look 16 has no rows
    fits = look_fits(x, f, g, look, wanted)
    fitted = 0
    for fit, number in zip(fits, wanted):
        m = look == number
        ref = common_shape_fit(x[m], f[m], g[m])
        assert fit.note == ref.note
        if ref.note is None:
            fitted += 1
            for a, b in ((fit.shape, ref.shape), (fit.log_ratio, ref.log_ratio), (fit.loglik, ref.loglik),
                         (fit.se_log_ratio, ref.se_log_ratio), (fit.scale_force, ref.scale_force)):
                assert a == pytest.approx(b, rel=1e-12, abs=1e-13)
    assert 5 <= fitted < len(wanted)                # both kinds of look were there


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_each_end_is_where_the_looks_deviance_reaches_its_critical_value(seed):
    life, failed, group, look, looks = looks_of(seed, first=12)
    z = np.linspace(3.5, 2.0, looks.size)           # a boundary falling over the looks, as O'Brien-Fleming's
    lo, hi = profile_rci(life, failed, group, look, looks, z)
    assert np.isfinite(lo).all() and np.isfinite(hi).all()
    for i, number in enumerate(looks):
        m = look == number
        fit = common_shape_fit(life[m], failed[m], group[m])
        assert lo[i] < fit.log_ratio < hi[i]
        for end in (lo[i], hi[i]):
            assert ratio_deviance(life[m], failed[m], group[m], math.exp(end)) == pytest.approx(z[i] ** 2, abs=1e-7)
    # the bracketed search look by look (any model's path) finds the same ends
    centre = [f.log_ratio for f in look_fits(life, failed, group, look, looks)]
    slo, shi = profile_rci(life, failed, group, look, looks, z, centre, deviance=lambda *a: ratio_deviance(*a))
    assert slo == pytest.approx(lo, abs=1e-9) and shi == pytest.approx(hi, abs=1e-9)


def test_at_a_confidence_levels_critical_value_it_is_life_effects_interval():
    life, failed, group, look, looks = looks_of(4, n=12)
    m = look == looks[-1]
    r = life_effect(life[m], failed[m], group[m], confidence=0.90)
    lo, hi = profile_rci(life, failed, group, look, looks[-1:], [math.sqrt(scipy.stats.chi2.ppf(0.90, 1))])
    assert math.exp(lo[0]) == pytest.approx(r.life_ratio_lower, rel=1e-8)
    assert math.exp(hi[0]) == pytest.approx(r.life_ratio_upper, rel=1e-8)


def test_a_side_the_data_do_not_bound_is_nan_and_a_look_without_a_fit_too():
    """Two failures an adjustment: the deviance stays below 36 up to 1e6 times the estimate either way."""
    x = np.array([1.0, 2.0, 3.0, 5.0, 1.5, 2.5, 9.0, 9.0])
    f = np.array([1, 1, 0, 0, 1, 1, 0, 0], bool)
    g = np.array([0, 0, 0, 0, 1, 1, 1, 1])
    assert ratio_deviance(x, f, g, 1e6) < 36 and ratio_deviance(x, f, g, 1e-6) < 36
    lo, hi = profile_rci(np.r_[x, x], np.r_[f, f], np.r_[g, g], np.repeat([1, 2], 8), [1, 2], [6.0, 1.0])
    assert np.isnan([lo[0], hi[0]]).all() and lo[1] < 0.0 < hi[1]
    one = f & (g == 0) & (x < 1.5)                  # one failure of the distance-set hoses: no fit
    assert np.isnan(profile_rci(x, one | (g == 1) & f, g, np.ones(8, int), [1], [2.0])).all()


def test_another_models_deviance_is_searched_with_its_own_estimate():
    life, failed, group, look, looks = looks_of(5, n=10)
    m = look == looks[-1]
    fit = lognormal_effect_fit(life[m], failed[m], group[m])
    lo, hi = profile_rci(life, failed, group, look, looks[-1:], [2.5], [fit.log_ratio], lognormal_ratio_deviance)
    assert lo[0] < fit.log_ratio < hi[0]
    for end in (lo[0], hi[0]):
        assert lognormal_ratio_deviance(life[m], failed[m], group[m], math.exp(end)) == pytest.approx(6.25, abs=1e-6)


def test_the_interval_covers_a_known_ratio_at_its_nominal_rate():
    """300 simulated hose types, 12 hoses an adjustment, censored at 1.2 scales, the 90 % interval (z 1.645):
    it covers the true ratio in 85-95 % of them."""
    rng = np.random.default_rng(23)
    z, covered, n = 1.6449, 0, 300
    for _ in range(n):
        t = np.r_[1000.0 * rng.weibull(2.0, 12), 1.3 * 1000.0 * rng.weibull(2.0, 12)]
        x, f, g = np.minimum(t, 1200.0), t <= 1200.0, np.r_[np.zeros(12, int), np.ones(12, int)]
        lo, hi = profile_rci(x, f, g, np.ones(24, int), [1], [z])
        covered += bool(lo[0] < math.log(1.3) < hi[0])
    assert 0.85 * n <= covered <= 0.95 * n


def test_later_looks_with_more_hoses_move_no_earlier_interval():
    """The same looks with a later look of many more hoses beside them (wider padded matrices): every
    earlier look's ends and fit are bit-identical (the same raw/ up to a look gives the same interval whatever came
    after)."""
    life, failed, group, look, looks = looks_of(6, n=14, first=10)
    z = np.full(looks.size, 2.4)
    lo, hi = profile_rci(life, failed, group, look, looks, z)
    more = looks_of(7, n=60, first=110)
    wide = [np.r_[a, b] for a, b in zip((life, failed, group, look), more[:4])]
    later = more[4][:3] + 1000
    wide[3][life.size:] += 1000
    lo2, hi2 = profile_rci(*wide, np.r_[looks, later], np.r_[z, 2.0, 2.0, 2.0])
    assert np.array_equal(lo2[:looks.size], lo) and np.array_equal(hi2[:looks.size], hi)
    for a, b in zip(look_fits(life, failed, group, look, looks), look_fits(*wide, np.r_[looks, later])):
        assert (a.shape, a.loglik, a.log_ratio, a.se_log_ratio) == (b.shape, b.loglik, b.log_ratio, b.se_log_ratio)


def test_the_bartlett_factor_is_one_plus_its_coefficient_over_the_failures_and_nan_without_any():
    b = bartlett_factor([0, 10, 38.0])
    assert np.isnan(b[0]) and b[1] == pytest.approx(1.0 + BARTLETT / 10) and b[2] == pytest.approx(1.0 + BARTLETT / 38)


def test_the_bartlett_factor_is_the_mean_deviance_at_the_truth_of_complete_samples():
    """600 complete samples of 8 + 8 Weibull lives (shape 2.5, true ratio 1.3): the deviance at the true
    ratio averages 1 + BARTLETT / 16 (about 1.24), not chi-square's 1, within 3 Monte Carlo SE."""
    rng = np.random.default_rng(11)
    g, f = np.r_[np.zeros(8, int), np.ones(8, int)], np.ones(16, bool)
    d = np.array([ratio_deviance(rng.weibull(2.5, 16) * np.where(g == 1, 1.3, 1.0), f, g, 1.3) for _ in range(600)])
    se = d.std() / math.sqrt(d.size)
    assert abs(d.mean() - float(bartlett_factor(16))) <= 3 * se
    assert d.mean() > 1.0 + 2 * se
