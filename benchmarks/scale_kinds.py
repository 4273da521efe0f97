"""Issue 26's table and cost-curve plot of one change of each kind, from ``bench_scale`` JSON files.

``python -m benchmarks.bench_scale --per-kind --runs N --json FILE`` measures one change of each kind
at one campaign size; ``python -m benchmarks.bench_scale --render FILE --render FILE2 ...`` (no
measuring) reads such files (and ``bench_scale``'s cost-curve ``--json``, whose sizes carry
``per_kind``) and prints

* the issue's table: per kind, the issue's own "before" share (1,000 runs, :data:`ISSUE_BEFORE`) and,
  per size measured, the CPU share of that size's full rebuild with PASS / MISS against
  :func:`kind_target` (5 % at 1,000 runs, 2 % at 10,000), and the worst kind per size;
* the cost-curve plot (``--plot``, default ``benchmarks/scale.png``): each kind's share of a full
  rebuild against the runs, the worst kind drawn thick, the targets and the issue's before.

Nothing here measures: it is the pure rendering, tested on hand-made files.
"""
from __future__ import annotations

import json
import math
import statistics
from pathlib import Path

#: Issue 26's "before" (main, 1,000 runs, whole processes on 2 cores): each change's share of a full
#: rebuild [wall s / wall s]. The logbook line and plan.toml had no figure.
ISSUE_BEFORE = {"spring": 0.28, "step": 0.26, "pressure_step": 0.25, "leakage": 0.13, "durability": 0.12,
                "viscous": 0.10, "breakaway": 0.10, "no-op": 0.009}
#: The campaign size the issue's before was measured at [runs].
ISSUE_BEFORE_RUNS = 1000
#: The rows of the table, in the issue's order of targets (then what else a file may hold).
KIND_ORDER = ("spring", "breakaway", "leakage", "viscous", "durability", "pressure_step", "step", "logbook line",
              "plan.toml", "no-op")


def kind_target(runs: int) -> float:
    """Issue 26's target share of a full rebuild (CPU) for one change of any kind: 5 % up to
    1,000 runs, 2 % from 10,000 (interpolated on log runs between). [1]"""
    if runs <= 1000:
        return 0.05
    if runs >= 10000:
        return 0.02
    return 0.05 + (0.02 - 0.05) * math.log10(runs / 1000)


def per_kind_table(times: dict) -> list[str]:
    """The markdown table of one ``--per-kind`` run's medians: seconds and share of the version's full rebuild."""
    med = {v: {k: (statistics.median(w for w, _ in t), statistics.median(c for _, c in t)) for k, t in kinds.items()}
           for v, kinds in times.items()}
    if "before" not in med:  # --ref none: the version measured alone
        a = med["after"]
        return ["| change | wall s / CPU s | CPU share of full |", "|---|---|---|"] + [
            f"| {kind} | {a[kind][0]:.1f} / {a[kind][1]:.1f} | {a[kind][1] / a['full'][1]:.3f} |" for kind in a]
    b, a = med["before"], med["after"]
    lines = ["| change | before: wall s / CPU s | CPU share of full | after: wall s / CPU s | CPU share of full "
             "| after / before CPU |", "|---|---|---|---|---|---|"]
    for kind in b:
        lines.append(f"| {kind} | {b[kind][0]:.1f} / {b[kind][1]:.1f} | {b[kind][1] / b['full'][1]:.3f} "
                     f"| {a[kind][0]:.1f} / {a[kind][1]:.1f} | {a[kind][1] / a['full'][1]:.3f} "
                     f"| {a[kind][1] / b[kind][1]:.2f} |")
    return lines


def sizes_from(docs: list[tuple[str, dict]]) -> dict[int, dict]:
    """Per campaign size [runs]: ``full_cpu_s`` (the full rebuild's CPU s), ``kinds`` {kind: (CPU s, share
    of its own file's full rebuild)}, ``sources`` and ``load`` (the load averages the files noted).

    ``docs`` are (name, parsed JSON) in the order given: a ``--per-kind`` file (``runs``, ``times``; its
    ``after`` version, medians over the rounds) or a cost-curve file (``results``, each size's
    ``per_kind`` {kind: [wall s, CPU s]}). A kind measured at the same size by a later file wins.
    """
    out: dict[int, dict] = {}

    def put(name: str, runs: int, full: float, kinds: dict[str, float], load) -> None:
        size = out.setdefault(runs, {"full_cpu_s": full, "kinds": {}, "sources": [], "load": []})
        size["full_cpu_s"] = full
        size["kinds"].update({k: (c, c / full) for k, c in kinds.items()})
        size["sources"].append(name)
        if load:
            size["load"].append(load)

    for name, doc in docs:
        if "times" in doc:
            t = doc["times"]["after"]
            cpu = {k: statistics.median(c for _, c in rounds) for k, rounds in t.items() if rounds}
            if "full" not in cpu:
                raise ValueError(f"{name}: no full rebuild measured (the shares' denominator)")
            full = cpu.pop("full")
            put(name, int(doc["runs"]), full, cpu, doc.get("load"))
        elif "results" in doc:
            for r in doc["results"]:
                if r.get("per_kind") and r.get("full_cpu_s"):
                    put(name, int(r["runs"]), r["full_cpu_s"], {k: v[1] for k, v in r["per_kind"].items()},
                        None)
        else:
            raise ValueError(f"{name}: neither a --per-kind file (times) nor a cost-curve file (results)")
    return dict(sorted(out.items()))


