"""The rebuild end to end: runs, quarantine, views, exit codes, and the previous warehouse kept on failure."""
import pytest

from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_OK, EXIT_QUARANTINED, RebuildError
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


def test_a_copy_put_beside_a_run_does_not_take_its_place_whatever_its_path(raw, warehouse):
    """The file that holds a run in the live warehouse keeps it: a cut-short copy in ``archive/``
    (its path sorts first) is the one quarantined, by an incremental and by a --full rebuild."""
    raw.csv("c/runs/b.csv", {**STEP_META, "run_id": "r7"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    rebuild(raw.root, warehouse, jobs=1)
    raw.csv("c/archive/b.csv", {**STEP_META, "run_id": "r7"}, {"t[s]": T[:3], "x[m]": T[:3], "x_ref[m]": T[:3]})
    for full in (False, True):
        summary = rebuild(raw.root, warehouse, jobs=1, full=full)
        assert [(p.source_path, p.error) for p in summary.quarantine] == [
            ("c/archive/b.csv", "duplicate run_id `r7`, already used by `c/runs/b.csv`")]
        assert q(warehouse, "SELECT source_path, n_samples FROM runs") == [("c/runs/b.csv", 4)]


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

    import pipeline.serve.report.render as rp
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


def test_the_rebuilds_start_up_imports_no_duckdb_and_its_workers_inherit_pandas():
    """Issue 26: duckdb (~0.2 s) is imported while the files are read, not before the readers are
    forked; pandas (which pyarrow imports on a worker's first array) is imported once before the
    fork when there is a file to read, and not at all when there is none."""
    import subprocess
    import sys

    from tests.conftest import PROJECT_ROOT

    code = ("import sys, pipeline.cli\nfrom types import SimpleNamespace as P\nfrom pipeline.rebuild import flow\n"
            "start = 'duckdb' in sys.modules\nflow._import_before_fork([P(status='unchanged')])\n"
            "none = 'pandas' in sys.modules\nflow._import_before_fork([P(status='unchanged'), P(status='new')])\n"
            "print(start, none, 'pandas' in sys.modules, 'pyarrow.parquet' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=PROJECT_ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False", "True", "True"]


def test_the_channels_read_ahead_are_the_new_runs_in_the_run_pages_order_as_their_pages_name_them():
    import pandas as pd

    from pipeline.rebuild.flow import _new_channels

    runs = pd.DataFrame({"run_id": ["b", "a", "c", "d"],
                         "samples_path": ["s/b.parquet", "s/a.parquet", "s/c.parquet", None],
                         "n_samples": [10.0, float("nan"), 7.0, 3.0]})
    channels = pd.DataFrame({"run_id": ["a", "a", "a", "b", "b", "c"],
                             "column": ["x_m", "t_s", "p_a_pa", "x_m", "run_id", "p_b_pa"]})
    tables = {"runs": runs, "channels": channels}
    assert _new_channels(tables, {"s/c.parquet"}) == [("s/a.parquet", ["p_a_pa", "x_m"], 0),
                                                      ("s/b.parquet", ["x_m"], 10)]
    assert _new_channels({"runs": runs, "channels": channels.head(0)}, set())[2] == ("s/c.parquet", [], 7)
    assert _new_channels({"runs": runs.head(0), "channels": channels}, set()) == []


def test_the_channels_frame_is_the_same_whether_its_rows_were_read_tonight_or_taken_from_records():
    """Rows read tonight have the ingest's key order, rows from state records JSON's sorted order:
    the frame (and so its content key, ``table_keys``) is the same, columns in name order (issue 26:
    the first change after a full build rewrote ``channels`` and re-created every samples view)."""
    import json

    from pipeline.rebuild.assemble import frame_key
    from pipeline.rebuild.flow import _channels_frame

    fresh = [{"run_id": f"r{i}", "column": "x_m", "channel": "x", "raw_name": "x", "raw_unit": "mm", "unit": "m",
              "type": "DOUBLE"} for i in range(3)]
    stored = [json.loads(json.dumps(r, sort_keys=True)) for r in fresh]
    a, b = _channels_frame(fresh), _channels_frame(stored)
    assert list(a.columns) == sorted(fresh[0]) == list(b.columns)
    assert frame_key(a) == frame_key(b) and a.equals(b)
    assert frame_key(_channels_frame(stored[:1] + fresh[1:])) == frame_key(a)  # a changed run first: the same
    assert _channels_frame([]).empty


def test_the_report_of_a_rebuild_takes_the_table_keys_it_wrote_without_summing_the_tables(raw, warehouse):
    """The rebuild's report trusts ``table_keys`` of the database it has just written (``keys_checked``):
    every key matches its table as the report would check it, even after a table of the live database
    was edited by hand (the update writes that table again), so the report's parts are the same."""
    import duckdb

    from pipeline.serve.door import connect_readonly
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.keyed import table_keys

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 1, 3], "x_ref[mm]": [3] * 4})
    rebuild(raw.root, warehouse, jobs=1)
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"))
    con.execute("UPDATE runs SET campaign = 'edited by hand' WHERE run_id = 'c/a'")  # not by the rebuild
    con.close()
    with connect_readonly(warehouse) as con:
        db = ReportDB(con)
        assert "runs" in table_keys(db, checked=True) and "runs" not in table_keys(db)
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 2], "x_ref[mm]": [3] * 4})
    seen = []
    import pipeline.serve.report.keyed as keyed

    real = keyed.table_keys
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(keyed, "table_keys", lambda db, checked=False: seen.append(checked) or real(db, checked))
        assert rebuild(raw.root, warehouse, jobs=1).n_changed == 1
    assert seen == [True]
    with connect_readonly(warehouse) as con:
        db = ReportDB(con)
        checked, summed = table_keys(db, checked=True), table_keys(db)
    assert checked == summed and "runs" in summed and len(summed) > 10
    assert q(warehouse, "SELECT campaign FROM runs ORDER BY run_id") == [("c",), ("c",)]


