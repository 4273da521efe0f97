"""The no-op fast path: a rebuild whose inputs and code are unchanged carries the database over,
exactly as the incremental path would have written it."""
import os
import re
import shutil
import time
from pathlib import Path

import pytest

import pipeline.rebuild.flow as rb
import pipeline.rebuild.noop as noop
from pipeline.rebuild.flow import rebuild
from pipeline.serve.door import connect_readonly
from tests.conftest import PROJECT_ROOT, STEP_META
from tests.pipeline.rebuild.test_state import BREAK, T, age, q, step


# -- the no-op fast path -----------------------------------------------------------------------------
#: Columns that differ between two rebuilds of the same inputs by nature (the clock, the process).
CLOCK_COLUMNS = {"generation", "started_at", "finished_at", "duration_s", "mode"}


def _everything(warehouse):
    """Every table of the warehouse, bookkeeping included, rows sorted; the clock columns of
    rebuild_log left out, and the content keys of ``table_keys`` (the no-op forgets some: checked apart)."""
    con = connect_readonly(warehouse)
    try:
        out = {}
        for (t,) in con.execute("SELECT table_name FROM duckdb_tables() WHERE table_name <> 'table_keys' "
                                "ORDER BY 1").fetchall():
            cols = [r[0] for r in con.execute(f'DESCRIBE "{t}"').fetchall()]
            if t == "rebuild_log":
                cols = [c for c in cols if c not in CLOCK_COLUMNS]
            out[t] = con.execute(f'SELECT {", ".join(chr(34) + c + chr(34) for c in cols)} FROM "{t}" '
                                 "ORDER BY ALL").fetchall()
        # a view's SQL as DuckDB prints it back; EXCLUDE is a set, printed in either order
        out["views"] = [(v, re.sub(r"EXCLUDE \(([^)]*)\)", lambda m: ", ".join(sorted(m.group(1).split(", "))), sql))
                        for v, sql in con.execute("SELECT view_name, sql FROM duckdb_views() WHERE NOT internal "
                                                  "ORDER BY 1").fetchall()]
        return out
    finally:
        con.close()


def _campaign_with_changes(raw, warehouse):
    """A warehouse whose last rebuild saw new, changed, deleted and quarantined inputs, a logbook
    and a superseded samples file: every bookkeeping column has something to carry or reset."""
    for i in range(3):
        step(raw, f"c/a{i}.csv", scale=1 + i)
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    step(raw, "c/a1.csv", scale=7.0)
    (raw.root / "c/a2.csv").unlink()
    raw.csv("c/bad.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[mm]": T})
    raw.write("c/manifest.csv", "file,notes\na0.csv,checked\n")
    raw.write("c/notes.txt", "not an export\n")
    age(raw.root)
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.mode == "incremental" and s.n_changed and s.n_deleted


def test_a_noop_rebuild_carries_the_database_over_exactly_as_the_incremental_path_writes_it(raw, tmp_path,
                                                                                           monkeypatch):
    import shutil

    fast, slow = tmp_path / "fast", tmp_path / "slow"
    _campaign_with_changes(raw, fast)
    shutil.copytree(fast, slow)
    now = time.time()
    a = rebuild(raw.root, fast, jobs=1, clock=lambda: now)
    monkeypatch.setattr(rb, "nothing_changed", lambda *args: False)
    b = rebuild(raw.root, slow, jobs=1, clock=lambda: now)
    assert (a.mode, b.mode) == ("no-op", "incremental")
    assert b.stages_run == []  # the incremental path reused every stage too: the same work, done slowly
    for attr in ("n_files", "n_runs", "n_new", "n_changed", "n_deleted", "n_unchanged", "exit_code", "stages_run"):
        assert getattr(a, attr) == getattr(b, attr), attr
    assert sorted(a.stages_reused) == sorted(b.stages_reused)
    assert [p.error for p in a.quarantine] == [p.error for p in b.quarantine] and a.exit_code == 1
    ta, tb = _everything(fast), _everything(slow)
    assert set(ta) == set(tb)
    # the content keys of the tables the no-op updated are forgotten (the next rebuild writes them
    # again; a key also covers the rows' order, which differs between the two paths' frames)
    keys_a, keys_b = (dict(q(wh, "SELECT table_name, content_key FROM table_keys")) for wh in (fast, slow))
    assert set(keys_b) - set(keys_a) == set(noop.NOOP_WRITES) and set(keys_a) < set(keys_b)
    assert keys_a["*"] == keys_b["*"]
    for t in ta:
        assert ta[t] == tb[t], t
    assert q(fast, "SELECT count(*) FROM rebuild_inputs WHERE status <> 'unchanged'") == [(0,)]
    assert q(fast, "SELECT mode FROM rebuild_log ORDER BY finished_at DESC LIMIT 1") == [("no-op",)]
    assert (fast / "report" / "index.html").is_file()
    html = (fast / "report" / "index.html").read_text()
    assert "no-op rebuild" in html and a.generation in html


