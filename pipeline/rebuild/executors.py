"""Where per-file ingest and per-run analyses run: local worker processes or a Dask cluster.

An executor maps a picklable module-level function over a list of items and returns the
results in the order of the items. The rebuild uses one executor for ingest (one task per raw
file) and hands its ``map`` to the stages as ``StageContext.mapper`` (one task per run). Only the
calling process (the single writer) ever builds the DuckDB warehouse.

* :class:`LocalExecutor`: a process pool on this machine. Work on untrusted bytes (a ``map``
  with ``on_crash``: ingest) always runs in worker processes, whatever ``jobs`` is, so a reader
  crashing in C code costs that one file, never the rebuild. Those workers are forked from the
  rebuild when the first such item comes (none for a no-op rebuild), one per job and no more
  than there are items, and reused for every item; they start warm (everything the rebuild
  imported) and close the file descriptors they must not hold (the rebuild's lock).
  Other work (the stages' per-run analyses) runs in this process with ``jobs`` 1, else in a
  pool forked from the rebuild when the first such map comes: its workers start warm in a few
  milliseconds (a ``forkserver`` pool importing numpy, pandas, scipy and matplotlib afresh cost
  ~2 s of a 2-core machine, more than the work it spread; issue 14) and, like the readers,
  close the rebuild's lock at once.
  Every worker exits when the rebuild process dies, even by ``kill -9``.
* :class:`DaskExecutor`: a ``dask.distributed`` cluster (``--scheduler tcp://host:8786``), or a
  private ``LocalCluster`` when no address is given. Workers must see the raw tree and the
  warehouse folder at the same paths (a shared file system): ingest tasks write their samples
  Parquet there directly.
"""
from __future__ import annotations

import gc
import importlib
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures import TimeoutError as FuturesTimeout
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager

from pipeline.progress import Progress

EXECUTORS = ("local", "dask")
#: What ``on_crash`` is told when the worker process running an item died.
CRASH_REASON = "the worker process reading it died (a crash in a C library, or killed for memory)"
#: What ``on_crash`` is told when an item ran past its time limit and its worker was stopped
#: (the limit in seconds follows).
STUCK_REASON = "the reader was stopped after"


#: Python's cycle collector during a rebuild: its youngest generation collected after this many new
#: container objects (Python's default 700), the older ones after this many collections of the one
#: below (default 10, 10). A rebuild creates millions of objects that live to its end (the modules of
#: pandas, pyarrow, duckdb and the analyses, the runs rows, the frames): with the defaults a plan.toml
#: or logbook change at 1,000 runs made ~280 collections, 2 of them of every object (0.13-0.14 CPU-s
#: of its ~2.8), with these ~20, none of every object (0.04-0.07; issue 26). Cyclic garbage is still
#: collected, later. The rebuild command sets them before it imports the rebuild (``pipeline.cli``).
GC_THRESHOLD = (10_000, 20, 10)


#: Open :func:`fewer_collections` blocks that keep what the rebuild froze (the command's: its process ends).
_KEEP_FROZEN = [0]


@contextmanager
def fewer_collections(threshold: tuple[int, int, int] = GC_THRESHOLD, keep_frozen: bool = False):
    """Python's cycle collector at ``threshold`` (:data:`GC_THRESHOLD`; each a generation's, never
    below the one in force) while the block runs, the thresholds in force restored after it.

    What the rebuild froze out of the collector (``ingest_tasks._freeze``: :func:`gc.freeze`) is thawed
    when the block ends, if nothing was frozen when it began, so that a rebuild called as a library (a
    notebook, the tests) leaves the process as it found it; ``keep_frozen``: not while this block is
    open (the ``rebuild`` command, whose process ends after it: its exit's collection skips them)."""
    old = gc.get_threshold()
    frozen = gc.get_freeze_count()
    if old[0]:  # (0: collections turned off by the caller, left so)
        gc.set_threshold(*(max(a, b) for a, b in zip(old, threshold)))
    _KEEP_FROZEN[0] += bool(keep_frozen)
    try:
        yield
    finally:
        _KEEP_FROZEN[0] -= bool(keep_frozen)
        gc.set_threshold(*old)
        if not (frozen or keep_frozen or _KEEP_FROZEN[0]) and gc.get_freeze_count():
            gc.unfreeze()


def stuck_reason(limit_s: float) -> str:
    return f"{STUCK_REASON} {limit_s:.0f} s, far longer than a file of its size takes (a reader stuck in a loop)"


