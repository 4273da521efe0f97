"""The sequential verdict: spending functions, exact boundaries against published constants and an
independent multivariate-normal integration, inflation factors (Jennison & Turnbull 2000), the
sticky verdict."""
import math

import numpy as np
import pytest
from scipy import optimize, stats

from analyses import sequential
from analyses.sequential import (alpha_spent, crossing_probabilities, efficacy_boundaries, inflation_factor,
                                 information_per_failure, max_information, rare_failure_power, sequential_verdict)

Z975 = stats.norm.isf(0.025)


def test_spending_functions_hand_checked():
    for family in ("obrien-fleming", "pocock"):
        assert alpha_spent([0.0, 1.0, 1.7], 0.05, family) == pytest.approx([0.0, 0.05, 0.05], abs=1e-15)
        assert np.all(np.diff(alpha_spent(np.linspace(0, 1, 50), 0.05, family)) > 0)
    # O'Brien-Fleming type at t = 1/2: 2 - 2 Phi(1.95996 sqrt 2) = 0.005575; Pocock type 0.05 ln(1 + (e-1)/2)
    assert alpha_spent(0.5, 0.05, "obrien-fleming") == pytest.approx(2 * stats.norm.sf(Z975 * math.sqrt(2)), rel=1e-12)
    assert alpha_spent(0.5, 0.05, "obrien-fleming") == pytest.approx(0.005575, abs=1e-6)
    assert alpha_spent(0.5, 0.05, "pocock") == pytest.approx(0.05 * math.log(1 + (math.e - 1) / 2), rel=1e-12)
    with pytest.raises(ValueError):
        alpha_spent(0.5, 0.05, "haybittle")


@pytest.mark.parametrize("k,pocock,obf", [(2, 2.178, 1.977), (3, 2.289, 2.004), (4, 2.361, 2.024), (5, 2.413, 2.040)])
def test_published_pocock_and_obrien_fleming_constants_spend_alpha(k, pocock, obf):
    """J&T Table 2.1 (Pocock C_P) and 2.3 (O'Brien-Fleming C_B, boundaries C_B sqrt(K/k)) at alpha 0.05:
    the exact crossing probability of the published (3-decimal) constants is 0.05."""
    t = np.arange(1, k + 1) / k
    up, lo = crossing_probabilities(np.full(k, pocock), t)
    assert up.sum() + lo.sum() == pytest.approx(0.05, abs=3e-4)
    assert up.sum() == pytest.approx(lo.sum(), rel=1e-9)
    up, lo = crossing_probabilities(obf * np.sqrt(k / np.arange(1, k + 1)), t)
    assert up.sum() + lo.sum() == pytest.approx(0.05, abs=3e-4)


def test_lan_demets_boundaries_hand_checked():
    # one look: the fixed-sample 1.96; the first O'Brien-Fleming-type look spends exactly 2 Phi(-z/sqrt t1)
    assert efficacy_boundaries([1.0]) == pytest.approx([Z975], abs=1e-8)
    t = np.arange(1, 6) / 5
    c = efficacy_boundaries(t, 0.05, "obrien-fleming")
    assert c[0] == pytest.approx(Z975 / math.sqrt(0.2), abs=1e-7)
    assert np.all(np.diff(c) < 0) and 1.96 < c[-1] < 2.1
    # Lan-DeMets Pocock type, 5 equal looks, two-sided 0.05: the published 2.438 2.427 2.410 2.397 2.386
    assert efficacy_boundaries(t, 0.05, "pocock") == pytest.approx([2.438, 2.427, 2.410, 2.397, 2.386], abs=6e-4)


