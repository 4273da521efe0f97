"""Report parts kept by the content keys of the tables they read (issue 26: the cost of a change).

The parts cache (:mod:`~pipeline.serve.report.cache`) keeps the data-only parts whole under the
rebuild's inputs key: any change of any input renders every part anew. Most parts read a few
tables, and a change of one file changes a few tables: a plan.toml setting changes the decision's
and the test plan's tables, never the leakage map. So each part rendered here (a topic of the
results, the other figures, the runs index, the decision) is rendered through a
:class:`TrackedDB` that records every table it asks about (its SQL's table names, ``has``,
``count``, ``columns``), and kept with the content key of each of those tables as the new
database stores it (``table_keys``: each table's frame key and the sum of its rows' hashes,
:func:`pipeline.rebuild.assemble.frame_key`). The next report takes the part as it is when the
code, the part's own ``extra`` inputs and every table it read have the same keys: a part is a
function of what it read (the report is deterministic), so it has the bytes it would be drawn
with. A part that read a table without a key (a ``samples_<kind>`` view, a table the no-op
updated) or asked for the list of all tables, or a database without ``table_keys``, is always
rendered anew.
"""
from __future__ import annotations

import hashlib
import json
import re
from typing import Any, Callable

from pipeline.serve.report.db import ReportDB
from pipeline.warehouse import KEYS_TABLE, table_sums

#: Identifiers in an SQL text (a table name is one of them, quoted or not).
_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: The key of a table the database does not hold (a part asked ``has`` and got False).
ABSENT = "absent"
#: SQL that reads the catalogue (which tables there are, their columns): the part depends on all of it.
_CATALOGUE = re.compile(r"\b(duckdb_\w+|information_schema|pragma_\w+|describe|show|sqlite_master)\b", re.IGNORECASE)
#: The pseudo-table of the catalogue in a part's dependencies (every table's and view's name, columns, types).
CATALOGUE = "(catalogue)"


class _TrackedCon:
    """The connection of a :class:`TrackedDB`: ``execute`` records the tables its SQL names; any
    other use of the connection makes the part uncacheable."""

    def __init__(self, owner: TrackedDB):
        self._owner = owner

    def execute(self, sql: str, *args):
        self._owner.saw_sql(sql)
        return self._owner.db.con.execute(sql, *args)

    def __getattr__(self, name: str):
        self._owner.everything = True
        return getattr(self._owner.db.con, name)


class TrackedDB:
    """A :class:`~pipeline.serve.report.db.ReportDB` that records which tables were read.

    Parameters
    ----------
    db : ReportDB
        The report's database (its answers are returned unchanged).
    views : dict of str to str, optional
        The SQL of the database's views: a view read stands for the tables it reads.

    Attributes
    ----------
    read : set of str
        Names of tables and views asked about (present or not).
    everything : bool
        True when the part asked for something not tied to named tables (the list of all tables,
        another method of the connection): it cannot be kept.
    """

    def __init__(self, db: ReportDB, views: dict[str, str] | None = None):
        self.db = db
        self.views = views or {}
        self.read: set[str] = set()
        self.everything = False
        self.con = _TrackedCon(self)

    def saw_sql(self, sql: str) -> None:
        """Record the tables of the database named in ``sql`` (every identifier that is one), and
        :data:`CATALOGUE` when it reads the catalogue."""
        for w in _WORD.findall(sql):
            if w in self.db.tables and w not in self.read:
                self.read.add(w)
                if w in self.views:  # a view: the tables its SQL reads (its own text is the DDL's: code)
                    self.saw_sql(self.views[w])
        if _CATALOGUE.search(sql):
            self.read.add(CATALOGUE)

    @property
    def tables(self) -> set[str]:
        self.read.add(CATALOGUE)  # the names of all tables: the catalogue's key covers them
        return self.db.tables

    def has(self, table: str) -> bool:
        self.read.add(table)
        return self.db.has(table)

    def run_ids(self) -> set[str]:
        self.read.add("runs")
        return self.db.run_ids()

    def rows(self, sql: str, params=None) -> tuple[list[str], list[tuple]]:
        self.saw_sql(sql)
        return self.db.rows(sql, params)

    def columns(self, table: str) -> list[str]:
        self.read.add(CATALOGUE)  # a table's columns (none when it is absent): in the catalogue's key
        return self.db.columns(table)

    def count(self, table: str) -> int:
        self.read.add(table)
        return self.db.count(table)

    def log_order(self) -> str:
        self.read.add("rebuild_log")
        return self.db.log_order()

    def generation(self) -> str:
        self.read.add("rebuild_log")
        return self.db.generation()

    def inputs_key(self) -> str | None:
        self.read.add("rebuild_log")
        return self.db.inputs_key()

    def __getattr__(self, name: str):
        self.everything = True
        return getattr(self.db, name)


