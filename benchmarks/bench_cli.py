"""Speed a user feels: the whole ``pneubench`` command as a process, beside the whole-process
baseline a user would pick instead, measured in the same run.

One command::

    python -m benchmarks cli                         # 100 MB and 1 GB CSV, 1 GB TDMS, 2 GB RSS check
    python -m benchmarks.bench_cli --quick           # 100 MB CSV only, start-up and --jobs checks

What it measures (each a fresh process; medians of ``--repeat`` round-robin runs, so a load
change hits every command alike):

1. **One fresh export.** A raw tree holding one durability export (``t, p_a, p_b, x`` at 5 kHz;
   the same generator as ``bench_ingest``), rebuilt into a fresh warehouse with
   ``pneubench rebuild -q --no-report``; against ``pandas.read_csv`` + unit conversion (bar to
   Pa gauge, mm to m) + ``to_parquet`` as a whole ``python -c`` process, and ``pyarrow``
   ``read_csv`` + the same conversion + ``write_table``. TDMS against ``npTDMS`` read +
   ``as_dataframe`` + conversion + ``to_parquet``. Targets: 1.5x pandas at 100 MB, 2.5x at 1 GB
   (CSV), 2x npTDMS at 1 GB. Peak RSS of the whole process tree (sampled from /proc) under
   1 GB for a 2 GB export.
2. **Parallelism never costs.** ``--jobs 2`` (the default on 2 cores) against ``--jobs 1`` on
   the one-export tree and on the demo campaign: never more than 5 % slower.
3. **Nothing runs for nothing.** ``pneubench --help`` and ``pneubench query`` on a small
   warehouse start in under 0.5 s; the modules that cost most at start-up are listed from
   ``python -X importtime``. A stage with no runs of its kinds and no changed inputs costs under
   20 ms: the 100 MB tree rebuilt after its one (durability) export changed, the other stages'
   own times read from the rebuild's progress lines.
4. **Where the time goes.** The fresh 100 MB rebuild by phase (start-up, ingest, each stage,
   the rest), from its progress lines, for a target it misses.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import time
from pathlib import Path

from benchmarks.bench_ingest import make_csv, make_tdms
from benchmarks.proc import Series, measure, pneubench_cmd, verdict

DATA = Path(__file__).resolve().parent / "_data"
ROOT = Path(__file__).resolve().parent.parent

_CONVERT = """
import sys, numpy as np
src, out = sys.argv[1], sys.argv[2]
skip = 0
with open(src, 'rb') as fh:
    for line in fh:
        if not line.startswith(b'#'):
            break
        skip += 1
"""
BASELINES = {
    "pandas": _CONVERT + """
import pandas as pd
df = pd.read_csv(src, skiprows=skip)
df.columns = ['t_s', 'p_a_pa', 'p_b_pa', 'x_m']
df['p_a_pa'] *= 1e5; df['p_b_pa'] *= 1e5; df['x_m'] *= 1e-3
df.to_parquet(out)
""",
    "pyarrow": _CONVERT + """
import pyarrow as pa, pyarrow.csv as pacsv, pyarrow.compute as pc, pyarrow.parquet as pq
t = pacsv.read_csv(src, read_options=pacsv.ReadOptions(skip_rows=skip))
t = pa.table({'t_s': t.column(0), 'p_a_pa': pc.multiply(t.column(1), 1e5), 'p_b_pa': pc.multiply(t.column(2), 1e5),
              'x_m': pc.multiply(t.column(3), 1e-3)})
pq.write_table(t, out)
""",
    "duckdb": _CONVERT + """
import duckdb
con = duckdb.connect()
con.execute("SET enable_progress_bar = false")
con.execute(f\"\"\"COPY (SELECT column0 AS t_s, column1 * 1e5 AS p_a_pa, column2 * 1e5 AS p_b_pa, column3 * 1e-3 AS x_m
  FROM read_csv('{src}', skip={skip + 1}, header=false, columns={{'column0': 'DOUBLE', 'column1': 'DOUBLE',
  'column2': 'DOUBLE', 'column3': 'DOUBLE'}})) TO '{out}' (FORMAT parquet)\"\"\")
