"""Write an open query result (:class:`pipeline.serve.query.Result`): CSV, JSON, Markdown, an
aligned table fitted to the terminal, or one record per block; streamed, memory bounded by one
batch. Also the cell rule that keeps spreadsheets from running a text cell as a formula
(:func:`neutralise_cell`, the report's CSV downloads use it too).
"""
from __future__ import annotations

import csv
import io
import json
import math
import re
import shutil
import textwrap
import uuid
import warnings
from datetime import date, datetime, time
from decimal import Decimal
from typing import IO, Iterator

from pipeline.serve.query import BATCH_ROWS, Result

# pyarrow costs 0.15 s of a query's start-up: only the CSV writers import it, where they use it.


def _plain(v):
    """A value as JSON can hold it (times as ISO text, NaN and inf as None, bytes as hex)."""
    if isinstance(v, (datetime, date, time)):
        return v.isoformat()
    if isinstance(v, uuid.UUID):
        return str(v)
    if isinstance(v, Decimal):
        return float(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (bytes, bytearray)):
        return v.hex()
    return v


#: Rows the ``table`` format shows by default (it says how many more there are).
MAX_ROWS = 100
#: The formats :func:`write_result` writes.
FORMATS = ("auto", "table", "line", "csv", "json", "markdown")
#: ``auto`` shows one record per block (``line``) when fitting the table to the terminal would wrap
#: a column narrower than its header or than this many characters (or than its natural width,
#: when that is less): below it, a cell becomes a tower of fragments nobody can read.
NARROWEST = 10


def _rows(batch) -> list[tuple]:
    """An Arrow record batch as row tuples."""
    cols = [c.to_pylist() for c in batch.columns]
    return list(zip(*cols)) if cols else []


def _row_batches(result: Result) -> Iterator[list[tuple]]:
    """The result's batches as lists of row tuples, whether they come as Arrow or as tuples."""
    for batch in result.batches:
        yield batch if isinstance(batch, list) else _rows(batch)


def _count_rest(cur) -> int:
    """Rows left in a cursor: the first 100,000 fetched as tuples (no pyarrow to import for a
    result of a few thousand rows), the rest counted as Arrow batches (never turned into Python
    values)."""
    n = 0
    for _ in range(10):
        rows = cur.fetchmany(10_000)
        n += len(rows)
        if len(rows) < 10_000:
            return n

    with warnings.catch_warnings():  # "an extra copy of the rows": only their number is kept
        warnings.simplefilter("ignore")
        return n + sum(b.num_rows for b in cur.to_arrow_reader(BATCH_ROWS))


#: First characters that make a spreadsheet run a text cell as a formula (OWASP, "CSV Injection").
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def neutralise_cell(v):
    """A text cell a spreadsheet would run as a formula (``=HYPERLINK(...)``, ``@SUM(...)``) with
    a ``'`` put before it, as OWASP advises; every other value unchanged (a number such as -1.5
    stays a number: the advice is for text cells). Used by the report's CSV downloads and by
    ``pneubench query --format csv --csv-safe``."""
    if isinstance(v, str) and v.startswith(FORMULA_START):
        return "'" + v
    return v


def _safe_column(col):
    """An Arrow text column through :func:`neutralise_cell` (other columns unchanged)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if not (pa.types.is_string(col.type) or pa.types.is_large_string(col.type)):
        return col
    pattern = "^[" + "".join(re.escape(c) for c in FORMULA_START) + "]"
    if not pc.any(pc.match_substring_regex(col, pattern)).as_py():
        return col
    return pa.array([neutralise_cell(v) for v in col.to_pylist()], pa.string())


def _csv_cell(v):
    if v is None:
        return ""
    if isinstance(v, (list, dict, tuple)):
        return json.dumps(_plain(v), ensure_ascii=False)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ""
    if isinstance(v, bool):
        return "true" if v else "false"
    return _plain(v)


def _csv_column(col):
    """An Arrow column ready for Arrow's CSV writer (its unsupported types as text)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    t = col.type
    if pa.types.is_floating(t):
        return pc.if_else(pc.is_finite(col), col, pa.scalar(None, t))
    if pa.types.is_dictionary(t):
        return _csv_column(col.dictionary_decode())
    if (pa.types.is_nested(t) or pa.types.is_binary(t) or pa.types.is_large_binary(t) or pa.types.is_time(t)
            or pa.types.is_duration(t) or pa.types.is_interval(t) or pa.types.is_fixed_size_binary(t)):
        return pa.array([None if v is None else str(_csv_cell(v)) for v in col.to_pylist()], pa.string())
    return col


