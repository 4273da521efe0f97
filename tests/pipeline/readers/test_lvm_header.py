"""The text and headers of LVM files (pipeline/readers/lvm_header.py): the scanner, the file
header (separator, decimal mark, X_Columns, Description, Date / Time), special blocks, segment
headers and column rows, and their refusals."""
import pytest

from pipeline.readers import ReaderError, read_export
from pipeline.readers.base import MAX_CHANNELS, MAX_LINE_BYTES
from pipeline.readers.lvm_header import Scanner, parse_description, started_at
from tests.pipeline.readers.generators import LvmSegment, lvm_bytes
from tests.pipeline.readers.test_lvm import STEP, col, open_lvm, seg, table


def test_scanner_lines_across_chunks_that_cut_them(tmp_path):
    path = tmp_path / "a.lvm"
    path.write_bytes(b"head\r\nChannels\t2\n1\t2\nX_Value\tx\n5\t6")   # no line end at the end
    sc = Scanner(path, chunk=4)
    try:
        assert sc.peekline() == "head" and sc.readline() == "head" and sc.lineno == 2
        assert [sc.readline() for _ in range(5)] == ["Channels\t2", "1\t2", "X_Value\tx", "5\t6", None]
        assert sc.encoding == "utf-8"
    finally:
        sc.close()


def test_scanner_data_block_runs_to_the_next_header_line(tmp_path):
    path = tmp_path / "a.lvm"
    path.write_bytes(b"Channels\t2\n1\t2\nnan\t4\nX_Value\tx\n5\t6\n")
    sc = Scanner(path, chunk=1 << 10)
    try:
        assert sc.readline() == "Channels\t2"
        assert sc.data_block() == ("1\t2\nnan\t4\n", 2)      # NaN starts a data line, not a header
        assert sc.data_block() == ("", 4)                    # a header line next
        assert sc.readline() == "X_Value\tx"
        assert sc.data_block() == ("5\t6\n", 5)
        assert sc.data_block() is None
    finally:
        sc.close()


def test_scanner_reads_latin1_when_a_chunk_is_not_utf8(tmp_path):
    path = tmp_path / "a.lvm"
    path.write_bytes("x\nDruck \u00c4\n".encode("latin-1"))
    sc = Scanner(path, chunk=1 << 10)
    try:
        assert [sc.readline(), sc.readline(), sc.readline()] == ["x", "Druck \u00c4", None]
        assert sc.encoding == "latin-1"
    finally:
        sc.close()


def test_parse_description_pairs_and_free_text():
    assert parse_description("kind=step; rig = plpa-1\nfree;=x; more") == {
        "kind": "step", "rig": "plpa-1", "description": "free; =x; more"}


@pytest.mark.parametrize("date, time, expected", [
    ("2026/01/02", "03:04:05.25", "2026-01-02T03:04:05.25"),
    ("2025-11-9", "15:49:25.1711249351501464844", "2025-11-09T15:49:25.171124"),   # microseconds kept
    ("2026.1.2", "3:04", "2026-01-02T03:04:00"),
    ("02/01/2026", "03:04:05", None),                                               # not year first
    ("2026/01/02", "", None),
])
def test_started_at_from_date_and_time(date, time, expected):
    assert started_at(date, time) == expected


def test_lvm_latin1_labels(tmp_path):
    s = seg(n=2, channels={"Druck Kammer Ä": [1.0, 2.0], "x": [3.0, 4.0]}, units={"Druck Kammer Ä": "bar", "x": "µm"})
    ex = open_lvm(tmp_path, lvm_bytes([s], description="notes=Prüfung", encoding="latin-1"))
    assert {c.name: c.unit for c in ex.columns} == {"t": "s", "Druck Kammer Ä": "bar", "x": "µm"}
    assert ex.metadata["notes"] == "Prüfung"
    assert col(ex, "x") == [3.0, 4.0]


def test_lvm_description_metadata(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg()], description="kind=breakaway; direction=P;backpressure_bar = 2.5; "
                                                            "started_at=2026-03-04T05:06:07; free text"))
    assert ex.metadata == {"kind": "breakaway", "direction": "P", "backpressure_bar": "2.5",
                           "started_at": "2026-03-04T05:06:07", "description": "free text"}


def test_lvm_started_at_from_header_date_and_time(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg()], description="kind=step", date="2025/11/09",
                                      time="15:49:25.1711249351501464844"))
    assert ex.metadata["started_at"] == "2025-11-09T15:49:25.171124"


def test_lvm_quoted_multiline_description(tmp_path):
    ex = open_lvm(tmp_path, lvm_bytes([seg()], description="kind=step\nrig=plpa-2;operator=ab"))
    assert (ex.metadata["kind"], ex.metadata["rig"], ex.metadata["operator"]) == ("step", "plpa-2", "ab")
    assert col(ex, "x") == [0.0, 1.0, 2.0, 3.0]


