"""decision_sensitivity's verdict at no true difference: its error rate per failure definition (issues 23, 24).

One command::

    python -m benchmarks.bench_sensitivity             # 400 simulated hose types (~3.5 min; 14 on heavily loaded cores)
    python -m benchmarks.bench_sensitivity --quick     # 20 hose types, a look (seconds)
    python -m benchmarks.bench_sensitivity --every 200 # leak tests every 200 km instead of 40

``decision_sensitivity`` reads the decision's rule once per failure definition (the logbook's
failures; the leak path's first crossing of the plan's limit, at 0.5x and 2x that limit, a hose
that never crosses censored at its last plateau): the sequential boundary at the definition's
``failures / max_failures`` with the profile-likelihood check
(:func:`pipeline.stages.remaining_life.read_once`, the stage's own function, on the stage's lives
:func:`pipeline.stages.remaining_life.definition_lives`). Read once, not at every failure, it is
a fixed-sample test at a boundary no lower than the final one, so at a true life ratio of 1 it
should declare ``force longer`` or ``distance longer`` in at most ``alpha`` of the hose types.

The hose types: the remaining-life benchmark's wear generator
(:func:`benchmarks.bench_remaining_life.simulate_type`: 40 hoses, lognormal wear rate, leak
``(w d)^1.5`` measured every ``--every`` km with path and sensor noise, failure at the first
crossing of 2 l/min or by rupture, staggered campaign ends; hoses alive then run on), each hose
force- or distance-set at random, 20 each: the two adjustments are one population, the true
ratio is 1 under every definition. The crossing lives are lognormal, not Weibull: the stage reads
the leak definitions under the common-sigma lognormal (:data:`pipeline.stages.remaining_life.LEAK_MODEL`,
docs/decision.md "The sensitivity's life model"), the logbook's under the common-shape Weibull. The plan's limit is
:data:`PLAN_LIMIT` (half the failure leak: the 2x definition is the logbook's leak failures);
``max_failures`` is :data:`MAX_FAILURES` (``--max-failures``), so most definitions are read at the
final boundary, the least conservative reading (fewer failures: an earlier, higher boundary).

Two controls say why a definition misses, not counted against the stage: the 1x definition with
each hose's true crossing (no plateaus, no noise, censored where the hose left the test), and
40 complete lives of one population read by the same rule, lognormal (the crossing lives' law,
the generator's log sd) and Weibull of the same log-life sd (:func:`control`); each read under
both life models (:data:`READS`), so a row says what a model's misspecification costs. Also
counted: how often each model's profile interval at :data:`CONFIDENCE` holds the true ratio 1.

Counted per definition: the share declaring a longer life (PASS when the count is within the
one-sided 95 % binomial bound of ``alpha``), ``no practical difference``, ``undecided``, and
those left without a verdict (no failure, or a fit the data cannot tell). Seeded:
``numpy.random.default_rng([seed, type])``.

References: Jennison, C. & Turnbull, B. W. (2000), Group Sequential Methods, ch. 2 and 7; Meeker,
W. Q. & Escobar, L. A. (1998), Statistical Methods for Reliability Data, sec. 8.3 (likelihood
intervals) and ch. 13 (degradation); Lu, C. J. & Meeker, W. Q. (1993), Technometrics 35, 161-174.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
import pandas as pd
from scipy import stats

from analyses.decision import GROUP
from analyses.life_effect import ratio_deviance
from analyses.life_effect_lognormal import lognormal_ratio_deviance
from benchmarks.bench_remaining_life import GAMMA, HOSES, LIMIT, WEAR_CV, simulate_type
from pipeline.stages.remaining_life import DEFINITIONS, LEAK_MODEL, definition_lives, definition_model, read_once

#: The plan: margin, alpha, spending (read_once's keys).
PLAN = {"margin": 1.5, "alpha": 0.05, "spending": "obrien-fleming"}
#: The plan's max_failures (both adjustments) [-]: below the median failures of every definition, so
#: most types are read at the final boundary (the least conservative reading).
MAX_FAILURES = 16
#: The plan's leak limit [l/min]: half the generator's failure leak, so the 2x definition is the
#: logbook's leak failures and the 0.5x and 1x ones cross before a hose is taken off.
PLAN_LIMIT = LIMIT / 2
LONGER = ("force longer", "distance longer")
#: The leak-limit definition with each hose's true crossing (no plateau, no noise), a control.
EXACT = "leak limit, exact crossing"
#: The controls of :func:`control`.
CONTROLS = ("lognormal", "weibull")
#: The life models the exact crossing and the controls are read under: (label, read_once's model).
READS = (("Weibull", None), ("lognormal", LEAK_MODEL))
#: Confidence of the life-ratio intervals whose coverage of the true ratio (1) is counted [-].
CONFIDENCE = 0.90


def one_type(rng, every_km: float, max_failures: int = MAX_FAILURES) -> dict:
    """The verdict of each failure definition on one simulated hose type at a true ratio of 1."""
    hoses, points, truth = simulate_type(rng, every_km)
    hoses = hoses.assign(adjustment=rng.permutation(np.repeat(["distance", "force"], HOSES // 2)))
    out = {}
    for name, factor in DEFINITIONS:
        lives, _ = definition_lives(hoses, points, None if factor is None else PLAN_LIMIT * factor)
        out[name] = _read(lives, max_failures, definition_model(factor))
    exact = PLAN_LIMIT ** (1.0 / GAMMA) / truth["wear"]          # the true crossing, no plateau, no noise
    seen = hoses["distance_km"].to_numpy(float)
    lives = hoses[["hose_id", "adjustment"]].assign(distance_km=np.minimum(exact, seen), failed=exact <= seen)
    for label, model in READS:
        out[f"{EXACT} ({label})"] = _read(lives, max_failures, model)
    return out


def _read(lives: pd.DataFrame, max_failures: int, model: str | None) -> tuple[str, int, float]:
    """(the verdict read once under ``model``, or 'no failure'; the failures; whether the model's
    profile interval at :data:`CONFIDENCE` holds the true ratio 1, NaN when it cannot be made)."""
    sv, _ = read_once(lives, max_failures, PLAN, model)
    args = (lives["distance_km"].to_numpy(float), lives["failed"].to_numpy(bool),
            lives["adjustment"].map(GROUP).to_numpy(int))
    dev = lognormal_ratio_deviance(*args, 1.0) if model == LEAK_MODEL else ratio_deviance(*args, 1.0)
    covers = float(dev < stats.chi2.ppf(CONFIDENCE, 1)) if math.isfinite(dev) else math.nan
    return "no failure" if sv is None else sv.verdict, int(lives["failed"].sum()), covers


def control(rng, kind: str, model: str | None, max_failures: int = MAX_FAILURES) -> tuple[str, int, float]:
    """The same rule on 20 + 20 complete lives of one population: ``lognormal`` with the
    generator's log sd (the crossing lives' law), or ``weibull`` of the shape whose log-life sd is
    the same (``pi / (k sqrt 6)``), read under ``model`` (:data:`READS`): the cost of a life
    model's misspecification alone."""
    s_log = math.sqrt(math.log1p(WEAR_CV ** 2))
    n = HOSES
    life = (np.exp(s_log * rng.standard_normal(n)) if kind == "lognormal"
            else rng.weibull(math.pi / (s_log * math.sqrt(6.0)), n))
    lives = pd.DataFrame({"hose_id": [f"h{i:02d}" for i in range(n)],
                          "adjustment": np.repeat(["distance", "force"], n // 2), "distance_km": 1000.0 * life,
                          "failed": np.ones(n, bool)})
    return _read(lives, max_failures, model)


def bound(n: int, alpha: float) -> int:
    """The largest count of ``n`` declarations a true rate of ``alpha`` gives with probability at
    least 5 % (one-sided binomial bound)."""
    return int(stats.binom.ppf(0.95, n, alpha))


def run(types: int, every_km: float, seed: int, max_failures: int = MAX_FAILURES) -> pd.DataFrame:
    """One row per (hose type, definition): ``verdict``, ``failures``."""
    rows = []
    for t in range(types):
        for name, (verdict, failures, covers) in one_type(np.random.default_rng([seed, t]), every_km,
                                                          max_failures).items():
            rows.append({"type": t, "definition": name, "verdict": verdict, "failures": failures, "covers": covers})
        for kind in CONTROLS:
            for label, model in READS:     # the same lives under both models: the same seed
                verdict, failures, covers = control(np.random.default_rng([seed, t, 1 + CONTROLS.index(kind)]), kind,
                                                    model, max_failures)
                rows.append({"type": t, "definition": f"control: {kind} ({label})", "verdict": verdict,
                             "failures": failures, "covers": covers})
    return pd.DataFrame(rows).assign(max_failures=max_failures)


def report(df: pd.DataFrame) -> bool:
    """Print the counts per definition; True when every definition's longer-life count is within the bound."""
    alpha, ok = PLAN["alpha"], True
    print(f"{df['type'].nunique()} hose types x {HOSES} hoses, true ratio 1; max_failures {df['max_failures'].iloc[0]}, "
          f"margin {PLAN['margin']}, alpha {alpha}, {PLAN['spending']}; read once (decision_sensitivity's rule)")
    print(f"  {'definition':>38} {'failures':>12} {'longer':>14} {'bound':>5} {'npd':>6} {'undecided':>9} {'none':>5} "
          f"{'covers':>7}")
    extra = [f"{EXACT} ({label})" for label, _ in READS] + [f"control: {k} ({label})" for k in CONTROLS
                                                             for label, _ in READS]
    for name in [d for d, _ in DEFINITIONS] + extra:
        g = df[df["definition"] == name]
        read = g[g["verdict"] != "no failure"]
        n, longer = len(read), int(read["verdict"].isin(LONGER).sum())
        good = longer <= bound(n, alpha)
        ok &= good or name not in dict(DEFINITIONS)
        print(f"  {name:>38} {g['failures'].median():>5.0f} median {longer:>4}/{n} = {longer / max(n, 1):5.1%} "
              f"{bound(n, alpha):>5} {(read['verdict'] == 'no practical difference').mean():6.1%} "
              f"{(read['verdict'] == 'undecided').mean():9.1%} {len(g) - n:>5} {g['covers'].mean():7.1%}  "
              f"{'PASS' if good else 'MISS'}")
    print("  (longer: 'force longer' or 'distance longer' declared; bound: the one-sided 95 % binomial bound at "
          "alpha; npd: 'no practical difference'; none: no failure under the definition; the exact crossing and "
          "the two controls (40 complete lives of one population) are not the stage's, they tell why, each read "
          f"under both life models; covers: share of the model's {CONFIDENCE:.0%} profile interval holding the true "
          "ratio 1, the logbook's the common-shape one; the leak definitions are read under "
          f"{LEAK_MODEL!r})")
    return ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20 hose types (seconds)")
    ap.add_argument("--types", type=int, default=400, help="hose types (default 400)")
    ap.add_argument("--every", type=float, default=40.0, help="km between leak tests (default 40)")
    ap.add_argument("--seed", type=int, default=2424)
    ap.add_argument("--max-failures", type=int, default=MAX_FAILURES, help=f"the plan's (default {MAX_FAILURES})")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    ok = report(run(20 if args.quick else args.types, args.every, args.seed, args.max_failures))
    print(f"\n{'PASS' if ok else 'MISS'} ({time.monotonic() - t0:.0f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
