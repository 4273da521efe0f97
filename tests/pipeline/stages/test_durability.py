"""The durability stage: per-run distance from simulated runs, hose life across campaigns, service life,
leak growth, figures, and the warehouse tables and views after a rebuild."""
import math

import duckdb
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.simulator import simulate_durability
from pipeline.stages import StageContext
from pipeline.stages import durability as stage
from pipeline.stages import durability_runs as runs_stage

HEADER = "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,wall_thickness_mm,distance_km,notes\n"


def noisy(sim, seed):
    """The simulator's run with extra encoder jitter (re-quantised to 5 um) on top of its pressure noise."""
    rng = np.random.default_rng(seed)
    d = sim.data.copy()
    d["x_m"] = np.round((d["x_m"] + rng.normal(0, 3e-6, len(d))) / 5e-6) * 5e-6
    return d


class Bench:
    """A warehouse folder with samples Parquet, runs rows and a raw tree, for a StageContext."""

    def __init__(self, tmp_path):
        self.raw = tmp_path / "raw"
        self.wh = tmp_path / "wh"
        self.raw.mkdir()
        self.rows = []
        self.truth = {}

    def durability(self, run_id, campaign, started_at, hose_id, distance_m, seed, stroke_m=0.25, **kw):
        sim = simulate_durability(hose_id=hose_id, distance_m=distance_m, rng=seed, stroke_m=stroke_m, dwell_s=0.1, **kw)
        self.truth[run_id] = sim.truth
        self._write(run_id, "durability", campaign, started_at, {**sim.metadata, "hose_id": hose_id}, noisy(sim, seed))

    def leakage(self, run_id, campaign, started_at, hose_id):
        self._write(run_id, "leakage", campaign, started_at, {"hose_id": hose_id, "chamber": "A"},
                    pd.DataFrame({"t_s": [0.0, 1.0], "p_supply_pa": [0.0, 1e5], "q_leak_kg_s": [0.0, 0.0]}))

    def _write(self, run_id, kind, campaign, started_at, params, data):
        rel = f"samples/kind={kind}/campaign={campaign}/{run_id.replace('/', '_')}.parquet"
        path = self.wh / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pandas(data.assign(run_id=run_id), preserve_index=False), path)
        self.rows.append({"run_id": run_id, "kind": kind, "campaign": campaign,
                          "started_at": pd.Timestamp(started_at, tz="UTC"), "params": params, "samples_path": rel})

    def logbook(self, rel, text):
        p = self.raw / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(HEADER + text)

    def ctx(self, results=None):
        return StageContext(raw=self.raw, warehouse=self.wh, runs=pd.DataFrame(self.rows), results=results or {})


