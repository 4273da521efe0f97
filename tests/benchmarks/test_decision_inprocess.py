"""benchmarks/decision_inprocess.py: on one small campaign, the decision stage run in-process gives the
warehouse's rows exactly (so bench_decision's big count is the product's behaviour), and each simulated
hose type ran to the max_failures the stage froze."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from benchmarks import bench_decision as bd
from benchmarks.decision_inprocess import DECISION_TABLES, StageRunTo, stage_tables, write_campaign
from benchmarks.proc import measure, pneubench_cmd
from pipeline.simulator.decision import DecisionProfile, plan_toml

KEYS = {"life_effect": ["hose_type"], "life_verdict": ["hose_type"], "decision_looks": ["hose_type", "look"],
        "decision_look_hoses": ["hose_type", "look", "hose_id"]}


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Three hose types (one per scenario), each run to its frozen max_failures, rebuilt by
    `pneubench rebuild` as a process, and the same raw tree through the stage in-process."""
    root = tmp_path_factory.mktemp("inprocess")
    raw, wh = root / "raw", root / "wh"
    truth = write_campaign(raw, "mixed", 3, 4)
    m = measure([*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--no-report",
                 "--jobs", "1"])
    assert m.exit_code == 0, m.stderr[-2000:]
    return truth, bd.read_tables(wh / "pneubench.duckdb"), stage_tables(raw)


def _plain(v):
    """A cell as plain comparable data: times as UTC nanoseconds, every missing value None, lists as tuples."""
    if isinstance(v, (list, tuple, np.ndarray)):
        return tuple(_plain(x) for x in v)
    if v is None or v is pd.NA or v is pd.NaT or (isinstance(v, float) and math.isnan(v)):
        return None
    if isinstance(v, pd.Timestamp):
        return v.tz_convert("UTC").value if v.tzinfo else v.tz_localize("UTC").value
    if isinstance(v, (np.integer, np.bool_)):
        return v.item()
    if isinstance(v, np.floating):
        return float(v)
    return v


def _rows(df: pd.DataFrame, keys: list[str]) -> list[tuple]:
    df = df.sort_values(keys, ignore_index=True)
    return [tuple(_plain(v) for v in row) for row in zip(*(df[c].tolist() for c in sorted(df.columns)))]


@pytest.mark.parametrize("table", DECISION_TABLES)
def test_the_in_process_stage_gives_the_warehouses_rows_exactly(campaign, table):
    _, warehouse, inprocess = campaign
    mine, theirs = inprocess[table], warehouse[table]
    assert sorted(mine.columns) == sorted(theirs.columns)
    assert len(theirs) > 0 and _rows(mine, KEYS[table]) == _rows(theirs, KEYS[table])


def test_each_type_ran_to_the_max_failures_the_stage_froze(campaign):
    truth, warehouse, _ = campaign
    v = warehouse["life_verdict"].set_index("hose_type")
    assert len(v) == 3
    for name, t in truth["hose_types"].items():
        assert t["stopped_by"] == "max_failures" and t["run_to"] == v.loc[name, "max_failures"]
        assert v.loc[name, "max_failures_from"] == "design"
        assert t["n_failed"] == v.loc[name, "failures"] >= t["run_to"]
    assert truth["settings"]["run_to"] == "StageRunTo"


def test_run_to_waits_for_five_failures_of_each_adjustment():
    """Four force-set failures and twenty distance-set ones: no look qualifies, None without a stage run."""
    rows = []
    for i in range(24):
        adj = "force" if i < 4 else "distance"
        rows += [{"hose_id": f"T-H{i:03d}", "event": "installed", "at": "2025-01-06T07:00:00", "hose_type": "T",
                  "adjustment": adj},
                 {"hose_id": f"T-H{i:03d}", "event": "failed", "at": f"2025-01-{10 + i % 18:02d}T07:00:00",
                  "distance_km": 80.0 + i}]
    assert StageRunTo(plan_toml(DecisionProfile()))(rows, {}) is None
