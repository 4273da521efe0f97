"""Hose service life: censored Weibull MLE (checked on Nelson's fans), B10 bounds, Kaplan-Meier, LR test."""
import math

import numpy as np
import pytest
from scipy import optimize, stats

from analyses.service_life import (b10, kaplan_meier, newton_root, reduced_bias_shape, weibull_fit,
                                   weibull_loglik, weibull_lr_test, weibull_quantile_bounds,
                                   weibull_quantile_profile)

# Nelson (1982, Applied Life Data Analysis, p. 318): 70 diesel-engine fans, hours; 0 = failure,
# 1 = censored, as listed in the SAS/QC PROC RELIABILITY "Getting Started" example, whose Weibull
# MLE on hours/1000 is shape 1.0584, scale 26.2968.
FANS = """
450 0 460 1 1150 0 1150 0 1560 1 1600 0 1660 1 1850 1 1850 1 1850 1 1850 1 1850 1 2030 1 2030 1
2030 1 2070 0 2070 0 2080 0 2200 1 3000 1 3000 1 3000 1 3000 1 3100 0 3200 1 3450 0 3750 1 3750 1
4150 1 4150 1 4150 1 4150 1 4300 1 4300 1 4300 1 4300 1 4600 0 4850 1 4850 1 4850 1 4850 1 5000 1
5000 1 5000 1 6100 1 6100 0 6100 1 6100 1 6300 1 6450 1 6450 1 6700 1 7450 1 7800 1 7800 1 8100 1
8100 1 8200 1 8500 1 8500 1 8500 1 8750 1 8750 0 8750 1 9400 1 9900 1 10100 1 10100 1 10100 1 11500 1
"""


def fans():
    v = np.array(FANS.split(), float).reshape(-1, 2)
    return v[:, 0] / 1000.0, v[:, 1] == 0


def test_fan_data_as_published():
    life, failed = fans()
    assert len(life) == 70 and failed.sum() == 12


def test_weibull_on_nelson_fans_matches_sas_to_four_significant_figures():
    fit = weibull_fit(*fans())
    sig4 = lambda v: float(f"{v:.4g}")  # noqa: E731
    assert sig4(fit.shape) == sig4(1.0584) and abs(fit.shape - 1.0584) < 5e-5
    assert sig4(fit.scale) == sig4(26.2968) and abs(fit.scale - 26.2968) < 5e-4
    assert (fit.n, fit.n_failed) == (70, 12)
    # the log-likelihood is scipy's: log density of failures + log survival of suspensions
    life, failed = fans()
    w = stats.weibull_min(fit.shape, scale=fit.scale)
    assert fit.loglik == pytest.approx(w.logpdf(life[failed]).sum() + w.logsf(life[~failed]).sum(), rel=1e-10)


def test_b10_is_the_ten_percent_quantile_with_bracketing_lr_bounds():
    life, failed = fans()
    r = b10(life, failed, confidence=0.90)
    assert r["b10"] == pytest.approx(r["scale"] * (-math.log(0.9)) ** (1 / r["shape"]))
    assert r["b10_lower"] < r["b10"] < r["b10_upper"]
    # likelihood-ratio bounds: the profile deviance equals chi2(0.90, 1) at each bound
    fit = weibull_fit(life, failed)
    crit = stats.chi2.ppf(0.90, 1)
    for bound in (r["b10_lower"], r["b10_upper"]):
        dev = 2 * (fit.loglik - weibull_quantile_profile(math.log(bound), 0.10, life, failed))
        assert dev == pytest.approx(crit, abs=1e-4)
    wide = weibull_quantile_bounds(fit, life, failed, 0.10, 0.99)
    assert wide[1] < r["b10_lower"] and wide[2] > r["b10_upper"]


