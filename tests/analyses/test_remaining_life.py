"""Remaining life: Weibull predictive, pooled leak-growth model, backtest, leak-limit crossing."""
import math

import numpy as np
import pandas as pd
import pytest

from analyses.quality import Sensor
from analyses.remaining_life import (MIN_ESS, N_RUPTURE_SHAPES, LifeModel, RulSettings, WeibullPosterior,
                                     data_seed, degradation_fit, degradation_rul, leak_crossing_life,
                                     leak_crossing_lives, life_model, rul_over_shapes,
                                     rupture_model, rupture_shapes, weibayes_posterior, weibull_posterior, weibull_rul)
from analyses.remaining_life_group import remaining_life
from analyses.service_life import weibull_fit, weibull_loglik, weibull_loglik_many, weibull_shape_bounds
from analyses.service_life_lognormal import lognormal_loglik_many

SENSOR = Sensor(resolution=0.001, noise=0.005, source="metadata")   # floor 0.005, points above 0.05 used


def leak_paths(rng, n_hoses=40, gamma=1.5, log_w_mean=math.log(1.5e-3), log_w_sd=0.3, noise=0.08, every=50.0,
               end=800.0):
    """Leak paths ``(w_i d)^gamma`` with a lognormal wear rate, measured every ``every`` km to ``end``."""
    w = np.exp(log_w_mean + log_w_sd * rng.standard_normal(n_hoses))
    d = np.arange(every, end + 1e-9, every)
    rows = [(f"h{i:02d}", x, (w[i] * x) ** gamma * math.exp(noise * rng.standard_normal()))
            for i in range(n_hoses) for x in d]
    return pd.DataFrame(rows, columns=["hose_id", "distance_km", "leak_l_min"]), w


# -- leak-limit crossing (hand-checked) ------------------------------------------------------
def test_crossing_is_interpolated_between_the_plateaus_either_side():
    assert leak_crossing_life([300, 100, 200], [2.5, 0.5, 1.5], 2.0) == (250.0, True)


def test_a_path_that_never_reaches_the_limit_is_censored_at_its_last_plateau():
    assert leak_crossing_life([100, 200, 300], [0.5, 1.0, 1.9], 2.0) == (300.0, False)


def test_a_path_at_the_limit_from_its_first_plateau_crosses_there_and_no_points_is_nan():
    assert leak_crossing_life([100, 200], [2.2, 3.0], 2.0) == (100.0, True)
    life, crossed = leak_crossing_life([], [], 2.0)
    assert math.isnan(life) and not crossed


def test_crossing_lives_one_row_per_hose():
    pts = pd.DataFrame({"hose_id": ["a", "a", "b", "b"], "distance_km": [10, 20, 10, 20],
                        "leak_l_min": [1.0, 3.0, 0.1, 0.2]})
    out = leak_crossing_lives(pts, 2.0)
    assert out.to_dict("list") == {"hose_id": ["a", "b"], "life_km": [15.0, 20.0], "crossed": [True, False]}


# -- the shared likelihood ---------------------------------------------------------------------
def test_vectorised_loglik_matches_the_scalar_one():
    life, failed = np.array([1.0, 2.0, 3.5, 5.0]), np.array([True, False, True, True])
    many = weibull_loglik_many([1.5, 2.0, 0.7], [3.0, 4.0, 2.0], life, failed)
    assert many == pytest.approx([weibull_loglik(k, s, life, failed) for k, s in [(1.5, 3), (2, 4), (0.7, 2)]])
    assert weibull_loglik_many(-1.0, 3.0, life, failed) == -np.inf


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


# -- the degradation model -----------------------------------------------------------------------
def test_degradation_fit_recovers_the_growth_exponent_and_the_wear_rate_distribution():
    pts, w = leak_paths(np.random.default_rng(8), n_hoses=80)
    fit = degradation_fit(pts, SENSOR)
    assert fit.note is None
    assert fit.gamma == pytest.approx(1.5, abs=0.05)
    assert fit.sigma == pytest.approx(0.08, rel=0.15)
    assert fit.tau / fit.gamma == pytest.approx(0.3, rel=0.2)
    mean, sd = fit.wear_rate()
    true_mean = 1.5e-3 * math.exp(0.3 ** 2 / 2)
    assert mean == pytest.approx(true_mean, rel=0.1)
    assert sd == pytest.approx(true_mean * math.sqrt(math.expm1(0.09)), rel=0.25)


