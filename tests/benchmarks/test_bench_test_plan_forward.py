"""benchmarks/bench_test_plan_forward.py: its bench trial is the state it says, its futures continue
that trial, its counting is right by hand, and a seeded quick run is repeatable."""
import math

import numpy as np
import pandas as pd
import pytest

from analyses.life_effect import common_shape_fit
from benchmarks import bench_test_plan_forward as bf


def test_the_state_and_its_futures_continue_one_bench_trial():
    state, lab, alone = bf.lab_trial(np.random.default_rng(5), 2.0, 1.5, 4, 30, 12)
    starting = int(((lab.start == 0) & (lab.base == 0)).sum())                 # the 12th failure's replacement
    assert int(state.failed.sum()) == 12 and int(state.running.sum()) + starting == 8   # 4 benches each, loaded
    assert alone.base.size == int(state.running.sum()) and np.all(alone.base > 0) and np.all(alone.start == 0)
    assert np.all(lab.start[8:] >= 0) and np.all(lab.base[8:] == 0)             # replacements start new
    x, f, g = bf.look_state(state, lab, 0.0)                                     # now: the state itself
    fit, now = common_shape_fit(x, f, g), common_shape_fit(state.distance, state.failed, state.group)
    assert fit.log_ratio == pytest.approx(now.log_ratio) and fit.shape == pytest.approx(now.shape)
    first = np.min(lab.start + lab.life)
    x, f, g = bf.look_state(state, lab, first)
    assert int(f.sum()) == 13 and x.size == state.distance.size + starting      # one more failure; the new hose on


def test_read_future_decides_on_a_clear_effect_and_not_on_none():
    rng = np.random.default_rng(8)
    state, lab, _ = bf.lab_trial(rng, 3.0, 4.0, 4, 24, 12)                     # force-set live 4x longer
    at, times = bf.read_future(state, lab, 24)
    assert at is not None and times[0] == 0.0 and np.all(np.diff(times) >= 0)


def test_calibration_and_ratios_by_hand():
    df = pd.DataFrame({"power_now": [0.05, 0.05, 0.95, 0.95], "decided": [False, False, True, True]})
    bins, tot = bf.calibration(df)
    assert [(b[2], b[4]) for b in bins] == [(2, 0.0), (2, 1.0)]
    assert tot["predicted"] == pytest.approx(0.5) and tot["realised"] == pytest.approx(0.5)
    assert tot["brier"] == pytest.approx(0.05 ** 2) and tot["brier_constant"] == pytest.approx(0.25)
    r = bf.ratios(np.array([100.0, 130.0, 90.0, math.nan]), np.array([100.0, 100.0, 100.0, 100.0]))
    assert r["n"] == 3 and r["median"] == pytest.approx(1.0) and r["within_25"] == pytest.approx(2 / 3)
    assert r["mean_ratio"] == pytest.approx(320 / 300)


def test_a_quick_run_is_repeatable(capsys):
    a, b = bf.run(2, bf.CELLS[:1]), bf.run(2, bf.CELLS[:1])
    pd.testing.assert_frame_equal(a, b)
    assert bf.main(["--quick"]) in (0, 1) and "power_now against the realised decision" in capsys.readouterr().out


def test_screen_error_compares_the_same_replicates():
    """The screen against reading every look: counts of one state's replicates (the benchmark's N_SIM)."""
    differ, total, told = bf.screen_error(2, bf.CELLS[1:2])
    assert total == told * bf.N_SIM and told >= 1 and 0 <= differ <= total


def test_truth_power_plugs_the_true_model_into_power_nows_simulation():
    """--truth: where power_now is a fact or NULL, the same; else the share of replicates that decide with the
    running hoses' lives from the TRUE model: a true effect far past the margin decides often, the same
    state's no-effect truth hardly ever."""
    from analyses.life_effect import CommonShapeFit
    from analyses.sequential import design_for
    from analyses.sequential_boundaries import efficacy_boundaries
    from analyses.test_plan import PowerNow
    m = design_for(*bf.PLAN[:4], 2.0, 4).failures
    bounds = efficacy_boundaries(np.arange(1, m + 1) / m, bf.PLAN[1], bf.PLAN[3])
    state, _, _ = bf.lab_trial(np.random.default_rng(11), 2.0, 1.0, 4, m, m // 2)
    fit = common_shape_fit(state.distance, state.failed, state.group)
    told = PowerNow(0.5, 0.01, 100)
    strong = bf.truth_power(state, fit, told, CommonShapeFit(2.0, bf.SCALE, 5.0 * bf.SCALE), bounds, 3)
    none = bf.truth_power(state, fit, told, CommonShapeFit(2.0, bf.SCALE, bf.SCALE), bounds, 3)
    assert strong > 0.5 and none < 0.05           # 8 running hoses: a 5x truth decides in half the futures
    fact = PowerNow(1.0, 0.0, 0, "the current look decides")
    assert bf.truth_power(state, fit, fact, CommonShapeFit(2.0, bf.SCALE, bf.SCALE), bounds, 3) == 1.0
