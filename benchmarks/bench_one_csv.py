"""One fresh 100 MB CSV export, the whole rebuild as a process, before and after a change of the code,
beside pandas' and DuckDB's whole-process conversions, in one run (issue 26).

One command::

    python -m benchmarks one_csv                          # 100 MB, --ref main, median of 3
    python -m benchmarks.bench_one_csv --ref main~1 --repeat 5
    python -m benchmarks.bench_one_csv --quick            # 5 MB, one round (seconds to a minute)

What it measures, each a fresh process on the same raw tree (page cache warm for all), round-robin
so that a change of the machine's load hits every command alike:

* ``after``: ``pneubench rebuild -q`` (report included: the whole nightly command) of this
  checkout, into a fresh warehouse, from a raw tree holding one durability export
  (``benchmarks/_data/cli-csv-<N>mb/raw/bench/big.csv``: ``t, p_a, p_b, x`` at 5 kHz, the
  generator of :mod:`benchmarks.bench_ingest`, valid by the input contract);
* ``before``: the same with the code of ``--ref`` (``git archive``, as
  :mod:`benchmarks.bench_versions` runs it: same interpreter and libraries, bytecode cached as an
  installed package's is, so ``PYTHONDONTWRITEBYTECODE`` is dropped from the children's
  environment: a nightly job never compiles every module on every start);
* ``pandas``: ``read_csv`` + unit conversion + ``to_parquet`` as a ``python -c`` process;
* ``duckdb``: DuckDB's ``read_csv`` -> ``COPY ... TO parquet`` as a process (the floor).

Prints wall and CPU seconds (the process tree's) and peak tree RSS, the ratios, and PASS/MISS for
the issue's target "pandas' wall time / the rebuild's >= 1.5" and for "the change made the
rebuild no slower" (CPU after <= CPU before x 1.05). Then where a fresh rebuild's time goes, per
version: the process runs :func:`pipeline.rebuild.flow.rebuild` with a progress that stamps each
line with wall and CPU seconds (start-up imports, plan, ingest with the stages' imports beside
it, each stage, the database write with the figures drawn and the report's channel bands read
beside it, the report).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.bench_cli import BASELINES, _export
from benchmarks.bench_versions import _env, command
from benchmarks.proc import Series, measure, verdict
from benchmarks.same_behaviour import export

ROOT = Path(__file__).resolve().parent.parent
TARGET = 1.5  # pandas' wall seconds over the rebuild's (issue 26)
NO_SLOWER = 1.05  # CPU after over before: at most this

#: A rebuild in a process whose progress stamps each line: "<wall s> <cpu s> <children cpu s> <line>".
_STAMPED = """
import resource, sys, time
T0 = time.perf_counter(); C0 = time.process_time()
def _stamp(text):
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"{time.perf_counter() - T0:.3f} {time.process_time() - C0:.3f} {ch.ru_utime + ch.ru_stime:.3f} {text}",
          flush=True)
import pipeline.cli
from pipeline.progress import Progress
from pipeline.rebuild.flow import rebuild
_stamp("imported")
class Stamped(Progress):
    def message(self, text):
        _stamp(text)
