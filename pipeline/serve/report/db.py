"""The warehouse database as the report reads it (read-only): which tables are there, their
rows, columns and counts, the run ids, and the last rebuild's generation and inputs key."""
from __future__ import annotations

from pipeline.warehouse import log_order


class ReportDB:
    """A read-only connection to the warehouse with the questions the report asks of it.

    Parameters
    ----------
    con : duckdb.DuckDBPyConnection
        An open connection (:func:`pipeline.warehouse.connect_readonly`); the caller closes it.
    """

    def __init__(self, con):
        self.con = con
        self.tables = {r[0] for r in con.execute(
            "SELECT table_name FROM duckdb_tables() UNION SELECT view_name FROM duckdb_views() "
            "WHERE NOT internal").fetchall()}

    def has(self, table: str) -> bool:
        """Whether the database holds ``table`` (a table or a view)."""
        return table in self.tables

    def run_ids(self) -> set[str]:
        """Run ids of the warehouse (each has a page)."""
        if not hasattr(self, "_run_ids"):
            self._run_ids = ({r[0] for r in self.con.execute("SELECT run_id FROM runs").fetchall()}
                             if self.has("runs") else set())
        return self._run_ids

    def rows(self, sql: str, params=None) -> tuple[list[str], list[tuple]]:
        """(column names, rows) of a query."""
        cur = self.con.execute(sql, params or [])
        return [d[0] for d in cur.description], cur.fetchall()

    def columns(self, table: str) -> list[str]:
        """Column names of ``table`` (none when it is not there). The tables' are read at once on
        the first call (one catalogue query, not a ``DESCRIBE`` per table); a view's are
        described when asked (binding it is what says its columns)."""
        if not self.has(table):
            return []
        if not hasattr(self, "_columns"):
            self._columns: dict[str, list[str]] = {}
            for name, col in self.con.execute(
                    "SELECT table_name, column_name FROM duckdb_columns() WHERE database_name = current_database() "
                    "AND table_name IN (SELECT table_name FROM duckdb_tables() "
                    "WHERE database_name = current_database()) ORDER BY table_name, column_index").fetchall():
                self._columns.setdefault(name, []).append(col)
        if table in self._columns:
            return list(self._columns[table])
        return [r[0] for r in self.con.execute(f'DESCRIBE "{table}"').fetchall()]

    def count(self, table: str) -> int:
        """Rows of ``table`` (0 when it is not there)."""
        return self.con.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0] if self.has(table) else 0

    def log_order(self) -> str:
        """``rebuild_log``'s last rebuild first: by its number, never by wall time (a clock set back)."""
        return log_order(self.columns("rebuild_log"))

    def generation(self) -> str:
        """The generation of the last rebuild ("" without a ``rebuild_log``)."""
        if self.has("rebuild_log") and self.count("rebuild_log"):
            return self.con.execute(f"SELECT generation FROM rebuild_log ORDER BY {self.log_order()} LIMIT 1"
                                    ).fetchone()[0]
        return ""

    def inputs_key(self) -> str | None:
        """``rebuild_log.inputs_key`` of the last rebuild: every input and all of the code, so equal
        keys mean equal result tables (the rebuild is deterministic)."""
        if not self.has("rebuild_log") or "inputs_key" not in {
                r[0] for r in self.con.execute("DESCRIBE rebuild_log").fetchall()}:
            return None
        row = self.con.execute(f"SELECT inputs_key FROM rebuild_log ORDER BY {self.log_order()} LIMIT 1").fetchone()
        return row[0] if row and isinstance(row[0], str) else None
