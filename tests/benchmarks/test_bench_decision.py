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


def _verdicts() -> pd.DataFrame:
    return pd.DataFrame({"hose_type": ["A", "B", "C", "D"],
                         "verdict": ["undecided", "force longer", "force longer", "undecided"],
                         "power": [0.8, 0.8, 0.8, 0.8], "max_failures": [20, 30, 10, None],
                         "failures": [22, 25, 12, 4]})


def test_coverage_joins_the_truth_and_counts_open_sides_as_covering():
    c = bd.coverage(_life_effect(), TYPES)
    assert c["ratio"] == [1, 2] and c["shape"] == [2, 2] and c["ratio, separate shapes"] == [1, 1]
    assert c["absent"] == 0
    types = {**TYPES, "E": TYPES["A"]}
    assert bd.coverage(_life_effect(), types)["absent"] == 1


def test_verdicts_count_common_shape_types_their_reach_and_those_without_a_frozen_maximum():
    v = bd.verdicts(_verdicts(), {**TYPES, "D": TYPES["A"]})
    assert v["n"] == 3 and v["counts"] == {"undecided": 2, "force longer": 1}
    assert v["reached"] == 1                       # A: 22 of 20; B: 25 of 30; D: none frozen
    assert v["no_max"] == 1


def test_the_repeated_intervals_cover_when_every_designed_look_holds_the_truth():
    """A: true ratio 1 in every look's interval; B (1.5): the 2nd look's misses, so B is not covered;
    C (separate shapes) counted apart; A's 3rd look is past max_failures (20): counted under "all looks"
    only; D has no interval at all."""
    nan = float("nan")
    looks = pd.DataFrame({"hose_type": ["A", "A", "A", "B", "B", "C", "D"],
                          "failures": [10, 20, 21, 10, 11, 10, 3],
                          "rci_lower": [0.5, 0.8, 1.1, 1.0, 1.6, 1.2, nan],
                          "rci_upper": [2.0, 1.2, 1.3, 2.0, 2.0, 1.9, nan]})
    c = bd.rci_coverage(looks, _verdicts(), {**TYPES, "D": TYPES["A"]})
    assert c["designed"] == [1, 2] and c["all looks"] == [0, 2] and c["separate shapes"] == [1, 1]
    assert c["none"] == 1


def test_the_anatomy_reads_the_frozen_look_and_shape_from_the_note(capsys):
    rows = pd.DataFrame({"hose_type": ["A", "B"], "decided_at_look": [12, 14], "failures": [12, 20],
                         "max_failures": [12, 30], "note": [
                             "max_failures frozen at look 12 (2025-01-01T00:00:00+00:00): designed from that look's "
                             "common shape 3 and 4 hose(s) on test per adjustment; the 11 look(s) before it",
                             "max_failures frozen at look 10 (2025-01-02T00:00:00+00:00): designed from that look's "
                             "common shape 2.5 and 4 hose(s) on test per adjustment"]})
    bd.anatomy("misses", rows, TYPES, lambda shape: 10 * shape)
    out = capsys.readouterr().out
    assert "anatomy of misses (2 hose types)" in out
    assert "design at the true shape     21.2 / 22.5 / 23.8" in out    # 10 x (2.0, 2.5)
    assert "frozen shape / true shape    1.12 / 1.25 / 1.38" in out    # 3 / 2, 2.5 / 2.5
    assert "design below it): 1; reached max_failures: 1" in out     # A: 12 of 12; B: 20 of 30


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
    code = bd.main(["--rebuild", "--types", "2", "--shard", "1", "--keep", str(tmp_path)])
    err = capsys.readouterr().err
    if code == 2:
        assert "are not in this build" in err
    else:   # the stages are wired: the tables are there and counted
        assert code in (0, 1)


