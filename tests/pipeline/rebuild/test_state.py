"""Incremental rebuilds: unchanged files are not read, changes and deletions land, stages re-run
only when their inputs changed, and the result equals a full rebuild table by table."""
import json
import os
import re
import time
from pathlib import Path

import pandas as pd
import pytest

import pipeline.rebuild.flow as rb
from pipeline.rebuild.flow import rebuild
from pipeline.stages import StageOutput
from pipeline.serve.door import connect_readonly
from tests.conftest import PROJECT_ROOT, STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]
REBUILD_ONLY = {"rebuild_log", "rebuild_inputs", "ingest_state", "stage_cache", "superseded_files"}
BREAK = {"kind": "breakaway", "started_at": "2026-01-02T03:04:05", "rig": "plpa-1", "direction": "P",
         "backpressure_bar": 0, "force_rate_n_s": 1, "hose_area_m2": 4.9e-4}


def age(root, seconds=3600):
    """Move every file's mtime into the past (a file written this second is 'racy': always hashed)."""
    past = time.time() - seconds
    for p in root.rglob("*"):
        if p.is_file():
            os.utime(p, (past, past))


def step(raw, rel, scale=1.0, **meta):
    return raw.csv(rel, {**STEP_META, **meta}, {"t[s]": T, "x[mm]": [v * scale for v in (0, 1, 2, 3)],
                                                "x_ref[mm]": [3] * 4})


