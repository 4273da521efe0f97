"""The rebuild: ingest raw/, run the analysis stages, swap in a new warehouse.

:func:`rebuild` reads top-down: plan (what changed since the live warehouse) -> ingest (the files
to read, in worker processes) -> stages (run, or their cached outputs reused) -> assemble (every
table of the new database) -> publish (database and morning report swapped in, garbage collected).

Incremental (``pipeline/rebuild/state.py``): a run file whose content, applicable metadata and ingest
code are unchanged is not read again; a stage whose inputs are unchanged is not run again (its
cached outputs are reused). ``full=True`` rebuilds everything. Either way the result is the same.
When nothing changed at all, the live database is carried over (``pipeline/rebuild/noop.py``).

Atomic (``pipeline/rebuild/publish.py``): everything the new database refers to is written first
into immutable, content-addressed files (``samples/.../<run>-<key>.parquet``,
``stages/<stage>/<key>/``); then the database is built under a temporary name and swapped in with
one ``os.replace``. Files of the previous generation are kept (a reader may still be using them);
older ones are collected (``pipeline/rebuild/garbage.py``). The incremental state lives inside the
database, so it always matches the data it describes. ``kill -9`` at any point leaves the previous
warehouse as it was; the next rebuild removes the debris.

Exit codes (``pipeline/rebuild/options.py``, warehouse.md): 0 everything used; 1 warehouse built,
some inputs quarantined; 2 usage error; anything else: failed, the previous warehouse untouched
(3 failed, 4 another rebuild holds the lock). A report that cannot be rendered is a failure too (3).
"""
from __future__ import annotations

import errno
import logging
import os
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.progress import Progress
from pipeline.raw.plan import read_plan
from pipeline.raw.problems import Problem
from pipeline.raw.tree import RawTree, discover_runs
from pipeline.raw.walk import skip_reason
from pipeline.readers import READERS
from pipeline.rebuild.executors import Executor, fewer_collections, make_executor
from pipeline.rebuild.garbage import clean_debris, collect_garbage, split_kept
from pipeline.rebuild.history import append_log, compare_findings
from pipeline.rebuild.assemble import runs_frame, write_database
from pipeline.rebuild.ingest_tasks import deduplicate, held_in, ingest_incremental
from pipeline.rebuild.noop import InputsKey, confirm_same_bytes, nothing_changed, planned_records, rebuild_noop
from pipeline.rebuild.options import (EXIT_FAILED, EXIT_USAGE, RebuildError, RebuildOptions, RebuildRun, RebuildSummary,
                                      keep_superseded_h)
from pipeline.rebuild.publish import (check_mass_delete, clean_after_failure, crash_point, live_database,
                                      swap_in_new_database, warehouse_lock)
from pipeline.rebuild.stage_runner import StageInputs, StageResults, duration_text, reused_tables, run_stages_cached
from pipeline.rebuild.stage_store import FigureDrawer
from pipeline.rebuild.state import (FilePlan, FileRecord, PreviousState, load_previous, logbook_hash, plan_runs,
                                    side_records, superseded_files)
from pipeline.serve.report.publish import settle_report
from pipeline.versions import ingest_code_version
from pipeline.warehouse import DB_NAME

log = logging.getLogger("pneubench")

if TYPE_CHECKING:
    import pandas as pd

    from pipeline.ingest.result import IngestResult

# pandas, pyarrow, numpy and the analyses are imported by the functions that use them, not here:
# a no-op rebuild needs none of them (~0.5 s of a 10,000-run no-op's 2 s budget; issue 14).


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


