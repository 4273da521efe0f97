"""TDMS reader: one named scenario per edge case, files built by generators (no binaries).

Most files are written with ``nptdms.TdmsWriter``; the cases the writer cannot produce (DAQmx
raw data, interleaved data, a segment a crash left unfinished) are built byte by byte with
:class:`Segment`, after the TDMS file format description (and npTDMS' own test generators).
"""
from __future__ import annotations

import re
import struct

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

import pipeline.readers.tdms as tdms_reader
from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from pipeline.readers import ReaderError, read_export
from pipeline.readers.tdms import read_tdms
from schemas.units import lookup_unit

STEP = {"kind": "step", "started_at": "2026-01-02T03:04:05", "rig": "plpa-1"}
TIMESERIES = {**STEP, "kind": "timeseries"}
N = 50
T = np.arange(N) * 2e-4
X_MM = np.linspace(0.0, 20.0, N)
XREF_MM = np.full(N, 20.0)


# -- generators ----------------------------------------------------------------------------
def write_tdms(path, root: dict, groups: dict[str, dict[str, tuple]], segments: int = 1):
    """Write a TDMS file: ``groups = {group: {channel: (values, properties)}}``.

    ``segments > 1`` splits every channel into that many consecutive segments, the way a
    logging loop writes them.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with TdmsWriter(str(path)) as writer:
        for s in range(segments):
            objects = [RootObject(root)] if s == 0 else []
            for g, channels in groups.items():
                objects.append(GroupObject(g))
                for name, (values, props) in channels.items():
                    part = np.array_split(np.asarray(values), segments)[s]
                    objects.append(ChannelObject(g, name, part, properties=props if s == 0 else {}))
            writer.write_segment(objects)
    return path


def step_channels(**extra) -> dict[str, tuple]:
    chans = {"t": (T, {"unit_string": "s"}), "x": (X_MM, {"unit_string": "mm"}),
             "x_ref": (XREF_MM, {"unit_string": "mm"})}
    chans.update(extra)
    return chans


def si(values, unit: str, p_atm_pa: float = 101325.0) -> list[float]:
    """Values converted the way the project converts them (schemas.units), as a list."""
    return lookup_unit(unit).to_si(np.asarray(values, dtype=np.float64), p_atm_pa).tolist()


def ingest(raw, rel, warehouse):
    return ingest_file(RawTree(raw.root), raw.root / rel, warehouse)


def samples(res, warehouse) -> pa.Table:
    assert res.error is None, res.error
    return pq.read_table(warehouse / res.run["samples_path"])


def quarantined(raw, rel, warehouse) -> str:
    res = ingest(raw, rel, warehouse)
    assert res.run is None, "expected the file to be quarantined"
    assert "\n" not in res.error
    return res.error


_TOC = {"meta": 1 << 1, "raw": 1 << 3, "new_obj_list": 1 << 2, "interleaved": 1 << 5, "daqmx": 1 << 7}
_TYPES = {"i16": 2, "i32": 3, "u32": 7, "f64": 10, "str": 0x20}


def _string(text: str) -> bytes:
    b = text.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _properties(props: dict) -> bytes:
    out = struct.pack("<I", len(props))
    for name, value in props.items():
        out += _string(name)
        if isinstance(value, str):
            out += struct.pack("<I", _TYPES["str"]) + _string(value)
        elif isinstance(value, int):
            out += struct.pack("<Ii", _TYPES["i32"], value)
        else:
            out += struct.pack("<Id", _TYPES["f64"], float(value))
    return out


class Segment:
    """Bytes of one TDMS segment: lead-in, metadata (objects) and raw data."""

    def __init__(self, toc=("meta", "raw", "new_obj_list")):
        self.toc = toc
        self.objects: list[bytes] = []

    def root(self, props=None):
        self.objects.append(_string("/") + struct.pack("<I", 0xFFFFFFFF) + _properties(props or {}))
        return self

    def group(self, name, props=None):
        self.objects.append(_string(f"/'{name}'") + struct.pack("<I", 0xFFFFFFFF) + _properties(props or {}))
        return self

    def channel(self, group, name, dtype, n, props=None):
        index = struct.pack("<IIIQ", 20, _TYPES[dtype], 1, n)
        self.objects.append(_string(f"/'{group}'/'{name}'") + index + _properties(props or {}))
        return self

    def daqmx_channel(self, group, name, n, raw_type, byte_offset, width, props=None):
        """A DAQmx 'format changing scaler' channel: one scaler reading ``raw_type`` at ``byte_offset``."""
        index = struct.pack("<IIIQ", 0x1269, 0xFFFFFFFF, 1, n)
        index += struct.pack("<I", 1) + struct.pack("<IIIII", raw_type, 0, byte_offset, 0, 0)
        index += struct.pack("<II", 1, width)
        self.objects.append(_string(f"/'{group}'/'{name}'") + index + _properties(props or {}))
        return self

    def bytes(self, data: bytes, unfinished: bool = False) -> bytes:
        mask = 0
        for flag in self.toc:
            mask |= _TOC[flag]
        meta = struct.pack("<I", len(self.objects)) + b"".join(self.objects)
        next_offset = 0xFFFFFFFFFFFFFFFF if unfinished else len(meta) + len(data)
        return b"TDSm" + struct.pack("<iiQQ", mask, 4713, next_offset, len(meta)) + meta + data


# -- scenarios -----------------------------------------------------------------------------
def test_tdms_value_exact_round_trip(raw, warehouse):
    """Expected SI values worked out by hand (not with schemas.units): exact in float64."""
    chans = {"t": ([0.0, 2e-4, 4e-4, 6e-4], "s"),
             "x": ([0.0, 12.5, -2.5, 20.0], "mm"),
             "x_ref": ([20.0, 20.0, 0.5, 0.0], "mm"),
             "p_a": ([1.0, 1.5, 2.25, 6.0], "bar(a)"),      # absolute, p_atm_pa = 100000
             "p_b": ([0.0, 1.5, 0.25, 10.0], "bar")}        # gauge
    write_tdms(raw.root / "c/a.tdms", {**STEP, "p_atm_pa": 100000.0},
               {"Data": {k: (np.array(v), {"unit_string": u}) for k, (v, u) in chans.items()}})
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert table.column("t_s").to_pylist() == [0.0, 0.0002, 0.0004, 0.0006]
    assert table.column("x_m").to_pylist() == [0.0, 0.0125, -0.0025, 0.02]
    assert table.column("x_ref_m").to_pylist() == [0.02, 0.02, 0.0005, 0.0]
    assert table.column("p_a_pa").to_pylist() == [0.0, 50000.0, 125000.0, 500000.0]
    assert table.column("p_b_pa").to_pylist() == [0.0, 150000.0, 25000.0, 1000000.0]
    assert res.run["format"] == "tdms" and res.run["n_samples"] == 4
    assert res.run["sample_rate_hz"] == pytest.approx(5000.0)
    assert res.run["warnings"] == []


def test_tdms_root_properties_are_metadata(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms",
               {**STEP, "operator": "ana", "Bench Firmware": "v2", "n_cycles": np.int32(7),
                "calibrated_at": np.datetime64("2025-12-24T10:00:00.5")},
               {"Data": step_channels()})
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    assert export.metadata["kind"] == "step" and export.metadata["n_cycles"] == 7
    assert export.metadata["calibrated_at"] == "2025-12-24T10:00:00.500000+00:00"
    res = ingest(raw, "c/a.tdms", warehouse)
    params = res.run["params"]
    assert (params["operator"], params["Bench Firmware"], params["n_cycles"]) == ("ana", "v2", 7)
    assert res.run["rig"] == "plpa-1" and res.run["started_at"] == "2026-01-02T03:04:05+00:00"


def test_tdms_manifest_overrides_root_properties(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", {**STEP, "operator": "file-op"}, {"Data": step_channels()})
    raw.write("c/manifest.csv", "file,operator\na.tdms,manifest-op\n")
    raw.write("c/rig.toml", '[metadata]\nrig = "from-rig"\nnotes = "rig-notes"\n')
    res = ingest(raw, "c/a.tdms", warehouse)
    p = res.run["params"]
    assert (p["operator"], p["rig"], p["notes"]) == ("manifest-op", "plpa-1", "rig-notes")


def test_tdms_unit_string(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP,
               {"Data": {"t": (T * 1e3, {"unit_string": "ms"}), "x": (X_MM * 1e3, {"unit_string": " um "}),
                         "x_ref": (XREF_MM, {"unit_string": "mm"}), "temp": (T, {"unit_string": "degC"})}})
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    assert [(c.name, c.unit) for c in export.columns] == [("t", "ms"), ("x", "um"), ("x_ref", "mm"), ("temp", "degC")]
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("x_m").to_pylist() == si(X_MM * 1e3, "um")
    assert table.column("t_s").to_pylist() == si(T * 1e3, "ms")
    assert table.schema.field("temp_degc").metadata[b"unit"] == b"degC"


def test_tdms_unit_in_channel_name_when_no_unit_string(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP,
               {"Data": {"t[s]": (T, {}), "x[mm]": (X_MM, {}), "x_ref": (XREF_MM, {"unit_string": "mm"})}})
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("x_m").to_pylist() == si(X_MM, "mm")


def test_tdms_missing_unit_is_quarantined(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels(x=(X_MM, {}))})
    assert "no unit for channel `x`" in quarantined(raw, "c/a.tdms", warehouse)


def test_tdms_waveform_timing(raw, warehouse):
    wf = {"unit_string": "mm", "wf_increment": 0.001, "wf_start_offset": 0.5,
          "wf_start_time": np.datetime64("2026-03-04T05:06:07.250")}
    meta = {k: v for k, v in STEP.items() if k != "started_at"}
    write_tdms(raw.root / "c/a.tdms", meta, {"Data": {"x": (X_MM, wf), "x_ref": (XREF_MM, wf)}})
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    assert (export.columns[-1].name, export.columns[-1].unit) == ("t", "s")
    assert export.metadata["started_at"] == "2026-03-04T05:06:07.250000+00:00"
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert table.column("t_s").to_pylist() == (0.5 + np.arange(N, dtype=np.float64) * 0.001).tolist()
    assert res.run["sample_rate_hz"] == pytest.approx(1000.0)
    assert res.run["started_at"] == "2026-03-04T05:06:07.250000+00:00"


def test_tdms_root_started_at_beats_wf_start_time(raw, warehouse):
    wf = {"unit_string": "mm", "wf_increment": 0.001, "wf_start_time": np.datetime64("2026-03-04T05:06:07")}
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": {"x": (X_MM, wf), "x_ref": (XREF_MM, wf)}})
    assert read_tdms(raw.root / "c/a.tdms", {}, {}).metadata["started_at"] == STEP["started_at"]


def test_tdms_wf_start_time_at_labview_epoch_is_no_time(raw):
    wf = {"unit_string": "mm", "wf_increment": 0.001, "wf_start_time": np.datetime64("1904-01-01T00:00:00")}
    write_tdms(raw.root / "c/a.tdms", {"kind": "step"}, {"Data": {"x": (X_MM, wf)}})
    assert "started_at" not in read_tdms(raw.root / "c/a.tdms", {}, {}).metadata


def test_tdms_time_channel_wins(raw, warehouse):
    wf = {"unit_string": "mm", "wf_increment": 0.001, "wf_start_offset": 0.0}
    write_tdms(raw.root / "c/a.tdms", STEP,
               {"Data": {"x": (X_MM, wf), "x_ref": (XREF_MM, wf), "t": (T, {"unit_string": "s"})}})
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    assert [c.name for c in export.columns] == ["x", "x_ref", "t"]
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == T.tolist()


def test_tdms_timestamp_time_channel_is_seconds_since_first(raw, warehouse):
    t0 = np.datetime64("2026-05-06T07:08:09", "us")
    stamps = t0 + (np.arange(N) * 200).astype("timedelta64[us]")
    meta = {k: v for k, v in STEP.items() if k != "started_at"}
    write_tdms(raw.root / "c/a.tdms", meta, {"Data": step_channels(t=(stamps, {}))})
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert table.column("t_s").to_pylist() == (np.arange(N) * 200 / 1e6).tolist()
    assert res.run["started_at"] == "2026-05-06T07:08:09+00:00"


def test_tdms_group_key_selects_group(raw, warehouse):
    other = {"t": (T, {"unit_string": "s"}), "x": (X_MM + 1, {"unit_string": "mm"})}
    groups = {"Setup": other, "Measurement": step_channels()}
    write_tdms(raw.root / "c/a.tdms", STEP, groups)
    write_tdms(raw.root / "c/b.tdms", {**STEP, "group": "Measurement"}, groups)
    raw.write("c/manifest.csv", "file,group\na.tdms,Measurement\n")
    for rel in ("c/a.tdms", "c/b.tdms"):  # from the manifest; from a root property
        table = samples(ingest(raw, rel, warehouse), warehouse)
        assert table.column("x_m").to_pylist() == si(X_MM, "mm")
    raw.write("d/rig.toml", '[metadata]\ngroup = "measurement"\n')  # rig.toml; case-insensitive
    write_tdms(raw.root / "d/a.tdms", STEP, groups)
    assert samples(ingest(raw, "d/a.tdms", warehouse), warehouse).num_rows == N


def test_tdms_several_groups_without_group_key(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Setup": step_channels(), "Measurement": step_channels()})
    error = quarantined(raw, "c/a.tdms", warehouse)
    assert "several groups (`Setup`, `Measurement`)" in error and "`group`" in error


def test_tdms_group_key_names_missing_group(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Setup": step_channels(), "Measurement": step_channels()})
    raw.write("c/manifest.csv", "file,group\na.tdms,Messung\n")
    error = quarantined(raw, "c/a.tdms", warehouse)
    assert "group `Messung`" in error and "not found" in error and "`Setup`, `Measurement`" in error


def test_tdms_rig_toml_renames_channels(raw, warehouse):
    raw.write("c/rig.toml", '[channels."Druck A"]\nchannel = "p_a"\nunit = "bar"\n'
                            '[channels."Weg"]\nchannel = "x"\n')
    write_tdms(raw.root / "c/a.tdms", STEP,
               {"Data": {"t": (T, {"unit_string": "s"}), "Weg": (X_MM, {"unit_string": "mm"}),
                         "x_ref": (XREF_MM, {"unit_string": "mm"}), "Druck A": (X_MM, {})}})
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("x_m").to_pylist() == si(X_MM, "mm")
    assert table.column("p_a_pa").to_pylist() == si(X_MM, "bar")


def test_tdms_integer_and_float32_channels_are_numbers(raw, warehouse):
    counts = np.arange(N, dtype=np.int16) - 10
    x32 = X_MM.astype(np.float32)
    write_tdms(raw.root / "c/a.tdms", STEP,
               {"Data": step_channels(x=(x32, {"unit_string": "mm"}), counts=(counts, {}))})
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("counts").to_pylist() == counts.astype(float).tolist()
    assert table.column("x_m").to_pylist() == si(x32.astype(np.float64), "mm")


def test_tdms_daqmx_scaled(raw, warehouse):
    """Two DAQmx int16 channels in one raw buffer (4 bytes per sample), linear scales to bar."""
    n = 6
    raw_a = np.array([0, 1000, 2000, -500, 32767, -32768], dtype=np.int16)
    raw_b = np.array([5, 6, 7, 8, 9, 10], dtype=np.int16)

    def scaling(slope, intercept, unit):
        return {"NI_Number_Of_Scales": 2, "NI_Scale[1]_Scale_Type": "Linear",
                "NI_Scale[1]_Linear_Slope": slope, "NI_Scale[1]_Linear_Y_Intercept": intercept,
                "NI_Scale[1]_Linear_Input_Source": 0, "unit_string": unit,
                "wf_increment": 2e-4, "wf_start_offset": 0.0}

    seg = (Segment(("meta", "raw", "new_obj_list", "daqmx")).root(TIMESERIES).group("Dev1")
           .daqmx_channel("Dev1", "p_a", n, raw_type=3, byte_offset=0, width=4, props=scaling(0.001, 0.5, "bar"))
           .daqmx_channel("Dev1", "p_b", n, raw_type=3, byte_offset=2, width=4, props=scaling(0.002, -1.0, "bar")))
    data = np.column_stack([raw_a, raw_b]).astype("<i2").tobytes()
    raw.write("c/a.tdms", seg.bytes(data))
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    assert [c.name for c in export.columns] == ["p_a", "p_b", "t"]
    batch = next(export.batches())
    assert batch.column("c1").to_pylist() == (raw_a * 0.001 + 0.5).tolist()
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("p_a_pa").to_pylist() == si(raw_a * 0.001 + 0.5, "bar")
    assert table.column("p_b_pa").to_pylist() == si(raw_b * 0.002 - 1.0, "bar")
    assert table.column("t_s").to_pylist() == (np.arange(n) * 2e-4).tolist()


def test_tdms_interleaved_data(raw, warehouse):
    seg = (Segment(("meta", "raw", "new_obj_list", "interleaved")).root(TIMESERIES).group("g")
           .channel("g", "t", "f64", 4, {"unit_string": "s"}).channel("g", "x", "f64", 4, {"unit_string": "mm"}))
    data = np.column_stack([np.arange(4) * 0.1, [1.0, 2.0, 3.0, 4.0]]).astype("<f8").tobytes()
    raw.write("c/a.tdms", seg.bytes(data))
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("x_m").to_pylist() == si(np.array([1.0, 2.0, 3.0, 4.0]), "mm")


def test_tdms_multiple_segments(raw, warehouse, monkeypatch):
    """Segments of a logging loop are concatenated; batches cross segment boundaries."""
    monkeypatch.setattr(tdms_reader, "BATCH_ROWS", 7)
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels()}, segments=10)  # 5 rows each
    export = read_tdms(raw.root / "c/a.tdms", {}, {})
    sizes = [b.num_rows for b in export.batches()]
    assert sizes == [7] * 7 + [1]
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert table.column("t_s").to_pylist() == T.tolist()
    assert table.column("x_m").to_pylist() == si(X_MM, "mm")
    assert res.run["n_samples"] == N and res.run["warnings"] == []


def test_tdms_one_big_chunk_is_read_once_not_per_batch(raw, monkeypatch):
    """npTDMS reads whole chunks: a chunk larger than a batch sets the batch size."""
    monkeypatch.setattr(tdms_reader, "BATCH_ROWS", 7)
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels()}, segments=2)  # 25 rows each
    assert [b.num_rows for b in read_tdms(raw.root / "c/a.tdms", {}, {}).batches()] == [25, 25]


def test_tdms_truncated_final_segment_warns(raw, warehouse):
    """The bench crashed in the middle of the last segment's data: keep the complete samples."""
    path = write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels()}, segments=2)
    data = path.read_bytes()
    # Last segment: t, x, x_ref of 25 float64 each, contiguous. Cut inside x: t complete, x 10 values.
    path.write_bytes(data[: len(data) - 25 * 8 - 15 * 8 - 3])
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert res.run["n_samples"] == 25  # the first segment; x_ref has nothing in the last one
    assert table.column("x_m").to_pylist() == si(X_MM[:25], "mm")
    assert any("truncated" in w and "25 complete samples" in w for w in res.run["warnings"])


