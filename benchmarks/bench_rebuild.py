"""Rebuild benchmark: full, no-op and one-file-changed rebuilds of a 1,000-run campaign.

One command::

    python -m benchmarks.bench_rebuild                    # 1,000 runs from the simulator (demo profile)
    python -m benchmarks.bench_rebuild --runs 200         # a quick look
    python -m benchmarks.bench_rebuild --source csv       # small generated CSV step runs instead

The campaign is written under ``benchmarks/_data/rebuild-<source>-<runs>/raw`` (git-ignored,
reused when present). Then, in this process and in a fresh warehouse:

1. ``full``: the first rebuild (every file ingested, every stage run);
2. ``noop``: the same raw/ again (nothing read, every stage reused: state check + a new
   database and report);
3. ``changed``: one run file's bytes changed (a trailing newline appended; it is re-ingested
   and the stages reading its kind re-run);
4. ``noop-cli``: the no-op again through the ``pneubench rebuild`` console script in a new
   process, imports and worker start-up included: what cron sees.

It prints the times and the ratios no-op/full and changed/full (the issue's target: a no-op
well under a tenth of a full rebuild). ``--json FILE`` writes them too.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data"


def make_campaign(raw: Path, runs: int, source: str, seed: int) -> None:
    if raw.is_dir() and any(raw.rglob("*.*")):
        return
    raw.mkdir(parents=True, exist_ok=True)
    if source == "simulator":
        from pipeline.simulator.campaign import simulate_campaign
        simulate_campaign(raw, seed=seed, profile="demo", runs=runs)
        return
    import numpy as np
    rng = np.random.default_rng(seed)
    for i in range(runs):
        n = 500
        t = np.arange(n) / 100.0
        x = 20.0 * (1 - np.exp(-t / 0.8)) + rng.normal(0, 0.005, n)
        lines = ["# kind: step", f"# started_at: 2026-01-{1 + i % 28:02d}T08:00:00", "# rig: plpa-1",
                 "t[s],x[mm],x_ref[mm]"] + [f"{a:.3f},{b:.4f},20.0" for a, b in zip(t, x)]
        f = raw / f"bench{i // 250}" / f"run{i:05d}.csv"
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text("\n".join(lines) + "\n")


def timed(func):
    t0 = time.perf_counter()
    out = func()
    return time.perf_counter() - t0, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--source", choices=["simulator", "csv"], default="simulator")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    from pipeline.raw.tree import discover_runs
    from pipeline.rebuild.flow import rebuild

    source = args.source
    if source == "simulator":
        try:
            import pipeline.simulator.campaign  # noqa: F401
        except ImportError:
            print("simulator not available: using generated CSV step runs")
            source = "csv"
    base = DATA / f"rebuild-{source}-{args.runs}"
    raw, wh = base / "raw", base / "warehouse"
    t_gen, _ = timed(lambda: make_campaign(raw, args.runs, source, args.seed))
    files = discover_runs(raw)
    size = sum(f.stat().st_size for f in files)
    print(f"campaign: {len(files)} run files, {size / 1e6:.1f} MB under {raw} (written in {t_gen:.1f} s)")
    shutil.rmtree(wh, ignore_errors=True)
    # files written a moment ago are "racy" (hashed again on the next rebuild): age them, as a
    # night's files are hours old when the job runs
    past = time.time() - 3600
    for p in raw.rglob("*"):
        if p.is_file():
            os.utime(p, (past, past))

    results = {}
    t, s = timed(lambda: rebuild(raw, wh, jobs=args.jobs))
    results["full"] = t
    print(f"full     {t:8.2f} s  runs {s.n_runs}, quarantined {len(s.quarantine)}, stages run {s.stages_run}")
    t, s = timed(lambda: rebuild(raw, wh, jobs=args.jobs))
    results["noop"] = t
    print(f"no-op    {t:8.2f} s  unchanged {s.n_unchanged}, stages reused {s.stages_reused}")
    victim = next((f for f in files if f.suffix.lower() in (".csv", ".txt")), files[0])
    original = victim.read_bytes()
    try:
        victim.write_bytes(original + b"\n")
        t, s = timed(lambda: rebuild(raw, wh, jobs=args.jobs))
        results["changed"] = t
        print(f"changed  {t:8.2f} s  ({victim.relative_to(raw)}: changed {s.n_changed}, stages run {s.stages_run})")
    finally:
        victim.write_bytes(original)
        os.utime(victim, (past, past))
    rebuild(raw, wh, jobs=args.jobs)  # back to the original state
    exe = shutil.which("pneubench")
    cmd = [exe] if exe else [sys.executable, "-c", "from pipeline.cli import main; main()"]
    t, proc = timed(lambda: subprocess.run([*cmd, "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--quiet"],
                                           capture_output=True, text=True))
    results["noop_cli"] = t
    print(f"no-op CLI {t:7.2f} s  (new process, exit {proc.returncode}; imports and worker start-up included)")
    results["noop/full"] = results["noop"] / results["full"]
    results["changed/full"] = results["changed"] / results["full"]
    results["noop_cli/full"] = results["noop_cli"] / results["full"]
    print(f"ratios: no-op/full {results['noop/full']:.3f}, changed/full {results['changed/full']:.3f}, "
          f"no-op CLI/full {results['noop_cli/full']:.3f}  (target: no-op/full < 0.1)")
    results.update(runs=len(files), source=source, mb=size / 1e6)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0 if results["noop/full"] < 0.1 else 1


if __name__ == "__main__":
    sys.exit(main())