def write_csv(result: Result, out: IO[str], safe: bool = False) -> int:
    """Write the result as CSV: header first; NULL, NaN and inf empty; lists and structs as JSON.

    Batches go through Arrow's CSV writer (values quoted only where a batch needs it). The
    data is exact; ``safe``: text cells a spreadsheet would run as formulas get a leading ``'``
    (:func:`neutralise_cell`).
    """
    import pyarrow as pa
    import pyarrow.csv as pcsv

    cell = neutralise_cell if safe else (lambda v: v)
    csv.writer(out, lineterminator="\n").writerow([cell(c) for c in result.columns])
    n = 0
    for batch in result.batches:
        if isinstance(batch, list):  # rows already in Python
            csv.writer(out, lineterminator="\n").writerows([_csv_cell(cell(v)) for v in r] for r in batch)
            n += len(batch)
            continue
        columns = [_csv_column(c) for c in batch.columns]
        if safe:
            columns = [_safe_column(c) for c in columns]
        ready = pa.RecordBatch.from_arrays(columns,
                                           names=[f"c{i}" for i in range(batch.num_columns)])
        buf = io.BytesIO()
        try:
            pcsv.write_csv(ready, buf, pcsv.WriteOptions(include_header=False, quoting_style="none"))
        except pa.ArrowInvalid:  # a delimiter, quote or line break in a value: quote this batch
            buf = io.BytesIO()
            pcsv.write_csv(ready, buf, pcsv.WriteOptions(include_header=False, quoting_style="needed"))
        out.write(buf.getvalue().decode("utf-8"))
        n += batch.num_rows
    return n


def _json_value(v, is_json: bool):
    if is_json and isinstance(v, str):
        try:  # NaN and infinities (to_json writes them) are null, as in a plain column
            return json.loads(v, parse_constant=lambda _c: None)
        except ValueError:
            return v
    return _plain(v)


def write_json(result: Result, out: IO[str]) -> int:
    """Write the result as a JSON array of objects, one per line; JSON columns (``params``) nested."""
    is_json = [t == "JSON" for t in result.types]
    n = 0
    out.write("[")
    for rows in _row_batches(result):
        for r in rows:
            obj = {c: _json_value(v, j) for c, v, j in zip(result.columns, r, is_json)}
            out.write(("\n" if n == 0 else ",\n") + json.dumps(obj, ensure_ascii=False, allow_nan=False))
            n += 1
    out.write("\n]\n" if n else "]\n")
    return n


def _md_cell(v) -> str:
    text = "" if v is None else (json.dumps(_plain(v), ensure_ascii=False) if isinstance(v, (list, dict)) else
                                 str(v) if isinstance(v, Decimal) else str(_plain(v)))
    return text.replace("\\", "\\\\").replace("|", "\\|").replace("\r", "").replace("\n", "<br>")


def write_markdown(result: Result, out: IO[str]) -> int:
    """Write the result as a GitHub Markdown table (every row)."""
    out.write("| " + " | ".join(_md_cell(c) for c in result.columns) + " |\n")
    out.write("|" + "|".join("---:" if is_numeric(t) else "---" for t in result.types) + "|\n")
    n = 0
    for rows in _row_batches(result):
        for r in rows:
            out.write("| " + " | ".join(_md_cell(v) for v in r) + " |\n")
            n += 1
    return n


def is_numeric(duck_type: str) -> bool:
    """Whether a DuckDB type name is a number's (right-aligned in tables, plotted)."""
    return duck_type.split("(")[0] in ("BIGINT", "INTEGER", "SMALLINT", "TINYINT", "HUGEINT", "UBIGINT", "UINTEGER",
                                       "USMALLINT", "UTINYINT", "UHUGEINT", "DOUBLE", "FLOAT", "DECIMAL")


def _table_cell(v) -> str:
    if v is None:
        return "NULL"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, Decimal):  # exact: a DECIMAL(38) is not a double
        return str(v)
    if isinstance(v, (list, dict)):
        return json.dumps(_plain(v), ensure_ascii=False)
    return str(_plain(v))


def fit_widths(natural: list[int], total: int | None, cap: int | None = None, floor: int = 6) -> list[int]:
    """Column widths: each at most ``cap``; the widest shrunk first until the line fits ``total``.

    ``None`` for ``total`` / ``cap``: no limit. A column never gets narrower than ``floor``
    (or its natural width when that is smaller), so very many columns can still overflow.
    """
    widths = [min(w, cap) if cap else w for w in natural]
    if total is None:
        return widths
    mins = [min(w, floor) for w in widths]
    while sum(widths) + 2 * (len(widths) - 1) > total:
        i = max(range(len(widths)), key=lambda k: widths[k] - mins[k])
        if widths[i] <= mins[i]:
            break
        widths[i] -= 1
    return widths


