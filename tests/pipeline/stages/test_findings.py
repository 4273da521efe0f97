"""The findings stage: each paper conclusion as a check, on hand-built result tables."""
import numpy as np
import pandas as pd
import pytest

from analyses import breakaway as bk
from pipeline.rebuild.history import compare_findings
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


def test_leakage_findings_judge_the_setting_not_worn_hoses():
    # a leak check on a worn hose at 33 % force leaks at 5 bar; the characterisation runs of the
    # same setting do not: the paper's claim is about the setting, so the finding still holds
    lm = leakage()
    worn = lm[lm["spring_force_n"] == 429.0].assign(run_id="check-H7", hose_id="H7", leak_l_min=1.5)
    f = by_id(ctx_with(leakage_map=pd.concat([lm.assign(hose_id=None), worn], ignore_index=True)))
    assert bool(f["no_leak_33pct_5bar"]["holds"])
    assert "check-H7" not in f["no_leak_33pct_5bar"]["detail"]
    # with hose checks only for that setting they are all there is: then they count
    f = by_id(ctx_with(leakage_map=pd.concat([lm[lm["spring_force_n"] != 429.0].assign(hose_id=None), worn],
                                             ignore_index=True)))
    assert not bool(f["no_leak_33pct_5bar"]["holds"])


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


def test_every_check_declares_the_id_it_returns():
    declared = [fid for fid, _ in fs.CHECKS]
    assert list(by_id(ctx_with())) == declared and len(set(declared)) == len(declared)


def test_a_check_that_raises_keeps_its_own_id_with_null_and_the_error(monkeypatch):
    def broken(ctx):
        if ctx.results:
            raise ZeroDivisionError("float division\nby zero")
        return fs.spring_nrmse(ctx)  # its no-data row still gives the statement

    def hopeless(ctx):
        raise KeyError("x")

    checks = dict(fs.CHECKS)
    checks["spring_nrmse_below_2_5pct"] = broken
    checks["no_stribeck_dip"] = hopeless
    monkeypatch.setattr(fs, "CHECKS", tuple(checks.items()))
    f = by_id(ctx_with(spring_tests=pd.DataFrame({"run_id": ["a"], "nrmse_pct": [1.0]})))
    assert list(f) == [fid for fid, _ in fs.CHECKS]  # no check_<i>
    row = f["spring_nrmse_below_2_5pct"]
    assert pd.isna(row["holds"]) and row["measured"] is None and row["ord"] == 7
    assert row["detail"] == "could not be computed: ZeroDivisionError: float division by zero"
    assert row["statement"].startswith("The polytropic spring model") and row["paper"] == fs.PLA
    row = f["no_stribeck_dip"]
    assert pd.isna(row["holds"]) and row["detail"] == "could not be computed: KeyError: 'x'"
    # a check returning another id than it declares is caught the same way
    checks["no_stribeck_dip"] = fs.spring_nrmse
    monkeypatch.setattr(fs, "CHECKS", tuple(checks.items()))
    assert "declared 'no_stribeck_dip'" in by_id(ctx_with())["no_stribeck_dip"]["detail"]


def test_an_overturn_of_a_failing_check_is_tracked():
    df = fs.run(ctx_with()).tables["findings"]
    out = compare_findings(df, {"no_stribeck_dip": True}, had_previous=True, previous_changes={})
    assert out.set_index("finding_id").loc["no_stribeck_dip", "change"] == "no longer checkable"


def test_spring_uncertainty_is_the_exact_bootstrap_se_of_the_max():
    import itertools

    x = [1.16, 2.0, 2.39]
    maxima = [max(c) for c in itertools.product(x, repeat=3)]  # all 27 equally likely resamples
    assert fs.bootstrap_se_of_max(x) == pytest.approx(np.std(maxima))
    assert fs.bootstrap_se_of_max([1.0, 1.0, 1.0]) == 0.0 and fs.bootstrap_se_of_max([2.0]) is None
    row = by_id(ctx_with(spring_tests=pd.DataFrame({"run_id": list("abc"), "nrmse_pct": x})))["spring_nrmse_below_2_5pct"]
    assert row["uncertainty"] == pytest.approx(np.std(maxima)) and "bootstrap standard error" in row["detail"]
    one = by_id(ctx_with(spring_tests=pd.DataFrame({"run_id": ["a"], "nrmse_pct": [1.0]})))
    assert one["spring_nrmse_below_2_5pct"]["uncertainty"] is None


