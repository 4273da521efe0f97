"""Write the DuckDB warehouse: DDL from ``schemas/ddl``, tables, and the ``samples_<kind>`` views.

The database is always built under a temporary name beside the live one and swapped in with
an atomic rename (:func:`swap_in`), so a reader opening ``pneubench.duckdb`` sees the previous
complete warehouse or the new complete one, never a mix.
"""
from __future__ import annotations

import atexit
import itertools
import json
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import duckdb

from schemas import ddl_statements

# pandas and pyarrow (through schemas.channels) cost ~0.5 s each to import: `pneubench query` needs
# neither, so the writers below import them where they are used.
if TYPE_CHECKING:
    import pandas as pd

DB_NAME = "pneubench.duckdb"


#: DuckDB variable holding the warehouse folder; the ``samples_<kind>`` views read their
#: Parquet files relative to it, so a moved or copied warehouse reads its own files. Every
#: pneubench reader sets it (:func:`connect_readonly`); another DuckDB client runs
#: ``SET VARIABLE pneubench_warehouse = '/path/to/warehouse';`` first.
ROOT_VARIABLE = "pneubench_warehouse"


def _glob_escape_sql(expr: str) -> str:
    """SQL expression: ``expr`` with DuckDB's glob characters made literal (``[`` ``*`` ``?``)."""
    return f"replace(replace(replace({expr}, '[', '[[]'), '*', '[*]'), '?', '[?]')"


#: SQL expression of the warehouse folder (as DuckDB's ``filename`` column shows it). Unset, it
#: names the missing setting, so the error a plain DuckDB client gets says what to do.
ROOT_RAW_SQL = (f"coalesce(getvariable('{ROOT_VARIABLE}'), "
                f"'(run SET VARIABLE {ROOT_VARIABLE} = <warehouse folder>; see README)')")
#: The same, glob-escaped, as the views' file lists need it.
ROOT_SQL = _glob_escape_sql(ROOT_RAW_SQL)


def _glob_escape(text: str) -> str:
    return "".join(f"[{c}]" if c in "[*?" else c for c in text)


#: Default limits of every connection of the door (README, "Limits of pneubench query"):
#: DuckDB's memory (beyond it a query spills to the door's private temp folder, or fails), and
#: the spill files. The environment variables override them; ``connect_readonly``'s arguments
#: override both.
MEMORY_LIMIT = "2GB"
TEMP_LIMIT = "10GB"
MEMORY_LIMIT_ENV = "PNEUBENCH_QUERY_MEMORY_LIMIT"
TEMP_LIMIT_ENV = "PNEUBENCH_QUERY_TEMP_LIMIT"

_private: tuple[int, Path] | None = None  # (pid, folder) of this process's private folder
_door_ids = itertools.count()


def _private_folder() -> Path:
    """A folder of this process alone (``mkdtemp``: a new name, mode 0700), removed at exit.

    No other user can plant anything in it (a shared, fixed temp folder could be a symlink to
    theirs, and DuckDB lets SQL read its temp folder). A forked child makes its own.
    """
    global _private
    if _private is None or _private[0] != os.getpid() or not _private[1].is_dir():
        folder = Path(tempfile.mkdtemp(prefix="pneubench-door-"))
        _private = (os.getpid(), folder)
        atexit.register(_remove_private, os.getpid(), folder)
    return _private[1]


def _remove_private(pid: int, folder: Path) -> None:
    if os.getpid() == pid:
        shutil.rmtree(folder, ignore_errors=True)


def _attach_unnamed(con: duckdb.DuckDBPyConnection, db: Path, private: Path, n: int) -> None:
    """Attach ``db`` read-only through a name that is gone once it is open.

    DuckDB lets SQL read every file of an attached database (``allowed_paths``), even with
    external access off: ``read_blob('<warehouse>/pneubench.duckdb')`` would return the file. So
    the database is attached through a hard link (a copy when the link is refused: another
    file system, another owner) in the private folder, and the link is removed at once: the
    path DuckDB allows then names nothing, and the warehouse's own file is not allowed.
    """
    alias = private / f"db-{n}.duckdb"
    try:
        os.link(db, alias)
    except OSError:
        shutil.copyfile(db, alias)
    try:
        con.execute("ATTACH ? AS pneubench (READ_ONLY)", [str(alias)])
    finally:
        alias.unlink(missing_ok=True)


