"""Before and after a change of the code, in one run: the commands a user waits for, timed as
whole processes of both versions on the same raw tree, alternating.

One command::

    python -m benchmarks versions                                  # --ref main~1, 10,000 runs
    python -m benchmarks.bench_versions --ref 8789976 --runs 1000  # a quick look
    python -m benchmarks.bench_versions --ref c5101b4 --raw /tmp/demo/raw \
        --victim durability-2025/hoses.csv                         # what a feature adds to the demo

The reference version is exported with ``git archive`` (as :mod:`benchmarks.same_behaviour`
does) and run with this interpreter and these libraries, so only the code differs. The campaign
is :mod:`benchmarks.bench_scale`'s (``benchmarks/_data/scale-N/``, reused when present). Each
version builds its own warehouse from it once (``full``, timed), then, alternating before/after
so that a change of the machine's load hits both alike (medians of ``--repeat``):

* ``noop``: the same raw/ again;
* ``one file``: one run file's bytes changed (a newline appended), rebuilt, then put back with its
  old bytes and mtime and rebuilt again (untimed), so that both versions start the next round
  from the same state (every file keeps one fixed mtime: a new one would make the other
  version's next no-op hash every file);
* ``query start-up``: ``pneubench query "SELECT 1"`` (imports, the read-only door, the format);
* ``one-run query``: one run's samples through the view, as ``bench_scale`` times it.

Prints a table with the ratio after / before for each, and exits 1 when a median got slower by
more than ``--tolerance`` (default 15 %, about the spread of repeated runs on a shared machine)
and by more than 50 ms.
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

from benchmarks.bench_scale import DATA, make_campaign
from benchmarks.proc import measure
from benchmarks.same_behaviour import export

ROOT = Path(__file__).resolve().parent.parent


def command(tree: Path) -> list[str]:
    """``pneubench`` of the code under ``tree``, with this interpreter."""
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); "
            "from pipeline.cli import main; main()"]


def _env(tree: Path) -> dict:
    """The environment of a version's processes: its tree first on the path, and bytecode cached
    as an installed package's is (``PYTHONDONTWRITEBYTECODE`` would make every process compile
    every module it imports again: a cost no nightly job pays, and one that grows with the number
    of modules rather than with the work)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    for name in ("PNEUBENCH_RAW", "PNEUBENCH_WAREHOUSE", "PYTHONDONTWRITEBYTECODE"):
        env.pop(name, None)
    return env


def child_after_edit(path: Path, edit, argv: list[str], *, tree: Path, data: Path, cwd: Path,
                     label: str) -> dict:
    """One edit of a raw file measured by a child process, the copy put back after it.

    ``edit(path)`` changes the file and returns its old bytes; ``argv`` (run in ``cwd`` with the
    environment of ``tree``'s version) prints one line ``RESULT <json>``. The old bytes and mtime are
    put back whatever the child did, and the copy ``data`` is rebuilt quietly by ``tree``'s code so
    that the next edit starts from the same warehouse. Returns the child's JSON; a child that printed
    none ends the benchmark with its ``label`` and the end of its stderr."""
    st = path.stat()
    original = edit(path)
    try:
        p = subprocess.run(argv, cwd=cwd, env=_env(tree), capture_output=True, text=True)
    finally:
        path.write_bytes(original)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    subprocess.run([*command(tree), "rebuild", "--raw", str(data / "raw"), "--warehouse", str(data / "warehouse"),
                    "-q"], cwd=tree, env=_env(tree), capture_output=True)
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
    if not line:
        raise SystemExit(f"{label}: {p.stderr[-2000:]}")
    return json.loads(line[0][7:])


def _timed(tree: Path, *args: str) -> tuple[float, float]:
    """Wall and CPU seconds (the process tree's) of one ``pneubench`` command."""
    m = measure([*command(tree), *args], cwd=tree, env=_env(tree))
    if m.exit_code != 0:
        raise SystemExit(f"{tree}: pneubench {' '.join(args[:1])} exited {m.exit_code}: {m.stderr.strip()[-300:]}")
    return m.wall_s, m.cpu_s


def _age_to(raw: Path, when: float) -> None:
    """Every file's mtime set to ``when`` (the same moment every time: a file put back after a
    change has exactly its old stat again, so neither version sees the other's edit)."""
    for p in raw.rglob("*"):
        if p.is_file():
            os.utime(p, (when, when))


