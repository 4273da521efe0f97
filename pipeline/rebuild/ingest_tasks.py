"""The rebuild's ingest step: one task per raw file to read, run in worker processes, and the
messages that cross to them and back (frozen dataclasses: picklable, for the local pool and Dask).

A file whose stat alone changed is hashed first and keeps its previous record when its bytes
are the same; any other file that is not unchanged is ingested (:func:`pipeline.ingest.file.ingest_file`).
A worker that dies (a reader crashing in C code, killed for memory, stopped at its time limit)
costs its one file, quarantined (:data:`CRASHED`, :data:`STUCK`).
"""
from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.raw.problems import Problem
from pipeline.raw.tree import RawTree
from pipeline.raw.rawfile import RawOpenError, open_raw
from pipeline.readers import READERS
from pipeline.readers.base import read_time_limit
from pipeline.rebuild.executors import CRASH_REASON, STUCK_REASON, Executor
from pipeline.rebuild.options import RebuildRun
from pipeline.rebuild.publish import crash_point
from pipeline.rebuild.state import FilePlan, FileRecord, record_for, record_result

if TYPE_CHECKING:
    from pipeline.ingest.result import IngestResult

# pipeline.ingest.file (numpy, pyarrow) is imported by the functions that use it, not here: a
# no-op rebuild reads no file and needs neither (~0.5 s of a 10,000-run no-op's 2 s budget; issue 14).

#: The quarantine reason of a file whose reader's worker process died.
CRASHED = f"cannot read file: {CRASH_REASON}"
STUCK = f"cannot read file: {STUCK_REASON}"  # a reader stopped at its time limit: tried once more, as a crash

#: The reason a file is set aside for this night: it changed while it was read (a bench still
#: writing it). Not a lasting quarantine: the next rebuild reads it again.
#: At most this many bytes to read [B]: the rebuild imports what the stages and the readers need
#: before it forks its readers, which start warm. Above it the readers are forked first and import
#: while the rebuild imports (the two overlap: less wall time, the imports paid twice in CPU).
#: Issue 26: one changed file paid ~1.4 CPU-s for its reader's own imports.
WARM_READ_BYTES = 32 * 2**20
CHANGED_WHILE_READ = "file changed while it was read; will be read again at the next rebuild"


@dataclass(frozen=True)
class PreviousRead:
    """What the last rebuild recorded of a file whose stat alone changed."""

    sha: str | None  # its SHA-256 [hex]; None: its last read was not trustworthy
    crashed: bool    # its reader's worker died (or was stopped) last time


@dataclass(frozen=True)
class IngestTask:
    """One raw file to read, as sent to a worker process."""

    raw: str                      # the raw tree's root
    token: str                    # the rebuild's generation: one parsed raw tree per rebuild and worker
    path: str                     # the file
    warehouse: str
    reuse: bool                   # an existing samples file of the same key may be kept (not --full)
    previous: PreviousRead | None  # only its stat changed: the same bytes keep their record
    code: str                     # the ingest code version
    inode: int | None = None      # the inode the scan saw: another file there is not read


@dataclass(frozen=True)
class IngestOutcome:
    """What a worker answers for one :class:`IngestTask`."""

    sha: str | None               # the file's SHA-256 [hex] to record; None: not trustworthy
    reused: bool                  # same bytes as before: the previous record stands
    result: IngestResult | None   # the ingest's result (None when reused)
    retry: bool = False           # the next rebuild must look at the file again


def sha256_file(path, *args, **kwargs):
    """:func:`pipeline.ingest.hashing.sha256_file` (imported when a file is first hashed)."""
    from pipeline.ingest.hashing import sha256_file as _sha256_file

    return _sha256_file(path, *args, **kwargs)


def ingest_file(tree, path, *args, **kwargs):
    """:func:`pipeline.ingest.file.ingest_file` (imported when a file is first read)."""
    from pipeline.ingest.file import ingest_file as _ingest_file

    return _ingest_file(tree, path, *args, **kwargs)


_TREES: dict[tuple[str, str], RawTree] = {}


