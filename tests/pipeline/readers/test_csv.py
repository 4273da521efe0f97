"""CSV / TXT reader: one scenario per edge case of bench exports."""
import re

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from pipeline.readers import ReaderError, read_export
from pipeline.readers import csv as csv_module

META = "# kind: step\n# started_at: 2026-01-02T03:04:05\n# rig: plpa-1\n"


def open_csv(tmp_path, data, read=None, name="run.csv"):
    path = tmp_path / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
    return read_export(path, read or {})


def rows(export) -> dict:
    """Columns by raw name (unit appended when present), as Python lists."""
    table = pa.Table.from_batches(list(export.batches()))
    return {(f"{c.name}[{c.unit}]" if c.unit else c.name): table.column(c.key).to_pylist() for c in export.columns}


def ingest(raw, rel, warehouse):
    res = ingest_file(RawTree(raw.root), raw.root / rel, warehouse)
    assert res.error is None, res.error
    return res, pq.read_table(warehouse / res.run["samples_path"])


@pytest.mark.parametrize("delimiter", [",", ";", "\t"], ids=["comma", "semicolon", "tab"])
def test_csv_delimiter_detection(tmp_path, delimiter):
    text = delimiter.join(["t[s]", "x[mm]", "p_a[bar]"]) + "\n" + "\n".join(
        delimiter.join(r) for r in [["0", "1.5", "2"], ["0.5", "-2.5", "3e-1"]]) + "\n"
    assert rows(open_csv(tmp_path, text)) == {"t[s]": [0.0, 0.5], "x[mm]": [1.5, -2.5], "p_a[bar]": [2.0, 0.3]}


def test_csv_delimiter_detected_in_a_header_only_file(tmp_path):
    ex = open_csv(tmp_path, "t[s];x[mm];p_a[bar]\n")
    assert [(c.name, c.unit) for c in ex.columns] == [("t", "s"), ("x", "mm"), ("p_a", "bar")]


@pytest.mark.parametrize("delimiter", [";", "\t"], ids=["semicolon", "tab"])
def test_csv_decimal_comma(tmp_path, delimiter):
    text = f"t[s]{delimiter}x[mm]\n0{delimiter}1,5\n0,25{delimiter}-2,75\n1{delimiter}3\n"
    assert rows(open_csv(tmp_path, text)) == {"t[s]": [0.0, 0.25, 1.0], "x[mm]": [1.5, -2.75, 3.0]}



# -- decimal comma or thousands separator: decided from every numeric cell of the first rows ------
def test_csv_thousands_separator_is_not_read_as_a_decimal_comma(tmp_path):
    """Issue 21 item 16: `1,250` (Pa) beside `998` made the whole file "decimal comma": 1,250 Pa
    was stored as 1.25 while 998 stayed 998. A decimal-comma writer would have written 998 as
    `998,000` (fixed decimals) or 1.25 as `1,25` (general format): the comma groups thousands."""
    text = "t[s];p_a[Pa]\n0;998\n1;1,250\n2;1,001\n"
    with pytest.raises(ReaderError) as exc:
        rows(open_csv(tmp_path, text))
    assert str(exc.value) == ("`1,250` in column `p_a` groups thousands with `,` (beside `998` in the same column, "
                              "a decimal comma would have given `998,000` or `1,25`): digit grouping is not read; "
                              "export the numbers without thousands separators")


@pytest.mark.parametrize("text,example", [
    ("t[s]\tp_a[Pa]\n0\t1,250\n0.5\t2,500\n", "`1,250` in column `p_a` groups thousands with `,` (`0.5` in "
                                                 "column `t` has a decimal point)"),
    ("t[s];p_a[Pa]\n0;1,250,000\n1;2,000,500\n", "`1,250,000` in column `p_a` groups thousands with `,` (a "
                                                  "decimal comma appears once in a number)"),
    ("t[s];p_a[Pa]\n0,5;1.250\n1;2\n", "`1.250` in column `p_a` groups thousands with `.` (`0,5` in column `t` "
                                      "is a decimal comma)"),
    ("t[s];p_a[Pa]\n0;1,250.5\n1;2\n", "`1,250.5` in column `p_a` mixes `,` and `.`: digit grouping is not read"),
])
def test_csv_thousands_separator_proven_by_another_cell_is_refused(tmp_path, text, example):
    with pytest.raises(ReaderError, match="^" + re.escape(example)):
        open_csv(tmp_path, text)


