"""The remaining-life stage: hose_rul, rul_backtest and decision_sensitivity from small hand-made hose_life /
hose_leak_growth frames with known leak paths; the leak path at the plan's pressure; NULL + note where the data
or the plan cannot tell; the decision's rule read once; re-run only on logbooks, leakage, durability and the plan;
the same inputs give the same bytes; the demo rebuild with a leak limit in its plan."""
import io
import math
import shutil

import numpy as np
import pandas as pd
import pytest

from analyses.life_effect_lognormal import lognormal_effect_fit
from analyses.sequential_boundaries import efficacy_boundaries
from pipeline.raw.plan import Plan
from pipeline.stages import StageContext
from pipeline.stages import remaining_life as stage
from tests.conftest import query

#: The PLPA stage's sensors text: q_leak resolution 1e-7 kg/s (0.005 l/min ANR), noise 5e-8 kg/s.
SENSORS = "p_supply: resolution 100, noise 50 (metadata) Pa; q_leak: resolution 1e-07, noise 5e-08 (metadata) kg/s"
LIMIT, GAMMA, WEAR = 2.0, 1.5, {"force": 0.02, "distance": 0.05}
LEAK_PLAN = {"leak_limit_l_min": LIMIT, "leak_pressure_bar": 6.0, "max_failures": 20}


def campaign(n=8, seed=1, every=2.0):
    """n hoses per adjustment of type T: leak at 6 bar ``(w d)^1.5`` l/min with a lognormal wear rate w per hose
    (5 % scatter per point), failed by leakage when it reaches LIMIT (a check at the failure), else running at
    a distance drawn around the median life; plateaus 0..6 bar, the leak proportional to the pressure.

    Returns hose_life, hose_leak_growth, leakage_map and the true crossing distance per hose [km]."""
    rng = np.random.default_rng(seed)
    hoses, growth, truth = [], [], {}
    for adj, wear in WEAR.items():
        for i in range(n):
            hid = f"{adj[0].upper()}{i:02d}"
            w = wear * math.exp(0.3 * rng.normal())
            truth[hid] = LIMIT ** (1 / GAMMA) / w
            stop = rng.uniform(0.3, 1.5) * LIMIT ** (1 / GAMMA) / wear
            failed = truth[hid] < stop
            end = truth[hid] if failed else stop
            hoses.append({"hose_id": hid, "hose_type": "T", "adjustment": adj, "status": "failed" if failed else
                          "running", "distance_km": end, "failure_mode": "leakage" if failed else None})
            checks = list(np.arange(every, end, every)) + ([end] if failed else [])
            for k, d in enumerate(checks):
                path = (w * d) ** GAMMA * math.exp(0.05 * rng.normal()) if d < end else LIMIT
                growth += [{"hose_id": hid, "run_id": f"check-{hid}-{k:02d}", "distance_km": float(d),
                            "adjustment": adj, "chamber": "A", "pressure_bar": p + 0.01 * rng.normal(),
                            "leak_l_min": path * p / 6.0, "hose_status": None} for p in range(7)]
    g = pd.DataFrame(growth)
    return pd.DataFrame(hoses), g, pd.DataFrame({"run_id": sorted(set(g["run_id"])), "sensors": SENSORS}), truth


def context(life, growth, lmap, plan=LEAK_PLAN, present=True, max_failures=20):
    verdict = pd.DataFrame({"hose_type": ["T"], "max_failures": [max_failures], "verdict": ["undecided"]})
    return StageContext(raw=None, warehouse=None, runs=pd.DataFrame(), plan=Plan(present=present, defaults=plan),
                        results={"hose_life": life, "hose_leak_growth": growth, "leakage_map": lmap,
                                 "life_verdict": verdict})


@pytest.fixture(scope="module")
def built():
    life, growth, lmap, truth = campaign()
    return {"life": life, "growth": growth, "lmap": lmap, "truth": truth,
            "out": stage.run(context(life, growth, lmap))}


