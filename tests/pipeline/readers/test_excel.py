"""Spreadsheet reader: scenarios built with openpyxl in the test (no binaries committed)."""
import datetime as dt

import numpy as np
import pyarrow as pa
import pytest

openpyxl = pytest.importorskip("openpyxl")

from pipeline.readers import ReaderError, read_export  # noqa: E402
from pipeline.readers.excel import list_parts, read_excel  # noqa: E402
from tests.pipeline.readers.generators import xlsx_workbook  # noqa: E402


def _book(path, rows, title="run", meta=None, extra=None):
    return xlsx_workbook(path, {title: rows}, meta, extra)


def _values(exp):
    table = pa.Table.from_batches(list(exp.batches()))
    return {c.name: table.column(c.key).to_pylist() for c in exp.columns}


def test_comment_cell_that_is_not_a_key_is_kept_whole(tmp_path):
    p = _book(tmp_path / "r.xlsx", [["# Captured 2020-07-03 03:08:17.057076 by unknown user"], ["# kind: leakage"],
                                     ["t[s]", "p_supply[bar]"], [0.0, 1.5], [0.5, 2.0]])
    exp = read_excel(p)
    assert exp.metadata["comments"] == ["Captured 2020-07-03 03:08:17.057076 by unknown user"]
    assert exp.metadata["kind"] == "leakage" and not any(str(k).startswith("Captured") for k in exp.metadata)


def test_header_with_units_and_comment_metadata(tmp_path):
    p = _book(tmp_path / "r.xlsx", [["# kind: leakage"], ["# chamber: A"], ["t[s]", "p_supply (bar)", "q_leak[l/min]"],
                                     [0.0, 1.5, 0.25], [0.5, 2.0, 0.5], [1.0, 2.5, None]])
    exp = read_excel(p)
    assert exp.format == "excel"
    assert [(c.name, c.unit) for c in exp.columns] == [("t", "s"), ("p_supply", "bar"), ("q_leak", "l/min")]
    assert exp.metadata["kind"] == "leakage" and exp.metadata["chamber"] == "A" and exp.metadata["sheet"] == "run"
    v = _values(exp)
    assert v["t"] == [0.0, 0.5, 1.0] and v["p_supply"] == [1.5, 2.0, 2.5]
    assert v["q_leak"][:2] == [0.25, 0.5] and np.isnan(v["q_leak"][2])


def test_units_row_meta_sheet_and_rows_before_numbers(tmp_path):
    p = _book(tmp_path / "r.xlsx", [["t", "x", "note"], ["s", "mm", ""], ["(raw)", "", ""], [0, 1, "a"], [1, 2, "b"]],
              meta={"kind": "step", "rig": "plpa-9"})
    exp = read_excel(p, {"units_row": 2})
    assert [(c.name, c.unit, c.dtype) for c in exp.columns] == [("t", "s", "float"), ("x", "mm", "float"),
                                                                ("note", None, "string")]
    assert exp.metadata["kind"] == "step" and exp.metadata["rig"] == "plpa-9"
    assert _values(exp) == {"t": [0.0, 1.0], "x": [1.0, 2.0], "note": ["a", "b"]}


def test_datetime_time_column_becomes_seconds_and_started_at(tmp_path):
    t0 = dt.datetime(2026, 3, 1, 8, 0, 0)
    rows = [["time", "p[bar]"]] + [[t0 + dt.timedelta(seconds=0.25 * i), i] for i in range(5)]
    exp = read_excel(_book(tmp_path / "r.xlsx", rows))
    assert exp.columns[0].unit == "s"
    assert _values(exp)["time"] == pytest.approx([0, 0.25, 0.5, 0.75, 1.0])
    assert exp.metadata["started_at"] == "2026-03-01T08:00:00"


