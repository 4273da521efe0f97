"""The simulator's writers: each export read back by pneubench's own readers gives the raw values,
names, units and metadata written; the layout options are checked."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.readers import read_export
from pipeline.simulator.writers import (ColumnOut, CsvOptions, LvmOptions, TdmsOptions, default_columns, si_to_raw,
                                        write_csv, write_lvm, write_mat, write_mf4, write_tdms, write_xlsx)

T = np.arange(6) * 0.1
FRAME = pd.DataFrame({"t_s": T, "x_m": T * 0.01, "p_a_pa": np.full(6, 2e5)})
COLUMNS = default_columns(["x_m", "p_a_pa"], units={"x": "mm", "p_a": "bar(a)"})
META = {"kind": "step", "rig": "r1", "started_at": "2026-01-02T03:04:05"}
#: x in mm, p_a as absolute bar (2 bar gauge over the default atmosphere).
X_MM = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
P_BAR_ABS = 2.0 + 101325.0 / 1e5


def _read(path):
    """Name -> (unit, values) of every column, and the metadata, as the readers give them."""
    export = read_export(path)
    table = pd.concat([b.to_pandas() for b in export.batches()], ignore_index=True)
    return {c.name: (c.unit, table[c.key].to_numpy().tolist()) for c in export.columns}, export.metadata


def _check(columns):
    assert columns["t"][0] == "s" and columns["t"][1] == pytest.approx(T.tolist(), abs=1e-12)
    assert columns["x"] == ("mm", pytest.approx(X_MM, abs=1e-12))
    assert columns["p_a"] == ("bar(a)", pytest.approx([P_BAR_ABS] * 6, rel=1e-12))


@pytest.mark.parametrize("options", [{}, dict(delimiter=";", decimal=","), dict(delimiter="\t")])
def test_csv_round_trips_through_the_csv_reader(tmp_path, options):
    path = write_csv(tmp_path / "a.csv", FRAME, [ColumnOut("t_s", "t", "s")] + COLUMNS, META, **options)
    columns, meta = _read(path)
    _check(columns)
    assert {k: meta[k] for k in META} == META


def test_csv_in_chunks_writes_the_same_bytes_as_in_one_frame(tmp_path):
    cols = [ColumnOut("t_s", "t", "s")] + COLUMNS
    one = write_csv(tmp_path / "one.csv", FRAME, cols, META).read_bytes()
    chunks = write_csv(tmp_path / "chunks.csv", [FRAME.iloc[:2], FRAME.iloc[2:]], cols, META).read_bytes()
    assert one == chunks
    assert one.startswith(b"# kind: step\n# rig: r1\n# started_at: 2026-01-02T03:04:05\nt[s],x[mm],p_a[bar(a)]\n")


def test_csv_options_header_and_newline(tmp_path):
    path = write_csv(tmp_path / "a.txt", FRAME.iloc[:2], COLUMNS, None, header=False, newline="\r\n")
    assert path.read_bytes() == b"0,3.01325\r\n1,3.01325\r\n"


def test_csv_refuses_a_decimal_comma_with_comma_delimiter_and_unknown_options(tmp_path):
    with pytest.raises(ValueError, match="decimal comma"):
        write_csv(tmp_path / "a.csv", FRAME, COLUMNS, decimal=",")
    with pytest.raises(TypeError):
        write_csv(tmp_path / "a.csv", FRAME, COLUMNS, delimeter=";")
    assert CsvOptions() == CsvOptions(delimiter=",", decimal=".", header=True, newline="\n")


@pytest.mark.parametrize("options", [dict(segments=2), dict(x_columns="No", fs_hz=10.0)])
def test_lvm_round_trips_through_the_lvm_reader(tmp_path, options):
    path = write_lvm(tmp_path / "a.lvm", FRAME, COLUMNS, META, date="2026/01/02", time="03:04:05.000000", **options)
    columns, meta = _read(path)
    _check(columns)
    assert meta["kind"] == "step" and meta["rig"] == "r1"
    data = path.read_bytes()
    assert data.count(b"***End_of_Header***") == 1 + LvmOptions(**options).segments
    assert b"Date\t2026/01/02\r\n" in data and b"\n" not in data.replace(b"\r\n", b"")


@pytest.mark.parametrize("options", [{}, dict(waveform=True, fs_hz=10.0), dict(extra_group="Settings")])
def test_tdms_round_trips_through_the_tdms_reader(tmp_path, options):
    meta = {**META, "group": "Data"} if options.get("extra_group") else META
    path = write_tdms(tmp_path / "a.tdms", [FRAME.iloc[:3], FRAME.iloc[3:]], COLUMNS, meta, **options)
    columns, got = _read(path)
    _check(columns)
    assert got["kind"] == "step"
    assert TdmsOptions(**options).group == "Data"


@pytest.mark.parametrize("writer, ext", [(write_mat, "mat"), (write_xlsx, "xlsx"), (write_mf4, "mf4")])
def test_mat_xlsx_and_mf4_round_trip_and_repeat_their_bytes(tmp_path, writer, ext):
    cols = [ColumnOut("t_s", "t", "s")] + COLUMNS if ext == "xlsx" else COLUMNS
    a = writer(tmp_path / f"a.{ext}", FRAME, cols, META)
    columns, meta = _read(a)
    _check(columns)
    assert meta["kind"] == "step"
    b = writer(tmp_path / f"b.{ext}", FRAME, cols, META)
    assert a.read_bytes() == b.read_bytes()


def test_si_to_raw_inverts_the_units():
    assert si_to_raw([2e5], "bar(a)", p_atm_pa=1e5).tolist() == [3.0]
    assert si_to_raw([0.0015], "mm").tolist() == pytest.approx([1.5])
    with pytest.raises(ValueError, match="not an accepted unit"):
        si_to_raw([1.0], "furlong")


def test_default_columns_need_the_unit_of_a_non_canonical_column():
    assert default_columns(["temperature_degc"], {"temperature_degc": "degC"}, {"temperature_degc": "T"}) == [
        ColumnOut("temperature_degc", "T", "degC")]
    with pytest.raises(ValueError, match="not canonical"):
        default_columns(["temperature_degc"])
