"""The command line: exit codes of the spec and read-only queries."""
import json

import pytest
from click.testing import CliRunner

from pipeline.cli import main
from tests.conftest import STEP_META

T = [0.0, 0.1, 0.2]


def test_rebuild_exit_codes_and_query_formats(raw, warehouse):
    runner = CliRunner()
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    raw.csv("c/bad.csv", STEP_META, {"t[s]": T})
    res = runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"])
    assert res.exit_code == 1
    assert "quarantined c/bad.csv: missing channel `x`, `x_ref`" in res.output
    res = runner.invoke(main, ["query", "SELECT run_id, n_samples FROM runs", "--warehouse", str(warehouse),
                               "--format", "json"])
    assert json.loads(res.output) == [{"run_id": "c/a", "n_samples": 3}]
    res = runner.invoke(main, ["query", "SELECT run_id FROM runs", "--warehouse", str(warehouse), "--format", "csv"])
    assert res.output.splitlines() == ["run_id", "c/a"]


def test_usage_errors_exit_2(tmp_path):
    runner = CliRunner()
    assert runner.invoke(main, ["rebuild", "--raw", str(tmp_path / "nope")]).exit_code == 2
    assert runner.invoke(main, ["rebuild", "--jobs", "0"]).exit_code == 2
    res = runner.invoke(main, ["rebuild", "--raw", str(tmp_path), "--scheduler", "tcp://127.0.0.1:1"])
    assert res.exit_code == 2 and "--scheduler goes with --executor dask" in res.output
    assert runner.invoke(main, ["query", "SELECT 1", "--warehouse", str(tmp_path)]).exit_code == 2


def test_query_is_read_only(raw, warehouse):
    runner = CliRunner()
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"])
    res = runner.invoke(main, ["query", "DELETE FROM runs", "--warehouse", str(warehouse)])
    assert res.exit_code != 0 and "read-only" in res.output


def test_rebuild_into_an_unusable_warehouse_folder_fails_with_3(raw, tmp_path):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    (tmp_path / "afile").write_text("not a folder")
    res = CliRunner().invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(tmp_path / "afile" / "wh")])
    assert res.exit_code == 3
    assert "cannot create warehouse folder" in res.output and "Not a directory" in res.output


def test_an_empty_raw_tree_exits_2_naming_the_count_unless_allowed_by_flag_or_environment(raw, warehouse, tmp_path):
    runner = CliRunner()
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    args = ["rebuild", "--warehouse", str(warehouse), "--jobs", "1", "-q"]
    assert runner.invoke(main, [*args, "--raw", str(raw.root)]).exit_code == 0
    db = (warehouse / "pneubench.duckdb").read_bytes()
    empty = tmp_path / "unmounted"
    empty.mkdir()
    res = runner.invoke(main, [*args, "--raw", str(empty)])
    assert res.exit_code == 2
    assert "refusing to delete 1 of the warehouse's 1 runs" in res.output
    assert (warehouse / "pneubench.duckdb").read_bytes() == db
    res = runner.invoke(main, [*args, "--raw", str(empty)], env={"PNEUBENCH_ALLOW_MASS_DELETE": "0"})
    assert res.exit_code == 2
    res = runner.invoke(main, [*args, "--raw", str(empty)], env={"PNEUBENCH_ALLOW_MASS_DELETE": "1"})
    assert res.exit_code == 0, res.output
    runner.invoke(main, [*args, "--raw", str(raw.root)])
    res = runner.invoke(main, [*args, "--raw", str(empty), "--allow-mass-delete"])
    assert res.exit_code == 0, res.output


def _pneubench(*args, timeout=300, memory=6 << 30, env=None):
    """``pneubench ARGS`` in a child process under an address-space limit."""
    import os
    import resource
    import subprocess
    import sys
    from pathlib import Path

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))

    code = "import sys; sys.argv[0] = 'pneubench'; from pipeline.cli import main; main()"
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=limit,
                          env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]), **(env or {})})


def test_quiet_dask_rebuild_prints_nothing(raw, warehouse):
    """distributed's INFO chatter (33 lines: scheduler, nannies, workers, clients) is not the
    rebuild's output; its warnings still are, and DASK_LOGGING__DISTRIBUTED=info brings it back."""
    import pytest

    pytest.importorskip("distributed")
    from tests.conftest import raw_snapshot

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    before = raw_snapshot(raw.root)
    res = _pneubench("rebuild", "-q", "--executor", "dask", "--jobs", "1", "--no-report", "--raw", raw.root,
                     "--warehouse", warehouse)
    assert res.returncode == 0, res.stderr
    assert res.stderr == "" and res.stdout == ""
    assert raw_snapshot(raw.root) == before
    res = _pneubench("rebuild", "-q", "--executor", "dask", "--jobs", "1", "--no-report", "--full",
                     "--raw", raw.root, "--warehouse", warehouse, env={"DASK_LOGGING__DISTRIBUTED": "info"})
    assert res.returncode == 0 and "Scheduler at:" in res.stderr


def test_query_options_are_the_query_commands_options_after_the_sql_and_the_warehouse():
    import dataclasses

    from pipeline.cli import QueryOptions

    names = {p.name for p in main.commands["query"].params} - {"sql", "sql_file", "warehouse"}
    assert names == {f.name for f in dataclasses.fields(QueryOptions)}