""",
    "nptdms": """
import sys
from nptdms import TdmsFile
src, out = sys.argv[1], sys.argv[2]
df = TdmsFile.read(src).as_dataframe(time_index=True)
df.columns = ['p_a_pa', 'p_b_pa', 'x_m']
df['p_a_pa'] *= 1e5; df['p_b_pa'] *= 1e5; df['x_m'] *= 1e-3
df.index.name = 't_s'
df.reset_index().to_parquet(out)
""",
}


def _export(fmt: str, size_mb: float) -> Path:
    """raw/bench/big.<fmt> of about ``size_mb`` MB (generated once, reused)."""
    raw = DATA / f"cli-{fmt}-{int(size_mb)}mb" / "raw"
    src = raw / "bench" / f"big.{fmt}"
    (make_csv(src, size_mb) if fmt == "csv" else make_tdms(src, size_mb, 10_000))
    past = time.time() - 3600
    os.utime(src, (past, past))
    return src


def one_export(fmt: str, size_mb: float, repeat: int, baselines: list[str]) -> dict:
    src = _export(fmt, size_mb)
    raw = src.parent.parent
    mb = src.stat().st_size / 1e6
    work = DATA / "cli-out"
    commands = {"pneubench": lambda: [*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse",
                                      str(work / "wh"), "-q", "--no-report"]}
    for b in baselines:
        commands[b] = lambda b=b: [sys.executable, "-c", BASELINES[b], str(src), str(work / f"{b}.parquet")]
    series = {name: Series(name) for name in commands}
    for _ in range(repeat):
        for name, cmd in commands.items():
            shutil.rmtree(work, ignore_errors=True)
            work.mkdir(parents=True)
            m = measure(cmd(), cwd=ROOT)
            if name != "pneubench" and m.exit_code != 0:  # exit 1 is pneubench's "some quarantined", not a baseline's
                raise SystemExit(f"baseline {name} failed ({m.exit_code}):\n{m.stderr[-2000:]}")
            series[name].runs.append(m)
    shutil.rmtree(work, ignore_errors=True)
    print(f"\n{fmt.upper()} {mb:.0f} MB, whole processes, median of {repeat}:")
    for name, s in series.items():
        print(f"  {name:10s} {s.wall_s:7.2f} s  {mb / s.wall_s:6.0f} MB/s  cpu {s.cpu_s:6.2f} s  "
              f"peak RSS of the process tree {s.tree_peak_mb:6.0f} MB (PSS {s.tree_peak_pss_mb:6.0f} MB)")
    return {"mb": mb, **{n: {"wall_s": s.wall_s, "cpu_s": s.cpu_s, "tree_peak_mb": s.tree_peak_mb,
                             "tree_peak_pss_mb": s.tree_peak_pss_mb}
                         for n, s in series.items()}}


_STAGE_LINE = re.compile(r"^stage (\w+) (ran|reused): (.*) \((\d+(?:\.\d+)?) (ms|s)\b")
_PHASE_LINES = {"ingest": re.compile(r"^ingest: \d+/\d+ done in ([\d.]+) s"),
                "stages": re.compile(r"^stages: \d+/\d+ done in ([\d.]+) s"),
                "rebuild (in the process)": re.compile(r"^rebuild: .*, ([\d.]+) s$")}


def _stage_times(stderr: str) -> dict[str, tuple[str, float, int]]:
    """``{stage: (ran|reused, seconds, rows)}`` from a rebuild's progress lines."""
    out = {}
    for line in stderr.splitlines():
        m = _STAGE_LINE.match(line.strip())
        if m:
            rows = sum(int(n) for n in re.findall(r" (\d+) rows", m.group(3)))
            out[m.group(1)] = (m.group(2), float(m.group(4)) / (1e3 if m.group(5) == "ms" else 1.0), rows)
    return out


