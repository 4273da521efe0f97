"""Speed of the remaining-life stage (issue 24: under 5 s for the demo's hoses).

One command::

    python -m benchmarks.bench_remaining_life_stage                  # the demo's rebuild as processes, then the detail
    python -m benchmarks.bench_remaining_life_stage --in-process     # the detail only: a demo-sized hose type
    python -m benchmarks.bench_remaining_life_stage --quick          # the detail, 4 hoses per adjustment (a look)
    python -m benchmarks.bench_remaining_life_stage --warehouse WH   # the stage on a built warehouse's tables (the demo's)
    python -m benchmarks.bench_remaining_life_stage --same-as main --warehouse WH   # the same tables as main's code?

**As a process** (the default; what a user runs): the demo simulated and rebuilt once (not timed), then
whole ``pneubench rebuild`` processes on copies of that warehouse after the plan's ``leak_limit_l_min``
changed by 1 % (every remaining-life item new: cold), with and without the remaining-life stage
(:func:`benchmarks.bench_decision_stage.added_by`; the decision stages, which read every plan key,
re-run on both sides), and a no-op rebuild: wall and process-tree CPU seconds, and the difference
against 5 s of wall.

**Detail, in this process.** Synthetic hoses (seeded): one hose type, force- and distance-set hoses whose leak at 6 bar grows as
``(w d)^1.5`` l/min with a lognormal wear rate ``w`` per hose, checked every 2 km on plateaus 0..6 bar,
failed when the leak reaches the limit, else running. With ``--warehouse`` the stage reads that
warehouse's ``hose_life``, ``hose_leak_growth``, ``leakage_map`` and ``life_verdict`` with a plan that
sets ``leak_limit_l_min`` (``--limit``, default 4 l/min) and ``leak_pressure_bar`` (6 bar) for every
hose type. Timed in this process (one worker: the demo has one hose type, two groups): wall and CPU
seconds of :func:`pipeline.stages.remaining_life.run`, and its parts (the models and backtests per
group, the sensitivity per hose type). The machine's load average is printed beside: on a shared
machine the wall time is the CPU time stretched by the load. PASS/MISS against 5 s (CPU seconds,
which do not depend on the other work on the machine).

**Same results** (``--same-as REF``): a change meant only to make the stage faster must give the same
floats. The stage's three tables are computed on the same input (the ``--warehouse``'s tables, else
the synthetic ones) by this checkout and by ``REF`` (a commit or branch, exported with ``git archive``:
:func:`benchmarks.same_behaviour.export`), each in its own process, and compared exactly (every
column, every bit: ``pandas.testing.assert_frame_equal(check_exact=True)``). Exit 1 when any differs.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np
import pandas as pd

TARGET_S = 5.0
SENSORS = "p_supply: resolution 100, noise 50 (metadata) Pa; q_leak: resolution 1e-07, noise 5e-08 (metadata) kg/s"


def synthetic(n: int, seed: int = 1, limit: float = 2.0) -> dict[str, pd.DataFrame]:
    """The stage's input tables for one hose type of ``n`` hoses per adjustment (module docstring)."""
    rng = np.random.default_rng(seed)
    hoses, growth = [], []
    for adj, wear in (("force", 0.02), ("distance", 0.05)):
        for i in range(n):
            hid = f"{adj[0].upper()}{i:02d}"
            w = wear * math.exp(0.3 * rng.normal())
            life = limit ** (1 / 1.5) / w
            stop = rng.uniform(0.3, 1.5) * limit ** (1 / 1.5) / wear
            end = min(life, stop)
            hoses.append({"hose_id": hid, "hose_type": "T", "adjustment": adj, "distance_km": end,
                          "status": "failed" if life < stop else "running",
                          "failure_mode": "leakage" if life < stop else None})
            for k, d in enumerate(np.arange(2.0, end, 2.0)):
                q = (w * d) ** 1.5 * math.exp(0.05 * rng.normal())
                growth += [{"hose_id": hid, "run_id": f"check-{hid}-{k:02d}", "distance_km": float(d), "chamber": "A",
                            "pressure_bar": float(p), "leak_l_min": q * p / 6.0} for p in range(7)]
    g = pd.DataFrame(growth)
    return {"hose_life": pd.DataFrame(hoses), "hose_leak_growth": g,
            "leakage_map": pd.DataFrame({"run_id": sorted(set(g["run_id"])), "sensors": SENSORS}),
            "life_verdict": pd.DataFrame({"hose_type": ["T"], "max_failures": [20], "verdict": ["undecided"]})}


def from_warehouse(path: str) -> dict[str, pd.DataFrame]:
    """The stage's input tables read from a built warehouse."""
    from pipeline.serve.door import connect_readonly
    from pipeline.stages import remaining_life

    con = connect_readonly(path)
    try:
        have = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
        return {t: con.execute(f"SELECT * FROM {t}").df() for t in remaining_life.READS.tables if t in have}
    finally:
        con.close()


def timed(tables: dict[str, pd.DataFrame], limit: float) -> dict[str, tuple[float, float]]:
    """(wall, CPU) seconds of the stage and of its parts on ``tables``, one process."""
    from pipeline.raw.plan import Plan
    from pipeline.stages import StageContext
    from pipeline.stages import remaining_life as stage

    plan = Plan(present=True, defaults={"leak_limit_l_min": limit, "leak_pressure_bar": 6.0})
    ctx = StageContext(raw=None, warehouse=None, runs=pd.DataFrame(), results=tables, plan=plan)
    out = {}

    def clock(name, func, *args):
        t, c = time.perf_counter(), time.process_time()
        res = func(*args)
        out[name] = (time.perf_counter() - t, time.process_time() - c)
        return res

    groups, types = clock("items: leak paths at the plan's pressure, sensors", stage.stage_items, ctx)
    clock(f"models + backtests ({len(groups)} groups)", lambda: [stage.rul_group(g) for g in groups])
    clock(f"sensitivity ({len(types)} hose types x 4 definitions)", lambda: [stage.sensitivity_of(t) for t in types])
    clock("the whole stage", stage.run, ctx)
    return out


