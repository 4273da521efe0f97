"""The decision stage: its four tables from hose_life, durability runs and the logbooks; `no plan`; the plan's
max_failures or the design's; the sticky verdict at its deciding look; re-run only on logbooks, durability runs
and the plan; --full equal to incremental; the demo rebuild carries the tables."""
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analyses.hose_life import hose_life
from analyses.life_effect import ratio_deviance
from analyses.look_fits import bartlett_factor
from analyses.sequential import design_shape, max_information
from pipeline.raw.logbook import merge_logbooks, read_logbooks
from pipeline.raw.plan import Plan
from pipeline.simulator import simulate_durability
from pipeline.stages import StageContext
from pipeline.stages import decision as stage
from pipeline.stages import durability, durability_runs
from tests.conftest import query

HEADER = "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,wall_thickness_mm,distance_km,notes\n"
PLAN = "[defaults]\nmargin = 2.0\n"   # an unset max_failures: designed, cheaply at this margin


def settings(present=True, max_failures=20, margin=1.25, spending="pocock"):
    return {"present": present, "margin": margin, "alpha": 0.05, "power": 0.8, "confidence": 0.9,
            "max_failures": max_failures, "spending": spending, "plan_from": "defaults"}


def odometer_item(ratio=4.0, n=12, seed=3, present=True, max_failures=20):
    """n hoses per adjustment, one after another on one bench, odometer-only lives (Weibull shape 3)."""
    rng = np.random.default_rng(seed)
    hoses, t = [], pd.Timestamp("2026-01-01", tz="UTC")
    for i in range(n):
        for adj, scale in (("distance", 20.0), ("force", 20.0 * ratio)):
            km = float(scale * rng.weibull(3.0))
            end = t + pd.Timedelta(hours=km)
            hoses.append({"hose_id": f"{adj[0].upper()}{i:02d}", "adjustment": adj, "distance_km": km,
                          "status": "failed", "distance_source": "odometer", "installed_at": t, "ended_at": end})
            t = end
    plan = Plan(present=present, defaults={"max_failures": max_failures, "spending": "pocock"}).for_hose_type("T")
    no_runs = pd.DataFrame(columns=["run_id", "hose_id", "started_at", "duration_h", "distance_km"])
    item = stage.hose_type_item("T", pd.DataFrame(hoses), no_runs, plan)
    return {**item, "design": [max_failures, "plan", None, 1]}


def test_a_clear_ratio_decides_once_and_the_verdict_sticks():
    res = stage.decide_hose_type(odometer_item())
    v, looks = res["life_verdict"][0], pd.DataFrame(res["decision_looks"])
    assert v["verdict"] == "force longer" and v["max_failures"] == 20 and v["max_failures_from"] == "plan"
    assert looks["decides"].sum() == 1
    at = looks[looks["decides"]].iloc[0]
    assert (v["decided_at_look"], v["decided_at"], v["decided_ratio"]) == (at["look"], at["event_at"], at["life_ratio"])
    assert at["crossed"] == "force longer" and v["decided_lower"] < v["decided_ratio"] < v["decided_upper"]
    # decided at 13 failures by c_k^2 (the verdict's calibrated rule); the interval shown, Bartlett-corrected
    # (b = 1 + 3.8 / 13), still reaches ratio 1 there, and the note says so
    assert (v["decided_lower"] > 1) != ("does not show 'force longer' on its own" in v["note"])
    assert v["looks"] == len(looks) == 24 and v["failures"] == 24 and v["information_fraction"] == 1.0
    assert v["life_ratio"] == looks["life_ratio"].iloc[-1]
    late = looks[looks["failures"] > 20]
    assert not late["decides"].any() and late["note"].str.contains("no new information").all()
    # the log-scale boundaries are shown as ratios: efficacy at exp(+/- c se); the repeated interval is the
    # profile likelihood's, its ends where the look's deviance reaches c^2
    r = looks.dropna(subset=["life_ratio"]).iloc[-1]
    assert r["efficacy_upper"] == pytest.approx(math.exp(r["boundary_z"] * r["se_log_ratio"]))
    h = res["decision_look_hoses"]
    h = h[h["look"] == r["look"]]
    b = float(bartlett_factor(h["failed"].sum()))            # the deviance reaches b_k c_k^2 there
    for end in (r["rci_lower"], r["rci_upper"]):
        assert ratio_deviance(h["distance_km"].to_numpy(float), h["failed"].to_numpy(bool),
                              (h["adjustment"] == "force").to_numpy(int), end) == pytest.approx(
                                  b * r["boundary_z"] ** 2, abs=1e-6)
    assert r["rci_lower"] < r["life_ratio"] < r["rci_upper"]
    assert stage.effect_of(odometer_item())["life_ratio"] == pytest.approx(4.0, rel=0.35)


