"""The no-op fast path: a rebuild whose inputs and code are all as the last rebuild saw them
carries the live database over instead of building it again.

:class:`InputsKey` fingerprints everything a rebuild reads; :func:`nothing_changed` says whether
the live warehouse is exactly what this rebuild would write; :func:`rebuild_noop` then copies the
database and brings only the rebuild's bookkeeping up to date, with the same swap and the same
crash safety as a full rebuild. The path imports neither pandas nor pyarrow (issue 14).

A raw tree copied or moved (a backup restored, a new disk, ``cp -r``) gives every file a new
inode, and a new mtime unless the copy kept it: no file is unchanged at a glance. Such files are
hashed here, in this process (:func:`confirm_same_bytes`); a file with its recorded bytes is
unchanged, its record takes the new stat, and when nothing else changed the rebuild is still a
no-op (issue 26: a copied warehouse cost an incremental rebuild). The key hashes each file's
content (its recorded SHA-256) rather than its stat, so a moved tree has the key it had.
"""
from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.raw.problems import Problem
from pipeline.raw.rawfile import open_raw
from pipeline.raw.tree import RawTree
from pipeline.rebuild import ingest_tasks
from pipeline.rebuild.garbage import collect_garbage, split_kept
from pipeline.rebuild.history import append_log_in_database, carry_findings
from pipeline.rebuild.options import RebuildRun, RebuildSummary
from pipeline.rebuild.publish import swap_in_new_database
from pipeline.rebuild.stage_store import own_stage_folder
from pipeline.rebuild.state import RACY_S, FilePlan, FileRecord, PreviousState, superseded_files
from pipeline.versions import project_code_version
from pipeline.warehouse import DB_NAME, KEYS_TABLE

if TYPE_CHECKING:  # imported where the database is carried over: a fresh rebuild imports it while files are read
    import duckdb


@dataclass(frozen=True)
class InputsKey:
    """The fingerprint of everything a rebuild reads (:meth:`key`), its parts other than the files
    taken when raw/ is walked: the version of all the project's code, the files ignored or skipped
    and the raw tree's own problems (links, manifests, rig.toml; taken before the plan's lines are
    added). Equal keys with no file in doubt (:func:`nothing_changed`) mean the rebuild would write
    the same database again; the report keeps its parts under it (``pipeline.serve.report.cache``)."""

    code: tuple[str, str]
    ignored: tuple[str, ...]
    skipped: tuple[tuple, ...]
    problems: tuple[tuple, ...]

    @classmethod
    def of_tree(cls, tree: RawTree, code: str, ignored: list[Path]) -> InputsKey:
        return cls((code, project_code_version()), tuple(tree.rel(p) for p in ignored),
                   tuple(tuple(x) for x in tree.listing().skipped),
                   tuple((p.source_path, p.error, p.line, p.stage) for p in tree.problems))

    def key(self, runs: list[FileRecord], side: list[FileRecord]) -> str:
        """The key [32 hex digits] of the run files' and side files' records: each file's path, size,
        content (its SHA-256; its stat when it has none: not read, or in doubt) and the metadata that
        applies to a run. A file with the same bytes under a new stat (touched, copied) keeps the key."""
        blob = {
            "code": list(self.code),
            "runs": [[r.source_path, r.size_bytes, _content(r), r.meta_hash] for r in runs],
            "side": [[r.source_path, r.role, r.size_bytes, _content(r)] for r in side],
            "ignored": list(self.ignored),
            "skipped": [list(x) for x in self.skipped],
            "problems": [list(p) for p in self.problems],
        }
        return hashlib.sha256(json.dumps(blob, sort_keys=True, default=str).encode()).hexdigest()[:32]


def _content(r: FileRecord):
    return r.source_sha256 if r.source_sha256 is not None else ["stat", r.mtime_ns, r.inode]


