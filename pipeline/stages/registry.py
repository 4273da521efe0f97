"""The stages and what each declares: which modules are stages, what they read and write, in which order they run.

A stage module declares, at module level (dbt's ``ref()`` in spirit)::

    NAME = "durability"
    READS = Reads(kinds=("durability", "leakage"), tables=("leakage_map",), logbooks=True)
    WRITES = ("durability_runs", "hose_life", ...)

The rebuild runs a stage after every stage that writes a table it reads (:func:`run_order`),
refuses declarations that read each other in a circle (:class:`StageCircle`), keys a stage's
cached outputs on what it declared, and gives it a context that holds nothing else
(:class:`pipeline.stages.context.DeclaredContext`).
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from types import ModuleType

from pipeline.raw.plan import KEYS, Plan


@dataclass(frozen=True)
class Reads:
    """What a stage reads (its ``READS``); the rebuild re-runs it when any of it changes.

    Attributes
    ----------
    kinds : tuple of str
        Run kinds whose runs (rows of ``runs``) and samples it reads.
    tables : tuple of str
        Tables of earlier stages it reads (``ctx.results``), in the order it uses them (that order
        breaks the ties of :func:`run_order`).
    logbooks : bool
        Whether it reads the hose logbooks under ``raw/``.
    plan : bool or tuple of str
        Whether it reads the lab's test plan, ``raw/plan.toml`` (``ctx.plan``,
        :class:`pipeline.raw.plan.Plan`): True, all of it (it re-runs when what the plan says
        changes); a tuple of keys of :data:`pipeline.raw.plan.KEYS`, only those (it re-runs when
        one of them changes for some hose type, and reading another key raises).
    """

    kinds: tuple[str, ...] = ()
    tables: tuple[str, ...] = ()
    logbooks: bool = False
    plan: bool | tuple[str, ...] = False

    def plan_keys(self) -> tuple[str, ...]:
        """The plan keys the stage reads (every key for ``plan=True``, none for False)."""
        if self.plan is True:
            return tuple(KEYS)
        return tuple(self.plan) if self.plan else ()

    def plan_digest(self, plan: Plan) -> str | None:
        """What the stage sees of ``plan``, hashed for its cache key (None when it does not read it):
        all of it for ``plan=True`` (:attr:`Plan.digest`), else only its keys (:meth:`Plan.digest_of`:
        a hose type's table that sets none of them changes nothing)."""
        if self.plan is True:
            return plan.digest
        return plan.digest_of(self.plan_keys()) if self.plan else None


class StageCircle(Exception):
    """Stages whose declarations read each other's tables in a circle."""


def discover() -> list[ModuleType]:
    """Every stage module of the ``pipeline.stages`` package (a module with ``NAME`` and ``run``), by NAME."""
    package = importlib.import_module("pipeline.stages")
    mods = []
    for info in pkgutil.iter_modules(package.__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{package.__name__}.{info.name}")
        if hasattr(mod, "run") and hasattr(mod, "NAME"):
            mods.append(mod)
    return sorted(mods, key=lambda m: m.NAME)


def reads_of(stage) -> Reads:
    """A stage's ``READS`` (nothing when it declares none)."""
    return getattr(stage, "READS", None) or Reads()


def writes_of(stage) -> tuple[str, ...]:
    """A stage's ``WRITES``: the tables it fills."""
    return tuple(getattr(stage, "WRITES", ()) or ())


def run_order(stages) -> list:
    """The stages in the order they run: each after the stages that write a table it reads.

    Depth first, as ``make`` does: from each stage no other stage reads (by NAME), the writers of
    its tables first, in the order its ``READS`` lists them. Tables no stage writes are simply
    absent when read.

    Parameters
    ----------
    stages : iterable of stage modules (or objects with ``NAME``, ``READS``, ``WRITES``)

    Returns
    -------
    list
        The same stages, in run order.

    Raises
    ------
    StageCircle
        When declarations read each other in a circle (the message names it).
    """
    stages = sorted(stages, key=lambda s: s.NAME)
    writers: dict[str, list] = {}
    for stage in stages:
        for table in writes_of(stage):
            writers.setdefault(table, []).append(stage)
    inputs = {s.NAME: [w for t in reads_of(s).tables for w in writers.get(t, ())] for s in stages}
    read_by_others = {w.NAME for s in stages for w in inputs[s.NAME] if w is not s}
    order: list = []
    done: set[str] = set()

    def visit(stage, path: list[str]) -> None:
        if stage.NAME in done:
            return
        if stage.NAME in path:
            circle = path[path.index(stage.NAME):] + [stage.NAME]
            raise StageCircle(f"stages read each other's tables in a circle: {' reads from '.join(circle)}")
        for writer in inputs[stage.NAME]:
            visit(writer, path + [stage.NAME])
        done.add(stage.NAME)
        order.append(stage)

    for stage in [s for s in stages if s.NAME not in read_by_others] + stages:  # then any left: a circle
        visit(stage, [])
    return order
