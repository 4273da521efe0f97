"""Publishing a new warehouse safely: the rebuild lock, the refusal of a mass delete, the swap
of the new database (and its morning report) for the live one, and the clean-up after a failure.

Everything the new database refers to is written first into immutable, content-addressed files;
then the database is built under a temporary name and swapped in with one ``os.replace``. A
reader opening ``pneubench.duckdb`` sees the previous complete warehouse or the new one. The
morning report is rendered from the new database before the swap, so a report that cannot be
rendered is a failure too (3), with the previous warehouse and its report kept: the two always
agree. ``kill -9`` at any point leaves the previous warehouse as it was; the next rebuild
removes the debris (:func:`pipeline.rebuild.garbage.clean_debris`).
"""
from __future__ import annotations

import fcntl
import logging
import os
import signal
import socket
import time
from collections.abc import Callable
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

from pipeline.rebuild.garbage import clean_debris, collect_garbage, split_kept
from pipeline.rebuild.options import EXIT_LOCKED, EXIT_USAGE, RebuildError
from pipeline.rebuild.state import FilePlan, PreviousState, load_previous
from pipeline.serve.report.publish import publish_report, remove_report_folder
from pipeline.versions import project_code_version
from pipeline.rebuild.assemble import swap_in
from pipeline.warehouse import DB_NAME

log = logging.getLogger("pneubench")

#: Test hook: ``PNEUBENCH_CRASH_AT=<point>`` kills the rebuild with SIGKILL at that point.
CRASH_POINTS = ("after_ingest", "after_stages", "before_swap", "between_swaps", "after_swap")

#: A rebuild that would drop more than this share of the live warehouse's runs (their raw files
#: gone: a share not mounted, a raw/ moved) is refused (exit 2) unless it is allowed...
MASS_DELETE_SHARE = 0.5
#: ... when it drops at least this many runs; one that drops every run is refused whatever their number.
MASS_DELETE_MIN_RUNS = 5


def crash_point(name: str, sig: int = signal.SIGKILL) -> None:
    """Test-only: die by ``sig`` here when ``PNEUBENCH_CRASH_AT`` names this point
    (``PNEUBENCH_CRASH_SIGNAL=SIGSTOP``: stop instead, as a reader stuck in a loop would)."""
    if os.environ.get("PNEUBENCH_CRASH_AT") == name:
        other = os.environ.get("PNEUBENCH_CRASH_SIGNAL")
        os.kill(os.getpid(), getattr(signal, other) if other in ("SIGSTOP", "SIGSEGV", "SIGKILL") else sig)


@contextmanager
def warehouse_lock(warehouse: Path, wait_s: float = 0.0, on_wait=None):
    """Hold the warehouse's rebuild lock; a second rebuild waits ``wait_s`` [s] then gives up.

    ``flock`` on ``.rebuild.lock``: the kernel releases it when the holder dies, even by
    ``kill -9`` (worker processes are started by a fork server and do not inherit it). The
    holder writes ``<pid> on <host> since <time>`` into it; ``on_wait(text)`` is called once,
    naming the holder, when a rebuild starts waiting for it.
    """
    lock_path = Path(warehouse) / ".rebuild.lock"
    try:
        fh = open(lock_path, "a+")
    except OSError as exc:
        raise RebuildError(f"cannot open the rebuild lock {lock_path}: {exc.strerror or exc}") from None
    _wait_for_lock(fh, warehouse, wait_s, on_wait)
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


def _wait_for_lock(fh, warehouse: Path, wait_s: float, on_wait) -> None:
    """Take the lock on ``fh``, trying every 0.1 s for ``wait_s`` [s]; else close it and raise (exit 4)."""
    deadline = time.monotonic() + max(0.0, wait_s)
    while True:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
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


def swap_in_new_database(warehouse: Path, write: Callable[[Path], None], report: bool,
                         run_pages: str = "update", ahead=None, keys_checked: bool = False) -> Path | None:
    """Write the new database under a temporary name (``write(tmp_db)``), render the morning
    report from it, swap the database in, then publish the report; returns the report's path.

    Any failure before the swap removes the temporary database and staged page and raises
    :class:`RebuildError`: the previous warehouse and its report are kept (the two always agree).
    ``run_pages`` and ``ahead`` (the run pages' channel bands read while ``write`` runs) as for
    :func:`pipeline.serve.report.render_report`; ``keys_checked``: ``write`` left every ``table_keys``
    row matching its table as written (:func:`pipeline.rebuild.assemble.write_database` does), so the
    report takes them without summing every table again.
    """
    tmp_db = warehouse / f".{DB_NAME}.tmp-{os.getpid()}"
    page = None  # the morning report (index and run pages), a folder beside the live one: from the new database
    try:
        write(tmp_db)
        if report:  # before the swap: a failure keeps the previous warehouse and its report
            try:
                from pipeline.serve.report.render import FromRebuild, stage_report  # (and duckdb): off the start-up

                # the rebuild's one hash of the project's code keys the report's parts cache
                page = stage_report(warehouse, database=tmp_db, run_pages=run_pages,
                                    rebuild=FromRebuild(project_code_version(), ahead, keys_checked=keys_checked))
            except Exception as exc:
                log.exception("report failed")
                raise RebuildError(f"the morning report could not be written: {type(exc).__name__}: "
                                   f"{' '.join(str(exc).split())}; the previous warehouse and report are kept") from exc
        crash_point("before_swap")
        swap_in(tmp_db, warehouse / DB_NAME)
    except Exception as exc:
        tmp_db.unlink(missing_ok=True)
        Path(f"{tmp_db}.wal").unlink(missing_ok=True)
        if page is not None:
            remove_report_folder(page)
        if isinstance(exc, RebuildError):
            raise
        raise RebuildError(f"could not write the warehouse: {type(exc).__name__}: {exc}") from exc
    published = None
    crash_point("between_swaps")  # killed here: the next rebuild or report publishes the staged report
    if page is not None:  # straight after the swap: the report follows the warehouse it describes
        published = publish_report(warehouse, page)
    crash_point("after_swap")
    return published


def live_database(warehouse: Path) -> tuple[int, int, int] | None:
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
    ``live``: :func:`live_database` when the rebuild started; when it differs now the new
    warehouse is in place and only temporary files go. Called under the rebuild lock, after the
    worker processes are gone; never raises (the rebuild's own error is the one reported)."""
    try:
        clean_debris(warehouse)
        if live_database(warehouse) != live:
            return
        prev = load_previous(warehouse)
        if live is not None and prev.generation is None:  # the live database could not be read: keep all
            return
        collect_garbage(warehouse, *split_kept(prev.samples | prev.stage_folders | set(prev.superseded)))
    except Exception:  # pragma: no cover - the clean-up of a failure must not hide the failure
        log.exception("clean-up after a failed rebuild failed")
