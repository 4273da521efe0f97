"""CSV data parsed in parallel blocks cut at line ends (the ingest benchmark's speed-up).

Blocks are made tiny so every edge case crosses block boundaries.
"""
import pyarrow as pa
import pytest

from pipeline.readers import ReaderError, read_export
from pipeline.readers import csv as csv_module


@pytest.fixture(autouse=True)
def tiny_blocks(monkeypatch):
    monkeypatch.setattr(csv_module, "BLOCK_BYTES", 64)


def columns(tmp_path, data: bytes) -> list[list]:
    path = tmp_path / "run.csv"
    path.write_bytes(data)
    export = read_export(path)
    table = pa.Table.from_batches(list(export.batches()))
    return [table.column(c.key).to_pylist() for c in export.columns]


def test_csv_blocks_keep_every_row_in_order(tmp_path):
    n = 500
    data = "# kind: step\n# rig: plpa-1\nt[s],x[mm]\n" + "".join(f"{i / 8},{i * 3}\n" for i in range(n))
    t, x = columns(tmp_path, data.encode())
    assert t == [i / 8 for i in range(n)] and x == [float(i * 3) for i in range(n)]


def test_csv_blocks_line_longer_than_a_block(tmp_path):
    long = "y" * 300
    t, note = columns(tmp_path, f"t[s],note\n0,a\n1,{long}\n2,b\n".encode())
    assert t == [0.0, 1.0, 2.0] and note == ["a", long, "b"]


def test_csv_blocks_last_line_without_newline_and_blank_lines(tmp_path):
    body = "".join(f"{i},{i}\n" for i in range(40)) + "\n\n" + "40,40"
    t, x = columns(tmp_path, ("t[s],x[mm]\n" + body).encode())
    assert t == [float(i) for i in range(41)] and x == t


def test_csv_blocks_crlf(tmp_path):
    t, x = columns(tmp_path, ("t[s],x[mm]\r\n" + "".join(f"{i},{-i}\r\n" for i in range(60))).encode())
    assert x == [float(-i) for i in range(60)]


def test_csv_blocks_bom_headerless_first_line_is_data(tmp_path):
    path = tmp_path / "run.csv"
    path.write_bytes(b"\xef\xbb\xbf" + "".join(f"{i},{i}\n" for i in range(30)).encode())
    export = read_export(path, {"header": False})
    table = pa.Table.from_batches(list(export.batches()))
    assert table.column("c1").to_pylist() == [float(i) for i in range(30)]


def test_csv_lone_cr_line_ends_use_the_incremental_reader(tmp_path):
    t, x = columns(tmp_path, ("t[s],x[mm]\r" + "".join(f"{i},{i}\r" for i in range(50))).encode())
    assert t == [float(i) for i in range(50)]


def test_csv_blocks_bad_value_in_a_late_block_names_its_line(tmp_path):
    lines = ["t[s],x[mm]"] + [f"{i},{i}" for i in range(300)]
    lines[250] = "249,oops"
    path = tmp_path / "run.csv"
    path.write_text("\n".join(lines) + "\n")
    export = read_export(path)
    export.columns[1].dtype = "float"
    with pytest.raises(ReaderError, match="line 251"):
        list(export.batches())
