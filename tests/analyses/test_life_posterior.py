"""The life model's predictive posterior (``analyses.life_posterior``): Weibull and lognormal draws, Weibayes,
the union over shapes, the family mixture."""
import math

import numpy as np
import pytest

from analyses.life_posterior import (MIN_ESS, LifeModel, WeibullPosterior, life_model, rul_over_shapes,
                                     weibayes_posterior, weibull_posterior, weibull_rul)
from analyses.service_life import weibull_loglik_many
from analyses.service_life_lognormal import lognormal_loglik_many


# -- the Weibull predictive ----------------------------------------------------------------------
def test_with_many_failures_the_predictive_is_the_plug_in_conditional_weibull():
    rng = np.random.default_rng(1)
    life = 100.0 * rng.weibull(2.0, 3000)
    post = weibull_posterior(life, np.ones(life.size, bool), seed=2)
    q, note = weibull_rul(post, 50.0, confidence=0.90)
    assert note is None
    cond = lambda p: 100.0 * ((50.0 / 100.0) ** 2 - math.log1p(-p)) ** 0.5 - 50.0  # noqa: E731
    assert q == pytest.approx([cond(0.5), cond(0.05), cond(0.95)], rel=0.04)


def test_with_few_failures_the_interval_is_wider_than_the_plug_in_one():
    rng = np.random.default_rng(3)
    life = 100.0 * rng.weibull(2.0, 8)
    post = weibull_posterior(life, np.ones(8, bool), seed=4)
    q, _ = weibull_rul(post, 50.0, 0.90)
    k, s = post.fit.shape, post.fit.scale
    plug = [s * ((50.0 / s) ** k - math.log1p(-p)) ** (1 / k) - 50.0 for p in (0.05, 0.95)]
    assert q[2] - q[1] > 1.1 * (plug[1] - plug[0]) and q[2] > plug[1]


def test_reweighting_for_a_hose_cut_short_matches_a_refit():
    rng = np.random.default_rng(5)
    life = 100.0 * rng.weibull(2.0, 25)
    failed = np.ones(25, bool)
    cut = life.copy()
    cut[0] = 0.5 * life[0]
    failed_cut = failed.copy()
    failed_cut[0] = False
    re = weibull_posterior(life, failed, n_draws=4000, seed=6).changed([life[0]], [True], [cut[0]], [False])
    fresh = weibull_posterior(cut, failed_cut, n_draws=4000, seed=7)
    q_re, q_fresh = weibull_rul(re, cut[0])[0], weibull_rul(fresh, cut[0])[0]
    assert q_re == pytest.approx(q_fresh, rel=0.03)


def test_fewer_than_two_failures_give_nan_and_a_note():
    post = weibull_posterior([10.0, 20.0, 30.0], [True, False, False])
    q, note = weibull_rul(post, 25.0)
    assert np.isnan(q).all() and "too few failures" in note
    ok = weibull_posterior([10.0, 20.0, 30.0], [True, True, False], seed=1)
    assert "too few failures" in ok.changed([10.0], [True], [5.0], [False]).note
    q, note = weibull_rul(ok, float("nan"))
    assert np.isnan(q).all() and note == "no distance now"


def test_the_constant_hazard_posterior_is_the_jeffreys_gamma():
    life = np.array([10.0, 20.0, 30.0, 40.0])   # exposure 100 km, one failure: rate ~ Gamma(1.5, 100)
    post = weibayes_posterior(life, [True, False, False, False], n_draws=20000, seed=3)
    rate = 1.0 / post.scale
    assert post.ok and post.fixed_shape and (post.shape == 1.0).all()
    assert rate.mean() == pytest.approx(1.5 / 100.0, rel=0.03) and rate.var() == pytest.approx(1.5 / 1e4, rel=0.08)
    # re-weighting for a hose cut short: Gamma(1.5, 80 km); one failure stays enough for this model
    cut = post.changed([40.0], [False], [20.0], [False])
    w, _ = cut.weights()
    assert cut.ok and float(w @ (1.0 / cut.scale)) == pytest.approx(1.5 / 80.0, rel=0.03)
    assert not weibayes_posterior([0.0], [False]).ok


def test_the_weibayes_posterior_is_the_gamma_of_the_exposure_in_t_to_the_shape():
    """Known shape 2: ``scale^-2 ~ Gamma(r + 1/2, sum t^2)`` (Nelson 1985): one failure in
    10^2 + 20^2 + 30^2 + 40^2 = 3000 km^2; and its predictive quantiles (closed form) are the draws' mixture's."""
    life = np.array([10.0, 20.0, 30.0, 40.0])
    post = weibayes_posterior(life, [True, False, False, False], shape=2.0, n_draws=40000, seed=4)
    rate = post.scale ** -2.0
    assert post.ok and post.fixed_shape and (post.shape == 2.0).all()
    assert rate.mean() == pytest.approx(1.5 / 3000.0, rel=0.02) and rate.var() == pytest.approx(1.5 / 3000.0 ** 2,
                                                                                                rel=0.05)
    q, note = weibull_rul(post, 25.0, 0.90)
    # by hand: P(R > r) = (1 + ((25 + r)^2 - 25^2) / 3000)^-1.5; at the median (...)^-1.5 = 1/2
    median = math.sqrt(25.0 ** 2 + 3000.0 * (2.0 ** (1 / 1.5) - 1.0)) - 25.0
    assert note is None and q[0] == pytest.approx(median, rel=1e-9)
    mixed = WeibullPosterior(post.shape, post.scale, post.log_weight + np.arange(post.shape.size) * 0.0 + 1e-12 *
                             (np.arange(post.shape.size) == 0), post.fit)   # not equal weights: by bisection
    assert weibull_rul(mixed, 25.0, 0.90)[0] == pytest.approx(q, rel=0.03)
    # large shapes do not overflow: lives in km to the 20th
    big = weibayes_posterior(life * 1e3, [False] * 4, shape=20.0, seed=1)
    assert big.ok and np.isfinite(big.scale).all() and (big.scale > 40e3).mean() > 0.5


