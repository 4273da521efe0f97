"""Excel and MDF exports through the whole rebuild: manifest, rig.toml mapping, units, quarantine,
incremental rebuilds and the samples schema exactly like the other readers; files that are not
exports are listed in `skipped_files`."""
import numpy as np
import pytest

from pipeline.rebuild.flow import rebuild
from tests.conftest import query
from tests.pipeline.readers.generators import xlsx_workbook

openpyxl = pytest.importorskip("openpyxl")
asammdf = pytest.importorskip("asammdf")

pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")


def test_xlsx_and_mf4_runs_ingest_value_exact_and_other_files_are_listed(raw, warehouse):
    t = np.arange(6) * 0.1
    xlsx_workbook(raw.root / "lab" / "leak.xlsx",
          [["t", "supply", "q_leak"], ["s", "kPa", "l/min"]] + [[ti, 100.0 * i, 0.5 * i] for i, ti in enumerate(t)],
          meta={"kind": "leakage", "chamber": "A", "adjustment": "distance", "z_rollers_mm": 4,
                "started_at": "2026-05-01T10:00:00"})
    raw.write("lab/rig.toml", '[read]\nunits_row = 2\n[channels.supply]\nchannel = "p_supply"\n'
                              '[metadata]\nrig = "plpa-x"\n')
    _mf4_groups(raw.root / "lab" / "step.MF4", {"daq": (t, {"x": (t * 10, "mm"), "x_ref": (np.full(6, 0.5), "mm")})},
         "<HDcomment><TX>kind=step;started_at=2026-05-01T11:00:00</TX></HDcomment>")
    raw.write("lab/notes.docx", b"PK not really a docx")
    code = rebuild(raw.root, warehouse, jobs=1).exit_code
    assert code == 0, query(warehouse, "SELECT * FROM quarantine")
    runs = dict(query(warehouse, "SELECT run_id, format FROM runs ORDER BY run_id"))
    assert runs == {"lab/leak": "excel", "lab/step": "mdf"}
    p = [r[0] for r in query(warehouse, "SELECT p_supply_pa FROM samples_leakage ORDER BY t_s")]
    assert p == [0.0, 1e5, 2e5, 3e5, 4e5, 5e5]
    x = [r[0] for r in query(warehouse, "SELECT x_m FROM samples_step ORDER BY t_s")]
    assert x == pytest.approx(t * 10 * 1e-3, rel=1e-15)
    assert query(warehouse, "SELECT source_path, reason FROM skipped_files") == [
        ("lab/notes.docx", "not a supported format: .docx")]
    # incremental: nothing changed, nothing re-read
    assert rebuild(raw.root, warehouse, jobs=1).n_runs == 2
    assert query(warehouse, "SELECT count(*) FROM rebuild_changes")[0][0] == 0


def test_unusable_workbook_and_mdf_are_quarantined_the_rest_ingests(raw, warehouse):
    raw.csv("lab/ok.csv", {"kind": "step", "started_at": "2026-01-01T00:00:00", "rig": "r"},
            {"t[s]": [0, 0.1], "x[m]": [0, 0.1], "x_ref[m]": [0, 0]})
    raw.write("lab/locked.xlsx", b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(600))
    raw.write("lab/cut.mf4", b"MDF     4.10    " + bytes(100))
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 1
    errors = dict(query(warehouse, "SELECT source_path, error FROM quarantine"))
    assert "password-protected" in errors["lab/locked.xlsx"]
    assert "MDF" in errors["lab/cut.mf4"]
    assert query(warehouse, "SELECT run_id FROM runs") == [("lab/ok",)]


# -- files of several runs: one run per sheet, one run per MDF channel group ----------------------
def _book(path, sheets, meta=None):
    """A workbook with one sheet per entry: name -> rows (a `meta` sheet first when given)."""
    wb = openpyxl.Workbook()
    wb.remove(wb.active)
    if meta:
        ms = wb.create_sheet("meta")
        for k, v in meta.items():
            ms.append([k, v])
    for name, rows in sheets.items():
        ws = wb.create_sheet(name)
        for r in rows:
            ws.append(r)
    path.parent.mkdir(parents=True, exist_ok=True)
    wb.save(path)
    return path


_STEP_META = {"kind": "step", "started_at": "2026-05-01T10:00:00", "rig": "plpa-x"}


def _step_rows(scale, n=5):
    return [["t[s]", "x[mm]", "x_ref[mm]"]] + [[0.1 * i, scale * i, 0.0] for i in range(n)]


def _x_by_run(warehouse):
    out: dict = {}
    for rid, x in query(warehouse, "SELECT run_id, x_m FROM samples_step ORDER BY run_id, t_s"):
        out.setdefault(rid, []).append(x)
    return out


