"""pipeline/query.py: the read-only door of ``pneubench query`` and the formatting of results."""
from __future__ import annotations

import hashlib
from pathlib import Path

import duckdb
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.query import QueryError, check_sql, run_query
from pipeline.rebuild import rebuild
from pipeline.warehouse import DB_NAME, connect_readonly
from tests.conftest import STEP_META, RawBuilder

T = [0.0, 0.1, 0.2, 0.3]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """A warehouse with two step runs (one campaign), built by the real rebuild."""
    root = tmp_path_factory.mktemp("q")
    raw = RawBuilder(root / "raw")
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": [0, 1e-3, 2e-3, 3e-3], "x_ref[m]": T})
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": [0, 2e-3, 4e-3, 6e-3], "x_ref[m]": T})
    wh = root / "wh"
    summary = rebuild(raw.root, wh, jobs=1)
    assert summary.exit_code == 0
    (root / "secret.txt").write_text("top secret\n")
    return wh


def _digest(folder: Path) -> dict[str, str]:
    """Content hash of every file under ``folder``."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _samples_file(wh: Path) -> Path:
    return next((wh / "samples").rglob("*.parquet"), wh / "samples" / "none.parquet")


def escapes(wh: Path) -> dict[str, str]:
    """Every way out of the door the issue lists (and a few more), by name."""
    db = wh / DB_NAME
    samples = _samples_file(wh)
    secret = wh.parent / "secret.txt"
    return {
        "copy_over_database": f"COPY (SELECT 1 AS a) TO '{db}'",
        "copy_over_samples": f"COPY (SELECT 'x' AS run_id, 1.0 AS t_s) TO '{samples}' (FORMAT parquet)",
        "copy_into_samples_folder": f"COPY (SELECT 1 AS a) TO '{samples.parent / 'new.csv'}'",
        "copy_anywhere": f"COPY (SELECT 1 AS a) TO '{wh.parent / 'out.csv'}'",
        "copy_from": f"COPY runs FROM '{secret}'",
        "export_database": f"EXPORT DATABASE '{wh.parent / 'export'}'",
        "attach_read_write": f"ATTACH '{db}' AS w2 (READ_WRITE)",
        "attach_new": f"ATTACH '{wh / 'samples' / 'x.duckdb'}' AS x",
        "detach": "DETACH pneubench",
        "insert": "INSERT INTO runs (run_id) VALUES ('x')",
        "update": "UPDATE runs SET kind = 'x'",
        "delete": "DELETE FROM runs",
        "create_table": "CREATE TABLE t AS SELECT 1",
        "create_temp": "CREATE TEMP TABLE t AS SELECT 1",
        "drop": "DROP TABLE runs",
        "comment": "COMMENT ON TABLE runs IS 'x'",
        "install": "INSTALL httpfs",
        "load": "LOAD httpfs",
        "set_access": "SET enable_external_access = true",
        "reset_lock": "RESET lock_configuration",
        "set_root": f"SET VARIABLE pneubench_warehouse = '{wh.parent}'",
        "pragma": "PRAGMA enable_profiling",
        "call": "CALL enable_logging()",
        "checkpoint": "CHECKPOINT",
        "transaction": "BEGIN TRANSACTION",
        "two_statements": "SELECT 1; SELECT 2",
        "select_then_copy": f"SELECT 1; COPY (SELECT 1) TO '{wh.parent / 'two.csv'}'",
        "explain_analyze_copy": f"EXPLAIN ANALYZE COPY (SELECT 1) TO '{wh.parent / 'ex.csv'}'",
        "read_csv_passwd": "SELECT * FROM read_csv('/etc/passwd')",
        "read_text_passwd": "SELECT * FROM read_text('/etc/passwd')",
        "read_text_secret": f"SELECT * FROM read_text('{secret}')",
        "read_blob_traversal": f"SELECT * FROM read_blob('{wh / 'samples'}/../../secret.txt')",
        "glob_root": "SELECT * FROM glob('/root/*')",
        "glob_outside": f"SELECT * FROM glob('{wh.parent}/*')",
        "replacement_scan": f"SELECT * FROM '{secret}'",
        "http": "SELECT * FROM read_csv('https://example.com/x.csv')",
    }


ESCAPES = sorted(escapes(Path("/w/wh")))


@pytest.mark.parametrize("name", ESCAPES)
def test_every_escape_fails_and_changes_nothing(built, name):
    sql = escapes(built)[name]
    before = _digest(built.parent)
    with pytest.raises((QueryError, duckdb.Error)):
        run_query(built, sql)
    assert _digest(built.parent) == before
    assert run_query(built, "SELECT count(*) FROM samples_step") == (["count_star()"], [(8,)])


@pytest.mark.parametrize("name", ESCAPES)
def test_every_escape_fails_through_the_cli_with_one_line(built, name):
    sql = escapes(built)[name]
    before = _digest(built.parent)
    res = CliRunner().invoke(main, ["query", sql, "--warehouse", str(built)])
    assert res.exit_code in (2, 3), res.output
    assert res.stdout == ""
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert res.stderr.startswith("pneubench query: ")
    assert _digest(built.parent) == before


def test_refusals_name_what_was_refused(built):
    with pytest.raises(QueryError, match="one statement per call, got 2"):
        run_query(built, "SELECT 1; SELECT 2")
    with pytest.raises(QueryError, match="COPY statement refused: pneubench query is read-only.*--format csv"):
        run_query(built, "COPY runs TO 'x.csv'")
    with pytest.raises(QueryError, match="no SQL"):
        run_query(built, "  \n")
    with pytest.raises(QueryError, match="no SQL statement"):
        run_query(built, "-- just a comment\n;")
    with pytest.raises(duckdb.PermissionException, match="/etc/passwd"):
        run_query(built, "SELECT * FROM read_text('/etc/passwd')")


@pytest.mark.parametrize("sql, expected", [
    ("SELECT run_id FROM runs ORDER BY run_id", [("c/a",), ("c/b",)]),
    ("FROM runs SELECT count(*)", [(2,)]),
    ("WITH r AS (SELECT * FROM runs) SELECT count(*) FROM r", [(2,)]),
    ("SELECT run_id, max(x_m) FROM samples_step GROUP BY run_id ORDER BY run_id", [("c/a", 3e-3), ("c/b", 6e-3)]),
    ("SELECT DISTINCT kind, campaign FROM samples_step", [("step", "c")]),
    ("SELECT count(*) FROM samples_durability", [(0,)]),
    ("SELECT count(*) FROM rebuild_changes", [(2,)]),
    ("SELECT count(*) FROM (DESCRIBE runs) WHERE column_name = 'params'", [(1,)]),
    ("SELECT count(*) > 5 FROM (SHOW TABLES)", [(True,)]),
    ("SELECT count(*) FROM (SUMMARIZE runs) WHERE column_name = 'run_id'", [(1,)]),
    ("SELECT 1;", [(1,)]),
    ("PIVOT (SELECT kind FROM runs) ON kind IN ('step') USING count(*)", [(2,)]),
])
def test_legit_queries_still_work(built, sql, expected):
    assert run_query(built, sql)[1] == expected


def test_explain_of_a_select_works(built):
    cols, rows = run_query(built, "EXPLAIN SELECT count(*) FROM samples_step")
    assert cols and rows
    cols, rows = run_query(built, "EXPLAIN ANALYZE SELECT count(*) FROM runs")
    assert rows


def test_own_samples_files_are_readable_by_path(built):
    f = _samples_file(built)
    cols, rows = run_query(built, f"SELECT count(*) FROM read_parquet('{f}')")
    assert rows == [(4,)]
    cols, rows = run_query(built, f"SELECT count(*) FROM glob('{built / 'samples'}/**/*.parquet')")
    assert rows == [(2,)]


def test_the_door_itself_contains_sql_without_the_statement_check(built):
    """Defence in depth: the connection every reader gets refuses files and settings by itself."""
    con = connect_readonly(built)
    try:
        for sql in ["SELECT * FROM read_text('/etc/passwd')", f"COPY (SELECT 1) TO '{built.parent / 'd.csv'}'",
                    "SET enable_external_access = true", "SET allowed_directories = ['/']",
                    "INSERT INTO runs (run_id) VALUES ('x')", "LOAD httpfs"]:
            with pytest.raises(duckdb.Error):
                con.execute(sql)
        assert not (built.parent / "d.csv").exists()
        assert con.execute("SELECT count(*) FROM runs").fetchone() == (2,)
    finally:
        con.close()


def test_two_doors_and_a_plain_connection_coexist_in_one_process(built):
    plain = duckdb.connect(str(built / DB_NAME), read_only=True)
    a, b = connect_readonly(built), connect_readonly(built)
    try:
        assert a.execute("SELECT count(*) FROM samples_step").fetchone() == (8,)
        assert b.execute("SELECT count(*) FROM runs").fetchone() == (2,)
    finally:
        a.close(), b.close(), plain.close()


def test_check_sql_uses_the_parser_not_text(built):
    con = connect_readonly(built)
    try:
        # a ';' or a keyword inside a string is not a second statement or a COPY
        assert check_sql(con, "SELECT 'a; COPY x TO y' AS s") == "SELECT 'a; COPY x TO y' AS s"
        with pytest.raises(QueryError, match="refused"):
            check_sql(con, "/* SELECT */ DELETE FROM runs")
    finally:
        con.close()


def test_report_renders_through_the_door(built):
    assert (built / "report" / "index.html").is_file()
