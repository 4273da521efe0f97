"""The decision stage run in-process on a simulated raw tree, for :mod:`benchmarks.bench_decision`.

A ``pneubench rebuild`` of a ``decision`` campaign spends its minutes in the durability stage
(a Weibull fit and a figure per hose type and adjustment), not in the decision stage. To count
the verdict on hundreds of hose types, this module runs what the rebuild runs for the decision
tables and nothing else, with the product's own code: the logbooks read and merged
(:func:`pipeline.raw.logbook.read_logbooks`, :func:`~pipeline.raw.logbook.merge_logbooks`), the
hoses' lives as the durability stage builds them (:func:`analyses.hose_life.hose_life`, no
durability runs in these campaigns), the plan as the rebuild reads it
(:func:`pipeline.raw.plan.read_plan`), and the decision stage's ``run``
(:mod:`pipeline.stages.decision`: :func:`analyses.decision.freeze_look`, the design,
:func:`analyses.sequential.design_for`, the looks in logbook order, odometer-linear distances,
``decide``) on a :class:`~pipeline.stages.context.StageContext` whose ``map`` is a plain loop.
``tests/benchmarks/test_decision_inprocess.py`` checks that on one small campaign its tables equal
the warehouse's row for row, so a count over them is the product's behaviour.

:class:`StageRunTo` is the simulator's ``run_to``: at each failure, the ``max_failures`` the
decision stage would freeze from the logbook as it stands (the simulator may not import
analyses), so that a simulated type runs to its frozen maximum (Jennison & Turnbull 2000, ch. 7;
Mehta & Tsiatis 2001: the maximum re-estimated once from the nuisance shape).
"""
from __future__ import annotations

import json
import tempfile
from collections import Counter
from pathlib import Path

import pandas as pd

DECISION_TABLES = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses")


def stage_context(raw: Path):
    """The decision stage's context on ``raw``: ``hose_life`` and (empty) ``durability_runs`` as the
    durability stage gives them, the plan as the rebuild reads it, ``map`` a loop in this process."""
    from analyses.hose_life import hose_life
    from pipeline.raw.logbook import merge_logbooks, read_logbooks
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree
    from pipeline.stages.context import StageContext
    from pipeline.stages.durability import RUN_COLUMNS

    raw = Path(raw).resolve()
    events, _ = read_logbooks(raw)
    hoses, _ = merge_logbooks(events)
    runs = pd.DataFrame(columns=RUN_COLUMNS)
    life, _ = hose_life(hoses, runs)
    return StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results={"hose_life": life,
                                                                             "durability_runs": runs},
                        plan=read_plan(RawTree(raw)), mapper=lambda func, items, label: [func(i) for i in items])


def stage_tables(raw: Path) -> dict[str, pd.DataFrame]:
    """The decision stage's tables (:data:`DECISION_TABLES`) computed in this process from ``raw``."""
    from pipeline.stages import decision

    return dict(decision.run(stage_context(raw)).tables)


class StageRunTo:
    """The simulator's ``run_to``: the decision stage's frozen ``max_failures`` of one hose type from
    its logbook as it stands at a failure (None while the stage freezes none), with ``plan`` the
    campaign's plan.toml text. Below ``FEW_FAILURES / 2`` failures of an adjustment (the stage's own
    threshold, :func:`analyses.decision.freeze_look`) no look qualifies: None without running it."""

    def __init__(self, plan: str):
        self.plan = plan

    def __call__(self, rows: list[dict], truth: dict) -> int | None:
        from analyses.sequential import FEW_FAILURES
        from pipeline.simulator.campaign import csv_text
        from pipeline.simulator.decision import DECISION_CAMPAIGN
        from pipeline.simulator.hoses import HOSES_COLUMNS
        from pipeline.stages import decision

        adjustment = {r["hose_id"]: r["adjustment"] for r in rows if r["event"] == "installed"}
        failed = Counter(adjustment[r["hose_id"]] for r in rows if r["event"] == "failed")
        if min(failed.get("force", 0), failed.get("distance", 0)) < FEW_FAILURES / 2:
            return None
        with tempfile.TemporaryDirectory(prefix="run-to-") as tmp:
            raw = Path(tmp)
            (raw / DECISION_CAMPAIGN).mkdir()
            (raw / DECISION_CAMPAIGN / "hoses.csv").write_text(csv_text(rows, HOSES_COLUMNS), encoding="utf-8")
            (raw / "plan.toml").write_text(self.plan, encoding="utf-8")
            ctx = stage_context(raw)
            items = decision.hose_type_items(ctx)
            frozen, asks = decision.design_asks(ctx, items)
            designed = {json.dumps(a, sort_keys=True): decision.design_failures(a) for a in asks if a is not None}
            return decision.design_of(items[0], frozen[0], designed)[0]


def write_campaign(raw: Path, name: str, types: int, seed: int) -> dict:
    """A ``decision`` campaign of ``types`` hose types of scenario ``name`` written to ``raw``, each type
    run to the ``max_failures`` the stage freezes (:class:`StageRunTo`); its truth."""
    from pipeline.simulator.campaign import simulate_campaign
    from pipeline.simulator.decision import DecisionProfile, plan_toml

    plan = plan_toml(DecisionProfile(hose_types=types, scenario=name))
    simulate_campaign(raw, seed=seed, profile=DecisionProfile(hose_types=types, scenario=name, run_to=StageRunTo(plan)))
    return json.loads((Path(raw) / "truth.json").read_text())
