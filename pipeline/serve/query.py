"""Read-only SQL on the warehouse; results as a table, CSV, JSON or Markdown, streamed in batches;
the catalogue of tables (``tables``, ``describe``), one run's channels as a plot, the figures."""
from __future__ import annotations

import csv
import difflib
import io
import json
import math
import os
import re
import shutil
import textwrap
import threading
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import date, datetime, time
from decimal import Decimal
from pathlib import Path
from typing import IO, TYPE_CHECKING, Iterator

import duckdb

from pipeline.warehouse import INTERNAL_TABLES, MEMORY_LIMIT_ENV, TEMP_LIMIT_ENV, connect_readonly
from schemas.units import COLUMN_UNITS, column_unit

if TYPE_CHECKING:
    import pyarrow as pa


class QueryError(ValueError):
    """SQL that ``pneubench query`` refuses (one line: what and why)."""


class QueryLimitError(RuntimeError):
    """A statement stopped by a limit of the door: its memory, its spill files or its time (one
    line naming the limit and how to raise it)."""


#: Default statement timeout of ``pneubench query`` in seconds (README); ``$PNEUBENCH_QUERY_TIMEOUT``
#: overrides it, ``--timeout`` both; 0: none. Wall-clock time from the start of the statement
#: to its last row written.
TIMEOUT_S = 600.0
TIMEOUT_ENV = "PNEUBENCH_QUERY_TIMEOUT"


def _timeout_s(value: float | None) -> float:
    if value is None:
        text = os.environ.get(TIMEOUT_ENV, "").strip()
        try:
            value = float(text) if text else TIMEOUT_S
        except ValueError:
            raise QueryError(f"${TIMEOUT_ENV} = {text!r}: a number of seconds (0: no timeout)") from None
    if not value >= 0:
        raise QueryError(f"timeout {value!r}: a number of seconds >= 0 (0: no timeout)")
    return float(value)


@contextmanager
def _limited(con: duckdb.DuckDBPyConnection, timeout_s: float | None):
    """Run the body under the statement timeout (a watchdog thread calls ``con.interrupt()``:
    DuckDB has no statement timeout before 1.5, and this one also covers fetching the rows) and
    turn DuckDB's "Out of Memory" into one line naming the door's limit that was reached."""
    seconds = _timeout_s(timeout_s)
    fired = threading.Event()

    def stop():
        fired.set()
        con.interrupt()

    timer = threading.Timer(seconds, stop) if seconds else None
    if timer is not None:
        timer.daemon = True
        timer.start()
    try:
        yield
    except (duckdb.Error, OSError) as exc:  # Arrow's reader raises DuckDB's errors as OSError
        text = str(exc).strip()
        if fired.is_set() and (isinstance(exc, duckdb.InterruptException) or text.startswith("INTERRUPT Error")):
            raise QueryLimitError(f"statement timeout: stopped after {seconds:g} s (--timeout SECONDS or "
                                  f"${TIMEOUT_ENV} gives it longer; 0: no timeout)") from None
        if not (isinstance(exc, duckdb.OutOfMemoryException) or text.startswith("Out of Memory Error")):
            raise
        first = text.splitlines()[0]
        if "max_temp_directory_size" in str(exc):
            size = con.execute("SELECT current_setting('max_temp_directory_size')").fetchone()[0]
            raise QueryLimitError(f"{first} (the door's spill files are limited to max_temp_directory_size "
                                  f"{size}: --temp-limit or ${TEMP_LIMIT_ENV} raises it)") from None
        size = con.execute("SELECT current_setting('memory_limit')").fetchone()[0]
        raise QueryLimitError(f"{first} (the door's memory_limit is {size}: --memory-limit or "
                              f"${MEMORY_LIMIT_ENV} raises it)") from None
    finally:
        if timer is not None:
            timer.cancel()


_READ_ONLY = ("pneubench query is read-only: one SELECT, FROM, WITH, DESCRIBE, SHOW, SUMMARIZE or "
              "EXPLAIN statement over the warehouse")

#: Statement types a query may run: reading only.
_READ_TYPES = {duckdb.StatementType.SELECT}


