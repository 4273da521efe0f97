"""Calibration of the sequential verdict (issue 23): error rates counted from known truth.

One command::

    python -m benchmarks.bench_sequential            # 2,000 trials a scenario, both spending families
    python -m benchmarks.bench_sequential --quick    # 400 trials, O'Brien-Fleming only

Each trial is one simulated hose type: ``n`` force-set and ``n`` distance-set hoses start together
on the bench, Weibull lives with a known common shape (2) and a known force / distance life ratio;
the test ends at ``max_failures`` failures (both adjustments), from
:func:`analyses.sequential.max_information` for the margin, alpha and power. A look is taken at
EVERY failure. The estimate is the closed-form MLE of a Weibull life ratio with known shape
(``x^shape`` is exponential: the log ratio of the two mean ``x^shape`` per failure, divided by
the shape, SE ``sqrt(1/d_force + 1/d_distance) / shape``), undefined until both adjustments have
a failure. Counted, per scenario:

* true ratio 1: ``force longer`` or ``distance longer`` declared (target <= alpha + 2 MC SE);
  the naive reading (a fixed-sample 95 % test at every failure, stop at the first significance)
  counted on the same trials (expected to MISS);
* true ratio = margin: ``no practical difference`` declared (target <= alpha + 2 MC SE);
* true ratio = margin: ``force longer`` declared, against the plan's power (within 5 points);
* true ratio = margin^1.5: ``force longer`` declared (target >= power - 5 points).

Before the trials, the design's exact arithmetic: the power of the inflation factor's looks at its
drift, which :func:`analyses.sequential_boundaries.inflation_factor` finds from the null recursion by a change
of measure, recomputed by the recursion run under that drift
(:func:`analyses.sequential_boundaries.crossing_probabilities`): equal to the target power within 1e-6.

Seeded (``numpy.random.default_rng(2023 + scenario)``): the same numbers every run.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from analyses.sequential import max_information, sequential_verdict
from analyses.sequential_boundaries import DESIGN_LOOKS, crossing_probabilities, efficacy_boundaries, inflation_factor

SHAPE = 2.0


def simulate_looks(rng, ratio: float, n_per_arm: int, max_failures: int):
    """(log_ratio, se) at each of the first ``max_failures`` failures of one trial, closed form."""
    scale = np.array([ratio, 1.0])                        # force, distance (B10 ratio = scale ratio)
    life = scale[:, None] * rng.weibull(SHAPE, size=(2, n_per_arm))
    arm = np.repeat([0, 1], n_per_arm)
    x = life.ravel()
    order = np.argsort(x)[:max_failures]
    xs, a = x[order], arm[order]
    ys = xs ** SHAPE                                       # exponential on this scale
    d = np.stack([np.cumsum(a == 0), np.cumsum(a == 1)])   # failures so far per arm
    done = np.stack([np.cumsum(np.where(a == 0, ys, 0.0)), np.cumsum(np.where(a == 1, ys, 0.0))])
    exposure = done + (n_per_arm - d) * ys                 # sum of min(x, x_now)^shape per arm
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = exposure / d                                # MLE of scale^shape per arm
        log_ratio = np.log(mean[0] / mean[1]) / SHAPE
        se = np.sqrt(1.0 / d[0] + 1.0 / d[1]) / SHAPE
    bad = (d[0] == 0) | (d[1] == 0)
    return np.where(bad, np.nan, log_ratio), np.where(bad, np.nan, se)


def naive_declares(log_ratio, se) -> bool:
    """A fixed-sample 95 % test read at every failure: declared at the first |z| >= 1.96."""
    with np.errstate(invalid="ignore"):
        return bool(np.any(np.abs(log_ratio / se) >= 1.959964))


def run_scenario(rng, ratio: float, design, args) -> dict:
    """Counts of each verdict (and the naive declarations) over ``args.trials`` trials."""
    n_per_arm = math.ceil(0.75 * design.failures)
    t = np.arange(1, design.failures + 1) / design.failures
    counts = {"force longer": 0, "distance longer": 0, "no practical difference": 0, "undecided": 0, "naive": 0}
    for _ in range(args.trials):
        est, se = simulate_looks(rng, ratio, n_per_arm, design.failures)
        v = sequential_verdict(est, se, t, args.margin, args.alpha, args.spending)
        counts[v.verdict] += 1
        counts["naive"] += naive_declares(est, se)
    return counts


def _line(label: str, k: int, n: int, target: float, upper: bool) -> bool:
    p = k / n
    se = math.sqrt(max(target * (1 - target), 1e-12) / n)
    ok = p <= target + 2 * se if upper else abs(p - target) <= 0.05
    goal = f"<= {target:.3f} + 2 MC SE ({target + 2 * se:.3f})" if upper else f"{target:.2f} +/- 0.05"
    print(f"  {label:<58} {k:5d}/{n} = {p:.3f} (MC SE {math.sqrt(p * (1 - p) / n):.3f})  target {goal}: "
          f"{'PASS' if ok else 'MISS'}")
    return ok


def run_family(args) -> bool:
    """Every scenario of one spending family; True when all PASS (the naive line is expected to MISS)."""
    t0 = time.perf_counter()
    design = max_information(args.margin, args.alpha, args.power, args.spending, shape=SHAPE)
    c = efficacy_boundaries(np.arange(1, design.failures + 1) / design.failures, args.alpha, args.spending)
    print(f"\n{args.spending}: margin {args.margin}, alpha {args.alpha}, power {args.power}, shape {SHAPE:g}: "
          f"max_failures {design.failures} (fixed sample {design.failures_fixed:.1f}, inflation "
          f"{design.inflation:.4f}), a look at each failure, final boundary z {c[-1]:.3f} "
          f"({time.perf_counter() - t0:.1f} s to design)")
    looks = min(design.failures, DESIGN_LOOKS)   # a look at each failure, as the design's inflation factor
    _, drift = inflation_factor(looks, args.alpha, args.power, args.spending)
    t = np.arange(1, looks + 1) / looks
    direct = crossing_probabilities(efficacy_boundaries(t, args.alpha, args.spending), t, drift)[0].sum()
    ok = abs(direct - args.power) <= 1e-6
    print(f"  power of {looks} looks at the inflation factor's drift {drift:.6f}: {args.power} by the change of "
          f"measure, {direct:.8f} by the recursion run under the drift: {'PASS' if ok else 'MISS'} (within 1e-6)")
    n = args.trials
    h0 = run_scenario(np.random.default_rng(2023), 1.0, design, args)
    ok &= _line("ratio 1: force or distance longer (sequential)", h0["force longer"] + h0["distance longer"],
                n, args.alpha, True)
    _line("ratio 1: declared by the naive 95 % test at every failure", h0["naive"], n, args.alpha, True)
    at = run_scenario(np.random.default_rng(2024), args.margin, design, args)
    ok &= _line("ratio = margin: no practical difference", at["no practical difference"], n, args.alpha, True)
    ok &= _line("ratio = margin: force longer (power)", at["force longer"], n, args.power, False)
    big = run_scenario(np.random.default_rng(2025), args.margin ** 1.5, design, args)
    k = big["force longer"]
    above = k / n >= args.power - 0.05
    print(f"  {'ratio = margin^1.5: force longer':<58} {k:5d}/{n} = {k / n:.3f}  target >= {args.power - 0.05:.2f}: "
          f"{'PASS' if above else 'MISS'}")
    print(f"  ({time.perf_counter() - t0:.1f} s)")
    return ok and above


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_sequential", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="400 trials, O'Brien-Fleming only")
    ap.add_argument("--trials", type=int, default=None, help="trials per scenario (default 2000; 400 quick)")
    ap.add_argument("--margin", type=float, default=1.25)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--power", type=float, default=0.8)
    args = ap.parse_args(argv)
    args.trials = args.trials or (400 if args.quick else 2000)
    families = ("obrien-fleming",) if args.quick else ("obrien-fleming", "pocock")
    ok = True
    for spending in families:
        args.spending = spending
        ok &= run_family(args)
    print(f"\n{'PASS' if ok else 'MISS'}: the sequential verdict keeps its error rates")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