def run_stages(ctx):
    """The ``durability_runs`` stage, then ``durability`` on its tables, as a rebuild runs them: one output."""
    first = runs_stage.run(ctx)
    ctx.results = {**ctx.results, **first.tables}
    out = stage.run(ctx)
    out.tables = {**first.tables, **out.tables}
    out.warnings = {rid: first.warnings.get(rid, []) + out.warnings.get(rid, [])
                    for rid in {**first.warnings, **out.warnings}}
    return out


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Two campaigns: force-set hoses F1 (fails in c2) and F2 (removed); distance-set D1 (removed in c2),
    D2 (failed, odometer only), D3 (installed and failed in c2); durability runs from the simulator."""
    b = Bench(tmp_path_factory.mktemp("fleet"))
    b.logbook("c1/hoses.csv",
              "F1,installed,2026-01-01T08:00,FLEXIGOM AIR,force,,866,,,,\n"
              "F2,installed,2026-01-01T08:00,FLEXIGOM AIR,force,,866,,,,\n"
              "D1,installed,2026-01-01T08:00,FLEXIGOM AIR,distance,4.5,,,,,\n"
              "D2,installed,2025-06-01T08:00,FLEXIGOM AIR,distance,4.5,,,,,\n"
              "D2,failed,2025-07-01T08:00,,,,,rupture,,0.12,before runs were logged\n"
              "F2,removed,2026-01-04T08:00,,,,,,,,end of test\n")
    b.logbook("c2/hoses.csv",
              "F1,failed,2026-02-03T08:00,,,,,rupture,,,\n"
              "D1,inspected,2026-02-01T08:00,,,,,,2.7,,\n"
              "D1,removed,2026-02-05T08:00,,,,,,,0.5,\n"              # odometer disagrees with the runs
              "D3,installed,2026-02-01T08:00,FLEXIGOM AIR,distance,4.5,,,,,\n"
              "D3,failed,2026-02-04T08:00,,,,,leakage,,,\n"
              "D4,failed,2026-01-01T08:00,,,,,rupture,,,\n")          # line 7: failed, never installed
    b.durability("c1/f1_a", "c1", "2026-01-02T08:00", "F1", 60.0, 1)
    b.durability("c1/f1_b", "c1", "2026-01-03T08:00", "F1", 45.0, 2, fs_hz=2000.0)
    b.durability("c1/f2_a", "c1", "2026-01-02T09:00", "F2", 30.0, 3)
    b.durability("c1/d1_a", "c1", "2026-01-02T10:00", "D1", 50.0, 4)
    b.durability("c2/f1_c", "c2", "2026-02-02T08:00", "F1", 40.0, 5)
    b.durability("c2/f1_late", "c2", "2026-02-10T08:00", "F1", 5.0, 6)     # after its failure: not counted
    b.durability("c2/d3_a", "c2", "2026-02-02T08:00", "D3", 35.0, 7)
    b.durability("c2/d3_b", "c2", "2026-02-03T08:00", "D3", 25.0, 8)
    b.leakage("c2/leak_d3_1", "c2", "2026-02-02T12:00", "D3")
    b.leakage("c2/leak_d3_2", "c2", "2026-02-03T12:00", "D3")
    leak = pd.DataFrame({"run_id": ["c2/leak_d3_1", "c2/leak_d3_1", "c2/leak_d3_2", "c2/leak_d3_2"],
                         "hose_id": ["D3"] * 4, "chamber": ["A"] * 4, "adjustment": ["distance"] * 4,
                         "z_rollers_mm": [4.5] * 4, "spring_force_n": [None] * 4, "pressure_bar": [5.0, 6.0, 5.0, 6.0],
                         "leak_l_min": [0.0, 0.2, 0.1, 0.5]})
    out = run_stages(b.ctx({"leakage_map": leak}))
    return b, out


def test_distances_recovered_within_half_a_percent(fleet):
    b, out = fleet
    runs = out.tables["durability_runs"].set_index("run_id")
    assert sorted(runs.index) == sorted(r for r in b.truth)
    for rid, truth in b.truth.items():
        assert runs.loc[rid, "distance_km"] == pytest.approx(truth["distance_km"], rel=0.005), rid
        assert runs.loc[rid, "strokes"] == truth["strokes"], rid
        assert runs.loc[rid, "duration_h"] == pytest.approx(truth["duration_s"] / 3600, rel=1e-3)
        assert runs.loc[rid, "hose_id"] == truth["hose_id"]
    # the deadband is 20 floors of the 5 um encoder (estimated at rest), as the bench's 0.1 mm
    assert runs["deadband_mm"].to_numpy() == pytest.approx(0.1, rel=0.05)
    assert runs["note"].isna().all()
    strokes = out.tables["durability_strokes"]
    f1a = strokes[strokes["run_id"] == "c1/f1_a"]
    assert len(f1a) == b.truth["c1/f1_a"]["strokes"]
    assert f1a["length_mm"].to_numpy() == pytest.approx(250.0, abs=0.05)
    assert (f1a["dp_friction_bar"] > 0).all() and (f1a["friction_n"] > 0).all()
    assert set(f1a["direction"]) == {1, -1}


def test_hose_life_status_and_run_counts_across_campaigns(fleet):
    b, out = fleet
    life = out.tables["hose_life"].set_index("hose_id")
    t = {rid: tr["distance_km"] for rid, tr in b.truth.items()}
    assert list(life.index) == ["D1", "D2", "D3", "F1", "F2"]
    assert life["status"].to_dict() == {"D1": "removed", "D2": "failed", "D3": "failed", "F1": "failed",
                                        "F2": "removed"}
    assert life["n_runs"].to_dict() == {"D1": 1, "D2": 0, "D3": 2, "F1": 3, "F2": 1}
    assert life.loc["F1", "distance_km"] == pytest.approx(t["c1/f1_a"] + t["c1/f1_b"] + t["c2/f1_c"], rel=0.005)
    assert life.loc["F1", "strokes"] == sum(b.truth[r]["strokes"] for r in ("c1/f1_a", "c1/f1_b", "c2/f1_c"))
    assert life.loc["F1", "campaigns"] == ["c1", "c2"] and life.loc["F1", "failure_mode"] == "rupture"
    assert life.loc["D3", "failure_mode"] == "leakage"
    assert (life.loc["D2", "distance_km"], life.loc["D2", "distance_source"]) == (0.12, "odometer")
    assert life.loc["D1", "wall_thickness_mm"] == 2.7
    assert any("odometer 0.500 km" in w for w in life.loc["D1", "warnings"])
    assert life.loc["F1", "warnings"] == []
    # the run after F1's failure is reported, not counted
    assert any("outside every installation" in w for w in out.warnings["c2/f1_late"])
    # the nonsense logbook row is quarantined with its line; the others count
    assert [(p.source_path, p.line, p.stage) for p in out.problems] == [("c2/hoses.csv", 7, "logbook")]
    assert "before it was installed" in out.problems[0].error


def test_service_life_nulls_with_one_failure_and_bracketing_bounds(fleet):
    _, out = fleet
    sl = out.tables["service_life"].set_index("adjustment")
    assert sl.loc["force", "n_hoses"] == 2 and sl.loc["force", "n_failed"] == 1
    assert sl.loc[["force"], ["weibull_shape", "weibull_scale_km", "b10_km", "b10_lower_km", "b10_upper_km"]].isna().all().all()
    assert sl.loc["force", "note"] == "too few failures: 1 < 2" and pd.isna(sl.loc["distance", "note"])
    d = sl.loc["distance"]
    assert (d["n_hoses"], d["n_failed"], d["confidence"]) == (3, 2, 0.90)
    assert d["b10_lower_km"] < d["b10_km"] < d["b10_upper_km"]
    assert d["weibull_shape"] > 0 and d["weibull_scale_km"] > 0
    km = out.tables["hose_survival"]
    assert set(km["adjustment"]) == {"force", "distance"}
    force = km[km["adjustment"] == "force"].sort_values("distance_km")
    # F2 removed first (censored), then F1 fails with one hose at risk
    assert force["n_censored"].tolist() == [1, 0] and force["survival"].tolist() == [1.0, 0.0]
    test = out.tables["service_life_test"]
    assert len(test) == 1 and math.isnan(test["p_value"].iloc[0])      # force has a single failure
    assert test["n_force"].iloc[0] == 2 and test["n_distance"].iloc[0] == 3


def test_leak_growth_placed_at_the_hose_distance(fleet):
    b, out = fleet
    g = out.tables["hose_leak_growth"]
    assert len(g) == 4 and set(g["hose_id"]) == {"D3"}
    first = g[g["run_id"] == "c2/leak_d3_1"]["distance_km"].unique()
    second = g[g["run_id"] == "c2/leak_d3_2"]["distance_km"].unique()
    assert first == pytest.approx([b.truth["c2/d3_a"]["distance_km"]], rel=0.005)
    assert second == pytest.approx([b.truth["c2/d3_a"]["distance_km"] + b.truth["c2/d3_b"]["distance_km"]], rel=0.005)
    assert set(out.figures) == {"weibull_probability", "kaplan_meier", "hose_distance", "leak_growth"}


def test_without_leakage_map_no_growth_rows_and_broken_run_gives_nulls(tmp_path):
    b = Bench(tmp_path)
    b.logbook("c/hoses.csv", "H,installed,2026-01-01,T,force,,866,,,,\n")
    b.durability("c/ok", "c", "2026-01-02", "H", 10.0, 1)
    b.durability("c/broken", "c", "2026-01-03", "H", 10.0, 2)
    (b.wh / b.rows[-1]["samples_path"]).write_bytes(b"not parquet")
    out = run_stages(b.ctx())
    runs = out.tables["durability_runs"].set_index("run_id")
    assert pd.isna(runs.loc["c/broken", "distance_km"]) and pd.isna(runs.loc["c/broken", "strokes"])
    assert "cannot analyse" in out.warnings["c/broken"][0]
    assert out.tables["hose_leak_growth"].empty
    life = out.tables["hose_life"].iloc[0]
    assert life["status"] == "running" and life["n_runs"] == 2
    assert any("could not be analysed" in w for w in life["warnings"])
    assert out.tables["service_life"]["weibull_shape"].isna().all()


def test_rebuild_fills_tables_and_views(raw, warehouse):
    from pipeline.rebuild.flow import rebuild

    sim = simulate_durability(hose_id="H1", distance_m=5.0, rng=1, stroke_m=0.1, dwell_s=0.05, fs_hz=200.0)
    cols = {"t[s]": sim.data["t_s"].tolist(), "x[mm]": (sim.data["x_m"] * 1e3).round(3).tolist(),
            "p_a[Pa]": sim.data["p_a_pa"].tolist(), "p_b[Pa]": sim.data["p_b_pa"].tolist()}
    meta = {"kind": "durability", "rig": "plpa-1", "hose_id": "H1", "hose_area_m2": 4.9e-4}
    raw.csv("c1/d1.csv", {**meta, "started_at": "2026-01-02T08:00:00"}, cols)
    raw.csv("c2/d2.csv", {**meta, "started_at": "2026-01-05T08:00:00"}, cols)
    raw.write("c1/hoses.csv", HEADER + "H1,installed,2026-01-01T00:00,FLEX,force,,866,,,,\n"
                                       "H1,failed,2025-01-01T00:00,,,,,rupture,,,\n")
    raw.write("c2/hoses.csv", HEADER + "H1,failed,2026-01-06T00:00,,,,,rupture,,,\n")
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == 1                                   # the bad logbook row
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"), read_only=True)
    try:
        q = lambda sql: con.execute(sql).fetchall()  # noqa: E731
        assert q("SELECT source_path, line, stage FROM quarantine") == [("c1/hoses.csv", 3, "logbook")]
        got = q("SELECT run_id, strokes, distance_km FROM durability_runs ORDER BY run_id")
        assert [(r[0], r[1]) for r in got] == [("c1/d1", 50), ("c2/d2", 50)]
        assert got[0][2] == pytest.approx(0.005, rel=0.005)
        assert q("SELECT hose_id, status, n_runs, campaigns FROM hose_life") == [("H1", "failed", 2, ["c1", "c2"])]
        assert q("SELECT count(*) FROM durability_strokes") == [(100,)]
        assert q("SELECT n_hoses, n_failed, weibull_shape FROM service_life") == [(1, 1, None)]
        assert q("SELECT kind, run_id FROM latest_results") == [("durability", "c2/d2")]
        assert q("SELECT hose_id, n_runs, n_durability_runs, status FROM runs_per_hose") == [("H1", 2, 2, "failed")]
        assert q("SELECT run_id, hose_km_before FROM hose_runs ORDER BY started_at")[1][1] == pytest.approx(got[0][2])
        assert q("SELECT campaign, n_runs, n_quarantined, n_hoses FROM campaign_summary") == [
            ("c1", 1, 1, 1), ("c2", 1, 0, 1)]
        assert {r[0] for r in q("SELECT name FROM figures WHERE stage = 'durability'")} >= {"hose_distance"}
    finally:
        con.close()


def test_simulated_campaigns_hose_life_matches_truth(tmp_path, monkeypatch):
    """The simulator's campaign writer (hoses.csv in two campaigns, odometer-only hoses, a hose that
    spans both campaigns, TDMS/CSV/... durability runs): every hose's status, run count, distance,
    strokes and campaigns as the simulator drew them. Only this stage runs (others are not under test)."""
    import json

    from pipeline import stages as registry
    from pipeline.rebuild.flow import rebuild
    from pipeline.simulator.campaign import simulate_campaign

    raw = tmp_path / "raw"
    simulate_campaign(raw, seed=5, profile="mini")
    truth = json.loads((raw / "truth.json").read_text())
    monkeypatch.setattr(registry, "discover", lambda: [runs_stage, stage])
    summary = rebuild(raw, tmp_path / "wh", jobs=1)
    assert not [p for p in summary.quarantine if p.stage == "logbook"]
    con = duckdb.connect(str(tmp_path / "wh" / "pneubench.duckdb"), read_only=True)
    try:
        cur = con.execute("SELECT * FROM hose_life")
        cols = [d[0] for d in cur.description]
        life = {r[0]: dict(zip(cols, r)) for r in cur.fetchall()}
        runs = {r[0]: {"distance_km": r[1], "strokes": r[2]}
                for r in con.execute("SELECT run_id, distance_km, strokes FROM durability_runs").fetchall()}
    finally:
        con.close()
    assert sorted(life) == sorted(truth["hoses"])
    for hid, t in truth["hoses"].items():
        row = life[hid]
        assert (row["status"], row["n_runs"]) == (t["status"], t["n_runs"]), hid
        assert row["distance_km"] == pytest.approx(t["distance_km"], rel=0.005), hid
        assert sorted(row["campaigns"]) == sorted(t["campaigns"]), hid
        if t["strokes"] is not None:
            assert row["strokes"] == t["strokes"], hid
        assert row["failure_mode"] == t["failure_mode"], hid
    durability = {rid: r["truth"] for rid, r in truth["runs"].items() if r["kind"] == "durability"}
    assert sorted(runs) == sorted(durability)
    for rid, t in durability.items():
        assert runs[rid]["distance_km"] == pytest.approx(t["distance_km"], rel=0.005), rid
        assert runs[rid]["strokes"] == t["strokes"], rid


def test_deadband_from_the_stated_sensor_and_strokes_not_detectable(tmp_path):
    """A run whose encoder is stated 20x coarser gets a 20x wider deadband; 3 mm strokes under a stated
    50 um noise (deadband 1 mm > a quarter of the 3 mm stroke) are not reported, with a note."""
    b = Bench(tmp_path)
    b.logbook("c/hoses.csv", "H,installed,2026-01-01,T,force,,866,,,,\n")
    b.durability("c/coarse", "c", "2026-01-02", "H", 10.0, 1, sensor_x_resolution=1e-4, sensor_x_noise=0.0)
    b.durability("c/tiny", "c", "2026-01-03", "H", 0.2, 2, stroke_m=0.003, speed_m_s=0.05, sensor_x_noise=5e-5,
                 sensor_x_resolution=5e-6)
    out = run_stages(b.ctx())
    runs = out.tables["durability_runs"].set_index("run_id")
    assert runs.loc["c/coarse", "deadband_mm"] == pytest.approx(2.0)
    assert runs.loc["c/coarse", "distance_km"] == pytest.approx(b.truth["c/coarse"]["distance_km"], rel=0.005)
    tiny = runs.loc["c/tiny"]
    assert tiny["deadband_mm"] == pytest.approx(1.0) and pd.isna(tiny["distance_km"]) and pd.isna(tiny["strokes"])
    assert "strokes not detectable" in tiny["note"]
    assert any("strokes not detectable" in w for w in out.warnings["c/tiny"])


#: Two hose types' lives as the lab's logbook holds them (odometer readings, km; True: failed, False: removed)
LAB_LIVES = {("FLEXIGOM AIR", "distance"): ([412.0, 655.3, 760.0, 998.1, 1210.4, 1300.0, 1300.0],
                                            [True, True, True, True, True, False, False]),
             ("PU 8x6", "force"): ([150.2, 288.0, 301.5, 470.9, 520.0], [True, True, False, True, False])}


def lab_logbook(b: Bench) -> None:
    """hoses.csv as the lab writes it: an `installed` row per hose with its type and setting, then a
    `failed` or `removed` row with the odometer reading (no durability runs logged)."""
    rows, day = [], 0
    for (htype, adj), (lives, failed) in LAB_LIVES.items():
        for j, (km, dead) in enumerate(zip(lives, failed)):
            hid, day = f"{htype[:2]}{j + 1:02d}", day + 1
            setting = ",4.5," if adj == "distance" else ",,866"
            rows.append(f"{hid},installed,2025-03-{day:02d}T08:00,{htype},{adj}{setting},,,,")
            rows.append(f"{hid},{'failed' if dead else 'removed'},2025-06-{day:02d}T17:30,,,,,"
                        f"{'rupture' if dead else ''},,{km},{'' if dead else 'end of test'}")
    b.logbook("durability-2025/hoses.csv", "\n".join(rows) + "\n")


def test_service_life_takes_the_plans_b_life_confidence_and_mission_per_hose_type(tmp_path):
    """A logbook and a plan.toml written as the lab writes them: each hose type's row at its own
    B-life, confidence and mission (its table over [defaults]), the MLE with profile bounds and the
    rank regression beside it; without a plan the built-in B10 at 90 % and no reliability."""
    from analyses.service_life import service_life_summary
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    b = Bench(tmp_path)
    lab_logbook(b)
    (b.raw / "plan.toml").write_text('# the lab\'s plan\n[defaults]\nconfidence = 0.95\nmission_km = 300\n\n'
                                     '[hose_type."FLEXIGOM AIR"]\nb_life = 5\nconfidence = 0.90\n'
                                     "mission_km = 500.0\n")
    plan = read_plan(RawTree(b.raw))
    assert plan.present and plan.problems == ()
    ctx = b.ctx()
    ctx.plan = plan
    sl = stage.run(ctx).tables["service_life"].set_index("hose_type")
    assert list(sl.columns[:14]) == stage.SERVICE_COLUMNS[1:15]          # the old columns first, unchanged
    for htype, (b_life, conf, mission) in {"FLEXIGOM AIR": (5.0, 0.90, 500.0), "PU 8x6": (10.0, 0.95, 300.0)}.items():
        row = sl.loc[htype]
        lives, failed = next(v for k, v in LAB_LIVES.items() if k[0] == htype)
        want = service_life_summary(lives, failed, b_life_pct=b_life, confidence=conf, mission=mission)
        assert (row["b_life_pct"], row["confidence"], row["mission_km"]) == (b_life, conf, mission)
        assert row["n_failed"] == sum(failed) and row["n_suspended"] == len(lives) - sum(failed)
        for key, col in {**stage.SUMMARY_COLUMNS, "shape": "weibull_shape", "scale": "weibull_scale_km"}.items():
            assert row[col] == pytest.approx(want[key], rel=1e-12), col
        assert row["shape_lower"] < row["weibull_shape"] < row["shape_upper"]
        assert row["scale_lower_km"] < row["weibull_scale_km"] < row["scale_upper_km"]
        assert row["b_life_lower_km"] < row["b_life_km"] < row["b_life_upper_km"]
        assert row["reliability_at_mission_lower"] < row["reliability_at_mission"] < row["reliability_at_mission_upper"]
        assert row["preferred_method"] == "MRR" and pd.isna(row["bounds_note"]) and pd.isna(row["note"])
        assert row["b10_lower_km"] < row["b10_km"] < row["b10_upper_km"]
    assert sl.loc["FLEXIGOM AIR", "b_life_km"] < sl.loc["FLEXIGOM AIR", "b10_km"]      # B5 before B10
    # no plan: B10 at 90 %, no mission: the reliability columns NULL
    ctx = b.ctx()
    sl = stage.run(ctx).tables["service_life"].set_index("hose_type")
    assert (sl["b_life_pct"] == 10.0).all() and (sl["confidence"] == 0.90).all()
    assert sl[["mission_km", "reliability_at_mission", "reliability_at_mission_lower"]].isna().all().all()
    assert (sl["b_life_km"] == sl["b10_km"]).all() and (sl["b_life_upper_km"] == sl["b10_upper_km"]).all()
