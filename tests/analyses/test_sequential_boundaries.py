"""Alpha spending and the exact boundaries: spending functions, boundaries against published constants and an
independent multivariate-normal integration, crossing probabilities under a drift, inflation factors (Jennison &
Turnbull 2000), a design's boundaries kept per process, its power by a change of measure."""
import math

import numpy as np
import pytest
from scipy import optimize, stats

from analyses import sequential, sequential_boundaries
from analyses.sequential_boundaries import alpha_spent, crossing_probabilities, efficacy_boundaries

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


@pytest.mark.parametrize("spending", ["obrien-fleming", "pocock"])
def test_the_first_looks_of_an_even_design_get_the_whole_designs_boundaries_bit_for_bit(spending):
    sequential.clear_caches()
    for m, looks in ((40, 17), (7, 3), (63, 63)):
        t = np.arange(1, looks + 1) / m
        direct = np.array(sequential_boundaries._Design(t, 0.05, spending).boundaries(looks))   # the prefix alone
        assert np.array_equal(sequential_boundaries.efficacy_boundaries(t, 0.05, spending), direct)
    # computed only as far as asked, then extended: the same values as the whole design at once
    assert len(sequential_boundaries._design_of(40, 0.05, spending).c) == 17
    whole = sequential_boundaries._Design(np.arange(1, 41) / 40, 0.05, spending).boundaries(40)
    assert np.array_equal(sequential_boundaries.efficacy_boundaries(np.arange(1, 41) / 40, 0.05, spending), whole)
    assert sequential_boundaries._grid_of((0.1, 0.2, 0.35)) is None          # uneven: computed as given
    assert sequential_boundaries._grid_of((0.5, 1.0)) == 2
    assert sequential_boundaries._grid_of((1 / 3, 2 / 3)) == 3
    sequential.clear_caches()
    assert not sequential_boundaries._DESIGNS


@pytest.mark.parametrize("spending, looks", [("obrien-fleming", 30), ("pocock", 12), ("obrien-fleming", 1)])
def test_power_by_change_of_measure_is_the_direct_recursion_with_drift(spending, looks):
    """The design's power read from the null recursion's grids times the likelihood ratio equals the
    recursion run under each drift (crossing_probabilities), to 1e-9."""
    t = np.arange(1, looks + 1) / looks
    c = efficacy_boundaries(t, 0.05, spending)
    design = sequential_boundaries._design_of(looks, 0.05, spending)
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
    rec = sequential_boundaries._Recursion(t, 0.0)
    for k in range(t.size):
        if spend[k] >= 1e-15:
            root = optimize.brentq(lambda x: sum(rec.exit_probabilities(x)) - spend[k], 1e-6, 40.0, xtol=1e-12)
            assert c[k] == pytest.approx(root, abs=1e-9)
        rec.advance(c[k])


class _WrittenOut(sequential_boundaries._Recursion):
    """The recursion step as first written (one expression, temporaries): the reference for the buffered one."""

    def advance(self, c):
        t, k, d = self.t, self.k, self.drift
        if k == 0:
            return super().advance(c)
        m = d * math.sqrt(t[k])
        lo, hi = max(-c, m - sequential_boundaries._TAIL), min(c, m + sequential_boundaries._TAIL)
        z, w = sequential_boundaries.simpson(lo, hi, self.h[k])
        inc = t[k] - t[k - 1]
        s = math.sqrt(inc)
        u = (z[:, None] * math.sqrt(t[k]) - self.z[None, :] * math.sqrt(t[k - 1]) - d * inc) / s
        g = (np.exp(-0.5 * u * u) @ (self.w * self.g)) * math.sqrt(t[k]) / (s * math.sqrt(2 * math.pi))
        self.z, self.w, self.g, self.k = z, w, g, k + 1


@pytest.mark.parametrize("drift", [0.0, 2.7, -1.3])
def test_the_buffered_recursion_step_is_the_written_out_formula_bit_for_bit(drift):
    t = np.arange(1, 31) / 30
    c = sequential_boundaries.efficacy_boundaries(t, 0.05, "pocock")
    fast, ref = sequential_boundaries._Recursion(t, drift), _WrittenOut(t, drift)
    for ck in c:
        assert fast.exit_probabilities(ck) == ref.exit_probabilities(ck)
        fast.advance(ck)
        ref.advance(ck)
        assert np.array_equal(fast.z, ref.z) and np.array_equal(fast.g, ref.g)
