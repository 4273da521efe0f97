"""The rebuild: ingest raw/, run the analysis stages, swap in a new warehouse.

Incremental (``pipeline/rebuild/state.py``): a run file whose content, applicable metadata and ingest
code are unchanged is not read again; a stage whose inputs are unchanged is not run again (its
cached outputs are reused). ``full=True`` rebuilds everything. Either way the result is the same.

Atomic: everything the new database refers to is written first into immutable,
content-addressed files (``samples/.../<run>-<key>.parquet``, ``stages/<stage>/<key>/``); then the
database is built under a temporary name and swapped in with one ``os.replace``. A reader opening
``pneubench.duckdb`` sees the previous complete warehouse or the new one. Files of the previous
generation are kept (a reader may still be using them); older ones are collected. The incremental
state lives inside the database, so it always matches the data it describes. ``kill -9`` at any
point leaves the previous warehouse as it was; the next rebuild removes the debris.

Exit codes (warehouse.md): 0 everything used; 1 warehouse built, some inputs quarantined;
2 usage error; anything else: failed, the previous warehouse untouched (3 failed, 4 another
rebuild holds the lock). The morning report is rendered from the new database before the swap,
so a report that cannot be rendered is a failure too (3), with the previous warehouse and its
report kept: the two always agree.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import re
import shutil
import signal
import stat as stat_mod
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.rebuild.executors import CRASH_REASON, STUCK_REASON, Executor, default_jobs, forked_pool, make_executor
from pipeline.rebuild.executors import _kill_workers  # stop the figure worker of an interrupted rebuild
from pipeline.raw.layout import Problem, RawTree, discover_runs, skip_reason
from pipeline.rebuild.memo import LEGACY_FILE, LEGACY_TMP, MEMO_DIR, SHARD_FILE, SHARD_TMP, STAGE_NAME, Memo
from pipeline.readers import READERS
from pipeline.progress import Progress
from pipeline.versions import project_code_version
from pipeline.rebuild.state import (KEEP_SUPERSEDED_H, FilePlan, FileRecord, PreviousState, StageRecord, frame_hash,
                            ingest_code_version, load_previous, logbook_hash, plan_runs, record_for, side_records,
                            stage_code_version, stage_input_key, superseded_files)
from pipeline.rebuild.assemble import build_database, runs_frame, swap_in
from pipeline.warehouse import DB_NAME
from schemas.kind_names import KIND_NAMES  # not schemas.kinds: a no-op needs no pyarrow
from pipeline.rebuild.state import record_result  # files of several runs (kept apart for the merge)

log = logging.getLogger("pneubench")

if TYPE_CHECKING:
    import pandas as pd

    from pipeline import stages as stage_registry
    from pipeline.ingest.file import IngestResult

# pandas, pyarrow, numpy and the analyses are imported by the functions that use them, not here:
# a no-op rebuild needs none of them (~0.5 s of a 10,000-run no-op's 2 s budget; issue 14).


def sha256_file(path, *args, **kwargs):
    """:func:`pipeline.ingest.file.sha256_file` (imported when a file is first hashed)."""
    from pipeline.ingest.file import sha256_file as _sha256_file

    return _sha256_file(path, *args, **kwargs)


def ingest_file(tree, path, *args, **kwargs):
    """:func:`pipeline.ingest.file.ingest_file` (imported when a file is first read)."""
    from pipeline.ingest.file import ingest_file as _ingest_file

    return _ingest_file(tree, path, *args, **kwargs)

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE, EXIT_FAILED, EXIT_LOCKED = 0, 1, 2, 3, 4

#: Test hook: ``PNEUBENCH_CRASH_AT=<point>`` kills the rebuild with SIGKILL at that point.
CRASH_POINTS = ("after_ingest", "after_stages", "before_swap", "between_swaps", "after_swap")

#: Rows of ``rebuild_log`` carried from one warehouse to the next.
HISTORY_ROWS = 200

#: A rebuild that would drop more than this share of the live warehouse's runs (their raw files
#: gone: a share not mounted, a raw/ moved) is refused (exit 2) unless it is allowed...
MASS_DELETE_SHARE = 0.5
#: ... when it drops at least this many runs; one that drops every run is refused whatever their number.
MASS_DELETE_MIN_RUNS = 5


class RebuildError(Exception):
    """The rebuild failed; the previous warehouse is untouched. ``exit_code`` says how."""

    def __init__(self, message: str, exit_code: int = EXIT_FAILED):
        super().__init__(message)
        self.exit_code = exit_code


@dataclass
class RebuildSummary:
    """What a rebuild did."""

    raw: Path
    warehouse: Path
    n_files: int = 0
    n_runs: int = 0
    quarantine: list[Problem] = field(default_factory=list)
    seconds: float = 0.0
    tables: dict[str, int] = field(default_factory=dict)
    generation: str = ""
    mode: str = "incremental"
    n_new: int = 0
    n_changed: int = 0
    n_deleted: int = 0
    n_unchanged: int = 0
    stages_run: list[str] = field(default_factory=list)
    stages_reused: list[str] = field(default_factory=list)
    report: Path | None = None

    @property
    def exit_code(self) -> int:
        return EXIT_QUARANTINED if self.quarantine else EXIT_OK


def _crash_point(name: str, sig: int = signal.SIGKILL) -> None:
    """Test-only: die by ``sig`` here when ``PNEUBENCH_CRASH_AT`` names this point
    (``PNEUBENCH_CRASH_SIGNAL=SIGSTOP``: stop instead, as a reader stuck in a loop would)."""
    if os.environ.get("PNEUBENCH_CRASH_AT") == name:
        other = os.environ.get("PNEUBENCH_CRASH_SIGNAL")
        os.kill(os.getpid(), getattr(signal, other) if other in ("SIGSTOP", "SIGSEGV", "SIGKILL") else sig)


@contextmanager
def warehouse_lock(warehouse: Path, wait_s: float = 0.0, on_wait=None):
    """Hold the warehouse's rebuild lock; a second rebuild waits ``wait_s`` then gives up.

    ``flock`` on ``.rebuild.lock``: the kernel releases it when the holder dies, even by
    ``kill -9`` (worker processes are started by a fork server and do not inherit it). The
    holder writes ``<pid> on <host> since <time>`` into it; ``on_wait(text)`` is called once,
    naming the holder, when a rebuild starts waiting for it.
    """
    import socket

    lock_path = Path(warehouse) / ".rebuild.lock"
    try:
        fh = open(lock_path, "a+")
    except OSError as exc:
        raise RebuildError(f"cannot open the rebuild lock {lock_path}: {exc.strerror or exc}") from None
    deadline = time.monotonic() + max(0.0, wait_s)
    while True:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            if time.monotonic() >= deadline:
                fh.close()
                waited = f" after waiting {wait_s:g} s" if wait_s > 0 else ""
                raise RebuildError(f"another rebuild is running on {warehouse} (pid {holder}){waited}; "
                                   "try again when it has finished, or use --wait SECONDS", EXIT_LOCKED) from None
            if on_wait is not None:
                on_wait(f"waiting up to {wait_s:g} s for another rebuild of {warehouse} to finish (pid {holder})")
                on_wait = None
            time.sleep(0.1)
    try:
        fh.seek(0)
        fh.truncate()
        since = datetime.now(timezone.utc).astimezone().isoformat(timespec="seconds")
        fh.write(f"{os.getpid()} on {socket.gethostname()} since {since}")
        fh.flush()
        yield fh
    finally:
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


def check_folders(raw: str | Path, warehouse: str | Path) -> None:
    """Refuse a raw tree and a warehouse that overlap (equal, or one inside the other).

    Compared as resolved real paths (symlinks followed, a warehouse that does not exist yet
    resolved through its existing parents). Raises :class:`RebuildError` with exit code 2
    naming both paths; called before anything is written or deleted.
    """
    r, w = Path(os.path.realpath(raw)), Path(os.path.realpath(warehouse))
    if r == w:
        how = "are the same folder"
    elif r in w.parents:
        how = "overlap: the warehouse is inside the raw tree"
    elif w in r.parents:
        how = "overlap: the raw tree is inside the warehouse"
    else:
        return
    real = "" if (str(r), str(w)) == (str(raw), str(warehouse)) else f" ({r} and {w})"
    raise RebuildError(f"raw folder {raw} and warehouse {warehouse} {how}{real}; the rebuild writes and "
                       "deletes files in the warehouse and never touches raw/: give two separate folders",
                       EXIT_USAGE)


# -- ingest ------------------------------------------------------------------------------------
_TREES: dict[tuple[str, str], RawTree] = {}


def _tree(raw: str, token: str) -> RawTree:
    """One parsed raw tree per (raw folder, rebuild) in each worker process."""
    tree = _TREES.get((raw, token))
    if tree is None:
        _TREES.clear()
        tree = _TREES[(raw, token)] = RawTree(Path(raw))
    return tree


#: The quarantine reason of a file whose reader's worker process died.
CRASHED = f"cannot read file: {CRASH_REASON}"
STUCK = f"cannot read file: {STUCK_REASON}"  # a reader stopped at its time limit: tried once more, as a crash


def _unreadable(tree: RawTree, path: Path, error: str, transient: bool = False) -> IngestResult:
    from pipeline.ingest.file import IngestResult

    return IngestResult(source_path=tree.rel(path), campaign=tree.campaign(path), error=error, transient=transient)


#: The reason a file is set aside for this night: it changed while it was read (a bench still
#: writing it). Not a lasting quarantine: the next rebuild reads it again.
CHANGED_WHILE_READ = "file changed while it was read; will be read again at the next rebuild"


def _stat_or_none(path: Path) -> tuple[int, int, int] | None:
    """``(size, mtime_ns, inode)`` of a file, None when it cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, st.st_ino


