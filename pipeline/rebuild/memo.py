"""Per-item memo of the stages' per-run work: a changed run costs its own analysis, not its stage's.

The stage cache (``pipeline/rebuild/state.py``) re-runs a whole stage when any run it reads changed. Most
of a stage's time is its per-run work, done through ``StageContext.map(func, items)``; the memo
keeps the result of every item so that a re-run stage computes only the items that are new.

Key
    ``sha256`` of the function (module and qualified name), the code version of its module and
    every project module it imports (:func:`pipeline.versions.stage_code_version`), the Python and
    numerical libraries' versions, and a canonical JSON of the item (``sort_keys``; tuples kept
    apart from lists; strings naming files under the warehouse stored relative to it, so a
    moved warehouse still hits). Samples file names are content-addressed (source bytes,
    metadata, ingest code), so an item names its input completely. An item that cannot be
    serialised canonically (objects, non-string dict keys) is computed and not memoised. An item
    with a ``memo_key`` attribute is keyed by it alone (the rest of the item derived from it).
Storage
    ``memo/<stage>/<xx>.pkl`` in the warehouse, ``xx`` the first two hex digits of the keys it
    holds (at most 256 shards per stage): ``{key: pickled result}`` of the items of the stage's
    last run only. ``map`` reads only the shards of the keys it is asked for. ``save`` keeps
    exactly the entries this run used: it rewrites (temp files fsynced together, then ``os.replace``) only the shards
    whose set of entries changed (new keys, or keys no longer used), leaves the others untouched,
    and deletes the shard files left with no entry, also those no key was asked for (their
    entries are all unused: deleted without being read); so results of runs that are gone
    disappear with the next run of their stage, and one changed run rewrites one shard. Until
    ``save`` the results computed in this run wait, pickled, in an unnamed temporary file in the
    warehouse (removed by the system when the rebuild ends, however it ends), not in memory; a
    saved memo holds no entries (issue 26: a stage's memory does not grow with its items). A stage
    whose cached outputs are reused keeps its memo folder as it is (its items did not change). A
    memo folder whose stage has no folder the warehouse still keeps is collected
    (:func:`pipeline.rebuild.garbage.collect_garbage`). A missing, damaged or unreadable shard file, or
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
import tempfile
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

from pipeline.versions import function_code_version
from pipeline.warehouse import SHARD_FILE, STAGE_NAME

#: Folder of the memo, relative to the warehouse: one folder per stage.
MEMO_DIR = "memo"
#: Bump when the key or the file layout changes (old files are then misses).
FORMAT = 2
#: Hex digits of a key that name its shard file (``memo/<stage>/<xx>.pkl``: at most 256 shards).
SHARD_CHARS = 2
_KEY = re.compile(r"[0-9a-f]{64}")
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)  # a FIFO in a shard's place does not block the open


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
    """The memo key of ``func(item)``, or None when it cannot be memoised. An item with a ``memo_key`` attribute
    is keyed by that alone: what the result depends on, the rest of the item being derived from it (e.g. the
    decision's looks item carrying its design-free parts, computed by another memoised map; session 26)."""
    item = getattr(item, "memo_key", item)
    qualname = getattr(func, "__qualname__", "") or ""
    module = getattr(func, "__module__", "") or ""
    if not qualname or not module or "<" in qualname:  # lambdas, local functions
        return None
    version = function_code_version(func)
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


def _regular_file(path: Path) -> bool:
    try:
        return stat_mod.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def shard_of(key: str) -> str:
    """The shard a key is stored in: its first two hex digits (256 shards)."""
    return key[:SHARD_CHARS]


def _discard(fh, tmp: Path) -> None:
    """Close ``fh`` (if any) and remove the temporary file ``tmp``; errors ignored."""
    for step in ((lambda: fh.close()) if fh is not None else None, tmp.unlink):
        if step is None:
            continue
        try:
            step()
        except OSError:
            pass


class Memo:
    """The memo of one stage: ``map`` computes the items it has no result for.

    Parameters
    ----------
    warehouse : Path
        The warehouse; the files are ``<warehouse>/memo/<stage>/<xx>.pkl``.
    stage : str
        The stage's name.
    read : bool
        Use the stored results (False for ``--full``: everything is computed, every shard written).
    """

    def __init__(self, warehouse: str | Path, stage: str, read: bool = True):
        if not STAGE_NAME.fullmatch(stage):
            raise ValueError(f"not a stage name: {stage!r}")
        self.warehouse = Path(warehouse)
        self.stage = stage
        self.read = read
        self.folder = self.warehouse / MEMO_DIR / stage
        #: shard -> its stored entries, for the shards read so far (a shard is read once, when a
        #: key in it is first asked for)
        self._stored: dict[str, dict[str, bytes]] = {}
        #: shards whose file holds something else than ``_stored[shard]`` (damaged, foreign,
        #: entries of another shard): rewritten by ``save`` even when the keys are the same
        self._unclean: set[str] = set()
        #: shards to which ``map`` added a computed result
        self._computed_in: set[str] = set()
        #: key -> the entry this run used: its bytes (taken from a stored shard), or where in
        #: :attr:`_spill` a result computed tonight was written (offset, length)
        self._new: dict[str, bytes | tuple[int, int]] = {}
        #: the results computed tonight, pickled, until :meth:`save` writes them into their shards:
        #: an unnamed temporary file in the warehouse (gone with the process, whatever ends it),
        #: so that a stage's memory does not grow with its items (issue 26)
        self._spill = None
        #: items taken from the memo / computed / computed but not memoised
        self.hits = self.computed = self.unkeyed = 0
        self.used = False
        #: shard files written by :meth:`_write` and not yet committed (:meth:`_commit`): (file, temp, path)
        self._staged: list | None = None

    def shard_path(self, shard: str) -> Path:
        return self.folder / f"{shard}.pkl"

    def _readable(self) -> bool:
        return _real_dir(self.warehouse / MEMO_DIR) and _real_dir(self.folder)

    # -- reading ---------------------------------------------------------------------------
    def _load_shards(self, shards) -> None:
        todo = [s for s in shards if s not in self._stored]
        if not todo:
            return
        readable = self.read and self._readable()
        for shard in sorted(todo):
            self._stored[shard] = self._load(shard) if readable else {}

    def _load(self, shard: str) -> dict[str, bytes]:
        """The stored entries of one shard; empty when its file is missing, damaged, not a
        regular file or not the memo's own."""
        try:
            fd = os.open(self.shard_path(shard), os.O_RDONLY | _NOFOLLOW | _NONBLOCK)
        except OSError:
            return {}  # missing, a symlink
        try:
            with os.fdopen(fd, "rb") as fh:
                if not stat_mod.S_ISREG(os.fstat(fh.fileno()).st_mode):
                    self._unclean.add(shard)
                    return {}
                data = pickle.load(fh)
        except Exception:  # damaged, a pickle of another version: recompute
            self._unclean.add(shard)
            return {}
        if not (isinstance(data, dict) and data.get("format") == FORMAT and data.get("stage") == self.stage
                and data.get("shard") == shard and isinstance(data.get("entries"), dict)):
            self._unclean.add(shard)
            return {}
        entries = {k: v for k, v in data["entries"].items()
                   if isinstance(k, str) and _KEY.fullmatch(k) and k.startswith(shard) and isinstance(v, bytes)}
        if len(entries) != len(data["entries"]):
            self._unclean.add(shard)
        return entries

    # -- the map -----------------------------------------------------------------------------
    def map(self, compute: Callable, func: Callable, items: list, label: str = "") -> list:
        """``compute(func, items_to_do, label)`` for the items without a stored result; results
        in item order, stored ones unpickled afresh (a caller may modify what it gets). Only the
        shards of the items' keys are read."""
        self.used = True
        keys = [item_key(func, it, self.warehouse) for it in items]
        self._load_shards({shard_of(k) for k in keys if k is not None})
        out: list = [None] * len(items)
        todo: list[int] = []
        for i, k in enumerate(keys):
            blob = self._stored[shard_of(k)].get(k) if k is not None else None
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
                k = keys[i]
                if k is None:
                    self.unkeyed += 1
                    continue
                try:
                    self._new[k] = self._spilled(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
                except Exception:  # a result that cannot be pickled (or spilled) is simply not kept
                    self.unkeyed += 1
                    continue
                self._computed_in.add(shard_of(k))
        return out

    def _spilled(self, blob: bytes) -> tuple[int, int]:
        """Write ``blob`` to the spill file; where it is (offset, length)."""
        if self._spill is None:
            self._spill = tempfile.TemporaryFile(dir=self.warehouse)
        offset = self._spill.seek(0, os.SEEK_END)
        self._spill.write(blob)
        return offset, len(blob)

    def _blob(self, entry: bytes | tuple[int, int]) -> bytes:
        """An entry of :attr:`_new` as bytes (read back from the spill file)."""
        if isinstance(entry, bytes):
            return entry
        offset, length = entry
        self._spill.seek(offset)
        blob = self._spill.read(length)
        if len(blob) != length:
            raise OSError("the memo's spill file is short")
        return blob

    def release(self) -> None:
        """Forget the entries (the counts stay for :meth:`summary`) and close the spill file."""
        self._new, self._stored = {}, {}
        if self._spill is not None:
            self._spill.close()
            self._spill = None

    # -- writing -----------------------------------------------------------------------------
    def _unchanged(self, shard: str, entries: dict) -> bool:
        """Whether the shard's file already holds exactly ``entries`` (the same keys, every value
        taken from it, nothing else in it)."""
        stored = self._stored.get(shard)
        return (stored is not None and shard not in self._unclean and shard not in self._computed_in
                and stored.keys() == entries.keys())

    def save(self) -> None:
        """Keep exactly the entries used by this run of the stage: rewrite (temp file, then
        ``os.replace``) only the shards whose entries differ from their file's, delete the shard
        files left with none (without reading them). A stage without any memoised item leaves nothing. Failing to write is not an error.
        The memo is released afterwards (:meth:`release`): a saved memo holds no entries."""
        try:
            self._save()
        finally:
            self.release()

    def _save(self) -> None:
        memo = self.warehouse / MEMO_DIR
        by_shard: dict[str, dict[str, bytes | tuple[int, int]]] = {}
        for k, blob in self._new.items():
            by_shard.setdefault(shard_of(k), {})[k] = blob
        try:
            if not by_shard and not _real_dir(memo):
                return
            if by_shard:
                memo.mkdir(exist_ok=True)
                if not _real_dir(memo):
                    return
                self.folder.mkdir(exist_ok=True)
            if not _real_dir(self.folder):
                return
            with os.scandir(self.folder) as it:
                on_disk = {e.name[:SHARD_CHARS] for e in it
                           if SHARD_FILE.fullmatch(e.name) and e.is_file(follow_symlinks=False)}
        except OSError:
            return
        for shard in sorted(on_disk - by_shard.keys()):  # only entries no longer used
            try:
                self.shard_path(shard).unlink()
            except OSError:
                pass
        self._staged = []
        for shard, entries in sorted(by_shard.items()):
            if shard in on_disk and self._unchanged(shard, entries):
                continue
            self._write(shard, entries)
        self._commit()
        if not by_shard:
            try:
                self.folder.rmdir()
            except OSError:
                pass  # it holds something the memo did not write

    def _write(self, shard: str, entries: dict[str, bytes | tuple[int, int]]) -> None:
        """Write one shard's entries to its temporary file, left open for :meth:`_commit` (which makes it
        durable and puts it in the shard's place)."""
        path = self.shard_path(shard)
        if os.path.lexists(path) and not _regular_file(path):
            return  # a symlink or a folder in its place: left alone (the items are misses)
        tmp = self.folder / f".{shard}.pkl.tmp-{os.getpid()}"
        fh = None
        try:
            entries = {k: self._blob(v) for k, v in entries.items()}
            tmp.unlink(missing_ok=True)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW, 0o666)
            fh = os.fdopen(fd, "wb")
            pickle.dump({"format": FORMAT, "stage": self.stage, "shard": shard, "entries": entries}, fh,
                        protocol=pickle.HIGHEST_PROTOCOL)
            fh.flush()
        except OSError:
            _discard(fh, tmp)
            return
        staged = getattr(self, "_staged", None)
        if staged is None:          # called on its own: committed at once
            self._staged = [(fh, tmp, path)]
            self._commit()
        else:
            staged.append((fh, tmp, path))

    def _commit(self) -> None:
        """Every shard file :meth:`_write` staged: fsynced together (session 25: concurrent fsyncs of one
        stage's shards share the file system's journal commits, where one after another each waited for its
        own; ~200 shards a stage after a plan change), then each put in its shard's place (``os.replace``); a
        file whose fsync failed is removed, its shard left as it was."""
        staged, self._staged = getattr(self, "_staged", None) or [], None
        if not staged:
            return

        def durable(fh) -> bool:
            try:
                os.fsync(fh.fileno())
                return True
            except OSError:
                return False

        if len(staged) == 1:
            ok = [durable(staged[0][0])]
        else:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(min(16, len(staged))) as pool:
                ok = list(pool.map(durable, [fh for fh, _, _ in staged]))
        for (fh, tmp, path), good in zip(staged, ok):
            try:
                fh.close()
                if not good:
                    raise OSError("fsync failed")
                os.replace(tmp, path)
            except OSError:
                _discard(None, tmp)

    def summary(self) -> str:
        """``"per-run: N from the memo, M computed"`` (empty when the stage mapped nothing)."""
        if not self.used:
            return ""
        return f"per-run results: {self.hits} from the memo, {self.computed} computed"