def test_csv_numbers_ambiguous_under_both_readings_are_refused(tmp_path):
    text = "t[s];p_a[Pa]\n0;1,250\n1;2,500\n2;12,750\n"    # 1.25 .. or 1250 ..: nothing decides
    with pytest.raises(ReaderError) as exc:
        open_csv(tmp_path, text)
    assert str(exc.value) == ("`1,250` in column `p_a` reads as 1.25 with a decimal comma or 1250 with a thousands "
                              "separator, and no number in the first rows decides; set rig.toml [read] "
                              "decimal = \",\" if it is a decimal comma, or export without thousands separators")
    # the rig.toml says which: read as it says
    assert rows(open_csv(tmp_path, text, {"decimal": ","}))["p_a[Pa]"] == [1.25, 2.5, 12.75]


def test_csv_decimal_comma_and_decimal_point_in_one_file_are_refused(tmp_path):
    with pytest.raises(ReaderError, match=re.escape("`0,5` in column `x` is a decimal comma but `1.5` in column "
                                                    "`p_a` a decimal point")):
        open_csv(tmp_path, "t[s];x[mm];p_a[bar]\n0;0,5;1.5\n1;1;2\n")


@pytest.mark.parametrize("text,expected", [
    # a German export: decimal comma, some cells with three decimals that look like grouping
    ("t[s];p_a[Pa];x[mm]\n0;1,250;0,5\n0,001;998,5;12,3456\n", {"t[s]": [0.0, 0.001], "p_a[Pa]": [1.25, 998.5],
                                                               "x[mm]": [0.5, 12.3456]}),
    ("t[s]\tx[mm]\n0,000\t1,250\n0,010\t1,500\n", {"t[s]": [0.0, 0.01], "x[mm]": [1.25, 1.5]}),  # 0,xxx
    ("t[s];x[mm]\n0;1,25\n1;998\n", {"t[s]": [0.0, 1.0], "x[mm]": [1.25, 998.0]}),  # general format
    ("t[s];x[mm]\n0;1.250\n1;998\n", {"t[s]": [0.0, 1.0], "x[mm]": [1.25, 998.0]}),  # decimal point
    ("t[s];x[mm]\n0;1\n1;998\n", {"t[s]": [0.0, 1.0], "x[mm]": [1.0, 998.0]}),       # whole numbers
    ("t[s];x[mm];note\n0;1;12,500 cycles\n1;2;1,250\n", {"t[s]": [0.0, 1.0], "x[mm]": [1.0, 2.0],
                                                         "note": ["12,500 cycles", "1,250"]}),  # text column
    ("t[s];x[mm];date\n0;1,5;02.01.2026\n1;2;1.2.3\n", {"t[s]": [0.0, 1.0], "x[mm]": [1.5, 2.0],
                                                       "date": ["02.01.2026", "1.2.3"]}),  # dates are text
])
def test_csv_decimal_mark_consistent_with_every_value_is_read(tmp_path, text, expected):
    assert rows(open_csv(tmp_path, text)) == expected


def test_csv_decimal_decided_beyond_the_first_20_rows(tmp_path):
    """A column whose first rows are whole numbers and that shows its decimal comma only later
    (a slow ramp) is still decided by the cells of the head, not by a guess."""
    body = "".join(f"{i};{1000 + i}\n" for i in range(30)) + "30;1,250\n31;998,5\n"
    assert rows(open_csv(tmp_path, "t[s];p_a[Pa]\n" + body))["p_a[Pa]"][-2:] == [1.25, 998.5]

def test_csv_metadata_comment_lines(tmp_path):
    ex = open_csv(tmp_path, "# kind: breakaway\n#direction=P\n\n# notes: valve 2: new\nt[s],x[m]\n0,1\n")
    assert ex.metadata == {"kind": "breakaway", "direction": "P", "notes": "valve 2: new"}
    assert rows(ex) == {"t[s]": [0.0], "x[m]": [1.0]}


