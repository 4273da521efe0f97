"""Read-only SQL on the warehouse, and formatting of the result as a table, CSV or JSON."""
from __future__ import annotations

import csv
import io
import json
import math
from datetime import date, datetime
from decimal import Decimal
from pathlib import Path

import duckdb

from pipeline.warehouse import connect_readonly


class QueryError(ValueError):
    """SQL that ``pneubench query`` refuses (one line: what and why)."""


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


def run_query(warehouse: str | Path, sql: str) -> tuple[list[str], list[tuple]]:
    """Run one read-only statement on the warehouse. Returns (column names, rows).

    Raises :class:`QueryError` for SQL the door refuses, ``duckdb.Error`` for SQL DuckDB
    refuses (including every attempt to reach a file outside the warehouse's samples),
    ``FileNotFoundError`` when there is no warehouse.
    """
    con = connect_readonly(Path(warehouse))
    try:
        cur = con.execute(check_sql(con, sql))
        if cur.description is None:
            return [], []
        return [d[0] for d in cur.description], cur.fetchall()
    finally:
        con.close()


def _plain(v):
    if isinstance(v, (datetime, date)):
        return v.isoformat()
    if isinstance(v, Decimal):
        return float(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    return v


def format_rows(columns: list[str], rows: list[tuple], fmt: str = "table", max_width: int = 40) -> str:
    """Render a result as ``table`` (aligned text), ``csv`` or ``json`` (a list of objects)."""
    if fmt == "json":
        return json.dumps([dict(zip(columns, map(_plain, r))) for r in rows], indent=1, ensure_ascii=False)
    if fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(columns)
        for r in rows:
            w.writerow(["" if v is None else (json.dumps(_plain(v)) if isinstance(v, (list, dict)) else _plain(v))
                        for v in r])
        return buf.getvalue().rstrip("\n")
    if fmt != "table":
        raise ValueError(f"unknown format {fmt!r}")

    def cell(v):
        if v is None:
            return "NULL"
        if isinstance(v, float):
            text = f"{v:.6g}"
        else:
            text = str(_plain(v))
        text = " ".join(text.split())
        return text if len(text) <= max_width else text[: max_width - 1] + "…"

    body = [[cell(v) for v in r] for r in rows]
    widths = [max([len(c)] + [len(b[i]) for b in body]) for i, c in enumerate(columns)]
    numeric = [all(isinstance(r[i], (int, float)) or r[i] is None for r in rows) and rows for i in range(len(columns))]

    def line(cells):
        return "  ".join(c.rjust(w) if num else c.ljust(w) for c, w, num in zip(cells, widths, numeric)).rstrip()

    out = [line(columns), "  ".join("-" * w for w in widths)] + [line(b) for b in body]
    out.append(f"({len(rows)} row{'s' if len(rows) != 1 else ''})")
    return "\n".join(out)
