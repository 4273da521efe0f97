"""The parts cache: the report's parts that depend on the data only (the results sections with
their contents entries, the index of runs, the decision), kept in the report folder under the inputs key of the
rebuild that rendered them and the key of the code that rendered them (:func:`parts_key`). Equal
inputs keys mean equal result tables (the rebuild is deterministic) and equal code keys the same
rendering, so the next report with the same key takes them as they are (the no-op rebuild); a
report rendered by changed code (``pneubench report`` after an update) renders them anew."""
from __future__ import annotations

import json
import os
from pathlib import Path

from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.figures import code_key
from pipeline.serve.report.folders import REPORT_DIR

#: The cache file in a report folder.
PARTS_CACHE = ".parts-cache.json"
#: The code the parts are rendered with: all of the project's (the report reads the stages'
#: declarations, which import the analyses: the closure of what it imports is nearly all of it,
#: and hashing all of it costs a few hundredths of a second).
REPORT_CODE = ("pipeline/**/*.py", "analyses/**/*.py", "schemas/**/*.py", "schemas/**/*.sql")


def parts_key(db: ReportDB, code: str | None = None) -> str | None:
    """The key the parts are kept under: the database's inputs key and the version of the code
    rendering them (None without an inputs key). ``code``: that version as the caller knows it (the
    rebuild gives its hash of all of the project's code, ``pipeline.versions.project_code_version``,
    so that a rebuild hashes the code once); None: :data:`REPORT_CODE`'s
    :func:`~pipeline.serve.report.figures.code_key` (``pneubench report``)."""
    key = db.inputs_key()
    return None if key is None else f"{key}-{code or code_key(REPORT_CODE)}"


def cached_parts(db: ReportDB, warehouse: Path, code: str | None = None) -> tuple[str, list, str, str] | None:
    """(results HTML, contents entries, runs index HTML, decision HTML) of the live report when its
    key is :func:`parts_key` (of ``code``); None otherwise (no key, no cache, other inputs or code,
    a damaged file, a cache written before a part was kept)."""
    key = parts_key(db, code)
    if key is None:
        return None
    try:
        data = _live_cache(Path(warehouse))
        if data.get("key") != key:
            return None
        toc = [(a, t, [tuple(x) for x in sub]) for a, t, sub in data["toc"]]
        return str(data["results"]), toc, str(data["runs_index"]), str(data["decision"])
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None  # none yet, or damaged: rendered anew


def live_keyed(warehouse: Path) -> dict:
    """The parts the live report kept by the keys of the tables they read
    (:class:`~pipeline.serve.report.keyed.KeyedParts`; {} when there are none or the file is damaged)."""
    try:
        data = _live_cache(Path(warehouse))
        keyed = data.get("keyed") if isinstance(data, dict) else None
        return keyed if isinstance(keyed, dict) else {}
    except (OSError, ValueError):
        return {}


#: The live report's parts cache as last read: (its file's identity, what it holds).
_LAST_READ: list = [None, None]


def _live_cache(warehouse: Path):
    """The live report's parts cache, parsed (raises OSError, ValueError). Read once for
    :func:`cached_parts` and :func:`live_keyed` both (a few MB of JSON: the results are in it twice),
    again when the file is another (its path, inode, size or time)."""
    path = warehouse / REPORT_DIR / PARTS_CACHE
    st = path.stat()
    ident = (str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns)
    if _LAST_READ[0] != ident:
        _LAST_READ[:] = [None, None]
        _LAST_READ[:] = [ident, json.loads(path.read_text(encoding="utf-8"))]
    return _LAST_READ[1]


def cache_parts(db: ReportDB, folder: Path, results: str, toc: list, runs_index: str, decision: str,
                code: str | None = None, keyed: dict | None = None) -> None:
    """Keep the parts in the new report ``folder`` under :func:`parts_key` of ``code`` (none without one),
    and ``keyed``: the parts kept by the keys of the tables they read (``KeyedParts.kept``)."""
    key = parts_key(db, code)
    if key is None:
        return
    tmp = folder / f".parts-cache.tmp-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps({"key": key, "results": results, "toc": toc, "runs_index": runs_index,
                                   "decision": decision, "keyed": keyed or {}}),
                       encoding="utf-8")
        os.replace(tmp, folder / PARTS_CACHE)
    except OSError:
        tmp.unlink(missing_ok=True)  # a cache only: the report itself is unaffected