def test_crossing_probability_under_no_difference_is_alpha_by_an_independent_integration():
    """Unequal looks; P(all |Z_k| < c_k) by scipy's multivariate normal CDF with Cov = sqrt(t_j / t_k)."""
    t = np.array([0.23, 0.61, 1.0])
    for family in ("obrien-fleming", "pocock"):
        c = efficacy_boundaries(t, 0.05, family)
        cov = np.sqrt(np.minimum.outer(t, t) / np.maximum.outer(t, t))
        inside = stats.multivariate_normal(np.zeros(3), cov).cdf(c, lower_limit=-c)
        assert 1 - inside == pytest.approx(0.05, abs=2e-4)
        up, lo = crossing_probabilities(c, t)
        assert np.cumsum(up + lo) == pytest.approx(alpha_spent(t, 0.05, family), abs=1e-8)
    # an unfinished test spends only alpha(t) so far
    up, lo = crossing_probabilities(efficacy_boundaries([0.3, 0.5]), [0.3, 0.5])
    assert (up + lo).sum() == pytest.approx(alpha_spent(0.5), abs=1e-9)


def test_many_looks_still_spend_exactly_alpha():
    t = np.arange(1, 151) / 150
    c = efficacy_boundaries(t, 0.05, "pocock")
    up, lo = crossing_probabilities(c, t)
    assert (up + lo).sum() == pytest.approx(0.05, abs=1e-6)


def test_crossing_under_a_drift_agrees_with_simulated_brownian_motion():
    rng = np.random.default_rng(7)
    t = np.array([0.2, 0.45, 0.7, 1.0])
    c = efficacy_boundaries(t, 0.05, "pocock")
    drift = 2.9
    up, _ = crossing_probabilities(c, t, drift)
    inc = np.diff(np.concatenate([[0], t]))
    s = np.cumsum(rng.normal(drift * inc, np.sqrt(inc), size=(200_000, 4)), axis=1)
    z = s / np.sqrt(t)
    first = np.argmax(np.abs(z) >= c, axis=1)
    hit = np.abs(z[np.arange(len(z)), first]) >= c[first]
    sim = np.mean(hit & (z[np.arange(len(z)), first] > 0))
    assert up.sum() == pytest.approx(sim, abs=4 * math.sqrt(sim * (1 - sim) / len(z)))


@pytest.mark.parametrize("k,r_pocock,r_obf", [(2, 1.110, 1.008), (5, 1.229, 1.028)])
def test_inflation_factors_match_jennison_turnbull(k, r_pocock, r_obf):
    """J&T Tables 2.4 and 2.6 (alpha 0.05, power 0.8): R for the constant Pocock and O'Brien-Fleming tests."""
    t = np.arange(1, k + 1) / k
    fixed = Z975 + stats.norm.ppf(0.8)
    for c, r in ((np.full(k, {2: 2.178, 5: 2.413}[k]), r_pocock),
                 ({2: 1.977, 5: 2.040}[k] * np.sqrt(k / np.arange(1, k + 1)), r_obf)):
        drift = optimize.brentq(lambda d: crossing_probabilities(c, t, d)[0].sum() - 0.8, 1, 5)
        assert (drift / fixed) ** 2 == pytest.approx(r, abs=2e-3)


def test_max_information_hand_checked_and_inflated():
    # shape 1, margin 1.25: p = 1 / 2.25 = 0.4444, p (1 - p) = 0.24691, beta = ln 1.25 = 0.22314,
    # I / D = 0.24691 / (1 + 0.049793 * 0.24691) = 0.24391; I_fix = 2.80159^2 / 0.049793 = 157.63
    per = 0.24691358 / (1 + math.log(1.25) ** 2 * 0.24691358)
    fixed = (Z975 + stats.norm.ppf(0.8)) ** 2 / math.log(1.25) ** 2 / per
    assert per == pytest.approx(0.24391, abs=1e-5) and fixed == pytest.approx(646.3, abs=0.1)
    one = max_information(1.25, looks=1)
    assert one.failures_fixed == pytest.approx(fixed) and one.failures == math.ceil(fixed)
    assert one.inflation == pytest.approx(1.0, abs=1e-6)
    assert max_information(1 / 1.25, looks=1).failures == one.failures      # a ratio and its inverse
    five = max_information(1.25, 0.05, 0.8, "pocock", shape=2.0, looks=5)
    r, _ = inflation_factor(5, 0.05, 0.8, "pocock")
    per2, _ = information_per_failure(1.25, 2.0)
    assert five.inflation == pytest.approx(r) and five.failures == math.ceil(r * per * fixed / per2)
    every = max_information(1.25, 0.05, 0.8, "obrien-fleming", shape=2.0)
    assert every.looks == every.failures                                        # a look at every failure
    assert 1.0 < every.inflation < 1.1 and every.failures > every.failures_fixed
    with pytest.raises(ValueError):
        max_information(1.0)