# -- hose_rul ---------------------------------------------------------------------------------
def test_every_running_hose_gets_both_methods_and_the_leak_path_holds_its_true_end(built):
    rul, life, truth = built["out"].tables["hose_rul"], built["life"], built["truth"]
    running = life[life["status"] == "running"]
    assert list(rul.columns) == stage.RUL_COLUMNS and len(rul) == 2 * len(running) == 16
    assert sorted(rul["hose_id"].unique()) == sorted(running["hose_id"])
    assert (rul["confidence"] == 0.9).all() and (rul["leak_limit_l_min"] == LIMIT).all()
    assert (rul["leak_pressure_bar"] == 6.0).all() and rul["rul_median_km"].notna().all()
    # a note on a weibull row with numbers only says which life family carries it
    wb_note = rul.loc[rul["method"] == "weibull", "note"]
    assert (wb_note.isna() | wb_note.str.startswith("life model: ")).all()
    # no rupture logged, no rupture_shape in the plan: the joint interval holds for every shape, and says so
    assert rul.loc[rul["method"] == "degradation", "note"].str.startswith("the rupture shape is not known").all()
    assert ((rul["rul_lower_km"] <= rul["rul_median_km"]) & (rul["rul_median_km"] <= rul["rul_upper_km"])).all()
    deg = rul[rul["method"] == "degradation"].set_index("hose_id")
    wb = rul[rul["method"] == "weibull"].set_index("hose_id")
    left = pd.Series({h: truth[h] for h in deg.index}) - deg["distance_km"]
    held = ((deg["rul_lower_km"] <= left) & (left <= deg["rul_upper_km"])).sum()
    assert held >= 6                                                    # 90 % intervals, 8 running hoses
    # frequent leak tests: the leak path narrows the interval against the life model's (issue 24)
    assert ((deg["rul_upper_km"] - deg["rul_lower_km"]) < (wb["rul_upper_km"] - wb["rul_lower_km"])).all()
    # leak_now is the last point at 6 bar; its count the hose's leakage runs
    d05 = built["growth"].query("hose_id == 'D05' and pressure_bar > 5.5").sort_values("distance_km")
    assert deg.loc["D05", "leak_now_l_min"] == pytest.approx(d05["leak_l_min"].iloc[-1])
    assert deg.loc["D05", "n_leak_points"] == len(d05)


def test_the_backtest_is_per_adjustment_and_method_and_pools_its_two_fractions(built):
    bt, life = built["out"].tables["rul_backtest"], built["life"]
    assert list(bt.columns) == stage.BACKTEST_COLUMNS
    assert list(zip(bt["adjustment"], bt["method"])) == [("distance", "weibull"), ("distance", "degradation"),
                                                         ("force", "weibull"), ("force", "degradation")]
    failed = life[life["status"] == "failed"].groupby("adjustment").size()
    for r in bt.itertuples():
        assert r.n_predictions <= 2 * failed[r.adjustment] and r.confidence == 0.9
        assert min(r.coverage_at_50, r.coverage_at_80) <= r.coverage <= max(r.coverage_at_50, r.coverage_at_80)
    deg = bt[(bt["method"] == "degradation")]
    assert (deg["n_predictions"] == 2 * failed[deg["adjustment"]].to_numpy()).all() and deg["note"].isna().all()
    assert (bt["median_abs_error_km"] > 0).all()


def test_the_plans_rupture_shape_reaches_the_joint_model(built):
    """``rupture_shape`` stated: the Weibayes at it, no note; at 1 (the constant hazard, in the union's range)
    each interval lies inside the union's of the shape not known."""
    out = stage.run(context(built["life"], built["growth"], built["lmap"], plan={**LEAK_PLAN, "rupture_shape": 1.0}))
    union, known = (o.tables["hose_rul"].query("method == 'degradation'").set_index("hose_id")
                    for o in (built["out"], out))
    assert known["note"].isna().all() and known["rul_median_km"].notna().all()
    assert (known["rul_lower_km"] >= union["rul_lower_km"] - 1e-9).all()
    assert (known["rul_upper_km"] <= union["rul_upper_km"] + 1e-9).all()
    assert stage.READS.plan and "rupture_shape" in stage.READS.plan