def test_quantile_profile_is_the_likelihood_maximised_over_the_shape():
    """The exact profile (a concave problem in the shape) against a brute maximisation over a
    grid refined by a bounded search, for B10 and the median; at the MLE's quantile it is the maximum."""
    x = np.array([3.0, 7, 12, 20, 25, 31])
    f = np.array([1, 1, 1, 0, 1, 0], bool)
    fit = weibull_fit(x, f)
    for p in (0.10, 0.50):
        c = -math.log(1 - p)
        for log_q in (0.5, 1.5, 2.0, 2.8, 3.5):
            neg = lambda t, log_q=log_q: -weibull_loglik(math.exp(t), math.exp(log_q) / c ** math.exp(-t), x, f)  # noqa: E731
            grid = np.linspace(-4, 4, 801)
            t0 = grid[np.argmin([neg(t) for t in grid])]
            res = optimize.minimize_scalar(neg, bounds=(t0 - 0.02, t0 + 0.02), method="bounded",
                                           options={"xatol": 1e-11})
            assert weibull_quantile_profile(log_q, p, x, f) == pytest.approx(-res.fun, abs=1e-9)
        assert weibull_quantile_profile(math.log(fit.quantile(p)), p, x, f) == pytest.approx(fit.loglik, abs=1e-9)


def test_quantile_profile_is_the_same_from_any_start():
    """The shape's Newton solve ends at the same maximum from a near, a far and an edge start."""
    x, f = fans()
    fit = weibull_fit(x, f)
    for log_q in (0.5, 1.5, math.log(fit.quantile(0.1)), 3.5, 5.0):
        values = [weibull_quantile_profile(log_q, 0.1, x, f, start=s) for s in (0.0, math.log(fit.shape), -6.0, 6.0)]
        assert max(values) - min(values) < 1e-9 * abs(values[0])


def test_newton_root_is_brentqs_root_and_leaves_an_edge_to_the_caller():
    """A strictly decreasing function's root as brentq finds it, from either side; None when the
    root lies beyond the range (or the function has no root), so the caller's edge rule applies."""
    func = lambda t: (math.exp(-t) - 0.3 * t - 0.2, -math.exp(-t) - 0.3)  # noqa: E731
    want = optimize.brentq(lambda t: func(t)[0], -5, 5, xtol=1e-14)
    for start in (-5.0, -1.0, 0.0, 4.9, 50.0):
        assert newton_root(func, -5.0, 5.0, start) == pytest.approx(want, abs=1e-12)
    assert newton_root(func, 2.0, 5.0, 3.0) is None           # root (1.1..) below the range
    assert newton_root(lambda t: (-t - 10.0, -1.0), -5.0, 5.0, 0.0) is None
    assert newton_root(lambda t: (math.nan, -1.0), -5.0, 5.0, 0.0) is None


#: Nelson's fans and the 6-MP group of Freireich et al.'s leukemia remission times (weeks; the
#: ``anderson`` data of Kleinbaum & Klein, ``lifelines.datasets.load_leukemia`` rows with Rx = 0),
#: fitted by an independent implementation: reliability 0.9.0 (numpy 2.4.6, scipy 1.17.1,
#: autograd 1.9.1), ``Fit_Weibull_2P(failures=..., right_censored=..., method="MLE", CI=0.90,
#: show_probability_plot=False, print_results=False)`` -> ``alpha`` (scale), ``beta`` (shape),
#: ``loglik``. Stored because reliability is not one of the project's dependencies;
#: test_matches_the_reliability_package_live checks them wherever it is installed.
LEUKEMIA_6MP = ([35.0, 34, 32, 32, 25, 23, 22, 20, 19, 17, 16, 13, 11, 10, 10, 9, 7, 6, 6, 6, 6],
                [0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 1, 1, 0, 0, 1, 0, 1, 0, 1, 1, 1])
RELIABILITY_FIT_WEIBULL_2P = {
    "fans": dict(scale=26.29684502324552, shape=1.058445824687575, loglik=-52.259656595570846),
    "leukemia 6-MP": dict(scale=33.76514119656118, shape=1.353734209488257, loglik=-41.65867847688314),
}


def public_lives(name):
    """(life, failed) of a public data set named in RELIABILITY_FIT_WEIBULL_2P."""
    if name == "fans":
        return fans()
    return np.array(LEUKEMIA_6MP[0]), np.array(LEUKEMIA_6MP[1]) == 1