def test_degradation_rul_finds_a_hand_checked_crossing():
    """Hoses with one wear rate, no noise: the crossing of 2 l/min is 2^(1/1.5) / w exactly."""
    rng = np.random.default_rng(9)
    pts, w = leak_paths(rng, n_hoses=30, log_w_sd=0.3, noise=0.02)
    fit = degradation_fit(pts, SENSOR)
    d_cross = 2.0 ** (1 / 1.5) / w[0]
    now = pts.loc[pts["hose_id"] == "h00", "distance_km"].max()
    q, note = degradation_rul(fit, "h00", now, 2.0, seed=1)
    if d_cross <= now:
        assert "past the limit" in note
    else:
        assert note is None and q[0] == pytest.approx(d_cross - now, rel=0.05)
        assert q[1] < q[0] < q[2]


def _paths_with(hose_id, distance, leak):
    pts, _ = leak_paths(np.random.default_rng(10), n_hoses=10)
    return pd.concat([pts, pd.DataFrame({"hose_id": hose_id, "distance_km": distance, "leak_l_min": leak})],
                     ignore_index=True)


@pytest.mark.parametrize("distance, leak, reason", [
    ([100.0], [0.5], "too few leak points: 1 < 3"),
    ([100.0, 200.0, 300.0, 400.0], [0.004, 0.012, 0.031, 0.02], "noisy at the sensor floor"),
    ([100.0, 200.0, 300.0, 400.0], [0.9, 0.7, 0.6, 0.4], "leak path falling"),
    ([100.0, 200.0, 300.0, 400.0], [0.45, 0.8, 0.5, 0.6], "leak path flat"),
])
def test_a_hose_whose_own_path_cannot_tell_gets_nan_and_the_reason(distance, leak, reason):
    fit = degradation_fit(_paths_with("odd", distance, leak), SENSOR)
    assert fit.note is None
    q, note = degradation_rul(fit, "odd", max(distance), 2.0)
    assert np.isnan(q).all() and note.startswith(reason)


def test_too_few_hoses_to_pool_give_no_model():
    pts, _ = leak_paths(np.random.default_rng(11), n_hoses=2)
    fit = degradation_fit(pts, SENSOR)
    assert "too few hoses" in fit.note and math.isnan(fit.wear_rate()[0])
    assert "too few hoses" in degradation_rul(fit, "h00", 300.0, 2.0)[1]


def test_a_rupture_mode_shortens_the_remaining_life():
    pts, _ = leak_paths(np.random.default_rng(12), n_hoses=30, end=300.0)
    fit = degradation_fit(pts, SENSOR)
    rng = np.random.default_rng(13)
    rupture = weibull_posterior(np.r_[400 * rng.weibull(2.0, 10), np.full(20, 300.0)],
                                np.r_[np.ones(10, bool), np.zeros(20, bool)], seed=1)
    alone, _ = degradation_rul(fit, "h01", 300.0, 2.0)
    both, note = degradation_rul(fit, "h01", 300.0, 2.0, rupture)
    assert note is None and both[0] < alone[0] and both[2] <= alone[2] * 1.001


# -- one hose type, backtest ---------------------------------------------------------------------
def hose_type(rng, n=30):
    pts, w = leak_paths(rng, n_hoses=n, every=40.0, end=1600.0)
    cross = 2.0 ** (1 / 1.5) / w
    end = rng.uniform(200, 1600, n)
    failed = cross <= end
    life = np.minimum(cross, end)
    hoses = pd.DataFrame({"hose_id": [f"h{i:02d}" for i in range(n)], "distance_km": life,
                          "status": np.where(failed, "failed", "running"),
                          "failure_mode": np.where(failed, "leakage", None)})
    pts = pts[pts["distance_km"] <= pts["hose_id"].map(dict(zip(hoses["hose_id"], life)))]
    return hoses, pts.reset_index(drop=True)


def test_calibration_benchmark_runs_quick(capsys):
    from benchmarks.bench_remaining_life import main

    assert main(["--quick"]) == 0
    out = capsys.readouterr().out
    assert "weibull      running hoses:" in out and "wear rate mean" in out and "(quick: no verdict)" in out