def test_the_prediction_over_shapes_is_the_union_of_their_intervals():
    life = np.array([2.0, 3.0, 5.0, 7.0])
    posts = [weibayes_posterior(life, np.zeros(4, bool), k, seed=1) for k in (1.0, 2.0, 4.0)]
    alone = np.array([weibull_rul(p, 4.0, 0.90)[0] for p in posts])
    q, note = rul_over_shapes(lambda p: weibull_rul(p, 4.0, 0.90), posts)
    assert note is None and q[1] == alone[:, 1].min() and q[2] == alone[:, 2].max()
    assert alone[:, 0].min() < q[0] < alone[:, 0].max()   # the equal mixture's median lies among theirs
    # the wear-out shapes predict the rupture sooner than the constant hazard
    assert alone[2, 1] < alone[0, 1] and q[1] == alone[2, 1]
    assert rul_over_shapes(lambda p: weibull_rul(p, 4.0, 0.90), posts[:1])[0] == pytest.approx(alone[0])
    assert np.isnan(rul_over_shapes(lambda p: weibull_rul(p, 4.0, 0.90), [])[0]).all()


def test_two_failures_among_many_suspensions_give_enough_effective_draws():
    # the skewed posterior of two failures: two rounds of adaptation left fewer than MIN_ESS here
    rng = np.random.default_rng([9, 58])
    cross, rup = np.exp(0.35 * rng.standard_normal(25)), 3 * rng.weibull(2, 25)
    t, end = np.minimum(cross, rup), rng.uniform(0.6, 1.05, 25)
    other = (t <= end) & (rup < cross)
    assert other.sum() == 2
    post = weibull_posterior(np.minimum(t, end), other, seed=58)   # two rounds: effective size 4
    assert post.ok and post.weights()[1] >= MIN_ESS


# -- the life model's family ---------------------------------------------------------------------
def test_log_evidence_is_the_marginal_likelihood_under_the_flat_prior():
    """The importance-sampling estimate against a quadrature of the likelihood over (log shape, log scale)."""
    rng = np.random.default_rng(71)
    life = 100.0 * rng.weibull(2.0, 12)
    failed = np.ones(12, bool)
    failed[:4] = False
    for family in ("weibull", "lognormal"):
        post = weibull_posterior(life, failed, n_draws=4000, seed=72, family=family)
        ls, lk = np.meshgrid(np.linspace(math.log(30.0), math.log(400.0), 400), np.linspace(-2.5, 3.0, 400))
        shape, scale = np.exp(lk), np.exp(ls)
        ll = (weibull_loglik_many(shape, scale, life, failed) if family == "weibull"
              else lognormal_loglik_many(1.0 / shape, scale, life, failed))
        top = ll.max()
        quad = top + math.log(np.exp(ll - top).sum() * (ls[0, 1] - ls[0, 0]) * (lk[1, 0] - lk[0, 0]))
        assert post.log_evidence() == pytest.approx(quad, abs=0.05)


def test_the_life_model_weighs_the_family_the_lives_follow():
    rng = np.random.default_rng(73)
    logn = np.exp(math.log(500.0) + 0.8 * rng.standard_normal(150))
    model = life_model(logn, np.ones(150, bool), seed=74)
    ok, prob = model.usable()
    assert [p.family for p in ok] == ["weibull", "lognormal"] and prob[1] > 0.99
    q, note = weibull_rul(model, 100.0)
    q_ln, _ = weibull_rul(model.families[1], 100.0)
    assert q == pytest.approx(q_ln, rel=0.02) and note.startswith("life model: lognormal 1.00, Weibull 0.00")
    wei = 500.0 * rng.weibull(1.0, 400)
    model = life_model(wei, np.ones(400, bool), seed=75)
    assert model.usable()[1][0] > 0.99
    q, note = weibull_rul(model, 100.0)
    assert note is None and q == pytest.approx(weibull_rul(model.families[0], 100.0)[0], rel=0.02)


def test_a_lognormal_predictive_with_many_failures_is_the_plug_in_conditional_lognormal():
    rng = np.random.default_rng(76)
    life = np.exp(math.log(100.0) + 0.5 * rng.standard_normal(3000))
    post = weibull_posterior(life, np.ones(life.size, bool), seed=77, family="lognormal")
    q, note = weibull_rul(LifeModel((post,)), 80.0, 0.90)
    z_now = math.log(80.0 / 100.0) / 0.5
    sf_now = 0.5 * math.erfc(z_now / math.sqrt(2.0))
    from scipy.stats import norm
    want = [100.0 * math.exp(0.5 * norm.isf(sf_now * (1.0 - p))) - 80.0 for p in (0.5, 0.05, 0.95)]
    assert note.startswith("life model: lognormal 1.00") and q == pytest.approx(want, rel=0.04)
