"""benchmarks/bench_decision.py: its counting and truth joining on a small hand-made warehouse with
the contract's tables, its naive test against the life-effect fit, and its refusal without tables."""
from __future__ import annotations

import math

import duckdb
import numpy as np
import pandas as pd
import pytest

from analyses.life_effect import life_effect
from benchmarks import bench_decision as bd

TYPES = {
    "A": {"separate_shapes": False, "life_ratio": 1.0, "shape": 2.0},
    "B": {"separate_shapes": False, "life_ratio": 1.5, "shape": 2.5},
    "C": {"separate_shapes": True, "life_ratio": 1.5, "shape": None},
}
NAN = float("nan")


def _life_effect() -> pd.DataFrame:
    return pd.DataFrame([
        # hose_type, ratio, lower, upper, shape, lower, upper
        ("A", 1.0, 0.8, 1.2, 2.1, 1.5, 2.5),     # both cover
        ("B", 1.8, 1.6, 2.0, 2.4, NAN, 3.0),     # ratio misses; shape open below, covers
        ("C", 1.4, 1.2, 1.8, 2.0, 1.9, 2.2),     # separate true shapes: counted apart
        ("D", 1.0, 0.5, 2.0, 2.0, 1.0, 3.0),     # not in the truth: left out
        ("E", NAN, NAN, NAN, NAN, NAN, NAN),     # not in the truth either
    ], columns=["hose_type", "life_ratio", "life_ratio_lower", "life_ratio_upper", "shape", "shape_lower",
                "shape_upper"])


def _verdicts() -> tuple[pd.DataFrame, pd.DataFrame]:
    verdict = pd.DataFrame({"hose_type": ["A", "B", "C"], "verdict": ["undecided", "force longer", "force longer"],
                            "power": [0.8, 0.8, 0.8], "max_failures": [20, 30, 10], "failures": [22, 25, 12]})
    plan = pd.DataFrame({"hose_type": ["A", "A", "B", "B", "C"], "target_power": [0.8, 0.9, 0.8, 0.9, 0.8],
                         "failures_needed": [20, 27, 31, 40, 10]})
    return verdict, plan


def test_coverage_joins_the_truth_and_counts_open_sides_as_covering():
    c = bd.coverage(_life_effect(), TYPES)
    assert c["ratio"] == [1, 2] and c["shape"] == [2, 2] and c["ratio, separate shapes"] == [1, 1]
    assert c["absent"] == 0
    types = {**TYPES, "E": TYPES["A"]}
    assert bd.coverage(_life_effect(), types)["absent"] == 1


def test_verdicts_count_common_shape_types_their_reach_and_the_test_plans_max_failures():
    verdict, plan = _verdicts()
    v = bd.verdicts(verdict, plan, TYPES)
    assert v["n"] == 2 and v["counts"] == {"undecided": 1, "force longer": 1}
    assert v["reached"] == 1                       # A: 22 of 20; B: 25 of 30
    assert v["max_failures_from_test_plan"] == 1   # A: 20 = 20 at power 0.8; B: 30 != 31


def _look_hoses(rng, ratio: float, name: str) -> pd.DataFrame:
    life = np.r_[100 * rng.weibull(3.0, 12), ratio * 100 * rng.weibull(3.0, 12)]
    return pd.DataFrame({"hose_type": name, "look": 1, "hose_id": [f"{name}{i}" for i in range(24)],
                         "adjustment": ["distance"] * 12 + ["force"] * 12, "distance_km": life, "failed": True})


def test_the_naive_test_is_the_life_effects_likelihood_ratio_and_declares_at_any_look():
    rng = np.random.default_rng(5)
    far, same = _look_hoses(rng, 3.0, "far"), _look_hoses(rng, 1.0, "same")
    for d in (far, same):
        lr = bd.lr_statistic(d["distance_km"].to_numpy(), d["failed"].to_numpy(), (d["adjustment"] == "force").to_numpy(int))
        p = life_effect(d["distance_km"].to_numpy(), d["failed"].to_numpy(), (d["adjustment"] == "force").to_numpy(int)).p_value
        from scipy import stats
        assert stats.chi2.sf(lr, 1) == pytest.approx(p, rel=1e-5, abs=1e-12)
    early = same.assign(look=1)
    late = far.assign(look=2, hose_type="same")  # "same" crosses at its second look only
    assert bd.naive_lr_declared(pd.concat([far, early, late]), 0.05) == (2, 2)
    assert bd.naive_lr_declared(pd.concat([far, early]), 0.05) == (1, 2)
    assert bd.naive_lr_declared(pd.concat([far, early]), 0.05, limit=1) == (1, 1)   # "far" sorts first
    one_failure = far.assign(failed=[True] + [False] * 11 + [True] * 12)
    assert math.isnan(bd.lr_statistic(one_failure["distance_km"].to_numpy(), one_failure["failed"].to_numpy(),
                                      (one_failure["adjustment"] == "force").to_numpy(int)))


