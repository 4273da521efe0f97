"""The life effect: common-shape Weibull regression of life on the adjustment, profile bounds,
LR tests, NaN rules; cross-checked against lifelines' Weibull AFT fit."""
import math

import numpy as np
import pandas as pd
import pytest
import scipy

from analyses.life_effect import (COMMON, SEPARATE, LifeEffect, split_groups, b10_ratio_separate_shapes, common_shape_fit,
                                  life_effect)
from analyses.service_life import weibull_fit, weibull_loglik


def censored_sample(seed, n, ratio, shape, censor_km, scale_km=5000.0):
    """(life, failed, group): n hoses per adjustment, Type I censored at ``censor_km``."""
    rng = np.random.default_rng(seed)
    t = np.r_[scale_km * rng.weibull(shape, n), ratio * scale_km * rng.weibull(shape, n)]
    return np.minimum(t, censor_km), t <= censor_km, np.r_[np.zeros(n, int), np.ones(n, int)]


def test_recovers_a_known_ratio_and_shape_from_large_censored_samples():
    life, failed, group = censored_sample(1, 1500, ratio=1.6, shape=2.2, censor_km=7000.0)
    r = life_effect(life, failed, group)
    assert 0.2 < failed[group == 1].mean() < failed[group == 0].mean() < 0.9  # real censoring in both
    assert r.life_ratio == pytest.approx(1.6, rel=0.04) and r.shape == pytest.approx(2.2, rel=0.05)
    assert r.life_ratio_lower < 1.6 < r.life_ratio_upper and r.shape_lower < 2.2 < r.shape_upper
    assert r.model == COMMON and r.note is None and r.p_value < 1e-10
    assert r.log_ratio == pytest.approx(math.log(r.life_ratio))
    # the profile interval is close to the Wald one in large samples: width ~ 2 * 1.645 * se
    width = math.log(r.life_ratio_upper / r.life_ratio_lower)
    assert width == pytest.approx(2 * 1.6449 * r.se_log_ratio, rel=0.03)
    assert (r.n_force, r.n_distance) == (1500, 1500)
    assert (r.n_failed_force, r.n_failed_distance) == (int(failed[group == 1].sum()), int(failed[group == 0].sum()))


def test_equal_lives_give_ratio_one_and_a_large_p_value():
    life, failed, group = censored_sample(2, 800, ratio=1.0, shape=1.8, censor_km=6000.0)
    r = life_effect(life, failed, group, confidence=0.999)
    assert abs(r.log_ratio) < 0.15 and r.life_ratio_lower < 1.0 < r.life_ratio_upper and r.p_value > 0.001


def test_exponential_case_has_the_closed_form_ratio():
    """Each group's own shape score vanishes at 1 (hand-derived conditions), so the common shape is
    1 and the MLE ratio is the exponential one: (total km / failures) of force over that of distance."""
    # distance: failures at 1 and a with (a - 1) ln a = 2 (a + 1)
    a = scipy.optimize.brentq(lambda v: (v - 1) * math.log(v) - 2 * (v + 1), 2.0, 50.0)
    # force: failures at 1 and 2, a suspension at s; the score at shape 1 of r = 2 failures:
    #   r + sum(ln x_failed) - r * sum(x ln x) / sum(x) = 0
    s = scipy.optimize.brentq(lambda v: 2 + math.log(2) - 2 * (2 * math.log(2) + v * math.log(v)) / (3 + v), 2.5, 100)
    life = np.array([1.0, a, 1.0, 2.0, s])
    failed = np.array([True, True, True, True, False])
    group = np.array([0, 0, 1, 1, 1])
    r = life_effect(life, failed, group)
    assert r.shape == pytest.approx(1.0, abs=1e-9)
    assert r.life_ratio == pytest.approx(((3.0 + s) / 2) / ((1.0 + a) / 2), rel=1e-9)
    assert r.shape_test_p == pytest.approx(1.0, abs=1e-6)  # the separate shapes are both 1 as well


