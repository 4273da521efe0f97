"""Calibration of the service-life table's profile-likelihood bounds, by simulation from known truth.

One command::

    python -m benchmarks.bench_service_life              # 2 x 300 simulated hose groups (about a minute)
    python -m benchmarks.bench_service_life --seed 5 6   # other draws, a line per seed
    python -m benchmarks.bench_service_life --quick      # 2 x 25 groups, a few seconds (a look, no verdict)

Each simulated group is what the durability stage fits per (hose_type, adjustment): hoses with
Weibull lives, Type I censored (every hose still running at the test's end is a suspension),
in two scenarios:

* ``small``: 10 hoses, shape 2.0, scale 1,000 km, the test stopped at the true 70 % quantile
  (about 7 failures: Abernethy's median-rank-regression range);
* ``medium``: 30 hoses, shape 1.5, scale 1,000 km, stopped at the true 60 % quantile (about 18
  failures).

Each group is summarised with :func:`analyses.service_life.service_life_summary` at the plan's
defaults (90 % two-sided, B10) and a mission at the true 20 % quantile (true R = 0.80), and
counted: the shape, scale, B10 and R(mission) intervals each cover the truth. A bound the data
do not reach (NaN, an open side) counts as covering on that side; a group whose fit is NaN
(fewer than two failures) is counted and left out. Target: coverage between 85 and 95 % for each
of the four over all groups, in every seed given. Also printed, for the choice of
``preferred_method``: the median (over groups) of shape / true shape for MLE and MRR, the
small-sample bias Abernethy's rule is about. Seeded (``--seed``): the same command prints the
same counts.
"""
from __future__ import annotations

import argparse
import math

import numpy as np

TARGET = (0.85, 0.95)
NOMINAL = 0.90
SCALE_KM = 1000.0
#: name -> (hoses, true shape, fraction of the population failed when the test stops)
SCENARIOS = {"small": (10, 2.0, 0.70), "medium": (30, 1.5, 0.60)}
PARAMETERS = ("shape", "scale", "b_life", "reliability")
MISSION_F = 0.20


def quantile(shape: float, p: float) -> float:
    """The true p-quantile [km]."""
    return SCALE_KM * (-math.log1p(-p)) ** (1.0 / shape)


def simulate(rng: np.random.Generator, n: int, shape: float, stop_f: float) -> tuple[np.ndarray, np.ndarray]:
    """(life [km], failed) of one group: Weibull lives Type I censored at the true ``stop_f`` quantile."""
    t = SCALE_KM * rng.weibull(shape, n)
    stop = quantile(shape, stop_f)
    return np.minimum(t, stop), t <= stop


def covers(lower: float, upper: float, truth: float) -> bool:
    """Whether [lower, upper] holds ``truth``; a NaN bound is an open side."""
    return (math.isnan(lower) or lower <= truth) and (math.isnan(upper) or truth <= upper)


def assess(life, failed, shape: float) -> dict | None:
    """Coverage flags of one group (None when the fit is NaN) and its two shape estimates' ratios to the truth."""
    from analyses.service_life import service_life_summary

    mission = quantile(shape, MISSION_F)
    s = service_life_summary(life, failed, b_life_pct=10.0, confidence=NOMINAL, mission=mission)
    if not math.isfinite(s["shape"]):
        return None
    truth = {"shape": shape, "scale": SCALE_KM, "b_life": quantile(shape, 0.10), "reliability": 1.0 - MISSION_F}
    out = {name: covers(s[f"{name}_lower"], s[f"{name}_upper"], truth[name]) for name in PARAMETERS}
    out["open"] = any(math.isnan(s[f"{name}_{side}"]) for name in PARAMETERS for side in ("lower", "upper"))
    out["mle_bias"] = s["shape"] / shape
    out["mrr_bias"] = s["mrr_shape"] / shape
    return out


def run(groups: int, seed: int) -> dict[str, list]:
    """Assess ``groups`` groups per scenario, each group from its own seed."""
    out = {}
    for j, (name, (n, shape, stop_f)) in enumerate(SCENARIOS.items()):
        rows = []
        for i in range(groups):
            rng = np.random.default_rng([seed, j, i])
            rows.append(assess(*simulate(rng, n, shape, stop_f), shape))
        out[name] = rows
    return out


def report(results: dict[str, list], verdicts: bool) -> dict:
    """Print the counts per parameter and scenario; the coverage of each parameter [-] and ``ok``."""
    every = [r for rows in results.values() for r in rows]
    fitted = [r for r in every if r is not None]
    print(f"groups: {len(every)} simulated, {len(fitted)} fitted, {len(every) - len(fitted)} NaN (< 2 failures); "
          f"an open bound in {sum(r['open'] for r in fitted)}")
    heads = list(results) + ["all"]
    print(f"{'interval (90 % nominal)':<24} " + " ".join(f"{h:>18}" for h in heads) + "  verdict")
    rates, ok = {}, True
    for name in PARAMETERS:
        cells = []
        for rows in [[r for r in rows if r is not None] for rows in results.values()] + [fitted]:
            hits = sum(r[name] for r in rows)
            cells.append(f"{hits}/{len(rows)} {100 * hits / max(len(rows), 1):5.1f} %")
        rate = rates[name] = sum(r[name] for r in fitted) / len(fitted) if fitted else float("nan")
        within = TARGET[0] <= rate <= TARGET[1]
        ok &= within
        print(f"{name:<24} " + " ".join(f"{c:>18}" for c in cells) + f"  {('PASS' if within else 'MISS') if verdicts else ''}")
    for key, label in (("mle_bias", "MLE shape / true"), ("mrr_bias", "MRR shape / true")):
        meds = [float(np.median([r[key] for r in rows if r is not None])) for rows in results.values()]
        print(f"{label + ' (median)':<24} " + " ".join(f"{m:>18.3f}" for m in meds))
    return {**rates, "ok": ok}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_service_life", description=__doc__.splitlines()[0])
    ap.add_argument("--groups", type=int, default=300, help="simulated groups per scenario (default 300)")
    ap.add_argument("--seed", type=int, nargs="+", default=[17], help="seed(s) of the simulation (default 17)")
    ap.add_argument("--quick", action="store_true", help="25 groups per scenario: a look in seconds, no verdict")
    args = ap.parse_args(argv)
    groups = 25 if args.quick else args.groups
    ok = True
    for seed in args.seed:
        print(f"service_life calibration: {groups} groups per scenario, seed {seed}, target "
              f"{TARGET[0]:.0%}-{TARGET[1]:.0%} coverage of {NOMINAL:.0%} intervals")
        ok &= report(run(groups, seed), verdicts=not args.quick)["ok"]
    if not args.quick:
        print(f"every seed within {TARGET[0]:.0%}-{TARGET[1]:.0%} for shape, scale, B10 and R(mission): "
              f"{'PASS' if ok else 'MISS'}")
    return 0 if ok or args.quick else 1


if __name__ == "__main__":
    raise SystemExit(main())