def _tree(raw: str, token: str) -> RawTree:
    """One parsed raw tree per (raw folder, rebuild) in each worker process."""
    tree = _TREES.get((raw, token))
    if tree is None:
        _TREES.clear()
        tree = _TREES[(raw, token)] = RawTree(Path(raw))
    return tree


def _unreadable(tree: RawTree, path: Path, error: str, transient: bool = False) -> IngestResult:
    from pipeline.ingest.result import IngestResult

    return IngestResult(source_path=tree.rel(path), campaign=tree.campaign(path), error=error, transient=transient)


def _stat_or_none(path: Path) -> tuple[int, int, int] | None:
    """``(size, mtime_ns, inode)`` of a file, None when it cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, st.st_ino


def ingest_task(task: IngestTask) -> IngestOutcome:
    """Worker task: open the file once (:func:`pipeline.raw.rawfile.open_raw`: no symlink out of raw/
    followed, a regular file, the inode the scan saw), then :func:`_ingest_opened`. A file that
    cannot be opened so is quarantined for this night with the reason and looked at again next time."""
    path, tree = Path(task.path), _tree(task.raw, task.token)
    try:
        opened = open_raw(tree.root, path, inode=task.inode)
        try:
            opened.source  # the readers' link to the descriptor; no link, no read (never by name)
        except OSError:
            opened.close()
            raise
    except OSError as exc:
        why = str(exc) if isinstance(exc, RawOpenError) else f"cannot read file: {type(exc).__name__}: {exc}"
        return IngestOutcome(None, False, _unreadable(tree, path, why, transient=True), retry=True)
    with opened:
        return _ingest_opened(task, opened)


def _ingest_opened(task: IngestTask, opened) -> IngestOutcome:
    """Worker task: a file whose stat alone changed is hashed and keeps its previous record when
    its bytes are the same; any other file is ingested (and hashed while it is parsed).

    The outcome has ``retry`` when the next rebuild must look at the file again: it could not be
    opened (permissions, a share away), or it changed while it was read. A file whose size, mtime
    or inode differ after reading from before, or whose hash was not computed over exactly the
    bytes it had, is not published: its result is the one-line :data:`CHANGED_WHILE_READ` (its
    hash and its samples may be of different bytes).
    """
    path, tree = Path(task.path), _tree(task.raw, task.token)
    before = _stat_or_none(opened.source)  # the opened file's; after reading, the name's must match it
    sha, reuse, prev = None, task.reuse, task.previous
    hashed: list[int] = []
    if prev is not None:  # only the stat changed: the same bytes keep their record
        if prev.sha is None:
            reuse = False  # its last read was not trustworthy: a samples file named by its hash may be stale
        try:
            sha = sha256_file(opened.source, counted=hashed)
        except OSError as exc:
            res = _unreadable(tree, path, f"cannot read file: {type(exc).__name__}: {exc}", transient=True)
            return IngestOutcome(None, False, res, retry=True)
        if prev.sha == sha and before is not None and _stat_or_none(path) == before and hashed == [before[0]]:
            return IngestOutcome(sha, True, None)
    crash_point(f"ingest:{tree.rel(path)}", signal.SIGSEGV)  # a reader crashing in C code
    res = ingest_file(tree, path, Path(task.warehouse), reuse=reuse, sha256=sha, code_version=task.code,
                      opened=opened)
    if res.bytes_hashed is not None:
        hashed = [res.bytes_hashed]
    if before is not None and not res.transient and (
            _stat_or_none(path) != before or (hashed and hashed != [before[0]])):
        return IngestOutcome(None, False, _unreadable(tree, path, CHANGED_WHILE_READ, transient=True), retry=True)
    if res.transient or before is None:
        return IngestOutcome(None, False, res, retry=True)
    return IngestOutcome(_recorded_sha(res, sha, opened), False, res)


def _recorded_sha(res: IngestResult, sha: str | None, opened) -> str | None:
    """The hash to record for an ingested file: the one its run (or its runs) were read with."""
    if res.run is not None:
        return res.run["source_sha256"]
    if res.parts is not None:  # a file of several runs (sheets, MDF groups)
        return res.sha256
    if sha is None:  # quarantined before its hash was done: record it, or the next rebuild re-reads it
        try:
            return sha256_file(opened.source)
        except OSError:
            pass
    return sha


def _read_time_limit(task: IngestTask) -> float:
    """Seconds an ingest task may run (``pipeline.readers.base.read_time_limit`` of its file)."""
    try:
        size = os.stat(task.path).st_size
    except OSError:
        size = 0
    return read_time_limit(size)


def _ingest_crashed(task: IngestTask, reason: str) -> IngestOutcome:
    """Outcome of an ingest task whose worker process died: the file is quarantined.

    A first crash may pass (killed for memory): the next rebuild tries the file once more. A file
    that crashed its reader twice is hashed here (hashing cannot crash) and stays quarantined
    until its bytes change.
    """
    res = _unreadable(_tree(task.raw, task.token), Path(task.path), f"cannot read file: {reason}")
    if task.previous is not None and task.previous.crashed:
        try:
            with open_raw(_tree(task.raw, task.token).root, task.path) as opened:
                return IngestOutcome(sha256_file(opened.source), False, res)
        except OSError:
            pass
    return IngestOutcome(None, False, res, retry=True)


def _campaign_of(rel: str) -> str | None:
    """:meth:`RawTree.campaign` from the path as stored (``/``-separated, relative to raw/): its first
    folder, None at the top; without a ``Path`` made per record (issue 26: 10,000 records a change)."""
    head, sep, _rest = rel.partition("/")
    return head if sep and head else None


def _result_from_record(rec: FileRecord, tree: RawTree, path: Path) -> IngestResult:
    from pipeline.ingest.result import IngestResult

    rel = rec.source_path
    campaign = _campaign_of(rel) if rel == tree.rel(path) else tree.campaign(path)
    res = IngestResult(source_path=rec.source_path, campaign=campaign)
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


def _task_of(run: RebuildRun, tree: RawTree, p: FilePlan, code_version: str) -> IngestTask:
    """The task of a file to read; one whose stat alone changed carries what was recorded of it."""
    prev = None
    if p.previous is not None and p.status == "check" and p.reason == "content":
        # only the stat changed: a file with the same bytes keeps its record
        prev = PreviousRead(sha=p.previous.source_sha256,
                            crashed=p.previous.error == CRASHED or (p.previous.error or "").startswith(STUCK))
    return IngestTask(str(tree.root), run.generation, str(p.path), str(run.warehouse), not run.options.full, prev,
                      code_version, p.stat[2])


def ingest_incremental(run: RebuildRun, tree: RawTree, plans: list[FilePlan], executor: Executor,
                       code_version: str, while_waiting: Callable[[], object] | None = None
                       ) -> tuple[list[IngestResult], list[FileRecord]]:
    """Ingest what the plans say; reuse the previous records of unchanged files. ``while_waiting``:
    the caller's own work, done while the first files are read (``Executor.map``)."""
    results: dict[str, IngestResult] = {}
    records: dict[str, FileRecord] = {}
    todo = []
    _freeze(run.generation)
    for p in plans:
        if p.status == "unchanged":
            results[p.rel] = _result_from_record(p.previous, tree, p.path)
            records[p.rel] = p.previous
        else:
            todo.append((p, _task_of(run, tree, p, code_version)))
    _freeze(run.generation)
    if todo:
        run.progress.message(f"ingest: {len(todo)} of {len(plans)} run files to read")
    # forked local workers inherit the parsed raw tree and the readers of the formats present
    _TREES.clear()
    _TREES[(str(tree.root), run.generation)] = tree
    readers = sorted({READERS[p.path.suffix.lower()].split(":")[0] for p, _ in todo
                      if p.path.suffix.lower() in READERS})
    if todo and sum(p.stat[0] for p, _ in todo) <= WARM_READ_BYTES:
        readers, while_waiting = _import_first(readers, while_waiting)
    outs = executor.map(ingest_task, [t for _, t in todo], "ingest", run.progress, on_crash=_ingest_crashed,
                        preload=readers, while_waiting=while_waiting, time_limit=_read_time_limit)
    now = time.time()
    for (p, _), out in zip(todo, outs):
        if out.reused:
            p.status = "unchanged"
            results[p.rel] = _result_from_record(p.previous, tree, p.path)
            old = p.previous
            records[p.rel] = record_for(p, out.sha, code_version, old.result, old.error, now)
            continue
        res: IngestResult = out.result
        if p.status == "check":
            p.status = "changed"
        results[p.rel] = res
        records[p.rel] = record_for(p, out.sha, code_version, record_result(res), res.error, now, retry=out.retry)
    order = [p.rel for p in plans]
    return [results[r] for r in order], [records[r] for r in order]


