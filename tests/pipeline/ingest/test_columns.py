"""Column mapping (pipeline.ingest.columns): canonical channels, units, names, look-alikes, rig.toml [channels]."""
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.columns import map_columns, map_export_columns
from pipeline.ingest.result import IngestError
from pipeline.readers import RawColumn
from pipeline.readers.base import MAX_CHANNELS
from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, ingest, quarantine, samples_of


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


def test_q_unit_not_accepted(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[furlong]": T, "x_ref[m]": T})
    assert "unit `furlong` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_unit_of_wrong_quantity(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[bar]": T, "x_ref[m]": T})
    assert "unit `bar` not accepted for `x`" in quarantine(raw, warehouse)


def test_q_canonical_channel_without_unit(raw, warehouse):
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x": T, "x_ref[m]": T})
    assert "no unit for channel `x`" in quarantine(raw, warehouse)


def test_q_channel_twice(raw, warehouse):
    raw.write("c/a.csv", "# kind: step\n# started_at: 2026-01-01\n# rig: r\nt[s],x[m],X[mm],x_ref[m]\n0,0,0,0\n")
    assert "channel `x` appears twice" in quarantine(raw, warehouse)


def test_q_unit_with_milli_mega_case_swapped(raw, warehouse):
    # `mPa` is not an accepted unit; folding it onto MPa would store values 1e9 too large
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[Mm]": T, "x_ref[m]": T})
    assert "unit `Mm` not accepted for `x`" in quarantine(raw, warehouse)


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


# -- column mapping: linear, with a channel limit ---------------------------------------------
def _cols(names):
    """Raw columns of these names, without units."""
    return [RawColumn(key=f"c{i + 1}", name=n, unit=None, index=i + 1) for i, n in enumerate(names)]


def test_map_columns_identical_names_get_consecutive_suffixes():
    """4,096 columns named `a` -> a, a_2 ... a_4096 (the next free suffix per name is kept in a
    dict, so the de-duplication is one pass, not a search from _2 for every column)."""
    maps = map_columns(_cols(["a"] * MAX_CHANNELS), {})
    assert [m.column for m in maps] == ["a"] + [f"a_{k}" for k in range(2, MAX_CHANNELS + 1)]


def test_map_columns_suffix_skips_a_name_already_taken():
    assert [m.column for m in map_columns(_cols(["a", "a_2", "A", "a", "a-3"]), {})] == ["a", "a_2", "a_3", "a_4", "a_3_2"]


def test_map_columns_refuses_more_columns_than_the_limit():
    with pytest.raises(IngestError, match=f"^{MAX_CHANNELS + 1} columns: more than the limit of {MAX_CHANNELS} channels"):
        map_columns(_cols(["a"] * (MAX_CHANNELS + 1)), {})


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


def test_lookalike_mapped_in_rig_toml_is_the_channel(raw, warehouse):
    raw.write("c/rig.toml", '[channels."F"]\nchannel = "f"\nunit = "N"\nscale = 9.81\n')
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"}, {"t[s]": T, "F[g]": [1.0, 2.0, 0.0, 0.0]})
    table = samples_of(ingest(raw, "c/a.csv", warehouse), warehouse)
    assert table.column("f_n").to_pylist()[:2] == pytest.approx([9.81, 19.62])


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


def test_map_export_columns_keeps_a_lookalike_under_its_raw_name():
    cols = [RawColumn(key="c1", name="t", unit="s", index=1), RawColumn(key="c2", name="F", unit="g", index=2)]
    maps, looks = map_export_columns(cols, {})
    assert [(m.column, m.channel, m.raw_name) for m in maps] == [("t_s", "t", "t"), ("f_g", None, "F")]
    assert looks == {"c2": ("F", "f", "g")}
