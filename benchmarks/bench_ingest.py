"""Ingest benchmark: pneubench's CSV / TDMS / MF4 / XLSX -> Parquet against pandas, pyarrow, npTDMS, asammdf.

One command::

    python -m benchmarks.bench_ingest                 # ~1 GB CSV and ~1 GB TDMS
    python -m benchmarks.bench_ingest --size-mb 2048  # the issue's 2 GB case
    python -m benchmarks.bench_ingest --size-mb 64 --formats csv   # a quick look

It generates a durability-like export (``t, p_a, p_b, x`` at 5 kHz, as the PLPA bench logs it)
under ``benchmarks/_data/`` (git-ignored; reused when the size matches), then runs every
approach in its own subprocess, so each one's peak RSS is its own (``ru_maxrss`` of the child
via ``os.wait4``), and prints throughput (input MB/s, MB = 10^6 bytes), peak RSS and the
ratios the issue sets as targets:

* CSV: pneubench ``ingest_file`` >= 3x ``pandas.read_csv`` + ``DataFrame.to_parquet``, and
  within 1.5x of ``pyarrow.csv.read_csv`` + ``pyarrow.parquet.write_table``;
* TDMS: pneubench against ``TdmsFile.read`` + ``as_dataframe`` + ``to_parquet``;
* MF4 (1 GB): pneubench against ``asammdf.MDF`` + ``to_dataframe`` + ``to_parquet``;
* XLSX (50 MB, ``--xlsx-size-mb``): pneubench (python-calamine) against ``pandas.read_excel``
  with its default engine (openpyxl) and with ``engine="calamine"``;
* peak RSS bounded (under 1 GB for a 2 GB file).

The file is in the page cache for every approach (it was just generated or read), so the
figures compare parsing + conversion + writing, not the disk.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data"
RATE_HZ = 5000.0
META = {"kind": "durability", "run_id": "bench/big", "started_at": "2026-01-05T08:00:00",
        "rig": "plpa-1", "hose_id": "H-bench", "operator": "benchmark"}
TARGETS = {"pandas": 3.0, "pyarrow": 1.0 / 1.5}  # required speed-up of pneubench over each

#: Approaches per format: (name, description).
APPROACHES = {
    "csv": [("pneubench", "pipeline.ingest.file.ingest_file (sha256, validation, SI, Parquet)"),
            ("pandas", "pandas.read_csv + DataFrame.to_parquet"),
            ("pyarrow", "pyarrow.csv.read_csv + pyarrow.parquet.write_table"),
            ("pyarrow-stream", "pyarrow.csv.open_csv + ParquetWriter, batch by batch (reference)")],
    "tdms": [("pneubench", "pipeline.ingest.file.ingest_file (sha256, validation, SI, Parquet)"),
             ("nptdms", "TdmsFile.read + as_dataframe + DataFrame.to_parquet")],
    "mf4": [("pneubench", "pipeline.ingest.file.ingest_file (sha256, validation, SI, Parquet)"),
            ("asammdf", "asammdf.MDF + to_dataframe + DataFrame.to_parquet")],
    "xlsx": [("pneubench", "pipeline.ingest.file.ingest_file (python-calamine, SI, Parquet)"),
             ("pandas", "pandas.read_excel (openpyxl, its default) + DataFrame.to_parquet"),
             ("pandas-calamine", "pandas.read_excel(engine='calamine') + DataFrame.to_parquet")],
}
TARGETS_BY_FORMAT = {"mf4": {"asammdf": 1.0}, "xlsx": {"pandas": 1.0}}


# -- data ----------------------------------------------------------------------------------
def _signals(start: int, n: int, seed: int = 7):
    """``n`` samples from ``start`` of a durability run: strokes, chamber pressures, noise."""
    import numpy as np

    rng = np.random.default_rng(seed + start)
    i = np.arange(start, start + n, dtype=np.float64)
    t = i / RATE_HZ
    phase = 2 * np.pi * 0.5 * t
    x_mm = np.round(100.0 * np.sin(phase) / 0.005) * 0.005          # 5 um encoder
    p_a = 3.0 + 1.5 * np.cos(phase) + rng.normal(0, 0.003, n)        # bar, sigma 300 Pa
    p_b = 3.0 - 1.5 * np.cos(phase) + rng.normal(0, 0.003, n)
    return t, p_a, p_b, x_mm


def make_csv(path: Path, size_mb: float) -> Path:
    """A CSV export of about ``size_mb`` MB: metadata lines, ``name[unit]`` header, data."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.csv as pacsv

    target = int(size_mb * 1e6)
    if path.exists() and target <= path.stat().st_size < target + 20e6:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    chunk = 200_000
    with open(tmp, "wb") as fh:
        fh.write("".join(f"# {k}: {v}\n" for k, v in META.items()).encode())
        fh.write(b"t[s],p_a[bar],p_b[bar],x[mm]\n")
        start = 0
        while fh.tell() < target:
            t, p_a, p_b, x = _signals(start, chunk)
            table = pa.table({"t": np.round(t, 4), "p_a": np.round(p_a, 5), "p_b": np.round(p_b, 5),
                              "x": np.round(x, 3)})
            pacsv.write_csv(table, fh, pacsv.WriteOptions(include_header=False, quoting_style="none"))
            start += chunk
    os.replace(tmp, path)
    return path