def _import_for_stages() -> None:
    """What the stages, the database write and the report need: imported while the readers'
    workers work (they are forked first and import the readers themselves), and in any case
    before the stages' own pool is forked, so that it starts warm. matplotlib's figure and Agg
    canvas are not: the figure drawer imports them here when a figure is to be drawn, just
    before it forks its worker (:class:`~pipeline.rebuild.stage_store.FigureDrawer`); a change
    that draws none (a viscous or durability run's) does without them (issue 26)."""
    import pandas  # noqa: F401
    import pyarrow.dataset  # noqa: F401 (what the first pd.read_parquet of a process imports: ~15 ms)
    import pyarrow.pandas_compat  # noqa: F401

    import pipeline.serve.report.render  # noqa: F401 (and duckdb: kept off the start-up)
    from pipeline import stages

    stages.discover()


# -- the rebuild: plan -> ingest -> stages -> assemble -> publish -----------------------------------

def raw_folder_error(raw: Path) -> str | None:
    """Why ``raw`` is not a folder a rebuild can read, in one line; None when it is one.

    A symlink whose target is missing or loops back says so: "does not exist" sent a user looking
    for a folder that was there (a reviewer's `--raw loopA`, session 29)."""
    raw = Path(raw)
    if raw.is_dir():
        return None
    if raw.is_symlink():
        try:
            raw.resolve(strict=True)
        except RuntimeError:
            return f"raw folder {raw} is a symlink loop"
        except OSError as exc:
            return (f"raw folder {raw} is a symlink loop" if exc.errno == errno.ELOOP
                    else f"raw folder {raw} is a symlink to {os.readlink(raw)}, which does not exist")
        return f"raw folder {raw} is a symlink to something that is not a folder"
    if raw.exists():
        return f"raw folder {raw} is not a folder"
    return f"raw folder {raw} does not exist"

def rebuild(raw: str | Path, warehouse: str | Path, options: RebuildOptions | None = None,
            progress: Progress | None = None, **overrides) -> RebuildSummary:
    """Ingest ``raw``, run the analyses and swap in a new warehouse (incrementally).

    Parameters
    ----------
    raw : path-like
        The raw tree (never modified).
    warehouse : path-like
        The warehouse folder (created if missing).
    options : RebuildOptions, optional
        How the rebuild runs (default: all cores, incremental, local executor, with the report).
    progress : Progress, optional
        Where progress goes (silent by default).
    **overrides
        Fields of :class:`RebuildOptions` to set (``rebuild(raw, warehouse, jobs=1, full=True)``).

    Returns
    -------
    RebuildSummary

    Raises
    ------
    RebuildError
        When the rebuild fails (also when its report cannot be rendered); the previous
        warehouse and its report are left as they were.
    """
    options = replace(options or RebuildOptions(), **overrides)
    t0 = time.monotonic()
    started_at = datetime.now(timezone.utc)
    progress = progress or Progress()
    raw, warehouse = Path(raw), Path(warehouse)
    if (why := raw_folder_error(raw)) is not None:
        raise RebuildError(why, EXIT_USAGE)
    check_folders(raw, warehouse)
    options = replace(options, keep_superseded_h=keep_superseded_h(options.keep_superseded_h),
                      jobs=options.jobs or os.cpu_count() or 1, clock=options.clock or time.time)
    try:
        warehouse.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RebuildError(f"cannot create warehouse folder {warehouse}: {exc.strerror or exc}") from None
    generation = _generation()
    summary = RebuildSummary(raw=raw, warehouse=warehouse, generation=generation,
                             mode="full" if options.full else "incremental")
    with warehouse_lock(warehouse, options.lock_wait_s, progress.message) as lock:
        live = live_database(warehouse)
        run = RebuildRun(raw, warehouse, options, progress, generation, started_at, t0, summary, lock.fileno())
        try:
            with fewer_collections():
                return _rebuild_locked(run)
        except BaseException as exc:  # failed or interrupted (KeyboardInterrupt: re-raised as it is)
            if not (isinstance(exc, RebuildError) and exc.exit_code == EXIT_USAGE):  # refused: nothing written
                clean_after_failure(warehouse, live)
            if isinstance(exc, KeyboardInterrupt):  # for the caller's message: which warehouse is live
                exc.swapped = live_database(warehouse) != live
            if isinstance(exc, RebuildError) or not isinstance(exc, Exception):
                raise
            log.exception("rebuild failed")  # anything unexpected: exit 3, never 1 (= "quarantined")
            raise RebuildError(f"rebuild failed: {type(exc).__name__}: {exc}") from exc


