"""Remaining life as people read it, on a warehouse filled by hand with the contract's tables
(RUL_CONTRACT.md: ``hose_rul``, ``rul_backtest``, ``decision_sensitivity``) beside the decision's:
a hose type whose verdict flips with the failure definition, one whose plan sets no leak limit,
running hoses with both methods, with one NULL, with both NULL; and ``pneubench decision``'s list."""
from __future__ import annotations

from pathlib import Path

import duckdb
import pandas as pd
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.serve import remaining_life as rl
from pipeline.serve.door import connect_readonly
from pipeline.warehouse import DB_NAME
from tests.pipeline.serve.test_decision import DECIDED, OPEN, make_warehouse

#: The contract's tables (RUL_CONTRACT.md), column by column.
RUL_DDL = {
    "hose_rul": "hose_type VARCHAR, hose_id VARCHAR, adjustment VARCHAR, distance_km DOUBLE, method VARCHAR, "
                "rul_median_km DOUBLE, rul_lower_km DOUBLE, rul_upper_km DOUBLE, confidence DOUBLE, "
                "leak_now_l_min DOUBLE, leak_limit_l_min DOUBLE, leak_pressure_bar DOUBLE, n_leak_points BIGINT, "
                "note VARCHAR",
    "rul_backtest": "hose_type VARCHAR, adjustment VARCHAR, method VARCHAR, n_predictions BIGINT, coverage DOUBLE, "
                    "coverage_at_50 DOUBLE, coverage_at_80 DOUBLE, confidence DOUBLE, median_abs_error_km DOUBLE, "
                    "note VARCHAR",
    "decision_sensitivity": "hose_type VARCHAR, definition VARCHAR, leak_limit_l_min DOUBLE, leak_pressure_bar DOUBLE, "
                            "n_force BIGINT, n_failed_force BIGINT, n_distance BIGINT, n_failed_distance BIGINT, "
                            "model VARCHAR, life_ratio DOUBLE, life_ratio_lower DOUBLE, life_ratio_upper DOUBLE, "
                            "confidence DOUBLE, verdict VARCHAR, note VARCHAR",
    "hose_leak_growth": "hose_id VARCHAR, run_id VARCHAR, started_at TIMESTAMPTZ, distance_km DOUBLE, "
                        "adjustment VARCHAR, chamber VARCHAR, pressure_bar DOUBLE, leak_l_min DOUBLE, "
                        "hose_status VARCHAR",
    "hose_life": "hose_id VARCHAR, hose_type VARCHAR",
}
UNSET = f"plan.toml sets no leak_limit_l_min / leak_pressure_bar for {OPEN}"
FEW = "fewer than 3 leak points above the sensor floor"
FALLING = "its leak path falls"
NO_FAILURES = "fewer than two failures of its type"


def _rul(t, hose, adj, dist, method, med=None, lo=None, hi=None, note=None, leak=None, n=None, limit=2.0, p=6.0):
    return {"hose_type": t, "hose_id": hose, "adjustment": adj, "distance_km": dist, "method": method,
            "rul_median_km": med, "rul_lower_km": lo, "rul_upper_km": hi, "confidence": 0.9, "leak_now_l_min": leak,
            "leak_limit_l_min": limit, "leak_pressure_bar": p, "n_leak_points": n, "note": note}


def _sens(t, definition, verdict, ratio, lo, hi, limit=None, note=None):
    return {"hose_type": t, "definition": definition, "leak_limit_l_min": limit, "leak_pressure_bar": 6.0 if limit else None,
            "n_force": 10, "n_failed_force": 6, "n_distance": 10, "n_failed_distance": 8,
            "model": "common shape" if ratio else None, "life_ratio": ratio, "life_ratio_lower": lo,
            "life_ratio_upper": hi, "confidence": 0.9, "verdict": verdict, "note": note}


def _bt(t, adj, method, n, cov, note=None):
    return {"hose_type": t, "adjustment": adj, "method": method, "n_predictions": n, "coverage": cov,
            "coverage_at_50": cov, "coverage_at_80": cov, "confidence": 0.9, "median_abs_error_km": 40.0, "note": note}


def _leaks(hose, points, pressures=(2.0, 4.0, 6.0), chambers=("A",), tag="L"):
    """Leakage runs of ``hose`` at (distance, leak at 6 bar): the other plateaus leak less."""
    return [{"hose_id": hose, "run_id": f"{hose}-{tag}{k}", "distance_km": d, "adjustment": "force", "chamber": c,
             "pressure_bar": p, "leak_l_min": leak * (p / 6.0) ** 2 + (0.02 if c == "B" else 0.0), "hose_status": "running"}
            for k, (d, leak) in enumerate(points) for p in pressures for c in chambers]


