"""Calibration of the life effect's intervals (``analyses.life_effect``), by simulation from known truth.

One command::

    python -m benchmarks.bench_life_effect            # 480 simulated hose types (about a minute)
    python -m benchmarks.bench_life_effect --quick    # 40 hose types, a few seconds (a look, no verdict)

Each simulated hose type has 8 to 15 hoses per adjustment, a true Weibull shape drawn from 1.5
to 3 (the same for both adjustments), a distance-set scale of 5,000 km and a force-set scale of
``ratio`` times that (half the types at ratio 1.0, half at 1.5), and Type I censoring: every
hose still running at a test distance at which 60 to 95 % of the distance-set hoses fail is a
suspension. Each type is fitted with :func:`analyses.life_effect.life_effect` at 90 %
confidence and ``alpha`` 0.05 (the plan's defaults), and counted:

* ``ratio``: the reported ``life_ratio`` interval (common or separate shapes, as ``model``
  says) covers the true ratio; ``ratio, common shape`` and ``ratio, separate shapes``: the same,
  split by the ``model`` the shape test chose (the true shapes are equal: ``separate shapes`` is
  the shape test's false alarms, whose intervals are conditioned on data that look unlike the truth);
* ``shape``: the common shape's interval covers the true shape;
* the same for Wald (Fisher-matrix) intervals on the log scale from the observed information
  (:func:`analyses.life_effect.common_shape_fit`), for comparison.

A bound the data do not reach (NaN, an open side) counts as covering on that side. Hose types
whose fit is NaN (an adjustment with fewer than two failures) are counted and left out. Target
(issue 23): coverage between 85 and 95 % over at least 400 hose types, for the ratio and the
shape. Seeded (``--seed``): the same command prints the same counts.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

TARGET = (0.85, 0.95)
SCALE_KM = 5000.0


def simulate(rng: np.random.Generator, ratio: float) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray]:
    """(truth, life [km], failed, group) of one hose type."""
    shape = rng.uniform(1.5, 3.0)
    n_d, n_f = rng.integers(8, 16, size=2)
    censor = SCALE_KM * (-math.log1p(-rng.uniform(0.60, 0.95))) ** (1.0 / shape)
    t = np.r_[SCALE_KM * rng.weibull(shape, n_d), ratio * SCALE_KM * rng.weibull(shape, n_f)]
    group = np.r_[np.zeros(n_d, int), np.ones(n_f, int)]
    return {"ratio": ratio, "shape": shape}, np.minimum(t, censor), t <= censor, group


def covers(lower: float, upper: float, truth: float) -> bool:
    """Whether [lower, upper] holds ``truth``; a NaN bound is an open side."""
    return (math.isnan(lower) or lower <= truth) and (math.isnan(upper) or truth <= upper)


def assess(truth: dict, life, failed, group, z: float) -> dict | None:
    """Coverage flags of one hose type (None when the data cannot tell)."""
    from analyses.life_effect import COMMON, common_shape_fit, life_effect

    r = life_effect(life, failed, group, confidence=0.90, alpha=0.05)
    if math.isnan(r.life_ratio):
        return None
    fit = common_shape_fit(life, failed, group)
    se_shape = math.sqrt(fit.cov[2, 2])
    ratio = covers(r.life_ratio_lower, r.life_ratio_upper, truth["ratio"])
    return {
        "ratio": ratio,
        "ratio, common shape": ratio if r.model == COMMON else None,
        "ratio, separate shapes": None if r.model == COMMON else ratio,
        "shape": covers(r.shape_lower, r.shape_upper, truth["shape"]),
        "ratio, Wald": covers(math.exp(fit.log_ratio - z * fit.se_log_ratio),
                              math.exp(fit.log_ratio + z * fit.se_log_ratio), truth["ratio"]),
        "shape, Wald": covers(fit.shape * math.exp(-z * se_shape), fit.shape * math.exp(z * se_shape), truth["shape"]),
        "separate": r.model != COMMON,
        "open": math.isnan(r.life_ratio_lower) or math.isnan(r.life_ratio_upper),
    }


def run(types: int, seed: int) -> list[dict]:
    """Assess ``types`` hose types, half at ratio 1.0 and half at 1.5, each from its own seed."""
    from scipy.stats import norm

    z = float(norm.ppf(0.95))
    out = []
    for i in range(types):
        rng = np.random.default_rng([seed, i])
        truth, life, failed, group = simulate(rng, 1.0 if i % 2 == 0 else 1.5)
        row = assess(truth, life, failed, group, z)
        if row is not None:
            row["true_ratio"] = truth["ratio"]
        out.append(row)
    return out


def report(rows: list[dict], verdicts: bool) -> bool:
    """Print the counts per interval; True when every profile-likelihood figure is within the target."""
    fitted = [r for r in rows if r is not None]
    print(f"hose types: {len(rows)} simulated, {len(fitted)} fitted, {len(rows) - len(fitted)} NaN (an "
          f"adjustment with < 2 failures); separate shapes used in {sum(r['separate'] for r in fitted)}, "
          f"an open ratio bound in {sum(r['open'] for r in fitted)}")
    ok = len(fitted) >= 400
    print(f"{'interval (90 % nominal)':<26} {'true ratio 1.0':>16} {'true ratio 1.5':>16} {'all':>16}  verdict")
    for name in ("ratio", "ratio, common shape", "ratio, separate shapes", "shape", "ratio, Wald", "shape, Wald"):
        cells, total = [], [0, 0]
        for sub in ([r for r in fitted if r["true_ratio"] == 1.0], [r for r in fitted if r["true_ratio"] == 1.5],
                    fitted):
            flags = [r[name] for r in sub if r[name] is not None]
            cells.append(f"{sum(flags)}/{len(flags)} {100 * sum(flags) / max(len(flags), 1):5.1f} %")
            total = [sum(flags), len(flags)]
        rate = total[0] / max(total[1], 1)
        profile = name in ("ratio", "shape")
        within = TARGET[0] <= rate <= TARGET[1]
        verdict = ("PASS" if within else "MISS") if verdicts and profile else ("(comparison)" if verdicts else "")
        ok &= within or not profile
        print(f"{name:<26} {cells[0]:>16} {cells[1]:>16} {cells[2]:>16}  {verdict}")
    return ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_life_effect", description=__doc__.splitlines()[0])
    ap.add_argument("--types", type=int, default=480, help="simulated hose types (default 480)")
    ap.add_argument("--seed", type=int, default=23, help="seed of the simulation (default 23)")
    ap.add_argument("--quick", action="store_true", help="40 hose types: a look in a few seconds, no verdict")
    args = ap.parse_args(argv)
    types = 40 if args.quick else args.types
    print(f"life_effect calibration: {types} hose types, seed {args.seed}, target {TARGET[0]:.0%}-{TARGET[1]:.0%} "
          "coverage of 90 % intervals over >= 400 fitted types")
    ok = report(run(types, args.seed), verdicts=not args.quick)
    return 0 if ok or args.quick else 1


if __name__ == "__main__":
    sys.exit(main())
