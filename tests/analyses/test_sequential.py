"""The sequential design and verdict: the maximum information (failures) a design needs, the design on the
shape grid and its per-process caches, the sticky verdict."""
import math

import numpy as np
import pytest
from scipy import stats

from analyses import sequential
from analyses.sequential import max_information, sequential_verdict
from analyses.sequential_boundaries import efficacy_boundaries, inflation_factor
from analyses.sequential_information import information_per_failure, rare_failure_power

Z975 = stats.norm.isf(0.025)


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
    from analyses.sequential import max_information
    from analyses.sequential_boundaries import DESIGN_LOOKS, inflation_factor
    exact, _ = inflation_factor(2 * DESIGN_LOOKS, 0.05, 0.8, "pocock")
    mi = max_information(1.25, 0.05, 0.8, "pocock", shape=1.0)   # ~800 failures: far past the cap
    assert mi.looks > DESIGN_LOOKS
    assert mi.inflation <= exact < mi.inflation * 1.003
    assert mi.failures == math.ceil(mi.inflation * mi.failures_fixed - 1e-9)


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


def test_a_design_whose_bench_information_does_not_exist_is_refused_with_the_reason_not_invented():
    # session 18: a steep shape (lives 8-12 km: shape ~15) with hoses on test made the 3x3 information
    # singular and crashed the decision stage (LinAlgError), the whole night with it
    from analyses.sequential import design_for, design_shape
    from analyses.sequential_information import NoDesign
    with pytest.raises(NoDesign, match=r"no sequential design at shape 14.9 with 8 hose\(s\) on test"):
        design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(15.0), 8)
    with pytest.raises(NoDesign, match="OverflowError"):
        design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(50.0), 8)
    assert design_for(2.0, 0.05, 0.8, "obrien-fleming", design_shape(3.0), 8).failures == 14  # unchanged where it exists


def test_the_rare_failure_power_is_kept_per_design_and_is_the_figure_computed_afresh():
    sequential.clear_caches()
    m, shape = 23, 2.1
    c = efficacy_boundaries(np.arange(1, m + 1) / m, 0.05, "obrien-fleming")
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


def test_clear_caches_forgets_what_each_module_keeps():
    """The per-process caches of the three modules (the designs and inflation factors of
    sequential_boundaries, the information per failure of sequential_information, the designs on the
    grid and rare-failure powers here) are all filled by a design and all emptied by clear_caches."""
    from analyses import sequential_boundaries, sequential_information
    sequential.clear_caches()
    sequential.design_for(1.5, 0.05, 0.8, "obrien-fleming", 2.0, 6)
    caches = [sequential_boundaries.inflation_factor, sequential_information.information_per_failure,
              sequential._design_on_grid, sequential._rare_power]
    assert sequential_boundaries._DESIGNS and all(c.cache_info().currsize > 0 for c in caches)
    sequential.clear_caches()
    assert not sequential_boundaries._DESIGNS and all(c.cache_info().currsize == 0 for c in caches)
