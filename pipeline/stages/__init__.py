"""Analysis stages of the rebuild: the glue between the warehouse and the pure ``analyses``.

Each module in this package is one stage and defines, at module level::

    NAME = "plpa_characterisation"        # unique, used in logs and figure paths
    ORDER = 10                             # stages run by (ORDER, NAME); later ones see earlier results
    KINDS = ("leakage", "breakaway")       # run kinds it reads (for incremental re-runs)
    TABLES = ("leakage_map", ...)          # warehouse tables it fills (DDL in schemas/ddl/)

    def run(ctx: StageContext) -> StageOutput: ...

A stage reads runs and samples through the :class:`StageContext`, calls functions of
``analyses/`` (which know nothing of the warehouse), and returns DataFrames per table, figures,
quarantine rows and per-run warnings. A run that cannot be analysed gives NULLs and a warning,
never an exception; an exception out of ``run`` fails the rebuild (the previous warehouse stays).
"""
from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

import pandas as pd
import pyarrow.parquet as pq

from pipeline.raw.problems import Problem
from pipeline.progress import Progress


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

    def map(self, func: Callable, items: Iterable, label: str = "") -> list:
        """``[func(item) for item in items]`` in parallel (processes, or the configured executor).

        ``func`` must be a picklable module-level function. Order is preserved. With a
        :attr:`memo`, only the items it has no result for are computed.
        """
        items = list(items)
        if self.memo is not None:
            return self.memo.map(self._compute, func, items, label)
        return self._compute(func, items, label)

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


def read_samples(path: str | Path, columns: list[str] | None = None) -> pd.DataFrame:
    """A samples Parquet file as a DataFrame in SI, without ``run_id``.

    Only the requested ``columns`` that the run has are read (a run without an optional
    channel simply lacks that column); ``None`` reads every channel.
    """
    have = pq.read_schema(path).names
    wanted = [c for c in have if c != "run_id"] if columns is None else [c for c in columns if c in have]
    return pq.read_table(path, columns=wanted).to_pandas()


def discover() -> list[ModuleType]:
    """Every stage module of this package, in run order (ORDER, then NAME)."""
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "run") and hasattr(mod, "NAME"):
            mods.append(mod)
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 50), m.NAME))


# -- columns every result table gets from the runs it comes from ------------------------------------
#: Aggregated tables: the run-level table whose rows they pool and the columns that group them
#: (an empty tuple: the whole table is one pool). The rows' campaigns and runs are stated as
#: ``campaigns`` (sorted list) and ``n_runs``.
POOLS: dict[str, tuple[str, tuple[str, ...]]] = {
    "seal_envelope": ("leakage_map", ("chamber", "adjustment", "z_rollers_mm", "spring_force_n")),
    "breakaway_summary": ("breakaway", ("direction", "backpressure_bar", "force_rate_n_s")),
    "breakaway_findings": ("breakaway", ()),
    "viscous_fits": ("viscous_points", ("backpressure_bar", "direction")),
    "viscous_transition": ("viscous_points", ("backpressure_bar",)),
    "spring_fits": ("spring_tests", ("chamber",)),
    "pressure_dynamics": ("pressure_steps", ("chamber", "direction")),  # the stage fills its own (per rig, part)
    "service_life": ("hose_life", ("hose_type", "adjustment")),
    "hose_survival": ("hose_life", ("hose_type", "adjustment")),
    "service_life_test": ("hose_life", ("hose_type",)),
}


def _hose_of(params) -> str | None:
    if isinstance(params, str):
        import json

        try:
            params = json.loads(params)
        except ValueError:
            return None
    h = params.get("hose_id") if isinstance(params, dict) else None
    return None if h is None or (isinstance(h, float) and h != h) or str(h) == "" else str(h)


def _key(value):
    """A group-key cell comparable across tables (floats rounded to 9 digits, NULL as None)."""
    if value is None or (isinstance(value, float) and value != value):
        return None
    if isinstance(value, float):
        return round(value, 9)
    return value


