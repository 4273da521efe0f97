"""Runs the analysis stages of a rebuild, each after the stages it reads, or reuses its stored outputs.

At start-up the stages are ordered from their declarations (``READS`` / ``WRITES``,
:func:`pipeline.stages.registry.run_order`), which must not read each other in a circle. The
lab's test plan (``raw/plan.toml``) is read once by the caller with the tree it walked and given
in :class:`StageInputs`. A stage whose input key (its
code, the runs of the kinds it reads, the logbooks and the plan when it reads them) and the
tables it reads are unchanged since the previous rebuild is not run: its stored folder
(:mod:`pipeline.rebuild.stage_store`) is loaded instead. A stage that runs gets a context holding
only what it declared (:class:`pipeline.stages.DeclaredContext`): an undeclared read fails the
rebuild, since its key would not cover it.
"""
from __future__ import annotations

import functools
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.progress import Progress
from pipeline.raw.problems import Problem
from pipeline.rebuild.memo import Memo
from pipeline.rebuild.stage_store import (DeferredTable, FigureDrawer, PooledTables, load_stage_folder, own_stage_folder,
                                           save_stage_folder)
from pipeline.rebuild.state import PreviousState, StageRecord, encoded_runs, frame_hash, stage_input_key
from pipeline.versions import stage_code_version
from pipeline.rebuild.options import RebuildError

if TYPE_CHECKING:
    import pandas as pd

    from pipeline.raw.plan import Plan
    from pipeline.stages import Reads
    from pipeline.stages.run_columns import RunLookup

# pandas and the stage framework (which imports pandas and, through the stages, the analyses) are
# imported by the function that runs the stages: a no-op rebuild imports this module and needs none.


@dataclass(frozen=True)
class StageInputs:
    """What the stages of one rebuild read, and how their outputs are cached.

    Attributes
    ----------
    raw : Path
        The raw tree (the hose logbooks in it).
    warehouse : Path
        The warehouse folder (samples files, stage folders, memos).
    runs : list of dict
        The rebuild's runs rows, as hashed into the stages' input keys.
    runs_frame : DataFrame
        The same rows as the stages read them (``params`` a dict per row).
    previous : PreviousState
        The live warehouse's stage records (what may be reused).
    logbooks : str
        Hash of the hose logbooks (:func:`pipeline.rebuild.state.logbook_hash`).
    full : bool
        Run every stage, trusting no stored folder nor memo.
    generation : str
        The rebuild's generation (salts the folders of a full rebuild).
    jobs : int
        Worker processes for a stage's per-item work.
    mapper : callable or None
        The executor's ``map`` for a stage's per-item work (None: local processes).
    plan : Plan
        The lab's test plan, read once by the caller with the tree it walked
        (:func:`pipeline.raw.plan.read_plan`; the caller reports its quarantine lines).
    """

    raw: Path
    warehouse: Path
    runs: list[dict]
    runs_frame: pd.DataFrame
    previous: PreviousState
    logbooks: str
    plan: Plan
    full: bool = False
    generation: str = ""
    jobs: int = 1
    mapper: Callable | None = None


@dataclass
class StageResults:
    """Every stage's outputs, as the new database takes them."""

    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    figures: list[dict] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    warnings: dict[str, list[str]] = field(default_factory=dict)
    records: list[StageRecord] = field(default_factory=list)
    ran: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    #: per stage that ran: its per-item memo (hits, computed items)
    memos: dict[str, Memo] = field(default_factory=dict)
    #: the stages that wrote rows of each table of ``tables``
    origins: dict[str, set[str]] = field(default_factory=dict)
    #: :func:`frame_hash` of each table of ``tables`` as it is now (a table read by several stages
    #: is hashed once; dropped when a later stage adds rows to it)
    hashes: dict[str, str] = field(default_factory=dict)


def duration_text(s: float) -> str:
    """``"12 ms"`` below a second (a stage that is only reused), else ``"3.4 s"``."""
    return f"{s * 1e3:.0f} ms" if s < 1 else f"{s:.1f} s"


