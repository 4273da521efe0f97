"""LVM reader: one scenario per edge case of LabVIEW's Write To Measurement File output."""
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from pipeline.readers import ReaderError, read_export
from pipeline.readers import lvm as lvm_module
from tests.pipeline.readers.generators import LvmSegment, lvm_bytes

STEP = "kind=step; rig=plpa-1"


def open_lvm(tmp_path, data: bytes, name="run.lvm"):
    path = tmp_path / name
    path.write_bytes(data)
    return read_export(path)


def table(export) -> pa.Table:
    return pa.Table.from_batches(list(export.batches()))


def col(export, name):
    """Values of the column whose raw name is ``name``."""
    key = next(c.key for c in export.columns if c.name == name)
    return table(export).column(key).to_pylist()


def seg(n=4, dt=0.01, x0=0.0, **kw):
    base = {"x": [float(i) for i in range(n)], "p_a": [0.5 + i for i in range(n)]}
    return LvmSegment(kw.pop("channels", base), units=kw.pop("units", {"x": "mm", "p_a": "bar"}), dt=dt, x0=x0, **kw)


def test_lvm_x_columns_no_uses_delta_x(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=4, dt=0.25, x0=1.0)], x_columns="No"))
    assert [c.name for c in ex.columns] == ["t", "x", "p_a"]
    assert col(ex, "t") == [1.0, 1.25, 1.5, 1.75]
    assert col(ex, "x") == [0.0, 1.0, 2.0, 3.0]
    assert {c.name: c.unit for c in ex.columns} == {"t": "s", "x": "mm", "p_a": "bar"}


def test_lvm_x_columns_one_reads_the_x_column(tmp_path):
    s = seg(n=3)
    s.x = [0.0, 0.1, 0.35]          # irregular: must come from the file, not from Delta_X
    ex = open_lvm(tmp_path, lvm_bytes([s], x_columns="One"))
    assert col(ex, "t") == [0.0, 0.1, 0.35]
    assert col(ex, "p_a") == [0.5, 1.5, 2.5]


def test_lvm_x_columns_multi(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3, dt=0.5)], x_columns="Multi"))
    assert [c.name for c in ex.columns] == ["t", "x", "p_a"]
    assert col(ex, "t") == [0.0, 0.5, 1.0]
    assert col(ex, "p_a") == [0.5, 1.5, 2.5]


def test_lvm_x_columns_multi_disagreeing_x_is_refused_naming_the_line(tmp_path):
    s = seg(n=3, dt=0.5)
    s.x_multi = {"x": [0.0, 0.5, 1.0], "p_a": [0.0, 0.5, 1.1]}
    ex = open_lvm(tmp_path, lvm_bytes([s], x_columns="Multi"))
    with pytest.raises(ReaderError, match=r"line 26: the X column of `p_a` \(1.1\) disagrees"):
        table(ex)


def test_lvm_two_segments_concatenate_in_time(tmp_path):
    # LabVIEW restarts X0 at 0 for waveforms without a start time: time must run on.
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3, dt=0.5), seg(n=2, dt=0.5)], x_columns="No"))
    assert col(ex, "t") == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert col(ex, "x") == [0.0, 1.0, 2.0, 0.0, 1.0]


def test_lvm_later_segment_x0_that_carries_on_is_kept_with_its_pause(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2, dt=0.5), seg(n=2, dt=0.5, x0=10.0)], x_columns="No"))
    assert col(ex, "t") == [0.0, 0.5, 10.0, 10.5]


def test_lvm_two_segments_with_x_column_restarting(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2, dt=0.25), seg(n=2, dt=0.25)], x_columns="One"))
    assert col(ex, "t") == [0.0, 0.25, 0.5, 0.75]


def test_lvm_more_rows_than_samples(tmp_path):
    # Multi_Headings = No: later writes append rows without a new header.
    first = seg(n=2, dt=0.5)
    appended = seg(n=3, dt=0.5, header=False)
    ex = open_lvm(tmp_path, lvm_bytes([first, appended], x_columns="No", multi_headings="No"))
    assert col(ex, "t") == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert col(ex, "x") == [0.0, 1.0, 0.0, 1.0, 2.0]
    assert ex.warnings == []


def test_lvm_fewer_rows_than_samples_warns(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3, samples=10)], x_columns="No"))
    assert len(col(ex, "t")) == 3
    assert ex.warnings == ["segment 1 has 3 rows where its header says Samples 10 (file cut short?)"]