def test_sheets_all_makes_one_run_per_sheet_and_a_bad_sheet_is_one_quarantine_line(raw, warehouse):
    _book(raw.root / "lab" / "book.xlsx",
          {"A": _step_rows(1.0), "B": [["# started_at: 2026-05-02T08:00:00"]] + _step_rows(2.0),
           "C": _step_rows(3.0), "Broken": [["t[s]", "y[mm]"], [0.0, 1.0], [0.1, 2.0]]},
          meta=_STEP_META)
    raw.write("lab/rig.toml", '[read]\nsheets = "all"\n')
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.exit_code == 1
    assert query(warehouse, "SELECT source_path, error FROM quarantine") == [
        ("lab/book.xlsx", "sheet 'Broken': missing channel `x`, `x_ref` (kind step needs t, x, x_ref)")]
    runs = query(warehouse, "SELECT run_id, source_path, format, started_at FROM runs ORDER BY run_id")
    assert [r[:3] for r in runs] == [("lab/book/A", "lab/book.xlsx", "excel"), ("lab/book/B", "lab/book.xlsx", "excel"),
                                     ("lab/book/C", "lab/book.xlsx", "excel")]
    # the meta sheet applies to every sheet; a sheet's own `# key: value` cells win over it
    assert str(runs[1][3]).startswith("2026-05-02 08:00:00") and str(runs[0][3]).startswith("2026-05-01 10:00:00")
    x = _x_by_run(warehouse)
    assert sorted(x) == ["lab/book/A", "lab/book/B", "lab/book/C"]
    for s, k in (("A", 1), ("B", 2), ("C", 3)):
        assert x[f"lab/book/{s}"] == pytest.approx([k * i * 1e-3 for i in range(5)], rel=1e-15)
    assert len(set(r[0] for r in query(warehouse, "SELECT samples_path FROM runs"))) == 3


def test_sheets_all_incremental_reuse_change_delete_and_full_equals_incremental(raw, warehouse, tmp_path):
    book = _book(raw.root / "lab" / "book.xlsx", {"A": _step_rows(1.0), "B": _step_rows(2.0), "C": _step_rows(3.0)},
                 meta=_STEP_META)
    raw.write("lab/manifest.csv", "file,sheets\nbook.xlsx,all\n")   # the manifest key works as [read]
    raw.csv("lab/single.csv", _STEP_META, {"t[s]": [0, 0.1], "x[m]": [0, 0.1], "x_ref[m]": [0, 0]})
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    assert query(warehouse, "SELECT run_id FROM runs ORDER BY run_id") == [
        ("lab/book/A",), ("lab/book/B",), ("lab/book/C",), ("lab/single",)]
    paths = query(warehouse, "SELECT run_id, samples_path FROM runs ORDER BY run_id")

    # no-op: every run of the workbook reused, nothing read
    s = rebuild(raw.root, warehouse, jobs=1)
    assert (s.n_unchanged, s.n_changed, s.n_runs) == (2, 0, 4)
    assert query(warehouse, "SELECT run_id, samples_path FROM runs ORDER BY run_id") == paths

    # --full gives the same runs and samples as the incremental rebuild
    full_wh = tmp_path / "full"
    assert rebuild(raw.root, full_wh, jobs=1, full=True).exit_code == 0
    assert query(full_wh, "SELECT run_id, samples_path FROM runs ORDER BY run_id") == paths
    assert _x_by_run(full_wh) == _x_by_run(warehouse)

    # a changed workbook re-ingests all its sheets (here one sheet fewer, one changed)
    _book(book, {"A": _step_rows(1.0), "C": _step_rows(5.0)}, meta=_STEP_META)
    s = rebuild(raw.root, warehouse, jobs=1)
    assert (s.n_changed, s.n_unchanged, s.n_runs) == (1, 1, 3)
    assert _x_by_run(warehouse)["lab/book/C"] == pytest.approx([5.0 * i * 1e-3 for i in range(5)])
    assert "lab/book/B" not in _x_by_run(warehouse)

    # deleting it removes all its runs and, beyond retention, their samples files
    book.unlink()
    s = rebuild(raw.root, warehouse, jobs=1, keep_superseded_h=0)
    assert (s.n_deleted, s.n_runs) == (1, 1)
    assert query(warehouse, "SELECT run_id FROM runs") == [("lab/single",)]
    left = {p.name for p in (warehouse / "samples").rglob("*.parquet")}
    assert not any(n.startswith("lab_book_") for n in left) and len(left) == 1