def _generation() -> str:
    return datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ") + f"-{os.getpid()}"


def _rebuild_locked(run: RebuildRun) -> RebuildSummary:
    """The rebuild under its lock: the no-op when nothing changed, else every step."""
    plan = _plan(run)
    summary = run.summary
    if not run.options.full and nothing_changed(plan.prev, plan.plans, plan.side, plan.key, run.warehouse):
        summary.mode = "no-op"
        run.progress.message(f"rebuild {run.generation} (no-op): {len(plan.files)} run files under {run.raw}, "
                             "nothing changed since the last rebuild: its database is carried over")
        return rebuild_noop(run, plan.prev, plan.plans, plan.key, plan.side)
    n_quick = sum(p.status == "unchanged" for p in plan.plans)
    run.progress.message(f"rebuild {run.generation} ({summary.mode}): {len(plan.files)} run files under "
                         f"{run.raw}, {n_quick} unchanged at a glance")
    ex = _start_executor(run)
    with FigureDrawer(run.options.jobs if run.options.executor == "local" else 1, close_fds=(run.lock_fd,)) as drawer:
        with ex:
            ingested = _ingest(run, plan, ex)
            staged = _stages(run, plan, ingested, ex, drawer)
        crash_point("after_stages")
        tables, keep = _assemble(run, plan, ingested, staged, ex.name)
        check_raw_still_there(run, plan, ingested)
        # tables written by reused stages only: their keys are the live database's when the runs are (not
        # findings, which is compared with the previous rebuild's here)
        _publish(run, plan, tables, keep, drawer, reused_tables(staged, plan.prev) - {"findings"})
    summary.tables = {k: len(v) for k, v in tables.items()}
    if summary.report is not None:
        run.progress.message(f"report: {summary.report}")
    summary.seconds = time.monotonic() - run.t0
    summary.report_quarantine(run.progress)
    run.progress.message(f"rebuild: {summary.n_runs} runs ({summary.n_new} new, {summary.n_changed} changed, "
                         f"{summary.n_deleted} deleted, {summary.n_unchanged} unchanged), "
                         f"{len(summary.quarantine)} quarantined, stages run: {', '.join(staged.ran) or 'none'}, "
                         f"{summary.seconds:.1f} s")
    return summary


# -- plan ------------------------------------------------------------------------------------------
@dataclass
class _Plan:
    """What the rebuild found: the live warehouse's state, the raw tree and what changed in it."""

    prev: PreviousState
    tree: RawTree
    files: list[Path]          # run files
    ignored: list[Path]        # files that are not bench exports
    code: str                  # the ingest code version
    plans: list[FilePlan]      # per run file: new, changed, unchanged or to check
    side: list[FileRecord]     # manifests, rig.toml, logbooks
    side_changes: list[dict]   # their rows of rebuild_inputs
    key: str                   # :meth:`pipeline.rebuild.noop.InputsKey.key` of what the plan knows
    keyer: InputsKey           # the key's parts other than the files (taken when raw/ was walked)
    raw_id: tuple | None = None  # raw/'s (device, inode) when it was walked (:func:`_raw_identity`)


