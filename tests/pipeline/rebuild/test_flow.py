"""The rebuild end to end: runs, quarantine, views, exit codes, and the previous warehouse kept on failure."""
import pytest

from pipeline.rebuild.flow import EXIT_OK, EXIT_QUARANTINED, RebuildError, rebuild
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]


q = query


def test_rebuild_builds_runs_views_and_quarantine(raw, warehouse):
    raw.csv("c1/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    raw.csv("c1/b.csv", {**STEP_META, "extra": "yes"}, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "temp[degC]": T})
    raw.csv("c2/bad.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[mm]": T})
    raw.write("c1/README.md", "notes, not a run")
    summary = rebuild(raw.root, warehouse, jobs=2)
    assert summary.exit_code == EXIT_QUARANTINED
    assert q(warehouse, "SELECT run_id, kind, campaign, n_samples FROM runs ORDER BY run_id") == [
        ("c1/a", "step", "c1", 4), ("c1/b", "step", "c1", 4)]
    assert q(warehouse, "SELECT source_path FROM quarantine") == [("c2/bad.csv",)]
    # the view unifies runs with different channels by name
    rows = q(warehouse, "SELECT run_id, x_m, temp_degc FROM samples_step ORDER BY run_id, t_s")
    assert rows[3] == ("c1/a", pytest.approx(0.003), None)
    assert rows[4][2] == 0.0
    assert q(warehouse, "SELECT count(*) FROM samples_durability") == [(0,)]
    assert q(warehouse, "SELECT json_extract_string(params, '$.extra') FROM runs WHERE run_id = 'c1/b'") == [("yes",)]


