"""Ingest: metadata precedence, unit conversion, and one test per quarantine reason."""
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.ingest import ingest_file
from pipeline.layout import RawTree
from tests.conftest import STEP_META

T = [0.0, 0.1, 0.2, 0.3]


def ingest(raw, rel, warehouse):
    return ingest_file(RawTree(raw.root), raw.root / rel, warehouse)


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


def test_metadata_precedence_manifest_over_file_over_rig(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nrig = "from-rig"\noperator = "rig-op"\nnotes = "rig-notes"\n')
    raw.csv("c/sub/a.csv", {"kind": "step", "started_at": "2026-01-01T00:00:00", "operator": "file-op",
                            "notes": "file-notes"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/manifest.csv", "file,notes,custom_key\nsub/a.csv,manifest-notes,42\n")
    res = ingest(raw, "c/sub/a.csv", warehouse)
    p = res.run["params"]
    assert (p["rig"], p["operator"], p["notes"], p["custom_key"]) == ("from-rig", "file-op", "manifest-notes", "42")
    assert res.run["run_id"] == "c/a"
    assert res.run["started_at"] == "2026-01-01T00:00:00+00:00"


def test_sub_rig_toml_overrides_parent(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nrig = "parent"\nkind = "step"\n')
    raw.write("c/sub/rig.toml", '[metadata]\nrig = "child"\n')
    raw.csv("c/sub/a.csv", {"started_at": "2026-01-01"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/sub/a.csv", warehouse).run["rig"] == "child"


def test_started_at_with_offset_is_converted_to_utc(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "started_at": "2026-06-01T10:00:00+02:00"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/a.csv", warehouse).run["started_at"] == "2026-06-01T08:00:00+00:00"


def test_non_canonical_channels_and_unknown_keys_are_kept(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "Bench Firmware": "v2"},
            {"t[s]": T, "x[m]": T, "x_ref[m]": T, "Oil Temp[degC]": [20, 21, 22, 23], "status": ["ok", "ok", "hot", "ok"]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = pq.read_table(warehouse / res.run["samples_path"])
    assert table.column("oil_temp").to_pylist() == [20.0, 21.0, 22.0, 23.0]
    assert table.schema.field("oil_temp").metadata[b"unit"] == b"degC"
    assert table.column("status").to_pylist() == ["ok", "ok", "hot", "ok"]
    assert res.run["params"]["Bench Firmware"] == "v2"


def test_samples_footer_records_the_run(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    footer = json.loads(pq.read_metadata(warehouse / res.run["samples_path"]).metadata[b"pneubench"])
    assert footer["run"]["source_sha256"] == res.run["source_sha256"]


# -- one test per quarantine reason -----------------------------------------------------------
def quarantine(raw, warehouse, rel="c/a.csv"):
    res = ingest(raw, rel, warehouse)
    assert res.run is None, "expected the file to be quarantined"
    assert "\n" not in res.error
    return res.error


def test_q_missing_channel(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "breakaway", "direction": "P", "backpressure_bar": 0,
                        "force_rate_n_s": 1, "hose_area_m2": 4.9e-4}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T})
    assert "missing channel `x`" in quarantine(raw, warehouse)


def test_q_unit_not_accepted(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[m]": T})
    assert "unit `furlong` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_unit_of_wrong_quantity(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[bar]": T, "x_ref[m]": T})
    assert "unit `bar` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_canonical_channel_without_unit(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x": T, "x_ref[m]": T})
    assert "no unit for channel `x`" in quarantine(raw, warehouse)


def test_q_time_goes_backwards(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": [0, 1, 2, 1.5, 3], "x[m]": [0] * 5, "x_ref[m]": [0] * 5})
    assert "time goes backwards at row 4" in quarantine(raw, warehouse)


def test_q_time_missing(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": ["0", "1", "", "3"], "x[m]": T, "x_ref[m]": T})
    assert "time is missing at row 3" in quarantine(raw, warehouse)


def test_q_missing_kind(raw, warehouse):
    raw.csv("c/a.csv", {"started_at": "2026-01-01", "rig": "r"}, {"t[s]": T})
    assert "missing metadata `kind`" in quarantine(raw, warehouse)


def test_q_unknown_kind(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "wobble"}, {"t[s]": T})
    assert "`kind` must be one of" in quarantine(raw, warehouse)


def test_q_missing_required_metadata(raw, warehouse):
    raw.csv("c/a.csv", {"kind": "durability", "rig": "r"}, {"t[s]": T, "x[m]": T, "p_a[bar]": T, "p_b[bar]": T})
    err = quarantine(raw, warehouse)
    assert "missing metadata `started_at`, `hose_id`" in err


def test_q_bad_number_in_metadata(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "identification", "kp_v_m": "five"},
            {"t[s]": T, "x[m]": T, "u[V]": T, "u_d[V]": T, "x_ref[m]": T})
    assert "`kp_v_m` must be a number" in quarantine(raw, warehouse)


def test_q_bad_started_at(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "started_at": "last tuesday"}, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "`started_at` is not ISO 8601" in quarantine(raw, warehouse)


def test_q_wrong_chamber_for_rig(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "pressure_step", "chamber": "A"}, {"t[s]": T, "p[bar]": T, "p_ref[bar]": T})
    assert "`chamber` must be one of front, rear" in quarantine(raw, warehouse)


def test_q_not_a_number_in_data(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\nt[s],x[m],x_ref[m]\n0,0,0\n1,oops,0\n")
    assert "'oops'" in quarantine(raw, warehouse) and "not a number" in quarantine(raw, warehouse)


def test_q_channel_twice(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\nt[s],x[m],X[mm],x_ref[m]\n0,0,0,0\n")
    assert "channel `x` appears twice" in quarantine(raw, warehouse)


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


def test_empty_channel_is_a_warning_not_an_error(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": ["nan"] * 4})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.run["warnings"] == ["channel `x_ref_m` is empty"]


def test_raw_files_are_never_modified(raw, warehouse):
    p = raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    before = (p.read_bytes(), p.stat().st_mtime_ns)
    ingest(raw, "c/a.csv", warehouse)
    assert (p.read_bytes(), p.stat().st_mtime_ns) == before


def test_tdms_root_group_beats_rig_toml_group(raw, warehouse):
    """Precedence manifest > file > rig.toml also holds for the hints a reader uses."""
    import numpy as np
    from nptdms import ChannelObject, RootObject, TdmsWriter

    path = raw.root / "c" / "two_groups.tdms"
    path.parent.mkdir(parents=True)
    raw.write("c/rig.toml", '[metadata]\ngroup = "wrong"\n')
    root = RootObject({"kind": "step", "started_at": "2026-01-01T00:00:00", "rig": "r", "group": "right"})
    chans = []
    for group, value in (("wrong", 1.0), ("right", 2.0)):
        for name in ("t", "x", "x_ref"):
            data = np.arange(3.0) if name == "t" else np.full(3, value)
            chans.append(ChannelObject(group, name, data, properties={"unit_string": "s" if name == "t" else "m"}))
    with TdmsWriter(str(path)) as w:
        w.write_segment([root] + chans)
    res = ingest(raw, "c/two_groups.tdms", warehouse)
    assert res.error is None, res.error
    assert pq.read_table(warehouse / res.run["samples_path"]).column("x_m").to_pylist() == [2.0, 2.0, 2.0]


def test_reader_warnings_raised_while_reading_data_reach_the_run(raw, warehouse, monkeypatch):
    import pipeline.ingest as ingest_mod

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


def test_q_unit_with_milli_mega_case_swapped(raw, warehouse):
    # `mPa` is not an accepted unit; folding it onto MPa would store values 1e9 too large
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[Mm]": T, "x_ref[m]": T})
    assert "unit `Mm` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_reader_crash_is_one_line_naming_the_error(raw, warehouse, monkeypatch):
    # a library raising something unexpected on a corrupt file (h5py raises RuntimeError)
    import pipeline.ingest as ingest_mod

    def corrupt(*a, **k):
        raise RuntimeError("Link iteration failed (actual len exceeds EOA)\nsecond line")

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    monkeypatch.setattr(ingest_mod, "read_export", corrupt)
    err = quarantine(raw, warehouse)
    assert err == "cannot read file: RuntimeError: Link iteration failed (actual len exceeds EOA) second line"


def test_non_canonical_names_that_sanitise_alike_are_both_kept(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\n"
                         "t[s],x[m],x_ref[m],Foo Bar[V],foo-bar[V]\n0,0,0,1,2\n1,0,0,3,4\n")
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    table = pq.read_table(warehouse / res.run["samples_path"])
    assert table.column("foo_bar").to_pylist() == [1.0, 3.0]
    assert table.column("foo_bar_2").to_pylist() == [2.0, 4.0]
    assert [(c["column"], c["raw_name"]) for c in res.channels if c["column"].startswith("foo")] == [
        ("foo_bar", "Foo Bar"), ("foo_bar_2", "foo-bar")]


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


BREAKAWAY = {**STEP_META, "kind": "breakaway", "direction": "P", "backpressure_bar": 0, "force_rate_n_s": 1,
             "hose_area_m2": 4.9e-4}


@pytest.mark.parametrize("text", ["nan", "inf", "-Infinity"])
def test_q_non_finite_number_in_metadata(raw, warehouse, text):
    raw.csv("c/a.csv", {**BREAKAWAY, "hose_area_m2": text}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    assert quarantine(raw, warehouse) == f"metadata `hose_area_m2` must be a finite number, got {text!r}"


def test_q_non_finite_number_in_rig_toml_metadata(raw, warehouse):
    raw.write("c/rig.toml", "[metadata]\nhose_area_m2 = nan\n")          # a TOML float, not text
    meta = {k: v for k, v in BREAKAWAY.items() if k != "hose_area_m2"}
    raw.csv("c/a.csv", meta, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    assert quarantine(raw, warehouse) == "metadata `hose_area_m2` must be a finite number, got nan"


def test_new_ingest_code_writes_beside_the_live_samples_file(raw, warehouse, monkeypatch):
    # the samples file name carries the ingest code's version: output of changed code never
    # overwrites the file the live warehouse points at (a crash before the swap keeps it intact)
    import pipeline.code_version as code_version

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    old = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    monkeypatch.setattr(code_version, "ingest_code_version", lambda: "changed-code")
    new = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    assert new != old
    assert (warehouse / old).is_file() and (warehouse / new).is_file()
