"""Where one change's CPU goes, the whole process tree accounted (issue 26, "Session 26, floor2").

Runs ``pneubench rebuild`` of a code tree on a built copy of a campaign, in a child process that
times (``time.process_time``, inclusive: nested items are counted in their callers too) a list of
the rebuild's functions, every import by the package first imported at the outermost level
(``imports <package>``), Python's garbage collections, and the process's CPU before ``pipeline``
is imported (the interpreter's start-up) and at ``os._exit``. The tree's CPU (``measure``) less the
rebuild process's own is what its worker processes cost. Versions alternate::

    python -m benchmarks.floor_account --copy main=TREE_MAIN:DATA_MAIN --copy branch=.:DATA_BRANCH \\
        --kinds "logbook line,plan.toml" --rounds 2

Each round changes the file (:func:`benchmarks.bench_scale.change_victims`), rebuilds (timed),
puts the bytes and mtime back and rebuilds (untimed), as :mod:`benchmarks.bench_kinds_copies`.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

#: The functions timed, ``module:qualname`` (methods as ``Class.method``).
TARGETS = [
    "pipeline.cli:exit_now",
    "pipeline.rebuild.flow:rebuild", "pipeline.rebuild.flow:_plan", "pipeline.rebuild.flow:_ingest",
    "pipeline.rebuild.flow:_stages", "pipeline.rebuild.flow:_assemble", "pipeline.rebuild.flow:_publish",
    "pipeline.rebuild.flow:_import_for_stages", "pipeline.rebuild.flow:_start_executor",
    "pipeline.rebuild.flow:_inputs_table", "pipeline.rebuild.flow:_channels_frame",
    "pipeline.rebuild.flow:_new_channels",
    "pipeline.rebuild.publish:swap_in_new_database",
    "pipeline.rebuild.garbage:clean_debris", "pipeline.rebuild.garbage:collect_garbage",
    "pipeline.serve.report.publish:settle_report", "pipeline.serve.report.publish:publish_report",
    "pipeline.rebuild.state:load_previous", "pipeline.rebuild.state:plan_runs",
    "pipeline.rebuild.state:side_records", "pipeline.rebuild.state:encoded_runs",
    "pipeline.rebuild.state:frame_hash", "pipeline.rebuild.state:superseded_files",
    "pipeline.raw.tree:discover_runs", "pipeline.raw.tree:RawTree.scan_rigs",
    "pipeline.raw.tree:RawTree.scan_manifests", "pipeline.raw.plan:read_plan",
    "pipeline.rebuild.noop:confirm_same_bytes", "pipeline.rebuild.noop:nothing_changed",
    "pipeline.rebuild.noop:InputsKey.key", "pipeline.rebuild.noop:InputsKey.of_tree",
    "pipeline.rebuild.ingest_tasks:ingest_incremental", "pipeline.rebuild.ingest_tasks:deduplicate",
    "pipeline.rebuild.assemble:runs_frame", "pipeline.rebuild.assemble:write_database",
    "pipeline.rebuild.assemble:update_copy", "pipeline.rebuild.assemble:build_database",
    "pipeline.rebuild.assemble:_ddl_tables", "pipeline.rebuild.assemble:_table_sums",
    "pipeline.rebuild.assemble:frame_key", "pipeline.rebuild.assemble:_write_keys",
    "pipeline.rebuild.assemble:_update_tables", "pipeline.rebuild.assemble:_recreate_views",
    "pipeline.rebuild.assemble:swap_in", "pipeline.rebuild.assemble:comment_statements",
    "pipeline.rebuild.assemble:database_version",
    "pipeline.rebuild.history:append_log", "pipeline.rebuild.history:compare_findings",
    "pipeline.rebuild.stage_runner:run_stages_cached", "pipeline.rebuild.stage_runner:_run_stage",
    "pipeline.rebuild.stage_runner:_collect", "pipeline.rebuild.stage_runner:_input_key",
    "pipeline.rebuild.stage_runner:_tables_read", "pipeline.rebuild.stage_runner:_reusable",
    "pipeline.rebuild.stage_runner:_run_columns_source", "pipeline.rebuild.stage_runner:_deferrable",
    "pipeline.rebuild.stage_store:load_stage_folder", "pipeline.rebuild.stage_store:save_stage_folder",
    "pipeline.rebuild.stage_store:DeferredTable.read_frame",
    "pipeline.rebuild.stage_store:FigureDrawer.finish", "pipeline.rebuild.stage_store:FigureDrawer.__exit__",
    "pipeline.stages.run_columns:add_run_columns", "pipeline.stages.registry:discover",
    "pipeline.stages.registry:run_order",
    "pipeline.versions:stage_code_version", "pipeline.versions:project_code_version",
    "pipeline.versions:ingest_code_version",
    "pipeline.rebuild.memo:Memo.__init__", "pipeline.rebuild.memo:Memo.save",
    "pipeline.serve.door:connect_readonly",
    "pipeline.serve.report.render:stage_report", "pipeline.serve.report.render:_fill_folder",
    "pipeline.serve.report.render:_index",
    "pipeline.serve.report.pages:write_run_pages", "pipeline.serve.report.pages:BandsAhead.__exit__",
    "pipeline.rebuild.executors:LocalExecutor.close",
    "pipeline.serve.report.render:render_report", "pipeline.serve.report.sections:findings_section",
    "pipeline.serve.report.cache:cached_parts", "pipeline.serve.report.cache:live_keyed",
    "pipeline.serve.report.cache:cache_parts", "pipeline.serve.report.keyed:KeyedParts.__init__",
    "pipeline.serve.report.keyed:KeyedParts.get", "pipeline.serve.report.keyed:KeyedParts.render",
    "pipeline.serve.report.keyed:KeyedParts.taken_from_live", "pipeline.serve.report.keyed:table_keys",
    "pipeline.serve.report.results:results_sections", "pipeline.serve.report.sections:rebuild_section",
    "pipeline.serve.report.sections:rebuild_line", "pipeline.serve.report.pages:carry_pages",
    "pipeline.serve.report.pages:run_pages_present", "pipeline.serve.report.pages:runs_index",
    "pipeline.serve.report.publish:stage_folder", "pipeline.serve.report.db:ReportDB.columns",
    "pipeline.serve.report.db:ReportDB.run_ids", "pipeline.serve.report.db:ReportDB.rows",
    "pipeline.serve.report.decision:decision_section",
]
#: The own work of a breakaway, pressure-step or leakage change (session 27, kinds3): the stages they
#: re-run and the analyses' functions that import scipy.
TARGETS += [
    "pipeline.stages.plpa_characterisation:analyse_run", "pipeline.stages.plpa_characterisation:_frame",
    "analyses.breakaway:breakaway_findings", "analyses.breakaway:backpressure_ratio",
    "analyses.breakaway:force_rate_slope", "analyses.breakaway:breakaway_summary",
    "analyses.numerics:student_t_ppf", "analyses.numerics:student_t_sf", "analyses.numerics:welch_t_test_p",
    "analyses.leakage:leakage_map", "analyses.leakage:seal_envelope",
    "analyses.viscous_friction:viscous_transition",
    "pipeline.rebuild.stage_store:PooledTables.take",
    "pipeline.stages.models:fit_pressure_item", "pipeline.stages.models:_fit_pressure_runs",
    "analyses.pressure_dynamics:fit_pressure_dynamics", "analyses.pressure_dynamics:_fit_first",
    "analyses.pressure_dynamics:_fit_second", "analyses.pressure_groups:age_changes",
    "pipeline.stages.findings:breakaway_ratio", "pipeline.stages.findings:breakaway_rate",
    "pipeline.stages.findings:leak_free", "pipeline.stages.findings:life_verdicts",
    "pipeline.stages.findings:force_outlives_distance",
    "pipeline.stages.remaining_life:stage_items", "pipeline.stages.remaining_life:rul_weibull",
    "pipeline.stages.remaining_life:rul_group", "pipeline.stages.remaining_life:sensitivity_leak",
    "pipeline.stages.remaining_life:sensitivity_logbook", "pipeline.stages.remaining_life:read_once",
    "analyses.leak_degradation:degradation_fit", "analyses.leak_degradation:degradation_rul",
    "analyses.remaining_life_group:group_models", "analyses.remaining_life_group:remaining_life",
    "analyses.remaining_life_group:rul_backtest",
    "analyses.decision:decide", "pipeline.stages.remaining_life:sensitivity_of",
]
#: The modules whose first import's stack is kept (who pays for it), ``FLOOR_FIRST_IMPORTS``.
FIRST_IMPORTS = tuple(os.environ.get("FLOOR_FIRST_IMPORTS", "scipy.special,scipy.optimize,scipy.stats,"
                                     "matplotlib.figure").split(","))
#: Imports are labelled by this many parts of the name imported (``FLOOR_IMPORT_DEPTH``).
DEPTH = int(os.environ.get("FLOOR_IMPORT_DEPTH", "1"))
#: Each stage's ``run`` is timed as ``stage <name>`` (the stages that ran).
STAGES_PREFIX = "pipeline.stages."


# -- the child: one rebuild, timed ---------------------------------------------------------------
def child(out_path: str, argv: list[str]) -> None:
    """Run ``pneubench`` with ``argv`` here, timing :data:`TARGETS`, imports and collections; write
    the times to ``out_path`` as JSON when the process exits."""
    import builtins
    import functools
    import gc
    import importlib

    start_cpu = time.process_time()
    clock = time.process_time
    acc: dict[str, float] = {}
    calls: dict[str, int] = {}
    first: dict[str, list[str]] = {}  # per module of FIRST_IMPORTS: the stack of its first import
    noimp: dict[str, float] = {}  # per item that imported something: its CPU less those imports
    depth: dict[str, int] = {}
    me = os.getpid()

    def wrap(label: str, func):
        if getattr(func, "_floor_timed", False):
            return func

        @functools.wraps(func)
        def timed(*a, **k):
            d = depth.get(label, 0)
            depth[label] = d + 1
            t = clock()
            i0 = acc.get("imports (all)", 0.0)
            try:
                return func(*a, **k)
            finally:
                depth[label] = d
                if d == 0:
                    took = clock() - t
                    acc[label] = acc.get(label, 0.0) + took
                    imp = acc.get("imports (all)", 0.0) - i0
                    if imp > 0.0005:
                        noimp[label] = noimp.get(label, 0.0) + took - imp
                    calls[label] = calls.get(label, 0) + 1
        timed._floor_timed = True
        return timed

    by_module: dict[str, list[str]] = {}
    for t in TARGETS:
        mod, name = t.split(":")
        by_module.setdefault(mod, []).append(name)

    def patch(module) -> None:
        for name in by_module.get(module.__name__, ()):
            owner, _, attr = name.rpartition(".")
            obj = getattr(module, owner) if owner else module
            func = obj.__dict__.get(attr) if owner else getattr(module, attr, None)
            if func is None:
                continue
            label = name.split(".")[-1] if not owner else name
            if isinstance(func, (classmethod, staticmethod)):
                setattr(obj, attr, type(func)(wrap(label, func.__func__)))
            else:
                setattr(obj, attr, wrap(label, func))
        if module.__name__.startswith(STAGES_PREFIX) and hasattr(module, "NAME") and hasattr(module, "run"):
            module.run = wrap(f"stage {module.NAME}", module.run)

    # imports: CPU of each import that loads modules, exclusive of the imports nested in it, by the
    # top-level package of the name imported; "imports (all)" is the outermost ones' inclusive CPU
    real_import = builtins.__import__
    real_import_module = importlib.import_module
    stack: list[float] = []  # nested imports' inclusive CPU, per open import

    def timed(top, func, *a):
        t = clock()
        n0 = len(sys.modules)
        stack.append(0.0)
        try:
            return func(*a)
        finally:
            inner = stack.pop()
            if len(sys.modules) != n0:
                took = clock() - t
                if stack:
                    stack[-1] += took
                else:
                    acc["imports (all)"] = acc.get("imports (all)", 0.0) + took
                acc["imports " + top] = acc.get("imports " + top, 0.0) + took - inner

    def timed_import(name, globals=None, locals=None, fromlist=(), level=0):
        if not level and not fromlist and name in sys.modules:
            return real_import(name, globals, locals, fromlist, level)
        top = name if not level else ((globals or {}).get("__package__") or "?") + "." + name
        return timed(".".join(top.split(".")[:DEPTH]), real_import, name, globals, locals, fromlist, level)

    def timed_import_module(name, package=None):
        if name in sys.modules:
            return sys.modules[name]
        return timed(".".join((name if not package else package).lstrip(".").split(".")[:DEPTH]),
                     real_import_module, name, package)

    builtins.__import__ = timed_import
    importlib.import_module = timed_import_module

    # patch modules as they are imported: a meta path finder whose loader patches after exec
    class Patcher:
        def find_spec(self, fullname, path=None, target=None):
            if fullname in FIRST_IMPORTS and ("first import " + fullname) not in first:
                import traceback
                first["first import " + fullname] = [
                    f"{f.filename.rsplit('/', 2)[-1]}:{f.lineno} {f.name}" for f in traceback.extract_stack()[:-1]
                    if "importlib" not in f.filename and "floor_account" not in f.filename][-6:]
            if fullname not in by_module and not fullname.startswith(STAGES_PREFIX):
                return None
            for finder in sys.meta_path:
                if finder is self:
                    continue
                spec = getattr(finder, "find_spec", lambda *a: None)(fullname, path, target)
                if spec is not None:
                    loader = spec.loader
                    real_exec = loader.exec_module

                    def exec_module(module, real_exec=real_exec):
                        real_exec(module)
                        patch(module)
                    loader.exec_module = exec_module
                    return spec
            return None

    sys.meta_path.insert(0, Patcher())

    gc_t = [0.0, 0]

    def on_gc(phase, info):
        if phase == "start":
            gc_t[1] = clock()
        else:
            label = f"gc (Python's collections, generation {info['generation']})"
            acc[label] = acc.get(label, 0.0) + clock() - gc_t[1]
            calls[label] = calls.get(label, 0) + 1
    gc.callbacks.append(on_gc)

    real_exit = os._exit

    def dump(code):
        if os.getpid() == me:
            gc.callbacks.remove(on_gc) if on_gc in gc.callbacks else None
            ct = os.times()
            Path(out_path).write_text(json.dumps({
                "start-up (before pipeline is imported)": start_cpu, "process at exit": clock(),
                "children waited": ct.children_user + ct.children_system,
                "items": acc, "calls": calls,
                "items less imports": noimp, "first imports": first}, indent=1))
        return real_exit(code)

    os._exit = dump
    experiment = os.environ.get("FLOOR_GC")  # measuring only: how the collections would cost otherwise
    if experiment:
        a, b, c = (int(x) for x in experiment.split(","))
        gc.set_threshold(a, b, c)
    t = clock()
    from pipeline.cli import main  # noqa: E402
    acc["import pipeline.cli"] = clock() - t
    try:
        main(argv)
    except SystemExit as exc:
        dump(exc.code if isinstance(exc.code, int) else 1)


# -- the driver ----------------------------------------------------------------------------------
def _account(tree: Path, data: Path, out: Path) -> dict:
    from benchmarks.bench_versions import _env
    from benchmarks.proc import measure

    code = (f"import sys; sys.path.insert(0, {str(tree)!r}); import runpy; "
            f"m = runpy.run_path({str(Path(__file__).resolve())!r}); "
            f"m['child']({str(out)!r}, ['rebuild', '--raw', {str(data / 'raw')!r}, "
            f"'--warehouse', {str(data / 'warehouse')!r}])")
    m = measure([sys.executable, "-c", code], cwd=tree, env=_env(tree), check=False)
    if m.exit_code not in (0, 1):
        raise SystemExit(f"{tree}: rebuild exited {m.exit_code}: {(m.stdout + m.stderr)[-600:]}")
    got = json.loads(out.read_text())
    got["tree CPU"] = m.cpu_s
    got["wall"] = m.wall_s
    got["peak MB"] = m.tree_peak_mb
    got["load"] = os.getloadavg()[0]
    return got


def _rebuild(tree: Path, data: Path) -> None:
    from benchmarks.bench_kinds_copies import _rebuild as rb

    rb(tree, data)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--copy", action="append", required=True, metavar="NAME=TREE:DATA")
    ap.add_argument("--kinds", default="logbook line,plan.toml")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    from benchmarks.bench_kinds_copies import _note_edit, fresh_edits, parse_copies
    from benchmarks.bench_scale import bump_last_digit, change_victims

    copies = parse_copies(args.copy)
    names = list(copies)
    first = copies[names[0]][1]
    victims = change_victims(first / "raw", first / "warehouse")
    res: dict = {n: {} for n in names}
    tmp = Path(f"/tmp/floor-account-{os.getpid()}.json")
    for kind in args.kinds.split(","):
        path, edit = victims[kind]
        rel = path.relative_to(first / "raw")
        # edits no copy has seen (an edit seen before takes its stage folders back: the change reads cheaper)
        bys, stale = fresh_edits([d for _t, d in copies.values()], kind, args.rounds,
                                 10 if edit is bump_last_digit else None)
        if stale:
            print(f"  {kind}: {stale} of {args.rounds} edits seen before on these copies", flush=True)
        for i in range(args.rounds):
            for name in (names if i % 2 == 0 else names[::-1]):
                tree, data = copies[name]
                target = data / "raw" / rel
                st = target.stat()
                original = edit(target, bys[i])
                _note_edit(data, kind, bys[i])
                try:
                    got = _account(tree, data, tmp)
                finally:
                    target.write_bytes(original)
                    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
                _rebuild(tree, data)
                res[name].setdefault(kind, []).append(got)
                print(f"  {name}: {kind}: tree {got['tree CPU']:.2f} CPU-s, process {got['process at exit']:.2f}, "
                      f"load {got['load']:.1f}", flush=True)
                if args.json:
                    args.json.write_text(json.dumps(res, indent=1))
    for kind in args.kinds.split(","):
        for n in names:
            for lab, where in res[n][kind][0].get("first imports", {}).items():
                print(f"{n}: {kind}: {lab}: " + " <- ".join(reversed(where)))
        print(f"\n{kind}: CPU s, medians of {args.rounds} (inclusive; nested items counted in their callers too)")
        labels: dict[str, None] = {}
        for n in names:
            for g in res[n][kind]:
                labels.update(dict.fromkeys(g["items"]))
        rows = [("tree CPU", lambda g: g["tree CPU"]), ("process at exit", lambda g: g["process at exit"]),
                ("children (tree - process)", lambda g: g["tree CPU"] - g["process at exit"]),
                ("start-up (before pipeline)", lambda g: g["start-up (before pipeline is imported)"])]
        rows += [(lab, (lambda lab: lambda g: g["items"].get(lab, 0.0))(lab)) for lab in labels]
        med = {lab: [statistics.median(f(g) for g in res[n][kind]) for n in names] for lab, f in rows}
        order = [r[0] for r in rows[:4]] + sorted(labels, key=lambda lab: -max(med[lab]))
        print("| item | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        for lab in order:
            if max(med[lab]) >= 0.005:
                extra = []
                for n in names:
                    g = res[n][kind][0]
                    if lab in g.get("items less imports", {}):
                        less = statistics.median(x["items less imports"].get(lab, 0.0) for x in res[n][kind])
                        extra.append(f"{n} {less:.3f}")
                note = f" (less imports: {', '.join(extra)})" if extra else ""
                ncalls = res[names[0]][kind][0]["calls"].get(lab)
                note += f" x{ncalls}" if ncalls and ncalls > 1 else ""
                print(f"| {lab}{note} | " + " | ".join(f"{v:.3f}" for v in med[lab]) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