def dump(warehouse):
    con = connect_readonly(warehouse)
    try:
        names = [r[0] for r in con.execute("SELECT table_name FROM duckdb_tables() UNION ALL "
                                           "SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()]
        out = {}
        for t in sorted(set(names) - REBUILD_ONLY - {"rebuild_changes"}):
            cols = [c for c in (r[0] for r in con.execute(f'DESCRIBE "{t}"').fetchall())
                    if c not in ("previous_holds", "change") and (t, c) != ("figures", "path")]
            sel = ", ".join(f'"{c}"' for c in cols)
            out[t] = con.execute(f'SELECT {sel} FROM "{t}" ORDER BY ALL').fetchall()
        return out
    finally:
        con.close()


q = query


class ReadLog:
    """Calls recorded by hooks that run in the ingest worker processes (forked from the test, so
    they carry its monkeypatches): one JSON line per call in a file, read back here."""

    def __init__(self, path):
        self.path = path
        self.clear()

    def record(self, key, value):
        import json

        with open(self.path, "a") as fh:
            fh.write(json.dumps([key, value]) + "\n")

    def __getitem__(self, key):
        import json

        return [v for k, v in (json.loads(line) for line in self.path.read_text().splitlines()) if k == key]

    def as_dict(self, *keys):
        return {k: self[k] for k in keys}

    def clear(self):
        self.path.write_text("")


@pytest.fixture
def counting(monkeypatch, tmp_path):
    """Count files read (hashed or ingested) by the rebuild, in whatever process reads them."""
    seen = ReadLog(tmp_path / "reads.jsonl")
    real_sha, real_ingest = rb.sha256_file, rb.ingest_file
    monkeypatch.setattr(rb, "sha256_file", lambda p, *a, **k: seen.record("sha", p.name) or real_sha(p, *a, **k))
    monkeypatch.setattr(rb, "ingest_file",
                        lambda t, p, *a, **k: seen.record("ingest", p.name) or real_ingest(t, p, *a, **k))
    return seen


def test_noop_rebuild_reads_no_file_and_reruns_no_stage(raw, warehouse, counting):
    for i in range(3):
        step(raw, f"c/a{i}.csv")
    age(raw.root)
    first = rebuild(raw.root, warehouse, jobs=1)
    assert sorted(counting["ingest"]) == ["a0.csv", "a1.csv", "a2.csv"]
    assert first.n_new == 3 and first.stages_run
    counting.clear()
    second = rebuild(raw.root, warehouse, jobs=1)
    assert counting.as_dict("sha", "ingest") == {"sha": [], "ingest": []}
    assert (second.n_new, second.n_changed, second.n_deleted, second.n_unchanged) == (0, 0, 0, 3)
    assert second.stages_run == [] and set(second.stages_reused) == set(first.stages_run)
    assert q(warehouse, "SELECT count(*) FROM rebuild_log") == [(2,)]
    assert q(warehouse, "SELECT count(*) FROM rebuild_changes") == [(0,)]


def test_touch_hashes_but_does_not_reingest(raw, warehouse, counting):
    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    counting.clear()
    os.utime(raw.root / "c/a.csv", None)  # new mtime, same bytes
    s = rebuild(raw.root, warehouse, jobs=1)
    assert counting["sha"] == ["a.csv"] and counting["ingest"] == []
    assert s.n_unchanged == 1


def test_changes_deletions_and_metadata_changes(raw, warehouse, counting):
    step(raw, "c/a.csv")
    step(raw, "c/b.csv")
    step(raw, "c/sub/c.csv")
    step(raw, "d/e.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    counting.clear()
    step(raw, "c/b.csv", scale=2.0)                                   # content changed
    (raw.root / "d/e.csv").unlink()                                   # deleted
    raw.write("c/sub/manifest.csv", "file,operator\nc.csv,ana\n")     # metadata of c changed
    step(raw, "c/new.csv")                                            # new
    age(raw.root)
    s = rebuild(raw.root, warehouse, jobs=1)
    assert sorted(counting["ingest"]) == ["b.csv", "c.csv", "new.csv"]
    assert (s.n_new, s.n_changed, s.n_deleted, s.n_unchanged) == (1, 2, 1, 1)
    changes = {r[0]: r[1:] for r in q(warehouse, "SELECT source_path, status, reason FROM rebuild_changes")}
    assert changes == {"c/b.csv": ("changed", "content"), "c/sub/c.csv": ("changed", "metadata"),
                       "d/e.csv": ("deleted", None), "c/new.csv": ("new", None),
                       "c/sub/manifest.csv": ("new", None)}
    assert q(warehouse, "SELECT run_id FROM runs ORDER BY run_id") == [("c/a",), ("c/b",), ("c/c",), ("c/new",)]
    assert q(warehouse, "SELECT json_extract_string(params, '$.operator') FROM runs WHERE run_id = 'c/c'") == [("ana",)]
    assert q(warehouse, "SELECT max(x_m) FROM samples_step WHERE run_id = 'c/b'") == [(pytest.approx(0.006),)]
    assert q(warehouse, "SELECT count(*) FROM samples_step WHERE run_id = 'd/e'") == [(0,)]
    # the deleted run's samples file is kept for readers of earlier warehouses (24 h), then collected
    assert any(p.name.startswith("d_e-") for p in (warehouse / "samples").rglob("*.parquet"))
    rebuild(raw.root, warehouse, jobs=1, clock=lambda: time.time() + 25 * 3600)
    files = {p.name for p in (warehouse / "samples").rglob("*.parquet")}
    assert not any(f.startswith("d_e-") for f in files)


def test_rig_toml_change_reingests_the_files_below_it(raw, warehouse, counting):
    step(raw, "c/x/a.csv")
    step(raw, "c/y/b.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    counting.clear()
    raw.write("c/x/rig.toml", '[metadata]\nrig = "plpa-2"\n')
    s = rebuild(raw.root, warehouse, jobs=1)
    assert counting["ingest"] == ["a.csv"] and s.n_changed == 1
    # the embedded `rig` is stronger than rig.toml: same value, but the file was re-read


def test_quarantined_file_stays_quarantined_without_being_read(raw, warehouse, counting):
    raw.csv("c/bad.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[mm]": T})
    age(raw.root)
    a = rebuild(raw.root, warehouse, jobs=1)
    counting.clear()
    b = rebuild(raw.root, warehouse, jobs=1)
    assert counting["ingest"] == [] and b.exit_code == a.exit_code == 1
    assert [p.error for p in b.quarantine] == [p.error for p in a.quarantine]
    assert q(warehouse, "SELECT source_path, quarantined FROM rebuild_changes") == [("c/bad.csv", True)]


class CountingStage:
    """A stage reading step runs and the earlier tables; counts its runs."""
    NAME, ORDER, KINDS, TABLES = "zz_count", 95, ("step",), ("zz_count",)
    calls = 0

    @classmethod
    def run(cls, ctx):
        cls.calls += 1
        n = len(ctx.runs_of("step"))
        return StageOutput(tables={"zz_count": pd.DataFrame({"n_step_runs": [n]})})


def test_stage_reruns_only_when_its_kinds_change(raw, warehouse, monkeypatch):
    import pipeline.stages as st
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), CountingStage])
    step(raw, "c/a.csv")
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    age(raw.root)
    CountingStage.calls = 0
    rebuild(raw.root, warehouse, jobs=1)
    rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 1
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": [1, 2, 3, 4], "p_b[bar]": T, "x[mm]": T})  # other kind
    s = rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 1 and "zz_count" in s.stages_reused
    assert "plpa_characterisation" in s.stages_run
    step(raw, "c/c.csv")
    rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 2
    assert q(warehouse, "SELECT n_step_runs FROM zz_count") == [(2,)]
    rebuild(raw.root, warehouse, jobs=1, full=True)
    assert CountingStage.calls == 3


