"""Durability benchmark: streamed stroke/distance counting against whole-array pandas.

One command::

    python -m benchmarks.bench_durability                  # a full-profile run: 10 km, ~8 h at 1 kHz (29 M samples)
    python -m benchmarks.bench_durability --hours 8 --fs 5000   # a 5 kHz logger
    python -m benchmarks.bench_durability --hours 0.5       # a quick look

It writes a full-profile durability run (the simulator's stroke plan: 0.5 m strokes at 0.5 m/s,
5 um encoder, pressure noise; plus 3 um position jitter before quantisation, ``--jitter-um``) as a warehouse samples Parquet under ``benchmarks/_data/``
(git-ignored; reused when present), generated chunk by chunk. Then each approach runs in its own
subprocess so that its peak RSS is its own (``ru_maxrss`` of the child via ``os.wait4``, minus
the child's RSS after imports):

* ``stream``: what the stage does, :func:`pipeline.stages.durability.analyse_run` (Parquet
  batches of 1 M rows through :class:`analyses.durability.StrokeCounter`);
* ``core``: the counter alone on arrays already in memory (CPU cost of the algorithm);
* ``pandas``: the naive baseline: whole file into a DataFrame, ``x.diff().abs().sum()`` for the
  distance and sign changes of a deadbanded ``diff`` for the strokes.

Printed: samples/s, peak RSS, distance error against the simulator's truth, and the ratios
stream/pandas (throughput) and pandas/stream (memory).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data"


def full_profile_km() -> float:
    """Distance of one durability run of the simulator's ``full`` profile [km] (10 km, ~8 h)."""
    from pipeline.simulator.profiles import PROFILES

    return PROFILES["full"].dur_run_km


def _plan(hours: float | None, fs: float, km: float | None = None):
    from pipeline.simulator.durability import stroke_plan

    if km is not None:
        return stroke_plan(distance_m=km * 1e3, fs_hz=fs)
    return stroke_plan(duration_s=hours * 3600.0, fs_hz=fs)


