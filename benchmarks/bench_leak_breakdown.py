"""Where one leakage (or durability) change's CPU goes, function by function (issue 26).

One rebuild of a built copy (``DATA`` holds ``raw/`` and ``warehouse/``) after one change of the kind
(:func:`benchmarks.bench_scale.change_victims`, a fresh value each round), run **in process** with
``time.process_time`` around the rebuild's steps and around every module-level function of the stages
a leakage change re-runs (inclusive: a function's time holds its callees'), no profiler; the process
tree's CPU (this process and its reaped children) beside it. Each round is its own process; the old
bytes and mtime are put back and the copy rebuilt (untimed) after it::

    python -m benchmarks.bench_leak_breakdown --data DATA [--tree TREE] [--kind leakage] [--rounds 2]

``--tree``: the source tree of the version to time (default: this checkout). Prints, per timed item, the
CPU seconds of each round and how many calls.
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import resource
import sys
import time
import types
from pathlib import Path

#: (module, attribute) timed around; ``Class.method`` for methods.
STEPS = [
    ("pipeline.rebuild.flow", "_plan"), ("pipeline.rebuild.flow", "_ingest"),
    ("pipeline.rebuild.flow", "_import_for_stages"), ("pipeline.rebuild.flow", "_stages"),
    ("pipeline.rebuild.flow", "_assemble"), ("pipeline.rebuild.flow", "_publish"),
    ("pipeline.rebuild.stage_runner", "load_stage_folder"), ("pipeline.rebuild.stage_runner", "_collect"),
    ("pipeline.rebuild.stage_runner", "_input_key"), ("pipeline.rebuild.stage_runner", "_tables_read"),
    ("pipeline.rebuild.stage_runner", "save_stage_folder"), ("pipeline.rebuild.stage_store", "_warm_figures"),
    ("pipeline.rebuild.stage_store", "FigureDrawer.finish"), ("pipeline.rebuild.stage_store", "_save_figure"),
    ("pipeline.rebuild.stage_store", "PooledTables.take"), ("pipeline.rebuild.memo", "Memo.map"),
    ("pipeline.rebuild.memo", "Memo.save"), ("pipeline.rebuild.assemble", "update_copy"),
    ("pipeline.rebuild.assemble", "_update_tables"), ("pipeline.rebuild.assemble", "frame_key"),
    ("pipeline.rebuild.assemble", "insert_frame"), ("pipeline.rebuild.assemble", "_write_tables"),
    ("pipeline.rebuild.assemble", "_table_sums"), ("pipeline.rebuild.assemble", "_ddl_tables"),
    ("pipeline.rebuild.assemble", "_recreate_views"),
    ("pipeline.rebuild.stage_store", "DeferredTable.read_frame"),
]
#: Stage modules whose every module-level project function is timed.
STAGE_MODULES = ("pipeline.stages.plpa_characterisation", "pipeline.stages.durability", "pipeline.stages.findings",
                 "pipeline.stages.remaining_life", "pipeline.serve.report.render", "pipeline.serve.report.sections",
                 "pipeline.serve.report.pages", "pipeline.serve.report.figures", "pipeline.serve.report.tables",
                 "pipeline.serve.report.running_hoses", "pipeline.serve.report.summaries",
                 "pipeline.serve.report.results", "pipeline.serve.report.keyed", "pipeline.serve.report.decision")


def _timer(acc: dict, name: str, func):
    @functools.wraps(func)
    def timed(*args, **kwargs):
        t0 = time.process_time()
        try:
            return func(*args, **kwargs)
        finally:
            a = acc.setdefault(name, [0.0, 0])
            a[0] += time.process_time() - t0
            a[1] += 1
    return timed


def _stage_timer(acc: dict, func):
    @functools.wraps(func)
    def timed(mod, *args, **kwargs):
        t0 = time.process_time()
        try:
            return func(mod, *args, **kwargs)
        finally:
            a = acc.setdefault(f"stage {mod.NAME}", [0.0, 0])
            a[0] += time.process_time() - t0
            a[1] += 1
    return timed


def instrument(acc: dict) -> None:
    """Wrap :data:`STEPS`, every stage run and the stage modules' functions with timers into ``acc``."""
    import importlib

    for modname, attr in STEPS:
        mod = importlib.import_module(modname)
        if "." in attr:
            cls, meth = attr.split(".")
            owner = getattr(mod, cls)
            setattr(owner, meth, _timer(acc, attr, getattr(owner, meth)))
        else:
            setattr(mod, attr, _timer(acc, attr, getattr(mod, attr)))
    runner = importlib.import_module("pipeline.rebuild.stage_runner")
    runner._run_stage = _stage_timer(acc, runner._run_stage)
    for modname in STAGE_MODULES:
        mod = importlib.import_module(modname)
        short = modname.rsplit(".", 1)[1]
        for attr, value in list(vars(mod).items()):
            if (isinstance(value, types.FunctionType) and not attr.startswith("plot_")
                    and (value.__module__ or "").startswith(("pipeline", "analyses"))):
                setattr(mod, attr, _timer(acc, f"{short}.{attr}", value))