def _plan(run: RebuildRun) -> _Plan:
    """Clean up after a killed rebuild, read the live warehouse's state, walk raw/ and plan what to
    read; refuse a mass delete (exit 2) before anything is written."""
    warehouse, progress = run.warehouse, run.progress
    clean_debris(warehouse)
    settle_report(warehouse)  # a report staged by a rebuild killed after its database swap goes in
    prev = load_previous(warehouse)
    raw_id = _raw_identity(run.raw)
    tree = RawTree(run.raw)
    tree.scan_rigs()
    tree.scan_manifests()
    ignored: list[Path] = []
    files = discover_runs(tree, ignored)
    run.summary.n_files = len(files)
    if ignored:
        names = ", ".join(tree.rel(p) for p in ignored[:5]) + (", ..." if len(ignored) > 5 else "")
        progress.message(f"ignored {len(ignored)} file(s) that are not bench exports "
                         f"({', '.join(sorted(READERS))}): {names}")
    for rel, why in tree.listing().skipped:  # symlink aliases of files read under their own path
        progress.message(f"skipped {rel}: {why}")
    code = ingest_code_version()
    plans = plan_runs(tree, files, prev, code, warehouse, run.options.full)
    side, side_changes = side_records(tree, prev)
    if not run.options.allow_mass_delete:
        check_mass_delete(prev, plans)
    if not run.options.full:  # a file whose stat alone changed (touched, copied, moved): its bytes, hashed here
        confirm_same_bytes(tree, plans, run.options.jobs)
    keyer = InputsKey.of_tree(tree, code, ignored)
    return _Plan(prev, tree, files, ignored, code, plans, side, side_changes, keyer.key(planned_records(plans), side),
                 keyer, raw_id)


def _raw_identity(raw: Path) -> tuple | None:
    """raw/'s (device, inode), its symlink followed; None when it cannot be read."""
    try:
        st = os.stat(raw)
    except OSError:
        return None
    return (st.st_dev, st.st_ino)


def check_raw_still_there(run: RebuildRun, plan: _Plan, ingested: _Ingested) -> None:
    """Fail (exit 3: the spec's "failed, previous warehouse untouched", not a usage error; what the
    rebuild wrote so far is cleaned up) rather than publish what was read from a raw/ that went away
    while the rebuild ran.

    The mass-delete guard (:func:`~pipeline.rebuild.publish.check_mass_delete`) looks at raw/ when it
    is walked. A share unmounted, or a folder moved, after that turned every file still to be read,
    and the logbooks, into quarantine lines, and a gutted warehouse was published with exit 1 (a
    reviewer's night, session 29: 56 of 307 runs, the hoses' lives without their failures). So,
    before anything is written: raw/ must be the folder that was walked (the same device and inode:
    an unmount or a move changes them), and the files that could not be read for a reason that may
    pass (:attr:`IngestResult.transient`) are counted as gone by the same guard."""
    if _raw_identity(run.raw) != plan.raw_id:
        raise RebuildError(f"raw folder {run.raw} went away or was replaced while the rebuild read it (unmounted or "
                           "moved?): nothing is published, the previous warehouse and report are kept", EXIT_FAILED)
    if run.options.allow_mass_delete:
        return
    unread = {r.source_path for r in ingested.results if r.error is not None and r.transient}
    try:
        if unread:
            check_mass_delete(plan.prev, [p for p in plan.plans if p.rel not in unread])
    except RebuildError as exc:  # the guard's words; a failure now, not a refusal before anything was written
        raise RebuildError(str(exc), EXIT_FAILED) from None


# -- ingest ----------------------------------------------------------------------------------------
@dataclass
class _Ingested:
    """What the ingest gave: per run file its result and record; the runs, channels and problems."""

    results: list[IngestResult]
    records: list[FileRecord]
    runs: list[dict]
    channels: list[dict]
    problems: list[Problem]   # the raw tree's and the files' (stages' are added by _assemble)
    runs_df: pd.DataFrame


def _start_executor(run: RebuildRun) -> Executor:
    try:
        return make_executor(run.options.executor, run.options.jobs, run.options.scheduler,
                             close_in_workers=(run.lock_fd,))
    except Exception as exc:
        raise RebuildError(f"cannot start the {run.options.executor} executor: {type(exc).__name__}: {exc}") from exc


