"""MAT reader: v5, v7 (compressed), v7.3 (HDF5), MATLAB objects refused with a re-export hint."""
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from pipeline.readers import ReaderError, read_export
from pipeline.readers import mat as mat_module
from tests.pipeline.readers.generators import mat_v5, mat_v5_with_object, mat_v73

META = {"kind": "step", "rig": "plpa-1", "started_at": "2026-01-02T03:04:05"}
T = np.array([0.0, 0.1, 0.2, 0.3])


def values(export) -> dict:
    return pa.Table.from_batches(list(export.batches())).to_pydict()


def basic(**extra):
    return {"t": T, "x": np.array([1.5, 2.5, -3.0, 4.0]), "meta": dict(META), "units": {"t": "s", "x": "mm"}, **extra}


def test_mat_v5(tmp_path):
    ex = read_export(mat_v5(tmp_path / "a.mat", basic(), oned_as="column"))
    assert ex.format == "mat"
    assert [(c.name, c.unit) for c in ex.columns] == [("t", "s"), ("x", "mm")]
    assert values(ex) == {"t": T.tolist(), "x": [1.5, 2.5, -3.0, 4.0]}
    assert ex.metadata == META


def test_mat_v7_compressed(tmp_path):
    path = mat_v5(tmp_path / "a.mat", basic(), compress=True, oned_as="row")   # 1 x N vectors
    ex = read_export(path)
    assert values(ex) == {"t": T.tolist(), "x": [1.5, 2.5, -3.0, 4.0]}
    assert ex.metadata["kind"] == "step"


def test_mat_v73_hdf5(tmp_path):
    path = mat_v73(tmp_path / "a.mat", basic(note="Prüfstand"))
    assert path.read_bytes()[:10] == b"MATLAB 7.3" and path.read_bytes()[512:516] == b"\x89HDF"
    ex = read_export(path)
    assert {c.name: c.unit for c in ex.columns} == {"t": "s", "x": "mm"}
    assert values(ex) == {"t": T.tolist(), "x": [1.5, 2.5, -3.0, 4.0]}
    assert ex.metadata == {**META, "note": "Prüfstand"}


def test_mat_v73_streams_in_slices(tmp_path, monkeypatch):
    monkeypatch.setattr(mat_module, "BATCH_ROWS", 7)
    n = 50
    ex = read_export(mat_v73(tmp_path / "a.mat", {"t": np.arange(n) * 0.5, "x": np.arange(n) ** 2.0}))
    batches = list(ex.batches())
    assert len(batches) == 8 and max(b.num_rows for b in batches) == 7
    out = pa.Table.from_batches(batches)
    np.testing.assert_array_equal(out.column("x").to_numpy(), np.arange(n) ** 2.0)