def _wrap(text: str, width: int) -> list[str]:
    lines = []
    for part in text.splitlines() or [""]:
        lines += textwrap.wrap(part, width, break_long_words=True, replace_whitespace=False,
                               drop_whitespace=True) or [""]
    return lines


def format_table(columns: list[str], types: list[str], rows: list[tuple], n_total: int | None = None,
                 width: int | None = None, max_width: int | None = None) -> str:
    """Aligned text table; cells wrap within their column.

    Parameters
    ----------
    width : int, optional
        Line width to fit (the terminal's); None: no limit.
    max_width : int, optional
        Widest a column may be; None: only ``width`` limits; 0: no limit at all (cells whole,
        never wrapped).
    n_total : int, optional
        Rows of the whole result when ``rows`` is only its start.
    """
    body = [[_table_cell(v) for v in r] for r in rows]
    natural = [max([len(c)] + [max((len(x) for x in b[i].splitlines()), default=0) for b in body])
               for i, c in enumerate(columns)]
    if max_width == 0:
        widths = natural
    else:
        widths = fit_widths(natural, width, max_width or None)
    numeric = [is_numeric(t) for t in types] if types else [False] * len(columns)

    def lines(cells):
        wrapped = [_wrap(c, w) if len(c) > w or "\n" in c else [c] for c, w in zip(cells, widths)]
        height = max((len(x) for x in wrapped), default=1)
        out = []
        for k in range(height):
            parts = []
            for cell, w, num in zip(wrapped, widths, numeric):
                text = cell[k] if k < len(cell) else ""
                parts.append(text.rjust(w) if num else text.ljust(w))
            out.append("  ".join(parts).rstrip())
        return out

    out = lines(columns) + ["  ".join("-" * w for w in widths)]
    for b in body:
        out += lines(b)
    total = len(rows) if n_total is None else n_total
    if total > len(rows):
        out.append(f"({len(rows)} of {total} rows shown, {total - len(rows)} more: --max-rows 0 shows all, "
                   "--format csv streams them)")
    else:
        out.append(f"({total} row{'s' if total != 1 else ''})")
    return "\n".join(out)


def write_table(result: Result, out: IO[str], max_rows: int = MAX_ROWS, width: int | None = None,
                max_width: int | None = None, auto: bool = False) -> int:
    """Write the first ``max_rows`` rows (0: all) as a table and count the rest. Returns all rows.

    ``auto``: one record per block instead (:func:`format_records`) when the table does not fit
    ``width`` (:func:`table_squashed`)."""
    shown: list[tuple] = []
    n = 0
    if result.cursor is not None and max_rows:  # only the rows shown become Python values
        shown = result.cursor.fetchmany(max_rows)
        n = len(shown)
        if n == max_rows and result.cursor.fetchmany(1):
            n += 1 + _count_rest(result.cursor)
        out.write(_table_or_records(result, shown, n, width, max_width, auto) + "\n")
        return n
    for rows in _row_batches(result):
        if not max_rows or len(shown) < max_rows:
            shown += rows[: (max_rows - len(shown)) if max_rows else None]
        n += len(rows)
    out.write(_table_or_records(result, shown, n, width, max_width, auto) + "\n")
    return n


def _table_or_records(result: Result, shown: list[tuple], n: int, width: int | None, max_width: int | None,
                      auto: bool) -> str:
    if auto and table_squashed(result.columns, shown, width, max_width):
        return format_records(result.columns, shown, n, width, max_width)
    return format_table(result.columns, result.types, shown, n, width, max_width)


def table_squashed(columns: list[str], rows: list[tuple], width: int | None, max_width: int | None = None) -> bool:
    """Whether :func:`format_table` fitting ``rows`` into ``width`` wraps a column narrower than
    its header or than :data:`NARROWEST` characters (or than its natural width, when that is
    less). Never when nothing limits the width or ``max_width`` is 0 (never wrap); with no rows,
    when the headers alone would wrap."""
    if width is None or max_width == 0 or not columns:
        return False
    body = [[_table_cell(v) for v in r] for r in rows]
    natural = [max([len(c)] + [max((len(x) for x in b[i].splitlines()), default=0) for b in body])
               for i, c in enumerate(columns)]
    natural = [min(w, max_width) if max_width else w for w in natural]
    widths = fit_widths(natural, width, max_width or None)
    return any(w < min(nat, max(len(c), NARROWEST)) for w, nat, c in zip(widths, natural, columns))