# -- NULL + note ----------------------------------------------------------------------------------
def test_without_a_leak_limit_the_weibull_rows_stand_and_the_leak_side_is_null_with_the_plans_note(built):
    out = stage.run(context(built["life"], built["growth"], built["lmap"], plan={"max_failures": 20}))
    rul, note = out.tables["hose_rul"], stage.NO_LEAK_PLAN.format("T")
    deg, wb = rul[rul["method"] == "degradation"], rul[rul["method"] == "weibull"]
    assert deg["rul_median_km"].isna().all() and (deg["note"] == note).all()
    assert wb["rul_median_km"].notna().all() and (wb["note"].isna() | wb["note"].str.startswith("life model: ")).all()
    assert rul["n_leak_points"].isna().all() and rul["leak_limit_l_min"].isna().all()
    bt = out.tables["rul_backtest"].set_index(["adjustment", "method"])
    assert (bt.xs("degradation", level="method")["note"] == note).all()
    assert (bt.xs("degradation", level="method")["n_predictions"] == 0).all()
    assert bt.xs("weibull", level="method")["coverage"].notna().all()
    sens = out.tables["decision_sensitivity"].set_index("definition")
    assert list(sens.index) == [d for d, _ in stage.DEFINITIONS]
    assert sens.loc["logbook", "life_ratio"] > 1 and isinstance(sens.loc["logbook", "verdict"], str)
    leak = sens.drop(index="logbook")
    assert leak["life_ratio"].isna().all() and leak["verdict"].isna().all() and (leak["note"] == note).all()


def _replace_path(growth, hose_id, distances, leaks):
    """``hose_id``'s leak checks replaced by points at ``distances`` with 6-bar ``leaks`` (0..6 bar plateaus)."""
    rows = [{"hose_id": hose_id, "run_id": f"new-{hose_id}-{k}", "distance_km": d, "adjustment": None,
             "chamber": "A", "pressure_bar": float(p), "leak_l_min": q * p / 6.0, "hose_status": None}
            for k, (d, q) in enumerate(zip(distances, leaks)) for p in range(7)]
    return pd.concat([growth[growth["hose_id"] != hose_id], pd.DataFrame(rows)], ignore_index=True)


def test_one_point_a_falling_path_or_noise_at_the_floor_give_null_and_the_reason(built):
    growth, lmap = built["growth"], built["lmap"]
    running = sorted(built["life"].query("status == 'running' and adjustment == 'distance'")["hose_id"])[:3]
    growth = _replace_path(growth, running[0], [10.0], [0.5])                            # one point
    growth = _replace_path(growth, running[1], [2.0, 4.0, 6.0, 8.0], [0.8, 0.6, 0.45, 0.3])   # falling
    growth = _replace_path(growth, running[2], [2.0, 4.0, 6.0, 8.0], [0.01, 0.02, 0.01, 0.03])  # under 10 floors
    lmap = pd.concat([lmap, pd.DataFrame({"run_id": sorted(set(growth["run_id"]) - set(lmap["run_id"])),
                                          "sensors": SENSORS})], ignore_index=True)
    rul = stage.run(context(built["life"], growth, lmap)).tables["hose_rul"]
    deg = rul[rul["method"] == "degradation"].set_index("hose_id")
    assert deg.loc[running, "rul_median_km"].isna().all() and deg.loc[running, "rul_lower_km"].isna().all()
    assert deg.loc[running[0], "note"].startswith("too few leak points: 1")
    assert "falling" in deg.loc[running[1], "note"]
    assert "sensor floor" in deg.loc[running[2], "note"]
    others = deg.drop(index=running)
    assert others["rul_median_km"].notna().all()                     # the rest of the group still predicts


def test_a_leak_path_without_a_stated_sensor_is_null_not_guessed(built):
    lmap = built["lmap"].assign(sensors="p_supply: resolution 100, noise 50 (metadata) Pa")
    rul = stage.run(context(built["life"], built["growth"], lmap)).tables["hose_rul"]
    deg = rul[rul["method"] == "degradation"]
    assert deg["rul_median_km"].isna().all() and deg["note"].str.startswith("no leak-flow sensor").all()


