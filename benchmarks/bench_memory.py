"""A full rebuild's peak memory against the number of runs (issue 26: flat, under 1.5 GB at 10,000).

One command::

    python -m benchmarks.bench_memory                   # 1,000 and 3,000 runs (~15 min quiet)
    python -m benchmarks.bench_memory --with-10k        # and 10,000 runs (another ~10+ min)
    python -m benchmarks.bench_memory --quick           # 60 and 150 runs: a look in a minute or two

For each size the campaign is ``pneubench simulate DIR --seed 7 --runs N`` (demo profile, under
``benchmarks/_data/scale-N/``, shared with ``bench_scale``, git-ignored, reused when present); a
full rebuild into a fresh warehouse runs as a whole ``pneubench rebuild`` process (what cron
runs: its workers, the figures and the morning report included). Every ``--interval`` seconds
the process tree is sampled from ``/proc`` (``benchmarks/proc.py``): each process's PSS (its
private pages plus its share of the pages it shares with forked workers), summed; the peak of
the sum is the figure, printed beside the rebuild process's own peak, the workers' share at that
moment and the last progress line the rebuild printed before it (where the peak is).

Target (issue 26): the peak tree PSS at 10,000 runs under 1.5 GB, and flat in the number of runs.
The slope [MB per run] is a least-squares line through the sizes measured; without the 10,000-run
size, the 10,000-run figure is that line's value there (said so, and judged as such).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from benchmarks.bench_scale import DATA, ROOT, make_campaign
from benchmarks.proc import pneubench_cmd, tree_pss_by_process, verdict

#: Issue 26's target for a full rebuild of 10,000 runs: peak PSS of the process tree. [MB]
TARGET_MB = 1500.0
TARGET_RUNS = 10_000


@dataclass
class Peak:
    """One full rebuild's memory, sampled."""

    runs: int
    wall_s: float
    exit_code: int
    tree_pss_mb: float = 0.0      # peak of the tree's summed PSS
    main_pss_mb: float = 0.0      # the rebuild process's PSS at that moment
    workers_pss_mb: float = 0.0   # the other processes' at that moment
    n_processes: int = 0          # processes in the tree at that moment
    main_peak_mb: float = 0.0     # the rebuild process's own peak PSS, whenever it came
    phase: str = ""               # the last progress line before the peak


def rebuild_peak(raw: Path, warehouse: Path, runs: int, interval_s: float = 0.05,
                 jobs: int | None = None) -> Peak:
    """A full rebuild of ``raw`` into a fresh ``warehouse`` as a whole process; its peak tree PSS."""
    shutil.rmtree(warehouse, ignore_errors=True)
    cmd = [*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(warehouse)]
    if jobs:
        cmd += ["--jobs", str(jobs)]
    lines: list[str] = [""]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, errors="replace")

    def read():
        for line in proc.stderr:
            if line.strip():
                lines.append(line.strip()[:110])

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    peak = Peak(runs, 0.0, 0)
    while proc.poll() is None:
        by_pid = tree_pss_by_process(proc.pid)
        total = sum(by_pid.values()) / 1e6
        main = by_pid.get(proc.pid, 0) / 1e6
        peak.main_peak_mb = max(peak.main_peak_mb, main)
        if total > peak.tree_pss_mb:
            peak.tree_pss_mb, peak.main_pss_mb, peak.workers_pss_mb = total, main, total - main
            peak.n_processes, peak.phase = len(by_pid), lines[-1]
        time.sleep(interval_s)
    reader.join()
    peak.wall_s, peak.exit_code = time.perf_counter() - t0, proc.returncode
    if proc.returncode not in (0, 1):
        raise SystemExit(f"rebuild of {raw} failed ({proc.returncode}): {lines[-1]}")
    return peak


def slope(peaks: list[Peak]) -> tuple[float, float]:
    """Least-squares line of peak tree PSS [MB] against runs: (MB per run, MB at zero runs)."""
    import numpy as np

    if len(peaks) < 2:
        return float("nan"), float("nan")
    k, c = np.polyfit([p.runs for p in peaks], [p.tree_pss_mb for p in peaks], 1)
    return float(k), float(c)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_memory", description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="1000,3000", help="campaign sizes, comma-separated (default 1000,3000)")
    ap.add_argument("--with-10k", action="store_true", help="add the 10,000-run campaign (~10+ min more)")
    ap.add_argument("--quick", action="store_true", help="60 and 150 runs (a look, not the target)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=None, help="--jobs of the rebuild (default: its own, all cores)")
    ap.add_argument("--interval", type=float, default=0.05, help="sampling period [s]")
    args = ap.parse_args(argv)
    sizes = [60, 150] if args.quick else [int(n) for n in args.runs.split(",") if n.strip()]
    if args.with_10k and TARGET_RUNS not in sizes:
        sizes.append(TARGET_RUNS)
    print(f"full rebuild, peak PSS of the process tree; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    peaks = []
    for n in sizes:
        raw = make_campaign(DATA / f"scale-{n}", n, args.seed)
        p = rebuild_peak(raw, DATA / f"scale-{n}" / "warehouse-memory", n, args.interval, args.jobs)
        shutil.rmtree(DATA / f"scale-{n}" / "warehouse-memory", ignore_errors=True)
        peaks.append(p)
        print(f"  {n:>6} runs: tree PSS {p.tree_pss_mb:7.0f} MB (rebuild {p.main_pss_mb:.0f} + "
              f"{p.n_processes - 1} workers {p.workers_pss_mb:.0f}); rebuild's own peak {p.main_peak_mb:.0f} MB; "
              f"{p.wall_s:.0f} s; exit {p.exit_code}; peak during: {p.phase}", flush=True)
    k, c = slope(peaks)
    print(f"slope {k:.3f} MB per run (line through {len(peaks)} sizes; {c:.0f} MB at zero runs)")
    at = next((p.tree_pss_mb for p in peaks if p.runs == TARGET_RUNS), None)
    how = "measured"
    if at is None:
        at, how = k * TARGET_RUNS + c, "projected on the line"
    if args.quick:
        print(f"(quick: {how} {at:.0f} MB at {TARGET_RUNS} runs; not judged)")
        return 0
    ok = at < TARGET_MB
    print(f"{verdict(ok)}  full rebuild's peak tree PSS at {TARGET_RUNS} runs under {TARGET_MB:.0f} MB ({how}): "
          f"{at:.0f} MB")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