def _statement_types(con: duckdb.DuckDBPyConnection, sql: str) -> list[str]:
    """Type name of each statement of ``sql``, by DuckDB's own parser."""
    out = []
    for st in con.extract_statements(sql):
        try:
            out.append(st.type.name)
        except ValueError:  # a statement type the Python enum does not know yet
            out.append("UNKNOWN")
    return out


def _explained(sql: str) -> str:
    """The statement an ``EXPLAIN [ANALYZE] [(options)]`` statement explains."""
    tokens = duckdb.tokenize(sql)
    depth = 0
    for i, (offset, kind) in enumerate(tokens):
        end = tokens[i + 1][0] if i + 1 < len(tokens) else len(sql)
        text = sql[offset:end].strip()
        if kind == duckdb.token_type.comment:
            continue
        if kind == duckdb.token_type.operator and (depth or text.startswith("(")):
            depth += text.count("(") - text.count(")")
            continue
        if depth or (kind == duckdb.token_type.keyword and text.upper() in ("EXPLAIN", "ANALYZE", "ANALYSE")):
            continue
        return sql[offset:]
    return ""


def check_sql(con: duckdb.DuckDBPyConnection, sql: str) -> str:
    """Refuse anything but one read-only statement; returns the SQL to run.

    The statement is classified by DuckDB's parser: only ``SELECT`` (which includes
    ``FROM ...``, ``WITH ...``, ``DESCRIBE``, ``SHOW``, ``SUMMARIZE``, ``VALUES``) and ``EXPLAIN``
    of such a statement pass. Writes, ``COPY``, ``EXPORT``, ``ATTACH``/``DETACH``,
    ``INSTALL``/``LOAD``, ``SET``/``RESET``/``PRAGMA``/``CALL``, transactions and several
    statements at once raise :class:`QueryError`. The connection (:func:`connect_readonly`)
    contains what a ``SELECT`` may read.
    """
    if not sql or not sql.strip():
        raise QueryError("no SQL given")
    types = _statement_types(con, sql)
    if not types:
        raise QueryError("no SQL statement given (only comments or ';')")
    if len(types) > 1:
        raise QueryError(f"one statement per call, got {len(types)} ({', '.join(types)})")
    kind = types[0]
    if kind == "EXPLAIN":
        inner = _explained(sql)
        inner_types = _statement_types(con, inner) if inner.strip() else []
        if inner_types != ["SELECT"]:
            raise QueryError(f"EXPLAIN of {'/'.join(inner_types) or 'nothing'} refused: {_READ_ONLY}")
        return sql
    if kind not in {t.name for t in _READ_TYPES}:
        hint = " (write a result out with --format csv > FILE)" if kind in ("COPY", "EXPORT") else ""
        if kind == "MULTI":
            hint = " (a PIVOT needs its values listed: PIVOT t ON col IN ('a', 'b'))"
        raise QueryError(f"{kind} statement refused: {_READ_ONLY}{hint}")
    return sql


@contextmanager
def _no_samples_explained(sql: str):
    """DuckDB's "No files found that match the pattern" from ``samples('<run_id>')`` (a run_id
    the warehouse does not have, or a run without samples) as a :class:`QueryError` that says so."""
    try:
        yield
    except duckdb.IOException as exc:
        if "No files found" in str(exc) and re.search(r"\bsamples\s*\(", sql, re.IGNORECASE):
            raise QueryError("samples('<run_id>') found no samples file: no run with that run_id has samples in "
                             "this warehouse (SELECT run_id, samples_path FROM runs lists them)") from None
        raise


def _connect(warehouse: str | Path, memory_limit: str | None, temp_limit: str | None) -> duckdb.DuckDBPyConnection:
    try:
        return connect_readonly(Path(warehouse), memory_limit=memory_limit, temp_limit=temp_limit)
    except ValueError as exc:  # a limit that is not a size
        raise QueryError(str(exc)) from None