def test_lvm_special_blocks_are_skipped(tmp_path):
    special = b"***Start_Special***\r\nanything\tgoes 1.0\r\n3\t4\r\n***End_Special***\r\n"
    data = lvm_bytes([seg(n=2), seg(n=2)], x_columns="No", description=STEP)
    data = data.replace(b"Date\t", special + b"Date\t", 1)            # in the file header
    data = data.replace(b"\r\n\t\r\nChannels", b"\r\n" + special + b"Channels")   # between segments
    ex = open_lvm(tmp_path, data)
    assert ex.metadata["kind"] == "step"
    assert col(ex, "x") == [0.0, 1.0, 0.0, 1.0]


def test_lvm_not_a_labview_file_is_refused(tmp_path):
    path = tmp_path / "x.lvm"
    path.write_bytes(b"LabVIEW Measurement\t\nSeparator\tTab\n")
    with pytest.raises(ReaderError, match=r"file header has no \*\*\*End_of_Header\*\*\* line"):
        read_export(path)


def test_lvm_unknown_separator_is_refused(tmp_path):
    data = lvm_bytes([seg()], x_columns="No").replace(b"Separator\tTab", b"Separator\tSemicolon", 1)
    with pytest.raises(ReaderError, match=r"^Separator 'Semicolon' is not Tab or Comma$"):
        open_lvm(tmp_path, data)


def test_lvm_unknown_decimal_separator_is_refused(tmp_path):
    data = lvm_bytes([seg()], x_columns="No").replace(b"Decimal_Separator\t.", b"Decimal_Separator\t;", 1)
    with pytest.raises(ReaderError, match=r"^Decimal_Separator ';' is not '\.' or ','$"):
        open_lvm(tmp_path, data)


def test_lvm_decimal_comma_with_comma_separator_is_refused(tmp_path):
    s = LvmSegment({"x": [1.5, 2.5], "p_a": [0.5, 1.0]}, units={"x": "mm", "p_a": "bar"}, dt=1.0)
    data = lvm_bytes([s], x_columns="One", separator="Comma", decimal=",")
    assert b"Decimal_Separator,,\r\n" in data and b"\r\n0,0,1,5,0,5\r\n" in data   # ambiguous rows
    # Today the file opens and reads x = [0.0, 0.0], p_a = [1.0, 2.0] (fields shifted by the decimal commas).
    with pytest.raises(ReaderError, match=r"^Decimal_Separator ',' with Separator Comma cannot be parsed$"):
        table(open_lvm(tmp_path, data))


def test_lvm_unknown_x_columns_is_refused(tmp_path):
    data = lvm_bytes([seg()], x_columns="No").replace(b"X_Columns\tNo", b"X_Columns\tSome", 1)
    with pytest.raises(ReaderError, match=r"^X_Columns 'Some' is not No, One or Multi$"):
        open_lvm(tmp_path, data)


def test_lvm_second_file_header_in_the_middle_is_refused_naming_the_line(tmp_path):
    # Two exports concatenated (copy /b a.lvm + b.lvm): 26 lines, a blank line, then line 28.
    one = lvm_bytes([seg(n=2)], x_columns="No", description=STEP)
    assert one.count(b"\r\n") == 26
    ex = open_lvm(tmp_path, one + b"\r\n" + one)
    with pytest.raises(ReaderError, match=r"^line 28: a second file header \(files concatenated\?\)$"):
        table(ex)


@pytest.mark.parametrize("segment, line", [(1, 23), (2, 36)], ids=["first-segment", "later-segment"])
def test_lvm_segment_header_without_column_row_is_refused_naming_the_line(tmp_path, segment, line):
    data = lvm_bytes([seg(n=2), seg(n=2)], x_columns="No")
    start = -1
    for _ in range(segment):                           # drop the X_Value ... Comment row of that segment
        start = data.index(b"X_Value", start + 1)
    data = data[:start] + data[data.index(b"\r\n", start) + 2:]
    assert data.split(b"\r\n")[line - 2].startswith(b"***End_of_Header***")   # line = first data row
    message = rf"^line {line}: segment header of segment {segment} has no column row$"
    with pytest.raises(ReaderError, match=message):
        table(open_lvm(tmp_path, data))


def test_lvm_column_row_with_more_columns_than_the_limit_is_refused(tmp_path):
    channels = {f"ch{i}": [0.0, 1.0] for i in range(MAX_CHANNELS + 1)}
    data = lvm_bytes([LvmSegment(channels)], x_columns="No")
    with pytest.raises(ReaderError, match=rf"column row has {MAX_CHANNELS + 3} columns: more than the limit of "
                                          rf"{MAX_CHANNELS} channels per file"):
        open_lvm(tmp_path, data)


def test_lvm_line_without_end_longer_than_the_limit_is_refused(tmp_path):
    data = lvm_bytes([seg(n=2)], x_columns="No") + b"\r\n" + b"1" * (MAX_LINE_BYTES + (9 << 20))
    ex = open_lvm(tmp_path, data)
    with pytest.raises(ReaderError, match=r"^a line longer than 16 MiB \(no line break from byte \d+\): "
                                          r"not an LVM text file$"):
        table(ex)
