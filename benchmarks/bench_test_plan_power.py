"""The test_plan stage after a plan change of the power, in process: main's code against this checkout's (issue 23).

One command::

    python -m benchmarks.bench_test_plan_power --ref MAIN_TREE --rounds 3     # MAIN_TREE: git archive f325281
    python -m benchmarks.bench_test_plan_power --types 20                    # this checkout alone, a look
    python -m benchmarks.bench_test_plan_power --check                       # and the table through the memo = cold
    python -m benchmarks.bench_test_plan_power --shared                      # and what the decision stage computed too

The 200 synthetic hose types of ``bench_decision_stage`` (:func:`benchmarks.bench_decision_stage.campaign`, seed 23:
8-20 hoses per adjustment, shapes 1.5-3.5, odometer only, ``max_failures`` designed, margin 1.5), written once. Each
version runs in its own process (``--ref``: the tree's code first on ``PYTHONPATH``), alternately, round by round;
in it, with the stages' memo (:class:`pipeline.rebuild.memo.Memo`) in a warehouse folder of its own: the decision and
test_plan stages at power 0.8 (cold, the memo filled and saved, as a lab's last rebuild; once per version, untimed),
then, each round in a new process on a copy of that folder, at power 0.81 the
decision stage (through the memo) and the **test_plan stage, timed** (``time.process_time`` of this one process:
every map computed in it, no pool; the CPU a rebuild's two workers share), in a new process (nothing computed at 0.8 held:
designs, boundaries), as a rebuild is. Printed per round and version: the
stage's CPU, each map's items computed / from the memo, and a digest of the table. ``--check`` also builds (round 1) the
0.81 table cold (no memo) in the child and says whether it equals the one through the memo, bit for bit.
``--shared`` (session 28) also times every item computed (in this one process, as the stages ran) and prints, per
round, how many of test_plan's computed designs the decision stage computed in the same rebuild (the same item, the
same result bit for bit) and their CPU here, and of test_plan's computed boundaries how many maxima are also a maximum of
the decision's looks computed, how many lie above the designs file's looks (:data:`analyses.sequential_boundaries.DESIGN_LOOKS`;
those at or below it come whole from the file) and how many of their looks the decision read (its first looks only).
The wall of the whole rebuild is ``bench_decision_stage``'s; this resolves the stage's CPU at a load where wall
does not.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import hashlib, json, pickle, sys, time
from pathlib import Path
import pandas as pd
from pipeline.raw.plan import read_plan
from pipeline.raw.tree import RawTree
from pipeline.rebuild.memo import Memo
from pipeline.stages.context import StageContext
from pipeline.stages import decision, test_plan

raw, wh, check, mode = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3] == "1", sys.argv[4]
shared = len(sys.argv) > 5 and sys.argv[5] == "1"
plan_text = (raw / "plan.toml.in").read_text()
life, runs = pickle.loads((raw / "life.pkl").read_bytes())
counts = {}
done = {}   # --shared: label -> [(memo key, result, CPU-s)] of every item computed

def mapper(func, items, label):
    if not shared:
        return [func(i) for i in items]
    out = []
    for i in items:
        t0 = time.process_time()
        out.append(func(i))
        done.setdefault(label, []).append((getattr(i, "memo_key", i), out[-1], time.process_time() - t0))
    return out

class Counted(Memo):
    def map(self, compute, func, items, label=""):
        before = self.computed
        out = super().map(compute, func, items, label)
        got = counts.setdefault(label, [0, 0])
        got[0] += self.computed - before
        got[1] += len(items) - (self.computed - before)
        return out

def ctx_at(power, stage, memo=True):
    (raw / "plan.toml").write_text(plan_text.format(power=power))
    m = Counted(wh, stage) if memo else None
    ctx = StageContext(raw=raw, warehouse=wh, runs=pd.DataFrame(),
                       results={"hose_life": life, "durability_runs": runs}, plan=read_plan(RawTree(raw)),
                       mapper=mapper, memo=m)
    return ctx, m

def both(power, timed=False):
    done.clear()
    ctx, m = ctx_at(power, "decision")
    tables = dict(decision.run(ctx).tables)
    m.save()
    ctx, m = ctx_at(power, "test_plan")
    ctx.results.update(tables)
    counts.clear()
    t0 = time.process_time()
    df = test_plan.plan_table(ctx)
    cpu = time.process_time() - t0
    m.save()
    return tables, df, cpu

def digest(df):
    return hashlib.sha256(pd.util.hash_pandas_object(df.astype(str), index=True).values.tobytes()).hexdigest()[:16]

if mode == "fill":
    both(0.8)
    print("RESULT {}")
    sys.exit(0)
# a new rebuild process after the plan change: nothing computed at 0.8 is held (designs, boundaries)
tables, df, cpu = both(0.81, timed=True)
out = {"cpu_s": cpu, "maps": dict(counts), "digest": digest(df), "rows": len(df)}
if check:
    ctx, _ = ctx_at(0.81, "test_plan", memo=False)
    ctx.results.update(tables)
    cold = test_plan.plan_table(ctx)
    out["cold_equal"] = bool(df.equals(cold)) and digest(cold) == out["digest"]
if shared:   # what test_plan computed that the decision stage computed in the same rebuild (session 28)
    from analyses.sequential_boundaries import DESIGN_LOOKS
    dec = {json.dumps({k: v for k, v in key.items() if k != "designs"}, sort_keys=True): r
           for key, r, _ in done.get("decision: designs", [])}
    tp = [(json.dumps(key, sort_keys=True), r, c) for key, r, c in done.get("test plan designs", [])]
    same = [(k, r, c) for k, r, c in tp if k in dec]
    verdict = tables["life_verdict"].dropna(subset=["max_failures"])
    read = verdict.groupby(verdict["max_failures"].astype(int))["looks"].max().to_dict()   # the looks decision read
    maxima = {key["design"][0] for key, _, _ in done.get("decision: looks", []) if key["design"][0]}
    tb = [(key["looks"], c) for key, _, c in done.get("test plan: boundaries", [])]
    above = [(m, c) for m, c in tb if m > DESIGN_LOOKS]
    out["shared"] = {"designs": len(tp), "designs_shared": len(same), "bit_identical": all(dec[k] == r for k, r, _ in same),
                     "designs_cpu": sum(c for *_, c in tp), "designs_shared_cpu": sum(c for *_, c in same),
                     "decision_designs": len(dec), "boundaries": len(tb),
                     "boundaries_shared": sum(m in maxima for m, _ in tb), "above": len(above),
                     "above_shared": sum(m in maxima for m, _ in above),
                     "above_looks": sum(m for m, _ in above),
                     "above_read": sum(min(m, int(read.get(m, 0))) for m, _ in above if m in maxima),
                     "boundaries_cpu": sum(c for _, c in tb), "above_cpu": sum(c for _, c in above)}
print("RESULT " + json.dumps(out))
"""