def run_query(warehouse: str | Path, sql: str, timeout_s: float | None = None, memory_limit: str | None = None,
              temp_limit: str | None = None) -> tuple[list[str], list[tuple]]:
    """Run one read-only statement on the warehouse. Returns (column names, rows).

    Raises :class:`QueryError` for SQL the door refuses, ``duckdb.Error`` for SQL DuckDB
    refuses (including every attempt to reach a file outside the warehouse's samples),
    :class:`QueryLimitError` when a limit stops it (``timeout_s``: :data:`TIMEOUT_S`; the memory
    and spill limits: :func:`pipeline.warehouse.connect_readonly`), ``FileNotFoundError`` when
    there is no warehouse.
    """
    con = _connect(warehouse, memory_limit, temp_limit)
    try:
        with _limited(con, timeout_s):
            with _no_samples_explained(sql):
                cur = con.execute(check_sql(con, sql))
            if cur.description is None:
                return [], []
            return [d[0] for d in cur.description], cur.fetchall()
    finally:
        con.close()


def _plain(v):
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


# ---------------------------------------------------------------------------------------------
# Streaming results

#: Rows fetched from DuckDB at a time: memory is bounded by one batch, whatever the result size.
BATCH_ROWS = 65_536
#: Rows the ``table`` format shows by default (it says how many more there are).
MAX_ROWS = 100
FORMATS = ("auto", "table", "line", "csv", "json", "markdown")
#: ``auto`` shows one record per block (``line``) when fitting the table to the terminal would wrap
#: a column narrower than its header or than this many characters (or than its natural width,
#: when that is less): below it, a cell becomes a tower of fragments nobody can read.
NARROWEST = 10


@dataclass
class Result:
    """An open result: column names, DuckDB type names, and an iterator of Arrow record batches."""

    columns: list[str]
    types: list[str]
    batches: Iterator["pa.RecordBatch"]
    #: the DuckDB cursor the rows come from, when they are fetched as tuples (``arrow=False``)
    cursor: object = None


def _rows(batch) -> list[tuple]:
    cols = [c.to_pylist() for c in batch.columns]
    return list(zip(*cols)) if cols else []


def _row_batches(result: Result) -> Iterator[list[tuple]]:
    for batch in result.batches:
        yield batch if isinstance(batch, list) else _rows(batch)


def _fetch_batches(cur, batch_rows: int) -> Iterator[list[tuple]]:
    while rows := cur.fetchmany(batch_rows):
        yield rows


def _count_rest(cur) -> int:
    """Rows left in a cursor: the first 100,000 fetched as tuples (no pyarrow to import for a
    result of a few thousand rows), the rest counted as Arrow batches (never turned into Python
    values)."""
    import warnings

    n = 0
    for _ in range(10):
        rows = cur.fetchmany(10_000)
        n += len(rows)
        if len(rows) < 10_000:
            return n

    with warnings.catch_warnings():  # "an extra copy of the rows": only their number is kept
        warnings.simplefilter("ignore")
        return n + sum(b.num_rows for b in cur.to_arrow_reader(BATCH_ROWS))


@contextmanager
def open_query(warehouse: str | Path, sql: str, batch_rows: int = BATCH_ROWS, arrow: bool = True,
               timeout_s: float | None = None, memory_limit: str | None = None,
               temp_limit: str | None = None) -> Iterator[Result]:
    """Check and start one read-only statement; the result is read in batches of ``batch_rows``.

    ``arrow``: batches are Arrow record batches (what :func:`write_csv` streams); otherwise lists
    of row tuples, and pyarrow is never imported (0.15 s of a query's start-up). Columns of a
    type Python or Arrow cannot carry exactly come as DuckDB's text of them (:func:`_printable`).

    Raises :class:`QueryError`, ``duckdb.Error`` or ``FileNotFoundError`` (see :func:`run_query`)
    before anything is yielded; :class:`QueryLimitError` when a limit stops the statement, also
    while its rows are read (the timeout covers the whole ``with`` block).
    """
    con = _connect(warehouse, memory_limit, temp_limit)
    try:
        with _limited(con, timeout_s):
            with _no_samples_explained(sql):
                checked, bound = _printable(con, check_sql(con, sql))
                rel = (bound if bound is not None else con.sql(checked)) if arrow else None
                cur = None if arrow else con.execute(checked)
            if arrow:
                if rel is None:
                    yield Result([], [], iter(()))
                else:
                    yield Result(list(rel.columns), [str(t) for t in rel.types],
                                 iter(rel.to_arrow_reader(batch_rows)))
            else:
                desc = cur.description or []
                yield Result([d[0] for d in desc], [str(d[1]) for d in desc], _fetch_batches(cur, batch_rows),
                             cursor=cur if desc else None)
    finally:
        con.close()


