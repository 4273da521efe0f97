"""The rebuild's terms: what it is asked to do (:class:`RebuildOptions`), one rebuild under way
(:class:`RebuildRun`), and what it answers (:class:`RebuildSummary`, or :class:`RebuildError`
with one of the exit codes).

Exit codes (warehouse.md): 0 everything used; 1 warehouse built, some inputs quarantined;
2 usage error; anything else: failed, the previous warehouse untouched (3 failed, 4 another
rebuild holds the lock).
"""
from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from pipeline.progress import Progress
from pipeline.raw.problems import Problem
from pipeline.rebuild.state import KEEP_SUPERSEDED_H

EXIT_OK, EXIT_QUARANTINED, EXIT_USAGE, EXIT_FAILED, EXIT_LOCKED = 0, 1, 2, 3, 4


class RebuildError(Exception):
    """The rebuild failed; the previous warehouse is untouched. ``exit_code`` says how."""

    def __init__(self, message: str, exit_code: int = EXIT_FAILED):
        super().__init__(message)
        self.exit_code = exit_code


@dataclass(frozen=True)
class RebuildOptions:
    """How a rebuild runs: everything :func:`pipeline.rebuild.flow.rebuild` takes besides the two
    folders and the progress (built once, by the command line or the caller).

    Attributes
    ----------
    jobs : int, optional
        Worker processes; default all cores.
    full : bool
        Re-ingest every file and re-run every stage, ignoring the incremental state.
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
        :data:`pipeline.rebuild.publish.MASS_DELETE_SHARE` of them and at least
        :data:`pipeline.rebuild.publish.MASS_DELETE_MIN_RUNS` (their raw files gone). Without it
        such a rebuild is refused before anything is written (:class:`RebuildError`, exit 2): an
        empty or unmounted raw/ must not empty the warehouse.
    """

    jobs: int | None = None
    full: bool = False
    lock_wait_s: float = 0.0
    executor: str = "local"
    scheduler: str | None = None
    report: bool = True
    keep_superseded_h: float | None = None
    clock: Callable[[], float] | None = None
    allow_mass_delete: bool = False


def keep_superseded_h(value: float | None) -> float:
    """The retention of superseded files [h]: ``value``, else ``$PNEUBENCH_KEEP_SUPERSEDED_H``, else 24."""
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

    def report_quarantine(self, progress: Progress) -> None:
        """One progress line per quarantined input: ``quarantined <path>[:<line>]: <reason>``."""
        for p in self.quarantine:
            where = f"{p.source_path}:{p.line}" if p.line else p.source_path
            progress.message(f"quarantined {where}: {p.error}")


@dataclass(frozen=True)
class RebuildRun:
    """One rebuild under way: what every step of :func:`pipeline.rebuild.flow.rebuild` shares.

    Attributes
    ----------
    raw, warehouse : Path
        The raw tree and the warehouse folder.
    options : RebuildOptions
        Resolved: ``jobs`` a number, ``keep_superseded_h`` [h] a number, ``clock`` a function.
    progress : Progress
        Where progress goes.
    generation : str
        The new warehouse's generation (``<UTC time>-<pid>``).
    started_at : datetime
        When the rebuild started (UTC).
    t0 : float
        ``time.monotonic()`` when the rebuild started [s].
    summary : RebuildSummary
        What the rebuild did, filled in as it goes.
    lock_fd : int
        The rebuild lock's file descriptor (closed in every worker process).
    """

    raw: Path
    warehouse: Path
    options: RebuildOptions
    progress: Progress
    generation: str
    started_at: datetime
    t0: float
    summary: RebuildSummary
    lock_fd: int = -1