def test_sheet_by_name_and_index_trailing_empty_ignored(tmp_path):
    def more(wb):
        ws = wb.create_sheet("second")
        ws.append(["t[s]", "x[mm]"])
        ws.append([0, 5])
        ws["E20"] = None  # touched but empty
    p = _book(tmp_path / "r.xlsx", [["t[s]", "x[mm]"], [0, 1]], extra=more)
    assert _values(read_excel(p, hints={"sheet": "second"}))["x"] == [5.0]
    assert _values(read_excel(p, {"sheet": 1}))["x"] == [5.0]
    with pytest.raises(ReaderError, match="no sheet named 'nope'"):
        read_excel(p, hints={"sheet": "nope"})


def test_extension_in_any_case_goes_to_the_reader(tmp_path):
    p = _book(tmp_path / "R.XLSX", [["t[s]"], [0], [1]])
    assert read_export(p).format == "excel"


def test_refused_password_protected_workbook(tmp_path):
    # Office wraps an encrypted .xlsx in an OLE compound file
    p = tmp_path / "locked.xlsx"
    p.write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(504) + b"EncryptedPackage")
    with pytest.raises(ReaderError, match="password-protected"):
        read_excel(p)


def test_refused_chart_only_sheet(tmp_path):
    def chart(wb):
        wb.create_chartsheet("plot")
    p = _book(tmp_path / "c.xlsx", [["t[s]"], [0]], extra=chart)
    with pytest.raises(ReaderError, match="'plot' is a ChartSheet"):
        read_excel(p, hints={"sheet": "plot"})


def test_refused_not_a_workbook_and_no_data(tmp_path):
    bad = tmp_path / "bad.xlsx"
    bad.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(ReaderError, match="not a readable .xlsx workbook"):
        read_excel(bad)
    with pytest.raises(ReaderError, match="no data rows"):
        read_excel(_book(tmp_path / "h.xlsx", [["t[s]", "x[mm]"], ["", ""]]))
    with pytest.raises(ReaderError, match="column 2 has data but no name"):
        read_excel(_book(tmp_path / "n.xlsx", [["t[s]", None], [0, 1]]))


def test_formula_read_as_its_cached_value(tmp_path):
    import zipfile

    src = _book(tmp_path / "src.xlsx", [["a[s]", "b[s]"], [2, "=A2*2"]])
    out = tmp_path / "cached.xlsx"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "xl/worksheets/sheet1.xml":  # what a spreadsheet program saves
                data = data.replace(b"<f>A2*2</f><v></v>", b"<f>A2*2</f><v>4</v>")
            zout.writestr(item, data)
    assert _values(read_excel(out)) == {"a": [2.0], "b": [4.0]}


def test_list_parts_is_every_worksheet_but_meta_and_charts(tmp_path):
    def more(wb):
        wb.create_sheet("second").append(["t[s]"])
        wb.create_chartsheet("chart")

    p = _book(tmp_path / "b.xlsx", [["t[s]"], [0.0]], title="first", meta={"kind": "step"}, extra=more)
    assert list_parts(p) == ["first", "second"]
    only_meta = _book(tmp_path / "m.xlsx", [["kind", "step"]], title="META")
    with pytest.raises(ReaderError, match="no data worksheet"):
        list_parts(only_meta)


def test_own_cells_win_over_meta_sheet_only_in_sheets_all_mode(tmp_path):
    p = _book(tmp_path / "r.xlsx", [["# chamber: B"], ["t[s]", "x[mm]"], [0.0, 1.0]],
              meta={"chamber": "A", "kind": "step"})
    assert read_excel(p).metadata["chamber"] == "A"            # one run per file: as before
    exp = read_excel(p, {"sheets": "all"})                    # one run per sheet: the sheet is more specific
    assert exp.metadata["chamber"] == "B" and exp.metadata["kind"] == "step"


def test_meta_sheet_run_id_is_the_prefix_of_each_sheet_in_sheets_all_mode(tmp_path):
    def more(wb):
        ws = wb.create_sheet("own")
        for r in [["# run_id: special"], ["t[s]"], [0.0]]:
            ws.append(r)

    p = _book(tmp_path / "r.xlsx", [["t[s]"], [0.0]], title="S1", meta={"run_id": "bench7/day3"}, extra=more)
    assert read_excel(p).metadata["run_id"] == "bench7/day3"                                  # one run per file
    assert read_excel(p, {"sheets": "all"}, {"sheet": "S1"}).metadata["run_id"] == "bench7/day3/S1"
    assert read_excel(p, {"sheets": "all"}, {"sheet": "own"}).metadata["run_id"] == "special"  # its own cell