@pytest.mark.parametrize("name", sorted(RELIABILITY_FIT_WEIBULL_2P))
def test_matches_the_reliability_packages_fit_weibull_2p_on_public_data(name):
    ref = RELIABILITY_FIT_WEIBULL_2P[name]
    life, failed = public_lives(name)
    assert 0 < failed.sum() < len(failed)  # right-censored
    fit = weibull_fit(life, failed)
    assert fit.shape == pytest.approx(ref["shape"], rel=1e-5)
    assert fit.scale == pytest.approx(ref["scale"], rel=1e-5)
    assert fit.loglik == pytest.approx(ref["loglik"], rel=1e-9)
    assert b10(life, failed)["b10"] == pytest.approx(ref["scale"] * (-math.log(0.9)) ** (1 / ref["shape"]), rel=1e-4)


@pytest.mark.parametrize("name", sorted(RELIABILITY_FIT_WEIBULL_2P))
def test_matches_the_reliability_package_live(name):
    fitters = pytest.importorskip("reliability.Fitters")
    life, failed = public_lives(name)
    fit = fitters.Fit_Weibull_2P(failures=life[failed], right_censored=life[~failed], method="MLE", CI=0.90,
                                 show_probability_plot=False, print_results=False)
    ref = RELIABILITY_FIT_WEIBULL_2P[name]
    assert (fit.alpha, fit.beta, fit.loglik) == pytest.approx((ref["scale"], ref["shape"], ref["loglik"]), rel=1e-6)


def test_fewer_than_two_failures_give_nan():
    for failed in ([True, False, False, False], [False, False, False, False]):
        r = b10([10.0, 20.0, 30.0, 40.0], failed)
        assert all(math.isnan(r[k]) for k in ("shape", "scale", "b10", "b10_lower", "b10_upper"))
        assert r["n"] == 4 and r["n_failed"] == sum(failed)


def test_reduced_bias_shape_is_c4_to_the_3_5_hand_checked():
    # C4(10) = sqrt(2/9) Gamma(5) / Gamma(4.5) = 0.97266, ^3.5 = 0.90753; C4(2) = sqrt(2) / sqrt(pi)
    assert reduced_bias_shape(2.0, 10) == pytest.approx(2.0 * 0.90753, rel=1e-4)
    assert reduced_bias_shape(1.0, 2) == pytest.approx((2.0 / math.pi) ** 1.75, rel=1e-12)
    assert reduced_bias_shape(3.0, 10_000) == pytest.approx(3.0, rel=1e-3)   # no adjustment in the limit
    assert math.isnan(reduced_bias_shape(2.0, 1)) and math.isnan(reduced_bias_shape(math.nan, 10))


def test_reduced_bias_shape_is_median_unbiased_from_ten_failures():
    rng = np.random.default_rng(7)
    mle = np.array([weibull_fit(50.0 * rng.weibull(2.0, 10), np.ones(10, bool)).shape for _ in range(600)])
    assert np.median(mle) / 2.0 > 1.06 and mle.mean() / 2.0 > 1.12  # the MLE from 10 failures: steep
    rba = np.array([reduced_bias_shape(k, 10) for k in mle])
    assert abs(np.median(rba) / 2.0 - 1.0) < 0.03                   # median-unbiased (MC SE ~0.012)
    assert rba.mean() / 2.0 < mle.mean() / 2.0 - 0.09


def test_weibull_recovers_simulated_parameters_with_censoring():
    rng = np.random.default_rng(42)
    life = 90.0 * rng.weibull(2.4, 400)
    stop = rng.uniform(20, 200, 400)                 # random removals
    failed = life <= stop
    fit = weibull_fit(np.minimum(life, stop), failed)
    assert fit.shape == pytest.approx(2.4, rel=0.1)
    assert fit.scale == pytest.approx(90.0, rel=0.05)
    # and the MLE is a maximum
    for dk, ds in ((0.02, 0), (-0.02, 0), (0, 0.5), (0, -0.5)):
        assert weibull_loglik(fit.shape + dk, fit.scale + ds, np.minimum(life, stop), failed) < fit.loglik