def load_sizes(paths: list[Path]) -> dict[int, dict]:
    """:func:`sizes_from` of JSON files."""
    return sizes_from([(str(p), json.loads(Path(p).read_text())) for p in paths])


def worst(size: dict) -> tuple[str, float] | None:
    """The kind of change with the largest CPU share of the full rebuild (the no-op aside) and that share."""
    changes = {k: s for k, (_, s) in size["kinds"].items() if k != "no-op"}
    if not changes:
        return None
    kind = max(changes, key=lambda k: (changes[k], k))
    return kind, changes[kind]


def _name(kind: str) -> str:
    return kind.replace("_", " ")


def issue_table(sizes: dict[int, dict]) -> tuple[list[str], list[tuple[str, float, bool]]]:
    """Issue 26's table, before (:data:`ISSUE_BEFORE`) and after (each size's CPU share of its full rebuild,
    PASS / MISS against :func:`kind_target`), and a check per size: its worst kind under the target."""
    head = ["| change | before: issue 26, 1,000 runs (wall share) |"]
    rule = "|---|---|"
    for runs in sizes:
        head.append(f" after, {runs:,} runs: CPU share (CPU s), target {kind_target(runs):.0%} |")
        rule += "---|"
    lines = ["".join(head), rule,
             "| full rebuild, CPU s | (52-56 s wall) | " + " | ".join(f"{s['full_cpu_s']:.1f}" for s in sizes.values())
             + " |"]
    kinds = [k for k in KIND_ORDER if k in ISSUE_BEFORE or any(k in s["kinds"] for s in sizes.values())]
    kinds += sorted({k for s in sizes.values() for k in s["kinds"]} - set(kinds))
    for kind in kinds:
        cells = []
        for runs, s in sizes.items():
            if kind not in s["kinds"]:
                cells.append("not measured")
                continue
            cpu, share = s["kinds"][kind]
            ok = share < kind_target(runs)
            cells.append(f"{share:.4f} ({cpu:.1f}) {'PASS' if ok else 'MISS'}")
        before = f"{ISSUE_BEFORE[kind]:.3f}" if kind in ISSUE_BEFORE else "-"
        lines.append(f"| {_name(kind)} | {before} | " + " | ".join(cells) + " |")
    checks, worst_cells = [], []
    for runs, s in sizes.items():
        w = worst(s)
        if w is None:
            worst_cells.append("-")
            continue
        ok = w[1] < kind_target(runs)
        worst_cells.append(f"**{_name(w[0])} {w[1]:.4f} {'PASS' if ok else 'MISS'}**")
        checks.append((f"worst kind ({_name(w[0])}) under {kind_target(runs):.0%} of a full rebuild at {runs:,} runs "
                       f"(CPU; {len([k for k in s['kinds'] if k != 'no-op'])} kinds measured)", w[1], ok))
    before_worst = max((k for k in ISSUE_BEFORE if k != "no-op"), key=ISSUE_BEFORE.get)
    lines.append(f"| **worst kind** | **{_name(before_worst)} {ISSUE_BEFORE[before_worst]:.3f}** | "
                 + " | ".join(worst_cells) + " |")
    return lines, checks


def curve(sizes: dict[int, dict]) -> dict:
    """What the plot draws: ``runs`` [runs]; per kind its shares (None where not measured) [1]; the
    worst kind at the largest size measured (``worst_kind``) and each size's worst share
    (``worst_share``); the target line (``target_runs``, ``target``) from 300 runs (or fewer) to 10,000
    (or more)."""
    runs = list(sizes)
    kinds = [k for k in KIND_ORDER if any(k in s["kinds"] for s in sizes.values()) and k != "no-op"]
    kinds += sorted({k for s in sizes.values() for k in s["kinds"]} - set(kinds) - {"no-op"})
    shares = {k: [s["kinds"][k][1] if k in s["kinds"] else None for s in sizes.values()] for k in kinds}
    last = worst(sizes[runs[-1]]) if runs else None
    lo, hi = min([300, *runs]), max([10000, *runs])
    t_runs = [round(lo * (hi / lo) ** (i / 40)) for i in range(41)]
    return {"runs": runs, "shares": shares, "worst_kind": last[0] if last else None,
            "worst_share": [(worst(s) or (None, None))[1] for s in sizes.values()],
            "target_runs": t_runs, "target": [kind_target(n) for n in t_runs]}


