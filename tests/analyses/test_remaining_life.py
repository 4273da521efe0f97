"""Remaining life: the other failure modes' model (rupture shapes, rupture model), one hose type's predictions."""
import numpy as np
import pandas as pd
import pytest

from analyses.remaining_life import N_RUPTURE_SHAPES, RulSettings, rupture_model, rupture_shapes
from analyses.remaining_life_group import remaining_life
from analyses.service_life import weibull_fit, weibull_loglik, weibull_loglik_many, weibull_shape_bounds
from tests.analyses.test_leak_degradation import SENSOR, leak_paths


# -- the shared likelihood ---------------------------------------------------------------------
def test_vectorised_loglik_matches_the_scalar_one():
    life, failed = np.array([1.0, 2.0, 3.5, 5.0]), np.array([True, False, True, True])
    many = weibull_loglik_many([1.5, 2.0, 0.7], [3.0, 4.0, 2.0], life, failed)
    assert many == pytest.approx([weibull_loglik(k, s, life, failed) for k, s in [(1.5, 3), (2, 4), (0.7, 2)]])
    assert weibull_loglik_many(-1.0, 3.0, life, failed) == -np.inf


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
