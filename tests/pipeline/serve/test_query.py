"""pipeline/serve/query.py: one read-only statement, checked by DuckDB's parser; its limits
(timeout, memory), every DuckDB type printable, errors in one line naming the command."""
from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys

import duckdb
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.rebuild.flow import rebuild
from pipeline.serve.door import connect_readonly
from pipeline.serve.query import QueryError, check_sql, open_query, run_query
from tests.conftest import PROJECT_ROOT, STEP_META, RawBuilder
from tests.pipeline.serve.conftest import T, _cli, _figures_warehouse


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


def test_check_sql_uses_the_parser_not_text(built):
    con = connect_readonly(built)
    try:
        # a ';' or a keyword inside a string is not a second statement or a COPY
        assert check_sql(con, "SELECT 'a; COPY x TO y' AS s") == "SELECT 'a; COPY x TO y' AS s"
        with pytest.raises(QueryError, match="refused"):
            check_sql(con, "/* SELECT */ DELETE FROM runs")
    finally:
        con.close()


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


def test_a_memory_hungry_query_fails_with_one_line_naming_the_limit(built):
    sql = "SELECT list(range) FROM range(30000000)"  # one list: DuckDB cannot spill it
    res = _cli_process(built, sql, "--memory-limit", "50MB", "--format", "csv")
    assert res.returncode == 3, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith("pneubench query: Out of Memory Error") and "memory_limit is 47.6 MiB" in line
    assert "--memory-limit or $PNEUBENCH_QUERY_MEMORY_LIMIT" in line


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc/self/statm: Linux")
def test_a_statement_too_big_to_plan_stops_at_the_address_space_limit_which_is_given_back(built, monkeypatch):
    """DuckDB's memory_limit bounds its buffers, not planning: 20,000 UNION ALL terms took 10.6 GB
    before the door limited the process's address space while a statement runs."""
    import resource

    from pipeline.serve import query
    from pipeline.serve.query import QueryLimitError, _size_bytes

    assert _size_bytes("1.8 GiB") == int(1.8 * (1 << 30)) and _size_bytes("47.6 MiB") == int(47.6 * (1 << 20))
    assert _size_bytes("2GB") is None and _size_bytes("x GiB") is None and _size_bytes("10 parsecs") is None
    before = resource.getrlimit(resource.RLIMIT_AS)
    monkeypatch.setattr(query, "ADDRESS_HEADROOM", 512 << 20)  # the test's process grows 0.5 GB, not 4
    sql = "SELECT 1 AS one" + " UNION ALL SELECT 1" * 20000
    with pytest.raises(QueryLimitError) as caught:
        run_query(built, sql, memory_limit="50MB")
    (line,) = str(caught.value).splitlines()
    assert line.startswith("Out of Memory Error") and "memory_limit is 47.6 MiB" in line and "0 GiB more" in line
    assert resource.getrlimit(resource.RLIMIT_AS) == before
    # an ordinary statement under the same limit runs
    assert run_query(built, "SELECT 1 AS one UNION ALL SELECT 2", memory_limit="50MB")[1] == [(1,), (2,)]
    assert resource.getrlimit(resource.RLIMIT_AS) == before


def test_spill_files_are_capped_by_the_temp_limit(built):
    sql = "SELECT max(r) AS m FROM (SELECT range AS r, random() AS x FROM range(10000000) ORDER BY x)"
    res = _cli_process(built, sql, "--memory-limit", "100MB", "--temp-limit", "20MB", "--format", "csv")
    assert res.returncode == 3, res.stderr
    (line,) = res.stderr.strip().splitlines()
    assert "max_temp_directory_size 19.0 MiB" in line and "--temp-limit or $PNEUBENCH_QUERY_TEMP_LIMIT" in line
    # the same sort within a cap it fits: it spills and finishes
    res = _cli_process(built, sql, "--memory-limit", "100MB", "--temp-limit", "2GB", "--format", "csv")
    assert res.returncode == 0 and res.stdout == "m\n9999999\n", res.stderr


def test_the_samples_macro_says_in_one_line_when_no_run_has_that_id(tmp_path):
    """A run_id the warehouse has no samples for: a QueryError that says so, not DuckDB's "No files
    found that match the pattern" with the warehouse's glob; through the CLI, one line and exit 2."""
    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    raw.csv("c/a.csv", STEP_META, {"t[s]": T[:3], "x[mm]": [1, 2, 3], "x_ref[mm]": [3] * 3})
    rebuild(raw.root, wh, jobs=1, report=False)
    with pytest.raises(QueryError, match=r"^samples\('<run_id>'\) found no samples file"):
        run_query(wh, "SELECT * FROM samples('c/nope')")
    for arrow in (True, False):
        with pytest.raises(QueryError, match="found no samples file"):
            with open_query(wh, "select count(*) from SAMPLES ('nope')", arrow=arrow) as _:
                pass
    with pytest.raises(duckdb.Error, match="Permission Error"):  # other SQL keeps DuckDB's words
        run_query(wh, "SELECT * FROM read_parquet('samples/none-*.parquet')")
    assert run_query(wh, "SELECT count(*) FROM samples_step WHERE run_id = 'nope'")[1] == [(0,)]
    res = CliRunner().invoke(main, ["query", "--warehouse", str(wh), "SELECT * FROM samples('nope')"])
    assert res.exit_code == 2 and "found no samples file" in res.output and len(res.output.strip().splitlines()) == 1
    assert len(run_query(wh, "SELECT * FROM samples('c/a')")[1]) == 3


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
