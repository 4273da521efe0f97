"""Spreadsheet exports: Excel (``.xlsx``, ``.xlsm``, ``.xls``) and OpenDocument (``.ods``).

Read with python-calamine (a Rust reader; about ten times faster than openpyxl on the same
workbook, see ``benchmarks/README.md``). Formulas are read as the values the spreadsheet last
computed (cached values); a formula the spreadsheet never computed is an empty cell.

* **Which sheet.** The first sheet not named ``meta`` is the run, unless the ``sheet`` key
  (run metadata, e.g. in ``manifest.csv``, or ``rig.toml`` ``[read] sheet``) names one by its
  name or 0-based index. A chart sheet holds no cells and is refused.
* **One run per sheet.** With ``sheets = "all"`` (``rig.toml`` ``[read]``, or a manifest /
  ``[metadata]`` key) every worksheet not named ``meta`` is a run of its own
  (:func:`list_parts`; ingest reads each with the ``sheet`` key set).
* **Metadata.** A sheet named ``meta`` (case-insensitive) with two columns key / value, and
  ``# key: value`` cells in the first column above the header (as in CSV exports). The
  ``meta`` sheet wins over a sheet's own cells, except with ``[read] sheets = "all"`` (the
  one-run-per-sheet mode), where a sheet's own cells are more specific and win, and a
  ``run_id`` of the ``meta`` sheet becomes ``<run_id>/<sheet>``.
* **Header.** The header row is the first row after the metadata cells (``[read] skip_rows``
  skips more), or ``[read] header_row`` (the sheet's own 1-based row number). Headers
  ``name[unit]`` and ``name (unit)`` carry a unit; ``[read] units_row`` (1-based) names a row of
  units under the names instead (a common spreadsheet layout). Rows between the header (or
  units row) and the first row with a number are skipped (a second title row, blank rows).
* **Cells.** Empty trailing rows and columns are ignored; an empty cell in a numeric column is
  NaN. A column whose cells are date-times (Excel serial dates with a date format) becomes
  seconds since its first value with unit ``s``; when the run has no ``started_at``, the first
  date-time of the time column gives it. A column of text (or of numbers mixed with text) is
  kept as a text column: ingest keeps it as text when it is not a canonical channel and refuses
  it, naming the column, when it is.

Excel has no partial reads, so the chosen sheet is loaded whole (a sheet holds at most
1,048,576 rows by Excel's own limit) and then yielded in record batches. calamine loads it as
the dense grid from its first to its last cell: one stray cell at ``IV1048576`` makes a 1.7 KB
workbook a grid of 268 M cells (8 GiB). So an ``.xlsx`` / ``.xlsm`` sheet's XML is scanned first
(:func:`_check_sheet_extent`: cells present, the rows and columns they span) and a grid of more
than :data:`CELL_BYTES` x cells over :func:`pipeline.readers.base.inflate_cap` of the file is
refused, naming the span and the cells present. (``.xls`` grids are at most 65,536 x 256.)
"""
from __future__ import annotations

import datetime as dt
import math
import posixpath
import re
import xml.etree.ElementTree as ET
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import (MAX_LINE_BYTES, RawColumn, RawExport, ReaderError, check_part_count, exc_text,
                                   inflate_cap, mib, parse_key_value, split_name_unit)

FORMAT = "excel"
EXTENSIONS = (".xlsx", ".xlsm", ".xls", ".ods")

#: Rows per record batch.
BATCH_ROWS = 1 << 16
#: Bytes one cell of a sheet's grid takes while it is read: calamine's cell value (32 B) and the
#: Python list slot it becomes (8 B). Empty cells inside the span count as much as full ones. [B]
CELL_BYTES = 40

# An OLE compound file (D0 CF 11 E0): a legacy .xls, or an encrypted (password-protected)
# Office Open XML package, which Office wraps in one.
_CFB_MAGIC = b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1"
_PASSWORD_HINT = "open it in the spreadsheet program and save it without a password"