def test_information_per_failure_hand_checked_limits():
    # rare failures, margin 1.5, shape 2: p = 1 / (1 + 2.25) = 0.30769, p (1 - p) = 0.21302,
    # beta^2 = (2 ln 1.5)^2 = 0.65753: I / D = 4 * 0.21302 / (1 + 0.65753 * 0.21302) = 0.74738
    per, p = information_per_failure(1.5, 2.0)
    assert p == pytest.approx(0.30769, abs=1e-5) and per == pytest.approx(0.74738, abs=1e-5)
    # the full expected information tends to the closed form as the hoses on test grow, and with one
    # hose on test each run to many failures to a complete sample's: the failures split as the
    # renewal rates, 1 / (1 + margin) force-set, and I / D = shape^2 p (1 - p) = 4 * 0.24
    big, p_big = information_per_failure(1.5, 2.0, 72, 1_000_000)
    assert big == pytest.approx(per, rel=1e-3) and p_big == pytest.approx(p, rel=1e-3)
    one, p_one = information_per_failure(1.5, 2.0, 500, 1)
    assert p_one == pytest.approx(0.4, abs=2e-3) and one == pytest.approx(0.96, rel=5e-3)
    # no effect: the shape is orthogonal whatever the follow-up, shape^2 / 4 per failure
    assert information_per_failure(1.0 + 1e-9, 1.5, 30, 50)[0] == pytest.approx(1.5 ** 2 / 4, rel=1e-5)
    # fewer hoses on test per failure, more information per failure: fewer failures, never more than rare
    rare = max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0).failures
    few = [max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0, hoses_per_adjustment=n).failures for n in (4, 32)]
    assert few[0] < few[1] < rare
    assert max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0, hoses_per_adjustment=10_000).failures == rare


def test_renewal_function_of_exponential_lives_is_linear():
    """Shape 1: failures come as a Poisson process, M(t) = t / scale exactly; shape 2: the mean
    count of failures of 200,000 simulated benches by t = 1 and 3 (a replaced hose may fail again)."""
    from analyses.sequential import _renewal_function
    t = np.linspace(0.0, 6.0, 601)
    assert _renewal_function(t, 2.0, 1.0) == pytest.approx(t / 2.0, abs=1e-4)
    ends = np.cumsum(np.random.default_rng(1).weibull(2.0, (200_000, 12)), axis=1)
    m = _renewal_function(np.linspace(0.0, 3.0, 601), 1.0, 2.0)
    for i, at in ((200, 1.0), (600, 3.0)):
        count = (ends <= at).sum(axis=1)
        assert m[i] == pytest.approx(count.mean(), abs=3 * count.std() / math.sqrt(count.size) + 1e-3)


def test_renewal_function_solves_the_trapezoidal_recursion():
    """The series inversion gives what the discretised renewal equation gives step by step."""
    from analyses.sequential import _renewal_function
    t = np.linspace(0.0, 7.0, 300)
    for scale, shape in ((1.0, 2.0), (1.5, 0.7), (0.8, 3.5)):
        f = -np.expm1(-(t / scale) ** shape)
        df, m = np.diff(f), np.zeros(t.size)
        for i in range(1, t.size):   # M_i = F_i + sum_j (M(t_i - u_j) + M(t_i - u_{j+1})) / 2 dF_j
            m[i] = (f[i] + sum(0.5 * (m[i - j] + m[i - j - 1]) * df[j] for j in range(1, i))
                    + 0.5 * m[i - 1] * df[0]) / (1.0 - 0.5 * df[0])
        assert _renewal_function(t, scale, shape) == pytest.approx(m, abs=1e-12)


