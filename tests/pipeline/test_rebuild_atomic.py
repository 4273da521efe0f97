"""Atomic and safe: readers during a rebuild, kill -9 at several points, concurrent rebuilds."""
import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import duckdb
import pytest

from pipeline.rebuild import EXIT_LOCKED, rebuild, warehouse_lock
from pipeline.warehouse import connect_readonly
from tests.conftest import STEP_META, assert_raw_unchanged, raw_snapshot

T = [0.0, 0.1, 0.2, 0.3]
CLI = [sys.executable, "-c", "from pipeline.cli import main; main()"]


def step(raw, rel, n=4):
    t = [0.1 * i for i in range(n)]
    return raw.csv(rel, STEP_META, {"t[s]": t, "x[mm]": t, "x_ref[mm]": [3] * n})


def state(warehouse):
    """(run ids, samples rows) of the live warehouse; the samples view must agree with runs."""
    con = connect_readonly(warehouse)
    try:
        runs = [r[0] for r in con.execute("SELECT run_id FROM runs ORDER BY run_id").fetchall()]
        expected = con.execute("SELECT coalesce(sum(n_samples), 0) FROM runs WHERE kind = 'step'").fetchone()[0]
        got = con.execute("SELECT count(*) FROM samples_step").fetchone()[0]
        assert got == expected, (got, expected)
        con.execute("SELECT count(*) FROM findings").fetchone()
        return tuple(runs), got
    finally:
        con.close()


def cli_rebuild(raw, warehouse, *args, env=None):
    """``pneubench rebuild`` in a process of its own; raw/ must be byte-identical afterwards."""
    before = raw_snapshot(raw)
    res = subprocess.run([*CLI, "rebuild", "--raw", str(raw), "--warehouse", str(warehouse), "--jobs", "2", *args],
                         capture_output=True, text=True, env={**os.environ, **(env or {})}, timeout=300)
    assert_raw_unchanged(raw, before)
    return res


def debris(warehouse):
    return [p.name for p in warehouse.iterdir() if ".tmp" in p.name]


@pytest.mark.parametrize("point", ["after_ingest", "after_stages", "before_swap", "after_swap"])
def test_kill_9_leaves_a_complete_warehouse_and_the_next_rebuild_completes(raw, warehouse, point):
    step(raw, "c/a.csv")
    rebuild(raw.root, warehouse, jobs=1)
    before = state(warehouse)
    step(raw, "c/b.csv", n=6)
    step(raw, "c/c.csv", n=5)
    res = cli_rebuild(raw.root, warehouse, env={"PNEUBENCH_CRASH_AT": point})
    assert res.returncode == -signal.SIGKILL, res.stderr
    after = state(warehouse)
    if point == "after_swap":
        assert after == (("c/a", "c/b", "c/c"), 15)  # the new warehouse was already complete
    else:
        assert after == before  # the previous warehouse, untouched
    # the report describes the live warehouse, whichever it is
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"), read_only=True)
    try:
        live = con.execute("SELECT generation FROM rebuild_log ORDER BY finished_at DESC LIMIT 1").fetchone()[0]
    finally:
        con.close()
    assert f"generation {live}" in (warehouse / "report" / "index.html").read_text()
    # the lock died with the process (workers do not inherit it): the next rebuild runs at once
    s = rebuild(raw.root, warehouse, jobs=2)
    assert s.exit_code == 0
    assert state(warehouse) == (("c/a", "c/b", "c/c"), 15)
    assert debris(warehouse) == []
    assert not list((warehouse / "stages").glob(".tmp-*"))
    assert (warehouse / "report" / "index.html").is_file()


