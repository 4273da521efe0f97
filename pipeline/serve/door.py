"""The one door to the warehouse: a read-only, contained DuckDB connection.

Every reader (``pneubench query``, the catalogue, the report, the rebuild's look at the previous
state) opens the warehouse through :func:`connect_readonly`: the database attached read-only
through a hard link that is gone once it is open, external access limited to the warehouse's
samples, DuckDB's memory and spill files limited, its spill files in a folder private to the
process.
"""
from __future__ import annotations

import atexit
import itertools
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.warehouse import DB_NAME, ROOT_VARIABLE, glob_escape

if TYPE_CHECKING:  # imported where a connection is made: a fresh rebuild imports this module and needs
    import duckdb  # duckdb only later, while its files are read (issue 26)

#: Default limits of every connection of the door (README, "Limits of pneubench query"):
#: DuckDB's memory (beyond it a query spills to the door's private temp folder, or fails), and
#: the spill files. The environment variables override them; ``connect_readonly``'s arguments
#: override both.
MEMORY_LIMIT = "2GB"
TEMP_LIMIT = "10GB"
MEMORY_LIMIT_ENV = "PNEUBENCH_QUERY_MEMORY_LIMIT"
TEMP_LIMIT_ENV = "PNEUBENCH_QUERY_TEMP_LIMIT"
#: ``pneubench query``'s statement timeout [s] (:data:`pipeline.serve.query.TIMEOUT_S`).
TIMEOUT_ENV = "PNEUBENCH_QUERY_TIMEOUT"


class DoorSettingError(ValueError):
    """A ``$PNEUBENCH_QUERY_*`` variable whose value the door cannot use (one line naming it and its value)."""


class UnreadableDatabase(RuntimeError):
    """The warehouse's database file is there but DuckDB cannot open it (empty, damaged, foreign):
    one line naming the file. ``path``: that file."""

    def __init__(self, message: str, path: Path):
        super().__init__(message)
        self.path = path


def check_environment(overridden: tuple[str, ...] = ()) -> None:
    """Refuse a bad ``$PNEUBENCH_QUERY_MEMORY_LIMIT``, ``$PNEUBENCH_QUERY_TEMP_LIMIT`` or
    ``$PNEUBENCH_QUERY_TIMEOUT`` before any work, rather than at the first connection.

    An unset or empty variable is the default. The sizes are checked by DuckDB itself (duckdb
    is imported only when one of them is set).

    Parameters
    ----------
    overridden : tuple of str
        Variables an option replaces in this call (``pneubench query --memory-limit``): not checked.

    Raises
    ------
    DoorSettingError
        Naming the first bad variable and its value.
    """
    if TIMEOUT_ENV not in overridden:
        timeout_from_env()
    sizes = [(env, setting, default) for env, setting, default in ((MEMORY_LIMIT_ENV, "memory_limit", MEMORY_LIMIT),
                                                                   (TEMP_LIMIT_ENV, "max_temp_directory_size", TEMP_LIMIT))
             if os.environ.get(env) and env not in overridden]
    if not sizes:
        return
    import duckdb

    con = duckdb.connect(":memory:")
    try:
        for env, setting, default in sizes:
            try:
                _limit(con, setting, None, env, default)  # the connection's own rule and words
            except ValueError as exc:
                raise DoorSettingError(str(exc)) from None
    finally:
        con.close()


def timeout_from_env() -> float | None:
    """``$PNEUBENCH_QUERY_TIMEOUT`` in seconds; None when it is unset or empty.

    Raises
    ------
    DoorSettingError
        When it is not a finite number of seconds >= 0 (0: no timeout).
    """
    text = (os.environ.get(TIMEOUT_ENV) or "").strip()
    if not text:
        return None
    try:
        seconds = float(text)
    except ValueError:
        seconds = float("nan")
    if not 0 <= seconds < float("inf"):
        raise DoorSettingError(f"${TIMEOUT_ENV} = {text!r}: not a number of seconds >= 0 (0: no timeout)")
    return seconds

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
    import duckdb

    alias = private / f"db-{n}.duckdb"
    try:
        os.link(db, alias)
    except OSError:
        shutil.copyfile(db, alias)
    try:
        con.execute("ATTACH ? AS pneubench (READ_ONLY)", [str(alias)])
    except duckdb.Error as exc:  # empty, damaged, another program's: named by its own path, not the link's
        why = str(exc).splitlines()[0].replace(str(alias), str(db))
        raise UnreadableDatabase(f"{db} is not a readable DuckDB database ({why}); `pneubench rebuild` builds "
                                 "it again", db) from None
    finally:
        alias.unlink(missing_ok=True)


def _limit(con: duckdb.DuckDBPyConnection, setting: str, value: str | None, env: str, default: str) -> None:
    """Set a size ``setting``: ``value``, else ``$env``, else ``default``; ValueError when DuckDB refuses it."""
    import duckdb

    source = setting if value is not None else f"${env} ="
    value = value if value is not None else (os.environ.get(env) or default)
    try:
        con.execute(f"SET {setting} = ?", [str(value)])
    except duckdb.Error as exc:
        raise ValueError(f"{source} {value!r}: not a size DuckDB understands such as 2GB or 500MB "
                         f"({str(exc).splitlines()[0]})") from None


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
    UnreadableDatabase
        When the database file is not one DuckDB can open (empty, damaged).
    ValueError
        When a limit is not a size DuckDB understands.
    """
    warehouse = Path(warehouse).resolve()
    db = Path(database).resolve() if database is not None else warehouse / DB_NAME
    if not db.is_file():
        raise FileNotFoundError(f"no warehouse at {db} (run `pneubench rebuild` first)")
    import duckdb

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
        con.execute("SET allowed_directories = ?", [sorted({samples, glob_escape(samples)})])
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
    except Exception:
        con.close()
        raise
    return con
