"""The ready views of ``schemas/ddl/90_views.sql``, on tables built from the DDL by hand."""
from __future__ import annotations

import duckdb
import pandas as pd
import pytest

from pipeline.warehouse import ddl_comments
from schemas import ddl_statements


def _warehouse(tables: dict[str, list[dict]]) -> duckdb.DuckDBPyConnection:
    """An in-memory warehouse of the whole DDL holding ``tables`` (``{table: rows}``)."""
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    for _name, sql in ddl_statements():
        con.execute(sql)
    for table, rows in tables.items():
        con.register("_rows", pd.DataFrame(rows))
        con.execute(f"INSERT INTO {table} BY NAME SELECT * FROM _rows")
        con.unregister("_rows")
    return con


def _run(run_id: str, kind: str, started_at: str) -> dict:
    """A ``runs`` row with the NOT NULL columns filled."""
    return {"run_id": run_id, "kind": kind, "campaign": "c", "source_path": f"{run_id}.csv",
            "source_sha256": "0" * 64, "n_samples": 10, "started_at": pd.Timestamp(started_at, tz="UTC")}


def _results(con: duckdb.DuckDBPyConnection) -> dict[str, str | None]:
    """``latest_results`` as ``{kind: result}``."""
    return dict(con.execute("SELECT kind, result FROM latest_results").fetchall())


def test_leakage_headline_names_the_pressure_of_the_largest_leak_lowest_on_ties():
    """The largest leak (0.3 l/min) is at 2 and 3 bar, below the 6 bar top plateau: the words name
    2 bar (the lowest pressure of the tied largest leaks), not the top pressure; an older run is not shown."""
    plateaus = [(0, 1.0, 0.01), (1, 3.0, 0.3), (2, 2.0, 0.3), (3, 4.0, 0.05), (4, 6.0, 0.2)]
    con = _warehouse({
        "runs": [_run("c/leak-old", "leakage", "2025-01-01"), _run("c/leak-new", "leakage", "2025-01-02")],
        "leakage_map": [{"run_id": "c/leak-new", "chamber": "A", "plateau": i, "pressure_bar": p, "leak_l_min": q}
                        for i, p, q in plateaus]
        + [{"run_id": "c/leak-old", "chamber": "A", "plateau": 0, "pressure_bar": 1.0, "leak_l_min": 9.0}],
    })
    try:
        assert con.execute("SELECT run_id, result FROM latest_results").fetchall() == [
            ("c/leak-new", "max leak 0.3 l/min at 2.0 bar, 5 plateaus")]
    finally:
        con.close()


def test_step_headlines_say_their_maxima_are_over_all_steps():
    """Overshoot and settling time are the largest of any step (here of different steps): "up to"."""
    con = _warehouse({
        "runs": [_run("c/step", "step", "2025-01-01")],
        "step_response": [{"run_id": "c/step", "step_mm": 20.0, "overshoot_pct": 5.0, "settling_time_s": 1.0},
                          {"run_id": "c/step", "step_mm": -20.0, "overshoot_pct": 2.0, "settling_time_s": 3.0}],
    })
    try:
        assert _results(con) == {"step": "2 steps, overshoot up to 5.0 %, settling up to 3.0 s"}
    finally:
        con.close()


@pytest.mark.parametrize("nrmse, words", [
    ([0.147, 0.143, None], "3 steps between 0.1 and 3.0 bar gauge, 2 fitted"),
    ([None, None, None], "3 steps between 0.1 and 3.0 bar gauge, 0 fitted"),
])
def test_pressure_step_headline(nrmse, words):
    """A pressure_step run has a headline from pressure_steps: its steps, set-point range and fits."""
    steps = [(1.0, 3.0), (3.0, 1.0000000000000002), (0.1, 0.3)]
    con = _warehouse({
        "runs": [_run("c/pstep", "pressure_step", "2025-01-01")],
        "pressure_steps": [{"run_id": "c/pstep", "chamber": "front", "t_step_s": float(i), "p_from_bar": a,
                            "p_to_bar": b, "nrmse_pct": e, "note": None if e is not None else "under the floor"}
                           for i, ((a, b), e) in enumerate(zip(steps, nrmse))],
    })
    try:
        assert _results(con) == {"pressure_step": words}
    finally:
        con.close()


def test_breakaway_forces_in_time_order_and_timeseries_without_headline():
    """Breakaway forces are listed in onset order; a timeseries run has no headline, as the view's
    comment (docs/warehouse.md) says."""
    con = _warehouse({
        "runs": [_run("c/brk", "breakaway", "2025-01-01"), _run("c/ts", "timeseries", "2025-01-01")],
        "breakaway": [{"run_id": "c/brk", "onset_t_s": 2.0, "breakaway_force_n": 7.0},
                      {"run_id": "c/brk", "onset_t_s": 1.0, "breakaway_force_n": 5.0}],
    })
    try:
        assert _results(con) == {"breakaway": "breakaway 5.0, 7.0 N", "timeseries": None}
    finally:
        con.close()
    assert "timeseries" in ddl_comments()["latest_results"]["comment"]