def test_no_plan_computes_every_number_and_declares_nothing():
    res = stage.decide_hose_type(odometer_item(present=False))
    v, looks = res["life_verdict"][0], pd.DataFrame(res["decision_looks"])
    assert v["verdict"] == "no plan" and "decided_at" not in v and not looks["decides"].any()
    assert "would have been declared 'force longer'" in v["note"]
    assert looks["crossed"].eq("force longer").any() and np.isfinite(v["life_ratio"])


def test_too_few_failures_give_null_estimates_with_notes():
    item = odometer_item(n=1)
    res = stage.decide_hose_type(item)
    looks = pd.DataFrame(res["decision_looks"])
    assert looks["life_ratio"].isna().all() and looks["note"].str.startswith("too few failures").all()
    assert res["life_verdict"][0]["verdict"] == "undecided" and "without an estimate" in res["life_verdict"][0]["note"]
    effect = stage.effect_of(item)
    assert math.isnan(effect["life_ratio"]) and effect["note"].startswith("too few failures")


def test_the_design_item_is_the_frozen_looks_shape_and_hoses_on_test_by_its_time():
    plan = settings(max_failures=None, margin=2.0, spending="obrien-fleming")
    hoses = odometer_item()["hoses"]   # one hose after another on one bench: one on test at a time
    frozen = {"look": 10, "event_at": hoses["ended_at"][5], "shape": 2.5, "failures": [5, 5]}
    ask = stage.design_item(plan, frozen, hoses)
    assert ask == {"margin": 2.0, "alpha": 0.05, "power": 0.8, "spending": "obrien-fleming",
                   "shape": design_shape(2.5), "hoses": 1}    # on the design grid
    assert stage.design_failures(ask)[0] == max_information(2.0, 0.05, 0.8, "obrien-fleming", design_shape(2.5),
                                                            hoses_per_adjustment=1).failures
    # hoses installed after the frozen look's time are not counted: three more on test at once later on
    later = {c: list(v) for c, v in hoses.items()}
    t_late = hoses["ended_at"][-1] + 1
    for h in ("X1", "X2", "X3"):
        for c, v in {"hose_id": h, "adjustment": "force", "distance_km": 1.0, "status": "running",
                     "distance_source": "odometer", "installed_at": t_late, "ended_at": None, "odometer_at": None}.items():
            later[c].append(v)
    assert stage.design_item(plan, frozen, later)["hoses"] == 1
    assert stage.design_item(plan, dict(frozen, event_at=t_late), later)["hoses"] == 3
    assert stage.design_item({**plan, "max_failures": 30}, frozen, hoses) is None
    # a design below the failures already seen at the frozen look ends the test at that look
    item = {"plan": plan, "hoses": hoses}
    key = __import__("json").dumps(ask, sort_keys=True)
    m, src, note, first = stage.design_of(item, frozen, {key: [7, None]})
    assert (m, src, first) == (10, "design", 10) and "the design's 7 is below the 10 failures" in note
    assert stage.design_of(item, frozen, {key: [25, None]})[0] == 25
    assert stage.design_of({"plan": {**plan, "max_failures": 30}, "hoses": hoses}, None, {}) == [30, "plan", None, 1]
    unfrozen = stage.design_of(item, {"look": None, "event_at": None, "shape": None, "failures": [4, 7]}, {})
    assert unfrozen[0] is None and unfrozen[3] is None and "so far 4 distance-set, 7 force-set" in unfrozen[2]
    assert stage.design_item(plan, {"look": None, "event_at": None, "shape": None, "failures": [4, 7]}, hoses) is None


def _logbook_fleet(tmp_path):
    """Logbook and durability runs of type T (both adjustments, a run outside every installation) and of a
    type U with force-set hoses only (no row)."""
    raw = tmp_path / "raw"
    (raw / "c").mkdir(parents=True)
    (raw / "c" / "hoses.csv").write_text(HEADER + (
        "D1,installed,2026-01-01,T,distance,4.5,,,,,\n"
        "F1,installed,2026-01-01,T,force,,866,,,,\n"
        "D1,failed,2026-01-03,,,,,rupture,,,\n"
        "F1,failed,2026-01-05,,,,,rupture,,,\n"
        "U1,installed,2026-01-01,U,force,,866,,,,\n"))
    runs = pd.DataFrame({"run_id": ["r1", "r2", "r3", "r4"], "hose_id": ["D1", "F1", "F1", "D1"],
                         "started_at": pd.to_datetime(["2026-01-01T01:00", "2026-01-01T01:00", "2026-01-04T01:00",
                                                       "2026-01-04T01:00"], utc=True),
                         "duration_h": [2.0, 2.0, 2.0, 2.0], "distance_km": [3.0, 3.0, 4.0, 9.0], "strokes": [1, 1, 1, 1]})
    hoses, _ = merge_logbooks(read_logbooks(raw)[0])
    life, _ = hose_life(hoses, runs)
    return StageContext(raw=raw, warehouse=tmp_path, runs=pd.DataFrame(),   # no plan.toml, max_failures given
                        results={"hose_life": life, "durability_runs": runs}, plan=Plan(defaults={"max_failures": 20}))