def plot(sizes: dict[int, dict], path: Path) -> dict:
    """Draw :func:`curve` as a PNG at ``path``: the CPU share of a full rebuild of one change of each kind
    against the runs (log-log), the worst kind thick, each size's worst share, the targets and the issue's
    before at 1,000 runs. Returns the curve drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401 (matplotlib.ticker.NullFormatter)

    c = curve(sizes)
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    labels = []  # (runs, share) of each other kind's last point, named beside it
    for kind, ys in c["shares"].items():
        have = [(n, y) for n, y in zip(c["runs"], ys) if y is not None]
        if kind == c["worst_kind"] or not have:
            continue
        ax.plot(*zip(*have), ".-", color="0.7", lw=0.8)
        labels.append((have[-1], _name(kind)))
    placed: dict[int, float] = {}  # per size, the log10 height of the last label: labels kept apart
    for (n, y), name in sorted(labels, key=lambda t: (t[0][0], t[0][1])):
        at = max(math.log10(y), placed.get(n, -9.0) + 0.035)
        placed[n] = at
        ax.annotate(name, (n, y), xytext=(n * 1.06, 10 ** at), fontsize=6.5, color="0.4", va="center")
    if c["worst_kind"]:
        have = [(n, y) for n, y in zip(c["runs"], c["shares"][c["worst_kind"]]) if y is not None]
        ax.plot(*zip(*have), "o-", color="tab:red", lw=2.2,
                label=f"one change of the worst kind ({_name(c['worst_kind'])}), CPU share of full")
        for n, y in have:
            ax.annotate(f"{_name(c['worst_kind'])} {y:.3f}", (n, y), xytext=(-6, 7), textcoords="offset points",
                        fontsize=8, color="tab:red", ha="right")
    worst_pts = [(n, y) for n, y in zip(c["runs"], c["worst_share"]) if y is not None]
    if worst_pts and [y for _, y in worst_pts] != [y for _, y in zip(c["runs"], c["shares"].get(c["worst_kind"], []))]:
        ax.plot(*zip(*worst_pts), "x--", color="tab:orange", label="each size's worst kind")
    ax.plot(c["target_runs"], c["target"], "-", color="black", lw=1.2, label="target: 5 % at 1,000 runs, 2 % at 10,000")
    bk = max((k for k in ISSUE_BEFORE if k != "no-op"), key=ISSUE_BEFORE.get)
    ax.plot([ISSUE_BEFORE_RUNS], [ISSUE_BEFORE[bk]], "s", color="tab:blue", mfc="none", ms=8,
            label=f"before (issue 26, wall share): {_name(bk)} {ISSUE_BEFORE[bk]:.2f}")
    for n in (1000, 10000):
        ax.annotate(f"{kind_target(n):.0%}", (n, kind_target(n)), xytext=(0, -11), textcoords="offset points",
                    fontsize=7.5, ha="center")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ticks = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0]
    ax.set_yticks(ticks, [f"{t:.1%}" if t < 0.01 else f"{t:.0%}" for t in ticks])
    ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ys = [y for v in c["shares"].values() for y in v if y is not None] + [ISSUE_BEFORE[bk], 0.02]
    ax.set_ylim(min(ys) / 1.5, max(ys) * 1.5)
    ax.set_xlim(c["target_runs"][0] * 0.8, c["target_runs"][-1] * 1.6)
    ax.set_xlabel("runs in raw/")
    ax.set_ylabel("one changed file: share of a full rebuild (CPU)")
    ax.set_title("pneubench: the cost of one change against the runs (2 cores)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7.5, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return c


def render(paths: list[Path], plot_path: Path | None) -> int:
    """``bench_scale --render``: print :func:`issue_table` and its checks, draw :func:`plot`; 0 when every
    size's worst kind meets its target."""
    sizes = load_sizes(paths)
    if not sizes:
        print("no per-kind figures in " + ", ".join(map(str, paths)))
        return 1
    lines, checks = issue_table(sizes)
    print("\n".join(lines) + "\n")
    for runs, s in sizes.items():
        if s["load"]:
            print(f"{runs:,} runs: load average {', '.join(map(str, s['load']))} ({', '.join(s['sources'])})")
    for what, value, ok in checks:
        print(f"{'PASS' if ok else 'MISS'}  {what}: {value:.3f}")
    if plot_path:
        plot(sizes, plot_path)
        print(f"plot: {plot_path}")
    return 0 if all(ok for _, _, ok in checks) else 1
