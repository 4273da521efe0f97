"""Speed of the decision stage (issue 23: it adds under 10 s at 200 hose types, under 2 s to the demo).

One command::

    python -m benchmarks.bench_decision_stage                 # 200 hose types, ~30 hoses, ~20 failures each
    python -m benchmarks.bench_decision_stage --large         # 200 hose types, ~64 hoses, ~60 failures each
    python -m benchmarks.bench_decision_stage --quick         # 20 hose types (a look)
    python -m benchmarks.bench_decision_stage --warehouse WH  # also the decision and test_plan stages on a built
                                                              # warehouse's tables (the demo's), cold

Synthetic hose types (seeded): 15 hoses per adjustment installed in waves on benches, Weibull lives
(shape 2.5, force-set 1.3x longer), durability runs of 5 km (8 h) logged for two hoses in three,
odometer readings only for the others, the test stopped when about 20 have failed (``--large``: 32
hoses per adjustment stopped at about 60 failures, the size of the ``decision`` simulator profile's
hose types, where ``bench_decision``'s timing run measured the stages). A logbook
(``hoses.csv``) is written to a temporary raw/ so the stage reads and matches runs as in a rebuild.
Timed in this process:

* first, the designed case: a first rebuild's decision and test_plan stages (cold: no memo, and
  :func:`analyses.sequential.clear_caches`), ``max_failures`` unset in the plan (margin
  :data:`DESIGN_MARGIN`, the demo's and the ``decision`` profile's), on a campaign whose hose types
  vary in shape (1.5-3.5) and hoses (8-``size``), so that each stage computes one sequential design
  (:func:`analyses.sequential.design_for`) per distinct (grid shape, hoses on test): the count is
  printed; target < 10 s for the decision stage at 200 hose types;

then with the plan setting ``max_failures`` (the lab's usual case once ``test_plan`` has been read):

* baseline: :func:`pipeline.stages.durability.service_life` on the same ``hose_life`` (what a rebuild
  already spends on these hoses);
* the stage's parts: ``life_effect`` (profile-likelihood bounds), the looks (a common-shape fit at
  every failure and the sequential verdict), reading and matching the logbooks;
* the whole stage (:func:`pipeline.stages.decision.run`) with one and two worker processes.

Printed: wall seconds (what the target is about) and this process's CPU seconds (steadier on a shared
machine; the 2-process run's workers are not in it), the ratio to the baseline and PASS/MISS against
10 s (200 types) or 2 s (a warehouse).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

HEADER = "hose_id,event,at,hose_type,adjustment,z_rollers_mm,spring_force_n,failure_mode,wall_thickness_mm,distance_km,notes\n"
START = pd.Timestamp("2026-01-05T08:00", tz="UTC")
RUN_KM, KM_PER_H = 5.0, 5.0 / 8.0
#: The plan's margin in the designed case (the demo's FLEXIGOM AIR and the ``decision`` profile's).
DESIGN_MARGIN = 1.5


def _hose_type(rng, t: int, n: int, lines: list, runs: list, failures: int = 20, shape: float = 2.5) -> None:
    """One hose type's logbook lines and runs: n hoses per adjustment, Weibull lives of ``shape``, stopped
    near ``failures`` failures."""
    adj = np.repeat(["distance", "force"], n)
    life = np.where(adj == "force", 1.3, 1.0) * 40.0 * rng.weibull(shape, 2 * n)
    installed = START + pd.to_timedelta(rng.integers(0, 20, 2 * n) * 24, unit="h")
    end_h = life / KM_PER_H
    stop = np.sort((installed - START) / pd.Timedelta(hours=1) + end_h)[min(failures - 1, 2 * n - 1)] + 1.0
    for i in range(2 * n):
        hid = f"T{t:03d}-{i:02d}"
        h0 = (installed[i] - START) / pd.Timedelta(hours=1)
        failed = h0 + end_h[i] <= stop
        km = life[i] if failed else max(0.0, (stop - h0) * KM_PER_H)
        lines.append(f"{hid},installed,{installed[i].isoformat()},TYPE {t:03d},{adj[i]},4.5,866,,,,\n")
        by_runs = i % 3 != 2
        if by_runs:
            done = 0.0
            while done < km - 1e-9:
                d = min(RUN_KM, km - done)
                runs.append({"run_id": f"{hid}/r{len(runs)}", "hose_id": hid,
                             "started_at": installed[i] + pd.Timedelta(hours=done / KM_PER_H),
                             "duration_h": d / KM_PER_H, "distance_km": d, "strokes": int(d * 1000)})
                done += d
        if failed:
            at = installed[i] + pd.Timedelta(hours=end_h[i])
            lines.append(f"{hid},failed,{at.isoformat()},,,,,rupture,,{'' if by_runs else f'{km:.3f}'},\n")


def campaign(types: int, seed: int, root: Path, size: tuple[int, int] = (15, 20),
             varied: bool = False) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Write raw/c/hoses.csv under ``root``; the ``hose_life`` and ``durability_runs`` a rebuild would give
    (``size``: hoses per adjustment, failures at which each type's test stops; ``varied``: each type's
    shape drawn from 1.5..3.5 and its hoses per adjustment from 8..``size[0]``, so that the designs differ)."""
    from analyses.hose_life import hose_life
    from pipeline.raw.logbook import merge_logbooks, read_logbooks

    rng = np.random.default_rng(seed)
    lines, runs = [], []
    for t in range(types):
        if varied:
            _hose_type(rng, t, int(rng.integers(8, size[0] + 1)), lines, runs, size[1], float(rng.uniform(1.5, 3.5)))
        else:
            _hose_type(rng, t, size[0], lines, runs, size[1])
    (root / "c").mkdir(parents=True, exist_ok=True)
    (root / "c" / "hoses.csv").write_text(HEADER + "".join(lines))
    runs_df = pd.DataFrame(runs)
    hoses, problems = merge_logbooks(read_logbooks(root)[0])
    assert not problems, problems[:3]
    return hose_life(hoses, runs_df)[0], runs_df


