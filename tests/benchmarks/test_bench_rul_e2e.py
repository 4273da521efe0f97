"""benchmarks/bench_rul_e2e.py: the wear rates refitted on the stage's leak paths, and the running
hoses' outcomes counted from the stage's tables."""
from __future__ import annotations

import math

import duckdb
import numpy as np
import pandas as pd
import pytest

from benchmarks import bench_rul_e2e as be


def _growth(rows):
    return pd.DataFrame(rows, columns=["hose_id", "run_id", "distance_km", "chamber", "pressure_bar", "leak_l_min"])


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


def test_wear_rates_are_refitted_on_the_stages_leak_paths_and_recover_the_drawn_rate(tmp_path):
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    (tmp_path / "plan.toml").write_text("[defaults]\nleak_limit_l_min = 2.0\nleak_pressure_bar = 6.0\n")
    con = _warehouse(tmp_path, np.random.default_rng(7))
    wear = be.wear_rates(con, read_plan(RawTree(tmp_path.resolve())))
    # the wear rate the paths were drawn with: median 0.5 1/km, log sd 0.3
    assert wear[["hose_type", "adjustment"]].values.tolist() == [["T", "distance"]]
    assert wear["wear_mean_per_km"].iloc[0] == pytest.approx(0.5 * math.exp(0.045), rel=0.25)
    assert wear["gamma"].iloc[0] == pytest.approx(1.5, abs=0.15)
    (tmp_path / "plan.toml").write_text("[defaults]\nmargin = 1.5\n")   # no leak limit: nothing to fit
    assert be.wear_rates(con, read_plan(RawTree(tmp_path.resolve()))).empty


def test_running_outcomes_count_a_future_inside_its_interval_and_leave_a_null_out(tmp_path):
    con = duckdb.connect(str(tmp_path / "w.duckdb"))
    con.execute("CREATE TABLE hose_rul AS SELECT * FROM (VALUES ('T', 'a', 10.0, 'weibull', 5.0, 2.0, 9.0, 0.9, NULL),"
                " ('T', 'b', 20.0, 'weibull', 5.0, 2.0, 9.0, 0.9, NULL), ('T', 'c', 30.0, 'weibull', NULL, NULL, NULL,"
                " 0.9, 'too few failures')) t(hose_type, hose_id, distance_km, method, rul_median_km, rul_lower_km,"
                " rul_upper_km, confidence, note)")
    con.execute("CREATE TABLE rul_backtest AS SELECT 'T' hose_type, 'force' adjustment, 'weibull' method, "
                "10 n_predictions, 0.8 coverage")
    rul, backtest = be.stage_tables(con)
    out = be.running_outcomes(rul, {"a": {"failure_km": 18.0}, "b": {"failure_km": 40.0}, "c": {"failure_km": 31.0}})
    assert out["made"].tolist() == [True, True, False]
    assert out["covered"].tolist() == [True, False, False]   # a: 8 km left, in [2, 9]; b: 20 km left, beyond
    assert backtest["coverage"].tolist() == [0.8]
    assert out["above"].tolist() == [False, True, False] and not out["below"].any()
    assert out["mode"].tolist() == ["?", "?", "?"]   # a truth without the simulator's failure mode


def test_misses_are_split_by_side_distance_now_and_failure_mode(capsys):
    rul = pd.DataFrame({"hose_type": "T", "adjustment": "force", "hose_id": list("abcdefgh"), "method": "weibull",
                        "distance_km": [1.0, 2, 3, 4, 5, 6, 7, 8], "rul_median_km": 5.0, "rul_lower_km": 2.0,
                        "rul_upper_km": 9.0, "confidence": 0.9, "note": None})
    left = {"a": 1.0, "b": 5, "c": 5, "d": 5, "e": 5, "f": 5, "g": 5, "h": 12}   # a under 2 km, h over 9 km
    truth = {h: {"failure_km": d + left[h], "failure_mode_true": "rupture" if h == "a" else "leakage"}
             for h, d in zip(rul["hose_id"], rul["distance_km"])}
    out = be.running_outcomes(rul, truth)
    be.misses(out[out["made"]])
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 6   # four quartiles, two modes
    assert "quartile 1" in lines[0] and "covered    1" in lines[0] and "below the lower end   1" in lines[0]
    assert "quartile 4" in lines[3] and "above the upper end   1" in lines[3]
    assert "ends by leakage" in lines[4] and "covered    6" in lines[4] and "above the upper end   1" in lines[4]
    assert "ends by rupture" in lines[5] and "below the lower end   1" in lines[5]


def test_the_control_counts_every_running_hose_under_each_rule():
    rng = np.random.default_rng(3)
    out = be.control_group(rng, be.CONTROL_LAWS["lognormal lives (sigma 0.35)"], 0.90)
    # the same draws again: the running hoses are those whose life passed their campaign's end
    again = np.random.default_rng(3)
    truth = np.exp(0.35 * again.standard_normal(25))
    n_running = int((truth > again.uniform(0.6, 1.05, 25)).sum())
    assert out["rule"].value_counts().to_dict() == {r: n_running for r in ("weibull only", "better fit", "mixture")}
    assert out["made"].all() and (out["width"] > 0).all()
    # lognormal lives: the mixture's intervals are never narrower in the median than the Weibull's alone
    by = out.groupby("rule")["width"].median()
    assert by["mixture"] >= by["weibull only"]