def test_tdms_truncated_interleaved_segment_keeps_complete_samples(raw, warehouse):
    """A crash mid-row of interleaved data: the partial row is dropped, the rest kept."""
    seg = (Segment(("meta", "raw", "new_obj_list", "interleaved")).root(TIMESERIES).group("g")
           .channel("g", "t", "f64", 4, {"unit_string": "s"}).channel("g", "x", "f64", 4, {"unit_string": "mm"}))
    data = np.column_stack([np.arange(4) * 0.1, [1.0, 2.0, 3.0, 4.0]]).astype("<f8").tobytes()
    later = np.column_stack([0.4 + np.arange(4) * 0.1, [1.0, 2.0, 3.0, 4.0]]).astype("<f8").tobytes()
    first = seg.bytes(data)
    second = Segment(("raw", "interleaved")).bytes(later, unfinished=True)  # same objects, crash: offset never written
    kept = len(second) - len(later) + 2 * 16 + 8 + 3  # 2 full rows, t of row 3, 3 bytes of its x
    raw.write("c/a.tdms", first + second[:kept])
    res = ingest(raw, "c/a.tdms", warehouse)
    table = samples(res, warehouse)
    assert table.column("x_m").to_pylist() == si(np.array([1.0, 2.0, 3.0, 4.0, 1.0, 2.0]), "mm")
    assert any("truncated" in w for w in res.run["warnings"])