def test_list_parts_refuses_more_sheets_than_the_limit(tmp_path, monkeypatch):
    import pipeline.readers.base as base

    p = _book(tmp_path / "b.xlsx", [["t[s]"], [0.0]], extra=lambda wb: [wb.create_sheet(f"s{i}") for i in range(3)])
    monkeypatch.setattr(base, "MAX_PARTS", 3)
    with pytest.raises(ReaderError, match="4 sheets: more than the limit of 3 runs per file"):
        list_parts(p)


def test_refused_meta_sheet_that_cannot_be_read(tmp_path):
    """A `meta` sheet the workbook lists but whose part is damaged or gone let calamine's errors
    (WorksheetNotFound, XmlError) escape the reader (tests/fuzz): one ReaderError naming the sheet."""
    import zipfile

    good = _book(tmp_path / "good.xlsx", [["t[s]", "x[mm]"], [0, 1], [1, 2]], meta={"kind": "step"})
    bad = tmp_path / "bad.xlsx"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        names = src.namelist()
        meta_part = [n for n in names if n.startswith("xl/worksheets/")][-1]  # openpyxl writes `meta` last
        for name in names:
            if name != meta_part:
                dst.writestr(name, src.read(name))
    assert read_excel(good).metadata["kind"] == "step"
    with pytest.raises(ReaderError, match=r"sheet 'meta' cannot be read \(\w+"):
        read_excel(bad)


# -- a sheet's grid is bounded by what the workbook holds --------------------------------------
_DATA = [["t [s]", "x [mm]"]] + [[i * 1e-3, i * 0.1] for i in range(20)]


def _rewrite_sheet(src, dst, change):
    """A copy of workbook ``src`` whose first worksheet's XML is ``change(xml)``."""
    import zipfile

    with zipfile.ZipFile(src) as a, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as b:
        for info in a.infolist():
            data = a.read(info)
            b.writestr(info, change(data) if info.filename == "xl/worksheets/sheet1.xml" else data)
    return dst


def test_a_note_cell_beside_the_data_is_read(tmp_path):
    """A note at Z1 and a value far down (A5000): the grids (5,000 x 26) fit in what the file may take."""
    def extra(wb):
        wb["run"]["Z1"] = "checked by AB"
        wb["run"]["A5000"] = "end"
    ex = read_excel(_book(tmp_path / "b.xlsx", _DATA, extra=extra))
    assert _values(ex)["x"][:3] == [0.0, 0.1, 0.2]


@pytest.mark.parametrize("order", ["r first", "r after another attribute", "lower-case reference",
                                   "single quotes"])
def test_a_stray_cell_far_from_the_data_is_refused_naming_the_span(tmp_path, order):
    """One cell at IV65536 in a 5 KB workbook: calamine would load a 65,536 x 256 grid (16.8 M
    cells, 512 MiB; at IV1048576, 8 GiB: see the child-process test below). Refused from the
    sheet's XML, before calamine sees it; the second case writes its cells as `<c s="0" r="A1">`
    (the exact scan, not the quick bound)."""
    p = _book(tmp_path / "b.xlsx", _DATA, extra=lambda wb: wb["run"].cell(row=65536, column=256, value=1))
    if order == "r after another attribute":
        p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b'<c r="', b'<c s="0" r="'))
    if order == "single quotes":                          # XML allows them; the quick bound sees no <c r="
        p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b'r="IV65536"', b"r='IV65536'"))
    if order == "lower-case reference":                   # calamine reads iv65536 as IV65536
        p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b'r="IV65536"', b'r="iv65536"'))
    size = p.stat().st_size
    with pytest.raises(ReaderError, match=(
            rf"^sheet 'run': its cells span 65,536 rows x 256 columns \(16,777,216 cells, 640\.0 MiB to read "
            rf"as a grid\) but 43 are present: more than the 64\.0 MiB a {size:,}-byte workbook may take "
            r"\(a stray cell far from the data\?\)$")):
        read_excel(p)