_EXIT_PROBE = """
import atexit, sys, threading
from pipeline.cli import exit_now

class Torn:
    def __del__(self):
        sys.stdout.write(" torn down")

kept = Torn()
atexit.register(lambda: sys.stdout.write(" atexit"))
if sys.argv[1] == "thread":
    threading.Thread(target=threading.Event().wait, daemon=True).start()
sys.stdout.write("out")
exit_now(5)
"""


@pytest.mark.parametrize("other_thread", [False, True])
def test_exit_now_skips_the_teardown_only_in_a_process_of_its_own(other_thread):
    """The exit code, the output and the atexit handlers as sys.exit gives them; the objects' teardown
    is skipped, unless another thread is alive (then it is sys.exit)."""
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-c", _EXIT_PROBE, "thread" if other_thread else "alone"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 5, p.stderr
    assert p.stdout == ("out atexit torn down" if other_thread else "out atexit")


def test_exit_now_inside_another_program_is_sys_exit():
    """Under pytest (or click's test runner) it raises SystemExit: the calling program goes on."""
    from pipeline.cli import exit_now

    with pytest.raises(SystemExit) as exc:
        exit_now(3)
    assert exc.value.code == 3


# The door's environment, a damaged database and a closed stdout, for every command that reads the warehouse.
READERS = [["tables"], ["describe", "runs"], ["plot", "c/a"], ["figures", "-o", "FIGS"], ["decision"], ["report"],
           ["query", "SELECT 1"]]


def _reader_args(args, tmp_path, warehouse):
    return [str(tmp_path / "figs") if a == "FIGS" else a for a in args] + ["--warehouse", str(warehouse)]


@pytest.mark.parametrize("env, value", [("PNEUBENCH_QUERY_MEMORY_LIMIT", "abc"), ("PNEUBENCH_QUERY_TEMP_LIMIT", "abc"),
                                        ("PNEUBENCH_QUERY_TIMEOUT", "abc")])
def test_a_bad_door_variable_is_one_line_exit_2_before_any_work(raw, warehouse, tmp_path, env, value):
    runner = CliRunner()
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"],
                        env={env: value})
    assert res.exit_code == 2, res.output
    assert len(res.stderr.splitlines()) == 1 and res.stderr.startswith(f"pneubench rebuild: ${env} = {value!r}: ")
    assert not warehouse.exists()  # refused before it started (was: the whole rebuild, then its report failed)
    assert runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"]
                         ).exit_code == 0
    for args in READERS:
        res = runner.invoke(main, _reader_args(args, tmp_path, warehouse), env={env: value})
        assert res.exit_code == 2, (args, res.output)
        assert len(res.stderr.splitlines()) == 1 and res.stderr.startswith(f"pneubench {args[0]}: ${env} = 'abc': ")
        assert res.exception is None or isinstance(res.exception, SystemExit)


@pytest.mark.parametrize("content", [b"", b"\x00garbage" * 4096], ids=["empty", "garbage"])
def test_a_damaged_database_is_one_line_exit_3_naming_it_for_every_reader(raw, warehouse, tmp_path, content):
    warehouse.mkdir()
    db = warehouse / "pneubench.duckdb"
    db.write_bytes(content)
    runner = CliRunner()
    for args in READERS:
        res = runner.invoke(main, _reader_args(args, tmp_path, warehouse))
        assert res.exit_code == 3, (args, res.output)
        assert res.stderr.splitlines() == [
            f"pneubench {args[0]}: {db.resolve()} is not a readable DuckDB database "
            f"(IO Error: The file \"{db.resolve()}\" exists, but it is not a valid DuckDB database file!); "
            "`pneubench rebuild` builds it again"], args
    assert not (tmp_path / "figs").exists() and not (warehouse / "report").exists()
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})  # a rebuild replaces it
    res = runner.invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"])
    assert res.exit_code == 0, res.output
    assert runner.invoke(main, ["tables", "--warehouse", str(warehouse)]).exit_code == 0


def _closed_stdout(*args):
    """``pneubench ARGS`` in a child process whose stdout's reader is gone (``| head -0``): (exit, stderr)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    read, write = os.pipe()
    os.close(read)
    try:
        code = "import sys; sys.argv[0] = 'pneubench'; from pipeline.cli import main; main()"
        done = subprocess.run([sys.executable, "-c", code, *map(str, args)], stdout=write, stderr=subprocess.PIPE,
                              text=True, timeout=300,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])})
    finally:
        os.close(write)
    return done.returncode, done.stderr


def test_a_closed_stdout_ends_a_reader_quietly_with_exit_0(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert CliRunner().invoke(main, ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse),
                                     "--jobs", "1", "--no-report"]).exit_code == 0
    wh = ["--warehouse", warehouse]
    for args in [["query", "SELECT * FROM range(200000)", "--format", "csv", *wh], ["query", "SELECT 1", *wh],
                 ["query", "SELECT * FROM runs", "--format", "line", *wh], ["tables", *wh], ["describe", "runs", *wh],
                 ["decision", *wh], ["schedule"]]:
        assert _closed_stdout(*args) == (0, ""), args  # was exit 1 (click's), or a traceback
