"""Speed of the decision stages (issue 23: they add under 10 s at 200 hose types, under 2 s to the demo).

One command::

    python -m benchmarks.bench_decision_stage                 # the demo and 200 hose types, as processes
    python -m benchmarks.bench_decision_stage --no-demo       # 200 hose types only
    python -m benchmarks.bench_decision_stage --types 0       # the demo only
    python -m benchmarks.bench_decision_stage --quick         # 20 hose types, no demo (a look)
    python -m benchmarks.bench_decision_stage --detail        # also the in-process breakdown below
    python -m benchmarks.bench_decision_stage --warehouse WH  # also the two stages on a built warehouse's tables
    python -m benchmarks.bench_decision_stage --same-as main  # the same tables as main's code? (12 types, bit for bit)
    python -m benchmarks.bench_decision_stage --no-demo --ref main --repeat 2   # main's code and this, alternately

**What is measured: what a user runs.** Whole ``pneubench rebuild`` processes (all cores, the
report written), timed by :func:`benchmarks.proc.measure`: wall seconds and the CPU seconds of the
process tree (the rebuild and every worker it started). From one warm warehouse (a first rebuild,
not timed) and a copy of it settled by one untimed rebuild, both rebuilt in place (:func:`added_by`),
the plan's ``power`` goes from 0.8 to 0.81 and back, round by round, which only the decision and
test_plan stages read among the stages compared: every hose type's looks and plan rows are new, so the
stages re-run cold (no memo entry, no design in any process); since session 23 the ``life_effect``
items carry only what they read (not the power: taken from the memo) and the even designs' boundaries are
read from the warehouse's ``cache/designs-<key>.npz`` (written by the first rebuild), as in a lab's rebuild
after a plan change; since session 24 only what reads the power re-runs: the designs at the new power, and the
looks and simulations of the hose types whose ``max_failures`` or ``failures_needed`` it moved (the others,
the frozen looks and the designs at 0.9 come from the memo). The in-process designed case (``--detail``) stays cold: no memo, no designs file. The same rebuild is run with every stage and
with the two stages absent (``pneubench`` with them left out of the stage registry: the baseline a
lab without them would run), alternately, and a no-op rebuild beside; the difference is what the
decision stages add (their tables assembled and their report section included). The
remaining-life stage is left out of both sides (:data:`NOT_COMPARED`: it reads ``life_verdict``, so
it re-runs whenever that changes; ``bench_remaining_life_stage`` measures it). The stages' own wall
from the rebuild's log is printed beside. PASS when the wall added is under the target (2 s on the
demo, 10 s at 200 hose types, in proportion for other counts).

Campaigns: the demo (:func:`pipeline.simulator.campaign.simulate_demo`, its plan.toml) and a
synthetic one of ``--types`` hose types of varied shape (1.5-3.5) and hoses (8-20 per adjustment),
about 20 failures each, known by their logbook odometer only (the ``decision`` simulator profile's
form: no run files to ingest), margin 1.5, ``max_failures`` left to the design.

**Detail** (``--detail``), in this process:

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
  printed;

then with the plan setting ``max_failures`` (the lab's usual case once ``test_plan`` has been read):

* baseline: :func:`pipeline.stages.durability.service_life` on the same ``hose_life`` (what a rebuild
  already spends on these hoses);
* the stage's parts: ``life_effect`` (profile-likelihood bounds), the looks (a common-shape fit at
  every failure and the sequential verdict), reading and matching the logbooks;
* the whole stage (:func:`pipeline.stages.decision.run`) with one and two worker processes.

Printed: wall seconds and this process's CPU seconds (the 2-process run's workers are not in it) and
the ratio to the baseline; no verdict (the verdict is the processes').

**Same results** (``--same-as REF``): a change meant only to make the stages faster must give the same
floats. The designed case's campaign (``--types``, default 12 here; ``--seed``) is built by this checkout
and by ``REF`` (a commit or branch, exported with ``git archive``: :func:`benchmarks.same_behaviour.export`),
each in its own process with two workers, and both stages' tables (``life_effect``, ``life_verdict``,
``decision_looks``, ``decision_look_hoses``, ``test_plan``, and the bench schedule's hose-km behind each
``expected_decision_date``, which the table rounds to a day) are compared exactly (every column, every bit:
``pandas.testing.assert_frame_equal(check_exact=True)``). Exit 1 when any differs.
"""
from __future__ import annotations