@pytest.mark.parametrize("change", ["same size, other bytes", "new run file", "delete a run file", "new ignored file",
                                    "manifest", "rig.toml", "logbook", "code", "stage folder gone", "--full"])
def test_anything_that_may_change_the_warehouse_takes_the_incremental_path(raw, warehouse, monkeypatch, change):
    step(raw, "c/a.csv")
    step(raw, "c/b.csv")
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    assert rebuild(raw.root, warehouse, jobs=1).mode == "no-op"
    full = False
    if change == "same size, other bytes":  # a touch alone is a no-op (test_a_copied_...)
        path = raw.root / "c/a.csv"
        data = path.read_bytes()
        path.write_bytes(data.replace(b"1", b"4"))
        assert path.stat().st_size == len(data) and path.read_bytes() != data
    elif change == "new run file":
        step(raw, "c/c.csv")
    elif change == "delete a run file":
        (raw.root / "c/b.csv").unlink()
    elif change == "new ignored file":  # a README is a known non-run, in no table: that would be a no-op
        raw.write("c/extra.json", "{}\n")
    elif change == "manifest":
        raw.write("c/manifest.csv", "file,operator\na.csv,ana\n")
    elif change == "rig.toml":
        raw.write("c/rig.toml", '[metadata]\nrig = "plpa-2"\n')
    elif change == "logbook":
        raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                                 "H1,installed,2026-01-02T00:00:00,FLEXIGOM AIR,force,858\n")
    elif change == "code":
        import pipeline.versions as cv
        monkeypatch.setattr(noop, "project_code_version", lambda: "another-version")
    elif change == "stage folder gone":
        folder = q(warehouse, "SELECT folder FROM stage_cache LIMIT 1")[0][0]
        (warehouse / folder / "output.json").unlink()
    elif change == "--full":
        full = True
    age(raw.root, 1200)
    s = rebuild(raw.root, warehouse, jobs=1, full=full)
    assert s.mode == ("full" if full else "incremental"), change
    assert rebuild(raw.root, warehouse, jobs=1).mode == "no-op"  # and the next night is a no-op again


def _copy_tree(src, dst, keep_mtime: bool):
    """``cp -a`` (mtimes kept, new inodes) or ``cp -r`` (new mtimes too, aged as a night's files are)."""
    shutil.copytree(src, dst, symlinks=True, copy_function=shutil.copy2 if keep_mtime else shutil.copyfile)
    if not keep_mtime:
        age(dst, 900)


