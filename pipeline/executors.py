"""Where per-file ingest and per-run analyses run: local worker processes or a Dask cluster.

An executor maps a picklable module-level function over a list of items and returns the
results in the order of the items. The rebuild uses one executor for ingest (one task per raw
file) and hands its ``map`` to the stages as ``StageContext.mapper`` (one task per run). Only the
calling process (the single writer) ever builds the DuckDB warehouse.

* :class:`LocalExecutor`: a process pool on this machine. Workers are started with the
  ``forkserver`` method, so they inherit no file descriptors of the rebuild (its lock above
  all) and exit when the rebuild process dies, even by ``kill -9``.
* :class:`DaskExecutor`: a ``dask.distributed`` cluster (``--scheduler tcp://host:8786``), or a
  private ``LocalCluster`` when no address is given. Workers must see the raw tree and the
  warehouse folder at the same paths (a shared file system): ingest tasks write their samples
  Parquet there directly.
"""
from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from pipeline.progress import Progress

EXECUTORS = ("local", "dask")
#: What ``on_crash`` is told when the worker process running an item died.
CRASH_REASON = "the worker process reading it died (a crash in a C library, or killed for memory)"


class Executor:
    """Runs ``func`` over items in order; the base class runs them in this process."""

    name = "serial"

    def map(self, func: Callable, items: Iterable, label: str = "", progress: Progress | None = None,
            on_crash: Callable | None = None) -> list:
        """``func`` over ``items``, results in item order. ``on_crash(item, reason)`` stands in for
        the result of an item whose worker process died (executors with worker processes)."""
        items = list(items)
        progress = progress or Progress()
        out = []
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            for item in items:
                out.append(func(item))
                task.advance()
        return out

    def mapper(self, progress: Progress) -> Callable:
        """A ``StageContext.mapper``: ``mapper(func, items, label) -> list``."""
        return lambda func, items, label="": self.map(func, items, label, progress)

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
    import threading

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


def preload_modules() -> list[str]:
    """Modules the fork server imports once, so each worker starts warm (readers, stages, analyses)."""
    import pkgutil

    mods = ["numpy", "pandas", "pyarrow.parquet", "scipy.optimize", "scipy.signal", "scipy.stats",
            "matplotlib.pyplot", "pipeline.ingest"]
    try:
        from pipeline import readers, stages

        mods += [f"pipeline.readers.{m.name}" for m in pkgutil.iter_modules(readers.__path__)]
        mods += [f"pipeline.stages.{m.name}" for m in pkgutil.iter_modules(stages.__path__) if not m.name.startswith("_")]
    except ImportError:  # pragma: no cover
        pass
    return mods


class LocalExecutor(Executor):
    """A pool of ``jobs`` worker processes on this machine (serial when ``jobs`` is 1)."""

    name = "local"

    def __init__(self, jobs: int | None = None):
        self.jobs = max(1, int(jobs or os.cpu_count() or 1))
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            ctx = multiprocessing.get_context("forkserver")
            ctx.set_forkserver_preload(preload_modules())
            self._pool = ProcessPoolExecutor(max_workers=self.jobs, mp_context=ctx, initializer=_watch_parent,
                                             initargs=(os.getpid(),))
        return self._pool

    def map(self, func, items, label="", progress=None, on_crash: Callable | None = None):
        """``func`` over ``items`` in worker processes, results in item order.

        With ``jobs`` 1 everything runs in this process. Otherwise a worker that dies (a segfault
        in a C library reading a corrupt file) breaks the pool.
        With ``on_crash`` the items not finished then are run again, each in a process of its
        own, and an item whose process dies again gets ``on_crash(item, reason)`` as its result;
        without it the :class:`~concurrent.futures.process.BrokenProcessPool` error is raised.
        """
        items = list(items)
        if not items or self.jobs <= 1 or (len(items) == 1 and on_crash is None):
            return super().map(func, items, label, progress)  # in this process: no isolation
        progress = progress or Progress()
        out = []
        chunk = max(1, min(16, len(items) // (self.jobs * 8)))
        with progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            try:
                for res in self._get_pool().map(func, items, chunksize=chunk):
                    out.append(res)
                    task.advance()
            except BrokenProcessPool:
                if on_crash is None:
                    raise
                self._pool = None  # broken: the next map starts a new one
                progress.message(f"{label or 'work'}: a worker process died; running the "
                                 f"{len(items) - len(out)} unfinished items one process each")
                for item in items[len(out):]:
                    out.append(self._isolated(func, item, on_crash))
                    task.advance()
        return out

    def _isolated(self, func, item, on_crash: Callable):
        """Run one item in a fresh single-worker pool; ``on_crash`` if that worker dies."""
        ctx = multiprocessing.get_context("forkserver")
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_watch_parent,
                                 initargs=(os.getpid(),)) as pool:
            try:
                return pool.submit(func, item).result()
            except BrokenProcessPool:
                return on_crash(item, CRASH_REASON)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


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
        try:
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

    def map(self, func, items, label="", progress=None, on_crash: Callable | None = None):
        from distributed import KilledWorker, as_completed

        items = list(items)
        progress = progress or Progress()
        if not items:
            return []
        futures = self.client.map(func, items, pure=False)
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


def make_executor(name: str = "local", jobs: int | None = None, scheduler: str | None = None) -> Executor:
    """The executor called ``name`` (``local`` or ``dask``)."""
    if name == "local":
        return LocalExecutor(jobs)
    if name == "dask":
        return DaskExecutor(scheduler, jobs)
    raise ValueError(f"unknown executor {name!r} (one of {', '.join(EXECUTORS)})")