def test_a_raw_folder_that_is_not_one_says_why_in_one_line(tmp_path):
    """A symlink loop or a dangling link is named as such, not as a folder that "does not exist"."""
    from pipeline.rebuild.flow import raw_folder_error

    (tmp_path / "raw").mkdir()
    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("a")
    (tmp_path / "dangling").symlink_to("missing")
    (tmp_path / "afile").write_text("x")
    (tmp_path / "tofile").symlink_to("afile")
    assert raw_folder_error(tmp_path / "raw") is None
    assert raw_folder_error(tmp_path / "a") == f"raw folder {tmp_path / 'a'} is a symlink loop"
    assert raw_folder_error(tmp_path / "dangling") == f"raw folder {tmp_path / 'dangling'} is a symlink to missing, which does not exist"
    assert raw_folder_error(tmp_path / "afile") == f"raw folder {tmp_path / 'afile'} is not a folder"
    assert raw_folder_error(tmp_path / "tofile").endswith("is a symlink to something that is not a folder")
    assert raw_folder_error(tmp_path / "nothere") == f"raw folder {tmp_path / 'nothere'} does not exist"


def test_a_raw_folder_that_goes_away_during_the_rebuild_publishes_nothing(raw, warehouse, monkeypatch):
    """raw/ unmounted or moved after it was walked: the files still to be read and the logbooks
    would have been quarantine lines and the warehouse published gutted (a reviewer's night). The
    rebuild fails before the database is written (exit 3: failed, the previous warehouse untouched);
    the night after, raw/ back, recovers."""
    from pipeline.rebuild import flow
    from pipeline.rebuild.options import EXIT_FAILED

    for i in range(3):
        raw.csv(f"c/r{i}.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": [0.3] * 4})
    rebuild(raw.root, warehouse, jobs=1)
    before = q(warehouse, "SELECT run_id, source_path FROM runs ORDER BY 1")
    real = flow._assemble

    def assemble_then_unmount(*a, **k):
        out = real(*a, **k)
        raw.root.rename(raw.root.with_name("raw.gone"))
        return out

    monkeypatch.setattr(flow, "_assemble", assemble_then_unmount)
    unguarded = getattr(rebuild, "__wrapped_rebuild__", rebuild)  # the test moves raw/ itself (the guard's job)
    with pytest.raises(RebuildError, match="went away or was replaced while the rebuild read it") as caught:
        unguarded(raw.root, warehouse, jobs=1, full=True)
    assert caught.value.exit_code == EXIT_FAILED
    assert q(warehouse, "SELECT run_id, source_path FROM runs ORDER BY 1") == before
    monkeypatch.setattr(flow, "_assemble", real)
    raw.root.with_name("raw.gone").rename(raw.root)
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_OK


def test_files_that_could_not_be_read_for_a_passing_reason_count_as_gone_for_the_mass_delete_guard(
        raw, warehouse, monkeypatch):
    """A share that stalls (every read an I/O error, raw/ itself still there) fails (exit 3) with the
    guard's words, like one that is not mounted, unless --allow-mass-delete."""
    from pipeline.rebuild import flow
    from pipeline.rebuild.options import EXIT_FAILED

    for i in range(3):
        raw.csv(f"c/r{i}.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": [0.3] * 4})
    rebuild(raw.root, warehouse, jobs=1)
    real = flow.ingest_incremental

    def stalled(*a, **k):
        results, records = real(*a, **k)
        for r in results:
            r.run, r.error, r.transient = None, "cannot read file: [Errno 5] Input/output error", True
        return results, records

    monkeypatch.setattr(flow, "ingest_incremental", stalled)
    with pytest.raises(RebuildError, match="refusing to delete 3 of the warehouse's 3 runs") as caught:
        rebuild(raw.root, warehouse, jobs=1, full=True)
    assert caught.value.exit_code == EXIT_FAILED
    assert q(warehouse, "SELECT count(*) FROM runs") == [(3,)]
    assert rebuild(raw.root, warehouse, jobs=1, full=True, allow_mass_delete=True).exit_code == EXIT_QUARANTINED
    assert q(warehouse, "SELECT count(*) FROM runs") == [(0,)]