def _open_workbook(path: Path):
    """The workbook opened by calamine; refused in one line when encrypted or unreadable."""
    import python_calamine as pc   # a compiled reader: imported only when a workbook is opened

    with open(path, "rb") as fh:
        head = fh.read(8)
    if head == _CFB_MAGIC and path.suffix.lower() in (".xlsx", ".xlsm"):
        raise ReaderError(f"password-protected (encrypted) workbook: {_PASSWORD_HINT}")
    try:
        return pc.CalamineWorkbook.from_path(str(path))
    except pc.PasswordError:
        raise ReaderError(f"password-protected (encrypted) workbook: {_PASSWORD_HINT}") from None
    except (pc.CalamineError, pc.ZipError, pc.XmlError, ValueError, OSError) as exc:
        if isinstance(exc, OSError) and exc.errno is not None:
            raise
        raise ReaderError(f"not a readable {path.suffix.lower()} workbook ({exc_text(exc, 200)})") from None


#: ``[read]`` / metadata key that makes every data sheet a run, and the key naming one sheet.
PARTS_KEY, PART_KEY = "sheets", "sheet"


def list_parts(path: str | Path) -> list[str]:
    """Names of the sheets that are runs when ``sheets = "all"``: every worksheet not named
    ``meta`` (chart sheets hold no cells and are left out), in workbook order.

    Raises
    ------
    ReaderError
        The workbook cannot be opened, or has no such sheet.
    """
    path = Path(path)
    wb = _open_workbook(path)
    check_part_count(len(wb.sheet_names), "sheets")
    names = [n for n in wb.sheet_names
             if n.strip().casefold() != "meta" and _sheet_kind(wb, n) == "WorkSheet"]
    if not names:
        raise ReaderError("workbook has no data worksheet (only `meta` or chart sheets)")
    return names


def _pick_sheet(wb, selector) -> str:
    """The name of the sheet ``selector`` names (a name or a 0-based index), else the first sheet not named ``meta``."""
    names = list(wb.sheet_names)
    if not names:
        raise ReaderError("workbook has no sheets")
    if selector is None or str(selector).strip() == "":
        data = [n for n in names if n.strip().casefold() != "meta"]
        if not data:
            raise ReaderError("workbook has only a `meta` sheet: no data sheet")
        return data[0]
    text = str(selector).strip()
    if text in names:
        return text
    if text.lstrip("-").isdigit():
        i = int(text)
        if 0 <= i < len(names):
            return names[i]
        raise ReaderError(f"sheet index {i} out of range: the workbook has {len(names)} sheet(s) {names}")
    raise ReaderError(f"no sheet named {text!r}; sheets: {names}")


_NS = r"(?:[A-Za-z_][\w.-]*:)?"                                # an element may carry a prefix (x:c)
_CELL_REF = re.compile(rb"<" + _NS.encode() + rb"c\s[^>]*?\br\s*=\s*[\"']([A-Za-z]+)([0-9]+)[\"']")  # a1 too
_CELL_ANY_REF = re.compile(rb"<" + _NS.encode() + rb"c\s[^>]*?\br\s*=")
_ROW_REF = re.compile(rb"<" + _NS.encode() + rb"row\s[^>]*?\br\s*=\s*[\"']([0-9]+)[\"']")
_CHUNK = 4 << 20


def _col_number(letters: bytes) -> int:
    """A column's letters as its 1-based number (``A`` -> 1, ``AA`` -> 27)."""
    n = 0
    for ch in letters.upper():
        n = 26 * n + ch - 64
    return n