class Executor:
    """Runs ``func`` over items in order; the base class runs them in this process."""

    name = "serial"

    def map(self, func: Callable, items: Iterable, label: str = "", progress: Progress | None = None,
            on_crash: Callable | None = None, preload: Iterable[str] = (),
            while_waiting: Callable[[], object] | None = None, time_limit: Callable | None = None) -> list:
        """``func`` over ``items``, results in item order. ``on_crash(item, reason)`` stands in for
        the result of an item whose worker process died (executors with worker processes).
        ``preload``: modules this process imports for the work (once, where that helps).
        ``while_waiting()``: work of the caller's own, called once while the first items run
        elsewhere (in this process's executor: before them), so that it costs no wall time
        beside worker processes. ``time_limit(item)``: seconds an item may run before its worker
        is stopped (executors that can stop one; see :class:`LocalExecutor`)."""
        items = list(items)
        progress = progress or Progress()
        if items and while_waiting is not None:
            while_waiting()
        out = []
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            for item in items:
                out.append(func(item))
                task.advance()
        return out

    def mapper(self, progress: Progress) -> Callable:
        """A ``StageContext.mapper``: ``mapper(func, items, label) -> list``."""
        return lambda func, items, label="": self.map(func, items, label, progress)

    def release_readers(self) -> None:
        """The work on untrusted bytes is done (the ingest): stop the processes kept for it, whose
        memory the rest of the rebuild would otherwise hold (executors with such processes)."""

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def _watch_parent(pid: int, every_s: float = 0.2) -> None:
    """Worker initializer: exit as soon as the rebuild process ``pid`` is gone (even by kill -9).

    A worker blocked on its task queue would otherwise live on, holding the rebuild's stdout,
    stderr and any file it had open.
    """
    def alive() -> bool:
        try:
            os.kill(pid, 0)
        except (ProcessLookupError, PermissionError):
            return False
        try:  # a killed parent not yet reaped by its own parent is a zombie: dead for us
            with open(f"/proc/{pid}/stat", "rb") as fh:
                return fh.read().rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")
        except (OSError, IndexError):
            return True

    def watch():
        while True:
            time.sleep(every_s)
            if not alive():
                os._exit(70)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _reader_worker_init(pid: int, close_fds: tuple[int, ...]) -> None:
    """Initializer of a forked reader worker: close the rebuild's descriptors it must not hold
    (its lock: a worker outliving a killed rebuild would keep the warehouse locked), then watch
    the rebuild process. A worker ignores SIGINT (Ctrl-C signals the whole process group: the
    rebuild stops its workers itself, without a traceback from each) and dies of SIGTERM (the
    rebuild's own handler, inherited by the fork, is not its)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # what the rebuild held when it forked this worker is left out of the worker's garbage
    # collections: a collection writes into every object it visits, and so would copy every page
    # of the parent's heap it shares into this process (issue 26: memory flat in the runs)
    gc.freeze()
    for fd in close_fds:
        try:
            os.close(fd)
        except OSError:
            pass
    _watch_parent(pid)


def forked_pool(workers: int, close_fds: tuple[int, ...] = ()) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes forked from this one when the first task comes (warm at
    once: everything imported here is there), which close ``close_fds`` (the rebuild's lock) and
    exit when this process dies."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                               initializer=_reader_worker_init, initargs=(os.getpid(), tuple(close_fds)))


def _kill_workers(pool: ProcessPoolExecutor) -> None:
    """SIGKILL every worker process of ``pool`` (a stuck one does not answer anything else)."""
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        proc.kill()


def default_jobs(jobs: int | None) -> int:
    """``jobs``, or every core when None."""
    return max(1, int(jobs or os.cpu_count() or 1))


class LocalExecutor(Executor):
    """A pool of ``jobs`` worker processes on this machine.

    Parameters
    ----------
    jobs : int, optional
        Worker processes (default: all cores). With 1, work without ``on_crash`` runs in this
        process; work with ``on_crash`` (untrusted bytes) never does.
    close_in_workers : tuple of int
        File descriptors of this process that forked workers close at once (the rebuild lock).
    """

    name = "local"

    def __init__(self, jobs: int | None = None, close_in_workers: tuple[int, ...] = ()):
        self.jobs = default_jobs(jobs)
        self.close_in_workers = tuple(close_in_workers)
        self._pool: ProcessPoolExecutor | None = None
        self._readers: ProcessPoolExecutor | None = None
        #: worker processes started for untrusted work (for the report and the tests)
        self.reader_processes_started = 0

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:  # forked: warm at once; the lock closed in each worker
            self._pool = forked_pool(self.jobs, self.close_in_workers)
        return self._pool

    def _reader_pool(self, workers: int) -> ProcessPoolExecutor:
        if self._readers is None:
            self._readers = forked_pool(workers, self.close_in_workers)
            self.reader_processes_started += workers  # started on the first submit, one per worker
        return self._readers

    def release_readers(self) -> None:
        self._drop_readers()

    def _drop_readers(self) -> None:
        if self._readers is not None:
            self._readers.shutdown(wait=True, cancel_futures=True)
            self._readers = None

    def map(self, func, items, label="", progress=None, on_crash: Callable | None = None, preload=(),
            while_waiting=None, time_limit: Callable | None = None):
        """``func`` over ``items`` in worker processes, results in item order.

        With ``on_crash`` (work on untrusted bytes) the items always run in worker processes:
        a worker that dies (a segfault in a C library reading a corrupt file) costs only the item
        it was running, which gets ``on_crash(item, reason)`` as its result; the other items go on
        in a fresh worker. Without ``on_crash``, ``jobs`` 1 runs everything in this process, and a
        dying worker raises :class:`~concurrent.futures.process.BrokenProcessPool`.
        With ``on_crash``, ``time_limit(item)`` may give the seconds an item may run: past them
        its worker is stopped and the item gets ``on_crash(item, stuck_reason(limit))``.
        """
        items = list(items)
        if not items:
            return []
        if on_crash is not None:
            return self._map_isolated(func, items, label, progress or Progress(), on_crash, preload, while_waiting,
                                      time_limit)
        if self.jobs <= 1 or len(items) == 1:  # in this process: trusted work only
            return super().map(func, items, label, progress, while_waiting=while_waiting)
        progress = progress or Progress()
        out = []
        chunk = max(1, min(16, len(items) // (self.jobs * 8)))
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            results = self._get_pool().map(func, items, chunksize=chunk)  # submitted at once
            if while_waiting is not None:
                while_waiting()
            for res in results:
                out.append(res)
                task.advance()
        return out

    def _map_isolated(self, func, items, label, progress, on_crash, preload, while_waiting=None,
                      time_limit=None) -> list:
        """Items in forked worker processes, at most one in flight per worker, so that a dead
        worker's item is known: with one suspect it is the culprit; with several (``jobs`` > 1)
        each is run again alone.

        The workers are forked before ``preload`` is imported here: each imports what its items
        need while this process imports ``preload`` and runs ``while_waiting`` (the two would
        otherwise come one after the other; issue 14). A worker forked again later (after a
        crash) starts warm."""
        workers = min(self.jobs, len(items))
        out: list = [None] * len(items)
        todo = list(range(len(items)))[::-1]
        running: dict = {}
        deadline: dict = {}  # future -> time.monotonic() past which its item is stuck
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            while todo or running:
                pool = self._reader_pool(workers)
                while todo and len(running) < workers:
                    i = todo.pop()
                    fut = pool.submit(func, items[i])
                    running[fut] = i
                    if time_limit is not None:
                        limit = time_limit(items[i])
                        deadline[fut] = (time.monotonic() + limit, limit)
                if preload is not None:
                    for mod in preload:
                        importlib.import_module(mod)
                    preload = None
                    if while_waiting is not None:
                        while_waiting()
                first = min((deadline[f][0] for f in running if f in deadline), default=None)
                finished, _ = wait(running, return_when=FIRST_COMPLETED,
                                   timeout=None if first is None else max(0.0, first - time.monotonic()))
                if not finished:  # an item ran past its limit: stop the workers, set it aside
                    now = time.monotonic()
                    stuck = {f: i for f, i in running.items() if f in deadline and deadline[f][0] <= now}
                    if stuck:
                        self._kill_readers()
                        for f, i in sorted(stuck.items(), key=lambda fi: fi[1]):
                            out[i] = on_crash(items[i], stuck_reason(deadline[f][1]))
                            task.advance()
                        todo += sorted((i for f, i in running.items() if f not in stuck), reverse=True)
                        running.clear()
                        deadline.clear()
                        progress.message(f"{label or 'work'}: {len(stuck)} item(s) ran past their time limit; "
                                         "their worker was stopped and they are set aside")
                    continue
                suspects = []
                for fut in finished:
                    i = running.pop(fut)
                    deadline.pop(fut, None)
                    try:
                        out[i] = fut.result()  # a task's own exception is raised here
                    except BrokenProcessPool:
                        suspects.append(i)
                        continue
                    task.advance()
                if not suspects:
                    continue
                # the pool is broken: every item still running failed with it
                for fut, i in list(running.items()):
                    try:
                        out[i] = fut.result()
                        task.advance()
                    except BrokenProcessPool:
                        suspects.append(i)
                running.clear()
                self._drop_readers()
                progress.message(f"{label or 'work'}: a worker process died; "
                                 f"{'its item is' if len(suspects) == 1 else 'its items are'} set aside")
                for i in sorted(suspects):
                    out[i] = on_crash(items[i], CRASH_REASON) if len(suspects) == 1 else \
                        self._isolated(func, items[i], on_crash, time_limit)
                    task.advance()
        return out

    def _kill_readers(self) -> None:
        """Stop the readers' workers at once (one is stuck); the pool is dropped."""
        if self._readers is not None:
            _kill_workers(self._readers)
            self._drop_readers()

    def _isolated(self, func, item, on_crash: Callable, time_limit: Callable | None = None):
        """Run one item in a fresh forked single-worker pool; ``on_crash`` if that worker dies
        (or runs past ``time_limit(item)``: then it is stopped)."""
        self.reader_processes_started += 1
        pool = forked_pool(1, self.close_in_workers)
        limit = None if time_limit is None else time_limit(item)
        try:
            return pool.submit(func, item).result(timeout=limit)
        except BrokenProcessPool:
            return on_crash(item, CRASH_REASON)
        except FuturesTimeout:
            _kill_workers(pool)
            return on_crash(item, stuck_reason(limit))
        finally:
            pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        self._drop_readers()
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __exit__(self, exc_type, *exc):
        if exc_type is not None and not issubclass(exc_type, Exception):  # interrupted (Ctrl-C, SIGTERM)
            for pool in (self._readers, self._pool):  # at once: not after the items they are running
                if pool is not None:
                    _kill_workers(pool)
        self.close()
        return False


