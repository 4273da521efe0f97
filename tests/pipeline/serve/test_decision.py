"""The decision in words and in the terminal (``pneubench decision``), on warehouses filled by
hand with the contract's tables (DECISION_CONTRACT.md): a decided hose type, an undecided one
with its plan, one without plan.toml, one without an estimate yet."""
from __future__ import annotations

import math
from datetime import date, datetime, timedelta, timezone
from pathlib import Path

import duckdb
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.serve import decision as dc
from pipeline.serve.door import connect_readonly
from pipeline.serve.query import QueryError
from pipeline.warehouse import DB_NAME

#: The contract's tables (DECISION_CONTRACT.md), column by column.
DDL = {
    "life_effect": "hose_type VARCHAR, n_force BIGINT, n_failed_force BIGINT, n_distance BIGINT, "
                   "n_failed_distance BIGINT, model VARCHAR, shape DOUBLE, shape_lower DOUBLE, shape_upper DOUBLE, "
                   "life_ratio DOUBLE, life_ratio_lower DOUBLE, life_ratio_upper DOUBLE, confidence DOUBLE, "
                   "p_value DOUBLE, shape_test_p DOUBLE, note VARCHAR",
    "life_verdict": "hose_type VARCHAR, verdict VARCHAR, margin DOUBLE, alpha DOUBLE, power DOUBLE, confidence DOUBLE, "
                    "spending VARCHAR, max_failures BIGINT, max_failures_from VARCHAR, plan_from VARCHAR, "
                    "failures BIGINT, information_fraction DOUBLE, looks BIGINT, life_ratio DOUBLE, "
                    "se_log_ratio DOUBLE, z DOUBLE, boundary_z DOUBLE, efficacy_lower DOUBLE, efficacy_upper DOUBLE, "
                    "futility_lower DOUBLE, futility_upper DOUBLE, rci_lower DOUBLE, rci_upper DOUBLE, "
                    "decided_at TIMESTAMPTZ, decided_at_look BIGINT, decided_ratio DOUBLE, decided_lower DOUBLE, "
                    "decided_upper DOUBLE, note VARCHAR",
    "decision_looks": "hose_type VARCHAR, look BIGINT, event_at TIMESTAMPTZ, hose_id VARCHAR, failures BIGINT, "
                      "n_hoses BIGINT, total_km DOUBLE, information_fraction DOUBLE, life_ratio DOUBLE, "
                      "se_log_ratio DOUBLE, z DOUBLE, boundary_z DOUBLE, alpha_spent DOUBLE, efficacy_lower DOUBLE, "
                      "efficacy_upper DOUBLE, futility_lower DOUBLE, futility_upper DOUBLE, rci_lower DOUBLE, "
                      "rci_upper DOUBLE, crossed VARCHAR, decides BOOLEAN, note VARCHAR",
    "decision_look_hoses": "hose_type VARCHAR, look BIGINT, hose_id VARCHAR, adjustment VARCHAR, distance_km DOUBLE, "
                           "failed BOOLEAN, distance_from VARCHAR",
    "test_plan": "hose_type VARCHAR, target_power DOUBLE, failures_needed BIGINT, failures BIGINT, power_now DOUBLE, "
                 "more_hoses_per_adjustment BIGINT, more_km DOUBLE, benches BIGINT, km_per_day DOUBLE, "
                 "capacity_from VARCHAR, expected_decision_date DATE, n_simulations BIGINT, mc_se DOUBLE, note VARCHAR",
}

DECIDED, OPEN, NO_PLAN, NO_ESTIMATE = "FLEXIGOM AIR", "PU 8x6", "NBR <b>10</b>", "SIL 4"
T0 = datetime(2026, 1, 19, 14, 30, tzinfo=timezone.utc)  # look k at T0 + 3k days: the 14th on 2026-03-02


def _looks(hose_type: str, n: int, ratio, decides_at=None, crossed_at=None, spread=0.8, top=40) -> list[dict]:
    """``n`` looks (one failure each) of estimate ``ratio(k)`` with standard error ``spread / sqrt(k)``,
    boundaries falling like O'Brien-Fleming's."""
    rows = []
    for k in range(1, n + 1):
        r = ratio(k)
        se = spread / math.sqrt(k) if r is not None else None
        c = 2.0 * (top / k) ** 0.25
        fut = (math.log(1.25) - c * se) if se is not None else None
        rows.append({"hose_type": hose_type, "look": k, "event_at": T0 + timedelta(days=3 * k), "hose_id": f"H{k}",
                     "failures": k, "n_hoses": 2 * k + 4, "total_km": 100.0 * k, "information_fraction": k / top,
                     "life_ratio": r, "se_log_ratio": se, "z": math.log(r) / se if r else None, "boundary_z": c,
                     "alpha_spent": 0.05 * k / top,
                     "efficacy_lower": math.exp(-c * se) if se else None, "efficacy_upper": math.exp(c * se) if se else None,
                     "futility_lower": math.exp(-fut) if fut and fut > 0 else None,
                     "futility_upper": math.exp(fut) if fut and fut > 0 else None,
                     "rci_lower": r * math.exp(-c * se) if r else None, "rci_upper": r * math.exp(c * se) if r else None,
                     "crossed": "force longer" if k in (decides_at, crossed_at) else None, "decides": k == decides_at,
                     "note": None if r else "an adjustment has no failure yet"})
    return rows