#: DuckDB types (``DuckDBPyType.id``) whose Python and Arrow values are what DuckDB holds; a
#: column of any other type is written as DuckDB's own text of it (INTERVAL, UHUGEINT, BIGNUM,
#: BIT, TIMETZ, TIME_NS, TIMESTAMP_NS, DATE with its infinities, and types DuckDB adds later),
#: nested ones (LIST, STRUCT, MAP, ARRAY, UNION) as JSON (``to_json``).
_NATIVE_TYPES = {"boolean", "tinyint", "smallint", "integer", "bigint", "utinyint", "usmallint", "uinteger",
                 "ubigint", "hugeint", "float", "double", "decimal", "varchar", "blob", "uuid", "time", "timestamp",
                 "timestamp_s", "timestamp_ms", "timestamp with time zone", "enum", "null"}
_NESTED_TYPES = {"list", "struct", "map", "array", "union"}


def _statement_body(sql: str) -> str:
    """``sql`` without its trailing ``;`` and comments (to be wrapped as a subquery)."""
    end = 0
    tokens = duckdb.tokenize(sql)
    for i, (offset, kind) in enumerate(tokens):
        stop = tokens[i + 1][0] if i + 1 < len(tokens) else len(sql)
        if kind != duckdb.token_type.comment and sql[offset:stop].strip() != ";":
            end = stop
    return sql[:end].rstrip().rstrip(";")


def _printable(con: duckdb.DuckDBPyConnection, sql: str) -> tuple[str, "duckdb.DuckDBPyRelation | None"]:
    """The statement with every column of a type outside :data:`_NATIVE_TYPES` as text (JSON
    for nested types), so every DuckDB type prints, exactly (issue 21): Python's ``timedelta``
    has no months, Arrow's CSV writer cannot write BIGNUM and writes a UHUGEINT above 2^127 as
    a negative number, ``DATE 'infinity'`` becomes 9999-12-31 in Python.

    Returns the SQL to run and, when it is ``sql`` itself, its bound relation (else None)."""
    rel = con.sql(sql)  # binds the statement (a SELECT is not run)
    if rel is None:
        return sql, None
    exprs, changed = [], False
    for i, (name, typ) in enumerate(zip(rel.columns, rel.types)):
        kind = typ.id
        col = f"c{i}"
        if kind in _NESTED_TYPES:
            expr = f"to_json({col})"
        elif kind in _NATIVE_TYPES or str(typ) == "JSON":
            expr = col
        else:
            expr = f"CAST({col} AS VARCHAR)"
        changed |= expr != col
        exprs.append(f'{expr} AS "{name.replace(chr(34), chr(34) * 2)}"')
    if not changed:
        return sql, rel
    cols = ", ".join(f"c{i}" for i in range(len(exprs)))
    return f"SELECT {', '.join(exprs)} FROM (\n{_statement_body(sql)}\n) AS _q({cols})", None


def read_sql(text: str | None, file: IO[str] | None = None) -> str:
    """The SQL of a call: ``text`` (``-`` reads stdin, passed as ``file``) or a file's content."""
    sql = file.read() if file is not None else (text or "")
    if not sql.strip():
        raise QueryError("no SQL given: pneubench query \"SELECT ...\", -f FILE.sql, or - to read stdin")
    return sql


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
    out.write("|" + "|".join("---:" if _numeric(t) else "---" for t in result.types) + "|\n")
    n = 0
    for rows in _row_batches(result):
        for r in rows:
            out.write("| " + " | ".join(_md_cell(v) for v in r) + " |\n")
            n += 1
    return n