def test_the_stage_writes_the_contract_tables(tmp_path):
    ctx = _logbook_fleet(tmp_path)
    out = stage.run(ctx)
    assert list(out.tables) == list(stage.WRITES)
    assert list(out.tables["life_verdict"].columns) == stage.VERDICT_COLUMNS
    assert list(out.tables["life_effect"]["hose_type"]) == ["T"]               # U has force-set hoses only
    v = out.tables["life_verdict"].iloc[0]
    assert v["verdict"] == "no plan" and v["plan_from"] == "built-in" and v["looks"] == 2
    assert (v["max_failures"], v["information_fraction"]) == (20, 0.1)
    lh = out.tables["decision_look_hoses"]
    # r4 started after D1 failed: outside its installation, not counted (the durability stage's matching)
    assert lh[(lh["look"] == 2) & (lh["hose_id"] == "D1")]["distance_km"].item() == 3.0
    assert lh[(lh["look"] == 1) & (lh["hose_id"] == "F1")]["distance_km"].item() == 3.0
    looks = out.tables["decision_looks"]
    assert list(looks["hose_id"]) == ["D1", "F1"] and looks["event_at"].dt.tz is not None


def _durability_csv(raw, rel, hose, started):
    sim = simulate_durability(hose_id=hose, distance_m=5.0, rng=1, stroke_m=0.1, dwell_s=0.05, fs_hz=200.0)
    cols = {"t[s]": sim.data["t_s"].tolist(), "x[mm]": (sim.data["x_m"] * 1e3).round(3).tolist(),
            "p_a[Pa]": sim.data["p_a_pa"].tolist(), "p_b[Pa]": sim.data["p_b_pa"].tolist()}
    raw.csv(rel, {"kind": "durability", "rig": "plpa-1", "hose_id": hose, "started_at": started}, cols)


def test_reruns_only_on_logbooks_durability_runs_and_plan_and_full_equals_incremental(raw, warehouse, monkeypatch):
    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild

    monkeypatch.setattr(registry, "discover", lambda: [durability_runs, durability, stage])
    logbook = HEADER + ("D1,installed,2026-01-01,T,distance,4.5,,,,,\nF1,installed,2026-01-01,T,force,,866,,,,\n"
                        "D1,failed,2026-01-03,,,,,rupture,,,\n")
    raw.write("c/hoses.csv", logbook)
    _durability_csv(raw, "c/d1.csv", "D1", "2026-01-01T08:00:00")
    _durability_csv(raw, "c/f1.csv", "F1", "2026-01-01T09:00:00")
    raw.write("plan.toml", PLAN)
    ran = lambda: rebuild(raw.root, warehouse, jobs=1, report=False)  # noqa: E731
    assert "decision" in ran().stages_run
    raw.csv("c/leak.csv", {"kind": "leakage", "rig": "plpa-1", "hose_id": "F1", "chamber": "A", "adjustment": "force", "spring_force_n": 866, "started_at": "2026-01-02T08:00:00"},
            {"t[s]": [0.0, 1.0, 2.0], "p_supply[bar]": [0.0, 1.0, 1.0], "q_leak[l/min]": [0.0, 0.1, 0.1]})
    assert "decision" in ran().stages_reused                                       # a leakage run
    assert query(warehouse, "SELECT kind FROM runs WHERE run_id = 'c/leak'") == [("leakage",)]
    assert query(warehouse, "SELECT max_failures_from FROM life_verdict") == [("design",)]
    raw.write("plan.toml", PLAN + "max_failures = 20\nspending = \"pocock\"\n")
    assert "decision" in ran().stages_run                                          # the plan
    assert query(warehouse, "SELECT verdict, max_failures, max_failures_from, spending FROM life_verdict") == [
        ("undecided", 20, "plan", "pocock")]
    raw.write("c/hoses.csv", logbook + "F1,failed,2026-01-04,,,,,rupture,,,\n")
    assert "decision" in ran().stages_run                                          # the logbook
    _durability_csv(raw, "c/f2.csv", "F1", "2026-01-02T09:00:00")
    assert "decision" in ran().stages_run                                          # a durability run
    tables = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")
    before = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert before["decision_look_hoses"] and len(before["decision_looks"]) == 2
    assert "decision" in rebuild(raw.root, warehouse, jobs=1, report=False, full=True).stages_run
    assert {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables} == before