def _verdict(hose_type, verdict, failures, ratio, **extra) -> dict:
    row = {c.split()[0]: None for c in DDL["life_verdict"].split(", ")}
    row.update(hose_type=hose_type, verdict=verdict, margin=1.25, alpha=0.05, power=0.8, confidence=0.9,
               spending="obrien-fleming", max_failures=40, max_failures_from="design", plan_from="hose_type",
               failures=failures, information_fraction=failures / 40, looks=failures, life_ratio=ratio,
               se_log_ratio=0.8 / math.sqrt(max(failures, 1)) if ratio else None)
    row.update(extra)
    return row


def _effect(hose_type, ratio, lower, upper, note=None) -> dict:
    row = {c.split()[0]: None for c in DDL["life_effect"].split(", ")}
    row.update(hose_type=hose_type, n_force=10, n_failed_force=6, n_distance=10, n_failed_distance=8,
               model="common shape" if ratio else None, shape=2.1 if ratio else None, life_ratio=ratio,
               life_ratio_lower=lower, life_ratio_upper=upper, confidence=0.9, note=note)
    return row


def _plan(hose_type, power, needed, have, hoses, when, power_now=0.45, capacity="plan") -> dict:
    return {"hose_type": hose_type, "target_power": power, "failures_needed": needed, "failures": have,
            "power_now": power_now, "more_hoses_per_adjustment": hoses, "more_km": None, "benches": 2,
            "km_per_day": 40.0, "capacity_from": capacity, "expected_decision_date": when, "n_simulations": 2000,
            "mc_se": 0.01, "note": None}


def decision_rows() -> dict[str, list[dict]]:
    """The four hose types of the contract's cases, as table rows."""
    decided_looks = _looks(DECIDED, 16, lambda k: 1.5 + 0.02 * k, decides_at=14)
    return {
        "life_effect": [_effect(DECIDED, 1.82, 1.31, 2.53), _effect(OPEN, 1.3, 0.9, 1.9),
                        _effect(NO_PLAN, 1.4, 1.02, 1.95),
                        _effect(NO_ESTIMATE, None, None, None, "fewer than two failures in an adjustment")],
        "life_verdict": [
            _verdict(DECIDED, "force longer", 16, 1.82, decided_at=datetime(2026, 3, 2, 14, 30, tzinfo=timezone.utc),
                     decided_at_look=14, decided_ratio=1.78, decided_lower=1.12, decided_upper=2.83),
            _verdict(OPEN, "undecided", 29, 1.15),
            _verdict(NO_PLAN, "no plan", 12, 1.4, plan_from="built-in", note="no plan.toml: built-in defaults"),
            _verdict(NO_ESTIMATE, "undecided", 1, None, note="fewer than two failures in an adjustment")],
        "decision_looks": decided_looks + _looks(OPEN, 29, lambda k: 1.15, spread=0.4) + _looks(NO_PLAN, 12, lambda k: 1.4,
                                                                                   crossed_at=9)
        + _looks(NO_ESTIMATE, 1, lambda k: None),
        "decision_look_hoses": [{"hose_type": DECIDED, "look": 1, "hose_id": "H1", "adjustment": "force",
                                 "distance_km": 120.0, "failed": True, "distance_from": "runs"}],
        "test_plan": [_plan(OPEN, 0.8, 40, 29, 6, date(2026, 8, 14)), _plan(OPEN, 0.9, 52, 29, 12, date(2026, 11, 2)),
                      _plan(NO_PLAN, 0.8, 40, 12, 15, None, capacity=None),
                      _plan(NO_PLAN, 0.9, 52, 12, 20, None, capacity=None)],
    }