def rul_rows() -> dict[str, list[dict]]:
    """The hand-made rows: DECIDED's hoses (limit 2 l/min at 6 bar) and OPEN's (plan unset)."""
    return {
        "hose_rul": [
            _rul(DECIDED, "F1", "force", 400.0, "weibull", 900.0, 300.0, 2100.0, leak=0.8, n=6),
            _rul(DECIDED, "F1", "force", 400.0, "degradation", 350.0, 250.0, 480.0, leak=0.8, n=6),
            _rul(DECIDED, "F2", "force", 150.0, "weibull", 1100.0, 420.0, 2600.0, leak=0.05, n=2),
            _rul(DECIDED, "F2", "force", 150.0, "degradation", note=FEW, leak=0.05, n=2),
            _rul(DECIDED, "D1", "distance", 600.0, "weibull", 200.0, 40.0, 700.0, leak=1.1, n=5),
            _rul(DECIDED, "D1", "distance", 600.0, "degradation", 260.0, 180.0, 390.0, leak=1.1, n=5),
            _rul(DECIDED, "D2", "distance", 50.0, "weibull", note=NO_FAILURES, leak=0.3, n=3),
            _rul(DECIDED, "D2", "distance", 50.0, "degradation", note=FALLING, leak=0.3, n=3),
            _rul(OPEN, "P1", "force", 300.0, "weibull", 1500.0, 400.0, 3600.0, limit=None, p=None),
            _rul(OPEN, "P1", "force", 300.0, "degradation", note=UNSET, limit=None, p=None)],
        "rul_backtest": [
            _bt(DECIDED, "force", "weibull", 40, 0.86), _bt(DECIDED, "force", "degradation", 36, 0.9167),
            _bt(DECIDED, "distance", "weibull", 12, 0.75),
            _bt(DECIDED, "distance", "degradation", 0, None, "no failed hose with 3 leak points"),
            _bt(OPEN, "force", "weibull", 8, 1.0), _bt(OPEN, "force", "degradation", 0, None, UNSET)],
        "decision_sensitivity": [
            _sens(DECIDED, "leak limit x2", "force longer", 2.1, 1.4, 3.2, limit=4.0),
            _sens(DECIDED, "logbook", "force longer", 1.82, 1.31, 2.53),
            _sens(DECIDED, "leak limit", "force longer", 1.9, 1.2, 3.1, limit=2.0),
            _sens(DECIDED, "leak limit x0.5", "undecided", 1.3, 0.9, 1.9, limit=1.0),
            _sens(OPEN, "logbook", "undecided", 1.15, 0.8, 1.6),
            *(_sens(OPEN, d, None, None, None, None, note=UNSET) for d in ("leak limit", "leak limit x0.5",
                                                                           "leak limit x2"))],
        "hose_leak_growth": (_leaks("F1", [(50, 0.1), (150, 0.3), (250, 0.5), (320, 0.62), (400, 0.8)],
                                    chambers=("A", "B"))
                             + _leaks("F1", [(200, 9.0)], pressures=(1.0, 2.0, 3.0), tag="low")  # no plateau near 6 bar
                             + _leaks("D1", [(100, 0.2), (300, 0.5), (450, 0.8), (600, 1.1)])
                             + _leaks("D2", [(10, 0.5), (30, 0.4), (50, 0.3)], pressures=(6.0,))
                             + _leaks("P1", [(100, 0.2), (300, 0.4)])),
        "hose_life": [{"hose_id": h, "hose_type": DECIDED} for h in ("F1", "F2", "D1", "D2")]
                     + [{"hose_id": "P1", "hose_type": OPEN}],
    }


def make_rul_warehouse(folder: Path, rows: dict[str, list[dict]] | None = None) -> Path:
    """The decision's hand-made warehouse (``make_warehouse``) with the remaining-life tables added."""
    make_warehouse(folder)
    rows = rul_rows() if rows is None else rows
    con = duckdb.connect(str(folder / DB_NAME))
    try:
        for t, ddl in RUL_DDL.items():
            con.execute(f'CREATE TABLE "{t}" ({ddl})')
            cols = [c.split()[0] for c in ddl.split(", ")]
            for r in rows.get(t, []):
                con.execute(f'INSERT INTO "{t}" VALUES ({", ".join("?" * len(cols))})', [r.get(c) for c in cols])
    finally:
        con.close()
    return folder