# -- the leak path and the sensor ---------------------------------------------------------------
def test_the_leak_path_takes_the_plateau_nearest_the_plan_pressure_within_half_the_spacing_mean_over_chambers():
    rows = [{"hose_id": "H", "run_id": f"r{k}", "chamber": ch, "distance_km": 5.0 * (k + 1), "pressure_bar": p,
             "leak_l_min": (k + 1) * p + (0.5 if ch == "B" else 0.0)} for k in range(2) for ch in "AB"
            for p in (1.0, 2.0, 3.0)]
    g = pd.DataFrame(rows)
    pts, note = stage.leak_paths(g, 2.4)
    assert note is None and list(pts["distance_km"]) == [5.0, 10.0]
    assert list(pts["leak_l_min"]) == [2.25, 4.25]                   # the 2-bar plateau, chambers A and B averaged
    pts, note = stage.leak_paths(g, 3.6)                             # 0.6 bar beyond the last plateau
    assert pts.empty and note.startswith("no plateau within 0.5 bar (half the plateau spacing)")
    pts, note = stage.leak_paths(g[g["pressure_bar"] == 2.0], 2.0)
    assert pts.empty and "one plateau each" in note
    assert stage.plateau_spacing(g) == 1.0


def test_the_leak_sensor_is_the_coarsest_stated_in_l_min():
    coarse = SENSORS.replace("resolution 1e-07", "resolution 2e-07")
    res, noise = stage.leak_sensor([SENSORS, coarse, None, "no sensor here"])
    assert res == pytest.approx(2e-7 / 1.185 * 60_000, rel=1e-3)    # kg/s to l/min ANR (1.185 kg/m3)
    assert noise == pytest.approx(5e-8 / 1.185 * 60_000, rel=1e-3)
    assert stage.leak_sensor(["p_supply: resolution 1, noise 1 (metadata) Pa"]) is None


# -- decision_sensitivity ---------------------------------------------------------------------------
def test_leak_definitions_cross_by_interpolation_and_hoses_without_a_path_keep_their_logbook_distance_censored():
    hoses = pd.DataFrame({"hose_id": ["A", "B", "C"], "adjustment": ["force", "force", "distance"],
                          "distance_km": [30.0, 40.0, 25.0], "status": ["failed", "running", "failed"]})
    points = pd.DataFrame({"hose_id": ["A", "A", "B", "B"], "distance_km": [10.0, 20.0, 10.0, 30.0],
                           "leak_l_min": [1.0, 3.0, 0.5, 0.9]})
    lives, note = stage.definition_lives(hoses, points, 2.0)
    assert lives.set_index("hose_id")["distance_km"].to_dict() == {"A": 15.0, "B": 30.0, "C": 25.0}
    assert lives.set_index("hose_id")["failed"].to_dict() == {"A": True, "B": False, "C": False}
    assert note == "1 hose(s) without a leak path: their logbook distance, censored"
    lives, note = stage.definition_lives(hoses, points, None)                   # the logbook
    assert list(lives["failed"]) == [True, False, True] and note is None