def test_force_lives_a_multiple_of_distance_lives_give_that_ratio_exactly():
    """Hand-checked invariance: force lives = 1.7 x distance lives (same censoring pattern)."""
    x = np.array([820.0, 1300, 1750, 2100, 2600, 3000, 3000, 3000])
    f = np.array([1, 1, 1, 1, 1, 0, 0, 0], bool)
    r = life_effect(np.r_[x, 1.7 * x], np.r_[f, f], np.r_[np.zeros(8, int), np.ones(8, int)])
    own = weibull_fit(x, f)
    assert r.life_ratio == pytest.approx(1.7, rel=1e-10)
    assert r.shape == pytest.approx(own.shape, rel=1e-8)
    assert r.shape_test_p == pytest.approx(1.0, abs=1e-6) and r.model == COMMON
    # p-value: LR against one Weibull for both (shape and scale shared)
    pooled = weibull_fit(np.r_[x, 1.7 * x], np.r_[f, f])
    ll = 2 * own.loglik - 5 * math.log(1.7)  # the force group's log-likelihood is the distance one's minus r_f ln 1.7
    assert r.p_value == pytest.approx(scipy.stats.chi2.sf(2 * (ll - pooled.loglik), 1), rel=1e-6)


def test_profile_bounds_sit_where_the_deviance_reaches_its_critical_value():
    life, failed, group = censored_sample(3, 12, ratio=1.5, shape=2.0, censor_km=6500.0)
    r = life_effect(life, failed, group, confidence=0.90)
    fit = common_shape_fit(life, failed, group)
    crit = scipy.stats.chi2.ppf(0.90, 1)
    d = group == 0
    for ratio in (r.life_ratio_lower, r.life_ratio_upper):
        # an independent profile: maximise over (shape, scale_distance) with the ratio held
        def neg(p, ratio=ratio):
            k, s = math.exp(p[0]), math.exp(p[1])
            return -(weibull_loglik(k, s, life[d], failed[d]) + weibull_loglik(k, ratio * s, life[~d], failed[~d]))
        res = scipy.optimize.minimize(neg, [math.log(fit.shape), math.log(fit.scale_distance)], method="Nelder-Mead",
                                      options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 5000})
        assert 2 * (fit.loglik + res.fun) == pytest.approx(crit, abs=1e-5)
    wide = life_effect(life, failed, group, confidence=0.99)
    assert wide.life_ratio_lower < r.life_ratio_lower < r.life_ratio < r.life_ratio_upper < wide.life_ratio_upper
    assert wide.shape_lower < r.shape_lower < r.shape < r.shape_upper < wide.shape_upper


#: lifelines 0.30.3's WeibullAFTFitter on :func:`censored_sample` (seed, ratio, shape), n = 14 (simulated
#: data; the public-data case is LIFELINES_AFT_LEUKEMIA below),
#: censored at 6000 km (numpy 2.4.6): log scale = b0 + b1 * force, shape rho = exp(a0), so exp(b1)
#: is the life ratio and se(b1) the standard error of its log (observed information). Stored, not
#: run here: lifelines requires pandas < 3, which the project does not test with; regenerate with
#: ``WeibullAFTFitter().fit(DataFrame({"T": life, "E": failed, "force": group}), "T", "E")``.
LIFELINES_AFT = {
    (4, 1.5, 2.5): dict(ratio=1.4507199929292818, shape=3.294896159336651, se_log_ratio=0.17422003164369765,
                        scale_distance=5218.1733357277335, loglik=-158.3043545264347),
    (5, 1.0, 1.6): dict(ratio=0.9838117956055115, shape=1.5610940642042321, se_log_ratio=0.2674243473353368,
                        scale_distance=4459.906894404591, loglik=-213.36475750904017),
    (6, 0.8, 3.0): dict(ratio=0.8297484240194377, shape=2.7906059140823274, se_log_ratio=0.14094205337750298,
                        scale_distance=4578.832684895724, loglik=-227.69389852997895),
}


@pytest.mark.parametrize("case", sorted(LIFELINES_AFT))
def test_matches_lifelines_weibull_aft_fit(case):
    """An independent implementation (lifelines' Weibull AFT regression) on the same data."""
    seed, ratio, shape = case
    ref = LIFELINES_AFT[case]
    life, failed, group = censored_sample(seed, 14, ratio, shape, censor_km=6000.0)
    r = life_effect(life, failed, group)
    assert r.life_ratio == pytest.approx(ref["ratio"], rel=1e-3)
    assert r.shape == pytest.approx(ref["shape"], rel=1e-3)
    assert r.se_log_ratio == pytest.approx(ref["se_log_ratio"], rel=1e-3)
    fit = common_shape_fit(life, failed, group)
    assert fit.scale_distance == pytest.approx(ref["scale_distance"], rel=1e-3)
    assert fit.loglik == pytest.approx(ref["loglik"], rel=1e-6)