def test_tdms_crash_before_segment_metadata_was_written(raw, warehouse):
    path = write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels()}, segments=1)
    complete = path.read_bytes()
    extra = Segment(("raw",)).bytes(b"\0" * 64, unfinished=True)[:20]  # a lead-in cut short
    path.write_bytes(complete + extra)
    res = ingest(raw, "c/a.tdms", warehouse)
    assert samples(res, warehouse).num_rows == N
    assert any("truncated" in w for w in res.run["warnings"])


def test_tdms_unequal_channel_lengths_in_an_intact_file(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels(x=(X_MM[:30], {"unit_string": "mm"}))})
    error = quarantined(raw, "c/a.tdms", warehouse)
    assert "different lengths" in error and "`x` 30" in error


def test_tdms_string_and_timestamp_channels_are_kept_as_text(raw, warehouse):
    status = np.array([f"s{i}" for i in range(N)])
    stamps = np.datetime64("2026-01-01T00:00:00", "us") + np.arange(N).astype("timedelta64[ms]")
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels(status=(status, {}), stamp=(stamps, {}))})
    table = samples(ingest(raw, "c/a.tdms", warehouse), warehouse)
    assert table.column("status").to_pylist() == status.tolist()
    assert table.column("stamp").to_pylist()[:2] == ["2026-01-01T00:00:00.000000+00:00",
                                                      "2026-01-01T00:00:00.001000+00:00"]
    assert table.schema.field("stamp").type == pa.string()