def test_a_single_rupture_gets_a_constant_hazard_and_an_unnamed_mode_is_read_from_the_leak_path():
    hoses, pts = hose_type(np.random.default_rng(17))
    i = int(np.flatnonzero(hoses["status"] == "failed")[0])
    one = hoses.copy()
    one.loc[i, "failure_mode"] = "rupture"
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR, rupture_shape=1.0)   # the constant hazard, stated
    out = remaining_life(one, pts, s, seed=1)
    none = remaining_life(hoses, pts, s, seed=1)
    deg = (out["method"] == "degradation") & out["rul_median_km"].notna()
    assert deg.sum() and out.loc[deg, "note"].isna().all()
    # the rupture seen once shortens every prediction against the type that saw none
    assert (out.loc[deg, "rul_lower_km"].to_numpy() < none.loc[deg, "rul_lower_km"].to_numpy()).all()
    failed = hoses[hoses["status"] == "failed"]
    seen = pd.concat([pts, pd.DataFrame({"hose_id": failed["hose_id"], "distance_km": failed["distance_km"],
                                         "leak_l_min": 2.2})], ignore_index=True)   # the check that found it
    unnamed = remaining_life(hoses.assign(failure_mode=None), seen, s, seed=1)
    pd.testing.assert_frame_equal(unnamed, remaining_life(hoses, seen, s, seed=1))   # all read as leak failures
    silent = remaining_life(hoses.assign(failure_mode=None), pts, s, seed=1)          # none seen: all "other"
    assert not silent.equals(unnamed)


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


def test_the_rupture_shapes_run_from_1_to_the_logbook_shape_s_upper_bound():
    rng = np.random.default_rng(21)
    t, end = 1000.0 * rng.weibull(3.0, 40), rng.uniform(300, 1500, 40)
    life, failed = np.minimum(t, end), t <= end
    shapes, note = rupture_shapes(life, failed, 0.90)
    upper = weibull_shape_bounds(weibull_fit(life, failed), life, failed, 0.90)[1]
    assert upper > weibull_fit(life, failed).shape > 2.0 and len(shapes) == N_RUPTURE_SHAPES   # a wear-out (truth 3)
    assert shapes[0] == pytest.approx(1.0) and shapes[-1] == pytest.approx(upper)
    assert "not known" in note and f"{upper:.3g}" in note
    # a logbook with one failure cannot bound it: no shapes, and the note says why
    none, why = rupture_shapes(life, np.arange(40) == 0, 0.90)
    assert none.size == 0 and "cannot bound it" in why and "too few failures" in why


def test_the_rupture_model_is_the_stated_shape_the_weibull_or_the_grid():
    rng = np.random.default_rng(22)
    t, end = 1000.0 * rng.weibull(3.0, 40), rng.uniform(300, 1500, 40)
    life, failed = np.minimum(t, end), t <= end
    none, one, two = np.zeros(40, bool), np.arange(40) == int(np.flatnonzero(failed)[0]), failed & (life < 700)
    assert two.sum() >= 2
    stated, note = rupture_model(life, failed, none, shape=2.5, seed=1)
    assert note is None and len(stated) == 1 and (stated[0].shape == 2.5).all()
    weib, note = rupture_model(life, failed, two, seed=1)
    assert note is None and len(weib) == 1 and not weib[0].fixed_shape
    grid, note = rupture_model(life, failed, one, seed=1)
    assert len(grid) == N_RUPTURE_SHAPES and [p.shape[0] for p in grid] == pytest.approx(rupture_shapes(life, failed)[0])
    assert "not known" in note
    assert rupture_model(life, one, one, seed=1) == ([], rupture_shapes(life, one)[1])   # nothing bounds it


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


def test_a_stated_rupture_shape_replaces_the_union_and_no_bound_gives_null():
    hoses, pts = hose_type(np.random.default_rng(17))
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR)
    unknown = remaining_life(hoses, pts, s, seed=1)
    known = remaining_life(hoses, pts, RulSettings(limit_l_min=2.0, sensor=SENSOR, rupture_shape=1.0), seed=1)
    deg = (unknown["method"] == "degradation") & unknown["rul_median_km"].notna()
    assert deg.sum() and unknown.loc[deg, "note"].str.contains("rupture shape is not known").all()
    assert known.loc[deg, "note"].isna().all()
    # the union holds for shape 1 too: never narrower than the constant hazard's interval
    assert (unknown.loc[deg, "rul_lower_km"] <= known.loc[deg, "rul_lower_km"] * 1.02).all()
    assert (unknown.loc[deg, "rul_upper_km"] >= known.loc[deg, "rul_upper_km"] * 0.98).all()
    # one failure in the logbook: the shape has no bound, the joint prediction is NULL with the reason
    first = hoses.index[hoses["status"] == "failed"][1:]
    lone = hoses.assign(status=np.where(hoses.index.isin(first), "removed", hoses["status"]))
    out = remaining_life(lone, pts, s, seed=1)
    d = out["method"] == "degradation"
    assert out.loc[d, "rul_median_km"].isna().all() and out.loc[d, "note"].str.contains("cannot bound it").all()
    assert remaining_life(lone, pts, RulSettings(limit_l_min=2.0, sensor=SENSOR, rupture_shape=2.0),
                          seed=1).loc[d, "rul_median_km"].notna().any()


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