def _numeric(duck_type: str) -> bool:
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
    numeric = [_numeric(t) for t in types] if types else [False] * len(columns)

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
    less). Never when nothing limits the width, ``max_width`` is 0 (never wrap) or there are no rows."""
    if width is None or max_width == 0 or not rows or not columns:
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


def format_rows(columns: list[str], rows: list[tuple], fmt: str = "table", max_width: int | None = None,
                types: list[str] | None = None) -> str:
    """Render an in-memory result (see :func:`write_result`)."""
    buf = io.StringIO()
    types = types or [("DOUBLE" if all(isinstance(r[i], (int, float)) or r[i] is None for r in rows) and rows
                       else "VARCHAR") for i in range(len(columns))]
    write_result(Result(columns, types, iter([rows])), buf, fmt, max_rows=0, max_width=max_width)
    return buf.getvalue().rstrip("\n")


# ---------------------------------------------------------------------------------------------
# Catalogue: tables and describe

#: Units of column-name suffixes (longest match wins); a column without one has no unit. The one
#: table is :data:`schemas.units.COLUMN_UNITS` (the report's headers use its short forms).
UNIT_SUFFIXES = {s: u[0] for s, u in COLUMN_UNITS.items()}


def unit_of(column: str) -> str | None:
    """Unit a warehouse column name ends in (``leak_l_min`` -> ``l/min (ANR)``), else None."""
    found = column_unit(column)
    return found[1] if found else None


def list_tables(warehouse: str | Path) -> list[dict]:
    """Tables and views of the warehouse: science first (by name), then internal ones.

    Each: ``name``, ``type`` (table/view), ``rows`` (tables only), ``internal``, ``comment``.
    """
    con = connect_readonly(Path(warehouse))
    try:
        found = con.execute(
            "SELECT table_name, 'table', estimated_size, comment FROM duckdb_tables() "
            "WHERE database_name = current_database() UNION ALL "
            "SELECT view_name, 'view', NULL, comment FROM duckdb_views() "
            "WHERE NOT internal AND database_name = current_database()").fetchall()
        out = []
        for name, typ, _est, comment in found:
            rows = con.execute(f'SELECT count(*) FROM "{name}"').fetchone()[0] if typ == "table" else None
            out.append({"name": name, "type": typ, "rows": rows, "internal": name in INTERNAL_TABLES,
                        "comment": comment})
    finally:
        con.close()
    return sorted(out, key=lambda t: (t["internal"], t["name"].startswith("samples_"), t["name"]))


def describe_table(warehouse: str | Path, table: str) -> tuple[str | None, list[dict]]:
    """(table comment, columns) of one table or view: ``column``, ``type``, ``unit``, ``comment``.

    Raises :class:`QueryError` naming the closest tables when there is none of that name.
    """
    con = connect_readonly(Path(warehouse))
    try:
        names = {r[0]: r[1] for r in con.execute(
            "SELECT table_name, comment FROM duckdb_tables() WHERE database_name = current_database() UNION ALL "
            "SELECT view_name, comment FROM duckdb_views() WHERE NOT internal "
            "AND database_name = current_database()").fetchall()}
        if table not in names:
            near = difflib.get_close_matches(table, list(names), n=3)
            raise QueryError(f"no table or view {table!r}" + (f"; did you mean {', '.join(near)}?" if near else
                                                               " (pneubench tables lists them)"))
        comments = dict(con.execute("SELECT column_name, comment FROM duckdb_columns() "
                                    "WHERE database_name = current_database() AND table_name = ?", [table]).fetchall())
        cols = [{"column": r[0], "type": r[1], "unit": unit_of(r[0]), "comment": comments.get(r[0])}
                for r in con.execute(f'DESCRIBE "{table}"').fetchall()]
    finally:
        con.close()
    return names[table], cols


# ---------------------------------------------------------------------------------------------
# One run's channels as a plot; the current figures

#: Channels of a samples view that are not signals.
_NOT_SIGNALS = ("run_id", "kind", "campaign", "t_s")


def run_traces(warehouse: str | Path, run_id: str, channels: list[str] | None = None,
               columns: int = 1000) -> tuple[str, dict[str, tuple[list[float], list[float]]]]:
    """One run's channels, reduced to at most ``2 * columns + 2`` points each.

    A long run is cut into ``columns`` equal time slices (one per pixel column of the plot) and
    each slice keeps its minimum and its maximum, in time order: every spike stays visible; the
    first and last samples are kept too.

    Returns
    -------
    kind : str
    traces : dict
        ``{column: (t [s], values [column's unit])}``.
    """
    con = connect_readonly(Path(warehouse))
    try:
        row = con.execute("SELECT kind FROM runs WHERE run_id = ?", [run_id]).fetchone()
        if row is None:
            near = difflib.get_close_matches(run_id, [r[0] for r in con.execute("SELECT run_id FROM runs").fetchall()],
                                             n=3)
            raise QueryError(f"no run {run_id!r}" + (f"; did you mean {', '.join(near)}?" if near else ""))
        kind = row[0]
        view = f"samples_{kind}"
        have = [r[0] for r in con.execute(f'DESCRIBE "{view}"').fetchall()
                if r[0] not in _NOT_SIGNALS and _numeric(r[1])]
        present = {c for c in have if con.execute(
            f'SELECT count("{c}") FROM "{view}" WHERE run_id = ?', [run_id]).fetchone()[0]}
        if channels:
            unknown = [c for c in channels if c not in have]
            if unknown:
                raise QueryError(f"run {run_id!r} ({kind}) has no channel {', '.join(unknown)}; "
                                 f"it has {', '.join(c for c in have if c in present)}")
            wanted = list(channels)
        else:
            wanted = [c for c in have if c in present]
        traces = {}
        for c in wanted:
            rows = con.execute(f"""
                WITH s AS (SELECT t_s, "{c}" AS v FROM "{view}" WHERE run_id = $run AND "{c}" IS NOT NULL
                           AND t_s IS NOT NULL),
                     r AS (SELECT min(t_s) AS t0, max(t_s) - min(t_s) AS span, count(*) AS n FROM s),
                     b AS (SELECT CASE WHEN r.n <= 2 * $cols OR r.span = 0 THEN s.t_s
                                       ELSE least(floor((s.t_s - r.t0) / r.span * $cols), $cols - 1) END AS px,
                                  s.t_s, s.v FROM s, r)
                SELECT * FROM (
                    SELECT px, arg_min(t_s, v) AS t, min(v) AS v FROM b GROUP BY px
                    UNION ALL
                    SELECT px, arg_max(t_s, v) AS t, max(v) AS v FROM b GROUP BY px
                    UNION ALL  -- the first and last samples: the plot spans the whole run
                    SELECT -1, min(t_s), arg_min(v, t_s) FROM s
                    UNION ALL
                    SELECT $cols, max(t_s), arg_max(v, t_s) FROM s)
                ORDER BY t, v""", {"run": run_id, "cols": columns}).fetchall()
            seen, ts, vs = set(), [], []
            for _px, t, v in rows:
                if (t, v) not in seen:
                    seen.add((t, v))
                    ts.append(t)
                    vs.append(v)
            traces[c] = (ts, vs)
    finally:
        con.close()
    return kind, traces


#: Result tables whose rows name events of a run (see :func:`pipeline.serve.report.channels.run_events`).
EVENT_TABLES = ("breakaway", "viscous_points", "leakage_map", "step_response", "pressure_steps")


def run_result_rows(warehouse: str | Path, run_id: str) -> list[tuple[str, list[str], tuple]]:
    """``(table, columns, row)`` of the rows of :data:`EVENT_TABLES` derived from one run."""
    con = connect_readonly(Path(warehouse))
    try:
        have = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables() "
                                          "WHERE database_name = current_database()").fetchall()}
        out = []
        for table in EVENT_TABLES:
            if table in have:
                cur = con.execute(f'SELECT * FROM "{table}" WHERE run_id = ?', [run_id])
                cols = [d[0] for d in cur.description]
                out += [(table, cols, r) for r in cur.fetchall()]
    finally:
        con.close()
    return out


def plot_run(warehouse: str | Path, run_id: str, out: str | Path, channels: list[str] | None = None,
             width_px: int = 1200) -> Path:
    """Plot one run's channels against time, one panel per channel, to ``.png``, ``.svg`` or ``.html``."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".png", ".svg", ".html"):
        raise QueryError(f"{out}: plot to a .png, .svg or .html file")
    kind, traces = run_traces(warehouse, run_id, channels, columns=width_px)
    if not traces:
        raise QueryError(f"run {run_id!r} has no samples to plot")
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dpi = 100
    fig, axes = plt.subplots(len(traces), 1, sharex=True, squeeze=False,
                             figsize=(width_px / dpi, 1.0 + 1.6 * len(traces)), dpi=dpi)
    from matplotlib.ticker import FixedLocator, FuncFormatter

    from pipeline.serve.report.channels import EVENT_STYLE, MAX_EVENTS, hms, run_events, time_ticks
    from schemas.units import to_display

    events = run_events(run_result_rows(warehouse, run_id))[:MAX_EVENTS]  # what the analyses saw
    for ax, (col, (t, v)) in zip(axes[:, 0], traces.items()):
        shown, name, unit = to_display(col, np.asarray(v, dtype=float))  # the report's units; storage stays SI
        for kind_, a, b, _text in events:
            label = EVENT_STYLE[kind_][0] if ax is axes[0, 0] else None
            if b is None:
                ax.axvline(a, color=EVENT_STYLE[kind_][1], lw=1.0, ls="--", label=label)
            else:
                ax.axvspan(a, b, color=EVENT_STYLE[kind_][1], alpha=0.16, lw=0, label=label)
        ax.plot(t, shown, lw=0.7)
        ax.set_ylabel(f"{name}" + (f"\n[{unit}]" if unit else ""), fontsize=8)
        ax.grid(alpha=0.3)
    ts = [x for t, _v in traces.values() for x in t if x is not None]
    t0, t1 = (min(ts), max(ts)) if ts else (0.0, 0.0)
    ticks, _labels, tunit = time_ticks(t0, t1)
    if tunit == "h:mm:ss":  # past an hour: h:mm:ss on whole minutes or hours, not 1.125e+04
        axes[-1, 0].xaxis.set_major_locator(FixedLocator(ticks))
        axes[-1, 0].xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: hms(x)))
    axes[-1, 0].set_xlabel(f"t [{tunit}]")
    if events:
        handles, labels = axes[0, 0].get_legend_handles_labels()
        seen = dict(zip(labels, handles))  # one entry per kind
        axes[0, 0].legend(seen.values(), seen.keys(), fontsize=7, loc="upper right", framealpha=0.8)
    fig.suptitle(f"{run_id} ({kind})", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        if suffix == ".html":
            buf = io.StringIO()
            fig.savefig(buf, format="svg", metadata={"Date": None})
            import html

            out.write_text(f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(run_id)}'
                           f"</title></head><body>\n{buf.getvalue()}\n</body></html>\n", encoding="utf-8")
        else:
            fig.savefig(out, metadata={"Software": None} if suffix == ".png" else {"Date": None})
    finally:
        plt.close(fig)
    return out


def copy_figures(warehouse: str | Path, dest: str | Path) -> list[tuple[Path, str]]:
    """Copy the current figures (table ``figures``) out of their content-hashed stage folders.

    Files are named ``<stage>-<name><ext>`` in ``dest``. Returns ``(file, caption)`` per figure.
    """
    import re

    warehouse = Path(warehouse).resolve()
    dest = Path(dest)
    con = connect_readonly(warehouse)
    try:
        has = con.execute("SELECT count(*) FROM duckdb_tables() WHERE table_name = 'figures' "
                          "AND database_name = current_database()").fetchone()[0]
        rows = con.execute("SELECT stage, name, path, caption FROM figures ORDER BY stage, name").fetchall() \
            if has else []
    finally:
        con.close()
    dest.mkdir(parents=True, exist_ok=True)
    out = []
    for stage, name, rel, caption in rows:
        src = (warehouse / rel).resolve()
        if not src.is_relative_to(warehouse) or not src.is_file():
            raise QueryError(f"figure {stage}/{name}: {rel} is not a file of the warehouse")
        target = dest / (re.sub(r"[^A-Za-z0-9._-]+", "_", f"{stage}-{name}") + src.suffix)
        shutil.copyfile(src, target)
        out.append((target, caption or ""))
    return out