def test_a_manifest_run_id_of_a_workbook_of_sheets_is_the_prefix_of_its_runs(raw, warehouse):
    _book(raw.root / "lab" / "book.xlsx", {"A": _step_rows(1.0), "B": _step_rows(2.0)}, meta=_STEP_META)
    raw.write("lab/manifest.csv", "file,sheets,run_id\nbook.xlsx,all,bench7/day3\n")
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    assert query(warehouse, "SELECT run_id FROM runs ORDER BY run_id") == [("bench7/day3/A",), ("bench7/day3/B",)]


def test_sheets_other_than_all_is_one_clear_quarantine_line(raw, warehouse):
    _book(raw.root / "lab" / "book.xlsx", {"A": _step_rows(1.0)}, meta=_STEP_META)
    raw.write("lab/rig.toml", '[read]\nsheets = "A,B"\n')
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 1
    (path, error), = query(warehouse, "SELECT source_path, error FROM quarantine")
    assert path == "lab/book.xlsx" and "`sheets = 'A,B'`" in error and '"all"' in error


def _mf4_groups(path, groups, comment):
    """An MF4 with one channel group per entry: acquisition name -> (t, {name: (values, unit)})."""
    m = asammdf.MDF(version="4.10")
    for acq, (t, signals) in groups.items():
        m.append([asammdf.Signal(v, t, name=n, unit=u) for n, (v, u) in signals.items()], acq_name=acq)
    m.header.comment = comment
    path.parent.mkdir(parents=True, exist_ok=True)
    m.save(path, overwrite=True)
    m.close()
    return path


def test_mdf_groups_all_makes_one_run_per_channel_group_at_its_own_rate(raw, warehouse):
    fast, slow = np.arange(20) * 0.001, np.arange(4) * 0.1
    _mf4_groups(raw.root / "lab" / "log.mf4",
                {"fast": (fast, {"x": (fast * 10, "mm"), "x_ref": (np.zeros(20), "mm")}),
                 "slow": (slow, {"x": (slow * 2, "mm"), "x_ref": (np.ones(4), "mm")})},
                "<HDcomment><TX>kind=step;started_at=2026-05-01T11:00:00;rig=plpa-x</TX></HDcomment>")
    # without the key the file is refused, naming its groups
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 1
    assert "2 channel groups" in query(warehouse, "SELECT error FROM quarantine")[0][0]
    raw.write("lab/rig.toml", '[read]\ngroups = "all"\n')
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    runs = query(warehouse, "SELECT run_id, n_samples, sample_rate_hz FROM runs ORDER BY run_id")
    assert [r[:2] for r in runs] == [("lab/log/fast", 20), ("lab/log/slow", 4)]
    assert runs[0][2] == pytest.approx(1000.0) and runs[1][2] == pytest.approx(10.0)
    x = _x_by_run(warehouse)
    assert x["lab/log/fast"] == pytest.approx(fast * 10e-3, rel=1e-15)
    assert x["lab/log/slow"] == pytest.approx(slow * 2e-3, rel=1e-15)


def test_a_manifest_row_file_hash_sheet_gives_that_sheet_its_own_metadata(raw, warehouse):
    _book(raw.root / "lab" / "book.xlsx", {"A": _step_rows(1.0), "B": _step_rows(2.0)}, meta=_STEP_META)
    raw.write("lab/manifest.csv", "file,sheets,started_at,run_id\nbook.xlsx,all,,day3\n"
                                  "book.xlsx#B,,2026-06-01T09:00:00,special\n")
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == 0
    runs = query(warehouse, "SELECT run_id, started_at, params FROM runs ORDER BY run_id")
    assert [r[0] for r in runs] == ["day3/A", "special"]
    assert str(runs[0][1]).startswith("2026-05-01 10:00:00") and str(runs[1][1]).startswith("2026-06-01 09:00:00")
    # a change to the sheet's row alone re-ingests the workbook
    raw.write("lab/manifest.csv", "file,sheets,started_at,run_id\nbook.xlsx,all,,day3\n"
                                  "book.xlsx#B,,2026-06-02T09:00:00,special\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.n_changed == 1
    assert str(query(warehouse, "SELECT started_at FROM runs WHERE run_id = 'special'")[0][0]).startswith("2026-06-02")
    # a row naming no sheet after `#` is one manifest problem; the runs are unaffected
    raw.write("lab/manifest.csv", "file,sheets\nbook.xlsx,all\nbook.xlsx#,\n")
    assert rebuild(raw.root, warehouse, jobs=1).n_runs == 2
    assert query(warehouse, "SELECT source_path, error FROM quarantine") == [
        ("lab/manifest.csv", "entry `book.xlsx#` names no sheet or group after `#`")]