def run_stages_cached(inputs: StageInputs, progress: Progress, drawer: FigureDrawer | None = None) -> StageResults:
    """Run every stage after the stages it reads, or reuse its stored outputs when what it declared is unchanged.

    Parameters
    ----------
    inputs : StageInputs
        What the stages read, and the previous rebuild's stage records.
    progress : Progress
        Where the stages report (one message per stage).
    drawer : FigureDrawer or None
        Draws the figures; None: a drawer of its own, finished (every figure drawn) before this returns.

    Returns
    -------
    StageResults
        With a ``drawer``, figures may still be being drawn: the caller calls ``drawer.finish()``
        before it publishes the stage folders.

    Raises
    ------
    RebuildError
        A stage failed (or read what it did not declare), or the stages' declarations read each
        other in a circle.
    """
    from pipeline import stages
    from pipeline.stages.run_columns import run_lookup

    try:
        mods = stages.run_order(stages.discover())
    except stages.StageCircle as exc:
        raise RebuildError(str(exc)) from exc
    res = StageResults()
    own_drawer = drawer is None
    drawer = drawer or FigureDrawer()
    # every stage's code version up front: the project's sources are read and hashed once for all
    codes = {mod.NAME: stage_code_version(getattr(mod, "__file__", None) or mod.NAME) for mod in mods}
    encoded = encoded_runs(inputs.runs)  # every runs row encoded once for all the stages' keys
    deferrable = _deferrable(mods)  # tables a reused stage need not read: no stage reads them
    # and read once for all their tables' run columns
    run_columns = run_lookup(_run_columns_source(inputs.runs_frame))
    with progress.task("stages", len(mods)) as task:
        for mod in mods:
            t0 = time.monotonic()
            reads = stages.reads_of(mod)
            key = _input_key(mod.NAME, codes[mod.NAME], reads, inputs, encoded)
            read = _tables_read(reads, res)
            record = _reusable(mod.NAME, key, read, inputs)
            if record is not None:
                loaded = load_stage_folder(inputs.warehouse, record.folder, mod.NAME, defer=deferrable)
                res.reused.append(mod.NAME)
                how = "reused"
            else:
                record, loaded = _run_stage(mod, (reads, read), key, inputs, res, drawer, progress)
                res.ran.append(mod.NAME)
                how = "ran"
            res.records.append(record)
            tables = _collect(res, loaded, run_columns)
            for t in tables:
                res.origins.setdefault(t, set()).add(mod.NAME)
            memo_note = res.memos[mod.NAME].summary() if mod.NAME in res.memos else ""
            progress.message(f"stage {mod.NAME} {how}: " + ", ".join(f"{k} {len(v)} rows" for k, v in tables.items())
                             + f" ({duration_text(time.monotonic() - t0)}{'; ' + memo_note if memo_note else ''})")
            task.advance()
    if own_drawer:
        drawer.finish()
    return res


def reused_tables(res: StageResults, previous: PreviousState) -> set[str]:
    """Tables of ``res`` that are the previous rebuild's frames again when the runs are: every stage that
    wrote rows of them reused its stored folder (the previous rebuild's own), and the stages are the
    previous rebuild's (none added or gone, which would add or take rows)."""
    if not previous.stages or set(previous.stages) != set(res.ran) | set(res.reused):
        return set()
    reused = set(res.reused)
    return {t for t, names in res.origins.items() if names <= reused}


def _input_key(name: str, code: str, reads: Reads, inputs: StageInputs,
               encoded: list[tuple[str, bytes]] | None = None) -> str:
    """A stage's input key: its code, the runs of the kinds it reads, the logbooks and the plan if it
    reads them (``encoded``: the runs rows as :func:`pipeline.rebuild.state.encoded_runs` gives them)."""
    return stage_input_key(name, code, inputs.runs, set(reads.kinds), inputs.logbooks if reads.logbooks else None,
                           reads.plan_digest(inputs.plan), encoded)


def _deferrable(mods) -> frozenset[str]:
    """Tables no stage reads (its ``READS``), not pooled with another for their run columns
    (:data:`pipeline.stages.run_columns.POOLS`), and not ``findings`` (compared with the previous rebuild's
    by the rebuild): a reused stage's folder gives them as :class:`DeferredTable`."""
    from pipeline import stages
    from pipeline.stages.run_columns import POOLS

    read = set().union(*(stages.reads_of(mod).tables for mod in mods)) if mods else set()
    pooled = set(POOLS) | {source for source, _keys in POOLS.values()}
    return _NotIn(read | pooled | {"findings"})


class _NotIn(frozenset):
    """Every name but the given ones (``in`` inverted): the tables a stage writes are known when its folder is read."""

    def __contains__(self, name) -> bool:
        return not frozenset.__contains__(self, name)


def _run_columns_source(runs_frame: pd.DataFrame) -> pd.DataFrame:
    """What :func:`pipeline.stages.add_run_columns` reads of the runs (``run_id``, ``campaign``,
    ``params``), their values read out once into object columns.

    The same values as the runs frame's, so the same run columns: ``add_run_columns`` reads the
    runs cell by cell, and a cell of pandas' Arrow-backed string columns costs ~20x one of an
    object column; it did so for every stage's tables (issue 26: ~1 CPU-s of every change at
    10,000 runs). A frame without those columns is given as it is."""
    import pandas as pd

    cols = ["run_id", "campaign", "params"]
    if runs_frame is None or not set(cols) <= set(runs_frame.columns):
        return runs_frame
    return pd.DataFrame({c: pd.Series(list(runs_frame[c]), index=runs_frame.index, dtype=object) for c in cols})


def _tables_read(reads: Reads, res: StageResults) -> dict[str, str]:
    """Content hash of each earlier table a stage reads (``"absent"`` for one no stage wrote); each
    table is hashed once however many stages read it (``res.hashes``)."""
    out = {}
    for t in sorted(reads.tables):
        if t not in res.hashes:
            res.hashes[t] = frame_hash(res.tables.get(t))
        out[t] = res.hashes[t]
    return out


