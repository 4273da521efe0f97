"""Ingest of one raw file (pipeline.ingest.file): the flow, files that cannot be used, files of several runs."""
import json

import pyarrow.parquet as pq

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, ingest, quarantine
from tests.pipeline.readers.generators import xlsx_workbook


def test_q_no_data_rows(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\nt[s],x[m],x_ref[m]\n")
    assert "no data rows" in quarantine(raw, warehouse)


def test_q_not_in_a_campaign_folder(raw, warehouse):
    raw.csv("a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "not in a campaign folder" in quarantine(raw, warehouse, "a.csv")


def test_q_invalid_rig_toml(raw, warehouse):
    raw.write("c/rig.toml", "[metadata\nrig = 1\n")
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "cannot use c/rig.toml: invalid TOML" in quarantine(raw, warehouse)


def test_rig_toml_with_unknown_table_is_refused(raw, warehouse):
    raw.write("c/rig.toml", '[sensor]\nx = 1\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "unknown or malformed table(s) sensor" in quarantine(raw, warehouse)


def test_raw_files_are_never_modified(raw, warehouse):
    p = raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    before = (p.read_bytes(), p.stat().st_mtime_ns)
    ingest(raw, "c/a.csv", warehouse)
    assert (p.read_bytes(), p.stat().st_mtime_ns) == before


def test_reader_warnings_raised_while_reading_data_reach_the_run(raw, warehouse, monkeypatch):
    import pipeline.raw.metadata as ingest_mod

    real = ingest_mod.read_export

    def reader_that_warns_late(path, read, hints):
        export = real(path, read, hints)
        inner = export.batches

        def batches():
            yield from inner()
            export.warnings.append("file cut short after the last batch")
        export.batches = batches
        return export

    monkeypatch.setattr(ingest_mod, "read_export", reader_that_warns_late)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/a.csv", warehouse).run["warnings"] == ["file cut short after the last batch"]


# -- files of several runs ---------------------------------------------------------------------
def test_sheets_all_gives_one_part_per_sheet_each_with_its_samples_file(raw, warehouse):
    rows = [["t[s]", "x[mm]", "x_ref[mm]"], [0.0, 1.0, 0.0], [0.1, 2.0, 0.0]]
    xlsx_workbook(raw.root / "c" / "b.xlsx", {"S1": rows, "S 2": rows, "bad": [["t[s]", "x[mm]"], [0.0, "oops"]]},
              STEP_META)
    raw.write("c/rig.toml", '[read]\nsheets = "all"\n')
    res = ingest(raw, "c/b.xlsx", warehouse)
    assert res.run is None and res.error is None and len(res.sha256) == 64
    assert [p.run["run_id"] if p.run else None for p in res.parts] == ["c/b/S1", "c/b/S 2", None]
    assert res.parts[2].error.startswith("sheet 'bad': ")
    assert all(p.source_path == "c/b.xlsx" for p in res.parts)
    ok = [p.run for p in res.parts[:2]]
    assert [r["params"]["sheet"] for r in ok] == ["S1", "S 2"] and all("sheets" not in r["params"] for r in ok)
    assert len({r["samples_path"] for r in ok}) == 2 and all(r["source_sha256"] == res.sha256 for r in ok)
    for r in ok:
        footer = json.loads(pq.read_metadata(warehouse / r["samples_path"]).metadata[b"pneubench"])
        assert footer["run"] == r
        assert pq.read_table(warehouse / r["samples_path"]).column("x_m").to_pylist() == [0.001, 0.002]


def test_a_file_whose_sheets_cannot_be_listed_is_one_file_error(raw, warehouse):
    raw.write("c/b.xlsx", b"PK\x03\x04 not a workbook")
    raw.write("c/rig.toml", '[read]\nsheets = "all"\n')
    res = ingest(raw, "c/b.xlsx", warehouse)
    assert res.parts is None and res.run is None and "not a readable .xlsx workbook" in res.error