def test_tdms_complex_channel_is_skipped_with_warning(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels(z=(np.ones(N, dtype=np.complex128), {}))})
    res = ingest(raw, "c/a.tdms", warehouse)
    assert "z" not in samples(res, warehouse).column_names
    assert any("`z`" in w and "skipped" in w for w in res.run["warnings"])


def test_tdms_channel_without_data_is_an_empty_column(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": step_channels(spare=(np.array([], dtype=np.float64), {}))})
    res = ingest(raw, "c/a.tdms", warehouse)
    assert np.isnan(samples(res, warehouse).column("spare").to_numpy()).all()
    assert "channel `spare` is empty" in res.run["warnings"]


def test_tdms_not_a_tdms_file(raw, warehouse):
    raw.write("c/a.tdms", b"this is not TDMS at all, just text that a bench wrote\n" * 3)
    reason = quarantined(raw, "c/a.tdms", warehouse)
    assert reason.startswith("not a TDMS file (no TDSm lead-in; starts with b'this is ")


def test_tdms_empty_file_is_not_a_tdms_file(raw, warehouse):
    raw.write("c/a.tdms", b"")
    assert quarantined(raw, "c/a.tdms", warehouse) == "empty file (0 bytes)"  # said before any reader runs


def test_tdms_lead_in_with_unknown_version_is_not_a_tdms_file(raw, warehouse):
    raw.write("c/a.tdms", b"TDSm" + struct.pack("<IIqq", 0x0E, 9999, 0, 0) + b"\xff" * 60)
    assert quarantined(raw, "c/a.tdms", warehouse) == "not a TDMS file (lead-in version 9999, expected 4712 or 4713)"


def test_tdms_group_without_channels(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Empty": {}})
    with pytest.raises(ReaderError, match="no channels"):
        read_export(raw.root / "c/a.tdms")


def test_tdms_without_time_is_missing_channel_t(raw, warehouse):
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": {"x": (X_MM, {"unit_string": "mm"}),
                                                      "x_ref": (XREF_MM, {"unit_string": "mm"})}})
    assert "missing channel `t`" in quarantined(raw, "c/a.tdms", warehouse)


