"""Ingest: metadata precedence, unit conversion, and one test per quarantine reason."""
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.layout import RawTree
from tests.conftest import STEP_META
from tests.pipeline.readers.generators import xlsx_workbook

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
    raw.csv("c/a.csv", {**STEP_META, "Bench-Firmware": "v2"},
            {"t[s]": T, "x[m]": T, "x_ref[m]": T, "Oil Temp[degC]": [20, 21, 22, 23], "status": ["ok", "ok", "hot", "ok"]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = pq.read_table(warehouse / res.run["samples_path"])
    # non-canonical columns end in their unit (docs/inputs.md): `Oil Temp[degC]` -> oil_temp_degc
    assert table.column("oil_temp_degc").to_pylist() == [20.0, 21.0, 22.0, 23.0]
    assert table.schema.field("oil_temp_degc").metadata[b"unit"] == b"degC"
    assert table.column("status").to_pylist() == ["ok", "ok", "hot", "ok"]
    assert res.run["params"]["Bench-Firmware"] == "v2"


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
    # the spring model needs to know which side of the piston (its pressure and force signs)
    raw.csv("c/a.csv", {**STEP_META, "kind": "spring", "chamber": "A", "amplitude_mm": 5, "frequency_hz": 1},
            {"t[s]": T, "d[mm]": T, "f[N]": T, "p[bar]": T})
    assert "`chamber` must be one of front, rear" in quarantine(raw, warehouse)


@pytest.mark.parametrize("chamber,stored", [("patient", "patient"), ("Tube 2", "Tube 2"), ("REAR", "rear"),
                                            ("a", "A")])
def test_a_pressure_step_chamber_is_any_name_and_known_names_keep_their_spelling(raw, warehouse, chamber, stored):
    """Another rig's chamber names (a ventilator's `patient` line) are kept as written; the
    project's own names are stored in their spelling, whatever the case (issue 25 item 3)."""
    raw.csv("c/a.csv", {**STEP_META, "kind": "pressure_step", "chamber": chamber, "valve_id": "RPV-2",
                        "age_h": "594"}, {"t[s]": T, "p[bar]": T, "p_ref[bar]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None, res.error
    params = res.run["params"] if isinstance(res.run["params"], dict) else json.loads(res.run["params"])
    assert params["chamber"] == stored and params["valve_id"] == "RPV-2" and params["age_h"] == 594.0


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


def test_q_unit_with_milli_mega_case_swapped(raw, warehouse):
    # `mPa` is not an accepted unit; folding it onto MPa would store values 1e9 too large
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[Mm]": T, "x_ref[m]": T})
    assert "unit `Mm` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_reader_crash_is_one_line_naming_the_error(raw, warehouse, monkeypatch):
    # a library raising something unexpected on a corrupt file (h5py raises RuntimeError)
    import pipeline.raw.metadata as ingest_mod

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
    assert table.column("foo_bar_v").to_pylist() == [1.0, 3.0]
    assert table.column("foo_bar_v_2").to_pylist() == [2.0, 4.0]
    assert [(c["column"], c["raw_name"]) for c in res.channels if c["column"].startswith("foo")] == [
        ("foo_bar_v", "Foo Bar"), ("foo_bar_v_2", "foo-bar")]


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
    import pipeline.versions as code_version

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    old = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    monkeypatch.setattr(code_version, "ingest_code_version", lambda: "changed-code")
    new = ingest(raw, "c/a.csv", warehouse).run["samples_path"]
    assert new != old
    assert (warehouse / old).is_file() and (warehouse / new).is_file()


# -- column mapping: linear, with a channel limit ---------------------------------------------
def _cols(names):
    from pipeline.readers import RawColumn

    return [RawColumn(key=f"c{i + 1}", name=n, unit=None, index=i + 1) for i, n in enumerate(names)]


def test_map_columns_identical_names_get_consecutive_suffixes():
    """4,096 columns named `a` -> a, a_2 ... a_4096 (the next free suffix per name is kept in a
    dict, so the de-duplication is one pass, not a search from _2 for every column)."""
    from pipeline.ingest.columns import map_columns
    from pipeline.readers.base import MAX_CHANNELS

    maps = map_columns(_cols(["a"] * MAX_CHANNELS), {})
    assert [m.column for m in maps] == ["a"] + [f"a_{k}" for k in range(2, MAX_CHANNELS + 1)]


def test_map_columns_suffix_skips_a_name_already_taken():
    from pipeline.ingest.columns import map_columns

    assert [m.column for m in map_columns(_cols(["a", "a_2", "A", "a", "a-3"]), {})] == ["a", "a_2", "a_3", "a_4", "a_3_2"]


def test_map_columns_refuses_more_columns_than_the_limit():
    from pipeline.ingest.columns import IngestError, map_columns
    from pipeline.readers.base import MAX_CHANNELS

    with pytest.raises(IngestError, match=f"^{MAX_CHANNELS + 1} columns: more than the limit of {MAX_CHANNELS} channels"):
        map_columns(_cols(["a"] * (MAX_CHANNELS + 1)), {})


# -- time base from metadata (exports without a time column) ---------------------------------
def samples_of(res, warehouse):
    assert res.error is None, res.error
    return pq.read_table(warehouse / res.run["samples_path"])


def test_csv_without_time_column_takes_sample_rate_from_the_manifest(raw, warehouse):
    raw.csv("c/a.csv", {"kind": "timeseries", "started_at": "2026-01-01", "rig": "r"},
            {"temperature[degC]": [20.0, 20.5, 21.0, 21.5]})
    raw.write("c/manifest.csv", "file,sample_rate_hz,t0_s\na.csv,0.25,8\n")   # one sample every 4 s
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    assert table.column("t_s").to_pylist() == [8.0, 12.0, 16.0, 20.0]
    assert res.run["sample_rate_hz"] == pytest.approx(0.25)
    assert any("time from `sample_rate_hz`" in w for w in res.run["warnings"])
    assert {"column": "t_s", "channel": "t"}.items() <= next(c for c in res.channels if c["column"] == "t_s").items()


def test_headerless_text_takes_dt_s_from_rig_toml(raw, warehouse):
    raw.write("c/rig.toml", '[read]\ndelimiter = "whitespace"\nheader = false\n'
                            '[channels."1"]\nchannel = "x"\nunit = "mm"\n[channels."2"]\nchannel = "x_ref"\nunit = "mm"\n'
                            '[metadata]\nkind = "step"\nrig = "r"\nstarted_at = "2026-01-01"\ndt_s = 0.002\n')
    raw.write("c/a.txt", "1.0 2.0\n1.5 2.0\n2.0 2.0\n")
    table = samples_of(ingest(raw, "c/a.txt", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == [0.0, 0.002, 0.004]
    assert table.column("x_m").to_pylist() == [1e-3, 1.5e-3, 2e-3]


@pytest.mark.parametrize("scalar, value, expected", [("Fs", 50.0, [0.0, 0.02, 0.04]), ("fs", 4.0, [0.0, 0.25, 0.5]),
                                                      ("dt", 0.5, [0.0, 0.5, 1.0])])
def test_mat_scalar_sample_rate_gives_time(raw, warehouse, scalar, value, expected):
    from tests.pipeline.readers.generators import mat_v5

    (raw.root / "c").mkdir(parents=True)
    mat_v5(raw.root / "c/a.mat", {"x": np.array([1.0, 2.0, 3.0]), "x_ref": np.array([0.0, 0.0, 0.0]),
                                  scalar: value, "units": {"x": "mm", "x_ref": "mm"},
                                  "meta": {"kind": "step", "rig": "r", "started_at": "2026-01-01"}})
    table = samples_of(ingest(raw, "c/a.mat", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == pytest.approx(expected, abs=0)


def test_tdms_without_time_or_waveform_takes_sample_rate_from_metadata(raw, warehouse):
    from tests.pipeline.readers.test_tdms import write_tdms

    write_tdms(raw.root / "c/a.tdms", {"kind": "step", "rig": "r", "started_at": "2026-01-01", "sample_rate_hz": 100.0},
               {"Data": {"x": (np.array([1.0, 2.0, 3.0]), {"unit_string": "mm"}),
                         "x_ref": (np.zeros(3), {"unit_string": "mm"})}})
    table = samples_of(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == [0.0, 0.01, 0.02]


def test_lvm_time_column_and_a_disagreeing_stated_rate_warn(raw, warehouse):
    from tests.pipeline.readers.generators import LvmSegment, lvm_bytes

    s = LvmSegment({"x": [0.0, 1.0, 2.0, 3.0], "x_ref": [0.0] * 4}, units={"x": "mm", "x_ref": "mm"}, dt=0.01)
    raw.write("c/a.lvm", lvm_bytes([s], x_columns="No", description="kind=step; rig=r; sample_rate_hz=1000"))
    raw.write("c/b.lvm", lvm_bytes([s], x_columns="No", description="kind=step; rig=r; sample_rate_hz=100"))
    a, b = ingest(raw, "c/a.lvm", warehouse), ingest(raw, "c/b.lvm", warehouse)
    assert samples_of(a, warehouse).column("t_s").to_pylist() == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert any("disagrees with `sample_rate_hz` 1000 Hz" in w for w in a.run["warnings"])
    assert not any("disagrees" in w for w in b.run["warnings"])


def test_q_no_time_and_no_stated_rate_says_how_to_fix(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"x[m]": T, "x_ref[m]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel `t`" in err and "sample_rate_hz" in err


@pytest.mark.parametrize("value", ["0", "-5", "fast", "inf"])
def test_q_bad_stated_sample_rate(raw, warehouse, value):
    raw.csv("c/a.csv", {**STEP_META, "sample_rate_hz": value}, {"x[m]": T, "x_ref[m]": T})
    assert "`sample_rate_hz` must be a" in quarantine(raw, warehouse)


# -- sensor characteristics -------------------------------------------------------------------
def test_sensor_metadata_from_rig_toml_and_metadata_in_si(raw, warehouse):
    raw.write("c/rig.toml", '[sensors.x]\nresolution = "5 um"\nnoise = 2e-6\n'
                            '[sensors.p_a]\nnoise = "300 Pa"\nresolution = "0.01 bar"\n'
                            '[sensors.q_leak]\nnoise = "1 g/s"\n')   # channel not in this run: not stored
    raw.csv("c/a.csv", {**STEP_META, "sensor_X_noise": "0.003 mm", "sensor_p_a_resolution": "1 kPa",
                        "sensor_p_b_noise": "0.003 bara"},
            {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bar(a)]": T, "p_b[bar]": T})
    p = ingest(raw, "c/a.csv", warehouse).run["params"]
    assert p["sensor_x_resolution"] == 5e-06
    assert p["sensor_x_noise"] == pytest.approx(3e-6)             # metadata overrides rig.toml
    assert p["sensor_p_a_noise"] == 300.0
    assert p["sensor_p_a_resolution"] == 1000.0                    # a difference: no gauge offset
    assert p["sensor_p_b_noise"] == pytest.approx(300.0)           # bara: still a difference
    assert "sensor_X_noise" not in p and "sensor_q_leak_noise" not in p


@pytest.mark.parametrize("toml, reason", [
    ('[sensors.x]\nresolution = "5 bar"\n', "unit `bar` is not a length unit"),
    ('[sensors.x]\nresolution = "-5 um"\n', "must be zero or positive"),
    ('[sensors.x]\nnoise = "inf"\n', "not a number with a unit"),
    ('[sensors.x]\nnoise = nan\n', "must be zero or positive and finite"),
    ('[sensors.x]\nnoise = "a lot"\n', "not a number with a unit"),
    ('[sensors.x]\nresolutoin = "5 um"\n', "unknown key(s) resolutoin"),
    ('[sensors]\nx = "5 um"\n', "must be a table"),
])
def test_q_bad_sensor_values(raw, warehouse, toml, reason):
    raw.write("c/rig.toml", toml)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    err = quarantine(raw, warehouse)
    assert "[sensors" in err and reason in err


def test_zero_resolution_states_an_analog_sensor(raw, warehouse):
    raw.write("c/rig.toml", '[sensors.x]\nresolution = 0\nnoise = "20 um"\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    assert (res.run["params"]["sensor_x_resolution"], res.run["params"]["sensor_x_noise"]) == (0.0, 2e-05)


def test_q_bad_sensor_metadata(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "sensor_x_resolution": "5 N"}, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T})
    assert "metadata `sensor_x_resolution`: unit `N` is not a length unit" in quarantine(raw, warehouse)


# -- derived channels -------------------------------------------------------------------------
VISCOUS = {"kind": "viscous", "started_at": "2026-01-01", "rig": "lc", "backpressure_bar": 1.0}


def test_derived_drive_force_lands_in_samples(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nhose_area_m2 = 4.9e-4\n[derived]\nf = "f_cell - p_b * hose_area_m2"\n'
                            'f_net_kn = { expr = "f / 1000", unit = "kN" }\n')
    raw.csv("c/a.csv", VISCOUS, {"t[s]": T, "x[mm]": T, "f_cell[kN]": [0.1, 0.2, 0.3, 0.4], "p_b[bar]": [1, 1, 2, 2]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    # f_cell is not canonical: it enters the expression as recorded (kN); p_b in SI (Pa)
    expected = np.array([0.1, 0.2, 0.3, 0.4]) - np.array([1e5, 1e5, 2e5, 2e5]) * 4.9e-4
    np.testing.assert_allclose(table.column("f_n").to_numpy(), expected)
    np.testing.assert_allclose(table.column("f_net_kn").to_numpy(), expected / 1000)
    assert table.schema.field("f_n").metadata[b"unit"] == b"N"
    assert table.schema.field("f_net_kn").metadata[b"unit"] == b"kN"
    ch = {c["column"]: c for c in res.channels}
    assert ch["f_n"]["channel"] == "f" and ch["f_n"]["raw_name"] == "= f_cell - p_b * hose_area_m2"


def test_derived_channel_whose_inputs_are_absent_is_skipped_with_a_warning(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nload = { expr = "f_cell * 2", unit = "N" }\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert "load_n" not in samples_of(res, warehouse).column_names
    assert any("derived channel `load` not computed: no channel or numeric metadata `f_cell`" in w
               for w in res.run["warnings"])


@pytest.mark.parametrize("toml, reason", [
    ('[derived]\nf = "__import__(\'os\').system(\'touch /tmp/pwned\')"\n', "may be called"),
    ('[derived]\nf = "x.__class__"\n', "Attribute not allowed"),
    ('[derived]\nf = "9**9**9"\n', "literal exponent"),
    ('[derived]\nx_ref = "x * 2"\n', "already has channel `x_ref`"),
    ('[derived]\nf = { expression = "x" }\n', "must be an expression or a table with `expr`"),
])
def test_q_hostile_or_conflicting_derived(raw, warehouse, toml, reason):
    raw.write("c/rig.toml", toml)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    err = quarantine(raw, warehouse)
    assert "rig.toml [derived]" in err and reason in err


def test_rig_toml_with_unknown_table_is_refused(raw, warehouse):
    raw.write("c/rig.toml", '[sensor]\nx = 1\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert "unknown or malformed table(s) sensor" in quarantine(raw, warehouse)


# -- names that only look canonical ---------------------------------------------------------
def test_accelerometer_named_f_in_g_is_kept_non_canonical(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"}, {"t[s]": T, "F[g]": [0.1, -0.2, 0.0, 1.5]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    assert "f_n" not in table.column_names
    assert table.column("f_g").to_pylist() == [0.1, -0.2, 0.0, 1.5]
    assert table.schema.field("f_g").metadata[b"unit"] == b"g"
    assert {"column": "f_g", "channel": None, "raw_name": "F", "raw_unit": "g"}.items() <= \
        next(c for c in res.channels if c["column"] == "f_g").items()
    assert any("`F` in `g` looks like channel `f`" in w for w in res.run["warnings"])


def test_q_lookalike_needed_by_the_kind_says_how_to_map_it(raw, warehouse):
    raw.csv("c/a.csv", {**STEP_META, "kind": "spring", "chamber": "front", "amplitude_mm": 5, "frequency_hz": 1},
            {"t[s]": T, "d[mm]": T, "F[g]": T, "p[bar]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel `f`" in err
    assert '[channels."F"] channel = "f" unit = "N"' in err


def test_lookalike_mapped_in_rig_toml_is_the_channel(raw, warehouse):
    raw.write("c/rig.toml", '[channels."F"]\nchannel = "f"\nunit = "N"\nscale = 9.81\n')
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"}, {"t[s]": T, "F[g]": [1.0, 2.0, 0.0, 0.0]})
    table = samples_of(ingest(raw, "c/a.csv", warehouse), warehouse)
    assert table.column("f_n").to_pylist()[:2] == pytest.approx([9.81, 19.62])


def test_derived_never_reads_a_lookalike_as_the_canonical_channel(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nload = { expr = "f * 2", unit = "N" }\nacc = { expr = "f_g * 9.81", unit = "m/s2" }\n')
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"}, {"t[s]": T, "F[g]": [1.0, 2.0, 3.0, 4.0]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    assert "load_n" not in table.column_names
    assert table.column("acc_m_s2").to_pylist() == pytest.approx([9.81, 19.62, 29.43, 39.24])
    assert any("`load` not computed: no channel or numeric metadata `f`" in w for w in res.run["warnings"])


def test_derived_time_from_a_non_canonical_clock(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nt = "clock_ms / 1000"\n')
    raw.csv("c/a.csv", STEP_META, {"clock[ms]": [10, 20, 30, 40], "x[m]": T, "x_ref[m]": T})
    table = samples_of(ingest(raw, "c/a.csv", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == pytest.approx([0.01, 0.02, 0.03, 0.04])


def test_q_derived_time_and_a_stated_rate_conflict(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nt = "clock_ms / 1000"\n')
    raw.csv("c/a.csv", {**STEP_META, "sample_rate_hz": 100}, {"clock[ms]": [10, 20, 30, 40], "x[m]": T, "x_ref[m]": T})
    assert "rig.toml [derived] `t`: the file already has channel `t`" in quarantine(raw, warehouse)


def test_q_too_many_derived_channels(raw, warehouse):
    from pipeline.ingest.derived import MAX_DERIVED

    raw.write("c/rig.toml", "[derived]\n" + "".join(f'd{i} = "x * {i}"\n' for i in range(MAX_DERIVED + 1)))
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert f"at most {MAX_DERIVED}" in quarantine(raw, warehouse)


def test_q_missing_channel_names_the_derived_channel_that_could_not_be_computed(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nhose_area_m2 = 4.9e-4\n[derived]\nf = "f_cell - p_b * hose_area_m2"\n')
    raw.csv("c/a.csv", VISCOUS, {"t[s]": T, "x[mm]": T, "load[N]": T})
    err = quarantine(raw, warehouse)
    assert "missing channel" in err
    assert "derived channel `f` not computed: no channel or numeric metadata `f_cell`, `p_b`" in err


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


def test_parts_keys_are_ignored_by_one_run_formats(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    raw.write("c/rig.toml", '[read]\nsheets = "all"\ngroups = "all"\n')
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.parts is None and res.run["run_id"] == "c/a"


def test_a_file_whose_sheets_cannot_be_listed_is_one_file_error(raw, warehouse):
    raw.write("c/b.xlsx", b"PK\x03\x04 not a workbook")
    raw.write("c/rig.toml", '[read]\nsheets = "all"\n')
    res = ingest(raw, "c/b.xlsx", warehouse)
    assert res.parts is None and res.run is None and "not a readable .xlsx workbook" in res.error


def test_sheet_names_with_control_characters_give_one_line_run_ids(raw, warehouse):
    rows = [["t[s]", "x[mm]", "x_ref[mm]"], [0.0, 1.0, 0.0], [0.1, 2.0, 0.0]]
    xlsx_workbook(raw.root / "c" / "b.xlsx", {"a\tb": rows}, STEP_META)
    raw.write("c/manifest.csv", "file,sheets,run_id\nb.xlsx,all,day3\n")
    (part,) = ingest(raw, "c/b.xlsx", warehouse).parts
    assert part.run["run_id"] == "day3/a\\x09b" and part.run["params"]["sheet"] == "a\tb"


# -- plausibility of stated values (schemas.kinds.PLAUSIBLE) ---------------------------------------
def test_q_ambient_pressure_in_hpa_written_as_pa_is_refused_not_shifted(raw, warehouse):
    """Issue 21 item 15: `p_atm_pa = 1013.25` (hPa written as Pa) with `bara` channels moved every
    pressure by about 1 bar without a word. A lab at 500 m (95 kPa) stays read right."""
    cols = {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bara]": [1.0, 2.0, 3.0, 4.0]}
    raw.csv("c/a.csv", {**STEP_META, "p_atm_pa": "1013.25"}, cols)
    assert quarantine(raw, warehouse) == (
        "metadata `p_atm_pa` = 1013.25 Pa is outside its plausible range 50000 to 110000 Pa (ambient air "
        "pressure from 5,400 m altitude (Everest base camp, about 53 kPa) to below sea level (Dead Sea shore "
        "about 107 kPa, record high 108.4 kPa); hPa written as Pa is 100 times too small)")
    raw.csv("c/b.csv", {**STEP_META, "p_atm_pa": "95000"}, cols)
    res = ingest(raw, "c/b.csv", warehouse)
    assert res.error is None
    assert pq.read_table(warehouse / res.run["samples_path"]).column("p_a_pa").to_pylist() == [
        5000.0, 105000.0, 205000.0, 305000.0]


@pytest.mark.parametrize("key,value,shown,range_text", [
    ("hose_area_m2", "490", "490 m2", "1e-07 to 1 m2"),               # mm2 written as m2
    ("hose_area_m2", "-4.9e-4", "-0.00049 m2", "1e-07 to 1 m2"),
    ("backpressure_bar", "200000", "200000 bar", "-1.1 to 100 bar"),   # Pa written as bar
    ("backpressure_bar", "-3", "-3 bar", "-1.1 to 100 bar"),           # below a vacuum
    ("force_rate_n_s", "0", "0 N/s", "0.001 to 1e+06 N/s"),
    ("temperature_c", "293.15", "293.15 degC", "-100 to 250 degC"),    # kelvin written as degC
    ("p0_bar_abs", "-0.5", "-0.5 bar", "0 to 101 bar"),
    ("sample_rate_hz", "5e12", "5e+12 Hz", "0.0001 to 1e+09 Hz"),
    ("amplitude_mm", "0", "0 mm", "0.0001 to 10000 mm"),
])
def test_q_metadata_outside_its_plausible_range(raw, warehouse, key, value, shown, range_text):
    raw.csv("c/a.csv", {**BREAKAWAY, key: value}, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    err = quarantine(raw, warehouse)
    assert err.startswith(f"metadata `{key}` = {shown} is outside its plausible range {range_text} (")


def test_plausible_values_at_both_ends_of_a_range_are_kept(raw, warehouse):
    meta = {**BREAKAWAY, "p_atm_pa": 53000, "backpressure_bar": -1.0, "hose_area_m2": 7.9e-7,
            "temperature_c": -40, "force_rate_n_s": 5000}
    raw.csv("c/a.csv", meta, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    assert res.run["params"]["p_atm_pa"] == 53000.0 and res.run["params"]["hose_area_m2"] == 7.9e-7


@pytest.mark.parametrize("where,stated,reason", [
    ("meta", {"sensor_x_resolution": "5"}, "metadata `sensor_x_resolution`: resolution 5 m is outside its plausible "
                                           "range 0 to 0.1 m ("),          # um meant, a bare number is metres
    ("rig", '[sensors.p_a]\nnoise = "300 bar"\n', "rig.toml [sensors.p_a]: noise 3e+07 Pa is outside its plausible "
                                                  "range 0 to 100000 Pa ("),
])
def test_q_sensor_values_outside_their_plausible_range(raw, warehouse, where, stated, reason):
    meta = dict(STEP_META)
    if where == "rig":
        raw.write("c/rig.toml", stated)
    else:
        meta.update(stated)
    raw.csv("c/a.csv", meta, {"t[s]": T, "x[mm]": T, "x_ref[mm]": T, "p_a[bar]": T})
    assert quarantine(raw, warehouse).startswith(reason)


def test_q_mat_scalar_rate_outside_the_sample_rate_range(raw, warehouse):
    from tests.pipeline.readers.generators import mat_v5

    (raw.root / "c").mkdir(parents=True)
    mat_v5(raw.root / "c/a.mat", {"x": np.array([1.0, 2.0, 3.0]), "x_ref": np.array([0.0, 0.0, 0.0]),
                                  "dt": 1e-12, "units": {"x": "mm", "x_ref": "mm"},    # ps: a unit slip
                                  "meta": {"kind": "step", "rig": "r", "started_at": "2026-01-01"}})
    assert quarantine(raw, warehouse, "c/a.mat").startswith(
        "MAT scalar `dt` = 1e-12 s is outside its plausible range 1e-09 to 10000 s (")


# -- issue 25 item 16: a file without `kind` says where to declare it ---------------------------
def _foreign_lvm_without_kind(raw):
    """The foreign campaign's 1 um encoder run, as LabVIEW wrote it, with no `kind` anywhere:
    not in the LVM's Description, not in its lab's rig.toml, no manifest."""
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS, plan, simulate
    from pipeline.simulator.writers import ColumnOut, write_lvm

    run = next(r for r in plan() if r.fmt == "lvm")
    sim = simulate(run, 1)
    cols = [ColumnOut(c, c.rsplit("_", 1)[0], u) for c, u in run.units.items()]
    meta = {k: v for k, v in sim.metadata.items() if k not in ("rig", "hose_area_m2", "kind")}  # as write_run
    meta = {"run_id": run.run_id, "started_at": "2026-02-02T09:00:00", "operator": "guest", **meta}
    path = raw.root / run.rel_path
    path.parent.mkdir(parents=True, exist_ok=True)
    write_lvm(path, sim.data, cols, meta, fs_hz=run.sim["fs_hz"])
    raw.write(f"{CAMPAIGN}/{run.folder}/rig.toml", RIG_TOMLS[f"{run.folder}/rig.toml"], dedent=False)
    return run


def test_missing_kind_says_where_to_declare_it_and_each_way_works(raw, warehouse):
    from pipeline.rebuild.flow import rebuild
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS

    run = _foreign_lvm_without_kind(raw)
    (p,) = rebuild(raw.root, warehouse, jobs=1, report=False).quarantine
    assert p.source_path == run.rel_path and "\n" not in p.error
    assert p.error.startswith("missing metadata `kind` (one of ")
    # the three places, each with its one-line example, the manifest row naming this very file
    assert "`kind=viscous`" not in p.error  # an example, not a guess of this run's kind
    assert "the file's own metadata (LVM: `kind=step` in the header's Description)" in p.error
    assert "a manifest.csv row (`file,kind` then `encoder-1um.lvm,step`)" in p.error
    assert "rig.toml (`[metadata]` then `kind = \"step\"`)" in p.error
    folder = f"{CAMPAIGN}/{run.folder}"
    # as the manifest example says (with this run's kind): the run ingests
    raw.write(f"{folder}/manifest.csv", "file,kind\nencoder-1um.lvm,viscous\n")
    summary = rebuild(raw.root, warehouse, jobs=1, report=False)
    assert summary.quarantine == [] and summary.exit_code == 0
    # as the rig.toml example says: too
    (raw.root / folder / "manifest.csv").unlink()
    raw.write(f"{folder}/rig.toml", RIG_TOMLS[f"{run.folder}/rig.toml"].replace(
        "[metadata]\n", '[metadata]\nkind = "viscous"\n'), dedent=False)
    summary = rebuild(raw.root, warehouse, jobs=1, report=False)
    assert summary.quarantine == [] and summary.exit_code == 0


def test_missing_kind_in_a_csv_names_the_csv_comment_line(raw, warehouse):
    raw.csv("c/run 01.csv", {"started_at": "2026-01-01", "rig": "r"}, {"t[s]": T})
    err = quarantine(raw, warehouse, "c/run 01.csv")
    assert "the file's own metadata (CSV: a `# kind: step` line above the header)" in err
    assert "(`file,kind` then `run 01.csv,step`)" in err
    raw.write("c/a,b.csv", "# rig: r\nt[s]\n0\n")  # a name the CSV row must quote
    assert '(`file,kind` then `"a,b.csv",step`)' in quarantine(raw, warehouse, "c/a,b.csv")


# -- a [channels] key is the header text as written (issue 25 item 1) -------------------------
def test_channels_key_with_a_parenthesised_unit_maps_the_column(raw, warehouse):
    # A rig writes `time(sec)`, `pressure(kPa)`; its rig.toml maps the headers as written.
    raw.write("c/rig.toml", '[channels."time(sec)"]\nchannel = "t"\nunit = "s"\n'
                            '[channels."pressure(kPa)"]\nchannel = "p"\nunit = "kPa"\n')
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"},
            {"time(sec)": T, "pressure(kPa)": [100.0, 101.0, 102.0, 103.0], "valve [V]": [0, 1, 1, 0]})
    res = ingest(raw, "c/a.csv", warehouse)
    assert res.error is None
    table = samples_of(res, warehouse)
    assert table.column("t_s").to_pylist() == T
    assert table.column("p_pa").to_pylist() == pytest.approx([1.0e5, 1.01e5, 1.02e5, 1.03e5])
    assert next(c for c in res.channels if c["column"] == "p_pa")["raw_name"] == "pressure"


def test_channels_key_as_written_with_a_space_before_the_unit(raw, warehouse):
    raw.write("c/rig.toml", '[channels."Time (s)"]\nchannel = "t"\n')
    raw.csv("c/a.csv", STEP_META, {"Time (s)": T, "x[m]": T, "x_ref[m]": T})
    assert ingest(raw, "c/a.csv", warehouse).error is None


def test_channels_key_for_another_header_leaves_the_column_unmapped(raw, warehouse):
    # The happy case's hostile twin: a key for `time(ms)` does not map `time(sec)`.
    raw.write("c/rig.toml", '[channels."time(ms)"]\nchannel = "t"\nunit = "ms"\n')
    raw.csv("c/a.csv", STEP_META, {"time(sec)": T, "x[m]": T, "x_ref[m]": T})
    assert "missing channel `t`" in quarantine(raw, warehouse)


# -- comment lines are not metadata (issue 25 item 4) ------------------------------------------
def test_comment_line_is_kept_under_comments_not_read_as_a_key(raw, warehouse):
    raw.write("c/a.csv", "# Captured 2020-07-03 03:08:17.057076 by unknown user\n# kind: step\n"
                         "# started_at: 2026-01-02T03:04:05\n# rig = plpa-1\nt[s],x[m],x_ref[m]\n0,0,0\n0.1,0,0\n")
    res = ingest(raw, "c/a.csv", warehouse)
    p = res.run["params"]
    assert p["comments"] == ["Captured 2020-07-03 03:08:17.057076 by unknown user"]
    assert not any(k.startswith("Captured") for k in p)
    assert res.run["rig"] == "plpa-1" and res.run["kind"] == "step"