def _ingest_task(args) -> dict:
    """Worker task: open the file once (:func:`pipeline.raw.rawfile.open_raw`: no symlink out of raw/
    followed, a regular file, the inode the scan saw), then :func:`_ingest_opened`. A file that
    cannot be opened so is quarantined for this night with the reason and looked at again next time."""
    from pipeline.raw.rawfile import RawOpenError, open_raw

    raw, token, path, warehouse, reuse, prev, code = args[:7]
    seen = args[7] if len(args) > 7 else None  # the inode the scan saw
    path, tree = Path(path), _tree(raw, token)
    try:
        opened = open_raw(tree.root, path, inode=seen)
        try:
            opened.source  # the readers' link to the descriptor; no link, no read (never by name)
        except OSError:
            opened.close()
            raise
    except OSError as exc:
        why = str(exc) if isinstance(exc, RawOpenError) else f"cannot read file: {type(exc).__name__}: {exc}"
        return {"sha": None, "reused": False, "result": _unreadable(tree, path, why, transient=True), "retry": True}
    with opened:
        return _ingest_opened(args, opened)


def _ingest_opened(args, opened) -> dict:
    """Worker task: a file whose stat alone changed is hashed and keeps its previous record when
    its bytes are the same; any other file is ingested (and hashed while it is parsed).

    Returns ``{"sha", "reused", "result"}``, with ``"retry": True`` when the next rebuild must
    look at the file again: it could not be opened (permissions, a share away), or it changed
    while it was read. A file whose size, mtime or inode differ after reading from before, or
    whose hash was not computed over exactly the bytes it had, is not published: its result is
    the one-line :data:`CHANGED_WHILE_READ` (its hash and its samples may be of different bytes).
    """
    raw, token, path, warehouse, reuse, prev, code = args[:7]
    path, tree = Path(path), _tree(raw, token)
    before = _stat_or_none(opened.source)  # the opened file's; after reading, the name's must match it
    sha = None
    hashed: list[int] = []
    if prev is not None:  # only the stat changed: the same bytes keep their record
        if prev["sha"] is None:
            reuse = False  # its last read was not trustworthy: a samples file named by its hash may be stale
        try:
            sha = sha256_file(opened.source, counted=hashed)
        except OSError as exc:
            res = _unreadable(tree, path, f"cannot read file: {type(exc).__name__}: {exc}", transient=True)
            return {"sha": None, "reused": False, "result": res, "retry": True}
        if prev["sha"] == sha and before is not None and _stat_or_none(path) == before and hashed == [before[0]]:
            return {"sha": sha, "reused": True, "result": None}
    _crash_point(f"ingest:{tree.rel(path)}", signal.SIGSEGV)  # a reader crashing in C code
    res = ingest_file(tree, path, Path(warehouse), reuse=reuse, sha256=sha, code_version=code, opened=opened)
    if res.bytes_hashed is not None:
        hashed = [res.bytes_hashed]
    if before is not None and not res.transient and (
            _stat_or_none(path) != before or (hashed and hashed != [before[0]])):
        return {"sha": None, "reused": False, "result": _unreadable(tree, path, CHANGED_WHILE_READ, transient=True),
                "retry": True}
    if res.transient or before is None:
        return {"sha": None, "reused": False, "result": res, "retry": True}
    if res.run is not None:
        sha = res.run["source_sha256"]
    elif res.parts is not None:  # a file of several runs (sheets, MDF groups)
        sha = res.sha256
    elif sha is None:  # quarantined before its hash was done: record it, or the next rebuild re-reads it
        try:
            sha = sha256_file(opened.source)
        except OSError:
            pass
    return {"sha": sha, "reused": False, "result": res}


def _read_time_limit(args) -> float:
    """Seconds an ingest task may run (``pipeline.readers.base.read_time_limit`` of its file)."""
    from pipeline.readers.base import read_time_limit

    try:
        size = os.stat(args[2]).st_size
    except OSError:
        size = 0
    return read_time_limit(size)


def _ingest_crashed(args, reason: str) -> dict:
    """Result of an ingest task whose worker process died: the file is quarantined.

    A first crash may pass (killed for memory): the next rebuild tries the file once more. A file
    that crashed its reader twice is hashed here (hashing cannot crash) and stays quarantined
    until its bytes change.
    """
    from pipeline.raw.rawfile import open_raw

    raw, token, path, warehouse, reuse, prev, code = args[:7]
    res = _unreadable(_tree(raw, token), Path(path), f"cannot read file: {reason}")
    if prev is not None and prev.get("crashed"):
        try:
            with open_raw(_tree(raw, token).root, path) as opened:
                return {"sha": sha256_file(opened.source), "reused": False, "result": res}
        except OSError:
            pass
    return {"sha": None, "reused": False, "result": res, "retry": True}


def _result_from_record(rec: FileRecord, tree: RawTree, path: Path) -> IngestResult:
    from pipeline.ingest.file import IngestResult

    res = IngestResult(source_path=rec.source_path, campaign=tree.campaign(path))
    if rec.result is not None and "parts" in rec.result:  # a file of several runs
        res.sha256 = rec.source_sha256
        res.parts = [IngestResult(source_path=rec.source_path, campaign=res.campaign, run=p.get("run"),
                                  channels=p.get("channels") or [], error=p.get("error"))
                     for p in rec.result["parts"]]
    elif rec.result is not None:
        res.run, res.channels = rec.result["run"], rec.result["channels"]
    else:
        res.error = rec.error
    return res


def _import_for_stages() -> None:
    """What the stages need (pandas, the analyses): imported while the readers' workers work (they
    are forked first and import the readers themselves), and in any case before the stages' own
    pool is forked, so that its workers start warm."""
    import pandas  # noqa: F401
    import pyarrow.dataset  # noqa: F401 (what the first pd.read_parquet of a process imports: ~15 ms)
    import pyarrow.pandas_compat  # noqa: F401

    from pipeline import stages

    stages.discover()


def ingest_incremental(tree: RawTree, plans: list[FilePlan], warehouse: Path, executor: Executor,
                       progress: Progress, code_version: str, full: bool, token: str,
                       while_waiting=None) -> tuple[list[IngestResult], list[FileRecord]]:
    """Ingest what the plans say; reuse the previous records of unchanged files. ``while_waiting``:
    the caller's own work, done while the first files are read (``Executor.map``)."""
    results: dict[str, IngestResult] = {}
    records: dict[str, FileRecord] = {}
    todo = []
    for p in plans:
        if p.status == "unchanged":
            results[p.rel] = _result_from_record(p.previous, tree, p.path)
            rec = p.previous
            records[p.rel] = rec
        else:
            prev = None
            if p.previous is not None and p.status == "check" and p.reason == "content":
                # only the stat changed: a file with the same bytes keeps its record
                prev = {"sha": p.previous.source_sha256,
                        "crashed": p.previous.error == CRASHED or (p.previous.error or "").startswith(STUCK)}
            todo.append((p, (str(tree.root), token, str(p.path), str(warehouse), not full, prev, code_version,
                             p.stat[2])))  # the inode the scan saw: another file there is not read
    if todo:
        progress.message(f"ingest: {len(todo)} of {len(plans)} run files to read")
    # forked local workers inherit the parsed raw tree and the readers of the formats present
    _TREES.clear()
    _TREES[(str(tree.root), token)] = tree
    readers = sorted({READERS[p.path.suffix.lower()].split(":")[0] for p, _ in todo
                      if p.path.suffix.lower() in READERS})
    outs = executor.map(_ingest_task, [a for _, a in todo], "ingest", progress, on_crash=_ingest_crashed,
                        preload=readers, while_waiting=while_waiting, time_limit=_read_time_limit)
    now = time.time()
    for (p, _), out in zip(todo, outs):
        if out["reused"]:
            p.status = "unchanged"
            results[p.rel] = _result_from_record(p.previous, tree, p.path)
            old = p.previous
            records[p.rel] = record_for(p, out["sha"], code_version, old.result, old.error, now)
            continue
        res: IngestResult = out["result"]
        if p.status == "check":
            p.status = "changed"
        results[p.rel] = res
        result = record_result(res)
        records[p.rel] = record_for(p, out["sha"], code_version, result, res.error, now, retry=out.get("retry", False))
    order = [p.rel for p in plans]
    return [results[r] for r in order], [records[r] for r in order]