# -- refusals, one scenario each -------------------------------------------------------------
@pytest.mark.parametrize("increment, shown", [(0.0, "0.0"), (-0.001, "-0.001"), (float("nan"), "nan")],
                         ids=["zero", "negative", "nan"])
def test_tdms_waveform_increment_not_positive_is_quarantined(raw, warehouse, increment, shown):
    wf = {"unit_string": "mm", "wf_increment": increment, "wf_start_offset": 0.0}
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": {"x": (X_MM, wf), "x_ref": (XREF_MM, wf)}})
    assert quarantined(raw, "c/a.tdms", warehouse) == (
        f"TDMS waveform property wf_increment is not a positive number: {shown}")


def test_tdms_other_file_named_tdms_is_quarantined_with_what_it_starts_with(raw, warehouse):
    raw.write("c/a.tdms", b"PK\x03\x04" + b"\0" * 60)          # a zip archive renamed .tdms
    assert quarantined(raw, "c/a.tdms", warehouse) == (
        "not a TDMS file (no TDSm lead-in; starts with b'PK\\x03\\x04\\x00\\x00\\x00\\x00')")


def test_tdms_file_cut_inside_its_first_lead_in(raw, warehouse):
    """The bench crashed right after creating the file: nothing but 8 bytes of a lead-in."""
    raw.write("c/a.tdms", Segment().root(STEP).bytes(b"")[:8])
    assert quarantined(raw, "c/a.tdms", warehouse) == "TDMS file cut inside its first lead-in (8 of 28 bytes): no data"