def _sheet_parts(zf: zipfile.ZipFile, names: list[str]) -> dict[str, str]:
    """Zip member of each named worksheet (workbook.xml -> its relationships); a name that cannot
    be mapped is left out."""
    def xml(member):
        with zf.open(member) as fh:
            data = fh.read(MAX_LINE_BYTES + 1)
        if len(data) > MAX_LINE_BYTES:
            raise ReaderError(f"workbook part {member} is over {mib(MAX_LINE_BYTES)}")
        return ET.fromstring(data)

    try:
        rels = {r.get("Id"): r.get("Target", "") for r in xml("xl/_rels/workbook.xml.rels")}
        ids = {}
        for el in xml("xl/workbook.xml").iter():
            if el.tag.rsplit("}", 1)[-1] == "sheet":
                rid = next((v for k, v in el.attrib.items() if k.rsplit("}", 1)[-1] == "id"), None)
                ids[el.get("name")] = rels.get(rid)
    except (KeyError, ET.ParseError):
        return {}
    out = {}
    for name in names:
        target = ids.get(name)
        if target:
            out[name] = posixpath.normpath(target.lstrip("/") if target.startswith("/") else "xl/" + target)
    return out


def _xml_chunks(zf: zipfile.ZipFile, member: str, name: str, cap: int, size: int) -> Iterator[bytes]:
    """A sheet's XML inflated in chunks that end before a tag (refused past ``cap`` bytes)."""
    inflated, carry = 0, b""
    with zf.open(member) as fh:
        while True:
            try:
                chunk = fh.read(_CHUNK)
            except (zipfile.BadZipFile, zlib.error, EOFError) as exc:   # a bad CRC, a cut stream
                raise ReaderError(f"sheet {name!r}: its XML cannot be read ({exc_text(exc)})") from None
            inflated += len(chunk)
            if inflated > cap:
                raise ReaderError(f"sheet {name!r}: its XML inflates past {mib(cap)}, more than "
                                  f"{cap // max(size, 1):,} x the {size:,}-byte workbook (a decompression bomb?)")
            buf = carry + chunk
            cut = buf.rfind(b"<") if chunk else len(buf)
            if cut < 0 or len(buf) - cut > 1 << 20:      # no tag open at the end (or one that long)
                cut = len(buf)
            yield buf[:cut]
            carry = buf[cut:]
            if not chunk:
                return


def _cell_tags(buf: bytes) -> int:
    """Cell elements in ``buf``: ``<c`` or ``<prefix:c`` followed by a space, a tab, a line break,
    ``/`` or ``>`` (vectorised: a regex over every cell of a large sheet costs a second)."""
    a = np.frombuffer(buf, dtype=np.uint8)
    if a.size < 3:
        return 0
    c = (a[1:-1] == 0x63) & ((a[:-2] == 0x3C) | (a[:-2] == 0x3A))          # "<c" or ":c"
    nxt = a[2:]
    c &= (nxt == 0x20) | (nxt == 0x09) | (nxt == 0x0A) | (nxt == 0x0D) | (nxt == 0x2F) | (nxt == 0x3E)
    return int(np.count_nonzero(c))


def _widest(buf: bytes, pattern: bytes, most: int, known: int) -> int:
    """Largest ``k`` in (``known``, ``most``] such that ``pattern % k`` occurs in ``buf``, else ``known``."""
    return next((k for k in range(most, known, -1) if re.search(pattern % k, buf)), known)


def _sheet_extent(chunks) -> tuple[int, int, int] | None:
    """(cells present, rows, columns spanned) when every cell is written ``<c r="A1"`` (as Excel
    and most writers write them), as upper bounds from the widest references: rows < 10 **
    digits, columns <= 26 + 26 ** 2 + ... for their letters; None when some cell is written
    otherwise (another attribute first, a prefix, no reference)."""
    cells = digits = letters = 0
    for buf in chunks:
        n = _cell_tags(buf)
        if buf.count(b'<c r="') != n or re.search(rb'<c r="(?![A-Za-z]+[0-9]+")', buf):
            return None
        cells += n
        if re.search(rb'<c r="(?:[A-Za-z]{%d}|[A-Za-z]+[0-9]{%d})' % (letters + 1, digits + 1), buf):
            digits = _widest(buf, rb'<c r="[A-Za-z]+[0-9]{%d}', 8, digits)
            letters = _widest(buf, rb'<c r="[A-Za-z]{%d}', 4, letters)
            if digits == 8 or letters == 4:                  # past Excel's own grid: no bound from these
                return None
    return cells, 10 ** digits - 1, sum(26 ** k for k in range(1, letters + 1))


