"""Per-item memo of the stages' per-run work: a changed run costs its own analysis, not its stage's.

The stage cache (``pipeline/state.py``) re-runs a whole stage when any run it reads changed. Most
of a stage's time is its per-run work, done through ``StageContext.map(func, items)``; the memo
keeps the result of every item so that a re-run stage computes only the items that are new.

Key
    ``sha256`` of the function (module and qualified name), the code version of its module and
    every project module it imports (:func:`pipeline.state.stage_code_version`), the Python and
    numerical libraries' versions, and a canonical JSON of the item (``sort_keys``; tuples kept
    apart from lists; strings naming files under the warehouse stored relative to it, so a
    moved warehouse still hits). Samples file names are content-addressed (source bytes,
    metadata, ingest code), so an item names its input completely. An item that cannot be
    serialised canonically (objects, non-string dict keys) is computed and not memoised.
Storage
    ``memo/<stage>.pkl`` in the warehouse: ``{key: pickled result}`` of the items of the stage's
    last run only, rewritten atomically (temp file, ``os.replace``) each time the stage runs; so
    results of runs that are gone disappear with the next run of their stage. A stage whose
    cached outputs are reused keeps its memo file as it is (its items did not change). A memo
    file whose stage has no folder the warehouse still keeps is collected
    (:func:`pipeline.rebuild.collect_garbage`). A missing, damaged or unreadable memo file, or
    entry, is a miss: the item is computed again, never a failure.
Trust
    The values are pickles: the memo is the pipeline's own output, read only from the warehouse
    the rebuild writes (never through a symlink), so the warehouse must be writable only by the
    account that runs the rebuild (``docs/security.md``).

A ``--full`` rebuild does not read the memo (it computes every item) but writes it. Analyses run
without the rebuild (a plain :class:`pipeline.stages.StageContext`) have no memo.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import re
import stat as stat_mod
import sys
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

#: Folder of the memo files, relative to the warehouse.
MEMO_DIR = "memo"
#: Bump when the key or the file layout changes (old files are then misses).
FORMAT = 1
#: A memo file (``<stage>.pkl``) and its temp name (``.<stage>.pkl.tmp-<pid>``).
MEMO_FILE = re.compile(r"([a-z_][a-z0-9_]*)\.pkl")
MEMO_TMP = re.compile(r"\.[a-z_][a-z0-9_]*\.pkl\.tmp-[0-9]+")


class _NotCanonical(Exception):
    pass


@lru_cache(maxsize=1)
def environment() -> str:
    """Python and the numerical libraries a result may depend on (part of every key)."""
    parts = [f"python {sys.version_info[0]}.{sys.version_info[1]}.{sys.version_info[2]}"]
    for name in ("numpy", "pandas", "scipy", "pyarrow"):
        mod = sys.modules.get(name)
        if mod is None:
            try:
                mod = __import__(name)
            except ImportError:
                parts.append(f"{name} -")
                continue
        parts.append(f"{name} {getattr(mod, '__version__', '?')}")
    return "; ".join(parts)


def code_version(func: Callable) -> str | None:
    """Version of ``func``'s module and the project code it imports; None: not memoisable."""
    from pipeline.state import stage_code_version

    mod = sys.modules.get(getattr(func, "__module__", None) or "")
    file = getattr(mod, "__file__", None)
    if not file:
        return None
    return stage_code_version(file)


def _canonical(value, prefix: str):
    """``value`` as JSON-able data with unambiguous types; raises :class:`_NotCanonical`."""
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, str):
        return {"wh": value[len(prefix):]} if value.startswith(prefix) else value
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return {"float": repr(float(value))}  # exact, NaN and -0.0 included
    if isinstance(value, os.PathLike):
        return {"path": _canonical(os.fspath(value), prefix)}
    if isinstance(value, tuple):
        return {"tuple": [_canonical(v, prefix) for v in value]}
    if isinstance(value, list):
        return [_canonical(v, prefix) for v in value]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise _NotCanonical("dict with keys that are not strings")
        return {"dict": {k: _canonical(v, prefix) for k, v in value.items()}}
    raise _NotCanonical(type(value).__name__)


def item_key(func: Callable, item, warehouse: str | Path) -> str | None:
    """The memo key of ``func(item)``, or None when it cannot be memoised."""
    qualname = getattr(func, "__qualname__", "") or ""
    module = getattr(func, "__module__", "") or ""
    if not qualname or not module or "<" in qualname:  # lambdas, local functions
        return None
    version = code_version(func)
    if version is None:
        return None
    prefix = os.fspath(warehouse).rstrip(os.sep) + os.sep
    try:
        blob = json.dumps({"format": FORMAT, "func": f"{module}:{qualname}", "code": version, "env": environment(),
                           "item": _canonical(item, prefix)}, sort_keys=True, separators=(",", ":"))
    except (_NotCanonical, ValueError, TypeError, RecursionError):
        return None
    return hashlib.sha256(blob.encode()).hexdigest()