def run(ref: str, runs: int, repeat: int, seed: int, raw_given: Path | None = None, victim_rel: str | None = None) -> dict:
    work = Path(tempfile.mkdtemp(prefix="pneubench-versions-"))
    if raw_given is not None:  # a copy: the benchmark edits a file and sets mtimes
        raw = work / "raw"
        shutil.copytree(raw_given, raw, symlinks=True)
    else:
        raw = make_campaign(DATA / f"scale-{runs}", runs, seed)
    past = time.time() - 3600  # a night's files, an hour old
    _age_to(raw, past)
    try:
        trees = {"before": export(ref, work / "before"), "after": ROOT}
        wh = {name: work / f"warehouse-{name}" for name in trees}
        rebuild = {name: ["rebuild", "--raw", str(raw), "--warehouse", str(wh[name]), "-q"] for name in trees}
        times: dict[str, dict[str, list[float]]] = {name: {} for name in trees}

        def add(name, what, seconds):
            """Wall seconds under ``what``, CPU seconds under ``what (CPU)``: on a shared machine
            the CPU time is the steadier comparison, the wall time what a user waits."""
            times[name].setdefault(what, []).append(seconds[0])
            times[name].setdefault(f"{what} (CPU)", []).append(seconds[1])

        for name, tree in trees.items():
            add(name, "full", _timed(tree, *rebuild[name]))
            print(f"  {name}: full rebuild {times[name]['full'][0]:.1f} s", flush=True)
        victim = (raw / victim_rel if victim_rel else
                  next(p for p in sorted(raw.rglob("*.csv")) if p.name not in ("manifest.csv", "hoses.csv")))
        original = victim.read_bytes()
        query = {name: ["query", "--warehouse", str(wh[name]), "--format", "csv"] for name in trees}
        run_id = measure([*command(ROOT), *query["after"], "SELECT min(run_id) FROM runs WHERE samples_path IS NOT NULL"],
                         cwd=ROOT, env=_env(ROOT)).stdout.splitlines()[1].strip()
        kind = measure([*command(ROOT), *query["after"], f"SELECT kind FROM runs WHERE run_id = '{run_id}'"],
                       cwd=ROOT, env=_env(ROOT)).stdout.splitlines()[1].strip()
        for i in range(repeat):
            order = list(trees) if i % 2 == 0 else list(reversed(trees))
            for name in order:
                tree = trees[name]
                add(name, "noop", _timed(tree, *rebuild[name]))
                victim.write_bytes(original + b"\n")
                try:
                    add(name, "one file", _timed(tree, *rebuild[name]))
                finally:
                    victim.write_bytes(original)
                    os.utime(victim, (past, past))
                _timed(tree, *rebuild[name])
                add(name, "query start-up", _timed(tree, *query[name], "SELECT 1"))
                add(name, "one-run query", _timed(tree, *query[name],
                                                  f"SELECT * FROM samples_{kind} WHERE run_id = '{run_id}'"))
        return {name: {what: statistics.median(v) for what, v in t.items()} for name, t in times.items()}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default="main~1", help="the version before (a commit, branch or tag)")
    ap.add_argument("--runs", type=int, default=10000, help="campaign size")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--tolerance", type=float, default=0.15)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--raw", type=Path, default=None,
                    help="time on a copy of this raw tree (e.g. the demo's) instead of the scale campaign")
    ap.add_argument("--victim", default=None,
                    help="the file (relative to raw/) that 'one file' changes; default the first run CSV")
    args = ap.parse_args(argv)
    rev = subprocess.run(["git", "rev-parse", "--short", args.ref], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    what_raw = f"raw tree {args.raw}" if args.raw else f"{args.runs} runs"
    print(f"before: {args.ref} ({rev}); after: this checkout; {what_raw}, {os.cpu_count()} cores; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    med = run(args.ref, args.runs, args.repeat, args.seed, args.raw, args.victim)
    print(f"\n| command ({args.raw.name if args.raw else f'{args.runs:,} runs'}) | before [s] | after [s] | after / before |")
    print("|---|---|---|---|")
    slower = []
    for what in med["before"]:
        b, a = med["before"][what], med["after"][what]
        print(f"| {what} | {b:.3f} | {a:.3f} | {a / b:.2f} |")
        if not what.startswith("full") and a > b * (1 + args.tolerance) and a - b > 0.05:
            slower.append(what)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    if args.json:
        args.json.write_text(json.dumps({"ref": rev, "runs": args.runs, "medians": med}, indent=1))
    if slower:
        print(f"SLOWER: {', '.join(slower)}")
    return 1 if slower else 0


if __name__ == "__main__":
    sys.exit(main())
