"""Assemble the DuckDB warehouse: DDL from ``schemas/ddl``, the tables, the ``samples_<kind>``
views and the ``samples()`` macro, the comments on every table and column; then swap it in.

The database is always built under a temporary name beside the live one and swapped in with
an atomic rename (:func:`swap_in`), so a reader opening ``pneubench.duckdb`` sees the previous
complete warehouse or the new complete one, never a mix.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.warehouse import (FILES_TABLE, INTERNAL_PREFIX, INTERNAL_TABLES, KEYS_TABLE, ROOT_RAW_SQL,
                                ROOT_SQL, ROOT_VARIABLE, ddl_comments, glob_escape, sql_str, table_sums)
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


def _columns_by_run(con: duckdb.DuckDBPyConnection,
                    run_ids: list[str] | None = None) -> dict[str, frozenset[tuple[str, str]]]:
    """(column, type) of each run's samples file, from the ``channels`` table (``run_id`` + one
    row per column; type ``""`` where the table does not say it); ``run_ids``: of these runs only."""
    if "channels" not in {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}:
        return {}
    have = set(table_columns(con, "channels"))
    if not {"run_id", "column"} <= have:
        return {}
    typ = "coalesce(type, '')" if "type" in have else "''"
    where, params = ("", []) if run_ids is None else ("WHERE run_id IN (SELECT unnest($1)) ", [list(run_ids)])
    rows = con.execute(f'SELECT run_id, list(DISTINCT ("column", {typ})) FROM channels {where}GROUP BY run_id',
                       params).fetchall()
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


def _write_files_table(con: duckdb.DuckDBPyConnection, files: list[tuple[str, str, str | None, str]],
                       create: bool = True) -> None:
    """The ``samples_files`` table (:data:`~pipeline.warehouse.FILES_TABLE`), rows sorted by path
    (``create`` False: into the existing table, emptied first)."""
    if create:
        con.execute(f"CREATE TABLE {FILES_TABLE} (run_id VARCHAR, kind VARCHAR, campaign VARCHAR, path VARCHAR)")
    else:
        con.execute(f"DELETE FROM {FILES_TABLE}")
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
    lst = ", ".join(sql_str(glob_escape(f)) for f in sorted(paths))
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
                   keys: dict[str, str] | None = None) -> None:
    """Create a complete database at ``path`` (which must not exist); ``keys``: the tables' content
    keys (:func:`frame_key`) for the ``table_keys`` table (computed here when not given)."""
    import duckdb

    path = Path(path)
    if path.exists():
        path.unlink()
    keys = keys if keys is not None else {t: frame_key(df) for t, df in tables.items()}
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
        _write_keys(con, keys, run_columns=run_columns_key(runs))
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
        df = _frame(df)
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


def comment_statements(con: duckdb.DuckDBPyConnection, only: set[str] | None = None) -> list[str]:
    """``COMMENT ON`` statements for every table, view and column the DDL or the channels describe
    (``only``: of these tables and views alone). The texts are the ones ``docs/warehouse.md`` gives:
    :func:`pipeline.serve.reference.table_comment` and :func:`~pipeline.serve.reference.column_meanings`
    (the DDL's comment, else the shared glossary, else what the name derives from)."""
    from pipeline.serve.reference import column_meanings, samples_meanings, table_comment
    from schemas.kinds import KINDS

    present = {r[0]: r[1] for r in con.execute(
        "SELECT table_name, 'TABLE' FROM duckdb_tables() WHERE database_name = current_database() "
        "UNION ALL SELECT view_name, 'VIEW' FROM duckdb_views() WHERE NOT internal "
        "AND database_name = current_database()").fetchall()}
    columns: dict[str, list[str]] = {}
    for table, column in con.execute("SELECT table_name, column_name FROM duckdb_columns() "
                                     "WHERE database_name = current_database()").fetchall():
        columns.setdefault(table, []).append(column)
    out = []
    described = ddl_comments()
    mixed = _mixed_columns(con)
    for table, kind in sorted(present.items()):
        if only is not None and table not in only:
            continue
        comment = table_comment(table, described)
        if table.startswith("samples_") and table[8:] in KINDS:
            comment = f"One row per sample of a run of kind {table[8:]}, channels in SI units (column suffix = unit)."
            colcomments = samples_meanings()
            colcomments.update({col: "Non-canonical channel, text in some runs of this kind and numbers in others: "
                                     "VARCHAR in this view, the numbers written as text ('1.5'; TRY_CAST(... AS "
                                     "DOUBLE) gives them back); channels.type says which runs have text."
                                for k, col in mixed if k == table[8:]})
        else:
            colcomments = column_meanings(table, columns.get(table, []), described)
        if table in INTERNAL_TABLES:
            comment = INTERNAL_PREFIX + (comment or "")
        if comment:
            out.append(f"COMMENT ON {kind} \"{table}\" IS {sql_str(comment.strip())}")
        for col, text in sorted(colcomments.items()):
            if text and col in columns.get(table, ()):
                out.append(f"COMMENT ON COLUMN \"{table}\".\"{col}\" IS {sql_str(text)}")
    return out


# -- the database written incrementally (issue 26) -------------------------------------------------
#: A copy of the live database whose file is more than this share free blocks (DuckDB reuses the
#: blocks a dropped table frees, but never shrinks its file; its docs: "compact a database by
#: copying") is not updated: the database is built whole, at its fresh size again.
MAX_FREE_SHARE = 1 / 3  # the file at most 1.5x the blocks in use ...
#: ... once the free blocks are this many bytes (a small database's few blocks are not worth a whole build)
MIN_FREE_BYTES = 4 << 20

#: Tables ``samples_<kind>`` views are made from: when neither changed, the views, the
#: ``samples_files`` table and the ``samples()`` macro are kept as they are.
VIEW_SOURCES = ("runs", "channels")


def _frame(df):
    """A table's frame: ``df``, or a reused stage's table read now
    (:class:`~pipeline.rebuild.stage_store.DeferredTable`, by its ``read_frame``)."""
    read = getattr(type(df), "read_frame", None)
    return read(df) if read is not None else df


def frame_key(df: pd.DataFrame | None) -> str:
    """Content key of a frame as the database takes it [32 hex digits]: its Arrow form (column names,
    types, values; DuckDB reads a frame through Arrow) serialised as an IPC stream and hashed, the
    frame's dtypes with it (``string`` and ``str``, ``Int64`` and ``int64``, are written alike but
    kept apart); a frame Arrow cannot take (mixed Python types in a column) by its exact JSON.
    ``"none"`` for a frame that is not written (None, or without columns)."""
    import pyarrow as pa

    df = _frame(df)
    if df is None or len(df.columns) == 0:
        return "none"
    h = hashlib.sha256(json.dumps([len(df)] + [[str(c), str(t)] for c, t in df.dtypes.items()]).encode())
    try:
        table = pa.Table.from_pandas(df, preserve_index=False)
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, table.schema.remove_metadata()) as writer:
            writer.write_table(table.replace_schema_metadata(None))
        h.update(sink.getvalue())
    except (pa.ArrowException, TypeError, ValueError):
        for col in df.columns:
            h.update(json.dumps([repr(v) for v in df[col].tolist()]).encode())
    return h.hexdigest()[:32]