def _sheet_extent_exact(chunks) -> tuple[int, int, int] | None:
    """(cells present, rows, columns) of the grid from the first cell to the last, whatever the
    attribute order or prefixes; a cell or row without a reference takes the next position.
    None when a cell has a reference that is not a plain ``A1`` one (it cannot be bounded)."""
    cells = refs = any_refs = rows = row_refs = max_row = max_col = 0
    min_row = min_col = 1 << 62
    cell = re.compile(rb"<" + _NS.encode() + rb"c[\s/>]")
    row = re.compile(rb"<" + _NS.encode() + rb"row[\s/>]")
    for buf in chunks:
        cells += len(cell.findall(buf))
        rows += len(row.findall(buf))
        any_refs += len(_CELL_ANY_REF.findall(buf))
        found = _CELL_REF.findall(buf)
        if found:
            refs += len(found)
            at = [int(r) for _, r in found]
            max_row, min_row = max(max_row, max(at)), min(min_row, min(at))
            at = [_col_number(c) for c in {c for c, _ in found}]
            max_col, min_col = max(max_col, max(at)), min(min_col, min(at))
        found = _ROW_REF.findall(buf)
        if found:
            row_refs += len(found)
            at = [int(r) for r in found]
            max_row, min_row = max(max_row, max(at)), min(min_row, min(at))
    if any_refs > refs:
        return None
    n_rows = (max_row - min_row + 1 if max_row else 0) + max(0, rows - row_refs)
    n_cols = (max_col - min_col + 1 if max_col else 0) + max(0, cells - refs)
    return cells, n_rows, n_cols


def _check_sheet_extent(path: Path, names: list[str]) -> None:
    """Refuse an ``.xlsx`` / ``.xlsm`` sheet whose grid (the rows and columns its cells span, as
    calamine loads it) would take more than ``inflate_cap(file size)`` at :data:`CELL_BYTES` a
    cell, or whose XML inflates past that cap. Other formats pass (see the module docstring).

    A first pass bounds the grid from the widest cell references (cheap); only a sheet that
    bound does not clear is scanned cell by cell for its exact span."""
    if path.suffix.lower() not in (".xlsx", ".xlsm"):
        return
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as zf:
            _check_extents(zf, names, size)
    except ReaderError:
        raise
    except OSError as exc:
        if exc.errno is not None:                            # an I/O error: not the file's fault
            raise
    except Exception:  # noqa: BLE001 - a damaged zip or XML part: calamine says what is wrong
        pass


def _check_extents(zf: zipfile.ZipFile, names: list[str], size: int) -> None:
    """Refuse a sheet among ``names`` whose grid (or XML) is larger than ``inflate_cap(size)`` allows
    (see :func:`_check_sheet_extent`)."""
    cap = inflate_cap(size)
    parts = _sheet_parts(zf, names)
    parts = {n: m for n, m in parts.items() if m in zf.NameToInfo}
    if len(parts) < len(names):       # a sheet not found through the workbook's links: every worksheet part
        sheets = [m for m in zf.namelist() if m.startswith("xl/worksheets/") and m.endswith(".xml")]
        check_part_count(len(sheets), "worksheet parts")
        parts.update({m: m for m in sheets if m not in parts.values()})
    for name, member in parts.items():
        bound = _sheet_extent(_xml_chunks(zf, member, name, cap, size))
        if bound is not None and max(bound[0], bound[1] * bound[2]) * CELL_BYTES <= cap:
            continue
        exact = _sheet_extent_exact(_xml_chunks(zf, member, name, cap, size))
        if exact is None:
            raise ReaderError(f"sheet {name!r}: a cell reference is not a plain A1 reference: its grid cannot be "
                              "bounded before it is read")
        cells, n_rows, n_cols = exact
        grid = n_rows * n_cols
        if max(grid, cells) * CELL_BYTES > cap:
            raise ReaderError(f"sheet {name!r}: its cells span {n_rows:,} rows x {n_cols:,} columns "
                              f"({grid:,} cells, {mib(grid * CELL_BYTES)} to read as a grid) but {cells:,} "
                              f"are present: more than the {mib(cap)} a {size:,}-byte workbook may take "
                              "(a stray cell far from the data?)")