#: Public data: Freireich et al.'s (1963) leukemia remission times [weeks] of 21 patients on 6-MP
#: (9 relapses, 12 censored) and 21 on placebo (all relapsed), the ``anderson``
#: data of Kleinbaum & Klein's Survival Analysis, as ``lifelines.datasets.load_leukemia`` gives
#: it (columns t, status, Rx; Rx = 1 placebo, here in the place of ``group``). Fitted by lifelines
#: 0.30.3 (pandas 2.3.3, numpy 2.4.6): ``WeibullAFTFitter().fit(load_leukemia()[["t", "status", "Rx"]],
#: "t", "status")`` -> coef lambda_ Rx -1.2673347224637774 (se 0.3106399886940591), lambda_
#: Intercept 3.51568723518389, rho_ Intercept 0.31170926264876553, log-likelihood -106.57949158156515.
LEUKEMIA = dict(
    t=[35.0, 34, 32, 32, 25, 23, 22, 20, 19, 17, 16, 13, 11, 10, 10, 9, 7, 6, 6, 6, 6,
       23, 22, 17, 15, 12, 12, 11, 11, 8, 8, 8, 8, 5, 5, 4, 4, 3, 2, 2, 1, 1],
    status=[0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 1, 1, 0, 0, 1, 0, 1, 0, 1, 1, 1] + [1] * 21,
    Rx=[0] * 21 + [1] * 21)
LIFELINES_AFT_LEUKEMIA = dict(ratio=math.exp(-1.2673347224637774), shape=math.exp(0.31170926264876553),
                              se_log_ratio=0.3106399886940591, scale_distance=math.exp(3.51568723518389),
                              loglik=-106.57949158156515)


def test_matches_lifelines_weibull_aft_fit_on_public_data():
    life, failed, group = (np.array(LEUKEMIA[k]) for k in ("t", "status", "Rx"))
    ref = LIFELINES_AFT_LEUKEMIA
    r = life_effect(life, failed == 1, group)
    assert (r.n_distance, r.n_failed_distance, r.n_force, r.n_failed_force) == (21, 9, 21, 21)
    assert r.model == COMMON and r.shape_test_p > 0.5  # one shape fits: the ratio is lifelines' exp(coef)
    assert r.life_ratio == pytest.approx(ref["ratio"], rel=1e-5)
    assert r.shape == pytest.approx(ref["shape"], rel=1e-5)
    assert r.se_log_ratio == pytest.approx(ref["se_log_ratio"], rel=1e-5)
    fit = common_shape_fit(life, failed == 1, group)
    assert fit.scale_distance == pytest.approx(ref["scale_distance"], rel=1e-5)
    assert fit.loglik == pytest.approx(ref["loglik"], rel=1e-9)
    assert r.life_ratio_lower < ref["ratio"] < r.life_ratio_upper < 1.0 and r.p_value < 1e-4