def planned_records(plans: list[FilePlan]) -> list[FileRecord]:
    """The run files' records as the plan knows them: an unchanged file's (its recorded content), any
    other file's stat alone (its content not read yet)."""
    return [p.previous if p.status == "unchanged" else FileRecord(p.rel, "run", *p.stat, None, p.meta_hash)
            for p in plans]


def confirm_same_bytes(tree: RawTree, plans: list[FilePlan], jobs: int = 1, now: float | None = None) -> int:
    """Hash, here, the run files whose stat alone changed (touched, copied, moved: same size, same
    metadata and code, a recorded hash); each with its recorded bytes becomes ``unchanged``, its
    record taking the new stat as the ingest would record it. Returns how many did.

    The same check as the ingest's worker (:func:`pipeline.rebuild.ingest_tasks.ingest_task`): the
    file opened once from raw/ (no symlink out, the inode the scan saw), hashed through that
    descriptor, its stat the same after as before, every byte hashed. A file that fails any of it
    is left to the ingest (read, or hashed again). Threads: ``hashlib`` releases the GIL."""
    todo = [p for p in plans if p.status == "check" and p.reason == "content" and p.previous is not None
            and p.previous.source_sha256 is not None and p.previous.size_bytes == p.stat[0]]
    if not todo:
        return 0
    with ThreadPoolExecutor(max(1, min(jobs, len(todo)))) as pool:
        same = list(pool.map(lambda p: _same_bytes(tree, p), todo))
    now = time.time() if now is None else now
    for p, ok in zip(todo, same):
        if ok:
            p.status, p.reason, p.previous = "unchanged", "", restat(p.previous, p.stat, now)
    return sum(same)


def _same_bytes(tree: RawTree, p: FilePlan) -> bool:
    """Whether a run file still holds the bytes its record hashed (:func:`confirm_same_bytes`)."""
    try:
        with open_raw(tree.root, p.path, inode=p.stat[2]) as opened:
            before = _stat(opened.source)
            counted: list[int] = []
            sha = ingest_tasks.sha256_file(opened.source, counted=counted)
            return (sha == p.previous.source_sha256 and before is not None and before == p.stat
                    and _stat(p.path) == before and counted == [before[0]])
    except OSError:
        return False