def database_version() -> str:
    """Version of how a database is laid out: the DDL, the schemas (channels and kinds: views and
    comments), this module, the warehouse's names, the columns' meanings (``pipeline/serve/reference.py``:
    the comments) and DuckDB's version. A live database of another
    version is never updated in place: the new one is built whole."""
    import duckdb

    from pipeline.versions import ROOT, hash_sources

    files = [*ROOT.glob("schemas/ddl/*.sql"), *ROOT.glob("schemas/*.py"), ROOT / "pipeline" / "rebuild" / "assemble.py",
             ROOT / "pipeline" / "warehouse.py", ROOT / "pipeline" / "serve" / "reference.py"]
    return f"{duckdb.__version__}-{hash_sources([f for f in files if f.is_file()])}"


def _table_sums(con: duckdb.DuckDBPyConnection, names) -> dict[str, str]:
    """``<rows>-<sum of the rows' hashes>`` of each table of ``names`` in the database, as DuckDB
    stores it (one query, ~35 ms at 1,000 runs): a table changed in the live database by anything but
    the rebuild does not match its stored key and is written again."""
    present = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
    return table_sums(con, sorted(n for n in names if n in present))


#: The row of ``table_keys`` (not a table) holding :func:`run_columns_key` of the runs the database was written with.
RUN_COLUMNS_ROW = "*run_columns"