def _bench_trial(rng, benches: int, failures: int, margin: float, shape: float):
    """Hoses on ``benches`` benches per adjustment, each failed hose replaced at once, at the
    ``failures``-th failure: (distance, failed, force)."""
    group = np.repeat([0, 1], benches)
    life = np.where(group[:, None] == 1, margin, 1.0) * rng.weibull(shape, (2 * benches, failures + 2))
    start = np.cumsum(life, axis=1) - life
    end, group = (start + life).ravel(), np.repeat(group, failures + 2)
    start, life = start.ravel(), life.ravel()
    now = np.sort(end)[failures - 1]
    on = start < now
    return np.minimum(life, now - start)[on], (end <= now)[on], group[on]


@pytest.mark.parametrize("benches, failures", [(200, 60), (4, 40)])
def test_information_per_failure_matches_the_refitted_variance(benches, failures):
    """Var of the common-shape MLE of the log ratio over simulated trials, against 1 / I: failures
    rare among 200 hoses on test each, and 4 hoses on test each run to 40 failures (replaced)."""
    from analyses.life_effect import common_shape_fit
    rng = np.random.default_rng(5)
    est, share = [], []
    for _ in range(400):
        x, failed, force = _bench_trial(rng, benches, failures, 1.5, 2.0)
        est.append(common_shape_fit(x, failed, force).log_ratio)
        share.append(force[failed].mean())
    per, p = information_per_failure(1.5, 2.0, failures, benches)
    # sampling error of a variance from 400 draws: ~7 %; with 4 hoses each the rare figure
    # (0.747 per failure) is 34 % smaller, the even split's shape^2 / 4 = 1 is 14 % larger
    assert np.var(est) * per * failures == pytest.approx(1.0, abs=0.15)
    assert np.mean(share) == pytest.approx(p, abs=0.01)


def test_verdict_sticks_once_declared():
    t = np.arange(1, 6) / 5
    se = np.array([0.1, 0.1, 0.1, 0.05, 0.1])
    c = efficacy_boundaries(t)
    est = np.array([0.1, 0.05, c[2] * 0.1 + 0.01, 0.0, -0.5])     # crosses up at look 2, then falls
    v = sequential_verdict(est, se, t, margin=1.25)
    assert (v.verdict, v.decided_at) == ("force longer", 2)
    assert v.crossed == ("", "", "force longer", "no practical difference", "distance longer")
    assert v.boundary_z == pytest.approx(c)
    assert v.efficacy_upper == pytest.approx(c * se) and v.rci_lower == pytest.approx(est - c * se)
    down = sequential_verdict(-est, se, t, margin=1.25)
    assert (down.verdict, down.decided_at) == ("distance longer", 2)


def test_no_practical_difference_when_the_interval_lies_inside_the_margin():
    t = np.array([0.5, 1.0])
    v = sequential_verdict([0.01, 0.0], [0.02, 0.02], t, margin=1.25)
    assert (v.verdict, v.decided_at) == ("no practical difference", 0)
    lm = math.log(1.25)
    assert v.futility_upper[0] == pytest.approx(lm - v.boundary_z[0] * 0.02)
    # wide interval: neither, and the futility range is empty (NaN)
    w = sequential_verdict([0.05, 0.05], [0.2, 0.2], t, margin=1.25)
    assert (w.verdict, w.decided_at) == ("undecided", None) and np.isnan(w.futility_upper).all()