def _import_before_fork(plans: list[FilePlan]) -> None:
    """numpy, pyarrow and pandas, imported here before the readers' workers are forked when there is
    a file to read: the workers inherit them. pyarrow imports pandas on a worker's first array
    (``pa.array``, ``to_numpy``), so a worker forked cold imported pandas as well as this process
    did: twice the CPU, and on a one-export rebuild's critical path (issue 26)."""
    if any(p.status != "unchanged" for p in plans):
        import pandas  # noqa: F401 (numpy and pyarrow with it)
        import pyarrow.parquet  # noqa: F401


def _ingest(run: RebuildRun, plan: _Plan, ex: Executor) -> _Ingested:
    """Read the new and changed files (the stages' imports done meanwhile); deduplicate the runs."""
    _import_before_fork(plan.plans)
    results, records = ingest_incremental(run, plan.tree, plan.plans, ex, plan.code, while_waiting=_import_for_stages)
    ex.release_readers()  # their memory is not held through the stages and the database write
    crash_point("after_ingest")
    runs, channels, problems = deduplicate(results, held_in(plan.prev))
    return _Ingested(results, records, runs, channels, plan.tree.problems + problems, runs_frame(runs))


# -- stages ----------------------------------------------------------------------------------------
def _stages(run: RebuildRun, plan: _Plan, ingested: _Ingested, ex: Executor, drawer: FigureDrawer) -> StageResults:
    """Run the stages whose inputs changed, reuse the others' outputs (:func:`run_stages_cached`)."""
    runs, runs_df = ingested.runs, ingested.runs_df
    lab_plan = read_plan(plan.tree)  # with the tree the plan step walked: raw/ is not walked twice
    inputs = StageInputs(raw=plan.tree.root, warehouse=run.warehouse, runs=runs,
                         runs_frame=runs_df.assign(params=[r["params"] for r in runs]) if runs else runs_df,
                         previous=plan.prev, logbooks=logbook_hash(plan.side), full=run.options.full,
                         generation=run.generation, jobs=run.options.jobs, mapper=ex.mapper(run.progress),
                         plan=lab_plan)
    from pipeline.raw.logbook import walked  # (pandas: the incremental path has it imported by now)

    with walked(plan.tree.root, plan.tree.listing().side):  # the stages' logbooks: this walk's, read once
        staged = run_stages_cached(inputs, run.progress, drawer)
    staged.problems += lab_plan.problems  # given to the stages: its lines are ours to report
    return staged


# -- assemble --------------------------------------------------------------------------------------
def _assemble(run: RebuildRun, plan: _Plan, ingested: _Ingested, staged: StageResults,
              executor: str) -> tuple[dict[str, pd.DataFrame], set[str]]:
    """Every table of the new database, and the files it keeps (in use, or superseded and kept
    for the readers of earlier warehouses); fills in ``run.summary``."""
    import pandas as pd  # the incremental path: what the no-op does without

    summary, prev, runs_df = run.summary, plan.prev, ingested.runs_df
    problems = ingested.problems + staged.problems
    if staged.warnings and not runs_df.empty:
        runs_df["warnings"] = [list(w) + staged.warnings.get(rid, [])
                               for rid, w in zip(runs_df["run_id"], runs_df["warnings"])]
    stage_tables = dict(staged.tables)
    if "findings" in stage_tables:
        stage_tables["findings"] = compare_findings(stage_tables["findings"], prev.findings,
                                                    prev.generation is not None, prev.finding_changes, run.started_at)
    seen = {p.rel for p in plan.plans} | {r.source_path for r in plan.side}
    inputs = _inputs_table(plan.plans, plan.side_changes, prev, seen, problems, ingested.results)
    _count_inputs(summary, inputs)
    summary.n_runs = len(ingested.runs)
    summary.quarantine = problems
    summary.stages_run, summary.stages_reused = staged.ran, staged.reused
    history = append_log(prev.history, _log_row(run, plan, executor, ingested, staged))
    in_use = set(runs_df.get("samples_path", [])) | {r.folder for r in staged.records}
    kept, _expired = superseded_files(prev, in_use, run.options.clock(), run.options.keep_superseded_h)
    tables = {
        "runs": runs_df, "quarantine": _quarantine_frame(problems), "channels": _channels_frame(ingested.channels),
        "skipped_files": _skipped_files(plan.tree, plan.ignored),
        "figures": pd.DataFrame(staged.figures, columns=["stage", "name", "path", "caption"]),
        **stage_tables,
        "rebuild_log": history, "rebuild_inputs": inputs,
        "ingest_state": pd.DataFrame([r.as_row() for r in ingested.records + plan.side]),
        "stage_cache": pd.DataFrame([r.as_row() for r in staged.records]),
        "superseded_files": _superseded_frame(kept),
    }
    return tables, in_use | set(kept)