def _sheet_kind(wb, name: str) -> str:
    """The kind of sheet ``name`` as calamine names it (``WorkSheet``, ``ChartSheet``, ...)."""
    for meta in wb.sheets_metadata:
        if meta.name == name:
            return str(meta.typ).rsplit(".", 1)[-1]
    return "WorkSheet"


def _is_empty(v) -> bool:
    """Whether a cell is empty (None or blank text)."""
    return v is None or (isinstance(v, str) and not v.strip())


def _trim(rows: list[list]) -> list[list]:
    """Rows without empty trailing rows and columns."""
    while rows and all(_is_empty(v) for v in rows[-1]):
        rows.pop()
    width = 0
    for r in rows:
        for j in range(len(r) - 1, -1, -1):
            if not _is_empty(r[j]):
                width = max(width, j + 1)
                break
    return [list(r[:width]) + [None] * (width - len(r[:width])) for r in rows]


def _sheet_rows(wb, name: str) -> list[list]:
    """A worksheet's cells as rows (trimmed); a sheet calamine cannot read (a damaged part of the
    zip, XML that does not parse, a sheet listed but missing) is a :class:`ReaderError`."""
    try:
        return _trim(wb.get_sheet_by_name(name).to_python(skip_empty_area=False))
    except Exception as exc:  # calamine's own errors on malformed sheets
        raise ReaderError(f"sheet {name!r} cannot be read ({exc_text(exc)})") from None


def _meta_sheet(wb) -> dict:
    """The ``meta`` sheet's key / value rows as metadata (empty without such a sheet)."""
    for name in wb.sheet_names:
        if name.strip().casefold() == "meta":
            out = {}
            for r in _sheet_rows(wb, name):
                if len(r) >= 2 and not _is_empty(r[0]) and not _is_empty(r[1]):
                    out[str(r[0]).strip()] = _meta_value(r[1])
            return out
    return {}


def _meta_value(v):
    """A ``meta`` cell as plain metadata: ISO text for dates, whole numbers as int."""
    if isinstance(v, (dt.datetime, dt.date)):
        return v.isoformat()
    if isinstance(v, float) and v.is_integer() and abs(v) < 2 ** 53:
        return int(v)
    return v


def _is_number(v) -> bool:
    """Whether a cell holds a number (a logical cell too)."""
    return isinstance(v, (int, float))  # bool is an int: a logical cell is 0 / 1


def _row_number(read: dict, key: str) -> int | None:
    """The 1-based row number ``read[key]`` (None when not given); refused when not a row number."""
    v = read.get(key)
    if v is None:
        return None
    try:
        n = int(v)
    except (TypeError, ValueError):
        raise ReaderError(f"rig.toml [read] {key} = {v!r} is not a row number") from None
    if n < 1:
        raise ReaderError(f"rig.toml [read] {key} = {n}: sheet rows are numbered from 1")
    return n


def _as_datetime(v) -> dt.datetime | None:
    """A date or date-time cell as a datetime (a date at midnight); None for anything else."""
    if isinstance(v, dt.datetime):
        return v
    if isinstance(v, dt.date):
        return dt.datetime(v.year, v.month, v.day)
    return None