def _limit(con: duckdb.DuckDBPyConnection, setting: str, value: str | None, env: str, default: str) -> None:
    value = value if value is not None else (os.environ.get(env) or default)
    try:
        con.execute(f"SET {setting} = ?", [str(value)])
    except duckdb.Error as exc:
        raise ValueError(f"{setting} {value!r} (from the option or ${env}): {str(exc).splitlines()[0]}") from None


def connect_readonly(warehouse: Path, database: Path | None = None, memory_limit: str | None = None,
                     temp_limit: str | None = None) -> duckdb.DuckDBPyConnection:
    """The one door to the warehouse: a read-only, contained DuckDB connection.

    Every reader (``pneubench query``, the report, the rebuild's look at the previous state)
    opens the warehouse here. The connection sees the warehouse's tables and views and can
    read the files under ``<warehouse>/samples/`` and nothing else on the machine: external
    access is off except that folder, extensions are neither installed nor loaded, and the
    configuration is locked, so no SQL can undo any of it. Writes fail (the database is
    attached read-only; nothing may be written under samples either, see
    :func:`pipeline.serve.query.check_sql`). The database file itself is not readable as a file
    (:func:`_attach_unnamed`); DuckDB's spill files go to a folder private to this process
    (:func:`_private_folder`). DuckDB's memory and its spill files are limited (``memory_limit``,
    ``max_temp_directory_size``: :data:`MEMORY_LIMIT`, :data:`TEMP_LIMIT`).

    Parameters
    ----------
    warehouse : path
        The warehouse folder.
    database : path, optional
        DuckDB file to open instead of ``<warehouse>/pneubench.duckdb`` (the rebuild renders the
        report from the new database before swapping it in).

    Raises
    ------
    FileNotFoundError
        When there is no database yet.
    ValueError
        When a limit is not a size DuckDB understands.
    """
    warehouse = Path(warehouse).resolve()
    db = Path(database).resolve() if database is not None else warehouse / DB_NAME
    if not db.is_file():
        raise FileNotFoundError(f"no warehouse at {db} (run `pneubench rebuild` first)")
    # An in-memory instance of its own (never Python's cached instance of the file, whose
    # settings other connections share) with the warehouse attached read-only.
    con = duckdb.connect(":memory:", config={
        "autoinstall_known_extensions": False, "autoload_known_extensions": False,
        "allow_community_extensions": False, "allow_unsigned_extensions": False})
    try:
        private = _private_folder()
        n = next(_door_ids)
        _attach_unnamed(con, db, private, n)
        con.execute("USE pneubench")
        con.execute("SET TimeZone = 'UTC'")
        con.execute("SET enable_progress_bar = false")  # it would print into the result on stdout
        con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [warehouse.as_posix()])
        # made by DuckDB when it first spills, removed when the connection closes
        con.execute("SET temp_directory = ?", [(private / f"spill-{n}").as_posix()])
        _limit(con, "memory_limit", memory_limit, MEMORY_LIMIT_ENV, MEMORY_LIMIT)
        _limit(con, "max_temp_directory_size", temp_limit, TEMP_LIMIT_ENV, TEMP_LIMIT)
        samples = (warehouse / "samples").as_posix() + "/"
        # the views name files by glob-escaped paths ([*] for *), which match only the real ones
        con.execute("SET allowed_directories = ?", [sorted({samples, _glob_escape(samples)})])
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
    except Exception:
        con.close()
        raise
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