def run_columns_key(runs: pd.DataFrame | None) -> str:
    """Key [32 hex digits] of what the rebuild joins to every stage table's rows: each run's ``run_id``,
    ``campaign`` and ``params`` (:func:`pipeline.stages.add_run_columns` reads these alone; ``params``
    as the runs table holds it, JSON of sorted keys), in the frame's order. A changed run file whose
    run keeps its campaign and parameters (a new value in its samples: the usual change) leaves it."""
    cols = [c for c in ("run_id", "campaign", "params") if runs is not None and c in runs.columns]
    blob = json.dumps([cols] + [runs[c].tolist() for c in cols], default=str)
    return hashlib.sha256(blob.encode("utf-8", "surrogatepass")).hexdigest()[:32]


def _write_keys(con: duckdb.DuckDBPyConnection, keys: dict[str, str], known: dict[str, str] | None = None,
                run_columns: str | None = None) -> None:
    """``table_keys``: every table's content key (its frame's :func:`frame_key` and its
    :func:`_table_sums` as written), the row ``*`` of :func:`database_version` and the row
    :data:`RUN_COLUMNS_ROW` of ``run_columns`` (:func:`run_columns_key`; none when None). ``known``: the
    sums of tables not written since they were summed (an updated copy's unchanged tables: only the
    tables written are summed again, ~half of the sums' CPU of a one-file change, issue 26)."""
    known = known or {}
    sums = {**{t: known[t] for t in keys if t in known}, **_table_sums(con, [t for t in keys if t not in known])}
    rows = sorted((t, f"{k}:{sums.get(t, 'absent')}") for t, k in keys.items()) + [("*", database_version())]
    if run_columns is not None:
        rows.append((RUN_COLUMNS_ROW, run_columns))
    con.execute(f"DELETE FROM {KEYS_TABLE}")
    con.execute(f"INSERT INTO {KEYS_TABLE} SELECT unnest($1), unnest($2)",
                [[r[0] for r in rows], [r[1] for r in rows]])


def write_database(path: Path, warehouse: Path, tables: dict[str, pd.DataFrame], runs: pd.DataFrame,
                   live: Path | None, unchanged: frozenset[str] | set[str] = frozenset()) -> str:
    """Write the new database at ``path``: a copy of ``live`` with only the tables whose content
    key changed written again (:func:`update_copy`), or, when that cannot be (no live database,
    ``--full``, another version, a grown or unreadable copy), built whole (:func:`build_database`).
    Returns one line for the log saying which, and why; ``live`` None: ``--full`` asked for a whole build.

    ``unchanged``: tables the caller knows are the previous rebuild's frames again when the ``runs``
    table is (every stage that wrote them reused its stored folder, nothing changed them after): in a
    copy whose ``runs`` key is the new one, their content keys are the copy's, not hashed again
    (:func:`_keys_of`; ~0.1 CPU-s of a one-file change at 1,000 runs, issue 26)."""
    unchanged = frozenset(unchanged) & (set(tables) - {"runs"})
    keys = {t: frame_key(df) for t, df in tables.items() if t not in unchanged}
    why = "--full" if live is None else None if Path(live).is_file() else "no live database"
    if why is None:
        done = update_copy(Path(path), Path(live), warehouse, tables, runs, keys, unchanged)
        if isinstance(done, list):
            return (f"warehouse: the live database copied, {len(done)} of {len(tables)} tables written again"
                    + (f" ({', '.join(done)})" if done else ""))
        why = done
    keys = {t: keys[t] if t in keys else frame_key(df) for t, df in tables.items()}
    build_database(path, warehouse, tables, runs, keys)
    return f"warehouse: built whole ({why}), {len(tables)} tables"


