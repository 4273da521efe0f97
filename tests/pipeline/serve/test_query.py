"""pipeline/serve/query.py: the read-only door of ``pneubench query`` and the formatting of results."""
from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import duckdb
import pandas as pd
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.serve.query import QueryError, check_sql, copy_figures, run_query, run_traces
from pipeline.rebuild.flow import rebuild
from pipeline.warehouse import DB_NAME, build_database, connect_readonly, runs_frame
from tests.conftest import PROJECT_ROOT, STEP_META, RawBuilder, query

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
    code = ("import sys; from pipeline.warehouse import connect_readonly; c = connect_readonly(sys.argv[1]); "
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


# ---------------------------------------------------------------------------------------------
# Query UX (issue 13)

def _cli(built, *args, input=None, env=None):
    return CliRunner().invoke(main, ["query", *args, "--warehouse", str(built)], input=input, env=env)


@pytest.mark.parametrize("args", [[""], ["   \n"], [], ["-"]])
def test_empty_sql_is_a_one_line_usage_error(built, args):
    res = _cli(built, *args, input="")
    assert res.exit_code == 2
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert "Traceback" not in res.output
    assert len(res.stderr.strip().splitlines()) == 1 and "no SQL given" in res.stderr


def test_sql_errors_show_duckdbs_whole_message(built):
    res = _cli(built, "SELECT * FROM runz")
    assert res.exit_code == 3
    assert "Table with name runz does not exist" in res.stderr and 'Did you mean "runs"' in res.stderr
    res = _cli(built, "SELECT run_idd FROM runs")
    assert 'run_idd' in res.stderr and "Candidate bindings" in res.stderr


def test_sql_from_a_file_and_from_stdin(built, tmp_path):
    f = tmp_path / "q.sql"
    f.write_text("-- how many runs\nSELECT count(*) AS n FROM runs;\n")
    res = _cli(built, "-f", str(f), "--format", "csv")
    assert res.exit_code == 0 and res.stdout.splitlines() == ["n", "2"]
    res = _cli(built, "-", "--format", "csv", input="SELECT run_id FROM runs ORDER BY 1")
    assert res.exit_code == 0 and res.stdout.splitlines() == ["run_id", "c/a", "c/b"]
    res = _cli(built, "-f", "-", "--format", "csv", input="SELECT 7 AS x")
    assert res.stdout.splitlines() == ["x", "7"]
    res = _cli(built, "SELECT 1", "-f", str(f))
    assert res.exit_code == 2 and "not both" in res.stderr


LONG = "word " * 60


def test_table_fits_the_terminal_by_wrapping(built):
    res = _cli(built, f"SELECT 'c/a' AS run_id, '{LONG.strip()}' AS notes", env={"COLUMNS": "60"})
    assert res.exit_code == 0
    lines = res.stdout.splitlines()
    assert max(len(x) for x in lines) <= 60
    assert len(lines) > 5  # wrapped, not cut
    # every word is there: nothing is cut off
    assert " ".join(lines).split().count("word") == 60


def test_max_width_zero_shows_everything_on_one_line(built):
    res = _cli(built, f"SELECT '{LONG.strip()}' AS notes", "--max-width", "0", env={"COLUMNS": "40"})
    assert LONG.strip() in res.stdout.splitlines()


def test_max_width_caps_columns(built):
    res = _cli(built, f"SELECT '{LONG.strip()}' AS notes", "--max-width", "12", env={"COLUMNS": "200"})
    assert max(len(x) for x in res.stdout.splitlines()[:-1]) <= 12


def test_formats(built):
    sql = ("SELECT run_id, params, warnings, NULL AS nothing, 'a|b' AS pipe, 1.5 AS x FROM runs "
           "WHERE run_id = 'c/a'")
    res = _cli(built, sql, "--format", "json")
    rows = json.loads(res.stdout)
    assert rows[0]["params"]["kind"] == "step" and rows[0]["params"]["rig"] == "plpa-1"
    warnings = run_query(built, "SELECT warnings FROM runs WHERE run_id = 'c/a'")[1][0][0]
    assert warnings  # a 4-sample step run is too short for step metrics: a list to render
    assert rows[0]["warnings"] == warnings and rows[0]["nothing"] is None and rows[0]["x"] == 1.5
    res = _cli(built, sql, "--format", "csv")
    parsed = list(csv.reader(io.StringIO(res.stdout)))
    assert parsed[0] == ["run_id", "params", "warnings", "nothing", "pipe", "x"]
    assert parsed[1][0] == "c/a" and json.loads(parsed[1][1])["kind"] == "step"
    assert json.loads(parsed[1][2]) == warnings
    assert parsed[1][3] == "" and parsed[1][4] == "a|b" and float(parsed[1][5]) == 1.5
    res = _cli(built, sql, "--format", "markdown")
    lines = res.stdout.splitlines()
    assert lines[0].startswith("| run_id | params |") and lines[1].startswith("|---|")
    assert "a\\|b" in lines[2] and len(lines) == 3
    res = _cli(built, "SELECT run_id FROM runs ORDER BY 1", "--format", "json")
    assert json.loads(res.stdout) == [{"run_id": "c/a"}, {"run_id": "c/b"}]
    res = _cli(built, "SELECT 1 AS a WHERE false", "--format", "json")
    assert json.loads(res.stdout) == []


def test_table_shows_the_first_rows_and_says_how_many_more(built):
    res = _cli(built, "SELECT range AS i FROM range(250)")
    lines = res.stdout.splitlines()
    assert lines[-1].startswith("(100 of 250 rows shown, 150 more")
    assert len(lines) == 2 + 100 + 1
    res = _cli(built, "SELECT range AS i FROM range(250)", "--max-rows", "0")
    assert res.stdout.splitlines()[-1] == "(250 rows)"


# Peak RSS of a grandchild forked by a small wrapper: Linux carries the forking process's memory
# high-water mark across exec into ru_maxrss, so a CLI forked straight from a large pytest
# process would report pytest's size, not its own.
_PEAK = ("import os, subprocess, sys\n"
         "p = subprocess.Popen(sys.argv[1:])\n"
         "_, status, usage = os.wait4(p.pid, 0)\n"
         "print(usage.ru_maxrss, file=sys.stderr)\n"
         "sys.exit(os.waitstatus_to_exitcode(status))\n")


def test_csv_streams_ten_million_rows_in_bounded_memory(built):
    """Peak RSS of the CLI writing a 10 M-row result as CSV stays under 300 MB."""
    code = "import sys; sys.argv[0] = 'pneubench'; from pipeline.cli import main; main()"
    proc = subprocess.Popen([sys.executable, "-c", _PEAK, sys.executable, "-c", code, "query", "--warehouse",
                             str(built), "--format", "csv", "SELECT range AS i, random() AS r FROM range(10000000)"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONPATH": str(PROJECT_ROOT)})
    lines = 0
    last = b""
    while chunk := proc.stdout.read(1 << 20):
        lines += chunk.count(b"\n")
        last = chunk
    err = proc.stderr.read()
    assert proc.wait() == 0, err
    assert lines == 10_000_001
    assert last.splitlines()[-1].startswith(b"9999999,")
    peak_kb = int(err.splitlines()[-1])
    assert peak_kb * 1024 < 300e6, f"peak RSS {peak_kb / 1024:.0f} MB"


def test_tables_lists_science_first_and_marks_internal_ones(built):
    res = CliRunner().invoke(main, ["tables", "--warehouse", str(built)])
    assert res.exit_code == 0
    lines = res.stdout.splitlines()
    names = [x.split()[0] for x in lines]
    internal = [n for n, x in zip(names, lines) if "[internal]" in x]
    assert set(internal) == {"rebuild_log", "rebuild_inputs", "rebuild_changes", "ingest_state", "stage_cache", "samples_files",
                             "figures"}
    assert names.index("runs") < min(names.index(n) for n in internal)
    assert names.index("service_life") < names.index("samples_step") < min(names.index(n) for n in internal)
    runs_line = lines[names.index("runs")]
    assert "2 rows" in runs_line and "One row per ingested run" in runs_line


def test_describe_gives_types_units_and_meaning(built):
    res = CliRunner().invoke(main, ["describe", "leakage_map", "--warehouse", str(built), "--max-width", "0"])
    assert res.exit_code == 0
    line = next(x for x in res.stdout.splitlines() if x.startswith("leak_l_min"))
    assert "DOUBLE" in line and "l/min (ANR)" in line and "plateau mean, l/min ANR" in line
    res = CliRunner().invoke(main, ["describe", "samples_step", "--warehouse", str(built), "--max-width", "0"])
    line = next(x for x in res.stdout.splitlines() if x.startswith("x_m "))
    assert " m " in line and "Carriage position." in line
    res = CliRunner().invoke(main, ["describe", "runz", "--warehouse", str(built)])
    assert res.exit_code == 2 and "did you mean runs" in res.stderr


def test_descriptions_are_in_the_database_for_any_client(built):
    con = duckdb.connect(str(built / DB_NAME), read_only=True)
    try:
        got = con.execute("SELECT comment FROM duckdb_columns() WHERE table_name = 'runs' "
                          "AND column_name = 'campaign'").fetchone()
        assert got == ("first folder under raw/",)
        got = con.execute("SELECT comment FROM duckdb_tables() WHERE table_name = 'rebuild_log'").fetchone()[0]
        assert got.startswith("(internal")
    finally:
        con.close()


@pytest.fixture(scope="module")
def long_run(tmp_path_factory) -> Path:
    """A warehouse with one 20 000-sample step run: x is 0 except one spike of 50 mm at t = 12.345 s."""
    root = tmp_path_factory.mktemp("plot")
    raw = RawBuilder(root / "raw")
    n = 20_000
    t = [i / 1000 for i in range(n)]
    x = [0.05 if i == 12_345 else 0.001 * (i % 7) for i in range(n)]
    raw.csv("c/long.csv", STEP_META, {"t[s]": t, "x[m]": x, "x_ref[m]": [0.0] * n})
    wh = root / "wh"
    rebuild(raw.root, wh, jobs=1, report=False)
    return wh


def test_run_traces_keep_min_and_max_per_pixel_column(long_run):
    kind, traces = run_traces(long_run, "c/long", columns=100)
    assert kind == "step" and set(traces) == {"x_m", "x_ref_m"}
    t, x = traces["x_m"]
    assert len(t) <= 202 and t == sorted(t)
    assert max(x) == 0.05 and t[x.index(0.05)] == pytest.approx(12.345)  # the spike survives
    assert min(x) == 0.0 and t[0] == 0.0 and t[-1] == pytest.approx(19.999)
    kind, traces = run_traces(long_run, "c/long", ["x_m"], columns=20_000)  # short enough: every sample
    assert len(traces["x_m"][0]) == 20_000


@pytest.mark.parametrize("suffix, magic", [(".png", b"\x89PNG"), (".svg", b"<svg"), (".html", b"<!DOCTYPE html")])
def test_plot_command_writes_png_svg_html(long_run, tmp_path, suffix, magic):
    out = tmp_path / f"p{suffix}"
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    data = out.read_bytes()
    assert magic in data[:400]
    if suffix != ".png":
        assert b"<svg" in data and b"c/long" in data


def test_plot_refuses_unknown_runs_and_channels(long_run, tmp_path):
    res = CliRunner().invoke(main, ["plot", "c/lung", "--warehouse", str(long_run), "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 2 and "no run 'c/lung'; did you mean c/long?" in res.stderr
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "p_a_pa",
                                    "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 2 and "no channel p_a_pa" in res.stderr and "x_m" in res.stderr
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-o", str(tmp_path / "a.pdf")])
    assert res.exit_code == 2 and ".png, .svg or .html" in res.stderr
    assert not list(tmp_path.iterdir())


def _figures_warehouse(tmp_path: Path, rows: list[tuple]) -> Path:
    wh = tmp_path / "wh"
    wh.mkdir()
    for _stage, _name, rel, _cap in rows:
        f = wh / rel
        if not f.exists() and ".." not in rel:
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_bytes(b"\x89PNG fake " + rel.encode())
    figs = pd.DataFrame(rows, columns=["stage", "name", "path", "caption"])
    build_database(wh / DB_NAME, wh, {"figures": figs}, runs_frame([]))
    return wh


def test_figures_are_copied_out_of_their_hashed_folders(tmp_path):
    rows = [("durability", "kaplan_meier", "stages/durability/0a1b2c/figures/kaplan_meier.png", "KM curve"),
            ("models", "step", "stages/models/9f8e7d/figures/step.png", "Step responses")]
    wh = _figures_warehouse(tmp_path, rows)
    out = tmp_path / "figs"
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["durability-kaplan_meier.png", "models-step.png"]
    assert (out / "models-step.png").read_bytes() == (wh / rows[1][2]).read_bytes()
    assert "KM curve" in res.stdout


def test_figures_never_copy_from_outside_the_warehouse(tmp_path):
    (tmp_path / "secret.png").write_bytes(b"secret")
    wh = _figures_warehouse(tmp_path, [("x", "evil", "../secret.png", "")])
    with pytest.raises(QueryError, match="not a file of the warehouse"):
        copy_figures(wh, tmp_path / "out")
    assert not (tmp_path / "out" / "x-evil.png").exists()


# ---------------------------------------------------------------------------------------------
# Issue 21: CSV formula injection (item 9), every DuckDB type prints (item 17), the door's limits (item 19)

FORMULAS = ["=HYPERLINK(\"http://x\",\"y\")", "+1+1", "-2+3", "@SUM(1)", "\tx", "\rx"]


def test_query_csv_is_exact_by_default_and_neutralised_with_csv_safe(built):
    cells = ", ".join(f"'{f}' AS f{i}" for i, f in enumerate(FORMULAS))
    sql = f"SELECT {cells}, -1.5 AS neg, 'c/a' AS plain, '=x' AS \"=h\""
    res = _cli(built, sql, "--format", "csv")
    assert res.exit_code == 0, res.stderr
    header, row = list(csv.reader(io.StringIO(res.stdout)))
    assert row == FORMULAS + ["-1.5", "c/a", "=x"] and header[-1] == "=h"  # exact: what the warehouse holds
    res = _cli(built, sql, "--format", "csv", "--csv-safe")
    assert res.exit_code == 0, res.stderr
    header, row = list(csv.reader(io.StringIO(res.stdout)))
    assert row == ["'" + f for f in FORMULAS] + ["-1.5", "c/a", "'=x"] and header[-1] == "'=h"
    assert float(row[-3]) == -1.5  # a number stays a number
    res = _cli(built, sql, "--format", "json", "--csv-safe")
    assert res.exit_code == 2 and "--csv-safe goes with --format csv" in res.stderr


def test_csv_safe_rows_already_in_python_take_the_same_rule():
    from pipeline.serve.query import Result, write_csv

    out = io.StringIO()
    write_csv(Result(["run_id", "x"], ["VARCHAR", "DOUBLE"], iter([[("@SUM(1)", -1.5), ("c/a", 2.0)]])), out,
              safe=True)
    assert list(csv.reader(io.StringIO(out.getvalue()))) == [["run_id", "x"], ["'@SUM(1)", "-1.5"], ["c/a", "2.0"]]


def _all_types_sql() -> str:
    have = {r[0] for r in duckdb.connect().execute("SELECT type_name FROM duckdb_types()").fetchall()}
    bignum = "bignum" if "bignum" in have else "varint" if "varint" in have else None
    cols = {
        "i": "INTERVAL 1 YEAR + INTERVAL 2 MONTH + INTERVAL 3 DAY + INTERVAL 4 HOUR + INTERVAL 5 MICROSECOND",
        "h": "170141183460469231731687303715884105727::HUGEINT",
        "uh": "340282366920938463463374607431768211455::UHUGEINT",
        "d38": "-12345678901234567890123456789.123456789::DECIMAL(38,9)",
        "u": "'a0eebc99-9c0b-4ef8-bb6d-6bb9bd380a11'::UUID", "b": "'\\x00\\xFFab'::BLOB", "bit": "'10101'::BIT",
        "t": "TIME '12:34:56.789'", "ttz": "TIMETZ '12:34:56+02:30'",
        "tns": "TIMESTAMP_NS '2026-01-02 03:04:05.123456789'", "dinf": "DATE 'infinity'",
        "e": "'b'::ENUM('a', 'b')", "l": "[1, NULL, 3]", "s": "{'x': 1, 'y': 'z'}", "m": "MAP {'k': 1.5}",
        "un": "union_value(num := 2)::UNION(num INTEGER, str VARCHAR)", "arr": "[1.5, 2.5]::DOUBLE[2]",
        "n": "NULL", "li": "[INTERVAL 1 DAY]", "nan": "[1.5, 'NaN'::DOUBLE]",
    }
    if bignum:
        cols["bn"] = f"'123456789012345678901234567890123456789012345'::{bignum.upper()}"
    return "SELECT " + ", ".join(f"{v} AS {k}" for k, v in cols.items())


#: What each column must print as (its text in every format; JSON: the value).
EXPECTED_TEXT = {
    "i": "1 year 2 months 3 days 04:00:00.000005", "h": "170141183460469231731687303715884105727",
    "uh": "340282366920938463463374607431768211455", "bit": "10101", "ttz": "12:34:56+02:30",
    "tns": "2026-01-02 03:04:05.123456789", "dinf": "infinity", "u": "a0eebc99-9c0b-4ef8-bb6d-6bb9bd380a11",
    "bn": "123456789012345678901234567890123456789012345",
}


@pytest.mark.parametrize("fmt", ["table", "csv", "json", "markdown"])
def test_every_duckdb_type_prints_in_every_format(built, fmt):
    res = _cli(built, _all_types_sql(), "--format", fmt, "--max-width", "0") if fmt == "table" else \
        _cli(built, _all_types_sql(), "--format", fmt)
    assert res.exit_code == 0, res.stderr
    assert res.stderr == ""
    out = res.stdout
    for col, text in EXPECTED_TEXT.items():
        if col == "bn" and "bn" not in _all_types_sql():
            continue
        assert text in out, (col, text)
    if fmt != "json":  # a DECIMAL(38) exactly (JSON: a number, a double)
        assert "-12345678901234567890123456789.123456789" in out
    if fmt == "json":
        (row,) = json.loads(out)
        assert row["i"] == EXPECTED_TEXT["i"] and row["dinf"] == "infinity" and row["l"] == [1, None, 3]
        assert row["s"] == {"x": 1, "y": "z"} and row["m"] == {"k": 1.5} and row["nan"] == [1.5, None]
        assert row["n"] is None and row["t"] == "12:34:56.789000" and row["arr"] == [1.5, 2.5]
    if fmt == "csv":
        header, row = list(csv.reader(io.StringIO(out)))
        got = dict(zip(header, row))
        assert got["d38"] == "-12345678901234567890123456789.123456789" and got["uh"] == EXPECTED_TEXT["uh"]
        assert got["li"] == '["1 day"]' and got["e"] == "b" and got["n"] == ""


def _cli_process(built, *args, env=None, timeout=120, memory=4 << 30):
    """``pneubench query`` in a child process under an address-space limit (a query that escapes
    its limits cannot take the machine), killed after ``timeout`` seconds."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    code = "import sys; sys.argv[0] = 'pneubench'; from pipeline.cli import main; main()"
    return subprocess.run([sys.executable, "-c", code, "query", "--warehouse", str(built), *args],
                          capture_output=True, text=True, timeout=timeout, preexec_fn=limit,
                          env={**os.environ, "PYTHONPATH": str(PROJECT_ROOT), **(env or {})})


def test_a_statement_that_runs_for_ever_is_stopped_by_the_timeout(built):
    import time

    for args, env in [(["--timeout", "1"], None), ([], {"PNEUBENCH_QUERY_TIMEOUT": "1"})]:
        t0 = time.monotonic()
        res = _cli_process(built, "SELECT count(*) FROM range(1e15::BIGINT)", *args, env=env, timeout=60)
        assert res.returncode == 3, res.stderr
        assert time.monotonic() - t0 < 30
        assert res.stderr.strip().splitlines() == [
            "pneubench query: statement timeout: stopped after 1 s (--timeout SECONDS or $PNEUBENCH_QUERY_TIMEOUT "
            "gives it longer; 0: no timeout)"]
    # the timeout covers the rows as they stream out, too
    res = _cli_process(built, "SELECT range FROM range(1e13::BIGINT)", "--format", "csv", "--timeout", "2",
                       timeout=60)
    assert res.returncode == 3 and "statement timeout" in res.stderr
    # a statement within it is not touched; the default is finite
    res = _cli(built, "SELECT count(*) AS n FROM range(1000)", "--timeout", "5", "--format", "csv")
    assert res.stdout == "n\n1000\n"
    from pipeline.serve.query import TIMEOUT_S
    assert 0 < TIMEOUT_S < float("inf")


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


def test_a_memory_hungry_query_fails_with_one_line_naming_the_limit(built):
    sql = "SELECT list(range) FROM range(30000000)"  # one list: DuckDB cannot spill it
    res = _cli_process(built, sql, "--memory-limit", "50MB", "--format", "csv")
    assert res.returncode == 3, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith("pneubench query: Out of Memory Error") and "memory_limit is 47.6 MiB" in line
    assert "--memory-limit or $PNEUBENCH_QUERY_MEMORY_LIMIT" in line


def test_spill_files_are_capped_by_the_temp_limit(built):
    sql = "SELECT max(r) AS m FROM (SELECT range AS r, random() AS x FROM range(10000000) ORDER BY x)"
    res = _cli_process(built, sql, "--memory-limit", "100MB", "--temp-limit", "20MB", "--format", "csv")
    assert res.returncode == 3, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert "max_temp_directory_size 19.0 MiB" in line and "--temp-limit or $PNEUBENCH_QUERY_TEMP_LIMIT" in line
    # the same sort within a cap it fits: it spills and finishes
    res = _cli_process(built, sql, "--memory-limit", "100MB", "--temp-limit", "2GB", "--format", "csv")
    assert res.returncode == 0 and res.stdout == "m\n9999999\n", res.stderr


# ---------------------------------------------------------------------------------------------
# Issue 25: each command names itself in its errors (item 8); one record per block when a table
# does not fit the terminal (item 14)


def test_describe_plot_and_figures_errors_name_their_command(built, long_run, tmp_path):
    res = CliRunner().invoke(main, ["describe", "runz", "--warehouse", str(built)])
    assert res.exit_code == 2 and res.stderr.startswith("pneubench describe: no table"), res.stderr
    res = CliRunner().invoke(main, ["plot", "c/lung", "--warehouse", str(long_run), "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 2 and res.stderr.startswith("pneubench plot: no run 'c/lung'"), res.stderr
    (tmp_path / "secret.png").write_bytes(b"secret")
    wh = _figures_warehouse(tmp_path, [("x", "evil", "../secret.png", "")])
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(tmp_path / "out")])
    assert res.exit_code == 2 and res.stderr.startswith("pneubench figures: "), res.stderr
    assert "not a file of the warehouse" in res.stderr
    # the query command still names itself
    res = _cli(built, "SELECT * FROM runz")
    assert res.exit_code == 3 and res.stderr.startswith("pneubench query: ")


def test_a_wide_result_shows_one_record_per_block_at_80_columns(built):
    res = _cli(built, "SELECT * FROM runs ORDER BY run_id LIMIT 2", env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.stderr
    lines = res.stdout.splitlines()
    columns = run_query(built, "SELECT * FROM runs LIMIT 0")[0]
    assert lines[0].startswith("-[ RECORD 1 ]") and sum(x.startswith("-[ RECORD ") for x in lines) == 2
    name_w = max(len(c) for c in columns)
    # lines fit 80 columns; only a single word longer than the room (a hash, a path) stays whole
    assert all(len(x) <= 80 or " " not in x.split(" | ", 1)[1] for x in lines)
    sha = run_query(built, "SELECT source_sha256 FROM runs WHERE run_id = 'c/a'")[1][0][0]
    assert f"{'source_sha256':<{name_w}} | {sha}" in lines
    # every column is one `name | value` line of each record (a long value continues below it)
    for c in columns:
        assert sum(x.startswith(f"{c:<{name_w}} | ") for x in lines) == 2, c
    assert f"{'run_id':<{name_w}} | c/a" in lines and f"{'kind':<{name_w}} | step" in lines
    assert lines[-1] == "(2 rows)"
    assert len(lines) < 4 * len(columns)  # was 107 lines for two rows, every cell in a 6-character column


def test_a_result_that_fits_stays_a_table_and_the_format_can_be_forced(built):
    sql = "SELECT run_id, kind, n_samples FROM runs ORDER BY run_id"
    res = _cli(built, sql, env={"COLUMNS": "80"})
    assert res.stdout.splitlines()[0].split() == ["run_id", "kind", "n_samples"]
    res = _cli(built, sql, "--format", "line", env={"COLUMNS": "80"})
    assert res.stdout.splitlines()[:4] == ["-[ RECORD 1 ]---", "run_id    | c/a", "kind      | step",
                                           "n_samples | 4"]
    # --format table asked for by name is a table, wrapped to the terminal however narrow
    res = _cli(built, "SELECT * FROM runs ORDER BY run_id LIMIT 2", "--format", "table", env={"COLUMNS": "80"})
    assert res.stdout.splitlines()[0].split()[:2] == ["run_id", "kind"] and "RECORD" not in res.stdout
    # never wrapping (--max-width 0) or a cap of the user's: a table too
    res = _cli(built, "SELECT * FROM runs ORDER BY run_id LIMIT 2", "--max-width", "0", env={"COLUMNS": "80"})
    assert "RECORD" not in res.stdout and len(res.stdout.splitlines()) == 5


def test_line_format_counts_the_rows_it_does_not_show_and_wraps_long_values(built):
    res = _cli(built, "SELECT run_id FROM runs ORDER BY run_id", "--format", "line", "--max-rows", "1")
    assert res.exit_code == 0
    assert res.stdout.splitlines() == ["-[ RECORD 1 ]", "run_id | c/a",
                                       "(1 of 2 rows shown, 1 more: --max-rows 0 shows all, --format csv streams them)"]
    res = _cli(built, f"SELECT '{LONG.strip()}' AS notes, NULL AS nothing, 'a\nb' AS two", "--format", "line",
               env={"COLUMNS": "40"})
    lines = res.stdout.splitlines()
    assert max(len(x) for x in lines) <= 40 and lines[1].startswith("notes   | word")
    assert all(x.startswith("notes   | ") or x.startswith("        | ") for x in lines[1:-4])
    assert " ".join(lines).split().count("word") == 60  # wrapped, nothing cut
    assert lines[-4:] == ["nothing | NULL", "two     | a", "        | b", "(1 row)"]


def test_line_format_streams_records_as_they_come():
    from pipeline.serve.query import Result, write_result

    fetched = []

    def batches():
        for k in range(3):
            fetched.append(k)
            yield [(k, "x" * 5)]

    out = io.StringIO()

    class Spy(io.StringIO):
        def write(self, s):
            if "RECORD 1 " in s:
                assert fetched == [0]  # written before the next batch is read
            return out.write(s)

    n = write_result(Result(["i", "s"], ["INTEGER", "VARCHAR"], batches()), Spy(), "line", max_rows=0)
    assert n == 3 and out.getvalue().count("-[ RECORD") == 3 and out.getvalue().endswith("(3 rows)\n")


# -- issue 25 items 10, 13: `plot` shows the report's units and reads h:mm:ss past an hour ---------------
@pytest.fixture(scope="module")
def hour_run(tmp_path_factory) -> Path:
    """A step run logged at 1 Hz for 2 h 10 min, position written in mm (x 0..40 mm)."""
    root = tmp_path_factory.mktemp("hplot")
    raw = RawBuilder(root / "raw")
    n = 7_800
    raw.csv("c/hour.csv", STEP_META, {"t[s]": list(range(n)), "x[mm]": [40.0 * (i % 600 > 300) for i in range(n)],
                                      "x_ref[mm]": [40.0 * (i % 600 > 300) for i in range(n)]})
    wh = root / "wh"
    rebuild(raw.root, wh, jobs=1, report=False)
    return wh


def _svg_text(path: Path) -> list[str]:
    """The texts of a matplotlib SVG (each glyph run is preceded by a comment with its text)."""
    return [t.strip() for t in re.findall(r"<!-- (.*?) -->", path.read_text(), flags=re.S)]


def test_plot_shows_mm_and_h_mm_ss_past_an_hour(hour_run, long_run, tmp_path):
    out = tmp_path / "h.svg"
    res = CliRunner().invoke(main, ["plot", "c/hour", "--warehouse", str(hour_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    texts = _svg_text(out)
    assert ["x", "[mm]"] == texts[texts.index("x"):texts.index("x") + 2]
    assert "t [h:mm:ss]" in texts and {"0:00:00", "1:00:00", "2:00:00"} <= set(texts)
    assert "40" in texts and not any("e+" in t or "1e4" in t or "[m]" in t for t in texts), texts
    steps = query(hour_run, "SELECT count(*) FROM step_response WHERE run_id = 'c/hour'")[0][0]
    assert steps > 0 and "set-point step" in texts  # the steps the analysis found, with a legend
    assert out.read_text().count('stroke-dasharray') >= steps
    out = tmp_path / "s.svg"  # a short run keeps seconds
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    texts = _svg_text(out)
    assert "t [s]" in texts and "[mm]" in texts and "40" in texts and not any(":" in t for t in texts[1:])
