"""Excel and MDF exports through the whole rebuild: manifest, rig.toml mapping, units, quarantine,
incremental rebuilds and the samples schema exactly like the other readers; files that are not
exports are listed in `skipped_files`."""
import numpy as np
import pytest

from pipeline.rebuild import rebuild
from tests.conftest import query

openpyxl = pytest.importorskip("openpyxl")
asammdf = pytest.importorskip("asammdf")

pytestmark = pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")


def _xlsx(path, rows, meta=None):
    wb = openpyxl.Workbook()
    ws = wb.active
    for r in rows:
        ws.append(r)
    if meta:
        ms = wb.create_sheet("meta")
        for k, v in meta.items():
            ms.append([k, v])
    path.parent.mkdir(parents=True, exist_ok=True)
    wb.save(path)
    return path


def _mf4(path, t, signals, comment):
    m = asammdf.MDF(version="4.10")
    m.append([asammdf.Signal(v, t, name=n, unit=u) for n, (v, u) in signals.items()], acq_name="daq")
    m.header.comment = comment
    path.parent.mkdir(parents=True, exist_ok=True)
    m.save(path, overwrite=True)
    m.close()
    return path


def test_xlsx_and_mf4_runs_ingest_value_exact_and_other_files_are_listed(raw, warehouse):
    t = np.arange(6) * 0.1
    _xlsx(raw.root / "lab" / "leak.xlsx",
          [["t", "supply", "q_leak"], ["s", "kPa", "l/min"]] + [[ti, 100.0 * i, 0.5 * i] for i, ti in enumerate(t)],
          meta={"kind": "leakage", "chamber": "A", "adjustment": "distance", "z_rollers_mm": 4,
                "started_at": "2026-05-01T10:00:00"})
    raw.write("lab/rig.toml", '[read]\nunits_row = 2\n[channels.supply]\nchannel = "p_supply"\n'
                              '[metadata]\nrig = "plpa-x"\n')
    _mf4(raw.root / "lab" / "step.MF4", t, {"x": (t * 10, "mm"), "x_ref": (np.full(6, 0.5), "mm")},
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