def update_copy(path: Path, live: Path, warehouse: Path, tables: dict[str, pd.DataFrame], runs: pd.DataFrame,
                keys: dict[str, str], unchanged: frozenset[str] = frozenset()) -> list[str] | str:
    """Copy ``live`` to ``path`` and, in one transaction, drop, re-create and fill the tables whose
    content key (``keys``) differs from the one the copy stores, drop those no longer written,
    re-create the ``samples_<kind>`` views only when their sources (:data:`VIEW_SOURCES`) changed,
    and comment only what was re-created. Returns the tables written, or why the copy could not
    be used (``path`` removed: the caller builds the database whole)."""
    import duckdb

    shutil.copyfile(live, path)
    try:
        con = duckdb.connect(str(path))
        try:
            done = _update_tables(con, warehouse, tables, runs, dict(keys), unchanged)
        finally:
            con.close()
    except duckdb.Error as exc:
        done = f"its copy could not be updated: {type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
    if isinstance(done, str):
        path.unlink(missing_ok=True)
        Path(f"{path}.wal").unlink(missing_ok=True)
    return done


def _update_tables(con: duckdb.DuckDBPyConnection, warehouse: Path, tables: dict[str, pd.DataFrame],
                   runs: pd.DataFrame, keys: dict[str, str], unchanged: frozenset[str] = frozenset()) -> list[str] | str:
    """The body of :func:`update_copy` on the open copy (``keys``: of every table but ``unchanged``, filled in)."""
    present = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
    old = dict(con.execute(f"SELECT table_name, content_key FROM {KEYS_TABLE}").fetchall()) \
        if KEYS_TABLE in present else {}
    if old.get("*") != database_version():
        return "the live database has no table keys" if not old else "the live database is of another DDL/code version"
    total, free, block = con.execute("SELECT total_blocks, free_blocks, block_size FROM pragma_database_size() "
                                     "WHERE database_name = current_database()").fetchone()
    if total and free > MAX_FREE_SHARE * total and free * block >= MIN_FREE_BYTES:
        return f"the copy is {free / total:.0%} free blocks: compacted by a whole build"
    run_columns = run_columns_key(runs)
    keys.update(_keys_of(unchanged, old, keys, tables, run_columns))
    stored = _table_sums(con, tables)
    changed = sorted(t for t in tables if f"{keys[t]}:{stored.get(t, 'absent')}" != old.get(t))
    gone = sorted(t for t in old if not t.startswith("*") and t not in tables)
    con.execute("SET TimeZone = 'UTC'")
    con.execute("BEGIN TRANSACTION")
    ddl = _ddl_tables(warehouse) if changed or gone else {}
    for t in changed + gone:
        if t in present:
            con.execute(f'DROP TABLE "{t}"')
        if t in ddl:
            con.execute(ddl[t])
    _write_tables(con, {t: tables[t] for t in changed})
    redone = set(changed + gone) | {KEYS_TABLE}
    if set(VIEW_SOURCES) & redone:
        redone |= _recreate_views(con, warehouse, runs)
    _write_keys(con, keys, {t: v for t, v in stored.items() if t not in redone}, run_columns)
    comments = comment_statements(con, redone)
    if comments:
        con.execute(";\n".join(comments))
    con.execute("COMMIT")
    con.execute("CHECKPOINT")
    return changed + gone


def _keys_of(unchanged: frozenset[str], old: dict[str, str], keys: dict[str, str],
             tables: dict[str, pd.DataFrame], run_columns: str | None = None) -> dict[str, str]:
    """The content keys of the ``unchanged`` tables: the copy's stored frame key (``old``, ``table_keys``:
    ``<frame key>:<sums>``) when what their run columns are joined from is the copy's: the new ``runs``
    frame has the copy's key, or ``run_columns`` (:func:`run_columns_key` of the new runs) is the copy's
    :data:`RUN_COLUMNS_ROW` (a changed run whose campaign and parameters are the same: issue 26, a step
    change keyed and read every reused table again, ~1 CPU-s at 10,000 runs); else :func:`frame_key` of
    the frame. A stored key taken here is the one :func:`frame_key` would give: the same frame, from the
    same Parquet files and run columns, keyed by the same code (the database version, which names this
    module, is the copy's)."""
    same_runs = "runs" in keys and (old.get("runs", "").split(":")[0] == keys["runs"]
                                    or (run_columns is not None and old.get(RUN_COLUMNS_ROW) == run_columns))
    out = {}
    for t in unchanged:
        prior = old.get(t, "").split(":")[0] if same_runs else ""
        out[t] = prior if prior and prior != "none" else frame_key(tables[t])
    return out


