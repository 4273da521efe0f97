"""Executors: local processes and a Dask cluster (two worker processes) give identical results."""
import pytest

from pipeline.rebuild.executors import CRASH_REASON, DaskExecutor, Executor, LocalExecutor, make_executor
from pipeline.rebuild.flow import rebuild
from pipeline.serve.door import connect_readonly
from tests.conftest import PROJECT_ROOT, STEP_META

distributed = pytest.importorskip("distributed")


def square(x):
    return x * x


def boom(x):
    if x == 3:
        raise ValueError("bad item 3")
    return x


#: Tables that describe the rebuild itself (times, generation, executor), not its results.
REBUILD_ONLY = {"rebuild_log", "rebuild_inputs", "rebuild_changes", "ingest_state", "stage_cache", "figures",
                "superseded_files", "table_keys"}


def dump(warehouse):
    """Every result table and view of a warehouse, rows sorted."""
    con = connect_readonly(warehouse)
    try:
        tables = sorted({r[0] for r in con.execute("SELECT table_name FROM duckdb_tables() UNION ALL SELECT "
                                                   "view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
                        - REBUILD_ONLY)
        assert {"runs", "channels", "quarantine", "step_response", "findings"} <= set(tables)
        out = {t: con.execute(f'SELECT * FROM "{t}" ORDER BY ALL').fetchall() for t in tables}
        out["samples"] = con.execute("SELECT * FROM samples_step ORDER BY ALL").fetchall()
        out["rebuild_log.executor"] = con.execute("SELECT executor FROM rebuild_log").fetchall()
        return out
    finally:
        con.close()


@pytest.fixture(scope="module")
def cluster():
    c = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    yield c
    c.close()


def test_executors_keep_order_and_raise_task_errors(cluster):
    items = list(range(20))
    assert Executor().map(square, items) == [i * i for i in items]
    with LocalExecutor(2) as ex:
        assert ex.map(square, items) == [i * i for i in items]
    with DaskExecutor(cluster.scheduler_address) as ex:
        assert ex.map(square, items) == [i * i for i in items]
        workers = ex.client.run(lambda: __import__("os").getpid())
        assert len(set(workers.values())) == 2  # two worker processes
        with pytest.raises(ValueError, match="bad item 3"):
            ex.map(boom, items)
    with pytest.raises(ValueError):
        make_executor("spark")


def test_dask_rebuild_equals_local_rebuild(raw, tmp_path, cluster):
    for i in range(6):
        t = [0.05 * k for k in range(200)]
        x = [min(20.0, 0.3 * k) for k in range(200)]
        raw.csv(f"c/s{i}.csv", {**STEP_META, "operator": f"op{i}"}, {"t[s]": t, "x[mm]": x, "x_ref[mm]": [20.0] * 200})
    raw.csv("c/bad.csv", STEP_META, {"t[s]": [0, 1], "x[furlong]": [0, 1], "x_ref[mm]": [0, 1]})
    local = rebuild(raw.root, tmp_path / "local", jobs=2, executor="local")
    dask = rebuild(raw.root, tmp_path / "dask", jobs=2, executor="dask", scheduler=cluster.scheduler_address)
    assert dask.exit_code == local.exit_code == 1
    a, b = dump(tmp_path / "local"), dump(tmp_path / "dask")
    assert a.pop("rebuild_log.executor") == [("local",)] and b.pop("rebuild_log.executor") == [("dask",)]
    assert a == b
    assert len(a["runs"]) == 6 and len(a["step_response"]) >= 6
    # the workers wrote the samples files: same content-addressed names in both warehouses
    names = lambda w: sorted(p.name for p in (w / "samples").rglob("*.parquet"))  # noqa: E731
    assert names(tmp_path / "local") == names(tmp_path / "dask")


def pid_of(x):
    import os

    return x, os.getpid()


def segfault_on_3(x):
    import os

    from tests.conftest import segfault

    if x == 3:
        segfault()  # a reader crashing in C code
    return x, os.getpid()


def crashed(item, reason):
    return item, "crashed: " + reason


@pytest.mark.parametrize("jobs", [1, 2])
def test_untrusted_work_always_runs_in_worker_processes_started_once_and_only_when_needed(jobs):
    import os

    with LocalExecutor(jobs) as ex:
        assert ex.map(pid_of, [], on_crash=crashed) == []
        assert ex.reader_processes_started == 0  # nothing to read: no process
        out = ex.map(pid_of, list(range(6)), on_crash=crashed)
        assert [x for x, _ in out] == list(range(6))
        pids = {p for _, p in out}
        assert os.getpid() not in pids and len(pids) <= jobs  # reused for every item
        assert ex.reader_processes_started == jobs
    with LocalExecutor(jobs) as ex:  # never more workers than items
        ex.map(pid_of, [1], on_crash=crashed)
        assert ex.reader_processes_started == 1
    # trusted work (the stages' per-run analyses) still runs in this process with one job
    if jobs == 1:
        assert {p for _, p in LocalExecutor(1).map(pid_of, [1, 2])} == {os.getpid()}


def waits_for(path):
    """An item that waits (at most 20 s) for ``path`` to appear: True if it did."""
    import os
    import time

    end = time.monotonic() + 20
    while time.monotonic() < end:
        if os.path.exists(path):
            return True
        time.sleep(0.01)
    return False


@pytest.mark.parametrize("jobs", [1, 2])
def test_while_waiting_runs_once_here_while_the_workers_read(jobs, tmp_path):
    """The rebuild imports what its stages need while the readers' workers work: ``while_waiting``
    runs in this process while the first items are in flight (they wait for what it writes)."""
    import os

    calls = []
    flag = tmp_path / "flag"

    def meanwhile():
        calls.append(os.getpid())
        flag.write_text("ok")

    with LocalExecutor(jobs) as ex:
        out = ex.map(waits_for, [str(flag)] * 3, on_crash=crashed, while_waiting=meanwhile)
    assert out == [True] * 3 and calls == [os.getpid()]
    with LocalExecutor(jobs) as ex:  # nothing to do: nothing run
        assert ex.map(waits_for, [], on_crash=crashed, while_waiting=meanwhile) == [] and len(calls) == 1


def sleeps_on_3(x):
    import time

    if x == 3:
        time.sleep(120)  # a reader stuck in a loop
    return x


@pytest.mark.parametrize("jobs", [1, 2])
def test_an_item_past_its_time_limit_is_stopped_and_the_others_get_their_results(jobs):
    import time

    from pipeline.rebuild.executors import stuck_reason

    t0 = time.monotonic()
    with LocalExecutor(jobs) as ex:
        out = ex.map(sleeps_on_3, list(range(6)), on_crash=crashed, time_limit=lambda x: 2.0)
    assert time.monotonic() - t0 < 30
    assert out == [0, 1, 2, (3, "crashed: " + stuck_reason(2.0)), 4, 5]
    assert stuck_reason(2.0).startswith("the reader was stopped after 2 s")


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_segfaulting_item_gets_on_crash_and_the_others_their_results(jobs):
    import os

    with LocalExecutor(jobs) as ex:
        out = ex.map(segfault_on_3, list(range(8)), on_crash=crashed)
        assert out[3] == (3, "crashed: " + CRASH_REASON)
        assert [x for x, _ in out] == list(range(8))
        assert all(isinstance(p, int) and p != os.getpid() for i, (_, p) in enumerate(out) if i != 3)
        if jobs == 1:  # the one suspect is the culprit: not run again; the rest goes on in one new worker
            assert ex.reader_processes_started == 2
            assert len({p for _, p in out[:3]}) == 1 and len({p for _, p in out[4:]}) == 1
    # without on_crash, a dead worker is an error (trusted work must not crash)
    from concurrent.futures.process import BrokenProcessPool

    with LocalExecutor(2) as ex, pytest.raises(BrokenProcessPool):
        ex.map(segfault_on_3, list(range(8)))


def test_a_deliberately_crashed_worker_prints_no_fatal_error_dump():
    """pytest enables faulthandler and a forked worker inherits it, writing past the capture: the
    crash tests crash without it (``segfault``), and the crash is still reported."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("from pipeline.rebuild.executors import LocalExecutor\n"
            "from tests.pipeline.rebuild.test_executors import crashed, segfault_on_3\n"
            "with LocalExecutor(1) as ex:\n"
            "    print(ex.map(segfault_on_3, [2, 3], on_crash=crashed)[1])\n")
    root = str(PROJECT_ROOT)
    res = subprocess.run([sys.executable, "-X", "faulthandler", "-c", code], capture_output=True, text=True,
                         timeout=120, cwd=root, env={**os.environ, "PYTHONPATH": root})
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == str((3, "crashed: " + CRASH_REASON))
    assert "Fatal Python error" not in res.stderr and res.stderr == ""


def frozen_objects(x):
    """The worker's pid and how many objects its garbage collector leaves alone (``gc.freeze``)."""
    import gc
    import os

    return os.getpid(), gc.get_freeze_count()


@pytest.mark.parametrize("jobs", [1, 2])
def test_readers_released_after_the_ingest_are_gone_and_workers_leave_the_parents_objects_to_it(jobs):
    """Issue 26: the reader processes do not live through the stages, and a forked worker's
    garbage collections do not visit (and so copy) what it inherited from the rebuild."""
    import gc
    import os
    import time

    frozen = gc.get_freeze_count()  # (an earlier in-process `pneubench rebuild` keeps what it froze, as the command does)
    with LocalExecutor(jobs) as ex:
        out = ex.map(frozen_objects, list(range(4)), on_crash=crashed)
        assert all(n > 1000 for _, n in out)  # everything imported here before the fork
        readers = {p for p, _ in out}
        ex.release_readers()
        end = time.monotonic() + 10
        while time.monotonic() < end and any(os.path.exists(f"/proc/{p}") and
                                             open(f"/proc/{p}/stat").read().split()[2] != "Z" for p in readers):
            time.sleep(0.05)
        assert not any(os.path.exists(f"/proc/{p}") for p in readers)
        again = ex.map(frozen_objects, [1], on_crash=crashed)  # a later read starts fresh workers
        assert again[0][0] not in readers
        if jobs == 2:  # the stages' pool freezes too
            assert all(n > 1000 for _, n in ex.map(frozen_objects, list(range(4))))
    assert gc.get_freeze_count() <= frozen  # this process froze nothing more (frozen objects freed leave the count)
    Executor().release_readers()  # an executor without reader processes: nothing to do


def test_the_rebuild_collects_cycles_less_often_and_gives_the_thresholds_back():
    """Issue 26: ~280 collections of a one-file change at 1,000 runs, 2 of them of every object, cost
    0.13 CPU-s; the rebuild raises the thresholds while it runs (never lowers one) and restores them."""
    import gc

    from pipeline.rebuild.executors import GC_THRESHOLD, fewer_collections

    before = gc.get_threshold()
    try:
        gc.set_threshold(700, 10, 10)
        with fewer_collections():
            assert gc.get_threshold() == GC_THRESHOLD
        assert gc.get_threshold() == (700, 10, 10)
        gc.set_threshold(50_000, 5, 50)
        with fewer_collections():
            assert gc.get_threshold() == (50_000, GC_THRESHOLD[1], 50)
        gc.set_threshold(0)  # collections turned off by the caller: left off
        with fewer_collections():
            assert gc.get_threshold()[0] == 0
        gc.set_threshold(700, 10, 10)
        with pytest.raises(ValueError), fewer_collections():
            raise ValueError("a failed rebuild")
        assert gc.get_threshold() == (700, 10, 10)
    finally:
        gc.set_threshold(*before)


def test_what_a_rebuild_froze_is_thawed_when_its_block_ends_unless_the_command_keeps_it():
    """``ingest_tasks._freeze`` freezes the rebuild's long-lived objects (issue 26); a rebuild called as a
    library leaves the process unfrozen, the ``rebuild`` command's block (its process ends) keeps them."""
    import gc

    from pipeline.rebuild.executors import fewer_collections

    gc.unfreeze()   # an earlier in-process `pneubench rebuild` (the CLI tests) keeps what it froze, as the command does
    try:
        with fewer_collections():
            gc.freeze()                                   # as the ingest step does
            assert gc.get_freeze_count() > 0
        assert gc.get_freeze_count() == 0                 # thawed
        with fewer_collections(keep_frozen=True):
            with fewer_collections():                     # flow.rebuild's block inside the command's
                gc.freeze()
            assert gc.get_freeze_count() > 0              # kept: the command's block is open
        assert gc.get_freeze_count() > 0
        gc.unfreeze()
        gc.freeze()                                       # frozen before the block: not the block's to thaw
        with fewer_collections():
            pass
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()

