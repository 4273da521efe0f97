"""``python -m tests.fuzz --mutants 20000 --seed 7``: fuzz the readers, print counts per outcome.

Exit 0 when no mutant crashed, hung, ran out of memory or gave an unexplained / multi-line
reason; 1 otherwise (the failing mutants are saved under /tmp/pneubench-fuzz/).
``--replay FILE`` ingests one saved mutant again.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tests.fuzz import FINDINGS, TIMEOUT_S, child_main, replay, run


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        child_main()
        return 0
    parser = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__.splitlines()[0])
    parser.add_argument("--mutants", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, help="seconds per mutant")
    parser.add_argument("--only", help="mutate only the seeds whose name contains this (e.g. v5, tdms, csv)")
    parser.add_argument("--reasons", action="store_true", help="also count quarantine reasons by shape")
    parser.add_argument("--replay", type=Path, help="ingest one saved mutant again")
    args = parser.parse_args(argv)
    if args.replay:
        outcome, reason = replay(args.replay, args.timeout)
        print(f"{outcome}: {reason}")
        return int(outcome in FINDINGS)
    report = run(args.mutants, args.seed, timeout=args.timeout, only=args.only,
                 log=lambda s: print(s, file=sys.stderr, flush=True))
    print(report.summary())
    if args.reasons:
        for shape, n in report.reasons.most_common(40):
            print(f"{n:7d}  {shape}")
    return int(any(report.counts[k] for k in FINDINGS))


if __name__ == "__main__":
    sys.exit(main())
