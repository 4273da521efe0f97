"""One hose type's remaining-life predictions and backtest (``analyses.remaining_life_group``)."""
import numpy as np
import pandas as pd

from analyses.remaining_life import N_RUPTURE_SHAPES, RulSettings, data_seed
from analyses.remaining_life_group import METHODS, backtest_summary, group_models, remaining_life, rul_backtest
from tests.analyses.test_remaining_life import SENSOR, hose_type


def test_remaining_life_gives_both_methods_for_every_running_hose_and_is_deterministic():
    hoses, pts = hose_type(np.random.default_rng(14))
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR)
    out = remaining_life(hoses, pts, s)
    running = set(hoses.loc[hoses["status"] == "running", "hose_id"])
    assert set(out["hose_id"]) == running and len(out) == 2 * len(running)
    assert out.groupby("method").size().to_dict() == {"degradation": len(running), "weibull": len(running)}
    made = out.dropna(subset=["rul_median_km"])
    assert ((made["rul_lower_km"] < made["rul_median_km"]) & (made["rul_median_km"] < made["rul_upper_km"])).all()
    assert (out["leak_limit_l_min"] == 2.0).all() and (out["n_leak_points"] >= 0).all()
    pd.testing.assert_frame_equal(out, remaining_life(hoses, pts, s))
    assert data_seed(hoses, pts) == data_seed(hoses.copy(), pts.copy())


def test_no_failures_of_the_type_gives_weibull_nan_with_a_note():
    hoses, pts = hose_type(np.random.default_rng(15))
    hoses = hoses.assign(status="running")
    out = remaining_life(hoses, pts, RulSettings(limit_l_min=2.0, sensor=SENSOR))
    wb = out[out["method"] == "weibull"]
    assert wb["rul_median_km"].isna().all() and wb["note"].str.contains("too few failures").all()


def test_backtest_predicts_every_failed_hose_twice_per_method_and_mostly_covers():
    hoses, pts = hose_type(np.random.default_rng(16))
    bt = rul_backtest(hoses, pts, RulSettings(limit_l_min=2.0, sensor=SENSOR, n_draws=500), seed=3)
    n_failed = int((hoses["status"] == "failed").sum())
    assert len(bt) == 4 * n_failed
    assert set(bt["fraction"]) == {0.5, 0.8}
    s = backtest_summary(bt).set_index("method")
    assert s.loc["weibull", "n_predictions"] == 2 * n_failed
    assert 0.6 <= s.loc["degradation", "coverage"] <= 1.0 and 0.6 <= s.loc["weibull", "coverage"] <= 1.0
    assert s.loc["degradation", "median_abs_error_km"] < s.loc["weibull", "median_abs_error_km"]


def test_models_fitted_once_give_the_numbers_each_call_fitting_its_own():
    hoses, pts = hose_type(np.random.default_rng(17), n=12)
    first = hoses.index[hoses["status"] == "failed"][0]
    hoses.loc[first, "failure_mode"] = "burst"   # one rupture: the Weibayes grid over shapes, bounded by the logbook
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR, n_draws=300)
    models = group_models(hoses, pts, s)
    assert len(models.rupture[0]) == N_RUPTURE_SHAPES and models.degradation.ok
    shared = (remaining_life(hoses, pts, s, models=models), rul_backtest(hoses, pts, s, models=models))
    # the backtest after the predictions used the same models: nothing in them was changed by the use
    pd.testing.assert_frame_equal(shared[1], rul_backtest(hoses, pts, s))
    pd.testing.assert_frame_equal(shared[0], remaining_life(hoses, pts, s, models=group_models(hoses, pts, s)))
    assert shared[0]["rul_median_km"].notna().all()


def test_backtest_without_failed_hoses_says_so():
    s = backtest_summary(pd.DataFrame(columns=["method", "abs_error_km", "covered", "note"]))
    assert (s["n_predictions"] == 0).all() and (s["note"] == "no failed hose to backtest").all()


def test_the_weibull_rows_read_the_lives_only_and_a_changed_leak_point_moves_the_degradation_rows_only():
    hoses, pts = hose_type(np.random.default_rng(18), n=16)
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR, n_draws=300)
    moved = pts.copy()
    moved.loc[moved.index[-1], "leak_l_min"] *= 1.01   # the last point of one hose: one leak check changed
    before, after = remaining_life(hoses, pts, s), remaining_life(hoses, moved, s)
    by, cols = before["method"] == "weibull", ["hose_id", "rul_median_km", "rul_lower_km", "rul_upper_km", "note"]
    pd.testing.assert_frame_equal(before.loc[by, cols], after.loc[by, cols])   # the leak now is the hose's own
    assert not before.loc[~by, "rul_median_km"].equals(after.loc[~by, "rul_median_km"])
    # the life model is seeded by the lives alone; the degradation and rupture draws by the leak path too
    assert group_models(hoses, pts, s, methods=("weibull",)).life.families[0].shape.tolist() == \
        group_models(hoses, moved, s).life.families[0].shape.tolist()
    assert group_models(hoses, pts, s).seed == data_seed(hoses, pts) != data_seed(hoses, moved)
    tested = (rul_backtest(hoses, pts, s), rul_backtest(hoses, moved, s))
    w = [t[t["method"] == "weibull"].reset_index(drop=True) for t in tested]
    pd.testing.assert_frame_equal(w[0], w[1])


def test_each_method_alone_gives_its_rows_of_both_methods():
    hoses, pts = hose_type(np.random.default_rng(19), n=14)
    first = hoses.index[hoses["status"] == "failed"][0]
    hoses.loc[first, "failure_mode"] = "burst"   # a rupture model: the logbook's Weibull bounds its shape
    s = RulSettings(limit_l_min=2.0, sensor=SENSOR, n_draws=300)
    both = remaining_life(hoses, pts, s), rul_backtest(hoses, pts, s)
    for method in METHODS:
        models = group_models(hoses, pts, s, methods=(method,))
        assert (models.life is None) == (method == "degradation")
        assert (models.rupture == ([], None)) == (method == "weibull")
        alone = remaining_life(hoses, pts, s, models=models), rul_backtest(hoses, pts, s, models=models)
        for whole, part in zip(both, alone):
            assert set(part["method"]) == {method}
            pd.testing.assert_frame_equal(part.reset_index(drop=True),
                                          whole[whole["method"] == method].reset_index(drop=True))
