"""Hose life: runs matched to a hose's installations, distance from runs or odometer, warnings."""
import pandas as pd
import pytest

from analyses.hose_life import hose_distance_at, hose_life, match_runs
from pipeline.raw.logbook import merge_logbooks, read_logbook
from tests.pipeline.raw.test_logbook import HEADER


def ts(text):
    return pd.Timestamp(text, tz="UTC")


def runs(*rows):
    return pd.DataFrame([{"run_id": r, "hose_id": h, "started_at": ts(t), "distance_km": d, "strokes": s}
                         for r, h, t, d, s in rows])


def test_reinstalled_hose_continues_its_life_and_failed_hose_cannot_return(raw):
    raw.write("c/hoses.csv", HEADER +
              "H1,installed,2026-01-01,T,force,,866,,,,\n"
              "H1,removed,2026-01-10,,,,,,,,\n"
              "H1,installed,2026-02-01,T,force,,866,,,,\n"
              "H1,failed,2026-02-10,,,,,rupture,,,\n"
              "H1,installed,2026-03-01,T,force,,866,,,,\n"     # line 6: after failure
              "H2,installed,2026-01-01,T,force,,866,,,,\n"
              "H2,installed,2026-01-02,T,force,,866,,,,\n")    # line 8: already installed
    events, _ = read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")
    hoses, problems = merge_logbooks(events)
    assert sorted(p.line for p in problems) == [6, 8]
    h = hoses.set_index("hose_id")
    assert h.loc["H1", "status"] == "failed" and h.loc["H1", "n_installations"] == 2
    r = runs(("r1", "H1", "2026-01-05", 10.0, 100), ("r2", "H1", "2026-01-20", 99.0, 999),  # r2 in the pause
             ("r3", "H1", "2026-02-05", 5.0, 50), ("r4", "H2", "2025-12-31", 1.0, 1), ("r5", "H7", "2026-01-05", 2.0, 20))
    life, warnings = hose_life(hoses, r)
    L = life.set_index("hose_id")
    assert (L.loc["H1", "distance_km"], L.loc["H1", "strokes"], L.loc["H1", "n_runs"]) == (15.0, 150, 2)
    assert L.loc["H2", "n_runs"] == 0 and L.loc["H2", "distance_km"] == 0.0 and L.loc["H2", "status"] == "running"
    assert set(warnings) == {"r2", "r4", "r5"}
    assert "outside every installation" in warnings["r2"][0]
    assert L.loc["H7", "status"] == "running" and L.loc["H7", "distance_km"] == 2.0
    assert "no hoses.csv" in L.loc["H7", "warnings"][0]


def test_odometer_used_without_runs_and_checked_against_runs(raw):
    raw.write("c/hoses.csv", HEADER +
              "A,installed,2026-01-01,T,distance,4,,,,,\nA,failed,2026-01-09,,,,,rupture,,30.0,\n"
              "B,installed,2026-01-01,T,distance,4,,,,,\nB,removed,2026-01-09,,,,,,,20.0,\n"
              "C,installed,2026-01-01,T,distance,4,,,,,\nC,failed,2026-01-09,,,,,rupture,,10.0,\n"
              "D,installed,2026-01-01,T,distance,4,,,,,\nD,failed,2026-01-09,,,,,rupture,,,\n")
    hoses, _ = merge_logbooks(read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")[0])
    r = runs(("b1", "B", "2026-01-02", 10.0, 10), ("b2", "B", "2026-01-03", 9.9, 10),   # 19.9 vs 20: 0.5 %
             ("c1", "C", "2026-01-02", 11.0, 10))                                      # 11 vs 10: 10 %
    life, _ = hose_life(hoses, r)
    L = life.set_index("hose_id")
    assert (L.loc["A", "distance_km"], L.loc["A", "distance_source"], L.loc["A", "n_runs"]) == (30.0, "odometer", 0)
    assert pd.isna(L.loc["A", "strokes"])
    assert L.loc["B", "distance_km"] == pytest.approx(19.9) and L.loc["B", "warnings"] == []
    assert L.loc["C", "distance_km"] == 11.0 and "+10.0 %" in L.loc["C", "warnings"][0]
    assert pd.isna(L.loc["D", "distance_km"]) and "life unknown" in L.loc["D", "warnings"][0]
    assert list(L["status"]) == ["failed", "removed", "failed", "failed"]


def test_match_runs_and_distance_at_time(raw):
    raw.write("c/hoses.csv", HEADER + "H,installed,2026-01-01,T,force,,866,,,,\nH,failed,2026-01-10,,,,,rupture,,,\n")
    hoses, _ = merge_logbooks(read_logbook(raw.root / "c/hoses.csv", "c/hoses.csv")[0])
    r = runs(("a", "H", "2026-01-02", 1.0, 1), ("b", "H", "2026-01-10", 1.0, 1), ("c", "H", "2026-01-03", 2.5, 1))
    matched, warnings = match_runs(hoses, r)
    assert list(matched) == ["H", None, "H"] and list(warnings) == ["b"]   # the failure time ends the interval
    mine = r[matched == "H"]
    assert hose_distance_at(mine, ts("2026-01-01")) == 0.0
    assert hose_distance_at(mine, ts("2026-01-02T12:00")) == 1.0
    assert hose_distance_at(mine, ts("2026-01-09")) == 3.5


def test_runs_without_any_logbook_give_running_hoses_and_warnings():
    hoses = pd.DataFrame(columns=["hose_id", "intervals"])
    r = runs(("a", "H9", "2026-01-02", 1.5, 10), ("b", None, "2026-01-02", 2.0, 20), ("c", "H9", "2026-01-03", 1.0, float("nan")))
    life, warnings = hose_life(hoses, r)
    assert warnings == {"a": ["hose H9 is in no hoses.csv logbook"], "c": ["hose H9 is in no hoses.csv logbook"]}
    row = life.iloc[0]
    assert (row["hose_id"], row["status"], row["distance_km"], row["strokes"], row["n_runs"]) == ("H9", "running", 2.5, 10, 2)
    assert row["warnings"] == ["hose is in no hoses.csv logbook",
                               "1 of its runs could not be analysed; their distance is missing"]
    empty, none = hose_life(hoses, runs())
    assert empty.empty and none == {}