rebuild(sys.argv[1], sys.argv[2], progress=Stamped())
_stamp("end")
"""

#: Which step a progress line ends (the line is printed when the step is done).
_STEPS = [(re.compile(r"^imported$"), "start-up: imports of the command"),
          (re.compile(r"^ingest: \d+ of \d+ run files to read"), "plan (walk raw/, previous state)"),
          (re.compile(r"^stage (\w+) (ran|reused)"), "stage {0} {1}"),
          (re.compile(r"^warehouse: writing"), "after the stages (assemble the tables)"),
          (re.compile(r"^figures: "), "database write (figures drawn, the new runs' channels read beside it)"),
          (re.compile(r"^report: "), "report"),
          (re.compile(r"^end$"), "the rest (summary, exit)")]


def steps(stamped: str) -> list[tuple[str, float, float]]:
    """``[(step, wall s, cpu s of the rebuild's own process)]`` from the stamped progress lines of
    :data:`_STAMPED`: each step ends at its line. The time between the stage lines that the first
    stage line ends includes the ingest (run in workers) and the stages' imports beside it."""
    out, last_w, last_c = [], 0.0, 0.0
    for line in stamped.splitlines():
        parts = line.split(" ", 3)
        if len(parts) < 4:
            continue
        try:
            w, c = float(parts[0]), float(parts[1])
        except ValueError:
            continue
        for rx, name in _STEPS:
            m = rx.match(parts[3])
            if m:
                if not out or not out[-1][0].startswith("plan") or not name.startswith("stage"):
                    label = name.format(*m.groups())
                else:  # the first stage line after the plan: the ingest is in between
                    label = "ingest (workers) + the stages' imports, then " + name.format(*m.groups())
                out.append((label, w - last_w, c - last_c))
                last_w, last_c = w, c
                break
    return out


def _children_cpu(stamped: str) -> float:
    """CPU seconds of the workers (ingest, stages, figures) reaped by the end [s]."""
    last = [ln.split(" ", 3) for ln in stamped.splitlines() if ln.endswith(" end")]
    return float(last[-1][2]) if last else float("nan")


def breakdown(tree: Path, raw: Path, work: Path) -> dict:
    """One fresh rebuild of ``raw`` by the code of ``tree``, its steps stamped."""
    wh = work / "breakdown-wh"
    shutil.rmtree(wh, ignore_errors=True)
    m = measure([sys.executable, "-c", _STAMPED, str(raw), str(wh)], cwd=tree, env=_env(tree))
    shutil.rmtree(wh, ignore_errors=True)
    return {"wall_s": m.wall_s, "cpu_s": m.cpu_s, "steps": steps(m.stdout), "workers_cpu_s": _children_cpu(m.stdout)}


def _commands(trees: dict[str, Path], src: Path, work: Path) -> dict[str, tuple[list[str], Path, dict | None]]:
    raw = src.parent.parent
    cmds = {name: ([*command(tree), "rebuild", "--raw", str(raw), "--warehouse", str(work / f"wh-{name}"), "-q"],
                   tree, _env(tree)) for name, tree in trees.items()}
    for b in ("pandas", "duckdb"):
        cmds[b] = ([sys.executable, "-c", BASELINES[b], str(src), str(work / f"{b}.parquet")], ROOT, None)
    return cmds


def run(size_mb: float, repeat: int, ref: str | None, work: Path) -> dict:
    """Every command ``repeat`` times round-robin (after one untimed round that writes the
    reference tree's bytecode and warms the page cache); medians."""
    src = _export("csv", size_mb)
    trees = {"after": ROOT} | ({"before": export(ref, work / "before")} if ref else {})
    cmds = _commands(trees, src, work)
    series = {name: Series(name) for name in cmds}
    for i in range(repeat + 1):
        for name, (cmd, cwd, env) in cmds.items():
            shutil.rmtree(work / f"wh-{name}", ignore_errors=True)
            (work / f"{name}.parquet").unlink(missing_ok=True)
            m = measure(cmd, cwd=cwd, env=env)
            if m.exit_code != 0:
                raise SystemExit(f"{name} exited {m.exit_code}:\n{m.stderr[-2000:]}")
            if i:
                series[name].runs.append(m)
    return {"mb": src.stat().st_size / 1e6, "src": src,
            "times": {n: {"wall_s": s.wall_s, "cpu_s": s.cpu_s, "tree_peak_mb": s.tree_peak_mb,
                          "walls": [r.wall_s for r in s.runs]} for n, s in series.items()},
            "breakdown": {name: breakdown(tree, src.parent.parent, work) for name, tree in trees.items()}}


def report(res: dict, repeat: int) -> list[tuple[str, float, bool]]:
    """Print the table, the ratios and the breakdown; the checks as (what, value, passed)."""
    t = res["times"]
    print(f"\nCSV {res['mb']:.0f} MB, whole processes, median of {repeat}:")
    print("| command | wall [s] | cpu [s] | peak RSS of the tree [MB] |\n|---|---|---|---|")
    for name, v in t.items():
        print(f"| {name} | {v['wall_s']:.2f} | {v['cpu_s']:.2f} | {v['tree_peak_mb']:.0f} |")
    checks = [(f"rebuild (after) >= {TARGET}x pandas, wall", t["pandas"]["wall_s"] / t["after"]["wall_s"], None)]
    print(f"\npandas / rebuild after: wall {t['pandas']['wall_s'] / t['after']['wall_s']:.2f}x, "
          f"cpu {t['pandas']['cpu_s'] / t['after']['cpu_s']:.2f}x; rebuild after / DuckDB (the floor): wall "
          f"{t['after']['wall_s'] / t['duckdb']['wall_s']:.2f}x, cpu {t['after']['cpu_s'] / t['duckdb']['cpu_s']:.2f}x")
    if "before" in t:
        print(f"pandas / rebuild before: wall {t['pandas']['wall_s'] / t['before']['wall_s']:.2f}x; "
              f"after / before: wall {t['after']['wall_s'] / t['before']['wall_s']:.2f}, "
              f"cpu {t['after']['cpu_s'] / t['before']['cpu_s']:.2f}")
        checks.append((f"rebuild cpu after / before <= {NO_SLOWER}", t["after"]["cpu_s"] / t["before"]["cpu_s"], None))
    for name, b in res["breakdown"].items():
        print(f"\nwhere a fresh rebuild goes ({name}; one process: wall {b['wall_s']:.2f} s, cpu of the tree "
              f"{b['cpu_s']:.2f} s, of it the workers {b['workers_cpu_s']:.2f} s):")
        for step, w, c in b["steps"]:
            print(f"  {step:70s} wall {w:6.2f} s  cpu {c:6.2f} s")
    out = []
    for what, value, _ in checks:
        ok = value >= TARGET if what.startswith("rebuild (after)") else value <= NO_SLOWER
        out.append((what, value, ok))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size-mb", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ref", default="main", help="the code before (a commit, branch or tag); '' for none")
    ap.add_argument("--quick", action="store_true", help="5 MB, one round")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    size, repeat = (5.0, 1) if args.quick else (args.size_mb, args.repeat)
    rev = subprocess.run(["git", "rev-parse", "--short", args.ref], cwd=ROOT, capture_output=True,
                         text=True).stdout.strip() if args.ref else ""
    print(f"one fresh CSV export, whole processes: {os.cpu_count()} cores, python {sys.version.split()[0]}, "
          f"before: {args.ref or '-'} ({rev or '-'}), after: this checkout; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="pneubench-one-csv-"))
    try:
        res = run(size, repeat, args.ref or None, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    checks = report(res, repeat)
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for what, value, ok in checks:
        print(f"{verdict(ok)}  {what}: {value:.3f}")
    if args.json:
        res.pop("src")
        args.json.write_text(json.dumps({"results": res, "checks": checks}, indent=1, default=str))
    return 0 if all(ok for _, _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