def test_csv_comment_line_that_is_not_a_key_is_kept_whole(tmp_path):
    # A real rig's export (issue 25 item 4): a sentence with a time in it is not `key: value`.
    ex = open_csv(tmp_path, "# Captured 2020-07-03 03:08:17.057076 by unknown user\n# kind: step\n"
                            "# gain = 2.5\n# Bench Firmware: v2\n# \n# valve: V-12\nt[s],x[m]\n0,1\n")
    assert ex.metadata == {"kind": "step", "gain": "2.5", "valve": "V-12",
                           "comments": ["Captured 2020-07-03 03:08:17.057076 by unknown user", "Bench Firmware: v2"]}
    assert rows(ex) == {"t[s]": [0.0], "x[m]": [1.0]}


def test_csv_metadata_keys_with_dots_dashes_and_digits(tmp_path):
    ex = open_csv(tmp_path, "# sensor.p_a-range2: 10 bar\n# 2nd_valve = V-3\nt[s],x[m]\n0,1\n")
    assert ex.metadata == {"sensor.p_a-range2": "10 bar", "2nd_valve": "V-3"}


def test_csv_headerless_whitespace_with_rig_toml(raw, warehouse):
    raw.write("c/rig.toml", """
        [read]
        delimiter = "whitespace"
        header = false
        [channels."1"]
        channel = "t"
        unit = "ms"
        [channels."2"]
        channel = "x"
        unit = "mm"
        scale = 2.0
        offset = -1.0
        [channels."3"]
        channel = "x_ref"
        unit = "mm"
        [metadata]
        kind = "step"
        rig = "plpa-1"
        started_at = "2026-01-02"
        """)
    raw.write("c/a.txt", "0    1.0   5\n  1\t2.5   6  \n2 -3.0 7\n", dedent=False)
    res, out = ingest(raw, "c/a.txt", warehouse)
    assert out.column("t_s").to_pylist() == [0.0, 0.001, 0.002]
    assert out.column("x_m").to_pylist() == [1e-3, 4e-3, -7e-3]      # (v * 2 - 1) mm
    assert out.column("x_ref_m").to_pylist() == [5e-3, 6e-3, 7e-3]


def test_csv_whitespace_decimal_comma_from_rig_toml(tmp_path):
    ex = open_csv(tmp_path, "t x\n0 1,5\n1 2,5\n", {"delimiter": "whitespace", "decimal": ","})
    assert rows(ex) == {"t": [0.0, 1.0], "x": [1.5, 2.5]}


def test_csv_skip_rows(tmp_path):
    text = "Bench XYZ export v2\nserial 1234\nt[s],x[mm]\n0,1\n1,2\n"
    assert rows(open_csv(tmp_path, text, {"skip_rows": 2})) == {"t[s]": [0.0, 1.0], "x[mm]": [1.0, 2.0]}


def test_csv_skip_rows_headerless(tmp_path):
    ex = open_csv(tmp_path, "junk line\n0;1,5\n1;2,5\n", {"skip_rows": 1, "header": False})
    assert rows(ex) == {"1": [0.0, 1.0], "2": [1.5, 2.5]}


def test_csv_bom(tmp_path):
    ex = open_csv(tmp_path, b"\xef\xbb\xbf# kind: step\nt[s],x[mm]\n0,1\n")
    assert ex.metadata == {"kind": "step"}
    assert rows(ex) == {"t[s]": [0.0], "x[mm]": [1.0]}


def test_csv_bom_headerless(tmp_path):
    assert rows(open_csv(tmp_path, b"\xef\xbb\xbf0,1\n2,3\n", {"header": False})) == {"1": [0.0, 2.0], "2": [1.0, 3.0]}


def test_csv_trailing_delimiter(tmp_path):
    ex = open_csv(tmp_path, "t[s],x[mm],\n0,1,\n1,2,\n")
    assert rows(ex) == {"t[s]": [0.0, 1.0], "x[mm]": [1.0, 2.0]}