def test_mat_timetable_refused_with_reexport_hint(tmp_path):
    # A real v5 byte layout: mxOPAQUE_CLASS, type system MCOS, class timetable (see generators).
    path = mat_v5_with_object(tmp_path / "run7.mat", "tt", "timetable", plain={"t": [0.0, 1.0, 2.0]})
    with pytest.raises(ReaderError) as err:
        read_export(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("MATLAB timetable object `tt` can only be read by MATLAB")
    assert "timetable2table(tt, 'ConvertRowTimes', false)" in msg
    assert "table2struct(" in msg and "'ToScalar', true" in msg
    assert "s.t = seconds(tt.Properties.RowTimes - tt.Properties.RowTimes(1))" in msg
    assert "save('run7.mat', '-struct', 's', '-v7')" in msg


def test_mat_table_object_refused_with_table2struct_hint(tmp_path):
    path = mat_v5_with_object(tmp_path / "a.mat", "T", "table")
    with pytest.raises(ReaderError, match=r"MATLAB table object `T` .*s = table2struct\(T, 'ToScalar', true\)"):
        read_export(path)


def test_mat_v73_timetable_refused_with_reexport_hint(tmp_path):
    path = mat_v73(tmp_path / "a.mat", {"t": T}, objects={"tt": "timetable"})
    with pytest.raises(ReaderError, match=r"MATLAB timetable object `tt` .*save\('a.mat', '-struct', 's', '-v7'\)"):
        read_export(path)


def test_mat_object_inside_meta_refused(tmp_path):
    path = mat_v73(tmp_path / "a.mat", {"t": T, "meta": {"kind": "step"}})
    import h5py
    with h5py.File(path, "r+") as f:
        ds = f["meta"].create_dataset("started_at", data=np.zeros((1, 6), dtype=np.uint32))
        ds.attrs["MATLAB_class"] = np.bytes_("datetime")
        ds.attrs["MATLAB_object_decode"] = np.int32(3)
    with pytest.raises(ReaderError, match=r"MATLAB datetime object `meta.started_at`"):
        read_export(path)


def test_mat_unequal_lengths(tmp_path):
    path = mat_v5(tmp_path / "a.mat", {"t": T, "x": np.arange(3.0), "f": np.arange(4.0)})
    with pytest.raises(ReaderError, match=r"channels have different lengths \(`t` 4, `x` 3, `f` 4\)"):
        read_export(path)


def test_mat_units_struct(tmp_path):
    ex = read_export(mat_v5(tmp_path / "a.mat", {"t": T, "P_A": T, "f": T, "units": {"t": "ms", "p_a": "bar(a)"}}))
    assert {c.name: c.unit for c in ex.columns} == {"t": "ms", "P_A": "bar(a)", "f": None}


def test_mat_scalars_and_meta_are_metadata(tmp_path):
    ex = read_export(mat_v5(tmp_path / "a.mat", {"t": T, "backpressure_bar": 2.5, "hose_id": 7.0, "ok": True,
                                                 "operator": "ab", "meta": {"chamber": "A", "z_rollers_mm": 12.0}}))
    assert ex.metadata == {"backpressure_bar": 2.5, "hose_id": 7, "ok": 1, "operator": "ab", "chamber": "A",
                           "z_rollers_mm": 12}


def test_mat_matrices_cells_and_other_structs_are_skipped_with_a_warning(tmp_path):
    ex = read_export(mat_v5(tmp_path / "a.mat", {"t": T, "M": np.ones((4, 4)), "data": {"x": T},
                                                 "z": np.array([1 + 2j, 3j])}))
    assert [c.name for c in ex.columns] == ["t"]
    assert ex.warnings == ["variable `M` (4 x 4 matrix) ignored",
                           "struct `data` ignored (only `meta` and `units` structs are read)",
                           "variable `z` (complex) ignored"]


def test_mat_integer_and_logical_vectors_are_channels(tmp_path):
    ex = read_export(mat_v5(tmp_path / "a.mat", {"t": T, "count": np.arange(4, dtype=np.int16),
                                                 "valve": np.array([True, False, True, True])}))
    assert values(ex) == {"t": T.tolist(), "count": [0.0, 1.0, 2.0, 3.0], "valve": [1.0, 0.0, 1.0, 1.0]}


def test_mat_without_channels_is_refused(tmp_path):
    with pytest.raises(ReaderError, match="no channel"):
        read_export(mat_v5(tmp_path / "a.mat", {"a": 1.0, "meta": {"kind": "step"}}))


def test_mat_not_a_mat_file_is_refused(tmp_path):
    path = tmp_path / "a.mat"
    path.write_bytes(b"this is not MATLAB data at all" * 10)
    with pytest.raises(ReaderError, match=r"^not a MAT file \(no MAT v5/v7 header or HDF5 signature"):
        read_export(path)


def test_mat_canonical_channel_without_unit_is_quarantined(raw, warehouse):
    (raw.root / "c").mkdir(parents=True)
    mat_v5(raw.root / "c" / "a.mat", {"t": T, "x": T, "x_ref": T, "meta": META, "units": {"t": "s", "x": "m"}})
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.mat", warehouse)
    assert res.run is None and "no unit for channel `x_ref`" in res.error


def test_mat_timetable_is_quarantined_with_one_line(raw, warehouse):
    (raw.root / "c").mkdir(parents=True)
    mat_v5_with_object(raw.root / "c" / "a.mat")
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.mat", warehouse)
    assert res.run is None and res.error.startswith("MATLAB timetable object `tt`") and "-v7" in res.error


@pytest.mark.parametrize("version", ["v5", "v7", "v7.3"])
def test_mat_value_exact_round_trip_through_ingest(raw, warehouse, version):
    (raw.root / "c").mkdir(parents=True)
    variables = {"t": np.array([0.0, 1.0, 2.0]), "x": np.array([1.5, 2.5, -3.0]), "x_ref": np.array([10.0, 20.0, 30.0]),
                 "p_a": np.array([1.0, 2.0, 3.0]), "meta": {**META, "p_atm_pa": 100000.0},
                 "units": {"t": "ms", "x": "mm", "x_ref": "um", "p_a": "bar(a)"}}
    path = raw.root / "c" / "a.mat"
    if version == "v7.3":
        mat_v73(path, variables)
    else:
        mat_v5(path, variables, compress=version == "v7")
    res = ingest_file(RawTree(raw.root), path, warehouse)
    assert res.error is None, res.error
    out = pq.read_table(warehouse / res.run["samples_path"])
    assert out.column("t_s").to_pylist() == [0.0, 0.001, 0.002]
    assert out.column("x_m").to_pylist() == [1.5e-3, 2.5e-3, -3.0e-3]
    assert out.column("x_ref_m").to_pylist() == [1e-5, 2e-5, 3e-5]
    assert out.column("p_a_pa").to_pylist() == [0.0, 100000.0, 200000.0]
    assert res.run["format"] == "mat" and res.run["params"]["rig"] == "plpa-1"


# -- resource limits of MAT v7.3 (the v5 element walk: test_mat_elements.py) ---------------


def test_mat_v73_dataset_larger_than_the_file_can_hold_is_refused(tmp_path):
    """An HDF5 dataset of 2^34 doubles whose chunks were never written: a few KB on disk."""
    import h5py

    path = mat_v73(tmp_path / "a.mat", {"t": T, "meta": dict(META)})
    with h5py.File(path, "r+") as f:
        ds = f.create_dataset("x", shape=(1, 1 << 34), dtype="f8", chunks=(1, 1 << 16))
        ds.attrs["MATLAB_class"] = np.bytes_("double")
    with pytest.raises(ReaderError, match=r"^MAT v7.3 variable `x` declares 17179869184 x 1 values \(131072.0 MiB\) "
                                          r"in a file of 0.0 MiB: more than the limit of 64.0 MiB"):
        read_export(path)


def test_mat_v73_external_link_is_not_followed(tmp_path):
    import h5py

    other = mat_v73(tmp_path / "other.mat", {"x": np.array([1.0, 2.0, 3.0, 4.0])})
    path = mat_v73(tmp_path / "a.mat", {"t": T, "meta": dict(META)})
    with h5py.File(path, "r+") as f:
        f["x"] = h5py.ExternalLink(str(other), "/x")
    ex = read_export(path)
    assert [c.name for c in ex.columns] == ["t"]
    assert "variable `x` (an HDF5 link) ignored" in ex.warnings


# -- 2-D arrays and the time base ------------------------------------------------------------
P = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]])     # N x 2: samples down the rows