def deduplicate(results: list[IngestResult]) -> tuple[list[dict], list[dict], list[Problem]]:
    """Runs, channel rows and quarantine rows; a repeated run_id is quarantined (first path wins)."""
    runs, channels, problems = [], [], []
    owner: dict[str, str] = {}
    flat = [p for r in results for p in (r.parts if r.parts is not None else [r])]  # a file of several runs
    for r in sorted(flat, key=lambda r: r.source_path):
        if r.error is not None:
            problems.append(Problem(r.source_path, r.error))
            continue
        rid = r.run["run_id"]
        if rid in owner:
            problems.append(Problem(r.source_path, f"duplicate run_id `{rid}`, already used by `{owner[rid]}`"))
            continue
        owner[rid] = r.source_path
        runs.append(r.run)
        channels += r.channels
    return runs, channels, problems


# -- stages ------------------------------------------------------------------------------------
class _TrackedResults(dict):
    """``ctx.results`` that remembers which earlier tables a stage looked at."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.read: set[str] = set()

    def __getitem__(self, k):
        self.read.add(k)
        return super().__getitem__(k)

    def get(self, k, default=None):
        self.read.add(k)
        return super().get(k, default)

    def __contains__(self, k):
        self.read.add(k)
        return super().__contains__(k)

    def _all(self):
        self.read.update(super().keys())

    def keys(self):
        self._all()
        return super().keys()

    def values(self):
        self._all()
        return super().values()

    def items(self):
        self._all()
        return super().items()

    def __iter__(self):
        self._all()
        return super().__iter__()


def _tracked_context(**kwargs):
    """A :class:`_TrackedContext` (its class made on first use: it subclasses the stages'
    StageContext, whose module imports pandas)."""
    global _TrackedContext
    if _TrackedContext is None:
        _TrackedContext = _make_tracked_context()
    return _TrackedContext(**kwargs)


_TrackedContext = None


def _make_tracked_context():
    from pipeline import stages as stage_registry

    class _TrackedContext(stage_registry.StageContext):
        """A StageContext that remembers which kinds of runs a stage read (for its cache key)."""

        @property
        def runs(self):
            if not self.__dict__.get("_inside", 0):
                self.__dict__["all_runs_read"] = True
            return self.__dict__["_runs"]

        @runs.setter
        def runs(self, value):
            self.__dict__["_runs"] = value

        @contextmanager
        def _internal(self):
            self.__dict__["_inside"] = self.__dict__.get("_inside", 0) + 1
            try:
                yield
            finally:
                self.__dict__["_inside"] -= 1

        @property
        def kinds_read(self) -> set[str]:
            return self.__dict__.setdefault("_kinds_read", set())

        def runs_of(self, *kinds):
            self.kinds_read.update(kinds)
            with self._internal():
                return super().runs_of(*kinds)

        def samples_file(self, run_id):
            with self._internal():
                return super().samples_file(run_id)

    return _TrackedContext


def _reads_logbooks(mod) -> bool:
    return bool(getattr(mod, "READS_LOGBOOKS", False)) or "durability" in tuple(getattr(mod, "KINDS", ()))


@dataclass
class StageResults:
    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    figures: list[dict] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    warnings: dict[str, list[str]] = field(default_factory=dict)
    records: list[StageRecord] = field(default_factory=list)
    ran: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    #: per stage that ran: its per-item memo (hits, computed items)
    memos: dict[str, Memo] = field(default_factory=dict)


def _save_figure(fig, path: Path) -> None:
    """Save a stage figure (a matplotlib Figure or a ``FigureRecipe``) as PNG, byte for byte the
    same for the same figure (no software or date in the metadata)."""
    from pipeline import stages as stage_registry

    fig = stage_registry.figure_of(fig)
    fig.savefig(path, dpi=110, metadata={"Software": None})


def _warm_figures() -> None:
    """Import what drawing a figure needs (in the drawing worker, while the stages run)."""
    import matplotlib.backends.backend_agg  # noqa: F401
    import matplotlib.figure  # noqa: F401


class FigureDrawer:
    """Draws the stages' figures into their stage folders, off the rebuild's critical path.

    With ``jobs`` > 1, each figure (a ``FigureRecipe``) is drawn in one worker process forked
    from the rebuild, while this process goes on with the next stages and the database; with
    ``jobs`` 1 (or a figure already drawn), here, at once. A stage folder is written under its
    temporary name and renamed into place only when its figures are all drawn (:meth:`finish`,
    before the new database is swapped in), so a folder under its final name always holds every
    figure its ``output.json`` lists, whenever the rebuild is killed. A figure that fails fails
    the rebuild, as a failing stage does. Use it as a context manager (the worker is closed).
    """

    def __init__(self, jobs: int | None = 1, close_fds: tuple[int, ...] = ()):
        self.jobs = default_jobs(jobs)
        self.close_fds = tuple(close_fds)
        self._pool = None
        self._pending: list[tuple[object, str, str]] = []  # (future, stage, figure name)
        self._folders: list[tuple[Path, Path]] = []  # (temporary folder, final folder)

    def _submit(self, func, *args):
        if self.jobs <= 1:
            return None
        if self._pool is None:
            self._pool = forked_pool(1, self.close_fds)
        return self._pool.submit(func, *args)

    def warm(self) -> None:
        """Start the drawing worker and its matplotlib import now (a stage is about to run)."""
        if self._pool is None:
            self._submit(_warm_figures)

    def draw(self, stage: str, name: str, fig, path: Path) -> None:
        from pipeline import stages as stage_registry

        fut = self._submit(_save_figure, fig, path) if isinstance(fig, stage_registry.FigureRecipe) else None
        if fut is None:
            _save_figure(fig, path)
        else:
            self._pending.append((fut, stage, name))

    @property
    def busy(self) -> bool:
        return bool(self._pending)

    def publish(self, tmp: Path, final: Path) -> None:
        """Rename ``tmp`` to ``final`` once the figures drawn into it are done."""
        self._folders.append((tmp, final))

    def finish(self) -> int:
        """Wait for every figure; then put the stage folders in place. Returns how many figures
        were drawn in the worker."""
        pending, self._pending = self._pending, []
        failed = None
        for fut, stage, name in pending:
            try:
                fut.result()
            except Exception as exc:  # a bug in a plot function, or its worker died
                failed = failed or RebuildError(f"stage {stage} failed: figure {name}: {type(exc).__name__}: {exc}")
        folders, self._folders = self._folders, []
        if failed is not None:
            for tmp, _final in folders:
                shutil.rmtree(tmp, ignore_errors=True)
            raise failed
        for tmp, final in folders:
            _place_stage_folder(tmp, final)
        return len(pending)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if self._pool is not None and exc_type is not None and not issubclass(exc_type, Exception):
            _kill_workers(self._pool)  # interrupted: not after the figure it is drawing
        self.close()
        return False


def _place_stage_folder(tmp: Path, final: Path) -> None:
    if final.exists():  # damaged (its output.json gone), or tables that could not be stored
        remove_stage_folder(final)
    final.parent.mkdir(parents=True, exist_ok=True)  # the collection before the database removes empty folders
    os.replace(tmp, final)


def _save_stage_folder(warehouse: Path, name: str, folder_key: str, out: stage_registry.StageOutput,
                       drawer: FigureDrawer | None = None) -> tuple[str, bool, Path]:
    """Write a stage's outputs to ``stages/<name>/<key>/`` (temp folder, then one rename).

    Returns (folder relative to the warehouse, whether the tables could be cached, the folder
    that holds them now). With a ``drawer``, figures may still be being drawn into a temporary
    folder, which the drawer renames into place (:meth:`FigureDrawer.finish`).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    rel = f"stages/{name}/{folder_key}"
    final = warehouse / rel
    tmp = warehouse / "stages" / f".tmp-{name}-{folder_key}-{os.getpid()}"
    if final.exists() and (final / "output.json").is_file() and _cacheable_tables(out):
        # same inputs, same outputs (stages are deterministic): keep the folder a live warehouse
        # may use, and draw nothing
        return rel, True, final
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "tables").mkdir(parents=True)
    (tmp / "figures").mkdir()
    cacheable = True
    empty = {}  # a table without rows is kept as its columns' dtypes in output.json, not a Parquet file
    for table, df in out.tables.items():
        try:
            arrow = pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False)
            columns = _empty_columns(arrow) if arrow.num_rows == 0 else None
            if columns is not None:
                empty[table] = columns
                continue
            pq.write_table(arrow, tmp / "tables" / f"{table}.parquet")
        except (pa.ArrowException, TypeError, ValueError):
            cacheable = False
    drawer = drawer or FigureDrawer()
    figures = {}
    for fname, fig in sorted(out.figures.items()):
        file = f"{fname}.png"
        drawer.draw(name, fname, fig, tmp / "figures" / file)
        figures[fname] = {"file": file, "caption": out.captions.get(fname, "")}
    meta = {"tables": sorted(out.tables), "empty": empty, "figures": figures, "cacheable": cacheable,
            "problems": [{"source_path": p.source_path, "error": p.error, "line": p.line, "stage": p.stage}
                         for p in out.problems],
            "warnings": {k: list(v) for k, v in sorted(out.warnings.items())}}
    (tmp / "output.json").write_text(json.dumps(meta, sort_keys=True, default=str))
    final.parent.mkdir(parents=True, exist_ok=True)
    drawer.publish(tmp, final)
    if drawer.busy:
        return rel, cacheable, tmp
    drawer.finish()
    return rel, cacheable, final


