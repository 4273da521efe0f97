"""pipeline/warehouse.py: the samples views do not depend on where the warehouse sits (the root
variable); the DDL's descriptions."""
from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import pytest

from pipeline.rebuild.flow import rebuild
from pipeline.serve.query import run_query
from pipeline.warehouse import DB_NAME, ROOT_VARIABLE
from tests.conftest import STEP_META, RawBuilder


T = [0.0, 0.1, 0.2]


def _step(raw: RawBuilder, rel: str, scale: float = 1.0) -> None:
    raw.csv(rel, STEP_META, {"t[s]": T, "x[m]": [0.0, 1e-3 * scale, 2e-3 * scale], "x_ref[m]": T})


def _build(raw: RawBuilder, wh: Path) -> Path:
    summary = rebuild(raw.root, wh, jobs=1, report=False)
    assert summary.exit_code == 0, summary
    return wh


def _samples(wh: Path) -> list[tuple]:
    return run_query(wh, "SELECT run_id, kind, campaign, t_s, x_m FROM samples_step ORDER BY ALL")[1]


def _expected(runs: dict[str, float]) -> list[tuple]:
    rows = []
    for run_id, scale in runs.items():
        for t, x in zip(T, [0.0, 1e-3 * scale, 2e-3 * scale]):
            rows.append((run_id, "step", run_id.split("/")[0], t, x))
    return sorted(rows)


@pytest.mark.parametrize("where", ["campaign=archive/wh", "run_id=EVIL/t_s=0/wh", "kind=leakage/wh", "wh[1]/w*h"])
def test_folders_above_the_warehouse_change_nothing(tmp_path, where):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / where)
    assert _samples(wh) == _expected({"c/a": 1.0})


