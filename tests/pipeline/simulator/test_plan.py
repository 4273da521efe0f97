"""Run plans: where the planner puts a run, when, in which variant, by which operator."""
from __future__ import annotations

from datetime import datetime

from pipeline.simulator.plan import CAMPAIGN_START, OPERATORS, Planner, RunSpec, iso
from pipeline.simulator.profiles import PROFILES
from pipeline.simulator.variants import VARIANTS


def _spec(stem, **kw):
    return RunSpec("plpa-2025", "leakage", "leakage", stem, {"chamber": "A"}, **kw)


def test_add_places_runs_on_the_campaign_clock_and_cycles_variants_and_operators():
    pl = Planner(PROFILES["mini"], seed=1)
    a = pl.add(_spec("a", meta={"hose_id": "H1"}), minutes=15)
    b = pl.add(_spec("b"))
    assert (a.index, b.index) == (0, 1)
    assert a.run_id == "plpa-2025/a" and a.kind == "leakage" and a.group == "leakage"
    assert a.rel_path == "plpa-2025/leakage/a.csv" and a.fmt == "csv"
    assert b.variant is VARIANTS["leakage"][1] and b.rel_path == "plpa-2025/leakage/eu/b.csv"
    assert a.metadata == {"run_id": "plpa-2025/a", "started_at": "2025-03-03T08:00:00", "operator": OPERATORS[0],
                          "hose_id": "H1"}
    assert b.metadata["started_at"] == "2025-03-03T08:15:00" and b.metadata["operator"] == OPERATORS[1]
    assert pl.clock["plpa-2025"] == datetime(2025, 3, 3, 8, 20)
    assert pl.plans == [a, b] and a.kwargs == {"chamber": "A"}


def test_add_at_a_given_time_leaves_the_clock_and_a_given_variant_is_used():
    pl = Planner(PROFILES["mini"], seed=1)
    v = VARIANTS["leakage"][2]
    plan = pl.add(_spec("x"), variant=v, when=datetime(2024, 1, 1, 6, 0))
    assert plan.metadata["started_at"] == "2024-01-01T06:00:00" and plan.fmt == "tdms"
    assert pl.clock == CAMPAIGN_START
    assert pl.variant("leakage", 1) is VARIANTS["leakage"][1]    # the count moved on anyway
    assert pl.add(_spec("y")).variant is VARIANTS["leakage"][1]


def test_the_characterisation_matrices():
    pl = Planner(PROFILES["demo"], seed=1)
    pl.leakage()
    pl.spring()
    pl.timeseries()
    assert len(pl.plans) == 2 * (7 + 3) + 120 + 2
    spring = [p for p in pl.plans if p.kind == "spring"]
    assert {p.run_id.split("/")[0] for p in spring} == {"pla-2016"} and len({p.run_id for p in spring}) == 120
    logger = [p for p in pl.plans if p.kind == "timeseries"]
    assert [p.metadata["started_at"] for p in logger] == ["2025-03-03T07:30:00", "2025-03-04T07:30:00"]
    assert [p.kwargs["supply"] for p in logger] == [True, False]


def test_iso():
    assert iso(datetime(2025, 3, 3, 8, 0, 5, 999)) == "2025-03-03T08:00:05"