def test_the_demo_rebuild_fills_the_decision_tables(demo):
    wh = demo["warehouse"]
    life = query(wh, "SELECT hose_type, count(*) FILTER (WHERE status = 'failed' AND distance_km > 0) FROM hose_life "
                     "GROUP BY hose_type ORDER BY hose_type")
    assert [t for (t,) in query(wh, "SELECT hose_type FROM life_effect ORDER BY hose_type")] == [t for t, _ in life]
    looks = dict(query(wh, "SELECT hose_type, max(look) FROM decision_looks GROUP BY hose_type"))
    assert looks == {t: n for t, n in life if n}
    for (t, verdict, failures, n_looks) in query(wh, "SELECT hose_type, verdict, failures, looks FROM life_verdict"):
        assert failures == n_looks == looks.get(t, 0) and verdict in ("no plan", "undecided", "force longer",
                                                                      "distance longer", "no practical difference")
    assert query(wh, "SELECT count(*) FROM decision_look_hoses WHERE distance_km < 0 OR distance_km IS NULL") == [(0,)]
    # an absent text is NULL, never the text 'nan'
    assert query(wh, "SELECT count(*) FROM life_effect WHERE 'nan' IN (model, note)") == [(0,)]
    assert query(wh, "SELECT count(*) FROM decision_looks WHERE 'nan' IN (crossed, note)") == [(0,)]


def test_item_times_come_back_to_the_nanosecond():
    # int nanoseconds through a float lose up to 128 ns at today's times: the item's times must come back exact
    times = pd.Series(pd.to_datetime(["2026-03-02T10:11:12.345Z", None, "2026-03-02T10:11:12.345000129Z"], utc=True))
    back = stage._frame({"t": stage._ns_list(times)}, {"t": "time"})["t"]
    assert back.dtype == times.dtype and back.isna().tolist() == [False, True, False]
    assert (back[[0, 2]] == times[[0, 2]]).all()


