"""Spring-fit benchmark: the 120 PLA spring tests of seed 001, as the ``models`` stage fits them,
against a straightforward unvectorised fit.

One command::

    python -m benchmarks.bench_spring_fit                # 120 tests, 3 cycles at 1 kHz, 2 workers
    python -m benchmarks.bench_spring_fit --jobs 1       # one core
    python -m benchmarks.bench_spring_fit --cycles 10    # longer tests

It writes the paper's test matrix (front and rear chamber x P0 2, 3, 4, 5 bar abs x D 3, 5, 7 mm
x f 0.5, 1, 1.5, 2, 4 Hz) with the simulator as warehouse samples Parquet under
``benchmarks/_data/spring/`` (git-ignored; reused when present), then times, in this run:

* ``stage``: what ``pipeline.stages.models`` does: :func:`pipeline.stages.models.analyse_run` per
  test through a pool of ``--jobs`` processes (read Parquet, P0, velocity, loop energy, the run's
  sufficient statistics), then one fit per chamber in this process from the sums
  (:func:`pipeline.stages.models.fit_spring_item`: paper seeds, variable projection), NRMSE of
  every test;
* ``baseline``: the same reading and seeds in one process, then a plain fit: a residual that loops
  over the tests and their samples in Python, finite-difference Jacobian, every sample used.

Printed: seconds for each, the ratio baseline/stage, the fitted parameters of both against the
simulator's truth, and the worst test NRMSE. Target (issue #5): the stage path under 30 s on 2
cores.
"""
from __future__ import annotations

import argparse
import itertools
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

DATA = Path(__file__).resolve().parent / "_data" / "spring"
P0S, AMPS, FREQS = (2.0, 3.0, 4.0, 5.0), (3.0, 5.0, 7.0), (0.5, 1.0, 1.5, 2.0, 4.0)