def _reusable(name: str, key: str, tables_read: dict[str, str], inputs: StageInputs) -> StageRecord | None:
    """The previous rebuild's record of a stage when its outputs can be reused (same input key, same
    tables read, its folder still there), else None."""
    old = inputs.previous.stages.get(name)
    if inputs.full or old is None or (folder := own_stage_folder(inputs.warehouse, old.folder, name)) is None:
        return None
    if key == old.input_key and (folder / "output.json").is_file() and tables_read == old.results_read:
        return old
    return None


def _run_stage(mod, reads_read: tuple[Reads, dict[str, str]], key: str, inputs: StageInputs, res: StageResults,
               drawer: FigureDrawer, progress: Progress) -> tuple[StageRecord, tuple]:
    """Run a stage on what it declared (``reads_read``: its declaration and the hashes of the tables
    it reads, :func:`_tables_read`), store its outputs; its record and its outputs as stored."""
    from pipeline import stages

    reads, read = reads_read
    name = mod.NAME
    old = inputs.previous.stages.get(name)
    # the previous folder (its figures and pooled tables, by key): only one of this warehouse's own
    previous = None if inputs.full or old is None else own_stage_folder(inputs.warehouse, old.folder, name)
    if previous is None:  # every figure to draw: the drawing worker imports matplotlib while the stage runs
        drawer.warm()  # (else it starts with the first figure whose key changed, if any)
    # per-run results of earlier rebuilds (not read by --full, written either way)
    memo = res.memos[name] = Memo(inputs.warehouse, name, read=not inputs.full)
    ctx = stages.DeclaredContext(name, reads, raw=inputs.raw, warehouse=inputs.warehouse, runs=inputs.runs_frame,
                                 results=res.tables, jobs=inputs.jobs, progress=progress, mapper=inputs.mapper,
                                 memo=memo, plan=inputs.plan, pooled_tables=(pooled := PooledTables(previous)))
    try:
        out = mod.run(ctx)
    except Exception as exc:  # a bug in an analysis: fail, keep the previous warehouse
        raise RebuildError(f"stage {name} failed: {type(exc).__name__}: {exc}") from exc
    memo.save()
    # --full writes a fresh folder (never trusts an existing one); incremental runs reuse a folder
    # with the same inputs (stages are deterministic)
    salt = inputs.generation if inputs.full else ""
    folder_key = hashlib.sha256(json.dumps([key, read, salt], sort_keys=True).encode()).hexdigest()[:20]
    rel, cacheable, now_in = save_stage_folder(inputs.warehouse, name, folder_key, out, drawer, previous, pooled.keys)
    if pooled.taken:
        progress.message(f"stage {name}: {', '.join(pooled.taken)} taken from its previous run (inputs unchanged)")
    record = StageRecord(name, key if cacheable else "uncacheable", rel, sorted(reads.kinds), False, read)
    return record, load_stage_folder(inputs.warehouse, rel, name, out, now_in)


def _own_run_columns(name: str, runs_frame: pd.DataFrame | RunLookup | None, df: pd.DataFrame) -> pd.DataFrame:
    """:func:`pipeline.stages.add_run_columns` of one table that pools no other."""
    from pipeline import stages

    return stages.add_run_columns({name: df}, runs_frame)[name]


def _read(df):
    """A frame of ``res.tables``, a :class:`DeferredTable` read."""
    return df.read_frame() if isinstance(df, DeferredTable) else df


def _collect(res: StageResults, loaded: tuple, runs_frame: pd.DataFrame | RunLookup | None) -> dict[str, pd.DataFrame]:
    """Add a stage's loaded outputs (tables with their run columns, figures, problems, warnings) to
    ``res`` (``runs_frame``: the runs, their :func:`_run_columns_source`, or its
    :func:`pipeline.stages.run_columns.run_lookup`)."""
    import pandas as pd

    from pipeline import stages

    tables, figures, problems, warnings = loaded
    deferred = {t: df for t, df in tables.items() if isinstance(df, DeferredTable)}
    tables = stages.add_run_columns({t: df for t, df in tables.items() if t not in deferred}, runs_frame)
    for t, df in deferred.items():  # their run columns when read (a table of its own: not pooled with another)
        df.finish = functools.partial(_own_run_columns, t, runs_frame)
        tables[t] = df
    for t, df in tables.items():
        if t in res.tables:  # rows of a table an earlier stage wrote too: both read now
            df = pd.concat([_read(res.tables[t]), _read(df)], ignore_index=True)
        res.tables[t] = df
        res.hashes.pop(t, None)  # hashed anew when a later stage reads it
    res.figures += figures
    res.problems += problems
    for rid, ws in warnings.items():
        res.warnings.setdefault(rid, []).extend(ws)
    return tables