@pytest.fixture
def wh(tmp_path) -> Path:
    return make_rul_warehouse(tmp_path / "wh")


def _con(wh):
    return connect_readonly(wh)


def test_running_hoses_nearest_their_end_first_without_a_number_last(wh):
    con = _con(wh)
    try:
        hoses = rl.read_running(con)
        assert [h.hose_id for h in hoses] == ["D1", "F1", "F2", "P1", "D2"]  # 200, 350, 1100, 1500, none
        assert [h.nearest_km() for h in hoses] == [200.0, 350.0, 1100.0, 1500.0, None]
        assert hoses[-1].notes() == f"weibull: {NO_FAILURES}; degradation: {FALLING}"
        assert [h.hose_id for h in rl.read_running(con, OPEN)] == ["P1"]
        assert rl.rul_missing(con) is None
    finally:
        con.close()


def test_words_of_a_prediction_a_backtest_and_a_sensitivity(wh):
    con = _con(wh)
    try:
        f1 = next(h for h in rl.read_running(con) if h.hose_id == "F1")
        backtest, sens = rl.read_backtest(con), rl.read_sensitivity(con)
    finally:
        con.close()
    assert rl.rul_text(f1.rows["weibull"]) == "900 km [300-2,100]"
    assert rl.rul_text({"rul_median_km": 42.456, "rul_lower_km": None, "rul_upper_km": 61.0}) == "42.5 km [—-61]"
    assert rl.rul_text({"rul_median_km": None, "note": FEW}) == "—" and rl.rul_text(None) == "—"
    assert rl.coverage_text(backtest[(DECIDED, "force", "degradation")]) == \
        "backtest: 92 % of 36 intervals held (nominal 90 %)"
    assert rl.coverage_text(backtest[(DECIDED, "distance", "degradation")]) == \
        "backtest: no interval to check (no failed hose with 3 leak points)"
    assert rl.coverage_text(None) == "backtest: none"
    assert rl.interval_name([f1]) == "90 % prediction interval"
    other = rl.RunningHose("X", "X1", "force", 10.0, {"weibull": {"confidence": 0.8}})
    assert rl.interval_name([f1, other]) == "prediction interval at each hose type's plan confidence"
    assert [r["definition"] for r in sens[DECIDED]] == list(rl.DEFINITIONS)  # in the contract's order
    assert [rl.differs(r, sens[DECIDED]) for r in sens[DECIDED]] == [False, False, True, False]
    assert not any(rl.differs(r, sens[OPEN]) for r in sens[OPEN])  # a NULL verdict is not a flip
    no_crossing = {**sens[DECIDED][2], "life_ratio": None, "life_ratio_lower": None, "life_ratio_upper": None}
    assert not rl.differs(no_crossing, [*sens[DECIDED][:2], no_crossing])  # no data under it: not a flip
    assert rl.sensitivity_words(sens[DECIDED]) == (
        "logbook: force longer, 1.82x (90 % CI 1.31-2.53x); leak limit (2 l/min at 6 bar): force longer, 1.9x "
        "(90 % CI 1.2-3.1x); leak limit x0.5 (1 l/min at 6 bar): undecided, 1.3x (90 % CI 0.9-1.9x) <- differs; "
        "leak limit x2 (4 l/min at 6 bar): force longer, 2.1x (90 % CI 1.4-3.2x)")
    assert rl.sensitivity_words(sens[OPEN]).endswith(f"leak limit x2: — ({UNSET})")


def test_the_leak_path_is_at_the_plateau_nearest_the_plans_pressure(wh):
    con = _con(wh)
    try:
        hoses = rl.read_running(con)
        paths = rl.leak_paths(con, hoses)
    finally:
        con.close()
    # F1: the mean of its two chambers at 6 bar; the run with plateaus 1-3 bar is 3 bar from 6, over the spacing
    assert [d for d, _ in paths["F1"]] == [50, 150, 250, 320, 400]
    assert [v for _, v in paths["F1"]] == pytest.approx([0.11, 0.31, 0.51, 0.63, 0.81])
    assert paths["D2"] == [(10, 0.5), (30, 0.4), (50, 0.3)]  # one plateau pressure, exactly the plan's
    assert "P1" not in paths  # its plan sets no pressure
    # the points the stage fitted: its own pressure matching on the hose type's rows
    from pipeline.stages.remaining_life import leak_paths as stage_paths
    growth = pd.DataFrame(rul_rows()["hose_leak_growth"])
    pts, _ = stage_paths(growth[growth["hose_id"].isin(["F1", "F2", "D1", "D2"])], 6.0)
    assert paths["D1"] == list(zip(pts.loc[pts["hose_id"] == "D1", "distance_km"], pts.loc[pts["hose_id"] == "D1", "leak_l_min"]))