def _channels_frame(channels: list[dict]) -> pd.DataFrame:
    """``channels`` rows as a frame, its columns in name order whatever the order of the rows' keys.

    A run read tonight has its keys in the ingest's order, a run taken from its state record in
    JSON's sorted order; the frame took the order of its first row, so its content key
    (``table_keys``) changed with where that row came from, though its rows did not. Issue 26: the
    first change after a full build (every row read that night) wrote ``channels`` again and so
    re-created every ``samples_<kind>`` view and re-drew every run page (~3 CPU-s at 10,000 runs).
    The database takes the columns by name: the table is the same either way."""
    import pandas as pd

    df = pd.DataFrame(channels)
    return df[sorted(df.columns, key=str)] if len(df.columns) else df


def _inputs_table(plans: list[FilePlan], side_changes: list[dict], prev: PreviousState, seen: set[str],
                  problems: list[Problem], results: list[IngestResult]) -> pd.DataFrame:
    """``rebuild_inputs``: every input file, its status (new, changed, unchanged, deleted) and error."""
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


def _count_inputs(summary: RebuildSummary, inputs: pd.DataFrame) -> None:
    """The summary's counts of run files by status."""
    runs = inputs["role"] == "run"
    summary.n_new = int(((inputs["status"] == "new") & runs).sum())
    summary.n_changed = int(((inputs["status"] == "changed") & runs).sum())
    summary.n_deleted = int(((inputs["status"] == "deleted") & runs).sum())
    summary.n_unchanged = int(((inputs["status"] == "unchanged") & runs).sum())


def _log_row(run: RebuildRun, plan: _Plan, executor: str, ingested: _Ingested, staged: StageResults) -> dict:
    """This rebuild's row of ``rebuild_log`` (its ``seq`` is given by :func:`append_log`)."""
    s = run.summary
    return {"generation": run.generation, "started_at": run.started_at, "finished_at": datetime.now(timezone.utc),
            "duration_s": time.monotonic() - run.t0, "mode": s.mode, "executor": executor,
            "n_files": len(plan.files), "n_runs": len(ingested.runs), "n_new": s.n_new, "n_changed": s.n_changed,
            "n_deleted": s.n_deleted, "n_unchanged": s.n_unchanged, "n_quarantined": len(s.quarantine),
            "stages_run": staged.ran, "stages_reused": staged.reused, "exit_code": s.exit_code,
            "inputs_key": plan.keyer.key(ingested.records, plan.side)}


def _quarantine_frame(problems: list[Problem]) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame([{"source_path": p.source_path, "error": p.error, "line": p.line,
                          "campaign": p.source_path.split("/")[0] if "/" in p.source_path else None,
                          "stage": p.stage} for p in problems],
                        columns=["source_path", "error", "line", "campaign", "stage"])


def _skipped_files(tree: RawTree, ignored: list[Path]) -> pd.DataFrame:
    """``skipped_files``: files that are not bench exports, and symlink aliases of files read."""
    import pandas as pd

    return pd.DataFrame(
        [{"source_path": tree.rel(p), "campaign": tree.campaign(p), "reason": skip_reason(p)} for p in ignored]
        + [{"source_path": rel, "campaign": rel.split("/")[0] if "/" in rel else None, "reason": why}
           for rel, why in tree.listing().skipped], columns=["source_path", "campaign", "reason"])


