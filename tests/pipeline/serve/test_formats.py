"""pipeline/serve/formats.py: the result as a table fitted to the terminal, one record per block,
CSV (streamed, exact, or neutralised for spreadsheets), JSON and Markdown."""
from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys

from pipeline.serve.formats import write_csv, write_result
from pipeline.serve.query import Result, run_query
from tests.conftest import PROJECT_ROOT
from tests.pipeline.serve.conftest import _cli


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
    out = io.StringIO()
    write_csv(Result(["run_id", "x"], ["VARCHAR", "DOUBLE"], iter([[("@SUM(1)", -1.5), ("c/a", 2.0)]])), out,
              safe=True)
    assert list(csv.reader(io.StringIO(out.getvalue()))) == [["run_id", "x"], ["'@SUM(1)", "-1.5"], ["c/a", "2.0"]]


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


def test_auto_with_no_rows_follows_the_same_rule_as_with_rows(built):
    # the headers alone of a wide result would wrap at 80 columns (to 6 characters): one record per
    # block, as with rows (was a table of wrapped headers ~200 characters wide)
    res = _cli(built, "SELECT * FROM runs WHERE false", env={"COLUMNS": "80"})
    assert res.exit_code == 0, res.stderr
    assert res.stdout.splitlines() == ["(0 rows)"]
    # headers that fit stay a table
    res = _cli(built, "SELECT run_id, kind FROM runs WHERE false", env={"COLUMNS": "80"})
    assert res.stdout.splitlines() == ["run_id  kind", "------  ----", "(0 rows)"]


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
