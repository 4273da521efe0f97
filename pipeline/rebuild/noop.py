"""The no-op fast path: a rebuild whose inputs and code are all as the last rebuild saw them
carries the live database over instead of building it again.

:func:`inputs_key` fingerprints everything a rebuild reads; :func:`nothing_changed` says whether
the live warehouse is exactly what this rebuild would write; :func:`rebuild_noop` then copies the
database and brings only the rebuild's bookkeeping up to date, with the same swap and the same
crash safety as a full rebuild. The path imports neither pandas nor pyarrow (issue 14).
"""
from __future__ import annotations

import hashlib
import json
import shutil
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.raw.problems import Problem
from pipeline.raw.tree import RawTree
from pipeline.rebuild.garbage import collect_garbage, split_kept
from pipeline.rebuild.history import append_log_in_database, carry_findings
from pipeline.rebuild.options import RebuildRun, RebuildSummary
from pipeline.rebuild.publish import swap_in_new_database
from pipeline.rebuild.state import FilePlan, FileRecord, PreviousState, superseded_files
from pipeline.versions import project_code_version
from pipeline.warehouse import DB_NAME

if TYPE_CHECKING:  # imported where the database is carried over: a fresh rebuild imports it while files are read
    import duckdb


def inputs_key(tree: RawTree, code: str, plans: list[FilePlan], side: list[FileRecord], ignored: list[Path]) -> str:
    """Fingerprint of everything a rebuild reads: every run file's path, ``(size, mtime, inode)``
    and applicable metadata, every side file's path and stat, the files ignored or skipped, the
    raw tree's own problems (links, manifests, rig.toml) and the version of all the project's
    code. Equal keys with no file in doubt (:func:`nothing_changed`) mean the rebuild would write
    the same database again."""
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


def rebuild_noop(run: RebuildRun, prev: PreviousState, plans: list[FilePlan], key: str) -> RebuildSummary:
    """Nothing changed: the previous database is copied and only the rebuild's bookkeeping is
    brought up to date, as the incremental path would have written it (``rebuild_log`` gets this
    rebuild's row; ``rebuild_inputs`` says every input is unchanged; ``findings`` carry their
    last change; ``superseded_files`` drops what has expired). The report is rendered anew (it
    states the time and the last rebuild) without redrawing run pages whose inputs are the
    same. Same swap, same crash safety as a full rebuild."""
    warehouse, summary = run.warehouse, run.summary
    in_use = prev.samples | prev.stage_folders
    kept, expired = superseded_files(prev, in_use, run.options.clock(), run.options.keep_superseded_h)

    def carry_over(tmp_db: Path) -> None:
        import duckdb

        shutil.copyfile(warehouse / DB_NAME, tmp_db)
        con = duckdb.connect(str(tmp_db))
        try:
            _bring_up_to_date(con, run, plans, key, expired)
        finally:
            con.close()

    collect_garbage(warehouse, *split_kept(in_use | set(kept)))  # before the copy: room on a nearly full disk
    summary.report = swap_in_new_database(warehouse, carry_over, run.options.report, run_pages="missing")
    keep = in_use | set(kept)
    collect_garbage(warehouse, *split_kept(keep))
    summary.seconds = time.monotonic() - run.t0
    if summary.report is not None:
        run.progress.message(f"report: {summary.report}")
    summary.report_quarantine(run.progress)
    run.progress.message(f"rebuild: {summary.n_runs} runs (0 new, 0 changed, 0 deleted, {summary.n_unchanged} "
                         f"unchanged: a no-op), {len(summary.quarantine)} quarantined, stages run: none, "
                         f"{summary.seconds:.1f} s")
    return summary


def _bring_up_to_date(con: duckdb.DuckDBPyConnection, run: RebuildRun, plans: list[FilePlan], key: str,
                      expired: set[str]) -> None:
    """The carried-over database's bookkeeping, as this rebuild would have written it; fills in
    ``run.summary``."""
    summary = run.summary
    con.execute("SET TimeZone = 'UTC'")
    con.execute("DELETE FROM rebuild_inputs WHERE status = 'deleted'")
    con.execute("UPDATE rebuild_inputs SET status = 'unchanged', reason = NULL WHERE status <> 'unchanged'")
    carry_findings(con, run.started_at)
    if expired:
        con.executemany("DELETE FROM superseded_files WHERE path = ?", [[p] for p in sorted(expired)])
    problems = [Problem(s, e, ln, st) for s, e, ln, st in con.execute(
        "SELECT source_path, error, line, stage FROM quarantine").fetchall()]
    n_runs = con.execute("SELECT count(*) FROM runs").fetchone()[0]
    stages = [r[0] for r in con.execute("SELECT stage FROM stage_cache").fetchall()]
    summary.n_files = len(plans)
    summary.n_runs, summary.n_unchanged, summary.quarantine = n_runs, len(plans), problems
    summary.stages_reused = stages
    append_log_in_database(con, {
        "generation": run.generation, "started_at": run.started_at, "finished_at": datetime.now(timezone.utc),
        "duration_s": time.monotonic() - run.t0, "mode": "no-op", "executor": run.options.executor,
        "n_files": len(plans), "n_runs": n_runs, "n_new": 0, "n_changed": 0, "n_deleted": 0,
        "n_unchanged": len(plans), "n_quarantined": len(problems), "stages_run": [],
        "stages_reused": stages, "exit_code": summary.exit_code, "inputs_key": key})
    summary.tables = {t: con.execute(f'SELECT count(*) FROM "{t}"').fetchone()[0] for (t,) in con.execute(
        "SELECT table_name FROM duckdb_tables() WHERE schema_name = 'main' ORDER BY table_name").fetchall()}
    con.execute("CHECKPOINT")