def make_warehouse(folder: Path, rows: dict[str, list[dict]] | None = None, tables=tuple(DDL)) -> Path:
    """A warehouse folder whose database holds the contract's ``tables`` filled with ``rows``."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = decision_rows() if rows is None else rows
    con = duckdb.connect(str(folder / DB_NAME))
    try:
        for t in tables:
            con.execute(f'CREATE TABLE "{t}" ({DDL[t]})')
            cols = [c.split()[0] for c in DDL[t].split(", ")]
            for r in rows.get(t, []):
                con.execute(f'INSERT INTO "{t}" VALUES ({", ".join("?" * len(cols))})', [r.get(c) for c in cols])
    finally:
        con.close()
    return folder


@pytest.fixture
def wh(tmp_path) -> Path:
    return make_warehouse(tmp_path / "wh")


def _decisions(wh: Path, hose_type=None) -> dict[str, dc.HoseDecision]:
    con = connect_readonly(wh)
    try:
        return {d.hose_type: d for d in dc.read_decisions(con, hose_type)}
    finally:
        con.close()


def test_each_verdict_in_words(wh):
    d = _decisions(wh)
    assert list(d) == sorted([DECIDED, OPEN, NO_PLAN, NO_ESTIMATE])
    assert dc.verdict_words(d[DECIDED]) == (
        "force-set FLEXIGOM AIR hoses live 1.82x longer (90 % CI 1.31-2.53x); decided on 2026-03-02 at the 14th "
        "failure (then 1.78x, repeated 95 % CI 1.12-2.83x)")
    assert dc.verdict_words(d[OPEN]) == ("not yet: PU 8x6 force / distance life ratio 1.3x (90 % CI 0.9-1.9x) after "
                                         "29 of 40 planned failures")
    no_plan = dc.verdict_words(d[NO_PLAN])
    assert no_plan.startswith("no plan.toml: no verdict is declared without the lab's plan (raw/plan.toml); "
                              "NBR <b>10</b> force / distance life ratio 1.4x (90 % CI 1.02-1.95x) after 12 of 40")
    assert no_plan.endswith("under the built-in defaults the 9th failure's data showed 'force longer'")
    assert dc.verdict_words(d[NO_ESTIMATE]) == ("not yet: SIL 4 no estimate of the force / distance life ratio yet "
                                                "after 1 of 40 planned failures")


def test_distance_longer_is_said_the_other_way_round_and_no_difference_with_its_band(wh):
    d = _decisions(wh)[DECIDED]
    flipped = dc.HoseDecision(d.hose_type, {**d.verdict, "verdict": "distance longer", "decided_ratio": 0.5,
                                            "decided_lower": 0.25, "decided_upper": 0.8},
                              {**d.effect, "life_ratio": 0.5, "life_ratio_lower": 0.4, "life_ratio_upper": None},
                              d.looks, [])
    assert dc.verdict_words(flipped) == (
        "distance-set FLEXIGOM AIR hoses live 2x longer (90 % CI up to 2.5x, open below); decided on 2026-03-02 at "
        "the 14th failure (then 2x, repeated 95 % CI 1.25-4x)")
    same = dc.HoseDecision(d.hose_type, {**d.verdict, "verdict": "no practical difference", "decided_ratio": None},
                           {**d.effect, "life_ratio": 1.02, "life_ratio_lower": 0.93, "life_ratio_upper": 1.12},
                           d.looks, [])
    assert dc.verdict_words(same) == ("no practical difference for FLEXIGOM AIR hoses: the force / distance life ratio "
                                      "is within 1/1.25..1.25: 1.02x (90 % CI 0.93-1.12x); decided on 2026-03-02 at "
                                      "the 14th failure")
    # a declared verdict stays while the data go on: an estimate that moved back is said as such
    moved = dc.HoseDecision(d.hose_type, d.verdict, {**d.effect, "life_ratio": 0.97}, d.looks, [])
    assert dc.verdict_words(moved).startswith("force-set FLEXIGOM AIR hoses live longer (declared), but the estimate "
                                              "has since moved to 0.97x (90 % CI 1.31-2.53x); decided on 2026-03-02")
    blank = dc.HoseDecision(d.hose_type, {**d.verdict, "life_ratio": None}, {}, d.looks, [])
    assert dc.verdict_words(blank) == ("force longer: FLEXIGOM AIR no estimate of the force / distance life ratio yet "
                                       "after 16 of 40 planned failures; decided on 2026-03-02 at the 14th failure "
                                       "(then 1.78x, repeated 95 % CI 1.12-2.83x)")
    # without life_effect's estimate the last look's repeated interval is said, named as such
    bare = dc.HoseDecision(d.hose_type, {**d.verdict, "rci_lower": 1.2, "rci_upper": 2.9}, {}, d.looks, [])
    assert dc.verdict_words(bare).startswith("force-set FLEXIGOM AIR hoses live 1.82x longer (repeated 95 % CI 1.2-2.9x)")


def test_information_plan_and_bar(wh):
    d = _decisions(wh)
    assert dc.information_words(d[OPEN]) == "72 % of the information: 29 of 40 failures (maximum from the design)"
    assert dc.text_bar(29 / 40, 20) == "[" + "#" * 14 + "." * 6 + "]"
    assert dc.text_bar(None, 4) == "[....]" and dc.text_bar(1.7, 4) == "[####]"
    assert dc.plan_words(d[OPEN]) == ("11 more failures, about 6 more hoses per adjustment, verdict expected by 2026-08 "
                                      "(80 % power; 45 % chance of a verdict with the hoses on test now); for 90 % "
                                      "power: 23 more failures, about 12 more hoses per adjustment, verdict expected by 2026-11")
    assert dc.plan_words(d[NO_PLAN]).startswith("28 more failures, about 15 more hoses per adjustment, "
                                                "no date (bench capacity unknown) (80 % power")
    assert dc.plan_words(d[DECIDED]) == "decided: no more failures are needed for this verdict"
    assert dc.plan_words(d[NO_ESTIMATE]) == "no test plan for this hose type"
    assert [dc.ordinal(n) for n in (1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st", "111th"]


def test_missing_and_empty_tables_say_so_in_one_line(tmp_path):
    old = make_warehouse(tmp_path / "old", {}, tables=("test_plan",))
    empty = make_warehouse(tmp_path / "empty", {})
    for folder, start in ((old, "no decision tables in this warehouse"), (empty, "no hose type has hoses of both")):
        con = connect_readonly(folder)
        try:
            line = dc.missing_line(con)
            assert line.startswith(start) and "\n" not in line
            assert dc.read_decisions(con) == []
        finally:
            con.close()
        assert dc.decision_text(folder) == line


def test_unknown_hose_type_names_it_and_the_known_ones(wh):
    with pytest.raises(QueryError) as err:
        _decisions(wh, "FLEXIGOM AIRR")
    assert str(err.value) == ("no hose type 'FLEXIGOM AIRR' (did you mean 'FLEXIGOM AIR'?); known: 'FLEXIGOM AIR', "
                              "'NBR <b>10</b>', 'PU 8x6', 'SIL 4'")
    assert list(_decisions(wh, OPEN)) == [OPEN]


def test_the_command_prints_every_hose_type_or_one_with_its_looks(wh, tmp_path):
    narrow = CliRunner().invoke(main, ["decision", "--warehouse", str(wh)], env={"COLUMNS": "72"})
    assert narrow.exit_code == 0 and max(len(x) for x in narrow.output.splitlines()) <= 72
    assert narrow.output.splitlines()[1].startswith("               ")  # wrapped under the text, not the heading
    res = CliRunner().invoke(main, ["decision", "--warehouse", str(wh)], env={"COLUMNS": "400"})
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0].startswith("FLEXIGOM AIR: force-set FLEXIGOM AIR hoses live 1.82x longer")
    assert "  information  [" + "#" * 12 + "." * 18 + "] 40 % of the information: 16 of 40 failures" in res.output
    assert "  looks        16: pneubench decision --hose-type 'FLEXIGOM AIR' lists them" in lines
    assert "  plan         11 more failures, about 6 more hoses per adjustment, verdict expected by 2026-08" in res.output
    assert "  note         fewer than two failures in an adjustment" in lines
    one = CliRunner().invoke(main, ["decision", "--warehouse", str(wh), "--hose-type", DECIDED],
                             env={"COLUMNS": "160"})
    assert one.exit_code == 0 and one.output.startswith("FLEXIGOM AIR: force-set")
    table = one.output[one.output.index("look  "):one.output.index("(16 rows)") + len("(16 rows)")].splitlines()
    assert one.output.rstrip().endswith("`pneubench rebuild` adds it")  # then the running hoses: not computed here
    assert table[0].split() == ["look", "date", "failed", "failures", "info", "ratio", "repeated", "CI", "efficacy",
                                "futility", "crossed", "decides"]
    assert len(table) == 2 + 16 + 1 and table[-1] == "(16 rows)"
    row = table[15].split()
    assert row[:6] == ["14", "2026-03-02", "H14", "14", "35", "%"] and row[-3:] == ["force", "longer", "yes"]
    half = 2 * (40 / 14) ** 0.25 * 0.8 / math.sqrt(14)  # the boundary's c * se at look 14
    assert row[6] == "1.78" and row[7] == f"{1.78 * math.exp(-half):.3g}-{1.78 * math.exp(half):.3g}"
    assert row[8] == f"{math.exp(-half):.3g}-{math.exp(half):.3g}" and math.exp(half) < 1.78  # crossed
    assert "PU 8x6" not in one.output
    bad = CliRunner().invoke(main, ["decision", "--warehouse", str(wh), "--hose-type", "PU 8x7"])
    assert bad.exit_code == 2
    assert bad.output.strip().splitlines() == [
        "pneubench decision: no hose type 'PU 8x7' (did you mean 'PU 8x6'?); known: 'FLEXIGOM AIR', 'NBR <b>10</b>', "
        "'PU 8x6', 'SIL 4'"]
    none = CliRunner().invoke(main, ["decision", "--warehouse", str(tmp_path / "nowhere")])
    assert none.exit_code == 2 and "no warehouse" in none.output