@pytest.mark.parametrize("writer", ["v5", "v73"])
@pytest.mark.parametrize("transpose", [False, True])
def test_mat_2d_array_is_k_channels(tmp_path, writer, transpose):
    data = P.T if transpose else P                                    # k x N works the same
    variables = {"t": T, "p": data, "units": {"t": "s", "p": "bar", "p_2": "kPa"}}
    path = (mat_v5 if writer == "v5" else mat_v73)(tmp_path / "a.mat", variables)
    ex = read_export(path)
    # (HDF5 lists variables by name: compare as a mapping)
    assert {c.name: c.unit for c in ex.columns} == {"t": "s", "p_1": "bar", "p_2": "kPa"}
    assert values(ex) == {"t": T.tolist(), "p_1": [1.0, 2.0, 3.0, 4.0], "p_2": [10.0, 20.0, 30.0, 40.0]}


def test_mat_wide_or_square_matrices_are_still_skipped(tmp_path):
    k = mat_module.MAX_MATRIX_CHANNELS + 1
    ex = read_export(mat_v5(tmp_path / "a.mat", {"t": T, "W": np.ones((k, k + 3)), "S": np.ones((3, 3))}))
    assert [c.name for c in ex.columns] == ["t"]
    assert any(f"`W` ({k} x {k + 3} matrix) ignored" in w for w in ex.warnings)
    assert any("`S` (3 x 3 matrix) ignored" in w for w in ex.warnings)