def test_kaplan_meier_hand_checked():
    km = kaplan_meier([1, 2, 2, 3, 4], [True, False, True, True, False])
    assert km["life"].tolist() == [1, 2, 3, 4]
    assert km["n_at_risk"].tolist() == [5, 4, 2, 1]
    assert km["n_failed"].tolist() == [1, 1, 1, 0]
    assert km["n_censored"].tolist() == [0, 1, 0, 1]
    assert km["survival"].to_numpy() == pytest.approx([0.8, 0.6, 0.3, 0.3])
    # Greenwood at the first step: S * sqrt(d / (n (n - d)))
    assert km["std_err"].iloc[0] == pytest.approx(0.8 * math.sqrt(1 / (5 * 4)))


def test_kaplan_meier_without_censoring_is_the_empirical_survival():
    km = kaplan_meier([3, 1, 2, 4], [True] * 4)
    assert km["survival"].to_numpy() == pytest.approx([0.75, 0.5, 0.25, 0.0])


def test_lr_test_tells_different_groups_apart():
    rng = np.random.default_rng(7)
    force = 90.0 * rng.weibull(2.4, 40)
    dist = 40.0 * rng.weibull(1.8, 40)
    same = 40.0 * rng.weibull(1.8, 40)
    stop = 150.0
    g = lambda x: (np.minimum(x, stop), x <= stop)  # noqa: E731
    differ = weibull_lr_test({"force": g(force), "distance": g(dist)})
    assert differ["df"] == 2 and differ["p_value"] < 1e-4
    assert differ["lr"] == pytest.approx(2 * (differ["loglik_separate"] - differ["loglik_pooled"]))
    alike = weibull_lr_test({"a": g(same), "b": g(dist)})
    assert alike["p_value"] > 0.05
    one = weibull_lr_test({"force": ([10.0, 20.0, 30.0], [True, False, False]), "distance": g(dist)})
    assert math.isnan(one["p_value"])


@pytest.mark.parametrize("life,failed", [([10.0, 10.0, 10.0], [True, True, True]),          # one distance
                                         ([1.0, 2.0, 10.0, 10.0], [False, False, True, True]),
                                         ([10.0, 10.00001, 10.00002], [True, True, True])])
def test_shape_mle_at_the_search_bound_is_null_with_a_note(life, failed):
    fit = weibull_fit(life, failed)
    assert not fit.ok and math.isnan(fit.shape) and math.isnan(fit.scale)
    assert "bound" in fit.note and "cannot tell a shape" in fit.note
    r = b10(life, failed)
    assert math.isnan(r["b10"]) and r["note"] == fit.note


def test_too_few_failures_and_a_sound_fit_say_so():
    assert weibull_fit([10.0, 20.0, 30.0], [True, False, False]).note == "too few failures: 1 < 2"
    fit = weibull_fit([5.0, 10.0, 20.0, 30.0], [True, True, True, False])
    assert fit.ok and fit.note is None and b10([5.0, 10.0, 20.0, 30.0], [True, True, True, False])["note"] is None


# -- the service-life table a Weibull++ user expects (issue 25, item 17) -----------------------------------
from analyses.service_life import (MRR_MAX_FAILURES, SCALE_FRACTION, median_ranks, preferred_method,  # noqa: E402
                                   service_life_summary, weibull_rank_regression, weibull_reliability_bounds,
                                   weibull_shape_bounds)