#: Run in a process whose ``PYTHONPATH`` is one version's tree: the stage's tables on the input
#: ``argv[1]`` (a warehouse, or ``synthetic:N``) with the plan's ``leak_limit_l_min`` ``argv[2]``, pickled to ``argv[3]``.
_STAGE_TABLES = """
import pickle, sys
import pandas as pd
from benchmarks.bench_remaining_life_stage import from_warehouse, synthetic
from pipeline.raw.plan import Plan
from pipeline.stages import StageContext
from pipeline.stages import remaining_life as stage
src, limit, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
tables = synthetic(int(src.split(":")[1])) if src.startswith("synthetic:") else from_warehouse(src)
plan = Plan(present=True, defaults={"leak_limit_l_min": limit, "leak_pressure_bar": 6.0})
res = stage.run(StageContext(raw=None, warehouse=None, runs=pd.DataFrame(), results=tables, plan=plan))
pickle.dump(dict(res.tables), open(out, "wb"))
"""


def same_as(ref: str, source: str, limit: float) -> bool:
    """Whether this checkout's stage gives the same tables as ``ref``'s on ``source`` (a warehouse, or
    ``synthetic:N``), bit for bit; prints one line per table."""
    from benchmarks.same_behaviour import stage_tables_same

    return stage_tables_same(ref, _STAGE_TABLES, [source, repr(limit)], "pneubench-rul-same-")


def on_demo(repeat: int) -> bool:
    """What the remaining-life stage adds to a rebuild of the demo, as whole ``pneubench rebuild`` processes
    (:func:`benchmarks.bench_decision_stage.added_by`): the plan's ``leak_limit_l_min`` changed by 1 %
    (every item new: cold), the same rebuild with and without the stage, on copies of one warm warehouse.
    PASS when the wall difference is under :data:`TARGET_S`."""
    import tempfile
    from pathlib import Path

    from benchmarks.bench_decision_stage import added_by, first_rebuild, plan_changer, report_added
    from pipeline.simulator.campaign import simulate_demo
    from pipeline.simulator.profiles import LEAK_LIMIT_L_MIN

    with tempfile.TemporaryDirectory(prefix="pneubench-rul-proc-") as tmp:
        raw, wh = Path(tmp) / "raw", Path(tmp) / "wh"
        raw.mkdir()
        simulate_demo(raw)
        print("the demo campaign:")
        first_rebuild(raw, wh, ())
        change = plan_changer(raw / "plan.toml", f"leak_limit_l_min = {LEAK_LIMIT_L_MIN!r}",
                              f"leak_limit_l_min = {LEAK_LIMIT_L_MIN * 1.01!r}")
        res = added_by(raw, wh, change, ("remaining_life",), repeat, ())
        return report_added(f"the demo, plan leak_limit_l_min {LEAK_LIMIT_L_MIN:g} -> {LEAK_LIMIT_L_MIN * 1.01:g} l/min "
                            "(the remaining-life stage re-runs cold; the decision stages too, on both sides)",
                            res, TARGET_S, ("remaining_life",))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="in this process only, 4 hoses per adjustment (seconds)")
    ap.add_argument("--in-process", action="store_true", help="the stage in this process only (no rebuilds)")
    ap.add_argument("--repeat", type=int, default=1, help="measured rebuilds of each kind (medians; default 1)")
    ap.add_argument("--warehouse", help="time the stage on this built warehouse's tables (the demo's)")
    ap.add_argument("--limit", type=float, default=4.0, help="leak_limit_l_min of the plan with --warehouse [l/min]")
    ap.add_argument("--same-as", metavar="REF", help="only compare the stage's tables with REF's code (bit for bit)")
    a = ap.parse_args(argv)
    if a.same_as:
        source = a.warehouse or f"synthetic:{4 if a.quick else 8}"
        limit = a.limit if a.warehouse else 2.0
        print(f"the remaining_life stage's tables on {source}, this checkout against {a.same_as}:")
        return 0 if same_as(a.same_as, source, limit) else 1
    ok = True
    if not (a.quick or a.in_process or a.warehouse):
        ok = on_demo(a.repeat)
        print("detail, in this process:")
    if a.warehouse:
        tables, limit, what = from_warehouse(a.warehouse), a.limit, f"warehouse {a.warehouse}"
    else:
        n = 4 if a.quick else 8
        tables, limit, what = synthetic(n), 2.0, f"synthetic: 1 hose type, {n} hoses per adjustment"
    life = tables.get("hose_life", pd.DataFrame(columns=["status"]))
    print(f"remaining_life stage on {what}: {len(life)} hoses, {int((life['status'] == 'running').sum())} running, "
          f"{len(tables.get('hose_leak_growth', []))} leak plateaus; limit {limit:g} l/min at 6 bar")
    res = timed(tables, limit)
    for name, (wall, cpu) in res.items():
        print(f"  {name:<55} wall {wall:7.2f} s   cpu {cpu:7.2f} s")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    wall, cpu = res["the whole stage"]
    print(f"load average {load:.1f} on {os.cpu_count()} cores")
    print(f"stage cpu {cpu:.2f} s (wall {wall:.2f} s) against {TARGET_S:g} s: {'PASS' if cpu < TARGET_S else 'MISS'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