@pytest.mark.parametrize("writer", ["v5", "v73"])
def test_mat_fs_scalar_and_matrix_ingest_without_a_time_vector(raw, warehouse, writer):
    (raw.root / "c").mkdir(parents=True)
    xy = np.column_stack([np.arange(6.0), np.zeros(6)])              # x [mm], x_ref [mm]
    path = (mat_v5 if writer == "v5" else mat_v73)(raw.root / "c/a.mat",
                                                    {"pos": xy, "Fs": 20.0, "meta": dict(META),
                                                     "units": {"pos": "mm"}})
    raw.write("c/rig.toml", '[channels.pos_1]\nchannel = "x"\n[channels.pos_2]\nchannel = "x_ref"\n')
    res = ingest_file(RawTree(raw.root), path, warehouse)
    assert res.error is None, res.error
    out = pq.read_table(warehouse / res.run["samples_path"])
    assert out.column("t_s").to_pylist() == [0.0, 0.05, 0.1, 0.15, 0.2, 0.25]
    assert out.column("x_m").to_pylist() == [0.0, 0.001, 0.002, 0.003, 0.004, 0.005]
    assert res.run["params"]["Fs"] == 20


def test_mat_bad_fs_is_quarantined(raw, warehouse):
    (raw.root / "c").mkdir(parents=True)
    path = mat_v5(raw.root / "c/a.mat", {"x": T, "x_ref": T, "Fs": -1.0, "meta": dict(META),
                                         "units": {"x": "m", "x_ref": "m"}})
    res = ingest_file(RawTree(raw.root), path, warehouse)
    assert res.run is None and "MAT scalar `Fs` must be a positive finite number" in res.error


def test_mat_v73_data_kept_in_another_file_is_refused_not_read(tmp_path):
    """HDF5 lets a dataset keep its bytes in any other file (external storage) or map them from
    other HDF5 files (a virtual dataset): h5py would read that file by name, wherever it is (a
    file outside raw/). Such a variable is refused with one line; a plain v7.3 file beside it reads."""
    import h5py

    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"SECRET-EXTERNAL-DATA-0123456789abcdef")
    t = np.arange(4) * 0.1
    plain = mat_v73(tmp_path / "plain.mat", {"t": t, "x": t * 2})
    assert read_export(plain).columns[1].name == "x"
    ext = mat_v73(tmp_path / "external.mat", {"t": t})
    with h5py.File(ext, "a") as f:
        f.create_dataset("x", shape=(1, 4), dtype="<f8", external=[(str(secret), 0, 32)])
        f["x"].attrs["MATLAB_class"] = np.bytes_("double")
    with pytest.raises(ReaderError, match=r"^variable `x` keeps its data "
                                          r"in another file \(HDF5 external storage\): not read$"):
        read_export(ext)
    virt = mat_v73(tmp_path / "virtual.mat", {"t": t})
    layout = h5py.VirtualLayout(shape=(1, 4), dtype="<f8")
    layout[0, :] = h5py.VirtualSource(str(plain), "x", shape=(1, 4))[0, :]
    with h5py.File(virt, "a") as f:
        f.create_virtual_dataset("x", layout)
        f["x"].attrs["MATLAB_class"] = np.bytes_("double")
    with pytest.raises(ReaderError, match=r"variable `x` keeps its data in another file \(HDF5 virtual dataset\)"):
        read_export(virt)