def test_kill_9_at_random_moments(raw, warehouse):
    for i in range(6):
        step(raw, f"c/r{i}.csv", n=50)
    rebuild(raw.root, warehouse, jobs=1)
    good = {state(warehouse)}
    rng = random.Random(7)
    for k in range(3):
        step(raw, f"c/new{k}.csv", n=10 + k)
        before = raw_snapshot(raw.root)
        p = subprocess.Popen([*CLI, "rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "2"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.5, 3.0))
        p.send_signal(signal.SIGKILL)
        p.wait()
        assert_raw_unchanged(raw.root, before)
        now = state(warehouse)  # readable and self-consistent, whichever generation it is
        good.add(now)
    final = rebuild(raw.root, warehouse, jobs=1)
    assert final.exit_code == 0
    runs, _ = state(warehouse)
    assert len(runs) == 9


HAMMER = textwrap.dedent("""
    import json, sys, time, duckdb
    db, stop, out = sys.argv[1], sys.argv[2], sys.argv[3]
    seen, errors, n = [], [], 0
    import os
    while not os.path.exists(stop):
        try:
            con = duckdb.connect(db, read_only=True)
            try:
                # a plain DuckDB client: the samples views read relative to this variable
                con.execute("SET VARIABLE pneubench_warehouse = ?", [os.path.dirname(db)])
                runs = con.execute("SELECT count(*), coalesce(sum(n_samples), 0) FROM runs").fetchone()
                view = con.execute("SELECT count(*) FROM samples_step").fetchone()[0]
                gen = con.execute("SELECT max(generation) FROM rebuild_log").fetchone()[0]
                seen.append([runs[0], int(runs[1]), view, gen])
            finally:
                con.close()
        except Exception as exc:
            errors.append(f"{type(exc).__name__}: {exc}")
        n += 1
    json.dump({"seen": seen, "errors": errors, "n": n}, open(out, "w"))
""")


def test_a_reader_hammering_the_warehouse_sees_old_or_new_never_a_mix(raw, warehouse, tmp_path):
    step(raw, "c/a.csv")
    rebuild(raw.root, warehouse, jobs=1)
    stop, out = tmp_path / "stop", tmp_path / "seen.json"
    reader = subprocess.Popen([sys.executable, "-c", HAMMER, str(warehouse / "pneubench.duckdb"), str(stop), str(out)])
    try:
        time.sleep(1.0)
        for i in range(5):
            step(raw, f"c/b{i}.csv", n=5 + i)
            if i == 3:
                (raw.root / "c/a.csv").unlink()
            rebuild(raw.root, warehouse, jobs=1)
    finally:
        stop.touch()
        reader.wait(timeout=60)
    result = json.loads(out.read_text())
    assert result["errors"] == []
    assert len(result["seen"]) >= 10
    for n_runs, n_samples, view_rows, gen in result["seen"]:
        assert view_rows == n_samples  # the samples of exactly the runs of that generation
    # all six generations were complete states: runs count grows 1, 2, 3, 4, 4 (a deleted), 5
    allowed = {(1, 4), (2, 9), (3, 15), (4, 22), (4, 26), (5, 35)}
    assert {(r[0], r[1]) for r in result["seen"]} <= allowed


def test_second_rebuild_exits_4_with_a_clear_message_or_waits(raw, warehouse):
    step(raw, "c/a.csv")
    warehouse.mkdir(parents=True)
    with warehouse_lock(warehouse):
        res = cli_rebuild(raw.root, warehouse)
    assert res.returncode == EXIT_LOCKED
    assert "another rebuild is running" in res.stderr and "--wait" in res.stderr
    assert not (warehouse / "pneubench.duckdb").exists()
    # two at once, both willing to wait: both complete, one after the other
    before = raw_snapshot(raw.root)
    procs = [subprocess.Popen([*CLI, "rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse),
                               "--jobs", "1", "--wait", "120"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    codes = [p.wait(timeout=300) for p in procs]
    assert_raw_unchanged(raw.root, before)
    assert codes == [0, 0], [p.stderr.read() for p in procs]
    assert state(warehouse) == (("c/a",), 4)
    assert debris(warehouse) == []


def test_a_worker_crash_quarantines_that_file_and_the_rest_ingests(raw, warehouse):
    # a segfault in a C library (scipy's loadmat on a corrupt MAT file did this) kills the
    # worker process; the file is quarantined, the other files ingest, the rebuild exits 1
    for name in "abcdef":
        step(raw, f"c/{name}.csv")
    res = cli_rebuild(raw.root, warehouse, env={"PNEUBENCH_CRASH_AT": "ingest:c/c.csv"})
    assert res.returncode == 1, res.stderr
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"), read_only=True)
    try:
        assert con.execute("SELECT source_path, error FROM quarantine").fetchall() == [
            ("c/c.csv", "cannot read file: the worker process reading it died (a crash in a C library, "
                        "or killed for memory)")]
        assert [r[0] for r in con.execute("SELECT run_id FROM runs ORDER BY 1").fetchall()] == [
            "c/a", "c/b", "c/d", "c/e", "c/f"]
    finally:
        con.close()
    # a crash may pass (killed for memory): the next rebuild tries the file once more ...
    res = cli_rebuild(raw.root, warehouse)
    assert res.returncode == 0, res.stderr
    assert state(warehouse)[0] == ("c/a", "c/b", "c/c", "c/d", "c/e", "c/f")


def test_a_file_that_crashes_its_reader_twice_is_not_read_every_night(raw, warehouse):
    for name in "abc":
        step(raw, f"c/{name}.csv")
    crash = {"PNEUBENCH_CRASH_AT": "ingest:c/c.csv"}
    assert cli_rebuild(raw.root, warehouse, env=crash).returncode == 1   # first crash: retried next time
    assert cli_rebuild(raw.root, warehouse, env=crash).returncode == 1   # second crash: hashed, kept
    res = cli_rebuild(raw.root, warehouse, "--jobs", "2", env=crash)
    assert res.returncode == 1
    assert "1 of 3 run files to read" not in res.stderr and "0 changed" in res.stderr
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"), read_only=True)
    try:
        assert con.execute("SELECT source_path FROM quarantine").fetchall() == [("c/c.csv",)]
    finally:
        con.close()


def test_a_stuck_reader_is_stopped_at_its_time_limit_and_the_night_goes_on(raw, warehouse, monkeypatch):
    """A reader that never returns (asammdf looping over an MDF file whose block links point
    back on themselves did: tests/fuzz) is stopped at the file's time limit; the file is
    quarantined, tried once more the next night, then kept quarantined until its bytes change."""
    import pipeline.readers.base as base
    from tests.conftest import query

    monkeypatch.setattr(base, "READ_TIME_FLOOR_S", 3.0)  # the limits are computed by the rebuild process
    monkeypatch.setattr(base, "READ_RATE_FLOOR_B_S", 1e12)
    for name in "abcd":
        step(raw, f"c/{name}.csv")
    monkeypatch.setenv("PNEUBENCH_CRASH_AT", "ingest:c/b.csv")
    monkeypatch.setenv("PNEUBENCH_CRASH_SIGNAL", "SIGSTOP")  # the worker stops and never answers
    for jobs in (1, 2):
        t0 = time.monotonic()
        s = rebuild(raw.root, warehouse, jobs=jobs)
        assert time.monotonic() - t0 < 60
        assert s.exit_code == 1
        assert [(p.source_path, p.error) for p in s.quarantine] == [
            ("c/b.csv", "cannot read file: the reader was stopped after 3 s, far longer than a file of its size "
                        "takes (a reader stuck in a loop)")]
        assert [r[0] for r in query(warehouse, "SELECT run_id FROM runs ORDER BY 1")] == ["c/a", "c/c", "c/d"]
    # stuck twice: hashed and kept quarantined, not read again while its bytes stay the same
    monkeypatch.delenv("PNEUBENCH_CRASH_AT")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.exit_code == 1 and [p.source_path for p in s.quarantine] == ["c/b.csv"]
    step(raw, "c/b.csv", n=5)  # new bytes: read again
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.exit_code == 0 and [r[0] for r in query(warehouse, "SELECT run_id FROM runs ORDER BY 1")] == [
        "c/a", "c/b", "c/c", "c/d"]


def test_a_waiting_rebuild_says_once_whose_lock_it_waits_for(raw, warehouse):
    """--wait names the holder (pid, host, since when) once, when it starts waiting; a free lock
    is taken without a word."""
    import socket
    import threading

    step(raw, "c/a.csv")
    warehouse.mkdir(parents=True)
    held, release = threading.Event(), threading.Event()

    def holder():
        with warehouse_lock(warehouse):
            held.set()
            release.wait(60)

    th = threading.Thread(target=holder)
    th.start()
    held.wait(30)
    try:
        res = cli_rebuild(raw.root, warehouse, "--wait", "1.5")
    finally:
        release.set()
        th.join()
    assert res.returncode == EXIT_LOCKED
    who = f"pid {os.getpid()} on {socket.gethostname()} since "
    waiting = [x for x in res.stderr.splitlines() if x.startswith("waiting")]
    assert len(waiting) == 1 and who in waiting[0] and "up to 1.5 s" in waiting[0], res.stderr
    assert who in res.stderr.splitlines()[-1] and "after waiting 1.5 s" in res.stderr.splitlines()[-1]
    res = cli_rebuild(raw.root, warehouse, "--wait", "60")
    assert res.returncode == 0 and "waiting up to" not in res.stderr, res.stderr
