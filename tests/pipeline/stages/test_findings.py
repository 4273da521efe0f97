"""The findings stage: each paper conclusion as a check, on hand-built result tables."""
import numpy as np
import pandas as pd
import pytest

from analyses import breakaway as bk
from pipeline.rebuild import compare_findings
from pipeline.stages import StageContext
from pipeline.stages import findings as fs


def ctx_with(**tables):
    return StageContext(raw=None, warehouse=None, runs=pd.DataFrame(), results=dict(tables))


def by_id(ctx):
    df = fs.run(ctx).tables["findings"]
    return {r["finding_id"]: r for r in df.to_dict("records")}


def breakaway_events(f0=10.0, f1=5.0, slope=0.0, seed=1):
    rng = np.random.default_rng(seed)
    rows = []
    for d in ("P", "N"):
        for bp in (0.0, 1.0, 2.0, 3.0, 4.0):
            for rate in (0.25, 0.5, 1.0, 2.0, 4.0):
                for _ in range(3):
                    f = (f0 if bp == 0 else f1) + slope * rate + rng.normal(0, 0.5)
                    rows.append({"run_id": f"r{len(rows)}", "direction": d, "backpressure_bar": bp,
                                 "force_rate_n_s": rate, "breakaway_force_n": f})
    return pd.DataFrame(rows)


def leakage(pseal_of_force=lambda f: 2.0 + 9.7 * f / 1300):
    rows = []
    for f in (429.0, 858.0, 1300.0):
        for p in range(7):
            q = 2.0 * max(p - pseal_of_force(f), 0) ** 1.5
            rows.append({"run_id": f"L{f:g}", "adjustment": "force", "spring_force_n": f, "z_rollers_mm": None,
                         "chamber": "A", "pressure_bar": p + 0.01, "leak_l_min": q + 0.001, "leak_std_l_min": 0.002})
    return pd.DataFrame(rows)


def weibull_lives(seed=3, n=30, scales=(90.0, 40.0)):
    rng = np.random.default_rng(seed)
    rows = []
    for adj, scale, shape in (("force", scales[0], 2.4), ("distance", scales[1], 1.8)):
        for i, life in enumerate(scale * rng.weibull(shape, n)):
            rows.append({"hose_id": f"{adj}{i}", "hose_type": "FLEXIGOM AIR", "adjustment": adj,
                         "distance_km": life, "status": "failed"})
    return pd.DataFrame(rows)


def test_no_data_gives_null_and_says_so():
    f = by_id(ctx_with())
    assert len(f) == 8
    for row in f.values():
        assert pd.isna(row["holds"]) and row["detail"].startswith("no data"), row


def test_breakaway_findings_hold_on_paper_like_data_and_reuse_the_stage_table():
    ev = breakaway_events()
    f = by_id(ctx_with(breakaway=ev))  # derived here from the events
    assert f["breakaway_0bar_twice"]["measured"] == pytest.approx(2.0, abs=0.1)
    assert f["breakaway_0bar_twice"]["holds"] is True or f["breakaway_0bar_twice"]["holds"] == True  # noqa: E712
    assert 0 < f["breakaway_0bar_twice"]["uncertainty"] < 0.1
    assert bool(f["breakaway_rate_no_effect"]["holds"])
    # the other stage's table is preferred: doctor it and see its number come through
    table = bk.breakaway_findings(ev)
    table.loc[(table["finding"] == "backpressure_ratio") & (table["direction"] == "all"), "estimate"] = 1.1
    f2 = by_id(ctx_with(breakaway=ev, breakaway_findings=table))
    assert f2["breakaway_0bar_twice"]["measured"] == pytest.approx(1.1)
    assert not bool(f2["breakaway_0bar_twice"]["holds"])
    assert "breakaway_findings" in f2["breakaway_0bar_twice"]["source_tables"]


def test_breakaway_no_longer_twice_and_rate_effect_are_caught():
    f = by_id(ctx_with(breakaway=breakaway_events(f0=5.0, f1=5.0, slope=1.5)))
    assert f["breakaway_0bar_twice"]["measured"] == pytest.approx(1.0, abs=0.15)
    assert not bool(f["breakaway_0bar_twice"]["holds"])
    assert f["breakaway_rate_no_effect"]["measured"] == pytest.approx(1.5, abs=0.1)
    assert not bool(f["breakaway_rate_no_effect"]["holds"])


