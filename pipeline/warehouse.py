"""The warehouse folder as every reader and the writer know it: the database's file name, the
variable its ``samples_<kind>`` views read their folder from, the ``samples_files`` table, the
internal tables, and what the DDL says each table and column is.

The writer (:mod:`pipeline.rebuild.assemble`) builds the database from these; the door
(:mod:`pipeline.serve.door`), the catalogue and the docs' table reference
(:mod:`pipeline.serve.reference`) read by them.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import stat
import tempfile
from pathlib import Path

from pipeline.own_files import read_own_file
from schemas import ddl_statements

DB_NAME = "pneubench.duckdb"


#: DuckDB variable holding the warehouse folder; the ``samples_<kind>`` views read their
#: Parquet files relative to it, so a moved or copied warehouse reads its own files. Every
#: pneubench reader sets it (:func:`pipeline.serve.door.connect_readonly`); another DuckDB client runs
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


def glob_escape(text: str) -> str:
    """``text`` with DuckDB's glob characters made literal (``[`` ``*`` ``?`` as ``[[]`` ``[*]`` ``[?]``)."""
    return "".join(f"[{c}]" if c in "[*?" else c for c in text)


#: Table of every samples file: (run_id, kind, campaign, path relative to the warehouse).
FILES_TABLE = "samples_files"

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

#: Table of the content key of every table the last rebuild wrote, and of the build's version (row ``*``):
#: the next rebuild writes only the tables whose key changed into a copy of the live database.
KEYS_TABLE = "table_keys"

#: Tables that describe the rebuild itself, not the lab's data (``pneubench tables`` marks them).
INTERNAL_TABLES = ("rebuild_log", "rebuild_inputs", "rebuild_changes", "ingest_state", "stage_cache", "figures",
                   FILES_TABLE, KEYS_TABLE)

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


#: The warehouse's folder of what the rebuild keeps between rebuilds that is not a result (the DDL's
#: tables, :func:`ddl_tables`; the decision's designs, ``pipeline.stages.decision.DESIGNS_DIR``).
CACHE_DIR = "cache"
#: The DDL's tables as DuckDB states them, ``cache/ddl-tables-<key>.json`` (:func:`ddl_tables`).
DDL_TABLES_FILE = re.compile(r"ddl-tables-[0-9a-f]{32}\.json")
#: The largest such file read [bytes] (the DDL's ~45 tables: ~20 kB).
DDL_TABLES_MAX_BYTES = 1 << 20


def ddl_tables(warehouse: str | os.PathLike | None = None) -> dict[str, str]:
    """The ``CREATE TABLE`` statement of every DDL table as the whole DDL leaves it (its later
    ``ALTER TABLE`` applied): ``{table: SQL}``, read from an in-memory DuckDB built from the DDL.

    With ``warehouse``, kept in its :data:`CACHE_DIR` under a key of the DDL's text and DuckDB's
    version (``ddl-tables-<key>.json``): the statements are a function of those two, and building the
    instance costs ~0.08 CPU-s, ~3 % of a one-file change's rebuild at 1,000 runs (issue 26). A file
    that is missing, not a regular file in a real folder (no symlink is followed), larger than
    :data:`DDL_TABLES_MAX_BYTES` or not ``{name: "CREATE TABLE ..."}`` is built again and written
    (files of other keys removed); a file that cannot be written leaves the statements as built.

    Parameters
    ----------
    warehouse : path-like, optional
        The warehouse folder (None: built, not kept).

    Returns
    -------
    dict of str to str
        Table name -> its ``CREATE TABLE`` statement.
    """
    import duckdb

    statements = ddl_statements()
    if warehouse is None:
        return _ddl_tables_built(statements)
    key = hashlib.sha256(json.dumps([duckdb.__version__, statements]).encode()).hexdigest()[:32]
    folder = Path(warehouse) / CACHE_DIR
    path = folder / f"ddl-tables-{key}.json"
    got = _read_ddl_tables(path)
    if got is not None:
        return got
    built = _ddl_tables_built(statements)
    _write_ddl_tables(folder, path, built)
    return built


def _ddl_tables_built(statements: list[tuple[str, str]]) -> dict[str, str]:
    import duckdb

    con = duckdb.connect(":memory:")
    try:
        for _name, sql in statements:
            con.execute(sql)
        return dict(con.execute("SELECT table_name, sql FROM duckdb_tables()").fetchall())
    finally:
        con.close()


def _read_ddl_tables(path: Path) -> dict[str, str] | None:
    """The statements of a :func:`ddl_tables` file, or None (see there)."""
    data = read_own_file(path, DDL_TABLES_MAX_BYTES)
    if data is None:
        return None
    try:
        got = json.loads(data.decode("utf-8"))
    except ValueError:
        return None
    if not isinstance(got, dict) or not got or not all(
            isinstance(k, str) and isinstance(v, str) and v.lstrip().upper().startswith("CREATE TABLE")
            for k, v in got.items()):
        return None
    return got


def _write_ddl_tables(folder: Path, path: Path, tables: dict[str, str]) -> None:
    """Write ``tables`` to ``path`` (whole or not at all) and remove the files of other keys."""
    try:
        folder.mkdir(exist_ok=True)
        if not stat.S_ISDIR(os.lstat(folder).st_mode):
            return
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".ddl-tables-", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                json.dump(tables, fh, sort_keys=True)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        for other in folder.iterdir():
            if other != path and DDL_TABLES_FILE.fullmatch(other.name) and not other.is_symlink():
                other.unlink(missing_ok=True)
    except OSError:
        pass  # a cache only: the statements built are used


# -- what readers of the warehouse share ---------------------------------------------------------
def log_order(columns) -> str:
    """``ORDER BY`` of ``rebuild_log``, the last rebuild first: by ``seq`` (a log from before the
    column: by its stored order, the order rebuilds appended it)."""
    return "seq DESC NULLS LAST" if "seq" in set(columns) else "rowid DESC"



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


def sql_str(text: str) -> str:
    """``text`` as an SQL string literal (its quotes doubled)."""
    return "'" + str(text).replace("'", "''") + "'"


def table_sums(con, names) -> dict[str, str]:
    """``<rows>-<sum of the rows' hashes>`` of each table of ``names`` (one query; DuckDB's ``hash`` of
    each row): the second half of a ``table_keys`` content key, which the rebuild writes, the report
    checks and the run pages key their tables by. Every name must be a table of ``con``'s database."""
    names = list(names)
    if not names:
        return {}
    sql = " UNION ALL ".join(f'SELECT {sql_str(n)}, count(*), coalesce(sum(hash(t)), 0)::VARCHAR FROM "{n}" AS t'
                             for n in names)
    return {n: f"{c}-{h}" for n, c, h in con.execute(sql).fetchall()}