#: Table of every samples file: (run_id, kind, campaign, path relative to the warehouse).
FILES_TABLE = "samples_files"


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
    files = []  # (run_id, kind, campaign, path) of every samples file, for the samples_files table
    if not runs.empty:
        for run_id, kind, campaign, path in runs[["run_id", "kind", "campaign", "samples_path"]].itertuples(index=False):
            if isinstance(path, str) and path and kind in KINDS:
                files.append((str(run_id), kind, campaign if isinstance(campaign, str) else None,
                              Path(path).as_posix()))
    con.execute(f"CREATE TABLE {FILES_TABLE} (run_id VARCHAR, kind VARCHAR, campaign VARCHAR, path VARCHAR)")
    if files:  # one statement of four lists: executemany inserts row by row (10,000 runs: ~5 s)
        rows = sorted(files, key=lambda f: f[3])
        con.execute(f"INSERT INTO {FILES_TABLE} SELECT unnest($1), unnest($2), unnest($3), unnest($4)",
                    [[r[i] for r in rows] for i in range(4)])
    for kind, spec in KINDS.items():
        groups: dict[tuple | None, list[str]] = {}
        for run_id, fkind, _campaign, path in files:
            if fkind == kind:
                cols = columns.get(run_id)
                groups.setdefault(tuple(sorted(cols)) if cols else None, []).append(path)
        parts = []
        for key in sorted(groups, key=lambda k: (k is None, k or ())):
            lst = ", ".join(_sql_str(_glob_escape(f)) for f in sorted(groups[key]))
            files_sql = f"list_transform([{lst}], lambda f: {ROOT_SQL} || '/' || f)"
            if key is None:  # columns unknown: read every schema (slow to bind, never wrong)
                source = f"read_parquet({files_sql}, union_by_name = true, hive_partitioning = false, filename = true)"
            else:
                source = f"read_parquet({files_sql}, union_by_name = false, hive_partitioning = false, filename = true)"
            parts.append(
                f"SELECT m.run_id, s.* EXCLUDE (run_id, filename), m.kind, m.campaign FROM {source} AS s "
                f"JOIN {FILES_TABLE} AS m ON s.filename = {ROOT_RAW_SQL} || '/' || m.path")
        if parts:
            sql = " UNION ALL BY NAME ".join(parts)
        else:
            cols = ", ".join(f"CAST(NULL AS DOUBLE) AS {CHANNELS[c].column}" for c in spec.channels)
            sql = (f"SELECT CAST(NULL AS VARCHAR) AS run_id, {cols}, CAST(NULL AS VARCHAR) AS kind, "
                   "CAST(NULL AS VARCHAR) AS campaign WHERE false")
        con.execute(f"CREATE VIEW samples_{kind} AS {sql}")
    con.execute(SAMPLES_MACRO)


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


#: What one row of each contract table is (warehouse.md), for tables whose DDL has no comment
#: block of its own.
CONTRACT_ROWS = {
    "runs": "ingested run", "quarantine": "input that could not be used",
    "leakage_map": "pressure plateau of a leakage run", "breakaway": "breakaway event",
    "breakaway_summary": "(direction, backpressure_bar, force_rate_n_s)",
    "viscous_points": "constant-velocity pass", "viscous_fits": "(backpressure_bar, direction P/N)",
    "friction_dynamic": "viscous run", "identification": "identification run", "step_response": "step in a step run",
    "spring_fits": "PLA chamber", "spring_tests": "spring run",
    "pressure_dynamics": "(campaign, rig, chamber, direction) pooled, or one part at one age (level)",
    "durability_runs": "durability run",
    "hose_life": "hose", "service_life": "(hose_type, adjustment)",
    "findings": "conclusion of the seed papers, checked on the lab's latest data",
    FILES_TABLE: "samples Parquet file (path relative to the warehouse folder) of a run, as the "
                 "samples_<kind> views read it",
}

#: Start of the comment of an internal table.
INTERNAL_PREFIX = "(internal: the rebuild's own bookkeeping) "

#: Tables that describe the rebuild itself, not the lab's data (``pneubench tables`` marks them).
INTERNAL_TABLES = ("rebuild_log", "rebuild_inputs", "rebuild_changes", "ingest_state", "stage_cache", "figures",
                   FILES_TABLE)

_CREATE = re.compile(r"^\s*CREATE\s+(?:OR\s+REPLACE\s+)?(TABLE|VIEW)\s+(?:IF\s+NOT\s+EXISTS\s+)?\"?(\w+)\"?",
                     re.IGNORECASE)
_COLUMN = re.compile(r"^\s+(\"[^\"]+\"|\w+)\s+[A-Z]\w*[^-]*?(?:--\s*(.*))?$")