class DaskExecutor(Executor):
    """Tasks on a ``dask.distributed`` cluster; results gathered back in item order.

    Parameters
    ----------
    address : str, optional
        Scheduler address (``tcp://host:8786``). Without one, a private ``LocalCluster`` with
        ``jobs`` worker processes is started and closed with the executor.
    jobs : int, optional
        Worker processes of the private cluster.
    client : distributed.Client, optional
        An existing client to use (not closed by the executor).
    """

    name = "dask"

    def __init__(self, address: str | None = None, jobs: int | None = None, client=None):
        try:  # an optional dependency, imported only by the executor that needs it (~1 s)
            from distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise RuntimeError("the dask executor needs dask.distributed: pip install 'pneubench[dask]'") from exc
        self._own_client = client is None
        self._cluster = None
        if client is not None:
            self.client = client
        elif address:
            self.client = Client(address, timeout="30s")
        else:
            self._cluster = LocalCluster(n_workers=max(1, int(jobs or os.cpu_count() or 1)), threads_per_worker=1,
                                         processes=True, dashboard_address=None)
            self.client = Client(self._cluster)
        self.address = address or self.client.scheduler.address

    def map(self, func, items, label="", progress=None, on_crash: Callable | None = None, preload=(),
            while_waiting=None, time_limit=None):
        from distributed import KilledWorker, as_completed  # optional (pneubench[dask]), as in __init__

        items = list(items)
        progress = progress or Progress()
        if not items:
            return []
        futures = self.client.map(func, items, pure=False)  # time_limit: Dask cannot stop one task's worker
        if while_waiting is not None:
            while_waiting()
        index = {f.key: i for i, f in enumerate(futures)}
        out: list = [None] * len(items)
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            for fut in as_completed(futures):
                i = index[fut.key]
                try:
                    out[i] = fut.result()  # re-raises a task's exception here
                except KilledWorker:  # the task killed every worker that tried it
                    if on_crash is None:
                        raise
                    out[i] = on_crash(items[i], CRASH_REASON)
                task.advance()
        return out

    def close(self) -> None:
        if self._own_client:
            self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(name: str = "local", jobs: int | None = None, scheduler: str | None = None,
                  close_in_workers: tuple[int, ...] = ()) -> Executor:
    """The executor called ``name`` (``local`` or ``dask``); ``close_in_workers``: descriptors
    forked local workers close (the rebuild lock)."""
    if name == "local":
        return LocalExecutor(jobs, close_in_workers)
    if name == "dask":
        return DaskExecutor(scheduler, jobs)
    raise ValueError(f"unknown executor {name!r} (one of {', '.join(EXECUTORS)})")