def _superseded_frame(kept: dict[str, float]) -> pd.DataFrame:
    """``superseded_files``: path and when it was superseded [s since epoch -> UTC time]."""
    import pandas as pd

    kept_paths = sorted(kept)
    return pd.DataFrame({
        "path": pd.Series(kept_paths, dtype="string"),
        # whole microseconds, as DuckDB stores them: a time carried from rebuild to rebuild never drifts
        "superseded_at": pd.to_datetime(pd.Series([round(kept[p] * 1e6) for p in kept_paths], dtype="int64"),
                                        unit="us", utc=True)})


# -- publish ---------------------------------------------------------------------------------------
def _publish(run: RebuildRun, plan: _Plan, tables: dict[str, pd.DataFrame], keep: set[str],
             drawer: FigureDrawer, unchanged: set[str] = frozenset()) -> None:
    """Write the database (the figures drawn beside it put in place), swap it and its report in,
    and collect what neither warehouse uses nor keeps, before and after (``unchanged``: as for
    :func:`~pipeline.rebuild.assemble.write_database`)."""
    warehouse, progress, prev = run.warehouse, run.progress, plan.prev
    progress.message(f"warehouse: writing {len(tables)} tables")
    # the live database copied and only the tables whose rows changed written again, else built whole
    live = None if run.options.full else warehouse / DB_NAME

    def write(tmp_db):
        progress.message(write_database(tmp_db, warehouse, tables, tables["runs"], live, unchanged))
        waited = time.monotonic()
        n_aside = drawer.finish()  # the figures drawn beside the database, their stage folders put in place
        if n_aside:
            progress.message(f"figures: {n_aside} drawn in a worker beside the stages and the database "
                             f"(waited {duration_text(time.monotonic() - waited)} for them)")

    from pipeline.serve.report.pages import BandsAhead  # imported with the report's renderer while the files were read

    with BandsAhead(warehouse) as ahead:
        if run.options.report:  # the new runs' channels for their pages, read beside the database write
            ahead.read(_new_channels(tables, prev.samples))
        # before the new database is written, what neither warehouse uses nor keeps goes (files past
        # their retention, what a killed night left): a nearly full disk gets that room back first
        collect_garbage(warehouse, *split_kept(keep | prev.samples | prev.stage_folders))
        run.summary.report = swap_in_new_database(warehouse, write, run.options.report,  # --full: every figure drawn
                                                  run_pages="all" if run.options.full else "update", ahead=ahead,
                                                  keys_checked=True)  # write_database's table_keys: checked
    # files the new warehouse uses, and those of earlier ones still within their retention
    # (a reader that opened an earlier warehouse keeps reading its samples)
    collect_garbage(warehouse, *split_kept(keep))


def _new_channels(tables: dict[str, pd.DataFrame], live: set[str]) -> list[tuple[str, list[str], int]]:
    """(samples path, channels as its run page draws them, rows) of every run whose samples file is
    not one the live warehouse publishes (``live``), in the run pages' order: those pages are drawn
    anew, and their channels with them (:class:`~pipeline.serve.report.pages.BandsAhead`)."""
    runs, channels = tables["runs"], tables["channels"]
    if runs.empty:
        return []
    new = sorted((rid, path, n) for rid, path, n in zip(runs["run_id"], runs["samples_path"], runs["n_samples"])
                 if isinstance(path, str) and path and path not in live)
    columns: dict[str, list[str]] = {}
    if new and not channels.empty:  # the new runs' channels only (issue 26: not 40,000 rows sorted for one run)
        sub = channels[channels["run_id"].isin(sorted({rid for rid, _path, _n in new}))]
        for rid, col in sorted(zip(sub["run_id"], sub["column"])):
            if col not in ("t_s", "run_id"):
                columns.setdefault(rid, []).append(col)
    return [(path, columns.get(rid, []), int(n) if n is not None and n == n else 0)  # NaN: NULL, read as 0
            for rid, path, n in new]
