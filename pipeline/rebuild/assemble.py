"""Assemble the DuckDB warehouse: DDL from ``schemas/ddl``, the tables, the ``samples_<kind>``
views and the ``samples()`` macro, the comments on every table and column; then swap it in.

The database is always built under a temporary name beside the live one and swapped in with
an atomic rename (:func:`swap_in`), so a reader opening ``pneubench.duckdb`` sees the previous
complete warehouse or the new complete one, never a mix.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.warehouse import (CONTRACT_ROWS, FILES_TABLE, INTERNAL_PREFIX, INTERNAL_TABLES, ROOT_RAW_SQL, ROOT_SQL,
                                ROOT_VARIABLE, ddl_comments, glob_escape)
from schemas import ddl_statements

# pandas and pyarrow (through schemas.channels and schemas.kinds) cost ~0.5 s each to import: the
# no-op rebuild imports this module and needs neither, so the functions below import them where
# they are used.
if TYPE_CHECKING:
    import duckdb  # imported by build_database: a fresh rebuild imports it while its files are read
    import pandas as pd


def table_columns(con: duckdb.DuckDBPyConnection, table: str) -> list[str]:
    """Column names of ``table``, in order."""
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
    """``text`` as an SQL string literal."""
    return "'" + str(text).replace("'", "''") + "'"


def _columns_by_run(con: duckdb.DuckDBPyConnection) -> dict[str, frozenset[tuple[str, str]]]:
    """(column, type) of each run's samples file, from the ``channels`` table (``run_id`` + one
    row per column; type ``""`` where the table does not say it)."""
    if "channels" not in {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}:
        return {}
    have = set(table_columns(con, "channels"))
    if not {"run_id", "column"} <= have:
        return {}
    typ = "coalesce(type, '')" if "type" in have else "''"
    rows = con.execute(f'SELECT run_id, list(DISTINCT ("column", {typ})) FROM channels GROUP BY run_id').fetchall()
    return {rid: frozenset(tuple(c) for c in cols) | {("run_id", "")} for rid, cols in rows}


def _mixed_columns(con: duckdb.DuckDBPyConnection) -> set[tuple[str, str]]:
    """(kind, column) of every samples column that is DOUBLE in some of the kind's files and
    VARCHAR in others (the ``channels`` table's ``type``): the kind's view has it as VARCHAR."""
    tables = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
    if not {"channels", FILES_TABLE} <= tables or "type" not in table_columns(con, "channels"):
        return set()
    return set(con.execute(f'SELECT f.kind, c."column" FROM channels AS c JOIN {FILES_TABLE} AS f USING (run_id) '
                           "WHERE c.type IS NOT NULL GROUP BY ALL HAVING count(DISTINCT c.type) > 1").fetchall())


def create_samples_views(con: duckdb.DuckDBPyConnection, warehouse: Path, runs: pd.DataFrame) -> None:
    """One ``samples_<kind>`` view per kind over that kind's samples Parquet files.

    Files are listed explicitly so that a database only ever sees the files of its own
    generation, by their path relative to the warehouse folder, which the view reads from the
    variable ``pneubench_warehouse`` (:data:`ROOT_VARIABLE`) at query time: the warehouse may be
    moved or copied. ``kind`` and ``campaign`` are constants taken from ``runs``, never parsed
    from the path (no Hive partitioning: the folders above the warehouse, or a campaign named
    like a partition, cannot change them). A kind without runs gets an empty view with the
    kind's channels.

    Speed (issue 14): files with the same columns (``channels`` table) are read as one group
    with ``union_by_name = false``, so binding the view opens one file per group, not every
    file; groups are joined by name. ``run_id``, ``kind`` and ``campaign`` come from the
    ``samples_files`` table (:data:`FILES_TABLE`, one row per file) joined on DuckDB's
    ``filename`` column: a filter on ``run_id`` becomes a dynamic filter on the file name and
    DuckDB skips every other file without opening it (a one-run query at 10,000 runs reads one
    footer). The join is against a table, not a literal ``VALUES`` list in the view, so the
    view's SQL is the file list only; binding and planning still cost ~10-20 us per file of the
    kind (DuckDB's multi-file list: see benchmarks/README.md).

    A group is files with the same columns *of the same types* (``channels.type``): a
    non-canonical channel that is numeric in some files and text in others is in different
    groups, and the join by name makes it VARCHAR (one type per view; DuckDB writes the numbers
    as text, ``'1.5'``), never a conversion error at query time. The paths below the warehouse
    folder hold no glob character nor backslash (:func:`pipeline.ingest.file.samples_folder_name`:
    DuckDB's file glob takes ``\\`` for a path separator); only the warehouse folder's own glob
    characters are escaped.
    """
    from schemas.channels import CHANNELS
    from schemas.kinds import KINDS

    con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [Path(warehouse).resolve().as_posix()])
    columns = _columns_by_run(con)
    files = _samples_files(runs, KINDS)
    _write_files_table(con, files)
    for kind, spec in KINDS.items():
        sql = _kind_view_sql(kind, files, columns, [CHANNELS[c].column for c in spec.channels])
        con.execute(f"CREATE VIEW samples_{kind} AS {sql}")
    con.execute(SAMPLES_MACRO)


def _samples_files(runs: pd.DataFrame, kinds: dict) -> list[tuple[str, str, str | None, str]]:
    """(run_id, kind, campaign, path) of every samples file of ``runs`` (a kind of ``kinds``), for
    the ``samples_files`` table."""
    files = []
    if runs.empty:
        return files
    for run_id, kind, campaign, path in runs[["run_id", "kind", "campaign", "samples_path"]].itertuples(index=False):
        if isinstance(path, str) and path and kind in kinds:
            files.append((str(run_id), kind, campaign if isinstance(campaign, str) else None, Path(path).as_posix()))
    return files


def _write_files_table(con: duckdb.DuckDBPyConnection, files: list[tuple[str, str, str | None, str]]) -> None:
    """The ``samples_files`` table (:data:`~pipeline.warehouse.FILES_TABLE`), rows sorted by path."""
    con.execute(f"CREATE TABLE {FILES_TABLE} (run_id VARCHAR, kind VARCHAR, campaign VARCHAR, path VARCHAR)")
    if files:  # one statement of four lists: executemany inserts row by row (10,000 runs: ~5 s)
        rows = sorted(files, key=lambda f: f[3])
        con.execute(f"INSERT INTO {FILES_TABLE} SELECT unnest($1), unnest($2), unnest($3), unnest($4)",
                    [[r[i] for r in rows] for i in range(4)])


def _kind_view_sql(kind: str, files: list[tuple[str, str, str | None, str]],
                   columns: dict[str, frozenset[tuple[str, str]]], channels: list[str]) -> str:
    """SQL of the ``samples_<kind>`` view: one part per group of files with the same (column, type)
    set, joined by name; without files, an empty view of the kind's ``channels`` columns."""
    groups: dict[tuple | None, list[str]] = {}
    for run_id, fkind, _campaign, path in files:
        if fkind == kind:
            cols = columns.get(run_id)
            groups.setdefault(tuple(sorted(cols)) if cols else None, []).append(path)
    parts = [_group_sql(key is None, groups[key]) for key in sorted(groups, key=lambda k: (k is None, k or ()))]
    if parts:
        return " UNION ALL BY NAME ".join(parts)
    cols = ", ".join(f"CAST(NULL AS DOUBLE) AS {c}" for c in channels)
    return (f"SELECT CAST(NULL AS VARCHAR) AS run_id, {cols}, CAST(NULL AS VARCHAR) AS kind, "
            "CAST(NULL AS VARCHAR) AS campaign WHERE false")


def _group_sql(unknown: bool, paths: list[str]) -> str:
    """One group's part of a view: its files (relative to the warehouse variable) joined with
    ``samples_files`` on DuckDB's ``filename``; ``unknown``: the files' columns are not known."""
    lst = ", ".join(_sql_str(glob_escape(f)) for f in sorted(paths))
    files_sql = f"list_transform([{lst}], lambda f: {ROOT_SQL} || '/' || f)"
    if unknown:  # columns unknown: read every schema (slow to bind, never wrong)
        source = f"read_parquet({files_sql}, union_by_name = true, hive_partitioning = false, filename = true)"
    else:
        source = f"read_parquet({files_sql}, union_by_name = false, hive_partitioning = false, filename = true)"
    return (f"SELECT m.run_id, s.* EXCLUDE (run_id, filename), m.kind, m.campaign FROM {source} AS s "
            f"JOIN {FILES_TABLE} AS m ON s.filename = {ROOT_RAW_SQL} || '/' || m.path")


#: SQL of :func:`pipeline.ingest.file.safe_file_name` of the macro argument ``rid`` (the start of its
#: samples file's name; tests check the two agree).
SAFE_NAME_SQL = "coalesce(nullif(left(trim(regexp_replace(rid, '[^A-Za-z0-9._-]+', '_', 'g'), '._'), 80), ''), 'run')"

#: ``samples('<run_id>')``: one run's samples, whatever its kind, planned in constant time. The
#: views above cost ~10-60 us per file of their kind to plan and run (DuckDB's multi-file list:
#: 0.2-0.4 s for a one-run query on 6,500 spring runs); the macro globs the few files named like
#: the run (its safe name, any kind and campaign folder) and keeps the one ``samples_files``
#: lists for it (an earlier generation's file, kept for its readers, is never read). A run_id
#: without samples makes DuckDB say "No files found that match the pattern ..."; ``pneubench
#: query`` turns that into a one-line error naming the cause (``pipeline.serve.query``).
SAMPLES_MACRO = (
    "CREATE MACRO samples(rid) AS TABLE "
    f"SELECT m.run_id, s.* EXCLUDE (filename, run_id), m.kind, m.campaign "
    f"FROM read_parquet({ROOT_SQL} || '/samples/*/*/' || {SAFE_NAME_SQL} || '-*.parquet', filename = true, "
    "union_by_name = true, hive_partitioning = false) AS s "
    f"JOIN {FILES_TABLE} AS m ON s.filename = {ROOT_RAW_SQL} || '/' || m.path AND m.run_id = rid")


def build_database(path: Path, warehouse: Path, tables: dict[str, pd.DataFrame], runs: pd.DataFrame,
                   extra_sql: list[str] | None = None) -> None:
    """Create a complete database at ``path`` (which must not exist)."""
    import duckdb

    path = Path(path)
    if path.exists():
        path.unlink()
    con = duckdb.connect(str(path))
    try:
        con.execute("SET TimeZone = 'UTC'")
        # one transaction: committing each of ~300 statements (most of them COMMENT ON) was half
        # the time of writing a small warehouse
        con.execute("BEGIN TRANSACTION")
        for _name, sql in ddl_statements():
            con.execute(sql)
        _write_tables(con, tables)
        create_samples_views(con, warehouse, runs)
        for sql in extra_sql or []:
            con.execute(sql)
        comments = comment_statements(con)
        if comments:  # parsed and run as one script: ~300 round trips from Python cost ~0.1 s
            con.execute(";\n".join(comments))
        con.execute("COMMIT")
        con.execute("CHECKPOINT")
    finally:
        con.close()


def _write_tables(con: duckdb.DuckDBPyConnection, tables: dict[str, pd.DataFrame]) -> None:
    """Each frame into its table: created from the frame when the DDL has none, else inserted by
    column name (:func:`insert_frame`); a frame without columns is skipped."""
    existing = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
    for table, df in tables.items():
        if df is None or len(df.columns) == 0:
            continue
        if table not in existing:
            con.register("_frame", df)
            con.execute(f'CREATE TABLE "{table}" AS SELECT * FROM _frame')
            con.unregister("_frame")
            existing.add(table)
        else:
            insert_frame(con, table, df)


def runs_frame(runs: list[dict]) -> pd.DataFrame:
    """``runs`` rows (dicts from ingest) as a DataFrame ready for the warehouse."""
    import pandas as pd

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


def comment_statements(con: duckdb.DuckDBPyConnection) -> list[str]:
    """``COMMENT ON`` statements for every table, view and column the DDL or the channels describe."""
    from schemas.channels import CHANNELS
    from schemas.kinds import KINDS

    present = {r[0]: r[1] for r in con.execute(
        "SELECT table_name, 'TABLE' FROM duckdb_tables() WHERE database_name = current_database() "
        "UNION ALL SELECT view_name, 'VIEW' FROM duckdb_views() WHERE NOT internal "
        "AND database_name = current_database()").fetchall()}
    columns = {(r[0], r[1]) for r in con.execute(
        "SELECT table_name, column_name FROM duckdb_columns() WHERE database_name = current_database()").fetchall()}
    out = []
    described = ddl_comments()
    mixed = _mixed_columns(con)
    for table, kind in sorted(present.items()):
        info = described.get(table, {"comment": None, "columns": {}})
        comment = info["comment"] or (f"One row per {CONTRACT_ROWS[table]}." if table in CONTRACT_ROWS else None)
        colcomments = dict(info["columns"])
        if table.startswith("samples_") and table[8:] in KINDS:
            comment = f"One row per sample of a run of kind {table[8:]}, channels in SI units (column suffix = unit)."
            colcomments.update({ch.column: ch.description for ch in CHANNELS.values()})
            colcomments.update(run_id="Run identifier (runs.run_id).", kind="Test kind of the run.",
                               campaign="Campaign of the run (first folder under raw/).")
            colcomments.update({col: "Non-canonical channel, text in some runs of this kind and numbers in others: "
                                     "VARCHAR in this view, the numbers written as text ('1.5'; TRY_CAST(... AS "
                                     "DOUBLE) gives them back); channels.type says which runs have text."
                                for k, col in mixed if k == table[8:]})
        if table in INTERNAL_TABLES:
            comment = INTERNAL_PREFIX + (comment or "")
        if comment:
            out.append(f"COMMENT ON {kind} \"{table}\" IS {_sql_str(comment.strip())}")
        for col, text in sorted(colcomments.items()):
            if text and (table, col) in columns:
                out.append(f"COMMENT ON COLUMN \"{table}\".\"{col}\" IS {_sql_str(text)}")
    return out