def test_looks_without_an_estimate_or_new_information_do_not_decide():
    t = np.array([0.5, 1.0, 1.2, 1.4])      # capped at 1: the last two bring no new information
    v = sequential_verdict([np.nan, 0.0, 1.0, 1.0], [np.nan, 0.3, 0.1, 0.1], t, margin=1.25)
    assert v.verdict == "undecided" and v.decided_at is None
    assert v.crossed == ("", "", "force longer", "force longer")
    assert v.information_fraction == pytest.approx([0.5, 1, 1, 1])
    assert v.boundary_z[2] == v.boundary_z[1] == v.boundary_z[3]
    assert "without an estimate" in v.note and "new information" in v.note
    with pytest.raises(ValueError):
        sequential_verdict([0.1, 0.1], [0.1, 0.1], [0.6, 0.5], margin=1.25)


def test_calibration_benchmark_quick_passes():
    from benchmarks.bench_sequential import main
    assert main(["--quick"]) == 0


def test_many_looks_design_uses_the_capped_inflation_within_its_stated_error():
    """A design past DESIGN_LOOKS looks takes R of DESIGN_LOOKS looks: below the exact R of more
    looks, by less than the 0.3 % the constant's comment states."""
    from analyses.sequential import DESIGN_LOOKS, inflation_factor, max_information
    exact, _ = inflation_factor(2 * DESIGN_LOOKS, 0.05, 0.8, "pocock")
    mi = max_information(1.25, 0.05, 0.8, "pocock", shape=1.0)   # ~800 failures: far past the cap
    assert mi.looks > DESIGN_LOOKS
    assert mi.inflation <= exact < mi.inflation * 1.003
    assert mi.failures == math.ceil(mi.inflation * mi.failures_fixed - 1e-9)


def test_rare_failure_power_hand_checked():
    """Looks 1-4 cannot decide (no estimate before two failures each; c = 40 at look 4); at look 5
    with c = 0.4 the split 3 distance / 2 force gives ln ratio ln(1.5) / 2 = 0.2027 above
    0.4 sqrt(1/3 + 1/2 + ln(1.5)^2 / 5) / 2 = 0.1861: force longer; 2 / 3 gives distance longer.
    P(2 force-set of 5) = 10 p^2 (1 - p)^3 = 10 * 16 * 729 / 13^5 at p = 1 / 3.25 = 4 / 13."""
    assert rare_failure_power([40.0] * 4 + [0.4], 1.5, 2.0) == pytest.approx(10 * 16 * 729 / 13 ** 5, abs=1e-9)
    assert rare_failure_power([40.0] * 5, 1.5, 2.0) == 0.0


def test_max_information_rare_default_is_the_smallest_maximum_reaching_the_power():
    mi = max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0)
    power = [rare_failure_power(efficacy_boundaries(np.arange(1, m + 1) / m), 1.5, 2.0)
             for m in (mi.failures - 1, mi.failures)]
    assert power[0] < 0.8 <= power[1]
    # the Wald z's spread below 1 at the margin: fewer failures than the canonical process asks
    assert mi.failures < math.ceil(mi.inflation * mi.failures_fixed)


def test_max_information_notes_a_design_with_few_failures_of_the_longer_lived_adjustment():
    few = max_information(1.75, 0.10, 0.8, "obrien-fleming", 3.0)    # p = 1 / (1 + 1.75^3) = 0.157
    assert few.note is not None and f"about {round(few.failures * 0.1572)} failures" in few.note
    assert max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0).note is None   # 0.31 * 61 = 19
    assert "Pocock" in max_information(1.5, 0.05, 0.8, "pocock", 2.0).note


def test_design_for_rounds_the_shape_to_its_grid_and_gives_both_stages_one_answer():
    """Shapes within half a grid step share one design; the design is max_information's at the
    rounded shape, and the rounding moves the shape by at most half the 2 % step."""
    from analyses.sequential import DESIGN_SHAPE_STEP, design_for, design_shape, max_information
    for k in (0.8, 1.0, 2.13, 3.7):
        g = design_shape(k)
        assert abs(math.log(g / k)) <= DESIGN_SHAPE_STEP / 2 + 1e-12
        assert design_shape(g) == g
    assert design_shape(2.130) == design_shape(2.131)
    d = design_for(1.5, 0.05, 0.8, "obrien-fleming", 2.131)
    assert d.failures == max_information(1.5, 0.05, 0.8, "obrien-fleming", design_shape(2.131)).failures
    assert design_for(1.5, 0.05, 0.8, "obrien-fleming", 2.130) is d   # cached: one computation


def test_confirm_keeps_a_wald_crossing_from_deciding_until_the_second_check_agrees():
    """A look that crosses on the Wald scale but fails ``confirm`` does not cross; the verdict is
    the first confirmed crossing, and the note counts the unconfirmed looks."""
    from analyses.sequential import sequential_verdict
    est = np.array([1.0, 1.0, 1.0, 1.0])
    se = np.full(4, 0.05)                      # every look crosses "force longer" on the Wald scale
    t = np.array([0.25, 0.5, 0.75, 1.0])
    asked = []

    def confirm(i, crossed, c):
        asked.append((i, crossed))
        return i >= 2
    sv = sequential_verdict(est, se, t, 1.5, 0.05, "obrien-fleming", confirm=confirm)
    assert sv.decided_at == 2 and sv.verdict == "force longer"
    assert sv.crossed == ("", "", "force longer", "force longer")
    assert asked == [(0, "force longer"), (1, "force longer"), (2, "force longer"), (3, "force longer")]
    assert "2 look(s) crossed on the Wald scale but not by the profile likelihood" in sv.note
    plain = sequential_verdict(est, se, t, 1.5, 0.05, "obrien-fleming")
    assert plain.decided_at == 0


@pytest.mark.parametrize("spending", ["obrien-fleming", "pocock"])
def test_the_first_looks_of_an_even_design_get_the_whole_designs_boundaries_bit_for_bit(spending):
    sequential.clear_caches()
    for m, looks in ((40, 17), (7, 3), (63, 63)):
        t = np.arange(1, looks + 1) / m
        direct = np.array(sequential._Design(t, 0.05, spending).boundaries(looks))   # the prefix alone
        assert np.array_equal(sequential.efficacy_boundaries(t, 0.05, spending), direct)
    # computed only as far as asked, then extended: the same values as the whole design at once
    assert len(sequential._design_of(40, 0.05, spending).c) == 17
    whole = sequential._Design(np.arange(1, 41) / 40, 0.05, spending).boundaries(40)
    assert np.array_equal(sequential.efficacy_boundaries(np.arange(1, 41) / 40, 0.05, spending), whole)
    assert sequential._grid_of((0.1, 0.2, 0.35)) is None          # uneven: computed as given
    assert sequential._grid_of((0.5, 1.0)) == 2
    assert sequential._grid_of((1 / 3, 2 / 3)) == 3
    sequential.clear_caches()
    assert not sequential._DESIGNS


@pytest.mark.parametrize("spending, looks", [("obrien-fleming", 30), ("pocock", 12), ("obrien-fleming", 1)])
def test_power_by_change_of_measure_is_the_direct_recursion_with_drift(spending, looks):
    """The design's power read from the null recursion's grids times the likelihood ratio equals the
    recursion run under each drift (crossing_probabilities), to 1e-9."""
    t = np.arange(1, looks + 1) / looks
    c = efficacy_boundaries(t, 0.05, spending)
    design = sequential._design_of(looks, 0.05, spending)
    for drift in (0.0, 1.0, 2.9, 4.5, -2.0):
        assert design.upper_power(drift) == pytest.approx(crossing_probabilities(c, t, drift)[0].sum(), abs=1e-9)
    assert design.upper_power(0.0) == pytest.approx(0.025, abs=1e-6)      # half of alpha under no difference
    with pytest.raises(ValueError):
        design.upper_power(30.0)