def make_tests(fs: float, cycles: float) -> tuple[list[tuple], dict]:
    """(items for ``analyse_run``, truth per chamber); Parquet written once per configuration."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.simulator import simulate_spring

    folder = DATA / f"fs{fs:g}_c{cycles:g}"
    folder.mkdir(parents=True, exist_ok=True)
    items, truth = [], {}
    for i, (chamber, p0, amp, f) in enumerate(itertools.product(("front", "rear"), P0S, AMPS, FREQS)):
        run_id = f"bench/{chamber}_{p0:g}_{amp:g}_{f:g}"
        path = folder / f"{chamber}_{p0:g}_{amp:g}_{f:g}.parquet"
        sim = simulate_spring(chamber, p0, amp, f, rng=i, cycles=cycles, fs_hz=fs)
        truth[chamber] = {k: sim.truth[k] for k in ("n", "Ae", "eps", "delta")}
        if not path.is_file():
            tmp = path.with_suffix(".tmp")
            pq.write_table(pa.Table.from_pandas(sim.data, preserve_index=False), tmp)
            os.replace(tmp, path)
        params = {k: v for k, v in sim.metadata.items() if k != "p0_bar_abs"}   # P0 is read from the run
        items.append(("spring", run_id, str(path), params))
    return items, truth


def stage_path(items: list[tuple], jobs: int):
    """What the stage does: per-test preparation and per-chamber fits through a process pool."""
    from pipeline.stages.models import analyse_run, fit_spring_item

    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        results = list(pool.map(analyse_run, items, chunksize=max(1, len(items) // (jobs * 8))))
    stats = [r["extra"] for r in results if r["extra"] is not None]
    t1 = time.perf_counter()
    fits = [fit_spring_item((c, [r for r in stats if r.chamber == c])) for c in ("front", "rear")]
    print(f"    stage: read + prepare + sums {t1 - t0:.2f} s (pool start included), "
          f"fits {time.perf_counter() - t1:.3f} s")
    return {f.chamber: f for f in fits}, stats


def _plain_residual(x, tests, stroke_m, p_atm):
    """Unvectorised residual: a Python loop over every sample of every test."""
    n, ae, eps, delta = x
    half = stroke_m / 2
    out = []
    for t in tests:
        s = 1.0 if t["chamber"] == "rear" else -1.0
        sf = -s
        w = 1.0 / (t["range"] * math.sqrt(len(t["d"])))
        two_pi_f = 2 * math.pi * t["f"]
        for d, v, f in zip(t["d"], t["v"], t["force"]):
            pg = t["p0"] * (half / (half + s * d)) ** n - p_atm
            sgn = (v > 0) - (v < 0)
            model = pg * ae + sf * (sgn * eps * pg + delta * v / two_pi_f)
            out.append((model - f) * w)
    return out


def baseline_path(items: list[tuple]):
    """One process, same preparation and seeds, then a plain least-squares fit per chamber."""
    import numpy as np
    from scipy import optimize

    from analyses.pla_spring_fit import SpringFit, fit_spring_stats, spring_nrmse, spring_run_stats
    from pipeline.stages.models import spring_figure_run

    runs = [r for r in map(spring_figure_run, items) if r is not None]
    fits = {}
    for chamber in ("front", "rear"):
        group = [r for r in runs if r.chamber == chamber]
        seeds = fit_spring_stats([spring_run_stats(r) for r in group]).seeds
        x0 = [seeds["n_polytropic"], seeds["ae_m2"], seeds["epsilon_m2"], seeds["delta_n_m"]]
        tests = [{"chamber": r.chamber, "d": r.d.tolist(), "v": r.v.tolist(), "force": r.f.tolist(),
                  "p0": r.p0_abs, "f": r.frequency_hz, "range": float(np.ptp(r.f))} for r in group]
        sol = optimize.least_squares(lambda x: np.asarray(_plain_residual(x, tests, 0.040, 101325.0)), x0,
                                     x_scale=np.abs(x0), method="trf")
        fit = SpringFit(chamber, *map(float, sol.x), n_tests=len(group), seeds=seeds)
        fit.nrmse_pct = {r.run_id: spring_nrmse(r, fit) for r in group}
        fits[chamber] = fit
    return fits, runs


def _report(name, seconds, fits, truth):
    print(f"{name:>9}: {seconds:7.2f} s")
    for chamber, fit in sorted(fits.items()):
        tr = truth[chamber]
        errs = [fit.n_polytropic / tr["n"] - 1, fit.ae_m2 / tr["Ae"] - 1, fit.epsilon_m2 / tr["eps"] - 1,
                fit.delta_n_m / tr["delta"] - 1]
        print(f"           {chamber:5} n={fit.n_polytropic:.4f} Ae={fit.ae_m2:.4e} eps={fit.epsilon_m2:.4e} "
              f"delta={fit.delta_n_m:.1f}  error vs truth: " + " ".join(f"{100 * e:+.2f}%" for e in errs)
              + f"  worst NRMSE {max(fit.nrmse_pct.values()):.2f} % over {fit.n_tests} tests")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="worker processes of the stage path (default 2)")
    ap.add_argument("--fs", type=float, default=1000.0, help="logging rate of the tests [Hz]")
    ap.add_argument("--cycles", type=float, default=3.0, help="cycles per test")
    ap.add_argument("--no-baseline", action="store_true", help="time the stage path only")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    items, truth = make_tests(args.fs, args.cycles)
    print(f"{len(items)} spring tests ({args.cycles:g} cycles at {args.fs:g} Hz) ready in "
          f"{time.perf_counter() - t0:.1f} s; {os.cpu_count()} CPUs, stage path on {args.jobs} workers")

    t0 = time.perf_counter()
    fits, stats = stage_path(items, args.jobs)
    t_stage = time.perf_counter() - t0
    n_samples = sum(r.n_all for r in stats)
    print(f"{n_samples} samples in {len(stats)} tests")
    _report("stage", t_stage, fits, truth)
    ok = t_stage < 30.0 and all(max(f.nrmse_pct.values()) < 2.5 for f in fits.values())

    if not args.no_baseline:
        t0 = time.perf_counter()
        base, _ = baseline_path(items)
        t_base = time.perf_counter() - t0
        _report("baseline", t_base, base, truth)
        print(f"ratio baseline / stage: {t_base / t_stage:.1f}x")
    print(f"target: stage path under 30 s with NRMSE < 2.5 % everywhere: {'met' if ok else 'NOT met'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