def test_the_sensitivity_reads_the_decisions_rule_once_at_its_information_fraction(built):
    sens = built["out"].tables["decision_sensitivity"].set_index("definition")
    assert list(sens.columns) == stage.SENSITIVITY_COLUMNS[:1] + stage.SENSITIVITY_COLUMNS[2:]
    assert math.isnan(sens.loc["logbook", "leak_limit_l_min"])
    assert list(sens["leak_limit_l_min"].iloc[1:]) == [LIMIT, LIMIT / 2, LIMIT * 2]
    # with a check at every leak failure, the leak limit's failures are the logbook's (all failed by leakage)
    # and the running hoses whose last check is at the limit already
    top = built["growth"].query("pressure_bar > 5.5").merge(built["life"][["hose_id", "status"]], on="hose_id")
    crossed = top[top["leak_l_min"] >= LIMIT].drop_duplicates("hose_id")
    for adj in ("force", "distance"):
        assert sens.loc["leak limit", f"n_{adj}"] == sens.loc["logbook", f"n_{adj}"]
        assert sens.loc["leak limit", f"n_failed_{adj}"] == (crossed["hose_id"].str[0] == adj[0].upper()).sum()
    assert (crossed["status"] == "running").sum() >= 1                    # the case is in the data
    assert sens.loc["leak limit", "life_ratio"] == pytest.approx(sens.loc["logbook", "life_ratio"], rel=0.1)
    # a lower limit is reached sooner: more failures; true wear rates differ 2.5x, i.e. lives force/distance 2.5
    assert sens.loc["leak limit x0.5", "n_failed_force"] >= sens.loc["leak limit", "n_failed_force"]
    assert sens.loc["logbook", "life_ratio_lower"] < 2.5 < sens.loc["logbook", "life_ratio_upper"]
    assert sens.loc["logbook", "verdict"] == "force longer"
    assert sens.loc["logbook", "model"] in ("common shape", "separate shapes")
    leak = sens.iloc[1:]
    told = leak["life_ratio"].notna()
    assert (leak["model"][told] == stage.LEAK_MODEL).all() and stage.LEAK_MODEL == "lognormal, common sigma"
    assert told["leak limit"] and leak["note"][~told].str.contains("lognormal").all()   # untold: why, by the model
    life = built["life"].assign(failed=built["life"]["status"] == "failed")
    sv, _ = stage.read_once(life, 20, {"margin": 1.25, "alpha": 0.05, "spending": "obrien-fleming"})
    f = int(life["failed"].sum())
    assert sv.boundary_z[-1] == pytest.approx(efficacy_boundaries(np.arange(1, f + 1) / 20, 0.05)[-1])
    assert sv.verdict == "force longer" and sv.decided_at == f - 1
    # under the leak definitions' model the look reads the common-sigma lognormal's estimate
    _, est = stage.read_once(life, 20, {"margin": 1.25, "alpha": 0.05, "spending": "obrien-fleming"}, stage.LEAK_MODEL)
    ln = lognormal_effect_fit(life["distance_km"], life["failed"], (life["adjustment"] == "force").astype(int))
    assert est["log_ratio"] == ln.log_ratio and est["se_log_ratio"] == ln.se_log_ratio


def test_without_a_plan_the_sensitivity_says_no_plan_and_what_it_would_have_read(built):
    sens = stage.run(context(built["life"], built["growth"], built["lmap"], plan={}, present=False)).tables[
        "decision_sensitivity"].set_index("definition")
    assert sens.loc["logbook", "verdict"] == "no plan"
    assert sens.loc["logbook", "note"].startswith("no usable raw/plan.toml: read as 'force longer'")
    assert sens.loc["leak limit", "verdict"] is None


def test_the_logbook_row_names_life_verdicts_own_verdict_where_it_differs(built):
    ctx = context(built["life"], built["growth"], built["lmap"])
    assert "life_verdict (read at every failure, sticky) says 'undecided'" in stage.run(ctx).tables[
        "decision_sensitivity"]["note"].iloc[0]


def test_the_logbook_row_reads_no_leak_path_and_is_the_same_row_alone(built):
    _groups, types = stage.stage_items(context(built["life"], built["growth"], built["lmap"]))
    item = types[0]
    rows = stage.sensitivity_of(item)
    assert [r["definition"] for r in rows] == [d for d, _ in stage.DEFINITIONS]
    assert stage.sensitivity_logbook(stage.logbook_item(item)) == rows[:1]   # the same row, computed alone
    assert stage.sensitivity_leak(item) == rows[1:]
    # another leak path: the logbook's item (its memo key) is the same, the leak rows move
    moved = built["growth"].assign(leak_l_min=built["growth"]["leak_l_min"] * 1.5)
    _groups, other = stage.stage_items(context(built["life"], moved, built["lmap"]))
    assert other[0]["points"] != item["points"] and stage.logbook_item(other[0]) == stage.logbook_item(item)
    assert stage.sensitivity_leak(other[0]) != rows[1:]
    table = built["out"].tables["decision_sensitivity"]
    assert table["definition"].tolist() == [d for d, _ in stage.DEFINITIONS]