def test_csv_trailing_delimiter_on_data_rows_only(tmp_path):
    ex = open_csv(tmp_path, "t[s];x[mm]\n0;1,5;\n1;2,5;\n")
    assert rows(ex) == {"t[s]": [0.0, 1.0], "x[mm]": [1.5, 2.5]}


def test_csv_latin1_header(tmp_path):
    ex = open_csv(tmp_path, "# notes: Prüfung\nt[s];Temp Öl [°C];x[µm]\n0;20,5;1\n".encode("latin-1"))
    assert ex.metadata == {"notes": "Prüfung"}
    assert rows(ex) == {"t[s]": [0.0], "Temp Öl[°C]": [20.5], "x[µm]": [1.0]}


def test_csv_latin1_byte_that_python_treats_as_a_line_break(tmp_path):
    # 0x85 is "..." in Windows-1252 and NEL in Latin-1: str.splitlines() would break there.
    ex = open_csv(tmp_path, "# notes: wait\x85 done\nt[s],x[mm]\n0,1\n".encode("latin-1"))
    assert rows(ex) == {"t[s]": [0.0], "x[mm]": [1.0]}


def test_csv_quoted_headers(tmp_path):
    ex = open_csv(tmp_path, '"t [s]","x, carriage [mm]","Oil ""hot"" [degC]"\n0,"1.5",3\n1,2.5,4\n')
    assert [(c.name, c.unit, c.dtype) for c in ex.columns] == [
        ("t", "s", "float"), ("x, carriage", "mm", "float"), ('Oil "hot"', "degC", "float")]
    assert rows(ex)["x, carriage[mm]"] == [1.5, 2.5]


def test_csv_text_column_kept_as_string(raw, warehouse):
    raw.write("c/a.csv", META + "t[s],x[m],x_ref[m],state\n0,0,0,idle\n1,1,1,\n2,2,2,run 2\n")
    res, out = ingest(raw, "c/a.csv", warehouse)
    assert out.column("state").to_pylist() == ["idle", None, "run 2"]
    assert out.schema.field("state").type == pa.string()


def test_csv_bad_value_names_the_line(tmp_path):
    ex = open_csv(tmp_path, META + "t[s],x[m]\n0,0\n\n1,1\n2,2x\n")
    with pytest.raises(ReaderError, match=r"^line 8: value '2x' in column `x` is not a number$"):
        rows(ex)


def test_csv_bad_value_in_a_canonical_channel_past_the_sampled_rows(tmp_path):
    body = "".join(f"{i},{i}\n" for i in range(100))
    ex = open_csv(tmp_path, "t[s];x[mm]\n" + body.replace(",", ";") + "100;n/a?\n")
    with pytest.raises(ReaderError, match=r"line 102: value 'n/a\?' in column `x` is not a number"):
        rows(ex)


def test_csv_bad_value_quarantines_with_the_line(raw, warehouse):
    raw.write("c/a.csv", META + "t[s],x[m],x_ref[m]\n0,0,0\n1,oops,0\n")
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.csv", warehouse)
    assert res.error == "line 6: value 'oops' in column `x` is not a number"


def test_csv_row_with_too_many_fields_names_the_line(tmp_path):
    ex = open_csv(tmp_path, "t[s],x[m]\n0,1\n1,2,3\n")
    with pytest.raises(ReaderError, match=r"^line 3: 3 fields where the header has 2"):
        rows(ex)


def test_csv_crlf_and_spaces_after_delimiter(tmp_path):
    ex = open_csv(tmp_path, "t[s], x[mm]\r\n0, 1.5\r\n1, 2.5\r\n")
    assert rows(ex) == {"t[s]": [0.0, 1.0], "x[mm]": [1.5, 2.5]}


def test_csv_streams_in_blocks(tmp_path, monkeypatch):
    monkeypatch.setattr(csv_module, "BLOCK_BYTES", 1 << 10)
    n = 2000
    ex = open_csv(tmp_path, "t[s],x[mm]\n" + "".join(f"{i * 0.5},{i}\n" for i in range(n)))
    batches = list(ex.batches())
    assert len(batches) > 5
    assert pa.Table.from_batches(batches).column("c2").to_pylist() == [float(i) for i in range(n)]