#: The rebuild (its generation) that froze objects of this process out of the cyclic garbage collector.
_FROZEN: list = [None]


def _freeze(generation: str) -> None:
    """Freeze what the process holds out of the cyclic garbage collector (:func:`gc.freeze`): the
    imports, the previous state and the results of the unchanged files live through the whole
    rebuild, and each full collection visited them all again (issue 26: ~1 CPU-s of collections in
    a step change at 10,000 runs, ~0.4 less so). Frozen objects are still freed by their reference
    counts; cycles among them wait for the next rebuild in the same process (the tests), which thaws
    and collects them first. Nothing is frozen while the collector is off."""
    import gc

    if not gc.isenabled():
        return
    if _FROZEN[0] not in (None, generation) and gc.get_freeze_count():
        gc.unfreeze()
        gc.collect()
    gc.freeze()
    _FROZEN[0] = generation


def _import_first(readers: list[str], while_waiting: Callable[[], object] | None
                  ) -> tuple[list[str], Callable[[], object] | None]:
    """Import the ``readers`` and do ``while_waiting`` now, before the readers are forked (they
    inherit it all); nothing is left to preload nor to do while they read."""
    import importlib

    for mod in ("pipeline.ingest.file", "pipeline.ingest.hashing", *readers):
        importlib.import_module(mod)
    if while_waiting is not None:
        while_waiting()
    return [], None


