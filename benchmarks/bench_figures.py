"""The figures a one-file change redraws, and what each costs to draw (issue 26).

Two steps, each in processes of the version's own source tree::

    python -m benchmarks.bench_figures capture --data DATA --out DIR [--tree TREE] [--kinds spring,leakage]
    python -m benchmarks.bench_figures time --out DIR --tree main=TREE --tree branch=. [--rounds 3]

``capture``: on a built copy (``DATA`` holds ``raw/`` and ``warehouse/``), one change of each kind
(:func:`benchmarks.bench_scale.change_victims`, an edit no earlier run of this benchmark made on the copy),
rebuilt **in process** with the rebuild's own figure worker; every figure it draws is recorded (stage, name,
CPU of the worker's ``_save_figure`` [s]) and its recipe pickled to ``DIR/recipes/<stage>.<name>.pkl``, beside
the CPU of ``_warm_figures`` (matplotlib imported before the worker's fork) in the rebuild process. The old
bytes and mtime are put back and the copy rebuilt (untimed) after each kind. ``DIR/kinds.json`` holds it.

``time``: for each captured recipe, each round, each tree alternating, one fresh process: matplotlib's
figure and Agg canvas imported (timed: ``import``), then the recipe drawn (``draw``: the plot function) and
saved as the rebuild saves it (``save``: ``stage_store._save_figure``'s ``savefig``), ``time.process_time``
around each; the PNG is kept (``DIR/png/<tree>/<figure>.png``) and the trees' PNGs compared pixel by pixel
(the largest difference of a channel, 0-255, and how many pixels differ). A figure drawn in its own fresh
process pays what a one-file change's worker pays for it: a change draws one or two figures.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: Edits of the copy made by this benchmark (``{kind: [n, ...]}``), kept in the copy.
SEEN = ".bench-figures-edits.json"


def _child_capture(tree: Path, data: Path, out: Path) -> dict:
    """One rebuild of ``data`` in this process, every drawn figure recorded (runs in ``tree``)."""
    sys.path.insert(0, str(tree))
    from pipeline.rebuild import stage_store
    from pipeline.rebuild.flow import rebuild

    record = out / "drawn.jsonl"
    record.unlink(missing_ok=True)
    (out / "recipes").mkdir(parents=True, exist_ok=True)
    _CAPTURE.update(out=out, save=stage_store._save_figure, warm=stage_store._warm_figures, warm_s=0.0)
    stage_store._save_figure, stage_store._warm_figures = _timed_save, _timed_warm
    summary = rebuild(data / "raw", data / "warehouse")
    drawn = [json.loads(ln) for ln in record.read_text().splitlines()] if record.exists() else []
    return {"warm_s": _CAPTURE["warm_s"], "drawn": drawn, "ran": list(summary.stages_run),
            "matplotlib": sorted(m for m in ("matplotlib", "matplotlib.figure", "matplotlib.pyplot",
                                             "matplotlib.backends.backend_agg") if m in sys.modules)}


#: The capture's state in its process (module-level: the figure worker is handed ``_timed_save`` by name).
_CAPTURE: dict = {}


def _timed_save(fig, path):
    """``stage_store._save_figure``, timed, its recipe pickled and the figure recorded (in the worker)."""
    out = _CAPTURE["out"]
    parts = Path(path).parts
    stage, name = parts[parts.index("stages") + 1] if "stages" in parts else "?", Path(path).stem
    t0 = time.process_time()
    _CAPTURE["save"](fig, path)
    cpu = time.process_time() - t0
    try:
        (out / "recipes" / f"{stage}.{name}.pkl").write_bytes(pickle.dumps(fig))
    except Exception as exc:  # a recipe that does not pickle is still counted
        print(f"not pickled: {stage}.{name}: {exc}", file=sys.stderr)
    with (out / "drawn.jsonl").open("a") as fh:
        fh.write(json.dumps({"stage": stage, "figure": name, "cpu_s": cpu}) + "\n")


def _timed_warm():
    t0 = time.process_time()
    _CAPTURE["warm"]()
    _CAPTURE["warm_s"] += time.process_time() - t0


def capture(tree: Path, data: Path, out: Path, kinds: list[str]) -> dict:
    """Each kind's change on ``data``: the figures it draws (see the module's docstring)."""
    from benchmarks.bench_scale import change_victims
    from benchmarks.bench_versions import child_after_edit

    victims = change_victims(data / "raw", data / "warehouse")
    seen_path = data / SEEN
    seen = json.loads(seen_path.read_text()) if seen_path.exists() else {}
    out.mkdir(parents=True, exist_ok=True)
    result_path = out / "kinds.json"
    result = json.loads(result_path.read_text()) if result_path.exists() else {}
    for kind in kinds or [k for k in victims if k not in ("logbook line", "plan.toml")]:
        path, edit = victims[kind]
        n = max(seen.get(kind, [-1])) + 1
        seen.setdefault(kind, []).append(n)
        seen_path.write_text(json.dumps(seen))
        kout = out / kind.replace(" ", "_")
        kout.mkdir(parents=True, exist_ok=True)
        # a last digit has nine other values: a tenth run would repeat one
        got = child_after_edit(path, lambda p, n=n: edit(p, n % 9 + 1),
                               [sys.executable, "-m", "benchmarks.bench_figures", "child", "--data", str(data),
                                "--out", str(kout), "--tree", str(tree)],
                               tree=tree, data=data, cwd=Path(__file__).resolve().parent.parent, label=kind)
        got["load"] = os.getloadavg()[0]
        result[kind] = got
        result_path.write_text(json.dumps(result, indent=1))
        drawn = ", ".join(f"{d['stage']}.{d['figure']} {d['cpu_s']:.2f}" for d in got["drawn"]) or "none"
        print(f"{kind}: warm {got['warm_s']:.2f} CPU-s; drawn: {drawn}; imported: {got['matplotlib']}; "
              f"ran {', '.join(got['ran'])} (load {got['load']:.1f})", flush=True)
    return result


def _child_time(recipe: Path, png: Path) -> dict:
    """Import matplotlib, draw ``recipe``, save it to ``png``: CPU of each step (runs in the tree)."""
    t0 = time.process_time()
    import matplotlib.backends.backend_agg  # noqa: F401  (as stage_store._warm_figures)
    import matplotlib.figure  # noqa: F401
    t1 = time.process_time()
    from pipeline.rebuild import stage_store

    fig = pickle.loads(recipe.read_bytes())
    t2 = time.process_time()
    drawn = fig.figure()
    t3 = time.process_time()
    stage_store._save_figure(drawn, png)
    t4 = time.process_time()
    return {"import": t1 - t0, "draw": t3 - t2, "save": t4 - t3}


def time_trees(trees: dict[str, Path], out: Path, rounds: int, only: list[str]) -> dict:
    """Each recipe of ``out/recipes`` drawn by each tree, alternating (see the module's docstring)."""
    from benchmarks.bench_versions import _env

    recipes = sorted((out / "recipes").glob("*.pkl"))
    if only:
        recipes = [r for r in recipes if r.stem in only or r.stem.split(".", 1)[1] in only]
    res: dict = {}
    names = list(trees)
    for i in range(rounds):
        for recipe in recipes:
            for name in (names if i % 2 == 0 else names[::-1]):
                png = out / "png" / name / f"{recipe.stem}.png"
                png.parent.mkdir(parents=True, exist_ok=True)
                p = subprocess.run([sys.executable, "-m", "benchmarks.bench_figures", "child-time", "--recipe",
                                    str(recipe), "--png", str(png), "--tree", str(trees[name])],
                                   cwd=Path(__file__).resolve().parent.parent, env=_env(trees[name]),
                                   capture_output=True, text=True)
                line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
                if not line:
                    raise SystemExit(f"{name} {recipe.stem}: {p.stderr[-2000:]}")
                res.setdefault(recipe.stem, {}).setdefault(name, []).append(json.loads(line[0][7:]))
        print(f"round {i + 1} done, load {os.getloadavg()[0]:.1f}", flush=True)
    for fig, by in res.items():
        cells = []
        for name in names:
            med = {k: statistics.median(r[k] for r in by[name]) for k in ("import", "draw", "save")}
            cells.append(f"{name}: import {med['import']:.2f} draw {med['draw']:.3f} save {med['save']:.3f} "
                         f"(draw+save {med['draw'] + med['save']:.3f})")
        diff = pixel_diff(*(out / "png" / n / f"{fig}.png" for n in names[:2])) if len(names) > 1 else ""
        print(f"{fig:42s} " + " | ".join(cells) + f" | {diff}")
    (out / "times.json").write_text(json.dumps(res, indent=1))
    return res


def pixel_diff(a: Path, b: Path) -> str:
    """How two PNGs differ: the same bytes, or the largest channel difference (0-255) and the pixels."""
    if a.read_bytes() == b.read_bytes():
        return "same bytes"
    import numpy as np
    from matplotlib.image import imread

    x, y = imread(a), imread(b)
    if x.shape != y.shape:
        return f"shapes {x.shape} / {y.shape}"
    d = np.abs(x.astype(float) - y.astype(float)) * 255
    return f"max diff {d.max():.0f}/255, {int((d.max(axis=-1) > 0).sum())} px differ"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("step", choices=["capture", "time", "child", "child-time", "diff"])
    ap.add_argument("--data", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--tree", action="append", default=[])
    ap.add_argument("--kinds", default="")
    ap.add_argument("--only", default="", help="figures to time (stage.name or name), comma-separated")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--recipe", type=Path)
    ap.add_argument("--png", type=Path)
    args = ap.parse_args(argv)
    if args.step == "child":
        print("RESULT " + json.dumps(_child_capture(Path(args.tree[0]).resolve(), args.data.resolve(),
                                                    args.out.resolve())))
        return 0
    if args.step == "child-time":
        sys.path.insert(0, str(Path(args.tree[0]).resolve()))
        print("RESULT " + json.dumps(_child_time(args.recipe, args.png)))
        return 0
    if args.step == "capture":
        tree = Path(args.tree[0] if args.tree else ".").resolve()
        capture(tree, args.data.resolve(), args.out.resolve(), [k for k in args.kinds.split(",") if k])
        return 0
    trees = {}
    for spec in args.tree:
        name, _, path = spec.partition("=")
        trees[name] = Path(path).resolve()
    if args.step == "diff":
        a, b = list(trees)
        for png in sorted((args.out / "png" / a).glob("*.png")):
            print(f"{png.stem:42s} {pixel_diff(png, args.out / 'png' / b / png.name)}")
        return 0
    time_trees(trees, args.out.resolve(), args.rounds, [s for s in args.only.split(",") if s])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