def _value_width(columns: list[str], width: int | None, max_width: int | None) -> int | None:
    """Width a value of :func:`format_records` wraps at: ``max_width``, else what the terminal
    leaves beside the names (at least :data:`NARROWEST`); None: never wrap."""
    if max_width == 0:
        return None
    if max_width:
        return max_width
    if width is None:
        return None
    return max(width - max((len(c) for c in columns), default=0) - 3, NARROWEST)


def _record(k: int, columns: list[str], row: tuple, value_width: int | None) -> str:
    """Record ``k`` as psql's expanded display: a ``-[ RECORD k ]---`` line, then ``name | value``
    lines; a long or multi-line value continues on lines of its own under the ``|``, wrapped at
    spaces only: a longer word (a hash, a path) stays whole on its line, to be copied."""
    name_w = max((len(c) for c in columns), default=0)
    lines = []
    for c, v in zip(columns, row):
        text = _table_cell(v)
        parts = [line for part in text.splitlines() or [""]  # a word (hash, path, id) stays whole to copy
                 for line in (textwrap.wrap(part, value_width, break_long_words=False, break_on_hyphens=False)
                              if value_width and len(part) > value_width else [part]) or [""]]
        lines += [f"{c if i == 0 else '':<{name_w}} | {part}".rstrip() for i, part in enumerate(parts)]
    label = f"-[ RECORD {k} ]"
    rule = max((len(x) for x in lines), default=0)
    if value_width:
        rule = min(rule, name_w + 3 + value_width)  # an overlong word does not stretch the rule
    return "\n".join([label.ljust(rule, "-")] + lines)


def _rows_footer(shown: int, total: int) -> str:
    if total > shown:
        return (f"({shown} of {total} rows shown, {total - shown} more: --max-rows 0 shows all, "
                "--format csv streams them)")
    return f"({total} row{'s' if total != 1 else ''})"


def format_records(columns: list[str], rows: list[tuple], n_total: int | None = None, width: int | None = None,
                   max_width: int | None = None) -> str:
    """One record per block (psql's expanded display), for results too wide for a table.

    ``width``: the terminal's, long values wrap within what the names leave of it; ``max_width``
    caps a value's line (0: never wrap); ``n_total`` as for :func:`format_table`."""
    vw = _value_width(columns, width, max_width)
    out = [_record(k, columns, r, vw) for k, r in enumerate(rows, 1)]
    return "\n".join(out + [_rows_footer(len(rows), len(rows) if n_total is None else n_total)])


def write_line(result: Result, out: IO[str], max_rows: int = MAX_ROWS, width: int | None = None,
               max_width: int | None = None) -> int:
    """Stream the first ``max_rows`` rows (0: all) one record per block (:func:`format_records`)
    and count the rest; memory holds one batch. Returns all rows."""
    vw = _value_width(result.columns, width, max_width)
    shown = total = 0
    if result.cursor is not None and max_rows:  # only the rows shown become Python values
        batches = iter([result.cursor.fetchmany(max_rows)])
    else:
        batches = _row_batches(result)
    for rows in batches:
        for r in rows if not max_rows else rows[: max(max_rows - shown, 0)]:
            shown += 1
            out.write(_record(shown, result.columns, r, vw) + "\n")
        total += len(rows)
        if max_rows and shown >= max_rows:
            if result.cursor is not None:
                total += _count_rest(result.cursor)
            else:
                total += sum(len(rows) for rows in batches)
            break
    out.write(_rows_footer(shown, total) + "\n")
    return total


def write_result(result: Result, out: IO[str], fmt: str = "table", max_rows: int = MAX_ROWS,
                 width: int | None = None, max_width: int | None = None, csv_safe: bool = False) -> int:
    """Write an open result in ``fmt`` (one of :data:`FORMATS`). Returns the number of rows.

    ``csv_safe``: see :func:`write_csv`."""
    if fmt == "csv":
        return write_csv(result, out, safe=csv_safe)
    if fmt == "json":
        return write_json(result, out)
    if fmt == "markdown":
        return write_markdown(result, out)
    if fmt in ("table", "auto"):
        return write_table(result, out, max_rows, width, max_width, auto=fmt == "auto")
    if fmt == "line":
        return write_line(result, out, max_rows, width, max_width)
    raise ValueError(f"unknown format {fmt!r}")


def terminal_width() -> int:
    """Columns of the terminal (``$COLUMNS`` first; 80 when unknown)."""
    return shutil.get_terminal_size((80, 24)).columns
