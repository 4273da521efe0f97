"""pipeline/serve/door.py: the one read-only, contained connection; every way out of it fails
(issue 21), its temp folder is private, its memory and spill files are limited."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import duckdb
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.serve.door import DoorSettingError, UnreadableDatabase, check_environment, connect_readonly
from pipeline.serve.query import QueryError, run_query
from pipeline.warehouse import DB_NAME
from tests.conftest import PROJECT_ROOT
from tests.pipeline.serve.conftest import _cli


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
        "read_blob_database": f"SELECT * FROM read_blob('{db}')",
        "read_blob_database_via_samples": f"SELECT size FROM read_blob('{wh / 'samples'}/../{DB_NAME}')",
        "read_text_database_glob": f"SELECT * FROM read_text('{wh}/*.duckdb')",
        "read_csv_database": f"SELECT * FROM read_csv('{db}', delim = '\x01', header = false, strict_mode = false)",
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
    lines = res.stderr.strip().splitlines()
    assert res.stderr.startswith("pneubench query: ")
    # refusals and permission errors are one line; a file named as a table is simply not there
    # (DuckDB's catalog error, shown whole with its "Did you mean")
    assert len(lines) == 1 or lines[0].startswith("pneubench query: Catalog Error: Table with name"), res.stderr
    assert _digest(built.parent) == before


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


def test_the_database_is_attached_through_a_name_that_is_gone(built):
    """DuckDB allows SQL to read the files of an attached database: the door attaches it through
    a private link it removes at once, so the allowed path names nothing (issue 21, item 8)."""
    con = connect_readonly(built)
    try:
        allowed = con.execute("SELECT value FROM duckdb_settings() WHERE name = 'allowed_paths'").fetchone()[0]
        assert str(built / DB_NAME) not in allowed
        (path,) = con.execute("SELECT path FROM duckdb_databases() WHERE database_name = 'pneubench'").fetchone()
        assert not Path(path).exists() and Path(path).parent.stat().st_mode & 0o777 == 0o700
        try:  # nothing there: no rows, or "No files found"
            assert con.execute(f"SELECT * FROM read_blob('{path}')").fetchall() == []
        except duckdb.IOException as exc:
            assert "No files found" in str(exc)
        assert con.execute("SELECT count(*) FROM samples_step").fetchone() == (8,)
    finally:
        con.close()


def test_temp_folder_is_private_to_the_process(built, tmp_path, monkeypatch):
    """A folder another user planted where the old fixed temp folder was (a symlink to theirs)
    is not readable through the door; the temp folder is made by mkdtemp, mode 0700, per
    process (issue 21, item 7)."""
    import tempfile

    systmp = tmp_path / "systmp"
    theirs = tmp_path / "theirs"
    systmp.mkdir(), theirs.mkdir()
    (theirs / "planted.txt").write_text("planted by another user\n")
    (systmp / "pneubench-duckdb").symlink_to(theirs, target_is_directory=True)
    monkeypatch.setattr(tempfile, "tempdir", str(systmp))
    with pytest.raises(duckdb.PermissionException):
        run_query(built, f"SELECT * FROM read_text('{systmp}/pneubench-duckdb/planted.txt')")
    con = connect_readonly(built)
    try:
        temp = Path(con.execute("SELECT current_setting('temp_directory')").fetchone()[0])
    finally:
        con.close()
    assert temp.parent.name.startswith("pneubench-door-") and temp.parent.stat().st_mode & 0o777 == 0o700
    assert temp.parent.stat().st_uid == os.getuid()
    assert not temp.exists()  # DuckDB made it only to spill, and removed it on close
    # another process gets another folder
    code = ("import sys; from pipeline.serve.door import connect_readonly; c = connect_readonly(sys.argv[1]); "
            "print(c.execute(\"SELECT current_setting('temp_directory')\").fetchone()[0])")
    other = subprocess.run([sys.executable, "-c", code, str(built)], capture_output=True, text=True, check=True,
                           env={**os.environ, "PYTHONPATH": str(PROJECT_ROOT)})
    assert Path(other.stdout.strip()).parent != temp.parent
    assert not Path(other.stdout.strip()).parent.exists()  # removed when that process ended


def test_two_doors_and_a_plain_connection_coexist_in_one_process(built):
    plain = duckdb.connect(str(built / DB_NAME), read_only=True)
    a, b = connect_readonly(built), connect_readonly(built)
    try:
        assert a.execute("SELECT count(*) FROM samples_step").fetchone() == (8,)
        assert b.execute("SELECT count(*) FROM runs").fetchone() == (2,)
    finally:
        a.close(), b.close(), plain.close()


def test_report_renders_through_the_door(built):
    assert (built / "report" / "index.html").is_file()


def test_memory_limit_default_option_and_environment(built):
    def setting(*args, env=None):
        res = _cli(built, "SELECT current_setting('memory_limit') AS m, "
                   "current_setting('max_temp_directory_size') AS t", "--format", "json", *args, env=env)
        assert res.exit_code == 0, res.stderr
        return json.loads(res.stdout)[0]

    assert setting() == {"m": "1.8 GiB", "t": "9.3 GiB"}  # 2GB and 10GB: the documented defaults
    assert setting("--memory-limit", "300MB", "--temp-limit", "20MB") == {"m": "286.1 MiB", "t": "19.0 MiB"}
    assert setting(env={"PNEUBENCH_QUERY_MEMORY_LIMIT": "300MB", "PNEUBENCH_QUERY_TEMP_LIMIT": "1GB"}) == \
        {"m": "286.1 MiB", "t": "953.6 MiB"}
    res = _cli(built, "SELECT 1", "--memory-limit", "lots")
    assert res.exit_code == 2 and "memory_limit 'lots'" in res.stderr


@pytest.mark.parametrize("env, value", [("PNEUBENCH_QUERY_MEMORY_LIMIT", "abc"), ("PNEUBENCH_QUERY_TEMP_LIMIT", "lots"),
                                        ("PNEUBENCH_QUERY_TIMEOUT", "soon"), ("PNEUBENCH_QUERY_TIMEOUT", "-1"),
                                        ("PNEUBENCH_QUERY_TIMEOUT", "nan")])
def test_check_environment_refuses_a_bad_variable_naming_it_and_its_value(monkeypatch, env, value):
    monkeypatch.setenv(env, value)
    with pytest.raises(DoorSettingError, match=rf"^\${env} = '{value}': not a "):
        check_environment()
    check_environment(overridden=(env,))  # an option replaces it: not read, not checked


def test_check_environment_takes_good_unset_and_empty_variables(monkeypatch):
    monkeypatch.setenv("PNEUBENCH_QUERY_MEMORY_LIMIT", "300MB")
    monkeypatch.setenv("PNEUBENCH_QUERY_TEMP_LIMIT", "")
    monkeypatch.setenv("PNEUBENCH_QUERY_TIMEOUT", "0")
    check_environment()


@pytest.mark.parametrize("content", [b"", os.urandom(40_000)], ids=["empty", "random"])
def test_a_damaged_database_is_named_by_its_own_path(tmp_path, content):
    (tmp_path / DB_NAME).write_bytes(content)
    with pytest.raises(UnreadableDatabase) as err:
        connect_readonly(tmp_path)
    text = str(err.value)
    assert err.value.path == tmp_path / DB_NAME and "\n" not in text
    assert text.startswith(f"{tmp_path / DB_NAME} is not a readable DuckDB database (") and "pneubench rebuild" in text
    assert "pneubench-door-" not in text  # not the door's private link (was /tmp/pneubench-door-*/db-0.duckdb)
