"""The rebuild's ingest step: its worker messages, readers that crash or get stuck in worker
processes, and files that change while they are read."""
import os
import pickle

import pytest

import pipeline.rebuild.ingest_tasks as tasks
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.ingest_tasks import CRASHED, IngestOutcome, IngestTask, PreviousRead
from pipeline.rebuild.options import EXIT_QUARANTINED
from tests.conftest import STEP_META
from tests.pipeline.rebuild.test_state import ReadLog, age, q, step

T = [0.0, 0.1, 0.2, 0.3]


def test_worker_messages_are_frozen_and_cross_a_process_boundary():
    task = IngestTask("/raw", "gen-1", "/raw/c/a.csv", "/wh", True, PreviousRead("ab" * 32, False), "1-abc", 42)
    assert pickle.loads(pickle.dumps(task)) == task
    out = IngestOutcome(None, False, None, retry=True)
    assert pickle.loads(pickle.dumps(out)) == out
    with pytest.raises(AttributeError):
        task.path = "/raw/c/b.csv"


# -- readers of untrusted bytes never run in the rebuild's process --------------------------------
# -- readers of untrusted bytes never run in the rebuild's process --------------------------------
def test_a_reader_that_segfaults_with_one_job_quarantines_its_file_and_the_rest_ingests(raw, warehouse,
                                                                                       monkeypatch):
    # a 1-core server is --jobs 1: the reader still runs in a worker process, so a segfault in
    # C code (scipy's loadmat on a corrupt MAT file did this) costs one file, not the rebuild
    import os

    import pipeline.raw.metadata as ing
    from tests.conftest import segfault

    real = ing.read_export

    def reader(path, *a, **k):
        if "segv" in os.path.basename(path):
            segfault()
        return real(path, *a, **k)

    monkeypatch.setattr(ing, "read_export", reader)
    for name in ("a", "b_segv", "c"):
        raw.csv(f"c/{name}.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    parent = os.getpid()
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert os.getpid() == parent and summary.exit_code == EXIT_QUARANTINED
    assert [(p.source_path, p.error) for p in summary.quarantine] == [("c/b_segv.csv", CRASHED)]
    assert q(warehouse, "SELECT run_id FROM runs ORDER BY 1") == [("c/a",), ("c/c",)]


def test_ingest_starts_one_worker_process_for_one_job_and_none_when_nothing_is_read(raw, warehouse, monkeypatch):
    import os
    import time

    forks = []
    real_fork = os.fork

    def counting_fork():
        pid = real_fork()
        if pid:
            forks.append(pid)
        return pid

    monkeypatch.setattr(os, "fork", counting_fork)
    for name in "abcd":
        raw.csv(f"c/{name}.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    past = time.time() - 3600  # files written this second are hashed again next time ("racy")
    for p in raw.root.rglob("*.csv"):
        os.utime(p, (past, past))
    rebuild(raw.root, warehouse, jobs=1)
    assert len(forks) == 1  # one reader worker for four files; the stages run in this process
    forks.clear()
    assert rebuild(raw.root, warehouse, jobs=1).n_unchanged == 4
    assert forks == []  # a no-op rebuild starts no process



# -- files that change while they are read ----------------------------------------------------
def test_a_new_file_is_hashed_once(raw, warehouse, monkeypatch, tmp_path):
    # a new file is hashed by ingest while it parses it; a touched one by the rebuild, to decide
    import pipeline.ingest.hashing as ing

    log = ReadLog(tmp_path / "calls.jsonl")
    real = ing.sha256_file
    for mod in (tasks, ing):
        monkeypatch.setattr(mod, "sha256_file", lambda p, *a, **k: log.record("sha", p.name) or real(p, *a, **k))
    step(raw, "c/a.csv")
    rebuild(raw.root, warehouse, jobs=1)
    assert log["sha"].count("a.csv") == 1
    assert q(warehouse, "SELECT source_sha256 FROM runs") == [(real(raw.root / "c" / "a.csv"),)]
    # rewritten with other bytes of the same size: the rebuild hashes it in its own process to see
    # whether the bytes are the recorded ones (a copied or moved raw tree is a no-op, issue 26), then
    # the ingest reads it, hashing it while it parses it: twice, only for a same-size rewrite
    log.clear()
    age(raw.root)
    step(raw, "c/a.csv", scale=2.0)
    rebuild(raw.root, warehouse, jobs=1)
    assert log["sha"].count("a.csv") == 2
    # other bytes of another size: not hashed to decide, once by the ingest
    log.clear()
    step(raw, "c/a.csv", scale=20.0)
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    assert log["sha"].count("a.csv") == 1
    assert q(warehouse, "SELECT source_sha256 FROM runs") == [(real(raw.root / "c" / "a.csv"),)]


@pytest.mark.raw_written("c/a.csv")
def test_a_file_written_while_it_is_read_is_read_again_next_time(raw, warehouse, monkeypatch):
    # its hash and its samples may be of different bytes: the record says "look again"
    step(raw, "c/a.csv")
    age(raw.root)
    real = tasks.ingest_file

    def ingest_while_the_bench_writes(tree, path, *a, **k):
        res = real(tree, path, *a, **k)
        step(raw, "c/a.csv", scale=2.0)  # the DAQ rewrites the file meanwhile
        return res

    monkeypatch.setattr(tasks, "ingest_file", ingest_while_the_bench_writes)
    first = rebuild(raw.root, warehouse, jobs=1)
    monkeypatch.undo()
    assert [(p.source_path, p.error) for p in first.quarantine] == [("c/a.csv", tasks.CHANGED_WHILE_READ)]
    assert q(warehouse, "SELECT count(*) FROM runs") == [(0,)]  # not published this night
    assert q(warehouse, "SELECT mtime_ns, source_sha256 FROM ingest_state WHERE role = 'run'") == [(-1, None)]
    second = rebuild(raw.root, warehouse, jobs=1)
    assert second.n_changed == 1 and second.exit_code == 0
    assert q(warehouse, "SELECT max(x_m) FROM samples_step") == [(pytest.approx(0.006),)]


@pytest.mark.raw_written("c/a.csv")
def test_a_retried_file_is_read_again_not_taken_from_a_samples_file_of_the_same_name(raw, warehouse, monkeypatch,
                                                                                     tmp_path):
    # the racy read's samples may carry the new bytes' name with the old bytes' data: the
    # re-check must not reuse them
    step(raw, "c/a.csv")
    age(raw.root)
    real = tasks.ingest_file
    seen = ReadLog(tmp_path / "seen.jsonl")

    def ingest_while_the_bench_writes(tree, path, *a, **k):
        seen.record("reuse", k.get("reuse"))
        res = real(tree, path, *a, **k)
        if len(seen["reuse"]) == 1:
            step(raw, "c/a.csv", scale=2.0)
        return res

    monkeypatch.setattr(tasks, "ingest_file", ingest_while_the_bench_writes)
    rebuild(raw.root, warehouse, jobs=1)
    rebuild(raw.root, warehouse, jobs=1)
    assert seen["reuse"] == [True, False]


def test_a_file_that_cannot_be_opened_is_tried_again_next_time(raw, warehouse, monkeypatch):
    import pipeline.raw.metadata as ing

    step(raw, "c/a.csv")
    age(raw.root)
    real = ing.read_export

    def locked(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(ing, "read_export", locked)
    first = rebuild(raw.root, warehouse, jobs=1)
    assert [p.error for p in first.quarantine] == ["cannot read file: PermissionError: [Errno 13] Permission denied"]
    monkeypatch.setattr(ing, "read_export", real)  # chmod fixed it: the stat did not change
    second = rebuild(raw.root, warehouse, jobs=1)
    assert second.quarantine == [] and q(warehouse, "SELECT count(*) FROM runs") == [(1,)]


@pytest.mark.raw_written("c/a.csv")
def test_a_file_growing_while_its_reader_reads_it_is_not_published_and_is_read_next_time(raw, warehouse,
                                                                                       monkeypatch):
    # a bench still writing: the reader sees part of the file; publishing it would give a partial
    # run with a source_sha256 of neither version. It is set aside for the night (exit 1, listed
    # with the changes) and read whole at the next rebuild.
    import hashlib

    import pipeline.raw.metadata as ing

    step(raw, "c/a.csv")
    step(raw, "c/b.csv")
    age(raw.root)
    real = ing.read_export

    def reader_while_the_bench_appends(path, *a, **k):
        export = real(path, *a, **k)
        if path.name != "a.csv":
            return export
        batches = export.batches

        def growing():
            for i, batch in enumerate(batches()):
                if i == 0:
                    with open(path, "a") as fh:
                        fh.write("0.4,4.0,3\n0.5,5.0,3\n")
                yield batch
        export.batches = growing
        return export

    monkeypatch.setattr(ing, "read_export", reader_while_the_bench_appends)
    first = rebuild(raw.root, warehouse, jobs=1)
    monkeypatch.undo()
    assert first.exit_code == 1
    assert [(p.source_path, p.error) for p in first.quarantine] == [("c/a.csv", tasks.CHANGED_WHILE_READ)]
    assert q(warehouse, "SELECT run_id FROM runs") == [("c/b",)]
    assert q(warehouse, "SELECT source_path, status, quarantined, error FROM rebuild_changes "
                        "WHERE source_path = 'c/a.csv'") == [("c/a.csv", "new", True, tasks.CHANGED_WHILE_READ)]
    second = rebuild(raw.root, warehouse, jobs=1)
    assert second.exit_code == 0 and second.quarantine == []
    whole = hashlib.sha256((raw.root / "c/a.csv").read_bytes()).hexdigest()
    assert q(warehouse, "SELECT n_samples, source_sha256 FROM runs WHERE run_id = 'c/a'") == [(6, whole)]


def test_a_small_read_forks_its_readers_after_the_stages_imports_and_a_large_one_before(raw, warehouse, monkeypatch):
    """Below ``WARM_READ_BYTES`` the rebuild imports the readers and the stages' modules first and
    forks its reader workers warm (nothing left to preload nor to do while they read); above it the
    readers are forked first and import while the rebuild imports. The warehouse is the same."""
    from pipeline.rebuild.executors import LocalExecutor

    seen = []
    real_map = LocalExecutor.map

    def spy(self, func, items, *a, **k):
        if k.get("on_crash") is not None:
            seen.append((list(k.get("preload") or ()), k.get("while_waiting")))
        return real_map(self, func, items, *a, **k)

    monkeypatch.setattr(LocalExecutor, "map", spy)
    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    preload, waiting = seen[-1]
    assert preload == [] and waiting is None  # imported before the readers were forked
    first = q(warehouse, "SELECT run_id, n_samples FROM runs")
    monkeypatch.setattr(tasks, "WARM_READ_BYTES", 0)
    step(raw, "c/b.csv", scale=2.0)
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    preload, waiting = seen[-1]
    assert preload and waiting is not None  # the readers import while this process does
    assert len(q(warehouse, "SELECT run_id FROM runs")) == len(first) + 1


@pytest.mark.parametrize("rel", ["c/a.csv", "camp aign/sub/b.tdms", "top.csv", "m\\xe9sure/x.csv", "a/b/c/d.mat"])
def test_a_records_campaign_is_the_trees(tmp_path, rel):
    from pipeline.raw.tree import RawTree
    from pipeline.rebuild.ingest_tasks import _campaign_of

    tree = RawTree(tmp_path)
    assert _campaign_of(rel) == tree.campaign(tmp_path / rel)