def _real_dir(path: Path) -> bool:
    try:
        return stat_mod.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


class Memo:
    """The memo of one stage: ``map`` computes the items it has no result for.

    Parameters
    ----------
    warehouse : Path
        The warehouse; the file is ``<warehouse>/memo/<stage>.pkl``.
    stage : str
        The stage's name.
    read : bool
        Use the stored results (False for ``--full``: everything is computed, the file written).
    """

    def __init__(self, warehouse: str | Path, stage: str, read: bool = True):
        if not MEMO_FILE.fullmatch(f"{stage}.pkl"):
            raise ValueError(f"not a stage name: {stage!r}")
        self.warehouse = Path(warehouse)
        self.stage = stage
        self.read = read
        self.path = self.warehouse / MEMO_DIR / f"{stage}.pkl"
        self._old: dict[str, bytes] | None = None
        self._new: dict[str, bytes] = {}
        #: items taken from the memo / computed / computed but not memoisable
        self.hits = self.computed = self.unkeyed = 0
        self.used = False

    # -- reading ---------------------------------------------------------------------------
    def _stored(self) -> dict[str, bytes]:
        if self._old is None:
            self._old = self._load() if self.read else {}
        return self._old

    def _load(self) -> dict[str, bytes]:
        """The stored entries; empty when the file is missing, damaged or not the memo's own."""
        if not _real_dir(self.warehouse / MEMO_DIR):
            return {}
        try:
            fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
            with os.fdopen(fd, "rb") as fh:
                data = pickle.load(fh)
        except Exception:  # missing, damaged, a pickle of another version: recompute
            return {}
        if not (isinstance(data, dict) and data.get("format") == FORMAT and isinstance(data.get("entries"), dict)):
            return {}
        return {k: v for k, v in data["entries"].items() if isinstance(k, str) and isinstance(v, bytes)}

    # -- the map -----------------------------------------------------------------------------
    def map(self, compute: Callable, func: Callable, items: list, label: str = "") -> list:
        """``compute(func, items_to_do, label)`` for the items without a stored result; results
        in item order, stored ones unpickled afresh (a caller may modify what it gets)."""
        self.used = True
        keys = [item_key(func, it, self.warehouse) for it in items]
        stored = self._stored() if any(k is not None for k in keys) else {}
        out: list = [None] * len(items)
        todo: list[int] = []
        for i, k in enumerate(keys):
            blob = stored.get(k) if k is not None else None
            if blob is not None:
                try:
                    out[i] = pickle.loads(blob)
                except Exception:  # a damaged entry: computed again
                    todo.append(i)
                    continue
                self._new[k] = blob
                self.hits += 1
            else:
                todo.append(i)
        if todo:
            results = compute(func, [items[i] for i in todo], label)
            for i, res in zip(todo, results):
                out[i] = res
                self.computed += 1
                if keys[i] is None:
                    self.unkeyed += 1
                    continue
                try:
                    self._new[keys[i]] = pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL)
                except Exception:  # a result that cannot be pickled is simply not kept
                    self.unkeyed += 1
        return out

    # -- writing -----------------------------------------------------------------------------
    def save(self) -> None:
        """Write the entries used by this run of the stage (temp file, then ``os.replace``); a
        stage without any memoised item leaves no file. Failing to write is not an error."""
        folder = self.warehouse / MEMO_DIR
        try:
            if not self._new:
                if _real_dir(folder) and stat_mod.S_ISREG(os.lstat(self.path).st_mode):
                    self.path.unlink()
                return
        except OSError:
            return
        tmp = folder / f".{self.stage}.pkl.tmp-{os.getpid()}"
        try:
            folder.mkdir(exist_ok=True)
            if not _real_dir(folder):
                return
            with open(tmp, "wb") as fh:
                pickle.dump({"format": FORMAT, "stage": self.stage, "entries": self._new}, fh,
                            protocol=pickle.HIGHEST_PROTOCOL)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except OSError:
            try:
                tmp.unlink()
            except OSError:
                pass

    def summary(self) -> str:
        """``"per-run: N from the memo, M computed"`` (empty when the stage mapped nothing)."""
        if not self.used:
            return ""
        return f"per-run results: {self.hits} from the memo, {self.computed} computed"