def _column(values: list) -> tuple[str, pa.Array, str | None]:
    """(kind, array, first datetime iso) of one column's data cells.

    kind: ``float`` (numbers, empty -> NaN), ``datetime`` (seconds since the first value),
    ``duration`` (seconds) or ``string``.
    """
    if values and not isinstance(values[0], str):
        try:  # fast path: a column of numbers only (bool is a number), converted in C
            return "float", pa.array(np.array(values, dtype=float)), None
        except (TypeError, ValueError):
            pass
    present = [v for v in values if not _is_empty(v)]
    if present and all(_as_datetime(v) is not None for v in present):
        stamps = [_as_datetime(v) for v in values]
        t0 = next(s for s in stamps if s is not None)
        secs = [math.nan if s is None else (s - t0).total_seconds() for s in stamps]
        return "datetime", pa.array(np.asarray(secs, dtype=float)), t0.isoformat()
    if present and all(isinstance(v, (dt.timedelta, dt.time)) for v in present):
        def secs(v):
            if isinstance(v, dt.timedelta):
                return v.total_seconds()
            if isinstance(v, dt.time):
                return v.hour * 3600 + v.minute * 60 + v.second + v.microsecond * 1e-6
            return math.nan
        return "duration", pa.array(np.asarray([secs(v) for v in values], dtype=float)), None
    if all(_is_empty(v) or _is_number(v) for v in values):
        arr = np.asarray([math.nan if _is_empty(v) else float(v) for v in values], dtype=float)
        return "float", pa.array(arr), None
    return "string", pa.array([None if _is_empty(v) else str(v) for v in values], type=pa.string()), None


def read_excel(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open a spreadsheet export (one sheet = one run).

    Parameters
    ----------
    path : path-like
        The workbook.
    read : dict, optional
        ``rig.toml`` ``[read]``: ``sheet``, ``skip_rows``, ``header_row``, ``units_row``.
    hints : dict, optional
        Run metadata known before opening (manifest over rig.toml): ``sheet``.

    Returns
    -------
    RawExport
    """
    path = Path(path)
    read = dict(read or {})
    hints = dict(hints or {})
    wb, name, rows = _open_sheet(path, read, hints)
    metadata, i = _sheet_metadata(wb, name, rows, read)
    layout = _layout(name, rows, read, i)
    columns, arrays = _columns(name, layout, metadata)
    metadata.setdefault("sheet", name)
    keys = [c.key for c in columns]
    n = len(layout.data)

    def batches() -> Iterator[pa.RecordBatch]:
        for a in range(0, n, BATCH_ROWS):
            yield pa.RecordBatch.from_arrays([arr.slice(a, BATCH_ROWS) for arr in arrays], names=keys)

    return RawExport(format=FORMAT, columns=columns, metadata=metadata, batches=batches, warnings=[])


def _open_sheet(path: Path, read: dict, hints: dict) -> tuple[object, str, list[list]]:
    """The workbook, the name of the run's sheet and its cells as rows (trimmed); refused when
    that sheet is a chart sheet, too large a grid (:func:`_check_sheet_extent`) or empty."""
    wb = _open_workbook(path)
    name = _pick_sheet(wb, hints.get("sheet", read.get("sheet")))
    if _sheet_kind(wb, name) != "WorkSheet":
        raise ReaderError(f"sheet {name!r} is a {_sheet_kind(wb, name)}, not a worksheet: it holds no cells "
                          "(name the data sheet with the `sheet` key)")
    _check_sheet_extent(path, [name] + [n for n in wb.sheet_names if n.strip().casefold() == "meta"])
    rows = _sheet_rows(wb, name)
    if not rows:
        raise ReaderError(f"sheet {name!r} is empty (no cells with values)")
    return wb, name, rows


def _sheet_metadata(wb, name: str, rows: list[list], read: dict) -> tuple[dict, int]:
    """The run's metadata (the ``meta`` sheet and the sheet's own ``# key: value`` cells, in the
    precedence the module docstring gives) and the index of the first row after those cells."""
    metadata = _meta_sheet(wb)
    # one run per sheet: a sheet's own `# key: value` cells beat the workbook's `meta` sheet
    own: dict | None = {} if str(read.get(PARTS_KEY, "")).strip().casefold() == "all" else None
    i, notes = 0, []
    while i < len(rows) and (all(_is_empty(v) for v in rows[i])
                             or (isinstance(rows[i][0], str) and rows[i][0].lstrip().startswith("#"))):
        first = rows[i][0]
        if isinstance(first, str) and first.lstrip().startswith("#"):
            kv = parse_key_value(first.lstrip()[1:])
            if kv and own is not None:
                own.setdefault(kv[0], kv[1])
            elif kv:
                metadata.setdefault(kv[0], kv[1])
            elif first.lstrip()[1:].strip():   # not `key: value`: a comment, kept whole
                notes.append(first.lstrip()[1:].strip())
        i += 1
    if notes:
        (own if own is not None else metadata).setdefault("comments", notes)
    if own is not None:
        # the `meta` sheet's run_id is the workbook's: each sheet's run is `<run_id>/<sheet>`
        shared = [k for k in metadata if str(k).strip().casefold() == "run_id"]
        if shared and not any(str(k).strip().casefold() == "run_id" for k in own):
            metadata[shared[-1]] = f"{metadata[shared[-1]]}/{name}"
        metadata.update(own)
    return metadata, i


@dataclass(frozen=True)
class _Layout:
    """Where a sheet's table is: the header row (0-based index ``h`` and its cells), the units
    row's cells (None without one) and the data rows."""

    h: int
    header: list
    units: list | None
    data: list[list]