def _cacheable_tables(out: stage_registry.StageOutput) -> bool:
    """Whether every table of ``out`` can be stored as Parquet (and so read back from a folder)."""
    import pyarrow as pa

    try:
        for df in out.tables.values():
            pa.Schema.from_pandas(df, preserve_index=False)
    except (pa.ArrowException, TypeError, ValueError):
        return False
    return True


def _empty_frame(columns: list) -> pd.DataFrame:
    """The DataFrame ``pd.read_parquet`` gives for a table without rows, from its ``[[column, dtype]]``."""
    import pandas as pd

    return pd.DataFrame({c: pd.array([], dtype=d) for c, d in columns}, index=pd.RangeIndex(0), copy=False)


def _empty_columns(arrow) -> list | None:
    """``[[column, dtype]]`` of a table without rows, when :func:`_empty_frame` rebuilds exactly the
    frame its Parquet file would read back as; else None (the table is written as Parquet)."""
    import io

    import pandas as pd
    import pyarrow.parquet as pq

    buf = io.BytesIO()  # the round trip itself (Parquet has no second unit, for one: s comes back as ms)
    pq.write_table(arrow, buf)
    back = pd.read_parquet(io.BytesIO(buf.getvalue()))
    columns = [[c, str(d)] for c, d in back.dtypes.items()]
    if not all(isinstance(c, str) for c, _ in columns) or len(set(back.columns)) != len(columns):
        return None
    try:
        again = _empty_frame(columns)
    except (TypeError, ValueError):
        return None
    same = list(again.columns) == list(back.columns) and [repr(d) for d in again.dtypes] == [repr(d) for d in back.dtypes]
    return columns if same else None  # repr, not ==: a category dtype equals "category" whatever its categories


def _load_stage_folder(warehouse: Path, rel: str, stage: str, fresh: stage_registry.StageOutput | None = None,
                       folder: Path | None = None):
    """(tables, figure rows, problems, warnings) of a stage folder (``rel``; read from ``folder``
    when it is still under its temporary name)."""
    import pandas as pd

    folder = folder or warehouse / rel
    meta = json.loads((folder / "output.json").read_text())
    empty = meta.get("empty") or {}
    tables = {}
    for t in meta["tables"]:
        f = folder / "tables" / f"{t}.parquet"
        if t in empty:  # no rows: its dtypes were checked to come back exactly as from Parquet
            tables[t] = _empty_frame(empty[t])
        else:
            tables[t] = pd.read_parquet(f) if f.is_file() and meta.get("cacheable", True) else fresh.tables[t]
    figures = [{"stage": stage, "name": n, "path": f"{rel}/figures/{v['file']}", "caption": v["caption"]}
               for n, v in sorted(meta["figures"].items())]
    problems = [Problem(p["source_path"], p["error"], p["line"], p.get("stage") or stage) for p in meta["problems"]]
    return tables, figures, problems, meta["warnings"]


def _seconds(s: float) -> str:
    """``"12 ms"`` below a second (a stage that is only reused), else ``"3.4 s"``."""
    return f"{s * 1e3:.0f} ms" if s < 1 else f"{s:.1f} s"


def run_stages_cached(ctx_args: dict, runs: list[dict], prev: PreviousState, warehouse: Path, full: bool,
                      logbooks: str, progress: Progress, generation: str = "",
                      drawer: FigureDrawer | None = None) -> StageResults:
    """Run every stage in order, or reuse its cached outputs when its inputs are unchanged.

    With a ``drawer``, figures may still be being drawn when this returns: the caller calls
    ``drawer.finish()`` before it publishes the stage folders (without one, they are drawn here)."""
    import pandas as pd

    from pipeline import stages as stage_registry

    import hashlib

    res = StageResults()
    own_drawer = drawer is None
    drawer = drawer or FigureDrawer()
    mods = stage_registry.discover()
    # every stage's code version up front: the project's sources are read and hashed once for all
    codes = {mod.NAME: stage_code_version(getattr(mod, "__file__", None) or mod.NAME) for mod in mods}
    with progress.task("stages", len(mods)) as task:
        for mod in mods:
            t0 = time.monotonic()
            name = mod.NAME
            code = codes[name]
            declared = set(getattr(mod, "KINDS", ()) or ())
            logb = logbooks if _reads_logbooks(mod) else None
            old = prev.stages.get(name)
            hit = None
            if not full and old is not None:
                key = stage_input_key(name, code, runs, declared | set(old.kinds_read), old.all_runs_read, logb)
                if (key == old.input_key and (warehouse / old.folder / "output.json").is_file()
                        and all(frame_hash(res.tables.get(t)) == h for t, h in old.results_read.items())):
                    hit = old
            if hit is not None:
                record = hit
                tables, figures, problems, warnings = _load_stage_folder(warehouse, hit.folder, name)
                res.reused.append(name)
                how = "reused"
            else:
                drawer.warm()
                results = _TrackedResults(res.tables)
                ctx = _tracked_context(**ctx_args)
                ctx.results = results
                # per-run results of earlier rebuilds (not read by --full, written either way)
                ctx.memo = memo = res.memos[name] = Memo(warehouse, name, read=not full)
                try:
                    out = mod.run(ctx)
                except Exception as exc:  # a bug in an analysis: fail, keep the previous warehouse
                    raise RebuildError(f"stage {name} failed: {type(exc).__name__}: {exc}") from exc
                memo.save()
                kinds = declared | ctx.kinds_read
                all_runs = bool(ctx.__dict__.get("all_runs_read"))
                read = {t: frame_hash(res.tables.get(t)) for t in sorted(results.read)}
                key = stage_input_key(name, code, runs, kinds, all_runs, logb)
                # --full writes a fresh folder (never trusts an existing one); incremental runs reuse
                # a folder with the same inputs (stages are deterministic)
                salt = generation if full else ""
                folder_key = hashlib.sha256(json.dumps([key, read, salt], sort_keys=True).encode()).hexdigest()[:20]
                rel, cacheable, now_in = _save_stage_folder(warehouse, name, folder_key, out, drawer)
                record = StageRecord(name, key if cacheable else "uncacheable", rel, sorted(kinds), all_runs, read)
                tables, figures, problems, warnings = _load_stage_folder(warehouse, rel, name, out, now_in)
                res.ran.append(name)
                how = "ran"
            res.records.append(record)
            tables = stage_registry.add_run_columns(tables, ctx_args["runs"])  # campaign, hose_id, campaigns
            for t, df in tables.items():
                res.tables[t] = df if t not in res.tables else pd.concat([res.tables[t], df], ignore_index=True)
            res.figures += figures
            res.problems += problems
            for rid, ws in warnings.items():
                res.warnings.setdefault(rid, []).extend(ws)
            memo_note = res.memos[name].summary() if name in res.memos else ""
            progress.message(f"stage {name} {how}: " + ", ".join(f"{k} {len(v)} rows" for k, v in tables.items())
                             + f" ({_seconds(time.monotonic() - t0)}{'; ' + memo_note if memo_note else ''})")
            task.advance()
    if own_drawer:
        drawer.finish()
    return res


def run_stages(ctx: stage_registry.StageContext, progress: Progress):
    """Run every stage in order without any cache; returns (tables, figures, captions, problems, warnings)."""
    import pandas as pd

    from pipeline import stages as stage_registry

    tables: dict[str, pd.DataFrame] = {}
    figures: dict[tuple[str, str], object] = {}
    captions: dict[tuple[str, str], str] = {}
    problems: list[Problem] = []
    warnings: dict[str, list[str]] = {}
    for mod in stage_registry.discover():
        ctx.results = tables
        try:
            out = mod.run(ctx)
        except Exception as exc:
            raise RebuildError(f"stage {mod.NAME} failed: {type(exc).__name__}: {exc}") from exc
        for name, df in out.tables.items():
            tables[name] = df if name not in tables else pd.concat([tables[name], df], ignore_index=True)
        for name, fig in out.figures.items():
            figures[(mod.NAME, name)] = stage_registry.figure_of(fig)
            if name in out.captions:
                captions[(mod.NAME, name)] = out.captions[name]
        problems += out.problems
        for rid, ws in out.warnings.items():
            warnings.setdefault(rid, []).extend(ws)
    return tables, figures, captions, problems, warnings