def table_keys(db: ReportDB, checked: bool = False) -> dict[str, str]:
    """``table_keys`` of the database: table -> content key, for the tables whose rows are still the
    ones the rebuild wrote (the key's second half, the row count and the sum of the rows' hashes
    as stored, :func:`pipeline.warehouse.table_sums`, is checked on the table as it is: a
    table changed by anything but the rebuild has no key). Empty without ``table_keys``.

    ``checked``: the caller knows every row matches its table (the rebuild that has just written the
    database under its lock, whose keys hold the sums of the tables as written or as it checked them);
    then the sums are not taken again (one query over every table: ~0.05 CPU-s at 1,000 runs, issue 26)."""
    if not db.has(KEYS_TABLE):
        return {}
    try:
        stored = {t: k for t, k in db.con.execute(f"SELECT table_name, content_key FROM {KEYS_TABLE}").fetchall()
                  if t != "*" and isinstance(k, str) and ":" in k}
        present = {r[0] for r in db.con.execute("SELECT table_name FROM duckdb_tables() "
                                                "WHERE database_name = current_database()").fetchall()}
        names = sorted(t for t in stored if t in present)
        if not names:
            return {}
        if checked:
            return {t: stored[t] for t in names}
        sums = table_sums(db.con, names)
    except Exception:  # a damaged or foreign table_keys: nothing is kept
        return {}
    return {t: stored[t] for t in names if stored[t].rsplit(":", 1)[1] == sums.get(t)}


def _view_sql(db: ReportDB) -> dict[str, str]:
    """The SQL of every view of the database (none when it cannot be read)."""
    try:
        return {n: q or "" for n, q in db.con.execute(
            "SELECT view_name, sql FROM duckdb_views() WHERE NOT internal "
            "AND database_name = current_database()").fetchall()}
    except Exception:
        return {}


class KeyedParts:
    """The report's parts, each taken from the live report when what it read is unchanged.

    Parameters
    ----------
    db : ReportDB
        The database the report is rendered from.
    code : str
        The version of the code rendering the parts (a changed code renders every part anew).
    old : dict
        The live report's kept parts (:attr:`kept` of the report before; {} for none).
    checked : bool
        Every ``table_keys`` row matches its table (:func:`table_keys`).

    Attributes
    ----------
    kept : dict
        The parts of this report, to keep in its folder: name -> {"key", "deps", "value"}.
    taken, rendered : int
        How many parts were taken from the live report, and rendered.
    """

    def __init__(self, db: ReportDB, code: str, old: dict | None = None, checked: bool = False):
        self.db = db
        self.code = code
        self.keys = table_keys(db, checked)
        self.views = _view_sql(db) if self.keys else {}
        self.old = old if isinstance(old, dict) and self.keys else {}
        self.kept: dict[str, dict] = {}
        self.taken = self.rendered = 0

    def _catalogue_key(self) -> str:
        """A key of the catalogue: every table's and view's name and its columns' names and types."""
        if not hasattr(self, "_catalogue"):
            rows = self.db.con.execute(
                "SELECT table_name, column_name, data_type FROM duckdb_columns() "
                "WHERE database_name = current_database() ORDER BY ALL").fetchall()
            blob = json.dumps([sorted(self.db.tables), rows], default=str)
            self._catalogue = hashlib.sha256(blob.encode("utf-8", "surrogatepass")).hexdigest()[:32]
        return self._catalogue

    def _dep_key(self, table: str) -> str | None:
        """The content key of ``table`` now (:data:`ABSENT` when the database lacks it; None: it has no key)."""
        if table == CATALOGUE:
            return self._catalogue_key()
        if table in self.views:  # what it reads is among the dependencies; its text is code
            return "view"
        if table in self.keys:
            return self.keys[table]
        return None if self.db.has(table) else ABSENT

    def _part_key(self, name: str, extra: Any) -> str:
        blob = json.dumps([self.code, name, extra], default=str, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode("utf-8", "surrogatepass")).hexdigest()[:32]

    def taken_from_live(self, name: str, extra: Any = None) -> bool:
        """Whether the live report's part ``name`` is valid now (its key, of ``extra``, and the keys
        of every table it read are unchanged); then it is kept in this report too."""
        old = self.old.get(name)
        if isinstance(old, dict) and old.get("key") == self._part_key(name, extra) and \
                isinstance(old.get("deps"), dict) and all(self._dep_key(t) == k for t, k in old["deps"].items()):
            self.kept[name] = old
            self.taken += 1
            return True
        return False

    def render(self, name: str, render: Callable[[Any], Any], extra: Any = None) -> Any:
        """``render(db)`` through a :class:`TrackedDB`, kept under ``name`` with the keys of the
        tables it read (unless it read one without a key, or there are no keys)."""
        tracked = TrackedDB(self.db, self.views)
        value = render(tracked)
        self.rendered += 1
        deps = {t: self._dep_key(t) for t in sorted(tracked.read)}
        if self.keys and not tracked.everything and None not in deps.values():
            self.kept[name] = {"key": self._part_key(name, extra), "deps": deps, "value": value}
        return value

    def get(self, name: str, render: Callable[[Any], Any], extra: Any = None) -> Any:
        """The part ``name``: the live report's when its key (code, ``extra``) and the keys of every
        table it read are unchanged (:meth:`taken_from_live`), else :meth:`render`. The value must
        be JSON data (str, lists); it is returned as JSON gives it back when taken (tuples as lists)."""
        if self.taken_from_live(name, extra):
            return self.kept[name].get("value")
        return self.render(name, render, extra)
