"""Every benchmark in one command: ``python -m benchmarks [--quick]``.

Each benchmark measures its baseline in the same run and prints ratios; this only runs them one
after the other (each in its own process, so peak memory figures stay per benchmark).
``--quick`` uses small sizes for a look in a few minutes; without it the sizes are the issues'
(1 GB exports, a full-profile durability run: 10 km, ~8 h at 1 kHz, 29 M samples;
a 1,000-run campaign).
"""
from __future__ import annotations

import argparse
import subprocess
import sys

BENCHMARKS = {
    "ingest": (["--size-mb", "1000"], ["--size-mb", "100"]),
    "durability": ([], ["--hours", "0.5", "--repeat", "1"]),  # default: one full-profile run (10 km)
    "spring_fit": ([], []),
    "rebuild": (["--runs", "1000"], ["--runs", "150"]),
    "cli": ([], ["--quick"]),
    "one_csv": ([], ["--quick"]),  # one fresh 100 MB CSV: the whole rebuild before / after against pandas and DuckDB  # whole pneubench commands as processes against whole-process baselines
    "scale": ([], ["--runs", "300,1000"]),  # the cost curve to 10,000 runs
    "memory": ([], ["--quick"]),  # a full rebuild's peak PSS (process tree) at 1,000 and 3,000 runs, slope, 10k target
    "memo": ([], ["--entries", "1000"]),  # the per-run memo's own cost: one change out of 10,000
    "versions": ([], ["--runs", "300", "--repeat", "2"]),  # before / after a change (--ref main~1), same run
    "sequential": ([], ["--quick"]),  # the sequential verdict's error rates, looked at on every failure
    "life_effect": ([], ["--quick"]),  # coverage of the life ratio's and shape's 90 % intervals, 480 simulated hose types
    "decision_stage": ([], ["--quick"]),  # the decision stage's seconds at 200 hose types against service_life's
    "decision": ([], ["--quick"]),  # the decision: coverage and error rates on 3 x 460 simulated hose types (stage in-process)
    "test_plan": ([], ["--quick"]),  # failures_needed against a brute-force simulation of the same design
    "remaining_life": ([], ["--quick"]),  # remaining-life intervals' coverage on simulated futures (issue 24 groundwork)
    "remaining_life_stage": ([], ["--quick"]),  # the remaining_life stage's seconds on a demo-sized hose type (< 5 s)
    "service_life": ([], ["--quick"]),  # coverage of the service-life table's bounds (shape, scale, B10, R), 600 groups
    "rul_e2e": ([], ["--quick"]),  # remaining life end to end: hose_rul coverage per method against the simulator's futures
    "test_plan_forward": ([], ["--quick"]),  # power_now, more_km and the decision date against the real future
    "sensitivity": ([], ["--quick"]),  # decision_sensitivity's verdict at a true ratio of 1, per failure definition
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (minutes instead of ~15 min)")
    ap.add_argument("names", nargs="*", metavar="NAME", help=f"which to run: {', '.join(BENCHMARKS)} (default: all)")
    args = ap.parse_args(argv)
    unknown = [n for n in args.names if n not in BENCHMARKS]
    if unknown:
        ap.error(f"unknown benchmark {', '.join(unknown)} (choose from {', '.join(BENCHMARKS)})")
    failed = []
    for name in args.names or BENCHMARKS:
        full, quick = BENCHMARKS[name]
        cmd = [sys.executable, "-m", f"benchmarks.bench_{name}", *(quick if args.quick else full)]
        print(f"\n=== {name}: {' '.join(cmd[1:])}", flush=True)
        if subprocess.call(cmd) != 0:
            failed.append(name)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