def test_old_warehouse_says_remaining_life_not_computed(tmp_path):
    old = make_warehouse(tmp_path / "old")
    con = _con(old)
    try:
        assert rl.rul_missing(con) == rl.NOT_COMPUTED
        assert rl.read_running(con) == [] and rl.read_backtest(con) == {} and rl.read_sensitivity(con) == {}
        assert rl.running_lines(con, None, None) == [rl.NOT_COMPUTED]
    finally:
        con.close()
    res = CliRunner().invoke(main, ["decision", "--warehouse", str(old)], env={"COLUMNS": "72"})
    assert res.exit_code == 0, res.output
    assert " ".join(res.output.split()).endswith(" ".join(rl.NOT_COMPUTED.split()))
    assert max(len(x) for x in res.output.splitlines()) <= 72


def test_the_command_lists_the_running_hoses_after_the_verdicts(wh, monkeypatch):
    res = CliRunner().invoke(main, ["decision", "--warehouse", str(wh)], env={"COLUMNS": "250"})
    assert res.exit_code == 0, res.output
    out = res.output
    assert out.index("FLEXIGOM AIR: force-set") < out.index("Running hoses, nearest their end first")
    assert ("  definitions  logbook: force longer, 1.82x (90 % CI 1.31-2.53x); leak limit (2 l/min at 6 bar): "
            "force longer") in out
    assert "undecided, 1.3x (90 % CI 0.9-1.9x) <- differs" in out
    table = out[out.index("hose type "):].splitlines()
    assert table[0].split()[:4] == ["hose", "type", "hose", "adjustment"]
    rows = [line for line in table[1:] if line.startswith(("FLEXIGOM", "PU"))]
    assert [r.split()[2] for r in rows] == ["D1", "F1", "F2", "P1", "D2"]
    assert "200 km [40-700]" in rows[0] and "260 km [180-390]" in rows[0] and "1.1 / 2 l/min at 6 bar" in rows[0]
    assert rows[2].rstrip().endswith(f"degradation: {FEW}") and "—" in rows[2]
    assert "no limit" in rows[3] and rows[3].rstrip().endswith(f"degradation: {UNSET}")
    assert rows[4].rstrip().endswith(f"weibull: {NO_FAILURES}; degradation: {FALLING}")
    trust = out[out.index("How far to trust them"):].splitlines()[1:]
    assert [line.split(":")[0] for line in trust] == [
        "  FLEXIGOM AIR distance weibull", "  FLEXIGOM AIR distance degradation", "  FLEXIGOM AIR force weibull",
        "  FLEXIGOM AIR force degradation", "  PU 8x6 force weibull", "  PU 8x6 force degradation"]
    assert "  FLEXIGOM AIR force weibull: backtest: 86 % of 40 intervals held (nominal 90 %)" in out
    assert ("  FLEXIGOM AIR distance degradation: backtest: no interval to check (no failed hose with 3 leak "
            "points)") in out
    # capped without --hose-type: the nearest first, the rest counted
    monkeypatch.setattr(rl, "MAX_TERMINAL_HOSES", 2)
    capped = CliRunner().invoke(main, ["decision", "--warehouse", str(wh)], env={"COLUMNS": "250"}).output
    assert "(3 more running hoses: pneubench decision --hose-type T lists all of a type's)" in capped
    assert " F1 " in capped and " F2 " not in capped and "PU 8x6 force weibull" not in capped
    one = CliRunner().invoke(main, ["decision", "--warehouse", str(wh), "--hose-type", OPEN], env={"COLUMNS": "250"})
    assert one.exit_code == 0 and " P1 " in one.output and " F1 " not in one.output
    assert f"  definitions  logbook: undecided, 1.15x (90 % CI 0.8-1.6x); leak limit: — ({UNSET})" in one.output


def test_no_running_hose_is_one_line(tmp_path):
    wh = make_rul_warehouse(tmp_path / "wh", {})
    con = _con(wh)
    try:
        assert rl.running_lines(con, None, 80) == ["Running hoses: none"]
    finally:
        con.close()