def test_a_stray_cell_in_a_row_without_cell_references_is_refused(tmp_path):
    """`<row r="1048576"><c><v>1</v></c>`: the cell takes its row's position, at 1,048,576."""
    p = _book(tmp_path / "b.xlsx", _DATA)
    far = b'<row r="1048576"><c t="n"><v>1</v></c><c t="n"><v>1</v></c></row></sheetData>'
    p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b"</sheetData>", far))
    with pytest.raises(ReaderError, match=r"^sheet 'run': its cells span 1,048,576 rows x 4 columns"):
        read_excel(p)


def test_a_sheet_whose_xml_inflates_past_the_cap_is_refused(tmp_path):
    """80 MiB of blanks in a sheet's XML compress to about 80 KB: past the 64 MiB floor."""
    p = _book(tmp_path / "b.xlsx", _DATA)
    blanks = b" " * (80 << 20)
    p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b"</sheetData>", blanks + b"</sheetData>"))
    with pytest.raises(ReaderError, match=r"^sheet 'run': its XML inflates past 64\.0 MiB, more than [\d,]+ x the "
                                          r"[\d,]+-byte workbook \(a decompression bomb\?\)$"):
        read_excel(p)


def test_a_stray_cell_peak_memory_stays_bounded(tmp_path):
    """In a child process (peak RSS its own): refused at the memory of an interpreter."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    p = _book(tmp_path / "b.xlsx", _DATA, extra=lambda wb: wb["run"].cell(row=1048576, column=256, value=1))
    code = ("import resource, sys\nresource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))\n"
            "from pipeline.readers import ReaderError, read_export\n"
            "try:\n    read_export(sys.argv[1])\nexcept ReaderError as e:\n    print('refused', e)\n"
            "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0])\n")
    root = str(Path(__file__).resolve().parents[3])
    out = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=120,
                         cwd=root, env={**os.environ, "PYTHONPATH": root})
    lines = out.stdout.splitlines()
    assert lines and lines[0].startswith("refused sheet 'run': its cells span 1,048,576 rows"), out.stderr[-300:]
    assert int(lines[1]) * 1024 < 200 << 20       # [kB]; calamine's grid alone would be 8 GiB


def test_a_stray_cell_is_found_when_the_workbook_links_do_not_parse(tmp_path):
    """Relationships Python's XML parser refuses: every worksheet part is checked instead."""
    import zipfile

    p = _book(tmp_path / "b.xlsx", _DATA, extra=lambda wb: wb["run"].cell(row=65536, column=256, value=1))
    bad = tmp_path / "c.xlsx"
    with zipfile.ZipFile(p) as a, zipfile.ZipFile(bad, "w", zipfile.ZIP_DEFLATED) as b:
        for info in a.infolist():
            data = a.read(info)
            b.writestr(info, data + b"<" if info.filename == "xl/_rels/workbook.xml.rels" else data)
    with pytest.raises(ReaderError, match=r"^sheet 'xl/worksheets/sheet1\.xml': its cells span 65,536 rows x 256"):
        read_excel(bad)


def test_a_cell_reference_that_is_not_plain_a1_is_refused(tmp_path):
    """`r="&#73;V65536"` (a character reference): no bound can be read from it, so no grid is built."""
    p = _book(tmp_path / "b.xlsx", _DATA, extra=lambda wb: wb["run"].cell(row=65536, column=256, value=1))
    p = _rewrite_sheet(p, tmp_path / "c.xlsx", lambda x: x.replace(b'r="IV65536"', b'r="&#73;V65536"'))
    with pytest.raises(ReaderError, match=r"^sheet 'run': a cell reference is not a plain A1 reference: its grid "
                                          r"cannot be bounded before it is read$"):
        read_excel(p)