#: ReliaWiki's (Weibull++) "Example 1" after Kececioglu: six units, all failed [h]; its MLE example gives
#: shape 1.933, scale 73.526; the exact median ranks it tabulates for rank regression (0.1091 ... 0.8909).
RELIAWIKI_SIX = [16.0, 34, 53, 75, 93, 120]
RELIAWIKI_MEDIAN_RANKS = [0.1091, 0.2645, 0.4214, 0.5786, 0.7355, 0.8909]
#: ReliaWiki's likelihood-ratio example: five failures at 10 ... 50 h, MLE shape 2.2938, scale 33.9428.
RELIAWIKI_FIVE = [10.0, 20, 30, 40, 50]
#: Reliability HotWire 104 ("Median rank based on mean order number", the Weibull++ method): S 2500,
#: F 2730, F 3900, S 4100, F 5000 h; by Johnson's formula the failures' mean order numbers are 1.2, 2.4, 4.2.
HOTWIRE = ([2500.0, 2730, 3900, 4100, 5000], [False, True, True, False, True])
#: reliability 0.9.0 (numpy 2.4.6, scipy 1.17.1) ``Fit_Weibull_2P(failures=..., right_censored=...,
#: method="RRX", CI=0.90, show_probability_plot=False, print_results=False)`` -> ``alpha``, ``beta``: an
#: independent implementation of median-rank regression (Benard, Johnson's adjusted ranks; data sets without
#: a failure and a suspension at the same life, where its unstable sort leaves the order to chance).
RELIABILITY_RRX = {
    "reliawiki six": dict(scale=76.1095957909622, shape=1.4396632767940571),
    "hotwire": dict(scale=4706.287149747937, shape=3.2183943086483784),
    "leukemia 6-MP": dict(scale=22.797101060354887, shape=1.9726558549410969),
}


def rrx_lives(name):
    if name == "reliawiki six":
        return np.array(RELIAWIKI_SIX), np.ones(6, bool)
    if name == "hotwire":
        return np.array(HOTWIRE[0]), np.array(HOTWIRE[1])
    return public_lives(name)


def test_median_ranks_by_johnson_and_benard_hand_checked():
    mr = median_ranks(*HOTWIRE)
    assert mr["life"].tolist() == [2730.0, 3900.0, 5000.0]
    assert mr["adjusted_rank"].to_numpy() == pytest.approx([1.2, 2.4, 4.2], abs=1e-12)
    assert mr["median_rank"].to_numpy() == pytest.approx([0.9 / 5.4, 2.1 / 5.4, 3.9 / 5.4], abs=1e-12)
    # without suspensions: ranks 1..n and Benard's (i - 0.3) / (n + 0.4), within 0.0012 of the exact
    # (binomial) median ranks ReliaWiki tabulates
    mr = median_ranks(RELIAWIKI_SIX[::-1], [True] * 6)
    assert mr["adjusted_rank"].tolist() == [1.0, 2, 3, 4, 5, 6]
    assert mr["median_rank"].to_numpy() == pytest.approx((np.arange(1, 7) - 0.3) / 6.4, abs=1e-15)
    assert mr["median_rank"].to_numpy() == pytest.approx(RELIAWIKI_MEDIAN_RANKS, abs=1.2e-3)
    # a failure and a suspension at the same life: the failure first (as Kaplan-Meier)
    assert median_ranks([5.0, 5.0, 9.0], [False, True, True])["adjusted_rank"].tolist() == [1.0, 2.5]


def test_mle_matches_reliawikis_published_examples():
    """To the last digit ReliaWiki prints (it cuts rather than rounds: 33.94291 is printed 33.9428)."""
    for lives, shape, scale, decimals in ((RELIAWIKI_SIX, 1.933, 73.526, 3), (RELIAWIKI_FIVE, 2.2938, 33.9428, 4)):
        fit = weibull_fit(lives, [True] * len(lives))
        assert abs(fit.shape - shape) < 1.5 * 10.0 ** -decimals and abs(fit.scale - scale) < 1.5 * 10.0 ** -decimals


def test_rank_regression_on_x_is_the_least_squares_line_of_log_life_on_the_plot_ordinate():
    x = np.array(RELIAWIKI_SIX)
    y = np.log(-np.log(1 - (np.arange(1, 7) - 0.3) / 6.4))
    slope, intercept = np.polyfit(y, np.log(x), 1)            # ln(life) on y: X on Y
    mrr = weibull_rank_regression(x, np.ones(6, bool))
    assert mrr.shape == pytest.approx(1 / slope, rel=1e-12) and mrr.scale == pytest.approx(math.exp(intercept), rel=1e-12)
    assert mrr.loglik < weibull_fit(x, np.ones(6, bool)).loglik   # not the likelihood's maximum
    assert mrr.quantile(0.10) == pytest.approx(mrr.scale * (-math.log(0.9)) ** (1 / mrr.shape))