def test_tdms_string_channel_with_corrupt_offsets_cannot_be_read(raw, warehouse):
    """Metadata intact, raw data garbled: npTDMS fails while reading, after the file opened."""
    seg = Segment().root(TIMESERIES).group("g").channel("g", "t", "f64", 2, {"unit_string": "s"})
    path = _string("/'g'/'s'")
    index = struct.pack("<IIIQQ", 28, _TYPES["str"], 1, 2, 16)   # 2 strings, 16 bytes of raw data
    seg.objects.append(path + index + struct.pack("<I", 0))
    t = struct.pack("<2d", 0.0, 0.1)
    data = t + struct.pack("<II", 999_999, 5) + b"abcdefgh"      # first end offset far past the data
    raw.write("c/a.tdms", seg.bytes(data))
    read_export(raw.root / "c/a.tdms")                            # opens: the failure is in the data
    assert quarantined(raw, "c/a.tdms", warehouse) == (
        "cannot read TDMS data: read length must be non-negative or -1")


def test_tdms_unknown_daqmx_raw_type_says_what_is_wrong(raw, warehouse):
    seg = (Segment(("meta", "raw", "new_obj_list", "daqmx")).root(TIMESERIES).group("g")
           .daqmx_channel("g", "x", 4, 0x77, 0, 2, {"unit_string": "V"}))
    raw.write("c/a.tdms", seg.bytes(b"\0" * 8))
    error = quarantined(raw, "c/a.tdms", warehouse)
    assert error.startswith("not a readable TDMS file: ")
    assert "KeyError" in error or "DAQmx" in error or "data type" in error, error