def _stat(path) -> tuple[int, int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, st.st_ino


def restat(record: FileRecord, stat: tuple[int, int, int], now: float) -> FileRecord:
    """``record`` under a new ``(size, mtime_ns, inode)``, its content the same (its ``result`` not
    decoded); a racy mtime kept as -1, as :func:`pipeline.rebuild.state.record_for` keeps it."""
    new = copy.copy(record)
    new.size_bytes, new.mtime_ns, new.inode = stat
    if now - stat[1] / 1e9 < RACY_S:
        new.mtime_ns = -1
    return new


def nothing_changed(prev: PreviousState, plans: list[FilePlan], side: list[FileRecord], key: str,
                    warehouse: Path) -> bool:
    """Whether the live warehouse is exactly what this rebuild would write, bookkeeping aside.

    True when the previous rebuild saw the same inputs (same :meth:`InputsKey.key`), every run file
    is unchanged at a glance (same stat, metadata and ingest code, samples file present, no
    racy mtime; or its bytes hashed again by :func:`confirm_same_bytes`), every side file has
    its recorded bytes, and every stage's cached output is there and was cacheable. Anything in
    doubt gives False: the full incremental path.
    """
    if prev.generation is None or prev.inputs_key != key or not (warehouse / DB_NAME).is_file():
        return False
    if any(p.status != "unchanged" for p in plans) or len(prev.files) != len(plans) + len(side):
        return False
    for r in side:  # same bytes: the same stat (not racy), or hashed again tonight with the recorded hash
        old = prev.files.get(r.source_path)
        if old is None or old.source_sha256 != r.source_sha256 or (r.source_sha256 is None and (
                old.mtime_ns < 0 or _stat_of(old) != _stat_of(r))):
            return False
    if not prev.stages:
        return False
    return all(s.input_key != "uncacheable" and (folder := own_stage_folder(warehouse, s.folder, s.stage)) is not None
               and (folder / "output.json").is_file() for s in prev.stages.values())


def _stat_of(r: FileRecord) -> tuple[int, int, int]:
    return r.size_bytes, r.mtime_ns, r.inode


def restated(prev: PreviousState, plans: list[FilePlan], side: list[FileRecord]) -> list[FileRecord]:
    """The records of files whose stat changed with their bytes the same (touched, copied, moved):
    what the no-op writes into ``ingest_state`` so that the next night sees them unchanged at a glance."""
    runs = [p.previous for p in plans if p.previous is not prev.files.get(p.rel)]
    return runs + [r for r in side if (old := prev.files.get(r.source_path)) is None
                   or (*_stat_of(old), old.source_sha256) != (*_stat_of(r), r.source_sha256)]


def rebuild_noop(run: RebuildRun, prev: PreviousState, plans: list[FilePlan], key: str,
                 side: list[FileRecord] = ()) -> RebuildSummary:
    """Nothing changed: the previous database is copied and only the rebuild's bookkeeping is
    brought up to date, as the incremental path would have written it (``rebuild_log`` gets this
    rebuild's row; ``rebuild_inputs`` says every input is unchanged; ``findings`` carry their
    last change; ``superseded_files`` drops what has expired). The report is rendered anew (it
    states the time and the last rebuild) without redrawing run pages whose inputs are the
    same. Files whose bytes were confirmed under a new stat (``side``: the side files' records
    tonight) get their new stat in ``ingest_state``. Same swap, same crash safety as a full rebuild."""
    warehouse, summary = run.warehouse, run.summary
    in_use = prev.samples | prev.stage_folders
    kept, expired = superseded_files(prev, in_use, run.options.clock(), run.options.keep_superseded_h)

    def carry_over(tmp_db: Path) -> None:
        import duckdb

        shutil.copyfile(warehouse / DB_NAME, tmp_db)
        con = duckdb.connect(str(tmp_db))
        try:
            _bring_up_to_date(con, run, plans, key, expired)
            _record_stats(con, restated(prev, plans, list(side)))
            forget_keys(con, NOOP_WRITES)
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


#: Tables the no-op updates in its copy: their content keys (``table_keys``) no longer describe
#: them, so the next rebuild writes them again.
NOOP_WRITES = ("rebuild_log", "rebuild_inputs", "findings", "superseded_files", "ingest_state")


def forget_keys(con: duckdb.DuckDBPyConnection, tables: tuple[str, ...]) -> None:
    """Remove the content keys of ``tables`` from ``table_keys`` (a database from before it: nothing to do)."""
    if con.execute(f"SELECT count(*) FROM duckdb_tables() WHERE table_name = '{KEYS_TABLE}'").fetchone()[0]:
        con.execute(f"DELETE FROM {KEYS_TABLE} WHERE list_contains($1, table_name)", [list(tables)])


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


def _record_stats(con: duckdb.DuckDBPyConnection, records: list[FileRecord], chunk: int = 500) -> None:
    """Write the stat (and hash) of ``records`` into the carried-over ``ingest_state``, as the
    incremental path would have recorded them (one statement per ``chunk`` files)."""
    for i in range(0, len(records), chunk):
        part = records[i:i + chunk]
        values = ", ".join(["(?, ?, ?, ?, ?)"] * len(part))
        params = [v for r in part for v in (r.source_path, r.size_bytes, r.mtime_ns, r.inode, r.source_sha256)]
        con.execute("UPDATE ingest_state SET size_bytes = v.size_bytes, mtime_ns = v.mtime_ns, inode = v.inode, "
                    f"source_sha256 = v.sha FROM (VALUES {values}) AS v(path, size_bytes, mtime_ns, inode, sha) "
                    "WHERE ingest_state.source_path = v.path", params)
