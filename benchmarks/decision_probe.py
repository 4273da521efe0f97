"""What a measured rebuild spent, part by part, told by the rebuild itself (``bench_decision_stage``, session 26).

A whole ``pneubench rebuild`` process gives one wall and one CPU figure; two rounds of the same command
differed by 3.6 s of wall (session 25, merged) and nothing said why. :data:`PROBE` is Python source run in the
rebuild process before ``pipeline.cli.main`` (``python -c``; it imports nothing of the benchmarks, so the same
text probes any version's tree, ``--ref`` included). It wraps, by attribute and only where they exist:

* each stage that runs (``stage_runner._run_stage``): its wall and the CPU of the process tree, of its ``run``,
  of its memo's ``save`` (the fsyncs) and the rest (its folder: tables and figures written);
* each memoised map (``Memo.map``): its label, items, items from the memo (hits) and computed (misses), wall,
  tree CPU;
* the rebuild's phases (``flow._stages``, ``flow._assemble``, ``flow._publish``), the report
  (``render.stage_report``), its decision section (``render.decision_section``) and its looks figures
  (``_draw_elsewhere`` until session 28: how many drawn, whether in the pool's processes; since then
  ``looks_svg``: how many drawn, SVG text in the rebuild process).

The CPU of the process tree at a moment: this process's and its reaped children's (``os.times``) plus every
live descendant's from ``/proc/PID/stat`` (the rebuild's workers live across stages). Work running beside a
part (the figure drawer forked by the rebuild) is counted in the part it overlaps. At exit the rebuild process
prints one line ``bench-probe {json}`` to stderr; :func:`parse` reads it back, :func:`lines` formats it.
"""
from __future__ import annotations

import json

#: The marker of the probe's line in a rebuild's stderr.
MARK = "bench-probe "

#: Run in the rebuild process before ``pipeline.cli.main`` (``python -c PROBE + ...``).
PROBE = r'''
def _bench_probe():
    import atexit, json, os, sys, time
    me, tck = os.getpid(), os.sysconf("SC_CLK_TCK")
    rec = {"stages": {}, "maps": [], "phases": {}, "report": {}}

    def tree_cpu():
        t = os.times()
        total = t.user + t.system + t.children_user + t.children_system
        kids = {}
        for d in os.listdir("/proc"):
            if not d.isdigit():
                continue
            try:
                with open(f"/proc/{d}/stat", "rb") as fh:
                    r = fh.read().rsplit(b")", 1)[1].split()
            except OSError:
                continue
            kids.setdefault(int(r[1]), []).append((int(d), (int(r[11]) + int(r[12])) / tck))
        todo = [me]
        while todo:
            for pid, cpu in kids.get(todo.pop(), ()):
                total += cpu
                todo.append(pid)
        return total

    def timed(store, key, func):
        def wrapper(*a, **k):
            w0, c0 = time.perf_counter(), tree_cpu()
            try:
                return func(*a, **k)
            finally:
                store(key(a, k), time.perf_counter() - w0, tree_cpu() - c0)
        wrapper.__wrapped__ = func
        return wrapper

    def patch(modname, attr, make):
        try:
            mod = __import__(modname, fromlist=[attr])
            setattr(mod, attr, make(getattr(mod, attr)))
        except Exception as exc:   # another version's tree: what it lacks is not probed
            rec.setdefault("unprobed", []).append(f"{modname}.{attr}: {type(exc).__name__}")

    def stage_store(part):
        def store(name, wall, cpu):
            rec["stages"].setdefault(name, {})[part] = [round(wall, 4), round(cpu, 4)]
        return store

    def run_stage(func):
        def wrapper(mod, *a, **k):
            name, run = mod.NAME, mod.run
            mod.run = timed(lambda key, w, c: stage_store("run")(name, w, c), lambda a, k: None, run)
            try:
                return timed(lambda key, w, c: stage_store("total")(name, w, c), lambda a, k: None, func)(mod, *a, **k)
            finally:
                mod.run = run
        return wrapper

    def memo_map(func):
        def wrapper(self, compute, f, items, label=""):
            h0, n0 = self.hits, self.computed
            w0, c0 = time.perf_counter(), tree_cpu()
            out = func(self, compute, f, items, label)
            rec["maps"].append({"stage": self.stage, "label": label or getattr(f, "__name__", "?"),
                                "items": len(items), "hits": self.hits - h0, "computed": self.computed - n0,
                                "wall": round(time.perf_counter() - w0, 4), "cpu": round(tree_cpu() - c0, 4)})
            return out
        return wrapper

    def memo_save(func):
        def wrapper(self):
            w0, c0 = time.perf_counter(), tree_cpu()
            try:
                return func(self)
            finally:
                stage_store("memo save")(self.stage, time.perf_counter() - w0, tree_cpu() - c0)
        return wrapper

    def phase(name):
        return lambda func: timed(lambda k, w, c: rec["phases"].__setitem__(name, [round(w, 4), round(c, 4)]),
                                  lambda a, k: None, func)

    def report_part(name):
        return lambda func: timed(lambda k, w, c: rec["report"].__setitem__(name, [round(w, 4), round(c, 4)]),
                                  lambda a, k: None, func)

    def draw_elsewhere(func):
        def wrapper(todo, pool=None):
            out = func(todo, pool)
            rec["report"]["looks figures"] = {"to draw": len(todo), "in processes": len(out), "pool": pool is not None}
            return out
        return wrapper

    patch("pipeline.rebuild.stage_runner", "_run_stage", run_stage)
    patch("pipeline.rebuild.memo", "Memo", lambda cls: (setattr(cls, "map", memo_map(cls.map)),
                                                        setattr(cls, "save", memo_save(cls.save)), cls)[-1])
    for ph in ("_stages", "_assemble", "_publish"):
        patch("pipeline.rebuild.flow", ph, phase(ph.strip("_")))
    patch("pipeline.serve.report.render", "stage_report", report_part("stage_report"))
    patch("pipeline.serve.report.render", "decision_section", report_part("decision_section"))
    def looks_svg(func):
        def wrapper(lk):
            got = rec["report"].setdefault("looks drawn", 0)
            rec["report"]["looks drawn"] = got + 1
            return func(lk)
        return wrapper

    if __import__("importlib.util").util.find_spec("pipeline.serve.report.looks_svg") is not None:
        patch("pipeline.serve.report.decision", "looks_svg", looks_svg)         # session 28 on: SVG, here
    else:
        patch("pipeline.serve.report.decision", "_draw_elsewhere", draw_elsewhere)

    def dump():
        if os.getpid() == me:
            sys.stderr.write("bench-probe " + json.dumps(rec, sort_keys=True) + "\n")
            sys.stderr.flush()
    atexit.register(dump)


_bench_probe()
'''