def test_the_repeated_intervals_report_misses_and_their_first_look(capsys):
    """Both common-shape types miss (Binomial(2, 0.05)'s 97.5 % quantile allows one): MISS, and where
    the misses begin: A at its second look (12 failures), B at its first (10)."""
    looks = pd.DataFrame({"hose_type": ["A", "A", "B", "B"], "failures": [10, 12, 10, 11],
                          "rci_lower": [0.5, 1.1, 1.6, 1.0], "rci_upper": [2.0, 1.3, 2.0, 2.0]})
    verdict = pd.DataFrame({"hose_type": ["A", "B"], "max_failures": [20, 20]})
    s = bd.Scenario("x", {"hose_types": TYPES}, {"decision_looks": looks, "life_verdict": verdict}, 0.0, {})
    assert bd.report_rci([s], 0.05) is False
    out = capsys.readouterr().out
    assert "0/2" in out and "MISS" in out
    assert "misses (2): failures at the first missing look           10.5 / 11 / 11.5" in out
    assert "misses at the first look with an interval: 1" in out      # B misses at its first look, A at its second


def test_the_wald_ends_are_the_estimate_times_exp_of_the_boundary_times_its_se_and_are_counted_alike():
    """A's first look comes before the freeze (no repeated interval shown): no Wald interval either."""
    looks = pd.DataFrame({"hose_type": ["A", "A", "A", "B"], "failures": [5, 10, 20, 10],
                          "life_ratio": [3.0, 1.2, 0.9, 2.0], "se_log_ratio": [0.1, 0.1, 0.08, NAN],
                          "boundary_z": [4.0, 3.0, 2.0, 2.5], "rci_lower": [NAN, 0.8, NAN, NAN],
                          "rci_upper": [NAN, 1.5, 1.1, NAN]})
    w = bd.wald_ends(looks)
    assert w["wald_lower"].tolist()[1:3] == pytest.approx([1.2 * math.exp(-0.3), 0.9 * math.exp(-0.16)])
    assert w["wald_upper"].tolist()[1:3] == pytest.approx([1.2 * math.exp(0.3), 0.9 * math.exp(0.16)])
    assert w[["wald_lower", "wald_upper"]].iloc[[0, 3]].isna().all().all()
    c = bd.rci_coverage(w, _verdicts(), TYPES, ("wald_lower", "wald_upper"))
    assert c["designed"] == [1, 1] and c["none"] == 1      # A: 1.0 in both looks' intervals; B: none


def test_pointwise_counts_each_designed_looks_own_miss_against_its_nominal_rate_by_information_fraction():
    """A (max 20): looks at 10 and 20 failures (fractions 0.5, 1) cover, the 3rd (21) is past max_failures;
    B (max 30): its looks at 10 and 11 failures (0.33, 0.37), the 2nd misses the true 1.5; C has separate
    shapes: not counted."""
    from scipy import stats

    from analyses.look_fits import bartlett_factor
    looks = pd.DataFrame({"hose_type": ["A", "A", "A", "B", "B", "C"], "failures": [10, 20, 21, 10, 11, 10],
                          "boundary_z": [3.0, 2.0, 2.0, 3.0, 2.9, 3.0],
                          "rci_lower": [0.5, 0.8, 1.1, 1.0, 1.6, 1.2], "rci_upper": [2.0, 1.2, 1.3, 2.0, 2.0, 1.9]})
    pw = bd.pointwise(looks, _verdicts(), TYPES)
    assert pw["looks"].tolist() == [2, 1, 0, 0, 1] and pw["misses"].tolist() == [1, 0, 0, 0, 0]
    z = np.array([3.0, 3.0, 2.9, 2.0]) * np.sqrt(bartlett_factor([10, 10, 11, 20]))
    assert pw["expected"].sum() == pytest.approx(2 * stats.norm.sf(z).sum())


def test_the_bartlett_table_compares_the_factor_with_simulated_means():
    rows = bd.bartlett_table(20, 3)
    assert len(rows) == 10 and rows[0][:2] == (5, 5)
    for rd, rf, mean, se, b in rows:
        assert mean > 0 and se > 0 and b == pytest.approx(1 + 3.8 / (rd + rf))
