"""Samples Parquet (pipeline.ingest.samples): values in SI, the footer, the file's name and folder."""
import json

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.samples import samples_file, samples_folder_name

from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, ingest, quarantine


def test_value_exact_round_trip_after_unit_conversion(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "p_atm_pa": 100000},
            {"t[ms]": [0, 1, 2], "x[mm]": [1.5, 2.5, -3.0], "x_ref[um]": [10, 20, 30], "p_a[bar(a)]": [1, 2, 3]})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    table = pq.read_table(warehouse / res.run["samples_path"])
    assert table.column("t_s").to_pylist() == pytest.approx([0.0, 0.001, 0.002], abs=0)
    assert table.column("x_m").to_pylist() == [1.5e-3, 2.5e-3, -3.0e-3]
    assert table.column("x_ref_m").to_pylist() == [1e-5, 2e-5, 3e-5]
    assert table.column("p_a_pa").to_pylist() == [0.0, 100000.0, 200000.0]
    assert set(table.column("run_id").to_pylist()) == {"c/a"}
    assert res.run["n_samples"] == 3 and res.run["sample_rate_hz"] == pytest.approx(1000.0)
    assert table.schema.field("x_m").metadata[b"unit"] == b"m"


def test_samples_footer_records_the_run(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    footer = json.loads(pq.read_metadata(warehouse / res.run["samples_path"]).metadata[b"pneubench"])
    assert footer["run"]["source_sha256"] == res.run["source_sha256"]


def test_q_not_a_number_in_data(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\nt[s],x[m],x_ref[m]\n0,0,0\n1,oops,0\n")
    assert "'oops'" in quarantine(raw, warehouse) and "not a number" in quarantine(raw, warehouse)


def test_empty_channel_is_a_warning_not_an_error(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": ["nan"] * 4})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.run["warnings"] == ["channel `x_ref_m` is empty"]


def test_flow_round_trip_anr_and_normal_litres(raw, warehouse):
    # 60 l/min ANR = 1e-3 m3/s * 1.185 kg/m3; 60 Nl/min (DIN 1343) = 1e-3 m3/s * 1.293 kg/m3
    meta = {**STEP_META, "kind": "leakage", "chamber": "A", "adjustment": "distance", "z_rollers_mm": 4}
    raw.csv("c/anr.csv", meta, {"t[s]": [0, 1], "p_supply[bar]": [1, 2], "q_leak[l/min]": [0, 60]})
    raw.csv("c/din.csv", meta, {"t[s]": [0, 1], "p_supply[bar]": [1, 2], "q_leak[Nl/min]": [0, 60]})
    for rel, rho in (("c/anr.csv", 1.185), ("c/din.csv", 1.293)):
        res = ingest(raw, rel, warehouse)
        assert res.error is None, res.error
        q = pq.read_table(warehouse / res.run["samples_path"]).column("q_leak_kg_s").to_pylist()
        assert q[0] == 0.0
        assert q[1] == pytest.approx(1e-3 * rho, rel=1e-12)


def test_new_ingest_code_writes_beside_the_live_samples_file(raw, warehouse, monkeypatch):
    # the samples file name carries the ingest code's version: output of changed code never
    # overwrites the file the live warehouse points at (a crash before the swap keeps it intact)
    import pipeline.versions as code_version

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    old = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    monkeypatch.setattr(code_version, "ingest_code_version", lambda: "changed-code")
    new = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    assert new != old
    assert (warehouse / old).is_file() and (warehouse / new).is_file()


def test_samples_folder_name_quotes_glob_characters_one_to_one():
    assert samples_folder_name("pla-2016") == "campaign=pla-2016"
    assert samples_folder_name("data\\[old]") == "campaign=data%5C%5Bold%5D"
    assert samples_folder_name("100%") == "campaign=100%25"


def test_a_samples_file_is_renamed_into_place_only_when_finished(tmp_path):
    schema = pa.schema([("t_s", pa.float64())])
    table = pa.table({"t_s": [0.0, 0.1]}, schema=schema)
    with samples_file(tmp_path, "c/a", schema) as out:
        out.writer.write_table(table)
        out.finish(tmp_path / "a.parquet", {"run": {"run_id": "c/a"}, "channels": []})
    assert [p.name for p in tmp_path.iterdir()] == ["a.parquet"]
    assert json.loads(pq.read_metadata(tmp_path / "a.parquet").metadata[b"pneubench"])["run"] == {"run_id": "c/a"}
    with pytest.raises(RuntimeError), samples_file(tmp_path, "c/b", schema) as out:
        out.writer.write_table(table)
        raise RuntimeError("a bad batch")
    assert [p.name for p in tmp_path.iterdir()] == ["a.parquet"]   # no temporary file left