def where_the_time_goes(src: Path, repeat: int) -> dict:
    """The 100 MB rebuild by phase (its own progress lines, ``--jobs 1``), and what a stage with no
    runs of its kinds costs when only the export changed (those stages are reused)."""
    raw = src.parent.parent
    wh = DATA / "cli-phases-wh"
    cmd = [*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--no-report", "--jobs", "1"]
    shutil.rmtree(wh, ignore_errors=True)
    fresh = measure(cmd, cwd=ROOT)
    phases = {k: float(m.group(1)) for line in fresh.stderr.splitlines() for k, rx in _PHASE_LINES.items()
              if (m := rx.match(line.strip()))}
    stages = _stage_times(fresh.stderr)
    print(f"\nwhere a fresh 100 MB rebuild goes (--jobs 1, whole process {fresh.wall_s:.2f} s, cpu {fresh.cpu_s:.2f} s):")
    print(f"  start-up and imports before the rebuild starts: {fresh.wall_s - phases.get('rebuild (in the process)', 0):.2f} s")
    for k, v in phases.items():
        print(f"  {k}: {v:.2f} s")
    for name, (how, sec, rows) in stages.items():
        print(f"    stage {name} {how}: {sec:.3f} s ({rows} rows)")
    # one change that concerns only the durability stage: the others have no runs of their kinds
    original, st = src.read_bytes(), src.stat()
    reused: dict[str, list[float]] = {}
    try:
        for i in range(repeat):
            src.write_bytes(original + b"\n" * (i + 1))
            for name, (how, sec, _rows) in _stage_times(measure(cmd, cwd=ROOT).stderr).items():
                if how == "reused":
                    reused.setdefault(name, []).append(sec)
    finally:
        src.write_bytes(original)
        os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns))
        shutil.rmtree(wh, ignore_errors=True)
    med = {n: sorted(v)[len(v) // 2] for n, v in reused.items()}
    print("  one export changed, stages with no runs of their kinds (reused), median of "
          f"{repeat}: " + ", ".join(f"{n} {1e3 * v:.0f} ms" for n, v in med.items()))
    return {"wall_s": fresh.wall_s, "cpu_s": fresh.cpu_s, "phases": phases,
            "stages": {n: list(v) for n, v in stages.items()}, "reused_stage_s": med}


def jobs_cost(raw: Path, label: str, repeat: int) -> dict:
    """--jobs 1 against the default on ``raw``, full rebuilds into fresh warehouses."""
    wh = DATA / "cli-jobs-wh"
    out = {}
    series = {j: Series(str(j)) for j in ("1", "default")}
    for _ in range(repeat):
        for j in series:
            shutil.rmtree(wh, ignore_errors=True)
            cmd = [*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "-q", "--no-report"]
            series[j].runs.append(measure(cmd + (["--jobs", "1"] if j == "1" else []), cwd=ROOT))
    shutil.rmtree(wh, ignore_errors=True)
    out = {j: s.wall_s for j, s in series.items()}
    print(f"  {label:34s} --jobs 1 {out['1']:6.2f} s, default --jobs {out['default']:6.2f} s "
          f"({out['default'] / out['1']:.3f}x)")
    return out


def startup(repeat: int) -> dict:
    wh = DATA / "cli-startup-wh"
    raw = DATA / "cli-startup-raw"
    if not (wh / "pneubench.duckdb").is_file():
        shutil.rmtree(raw, ignore_errors=True)
        (raw / "c").mkdir(parents=True)
        (raw / "c" / "a.csv").write_text("# kind: step\n# started_at: 2026-01-01T00:00:00\n# rig: r\n"
                                         "t[s],x[mm],x_ref[mm]\n0,0,0\n0.1,1,1\n")
        measure([*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "-q", "--no-report"], cwd=ROOT)
    cmds = {"pneubench --help": [*pneubench_cmd(), "--help"],
            "pneubench query": [*pneubench_cmd(), "query", "SELECT count(*) FROM runs", "--warehouse", str(wh)]}
    out = {}
    for name, cmd in cmds.items():
        out[name] = Series(name, [measure(cmd, cwd=ROOT) for _ in range(repeat)]).wall_s
        m = measure([sys.executable, "-X", "importtime", *cmd[1:]], cwd=ROOT)
        costs = []
        for line in m.stderr.splitlines():
            parts = line.split("|")
            if len(parts) == 3 and parts[1].strip().isdigit():
                costs.append((int(parts[1]), parts[2].rstrip()))
        top = ", ".join(f"{n.strip()} {us / 1e3:.0f} ms" for us, n in sorted(costs, reverse=True)[:4])
        print(f"  {name:18s} {out[name]:.3f} s   biggest imports (cumulative): {top}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="100 MB CSV only (minutes)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    print(f"pneubench whole-command benchmark: {os.cpu_count()} cores, python {sys.version.split()[0]}, "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    checks = []
    res: dict = {}
    res["csv100"] = r = one_export("csv", 100, args.repeat, ["pandas", "pyarrow", "duckdb"])
    checks.append(("CSV 100 MB: pneubench rebuild >= 1.5x pandas", r["pandas"]["wall_s"] / r["pneubench"]["wall_s"], 1.5))
    res["csv100_phases"] = ph = where_the_time_goes(_export("csv", 100), args.repeat)
    for name, sec in ph["reused_stage_s"].items():
        checks.append((f"stage {name} with no runs of its kinds, inputs unchanged: seconds < 0.020", sec, None))
    if not args.quick:
        res["csv1000"] = r = one_export("csv", 1000, args.repeat, ["pandas", "pyarrow", "duckdb"])
        checks.append(("CSV 1 GB: pneubench rebuild >= 2.5x pandas", r["pandas"]["wall_s"] / r["pneubench"]["wall_s"], 2.5))
        res["tdms1000"] = r = one_export("tdms", 1000, args.repeat, ["nptdms"])
        checks.append(("TDMS 1 GB: pneubench rebuild >= 2x npTDMS", r["nptdms"]["wall_s"] / r["pneubench"]["wall_s"], 2.0))
        res["csv2000"] = r = one_export("csv", 2000, 1, [])
        checks.append(("CSV 2 GB: peak RSS of the process tree < 1000 MB", r["pneubench"]["tree_peak_mb"], None))
    print("\n--jobs (full rebuilds, fresh warehouses):")
    res["jobs_one_export"] = j = jobs_cost(_export("csv", 100).parent.parent, "one 100 MB CSV export", args.repeat)
    checks.append(("--jobs default <= 1.05x --jobs 1, one export", j["default"] / j["1"], None))
    demo = DATA / "cli-demo" / "raw"
    if not (DATA / "cli-demo" / ".complete").is_file():
        shutil.rmtree(demo.parent, ignore_errors=True)
        measure([*pneubench_cmd(), "simulate", str(demo), "--seed", "1", "-q"], cwd=ROOT)
        (DATA / "cli-demo" / ".complete").write_text("ok\n")
    res["jobs_demo"] = j = jobs_cost(demo, "demo campaign (simulate --seed 1)", args.repeat)
    checks.append(("--jobs default <= 1.05x --jobs 1, demo campaign", j["default"] / j["1"], None))
    print("\nstart-up:")
    res["startup"] = s = startup(args.repeat)
    checks += [("pneubench --help < 0.5 s", s["pneubench --help"], None),
               ("pneubench query < 0.5 s", s["pneubench query"], None)]
    print()
    ok_all = True
    for what, value, need in checks:
        if need is not None:
            ok = value >= need
        elif "no runs of its kinds" in what:
            ok = value < 0.020
        elif "RSS" in what:
            ok = value < 1000
        elif "jobs" in what:
            ok = value <= 1.05
        else:
            ok = value < 0.5
        ok_all &= ok
        print(f"{verdict(ok)}  {what}: {value:.3f}")
    if args.json:
        args.json.write_text(json.dumps({"results": res, "checks": checks}, indent=1, default=str))
    return 0 if ok_all else 1


if __name__ == "__main__":
    sys.exit(main())