def test_tdms_group_with_more_channels_than_the_limit_is_refused(raw, warehouse):
    from pipeline.readers.base import MAX_CHANNELS

    n = MAX_CHANNELS + 1
    chans = {f"c{i}": (np.array([0.0, 1.0]), {"unit_string": "V"}) for i in range(n)}
    write_tdms(raw.root / "c/a.tdms", STEP, {"Data": chans})
    assert quarantined(raw, "c/a.tdms", warehouse) == (
        f"{n} channels in TDMS group `Data`: more than the limit of {MAX_CHANNELS} channels per file")


def test_tdms_string_length_beyond_the_file_is_refused_without_allocating_it(raw, warehouse):
    """A corrupt 32-bit length before an object path: npTDMS reads ``length`` bytes."""
    seg = Segment().root(STEP)
    seg.objects.append(struct.pack("<I", 0xFFFFFFF0) + b"/'Data'")
    raw.write("c/a.tdms", seg.bytes(b""))
    assert quarantined(raw, "c/a.tdms", warehouse) == (
        "not a readable TDMS file: its metadata is corrupt or cut short (a field runs past the end of the file)")


def test_tdms_bounded_reader_never_asks_for_more_than_the_file_holds(tmp_path):
    """A plain buffered read(1 TiB) allocates 1 TiB first (MemoryError); the bounded one returns the rest."""
    path = tmp_path / "a.tdms"
    path.write_bytes(b"TDSm" + bytes(60))
    with tdms_reader._BoundedReader(path) as fh:
        fh.seek(60)
        assert fh.read(1 << 40) == bytes(4)
        assert fh.read(1 << 40) == b""