# -- determinism -----------------------------------------------------------------------------------
def _bytes(out) -> dict:
    blobs = {}
    for name, df in out.tables.items():
        buf = io.BytesIO()
        df.to_parquet(buf, index=False)
        blobs[name] = buf.getvalue()
    return blobs


def test_the_same_inputs_give_the_same_bytes(built):
    shuffled = built["growth"].sample(frac=1.0, random_state=3)
    assert _bytes(stage.run(context(built["life"][::-1], shuffled, built["lmap"]))) == _bytes(built["out"])


# -- incremental, and the demo ------------------------------------------------------------------------
HEADER = "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,wall_thickness_mm,distance_km,notes\n"
BOOK = HEADER + ("D1,installed,2026-01-01,T,distance,4.5,,,,,\nF1,installed,2026-01-01,T,force,,866,,,,\n"
                 "D1,failed,2026-01-03,,,,,leakage,,,\n")
RUL_PLAN = "[defaults]\nmargin = 2.0\nmax_failures = 20\nleak_limit_l_min = 2.0\nleak_pressure_bar = 3.0\n"


def _durability_csv(raw, rel, hose, started):
    from pipeline.simulator import simulate_durability
    sim = simulate_durability(hose_id=hose, distance_m=5.0, rng=1, stroke_m=0.1, dwell_s=0.05, fs_hz=200.0)
    cols = {"t[s]": sim.data["t_s"].tolist(), "x[mm]": (sim.data["x_m"] * 1e3).round(3).tolist(),
            "p_a[Pa]": sim.data["p_a_pa"].tolist(), "p_b[Pa]": sim.data["p_b_pa"].tolist()}
    raw.csv(rel, {"kind": "durability", "rig": "plpa-1", "hose_id": hose, "started_at": started}, cols)


def _leak_check_csv(raw, rel, hose, started, p_seal_bar, seed):
    from pipeline.simulator.plpa import simulate_leakage
    sim = simulate_leakage("A", "distance", 4.5, None, rng=seed, hose_id=hose, p_seal_bar=p_seal_bar, fs_hz=10.0,
                           plateau_s=2.0, pressures_bar=(1.0, 2.0, 3.0))
    cols = {"t[s]": sim.data["t_s"].tolist(), "p_supply[Pa]": sim.data["p_supply_pa"].tolist(),
            "q_leak[kg/s]": sim.data["q_leak_kg_s"].tolist()}
    raw.csv(rel, {"kind": "leakage", "rig": "plpa-1", "hose_id": hose, "chamber": "A", "adjustment": "distance",
                  "z_rollers_mm": 4.5, "started_at": started}, cols)


def test_reruns_only_on_logbooks_leakage_durability_and_plan_and_full_equals_incremental(raw, warehouse,
                                                                                         monkeypatch):
    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild
    from pipeline.stages import decision, durability, durability_runs, plpa_characterisation
    from tests.pipeline.rebuild.test_state import step

    monkeypatch.setattr(registry, "discover",
                        lambda: [plpa_characterisation, durability_runs, durability, decision, stage])
    raw.write("c/hoses.csv", BOOK)
    _durability_csv(raw, "c/d1.csv", "D1", "2026-01-01T08:00:00")
    _durability_csv(raw, "c/f1.csv", "F1", "2026-01-01T09:00:00")
    _leak_check_csv(raw, "c/check-d1.csv", "D1", "2026-01-01T10:00:00", 3.0, 1)
    raw.write("plan.toml", "[defaults]\nmargin = 2.0\nmax_failures = 20\n")
    ran = lambda: rebuild(raw.root, warehouse, jobs=1, report=False)  # noqa: E731
    assert "remaining_life" in ran().stages_run
    assert query(warehouse, "SELECT DISTINCT note FROM hose_rul WHERE method = 'degradation'") == [
        (stage.NO_LEAK_PLAN.format("T"),)]
    step(raw, "c/step.csv")
    assert "remaining_life" in ran().stages_reused                               # a run of another kind
    raw.write("plan.toml", RUL_PLAN)
    assert "remaining_life" in ran().stages_run                                  # the plan
    assert query(warehouse, "SELECT hose_id, method, leak_limit_l_min, leak_pressure_bar, n_leak_points FROM hose_rul "
                            "ORDER BY ALL") == [("F1", "degradation", 2.0, 3.0, 0), ("F1", "weibull", 2.0, 3.0, 0)]
    raw.write("c/hoses.csv", BOOK + "F1,failed,2026-01-04,,,,,rupture,,,\n")
    assert "remaining_life" in ran().stages_run                                  # the logbook
    assert query(warehouse, "SELECT count(*) FROM hose_rul") == [(0,)]           # no running hose left
    _leak_check_csv(raw, "c/check-d1b.csv", "D1", "2026-01-02T10:00:00", 2.5, 2)
    assert "remaining_life" in ran().stages_run                                  # a leakage run
    _durability_csv(raw, "c/f2.csv", "F1", "2026-01-02T09:00:00")
    assert "remaining_life" in ran().stages_run                                  # a durability run
    tables = ("hose_rul", "rul_backtest", "decision_sensitivity")
    before = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert len(before["rul_backtest"]) == 4 and len(before["decision_sensitivity"]) == 4
    assert "remaining_life" in rebuild(raw.root, warehouse, jobs=1, report=False, full=True).stages_run
    assert {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables} == before


