"""Incremental rebuilds: unchanged files are not read, changes and deletions land, stages re-run
only when their inputs changed, and the result equals a full rebuild table by table."""
import json
import os
import time
from pathlib import Path

import pytest

import pipeline.rebuild.ingest_tasks as tasks
from pipeline.rebuild.flow import rebuild
from pipeline.serve.door import connect_readonly
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]
REBUILD_ONLY = {"rebuild_log", "rebuild_inputs", "ingest_state", "stage_cache", "superseded_files", "table_keys"}
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
    real_sha, real_ingest = tasks.sha256_file, tasks.ingest_file
    monkeypatch.setattr(tasks, "sha256_file", lambda p, *a, **k: seen.record("sha", p.name) or real_sha(p, *a, **k))
    monkeypatch.setattr(tasks, "ingest_file",
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


def test_a_plan_toml_is_hashed_and_its_changes_reported_without_reingesting_a_run(raw, warehouse, counting):
    step(raw, "c/a.csv")
    raw.write("plan.toml", "[defaults]\nmargin = 1.3\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    assert q(warehouse, "SELECT role, status FROM rebuild_changes WHERE source_path = 'plan.toml'") == [("plan", "new")]
    assert q(warehouse, "SELECT role, source_sha256 IS NOT NULL FROM ingest_state WHERE source_path = 'plan.toml'") == [
        ("plan", True)]
    counting.clear()
    raw.write("plan.toml", "[defaults]\nmargin = 1.4\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.mode != "no-op" and counting["ingest"] == [] and s.n_unchanged == 1
    assert q(warehouse, "SELECT role, status, reason FROM rebuild_changes") == [("plan", "changed", "content")]
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)  # records the aged mtime (a file written this second is hashed again)
    assert rebuild(raw.root, warehouse, jobs=1).mode == "no-op"


def test_quarantined_file_stays_quarantined_without_being_read(raw, warehouse, counting):
    raw.csv("c/bad.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[mm]": T})
    age(raw.root)
    a = rebuild(raw.root, warehouse, jobs=1)
    counting.clear()
    b = rebuild(raw.root, warehouse, jobs=1)
    assert counting["ingest"] == [] and b.exit_code == a.exit_code == 1
    assert [p.error for p in b.quarantine] == [p.error for p in a.quarantine]
    assert q(warehouse, "SELECT source_path, quarantined FROM rebuild_changes") == [("c/bad.csv", True)]


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
    from pipeline.ingest.result import IngestResult
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




def test_runs_are_encoded_once_for_every_stage_key_with_the_same_fingerprints():
    from pipeline.rebuild.state import encoded_runs, runs_fingerprint, stage_input_key

    runs = [{"run_id": "b", "kind": "step", "params": {"x": 1.5}}, {"run_id": "a", "kind": "spring", "n": None},
            {"run_id": "c", "kind": "step", "when": Path("p")}]
    enc = encoded_runs(runs)
    assert [k for k, _ in enc] == ["spring", "step", "step"]  # sorted by run_id
    for kinds in (None, set(), {"step"}, {"spring", "step"}, {"leakage"}):
        assert runs_fingerprint(runs, kinds, enc) == runs_fingerprint(runs, kinds)
    assert stage_input_key("s", "c", runs, {"step"}, "lb", "pl", enc) == stage_input_key("s", "c", runs, {"step"}, "lb", "pl")
    assert runs_fingerprint(runs, {"step"}) != runs_fingerprint(runs, {"spring"})


def test_a_stored_records_result_is_written_back_as_the_text_it_was_read_from_unless_replaced():
    from pipeline.rebuild.state import FileRecord

    result = {"run": {"run_id": "c/a", "x": 0.1, "name": "m\u00e9sure"}, "channels": [{"column": "x_m"}]}
    text = json.dumps(result, sort_keys=True)
    row = ("c/a.csv", "run", 10, 5, 7, "sha", "mh", "1-x", text, None, None)
    rec = FileRecord.stored(row)
    assert rec.as_row()["result"] == text  # decoded for the row, written back as read
    assert rec.result == result and rec.result_text() == text
    rec.result = {"run": {"run_id": "c/a", "x": 0.2}}  # replaced: encoded again
    assert rec.as_row()["result"] == json.dumps(rec.result, sort_keys=True)
    for stored in (None, "", "null"):  # no result, whatever the column held
        assert FileRecord.stored(row[:8] + (stored, None, None)).as_row()["result"] is None
    fresh = FileRecord("c/b.csv", "run", 1, 2, 3, "s", None, None, result)
    assert fresh.as_row()["result"] == text


def test_a_stored_runs_row_keeps_its_text_and_encodes_to_the_bytes_a_fresh_row_does():
    from pipeline.rebuild.state import FileRecord, StoredRun, decode_result, encoded_runs, runs_fingerprint

    run = {"run_id": "c/a", "kind": "step", "x": 0.1, "name": "m\u00e9sure \"run\": ", "params": {"run": {"b": 1}},
           "warnings": ["w"]}
    result = {"run": run, "channels": [{"column": "x_m", "raw_name": ", \"run\": {"}]}
    text = json.dumps(result, sort_keys=True)
    rec = FileRecord.stored(("c/a.csv", "run", 10, 5, 7, "sha", "mh", "1-x", text, None, None))
    assert rec.result == result and type(rec.result["run"]) is StoredRun
    assert rec.result["run"].encoded == json.dumps(run, sort_keys=True, default=str).encode()
    assert rec.result_text() == text
    fresh = dict(run, run_id="c/b")
    assert encoded_runs([rec.result["run"], fresh]) == encoded_runs([dict(run), fresh])
    assert runs_fingerprint([rec.result["run"]], {"step"}) == runs_fingerprint([dict(run)], {"step"})
    parts = json.dumps({"parts": [{"run": run, "channels": []}, {"error": "e"}]}, sort_keys=True)
    others = [parts, '{"channels": [], "run": null}', '{"channels": [], "run": {"a": 1}, "x": 2}', "null",
              '{"channels": [1, 2]}']
    for other in others:  # anything else: decoded as it is
        assert decode_result(other) == json.loads(other)
    with pytest.raises(ValueError):
        decode_result('{"channels": [}')