@pytest.mark.parametrize("keep_mtime", [True, False])
def test_a_copied_raw_tree_and_warehouse_rebuild_as_a_noop_and_record_the_new_stats(raw, tmp_path, monkeypatch,
                                                                                    keep_mtime):
    """Issue 26: a raw tree and its warehouse copied elsewhere (a backup restored, a new disk): every
    file has a new inode (and, with ``cp -r``, a new mtime), so none is unchanged at a glance. Each is
    hashed once in the rebuild's own process (none read by a reader), no stage runs, and the rebuild is
    the no-op, writing what the incremental path writes (the new stats recorded): the next night hashes
    nothing."""
    import pipeline.rebuild.ingest_tasks as tasks

    _campaign_with_changes(raw, tmp_path / "wh")
    rebuild(raw.root, tmp_path / "wh", jobs=1)
    moved = tmp_path / "elsewhere"
    for src, name in ((raw.root, "raw"), (tmp_path / "wh", "fast")):
        _copy_tree(src, moved / name, keep_mtime)
    shutil.copytree(moved / "fast", moved / "slow", symlinks=True)
    hashed, read = [], []
    real_sha, real_ingest = tasks.sha256_file, tasks.ingest_file
    monkeypatch.setattr(tasks, "sha256_file", lambda p, *a, **k: hashed.append(Path(p).name) or real_sha(p, *a, **k))
    monkeypatch.setattr(tasks, "ingest_file", lambda t, p, *a, **k: read.append(p.name) or real_ingest(t, p, *a, **k))
    now = time.time()
    a = rebuild(moved / "raw", moved / "fast", jobs=2, clock=lambda: now)
    assert a.mode == "no-op" and a.stages_run == [] and read == []
    runs = sorted(Path(r[0]).name for r in q(moved / "fast", "SELECT source_path FROM ingest_state WHERE role = 'run'"))
    assert sorted(hashed) == runs and len(runs) >= 4  # each run file once, in this process
    assert q(moved / "fast", "SELECT mode, len(stages_run) FROM rebuild_log ORDER BY seq DESC LIMIT 1") == [("no-op", 0)]
    monkeypatch.setattr(rb, "nothing_changed", lambda *args: False)  # the incremental path, from the same state
    b = rebuild(moved / "raw", moved / "slow", jobs=1, clock=lambda: now)
    assert b.mode == "incremental" and b.stages_run == [] and read == []
    ta, tb = _everything(moved / "fast"), _everything(moved / "slow")
    assert {t: ta[t] for t in ta if ta[t] != tb[t]} == {}
    monkeypatch.undo()
    stats = {r[0]: r[1:] for r in q(moved / "fast", "SELECT source_path, size_bytes, mtime_ns, inode FROM ingest_state")}
    for rel, (size, mtime_ns, inode) in stats.items():
        st = (moved / "raw" / rel).stat()
        assert (size, mtime_ns, inode) == (st.st_size, st.st_mtime_ns, st.st_ino), rel
    hashed.clear()
    again = rebuild(moved / "raw", moved / "fast", jobs=1)
    assert again.mode == "no-op" and hashed == []


def test_a_noop_rebuild_killed_before_its_swap_leaves_the_warehouse_as_it_was(raw, warehouse):
    import subprocess
    import sys

    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    before = _everything(warehouse)
    code = ("import sys; from pipeline.rebuild.flow import rebuild; "
            "rebuild(sys.argv[1], sys.argv[2], jobs=1)")
    env = {**os.environ, "PNEUBENCH_CRASH_AT": "before_swap", "PYTHONPATH": str(PROJECT_ROOT)}
    p = subprocess.run([sys.executable, "-c", code, str(raw.root), str(warehouse)], env=env, capture_output=True)
    assert p.returncode == -9
    assert _everything(warehouse) == before
    s = rebuild(raw.root, warehouse, jobs=1)  # the debris is cleaned, the no-op goes through
    assert s.mode == "no-op" and not list(warehouse.glob(".*.tmp-*"))


def test_the_noops_imports_load_no_numeric_library():
    """The no-op's whole cost is start-up: the command line and the rebuild's flow import none of
    pandas, numpy, scipy, matplotlib or pyarrow (a report module importing a stage for a constant
    once pulled in scipy.stats and pandas: 0.3 s -> 2 s of imports)."""
    import subprocess
    import sys

    code = ("import sys, pipeline.cli\nfrom pipeline.rebuild import flow, noop\n"
            "print(sorted(m for m in ('pandas', 'numpy', 'scipy', 'matplotlib', 'pyarrow') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_a_touched_run_file_swapped_for_a_symlink_out_of_raw_with_the_same_bytes_is_not_confirmed(raw, warehouse,
                                                                                                  tmp_path):
    """Hostile beside the copied tree above: the same bytes and size behind a symlink out of raw/ are
    not a file whose stat alone changed; the night quarantines it with one line naming it, keeps the
    other runs, and neither the link nor its target is touched."""
    for name in ("c/a.csv", "c/b.csv", "c/c.csv"):
        step(raw, name)
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    victim = raw.root / "c" / "a.csv"
    outside = tmp_path / "outside.csv"
    shutil.copy2(victim, outside)
    body = outside.read_bytes()
    victim.unlink()
    os.symlink(outside, victim)
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.mode == "incremental"
    assert [(p.source_path, p.error.split(":")[0]) for p in s.quarantine] == [("c/a.csv", "symlink to a file outside raw/")]
    assert q(warehouse, "SELECT source_path FROM ingest_state WHERE role = 'run' ORDER BY 1") == [("c/b.csv",), ("c/c.csv",)]
    assert victim.is_symlink() and os.readlink(victim) == str(outside) and outside.read_bytes() == body