def test_lvm_comment_column(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3, comments={0: "valve open", 2: "note 2"})], x_columns="No"))
    comment = next(c for c in ex.columns if c.name == "comment")
    assert comment.dtype == "string"
    assert table(ex).column("comment").to_pylist() == ["valve open", None, "note 2"]


def test_lvm_comment_only_in_a_later_segment_is_kept(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2), seg(n=2, comments={1: "late"})], x_columns="No"))
    assert table(ex).column("comment").to_pylist() == [None, None, None, "late"]


def test_lvm_empty_comment_column_is_dropped(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3)], x_columns="One"))
    assert [c.name for c in ex.columns] == ["t", "x", "p_a"]


def test_lvm_empty_channel(tmp_path, raw, warehouse):
    s = seg(n=3, channels={"x": [1.0, 2.0, 3.0], "x_ref": [None] * 3}, units={"x": "mm", "x_ref": "mm"})
    ex = open_lvm(tmp_path, lvm_bytes([s], x_columns="No"))
    assert np.isnan(np.array(col(ex, "x_ref"), dtype=float)).all() and col(ex, "x") == [1.0, 2.0, 3.0]
    raw.write("c/a.lvm", lvm_bytes([s], x_columns="No", description=STEP))
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.lvm", warehouse)
    assert res.error is None
    assert res.run["warnings"] == ["channel `x_ref_m` is empty"]


def test_lvm_decimal_comma(tmp_path):
    s = seg(n=3, dt=0.125, channels={"x": [1.5, -2.25, 3e-3], "p_a": [0.5, 1.0, 1.5]})
    data = lvm_bytes([s], x_columns="One", decimal=",")
    assert b"\t-2,25" in data
    ex = open_lvm(tmp_path, data)
    assert col(ex, "t") == [0.0, 0.125, 0.25]
    assert col(ex, "x") == [1.5, -2.25, 3e-3]


def test_lvm_comma_separator(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2, dt=0.5, comments={1: "c"})], x_columns="One", separator="Comma"))
    assert col(ex, "t") == [0.0, 0.5]
    assert col(ex, "p_a") == [0.5, 1.5]
    assert table(ex).column("comment").to_pylist() == [None, "c"]


def test_lvm_x_unit_label(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2, dt=2.0, x_unit="ms")], x_columns="No"))
    assert next(c for c in ex.columns if c.name == "t").unit == "ms"
    assert col(ex, "t") == [0.0, 2.0]


def test_lvm_time_pref_absolute_is_made_relative_to_the_first_sample(tmp_path):
    t0 = 3.8e9   # seconds since 1904
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=3, dt=0.5, x0=t0)], x_columns="No", time_pref="Absolute"))
    assert col(ex, "t") == [0.0, 0.5, 1.0]


def test_lvm_channel_named_t_wins_over_x_values(tmp_path):
    s = seg(n=3, channels={"t": [0.0, 0.2, 0.4], "x": [1.0, 2.0, 3.0]}, units={"t": "s", "x": "mm"}, dt=99.0)
    ex = open_lvm(tmp_path, lvm_bytes([s], x_columns="One"))
    assert [c.name for c in ex.columns] == ["t", "x"]
    assert col(ex, "t") == [0.0, 0.2, 0.4]


def test_lvm_rows_without_the_leading_x_field(tmp_path):
    data = lvm_bytes([seg(n=2, dt=0.5, comments={0: "hi"})], x_columns="No")
    data = data.replace(b"\r\n\t", b"\r\n")       # data rows written without the empty X field
    ex = open_lvm(tmp_path, data)
    assert col(ex, "t") == [0.0, 0.5]
    assert col(ex, "p_a") == [0.5, 1.5]
    assert table(ex).column("comment").to_pylist() == ["hi", None]


def test_lvm_bad_value_names_the_line(tmp_path):
    data = lvm_bytes([seg(n=3)], x_columns="No").replace(b"\t2.5", b"\toops")
    ex = open_lvm(tmp_path, data)
    with pytest.raises(ReaderError, match=r"line 26: value 'oops' in column `p_a` is not a number"):
        table(ex)


def test_lvm_nan_and_inf_are_numbers(tmp_path):
    data = lvm_bytes([seg(n=3)], x_columns="No").replace(b"\t1.5", b"\tNaN").replace(b"\t2.5", b"\tInf")
    assert col(open_lvm(tmp_path, data), "p_a")[1:] == [pytest.approx(np.nan, nan_ok=True), np.inf]