def test_campaign_names_read_back_verbatim(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    names = {"lab%41b": 1.0, "rig=2": 2.0, "campaign=x": 3.0, "plain": 4.0, "x*": 5.0, "x1": 6.0, "b[1]": 7.0}
    for name, scale in names.items():
        _step(raw, f"{name}/a.csv", scale)
    wh = _build(raw, tmp_path / "wh")
    assert _samples(wh) == _expected({f"{n}/a": s for n, s in names.items()})
    counts = dict(run_query(wh, "SELECT campaign, count(*) FROM samples_step GROUP BY campaign")[1])
    assert counts == {n: 3 for n in names}


def test_moved_warehouse_reads_its_files(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    moved = tmp_path / "elsewhere" / "wh2"
    moved.parent.mkdir()
    shutil.move(wh, moved)
    assert _samples(moved) == _expected({"c/a": 1.0})


def test_copied_warehouse_reads_its_own_files_after_the_original_is_gone(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    copy = tmp_path / "copy"
    shutil.copytree(wh, copy)
    # the copy's own samples differ from the original's: a copy that read the original would show it
    for f in (wh / "samples").rglob("*.parquet"):
        f.write_bytes(b"not parquet")
    assert _samples(copy) == _expected({"c/a": 1.0})
    shutil.rmtree(wh)
    assert _samples(copy) == _expected({"c/a": 1.0})


def test_rebuild_after_a_move_works(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    shutil.move(wh, tmp_path / "wh2")
    _step(raw, "c/b.csv", 2.0)
    wh2 = _build(raw, tmp_path / "wh2")
    assert _samples(wh2) == _expected({"c/a": 1.0, "c/b": 2.0})


def test_plain_duckdb_client_needs_the_variable_and_says_so(tmp_path, monkeypatch):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    monkeypatch.chdir(tmp_path)
    con = duckdb.connect(str(wh / DB_NAME), read_only=True)
    try:
        with pytest.raises(duckdb.Error, match=f"SET VARIABLE {ROOT_VARIABLE}"):
            con.execute("SELECT * FROM samples_step").fetchall()
        con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [str(wh)])
        assert con.execute("SELECT count(*) FROM samples_step").fetchone() == (3,)
        assert con.execute("SELECT count(*) FROM runs").fetchone() == (1,)
    finally:
        con.close()


def test_glob_escape_in_python_and_in_sql_agree():
    """The door allows the glob-escaped samples folder and the views list glob-escaped paths: the
    two escapes must be the same, else a warehouse under ``wh[1]`` could not read its own files."""
    from pipeline.warehouse import ROOT_SQL, glob_escape

    folder = "/lab/wh[1]/a*b?c"
    assert glob_escape(folder) == "/lab/wh[[]1]/a[*]b[?]c"
    con = duckdb.connect()
    try:
        con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [folder])
        assert con.execute(f"SELECT {ROOT_SQL}").fetchone()[0] == glob_escape(folder)
    finally:
        con.close()


def test_ddl_comments_give_a_tables_block_and_its_columns_lines():
    from pipeline.warehouse import CONTRACT_ROWS, INTERNAL_TABLES, ddl_comments

    described = ddl_comments()
    assert described["runs"]["columns"]["campaign"] == "first folder under raw/"
    assert set(INTERNAL_TABLES) - {"samples_files"} <= set(described)  # every internal table is in the DDL
    assert all(isinstance(v, str) and v for v in CONTRACT_ROWS.values())


def test_the_ddls_tables_are_kept_in_the_warehouse_by_the_ddl_and_duckdb_version(tmp_path, monkeypatch):
    """Issue 26: the in-memory instance built from the DDL (~0.08 CPU-s of every change) is built once
    per DDL and DuckDB version; a damaged, foreign or symlinked file is built again, never trusted."""
    import os

    import pipeline.warehouse as wh

    built = wh.ddl_tables()
    assert "runs" in built and all(v.startswith("CREATE TABLE") for v in built.values())
    assert wh.ddl_tables(tmp_path) == built
    (path,) = (tmp_path / wh.CACHE_DIR).iterdir()
    assert wh.DDL_TABLES_FILE.fullmatch(path.name)
    calls = []
    real = wh._ddl_tables_built
    monkeypatch.setattr(wh, "_ddl_tables_built", lambda st: calls.append(1) or real(st))
    assert wh.ddl_tables(tmp_path) == built and calls == []  # read, not built
    for bad in ('{"runs": "DROP TABLE x"}', "not json", "{}", '["CREATE TABLE a (x INTEGER)"]'):
        path.write_text(bad)
        assert wh.ddl_tables(tmp_path) == built
    assert len(calls) == 4 and wh.ddl_tables(tmp_path) == built and len(calls) == 4  # written back whole
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text('{"runs": "CREATE TABLE runs (x INTEGER)"}')
    path.unlink()
    os.symlink(elsewhere, path)  # not followed: built again, the link replaced by the file
    assert wh.ddl_tables(tmp_path) == built and len(calls) == 5 and not path.is_symlink()
    stale = tmp_path / wh.CACHE_DIR / ("ddl-tables-" + "0" * 32 + ".json")
    stale.write_text("{}")
    path.unlink()
    wh.ddl_tables(tmp_path)
    assert sorted(p.name for p in (tmp_path / wh.CACHE_DIR).iterdir()) == [path.name]  # another key's: removed


def test_table_sums_count_rows_and_follow_their_content():
    """One ``<rows>-<hash sum>`` per table; equal rows give equal sums, a changed row another; names
    with quotes are quoted (``sql_str``)."""
    import duckdb

    from pipeline.warehouse import sql_str, table_sums

    assert sql_str("it's") == "'it''s'"
    con = duckdb.connect(":memory:")
    try:
        con.execute("CREATE TABLE a (x INTEGER, s VARCHAR)")
        con.execute("INSERT INTO a VALUES (1, 'p'), (2, 'q')")
        con.execute("CREATE TABLE \"b'c\" (x INTEGER, s VARCHAR)")
        con.execute("INSERT INTO \"b'c\" VALUES (2, 'q'), (1, 'p')")     # the same rows, another order
        con.execute("CREATE TABLE e (x INTEGER)")
        got = table_sums(con, ["a", "b'c", "e"])
        assert got["a"].startswith("2-") and got["a"] == got["b'c"] and got["e"] == "0-0"
        con.execute("UPDATE a SET s = 'r' WHERE x = 2")
        assert table_sums(con, ["a"])["a"] != got["a"]
        assert table_sums(con, []) == {}
    finally:
        con.close()