def test_the_naive_wald_reading_declares_when_any_look_is_beyond_the_fixed_sample_z():
    looks = pd.DataFrame({"hose_type": ["A", "A", "B", "B", "C"], "z": [0.5, 2.0, -1.9, 1.0, NAN]})
    assert bd.naive_wald_declared(looks, 0.05) == (1, 3)


def test_look_distances_are_compared_with_the_odometer_linear_in_time():
    truth = {"H1": {"installed_at": "2025-01-06T07:00:00", "ended_at": "2025-01-07T07:00:00", "odometer_at": None},
             "H2": {"installed_at": "2025-01-06T19:00:00", "ended_at": None, "odometer_at": "2025-01-09T07:00:00"}}
    looks = pd.DataFrame({"hose_type": "A", "look": [1, 2],
                          "event_at": pd.to_datetime(["2025-01-07T07:00:00Z", "2025-01-08T07:00:00Z"])})
    rows = pd.DataFrame({"hose_type": "A", "look": [1, 1, 2, 2], "hose_id": ["H1", "H2", "H1", "H2"],
                         "distance_km": [20.0, 10.0, 20.0, 30.0]})
    assert bd.look_distance_error(rows, looks, truth, 20.0) == pytest.approx(0.0, abs=1e-9)
    rows.loc[3, "distance_km"] = 30.5
    assert bd.look_distance_error(rows, looks, truth, 20.0) == pytest.approx(0.5)


def test_the_binomial_bound_is_the_975_quantile():
    n, p = 400, 0.05
    k = bd.binomial_bound(n, p)
    cdf = lambda m: sum(math.comb(n, i) * p ** i * (1 - p) ** (n - i) for i in range(m + 1))  # noqa: E731
    assert cdf(k) >= 0.975 > cdf(k - 1) and k == 29


def test_stage_seconds_reads_the_rebuilds_stage_lines():
    log = ("ingest: 0/0 done in 0.1 s\nstage durability ran: hose_life 3 rows (2.5 s)\n"
           "stage decision ran: life_effect 3 rows, life_verdict 3 rows (3.4 s; memo 2 hits)\n"
           "stage test_plan reused: test_plan 6 rows (512 ms)\n")
    assert bd.stage_seconds(log) == {"durability": 2.5, "decision": 3.4, "test_plan": 0.512}


def test_a_warehouse_without_the_decision_tables_is_refused_naming_them(tmp_path):
    db = tmp_path / "pneubench.duckdb"
    con = duckdb.connect(str(db))
    con.execute("CREATE TABLE life_effect (hose_type VARCHAR)")
    con.close()
    with pytest.raises(bd.MissingTables, match="no life_verdict, decision_looks, decision_look_hoses, test_plan"):
        bd.read_tables(db)


def test_the_tables_are_read_whole_when_there(tmp_path):
    db = tmp_path / "pneubench.duckdb"
    con = duckdb.connect(str(db))
    for t in bd.DECISION_TABLES:
        con.execute(f"CREATE TABLE {t} (hose_type VARCHAR, n BIGINT)")
        con.execute(f"INSERT INTO {t} VALUES ('A', 1), ('B', 2)")
    con.close()
    tables = bd.read_tables(db)
    assert set(tables) == set(bd.DECISION_TABLES) and list(tables["test_plan"]["n"]) == [1, 2]


def test_the_benchmark_says_why_it_cannot_count_when_the_stages_are_missing(tmp_path, capsys):
    """A whole (tiny) run: simulate, rebuild as a process; without the decision stages it stops
    with exit 2 and the one-line reason."""
    code = bd.main(["--types", "2", "--shard", "1", "--timing-types", "0", "--keep", str(tmp_path)])
    err = capsys.readouterr().err
    if code == 2:
        assert "are not in this build" in err
    else:   # the stages are wired: the tables are there and counted
        assert code in (0, 1)