def _layout(name: str, rows: list[list], read: dict, i: int) -> _Layout:
    """Header row, units row and data rows of a sheet whose metadata cells end before row
    index ``i`` (``[read] skip_rows``, ``header_row``, ``units_row`` applied)."""
    header_row = _row_number(read, "header_row")
    units_row = _row_number(read, "units_row")
    h = header_row - 1 if header_row else i + int(read.get("skip_rows", 0) or 0)
    if h >= len(rows):
        raise ReaderError(f"sheet {name!r} has no header row (row {h + 1} is past its last row {len(rows)})")
    header = rows[h]
    units = None
    after = h + 1
    if units_row:
        if units_row - 1 >= len(rows) or units_row - 1 <= h:
            raise ReaderError(f"rig.toml [read] units_row = {units_row} is not a row under the header (row {h + 1})")
        units = rows[units_row - 1]
        after = units_row
    start = after
    while start < len(rows) and not any(_is_number(v) or _as_datetime(v) is not None for v in rows[start]):
        start += 1
    data = rows[start:]
    if not data:
        raise ReaderError(f"sheet {name!r} has a header (row {h + 1}) but no data rows with numbers")
    return _Layout(h, header, units, data)


def _columns(name: str, layout: _Layout, metadata: dict) -> tuple[list[RawColumn], list[pa.Array]]:
    """The sheet's named columns and their values; the first date-time of a time column gives
    ``metadata["started_at"]`` when it has none."""
    columns: list[RawColumn] = []
    arrays: list[pa.Array] = []
    by_column = [list(c) for c in zip(*layout.data)]
    for j, cell in enumerate(layout.header):
        if _is_empty(cell):
            if all(_is_empty(v) for v in by_column[j]):
                continue
            raise ReaderError(f"sheet {name!r}: column {j + 1} has data but no name in the header (row {layout.h + 1})")
        text = str(cell).strip()
        cname, unit = split_name_unit(text)
        if layout.units is not None and not _is_empty(layout.units[j]):
            unit = str(layout.units[j]).strip()
        kind, arr, first_stamp = _column(by_column[j])
        if kind in ("datetime", "duration"):
            unit = "s"
            if kind == "datetime" and first_stamp and "started_at" not in metadata and cname.casefold() in ("t", "time"):
                metadata["started_at"] = first_stamp
        columns.append(RawColumn(key=f"c{j}", name=cname, unit=unit, index=j + 1,
                                 dtype="string" if kind == "string" else "float", header=text))
        arrays.append(arr)
    if not columns:
        raise ReaderError(f"sheet {name!r} has no named columns")
    return columns, arrays