def test_leakage_findings():
    f = by_id(ctx_with(leakage_map=leakage()))
    assert bool(f["no_leak_33pct_5bar"]["holds"]) and bool(f["no_leak_66pct_6bar"]["holds"])
    assert f["no_leak_33pct_5bar"]["measured"] < 0.01
    # a weaker seal at 33 %: leaks at 5 bar
    f = by_id(ctx_with(leakage_map=leakage(lambda F: 4.0 if F < 500 else 9.0)))
    assert not bool(f["no_leak_33pct_5bar"]["holds"])
    assert f["no_leak_33pct_5bar"]["measured"] == pytest.approx(2.0, abs=0.01)
    assert bool(f["no_leak_66pct_6bar"]["holds"])
    # tested only up to 3 bar: cannot say
    lm = leakage()
    f = by_id(ctx_with(leakage_map=lm[lm["pressure_bar"] < 3.5]))
    assert pd.isna(f["no_leak_33pct_5bar"]["holds"]) and "tested only up to" in f["no_leak_33pct_5bar"]["detail"]


def test_viscous_and_stribeck_and_spring():
    fits = pd.DataFrame({"backpressure_bar": [0, 0, 1, 1, 2, 2, 3, 3], "direction": list("PN") * 4,
                         "coulomb_n": 3.5, "viscous_n_s_m": [25, 25, 28.1, 27.9, 27.8, 28.2, 28.0, 28.1],
                         "viscous_se_n_s_m": 0.4, "nrmse_pct": 1.0, "n_points": 10})
    trans = pd.DataFrame({"backpressure_bar": [0.0], "stribeck_amplitude_n": [0.02], "stribeck_p_value": [0.6],
                          "stribeck_dip": [False], "n_points": [40]})
    spring = pd.DataFrame({"run_id": ["a", "b", "c"], "nrmse_pct": [1.16, 2.0, 2.39]})
    f = by_id(ctx_with(viscous_fits=fits, viscous_transition=trans, spring_tests=spring))
    v = f["viscous_independent_of_backpressure_1_3bar"]
    assert bool(v["holds"]) and v["p_value"] > 0.05 and v["measured"] < 2.0
    assert bool(f["no_stribeck_dip"]["holds"])
    assert f["spring_nrmse_below_2_5pct"]["measured"] == pytest.approx(2.39) and bool(f["spring_nrmse_below_2_5pct"]["holds"])
    fits.loc[fits["backpressure_bar"] == 3, "viscous_n_s_m"] = 40.0
    trans["stribeck_dip"] = True
    spring.loc[0, "nrmse_pct"] = 3.0
    f = by_id(ctx_with(viscous_fits=fits, viscous_transition=trans, spring_tests=spring))
    assert not bool(f["viscous_independent_of_backpressure_1_3bar"]["holds"])
    assert not bool(f["no_stribeck_dip"]["holds"])
    assert not bool(f["spring_nrmse_below_2_5pct"]["holds"]) and "1 of 3" in f["spring_nrmse_below_2_5pct"]["detail"]


def test_hose_life_force_vs_distance():
    f = by_id(ctx_with(hose_life=weibull_lives()))
    r = f["force_set_hoses_outlive_distance_set"]
    assert r["measured"] == pytest.approx(90 / 40, rel=0.25) and bool(r["holds"]) and r["p_value"] < 0.05
    assert 0 < r["uncertainty"] < 1.0
    f = by_id(ctx_with(hose_life=weibull_lives(scales=(40.0, 90.0))))
    assert not bool(f["force_set_hoses_outlive_distance_set"]["holds"])


def test_compare_findings_marks_overturned():
    df = fs.run(ctx_with(breakaway=breakaway_events(f0=5.0, f1=5.0))).tables["findings"]
    out = compare_findings(df, {"breakaway_0bar_twice": True, "no_stribeck_dip": None}, had_previous=True)
    row = out.set_index("finding_id").loc["breakaway_0bar_twice"]
    assert row["change"] == "overturned" and bool(row["previous_holds"])
    assert pd.isna(out.set_index("finding_id").loc["no_stribeck_dip", "change"])