DEMO_LEAK_PLAN = "\n[hose_type.\"FLEXIGOM AIR\"]\nleak_limit_l_min = {limit}\nleak_pressure_bar = 6.0\n"


@pytest.mark.slow
def test_the_demo_rebuild_with_a_leak_limit_fills_the_three_tables(demo, tmp_path):
    from pipeline.rebuild.flow import rebuild

    raw = tmp_path / "raw"
    shutil.copytree(demo["raw"], raw)
    growth = query(demo["warehouse"], "SELECT max(leak_l_min) FROM hose_leak_growth WHERE pressure_bar > 5.5")
    limit = round(0.5 * growth[0][0], 3)                        # half the worst leak seen: some paths cross it
    # the demo's own leak keys (if its plan has them) give way to this test's
    plan = "".join(ln for ln in (raw / "plan.toml").read_text().splitlines(keepends=True)
                   if not ln.lstrip().startswith(("leak_limit_l_min", "leak_pressure_bar")))
    plan = plan.replace('[hose_type."FLEXIGOM AIR"]\n', DEMO_LEAK_PLAN.format(limit=limit).lstrip("\n")) \
        if '[hose_type."FLEXIGOM AIR"]' in plan else plan + DEMO_LEAK_PLAN.format(limit=limit)
    (raw / "plan.toml").write_text(plan)
    wh = tmp_path / "warehouse"
    summary = rebuild(raw, wh, jobs=2, report=False)
    assert "remaining_life" in summary.stages_run
    running = query(wh, "SELECT hose_id FROM hose_life WHERE status = 'running' AND hose_type = 'FLEXIGOM AIR' "
                        "ORDER BY ALL")
    rul = query(wh, "SELECT * FROM hose_rul ORDER BY hose_id, method", frame=True)
    assert sorted(set(rul["hose_id"])) == [h for (h,) in running] and len(rul) == 2 * len(running)
    assert (rul["leak_limit_l_min"] == limit).all() and (rul["leak_pressure_bar"] == 6.0).all()
    sound = rul[rul["rul_median_km"].notna()]
    assert (sound["rul_lower_km"] <= sound["rul_median_km"]).all()
    assert rul[rul["rul_median_km"].isna()]["note"].notna().all()            # NULL only with a reason
    bt = query(wh, "SELECT adjustment, method FROM rul_backtest ORDER BY ALL")
    assert bt == [(a, m) for a in ("distance", "force") for m in ("degradation", "weibull")]
    sens = query(wh, "SELECT definition, verdict, leak_limit_l_min FROM decision_sensitivity", frame=True)
    assert list(sens["definition"]) == [d for d, _ in stage.DEFINITIONS]
    assert list(sens["leak_limit_l_min"].iloc[1:]) == pytest.approx([limit, limit / 2, limit * 2])
    assert sens["verdict"].notna().all()