def add_run_columns(tables: dict[str, pd.DataFrame], runs: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """The stage's tables with the columns a person filters by, joined from ``runs``.

    Every table with a ``run_id`` gets ``campaign`` and, when any of its runs names a hose,
    ``hose_id`` (columns a stage already fills are kept as they are). The aggregated tables of
    :data:`POOLS` get ``campaigns`` (sorted list) and ``n_runs``: the campaigns and the number of
    runs of the pooled rows of the same group (``seal_envelope`` pools its setting's
    characterisation runs, or its hose checks when it has nothing else, as ``runs_used`` says;
    hose tables pool the hoses' logbook campaigns and count no runs). A group whose rows cannot be
    matched gets NULLs, never a guess.

    Parameters
    ----------
    tables : dict of str to DataFrame
        One stage's output tables (not modified).
    runs : DataFrame
        ``runs`` rows with ``run_id``, ``campaign`` and ``params`` (dict or JSON text).

    Returns
    -------
    dict of str to DataFrame
    """
    if runs is None or runs.empty or "run_id" not in runs.columns:
        return tables
    campaign = dict(zip(runs["run_id"], runs["campaign"]))
    hose = {rid: h for rid, p in zip(runs["run_id"], runs["params"]) if (h := _hose_of(p)) is not None}
    out = dict(tables)
    for name, df in tables.items():
        if df is None or "run_id" not in df.columns:
            continue
        if df.empty:  # the same columns and dtypes, without pandas' per-column work (a reused empty stage)
            out[name] = df.assign(campaign=pd.array([], dtype="string")) if "campaign" not in df.columns else df.copy()
            continue
        df = df.copy()
        if "campaign" not in df.columns:
            df["campaign"] = pd.array(df["run_id"].map(campaign), dtype="string")
        if "hose_id" not in df.columns and df["run_id"].isin(list(hose)).any():
            df["hose_id"] = pd.array(df["run_id"].map(hose), dtype="string")
        out[name] = df
    for name, (source, keys) in POOLS.items():
        df, src = out.get(name), out.get(source)
        if (df is None or src is None or "campaigns" in df.columns or not set(keys) <= set(src.columns)
                or not set(keys) <= set(df.columns)):
            continue
        out[name] = _pool_columns(name, df, src, keys)
    return out


def _pool_columns(name: str, df: pd.DataFrame, src: pd.DataFrame, keys: tuple[str, ...]) -> pd.DataFrame:
    if "campaign" in src.columns:
        camp = src["campaign"].map(lambda c: [c] if isinstance(c, str) else [])
    elif "campaigns" in src.columns:
        camp = src["campaigns"].map(lambda c: [str(x) for x in c] if c is not None and not isinstance(c, str) else [])
    else:
        return df
    run = src["run_id"] if "run_id" in src.columns else pd.Series(None, index=src.index, dtype=object)
    hose_check = (src["hose_id"].map(lambda h: isinstance(h, str) and h != "") if "hose_id" in src.columns
                  else pd.Series(False, index=src.index))
    groups: dict[tuple, list[int]] = {}
    for i, k in zip(src.index, zip(*(src[c] for c in keys)) if keys else ((),) * len(src)):
        groups.setdefault(tuple(_key(v) for v in k), []).append(i)
    campaigns, n_runs = [], []
    for _, row in df.iterrows():
        idx = groups.get(tuple(_key(row[c]) for c in keys))
        if idx and name == "seal_envelope":  # the rows the envelope is made of (analyses/leakage.py)
            want = row.get("runs_used") == "hose_checks"
            idx = [i for i in idx if bool(hose_check[i]) == want] or None
        if not idx:
            campaigns.append(None)
            n_runs.append(None)
            continue
        campaigns.append(sorted({c for i in idx for c in camp[i]}))
        n_runs.append(int(run[idx].nunique()) if "run_id" in src.columns else None)
    df = df.copy()
    df["campaigns"] = pd.Series(campaigns, index=df.index, dtype=object)
    if "n_runs" not in df.columns and "run_id" in src.columns:
        df["n_runs"] = pd.array(n_runs, dtype="Int64")
    return df