def near_zero_points(stribeck_n, seed, n=60, noise_n=0.15):
    from analyses import viscous_friction as vfr

    rng = np.random.default_rng(seed)
    v = np.concatenate([np.geomspace(2e-4, 9e-3, n // 2), -np.geomspace(2e-4, 9e-3, n // 2)])
    f = np.tanh(v / 3e-4) * (3.0 + stribeck_n * np.exp(-(v / 1e-3) ** 2)) + 28.0 * v + rng.normal(0, noise_n, v.size)
    pts = pd.DataFrame({"run_id": "r", "backpressure_bar": 1.0, "velocity_m_s": v, "friction_n": f})
    return pts, vfr.viscous_transition(pts)


def test_stribeck_uncertainty_is_the_standard_error_of_the_fitted_amplitude():
    # a dip of 1.5 N is recovered within its standard error; the error is about right (repeat runs)
    estimates, ses = [], []
    for seed in range(12):
        pts, trans = near_zero_points(1.5, seed)
        row = by_id(ctx_with(viscous_points=pts, viscous_transition=trans))["no_stribeck_dip"]
        assert "least-squares covariance" in row["detail"]
        estimates.append(row["measured"])
        ses.append(row["uncertainty"])
    assert np.mean(ses) > 0
    assert abs(np.mean(estimates) - 1.5) < 3 * np.mean(ses) / np.sqrt(len(ses))
    assert 0.5 < np.std(estimates, ddof=1) / np.mean(ses) < 2.0
    # the analysis table carries it; a table without it gives no uncertainty, not a guess
    assert trans["stribeck_amplitude_se_n"].notna().all()
    row = by_id(ctx_with(viscous_transition=trans.drop(columns="stribeck_amplitude_se_n")))["no_stribeck_dip"]
    assert row["uncertainty"] is None and "not available" in row["detail"]


def test_compare_findings_keeps_the_last_change_while_holds_stays():
    from datetime import datetime, timezone

    t1, t2 = datetime(2026, 3, 1, 2, 30, tzinfo=timezone.utc), datetime(2026, 3, 1, 9, 0, tzinfo=timezone.utc)
    df = fs.run(ctx_with(breakaway=breakaway_events(f0=5.0, f1=5.0))).tables["findings"]
    first = compare_findings(df, {"breakaway_0bar_twice": True}, True, now=t1, previous_changes={}).set_index("finding_id")
    assert first.loc["breakaway_0bar_twice", "change"] == "overturned"
    assert first.loc["breakaway_0bar_twice", "changed_at"] == t1
    # the same result again: kept, with its time; never an invented change for the others
    prev = {k: (None if pd.isna(v) else bool(v)) for k, v in first["holds"].items()}
    changes = {k: (r["change"], r["changed_at"]) for k, r in first.iterrows()}
    second = compare_findings(df, prev, True, now=t2, previous_changes=changes).set_index("finding_id")
    assert second.loc["breakaway_0bar_twice", "change"] == "overturned"
    assert second.loc["breakaway_0bar_twice", "changed_at"] == t1
    assert not bool(second.loc["breakaway_0bar_twice", "previous_holds"])
    assert second.drop("breakaway_0bar_twice")["change"].isna().all()
    assert second.drop("breakaway_0bar_twice")["changed_at"].isna().all()
    # no previous warehouse: nothing changed
    assert compare_findings(df, {}, False, now=t2)["changed_at"].isna().all()


def test_stribeck_finding_without_any_amplitude_keeps_the_dip_test():
    # viscous_transition rows whose Stribeck amplitude is NULL (no standard error): the finding
    # reports the test, not an error
    trans = pd.DataFrame({"backpressure_bar": [0.0], "stribeck_amplitude_n": [None], "stribeck_amplitude_se_n": [None],
                          "stribeck_velocity_mm_s": [None], "stribeck_p_value": [0.8], "stribeck_dip": [False],
                          "n_points": [12], "note": ["Stribeck amplitude not identifiable from the data (no standard error)"]})
    row = fs.stribeck(ctx_with(viscous_transition=trans))
    assert row["holds"] is True and row["measured"] is None and row["p_value"] == pytest.approx(0.8)
    assert "no Stribeck amplitude" in row["detail"]


def test_a_check_that_reads_a_table_the_stage_did_not_declare_fails_the_stage_not_the_finding(monkeypatch):
    """A check raising gives its row "could not be computed"; an undeclared read is the stage's
    bug and goes through (the rebuild fails), and every table the checks read is declared."""
    from pipeline.stages import DeclaredContext, UndeclaredRead

    ctx = DeclaredContext("findings", fs.READS, raw=None, warehouse=None, runs=pd.DataFrame(),
                          results={"breakaway": breakaway_events()})
    assert len(by_id(ctx)) == len(fs.CHECKS)  # the real checks read only what READS declares
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", lambda c: fs._table(c, "zz_undeclared")),))
    with pytest.raises(UndeclaredRead, match="stage findings read table 'zz_undeclared'"):
        fs.run(ctx)


def test_the_findings_take_the_papers_values_from_schemas_papers():
    from schemas import papers

    rows = by_id(ctx_with())
    assert rows["breakaway_0bar_twice"]["criterion"] == "ratio of means within 1.5-2.5"
    assert rows["spring_nrmse_below_2_5pct"]["criterion"] == "largest NRMSE of the spring tests < 2.5 %"
    assert papers.PLPA_BREAKAWAY_RATIO_BAND == (1.5, 2.5) and papers.PLA_NRMSE_LIMIT_PCT == 2.5


def _verdicts():
    """life_verdict and life_effect rows of five hose types (the contract's columns that the finding reads)."""
    at = pd.Timestamp("2026-03-02 14:30", tz="UTC")
    base = {"margin": 1.25, "alpha": 0.05, "power": 0.8, "confidence": 0.9, "spending": "obrien-fleming",
            "max_failures": 40, "max_failures_from": "design", "plan_from": "hose_type", "note": None,
            "decided_at": pd.NaT, "decided_at_look": None, "decided_ratio": np.nan, "decided_lower": np.nan,
            "decided_upper": np.nan}
    verdict = pd.DataFrame([
        {**base, "hose_type": "PU 8x6", "verdict": "undecided", "failures": 29},
        {**base, "hose_type": "FLEXIGOM AIR", "verdict": "force longer", "failures": 16, "decided_at": at,
         "decided_at_look": 14, "decided_ratio": 1.78, "decided_lower": 1.12, "decided_upper": 2.83},
        {**base, "hose_type": "NBR 10", "verdict": "no plan", "failures": 12, "plan_from": "built-in"},
        {**base, "hose_type": "SIL 4", "verdict": "undecided", "failures": 1,
         "note": "fewer than two failures in an adjustment"},
        {**base, "hose_type": "EPDM 6", "verdict": "distance longer", "failures": 30, "decided_at": at,
         "decided_at_look": 25, "decided_ratio": 0.6, "decided_lower": 0.4, "decided_upper": 0.9},
        {**base, "hose_type": "PVC 12", "verdict": "no practical difference", "failures": 40, "decided_at": at,
         "decided_at_look": 40, "decided_ratio": 1.01, "decided_lower": 0.9, "decided_upper": 1.13}])
    effect = pd.DataFrame([
        {"hose_type": t, "life_ratio": r, "life_ratio_lower": lo, "life_ratio_upper": hi, "confidence": 0.9,
         "model": "common shape" if r == r else None, "n_force": 10, "n_failed_force": 6, "n_distance": 10,
         "n_failed_distance": 8, "note": note}
        for t, r, lo, hi, note in (("FLEXIGOM AIR", 1.82, 1.31, 2.53, None), ("PU 8x6", 1.3, 0.9, 1.9, None),
                                   ("NBR 10", 1.4, 1.02, np.nan, None),
                                   ("SIL 4", np.nan, np.nan, np.nan, "fewer than two failures in an adjustment"),
                                   ("EPDM 6", 0.62, 0.45, 0.85, None), ("PVC 12", 1.0, 0.92, 1.1, None))])
    return verdict, effect


def test_the_decision_is_a_finding_per_hose_type_after_the_papers():
    verdict, effect = _verdicts()
    f = by_id(ctx_with(life_verdict=verdict, life_effect=effect))
    ids = [k for k in f if k.startswith("life_verdict:")]
    assert ids == [f"life_verdict:{t}" for t in ("EPDM 6", "FLEXIGOM AIR", "NBR 10", "PU 8x6", "PVC 12", "SIL 4")]
    assert [f[k]["ord"] for k in ids] == list(range(len(fs.CHECKS) + 1, len(fs.CHECKS) + 7))
    holds = {k.split(":", 1)[1]: (None if pd.isna(f[k]["holds"]) else bool(f[k]["holds"])) for k in ids}
    assert holds == {"FLEXIGOM AIR": True, "EPDM 6": False, "PVC 12": False, "PU 8x6": None, "NBR 10": None,
                     "SIL 4": None}
    row = f["life_verdict:FLEXIGOM AIR"]
    z = 1.6448536269514722  # two-sided 90 %
    assert row["measured"] == 1.82 and row["unit"] == "ratio" and row["n"] == 16 and row["paper"] == fs.PLPA
    assert row["uncertainty"] == pytest.approx(1.82 * (np.log(2.53) - np.log(1.31)) / (2 * z))
    assert row["statement"] == ("FLEXIGOM AIR hoses live longer with force-set rollers than with distance-set ones "
                                "(the decision)")
    assert "margin 1.25, alpha 0.05 over all looks, obrien-fleming spending" in row["criterion"]
    assert row["detail"].startswith("verdict 'force longer' after 16 of 40 failures (design, margin from hose_type); "
                                    "decided at look 14 (2026-03-02): ratio 1.78, repeated CI 1.12-2.83; life ratio "
                                    "1.82 (90 % profile-likelihood CI 1.31-2.53, common shape)")
    assert pd.isna(row["p_value"]) and row["source_tables"] == "life_verdict, life_effect"
    # numbers the tables hold as NULL stay NULL, with the reason in the detail
    sil = f["life_verdict:SIL 4"]
    assert pd.isna(sil["measured"]) and pd.isna(sil["uncertainty"])
    assert "no life ratio: fewer than two failures in an adjustment" in sil["detail"]
    open_bound = f["life_verdict:NBR 10"]
    assert open_bound["measured"] == 1.4 and pd.isna(open_bound["uncertainty"])
    assert "no plan.toml: numbers with the built-in defaults, no verdict declared" in open_bound["detail"]


def test_a_hose_type_whose_verdict_cannot_be_read_is_null_with_the_error_the_others_stand(monkeypatch):
    verdict, effect = _verdicts()
    real = fs._verdict_row

    def broken(v, e):
        if v["hose_type"] == "PU 8x6":
            raise ValueError("bad\nrow")
        return real(v, e)

    monkeypatch.setattr(fs, "_verdict_row", broken)
    f = by_id(ctx_with(life_verdict=verdict, life_effect=effect))
    row = f["life_verdict:PU 8x6"]
    assert pd.isna(row["holds"]) and pd.isna(row["measured"])
    assert row["detail"] == "could not be computed: ValueError: bad row"
    assert row["statement"].startswith("PU 8x6 hoses live longer")
    assert bool(f["life_verdict:FLEXIGOM AIR"]["holds"]) and f["life_verdict:FLEXIGOM AIR"]["measured"] == 1.82
    # without life_effect the verdict still holds or not, the ratio is absent and says why
    f = by_id(ctx_with(life_verdict=verdict))
    row = f["life_verdict:FLEXIGOM AIR"]
    assert bool(row["holds"]) and pd.isna(row["measured"])
    assert "no life ratio: life_effect has no estimate" in row["detail"]


def test_the_stage_declares_the_decision_tables():
    assert {"life_verdict", "life_effect"} <= set(fs.READS.tables)


def test_hose_life_fits_go_through_the_memo_as_plain_lives_with_a_direct_fits_bits():
    from analyses import service_life as sl

    lives = weibull_lives()
    ctx = ctx_with(hose_life=lives)
    calls, plain = [], ctx.map
    ctx.map = lambda func, items, label="": calls.append((func, list(items))) or plain(func, items, label)
    r = by_id(ctx)["force_set_hoses_outlive_distance_set"]
    assert bool(r["holds"]) and [func for func, _ in calls] == [fs.weibull_fit_item]
    items = calls[0][1]
    assert all(type(v) is float for life, _ in items for v in life)   # plain data: what the memo keys on
    for (life, failed), (x, f) in zip(items, fs._life_groups(lives).values()):
        a, b = fs.weibull_fit_item((life, failed)), sl.weibull_fit(x, f)
        assert a.ok and (a.shape, a.scale, a.loglik) == (b.shape, b.scale, b.loglik)


def test_std_from_ci_uses_the_confidence():
    """Half the interval over z: 95 % by default, the row's confidence otherwise, log scale for ratios."""
    from scipy.special import ndtri

    r = {"estimate": 2.0, "ci_low": 1.0, "ci_high": 3.0}
    assert fs._std_from_ci(r) == 2.0 / (2 * float(ndtri(0.975)))
    assert fs._std_from_ci({**r, "confidence": 0.9}) == 2.0 / (2 * float(ndtri(0.95)))
    assert fs._std_from_ci({**r, "confidence": 0.9}, log=True) == 2.0 * (np.log(3.0) - np.log(1.0)) / (2 * float(ndtri(0.95)))
    assert fs._std_from_ci({"estimate": 2.0, "ci_low": None, "ci_high": 3.0}) is None
