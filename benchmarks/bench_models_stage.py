"""The ``models`` stage after one changed spring test (issue 26): its time and memory, before and after.

One command::

    python -m benchmarks.bench_models_stage --ref main --runs 1000   # both versions, the issue's campaign
    python -m benchmarks.bench_models_stage --quick                  # 60 runs, this checkout only (a look)

A campaign of ``--runs`` runs (``pneubench simulate``, seed 7, under ``benchmarks/_data/scale-N/``, shared
with ``bench_scale``, files aged an hour). Each version (``--ref`` exported with ``git archive``, and this
checkout) builds its own warehouse (a full rebuild, untimed); then ``--rounds`` times one value of one
spring CSV file is changed (its last digit, :func:`benchmarks.bench_scale.bump_last_digit`), rebuilt, put
back and rebuilt again: two one-spring-change rebuilds per round, each a child process (jobs 2, no
report) whose ``pipeline.stages.models.run`` is wrapped to measure the stage alone:

* wall seconds, and CPU seconds of the process tree (the process, its live workers from ``/proc``,
  and the workers that ended, from ``RUSAGE_CHILDREN``): the CPU figure is the one a loaded machine
  moves least;
* the rebuild process's peak resident memory during the stage (``VmHWM`` reset at the stage's start
  through ``/proc/self/clear_refs``) less its resident memory at the start: what the stage holds.

Median over the changes. Targets: the stage's CPU after one spring change at most a tenth of
before's (the joint fits no longer redone over every test's samples), and its memory growth no
larger than before's. PASS/MISS printed.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.proc import verdict

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: What the child process runs: a rebuild with the models stage measured (argv: raw, warehouse).
CHILD = r"""
import json, os, resource, sys, time
from pathlib import Path
import pipeline.stages.models as models
from pipeline.rebuild.flow import rebuild
from benchmarks.proc import _tree

def status_mb(key):
    with open("/proc/self/status") as fh:
        return next(int(l.split()[1]) / 1024 for l in fh if l.startswith(key + ":"))

def tree_cpu():
    tick, total = os.sysconf("SC_CLK_TCK"), 0.0
    for pid in _tree(os.getpid()):
        try:
            with open(f"/proc/{pid}/stat", "rb") as fh:
                f = fh.read().rsplit(b")", 1)[1].split()
            total += (int(f[11]) + int(f[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return total + ch.ru_utime + ch.ru_stime

rec, real = {}, models.run

def measured(ctx):
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass
    rss0, t0, c0 = status_mb("VmRSS"), time.perf_counter(), tree_cpu()
    out = real(ctx)
    rec.update(wall_s=time.perf_counter() - t0, cpu_s=tree_cpu() - c0, peak_growth_mb=status_mb("VmHWM") - rss0)
    return out

models.run = measured
summary = rebuild(Path(sys.argv[1]), Path(sys.argv[2]), jobs=2, report=False)
rec["exit_code"] = summary.exit_code
print("MEASURED " + json.dumps(rec))
"""


def _child(tree: Path, raw: Path, warehouse: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": f"{tree}{os.pathsep}{ROOT}"}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(raw), str(warehouse)], cwd=tree, env=env,
                          capture_output=True, text=True)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("MEASURED ")]
    if proc.returncode not in (0, 1) or not lines:
        raise SystemExit(f"rebuild with {tree} failed ({proc.returncode}): {proc.stderr.strip()[-800:]}")
    return json.loads(lines[-1][len("MEASURED "):])


def _spring_victim(raw: Path) -> Path:
    found = sorted(p for p in raw.rglob("*.csv") if "spring" in p.name)
    if not found:
        raise SystemExit(f"{raw}: no spring CSV file to change")
    return found[0]


def measure_versions(trees: dict[str, Path], raw: Path, work: Path, rounds: int) -> dict[str, list[dict]]:
    """Per version: the measured models stage of each one-spring-change rebuild (module docstring)."""
    from benchmarks.bench_scale import bump_last_digit

    victim, past = _spring_victim(raw), time.time() - 3600
    out: dict[str, list[dict]] = {name: [] for name in trees}
    for name, tree in trees.items():
        full = _child(tree, raw, work / f"wh-{name}")
        print(f"  {name}: full rebuild's models stage {full['wall_s']:.1f} s, CPU {full['cpu_s']:.1f} s", flush=True)
    for i in range(rounds):
        for name, tree in (trees.items() if i % 2 == 0 else reversed(list(trees.items()))):
            original = bump_last_digit(victim, i + 1)
            os.utime(victim, (past + 60 * (i + 1), past + 60 * (i + 1)))
            try:
                out[name].append(_child(tree, raw, work / f"wh-{name}"))
            finally:
                victim.write_bytes(original)
                os.utime(victim, (past, past))
            out[name].append(_child(tree, raw, work / f"wh-{name}"))   # put back: a change too
            for m in out[name][-2:]:
                print(f"  {name}: models stage {m['wall_s']:.1f} s, CPU {m['cpu_s']:.2f} s, "
                      f"memory +{m['peak_growth_mb']:.0f} MB", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--ref", default=None, help="the version before (git ref); without it this checkout only")
    ap.add_argument("--rounds", type=int, default=1, help="changes per version (each also put back: two rebuilds)")
    ap.add_argument("--quick", action="store_true", help="60 runs, this checkout only")
    args = ap.parse_args(argv)
    from benchmarks.bench_scale import DATA, make_campaign
    from benchmarks.same_behaviour import export

    runs = 60 if args.quick else args.runs
    raw = make_campaign(DATA / f"scale-{runs}", runs, args.seed)
    print(f"models stage after one changed spring test, {runs} runs, {os.cpu_count()} cores; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="pneubench-models-stage-"))
    try:
        trees = {"after": ROOT}
        if args.ref and not args.quick:
            trees = {"before": export(args.ref, work / "before"), **trees}
        times = measure_versions(trees, raw, work, args.rounds)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    med = {v: {k: statistics.median(m[k] for m in ms) for k in ("wall_s", "cpu_s", "peak_growth_mb")}
           for v, ms in times.items()}
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
    print("| models stage, one spring change | wall s | CPU s | memory growth MB |\n|---|---|---|---|")
    for v, m in med.items():
        print(f"| {v} | {m['wall_s']:.2f} | {m['cpu_s']:.2f} | {m['peak_growth_mb']:.0f} |")
    if "before" not in med:
        return 0
    b, a = med["before"], med["after"]
    ok_cpu = a["cpu_s"] <= 0.1 * b["cpu_s"]
    ok_mem = a["peak_growth_mb"] <= b["peak_growth_mb"]
    print(f"\n{verdict(ok_cpu)}  CPU after / before at most 0.1: {a['cpu_s'] / b['cpu_s']:.3f}")
    print(f"{verdict(ok_mem)}  memory growth after <= before: {a['peak_growth_mb']:.0f} / {b['peak_growth_mb']:.0f} MB")
    return 0 if ok_cpu and ok_mem else 1


if __name__ == "__main__":
    sys.exit(main())