def _ddl_tables(warehouse: Path | None = None) -> dict[str, str]:
    """The ``CREATE TABLE`` statement of every DDL table as the whole DDL leaves it (its later
    ``ALTER TABLE`` applied): :func:`pipeline.warehouse.ddl_tables` (kept in ``warehouse``'s cache)."""
    from pipeline.warehouse import ddl_tables

    return ddl_tables(warehouse)


def _recreate_views(con: duckdb.DuckDBPyConnection, warehouse: Path, runs: pd.DataFrame) -> set[str]:
    """Bring the copy's ``samples_<kind>`` views, ``samples_files`` table and ``samples()`` macro up
    to date with ``runs``; returns the names of the views and tables re-created (to be commented).

    Only the views of the kinds whose files changed are re-created (:func:`_changed_kinds`); the
    ``samples_files`` rows are written again into the same table. A view's SQL is made of its kind's
    files and of their columns (``channels``), and a samples file's name holds its content's key,
    so a kind whose files (run, campaign, path) are the same has the same view: one changed
    durability run re-created the view of 6,500 spring files too (issue 26: ~1 CPU-s at 10,000
    runs, most of it reading every run's columns back). Anything unexpected in the copy (no
    ``samples_files``, a view missing): every view is re-created, as a whole build makes them."""
    from schemas.channels import CHANNELS
    from schemas.kinds import KINDS

    files = _samples_files(runs, KINDS)
    kinds = _changed_kinds(con, files, KINDS)
    if kinds is None:
        return _recreate_all_views(con, warehouse, runs)
    _write_files_table(con, files, create=False)
    if not kinds:
        return set()
    con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [Path(warehouse).resolve().as_posix()])
    columns = _columns_by_run(con, sorted({f[0] for f in files if f[1] in kinds}))
    for kind in sorted(kinds):
        con.execute(f'DROP VIEW IF EXISTS "samples_{kind}"')
        sql = _kind_view_sql(kind, files, columns, [CHANNELS[c].column for c in KINDS[kind].channels])
        con.execute(f"CREATE VIEW samples_{kind} AS {sql}")
    return {f"samples_{kind}" for kind in kinds}


def _changed_kinds(con: duckdb.DuckDBPyConnection, files: list[tuple[str, str, str | None, str]],
                   kinds: dict) -> set[str] | None:
    """Kinds (of ``kinds``) whose ``samples_<kind>`` view changes with ``files``: a file added, gone,
    or with another run, kind, campaign or path than the copy's ``samples_files`` row; None when the
    copy lacks that table, one of the views, or the ``samples()`` macro."""
    views = {r[0] for r in con.execute("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
    tables = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
    macros = {r[0] for r in con.execute("SELECT function_name FROM duckdb_functions() "
                                        "WHERE function_type = 'table_macro' AND NOT internal").fetchall()}
    if FILES_TABLE not in tables or "samples" not in macros or any(f"samples_{k}" not in views for k in kinds):
        return None
    try:
        old = con.execute(f"SELECT run_id, kind, campaign, path FROM {FILES_TABLE}").fetchall()
    except Exception:  # a table of another shape: made anew
        return None
    return {f[1] for f in set(old) ^ set(files) if f[1] in kinds}


def _recreate_all_views(con: duckdb.DuckDBPyConnection, warehouse: Path, runs: pd.DataFrame) -> set[str]:
    """Drop and re-create the ``samples_<kind>`` views, the ``samples_files`` table and the
    ``samples()`` macro (:func:`create_samples_views`); returns their names."""
    from schemas.kinds import KINDS

    views = {f"samples_{kind}" for kind in KINDS}
    for v in sorted(views):
        con.execute(f'DROP VIEW IF EXISTS "{v}"')
    con.execute("DROP MACRO TABLE IF EXISTS samples")
    con.execute(f"DROP TABLE IF EXISTS {FILES_TABLE}")
    create_samples_views(con, warehouse, runs)
    return views | {FILES_TABLE}