@pytest.mark.parametrize("spending", ["obrien-fleming", "pocock"])
def test_boundaries_by_newton_are_the_bracketed_ones(spending):
    """Each look's boundary solved by Newton's method equals brentq's root of the same crossing
    probability (what the recursion did before) to 1e-9."""
    t = np.arange(1, 26) / 25
    c = efficacy_boundaries(t, 0.05, spending)
    spend = np.diff(np.concatenate([[0.0], alpha_spent(t, 0.05, spending)]))
    rec = sequential._Recursion(t, 0.0)
    for k in range(t.size):
        if spend[k] >= 1e-15:
            root = optimize.brentq(lambda x: sum(rec.exit_probabilities(x)) - spend[k], 1e-6, 40.0, xtol=1e-12)
            assert c[k] == pytest.approx(root, abs=1e-9)
        rec.advance(c[k])


def test_a_design_whose_bench_information_does_not_exist_is_refused_with_the_reason_not_invented():
    # session 18: a steep shape (lives 8-12 km: shape ~15) with hoses on test made the 3x3 information
    # singular and crashed the decision stage (LinAlgError), the whole night with it
    from analyses.sequential import NoDesign, design_for, design_shape
    with pytest.raises(NoDesign, match=r"no sequential design at shape 14.9 with 8 hose\(s\) on test"):
        design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(15.0), 8)
    with pytest.raises(NoDesign, match="OverflowError"):
        design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(50.0), 8)
    assert design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(3.0), 8).failures == 14  # unchanged where it exists


class _WrittenOut(sequential._Recursion):
    """The recursion step as first written (one expression, temporaries): the reference for the buffered one."""

    def advance(self, c):
        t, k, d = self.t, self.k, self.drift
        if k == 0:
            return super().advance(c)
        m = d * math.sqrt(t[k])
        lo, hi = max(-c, m - sequential._TAIL), min(c, m + sequential._TAIL)
        z, w = sequential._simpson(lo, hi, self.h[k])
        inc = t[k] - t[k - 1]
        s = math.sqrt(inc)
        u = (z[:, None] * math.sqrt(t[k]) - self.z[None, :] * math.sqrt(t[k - 1]) - d * inc) / s
        g = (np.exp(-0.5 * u * u) @ (self.w * self.g)) * math.sqrt(t[k]) / (s * math.sqrt(2 * math.pi))
        self.z, self.w, self.g, self.k = z, w, g, k + 1


@pytest.mark.parametrize("drift", [0.0, 2.7, -1.3])
def test_the_buffered_recursion_step_is_the_written_out_formula_bit_for_bit(drift):
    t = np.arange(1, 31) / 30
    c = sequential.efficacy_boundaries(t, 0.05, "pocock")
    fast, ref = sequential._Recursion(t, drift), _WrittenOut(t, drift)
    for ck in c:
        assert fast.exit_probabilities(ck) == ref.exit_probabilities(ck)
        fast.advance(ck)
        ref.advance(ck)
        assert np.array_equal(fast.z, ref.z) and np.array_equal(fast.g, ref.g)


def test_the_rare_failure_power_is_kept_per_design_and_is_the_figure_computed_afresh():
    sequential.clear_caches()
    m, shape = 23, 2.1
    c = sequential.efficacy_boundaries(np.arange(1, m + 1) / m, 0.05, "obrien-fleming")
    assert sequential._rare_power(m, 1.5, 0.05, "obrien-fleming", shape) == rare_failure_power(c, 1.5, shape)
    # two designs of one grid shape, other hoses on test and power: the second takes the first's figures
    first = sequential.design_for(1.5, 0.05, 0.8, "obrien-fleming", shape, 6)
    computed = sequential._rare_power.cache_info().misses
    second = sequential.design_for(1.5, 0.05, 0.8, "obrien-fleming", shape, 9)
    info = sequential._rare_power.cache_info()
    assert info.hits >= 2 and info.misses - computed < computed   # fewer maxima computed for the second
    for hoses, kept in ((6, first), (9, second)):   # the same designs computed cold, one by one
        sequential.clear_caches()
        assert sequential.design_for(1.5, 0.05, 0.8, "obrien-fleming", shape, hoses) == kept
    sequential.clear_caches()
    assert sequential._rare_power.cache_info().currsize == 0