@pytest.mark.parametrize("name", sorted(RELIABILITY_RRX))
def test_rank_regression_matches_the_reliability_packages_rrx(name):
    ref = RELIABILITY_RRX[name]
    mrr = weibull_rank_regression(*rrx_lives(name))
    assert (mrr.shape, mrr.scale) == pytest.approx((ref["shape"], ref["scale"]), rel=1e-10)


@pytest.mark.parametrize("name", sorted(RELIABILITY_RRX))
def test_rank_regression_matches_the_reliability_package_live(name):
    fitters = pytest.importorskip("reliability.Fitters")
    life, failed = rrx_lives(name)
    fit = fitters.Fit_Weibull_2P(failures=life[failed], right_censored=life[~failed] if (~failed).any() else None,
                                 method="RRX", CI=0.90, show_probability_plot=False, print_results=False)
    assert (fit.alpha, fit.beta) == pytest.approx((RELIABILITY_RRX[name]["scale"], RELIABILITY_RRX[name]["shape"]),
                                                  rel=1e-6)


def test_rank_regression_recovers_simulated_parameters_and_refuses_what_cannot_tell():
    rng = np.random.default_rng(11)
    life = 500.0 * rng.weibull(2.5, 400)
    stop = rng.uniform(300, 900, 400)
    mrr = weibull_rank_regression(np.minimum(life, stop), life <= stop)
    assert mrr.shape == pytest.approx(2.5, rel=0.1) and mrr.scale == pytest.approx(500.0, rel=0.05)
    assert weibull_rank_regression([10.0, 20.0, 30.0], [True, False, False]).note == "too few failures: 1 < 2"
    same = weibull_rank_regression([10.0, 10.0, 10.0], [True, True, True])
    assert not same.ok and "cannot tell a shape" in same.note


def test_preferred_method_follows_abernethys_twenty_failures():
    assert [preferred_method(r) for r in (0, 1, 2, MRR_MAX_FAILURES, MRR_MAX_FAILURES + 1, 500)] == [
        None, None, "MRR", "MRR", "MLE", "MLE"]
    assert MRR_MAX_FAILURES == 20


def _deviance_of_shape(k, x, f, fit):
    from analyses.service_life import weibull_scale_given_shape
    return 2 * (fit.loglik - weibull_loglik(k, weibull_scale_given_shape(k, x, f), x, f))


def test_shape_and_scale_bounds_are_where_the_profile_deviance_reaches_chi2():
    x, f = public_lives("leukemia 6-MP")
    fit = weibull_fit(x, f)
    crit = stats.chi2.ppf(0.90, 1)
    lo, hi = weibull_shape_bounds(fit, x, f, 0.90)
    assert lo < fit.shape < hi
    for k in (lo, hi):
        assert _deviance_of_shape(k, x, f, fit) == pytest.approx(crit, abs=1e-6)
    # the scale profile, maximised over the shape by brute force, reaches chi2 at the scale bounds
    _, s_lo, s_hi = weibull_quantile_bounds(fit, x, f, SCALE_FRACTION, 0.90)
    assert s_lo < fit.scale < s_hi
    for s in (s_lo, s_hi):
        best = -optimize.minimize_scalar(lambda t: -weibull_loglik(math.exp(t), s, x, f), bounds=(-3, 3),
                                         method="bounded", options={"xatol": 1e-10}).fun
        assert 2 * (fit.loglik - best) == pytest.approx(crit, abs=1e-5)
    wider = weibull_shape_bounds(fit, x, f, 0.99)
    assert wider[0] < lo and wider[1] > hi


def test_reliability_bounds_are_the_quantile_bounds_read_the_other_way():
    """p is inside the interval of F(t) exactly when t is inside the interval of the p-quantile: at a
    mission equal to a B10 bound, one bound of R is 0.90 (Meeker & Escobar 1998, section 8.3)."""
    x, f = fans()
    fit = weibull_fit(x, f)
    b, b_lo, b_hi = weibull_quantile_bounds(fit, x, f, 0.10, 0.90)
    r, r_lo, r_hi = weibull_reliability_bounds(fit, x, f, b_hi, 0.90)
    assert r_hi == pytest.approx(0.90, abs=1e-7) and r_lo < r < r_hi
    r, r_lo, r_hi = weibull_reliability_bounds(fit, x, f, b_lo, 0.90)
    assert r_lo == pytest.approx(0.90, abs=1e-7)
    r, r_lo, r_hi = weibull_reliability_bounds(fit, x, f, b, 0.90)
    assert r == pytest.approx(0.90) and r_lo < 0.90 < r_hi
    assert all(math.isnan(v) for v in weibull_reliability_bounds(fit, x, f, -1.0))
    assert all(math.isnan(v) for v in weibull_reliability_bounds(weibull_fit([1.0, 2.0], [True, False]), x, f, 5.0))