def test_different_shapes_switch_to_the_b10_ratio_of_separate_shapes():
    rng = np.random.default_rng(7)
    n = 40
    t = np.r_[5000 * rng.weibull(1.0, n), 7000 * rng.weibull(4.0, n)]
    life, failed, group = np.minimum(t, 9000.0), t <= 9000.0, np.r_[np.zeros(n, int), np.ones(n, int)]
    r = life_effect(life, failed, group, alpha=0.05)
    assert r.shape_test_p < 0.001 and r.model == SEPARATE
    own = [weibull_fit(life[group == g], failed[group == g]) for g in (0, 1)]
    assert r.life_ratio == pytest.approx(own[1].quantile(0.1) / own[0].quantile(0.1), rel=1e-6)
    assert r.life_ratio_lower < r.life_ratio < r.life_ratio_upper
    # the true B10 ratio: 7000 * c^(1/4) / (5000 * c), c = -ln 0.9
    c = -math.log(0.9)
    assert r.life_ratio_lower < 7000 * c ** 0.25 / (5000 * c) < r.life_ratio_upper
    # the common-shape columns are still the common-shape fit's
    assert r.log_ratio == pytest.approx(common_shape_fit(life, failed, group).log_ratio)
    assert r.shape_lower < r.shape < r.shape_upper
    # alpha below the shape test's p keeps the common shape
    common = life_effect(life, failed, group, alpha=r.shape_test_p / 2)
    assert common.model == COMMON
    # after the switch the interval is the union of the separate-shape profile interval and the
    # common-shape one, and the p-value the larger of the two tests of ratio = 1
    own = b10_ratio_separate_shapes(life, failed, group, confidence=0.90)
    assert own["life_ratio"] == r.life_ratio and own["note"] is None
    assert r.life_ratio_lower == min(own["life_ratio_lower"], common.life_ratio_lower)
    assert r.life_ratio_upper == max(own["life_ratio_upper"], common.life_ratio_upper)
    assert r.p_value == max(own["p_value"], common.p_value)
    assert r.life_ratio_lower < own["life_ratio_lower"] or r.life_ratio_upper > own["life_ratio_upper"]  # it widens


def test_union_after_the_switch_keeps_an_open_side_open():
    from analyses.life_effect import _separate_or_common

    nan = float("nan")
    out = _separate_or_common({"life_ratio_lower": 0.8, "life_ratio_upper": nan, "p_value": 0.2},
                              {"life_ratio": 1.4, "life_ratio_lower": 0.9, "life_ratio_upper": 2.0, "p_value": 0.01})
    assert out["life_ratio"] == 1.4 and out["life_ratio_lower"] == 0.8 and math.isnan(out["life_ratio_upper"])
    assert out["p_value"] == 0.2


#: reliability 0.9.0's ``Fit_Weibull_2P(..., method="MLE")`` on each LEUKEMIA group, (alpha = scale
#: [weeks], beta = shape): the call and versions of test_service_life's RELIABILITY_FIT_WEIBULL_2P,
#: whose 6-MP values these are (checked live there where reliability is installed).
RELIABILITY_LEUKEMIA = {0: (33.76514119656118, 1.353734209488257), 1: (9.482144704257015, 1.3704998724147957)}


def test_separate_shapes_b10_ratio_matches_the_reliability_packages_own_fits():
    life, failed, group = (np.array(LEUKEMIA[k]) for k in ("t", "status", "Rx"))
    own = b10_ratio_separate_shapes(life, failed == 1, group)
    b10s = [scale * (-math.log(0.9)) ** (1 / shape) for scale, shape in (RELIABILITY_LEUKEMIA[g] for g in (0, 1))]
    assert own["life_ratio"] == pytest.approx(b10s[1] / b10s[0], rel=1e-5)
    assert own["life_ratio_lower"] < own["life_ratio"] < own["life_ratio_upper"]
    few = b10_ratio_separate_shapes([1.0, 2, 3, 4], [1, 1, 1, 0], [0, 0, 1, 1])
    assert math.isnan(few["life_ratio"]) and few["note"] == "too few failures to tell a Weibull: force 1 < 2"


def test_fewer_than_two_failures_in_an_adjustment_gives_nan_and_a_note():
    r = life_effect([100.0, 200, 300, 400, 500, 600], [1, 1, 0, 1, 0, 0], [0, 0, 0, 1, 1, 1])
    assert isinstance(r, LifeEffect)
    assert (r.n_distance, r.n_failed_distance, r.n_force, r.n_failed_force) == (3, 2, 3, 1)
    assert all(math.isnan(v) for v in (r.shape, r.shape_lower, r.life_ratio, r.life_ratio_upper, r.p_value,
                                       r.shape_test_p, r.log_ratio, r.se_log_ratio))
    assert r.model is None and r.note == "too few failures to tell a Weibull: force 1 < 2"
    assert math.isnan(common_shape_fit([100.0, 200, 300, 400, 500, 600], [1, 1, 0, 1, 0, 0],
                                       [0, 0, 0, 1, 1, 1]).se_log_ratio)