def test_duplicate_run_id_is_quarantined_first_path_wins(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "run_id": "r7"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.csv("c/b/c.csv", {**STEP_META, "run_id": "r7"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert [p.error for p in summary.quarantine] == ["duplicate run_id `r7`, already used by `c/a.csv`"]


def test_manifest_entries_outside_raw_or_missing_are_quarantined(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/manifest.csv", "file,notes\na.csv,fine\n../../etc/passwd,evil\nnope.csv,gone\n")
    summary = rebuild(raw.root, warehouse, jobs=1)
    errors = {(p.source_path, p.line, p.error) for p in summary.quarantine}
    assert ("c/manifest.csv", 3, "entry `../../etc/passwd` points outside raw/") in errors
    assert ("c/manifest.csv", 4, "entry `nope.csv`: no such file") in errors
    assert q(warehouse, "SELECT json_extract_string(params, '$.notes') FROM runs") == [("fine",)]


def test_clean_tree_exits_zero(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_OK


def test_failed_stage_keeps_previous_warehouse(raw, warehouse, monkeypatch):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    rebuild(raw.root, warehouse, jobs=1)
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})

    class Boom:
        NAME = "boom"

        @staticmethod
        def run(ctx):
            raise RuntimeError("analysis bug")

    import pipeline.stages as st
    monkeypatch.setattr(st, "discover", lambda: [Boom])
    with pytest.raises(RebuildError, match="stage boom failed"):
        rebuild(raw.root, warehouse, jobs=1)
    assert q(warehouse, "SELECT run_id FROM runs") == [("c/a",)]
    assert not [p for p in warehouse.iterdir() if ".tmp" in p.name]


def test_rebuild_is_deterministic(raw, tmp_path):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    rebuild(raw.root, tmp_path / "w1", jobs=1)
    rebuild(raw.root, tmp_path / "w2", jobs=2)
    ra = q(tmp_path / "w1", "SELECT * EXCLUDE (samples_path) FROM runs")
    rb = q(tmp_path / "w2", "SELECT * EXCLUDE (samples_path) FROM runs")
    assert ra == rb
    fa = (tmp_path / "w1" / q(tmp_path / "w1", "SELECT samples_path FROM runs")[0][0]).read_bytes()
    fb = (tmp_path / "w2" / q(tmp_path / "w2", "SELECT samples_path FROM runs")[0][0]).read_bytes()
    assert fa == fb


def test_runs_with_and_without_fractional_seconds_build_together(raw, warehouse):
    # LVM headers give fractional seconds, CSV exports often none: one warehouse holds both
    raw.csv("c/a.csv", {**STEP_META, "started_at": "2026-01-02T03:04:05"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.csv("c/b.csv", {**STEP_META, "started_at": "2026-01-02T03:04:05.5"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_OK
    rows = q(warehouse, "SELECT run_id, epoch_ms(started_at) FROM runs ORDER BY run_id")
    assert [r[1] - rows[0][1] for r in rows] == [0, 500]


def test_manifest_rows_that_cannot_apply_are_quarantined_with_their_line(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.csv("d/z.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/manifest.csv", "file,notes\na.csv,first\n,orphan\n../d/z.csv,elsewhere\na.csv,second\n")
    raw.write("d/manifest.csv", "name,notes\nz.csv,no file column\n")
    summary = rebuild(raw.root, warehouse, jobs=1)
    errors = {(p.source_path, p.line, p.error) for p in summary.quarantine}
    assert errors == {
        ("c/manifest.csv", 3, "row has no `file`"),
        ("c/manifest.csv", 4, "entry `../d/z.csv` is not in the manifest's folder or below "
                              "(a manifest applies only there)"),
        ("c/manifest.csv", 5, "entry `a.csv` is listed twice; the later row is used"),
        ("d/manifest.csv", None, "no `file` column in the header"),
        # a manifest refused as a whole: the runs under it wait (issue 21, item 14)
        ("d/z.csv", None, "cannot use d/manifest.csv: no `file` column in the header"),
    }
    assert q(warehouse, "SELECT run_id, json_extract_string(params, '$.notes') FROM runs ORDER BY 1") == [
        ("c/a", "second")]


def test_rig_toml_problems_are_quarantined(raw, warehouse):
    raw.write("c/rig.toml", '[reading]\ndelimiter = ","\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("d/rig.toml", '[channels."x"]\nchannel = "x"\nunit = "mm"\nscale = "ten"\n')
    raw.csv("d/b.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    summary = rebuild(raw.root, warehouse, jobs=1)
    errors = {(p.source_path, p.error) for p in summary.quarantine}
    msg = "unknown or malformed table(s) reading (expected [read], [channels], [metadata], [sensors], [derived])"
    assert ("c/rig.toml", msg) in errors
    assert ("c/a.csv", f"cannot use c/rig.toml: {msg}") in errors
    assert ("d/b.csv", "rig.toml scale/offset of column `x` is not a number") in errors
    assert q(warehouse, "SELECT count(*) FROM runs") == [(0,)]


def test_files_that_are_not_runs_are_skipped(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    for name in ("c/a.tdms_index", "c/.hidden.csv", "c/.git/x.csv", "c/README.txt", "c/readme.md",
                 "c/hoses.csv", "c/rig.toml", "c/manifest.csv"):
        raw.write(name, "file\n" if name.endswith("manifest.csv") else "")
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,z_rollers_mm\n"
                             "H1,installed,2026-01-01T00:00:00,X,distance,4\n")
    raw.write("c/photo.jpg", b"\xff\xd8\xff")
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == EXIT_OK, [p.error for p in summary.quarantine]
    assert summary.n_files == 1
    assert q(warehouse, "SELECT source_path FROM runs") == [("c/a.csv",)]



def test_a_report_that_cannot_be_rendered_fails_the_rebuild_and_keeps_warehouse_and_report(raw, warehouse,
                                                                                          monkeypatch):
    from click.testing import CliRunner

    import pipeline.serve.report as rp
    from pipeline.cli import main

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    args = ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1"]
    assert CliRunner().invoke(main, args).exit_code == EXIT_OK
    page = (warehouse / "report" / "index.html").read_text()
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    monkeypatch.setattr(rp, "render_report", lambda *a, **k: {}["missing table"])
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 3, res.output
    assert "the morning report could not be written: KeyError: 'missing table'" in res.output
    # the previous warehouse and its report, which agree with each other
    assert q(warehouse, "SELECT run_id FROM runs ORDER BY 1") == [("c/a",)]
    assert (warehouse / "report" / "index.html").read_text() == page
    assert not [p for p in warehouse.iterdir() if ".tmp" in p.name]
    # without a report nothing can fail: the new warehouse goes in
    assert CliRunner().invoke(main, [*args, "--no-report"]).exit_code == EXIT_OK
    assert q(warehouse, "SELECT run_id FROM runs ORDER BY 1") == [("c/a",), ("c/b",)]


# -- raw/ and the warehouse never overlap; the clean-up deletes only what the warehouse wrote ----
def test_the_raw_guard_notices_any_change_to_the_raw_tree(raw, tmp_path):
    # the guard every rebuild of the suite runs under (tests/conftest.py) must be able to fail
    import os

    from tests.conftest import guard_raw

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/b.csv", "x\n")
    os.symlink("a.csv", raw.root / "c" / "link.csv")
    changes = {
        "bytes": lambda: (raw.root / "c/a.csv").write_text("changed\n"),
        "mode": lambda: os.chmod(raw.root / "c/b.csv", 0o600),
        "deleted": lambda: (raw.root / "c/b.csv").unlink(),
        "created": lambda: raw.write("c/new.txt", "x"),
        "symlink": lambda: (os.unlink(raw.root / "c/link.csv"), os.symlink("b.csv", raw.root / "c/link.csv")),
    }
    os.chmod(raw.root / "c/b.csv", 0o644)
    for name, change in changes.items():
        with pytest.raises(pytest.fail.Exception, match="modified its raw tree"):
            guard_raw(lambda root: change())(raw.root)
    assert guard_raw(lambda root: 7)(raw.root) == 7  # nothing changed: nothing to say


def _overlaps(tmp_path):
    import os

    raw = tmp_path / "X"
    (raw / "samples").mkdir(parents=True)          # a campaign folder named like the warehouse's
    os.symlink(raw, tmp_path / "link")
    return {
        "raw inside the warehouse": (raw / "samples", raw),       # --raw W/samples --warehouse W
        "the same folder": (raw, raw),
        "warehouse inside raw": (raw, raw / "wh"),
        "the same folder through a symlink": (raw, tmp_path / "link"),
        "warehouse inside raw through a symlink": (tmp_path / "link", raw / "w2"),
    }


@pytest.mark.parametrize("case", ["raw inside the warehouse", "the same folder", "warehouse inside raw",
                                  "the same folder through a symlink", "warehouse inside raw through a symlink"])
def test_overlapping_raw_and_warehouse_are_a_usage_error_before_anything_is_written(tmp_path, case):
    from click.testing import CliRunner

    from pipeline.cli import main
    from tests.conftest import RawBuilder, raw_snapshot

    raw_dir, wh = _overlaps(tmp_path)[case]
    builder = RawBuilder(tmp_path / "X")
    builder.csv("samples/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    builder.write("samples/kind=step/campaign=samples/a-0123456789abcdef.parquet", b"PAR1 not really")
    before = raw_snapshot(tmp_path / "X")
    with pytest.raises(RebuildError) as err:
        rebuild(raw_dir, wh, jobs=1)
    assert err.value.exit_code == 2
    assert str(raw_dir) in str(err.value) and str(wh) in str(err.value)
    for cmd in ("rebuild", "demo"):
        res = CliRunner().invoke(main, [cmd, "--raw", str(raw_dir), "--warehouse", str(wh), "--jobs", "1"])
        assert res.exit_code == 2, res.output
        assert str(raw_dir) in res.output and str(wh) in res.output
    assert raw_snapshot(tmp_path / "X") == before  # nothing written, nothing deleted (no demo/, no lock)


def test_the_clean_up_deletes_only_files_the_warehouse_wrote(raw, warehouse, tmp_path):
    import os

    from tests.conftest import raw_snapshot

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    rebuild(raw.root, warehouse, jobs=1)
    camp = warehouse / "samples" / "kind=step" / "campaign=c"
    # a raw tree copied where the clean-up looks, foreign names in the warehouse's own folders,
    # and a symlink out of the warehouse onto a tree of writer-like names
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "x-0123456789abcdef.parquet").write_bytes(b"someone's data")
    foreign = {
        "samples/kind=step/campaign=c/b.csv": b"t,x\n0,1\n",
        "samples/kind=step/campaign=c/notes.txt": b"mine",
        "samples/kind=step/campaign=c/run-12.parquet": b"not a writer name",
        "samples/kind=step/campaign=c/sub/z-0123456789abcdef.parquet": b"one folder too deep",
        "samples/c/a.csv": b"a raw tree under samples/",
        "samples/kind=nope/campaign=c/q-0123456789abcdef.parquet": b"not a kind",
        "stages/models/0123456789abcdef0123/tables/data.csv": b"foreign",
        "stages/models/0123456789abcdef0123/output.json.bak": b"foreign",
        "stages/Not-A-Stage/0123456789abcdef0123/output.json": b"{}",
        "stages/.tmp-notes/readme.txt": b"foreign",
        "report/.keep.tmp": b"foreign",
        ".pneubench.duckdb.tmp-old": b"foreign",
        "figures/readme.txt": b"foreign",
    }
    for rel, data in foreign.items():
        (warehouse / rel).parent.mkdir(parents=True, exist_ok=True)
        (warehouse / rel).write_bytes(data)
    os.symlink(outside, warehouse / "samples" / "kind=step" / "campaign=linked")
    orphan = camp / "zz-0123456789abcdef.parquet"       # writer-named, used by no warehouse: collected
    orphan.write_bytes(b"stale")
    debris = camp / ".a.123.0123456789ab.tmp"             # a killed writer's temp file: collected
    debris.write_bytes(b"partial")
    outside_before = raw_snapshot(outside)
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": [1.0] * 4})
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_OK
    rebuild(raw.root, warehouse, jobs=1)
    for rel, data in foreign.items():
        assert (warehouse / rel).read_bytes() == data, rel
    assert raw_snapshot(outside) == outside_before
    assert not orphan.exists() and not debris.exists()
    assert q(warehouse, "SELECT count(*) FROM runs") == [(2,)]


# -- readers of untrusted bytes never run in the rebuild's process --------------------------------
def test_a_reader_that_segfaults_with_one_job_quarantines_its_file_and_the_rest_ingests(raw, warehouse,
                                                                                       monkeypatch):
    # a 1-core server is --jobs 1: the reader still runs in a worker process, so a segfault in
    # C code (scipy's loadmat on a corrupt MAT file did this) costs one file, not the rebuild
    import os

    import pipeline.ingest.file as ing
    from pipeline.rebuild.flow import CRASHED
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


# -- readers of an earlier warehouse keep their samples for the retention period -------------------
class FakeClock:
    def __init__(self, t):
        self.t = t

    def __call__(self):
        return self.t


READER = """
import sys, duckdb
from pathlib import Path
from pipeline.serve.door import connect_readonly
con = connect_readonly(Path(sys.argv[1]).parent)
for line in sys.stdin:
    try:
        print(repr(con.execute("SELECT max(x_m) FROM samples_step").fetchone()[0]), flush=True)
    except duckdb.Error as exc:
        print("error: " + str(exc).splitlines()[0], flush=True)
"""


def test_a_connection_opened_before_two_rebuilds_still_reads_its_samples_until_the_retention_passes(raw, warehouse):
    import os
    import subprocess
    import sys
    import time

    def step(scale):
        raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [scale * v for v in (0, 1, 2, 3)], "x_ref[mm]": [3] * 4})
        past = time.time() - 3600
        os.utime(raw.root / "c/a.csv", (past, past))

    clock = FakeClock(1_800_000_000.0)
    step(1.0)
    rebuild(raw.root, warehouse, jobs=1, clock=clock)
    first = q(warehouse, "SELECT samples_path FROM runs")[0][0]
    # a long-lived reader in another process (a notebook left open overnight)
    reader = subprocess.Popen([sys.executable, "-c", READER, str(warehouse / "pneubench.duckdb")],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def ask():
        reader.stdin.write("?\n")
        reader.stdin.flush()
        return reader.stdout.readline().strip()

    try:
        assert ask() == "0.003"
        for scale in (2.0, 3.0):  # two rebuilds, the file changed each time
            clock.t += 3600
            step(scale)
            assert rebuild(raw.root, warehouse, jobs=1, clock=clock).n_changed == 1
        assert q(warehouse, "SELECT max(x_m) FROM samples_step") == [(pytest.approx(0.009),)]
        assert ask() == "0.003"  # its samples are still there
        assert q(warehouse, f"SELECT epoch(superseded_at) FROM superseded_files WHERE path = '{first}'") == [
            (1_800_003_600.0,)]
        clock.t = 1_800_003_600.0 + 24 * 3600 - 1  # not quite 24 h after the rebuild that stopped using it
        rebuild(raw.root, warehouse, jobs=1, clock=clock)
        assert (warehouse / first).is_file() and ask() == "0.003"
        clock.t += 1
        rebuild(raw.root, warehouse, jobs=1, clock=clock)
        assert not (warehouse / first).exists()
        assert ask().startswith("error: ")
    finally:
        reader.stdin.close()
        reader.wait(timeout=60)
    assert (warehouse / q(warehouse, "SELECT samples_path FROM runs")[0][0]).is_file()


def test_keep_superseded_option_and_environment(raw, warehouse, monkeypatch):
    from click.testing import CliRunner

    from pipeline.cli import main

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    args = ["rebuild", "--raw", str(raw.root), "--warehouse", str(warehouse), "--jobs", "1", "--no-report"]
    assert CliRunner().invoke(main, args).exit_code == 0
    first = q(warehouse, "SELECT samples_path FROM runs")[0][0]
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": [1.0] * 4, "x_ref[m]": T})
    monkeypatch.setenv("PNEUBENCH_KEEP_SUPERSEDED_H", "soon")
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 2 and "--keep-superseded" in res.output and "soon" in res.output
    with pytest.raises(RebuildError, match="PNEUBENCH_KEEP_SUPERSEDED_H='soon' is not a number") as err:
        rebuild(raw.root, warehouse, jobs=1)
    assert err.value.exit_code == 2
    monkeypatch.setenv("PNEUBENCH_KEEP_SUPERSEDED_H", "24")
    assert CliRunner().invoke(main, [*args, "--keep-superseded", "0"]).exit_code == 0  # the option wins
    assert not (warehouse / first).exists()


def test_a_stage_table_without_rows_is_kept_as_dtypes_and_loads_as_its_parquet_file_would(tmp_path, monkeypatch):
    """A table without rows is stored as its columns' dtypes in ``output.json`` (no Parquet file to
    write and read back: a stage with nothing to do costs milliseconds), and loads exactly as the
    Parquet file would have; a dtype its name does not rebuild exactly still goes to Parquet."""
    import json

    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    import pipeline.rebuild.flow as rb
    from pipeline.stages import StageOutput

    empty = pd.DataFrame({
        "run_id": pd.Series([], dtype="str"), "x": pd.Series([], dtype="float64"), "n": pd.Series([], dtype="Int64"),
        "k": pd.Series([], dtype="int64"), "ok": pd.Series([], dtype="boolean"), "flag": pd.Series([], dtype="bool"),
        "note": pd.Series([], dtype="string"), "anything": pd.Series([], dtype=object),
        "at": pd.Series([], dtype="datetime64[ns, UTC]"), "naive": pd.Series([], dtype="datetime64[s]"),
        "cat": pd.Series([], dtype=pd.CategoricalDtype(["a", "b"]))})
    full = pd.DataFrame({"run_id": ["a"], "x": [1.5]})

    def saved_and_loaded(out: StageOutput, key: str):
        rel, cacheable, now_in = rb._save_stage_folder(tmp_path, "demo", key, out)
        assert now_in == tmp_path / rel  # no figure to draw: in place at once
        assert cacheable
        folder = tmp_path / rel
        tables, *_ = rb._load_stage_folder(tmp_path, rel, "demo")
        for name, df in out.tables.items():  # what the Parquet file would give
            pq.write_table(pa.Table.from_pandas(df, preserve_index=False), tmp_path / f"{name}.parquet")
            pd.testing.assert_frame_equal(tables[name], pd.read_parquet(tmp_path / f"{name}.parquet"),
                                          check_index_type=True)
        return sorted(p.name for p in (folder / "tables").iterdir()), json.loads((folder / "output.json").read_text())

    files, meta = saved_and_loaded(StageOutput(tables={"empty": empty, "full": full}), "0" * 20)
    assert files == ["full.parquet"] and list(meta["empty"]) == ["empty"]
    assert dict(meta["empty"]["empty"])["naive"] == "datetime64[ms]"  # Parquet's unit, not the frame's
    real = rb._empty_frame
    monkeypatch.setattr(rb, "_empty_frame", lambda cols: real(cols).astype({"x": "float32"}) if
                        "x" in dict(cols) else real(cols))  # a name that does not rebuild its dtype
    files, meta = saved_and_loaded(StageOutput(tables={"empty": empty, "full": full}), "1" * 20)
    assert files == ["empty.parquet", "full.parquet"] and meta["empty"] == {}


def test_every_stage_loads_the_same_tables_with_or_without_empty_tables_kept_as_dtypes(raw, tmp_path, monkeypatch):
    """The whole rebuild: every stage's tables (most of them empty on a small tree) load equal to
    what the Parquet files gave before tables without rows were kept as dtypes."""
    import pandas as pd

    import pipeline.rebuild.flow as rb

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    loaded: dict[str, dict] = {}
    real = rb._load_stage_folder

    def spy(warehouse, rel, stage, fresh=None, folder=None):
        got = real(warehouse, rel, stage, fresh, folder)
        loaded.setdefault(warehouse.name, {})[stage] = got[0]
        return got

    monkeypatch.setattr(rb, "_load_stage_folder", spy)
    rebuild(raw.root, tmp_path / "as-dtypes", jobs=1, report=False)
    monkeypatch.setattr(rb, "_empty_columns", lambda arrow: None)  # every table as Parquet, as before
    rebuild(raw.root, tmp_path / "as-parquet", jobs=1, report=False)
    a, b = loaded["as-dtypes"], loaded["as-parquet"]
    assert sorted(a) == sorted(b) and sum(len(t) for t in a.values()) > 10
    n_empty = 0
    for stage in a:
        assert sorted(a[stage]) == sorted(b[stage])
        for name in a[stage]:
            pd.testing.assert_frame_equal(a[stage][name], b[stage][name], check_index_type=True)
            n_empty += a[stage][name].empty
    assert n_empty > 10


# -- figures drawn beside the rebuild (FigureDrawer) -----------------------------------------------
def tiny_plot(label: str, pid_file: str | None = None, fail: bool = False):
    """A module-level plot function for recipes: a small figure; notes the drawing process's pid."""
    import os

    from matplotlib.figure import Figure

    if fail:
        raise ValueError(f"cannot draw {label}")
    if pid_file:
        with open(pid_file, "a") as fh:
            fh.write(f"{os.getpid()}\n")
    fig = Figure(figsize=(2, 1.5))
    ax = fig.add_subplot()
    ax.plot([0, 1, 2], [0, 1, 4])
    ax.set_title(label)
    return fig


def _drawn(tmp_path, jobs, recipes, stage="demo"):
    """Draw ``recipes`` ({name: FigureRecipe}) with a FigureDrawer into a stage folder."""
    import pipeline.rebuild.flow as rb

    tmp, final = tmp_path / f".tmp-{stage}-{'0' * 20}-1", tmp_path / stage
    (tmp / "figures").mkdir(parents=True)
    with rb.FigureDrawer(jobs) as drawer:
        for name, recipe in recipes.items():
            drawer.draw(stage, name, recipe, tmp / "figures" / f"{name}.png")
        drawer.publish(tmp, final)
        placed_before_finish = final.exists()
        drawer.finish()
    return placed_before_finish, final


def test_figures_drawn_in_a_worker_are_the_bytes_drawn_at_once_and_placed_only_when_done(tmp_path):
    import os

    from pipeline.stages import FigureRecipe

    pids = tmp_path / "pids.txt"
    recipes = {n: FigureRecipe(tiny_plot, (n, str(pids))) for n in ("a", "b")}
    early, aside = _drawn(tmp_path / "aside", 2, recipes)
    drawers = {int(p) for p in pids.read_text().split()}
    assert not early  # the folder is put in place by finish(), after its figures
    assert drawers and os.getpid() not in drawers  # drawn in the worker process
    pids.unlink()
    early, here = _drawn(tmp_path / "here", 1, recipes)
    assert not early and {int(p) for p in pids.read_text().split()} == {os.getpid()}  # --jobs 1: here
    for n in recipes:
        assert (aside / "figures" / f"{n}.png").read_bytes() == (here / "figures" / f"{n}.png").read_bytes()


def test_a_figure_that_fails_fails_the_rebuild_and_places_no_folder(tmp_path):
    import pipeline.rebuild.flow as rb
    from pipeline.stages import FigureRecipe

    for jobs in (1, 2):
        root = tmp_path / f"jobs{jobs}"
        recipes = {"ok": FigureRecipe(tiny_plot, ("ok",)), "bad": FigureRecipe(tiny_plot, ("bad",), {"fail": True})}
        with pytest.raises((rb.RebuildError, ValueError), match="bad"):
            _drawn(root, jobs, recipes)
        assert not (root / "demo").exists()
        if jobs > 1:  # the worker's error names the stage and the figure; the temporary folder is gone
            assert not list(root.glob(".tmp-*"))


def test_a_stage_folder_that_exists_is_reused_without_drawing(tmp_path):
    import pandas as pd

    import pipeline.rebuild.flow as rb
    from pipeline.stages import StageOutput

    pids = tmp_path / "pids.txt"
    out = StageOutput(tables={"t": pd.DataFrame({"run_id": ["a"], "x": [1.0]})})
    out.draw("fig", tiny_plot, "fig", str(pids), caption="A figure.")
    with rb.FigureDrawer(2) as drawer:
        rel, cacheable, now_in = rb._save_stage_folder(tmp_path, "demo", "2" * 20, out, drawer)
        assert now_in != tmp_path / rel and not (tmp_path / rel).exists()  # being drawn
        drawer.finish()
    assert (tmp_path / rel / "figures" / "fig.png").is_file() and pids.read_text().count("\n") == 1
    _tables, figures, *_ = rb._load_stage_folder(tmp_path, rel, "demo")
    assert figures == [{"stage": "demo", "name": "fig", "path": f"{rel}/figures/fig.png", "caption": "A figure."}]
    again = rb._save_stage_folder(tmp_path, "demo", "2" * 20, out, rb.FigureDrawer(2))
    assert again == (rel, True, tmp_path / rel) and pids.read_text().count("\n") == 1  # not drawn again


def test_a_rebuild_draws_the_same_figures_with_jobs_2_as_with_jobs_1(raw, tmp_path):
    from pipeline.simulator import simulate_durability

    sim = simulate_durability(hose_id="H1", distance_m=5.0, rng=1, stroke_m=0.1, dwell_s=0.05, fs_hz=200.0)
    cols = {"t[s]": sim.data["t_s"].tolist(), "x[mm]": (sim.data["x_m"] * 1e3).round(3).tolist(),
            "p_a[Pa]": sim.data["p_a_pa"].tolist(), "p_b[Pa]": sim.data["p_b_pa"].tolist()}
    raw.csv("c/d1.csv", {"kind": "durability", "rig": "plpa-1", "hose_id": "H1",
                         "started_at": "2026-01-02T08:00:00"}, cols)
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,"
                             "wall_thickness_mm,distance_km,notes\nH1,installed,2026-01-01T00:00,FLEX,force,,866,,,,\n")
    figs = {}
    for jobs in (1, 2):
        wh = tmp_path / f"wh{jobs}"
        summary = rebuild(raw.root, wh, jobs=jobs, report=False)
        assert summary.exit_code == 0, summary.quarantine
        rows = query(wh, "SELECT stage, name, path FROM figures ORDER BY stage, name")
        figs[jobs] = {(s, n): (wh / p).read_bytes() for s, n, p in rows}
        assert not list((wh / "stages").glob(".tmp-*"))
    assert ("durability", "hose_distance") in figs[1]
    assert figs[2] == figs[1]


def _tree_listing(folder):
    """Every path under ``folder`` with its bytes' hash (the lock file aside: it holds the pid)."""
    import hashlib

    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None
            for p in sorted(folder.rglob("*")) if p.name != ".rebuild.lock"}


def _steps(raw, names):
    for n in names:
        raw.csv(f"c/{n}.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})


def test_an_empty_raw_tree_is_refused_before_anything_is_written_unless_allowed(raw, warehouse, tmp_path):
    # issue 21.1: an unmounted share (an empty raw/) emptied the warehouse with exit 0
    _steps(raw, "abcdefgh")
    assert rebuild(raw.root, warehouse, jobs=1).n_runs == 8
    before = _tree_listing(warehouse)
    empty = tmp_path / "mountpoint"
    empty.mkdir()
    with pytest.raises(RebuildError) as err:
        rebuild(empty, warehouse, jobs=1)
    assert err.value.exit_code == 2
    assert "refusing to delete 8 of the warehouse's 8 runs" in str(err.value)
    assert "c/a.csv, c/b.csv, c/c.csv, ..." in str(err.value) and "--allow-mass-delete" in str(err.value)
    assert _tree_listing(warehouse) == before  # database, report, samples, stages: as they were
    # more than half of the runs (and at least MASS_DELETE_MIN_RUNS): refused too
    for n in "abcde":
        (raw.root / f"c/{n}.csv").unlink()
    with pytest.raises(RebuildError, match="refusing to delete 5 of the warehouse's 8 runs"):
        rebuild(raw.root, warehouse, jobs=1)
    assert _tree_listing(warehouse) == before
    # intended: allowed
    s = rebuild(empty, warehouse, jobs=1, allow_mass_delete=True)
    assert (s.n_runs, s.n_deleted, s.exit_code) == (0, 8, EXIT_OK)
    assert query(warehouse, "SELECT count(*) FROM runs") == [(0,)]


def test_deleting_half_the_runs_or_fewer_than_five_goes_on_and_a_first_empty_build_is_no_mass_delete(raw, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    s = rebuild(empty, tmp_path / "w0", jobs=1)  # a first build of nothing deletes nothing
    assert (s.n_runs, s.exit_code) == (0, EXIT_OK)
    _steps(raw, "abcdefgh")
    wh = tmp_path / "w1"
    rebuild(raw.root, wh, jobs=1)
    for n in "abcd":  # exactly half
        (raw.root / f"c/{n}.csv").unlink()
    s = rebuild(raw.root, wh, jobs=1)
    assert (s.n_runs, s.n_deleted) == (4, 4)
    for n in "efg":  # 3 of 4: more than half, but fewer than MASS_DELETE_MIN_RUNS
        (raw.root / f"c/{n}.csv").unlink()
    s = rebuild(raw.root, wh, jobs=1)
    assert (s.n_runs, s.n_deleted) == (1, 3)
    (raw.root / "c/h.csv").unlink()  # the last run: all of them, refused whatever their number
    with pytest.raises(RebuildError, match="refusing to delete 1 of the warehouse's 1 runs"):
        rebuild(raw.root, wh, jobs=1)