def test_logbook_change_reruns_durability_only(raw, warehouse):
    step(raw, "c/a.csv")
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n,failure_mode,distance_km\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858,,\n"
                             "H1,failed,2026-02-01T00:00:00,,,,rupture,80\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert "durability" in s.stages_run and "plpa_characterisation" in s.stages_reused
    assert q(warehouse, "SELECT status FROM rebuild_changes WHERE source_path = 'c/hoses.csv'") == [("changed",)]
    assert q(warehouse, "SELECT hose_id, status FROM hose_life") == [("H1", "failed")]


def test_incremental_equals_full_table_by_table(raw, tmp_path):
    inc, full = tmp_path / "inc", tmp_path / "full"
    for i in range(4):
        step(raw, f"c/a{i}.csv", scale=1 + i)
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    raw.csv("c/bad.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[mm]": T})
    age(raw.root)
    rebuild(raw.root, inc, jobs=1)
    step(raw, "c/a1.csv", scale=7.0)
    (raw.root / "c/a2.csv").unlink()
    raw.write("c/manifest.csv", "file,notes\na0.csv,<b>bold</b>\n")
    step(raw, "d/z.csv")
    age(raw.root)
    rebuild(raw.root, inc, jobs=2)
    rebuild(raw.root, full, jobs=2, full=True)
    a, b = dump(inc), dump(full)
    assert set(a) == set(b)
    for table in a:
        assert a[table] == b[table], table
    assert len(a["runs"]) == 5 and len(a["quarantine"]) == 1


def test_a_stage_version_covers_the_project_modules_it_imports():
    # the durability stage reads hose logbooks through pipeline.raw.logbook: a change there must
    # re-run it (incremental == full), as must a unit change under an analysis (schemas.units)
    from pipeline.rebuild.state import _ROOT, project_imports

    files = {f.relative_to(_ROOT).as_posix() for f in project_imports(_ROOT / "pipeline/stages/durability.py")}
    assert {"pipeline/stages/durability.py", "pipeline/raw/logbook.py", "analyses/service_life.py",
            "analyses/durability.py"} <= files
    files = {f.relative_to(_ROOT).as_posix() for f in project_imports(_ROOT / "analyses/leakage.py")}
    assert "schemas/units.py" in files
    assert not any(f.startswith(("numpy", "pandas")) for f in files)


def test_project_imports_follows_imports_transitively(tmp_path, monkeypatch):
    import pipeline.rebuild.state as state

    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "a.py").write_text("import numpy\nfrom pipeline.b import thing\n")
    (tmp_path / "pipeline" / "b.py").write_text("from pipeline import c\nthing = 1\n")
    (tmp_path / "pipeline" / "c.py").write_text("x = 1\n")
    (tmp_path / "pipeline" / "d.py").write_text("x = 2\n")
    monkeypatch.setattr(state, "_ROOT", tmp_path)
    got = {f.name for f in state.project_imports(tmp_path / "pipeline" / "a.py")}
    assert got == {"a.py", "b.py", "c.py"}


def test_a_new_file_is_hashed_once(raw, warehouse, monkeypatch, tmp_path):
    # a new file is hashed by ingest while it parses it; a touched one by the rebuild, to decide
    import pipeline.ingest.file as ing

    log = ReadLog(tmp_path / "calls.jsonl")
    real = ing.sha256_file
    for mod in (rb, ing):
        monkeypatch.setattr(mod, "sha256_file", lambda p, *a, **k: log.record("sha", p.name) or real(p, *a, **k))
    step(raw, "c/a.csv")
    rebuild(raw.root, warehouse, jobs=1)
    assert log["sha"].count("a.csv") == 1
    assert q(warehouse, "SELECT source_sha256 FROM runs") == [(real(raw.root / "c" / "a.csv"),)]
    # touched with other bytes: the rebuild hashes it to decide and ingest reuses that hash
    log.clear()
    age(raw.root)
    step(raw, "c/a.csv", scale=2.0)
    rebuild(raw.root, warehouse, jobs=1)
    assert log["sha"].count("a.csv") == 1
    assert q(warehouse, "SELECT source_sha256 FROM runs") == [(real(raw.root / "c" / "a.csv"),)]