def _sparse_tdms(path, n: int):
    """A TDMS file whose channels `t` and `x` declare ``n`` float64 values each, all in a hole:
    the metadata is written, the raw data never (``truncate`` extends the file with a hole)."""
    seg = (Segment().root(TIMESERIES).group("g").channel("g", "t", "f64", n, {"unit_string": "s"})
           .channel("g", "x", "f64", n, {"unit_string": "mm"}))
    head = seg.bytes(b"")
    meta_len = struct.unpack("<Q", head[20:28])[0]
    head = head[:12] + struct.pack("<Q", meta_len + 16 * n) + head[20:]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(head)
        fh.truncate(len(head) + 16 * n)
    st = path.stat()
    if st.st_blocks * 512 >= st.st_size:
        pytest.skip("this file system does not make sparse files")
    return path


def test_tdms_sparse_file_declaring_more_than_it_stores_is_refused(raw, warehouse):
    """4 KB stored, 256 MiB apparent: npTDMS would read 32 M zeros per channel from the hole."""
    path = _sparse_tdms(raw.root / "c/a.tdms", 16 << 20)
    assert re.fullmatch(r"TDMS channels of group `g` declare 256\.0 MiB of values but the file stores [\d,]+ bytes "
                        r"of its 256\.0 MiB \(a sparse file whose holes read as zeros\): more than the 64\.0 MiB "
                        r"it may declare", quarantined(raw, "c/a.tdms", warehouse))


def test_tdms_sparse_file_within_the_inflate_cap_is_read(raw):
    """A hole of 1.6 MB (zeros a copy tool left unwritten) is under the 64 MiB floor: read."""
    path = _sparse_tdms(raw.root / "c/a.tdms", 100_000)
    ex = read_export(path)
    assert sum(b.num_rows for b in ex.batches()) == 100_000


def test_tdms_stored_bytes_of_dense_and_sparse_files(tmp_path):
    dense = tmp_path / "d.bin"
    dense.write_bytes(b"\1" * 10_000)
    with open(dense, "rb") as fh:
        assert tdms_reader._stored_bytes(fh.fileno(), 10_000) == 10_000 and fh.tell() == 0
    sparse = tmp_path / "s.bin"
    with open(sparse, "wb") as fh:
        fh.write(b"\1" * 4096)
        fh.truncate(1 << 30)
    with open(sparse, "rb") as fh:
        assert 4096 <= tdms_reader._stored_bytes(fh.fileno(), 1 << 30) < 1 << 20