import argparse
import os
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


def _hose_type(rng, t: int, n: int, lines: list, runs: list, failures: int = 20, shape: float = 2.5,
               odometer_only: bool = False) -> None:
    """One hose type's logbook lines and runs: n hoses per adjustment, Weibull lives of ``shape``, stopped
    near ``failures`` failures; ``odometer_only``: no durability runs, every hose known by its logbook
    odometer (a running hose's read at the stop, a removal and a reinstallation a minute later, as the
    ``decision`` simulator profile writes it)."""
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
        by_runs = i % 3 != 2 and not odometer_only
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
        elif odometer_only and km > 0:
            at = START + pd.Timedelta(hours=stop)
            lines.append(f"{hid},removed,{at.isoformat()},,,,,,,{km:.3f},odometer read; test continues\n")
            lines.append(f"{hid},installed,{(at + pd.Timedelta(minutes=1)).isoformat()},TYPE {t:03d},{adj[i]},"
                         "4.5,866,,,,reinstalled after the reading\n")


def campaign(types: int, seed: int, root: Path, size: tuple[int, int] = (15, 20),
             varied: bool = False, odometer_only: bool = False) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Write raw/c/hoses.csv under ``root``; the ``hose_life`` and ``durability_runs`` a rebuild would give
    (``size``: hoses per adjustment, failures at which each type's test stops; ``varied``: each type's
    shape drawn from 1.5..3.5 and its hoses per adjustment from 8..``size[0]``, so that the designs differ)."""
    from analyses.hose_life import hose_life
    from pipeline.raw.logbook import merge_logbooks, read_logbooks

    rng = np.random.default_rng(seed)
    lines, runs = [], []
    for t in range(types):
        if varied:
            _hose_type(rng, t, int(rng.integers(8, size[0] + 1)), lines, runs, size[1], float(rng.uniform(1.5, 3.5)),
                       odometer_only)
        else:
            _hose_type(rng, t, size[0], lines, runs, size[1], odometer_only=odometer_only)
    (root / "c").mkdir(parents=True, exist_ok=True)
    (root / "c" / "hoses.csv").write_text(HEADER + "".join(lines))
    runs_df = pd.DataFrame(runs, columns=["run_id", "hose_id", "started_at", "duration_h", "distance_km", "strokes"])
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


#: The synthetic campaign's plan.toml (``{power}``: the plan change that re-runs only the decision stages).
SYNTH_PLAN = """# bench_decision_stage: margin 1.5, max_failures left to the design
[defaults]
margin = 1.5
alpha = 0.05
power = {power}
confidence = 0.9
spending = "obrien-fleming"
benches = 2
km_per_day = 30.0
"""
#: The stages whose added cost is measured (the decision and the test plan read the same plan keys).
DECISION_STAGES = ("decision", "test_plan")
#: Stages left out of both sides of the comparison: the remaining-life stage reads ``life_verdict``, so any
#: change of it (here its ``power`` column) re-runs that stage whole; measured by
#: ``benchmarks/bench_remaining_life_stage.py``, not counted here.
NOT_COMPARED = ("remaining_life",)
#: ``pneubench`` without some stages: the baseline a lab without them would run (``{names}``: the dropped).
_WITHOUT = ("import sys; import pipeline.stages as s; d = s.discover; "
            "s.discover = lambda: [m for m in d() if m.NAME not in {names!r}]; "
            "from pipeline.cli import main; main()")


def tree_env(tree: Path | None) -> dict | None:
    """The environment of a rebuild importing ``tree``'s code (None: this checkout's, the default environment)."""
    if tree is None:
        return None
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PNEUBENCH_RAW",
                                                              "PNEUBENCH_WAREHOUSE")}
    return dict(env, PYTHONPATH=str(tree))


def rebuild_cmd(raw: Path, wh: Path, without: tuple = (), probe: bool = True) -> list[str]:
    """``pneubench rebuild`` of ``raw`` into ``wh`` as a user runs it (all cores), or, with ``without``,
    the same command with those stages absent (their tables absent from the warehouse and the report); ``probe``:
    the rebuild tells its parts at exit (:mod:`benchmarks.decision_probe`, session 26; both sides alike)."""
    from benchmarks.decision_probe import PROBE
    from benchmarks.proc import pneubench_cmd

    cmd = pneubench_cmd() if not without else [sys.executable, "-c", _WITHOUT.format(names=sorted(without))]
    if probe:
        cmd = cmd[:2] + [PROBE + "\n" + cmd[2]]
    return cmd + ["rebuild", "--raw", str(raw), "--warehouse", str(wh)]


def stage_seconds(log: str, name: str) -> float | None:
    """The stage's own time as the rebuild's progress line gives it (``stage NAME ran: ... (1.2 s``)."""
    import re

    m = re.search(rf"stage {name} ran: .*?\((\d+(?:\.\d+)?) (ms|s|min)\b", log)
    if m is None:
        return None
    return float(m.group(1)) * {"ms": 1e-3, "s": 1.0, "min": 60.0}[m.group(2)]


def stage_names() -> list[str]:
    """Every stage's name, in the order the rebuild runs them."""
    from pipeline import stages

    return [m.NAME for m in stages.run_order(stages.discover())]


def added_by(raw: Path, warm: Path, change, stages: tuple, repeat: int, common: tuple = NOT_COMPARED) -> dict:
    """Whole ``pneubench rebuild`` processes, each after a plan change: with every stage but ``common``
    (default :data:`NOT_COMPARED`) on the warm warehouse ``warm``, and with ``stages`` absent too on a
    second warehouse (a copy of ``warm`` settled by one untimed rebuild without them), ``repeat`` rounds,
    alternately; and a no-op rebuild (nothing changed) of ``warm`` after each round's ``with`` run.
    Round ``r`` applies ``change(r % 2 == 0)``: the plan goes to the changed value and back, each a change
    for both warehouses (``change(False)`` restores it at the end). Both warehouses are rebuilt in place:
    a copied warehouse re-runs stages whose inputs did not change (session 19), which a copy before every
    run would add to both sides.
    Returns the :class:`benchmarks.proc.Series` by ``"with"``, ``"without"``, ``"no-op"`` and the stages'
    own seconds in the ``with`` runs (``"own"``: stage -> list)."""
    import shutil

    from benchmarks.decision_probe import lines, parse
    from benchmarks.proc import Series, measure

    out = {k: Series(k) for k in ("with", "without", "no-op")}
    own = {}
    other = warm.parent / f"{warm.name}-without"
    shutil.rmtree(other, ignore_errors=True)
    shutil.copytree(warm, other, symlinks=True)
    m = measure(rebuild_cmd(raw, other, stages + common))
    print(f"  (the copy without {'+'.join(stages)} settled, not part of the comparison: {m.wall_s:.1f} s wall, "
          f"CPU {m.cpu_s:.1f} s)", flush=True)
    try:
        for r in range(repeat):
            change(r % 2 == 0)
            for label, wh, without in (("with", warm, common), ("no-op", warm, common),
                                       ("without", other, stages + common)):
                m = measure(rebuild_cmd(raw, wh, without))
                out[label].runs.append(m)
                print(f"  round {r + 1}, {label:7s}: {m.wall_s:7.1f} s wall, CPU {m.cpu_s:6.1f} s, load average "
                      f"{os.getloadavg()[0]:.1f}", flush=True)
                if label == "with":
                    print("\n".join(f"      {line}" for line in lines(parse(m.stdout + m.stderr))), flush=True)
                for n in stage_names() if label == "with" else ():
                    own.setdefault(n, []).append(stage_seconds(m.stdout + m.stderr, n))
    finally:
        change(False)
        shutil.rmtree(other, ignore_errors=True)
    return {**out, "own": own, "common": common}


def added_by_trees(raw: Path, warm: dict, change, stages: tuple, repeat: int, common: tuple = NOT_COMPARED) -> dict:
    """:func:`added_by` for several versions of the code at once (``--ref``): ``warm`` maps a label to (the
    tree whose code rebuilds it, or None for this checkout; its warm warehouse, built by that code). Round ``r``
    applies ``change(r % 2 == 0)`` once, then rebuilds every version's warehouse with every stage and its copy
    without ``stages``, the versions in turn (their order reversed every round), so that the load of each
    moment falls on both alike. Returns label -> the :func:`added_by` dict (no no-op runs)."""
    import shutil

    from benchmarks.decision_probe import lines, parse
    from benchmarks.proc import Series, measure

    res = {lab: {"with": Series("with"), "without": Series("without"), "no-op": Series("no-op"), "own": {},
                 "common": common} for lab in warm}
    other = {}
    for lab, (tree, wh) in warm.items():
        other[lab] = wh.parent / f"{wh.name}-without"
        shutil.rmtree(other[lab], ignore_errors=True)
        shutil.copytree(wh, other[lab], symlinks=True)
        m = measure(rebuild_cmd(raw, other[lab], stages + common), cwd=tree, env=tree_env(tree))
        print(f"  ({lab}: the copy without {'+'.join(stages)} settled: {m.wall_s:.1f} s wall, CPU {m.cpu_s:.1f} s)",
              flush=True)
    labels = list(warm)
    try:
        for r in range(repeat):
            change(r % 2 == 0)
            for lab in labels if r % 2 == 0 else labels[::-1]:
                tree, wh = warm[lab]
                for label, target, without in (("with", wh, common), ("without", other[lab], stages + common)):
                    m = measure(rebuild_cmd(raw, target, without), cwd=tree, env=tree_env(tree))
                    res[lab][label].runs.append(m)
                    print(f"  round {r + 1}, {lab:8s} {label:7s}: {m.wall_s:7.1f} s wall, CPU {m.cpu_s:6.1f} s, load "
                          f"average {os.getloadavg()[0]:.1f}", flush=True)
                    res[lab].setdefault("probe", {}).setdefault(label, []).append(rec := parse(m.stdout + m.stderr))
                    if label == "with" or rec is None:
                        print("\n".join(f"      {line}" for line in lines(rec)), flush=True)
                    for n in stage_names() if label == "with" else ():
                        res[lab]["own"].setdefault(n, []).append(stage_seconds(m.stdout + m.stderr, n))
    finally:
        change(False)
        for o in other.values():
            shutil.rmtree(o, ignore_errors=True)
    return res


def plan_changer(plan: Path, old: str, new: str):
    """``change(on)``: the plan file with ``old`` replaced by ``new`` (on) or as it was (off)."""
    text = plan.read_text()
    assert old in text, (plan, old)

    def change(on: bool) -> None:
        plan.write_text(text.replace(old, new) if on else text)
    return change


def report_added(name: str, res: dict, target: float, stages: tuple) -> bool:
    """Print one campaign's with / without / no-op rebuilds and the difference; PASS when the wall
    difference (what a user waits) is under ``target`` seconds."""
    w, wo, noop = res["with"], res["without"], res["no-op"]
    add, add_cpu = w.wall_s - wo.wall_s, w.cpu_s - wo.cpu_s
    print(f"{name}: whole `pneubench rebuild` processes (all cores), medians of {len(w.runs)}:")
    but = f" but {'+'.join(res['common'])}" if res["common"] else ""
    print(f"  plan change, every stage{but}: {w.wall_s:7.2f} s wall, CPU {w.cpu_s:7.2f} s (process tree)")
    print(f"  plan change, without {'+'.join(stages)} too: {wo.wall_s:7.2f} s wall, CPU {wo.cpu_s:7.2f} s")
    if noop.runs:
        print(f"  no-op rebuild (nothing changed)   {noop.wall_s:7.2f} s wall, CPU {noop.cpu_s:7.2f} s")
    own = ", ".join(f"{n} {np.median([v for v in vals if v is not None]):.2f} s" for n, vals in res["own"].items()
                    if any(v is not None for v in vals))
    print(f"  stages re-run (wall in the rebuild's log): {own or 'none found'}")
    ok = add < target
    print(f"  added by {'+'.join(stages)}: {add:.2f} s wall, {add_cpu:.2f} s CPU; target < {target:g} s: "
          f"{'PASS' if ok else 'MISS'} (of CPU: {'PASS' if add_cpu < target else 'MISS'}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores: above it the wall is the load's)")
    return ok


def first_rebuild(raw: Path, wh: Path, common: tuple = NOT_COMPARED, tree: Path | None = None) -> None:
    """The warm warehouse every measured rebuild starts from (not timed; without ``common``; ``tree``: the code
    that builds it, None for this checkout's)."""
    from benchmarks.proc import measure

    m = measure(rebuild_cmd(raw, wh, common), cwd=tree, env=tree_env(tree))
    print(f"  (first rebuild, not part of the comparison: {m.wall_s:.1f} s wall, CPU {m.cpu_s:.1f} s, exit {m.exit_code})",
          flush=True)


def on_demo(tmp: Path, repeat: int) -> bool:
    """The demo campaign: what the decision stages add to its rebuild (target < 2 s)."""
    from pipeline.simulator.campaign import simulate_demo

    raw, wh = tmp / "demo-raw", tmp / "demo-wh"
    raw.mkdir()
    simulate_demo(raw)
    first_rebuild(raw, wh)
    res = added_by(raw, wh, plan_changer(raw / "plan.toml", "power = 0.8\n", "power = 0.81\n"), DECISION_STAGES,
                   repeat)
    return report_added("the demo, plan power 0.8 -> 0.81 (the decision stages re-run what reads the power)", res,
                        2.0, DECISION_STAGES)


def on_synthetic(tmp: Path, types: int, seed: int, repeat: int) -> bool:
    """``types`` odometer-only hose types of varied shape and size, ``max_failures`` designed (target
    10 s at 200, in proportion below)."""
    raw, wh = tmp / "synth-raw", tmp / "synth-wh"
    raw.mkdir()
    life, _ = campaign(types, seed, raw, (20, 20), varied=True, odometer_only=True)
    (raw / "plan.toml").write_text(SYNTH_PLAN.format(power=0.8))
    print(f"{types} synthetic hose types (8-20 hoses per adjustment, shapes 1.5-3.5, ~20 failures each, "
          f"odometer only: {len(life)} hoses), margin {DESIGN_MARGIN}, max_failures designed:")
    first_rebuild(raw, wh)
    res = added_by(raw, wh, plan_changer(raw / "plan.toml", "power = 0.8\n", "power = 0.81\n"), DECISION_STAGES,
                   repeat)
    return report_added(f"{types} hose types, plan power 0.8 -> 0.81 (what reads the power re-runs)", res,
                        10.0 * types / 200, DECISION_STAGES)


def on_synthetic_against(tmp: Path, ref: str, types: int, seed: int, repeat: int) -> bool:
    """:func:`on_synthetic` for ``ref``'s code (exported with ``git archive``) and this checkout's, alternately
    (:func:`added_by_trees`): each version's added wall and CPU, and this checkout's against ``ref``'s."""
    from benchmarks.same_behaviour import export

    tree = Path(ref).resolve() if Path(ref).is_dir() else export(ref, tmp / "ref-tree")   # a tree already exported
    raw = tmp / "synth-raw"
    raw.mkdir()
    life, _ = campaign(types, seed, raw, (20, 20), varied=True, odometer_only=True)
    (raw / "plan.toml").write_text(SYNTH_PLAN.format(power=0.8))
    print(f"{types} synthetic hose types ({len(life)} hoses), margin {DESIGN_MARGIN}, max_failures designed; "
          f"{ref} against this checkout, alternately:")
    warm = {ref: (tree, tmp / "synth-wh-ref"), "this": (None, tmp / "synth-wh-this")}
    for lab, (t, wh) in warm.items():
        print(f"  {lab}:", end="", flush=True)
        first_rebuild(raw, wh, tree=t)
    res = added_by_trees(raw, warm, plan_changer(raw / "plan.toml", "power = 0.8\n", "power = 0.81\n"),
                         DECISION_STAGES, repeat)
    oks = {lab: report_added(f"{lab}: {types} hose types, plan power 0.8 -> 0.81", res[lab], 10.0 * types / 200,
                             DECISION_STAGES) for lab in warm}
    a, b = res[ref], res["this"]
    for what, key in (("wall", "wall_s"), ("CPU", "cpu_s")):
        ra = [w - o for w, o in zip((getattr(m, key) for m in a["with"].runs), (getattr(m, key) for m in a["without"].runs))]
        rb = [w - o for w, o in zip((getattr(m, key) for m in b["with"].runs), (getattr(m, key) for m in b["without"].runs))]
        print(f"  added {what} per round, {ref} / this: " + ", ".join(f"{x:.2f} / {y:.2f}" for x, y in zip(ra, rb))
              + f"; medians {np.median(ra):.2f} / {np.median(rb):.2f} s")
    return oks["this"]


def in_process(types: int, seed: int, large: bool, warehouse: Path | None, raw: Path | None) -> bool:
    """The in-process breakdown (detail): the designed case, the stage's parts, one and two workers."""
    first = designed(types, seed, (32, 60) if large else (20, 20))   # first: this process is still cold
    (n_designs, n_types), (s, cpu), (s2, cpu2) = first["designs"], first["decision"], first["test_plan"]
    print(f"detail, in this process: designed max_failures (margin {DESIGN_MARGIN}), {n_types} hose types, "
          f"{n_designs} distinct designs, a first rebuild's stages (cold), 1 process:")
    print(f"  decision stage  {s:7.2f} s (CPU {cpu:6.2f} s)")
    print(f"  test_plan stage {s2:7.2f} s (CPU {cpu2:6.2f} s); both stages {s + s2:.2f} s (CPU {cpu + cpu2:.2f} s)")
    with tempfile.TemporaryDirectory(prefix="pneubench-decision-") as tmp:
        raw_dir = Path(tmp)
        life, runs = campaign(types, seed, raw_dir, (32, 60) if large else (15, 20))
        failed = life[life["status"] == "failed"].groupby("hose_type").size()
        print(f"detail, in this process: {types} hose types, {len(life)} hoses, {len(runs)} durability runs, "
              f"{failed.mean():.1f} failures a type (seed {seed}), max_failures in the plan")
        split = parts(raw_dir, life, runs, _plan(40 if not large else 70))
        base = split["baseline: durability service_life"][0]
        for name, (s, cpu) in split.items():
            print(f"  {name:45s} {s:7.2f} s  ({s / base:6.1f}x baseline)  CPU {cpu:7.2f} s")
        for jobs in (1, 2):
            s, cpu = time_stage(raw_dir, life, runs, _plan(40 if not large else 70), jobs)
            print(f"  whole stage, {jobs} process(es): {s:7.2f} s ({s / base:.1f}x baseline) CPU here {cpu:.2f} s")
    if warehouse:
        wh = on_warehouse(warehouse, raw or warehouse.parent / "raw")
        (s, cpu), (s2, cpu2) = wh["decision"], wh["test_plan"]
        print(f"detail: on {warehouse} (cold, 1 process): decision {s:.2f} s (CPU {cpu:.2f} s), test_plan {s2:.2f} s "
              f"(CPU {cpu2:.2f} s)")


#: Run in a process whose ``PYTHONPATH`` is one version's tree: the designed case's two stages on ``argv[1]``
#: hose types (seed ``argv[2]``, two workers), their tables pickled to ``argv[3]``.
_STAGE_TABLES = """
import pickle, sys, tempfile
from pathlib import Path
import pandas as pd
from benchmarks.bench_decision_stage import _plan, campaign
from pipeline.stages import StageContext, decision, test_plan
types, seed, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
with tempfile.TemporaryDirectory() as tmp:
    raw = Path(tmp)
    life, runs = campaign(types, seed, raw, (20, 20), varied=True)
    res = {"hose_life": life, "durability_runs": runs}
    ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results=res, jobs=2, plan=_plan(None))
    tables = dict(decision.run(ctx).tables)
    ctx = StageContext(raw=raw, warehouse=raw, runs=pd.DataFrame(), results={**res, **tables}, jobs=2, plan=_plan(None))
    km, capacity = [], test_plan._capacity    # the schedule's hose-km behind each date, rounded in the table
    test_plan._capacity = lambda row, *a: (km.append((row["hose_type"], row["target_power"], row["decision_km"])),
                                           capacity(row, *a))[1]
    tables.update(test_plan.run(ctx).tables)
tables["test_plan decision_km"] = pd.DataFrame(km, columns=["hose_type", "target_power", "decision_km"])
pickle.dump(tables, open(out, "wb"))
"""


def same_as(ref: str, types: int, seed: int) -> bool:
    """Whether this checkout's decision and test_plan stages give the same tables as ``ref``'s on the
    designed case's campaign of ``types`` hose types, bit for bit; prints one line per table."""
    from benchmarks.same_behaviour import stage_tables_same

    return stage_tables_same(ref, _STAGE_TABLES, [str(types), str(seed)], "pneubench-decision-same-")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_decision_stage", description=__doc__.splitlines()[0])
    ap.add_argument("--types", type=int, help="synthetic hose types (default 200; 12 with --same-as)")
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--repeat", type=int, default=1, help="measured rebuilds of each kind (medians; default 1)")
    ap.add_argument("--quick", action="store_true", help="20 hose types, no demo")
    ap.add_argument("--no-demo", action="store_true", help="skip the demo campaign")
    ap.add_argument("--detail", action="store_true", help="also the in-process breakdown (stages and parts)")
    ap.add_argument("--large", action="store_true", help="detail: 32 hoses per adjustment, ~60 failures a type")
    ap.add_argument("--warehouse", type=Path, help="detail: also the stages on this warehouse's tables")
    ap.add_argument("--raw", type=Path, help="its raw/ (default: WAREHOUSE/../raw)")
    ap.add_argument("--ref", metavar="REF", help="also REF's code (git archive; or a folder holding a tree), "
                    "alternately with this checkout's (the synthetic campaign only)")
    ap.add_argument("--same-as", metavar="REF", help="only compare both stages' tables with REF's code (bit for bit)")
    args = ap.parse_args(argv)
    if args.same_as:
        types = 12 if args.types is None else args.types
        print(f"the decision stages' tables, {types} designed hose types (seed {args.seed}), this checkout against "
              f"{args.same_as}:")
        return 0 if same_as(args.same_as, types, args.seed) else 1
    types = 20 if args.quick else 200 if args.types is None else args.types
    ok = True
    with tempfile.TemporaryDirectory(prefix="pneubench-decision-proc-") as tmp:
        if not (args.quick or args.no_demo):
            ok &= on_demo(Path(tmp), args.repeat)
        if types and args.ref:
            ok &= on_synthetic_against(Path(tmp), args.ref, types, args.seed, args.repeat)
        elif types:   # --types 0: the demo alone
            ok &= on_synthetic(Path(tmp), types, args.seed, args.repeat)
    if args.detail or args.warehouse:
        in_process(types, args.seed, args.large, args.warehouse, args.raw)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