@pytest.mark.raw_written("c/a.csv")
def test_a_file_written_while_it_is_read_is_read_again_next_time(raw, warehouse, monkeypatch):
    # its hash and its samples may be of different bytes: the record says "look again"
    step(raw, "c/a.csv")
    age(raw.root)
    real = rb.ingest_file

    def ingest_while_the_bench_writes(tree, path, *a, **k):
        res = real(tree, path, *a, **k)
        step(raw, "c/a.csv", scale=2.0)  # the DAQ rewrites the file meanwhile
        return res

    monkeypatch.setattr(rb, "ingest_file", ingest_while_the_bench_writes)
    first = rebuild(raw.root, warehouse, jobs=1)
    monkeypatch.undo()
    assert [(p.source_path, p.error) for p in first.quarantine] == [("c/a.csv", rb.CHANGED_WHILE_READ)]
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
    real = rb.ingest_file
    seen = ReadLog(tmp_path / "seen.jsonl")

    def ingest_while_the_bench_writes(tree, path, *a, **k):
        seen.record("reuse", k.get("reuse"))
        res = real(tree, path, *a, **k)
        if len(seen["reuse"]) == 1:
            step(raw, "c/a.csv", scale=2.0)
        return res

    monkeypatch.setattr(rb, "ingest_file", ingest_while_the_bench_writes)
    rebuild(raw.root, warehouse, jobs=1)
    rebuild(raw.root, warehouse, jobs=1)
    assert seen["reuse"] == [True, False]


def test_a_file_that_cannot_be_opened_is_tried_again_next_time(raw, warehouse, monkeypatch):
    import pipeline.ingest.file as ing

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

    import pipeline.ingest.file as ing

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
    assert [(p.source_path, p.error) for p in first.quarantine] == [("c/a.csv", rb.CHANGED_WHILE_READ)]
    assert q(warehouse, "SELECT run_id FROM runs") == [("c/b",)]
    assert q(warehouse, "SELECT source_path, status, quarantined, error FROM rebuild_changes "
                        "WHERE source_path = 'c/a.csv'") == [("c/a.csv", "new", True, rb.CHANGED_WHILE_READ)]
    second = rebuild(raw.root, warehouse, jobs=1)
    assert second.exit_code == 0 and second.quarantine == []
    whole = hashlib.sha256((raw.root / "c/a.csv").read_bytes()).hexdigest()
    assert q(warehouse, "SELECT n_samples, source_sha256 FROM runs WHERE run_id = 'c/a'") == [(6, whole)]


def test_superseded_files_are_kept_for_the_retention_then_expire():
    from pipeline.rebuild.state import PreviousState, superseded_files

    prev = PreviousState(samples={"samples/a", "samples/b"}, stage_folders={"stages/s/1"},
                         superseded={"samples/old": 1000.0, "samples/back": 1000.0})
    kept, expired = superseded_files(prev, {"samples/b", "samples/back", "stages/s/2"}, now=5000.0, keep_h=2.0)
    # newly superseded: stamped now; superseded earlier: keeps its first stamp; used again: dropped
    assert kept == {"samples/a": 5000.0, "stages/s/1": 5000.0, "samples/old": 1000.0}
    assert expired == set()
    kept, expired = superseded_files(prev, {"samples/b"}, now=1000.0 + 3600.0, keep_h=1.0)
    assert expired == {"samples/old", "samples/back"} and "samples/a" in kept
    assert superseded_files(prev, set(), now=5000.0, keep_h=0.0)[0] == {}  # 0: collect at once


def _sheets_book(raw, rel, n=3):
    openpyxl = pytest.importorskip("openpyxl")
    wb = openpyxl.Workbook()
    wb.remove(wb.active)
    for i in range(n):
        ws = wb.create_sheet(f"S{i}")
        ws.append(["t[s]", "x[mm]", "x_ref[mm]"])
        for j in range(4):
            ws.append([0.1 * j, (i + 1) * j, 0.0])
    ms = wb.create_sheet("meta")
    for k, v in STEP_META.items():
        ms.append([k, v])
    path = raw.root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    wb.save(path)
    raw.write(str(Path(rel).parent / "rig.toml"), '[read]\nsheets = "all"\n')
    return path


