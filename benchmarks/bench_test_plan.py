"""The test plan checked by brute force (issue 23): failures_needed and power_now against full refits.

One command::

    python -m benchmarks.bench_test_plan               # 7 designs, 300 trials each; power_now case (~35 min, 2 loaded cores)
    python -m benchmarks.bench_test_plan --trials 500 --designs 4 5   # more trials, two designs
    python -m benchmarks.bench_test_plan --quick       # 1 design (4 hoses on test each), 150 trials; a smaller power_now case

1. ``failures_needed`` (:func:`analyses.sequential.max_information`, the design's maximum in
   failures) against the smallest ``max_failures`` that reaches the target power when the design
   is simulated in full: per trial ``n`` benches per adjustment run hoses with Weibull lives of
   the design's common shape and a true force / distance life ratio equal to the margin, a failed
   hose replaced by a new one at once (:func:`bench_lives`); ``n`` is the design's hoses on test
   (``hoses_per_adjustment``, what the stages pass: :func:`analyses.test_plan.hoses_on_test`) or,
   for failures rare among the hoses at risk, :data:`RARE` times the grid's largest ``M`` (no
   replacement comes into play then). At EVERY failure the common-shape Weibull is refitted
   (:func:`analyses.life_effect.common_shape_fit`, the hoses on test censored at their distance
   then) and the design read (:func:`analyses.sequential.sequential_verdict`, ``t = d / M``) with
   the decision stage's likelihood check of each crossing look
   (:func:`analyses.decision.likelihood_check`). Power = share of trials declaring ``force
   longer``. The same trials (common random numbers) serve every ``M`` of a grid around
   ``failures_needed``; the smallest ``M`` whose power reaches the target is compared with
   ``failures_needed``: PASS within 10 % (the issue's target). Also printed: the force-set share
   of the failures (simulated and the design's) and the share of trials declaring ``no practical
   difference`` at ``M = failures_needed`` (the design allows ``alpha / 2``).
2. ``power_now`` (:func:`analyses.test_plan.power_now`, since session 20 its simulated looks read by
   the stage's rule in batches, :mod:`analyses.plan_check`; until then failure counts and the
   canonical z-process) against a full-refit simulation of the same future for one hose type's current
   state, written independently: the remaining lives drawn from the same fitted model, the Weibull refitted at every
   future failure, the same boundaries and decision rule. PASS when the two agree within three
   combined Monte Carlo standard errors.

Figures of the last full run are in docs/decision.md ("Designing from the hoses on test").

Seeded (``numpy.random.default_rng(2300 + design)``): the same numbers every run.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from analyses.decision import crossing_holds
from analyses.life_effect import common_shape_fit, ratio_deviance
from analyses.sequential import max_information, sequential_verdict
from analyses.sequential_boundaries import efficacy_boundaries
from analyses.sequential_information import information_per_failure
from analyses.test_plan import HoseState, power_now, predictive_draws, remaining_km

#: (margin, shape, alpha, power, spending, hoses on test per adjustment): None = failures rare
#: among the hoses at risk, simulated with :data:`RARE` times the grid's largest M benches per
#: adjustment; a number = that many benches each, a failed hose replaced at once (the follow-up
#: the stages design from, passed to ``max_information(hoses_per_adjustment=...)``). The second
#: bench design is bench_decision's plan at its median shape (8 benches: 4 per adjustment).
DESIGNS = [(1.5, 2.0, 0.05, 0.8, "obrien-fleming", None), (1.5, 2.0, 0.05, 0.8, "pocock", None),
           (2.0, 1.5, 0.05, 0.9, "obrien-fleming", None), (1.75, 3.0, 0.10, 0.8, "obrien-fleming", None),
           (1.5, 2.0, 0.05, 0.8, "obrien-fleming", 4), (1.5, 2.5, 0.05, 0.8, "obrien-fleming", 4),
           (2.0, 1.5, 0.05, 0.9, "pocock", 8)]
GRID = (0.8, 0.85, 0.9, 0.95, 1.0, 1.05, 1.1, 1.15, 1.2, 1.3)
RARE = 4
TOLERANCE = 0.10


def bench_lives(rng, margin: float, shape: float, benches: int, failures: int):
    """One trial's hoses on ``benches`` benches per adjustment, each failed hose replaced at once:
    (bench distance at which each hose starts, its life, its adjustment: 1 force-set), enough hoses
    for the first ``failures`` failures."""
    per = failures + 2                      # a bench cannot see more failures than the whole trial
    group = np.repeat([0, 1], benches)
    life = np.where(group[:, None] == 1, margin, 1.0) * rng.weibull(shape, (2 * benches, per))
    start = np.cumsum(life, axis=1) - life
    return start.ravel(), life.ravel(), np.repeat(group, per)


def refit_path(rng, margin: float, shape: float, benches: int, looks: int):
    """(log_ratio, se, adjustment, confirm) refitted at each of the first ``looks`` failures of one
    trial (adjustment 1 where the failure is a force-set hose's) on ``benches`` benches per
    adjustment (:func:`bench_lives`); ``confirm`` is the decision stage's likelihood check of a
    look (:func:`analyses.decision.likelihood_check`'s rule, its deviances computed once per look
    and trial ratio)."""
    start, life, group = bench_lives(rng, margin, shape, benches, looks)
    end = start + life
    order = np.argsort(end)[:looks]

    def state(j: int):
        now = end[order[j]]
        on = start < now
        return np.minimum(life, now - start)[on], (end <= now)[on], group[on]

    est, se = np.full(looks, np.nan), np.full(looks, np.nan)
    for j in range(looks):
        fit = common_shape_fit(*state(j))
        if fit.note is None:
            est[j], se[j] = fit.log_ratio, fit.se_log_ratio
    deviances: dict = {}

    def deviance(j: int, ratio: float) -> float:
        if (j, ratio) not in deviances:
            deviances[j, ratio] = ratio_deviance(*state(j), ratio)
        return deviances[j, ratio]

    def confirm(j: int, crossed: str, c: float) -> bool:
        return crossing_holds(lambda r: deviance(j, r), crossed, c, margin)

    return est, se, group[order], confirm


def brute_force(design, trials: int, seed: int) -> tuple[int, int | None, dict, tuple]:
    """(failures_needed, the smallest M of the grid reaching the power, power per M, (the force-set
    share of the first failures_needed failures, the share the design expects, the share of trials
    declaring ``no practical difference`` at M = failures_needed: the design allows alpha / 2))."""
    margin, shape, alpha, power, spending, hoses = design
    needed = max_information(margin, alpha, power, spending, shape, hoses_per_adjustment=hoses).failures
    grid = sorted({max(4, round(needed * f)) for f in GRID})
    n = hoses or RARE * grid[-1]
    rng = np.random.default_rng(seed)
    paths = [refit_path(rng, margin, shape, n, grid[-1]) for _ in range(trials)]
    powers = {}
    for m in grid:
        t = np.arange(1, m + 1) / m
        wins = sum(sequential_verdict(e[:m], s[:m], t, margin, alpha, spending, confirm=ok).verdict == "force longer"
                   for e, s, _, ok in paths)
        powers[m] = wins / trials
    smallest = next((m for m in grid if powers[m] >= power), None)
    share = float(np.mean([g[:needed].mean() for _, _, g, _ in paths]))
    t = np.arange(1, needed + 1) / needed
    futile = np.mean([sequential_verdict(e[:needed], s[:needed], t, margin, alpha, spending, confirm=ok).verdict
                      == "no practical difference" for e, s, _, ok in paths])
    return needed, smallest, powers, (share, information_per_failure(margin, shape, needed, hoses)[1], float(futile))


def _current_state(rng, margin: float, shape: float, n: int, failures: int):
    """A hose type part way through its test: ``n`` hoses per adjustment, stopped at ``failures``."""
    group = np.repeat([0, 1], n)
    life = np.where(group == 1, margin, 1.0) * 1000.0 * rng.weibull(shape, 2 * n)
    now = np.sort(life)[failures - 1]
    failed = life <= now
    return HoseState(np.minimum(life, now), failed, ~failed, group)


def refit_power(rng, st: HoseState, fit, bounds, margin: float, trials: int) -> float:
    """power_now by full refits: the same future, the Weibull refitted at every future failure; each trial
    draws its own model from the fit's sampling distribution first, as power_now does (predictive)."""
    lm, d0 = math.log(margin), int(st.failed.sum())
    run = np.flatnonzero(st.running)
    looks = min(len(bounds) - d0, run.size)
    left = remaining_km(rng, st.distance[run], st.group[run], predictive_draws(rng, fit, trials), trials)
    decided = 0
    for row in left:
        order = np.argsort(row)
        for j in range(looks):
            elapsed = row[order[j]]
            x = st.distance.copy()
            x[run] = st.distance[run] + np.minimum(row, elapsed)
            failed = st.failed.copy()
            failed[run] = row <= elapsed
            f = common_shape_fit(x, failed, st.group)
            if f.note is not None or not np.isfinite(f.se_log_ratio):
                continue
            half = bounds[d0 + j] * f.se_log_ratio
            if abs(f.log_ratio) > half or abs(f.log_ratio) + half < lm:
                decided += 1
                break
    return decided / trials


def check_power_now(quick: bool) -> bool:
    """Part 2: one hose type's power_now, MC approximation against full refits."""
    margin, shape, alpha, power, spending, _ = DESIGNS[0]
    m = max_information(margin, alpha, power, spending, shape).failures
    n, d0, trials = (20, 14, 100) if quick else (52, 16, 400)
    rng = np.random.default_rng(2399)
    st = _current_state(rng, margin, shape, n, d0)
    fit = common_shape_fit(st.distance, st.failed, st.group)
    bounds = efficacy_boundaries(np.arange(1, m + 1) / m, alpha, spending)
    approx = power_now(st, fit, bounds, margin, 4000, seed=2398)
    full = refit_power(rng, st, fit, bounds, margin, trials)
    se = math.sqrt(approx.mc_se ** 2 + full * (1 - full) / trials)
    ok = abs(approx.power - full) <= 3 * se
    print(f"\npower_now, one hose type: {n} hoses per adjustment, {d0} failures so far, max_failures {m}, "
          f"fitted ratio {math.exp(fit.log_ratio):.2f}, shape {fit.shape:.2f}")
    print(f"  MC (each look read by the stage's rule, {approx.n_simulations}): {approx.power:.3f} +/- {approx.mc_se:.3f}")
    print(f"  full refit at every future failure, predictive ({trials}): {full:.3f} +/- "
          f"{math.sqrt(full * (1 - full) / trials):.3f}")
    print(f"  difference {approx.power - full:+.3f} (3 combined MC SE {3 * se:.3f}): {'PASS' if ok else 'MISS'}")
    return ok


def main(argv=None) -> int:
    args = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    args.add_argument("--quick", action="store_true", help="one design, fewer trials (a few seconds)")
    args.add_argument("--trials", type=int, default=300, help="trials a design (default 300)")
    args.add_argument("--designs", type=int, nargs="+", default=None,
                      help=f"only these designs (indices 0-{len(DESIGNS) - 1} of DESIGNS; each keeps its seed)")
    parsed = args.parse_args(argv)
    quick = parsed.quick
    picked = parsed.designs if parsed.designs is not None else ([4] if quick else range(len(DESIGNS)))
    trials = 150 if quick else parsed.trials
    t0 = time.monotonic()
    ok = True
    print(f"failures_needed against brute force ({trials} trials a design, a full refit at every failure):")
    print(f"{'margin':>6} {'shape':>5} {'alpha':>5} {'power':>5} {'spending':>14} {'hoses':>5} {'needed':>6} "
          f"{'brute':>5} {'diff':>6} {'force':>5} {'exp.':>5} {'npd':>5}  power at each M")
    print("  (hoses: on test per adjustment, failed ones replaced; rare = failures rare; force: share of force-set failures, exp.: the design's; "
          "npd: 'no practical difference' declared at M = needed, the design allows alpha / 2)")
    for i in picked:
        design = DESIGNS[i]
        needed, smallest, powers, (share, expected, futile) = brute_force(design, trials, 2300 + i)
        good = smallest is not None and abs(needed - smallest) <= TOLERANCE * smallest
        ok &= good
        diff = f"{(needed - smallest) / smallest:+.0%}" if smallest else "n/a"
        curve = " ".join(f"{m}:{p:.2f}" for m, p in powers.items())
        print(f"{design[0]:>6} {design[1]:>5} {design[2]:>5} {design[3]:>5} {design[4]:>14} {design[5] or 'rare':>5} "
              f"{needed:>6} {smallest if smallest else '>grid':>5} {diff:>6} {share:>5.2f} {expected:>5.2f} "
              f"{futile:>5.2f}  {curve}  {'PASS' if good else 'MISS'}")
    ok &= check_power_now(quick)
    print(f"\n{'PASS' if ok else 'MISS'} ({time.monotonic() - t0:.0f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