def deduplicate(results: list[IngestResult], held_before=None) -> tuple[list[dict], list[dict], list[Problem]]:
    """Runs, channel rows and quarantine rows; a run_id claimed by more than one file is kept by one
    of them and the others are quarantined.

    The file that holds the run in the live warehouse keeps it (``held_before(source_path, run_id)``:
    True for that file): a copy put anywhere in raw/, a cut-short backup in ``archive/`` say, must not
    take a good run's place because its path sorts first (a reviewer's finding, session 29: it had).
    Between files of which none held it, the first path in sorted order keeps it, as before."""
    runs, channels, problems = [], [], []
    flat = [p for r in results for p in (r.parts if r.parts is not None else [r])]  # a file of several runs
    flat.sort(key=lambda r: r.source_path)
    claims: dict[str, list[IngestResult]] = {}
    for r in flat:
        if r.error is None:
            claims.setdefault(r.run["run_id"], []).append(r)
    owner: dict[str, str] = {}
    for rid, rs in claims.items():
        incumbents = [r for r in rs if held_before is not None and len(rs) > 1 and held_before(r.source_path, rid)]
        owner[rid] = (incumbents[0] if len(incumbents) == 1 else rs[0]).source_path
    for r in flat:
        if r.error is not None:
            problems.append(Problem(r.source_path, r.error))
            continue
        rid = r.run["run_id"]
        if owner[rid] != r.source_path:
            problems.append(Problem(r.source_path, f"duplicate run_id `{rid}`, already used by `{owner[rid]}`"))
            continue
        runs.append(r.run)
        channels += r.channels
    return runs, channels, problems


def held_in(previous) -> Callable[[str, str], bool]:
    """``held(source_path, run_id)``: whether the live warehouse (``previous``, a
    :class:`pipeline.rebuild.state.PreviousState`) has ``run_id`` from that file in its ``runs``: the
    file's record names the run, and the run's samples file is one ``runs`` publishes (a copy that
    was read but lost the run_id to another file has a record naming it too). Only the contested
    files' records are decoded."""
    def held(source_path: str, run_id: str) -> bool:
        record = previous.files.get(source_path)
        if record is None or record.error is not None or not record.result:
            return False
        parts = record.result.get("parts") or [record.result]
        return any((run := part.get("run") or {}).get("run_id") == run_id and run.get("samples_path") in previous.samples
                   for part in parts)
    return held
