"""Run one read-only SQL statement on the warehouse: the statement check, the limits of the
door (timeout, memory, spill files), every DuckDB type made printable; the result whole
(:func:`run_query`) or open, to be read in batches (:func:`open_query`, :class:`Result`).

The output formats are :mod:`pipeline.serve.formats`; the connection is
:func:`pipeline.serve.door.connect_readonly`.
"""
from __future__ import annotations

import os
import re
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Iterator

import duckdb

from pipeline.serve.door import (MEMORY_LIMIT_ENV, TEMP_LIMIT_ENV, TIMEOUT_ENV, DoorSettingError, connect_readonly,
                                 timeout_from_env)

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


def _timeout_s(value: float | None) -> float:
    """The statement timeout [s]: ``value``, else ``$PNEUBENCH_QUERY_TIMEOUT``, else :data:`TIMEOUT_S`."""
    if value is None:
        try:
            value = timeout_from_env()
        except DoorSettingError as exc:
            raise QueryError(str(exc)) from None
        value = TIMEOUT_S if value is None else value
    if not value >= 0:
        raise QueryError(f"timeout {value!r}: a number of seconds >= 0 (0: no timeout)")
    return float(value)


#: What a statement may grow the process's address space by beyond DuckDB's ``memory_limit``:
#: its threads' stacks, the libraries' arenas, the rows being written. [bytes]
ADDRESS_HEADROOM = 4 << 30

_SIZE_UNITS = {"bytes": 1, "b": 1, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30, "tib": 1 << 40,
               "kb": 10 ** 3, "mb": 10 ** 6, "gb": 10 ** 9, "tb": 10 ** 12}


def _size_bytes(text: str) -> int | None:
    """``'1.8 GiB'`` (DuckDB's ``current_setting`` of a size) in bytes; None when it is not one."""
    parts = str(text).strip().split()
    if len(parts) != 2 or parts[1].lower() not in _SIZE_UNITS:
        return None
    try:
        return int(float(parts[0]) * _SIZE_UNITS[parts[1].lower()])
    except ValueError:
        return None


@contextmanager
def _address_space_limited(memory_limit: str):
    """Limit the process's address space (``RLIMIT_AS``, soft) while a statement runs to what it
    has now plus DuckDB's ``memory_limit`` plus :data:`ADDRESS_HEADROOM`, and give the old limit
    back after it.

    DuckDB's ``memory_limit`` bounds its buffers, not the memory a statement takes to be parsed,
    bound and planned: 20,000 ``UNION ALL`` terms (400 KB of SQL) took 10.6 GB (session 29). Under
    this limit an allocation beyond it fails inside DuckDB, which raises its "Out of Memory" error
    (one line, exit 3). ``memory_limit``: DuckDB's text of the setting (``'1.8 GiB'``). Linux only
    (elsewhere, and where the address space cannot be read, nothing is limited)."""
    try:
        import resource
        with open("/proc/self/statm", encoding="ascii") as f:
            now = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    except (ImportError, OSError, ValueError, IndexError):
        yield
        return
    memory = _size_bytes(memory_limit)
    limit = now + (memory or 0) + ADDRESS_HEADROOM
    if memory is None or (soft != resource.RLIM_INFINITY and soft <= limit) or \
            (hard != resource.RLIM_INFINITY and hard < limit):
        yield  # no size to go by, or a tighter limit set already: keep it
        return
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@contextmanager
def _limited(con: duckdb.DuckDBPyConnection, timeout_s: float | None):
    """Run the body under the statement timeout (a watchdog thread calls ``con.interrupt()``:
    DuckDB has no statement timeout before 1.5, and this one also covers fetching the rows) and
    under :func:`_address_space_limited`, and turn DuckDB's "Out of Memory" into one line naming
    the door's limit that was reached (the settings are read before the statement: a connection
    with a statement's unfinished result takes no other)."""
    memory, temp = con.execute("SELECT current_setting('memory_limit'), "
                               "current_setting('max_temp_directory_size')").fetchall()[0]
    with _address_space_limited(memory), _timed_and_sized(con, timeout_s, memory, temp):
        yield


@contextmanager
def _timed_and_sized(con: duckdb.DuckDBPyConnection, timeout_s: float | None, memory: str, temp: str):
    """The body of :func:`_limited`: the timeout and the "Out of Memory" line (``memory``, ``temp``:
    the door's limits as DuckDB writes them)."""
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
            raise QueryLimitError(f"{first} (the door's spill files are limited to max_temp_directory_size "
                                  f"{temp}: --temp-limit or ${TEMP_LIMIT_ENV} raises it)") from None
        raise QueryLimitError(f"{first} (the door's memory_limit is {memory}, and a statement may grow the "
                              f"process by that and {ADDRESS_HEADROOM >> 30} GiB more: --memory-limit or "
                              f"${MEMORY_LIMIT_ENV} raises both)") from None
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
    """The door's connection; a limit that is not a size as a :class:`QueryError`."""
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
    and spill limits: :func:`pipeline.serve.door.connect_readonly`), ``FileNotFoundError`` when
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


#: Rows fetched from DuckDB at a time: memory is bounded by one batch, whatever the result size.
BATCH_ROWS = 65_536


@dataclass
class Result:
    """An open result: column names, DuckDB type names, and an iterator of Arrow record batches."""

    columns: list[str]
    types: list[str]
    batches: Iterator["pa.RecordBatch"]
    #: the DuckDB cursor the rows come from, when they are fetched as tuples (``arrow=False``)
    cursor: object = None


def _fetch_batches(cur, batch_rows: int) -> Iterator[list[tuple]]:
    """The cursor's rows as lists of tuples, ``batch_rows`` at a time."""
    while rows := cur.fetchmany(batch_rows):
        yield rows


@contextmanager
def open_query(warehouse: str | Path, sql: str, batch_rows: int = BATCH_ROWS, arrow: bool = True,
               timeout_s: float | None = None, memory_limit: str | None = None,
               temp_limit: str | None = None) -> Iterator[Result]:
    """Check and start one read-only statement; the result is read in batches of ``batch_rows``.

    ``arrow``: batches are Arrow record batches (what :func:`pipeline.serve.formats.write_csv`
    streams); otherwise lists of row tuples, and pyarrow is never imported (0.15 s of a query's
    start-up). Columns of a type Python or Arrow cannot carry exactly come as DuckDB's text of
    them (:func:`_printable`).

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