class _FirstImport:
    """Records the stack of the first import of ``matplotlib.figure`` (who pays it)."""

    def __init__(self, acc: dict):
        self.acc = acc

    def find_spec(self, name, path=None, target=None):
        if name == "matplotlib.figure" and "_matplotlib_by" not in self.acc:
            import traceback
            self.acc["_matplotlib_by"] = [f"{f.filename.rsplit('/', 3)[-1]}:{f.lineno} {f.name}"
                                          for f in traceback.extract_stack()[:-1]
                                          if "importlib" not in f.filename][-8:]
        return None


def fresh_edit(path: Path, n: int) -> bytes:
    """Change one value of a run file to one of 90 values (the last digit + 1-9, the digit before the last
    comma + 0-9, by ``n``): a fresh value each round, where one seen before would take its stage folders
    and memo results back. Returns the old bytes."""
    original = path.read_bytes()
    data = bytearray(original)
    digits = [i for i, b in enumerate(data) if 48 <= b <= 57]
    last = digits[-1]
    data[last] = 48 + (data[last] - 48 + n % 9 + 1) % 10
    comma = data.rindex(b",")
    before = max(i for i in digits if i < comma)
    data[before] = 48 + (data[before] - 48 + (n // 9) % 10) % 10
    path.write_bytes(bytes(data))
    return original


def child(tree: Path, data: Path) -> dict:
    """One rebuild of ``data`` in this process, timed; the timings as a dict."""
    sys.path.insert(0, str(tree))
    acc: dict = {}
    sys.meta_path.insert(0, _FirstImport(acc))
    t0 = time.process_time()
    import pipeline  # noqa: F401 (its imports are the process's too)
    acc["import pipeline"] = [time.process_time() - t0, 1]
    assert Path(pipeline.__file__).resolve().is_relative_to(tree), pipeline.__file__
    from pipeline.rebuild.flow import rebuild

    instrument(acc)
    t1 = time.process_time()
    summary = rebuild(data / "raw", data / "warehouse")
    acc["rebuild"] = [time.process_time() - t1, 1]
    me = time.process_time()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    acc["process"] = [me, 1]
    acc["children (reaped)"] = [kids.ru_utime + kids.ru_stime, 1]
    acc["tree"] = [me + kids.ru_utime + kids.ru_stime, 1]
    acc["_ran"] = list(summary.stages_run)
    return acc


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--tree", type=Path, default=Path(".").resolve())
    ap.add_argument("--kind", default="leakage")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--fresh", type=int, help="the first round's value (0-89; default: from the clock)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    data, tree = args.data.resolve(), args.tree.resolve()
    if args.child:
        print("RESULT " + json.dumps(child(tree, data)))
        return 0
    from benchmarks.bench_scale import change_victims
    from benchmarks.bench_versions import child_after_edit

    path, _edit = change_victims(data / "raw", data / "warehouse")[args.kind]
    rounds = []
    for i in range(args.rounds):
        value = int(time.time() * 7) % 90 if args.fresh is None else args.fresh + i
        # this file as a script, in the tree: the tree's own pipeline is the one imported
        rounds.append(child_after_edit(path, lambda p, v=value: fresh_edit(p, v),
                                       [sys.executable, str(Path(__file__).resolve()), "--child", "--data", str(data),
                                        "--tree", str(tree)], tree=tree, data=data, cwd=tree, label=f"round {i}"))
        print(f"round {i + 1}: load {os.getloadavg()[0]:.1f}, tree {rounds[-1]['tree'][0]:.2f} CPU-s, "
              f"ran {', '.join(rounds[-1]['_ran'])}", flush=True)
    names = sorted({k for r in rounds for k in r if not k.startswith("_m") and k != "_ran"},
                   key=lambda k: -max(r.get(k, [0, 0])[0] for r in rounds))
    for k in names:
        cells = "  ".join(f"{r[k][0]:6.3f} x{r[k][1]:<4d}" if k in r else " " * 12 for r in rounds)
        print(f"{k:48s} {cells}")
    print("matplotlib.figure first imported by:", *rounds[0].get("_matplotlib_by", ["(never)"]), sep="\n  ")
    if args.json:
        args.json.write_text(json.dumps(rounds, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