@pytest.mark.parametrize("ratio, seed", [(4.0, 3), (1.0, 5), (1.6, 8)])
def test_the_looks_and_verdict_are_the_look_by_look_computation(ratio, seed):
    """Pins "no change of results" of the fast looks against the look-by-look computation they replaced (each
    look fitted alone by common_shape_fit, the likelihood check at every Wald crossing): estimates to 1e-12, the
    verdict, its look and every crossing up to it equal; after the verdict a look shows its Wald crossing,
    unchecked, and says so."""
    from analyses.decision import crossing_holds, failure_events, look_hoses, usable_hoses
    from analyses.life_effect import common_shape_fit, ratio_deviance
    from analyses.sequential import sequential_verdict

    item = odometer_item(ratio=ratio, n=14, seed=seed, max_failures=24)
    res = stage.decide_hose_type(item)
    looks, v = pd.DataFrame(res["decision_looks"]), res["life_verdict"][0]
    hoses = usable_hoses(stage._frame(item["hoses"], stage.HOSE_SPEC))
    events = failure_events(hoses)
    in_looks = look_hoses(hoses, stage._frame(item["runs"], stage.RUN_SPEC), events)
    x, f = in_looks["distance_km"].to_numpy(float), in_looks["failed"].to_numpy(bool)
    g, number = (in_looks["adjustment"] == "force").to_numpy(int), in_looks["look"].to_numpy(int)
    fits = [common_shape_fit(x[number == k], f[number == k], g[number == k]) for k in events["look"]]
    lr = np.array([ft.log_ratio if ft.note is None else np.nan for ft in fits])
    se = np.array([ft.se_log_ratio if ft.note is None else np.nan for ft in fits])
    np.testing.assert_allclose(np.log(looks["life_ratio"]), lr, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(looks["se_log_ratio"], se, rtol=1e-12)
    t = looks["failures"].to_numpy(float) / 24

    def every_look(i, crossed, c):
        m = number == events["look"].iloc[i]
        return crossing_holds(lambda r: ratio_deviance(x[m], f[m], g[m], r), crossed, c, 1.25)

    ref = sequential_verdict(lr, se, t, 1.25, 0.05, "pocock", confirm=every_look)
    wald = sequential_verdict(lr, se, t, 1.25, 0.05, "pocock")
    assert v["verdict"] == ref.verdict
    assert v.get("decided_at_look") == (None if ref.decided_at is None else ref.decided_at + 1)
    crossed = [c if isinstance(c, str) else "" for c in looks["crossed"]]
    upto = len(crossed) if ref.decided_at is None else ref.decided_at + 1
    assert crossed[:upto] == list(ref.crossed[:upto])
    assert crossed[upto:] == list(wald.crossed[upto:])
    after = looks.iloc[upto:]
    assert after["note"].fillna("").str.contains(stage.AFTER_VERDICT).tolist() == [bool(c) for c in crossed[upto:]]
    if ratio == 4.0:                                  # a verdict, and crossings after it
        assert ref.decided_at is not None and any(crossed[upto:])


def _campaign_lines(phase: int) -> str:
    """Odometer-only hoses of type T. Phase 1, installed on 2026-01-01: eight distance-set hoses of tight lives
    (5-15 km) failing on Jan 2-9 (looks 1-8), then eight force-set ones (20-60 km) on Jan 10-17 (looks 9-16).
    Phase 2, installed on Feb 1 (after every phase-1 event: no past look holds them): six of each, lives spread
    wide (a much smaller Weibull shape), failing in March."""
    lines = []
    if phase == 1:
        lives = {"distance": [5.0, 7.0, 8.0, 9.0, 10.0, 11.0, 13.0, 15.0], "force": [20, 28, 33, 38, 42, 46, 52, 60]}
        day = 2
        for adj, km in lives.items():
            for i, x in enumerate(km):
                h = f"{adj[0].upper()}{i}"
                lines += [f"{h},installed,2026-01-01,T,{adj},4.5,866,,,,",
                          f"{h},failed,2026-01-{day:02d},,,,,rupture,,{x},"]
                day += 1
        return "\n".join(lines) + "\n"
    lives = {"distance": [1.0, 3.0, 25.0, 0.5, 18.0, 6.0], "force": [5.0, 90.0, 2.0, 150.0, 30.0, 60.0]}
    for k, (adj, km) in enumerate(lives.items()):
        for i, x in enumerate(km):
            h = f"{adj[0].upper()}{10 + i}"
            lines += [f"{h},installed,2026-02-01,T,{adj},4.5,866,,,,",
                      f"{h},failed,2026-03-{1 + 2 * i + k:02d},,,,,rupture,,{x},"]
    return "\n".join(lines) + "\n"


def test_an_unset_max_failures_is_frozen_at_a_look_and_later_failures_move_no_past_look(raw, warehouse, monkeypatch):
    """Night N: 16 failures; the first look with FEW_FAILURES / 2 = 5 of each adjustment is look 13 (eight
    distance-set failures first, the fifth force-set one is the 13th failure): max_failures is designed there
    and kept. Night N+1 appends twelve failures of a much smaller shape, whose design would differ: the
    maximum, the verdict and every look of night N are unchanged, and --full equals incremental."""
    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild
    from analyses.sequential import design_for

    monkeypatch.setattr(registry, "discover", lambda: [durability_runs, durability, stage])
    raw.write("c/hoses.csv", HEADER + _campaign_lines(1))
    raw.write("plan.toml", PLAN)
    ran = lambda **kw: rebuild(raw.root, warehouse, jobs=1, report=False, **kw)  # noqa: E731
    assert "decision" in ran().stages_run
    looks_sql = "SELECT * EXCLUDE (note) FROM decision_looks WHERE look <= 16 ORDER BY look"
    v1 = query(warehouse, "SELECT verdict, max_failures, decided_at_look, decided_ratio, note FROM life_verdict")[0]
    looks1 = query(warehouse, looks_sql)
    shape1 = query(warehouse, "SELECT shape FROM life_effect")[0][0]
    assert v1[0] == "force longer" and v1[2] >= 13 and "max_failures frozen at look 13 (2026-01-14" in v1[4]
    assert query(warehouse, "SELECT look FROM decision_looks WHERE decides") == [(v1[2],)]
    early = query(warehouse, "SELECT count(*), count(crossed), count(rci_lower) FROM decision_looks WHERE look < 13")
    assert early == [(12, 0, 0)]       # before the freeze: shown, no boundary crossed, none decides
    assert query(warehouse, "SELECT count(*) FROM decision_looks WHERE look < 13 AND note LIKE '%before look 13%'"
                 ) == [(12,)]
    raw.write("c/hoses.csv", HEADER + _campaign_lines(1) + _campaign_lines(2))
    assert "decision" in ran().stages_run
    v2 = query(warehouse, "SELECT verdict, max_failures, decided_at_look, decided_ratio, note FROM life_verdict")[0]
    shape2 = query(warehouse, "SELECT shape FROM life_effect")[0][0]
    assert design_shape(shape2) != design_shape(shape1)
    moved = design_for(2.0, 0.05, 0.8, "obrien-fleming", shape2, 8).failures    # what a refitted design would say
    assert moved != v1[1] and v2[:4] == v1[:4] and query(warehouse, looks_sql) == looks1
    assert query(warehouse, "SELECT count(*) FROM decision_looks") == [(28,)]
    tables = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")
    before = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert "decision" in ran(full=True).stages_run
    assert {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables} == before


def test_with_max_failures_in_the_plan_the_tables_are_bit_identical_to_before_the_freeze(raw, warehouse, monkeypatch):
    """The campaign of the test above with max_failures = 20 in the plan: the four tables' rows (their repr,
    sha256) are the ones the stage wrote before max_failures was frozen (commit b84e19a, the same
    environment): the freeze changes nothing when the plan sets the maximum. Updated in session 20 for
    the repeated intervals by the profile likelihood (rci_*, decided_lower/upper) and the looks' fits summed
    in order (life_ratio, se_log_ratio and the boundaries on the ratio scale within 3 ulp; the other
    columns and tables equal, compared column by column against a077062). Updated in session 21 for the
    Bartlett-corrected repeated intervals: only rci_lower/upper (both tables) and decided_lower/upper
    changed, every other column and table equal (compared column by column against 0a3df02). Session 22: a
    new machine (AVX-512 FP16, a fresh install of the same pinned-by-range libraries) moved the last bits of
    life_effect, life_verdict and decision_looks with the code unchanged, so floats are digested at 10
    significant digits; the digests were recorded on 8491dfc's code."""
    import hashlib

    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild

    monkeypatch.setattr(registry, "discover", lambda: [durability_runs, durability, stage])
    raw.write("c/hoses.csv", HEADER + _campaign_lines(1) + _campaign_lines(2))
    raw.write("plan.toml", "[defaults]\nmargin = 2.0\nmax_failures = 20\nspending = \"pocock\"\n")
    rebuild(raw.root, warehouse, jobs=1, report=False)
    def text(v):    # times as ISO text: the repr of their zone depends on the machine's zoneinfo; floats to
        if hasattr(v, "isoformat"):    # 10 significant digits: their last bits follow the machine's SIMD
            return v.isoformat()       # paths and library builds (session 22's machine moved them)
        return f"{v:.10g}" if isinstance(v, float) else v

    def digest(rows):
        return hashlib.sha256(repr([tuple(text(v) for v in r) for r in rows]).encode()).hexdigest()[:16]

    digests = {t: digest(query(warehouse, f"SELECT * FROM {t} ORDER BY ALL"))
               for t in ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")}
    assert digests == {"life_effect": "9b239bda611b8088", "life_verdict": "cb6242c73098edb0",
                       "decision_looks": "5a649b762d04532a", "decision_look_hoses": "df8b677beec79410"}


def test_a_frozen_look_whose_design_does_not_exist_leaves_max_failures_null_with_the_reason():
    from pipeline.stages.decision import design_failures, design_of
    steep = {"margin": 2.0, "alpha": 0.05, "power": 0.8, "spending": "obrien-fleming", "shape": 14.9, "hoses": 8}
    failures, why = design_failures(steep)
    assert failures is None and why.startswith("no sequential design at shape 14.9 with 8 hose(s) on test")
    plan = {"max_failures": None, "margin": 2.0, "alpha": 0.05, "power": 0.8, "spending": "obrien-fleming"}
    frozen = {"look": 11, "event_at": 1.7e18, "shape": 14.9, "failures": (6, 5)}
    import json
    from pipeline.stages.decision import design_item
    hoses = {"installed_at": [], "ended_at": [], "adjustment": []}
    ask = design_item(plan, frozen, hoses)
    got = design_of({"plan": plan, "hoses": hoses}, frozen, {json.dumps(ask, sort_keys=True): [None, why]})
    assert got[0] is None and got[1] == "design" and got[3] is None
    assert got[2].startswith("max_failures not frozen at look 11 (") and got[2].endswith(f"{why}; max_failures in plan.toml lets the test decide")


def _designed_fleet(tmp_path, types=5, seed=11):
    """``types`` hose types of varied shape and size, odometer-only lives in waves on benches, some running at
    the stop (read then), ``max_failures`` left to the design (margin 2): each type froze its own design."""
    rng = np.random.default_rng(seed)
    raw, lines, start = tmp_path / "raw", [], pd.Timestamp("2026-01-05T08:00", tz="UTC")
    for t in range(types):
        n, shape = int(rng.integers(8, 14)), float(rng.uniform(1.5, 3.5))
        life = np.repeat([1.0, 1.6], n) * 40.0 * rng.weibull(shape, 2 * n)
        installed = rng.integers(0, 20, 2 * n) * 24.0 + 0.0
        stop = np.sort(installed + life / 0.625)[min(15, 2 * n - 1)] + 1.0
        for i in range(2 * n):
            hid, adj = f"T{t}-{i:02d}", ("distance", "force")[i >= n]
            lines.append(f"{hid},installed,{(start + pd.Timedelta(hours=installed[i])).isoformat()},TYPE {t},{adj},,,,,,\n")
            end = installed[i] + life[i] / 0.625
            if end <= stop:
                lines.append(f"{hid},failed,{(start + pd.Timedelta(hours=end)).isoformat()},,,,,rupture,,{life[i]:.3f},\n")
            elif stop > installed[i]:
                km = (stop - installed[i]) * 0.625
                lines.append(f"{hid},removed,{(start + pd.Timedelta(hours=stop)).isoformat()},,,,,,,{km:.3f},odometer read\n")
    (raw / "c").mkdir(parents=True)
    (raw / "c" / "hoses.csv").write_text(HEADER + "".join(lines))
    hoses, problems = merge_logbooks(read_logbooks(raw)[0])
    assert not problems
    no_runs = pd.DataFrame(columns=["run_id", "hose_id", "started_at", "duration_h", "distance_km", "strokes"])
    return raw, hose_life(hoses, no_runs)[0], no_runs


def test_the_tables_of_a_designed_fleet_do_not_depend_on_what_the_process_computed_before(tmp_path):
    """Designs shared between hose types and kept in a process (boundaries, rare-failure powers), two worker
    processes, the logbooks not read when no run is to be matched: the tables are bit for bit those of each
    hose type computed alone in a cold process, its frozen look found by the separate pass (freeze_of)."""
    from analyses import sequential

    raw, life, runs = _designed_fleet(tmp_path)
    plan = Plan(present=True, defaults={"margin": 2.0})
    ctx = StageContext(raw=raw, warehouse=tmp_path, runs=pd.DataFrame(), jobs=2, plan=plan,
                       results={"hose_life": life, "durability_runs": runs})
    sequential.clear_caches()
    shared = stage.run(ctx)
    assert shared.tables["life_verdict"]["max_failures_from"].eq("design").all()
    assert shared.tables["life_verdict"]["max_failures"].notna().sum() >= 3     # designs frozen and used
    looks, verdicts, look_hoses = [], [], []
    for item in stage.hose_type_items(ctx):
        sequential.clear_caches()
        frozen = stage.freeze_of(item)
        ask = stage.design_item(item["plan"], frozen, item["hoses"])
        designed = {} if ask is None else {json.dumps(ask, sort_keys=True): stage.design_failures(ask)}
        res = stage.decide_hose_type({**item, "design": stage.design_of(item, frozen, designed)})
        looks += res["decision_looks"]
        verdicts += res["life_verdict"]
        look_hoses.append(res["decision_look_hoses"])
    alone = stage.run(StageContext(raw=raw, warehouse=tmp_path, runs=pd.DataFrame(), jobs=1, plan=plan,
                                   results={"hose_life": life, "durability_runs": runs}))
    for name, table in shared.tables.items():
        pd.testing.assert_frame_equal(table, alone.tables[name], check_exact=True)
    pd.testing.assert_frame_equal(shared.tables["decision_looks"].reset_index(drop=True),
                                  stage._typed(looks, stage.LOOK_COLUMNS, ints=("look", "failures", "n_hoses"),
                                               times=("event_at",), bools=("decides",)), check_exact=True)
    one_by_one = stage._typed(verdicts, stage.VERDICT_COLUMNS, ints=("max_failures", "failures", "looks",
                                                                     "decided_at_look"), times=("decided_at",))
    pd.testing.assert_frame_equal(shared.tables["life_verdict"], one_by_one, check_exact=True)
    sequential.clear_caches()


def test_effect_of_reads_the_item_lists_as_life_effect_of_the_positive_lives():
    """effect_of takes the item's lists directly: the row is life_effect's of the hoses with a positive
    distance (NaN and 0 left out, a status other than 'failed' a suspension); an adjustment the fit does not
    know is refused as before."""
    from analyses.life_effect import life_effect

    rng = np.random.default_rng(1)
    n = 12
    hoses = {"adjustment": ["distance"] * n + ["force"] * n, "distance_km": list(100.0 * rng.weibull(2.0, 2 * n)),
             "status": ["failed", "running"] * n}
    hoses["distance_km"][3], hoses["distance_km"][4], hoses["status"][5] = math.nan, 0.0, None
    row = stage.effect_of({"hose_type": "T", "hoses": hoses, "plan": {"confidence": 0.9, "alpha": 0.05}})
    keep = [i for i, d in enumerate(hoses["distance_km"]) if d > 0]
    ref = life_effect(np.array(hoses["distance_km"])[keep], np.array([hoses["status"][i] == "failed" for i in keep]),
                      np.array([int(hoses["adjustment"][i] == "force") for i in keep]), confidence=0.9, alpha=0.05)
    assert row["n_distance"] == 10 and row["n_failed_distance"] == 5 and row["hose_type"] == "T"
    assert all(row[k] == getattr(ref, k) for k in ("shape", "life_ratio", "life_ratio_lower", "p_value", "model"))
    hoses["adjustment"][7] = None
    with pytest.raises(ValueError, match="group must be 0"):
        stage.effect_of({"hose_type": "T", "hoses": hoses, "plan": {"confidence": 0.9, "alpha": 0.05}})


def test_the_designs_file_is_written_once_then_read_and_a_damaged_stale_or_hostile_one_is_ignored(
        tmp_path, designs_table, monkeypatch):
    """keep_designs: the even designs computed once and written under the warehouse, read (not computed) by a
    cold process after; a file that is not the arrays of that form (garbage, truncated, a NaN boundary, a
    pickle, a symlink) is never used: they are computed again and the file rewritten; another designs file
    (other settings, code or libraries: another name) is deleted, anything else in the folder kept."""
    from analyses import sequential
    from analyses.sequential_table import holds_table

    computed = []
    monkeypatch.setattr(stage, "design_table", lambda a, s: computed.append((a, s)) or designs_table)
    items = [{"plan": {"alpha": 0.05, "spending": "obrien-fleming", "max_failures": None}},
             {"plan": {"alpha": 0.01, "spending": "pocock", "max_failures": 20}}]     # the plan's: no design
    stale = tmp_path / stage.DESIGNS_DIR / ("designs-" + "0" * 32 + ".npz")
    stale.parent.mkdir()
    stale.write_bytes(b"old")
    (tmp_path / stage.DESIGNS_DIR / "notes.txt").write_text("mine")
    sequential.clear_caches()
    path = Path(stage.keep_designs(tmp_path, items)[(0.05, "obrien-fleming")])
    assert computed == [(0.05, "obrien-fleming")] and path.is_file() and path.parent == stale.parent
    assert not stale.exists() and (tmp_path / stage.DESIGNS_DIR / "notes.txt").read_text() == "mine"
    assert path == stage.designs_path(tmp_path, 0.05, "obrien-fleming") != stage.designs_path(tmp_path, 0.05, "pocock")
    good = path.read_bytes()
    sequential.clear_caches()
    assert stage.keep_designs(tmp_path, items) and len(computed) == 1 and holds_table(0.05, "obrien-fleming")

    nan = dict(designs_table)
    nan["c_30"] = np.where(np.arange(30) == 29, np.nan, designs_table["c_30"])
    hostile = {"garbage": b"not an npz", "truncated": good[: len(good) // 2], "nan": nan,
               "pickle": {**designs_table, "c_30": np.array([object()] * 30, dtype=object)}}
    for name, content in hostile.items():
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            with open(path, "wb") as fh:
                np.savez(fh, **content)
        sequential.clear_caches()
        assert not stage.use_designs(path, 0.05, "obrien-fleming"), name
        stage.keep_designs(tmp_path, items)
        assert computed[-1] == (0.05, "obrien-fleming") and path.read_bytes() == good, name
    elsewhere = tmp_path / "elsewhere.npz"
    elsewhere.write_bytes(good)
    path.unlink()
    path.symlink_to(elsewhere)
    sequential.clear_caches()
    assert not stage.use_designs(path, 0.05, "obrien-fleming")          # a symlink is not followed
    stage.keep_designs(tmp_path, items)
    assert len(computed) == 2 + len(hostile) and not path.is_symlink() and path.read_bytes() == good
    sequential.clear_caches()


def test_a_rebuild_keeps_the_designs_in_the_warehouse_and_reading_them_gives_the_same_tables(tmp_path, monkeypatch):
    """The first rebuild of a designed fleet computes the even designs and writes them under the warehouse;
    a cold process that reads them (a full rebuild after the caches are cleared) gives the same tables."""
    from analyses import sequential
    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild

    monkeypatch.setattr(registry, "discover", lambda: [durability_runs, durability, stage])
    raw = _designed_fleet(tmp_path, types=3)[0]
    (raw / "plan.toml").write_text(PLAN)
    warehouse = tmp_path / "wh"
    tables = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")
    sequential.clear_caches()
    assert "decision" in rebuild(raw, warehouse, jobs=1, report=False).stages_run
    files = list((warehouse / stage.DESIGNS_DIR).iterdir())
    assert [f.name for f in files] == [stage.designs_path(warehouse, 0.05, "obrien-fleming").name]
    first = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert any(r is not None for r in query(warehouse, "SELECT max_failures FROM life_verdict"))
    sequential.clear_caches()
    read = []
    monkeypatch.setattr(stage, "design_table", lambda *a: read.append(a) or {})   # computed again: nothing written
    assert "decision" in rebuild(raw, warehouse, jobs=1, report=False, full=True).stages_run
    assert not read and {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables} == first
    sequential.clear_caches()


def test_the_life_effect_item_is_what_effect_of_reads_and_a_power_change_leaves_it_alone():
    """effect_of on effect_item's few columns is its row on the whole item; a plan change of a key it does not
    read (power, margin, max_failures) gives the same item (the same memo key), confidence or alpha another."""
    item = odometer_item()
    small = stage.effect_item(item)
    assert stage.effect_of(small) == stage.effect_of(item)
    assert set(small["hoses"]) == {"adjustment", "distance_km", "status"}
    other = {**item, "plan": {**item["plan"], "power": 0.81, "margin": 2.0, "max_failures": None}}
    assert stage.effect_item(other) == small
    assert stage.effect_item({**item, "plan": {**item["plan"], "confidence": 0.95}}) != small


def test_a_designs_folder_that_is_a_symlink_is_neither_read_nor_written(tmp_path, designs_table, monkeypatch):
    from analyses import sequential

    computed = []
    monkeypatch.setattr(stage, "design_table", lambda a, s: computed.append((a, s)) or designs_table)
    items = [{"plan": {"alpha": 0.05, "spending": "obrien-fleming", "max_failures": None}}]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    sequential.clear_caches()
    path = Path(stage.keep_designs(elsewhere, items)[(0.05, "obrien-fleming")])      # a valid file there
    (tmp_path / "wh").mkdir()
    (tmp_path / "wh" / stage.DESIGNS_DIR).symlink_to(elsewhere / stage.DESIGNS_DIR)
    sequential.clear_caches()
    stage.keep_designs(tmp_path / "wh", items)
    assert len(computed) == 2 and [p.name for p in (elsewhere / stage.DESIGNS_DIR).iterdir()] == [path.name]
    sequential.clear_caches()