def test_lvm_segment_with_other_channels_is_refused(tmp_path):
    other = seg(n=2, channels={"x": [1.0, 2.0], "f": [3.0, 4.0]}, units={"x": "mm", "f": "N"})
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=2), other], x_columns="No"))
    with pytest.raises(ReaderError, match=r"segment 2 has channels \['x', 'f'\] where segment 1 has \['x', 'p_a'\]"):
        table(ex)


def test_lvm_different_delta_x_with_x_columns_no_is_refused(tmp_path):
    data = lvm_bytes([seg(n=2, dt=0.5)], x_columns="No").replace(b"Delta_X\t0.5\t0.5", b"Delta_X\t0.5\t0.25")
    ex = open_lvm(tmp_path, data)
    with pytest.raises(ReaderError, match="channels have different Delta_X"):
        table(ex)


def test_lvm_streams_in_several_batches_with_continuous_time(tmp_path, monkeypatch):
    monkeypatch.setattr(lvm_module, "CHUNK_BYTES", 256)
    n = 200
    ex = open_lvm(tmp_path, lvm_bytes([seg(n=n, dt=0.5), seg(n=n, dt=0.5)], x_columns="No"))
    batches = list(ex.batches())
    assert len(batches) > 4
    t = pa.Table.from_batches(batches).column("t").to_numpy()
    np.testing.assert_array_equal(t, np.arange(2 * n) * 0.5)


def test_lvm_without_header_is_read_as_text_described_by_rig_toml(raw, warehouse):
    raw.write("c/rig.toml", '[read]\ndelimiter = "\\t"\nheader = false\n[metadata]\nkind = "step"\nrig = "r"\n'
                            'started_at = "2026-01-01"\n[channels."1"]\nchannel = "t"\nunit = "s"\n'
                            '[channels."2"]\nchannel = "x"\nunit = "mm"\n[channels."3"]\nchannel = "x_ref"\nunit = "mm"\n')
    raw.write("c/a.lvm", "0.0\t1.0\t2.0\n0.5\t3.0\t4.0\n")
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.lvm", warehouse)
    assert res.error is None and res.run["format"] == "lvm"
    assert pq.read_table(warehouse / res.run["samples_path"]).column("x_m").to_pylist() == [1e-3, 3e-3]


def test_lvm_value_exact_round_trip_through_ingest(raw, warehouse):
    s1 = LvmSegment({"x": [1.5, 2.5, -3.0], "x_ref": [10.0, 20.0, 30.0], "p_a": [1.0, 2.0, 3.0]},
                    units={"x": "mm", "x_ref": "um", "p_a": "bar(a)"}, dt=1.0, x_unit="ms", comments={1: "step"})
    s2 = LvmSegment({"x": [4.0], "x_ref": [40.0], "p_a": [4.0]}, units={"x": "mm", "x_ref": "um", "p_a": "bar(a)"},
                    dt=1.0, x_unit="ms")
    raw.write("c/a.lvm", lvm_bytes([s1, s2], x_columns="No", decimal=",", description=STEP + "; p_atm_pa=100000"))
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.lvm", warehouse)
    assert res.error is None, res.error
    out = pq.read_table(warehouse / res.run["samples_path"])
    assert out.column("t_s").to_pylist() == [0.0, 0.001, 0.002, 0.003]
    assert out.column("x_m").to_pylist() == [1.5e-3, 2.5e-3, -3.0e-3, 4.0e-3]
    assert out.column("x_ref_m").to_pylist() == [1e-5, 2e-5, 3e-5, 4e-5]
    assert out.column("p_a_pa").to_pylist() == [0.0, 100000.0, 200000.0, 300000.0]
    assert out.column("comment").to_pylist() == [None, "step", None, None]
    assert res.run["started_at"] == "2026-01-02T03:04:05.250000+00:00"
    assert res.run["format"] == "lvm" and res.run["n_samples"] == 4


def test_lvm_unit_outside_the_table_is_quarantined(raw, warehouse):
    s = seg(n=2, units={"x": "furlong", "p_a": "bar"})
    raw.write("c/a.lvm", lvm_bytes([s], description=STEP + "; started_at=2026-01-01"))
    raw.write("c/manifest.csv", "file,kind\na.lvm,durability\n")
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.lvm", warehouse)
    assert "unit `furlong` not accepted for `x`" in res.error


# -- refusals of the file header, one scenario each ------------------------------------------
# -- resource limits -------------------------------------------------------------------------