def make_run(hours: float | None, fs: float, jitter_um: float = 3.0, km: float | None = None) -> tuple[Path, dict]:
    """The benchmark run's samples file (written once) and its truth.

    ``km`` (whole strokes covering that distance) takes precedence over ``hours``.
    ``jitter_um``: Gaussian position noise added before the 5 um quantisation (the simulator's
    encoder is noise-free), so that the naive ``sum |dx|`` shows what noise does to it.
    """
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.simulator.durability import iter_durability_chunks

    plan = _plan(hours, fs, km)
    size = f"{km:g}km" if km is not None else f"{hours:g}h"
    path = DATA / f"durability_{size}_{fs:g}hz_{jitter_um:g}um.parquet"
    truth = {"distance_m": plan.distance_m, "strokes": plan.strokes, "n_samples": plan.n_samples}
    if path.is_file() and pq.ParquetFile(path).metadata.num_rows == plan.n_samples:
        return path, truth
    DATA.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    writer = None
    t0 = time.perf_counter()
    rng = np.random.default_rng(2)
    for chunk in iter_durability_chunks(plan, rng=1, chunk_rows=1_000_000):
        if jitter_um > 0:
            chunk["x_m"] = np.round((chunk["x_m"] + rng.normal(0.0, jitter_um * 1e-6, len(chunk))) / 5e-6) * 5e-6
        table = pa.Table.from_pandas(chunk, preserve_index=False)
        if writer is None:
            writer = pq.ParquetWriter(tmp, table.schema)
        writer.write_table(table)
    writer.close()
    os.replace(tmp, path)
    print(f"wrote {path.name}: {plan.n_samples:,} samples in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return path, truth


# -- the approaches (each runs in a child process) --------------------------------------------
def _rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def worker(approach: str, path: str) -> dict:
    import numpy as np
    import pandas as pd
    import pyarrow.parquet as pq

    from analyses.durability import DEADBAND_M, StrokeCounter
    from pipeline.stages.durability import analyse_run

    if approach == "core":  # load first; only the counter is timed, its memory is the arrays'
        tbl = pq.read_table(path, columns=["t_s", "x_m", "p_a_pa", "p_b_pa"])
        t, x = tbl["t_s"].to_numpy(), tbl["x_m"].to_numpy()
        dp = tbl["p_a_pa"].to_numpy() - tbl["p_b_pa"].to_numpy()
        del tbl
    base = _rss_mb()
    t0 = time.perf_counter()
    if approach == "stream":
        res = analyse_run(path)
        distance, strokes, n = res["distance_m"], res["strokes"], res["n_samples"]
    elif approach == "core":
        sc = StrokeCounter(DEADBAND_M)
        step = 1 << 20
        for a in range(0, len(x), step):
            sc.update(t[a:a + step], x[a:a + step], dp[a:a + step])
        s = sc.finish()
        distance, strokes, n = s.distance_m, s.strokes, s.n_samples
    elif approach == "pandas":
        df = pd.read_parquet(path)
        dx = df["x_m"].diff()
        distance = float(dx.abs().sum())
        moving = dx[dx.abs() > 0]
        strokes = int((np.sign(moving).diff().fillna(0) != 0).sum()) + 1
        _ = (df["p_a_pa"] - df["p_b_pa"]).groupby(np.sign(dx).fillna(0).values).mean()
        n = len(df)
    else:
        raise SystemExit(f"unknown approach {approach}")
    seconds = time.perf_counter() - t0
    return {"approach": approach, "seconds": seconds, "n": int(n), "distance_m": float(distance),
            "strokes": int(strokes), "base_rss_mb": base}


def run_child(approach: str, path: Path) -> dict:
    proc = subprocess.Popen([sys.executable, "-m", "benchmarks.bench_durability", "--worker", approach, str(path)],
                            stdout=subprocess.PIPE, cwd=Path(__file__).resolve().parent.parent)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    if status != 0:
        raise SystemExit(f"{approach} failed")
    res = json.loads(out)
    res["peak_rss_mb"] = usage.ru_maxrss / 1024.0
    res["extra_rss_mb"] = res["peak_rss_mb"] - res["base_rss_mb"]
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=None,
                    help="run length [h] (default: a full-profile run, see --km)")
    ap.add_argument("--km", type=float, default=None,
                    help="run length as distance [km] (default without --hours: the full profile's "
                         "10 km run, ~8.06 h, 29 M samples at 1 kHz)")
    ap.add_argument("--fs", type=float, default=1000.0, help="sample rate [Hz] (default 1000)")
    ap.add_argument("--jitter-um", type=float, default=3.0,
                    help="position noise before the 5 um quantisation [um] (default 3)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per approach; the best time is kept")
    ap.add_argument("--worker", nargs=2, metavar=("APPROACH", "PATH"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(*args.worker)))
        return 0
    km = args.km if args.km is not None or args.hours is not None else full_profile_km()
    path, truth = make_run(args.hours, args.fs, args.jitter_um, km)
    hours = (truth["n_samples"] - 1) / args.fs / 3600.0
    print(f"durability run: {hours:.2f} h at {args.fs:g} Hz, {truth['n_samples']:,} samples, "
          f"{truth['strokes']:,} strokes, {truth['distance_m'] / 1e3:.3f} km true, {args.jitter_um:g} um jitter, "
          f"{path.stat().st_size / 1e6:.0f} MB Parquet")
    results = {}
    for approach in ("stream", "core", "pandas"):
        runs = [run_child(approach, path) for _ in range(args.repeat)]
        best = min(runs, key=lambda r: r["seconds"])
        best["peak_rss_mb"] = max(r["peak_rss_mb"] for r in runs)
        best["extra_rss_mb"] = max(r["extra_rss_mb"] for r in runs)
        results[approach] = best
    print(f"{'approach':<8} {'Msamples/s':>11} {'seconds':>8} {'peak RSS MB':>12} {'+RSS MB':>8} "
          f"{'distance err %':>15} {'strokes':>9}")
    for name, r in results.items():
        err = 100.0 * (r["distance_m"] - truth["distance_m"]) / truth["distance_m"]
        print(f"{name:<8} {r['n'] / r['seconds'] / 1e6:>11.1f} {r['seconds']:>8.2f} {r['peak_rss_mb']:>12.0f} "
              f"{r['extra_rss_mb']:>8.0f} {err:>15.4f} {r['strokes']:>9,}")
    s, p = results["stream"], results["pandas"]
    print(f"stream vs pandas: {p['seconds'] / s['seconds']:.2f}x throughput, "
          f"{p['extra_rss_mb'] / max(s['extra_rss_mb'], 1.0):.1f}x less memory above imports "
          f"({s['extra_rss_mb']:.0f} vs {p['extra_rss_mb']:.0f} MB); true strokes {truth['strokes']:,}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