def parse(log: str) -> dict | None:
    """The probe's record in a rebuild's output (None when the rebuild printed none)."""
    for line in reversed(log.splitlines()):
        if line.startswith(MARK):
            return json.loads(line[len(MARK):])
    return None


def stage_parts(rec: dict, stage: str) -> dict:
    """``{part: (wall, cpu)}`` of one stage: ``run``, ``memo save``, ``folder`` (the rest of the stage: its
    tables and figures stored) and ``total`` [s]."""
    s = rec.get("stages", {}).get(stage)
    if not s or "total" not in s:
        return {}
    out = {k: tuple(v) for k, v in s.items()}
    rest = [out["total"][i] - out.get("run", (0, 0))[i] - out.get("memo save", (0, 0))[i] for i in (0, 1)]
    out["folder"] = tuple(rest)
    return out


def lines(rec: dict | None, stages=("decision", "test_plan")) -> list[str]:
    """The record of one rebuild as printable lines: per stage its parts and its maps' hits and misses, then the
    report's decision section and the rebuild's phases."""
    if rec is None:
        return ["(no probe record)"]
    out = []
    for st in stages:
        parts = stage_parts(rec, st)
        if not parts:
            out.append(f"{st}: not run")
            continue
        hits = sum(m["hits"] for m in rec["maps"] if m["stage"] == st)
        comp = sum(m["computed"] for m in rec["maps"] if m["stage"] == st)
        out.append(f"{st}: " + ", ".join(f"{k} {w:.2f} s / {c:.2f} CPU-s" for k, (w, c) in parts.items())
                   + f"; memo {hits} hits, {comp} computed")
        for m in rec["maps"]:
            if m["stage"] == st and m["items"]:
                out.append(f"    {m['label']:28s} {m['items']:4d} items: {m['hits']:4d} from the memo, "
                           f"{m['computed']:4d} computed; {m['wall']:6.2f} s / {m['cpu']:6.2f} CPU-s")
    rep = rec.get("report", {})
    for k in ("stage_report", "decision_section"):
        if k in rep:
            out.append(f"report {k}: {rep[k][0]:.2f} s / {rep[k][1]:.2f} CPU-s")
    if "looks figures" in rep:
        lf = rep["looks figures"]
        out.append(f"report looks figures: {lf['to draw']} to draw, {lf['in processes']} in processes "
                   f"(pool given: {lf['pool']})")
    if "looks drawn" in rep:
        out.append(f"report looks figures: {rep['looks drawn']} drawn (SVG, in the rebuild process)")
    ph = rec.get("phases", {})
    if ph:
        out.append("phases: " + ", ".join(f"{k} {w:.2f} s / {c:.2f} CPU-s" for k, (w, c) in ph.items()))
    if rec.get("unprobed"):
        out.append("not probed: " + ", ".join(rec["unprobed"]))
    return out
