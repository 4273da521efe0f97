"""What a stage works with: the context it reads through and the output it returns.

A stage reads runs and samples through the :class:`StageContext`, calls functions of
``analyses/`` (which know nothing of the warehouse), and returns a :class:`StageOutput`:
DataFrames per table, figures (:class:`FigureRecipe`, drawn later), quarantine rows and per-run
warnings. The rebuild gives each stage a :class:`DeclaredContext`, which holds only what the
stage declared it reads (``READS``, :class:`pipeline.stages.registry.Reads`) and raises
:class:`UndeclaredRead` on anything else.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq

from pipeline.progress import Progress
from pipeline.raw.plan import KEYS as PLAN_KEYS
from pipeline.raw.plan import Plan
from pipeline.raw.problems import Problem
from pipeline.stages.registry import Reads


@dataclass(frozen=True)
class FigureRecipe:
    """A figure not drawn yet: ``func(*args, **kwargs)`` returns a matplotlib Figure.

    A stage hands the rebuild recipes (:meth:`StageOutput.draw`) rather than figures, so that
    the figures can be drawn off the rebuild's critical path, in a worker process beside the
    other stages and the database write (matplotlib's import and ``savefig`` were most of a
    one-export rebuild's stage time; issue 14), and not at all when the stage folder already
    holds them. ``func`` must be a module-level function and the arguments picklable.
    """

    func: Callable
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)

    def figure(self):
        """Draw it: the matplotlib Figure."""
        return self.func(*self.args, **self.kwargs)


def figure_of(fig):
    """A matplotlib Figure from a figure or a :class:`FigureRecipe`."""
    return fig.figure() if isinstance(fig, FigureRecipe) else fig


@dataclass
class StageOutput:
    """What a stage produces.

    Attributes
    ----------
    tables : dict of str to DataFrame
        Rows per warehouse table; columns by name (missing columns become NULL).
    figures : dict of str to FigureRecipe (or matplotlib Figure)
        Drawn and saved by the orchestrator as ``figures/<stage>/<name>.png`` and listed in the
        ``figures`` table; ``captions`` may describe them. Add them with :meth:`draw`.
    problems : list of Problem
        Inputs (files or lines) the stage could not use: quarantine rows.
    warnings : dict of str to list of str
        Per ``run_id`` warnings, appended to ``runs.warnings``.
    """

    tables: dict[str, pd.DataFrame] = field(default_factory=dict)
    figures: dict = field(default_factory=dict)
    captions: dict[str, str] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    warnings: dict[str, list[str]] = field(default_factory=dict)

    def warn(self, run_id: str, text: str) -> None:
        self.warnings.setdefault(run_id, []).append(text)

    def draw(self, name: str, func: Callable, *args, caption: str | None = None, **kwargs) -> None:
        """Figure ``name`` is ``func(*args, **kwargs)`` (a plot function of ``analyses``), drawn
        later by the rebuild (:class:`FigureRecipe`); ``caption`` describes it."""
        self.figures[name] = FigureRecipe(func, args, kwargs)
        if caption is not None:
            self.captions[name] = caption


class Carrying(dict):
    """A ``ctx.map`` item (a dict) with what another memoised map derived from it added under its own names,
    memoised by the item alone (``memo_key``, :func:`pipeline.rebuild.memo.item_key`): what it carries follows
    from the item, so the key need not hash it again (the decision's looks parts, session 26; the test plan's
    boundaries, session 27)."""

    def __init__(self, item: dict, **carried):
        super().__init__(item, **carried)
        self.memo_key = item


@dataclass
class StageContext:
    """What a stage may use: the ingested runs, their samples, earlier stages' tables.

    Attributes
    ----------
    raw : Path
        The raw tree (read only).
    warehouse : Path
        The warehouse folder (samples Parquet live under it).
    runs : DataFrame
        The ``runs`` rows of this rebuild; ``params`` is a dict per row.
    results : dict of str to DataFrame
        Tables produced by stages that ran before this one.
    plan : Plan
        The lab's test plan (``raw/plan.toml``, :func:`pipeline.raw.plan.read_plan`); without
        one, built-in defaults and ``present=False``.
    """

    raw: Path
    warehouse: Path
    runs: pd.DataFrame
    results: dict[str, pd.DataFrame] = field(default_factory=dict)
    jobs: int = 1
    progress: Progress = field(default_factory=Progress)
    mapper: Callable | None = None
    #: per-item results kept between rebuilds (``pipeline.rebuild.memo.Memo``; the rebuild sets one per stage)
    memo: object | None = None
    plan: Plan = field(default_factory=Plan)
    #: pooled tables kept between rebuilds (``pipeline.rebuild.stage_store.PooledTables``; set by the rebuild)
    pooled_tables: object | None = None

    def runs_of(self, *kinds: str) -> pd.DataFrame:
        """Runs of the given kinds, sorted by run_id."""
        if self.runs.empty:
            return self.runs
        return self.runs[self.runs["kind"].isin(kinds)].sort_values("run_id").reset_index(drop=True)

    def samples_file(self, run_id: str) -> Path:
        runs = self.runs
        cached = self.__dict__.get("_samples_paths")
        if cached is None or cached[0] is not runs:  # one index per runs frame, not a scan per run
            paths: dict = {}
            if runs is not None and not runs.empty and {"run_id", "samples_path"} <= set(runs.columns):
                for rid, sp in zip(runs["run_id"], runs["samples_path"]):
                    paths.setdefault(rid, sp)
            cached = self.__dict__["_samples_paths"] = (runs, paths)
        if run_id not in cached[1]:
            raise KeyError(f"no run {run_id!r}")
        return self.warehouse / cached[1][run_id]

    def samples(self, run_id: str, columns: list[str] | None = None) -> pd.DataFrame:
        """A run's samples as a DataFrame in SI (``t_s``, ``p_a_pa``, ...), without ``run_id``."""
        return read_samples(self.samples_file(run_id), columns)

    def map(self, func: Callable, items: Iterable, label: str = "", warm: tuple[str, ...] = ()) -> list:
        """``[func(item) for item in items]`` in parallel (processes, or the configured executor).

        ``func`` must be a picklable module-level function. Order is preserved. With a
        :attr:`memo`, only the items it has no result for are computed. ``warm``: modules imported
        in this process before any item is computed, so that the workers forked for them start with
        them loaded (else each imports them); not when every result comes from the memo (a plan
        change's decision stage: ``scipy.special`` not imported for nothing, ~0.3 CPU-s, issue 26).
        """
        items = list(items)
        compute = self._compute if not warm else partial(self._warm_compute, warm)
        if self.memo is not None:
            return self.memo.map(compute, func, items, label)
        return compute(func, items, label)

    def _warm_compute(self, warm: tuple[str, ...], func: Callable, items: list, label: str = "") -> list:
        if items:
            for name in warm:
                importlib.import_module(name)
        return self._compute(func, items, label)

    def pooled(self, table: str, func: Callable, *args, **kwargs) -> pd.DataFrame:
        """Table ``table`` as ``func(*args, **kwargs)``, a pooled result (a module-level function
        of data that may not have changed: e.g. Weibull fits of the hoses' lives when a leakage
        check changed). With :attr:`pooled_tables` (the rebuild), the previous rebuild's table is
        taken when the function, its code and the arguments' content are the same, and a computed
        one comes back as its Parquet file will (so both give the same frame); a plan among the
        arguments is keyed by what the stage declared it reads of it."""
        if self.pooled_tables is None:
            return func(*args, **kwargs)
        key_args = tuple(_plan_digest(a) if isinstance(a, (Plan, DeclaredPlan)) else a for a in args)
        held = self.pooled_tables.take(table, func, (key_args, dict(sorted(kwargs.items()))))
        return self.pooled_tables.settle(func(*args, **kwargs)) if held is None else held

    def _compute(self, func: Callable, items: list, label: str = "") -> list:
        if self.mapper is not None:
            return self.mapper(func, items, label)
        out = []
        with self.progress.task(label or getattr(func, "__name__", "work"), len(items)) as task:
            if self.jobs <= 1 or len(items) <= 1:
                for item in items:
                    out.append(func(item))
                    task.advance()
            else:
                with ProcessPoolExecutor(max_workers=self.jobs) as pool:
                    for res in pool.map(func, items, chunksize=max(1, len(items) // (self.jobs * 8))):
                        out.append(res)
                        task.advance()
        return out


def _plan_digest(plan) -> str:
    """What a stage can see of ``plan`` (a :class:`DeclaredPlan`: its declared keys), as a hash."""
    if isinstance(plan, DeclaredPlan):
        return "plan " + plan._plan.digest_of(plan._keys)
    return "plan " + plan.digest


def read_samples(path: str | Path, columns: list[str] | None = None) -> pd.DataFrame:
    """A samples Parquet file as a DataFrame in SI, without ``run_id``.

    Only the requested ``columns`` that the run has are read (a run without an optional
    channel simply lacks that column); ``None`` reads every channel.
    """
    have = pq.read_schema(path).names
    wanted = [c for c in have if c != "run_id"] if columns is None else [c for c in columns if c in have]
    return pq.read_table(path, columns=wanted).to_pandas()


# -- the context the rebuild gives a stage: what it declared, nothing else -----------------------------
class UndeclaredRead(Exception):
    """A stage read something its ``READS`` does not declare (a bug in the stage: declare it)."""


class DeclaredTables(Mapping):
    """Earlier stages' tables as a stage may read them: only those its ``READS`` names.

    Reading any other (``[name]``, ``get``, ``in``) raises :class:`UndeclaredRead`; iterating
    gives the declared tables that exist.
    """

    def __init__(self, tables: Mapping[str, pd.DataFrame], stage: str, declared: Iterable[str]):
        self._tables, self._stage, self._declared = tables, stage, frozenset(declared)

    def __getitem__(self, name: str) -> pd.DataFrame:
        if name not in self._declared:
            raise UndeclaredRead(f"stage {self._stage} read table {name!r}, which its READS does not declare")
        return self._tables[name]

    def __iter__(self) -> Iterator[str]:
        return (name for name in self._tables if name in self._declared)

    def __len__(self) -> int:
        return sum(1 for _ in self)


def _of_kinds(runs: pd.DataFrame, kinds: Iterable[str]) -> pd.DataFrame:
    """The rows of ``runs`` of some kinds (``runs`` itself when it has none)."""
    if runs is None or runs.empty or "kind" not in runs.columns:
        return runs
    return runs[runs["kind"].isin(list(kinds))].reset_index(drop=True)


class DeclaredContext(StageContext):
    """The :class:`StageContext` the rebuild gives a stage: only what the stage declared it reads.

    ``runs`` holds the runs of the declared kinds (and so :meth:`samples` only theirs),
    ``results`` the declared tables (:class:`DeclaredTables`); :meth:`runs_of` a kind not
    declared, ``raw`` (where the hose logbooks are) unless logbooks are declared, and ``plan``
    unless the plan is declared, raise
    :class:`UndeclaredRead`. The stage's cache key hashes exactly what it declared, so a read it
    did not declare could only give a stale result: it fails the rebuild instead.

    Parameters
    ----------
    stage : str
        The stage's ``NAME`` (for the messages).
    reads : Reads
        What the stage declared it reads.
    runs : DataFrame
        Every run of the rebuild.
    results : mapping of str to DataFrame
        Every table of the stages that ran before.
    **kwargs
        The other fields of :class:`StageContext` (``raw``, ``warehouse``, ``jobs``, ...).
    """

    def __init__(self, stage: str, reads: Reads, *, runs: pd.DataFrame, results: Mapping[str, pd.DataFrame],
                 **kwargs):
        self.stage, self.reads = stage, reads
        super().__init__(runs=_of_kinds(runs, reads.kinds), results=DeclaredTables(results, stage, reads.tables),
                         **kwargs)

    @property
    def raw(self) -> Path:
        """The raw tree, for the hose logbooks in it (only when the stage declares ``logbooks``)."""
        if not self.reads.logbooks:
            raise UndeclaredRead(f"stage {self.stage} read raw/ (the hose logbooks), which its READS does not declare")
        return self._raw

    @raw.setter
    def raw(self, value: Path) -> None:
        self._raw = value

    @property
    def plan(self) -> Plan:
        """The lab's test plan (only when the stage declares ``plan``; with declared keys, a plan
        whose settings raise on any other key: :class:`DeclaredPlan`)."""
        if not self.reads.plan:
            raise UndeclaredRead(f"stage {self.stage} read the test plan (raw/plan.toml), which its READS does "
                                 "not declare")
        if self.reads.plan is True:
            return self._plan
        return DeclaredPlan(self._plan, self.reads.plan_keys(), self.stage)

    @plan.setter
    def plan(self, value: Plan) -> None:
        self._plan = value

    def runs_of(self, *kinds: str) -> pd.DataFrame:
        undeclared = sorted(set(kinds) - set(self.reads.kinds))
        if undeclared:
            raise UndeclaredRead(f"stage {self.stage} read runs of kind {', '.join(undeclared)}, "
                                 "which its READS does not declare")
        return super().runs_of(*kinds)


class DeclaredPlan:
    """A :class:`Plan` seen by a stage that declared only some of its keys (``Reads(plan=(...))``):
    :meth:`for_hose_type` gives settings whose other keys raise :class:`UndeclaredRead` (the
    stage's cache key hashes only the declared ones); everything else is the plan's."""

    def __init__(self, plan: Plan, keys: tuple[str, ...], stage: str):
        self._plan, self._keys, self._stage = plan, keys, stage

    def __getattr__(self, name: str):
        if name in ("defaults", "hose_types", "digest"):  # the tables themselves hold every key
            raise UndeclaredRead(f"stage {self._stage} read the plan's {name}, which holds keys its READS does "
                                 f"not declare (it declares {', '.join(self._keys)}): use for_hose_type")
        return getattr(self._plan, name)

    def for_hose_type(self, hose_type: str | None) -> "_DeclaredSettings":
        """The hose type's settings, only the declared keys readable."""
        return _DeclaredSettings(self._plan.for_hose_type(hose_type), self._keys, self._stage)


class _DeclaredSettings:
    """:class:`pipeline.raw.plan.PlanSettings` whose undeclared keys raise."""

    def __init__(self, settings, keys: tuple[str, ...], stage: str):
        self._settings, self._keys, self._stage = settings, keys, stage

    def __getattr__(self, name: str):
        if name in PLAN_KEYS and name not in self._keys:
            raise UndeclaredRead(f"stage {self._stage} read the plan's {name}, which its READS does not declare "
                                 f"(it declares {', '.join(self._keys)})")
        return getattr(self._settings, name)

