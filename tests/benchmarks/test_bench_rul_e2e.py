"""benchmarks/bench_rul_e2e.py: the contract's leak path and sensor, and its predictions from a
small hand-made warehouse with the durability stage's tables."""
from __future__ import annotations

import math

import duckdb
import numpy as np
import pandas as pd
import pytest

from benchmarks import bench_rul_e2e as be
from schemas.units import kg_s_to_l_min_anr


def _growth(rows):
    return pd.DataFrame(rows, columns=["hose_id", "run_id", "distance_km", "chamber", "pressure_bar", "leak_l_min"])


def test_the_leak_path_takes_the_plateau_nearest_the_plans_pressure_and_the_mean_over_chambers():
    g = _growth([("h", "r1", 1.0, "A", 0.01, 0.0), ("h", "r1", 1.0, "A", 2.98, 0.1), ("h", "r1", 1.0, "A", 5.97, 1.0),
                 ("h", "r1", 1.0, "B", 6.02, 1.4),
                 # a run whose plateaus stop far below the pressure asked: no point
                 ("h", "r2", 2.0, "A", 0.0, 0.0), ("h", "r2", 2.0, "A", 1.0, 0.3)])
    pts = be.leak_points(g, 6.0)
    assert pts.to_dict("records") == [{"hose_id": "h", "run_id": "r1", "distance_km": 1.0,
                                       "leak_l_min": pytest.approx(1.2)}]
    assert be.leak_points(g.iloc[:0], 6.0).empty


def test_the_leak_sensor_is_the_coarsest_stated_in_leakage_map():
    s = pd.Series(["p_supply: resolution 1, noise 300 (estimated) Pa; q_leak: resolution 1e-08, noise 4e-08 "
                   "(metadata) kg/s", "p_supply: resolution 1, noise 300 (estimated) Pa; q_leak: resolution 1e-08, "
                   "noise 8e-08 (estimated) kg/s", None])
    sensor = be.leak_sensor(s)
    assert sensor.noise == pytest.approx(float(kg_s_to_l_min_anr(8e-8))) and sensor.source == "estimated"
    assert be.leak_sensor(pd.Series(["nothing stated"])) is None


def _warehouse(tmp_path, rng):
    """hose_life, hose_leak_growth and leakage_map of one hose type and adjustment: leak (w d)^1.5."""
    life, growth, lmap = [], [], []
    for i in range(24):
        w = 0.5 * math.exp(0.3 * rng.standard_normal())
        cross = 2.0 ** (2 / 3) / w
        end = rng.uniform(0.6, 1.2) * 2.0 ** (2 / 3) / 0.5
        failed = cross <= end
        dist = min(cross, end)
        life.append((f"h{i:02d}", "T", "distance", dist, "failed" if failed else "running",
                     "leakage" if failed else None))
        for k, d in enumerate(np.arange(0.3, dist, 0.3)):
            rid = f"c{i:02d}-{k}"
            for p in (0.0, 3.0, 6.0):
                leak = (w * d) ** 1.5 * math.exp(0.07 * rng.standard_normal()) if p == 6.0 else 0.0
                growth.append((f"h{i:02d}", rid, d, "A", p, leak))
            lmap.append((rid, f"h{i:02d}", "q_leak: resolution 1.98e-08, noise 3.95e-08 (metadata) kg/s"))
    con = duckdb.connect(str(tmp_path / "w.duckdb"))
    con.register("l", pd.DataFrame(life, columns=["hose_id", "hose_type", "adjustment", "distance_km", "status",
                                                  "failure_mode"]))
    con.register("g", _growth(growth))
    con.register("m", pd.DataFrame(lmap, columns=["run_id", "hose_id", "sensors"]))
    for name, view in (("hose_life", "l"), ("hose_leak_growth", "g"), ("leakage_map", "m")):
        con.execute(f"CREATE TABLE {name} AS SELECT * FROM {view}")
    return con


def test_predictions_from_a_warehouse_cover_every_running_hose_with_both_methods(tmp_path):
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    (tmp_path / "plan.toml").write_text("[defaults]\nleak_limit_l_min = 2.0\nleak_pressure_bar = 6.0\n")
    con = _warehouse(tmp_path, np.random.default_rng(7))
    rul, tests, wear = be.predictions_from_warehouse(con, read_plan(RawTree(tmp_path.resolve())))
    running = con.sql("SELECT hose_id FROM hose_life WHERE status = 'running'").df()["hose_id"]
    assert set(rul["hose_id"]) == set(running) and sorted(rul["method"].unique()) == ["degradation", "weibull"]
    assert (rul["hose_type"] == "T").all() and (rul["confidence"] == 0.9).all() and len(tests) > 0
    # the wear rate the paths were drawn with: median 0.5 1/km, log sd 0.3
    assert wear["wear_mean_per_km"].iloc[0] == pytest.approx(0.5 * math.exp(0.045), rel=0.25)
    assert wear["gamma"].iloc[0] == pytest.approx(1.5, abs=0.15)
    out = be.running_outcomes(rul, {h: {"failure_km": 1e9} for h in rul["hose_id"]})
    assert not out["covered"].any()   # a future far beyond every interval is never covered