def ddl_comments() -> dict[str, dict]:
    """Descriptions written as ``--`` comments in ``schemas/ddl``: ``{table: {"comment", "columns"}}``.

    A table's description is the comment block right above its ``CREATE``; a column's is the
    comment at the end of its line (continued on comment-only lines below it).
    """
    out: dict[str, dict] = {}
    for _name, sql in ddl_statements():
        block: list[str] = []
        table = column = None
        for line in sql.splitlines():
            stripped = line.strip()
            m = _CREATE.match(line)
            if m:
                table, column = m.group(2), None
                out[table] = {"comment": " ".join(block) or None, "columns": {}}
                block = []
                if m.group(1).upper() == "VIEW" or "(" not in line:
                    table = None if m.group(1).upper() == "VIEW" else table
                continue
            if table is None:
                block = block + [stripped[2:].strip()] if stripped.startswith("--") else []
                continue
            if stripped.startswith(")"):
                table = column = None
                block = []
                continue
            if stripped.startswith("--"):
                if column:
                    cols = out[table]["columns"]
                    cols[column] = ((cols.get(column) or "") + " " + stripped[2:].strip()).strip()
                continue
            m = _COLUMN.match(line)
            if m and not stripped.upper().startswith(("PRIMARY", "UNIQUE", "CHECK", "FOREIGN", "CONSTRAINT")):
                column = m.group(1).strip('"')
                if m.group(2):
                    out[table]["columns"][column] = m.group(2).strip()
    return out


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


# -- every name the warehouse writes ---------------------------------------------------------------
# The clean-up (pipeline/rebuild/garbage.py) deletes only what the warehouse itself wrote: a file
# is a candidate when it lies in the warehouse's own folders (never through a symlink) AND its
# name is one of these, which the writers use. Anything else found there (a raw tree placed there
# by mistake, a user's notes) is left alone. A writer that changes a name changes it here too.

#: A samples file, ``samples/kind=<kind>/campaign=<campaign>/<safe run>-<key>.parquet`` (the ingest).
SAMPLES_FILE = re.compile(r"[A-Za-z0-9._-]{1,80}-[0-9a-f]{16}\.parquet")
#: A samples file being written (the ingest's temporary name beside it).
SAMPLES_TMP = re.compile(r"\.[A-Za-z0-9._-]{1,80}\.[0-9]+\.[0-9a-f]{12}\.tmp")
#: A stage's name: its folder ``stages/<stage>/`` and its memo folder ``memo/<stage>/``.
STAGE_NAME = re.compile(r"[a-z_][a-z0-9_]*")
#: A stage output folder's key, ``stages/<stage>/<key>/``.
STAGE_KEY = re.compile(r"[0-9a-f]{20}")
#: A stage output folder being written, ``stages/.tmp-<stage>-<key>-<pid>/``.
STAGE_TMP = re.compile(r"\.tmp-([a-z_][a-z0-9_]*)-[0-9a-f]{20}-[0-9]+")
#: A table of a stage output folder, ``tables/<table>.parquet``.
STAGE_TABLE = re.compile(r"[A-Za-z0-9_]+\.parquet")
#: A stage output folder's description, ``output.json``.
STAGE_OUTPUT = re.compile(r"output\.json")
#: A figure, ``stages/<stage>/<key>/figures/<name>.png``.
FIGURE = re.compile(r"[A-Za-z0-9._-]+\.png")
#: The database being written beside the live one, ``.pneubench.duckdb.tmp-<pid>`` (and its WAL).
DB_TMP = re.compile(re.escape(f".{DB_NAME}.tmp-") + r"[0-9]+(\.wal)?")
#: A morning report being written, ``report/.index.html.tmp-<pid>`` or ``report/.parts-cache.tmp-<pid>``.
REPORT_TMP = re.compile(r"\.(index\.html|parts-cache)\.tmp-[0-9]+")
#: A memo shard, ``memo/<stage>/<xx>.pkl`` (``xx`` the first two hex digits of the keys it holds) ...
SHARD_FILE = re.compile(r"[0-9a-f]{2}\.pkl")
#: ... and the shard being written, ``memo/<stage>/.<xx>.pkl.tmp-<pid>``.
SHARD_TMP = re.compile(r"\.[0-9a-f]{2}\.pkl\.tmp-[0-9]+")
