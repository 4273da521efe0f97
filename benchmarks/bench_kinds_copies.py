"""The cost of one change of each kind on built copies of a campaign (issue 26 at 10,000 runs).

A full rebuild of 10,000 runs costs ~470 CPU-s: too much to build once per version and per
session. This benchmark takes copies already built (``cp -a`` of ``scale-10000``: ``raw/`` and
``warehouse/``), one per version of the code, and times on each the same change, alternating::

    python -m benchmarks.bench_kinds_copies --copy main=TREE_MAIN:DATA_MAIN --copy branch=.:DATA_BRANCH \\
        --kinds breakaway,viscous,step,"logbook line" --rounds 2 --noop 3 --json k10.json

``TREE`` is a source tree of the version (``git archive`` of a ref, or ``.``: this checkout) and
``DATA`` a folder holding ``raw/`` and ``warehouse/``. Each copy is first caught up with its
version (one rebuild, its wall and CPU printed; ``--no-catch-up`` skips it); then for each kind of
:func:`benchmarks.bench_scale.change_victims` (the victims are taken from the first copy's
warehouse and applied to every copy by their path under ``raw/``), each round changes the file,
rebuilds (timed: wall, CPU of the process tree), puts the old bytes and mtime back and rebuilds
(untimed). Each round's edit is one no copy has seen (:data:`SEEN_EDITS`, kept in each copy: a copy's
stage folders outlive its rebuilds, and an edit seen before takes them back); when a kind's edits run
out (a last digit has nine), the rounds that repeat one are said. ``--noop N``: N alternating no-op rebuilds of each copy. Shares are of ``--full-cpu``
(default 466.4 CPU-s, session 22's full rebuild of the seed-7 campaign) against 2 %.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from benchmarks.bench_scale import bump_last_digit, change_victims
from benchmarks.bench_versions import _env, command
from benchmarks.proc import measure, verdict

#: The full rebuild of the 10,000-run campaign the shares are of [CPU s] (session 22, main's code).
FULL_CPU_S = 466.4


def _rebuild(tree: Path, data: Path) -> tuple[float, float, str]:
    """One ``pneubench rebuild`` of a copy: wall [s], CPU of the process tree [s], its last line."""
    m = measure([*command(tree), "rebuild", "--raw", str(data / "raw"), "--warehouse", str(data / "warehouse")],
                cwd=tree, env=_env(tree), check=False)
    if m.exit_code not in (0, 1):
        raise SystemExit(f"{tree} on {data}: rebuild exited {m.exit_code}: {(m.stdout + m.stderr).strip()[-400:]}")
    last = (m.stdout + m.stderr).strip().splitlines()[-1:] or [""]
    return m.wall_s, m.cpu_s, last[0]


#: Per copy (in its data folder): the edits it has seen, ``{kind: [by, ...]}``. A copy keeps its stage
#: folders and memo between rebuilds, so an edit it saw before takes them back: the change reads
#: cheaper than a lab's new one (session 26: ~1.5 CPU-s of spring figures not drawn).
SEEN_EDITS = ".bench-kinds-edits.json"


def seen_edits(data: Path) -> dict[str, list[int]]:
    """:data:`SEEN_EDITS` of a copy (``{}`` when absent or damaged)."""
    try:
        got = json.loads((data / SEEN_EDITS).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return got if isinstance(got, dict) else {}


def fresh_edits(datas: list[Path], kind: str, rounds: int, period: int | None) -> tuple[list[int], int]:
    """``rounds`` edit amounts (``by``) no copy in ``datas`` has seen for ``kind``, smallest first, and how
    many of them had to be seen ones (none left: ``period`` edits are all there are, e.g. 10 for a last
    digit, whose ``by`` 10 would change nothing)."""
    def same(b: int) -> int:
        return b % period if period else b

    used = {same(int(b)) for d in datas for b in seen_edits(d).get(kind, []) if isinstance(b, int)}
    limit = (period - 1) if period else rounds + len(used)
    fresh = [b for b in range(1, limit + 1) if same(b) not in used][:rounds]
    stale = rounds - len(fresh)
    seen_before = [b for b in range(1, limit + 1) if same(b) in used]
    return fresh + [seen_before[i % len(seen_before)] for i in range(stale)], stale


def _note_edit(data: Path, kind: str, by: int) -> None:
    seen = seen_edits(data)
    seen[kind] = sorted(set(seen.get(kind, [])) | {by})
    (data / SEEN_EDITS).write_text(json.dumps(seen, sort_keys=True), encoding="utf-8")


def parse_copies(specs: list[str]) -> dict[str, tuple[Path, Path]]:
    """``--copy NAME=TREE:DATA`` options as ``{name: (code tree, data folder)}``, in their order."""
    copies = {}
    for spec in specs:
        name, _, rest = spec.partition("=")
        tree, _, data = rest.partition(":")
        copies[name] = (Path(tree).resolve(), Path(data).resolve())
    return copies


def on_copies(copies: dict[str, tuple[Path, Path]], kinds: list[str], rounds: int, noop: int = 0,
              catch_up: bool = True, save=None) -> dict:
    """Per copy ``{name: (code tree, data folder)}``: ``catch-up`` [wall, CPU], per kind the rounds'
    [wall, CPU] and ``noop`` [wall, CPU] pairs; ``save(out)`` after each kind."""
    out: dict = {name: {} for name in copies}
    names = list(copies)
    if catch_up:
        for name, (tree, data) in copies.items():
            wall, cpu, last = _rebuild(tree, data)
            out[name]["catch-up"] = [wall, cpu]
            print(f"  {name}: catch-up {wall:.1f} s, CPU {cpu:.1f} s: {last[-160:]}", flush=True)
    first = copies[names[0]][1]
    victims = change_victims(first / "raw", first / "warehouse")
    for kind in [k for k in kinds if k in victims] if kinds else list(victims):
        path, edit = victims[kind]
        rel = path.relative_to(first / "raw")
        bys, stale = fresh_edits([d for _t, d in copies.values()], kind, rounds,
                                 10 if edit is bump_last_digit else None)
        if stale:
            print(f"  {kind}: {stale} of {rounds} edits seen before on these copies: their stage folders are "
                  "taken back, those rounds read cheaper than a new change (use fresh copies)", flush=True)
        for i in range(rounds):
            for name in (names if i % 2 == 0 else list(reversed(names))):
                tree, data = copies[name]
                target = data / "raw" / rel
                st = target.stat()
                original = edit(target, bys[i])
                _note_edit(data, kind, bys[i])
                try:
                    wall, cpu, last = _rebuild(tree, data)
                finally:
                    target.write_bytes(original)
                    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
                out[name].setdefault(kind, []).append([wall, cpu])
                _rebuild(tree, data)  # back to the campaign as it was
                print(f"  {name}: {kind} ({rel}) {wall:.1f} s, CPU {cpu:.2f} s, load {os.getloadavg()[0]:.1f}: "
                      f"{last.split('stages run: ')[-1][:90]}", flush=True)
        if save:
            save(out)
    for i in range(noop):
        for name in (names if i % 2 == 0 else list(reversed(names))):
            wall, cpu, last = _rebuild(*copies[name])
            out[name].setdefault("noop", []).append([wall, cpu])
            print(f"  {name}: no-op {wall:.2f} s, CPU {cpu:.2f} s, load {os.getloadavg()[0]:.1f}", flush=True)
    if save:
        save(out)
    return out


def table(out: dict, full_cpu: float) -> list[str]:
    """The markdown table: per kind and copy, the rounds' CPU, their mean and its share of ``full_cpu``."""
    names = list(out)
    kinds = [k for k in dict.fromkeys(k for r in out.values() for k in r) if k != "catch-up"]
    lines = ["| change | " + " | ".join(f"{n}: CPU s (rounds), share" for n in names) + " |",
             "|---|" + "---|" * len(names)]
    for k in kinds:
        cells = []
        for n in names:
            got = [c for _w, c in out[n].get(k, [])]
            if not got:
                cells.append("-")
                continue
            mean = statistics.fmean(got)
            cells.append(f"{mean:.2f} ({', '.join(f'{c:.2f}' for c in got)}), {mean / full_cpu:.4f}")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--copy", action="append", required=True, metavar="NAME=TREE:DATA",
                    help="a version's code tree and its built copy (raw/ and warehouse/)")
    ap.add_argument("--kinds", default="", help="comma-separated kinds of change (default: all nine)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--noop", type=int, default=0, help="alternating no-op rebuilds per copy")
    ap.add_argument("--no-catch-up", action="store_true", help="the copies are caught up already")
    ap.add_argument("--full-cpu", type=float, default=FULL_CPU_S, help="the full rebuild's CPU s (shares)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    copies = parse_copies(args.copy)
    print(f"one change of each kind on built copies; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}, "
          f"{time.strftime('%H:%M:%S', time.gmtime())} UTC", flush=True)

    def save(out):
        if args.json:
            args.json.write_text(json.dumps({"copies": {k: [str(p) for p in v] for k, v in copies.items()},
                                             "load": os.getloadavg(), "times": out}, indent=1))

    out = on_copies(copies, [k for k in args.kinds.split(",") if k], args.rounds, args.noop,
                    not args.no_catch_up, save)
    print("\n" + "\n".join(table(out, args.full_cpu)))
    for n, r in out.items():
        kinds = {k: statistics.fmean(c for _w, c in v) for k, v in r.items() if k not in ("catch-up", "noop")}
        if kinds:
            worst = max(kinds, key=kinds.get)
            share = kinds[worst] / args.full_cpu
            print(f"{verdict(share < 0.02)}  {n}: worst measured kind ({worst}) under 2 % of a full rebuild: {share:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
