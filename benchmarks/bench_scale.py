"""The cost curve: what a user waits for as the raw tree grows to 10,000 runs.

One command::

    python -m benchmarks scale                              # 1,000, 3,000 and 10,000 runs (~15 min)
    python -m benchmarks.bench_scale --runs 300,1000        # a quick look

For each size it writes a campaign with ``pneubench simulate DIR --runs N`` (demo profile, under
``benchmarks/_data/scale-N/``, git-ignored, reused when present; files aged an hour, as a
night's files are when the job runs) and times, each as a whole ``pneubench`` process (imports,
workers and the morning report included, what cron runs):

* ``full``: the first ``pneubench rebuild`` into a fresh warehouse;
* ``noop``: the same raw/ again (median of 3);
* ``one file``: one run file's bytes changed (a newline appended), then rebuilt;
* ``one logbook line``: one ``hoses.csv`` line's notes changed, then rebuilt;
* ``one change of each kind`` (issue 26): the last digit of one CSV run file of each kind, a
  logbook line's notes, a ``plan.toml`` setting (:func:`change_victims`; a campaign simulated
  before the simulator wrote a plan.toml gets today's, :func:`ensure_plan`), each rebuilt and put
  back; the CPU seconds of the process tree as a share of the full rebuild's;
* the warehouse's size on disk;
* three typical queries through ``pneubench query`` (median of 3): one run's samples by run_id,
  the leak map at 5 bar, the service life table.

Targets (at the largest size): no-op under 2 s; one file changed under 5 % of a full rebuild;
at every size, the worst kind of change under 5 % of a full rebuild's CPU at 1,000 runs and 2 % at
10,000 (:func:`kind_target`);
the one-run samples query under 0.5 s; no-op and one-change time growing no faster than linear
in the number of runs (the exponent of a power law fitted over the sizes, log-log least squares,
at most 1.0). It prints every figure with PASS / MISS, writes ``--json`` and a log-log plot of
the curve (``--plot``, default ``benchmarks/scale.png``).

A raw tree and its warehouse copied elsewhere (issue 26: a backup restored, a new disk), ``cp -a``
and ``cp -r``, the first rebuild of the copy against a no-op, before and after a change::

    python -m benchmarks.bench_scale --copied --ref main --runs 60

The cost of a change of each kind (issue 26), before and after a change of the code in one run::

    python -m benchmarks.bench_scale --per-kind --ref main --runs 1000

Both versions (``--ref`` and ``--after``, default this checkout's HEAD, each exported with ``git
archive``) build their own warehouse from the same campaign (``full``), then, alternating before /
after per kind, one value of one file is changed (the last digit of one CSV run file of each kind;
a logbook line's notes; a setting of ``plan.toml``), rebuilt (timed) and put back with its old bytes
and mtime (rebuilt, untimed). Each rebuild is a whole process; the CPU seconds of its process tree
are the figure a loaded machine moves least. The table gives each kind's share of the version's
own full rebuild, CPU and wall. With ``--json`` the figures are written after each kind.

Issue 26's table (before: the issue's figures; after: each size's, PASS / MISS against 5 % / 2 %, the
worst kind) and ``scale.png`` redrawn as the worst kind's share against the runs, from such files
(:mod:`benchmarks.scale_kinds`; nothing measured)::

    python -m benchmarks.bench_scale --render k1000.json --render k10000.json
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import os
import shutil
import statistics
import sys
import time
from pathlib import Path

from benchmarks.proc import Series, measure, pneubench_cmd, verdict
from benchmarks.scale_kinds import kind_target, per_kind_table, render

DATA = Path(__file__).resolve().parent / "_data"
HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def _age(raw: Path, seconds: float = 3600.0) -> None:
    past = time.time() - seconds
    for p in raw.rglob("*"):
        if p.is_file():
            os.utime(p, (past, past))


def make_campaign(base: Path, runs: int, seed: int) -> Path:
    raw = base / "raw"
    if (base / ".complete").is_file():
        ensure_plan(raw)
        return raw
    shutil.rmtree(base, ignore_errors=True)
    base.mkdir(parents=True)
    m = measure([*pneubench_cmd(), "simulate", str(raw), "--seed", str(seed), "--runs", str(runs), "-q"], cwd=ROOT)
    print(f"  simulated {runs} runs in {m.wall_s:.0f} s: {m.stdout.strip()}")
    (base / ".complete").write_text("ok\n")
    return raw


def ensure_plan(raw: Path) -> bool:
    """Give a campaign simulated before the simulator wrote ``plan.toml`` the one it writes now
    (:data:`pipeline.simulator.profiles.DEMO_PLAN`, aged an hour), so that the ``plan.toml`` kind of
    change is measured (issue 26; session 19's 1,000-run campaign had none). True when written."""
    from pipeline.simulator.profiles import DEMO_PLAN

    plan = raw / "plan.toml"
    if plan.exists() or not raw.is_dir():
        return False
    plan.write_text(DEMO_PLAN, encoding="utf-8")
    past = time.time() - 3600
    os.utime(plan, (past, past))
    print(f"  {plan}: the simulator's plan.toml written (the campaign predates it)", flush=True)
    return True


def _size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def _edit_logbook(path: Path, note: str = "(checked)") -> bytes:
    """Change the notes of the logbook's first data line; returns the original bytes."""
    original = path.read_bytes()
    rows = list(csv.reader(io.StringIO(original.decode("utf-8"))))
    head = rows[0]
    col = head.index("notes") if "notes" in head else len(head) - 1
    rows[1][col] = (rows[1][col] + " " + note).strip()
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    path.write_text(buf.getvalue(), encoding="utf-8")
    return original


def _exponent(ns: list[int], ts: list[float]) -> float | None:
    """Slope of log(t) against log(n), least squares: t ~ n^k."""
    import numpy as np

    if len(ns) < 2:
        return None
    k, _ = np.polyfit(np.log(ns), np.log(ts), 1)
    return float(k)


#: Phases of a rebuild whose cumulative time the no-op profile reports [function name in cProfile].
PHASES = {"load_previous": "load_previous", "scan raw/": "discover_runs", "plan (stat, metadata)": "plan_runs",
          "ingest": "ingest_incremental", "stages (reuse or run)": "run_stages_cached",
          "write database": "build_database", "morning report": "render_report", "publish report": "publish_report",
          "collect garbage": "collect_garbage", "whole rebuild()": "rebuild"}


def profile_noop(rebuild: list[str], out: Path) -> dict:
    """Seconds per phase of one no-op rebuild (cProfile in the rebuild's process; the rest of the
    wall time is Python start-up and imports)."""
    import pstats

    argv = rebuild[3:]
    code = (f"import cProfile, sys; sys.argv = ['pneubench'] + {argv!r}; from pipeline.cli import main; "
            f"cProfile.run('main()', {str(out)!r})")
    measure([sys.executable, "-c", code], cwd=ROOT)
    st = pstats.Stats(str(out)).stats
    phases = {}
    for label, fn in PHASES.items():
        cum = [v[3] for (file, _line, name), v in st.items() if name == fn and "pipeline" in file]
        phases[label] = max(cum) if cum else 0.0
    phases["all in the process"] = max(v[3] for v in st.values())
    return phases


def bench_size(runs: int, seed: int, repeat: int, jobs: int | None) -> dict:
    base = DATA / f"scale-{runs}"
    print(f"\n{runs} runs ({base})")
    raw = make_campaign(base, runs, seed)
    _age(raw)
    wh = base / "warehouse"
    shutil.rmtree(wh, ignore_errors=True)
    rebuild = [*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "-q"]
    if jobs:
        rebuild += ["--jobs", str(jobs)]
    out: dict = {"runs": runs, "raw_mb": _size_mb(raw)}
    full = measure(rebuild, cwd=ROOT)
    out["full_s"], out["full_tree_mb"] = full.wall_s, full.tree_peak_mb
    out["full_cpu_s"] = full.cpu_s
    out["full_tree_pss_mb"] = full.tree_peak_pss_mb  # shared (forked) pages counted once
    noop = Series("noop", [measure(rebuild, cwd=ROOT) for _ in range(repeat)])
    out["noop_s"], out["noop_tree_mb"] = noop.wall_s, noop.tree_peak_mb
    out["noop_cpu_s"] = noop.cpu_s
    prof = profile_noop(rebuild, base / "noop.prof")
    print("  no-op profile [s, cumulative, under cProfile]: " + ", ".join(f"{k} {v:.2f}" for k, v in prof.items()))

    victim = next(p for p in sorted(raw.rglob("*.csv")) if p.name not in ("manifest.csv", "hoses.csv"))
    original = victim.read_bytes()
    victim.write_bytes(original + b"\n")
    out["one_file_s"] = measure(rebuild, cwd=ROOT).wall_s
    victim.write_bytes(original)
    _age(raw)
    measure(rebuild, cwd=ROOT)

    logbook = sorted(raw.rglob("hoses.csv"))[0]
    original = _edit_logbook(logbook)
    out["one_logbook_line_s"] = measure(rebuild, cwd=ROOT).wall_s
    logbook.write_bytes(original)
    _age(raw)
    measure(rebuild, cwd=ROOT)
    out["warehouse_mb"] = _size_mb(wh)
    out.update(kind_changes(raw, wh, rebuild))

    query = [*pneubench_cmd(), "query", "--warehouse", str(wh), "--format", "csv"]
    run_id = measure([*query, "SELECT run_id FROM runs WHERE kind = 'durability' ORDER BY n_samples DESC LIMIT 1"],
                     cwd=ROOT).stdout.splitlines()[1].strip()
    # and one run of the kind with the most runs (the most files a view could open)
    many = measure([*query, "SELECT kind, min(run_id) FROM runs WHERE samples_path IS NOT NULL GROUP BY kind "
                    "ORDER BY count(*) DESC, kind LIMIT 1"], cwd=ROOT).stdout.splitlines()[1].strip().split(",", 1)
    queries = {
        "query_one_run_s": f"SELECT * FROM samples_durability WHERE run_id = '{run_id}'",
        "query_one_run_many_files_s": f"SELECT * FROM samples_{many[0]} WHERE run_id = '{many[1]}'",
        # the same run through the samples() macro: planned without the kind's file list
        "query_one_run_macro_s": f"SELECT * FROM samples('{many[1]}')",
        "query_leak_5bar_s": "SELECT * FROM leakage_map WHERE round(pressure_bar) = 5 ORDER BY run_id",
        "query_service_life_s": "SELECT * FROM service_life",
    }
    shown = [*pneubench_cmd(), "query", "--warehouse", str(wh)]  # the default table format, as typed
    for key, sql in queries.items():
        q = Series(key, [measure([*shown, sql], cwd=ROOT) for _ in range(repeat)])
        out[key], out[key[:-2] + "_cpu_s"] = q.wall_s, q.cpu_s  # CPU: the figure a loaded machine does not move
    out["noop_profile"] = prof
    for k, v in out.items():
        if k not in ("runs", "noop_profile", "per_kind", "worst_kind"):
            print(f"  {k:22s} {v:10.3f}")
    return out


def kind_changes(raw: Path, wh: Path, rebuild: list[str]) -> dict:
    """One change of each kind (:func:`change_victims`) rebuilt as a whole process and put back
    (rebuilt, untimed): ``per_kind`` {kind: [wall s, CPU s]}, the worst kind by CPU and its wall
    seconds (``worst_kind_s``, the cost curve's series) and CPU share of the full rebuild (issue 26)."""
    per: dict[str, list[float]] = {}
    past = time.time() - 3600
    for kind, (path, edit) in change_victims(raw, wh).items():
        original = edit(path, 1)
        try:
            m = measure(rebuild, cwd=ROOT)
        finally:
            path.write_bytes(original)
            os.utime(path, (past, past))
        measure(rebuild, cwd=ROOT)  # back to the campaign as it was
        per[kind] = [m.wall_s, m.cpu_s]
        print(f"  change {kind} ({path.relative_to(raw)}): {m.wall_s:.1f} s, CPU {m.cpu_s:.1f} s", flush=True)
    if not per:
        return {}
    worst = max(per, key=lambda k: per[k][1])
    return {"per_kind": per, "worst_kind": worst, "worst_kind_s": per[worst][0], "worst_kind_cpu_s": per[worst][1]}


def kind_lines(results: list[dict]) -> tuple[list[str], list[tuple[str, float, bool]]]:
    """The per-kind table (CPU share of each size's full rebuild) and a check per size: the worst kind
    under :func:`kind_target`."""
    sized = [r for r in results if r.get("per_kind") and r.get("full_cpu_s")]
    if not sized:
        return [], []
    kinds = list(dict.fromkeys(k for r in sized for k in r["per_kind"]))
    lines = ["| change: CPU share of full (CPU s) | " + " | ".join(f"{r['runs']:,} runs" for r in sized) + " |",
             "|---|" + "---|" * len(sized)]
    lines.append("| full rebuild, CPU s | " + " | ".join(f"{r['full_cpu_s']:.1f}" for r in sized) + " |")
    for k in kinds:
        cells = [f"{r['per_kind'][k][1] / r['full_cpu_s']:.3f} ({r['per_kind'][k][1]:.1f})" if k in r["per_kind"]
                 else "-" for r in sized]
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    checks = []
    for r in sized:
        share = r["worst_kind_cpu_s"] / r["full_cpu_s"]
        target = kind_target(r["runs"])
        checks.append((f"worst kind ({r['worst_kind']}) under {target:.0%} of a full rebuild at {r['runs']} runs (CPU)",
                       share, share < target))
    return lines, checks


#: Run kinds whose one changed file the per-kind benchmark times (a CSV file of each).
CHANGE_KINDS = ("spring", "breakaway", "leakage", "viscous", "durability", "pressure_step", "step")


def bump_last_digit(path: Path, by: int) -> bytes:
    """Change one value of a run file: its last digit + ``by`` (mod 10); returns the old bytes."""
    original = path.read_bytes()
    data = bytearray(original)
    i = max(i for i, b in enumerate(data) if 48 <= b <= 57)
    data[i] = 48 + (data[i] - 48 + by) % 10
    path.write_bytes(bytes(data))
    return original


def bump_plan(path: Path, by: int) -> bytes:
    """Change one setting of ``plan.toml`` (``km_per_day``, or the first ``margin``); returns the old bytes."""
    import re

    original = path.read_bytes()
    text = original.decode("utf-8")
    m = re.search(r"^(km_per_day|margin)\s*=\s*([0-9.]+)", text, re.MULTILINE)
    if m is None:
        raise SystemExit(f"{path}: no km_per_day or margin setting to change")
    new = f"{m.group(1)} = {float(m.group(2)) + 0.01 * by:g}"
    path.write_text(text[:m.start()] + new + text[m.end():], encoding="utf-8")
    return original


def change_victims(raw: Path, warehouse: Path) -> dict[str, tuple[Path, object]]:
    """Per kind of change: the file changed and how (``edit(path, by) -> old bytes``)."""
    import duckdb

    con = duckdb.connect(str(warehouse / "pneubench.duckdb"), read_only=True)
    try:
        rows = con.execute("SELECT kind, min(source_path) FROM runs WHERE lower(source_path) LIKE '%.csv' "
                           "GROUP BY kind").fetchall()
    finally:
        con.close()
    found = dict(rows)
    out = {kind: (raw / found[kind], bump_last_digit) for kind in CHANGE_KINDS if kind in found}
    logbooks = sorted(raw.rglob("hoses.csv"))
    if logbooks:
        out["logbook line"] = (logbooks[0], lambda path, by: _edit_logbook(path, f"(checked {by})"))
    if (raw / "plan.toml").is_file():
        out["plan.toml"] = (raw / "plan.toml", bump_plan)
    return out


def per_kind(ref: str, after: str, runs: int, seed: int, rounds: int, kinds: tuple[str, ...] = (),
             save=None) -> dict:
    """Wall and CPU seconds of a full rebuild and of one change of each kind, versions ``ref`` and
    ``after`` alternating on the same campaign (:func:`change_victims`; only ``kinds`` when given);
    ``save(times)`` after the full rebuilds and after each kind (a long run stopped keeps what it did)."""
    import tempfile

    from benchmarks.bench_versions import _age_to, command, _env
    from benchmarks.same_behaviour import export

    raw = make_campaign(DATA / f"scale-{runs}", runs, seed)
    past = time.time() - 3600
    _age_to(raw, past)
    work = Path(tempfile.mkdtemp(prefix="pneubench-per-kind-"))
    try:
        trees = {"before": export(ref, work / "before")} if ref != "none" else {}  # none: only --after
        trees["after"] = export(after, work / "after")
        out: dict = {name: {} for name in trees}

        def rebuild(name: str) -> tuple[float, float]:
            m = measure([*command(trees[name]), "rebuild", "--raw", str(raw), "--warehouse", str(work / f"wh-{name}"),
                         "-q"], cwd=trees[name], env=_env(trees[name]))
            return m.wall_s, m.cpu_s

        for name in trees:
            out[name]["full"] = [rebuild(name)]
            print(f"  {name}: full {out[name]['full'][0][0]:.1f} s, CPU {out[name]['full'][0][1]:.1f} s", flush=True)
        if save:
            save(out)
        victims = change_victims(raw, work / "wh-after")
        for kind in [k for k in kinds if k in victims] if kinds else list(victims):  # in the order asked
            path, edit = victims[kind]
            for i in range(rounds):
                for name in (trees if i % 2 == 0 else list(reversed(trees))):
                    original = edit(path, i + 1)
                    try:
                        out[name].setdefault(kind, []).append(rebuild(name))
                    finally:
                        path.write_bytes(original)
                        os.utime(path, (past, past))
                    rebuild(name)  # back to the campaign as it was
                    print(f"  {name}: {kind} ({path.relative_to(raw)}) {out[name][kind][-1][0]:.1f} s, "
                          f"CPU {out[name][kind][-1][1]:.1f} s, load {os.getloadavg()[0]:.1f}", flush=True)
            if save:
                save(out)
        return out
    finally:
        shutil.rmtree(work, ignore_errors=True)


def copy_tree(src: Path, dst: Path, keep_mtime: bool) -> None:
    """``cp -a`` (``keep_mtime``: mtimes kept, new inodes) or ``cp -r`` (new mtimes as well, aged an
    hour as a restored night's files are) of ``src`` to ``dst``."""
    shutil.copytree(src, dst, symlinks=True, copy_function=shutil.copy2 if keep_mtime else shutil.copyfile)
    if not keep_mtime:
        _age(dst)


#: How a raw tree and its warehouse are copied elsewhere (``--copied``): name -> mtimes kept.
COPIES = {"cp -a": True, "cp -r": False}


def _rebuilt(m) -> str:
    """What a rebuild's last line says: ``no-op``, or the stages it ran."""
    last = (m.stdout + m.stderr).strip().splitlines()[-1:] or [""]
    if "a no-op" in last[0]:
        return "no-op"
    return "stages run: " + (last[0].split("stages run: ")[-1].rsplit(",", 1)[0] if "stages run: " in last[0] else "?")


def copied(ref: str, after: str, runs: int, seed: int) -> dict:
    """Per version (``ref``, ``after``): CPU and wall of a no-op rebuild, and of the first rebuild of
    its raw tree and warehouse copied elsewhere (:data:`COPIES`), with what it did (issue 26: a
    copied warehouse's no-op re-ran every stage in session 19's measurement)."""
    import tempfile

    from benchmarks.bench_versions import _age_to, command, _env
    from benchmarks.same_behaviour import export

    raw = make_campaign(DATA / f"scale-{runs}", runs, seed)
    _age_to(raw, time.time() - 3600)
    work = Path(tempfile.mkdtemp(prefix="pneubench-copied-"))
    out: dict = {}
    try:
        for name, ref_ in (("before", ref), ("after", after)):
            tree = export(ref_, work / name)

            def rebuild(r: Path, wh: Path):
                return measure([*command(tree), "rebuild", "--raw", str(r), "--warehouse", str(wh)], cwd=tree,
                               env=_env(tree))

            wh = work / f"wh-{name}"
            rebuild(raw, wh)
            m = rebuild(raw, wh)
            out[name] = {"no-op": [m.wall_s, m.cpu_s, _rebuilt(m)]}
            for how, keep in COPIES.items():
                dest = work / f"copy-{name}"
                copy_tree(raw, dest / "raw", keep)
                copy_tree(wh, dest / "warehouse", keep)
                m = rebuild(dest / "raw", dest / "warehouse")
                out[name][how] = [m.wall_s, m.cpu_s, _rebuilt(m)]
                shutil.rmtree(dest)
                print(f"  {name}: {how} {m.wall_s:.1f} s, CPU {m.cpu_s:.1f} s: {out[name][how][2]}", flush=True)
        return out
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _main_copied(args) -> int:
    """``--copied``: the table of :func:`copied`; PASS when the copies' rebuilds of ``--after`` are
    no-ops under twice the no-op's CPU."""
    n = int(args.runs.split(",")[0])
    print(f"a raw tree and its warehouse copied elsewhere, {n} runs, before {args.ref}, after {args.after}; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    res = copied(args.ref, args.after, n, args.seed)
    print("\n| rebuild | " + " | ".join(f"{v}: wall s / CPU s, what it did" for v in res) + " |")
    print("|---|" + "---|" * len(res))
    for how in ("no-op", *COPIES):
        cells = [f"{r[how][0]:.1f} / {r[how][1]:.1f}, {r[how][2]}" for r in res.values()]
        print(f"| {how} | " + " | ".join(cells) + " |")
    after, ok = res["after"], True
    for how in COPIES:
        good = after[how][2] == "no-op" and after[how][1] < 2 * after["no-op"][1]
        ok &= good
        print(f"{verdict(good)}  {how} copy rebuilt as a no-op under twice the no-op's CPU "
              f"({after['no-op'][1]:.2f} s): {after[how][1]:.2f} s, {after[how][2]}")
    return 0 if ok else 1


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = [r["runs"] for r in results]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    series = [("full_s", "full rebuild", "o-"), ("one_file_s", "one file changed", "s-"),
              ("worst_kind_s", "one change of the worst kind", "P-"),
              ("one_logbook_line_s", "one logbook line changed", "^-"), ("noop_s", "no-op rebuild", "D-"),
              ("query_one_run_s", "query: one run's samples", "v--"), ("query_service_life_s", "query: service life", "x--")]
    for key, label, style in series:
        have = [(r["runs"], r[key]) for r in results if key in r]  # sizes measured before a series existed lack it
        if have:
            worst = {r.get("worst_kind") for r in results if key == "worst_kind_s" and "worst_kind" in r}
            ax.plot(*zip(*have), style, label=label + (f" ({', '.join(sorted(worst))})" if worst else ""))
    ax.plot(ns, [ns[0] and results[0]["full_s"] * n / ns[0] for n in ns], ":", color="grey", label="linear in runs")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("runs in raw/")
    ax.set_ylabel("wall time, whole process [s]")
    ax.set_title("pneubench cost curve (2 cores)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default="1000,3000,10000", help="comma-separated campaign sizes")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--repeat", type=int, default=3, help="runs of the no-op and of each query (median)")
    ap.add_argument("--jobs", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--plot", type=Path, default=HERE / "scale.png")
    ap.add_argument("--with-json", type=Path, action="append", default=[],
                    help="also use the sizes measured by an earlier run (its --json), for the table, the "
                         "exponents and the plot (a size measured now wins)")
    ap.add_argument("--per-kind", action="store_true",
                    help="the cost of one change of each kind, versions --ref and --after alternating (issue 26)")
    ap.add_argument("--ref", default="main", help="--per-kind, --copied: the version before (--per-kind: none)")
    ap.add_argument("--after", default="HEAD", help="--per-kind: the version after")
    ap.add_argument("--rounds", type=int, default=1, help="--per-kind: changes of each kind per version (median)")
    ap.add_argument("--kinds", default="", help="--per-kind: only these changes (comma-separated, e.g. spring)")
    ap.add_argument("--render", type=Path, action="append", default=[],
                    help="measure nothing: issue 26's per-kind table (before / after, PASS / MISS) and the cost-curve "
                         "plot (--plot) from --per-kind or cost-curve --json files (repeat it for each)")
    ap.add_argument("--copied", action="store_true",
                    help="the first rebuild of a raw tree and warehouse copied elsewhere, --ref and --after (issue 26)")
    args = ap.parse_args(argv)
    if args.render:
        return render(args.render, args.plot)
    if args.per_kind:
        return _main_per_kind(args)
    if args.copied:
        return _main_copied(args)
    sizes = sorted(int(n) for n in args.runs.split(",") if n.strip())
    print(f"pneubench cost curve: {sizes} runs, {os.cpu_count()} cores, python {sys.version.split()[0]}")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    results = [bench_size(n, args.seed, args.repeat, args.jobs) for n in sizes]
    for f in args.with_json:
        results += [r for r in json.loads(f.read_text())["results"] if r["runs"] not in sizes]
    results.sort(key=lambda r: r["runs"])
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    big = results[-1]
    ns = [r["runs"] for r in results]
    k_noop = _exponent(ns, [r["noop_s"] for r in results])
    k_one = _exponent(ns, [r["one_file_s"] for r in results])
    checks = [
        (f"no-op rebuild at {big['runs']} runs < 2 s", big["noop_s"], big["noop_s"] < 2.0),
        (f"one file changed < 5 % of full at {big['runs']} runs", big["one_file_s"] / big["full_s"],
         big["one_file_s"] / big["full_s"] < 0.05),
        (f"one-run samples query at {big['runs']} runs < 0.5 s", big["query_one_run_s"], big["query_one_run_s"] < 0.5),
    ]
    if "query_one_run_many_files_s" in big:
        checks.append((f"one-run samples query, kind with the most files, at {big['runs']} runs < 0.5 s",
                       big["query_one_run_many_files_s"], big["query_one_run_many_files_s"] < 0.5))
    if "query_one_run_macro_s" in big:
        checks.append((f"one-run samples query through samples('<run_id>'), kind with the most files, at "
                       f"{big['runs']} runs < 0.5 s", big["query_one_run_macro_s"], big["query_one_run_macro_s"] < 0.5))
    if k_noop is not None:
        checks += [("no-op growth exponent <= 1 (linear)", k_noop, k_noop <= 1.0),
                   ("one-change growth exponent <= 1 (linear)", k_one, k_one <= 1.0)]
    print("\n| runs | raw MB | full s | no-op s | one file s | one logbook line s | warehouse MB | one-run query s "
          "| leak map query s | service life query s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['runs']:,} | {r['raw_mb']:.0f} | {r['full_s']:.1f} | {r['noop_s']:.2f} | {r['one_file_s']:.2f} "
              f"| {r['one_logbook_line_s']:.2f} | {r['warehouse_mb']:.0f} | {r['query_one_run_s']:.2f} "
              f"| {r['query_leak_5bar_s']:.2f} | {r['query_service_life_s']:.2f} |")
    table, kind_checks = kind_lines(results)
    checks += kind_checks
    if table:
        print("\n" + "\n".join(table))
    print()
    for what, value, ok in checks:
        print(f"{verdict(ok)}  {what}: {value:.3f}")
    if args.plot:
        plot(results, args.plot)
        print(f"plot: {args.plot}")
    if args.json:
        args.json.write_text(json.dumps({"results": results, "checks": [(w, v, ok) for w, v, ok in checks]}, indent=1))
    return 0 if all(ok for _, _, ok in checks) else 1


def _main_per_kind(args) -> int:
    """``--per-kind``: the table of one change of each kind before / after, and the issue's target."""
    n = int(args.runs.split(",")[0])
    print(f"one change of each kind, {n} runs, before {args.ref}, after {args.after}, {os.cpu_count()} cores; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    load = [f"{os.getloadavg()[0]:.1f}"]

    def save(times: dict) -> None:  # after each kind, with the load averages so far
        load[1:] = [f"{os.getloadavg()[0]:.1f}"]
        if args.json:
            args.json.write_text(json.dumps({"runs": n, "ref": args.ref, "after": args.after,
                                             "load": "-".join(load), "times": times}, indent=1))

    times = per_kind(args.ref, args.after, n, args.seed, args.rounds,
                     tuple(k.strip() for k in args.kinds.split(",") if k.strip()), save)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
    print("\n".join(per_kind_table(times)))
    full = statistics.median([c for _, c in times["after"]["full"]])
    worst = max((k for k in times["after"] if k != "full"),
                key=lambda k: statistics.median([c for _, c in times["after"][k]]))
    share = statistics.median([c for _, c in times["after"][worst]]) / full
    ok = share < kind_target(n)
    print(f"\n{verdict(ok)}  worst kind ({worst}) under {kind_target(n):.0%} of a full rebuild at {n} runs (CPU): "
          f"{share:.3f}")
    save(times)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