# -- findings against the previous warehouse -----------------------------------------------------
def compare_findings(findings: pd.DataFrame, previous: dict[str, bool | None], had_previous: bool,
                     previous_changes: dict[str, tuple] | None = None, now: datetime | None = None) -> pd.DataFrame:
    """Add ``previous_holds``, ``change`` (overturned, now holds, ...) and ``changed_at`` to the findings.

    ``change`` / ``changed_at`` are sticky: when ``holds`` differs from the previous warehouse they
    are the new change and ``now`` (the rebuild's start); while ``holds`` stays the same they are
    carried over from the previous warehouse (``previous_changes``: {finding_id: (change,
    changed_at)}), so a second rebuild in the same night does not clear an overturned finding.
    """
    import pandas as pd

    if findings is None or findings.empty:
        return findings
    now = now or datetime.now(timezone.utc)
    previous_changes = previous_changes or {}
    df = findings.copy()
    prev_holds, change, changed_at = [], [], []
    for fid, holds in zip(df["finding_id"], df["holds"]):
        holds = None if pd.isna(holds) else bool(holds)
        before = previous.get(fid) if fid in previous else None
        before = None if before is None or pd.isna(before) else bool(before)
        prev_holds.append(before)
        if not had_previous or fid not in previous:
            new = None
        elif before is True and holds is False:
            new = "overturned"
        elif before is False and holds is True:
            new = "now holds"
        elif before is None and holds is not None:
            new = "new data"
        elif before is not None and holds is None:
            new = "no longer checkable"
        else:
            new = None
        if new is not None:
            change.append(new)
            changed_at.append(now)
        elif had_previous and fid in previous:  # holds unchanged: keep the last change and its time
            ch, at = previous_changes.get(fid, (None, None))
            ok = ch is not None and at is not None and not pd.isna(ch) and not pd.isna(at)
            change.append(ch if ok else None)
            changed_at.append(at if ok else None)
        else:
            change.append(None)
            changed_at.append(None)
    df["previous_holds"] = pd.array(prev_holds, dtype="boolean")
    df["change"] = pd.array(change, dtype="string")
    df["changed_at"] = pd.to_datetime(pd.Series(changed_at, index=df.index, dtype=object), utc=True)
    return df


# -- garbage ---------------------------------------------------------------------------------------
# The clean-up deletes only what the warehouse itself wrote: a file is a candidate when it lies
# in the warehouse's own folders (never through a symlink) AND its name is one the writer uses.
# Anything else found there (a raw tree placed there by mistake, a user's notes) is left alone.
_SAMPLES_FILE = re.compile(r"[A-Za-z0-9._-]{1,80}-[0-9a-f]{16}\.parquet")      # ingest: <safe run>-<key>.parquet
_SAMPLES_TMP = re.compile(r"\.[A-Za-z0-9._-]{1,80}\.[0-9]+\.[0-9a-f]{12}\.tmp")  # ingest's temp name
_STAGE_NAME = re.compile(r"[a-z_][a-z0-9_]*")
_STAGE_KEY = re.compile(r"[0-9a-f]{20}")
_STAGE_TMP = re.compile(r"\.tmp-([a-z_][a-z0-9_]*)-[0-9a-f]{20}-[0-9]+")
_DB_TMP = re.compile(re.escape(f".{DB_NAME}.tmp-") + r"[0-9]+(\.wal)?")
_REPORT_TMP = re.compile(r"\.(index\.html|parts-cache)\.tmp-[0-9]+")
_FIGURE = re.compile(r"[A-Za-z0-9._-]+\.png")


def _real_dir(path: Path) -> bool:
    """A folder that is not a symlink (the clean-up never follows one)."""
    try:
        return stat_mod.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def _entries(folder: Path):
    """(name, path, is_dir, is_file) of a folder's entries, symlinks neither dir nor file."""
    try:
        with os.scandir(folder) as it:
            ents = sorted(it, key=lambda e: e.name)
    except OSError:
        return []
    return [(e.name, Path(e.path), e.is_dir(follow_symlinks=False), e.is_file(follow_symlinks=False)) for e in ents]


def _file_names(folder: Path) -> list[str]:
    """Names of a folder's regular files (not symlinks), sorted; no Path per entry (a samples
    folder holds thousands)."""
    try:
        with os.scandir(folder) as it:
            return sorted(e.name for e in it if e.is_file(follow_symlinks=False))
    except OSError:
        return []


def _unlink_if(path: Path, is_file: bool, pattern: re.Pattern) -> None:
    if is_file and pattern.fullmatch(path.name):
        path.unlink(missing_ok=True)


