"""The warehouse's catalogue: its tables and views with their rows and comments
(``pneubench tables``), one table's columns with their types, units and meaning
(``pneubench describe``)."""
from __future__ import annotations

import difflib
from pathlib import Path

from pipeline.serve.door import connect_readonly
from pipeline.serve.query import QueryError
from pipeline.warehouse import INTERNAL_TABLES
from schemas.units import column_unit


#: Units of the warehouse columns whose name does not end in their unit (a column's name is part of
#: the contract: never renamed to add one): column -> unit, as ``describe`` and docs/warehouse.md show it.
NAMED_UNITS = {"hose_km_before": "km", "km_per_day": "km/day"}


def unit_of(column: str) -> str | None:
    """Unit a warehouse column name ends in (``leak_l_min`` -> ``l/min (ANR)``), else None.

    The long form of the one unit table, :data:`schemas.units.COLUMN_UNITS` (longest suffix wins);
    a column of :data:`NAMED_UNITS` has the unit given there.
    """
    if column in NAMED_UNITS:
        return NAMED_UNITS[column]
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
