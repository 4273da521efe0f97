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

from pipeline.layout import Problem
from pipeline.progress import Progress


@dataclass
class StageOutput:
    """What a stage produces.

    Attributes
    ----------
    tables : dict of str to DataFrame
        Rows per warehouse table; columns by name (missing columns become NULL).
    figures : dict of str to matplotlib Figure
        Saved by the orchestrator as ``figures/<stage>/<name>.png`` and listed in the
        ``figures`` table; ``captions`` may describe them.
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

    def runs_of(self, *kinds: str) -> pd.DataFrame:
        """Runs of the given kinds, sorted by run_id."""
        if self.runs.empty:
            return self.runs
        return self.runs[self.runs["kind"].isin(kinds)].sort_values("run_id").reset_index(drop=True)

    def samples_file(self, run_id: str) -> Path:
        row = self.runs.loc[self.runs["run_id"] == run_id]
        if row.empty:
            raise KeyError(f"no run {run_id!r}")
        return self.warehouse / row.iloc[0]["samples_path"]

    def samples(self, run_id: str, columns: list[str] | None = None) -> pd.DataFrame:
        """A run's samples as a DataFrame in SI (``t_s``, ``p_a_pa``, ...), without ``run_id``."""
        return read_samples(self.samples_file(run_id), columns)

    def map(self, func: Callable, items: Iterable, label: str = "") -> list:
        """``[func(item) for item in items]`` in parallel (processes, or the configured executor).

        ``func`` must be a picklable module-level function. Order is preserved.
        """
        items = list(items)
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