def _rmdir(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass  # not empty: it holds something the warehouse did not write


def remove_stage_folder(folder: Path) -> None:
    """Delete a stage output folder the way ``_save_stage_folder`` wrote it (``output.json``,
    ``tables/*.parquet``, ``figures/*.png``); anything else in it stays, and so does the folder."""
    if not _real_dir(folder):
        return
    for sub, pattern in (("tables", re.compile(r"[A-Za-z0-9_]+\.parquet")), ("figures", _FIGURE)):
        if _real_dir(folder / sub):
            for _name, path, _is_dir, is_file in _entries(folder / sub):
                _unlink_if(path, is_file, pattern)
            _rmdir(folder / sub)
    for _name, path, _is_dir, is_file in _entries(folder):
        _unlink_if(path, is_file, re.compile(r"output\.json"))
    _rmdir(folder)


def _samples_folders(warehouse: Path):
    """``samples/kind=<kind>/campaign=<campaign>/`` folders (real folders only)."""
    samples = warehouse / "samples"
    if not _real_dir(samples):
        return
    for kname, kdir, kis_dir, _ in _entries(samples):
        if not (kis_dir and kname.startswith("kind=") and kname[5:] in KIND_NAMES):
            continue
        for cname, cdir, cis_dir, _ in _entries(kdir):
            if cis_dir and cname.startswith("campaign="):
                yield kdir, cdir


def clean_debris(warehouse: Path) -> None:
    """Remove what a killed rebuild left behind (temp databases, temp stage folders, temp samples
    and report files), by the writers' own temp names only."""
    for _name, path, _is_dir, is_file in _entries(warehouse):
        _unlink_if(path, is_file, _DB_TMP)
    if _real_dir(warehouse / "stages"):
        for name, path, is_dir, _ in _entries(warehouse / "stages"):
            if is_dir and _STAGE_TMP.fullmatch(name):
                remove_stage_folder(path)
    if _real_dir(warehouse / "report"):
        for _name, path, _is_dir, is_file in _entries(warehouse / "report"):
            _unlink_if(path, is_file, _REPORT_TMP)
    for _kdir, cdir in _samples_folders(warehouse):
        for name in _file_names(cdir):
            if _SAMPLES_TMP.fullmatch(name):
                (cdir / name).unlink(missing_ok=True)
    if _real_dir(warehouse / MEMO_DIR):
        for name, path, is_dir, is_file in _entries(warehouse / MEMO_DIR):
            _unlink_if(path, is_file, LEGACY_TMP)
            if is_dir and STAGE_NAME.fullmatch(name):
                for _name, spath, _is_dir, s_is_file in _entries(path):
                    _unlink_if(spath, s_is_file, SHARD_TMP)


def collect_garbage(warehouse: Path, keep_samples: set[str], keep_stages: set[str]) -> None:
    """Delete samples files and stage folders the warehouse wrote that are not in ``keep_*``
    (paths relative to the warehouse). Only writer-named files in the writer's folders go."""
    for kdir, cdir in list(_samples_folders(warehouse)):
        rel_dir = f"samples/{kdir.name}/{cdir.name}/"
        for name in _file_names(cdir):
            if _SAMPLES_FILE.fullmatch(name) and rel_dir + name not in keep_samples:
                (cdir / name).unlink(missing_ok=True)
        _rmdir(cdir)
        _rmdir(kdir)
    stages = warehouse / "stages"
    if _real_dir(stages):
        for sname, sdir, s_is_dir, _ in _entries(stages):
            if not (s_is_dir and _STAGE_NAME.fullmatch(sname)):
                continue
            for kname, kdir, k_is_dir, _ in _entries(sdir):
                if k_is_dir and _STAGE_KEY.fullmatch(kname) and f"stages/{sname}/{kname}" not in keep_stages:
                    remove_stage_folder(kdir)
            _rmdir(sdir)
    # a stage's per-item memo (memo/<stage>/<xx>.pkl) goes with the last of its stage folders
    # that is kept; the first layout's whole-stage files (memo/<stage>.pkl) are never read: all go
    memo = warehouse / MEMO_DIR
    if _real_dir(memo):
        live = {p.split("/")[1] for p in keep_stages if p.startswith("stages/") and p.count("/") >= 2}
        for name, path, is_dir, is_file in _entries(memo):
            _unlink_if(path, is_file, LEGACY_FILE)
            if is_dir and STAGE_NAME.fullmatch(name) and name not in live:
                for _name, spath, _is_dir, s_is_file in _entries(path):
                    _unlink_if(spath, s_is_file, SHARD_FILE)
                    _unlink_if(spath, s_is_file, SHARD_TMP)
                _rmdir(path)
        _rmdir(memo)
    legacy = warehouse / "figures"  # figures of the first layout (before generations): <stage>/<name>.png
    if _real_dir(legacy) and not any(p.startswith("figures/") for p in keep_stages):
        for sname, sdir, s_is_dir, _ in _entries(legacy):
            if s_is_dir and _STAGE_NAME.fullmatch(sname):
                for _name, path, _is_dir, is_file in _entries(sdir):
                    _unlink_if(path, is_file, _FIGURE)
                _rmdir(sdir)
        _rmdir(legacy)


# -- the rebuild -----------------------------------------------------------------------------------
def _generation() -> str:
    return datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ") + f"-{os.getpid()}"


def _inputs_table(plans: list[FilePlan], side_changes: list[dict], prev: PreviousState, seen: set[str],
                  problems: list[Problem], results: list[IngestResult]) -> pd.DataFrame:
    import pandas as pd

    errors: dict[str, list[str]] = {}
    for p in problems:
        errors.setdefault(p.source_path, []).append(f"line {p.line}: {p.error}" if p.line else p.error)
    by_path = {r.source_path: r for r in results}
    rows = []
    for p in plans:
        r = by_path.get(p.rel)
        run = r.run if r is not None else None
        rows.append({"source_path": p.rel, "role": "run", "status": p.status,
                     "reason": (p.reason or None) if p.status == "changed" else None,
                     "run_id": run["run_id"] if run else None, "kind": run["kind"] if run else None})
    rows += side_changes
    for rel, rec in sorted(prev.files.items()):
        if rel not in seen:
            run = (rec.result or {}).get("run") or {}
            rows.append({"source_path": rel, "role": rec.role, "status": "deleted", "reason": None,
                         "run_id": run.get("run_id"), "kind": run.get("kind")})
    df = pd.DataFrame(rows, columns=["source_path", "role", "status", "reason", "run_id", "kind"])
    df["quarantined"] = [p in errors and s != "deleted" for p, s in zip(df["source_path"], df["status"])]
    df["error"] = [" | ".join(errors[p]) if q else None for p, q in zip(df["source_path"], df["quarantined"])]
    return df.sort_values("source_path", kind="stable").reset_index(drop=True)


def rebuild(raw: str | Path, warehouse: str | Path, jobs: int | None = None, full: bool = False,
            progress: Progress | None = None, lock_wait_s: float = 0.0, executor: str = "local",
            scheduler: str | None = None, report: bool = True, keep_superseded_h: float | None = None,
            clock=None, allow_mass_delete: bool = False) -> RebuildSummary:
    """Ingest ``raw``, run the analyses and swap in a new warehouse (incrementally).

    Parameters
    ----------
    raw : path-like
        The raw tree (never modified).
    warehouse : path-like
        The warehouse folder (created if missing).
    jobs : int, optional
        Worker processes; default all cores.
    full : bool
        Re-ingest every file and re-run every stage, ignoring the incremental state.
    progress : Progress, optional
        Where progress goes (silent by default).
    lock_wait_s : float
        How long to wait for another rebuild of the same warehouse to finish [s].
    executor : {"local", "dask"}
        Where per-file ingest and per-run analyses run.
    scheduler : str, optional
        Dask scheduler address (``tcp://host:8786``); without one a local cluster is started.
    report : bool
        Write the morning report ``report/index.html``.
    keep_superseded_h : float, optional
        How long samples files and stage folders that the new warehouse no longer uses are kept
        for readers that still have an earlier warehouse open [h]; 0 collects them at once.
        Default ``$PNEUBENCH_KEEP_SUPERSEDED_H``, else 24.
    clock : callable, optional
        ``clock() -> float``, the time [s since epoch] superseded files are stamped and aged
        with (default ``time.time``; tests pass a fake one).
    allow_mass_delete : bool
        Go on when the rebuild would drop every run of the live warehouse, or more than
        :data:`MASS_DELETE_SHARE` of them and at least :data:`MASS_DELETE_MIN_RUNS` (their raw
        files gone). Without it such a rebuild is refused before anything is written
        (:class:`RebuildError`, exit 2): an empty or unmounted raw/ must not empty the warehouse.

    Returns
    -------
    RebuildSummary

    Raises
    ------
    RebuildError
        When the rebuild fails (also when its report cannot be rendered); the previous
        warehouse and its report are left as they were.
    """
    t0 = time.monotonic()
    started_at = datetime.now(timezone.utc)
    progress = progress or Progress()
    raw, warehouse = Path(raw), Path(warehouse)
    if not raw.is_dir():
        raise RebuildError(f"raw folder {raw} does not exist", EXIT_USAGE)
    check_folders(raw, warehouse)
    keep_h = _keep_superseded_h(keep_superseded_h)
    jobs = jobs or os.cpu_count() or 1
    try:
        warehouse.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RebuildError(f"cannot create warehouse folder {warehouse}: {exc.strerror or exc}") from None
    generation = _generation()
    summary = RebuildSummary(raw=raw, warehouse=warehouse, generation=generation,
                             mode="full" if full else "incremental")
    with warehouse_lock(warehouse, lock_wait_s, progress.message) as lock:
        live = _live_database(warehouse)
        try:
            return _rebuild_locked(raw, warehouse, jobs, full, progress, executor, scheduler, report,
                                   generation, summary, started_at, t0, lock.fileno(), keep_h, clock or time.time,
                                   allow_mass_delete)
        except BaseException as exc:  # failed or interrupted (KeyboardInterrupt: re-raised as it is)
            if not (isinstance(exc, RebuildError) and exc.exit_code == EXIT_USAGE):  # refused: nothing written
                clean_after_failure(warehouse, live)
            if isinstance(exc, KeyboardInterrupt):  # for the caller's message: which warehouse is live
                exc.swapped = _live_database(warehouse) != live
            if isinstance(exc, RebuildError) or not isinstance(exc, Exception):
                raise
            log.exception("rebuild failed")  # anything unexpected: exit 3, never 1 (= "quarantined")
            raise RebuildError(f"rebuild failed: {type(exc).__name__}: {exc}") from exc


def _live_database(warehouse: Path) -> tuple[int, int, int] | None:
    """(inode, mtime, size) of the live database, None without one: the swap changes it."""
    try:
        st = os.stat(warehouse / DB_NAME)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def clean_after_failure(warehouse: Path, live: tuple[int, int, int] | None) -> None:
    """Remove what a rebuild that failed (a full disk) or was interrupted before its swap wrote:
    its temporary files (:func:`clean_debris`), and the samples files, stage folders and memo
    files that the live warehouse neither uses nor keeps for its readers (``superseded_files``).
    ``live``: :func:`_live_database` when the rebuild started; when it differs now the new
    warehouse is in place and only temporary files go. Called under the rebuild lock, after the
    worker processes are gone; never raises (the rebuild's own error is the one reported)."""
    try:
        clean_debris(warehouse)
        if _live_database(warehouse) != live:
            return
        prev = load_previous(warehouse)
        if live is not None and prev.generation is None:  # the live database could not be read: keep all
            return
        collect_garbage(warehouse, *_split_kept(prev.samples | prev.stage_folders | set(prev.superseded)))
    except Exception:  # pragma: no cover - the clean-up of a failure must not hide the failure
        log.exception("clean-up after a failed rebuild failed")


def check_mass_delete(prev: PreviousState, plans: list[FilePlan]) -> None:
    """Refuse (exit 2) a rebuild that would drop every run of the live warehouse, or more than
    :data:`MASS_DELETE_SHARE` of them and at least :data:`MASS_DELETE_MIN_RUNS`, because their raw
    files are no longer listed (raw/ empty, moved, or a share not mounted). Called before anything
    is written; a first build (no runs yet) never is one."""
    live = prev.samples  # the samples file of every run the live warehouse publishes
    if not live:
        return
    listed = {p.rel for p in plans}
    gone = [(rel, [s for s in rec.samples_paths() if s in live]) for rel, rec in sorted(prev.files.items())
            if rec.role == "run" and rel not in listed]
    gone = [(rel, runs) for rel, runs in gone if runs]
    lost = sum(len(runs) for _rel, runs in gone)
    if lost < len(live) and not (lost > MASS_DELETE_SHARE * len(live) and lost >= MASS_DELETE_MIN_RUNS):
        return
    names = ", ".join(rel for rel, _ in gone[:3]) + (", ..." if len(gone) > 3 else "")
    raise RebuildError(
        f"refusing to delete {lost} of the warehouse's {len(live)} runs: their raw files are gone ({names}); "
        "is raw/ empty, moved, or a share not mounted? The previous warehouse and report are kept. If the "
        "deletion is intended, run again with --allow-mass-delete (or PNEUBENCH_ALLOW_MASS_DELETE=1)", EXIT_USAGE)


def _keep_superseded_h(value: float | None) -> float:
    """The retention of superseded files [h]: ``value``, else ``$PNEUBENCH_KEEP_SUPERSEDED_H``, else 24."""
    import math

    source = "--keep-superseded"
    if value is None:
        env = os.environ.get("PNEUBENCH_KEEP_SUPERSEDED_H", "").strip()
        if not env:
            return KEEP_SUPERSEDED_H
        source = "PNEUBENCH_KEEP_SUPERSEDED_H"
        try:
            value = float(env)
        except ValueError:
            raise RebuildError(f"{source}={env!r} is not a number of hours", EXIT_USAGE) from None
    if not (math.isfinite(value) and value >= 0):
        raise RebuildError(f"{source} must be a number of hours >= 0, got {value!r}", EXIT_USAGE)
    return float(value)


def _rebuild_locked(raw, warehouse, jobs, full, progress, executor, scheduler, report, generation, summary,
                    started_at, t0, lock_fd: int, keep_h: float, clock,
                    allow_mass_delete: bool = False) -> RebuildSummary:
    clean_debris(warehouse)
    from pipeline.serve.report import settle_report
    settle_report(warehouse)  # a report staged by a rebuild killed after its database swap goes in
    prev = load_previous(warehouse)
    tree = RawTree(raw)
    tree.scan_rigs()
    tree.scan_manifests()
    ignored: list[Path] = []
    files = discover_runs(tree, ignored)
    summary.n_files = len(files)
    if ignored:
        names = ", ".join(tree.rel(p) for p in ignored[:5]) + (", ..." if len(ignored) > 5 else "")
        progress.message(f"ignored {len(ignored)} file(s) that are not bench exports "
                         f"({', '.join(sorted(READERS))}): {names}")
    for rel, why in tree.listing().skipped:  # symlink aliases of files read under their own path
        progress.message(f"skipped {rel}: {why}")
    code = ingest_code_version()
    plans = plan_runs(tree, files, prev, code, warehouse, full)
    side, side_changes = side_records(tree, prev)
    n_quick = sum(p.status == "unchanged" for p in plans)
    if not allow_mass_delete:
        check_mass_delete(prev, plans)
    key = inputs_key(tree, code, plans, side, ignored)
    if not full and nothing_changed(prev, plans, side, key, warehouse):
        summary.mode = "no-op"
        progress.message(f"rebuild {generation} (no-op): {len(files)} run files under {raw}, nothing changed "
                         "since the last rebuild: its database is carried over")
        return _rebuild_noop(warehouse, prev, plans, key, executor, report, generation, summary, started_at, t0,
                             keep_h, clock, progress)
    progress.message(f"rebuild {generation} ({summary.mode}): {len(files)} run files under {raw}, "
                     f"{n_quick} unchanged at a glance")
    try:
        ex = make_executor(executor, jobs, scheduler, close_in_workers=(lock_fd,))
    except Exception as exc:
        raise RebuildError(f"cannot start the {executor} executor: {type(exc).__name__}: {exc}") from exc
    with FigureDrawer(jobs if executor == "local" else 1, close_fds=(lock_fd,)) as drawer:
        with ex:
            results, records = ingest_incremental(tree, plans, warehouse, ex, progress, code, full, generation,
                                                  while_waiting=_import_for_stages)
            import pandas as pd  # the incremental path: what the no-op does without
            _crash_point("after_ingest")
            runs, channels, problems = deduplicate(results)
            problems = tree.problems + problems
            runs_df = runs_frame(runs)
            ctx_args = dict(raw=tree.root, warehouse=warehouse,
                            runs=runs_df.assign(params=[r["params"] for r in runs]) if runs else runs_df,
                            jobs=jobs, progress=progress, mapper=ex.mapper(progress))
            staged = run_stages_cached(ctx_args, runs, prev, warehouse, full, logbook_hash(side), progress,
                                       generation, drawer)
        _crash_point("after_stages")
        problems += staged.problems
        if staged.warnings and not runs_df.empty:
            runs_df["warnings"] = [list(w) + staged.warnings.get(rid, [])
                                   for rid, w in zip(runs_df["run_id"], runs_df["warnings"])]
        quarantine = pd.DataFrame([{"source_path": p.source_path, "error": p.error, "line": p.line,
                                    "campaign": p.source_path.split("/")[0] if "/" in p.source_path else None,
                                    "stage": p.stage} for p in problems],
                                  columns=["source_path", "error", "line", "campaign", "stage"])
        stage_tables = dict(staged.tables)
        if "findings" in stage_tables:
            stage_tables["findings"] = compare_findings(stage_tables["findings"], prev.findings,
                                                        prev.generation is not None, prev.finding_changes, started_at)
        seen = {p.rel for p in plans} | {r.source_path for r in side}
        inputs = _inputs_table(plans, side_changes, prev, seen, problems, results)
        summary.n_new = int(((inputs["status"] == "new") & (inputs["role"] == "run")).sum())
        summary.n_changed = int(((inputs["status"] == "changed") & (inputs["role"] == "run")).sum())
        summary.n_deleted = int(((inputs["status"] == "deleted") & (inputs["role"] == "run")).sum())
        summary.n_unchanged = int(((inputs["status"] == "unchanged") & (inputs["role"] == "run")).sum())
        summary.n_runs = len(runs)
        summary.quarantine = problems
        summary.stages_run, summary.stages_reused = staged.ran, staged.reused
        log_row = pd.DataFrame([{
            "generation": generation, "started_at": started_at, "finished_at": datetime.now(timezone.utc),
            "duration_s": time.monotonic() - t0, "mode": summary.mode, "executor": ex.name,
            "n_files": len(files), "n_runs": len(runs), "n_new": summary.n_new, "n_changed": summary.n_changed,
            "n_deleted": summary.n_deleted, "n_unchanged": summary.n_unchanged, "n_quarantined": len(problems),
            "stages_run": staged.ran, "stages_reused": staged.reused, "exit_code": summary.exit_code,
            "inputs_key": key}])
        old_log = numbered_history(prev.history)
        in_use = set(runs_df.get("samples_path", [])) | {r.folder for r in staged.records}
        kept, _expired = superseded_files(prev, in_use, clock(), keep_h)
        kept_paths = sorted(kept)
        superseded = pd.DataFrame({
            "path": pd.Series(kept_paths, dtype="string"),
            # whole microseconds, as DuckDB stores them: a time carried from rebuild to rebuild never drifts
            "superseded_at": pd.to_datetime(pd.Series([round(kept[p] * 1e6) for p in kept_paths], dtype="int64"),
                                            unit="us", utc=True)})
        log_row["seq"] = int(old_log["seq"].max()) + 1 if old_log is not None else 1
        history = log_row
        if old_log is not None:
            history = pd.concat([old_log.tail(HISTORY_ROWS - 1), log_row], ignore_index=True)
        all_tables = {
            "runs": runs_df, "quarantine": quarantine, "channels": pd.DataFrame(channels),
            "skipped_files": pd.DataFrame(
                [{"source_path": tree.rel(p), "campaign": tree.campaign(p), "reason": skip_reason(p)} for p in ignored]
                + [{"source_path": rel, "campaign": rel.split("/")[0] if "/" in rel else None, "reason": why}
                   for rel, why in tree.listing().skipped], columns=["source_path", "campaign", "reason"]),
            "figures": pd.DataFrame(staged.figures, columns=["stage", "name", "path", "caption"]),
            **stage_tables,
            "rebuild_log": history, "rebuild_inputs": inputs,
            "ingest_state": pd.DataFrame([r.as_row() for r in records + side]),
            "stage_cache": pd.DataFrame([r.as_row() for r in staged.records]),
            "superseded_files": superseded,
        }
        progress.message(f"warehouse: writing {len(all_tables)} tables")

        def write(tmp_db):
            build_database(tmp_db, warehouse, all_tables, runs_df)
            waited = time.monotonic()
            n_aside = drawer.finish()  # the figures drawn beside the database, their stage folders put in place
            if n_aside:
                progress.message(f"figures: {n_aside} drawn in a worker beside the stages and the database "
                                 f"(waited {_seconds(time.monotonic() - waited)} for them)")

        # before the new database is written, what neither warehouse uses nor keeps goes (files past
        # their retention, what a killed night left): a nearly full disk gets that room back first
        collect_garbage(warehouse, *_split_kept(in_use | set(kept) | prev.samples | prev.stage_folders))
        summary.report = swap_in_new_database(warehouse, write, report)
        # files the new warehouse uses, and those of earlier ones still within their retention
        # (a reader that opened an earlier warehouse keeps reading its samples)
        keep = in_use | set(kept)
        collect_garbage(warehouse, *_split_kept(keep))
    summary.tables = {k: len(v) for k, v in all_tables.items()}
    if summary.report is not None:
        progress.message(f"report: {summary.report}")
    summary.seconds = time.monotonic() - t0
    _report_quarantine(problems, progress)
    progress.message(f"rebuild: {summary.n_runs} runs ({summary.n_new} new, {summary.n_changed} changed, "
                     f"{summary.n_deleted} deleted, {summary.n_unchanged} unchanged), {len(problems)} quarantined, "
                     f"stages run: {', '.join(staged.ran) or 'none'}, {summary.seconds:.1f} s")
    return summary


def numbered_history(history: pd.DataFrame | None) -> pd.DataFrame | None:
    """``rebuild_log`` of the previous warehouse with its ``seq`` (None when empty). A log from
    before the column is numbered 1, 2, ... in its stored order (the order rebuilds appended it)."""
    if history is None or history.empty:
        return None
    if "seq" not in history.columns or history["seq"].isna().any():
        history = history.assign(seq=range(1, len(history) + 1))
    return history


def _split_kept(keep: set[str]) -> tuple[set[str], set[str]]:
    """Paths to keep (relative to the warehouse) as (samples files, stage folders and the rest)."""
    return {p for p in keep if p.startswith("samples/")}, {p for p in keep if not p.startswith("samples/")}


def _report_quarantine(problems: list[Problem], progress: Progress) -> None:
    for p in problems:
        where = f"{p.source_path}:{p.line}" if p.line else p.source_path
        progress.message(f"quarantined {where}: {p.error}")

def swap_in_new_database(warehouse: Path, write, report: bool, run_pages: str = "update") -> Path | None:
    """Write the new database under a temporary name (``write(tmp_db)``), render the morning
    report from it, swap the database in, then publish the report; returns the report's path.

    Any failure before the swap removes the temporary database and staged page and raises
    :class:`RebuildError`: the previous warehouse and its report are kept (the two always agree).
    ``run_pages`` as for :func:`pipeline.serve.report.render_report`.
    """
    tmp_db = warehouse / f".{DB_NAME}.tmp-{os.getpid()}"
    page = None  # the morning report (index and run pages), a folder beside the live one: from the new database
    try:
        write(tmp_db)
        if report:  # before the swap: a failure keeps the previous warehouse and its report
            from pipeline.serve.report import stage_report
            try:
                page = stage_report(warehouse, database=tmp_db, run_pages=run_pages)
            except Exception as exc:
                log.exception("report failed")
                raise RebuildError(f"the morning report could not be written: {type(exc).__name__}: "
                                   f"{' '.join(str(exc).split())}; the previous warehouse and report are kept") from exc
        _crash_point("before_swap")
        swap_in(tmp_db, warehouse / DB_NAME)
    except Exception as exc:
        tmp_db.unlink(missing_ok=True)
        Path(f"{tmp_db}.wal").unlink(missing_ok=True)
        if page is not None:
            from pipeline.serve.report import remove_report_folder
            remove_report_folder(page)
        if isinstance(exc, RebuildError):
            raise
        raise RebuildError(f"could not write the warehouse: {type(exc).__name__}: {exc}") from exc
    published = None
    _crash_point("between_swaps")  # killed here: the next rebuild or report publishes the staged report
    if page is not None:  # straight after the swap: the report follows the warehouse it describes
        from pipeline.serve.report import publish_report
        published = publish_report(warehouse, page)
    _crash_point("after_swap")
    return published


# -- the no-op fast path ---------------------------------------------------------------------------
def inputs_key(tree: RawTree, code: str, plans: list[FilePlan], side: list[FileRecord], ignored: list[Path]) -> str:
    """Fingerprint of everything a rebuild reads: every run file's path, ``(size, mtime, inode)``
    and applicable metadata, every side file's path and stat, the files ignored or skipped, the
    raw tree's own problems (links, manifests, rig.toml) and the version of all the project's
    code. Equal keys with no file in doubt (:func:`nothing_changed`) mean the rebuild would write
    the same database again."""
    import hashlib

    blob = {
        "code": [code, project_code_version()],
        "runs": [[p.rel, *p.stat, p.meta_hash] for p in plans],
        "side": [[r.source_path, r.role, r.size_bytes, r.mtime_ns, r.inode, r.source_sha256] for r in side],
        "ignored": [tree.rel(p) for p in ignored],
        "skipped": [list(x) for x in tree.listing().skipped],
        "problems": [[p.source_path, p.error, p.line, p.stage] for p in tree.problems],
    }
    return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()[:32]


def nothing_changed(prev: PreviousState, plans: list[FilePlan], side: list[FileRecord], key: str,
                    warehouse: Path) -> bool:
    """Whether the live warehouse is exactly what this rebuild would write, bookkeeping aside.

    True when the previous rebuild saw the same inputs (same :func:`inputs_key`), every run file
    is unchanged at a glance (same stat, metadata and ingest code, samples file present, no
    racy mtime), every side file has the stat its record holds, and every stage's cached
    output is there and was cacheable. Anything in doubt gives False: the full incremental path.
    """
    if prev.generation is None or prev.inputs_key != key or not (warehouse / DB_NAME).is_file():
        return False
    if any(p.status != "unchanged" for p in plans) or len(prev.files) != len(plans) + len(side):
        return False
    for r in side:
        old = prev.files.get(r.source_path)
        if old is None or old.mtime_ns < 0 or (old.size_bytes, old.mtime_ns, old.inode) != \
                (r.size_bytes, r.mtime_ns, r.inode) or old.source_sha256 != r.source_sha256:
            return False
    if not prev.stages:
        return False
    return all(s.input_key != "uncacheable" and (warehouse / s.folder / "output.json").is_file()
               for s in prev.stages.values())


def _rebuild_noop(warehouse: Path, prev: PreviousState, plans: list[FilePlan], key: str, executor: str,
                  report: bool, generation: str, summary: RebuildSummary, started_at: datetime, t0: float,
                  keep_h: float, clock, progress: Progress) -> RebuildSummary:
    """Nothing changed: the previous database is copied and only the rebuild's bookkeeping is
    brought up to date, as the incremental path would have written it (``rebuild_log`` gets this
    rebuild's row; ``rebuild_inputs`` says every input is unchanged; ``findings`` carry their
    last change; ``superseded_files`` drops what has expired). The report is rendered anew (it
    states the time and the last rebuild) without redrawing run pages whose inputs are the
    same. Same swap, same crash safety as a full rebuild."""
    import duckdb

    in_use = prev.samples | prev.stage_folders
    kept, expired = superseded_files(prev, in_use, clock(), keep_h)

    def carry_over(tmp_db: Path) -> None:
        shutil.copyfile(warehouse / DB_NAME, tmp_db)
        con = duckdb.connect(str(tmp_db))
        try:
            con.execute("SET TimeZone = 'UTC'")
            con.execute("DELETE FROM rebuild_inputs WHERE status = 'deleted'")
            con.execute("UPDATE rebuild_inputs SET status = 'unchanged', reason = NULL WHERE status <> 'unchanged'")
            # compare_findings with every finding holding as before: the last change is carried over
            con.execute("UPDATE findings SET previous_holds = holds, "
                        "change = CASE WHEN change IS NOT NULL AND changed_at IS NOT NULL THEN change END, "
                        "changed_at = CASE WHEN change IS NOT NULL AND changed_at IS NOT NULL THEN changed_at END")
            if expired:
                con.executemany("DELETE FROM superseded_files WHERE path = ?", [[p] for p in sorted(expired)])
            problems = [Problem(s, e, ln, st) for s, e, ln, st in con.execute(
                "SELECT source_path, error, line, stage FROM quarantine").fetchall()]
            n_runs = con.execute("SELECT count(*) FROM runs").fetchone()[0]
            stages = [r[0] for r in con.execute("SELECT stage FROM stage_cache").fetchall()]
            summary.n_files = len(plans)
            summary.n_runs, summary.n_unchanged, summary.quarantine = n_runs, len(plans), problems
            summary.stages_reused = stages
            row = {"generation": generation, "started_at": started_at, "finished_at": datetime.now(timezone.utc),
                   "duration_s": time.monotonic() - t0, "mode": "no-op", "executor": executor,
                   "n_files": len(plans), "n_runs": n_runs, "n_new": 0, "n_changed": 0, "n_deleted": 0,
                   "n_unchanged": len(plans), "n_quarantined": len(problems), "stages_run": [],
                   "stages_reused": stages, "exit_code": summary.exit_code, "inputs_key": key,
                   "seq": con.execute("SELECT coalesce(max(seq), 0) + 1 FROM rebuild_log").fetchone()[0]}
            con.execute(f"INSERT INTO rebuild_log ({', '.join(row)}) VALUES ({', '.join('?' * len(row))})",
                        list(row.values()))
            con.execute("DELETE FROM rebuild_log WHERE rowid NOT IN "
                        f"(SELECT rowid FROM rebuild_log ORDER BY rowid DESC LIMIT {HISTORY_ROWS})")
            summary.tables = {t: con.execute(f'SELECT count(*) FROM "{t}"').fetchone()[0] for (t,) in con.execute(
                "SELECT table_name FROM duckdb_tables() WHERE schema_name = 'main' ORDER BY table_name").fetchall()}
            con.execute("CHECKPOINT")
        finally:
            con.close()

    collect_garbage(warehouse, *_split_kept(in_use | set(kept)))  # before the copy: room on a nearly full disk
    summary.report = swap_in_new_database(warehouse, carry_over, report, run_pages="missing")
    keep = in_use | set(kept)
    collect_garbage(warehouse, *_split_kept(keep))
    summary.seconds = time.monotonic() - t0
    if summary.report is not None:
        progress.message(f"report: {summary.report}")
    _report_quarantine(summary.quarantine, progress)
    progress.message(f"rebuild: {summary.n_runs} runs (0 new, 0 changed, 0 deleted, {summary.n_unchanged} unchanged: "
                     f"a no-op), {len(summary.quarantine)} quarantined, stages run: none, {summary.seconds:.1f} s")
    return summary