def _timed(func, *args):
    """(result, wall seconds, this process's CPU seconds)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = func(*args)
    return out, time.perf_counter() - t0, time.process_time() - c0


def time_stage(raw: Path, life: pd.DataFrame, runs: pd.DataFrame, plan, jobs: int) -> tuple[float, float]:
    """(wall, CPU) seconds of the whole stage on these tables."""
    from pipeline.stages import StageContext
    from pipeline.stages import decision

    ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results={"hose_life": life, "durability_runs": runs},
                       jobs=jobs, plan=plan)
    return _timed(decision.run, ctx)[1:]


def parts(raw: Path, life: pd.DataFrame, runs: pd.DataFrame, plan) -> dict[str, tuple[float, float]]:
    """(wall, CPU) seconds of each part of the stage, one process."""
    from pipeline.stages import StageContext
    from pipeline.stages import decision
    from pipeline.stages.durability import service_life

    out = {"baseline: durability service_life": _timed(service_life, life)[1:]}
    ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results={"hose_life": life, "durability_runs": runs},
                       plan=plan)
    items, *out["logbooks read, runs matched, items"] = _timed(decision.hose_type_items, ctx)
    out["life_effect (profile bounds)"] = _timed(lambda: [decision.effect_of(it) for it in items])[1:]
    for it in items:
        it["design"] = decision.design_of(it, None, {})   # the plan sets max_failures here
    out["looks (a fit at every failure) + verdict"] = _timed(lambda: [decision.decide_hose_type(it) for it in items])[1:]
    return out


def _plan(max_failures: int | None):
    from pipeline.raw.plan import Plan

    return Plan(present=True, defaults={"margin": DESIGN_MARGIN} if max_failures is None else
                {"max_failures": max_failures})


def designed(types: int, seed: int, size: tuple[int, int]) -> dict[str, tuple[float, float]]:
    """(wall, CPU) seconds of a first rebuild's decision and test_plan stages, one process, cold, on a
    campaign of varied hose types with ``max_failures`` left to the design; also the number of
    distinct designs (``"designs"``, as (count, hose types))."""
    from analyses import sequential
    from pipeline.stages import StageContext, decision, test_plan

    clear = getattr(sequential, "clear_caches", None)   # absent before designs were made cheap: a fresh process is cold
    if clear is not None:
        clear()
    with tempfile.TemporaryDirectory(prefix="pneubench-design-") as tmp:
        raw = Path(tmp)
        life, runs = campaign(types, seed, raw, size, varied=True)
        ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(),
                           results={"hose_life": life, "durability_runs": runs}, jobs=1, plan=_plan(None))
        out, *times = _timed(decision.run, ctx)
        ctx2 = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), jobs=1, plan=_plan(None),
                            results={"hose_life": life, "durability_runs": runs,
                                     "life_effect": out.tables["life_effect"],
                                     "life_verdict": out.tables["life_verdict"]})
        plan_times = _timed(test_plan.run, ctx2)[1:]
        items = decision.hose_type_items(ctx)
        asks = {str(a) for a in decision.design_asks(ctx, items)[1] if a is not None}
    return {"designs": (len(asks), len(items)), "decision": tuple(times), "test_plan": plan_times}


def on_warehouse(wh: Path, raw: Path) -> dict[str, tuple[float, float]]:
    """(wall, CPU) seconds of the decision and test_plan stages on a built warehouse's tables (its raw/ for
    the logbooks and plan.toml), one process, cold (:func:`analyses.sequential.clear_caches`)."""
    import duckdb

    from analyses import sequential
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree
    from pipeline.stages import StageContext, decision, test_plan

    con = duckdb.connect(str(wh / "pneubench.duckdb"), read_only=True)
    try:
        life, runs = (con.execute(f"SELECT * FROM {t}").df() for t in ("hose_life", "durability_runs"))
    finally:
        con.close()
    getattr(sequential, "clear_caches", lambda: None)()
    plan = read_plan(RawTree(raw))
    ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results={"hose_life": life, "durability_runs": runs},
                       jobs=1, plan=plan)
    out, *times = _timed(decision.run, ctx)
    ctx2 = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), jobs=1, plan=plan,
                        results={"hose_life": life, "durability_runs": runs, "life_effect": out.tables["life_effect"],
                                 "life_verdict": out.tables["life_verdict"]})
    return {"decision": tuple(times), "test_plan": _timed(test_plan.run, ctx2)[1:]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_decision_stage", description=__doc__.splitlines()[0])
    ap.add_argument("--types", type=int, default=200, help="synthetic hose types (default 200)")
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--quick", action="store_true", help="20 hose types")
    ap.add_argument("--large", action="store_true", help="32 hoses per adjustment, ~60 failures a type")
    ap.add_argument("--warehouse", type=Path, help="also time the stage on this warehouse's tables")
    ap.add_argument("--raw", type=Path, help="its raw/ (default: WAREHOUSE/../raw)")
    args = ap.parse_args(argv)
    types = 20 if args.quick else args.types
    target = 10.0 * types / 200
    first = designed(types, args.seed, (32, 60) if args.large else (20, 20))   # first: this process is still cold
    (n_designs, n_types), (s, cpu), (s2, cpu2) = first["designs"], first["decision"], first["test_plan"]
    print(f"designed max_failures (margin {DESIGN_MARGIN}, no max_failures in the plan): {n_types} hose types, "
          f"{n_designs} distinct designs, a first rebuild (cold), 1 process:")
    print(f"  decision stage  {s:7.2f} s (CPU {cpu:6.2f} s); target < {target:.0f} s: {'PASS' if s < target else 'MISS'}")
    print(f"  test_plan stage {s2:7.2f} s (CPU {cpu2:6.2f} s); both stages {s + s2:.2f} s (CPU {cpu + cpu2:.2f} s)")
    ok = s < target
    with tempfile.TemporaryDirectory(prefix="pneubench-decision-") as tmp:
        raw = Path(tmp)
        life, runs = campaign(types, args.seed, raw, (32, 60) if args.large else (15, 20))
        failed = life[life["status"] == "failed"].groupby("hose_type").size()
        print(f"decision stage: {types} hose types, {len(life)} hoses, {len(runs)} durability runs, "
              f"{failed.mean():.1f} failures a type (seed {args.seed})")
        split = parts(raw, life, runs, _plan(40 if not args.large else 70))
        base = split["baseline: durability service_life"][0]
        for name, (s, cpu) in split.items():
            print(f"  {name:45s} {s:7.2f} s  ({s / base:6.1f}x baseline)  CPU {cpu:7.2f} s")
        for jobs in (1, 2):
            s, cpu = time_stage(raw, life, runs, _plan(40 if not args.large else 70), jobs)
            verdict = "PASS" if s < target else "MISS"
            ok &= s < target or jobs == 1
            print(f"  whole stage, max_failures in the plan, {jobs} process(es): {s:7.2f} s ({s / base:.1f}x baseline) "
                  f"CPU here {cpu:.2f} s; target < {target:.0f} s: {verdict}")
    if args.warehouse:
        wh = on_warehouse(args.warehouse, args.raw or args.warehouse.parent / "raw")
        (s, cpu), (s2, cpu2) = wh["decision"], wh["test_plan"]
        print(f"on {args.warehouse} (cold, 1 process): decision {s:.2f} s (CPU {cpu:.2f} s), test_plan {s2:.2f} s "
              f"(CPU {cpu2:.2f} s); both {s + s2:.2f} s, target < 2 s: {'PASS' if s + s2 < 2 else 'MISS'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