def test_csv_value_exact_round_trip_with_decimal_comma(raw, warehouse):
    raw.write("c/a.csv", META + "# p_atm_pa: 100000\nt[ms];x[mm];x_ref[um];p_a[bar(a)];q[l/min]\n"
                                "0;1,5;10;1;0,5\n1;2,5;20;2;1\n2;-3;30;3,5;2\n")
    res, out = ingest(raw, "c/a.csv", warehouse)
    assert out.column("t_s").to_pylist() == [0.0, 0.001, 0.002]
    assert out.column("x_m").to_pylist() == [1.5e-3, 2.5e-3, -3e-3]
    assert out.column("x_ref_m").to_pylist() == [1e-5, 2e-5, 3e-5]
    assert out.column("p_a_pa").to_pylist() == [0.0, 100000.0, 250000.0]
    assert out.column("q_l_min").to_pylist() == [0.5, 1.0, 2.0]    # not canonical: kept as written
    assert out.schema.field("q_l_min").metadata[b"unit"] == b"l/min"


def test_csv_rig_toml_renames_a_named_channel(raw, warehouse):
    raw.write("c/rig.toml", '[channels."Druck A"]\nchannel = "p_a"\nunit = "bar"\n')
    raw.write("c/a.csv", "# kind: durability\n# hose_id: H1\n# rig: r\n# started_at: 2026-01-01\n"
                         "t[s],x[mm],Druck A,p_b[bar]\n0,1,2,3\n")
    res, out = ingest(raw, "c/a.csv", warehouse)
    assert out.column("p_a_pa").to_pylist() == [200000.0]


# -- refusals, one scenario each -------------------------------------------------------------
def test_csv_empty_file_is_refused(tmp_path):
    with pytest.raises(ReaderError, match=r"^no header or data rows$"):
        open_csv(tmp_path, b"")


def test_csv_file_of_metadata_lines_only_is_quarantined(raw, warehouse):
    raw.write("c/a.csv", META + "# notes: bench stopped before the header was written\n\n")
    with pytest.raises(ReaderError, match=r"^no header or data rows$"):
        read_export(raw.root / "c/a.csv")
    res = ingest_file(RawTree(raw.root), raw.root / "c/a.csv", warehouse)
    assert res.run is None and res.error == "no header or data rows"


# -- resource limits -------------------------------------------------------------------------
def test_csv_header_with_more_columns_than_the_limit_is_refused(tmp_path):
    """32,000 columns all named `a` (a 64 KB header): one line naming the count and the limit."""
    from pipeline.readers.base import MAX_CHANNELS

    text = ",".join(["a"] * 32_000) + "\n" + ",".join(["1"] * 32_000) + "\n"
    with pytest.raises(ReaderError) as exc:
        open_csv(tmp_path, text)
    assert str(exc.value) == f"32000 columns in the header: more than the limit of {MAX_CHANNELS} channels per file"


def test_csv_header_at_the_limit_is_read(tmp_path):
    from pipeline.readers.base import MAX_CHANNELS

    text = "t[s]," + ",".join(["a"] * (MAX_CHANNELS - 1)) + "\n" + ",".join(["1"] * MAX_CHANNELS) + "\n"
    ex = open_csv(tmp_path, text)
    assert len(ex.columns) == MAX_CHANNELS and ex.columns[-1].key == f"c{MAX_CHANNELS}"


def test_csv_line_without_end_longer_than_the_limit_is_refused(tmp_path):
    """25 MiB without a line break after the header: refused, not held whole and re-copied."""
    from pipeline.readers.base import MAX_LINE_BYTES

    ex = open_csv(tmp_path, b"t[s],x[mm]\n0,1\n" + b"1" * (MAX_LINE_BYTES + (9 << 20)))
    with pytest.raises(ReaderError, match=r"^a line longer than 16 MiB \(no line break from byte 15\): "
                                          r"not delimited text$"):
        list(ex.batches())