def write_campaign(root: Path, types: int, seed: int) -> None:
    """The synthetic campaign (raw/c/hoses.csv), its plan template and the stage inputs (``life.pkl``) in ``root``."""
    from benchmarks.bench_decision_stage import SYNTH_PLAN, campaign

    life, runs = campaign(types, seed, root, (20, 20), varied=True, odometer_only=True)
    (root / "plan.toml.in").write_text(SYNTH_PLAN.replace("{", "{{").replace("}", "}}").replace("{{power}}", "{power}"))
    (root / "life.pkl").write_bytes(pickle.dumps((life, runs)))


def run_child(tree: Path | None, raw: Path, wh: Path, mode: str, check: bool = False, shared: bool = False) -> dict:
    """One version's child process (``tree``: that code on ``PYTHONPATH``; None: this checkout): ``mode`` "fill" (the
    stages at 0.8 into ``wh``'s memo, untimed) or "measure" (a copy of ``wh`` taken to 0.81, test_plan timed)."""
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    with tempfile.TemporaryDirectory(prefix="tp-power-wh-", dir=raw.parent) as tmp:
        target = wh
        if mode == "measure":
            target = Path(tmp) / "wh"
            shutil.copytree(wh, target)
        proc = subprocess.run([sys.executable, "-c", CHILD, str(raw), str(target), "1" if check else "0", mode,
                           "1" if shared else "0"],
                              env=env, cwd=str(tree) if tree is not None else None, capture_output=True, text=True)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode or not lines:
        raise RuntimeError(f"child failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def shared_line(s: dict) -> str:
    """The ``--shared`` figures of one round as a line."""
    return (f"shared with the decision stage: designs {s['designs_shared']} of test_plan's {s['designs']} computed were "
            f"among the decision's {s['decision_designs']} (bit-identical: {s['bit_identical']}), {s['designs_shared_cpu']:.2f}"
            f" of the map's {s['designs_cpu']:.2f} CPU-s here; boundaries: {s['boundaries_shared']} of {s['boundaries']} "
            f"maxima also a maximum of the decision's looks computed, {s['above']} above the designs file's looks "
            f"({s['above_shared']} shared, whose first {s['above_read']} of {s['above_looks']} looks the decision read), "
            f"{s['boundaries_cpu']:.2f} CPU-s here, {s['above_cpu']:.2f} of it above the file")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_test_plan_power", description=__doc__.splitlines()[0])
    ap.add_argument("--types", type=int, default=200)
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--ref", type=Path, help="a folder holding the reference code's tree (git archive)")
    ap.add_argument("--check", action="store_true", help="also: the 0.81 table through the memo equals a cold one")
    ap.add_argument("--shared", action="store_true",
                    help="also: what test_plan computed that the decision stage computed in the same rebuild (session 28)")
    args = ap.parse_args(argv)
    versions = ([("ref", args.ref.resolve())] if args.ref else []) + [("this", None)]
    with tempfile.TemporaryDirectory(prefix="tp-power-") as tmp:
        raw = Path(tmp) / "raw"
        raw.mkdir()
        write_campaign(raw, args.types, args.seed)
        print(f"{args.types} hose types (seed {args.seed}); test_plan after power 0.8 -> 0.81, in process, CPU:",
              flush=True)
        cpus = {lab: [] for lab, _ in versions}
        digests = {}
        whs = {lab: Path(tmp) / f"wh-{lab}" for lab, _ in versions}
        for lab, tree in versions:    # each version's memo at 0.8, once (a lab's last rebuild; untimed)
            whs[lab].mkdir()
            run_child(tree, raw, whs[lab], "fill")
        for r in range(args.rounds):
            for lab, tree in versions:
                load = os.getloadavg()[0]
                res = run_child(tree, raw, whs[lab], "measure", args.check and r == 0, args.shared)
                cpus[lab].append(res["cpu_s"])
                digests.setdefault(lab, set()).add(res["digest"])
                maps = "; ".join(f"{k or '?'} {v[0]} computed / {v[1]} memo" for k, v in res["maps"].items())
                extra = f", through the memo = cold: {res['cold_equal']}" if "cold_equal" in res else ""
                print(f"  round {r + 1} {lab}: {res['cpu_s']:.2f} CPU-s (load {load:.1f}), {res['rows']} rows, "
                      f"table {res['digest']}{extra}; {maps}", flush=True)
                if "shared" in res:
                    print("    " + shared_line(res["shared"]), flush=True)
        for lab, v in cpus.items():
            print(f"  {lab}: median {sorted(v)[len(v) // 2]:.2f} CPU-s of {', '.join(f'{x:.2f}' for x in v)}")
        same = len({d for s in digests.values() for d in s}) == 1
        print(f"  tables {'identical' if same else 'DIFFER'} across versions and rounds")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