def make_tdms(path: Path, size_mb: float, segment_rows: int) -> Path:
    """A TDMS export of about ``size_mb`` MB as a LabVIEW logging loop writes it: one segment
    per ``segment_rows`` samples, float64 ``p_a``/``p_b`` [bar] and ``x`` [mm], waveform timing."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    target = int(size_mb * 1e6)
    if path.exists() and target <= path.stat().st_size < target + 20e6:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    wf = {"wf_increment": 1.0 / RATE_HZ, "wf_start_offset": 0.0}
    units = {"p_a": "bar", "p_b": "bar", "x": "mm"}
    with TdmsWriter(str(tmp)) as writer:
        start = 0
        while tmp.stat().st_size < target:
            _, p_a, p_b, x = _signals(start, segment_rows)
            data = {"p_a": p_a, "p_b": p_b, "x": x}
            first = start == 0
            objects = ([RootObject(META), GroupObject("Measurement")] if first else [])
            objects += [ChannelObject("Measurement", name, data[name],
                                      properties={"unit_string": units[name], **wf} if first else {})
                        for name in data]
            writer.write_segment(objects)
            start += segment_rows
    os.replace(tmp, path)
    return path


def make_mf4(path: Path, size_mb: float, chunk: int = 1_000_000) -> Path:
    """An ASAM MDF 4.10 export of about ``size_mb`` MB as a logger writes it: one channel group,
    float64 ``p_a``/``p_b`` [bar] and ``x`` [mm], the time as master channel; appended chunk by
    chunk (asammdf ``extend``), so generating it takes bounded memory."""
    from asammdf import MDF, Signal

    target = int(size_mb * 1e6)
    if path.exists() and target <= path.stat().st_size < target + 40e6:
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.mf4")
    mdf = MDF(version="4.10")
    mdf.header.comment = ";".join(f"{k}={v}" for k, v in META.items())
    start = 0
    while start * 32 < target:  # 4 float64 per record
        t, p_a, p_b, x = _signals(start, chunk)
        if start == 0:
            mdf.append([Signal(p_a, t, name="p_a", unit="bar"), Signal(p_b, t, name="p_b", unit="bar"),
                        Signal(x, t, name="x", unit="mm")], acq_name="Measurement")
        else:
            mdf.extend(0, [(t, None), (p_a, None), (p_b, None), (x, None)])
        start += chunk
    mdf.save(tmp, overwrite=True)
    mdf.close()
    os.replace(tmp, path)
    return path


def make_xlsx(path: Path, size_mb: float) -> Path:
    """An Excel workbook of about ``size_mb`` MB (one sheet, ``name[unit]`` header, metadata in
    a ``meta`` sheet), written by the simulator's writer; capped at Excel's 1,048,576 rows."""
    import numpy as np
    import pandas as pd

    from pipeline.simulator.writers import ColumnOut, write_xlsx

    if path.exists() and abs(path.stat().st_size - size_mb * 1e6) < 0.3 * size_mb * 1e6:
        return path
    rows = min(1_048_000, int(size_mb * 1e6 / 36))  # ~36 compressed bytes per row of 4 numbers
    t, p_a, p_b, x = _signals(0, rows)
    frame = pd.DataFrame({"t_s": t, "p_a_pa": (p_a - 0) * 1e5, "p_b_pa": p_b * 1e5, "x_m": np.round(x, 3) * 1e-3})
    cols = [ColumnOut("p_a_pa", "p_a", "bar"), ColumnOut("p_b_pa", "p_b", "bar"), ColumnOut("x_m", "x", "mm")]
    path.parent.mkdir(parents=True, exist_ok=True)
    write_xlsx(path, frame, cols, META)
    return path


# -- approaches (run in a child process) ---------------------------------------------------
def _meta_lines(path: Path) -> int:
    n = 0
    with open(path, "rb") as fh:
        for line in fh:
            if not line.startswith(b"#"):
                return n
            n += 1
    return n


def run_approach(fmt: str, name: str, src: Path, out: Path) -> dict:
    """Run one approach on ``src``; return work time [s] and output size."""
    if out.exists():
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    out.mkdir(parents=True)
    c0 = _cpu_seconds()
    t0 = time.perf_counter()
    if name == "pneubench":
        from pipeline.ingest.file import ingest_file
        from pipeline.raw.tree import RawTree

        res = ingest_file(RawTree(src.parent.parent), src, out / "warehouse", reuse=False)
        if res.error:
            raise SystemExit(f"pneubench failed: {res.error}")
        rows = res.run["n_samples"]
        written = out / "warehouse" / res.run["samples_path"]
    elif name == "pandas" and fmt == "csv":
        import pandas as pd

        df = pd.read_csv(src, skiprows=_meta_lines(src))
        rows = len(df)
        written = out / "pandas.parquet"
        df.to_parquet(written)
    elif name == "pyarrow":
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq

        table = pacsv.read_csv(src, read_options=pacsv.ReadOptions(skip_rows=_meta_lines(src)))
        rows = table.num_rows
        written = out / "pyarrow.parquet"
        pq.write_table(table, written)
    elif name == "pyarrow-stream":
        import pyarrow.csv as pacsv
        import pyarrow.parquet as pq

        reader = pacsv.open_csv(src, read_options=pacsv.ReadOptions(skip_rows=_meta_lines(src),
                                                                    block_size=1 << 23))
        written = out / "pyarrow-stream.parquet"
        rows = 0
        with pq.ParquetWriter(written, reader.schema) as writer:
            for batch in reader:
                writer.write_batch(batch)
                rows += batch.num_rows
    elif name == "asammdf":
        from asammdf import MDF

        mdf = MDF(str(src))
        df = mdf.to_dataframe()
        mdf.close()
        rows = len(df)
        written = out / "asammdf.parquet"
        df.to_parquet(written)
    elif name in ("pandas", "pandas-calamine") and fmt == "xlsx":
        import pandas as pd

        df = pd.read_excel(src, sheet_name=0, engine="calamine" if name == "pandas-calamine" else None)
        rows = len(df)
        written = out / f"{name}.parquet"
        df.to_parquet(written)
    elif name == "nptdms":
        from nptdms import TdmsFile

        df = TdmsFile.read(src).as_dataframe()
        rows = len(df)
        written = out / "nptdms.parquet"
        df.to_parquet(written)
    else:
        raise SystemExit(f"unknown approach {name!r}")
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "cpu_seconds": _cpu_seconds() - c0, "rows": int(rows),
            "parquet_bytes": written.stat().st_size}


def _cpu_seconds() -> float:
    """User + system CPU time of this process, all threads. [s]"""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _child(args) -> None:
    import pipeline.ingest.file  # noqa: F401 - imports before the baseline RSS is taken
    import pandas  # noqa: F401
    import pyarrow.csv  # noqa: F401
    import pyarrow.parquet  # noqa: F401
    import nptdms  # noqa: F401
    if args.format in ("mf4", "xlsx"):
        import pipeline.readers.excel  # noqa: F401
        import pipeline.readers.mdf  # noqa: F401
        import asammdf  # noqa: F401

    base_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    result = run_approach(args.format, args.child, Path(args.input), Path(args.out))
    result["import_rss_kb"] = base_kb
    print(json.dumps(result))


def measure(fmt: str, name: str, src: Path, out: Path) -> dict:
    """Run an approach in a subprocess; its own wall time and peak RSS (``os.wait4``)."""
    cmd = [sys.executable, "-m", "benchmarks.bench_ingest", "--child", name, "--format", fmt,
           "--input", str(src), "--out", str(out)]
    out.parent.mkdir(parents=True, exist_ok=True)
    log_out, log_err = out.parent / f"{out.name}.stdout", out.parent / f"{out.name}.stderr"
    with open(log_out, "wb") as fo, open(log_err, "wb") as fe:
        proc = subprocess.Popen(cmd, stdout=fo, stderr=fe, cwd=Path(__file__).resolve().parent.parent)
        _, status, usage = os.wait4(proc.pid, 0)  # reap it ourselves: its own rusage
        proc.returncode = code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise SystemExit(f"{fmt}/{name} failed ({code}):\n{log_err.read_text()[-2000:]}")
    result = json.loads(log_out.read_text().strip().splitlines()[-1])
    result["peak_rss_mb"] = usage.ru_maxrss * 1024 / 1e6  # ru_maxrss is in KiB on Linux
    result["import_rss_mb"] = result.pop("import_rss_kb") * 1024 / 1e6
    return result


# -- main ----------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size-mb", type=float, default=1000.0, help="size of each generated export [MB]")
    ap.add_argument("--formats", default="csv,tdms,mf4,xlsx", help="comma-separated: csv,tdms,mf4,xlsx")
    ap.add_argument("--xlsx-size-mb", type=float, default=50.0, help="size of the generated workbook [MB]")
    ap.add_argument("--approaches", default=None, help="comma-separated subset (default: all)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per approach; the median is reported")
    ap.add_argument("--tdms-segment-rows", type=int, default=10_000, help="samples per TDMS segment")
    ap.add_argument("--data-dir", type=Path, default=DATA)
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--format", help=argparse.SUPPRESS)
    ap.add_argument("--input", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(args)
        return 0

    formats = [f.strip() for f in args.formats.split(",") if f.strip()]
    wanted = set(args.approaches.split(",")) if args.approaches else None
    size_tag = f"{int(args.size_mb)}mb"
    print(f"pneubench ingest benchmark: {args.size_mb:g} MB per export, {os.cpu_count()} cores, "
          f"python {sys.version.split()[0]}")
    report = {"size_mb": args.size_mb, "cores": os.cpu_count(), "results": {}}
    for fmt in formats:
        # The campaign folder is the parent: raw/<campaign>/<file>.
        src = args.data_dir / "raw" / "bench" / f"big-{size_tag}.{fmt}"
        t0 = time.perf_counter()
        if fmt == "csv":
            make_csv(src, args.size_mb)
        elif fmt == "tdms":
            make_tdms(src, args.size_mb, args.tdms_segment_rows)
        elif fmt == "mf4":
            make_mf4(src, args.size_mb)
        elif fmt == "xlsx":
            src = args.data_dir / "raw" / "bench" / f"big-{int(args.xlsx_size_mb)}mb.xlsx"
            # in a child: a parent that held the 1 M-row frame would pass its memory high-water
            # mark to every approach it forks (Linux keeps it across exec in ru_maxrss)
            subprocess.run([sys.executable, "-c", "import sys; from pathlib import Path; "
                            "from benchmarks.bench_ingest import make_xlsx; make_xlsx(Path(sys.argv[1]), float(sys.argv[2]))",
                            str(src), str(args.xlsx_size_mb)], check=True, cwd=Path(__file__).resolve().parent.parent)
        else:
            raise SystemExit(f"unknown format {fmt!r}")
        mb = src.stat().st_size / 1e6
        print(f"\n{fmt.upper()}: {src.relative_to(args.data_dir.parent) if args.data_dir == DATA else src} "
              f"({mb:.0f} MB, ready in {time.perf_counter() - t0:.0f} s)")
        results = {}
        todo = [(name, what) for name, what in APPROACHES[fmt] if not wanted or name in wanted]
        runs: dict[str, list[dict]] = {name: [] for name, _ in todo}
        for _ in range(args.repeat):  # round robin: a load change hits every approach alike
            for name, _ in todo:
                runs[name].append(measure(fmt, name, src, args.data_dir / "out" / f"{fmt}-{name}"))
        for name, what in todo:
            runs_ = runs[name]
            seconds = statistics.median(r["seconds"] for r in runs_)
            r = {**runs_[0], "seconds": seconds, "mb_s": mb / seconds, "all_seconds": [x["seconds"] for x in runs_],
                 "cpu_seconds": statistics.median(x["cpu_seconds"] for x in runs_),
                 "peak_rss_mb": max(x["peak_rss_mb"] for x in runs_), "what": what}
            results[name] = r
            print(f"  {name:15s} {r['seconds']:7.2f} s {r['mb_s']:7.1f} MB/s  cpu {r['cpu_seconds']:6.2f} s"
                  f"  peak RSS {r['peak_rss_mb']:6.0f} MB"
                  f" (imports {r['import_rss_mb']:.0f})  {r['rows']:,} rows -> {r['parquet_bytes'] / 1e6:.0f} MB  [{what}]")
        shutil.rmtree(args.data_dir / "out", ignore_errors=True)
        if "pneubench" in results:
            pb = results["pneubench"]
            for base, res in results.items():
                if base == "pneubench":
                    continue
                speedup = res["seconds"] / pb["seconds"]
                need = TARGETS_BY_FORMAT.get(fmt, TARGETS).get(base)
                verdict = "" if need is None else ("  target met" if speedup >= need else "  TARGET MISSED")
                goal = "" if need is None else (f" (target >= {need:g}x)" if need >= 1 else
                                                f" (target: at most {1 / need:g}x slower)")
                print(f"  pneubench vs {base:14s} speed {speedup:5.2f}x{goal}{verdict};"
                      f" cpu {res['cpu_seconds'] / pb['cpu_seconds']:.2f}x less;"
                      f" peak RSS {pb['peak_rss_mb'] / res['peak_rss_mb']:.2f}x")
            print(f"  pneubench peak RSS per input MB: {pb['peak_rss_mb'] / mb:.3f}")
        report["results"][fmt] = {"input_mb": mb, **results}
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
