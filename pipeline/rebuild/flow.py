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

import json
import logging
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.progress import Progress
from pipeline.raw.problems import Problem
from pipeline.raw.tree import RawTree, discover_runs
from pipeline.raw.walk import skip_reason
from pipeline.readers import READERS
from pipeline.rebuild.executors import Executor, default_jobs, forked_pool, make_executor
from pipeline.rebuild.executors import _kill_workers  # stop the figure worker of an interrupted rebuild
from pipeline.rebuild.garbage import clean_debris, collect_garbage, remove_stage_folder, split_kept
from pipeline.rebuild.history import append_log, compare_findings
from pipeline.rebuild.ingest_tasks import deduplicate, ingest_incremental
from pipeline.rebuild.memo import Memo
from pipeline.rebuild.noop import inputs_key, nothing_changed, rebuild_noop
from pipeline.rebuild.options import (EXIT_USAGE, RebuildError, RebuildOptions, RebuildRun, RebuildSummary,
                                      keep_superseded_h)
from pipeline.rebuild.publish import (check_mass_delete, clean_after_failure, crash_point, live_database,
                                      swap_in_new_database, warehouse_lock)
from pipeline.rebuild.state import (FilePlan, FileRecord, PreviousState, StageRecord, frame_hash, load_previous,
                                    logbook_hash, plan_runs, side_records, stage_input_key, superseded_files)
from pipeline.serve.report.publish import settle_report
from pipeline.versions import ingest_code_version, stage_code_version
from pipeline.warehouse import build_database, runs_frame

log = logging.getLogger("pneubench")

if TYPE_CHECKING:
    import pandas as pd

    from pipeline import stages as stage_registry
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
    """What the stages need (pandas, the analyses): imported while the readers' workers work (they
    are forked first and import the readers themselves), and in any case before the stages' own
    pool is forked, so that its workers start warm."""
    import pandas  # noqa: F401
    import pyarrow.dataset  # noqa: F401 (what the first pd.read_parquet of a process imports: ~15 ms)
    import pyarrow.pandas_compat  # noqa: F401

    from pipeline import stages

    stages.discover()


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


# -- the rebuild: plan -> ingest -> stages -> assemble -> publish -----------------------------------
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
    if not raw.is_dir():
        raise RebuildError(f"raw folder {raw} does not exist", EXIT_USAGE)
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
        return rebuild_noop(run, plan.prev, plan.plans, plan.key)
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
        _publish(run, plan, tables, keep, drawer)
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
    key: str                   # :func:`pipeline.rebuild.noop.inputs_key`


def _plan(run: RebuildRun) -> _Plan:
    """Clean up after a killed rebuild, read the live warehouse's state, walk raw/ and plan what to
    read; refuse a mass delete (exit 2) before anything is written."""
    warehouse, progress = run.warehouse, run.progress
    clean_debris(warehouse)
    settle_report(warehouse)  # a report staged by a rebuild killed after its database swap goes in
    prev = load_previous(warehouse)
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
    key = inputs_key(tree, code, plans, side, ignored)
    return _Plan(prev, tree, files, ignored, code, plans, side, side_changes, key)


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


def _ingest(run: RebuildRun, plan: _Plan, ex: Executor) -> _Ingested:
    """Read the new and changed files (the stages' imports done meanwhile); deduplicate the runs."""
    results, records = ingest_incremental(run, plan.tree, plan.plans, ex, plan.code, while_waiting=_import_for_stages)
    crash_point("after_ingest")
    runs, channels, problems = deduplicate(results)
    return _Ingested(results, records, runs, channels, plan.tree.problems + problems, runs_frame(runs))


# -- stages ----------------------------------------------------------------------------------------
def _stages(run: RebuildRun, plan: _Plan, ingested: _Ingested, ex: Executor, drawer: FigureDrawer) -> StageResults:
    """Run the stages whose inputs changed, reuse the others' outputs (:func:`run_stages_cached`)."""
    runs, runs_df = ingested.runs, ingested.runs_df
    ctx_args = dict(raw=plan.tree.root, warehouse=run.warehouse,
                    runs=runs_df.assign(params=[r["params"] for r in runs]) if runs else runs_df,
                    jobs=run.options.jobs, progress=run.progress, mapper=ex.mapper(run.progress))
    return run_stages_cached(ctx_args, runs, plan.prev, run.warehouse, run.options.full, logbook_hash(plan.side),
                             run.progress, run.generation, drawer)


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
    history = append_log(prev.history, _log_row(run, plan, executor, len(ingested.runs), staged))
    in_use = set(runs_df.get("samples_path", [])) | {r.folder for r in staged.records}
    kept, _expired = superseded_files(prev, in_use, run.options.clock(), run.options.keep_superseded_h)
    tables = {
        "runs": runs_df, "quarantine": _quarantine_frame(problems), "channels": pd.DataFrame(ingested.channels),
        "skipped_files": _skipped_files(plan.tree, plan.ignored),
        "figures": pd.DataFrame(staged.figures, columns=["stage", "name", "path", "caption"]),
        **stage_tables,
        "rebuild_log": history, "rebuild_inputs": inputs,
        "ingest_state": pd.DataFrame([r.as_row() for r in ingested.records + plan.side]),
        "stage_cache": pd.DataFrame([r.as_row() for r in staged.records]),
        "superseded_files": _superseded_frame(kept),
    }
    return tables, in_use | set(kept)


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


def _log_row(run: RebuildRun, plan: _Plan, executor: str, n_runs: int, staged: StageResults) -> dict:
    """This rebuild's row of ``rebuild_log`` (its ``seq`` is given by :func:`append_log`)."""
    s = run.summary
    return {"generation": run.generation, "started_at": run.started_at, "finished_at": datetime.now(timezone.utc),
            "duration_s": time.monotonic() - run.t0, "mode": s.mode, "executor": executor,
            "n_files": len(plan.files), "n_runs": n_runs, "n_new": s.n_new, "n_changed": s.n_changed,
            "n_deleted": s.n_deleted, "n_unchanged": s.n_unchanged, "n_quarantined": len(s.quarantine),
            "stages_run": staged.ran, "stages_reused": staged.reused, "exit_code": s.exit_code,
            "inputs_key": plan.key}


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
             drawer: FigureDrawer) -> None:
    """Write the database (the figures drawn beside it put in place), swap it and its report in,
    and collect what neither warehouse uses nor keeps, before and after."""
    warehouse, progress, prev = run.warehouse, run.progress, plan.prev
    progress.message(f"warehouse: writing {len(tables)} tables")

    def write(tmp_db):
        build_database(tmp_db, warehouse, tables, tables["runs"])
        waited = time.monotonic()
        n_aside = drawer.finish()  # the figures drawn beside the database, their stage folders put in place
        if n_aside:
            progress.message(f"figures: {n_aside} drawn in a worker beside the stages and the database "
                             f"(waited {_seconds(time.monotonic() - waited)} for them)")

    # before the new database is written, what neither warehouse uses nor keeps goes (files past
    # their retention, what a killed night left): a nearly full disk gets that room back first
    collect_garbage(warehouse, *split_kept(keep | prev.samples | prev.stage_folders))
    run.summary.report = swap_in_new_database(warehouse, write, run.options.report)
    # files the new warehouse uses, and those of earlier ones still within their retention
    # (a reader that opened an earlier warehouse keeps reading its samples)
    collect_garbage(warehouse, *split_kept(keep))