def test_a_shape_at_the_search_bound_gives_nan_and_a_note():
    r = life_effect([100.0, 100, 200, 200], [1, 1, 1, 1], [0, 0, 1, 1])  # ties: the shape runs to infinity
    assert math.isnan(r.shape) and math.isnan(r.life_ratio) and r.model is None
    assert "search bound" in r.note


def test_a_bound_beyond_the_search_edge_is_nan_with_a_note():
    # nearly equal lives: the shape's upper bound lies beyond SHAPE_BOUNDS' 1000
    r = life_effect([1000.0, 1001.5, 1003, 2000, 2003, 2006], [1] * 6, [0, 0, 0, 1, 1, 1])
    assert r.shape < 1000 and math.isnan(r.shape_upper) and r.shape_lower < r.shape
    assert r.life_ratio == pytest.approx(2.0, rel=1e-3) and r.life_ratio_lower < 2.0 < r.life_ratio_upper
    assert r.note == "shape_upper not reached within the search edge: the data do not bound it"


def test_bad_groups_are_refused_and_bad_lives_ignored():
    with pytest.raises(ValueError):
        life_effect([1.0, 2.0], [1, 1], [0, 2])
    with pytest.raises(ValueError):
        life_effect([1.0, 2.0], [1, 1], [0])
    life, failed, group = censored_sample(8, 10, ratio=1.3, shape=2.0, censor_km=8000.0)
    r = life_effect(np.r_[life, np.nan, -1.0], np.r_[failed, True, True], np.r_[group, 0, 1])
    ref = life_effect(life, failed, group)
    assert (r.n_distance, r.n_force, r.n_failed_force) == (ref.n_distance, ref.n_force, ref.n_failed_force) == (
        10, 10, int(failed[group == 1].sum()))
    assert (r.life_ratio, r.life_ratio_upper, r.shape_lower, r.p_value) == (
        ref.life_ratio, ref.life_ratio_upper, ref.shape_lower, ref.p_value)
    assert math.isfinite(r.life_ratio)


def test_common_shape_fit_is_the_same_from_any_start():
    """The look's warm start changes the steps, not the fit: every start gives the brentq root."""
    rng = np.random.default_rng(11)
    g = np.r_[np.zeros(12, int), np.ones(12, int)]
    life = np.where(g == 1, 1.4, 1.0) * 30 * rng.weibull(2.0, 24)
    failed = life < 40
    life = np.minimum(life, 40.0)
    x = [(life[(g == v)], failed[(g == v)]) for v in (0, 1)]
    score = lambda t: sum(r / math.exp(t) + float(np.log(xx)[ff].sum()) - r * float(  # noqa: E731
        (np.exp(math.exp(t) * np.log(xx)) * np.log(xx)).sum() / np.exp(math.exp(t) * np.log(xx)).sum())
        for xx, ff in x for r in [float(ff.sum())])
    want = math.exp(scipy.optimize.brentq(score, math.log(0.01), math.log(100), xtol=1e-14))
    fits = [common_shape_fit(life, failed, g, shape_start=s) for s in (1.0, want, 0.001, 1000.0, math.nan)]
    for fit in fits:
        assert fit.shape == pytest.approx(want, rel=1e-11)
        assert fit.log_ratio == pytest.approx(fits[0].log_ratio, rel=1e-11, abs=1e-13)
        assert fit.se_log_ratio == pytest.approx(fits[0].se_log_ratio, rel=1e-11)


def test_calibration_benchmark_runs_quick(capsys):
    from benchmarks.bench_life_effect import main

    assert main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "hose types: 40 simulated" in out and "shape, Wald" in out


def test_split_groups_keeps_each_adjustments_lives_and_drops_unusable_ones():
    (xd, fd), (xf, ff) = split_groups([10.0, 0.0, 30.0, math.nan, 50.0], [1, 1, 0, 1, 1], [0, 0, 1, 1, 1])
    assert xd.tolist() == [10.0] and fd.tolist() == [True]
    assert xf.tolist() == [30.0, 50.0] and ff.tolist() == [False, True]
    with pytest.raises(ValueError, match="same length"):
        split_groups([1.0, 2.0], [1], [0, 1])
    with pytest.raises(ValueError, match="0 \\(distance\\) or 1"):
        split_groups([1.0], [1], [2])