def test_the_summary_row_with_a_plans_b_life_confidence_and_mission():
    x, f = public_lives("leukemia 6-MP")
    s = service_life_summary(x, f, b_life_pct=5.0, confidence=0.95, mission=10.0)
    fit = weibull_fit(x, f)
    assert (s["shape"], s["scale"]) == (fit.shape, fit.scale)
    assert (s["b_life"], s["b_life_lower"], s["b_life_upper"]) == weibull_quantile_bounds(fit, x, f, 0.05, 0.95)
    assert (s["shape_lower"], s["shape_upper"]) == weibull_shape_bounds(fit, x, f, 0.95)
    assert s["reliability"] == pytest.approx(math.exp(-(10.0 / fit.scale) ** fit.shape))
    assert s["reliability_lower"] < s["reliability"] < s["reliability_upper"]
    assert s["mrr_shape"] == pytest.approx(RELIABILITY_RRX["leukemia 6-MP"]["shape"])
    assert s["mrr_b_life"] == pytest.approx(s["mrr_scale"] * (-math.log(0.95)) ** (1 / s["mrr_shape"]))
    assert s["preferred_method"] == "MRR" and s["note"] is None and s["bounds_note"] is None
    # B10 and the plan's defaults: the b10 dict's values; no mission, no reliability
    d = service_life_summary(x, f)
    old = b10(x, f, 0.90)
    assert (d["b_life"], d["b_life_lower"], d["b_life_upper"]) == (old["b10"], old["b10_lower"], old["b10_upper"])
    assert math.isnan(d["reliability"]) and math.isnan(d["reliability_lower"])
    one = service_life_summary([10.0, 20.0, 30.0], [True, False, False], mission=5.0)
    assert all(math.isnan(one[k]) for k in ("shape", "shape_lower", "scale_upper", "b_life", "reliability", "mrr_shape"))
    assert one["preferred_method"] is None and one["note"] == "too few failures: 1 < 2" and one["bounds_note"] is None


def test_a_side_the_data_do_not_bound_is_nan_and_named():
    """Two early failures under forty long suspensions: nothing bounds the scale or B10 from above
    within 1e6 times the estimate, so those bounds are NaN and the note names them; the rest stand."""
    x = np.r_[[1.0, 1.001], np.full(40, 1000.0)]
    f = np.r_[[True, True], np.zeros(40, bool)]
    s = service_life_summary(x, f, mission=2000.0)
    assert s["note"] is None and math.isfinite(s["shape"])
    assert math.isnan(s["scale_upper"]) and math.isnan(s["b_life_upper"])
    assert s["bounds_note"] == "the data do not bound scale_upper, b_life_upper"
    assert s["shape_lower"] < s["shape"] < s["shape_upper"] and s["reliability_lower"] < s["reliability_upper"]




def test_lr_bound_evaluates_each_point_once_and_finds_the_root():
    """``brentq`` starts from the bracketing step's ends, which the outward search already evaluated
    (a profile solve each in the real callers): each point is computed once, the bound is the root."""
    from analyses.service_life import lr_bound

    calls = []

    def excess(t):
        calls.append(t)
        return t * t - 2.0

    assert abs(lr_bound(excess, 0.0, 10.0) - math.sqrt(2.0)) < 1e-10
    assert abs(lr_bound(excess, 0.0, -10.0) + math.sqrt(2.0)) < 1e-10
    assert len(calls) == len(set(calls))
    assert math.isnan(lr_bound(excess, 0.0, 1.0))      # never reaches the critical value up to the edge
