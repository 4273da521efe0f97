"""What a new warehouse carries over: a finding's last change (one rule, applied by the incremental
path in pandas and by the no-op in the database, with the same result) and ``rebuild_log``."""
from datetime import datetime, timezone

import duckdb
import pandas as pd
import pytest

from pipeline.rebuild.history import (HISTORY_ROWS, append_log, append_log_in_database, carry_findings,
                                      compare_findings, finding_change, numbered_history)

T1 = datetime(2026, 3, 1, 2, 30, tzinfo=timezone.utc)
T2 = datetime(2026, 3, 2, 2, 30, tzinfo=timezone.utc)


@pytest.mark.parametrize("before, holds, change", [
    (True, False, "overturned"), (False, True, "now holds"), (None, True, "new data"), (None, False, "new data"),
    (True, None, "no longer checkable"), (False, None, "no longer checkable")])
def test_a_change_of_holds_is_the_new_change_at_the_rebuilds_start(before, holds, change):
    assert finding_change(before, holds, ("overturned", T1), T2) == (change, T2)


@pytest.mark.parametrize("holds", [True, False, None])
def test_holds_unchanged_carries_the_last_change_only_when_it_is_complete(holds):
    assert finding_change(holds, holds, ("overturned", T1), T2) == ("overturned", T1)
    assert finding_change(holds, holds, ("overturned", None), T2) == (None, None)
    assert finding_change(holds, holds, (None, T1), T2) == (None, None)


def test_the_noop_in_the_database_equals_compare_findings_of_the_warehouse_with_itself():
    findings = pd.DataFrame({"finding_id": ["a", "b", "c", "d"],
                             "holds": pd.array([True, False, None, True], dtype="boolean")})
    changes = {"a": ("overturned", T1), "b": (None, None), "c": ("new data", None), "d": ("now holds", T1)}
    expected = compare_findings(findings, dict(zip(findings["finding_id"], [True, False, None, True])), True,
                                changes, T2)
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    con.execute("CREATE TABLE findings (finding_id VARCHAR, holds BOOLEAN, previous_holds BOOLEAN, change VARCHAR, "
                "changed_at TIMESTAMPTZ)")
    con.executemany("INSERT INTO findings VALUES (?, ?, NULL, ?, ?)",
                    [[f, h, *changes[f]] for f, h in zip("abcd", [True, False, None, True])])
    carry_findings(con, T2)
    got = con.execute("SELECT finding_id, holds, previous_holds, change, changed_at FROM findings "
                      "ORDER BY finding_id").fetchall()
    want = [(r.finding_id, None if pd.isna(r.holds) else bool(r.holds),
             None if pd.isna(r.previous_holds) else bool(r.previous_holds),
             None if pd.isna(r.change) else r.change, None if pd.isna(r.changed_at) else r.changed_at.to_pydatetime())
            for r in expected.itertuples()]
    assert got == want
    assert [g[3] for g in got] == ["overturned", None, None, "now holds"]


def test_the_log_keeps_the_last_rows_numbered_in_both_paths():
    old = pd.DataFrame({"generation": [f"g{i}" for i in range(HISTORY_ROWS)]})  # a log from before ``seq``
    assert list(numbered_history(old)["seq"]) == list(range(1, HISTORY_ROWS + 1))
    assert numbered_history(None) is None and numbered_history(old.iloc[:0]) is None
    new = append_log(old, {"generation": "new"})
    assert len(new) == HISTORY_ROWS and new["generation"].iloc[-1] == "new" and new["seq"].iloc[-1] == HISTORY_ROWS + 1
    assert list(append_log(None, {"generation": "first"})["seq"]) == [1]
    con = duckdb.connect()
    con.execute("CREATE TABLE rebuild_log (generation VARCHAR, seq BIGINT)")
    con.executemany("INSERT INTO rebuild_log VALUES (?, ?)", [[g, s] for g, s in zip(new["generation"], new["seq"])])
    append_log_in_database(con, {"generation": "noop"})
    rows = con.execute("SELECT generation, seq FROM rebuild_log ORDER BY rowid").fetchall()
    assert len(rows) == HISTORY_ROWS and rows[-1] == ("noop", HISTORY_ROWS + 2) and rows[0][1] == 3