def test_a_workbook_of_sheets_is_one_state_record_reused_read_by_its_bytes(raw, warehouse, counting):
    book = _sheets_book(raw, "c/b.xlsx")
    age(raw.root)
    assert rebuild(raw.root, warehouse, jobs=1).n_runs == 3
    assert counting["ingest"] == ["b.xlsx"]                     # one read for its three runs
    (rec,), = q(warehouse, "SELECT result FROM ingest_state WHERE role = 'run'")
    assert [p["run"]["run_id"] for p in json.loads(rec)["parts"]] == ["c/b/S0", "c/b/S1", "c/b/S2"]
    counting.clear()
    s = rebuild(raw.root, warehouse, jobs=1)                     # no-op: nothing read, all reused
    assert counting.as_dict("sha", "ingest") == {"sha": [], "ingest": []} and (s.n_unchanged, s.n_runs) == (1, 3)
    os.utime(book, None)                                         # touch: hashed, not re-read
    s = rebuild(raw.root, warehouse, jobs=1)
    assert counting["sha"] == ["b.xlsx"] and counting["ingest"] == [] and s.n_runs == 3
    # one sheet's samples file gone: the file is read again and all its runs are back
    lost = warehouse / q(warehouse, "SELECT samples_path FROM runs WHERE run_id = 'c/b/S1'")[0][0]
    lost.unlink()
    counting.clear()
    s = rebuild(raw.root, warehouse, jobs=1)
    assert counting["ingest"] == ["b.xlsx"] and s.n_runs == 3 and lost.is_file()


def test_result_runs_and_record_result_round_trip_parts():
    from pipeline.ingest.file import IngestResult
    from pipeline.rebuild.state import record_result, result_runs

    single = IngestResult("c/a.csv", "c", run={"run_id": "c/a", "samples_path": "s/a.parquet"}, channels=[{"c": 1}])
    assert record_result(single) == {"run": single.run, "channels": [{"c": 1}]}
    assert result_runs(record_result(single)) == [single.run]
    assert record_result(IngestResult("c/a.csv", "c", error="bad")) is None and result_runs(None) == []
    book = IngestResult("c/b.xlsx", "c", parts=[IngestResult("c/b.xlsx", "c", run={"run_id": "c/b/A"}),
                                                IngestResult("c/b.xlsx", "c", error="sheet 'B': bad")])
    rec = record_result(book)
    assert rec == {"parts": [{"run": {"run_id": "c/b/A"}, "channels": []}, {"error": "sheet 'B': bad"}]}
    assert result_runs(rec) == [{"run_id": "c/b/A"}]


# -- the no-op fast path -----------------------------------------------------------------------------
#: Columns that differ between two rebuilds of the same inputs by nature (the clock, the process).
CLOCK_COLUMNS = {"generation", "started_at", "finished_at", "duration_s", "mode"}


def _everything(warehouse):
    """Every table of the warehouse, bookkeeping included, rows sorted; the clock columns of
    rebuild_log left out."""
    con = connect_readonly(warehouse)
    try:
        out = {}
        for (t,) in con.execute("SELECT table_name FROM duckdb_tables() ORDER BY 1").fetchall():
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
    for t in ta:
        assert ta[t] == tb[t], t
    assert q(fast, "SELECT count(*) FROM rebuild_inputs WHERE status <> 'unchanged'") == [(0,)]
    assert q(fast, "SELECT mode FROM rebuild_log ORDER BY finished_at DESC LIMIT 1") == [("no-op",)]
    assert (fast / "report" / "index.html").is_file()
    html = (fast / "report" / "index.html").read_text()
    assert "no-op rebuild" in html and a.generation in html


@pytest.mark.parametrize("change", ["touch a run file", "new run file", "delete a run file", "new ignored file",
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
    if change == "touch a run file":
        os.utime(raw.root / "c/a.csv", (time.time() - 600, time.time() - 600))
    elif change == "new run file":
        step(raw, "c/c.csv")
    elif change == "delete a run file":
        (raw.root / "c/b.csv").unlink()
    elif change == "new ignored file":
        raw.write("c/readme.md", "notes\n")
    elif change == "manifest":
        raw.write("c/manifest.csv", "file,operator\na.csv,ana\n")
    elif change == "rig.toml":
        raw.write("c/rig.toml", '[metadata]\nrig = "plpa-2"\n')
    elif change == "logbook":
        raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                                 "H1,installed,2026-01-02T00:00:00,FLEXIGOM AIR,force,858\n")
    elif change == "code":
        import pipeline.versions as cv
        monkeypatch.setattr(rb, "project_code_version", lambda: "another-version")
    elif change == "stage folder gone":
        folder = q(warehouse, "SELECT folder FROM stage_cache LIMIT 1")[0][0]
        (warehouse / folder / "output.json").unlink()
    elif change == "--full":
        full = True
    age(raw.root, 1200)
    s = rebuild(raw.root, warehouse, jobs=1, full=full)
    assert s.mode == ("full" if full else "incremental"), change
    assert rebuild(raw.root, warehouse, jobs=1).mode == "no-op"  # and the next night is a no-op again


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
