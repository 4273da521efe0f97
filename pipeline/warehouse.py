"""Write the DuckDB warehouse: DDL from ``schemas/ddl``, tables, and the ``samples_<kind>`` views.

The database is always built under a temporary name beside the live one and swapped in with
an atomic rename (:func:`swap_in`), so a reader opening ``pneubench.duckdb`` sees the previous
complete warehouse or the new complete one, never a mix.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import duckdb
import pandas as pd

from schemas import ddl_statements
from schemas.channels import CHANNELS
from schemas.kinds import KINDS

DB_NAME = "pneubench.duckdb"


def connect_readonly(warehouse: Path) -> duckdb.DuckDBPyConnection:
    """Open the warehouse read-only (raises FileNotFoundError when there is none yet)."""
    db = Path(warehouse) / DB_NAME
    if not db.is_file():
        raise FileNotFoundError(f"no warehouse at {db} (run `pneubench rebuild` first)")
    con = duckdb.connect(str(db), read_only=True)
    con.execute("SET TimeZone = 'UTC'")
    return con


def table_columns(con: duckdb.DuckDBPyConnection, table: str) -> list[str]:
    return [r[0] for r in con.execute(f'DESCRIBE "{table}"').fetchall()]


def insert_frame(con: duckdb.DuckDBPyConnection, table: str, df: pd.DataFrame) -> None:
    """Insert a DataFrame by column name; columns the table lacks are added as they come."""
    if df is None or df.empty:
        return
    have = set(table_columns(con, table))
    for col in df.columns:
        if col not in have:
            con.register("_probe", df[[col]].head(0))
            dtype = con.execute("DESCRIBE _probe").fetchall()[0][1]
            con.unregister("_probe")
            con.execute(f'ALTER TABLE "{table}" ADD COLUMN "{col}" {dtype}')
    con.register("_frame", df)
    try:
        con.execute(f'INSERT INTO "{table}" BY NAME SELECT * FROM _frame')
    finally:
        con.unregister("_frame")


def _sql_str(text: str) -> str:
    return "'" + str(text).replace("'", "''") + "'"


def create_samples_views(con: duckdb.DuckDBPyConnection, warehouse: Path, runs: pd.DataFrame) -> None:
    """One ``samples_<kind>`` view per kind over that kind's samples Parquet files.

    Files are listed explicitly (absolute paths) so that a database only ever sees the files
    of its own generation. A kind without runs gets an empty view with the kind's channels.
    """
    warehouse = Path(warehouse).resolve()
    for kind, spec in KINDS.items():
        files = [] if runs.empty else sorted(runs.loc[runs["kind"] == kind, "samples_path"])
        if files:
            lst = ", ".join(_sql_str((warehouse / f).as_posix()) for f in files)
            sql = f"SELECT * FROM read_parquet([{lst}], union_by_name = true, hive_partitioning = true)"
        else:
            cols = ", ".join(f"CAST(NULL AS DOUBLE) AS {CHANNELS[c].column}" for c in spec.channels)
            sql = (f"SELECT CAST(NULL AS VARCHAR) AS run_id, {cols}, CAST(NULL AS VARCHAR) AS kind, "
                   "CAST(NULL AS VARCHAR) AS campaign WHERE false")
        con.execute(f"CREATE VIEW samples_{kind} AS {sql}")


def build_database(path: Path, warehouse: Path, tables: dict[str, pd.DataFrame], runs: pd.DataFrame,
                   extra_sql: list[str] | None = None) -> None:
    """Create a complete database at ``path`` (which must not exist)."""
    path = Path(path)
    if path.exists():
        path.unlink()
    con = duckdb.connect(str(path))
    try:
        con.execute("SET TimeZone = 'UTC'")
        for _name, sql in ddl_statements():
            con.execute(sql)
        for table, df in tables.items():
            if df is None or len(df.columns) == 0:
                continue
            if table not in {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}:
                con.register("_frame", df)
                con.execute(f'CREATE TABLE "{table}" AS SELECT * FROM _frame')
                con.unregister("_frame")
            else:
                insert_frame(con, table, df)
        create_samples_views(con, warehouse, runs)
        for sql in extra_sql or []:
            con.execute(sql)
        con.execute("CHECKPOINT")
    finally:
        con.close()


def runs_frame(runs: list[dict]) -> pd.DataFrame:
    """``runs`` rows (dicts from ingest) as a DataFrame ready for the warehouse."""
    cols = ["run_id", "kind", "campaign", "rig", "started_at", "source_path", "source_sha256", "n_samples",
            "sample_rate_hz", "params", "warnings", "format", "duration_s", "samples_path"]
    df = pd.DataFrame(runs, columns=cols)
    if not df.empty:
        df["params"] = df["params"].map(lambda p: json.dumps(p, sort_keys=True))
        df["started_at"] = pd.to_datetime(df["started_at"], utc=True, format="ISO8601")
        df["warnings"] = df["warnings"].map(lambda w: list(w or []))
    return df


def swap_in(tmp: Path, final: Path) -> None:
    """Atomically replace ``final`` with ``tmp`` (same folder; fsync'd first)."""
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, final)
    try:
        fd = os.open(Path(final).parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass
