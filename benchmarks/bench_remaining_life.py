"""Calibration of the remaining-life predictions (``analyses.remaining_life``) from known futures.

One command::

    python -m benchmarks.bench_remaining_life            # 20 hose types, 40 hoses each (~2-3 min)
    python -m benchmarks.bench_remaining_life --quick    # 1 hose type (a look, no verdict)
    python -m benchmarks.bench_remaining_life --design rupture   # the rupture model alone, 0-1 ruptures (~1 min)
    python -m benchmarks.bench_remaining_life --design rupture --rupture-shape 2   # with the shape stated

Its own generator (independent of the pipeline's simulator): each simulated hose type has 40
hoses; hose ``i`` wears at a rate ``w_i`` drawn from a lognormal (mean :data:`WEAR_MEAN` [1/km],
coefficient of variation :data:`WEAR_CV`); its true leak is ``(w_i d)^GAMMA`` l/min at distance
``d``, measured by a leakage run every ``--every`` km with a multiplicative path noise (log sd
:data:`PATH_NOISE`) and additive sensor noise (:data:`SENSOR`, quantised to its resolution). It
fails when its leak crosses :data:`LIMIT` (a last leakage run at the failure reads the leak then)
or earlier by rupture (Weibull :data:`RUPTURE`). The campaign ends for each hose at a distance
drawn uniformly from 200 to 1,600 km (staggered starts): hoses alive then are running. Truth:
every hose's failure distance, also for the running ones.

Counted, at the 90 % level:

* ``coverage``: per method, the fraction of running hoses whose true failure distance lies in
  their interval (target: within 7 points of 90 %, over at least 300 running hoses);
* ``backtest``: per method, the pooled coverage of :func:`rul_backtest` (target: within 10 points
  of the running hoses' coverage);
* ``wear rate``: the degradation model's mean and standard deviation of the wear rate, the median
  over hose types against the truth (target: within 15 %), and how often one type is within 15 %;
* ``narrower``: the median over running hoses with both intervals of degradation width / weibull
  width (target: <= 0.70, i.e. at least 30 % narrower with frequent leak tests).

A hose without a prediction (NaN) is counted and left out. Seeded (``--seed``): the same command
prints the same counts.

``--design rupture`` counts the rupture part of the joint model on its own: the groups of the ``rul``
design (:func:`simulate_rul_type`) that logged zero or one rupture, whose rupture shape the data cannot
tell (:func:`analyses.remaining_life.rupture_model`): without ``--rupture-shape`` the union of the
Weibayes intervals over the shapes from 1 to the logbook Weibull shape's upper bound
(:func:`analyses.life_posterior.rul_over_shapes`), with it the Weibayes at that shape (the plan's
``rupture_shape``). Per running hose, the prediction interval of its remaining distance to rupture
(``weibull_rul`` of those models) against the hose's true rupture distance (latent for most: the leak
ends them first), under two truths of the rupture life (:data:`RUPTURE_TRUTHS`): the ``rul`` design's
wear-out Weibull and a constant hazard with the same expected ruptures in the campaign. Target: within
7 points of 90 % over at least 300 running hoses, as for the methods; the union is conservative by
construction (it holds for the worst shape in its range), so its target is at least 83 %, and its
width is printed against the constant hazard's (the Weibayes at shape 1, the model before the union).
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np
import pandas as pd

#: Growth exponent of the leak with distance. [-]
GAMMA = 1.5
#: Leak limit. [l/min]
LIMIT = 2.0
#: Mean wear rate [1/km] and its coefficient of variation across hoses [-].
WEAR_MEAN, WEAR_CV = 1.6e-3, 0.35
#: Log-scale standard deviation of a measured leak around the hose's path. [-]
PATH_NOISE = 0.10
#: Leak sensor: resolution and noise. [l/min]
SENSOR = (0.001, 0.005)
#: Rupture life: Weibull (shape, scale [km]).
RUPTURE = (2.0, 2000.0)
HOSES = 40
CONFIDENCE = 0.90


def simulate_type(rng: np.random.Generator, every_km: float) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """(hoses, leak points, truth) of one hose type; truth: ``life_km`` per hose and the wear rates."""
    s_log = math.sqrt(math.log1p(WEAR_CV ** 2))
    w = WEAR_MEAN * np.exp(s_log * rng.standard_normal(HOSES) - s_log ** 2 / 2)
    crossing = LIMIT ** (1.0 / GAMMA) / w
    rupture = RUPTURE[1] * rng.weibull(RUPTURE[0], HOSES)
    truth = np.minimum(crossing, rupture)
    end = rng.uniform(200.0, 1600.0, HOSES)
    failed = truth <= end
    hoses = pd.DataFrame({"hose_id": [f"h{i:02d}" for i in range(HOSES)], "distance_km": np.minimum(truth, end),
                          "status": np.where(failed, "failed", "running"),
                          "failure_mode": np.where(~failed, None, np.where(crossing <= rupture, "leakage", "rupture"))})
    rows = []
    res, noise = SENSOR
    for i in range(HOSES):
        d = np.arange(every_km, hoses["distance_km"].iloc[i], every_km)
        if failed[i] and crossing[i] <= rupture[i]:
            d = np.append(d, truth[i])
        true = (w[i] * d) ** GAMMA
        meas = true * np.exp(PATH_NOISE * rng.standard_normal(d.size)) + noise * rng.standard_normal(d.size)
        rows += [(f"h{i:02d}", x, y) for x, y in zip(d, np.round(meas / res) * res)]
    points = pd.DataFrame(rows, columns=["hose_id", "distance_km", "leak_l_min"])
    return hoses, points, {"life_km": truth, "wear": w}


#: Truths of the rupture life in the ``rul`` design [median crossings]: draws ``(rng, n)``. ``wear-out``:
#: the design's Weibull(2, 3); ``constant``: an exponential whose mean (10.9) gives the same expected
#: cumulative hazard at the mean campaign end 0.825, ``(0.825 / 3)^2 = 0.825 / 10.9``.
RUPTURE_TRUTHS = {"wear-out": lambda rng, n: 3.0 * rng.weibull(2.0, n),
                  "constant": lambda rng, n: 10.9 * rng.exponential(1.0, n)}


def simulate_rul_type(rng: np.random.Generator, every_km: float,
                      rupture=RUPTURE_TRUTHS["wear-out"]) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """As :func:`simulate_type`, with the design of the simulator's ``rul`` profile in units of the
    type's median crossing (``--design rul``): 25 hoses, wear CV uniform over 0.25-0.45, checks
    every ``every_km`` / 200 median crossings (0.2 by default), rupture Weibull(2, 3 median
    crossings), campaign ends 0.6-1.05 median crossings, flow meter 0.001 / 0.002 l/min. The
    hoses have seen only the early failures: the case where the life model extrapolates. ``rupture``
    draws the rupture lives (:data:`RUPTURE_TRUTHS`); truth also holds every hose's ``rupture_km``."""
    n, cv = 25, rng.uniform(0.25, 0.45)
    s_log = math.sqrt(math.log1p(cv ** 2))
    w = LIMIT ** (1.0 / GAMMA) * np.exp(s_log * rng.standard_normal(n))   # median crossing 1
    crossing, rupture = LIMIT ** (1.0 / GAMMA) / w, rupture(rng, n)
    truth, end = np.minimum(crossing, rupture), rng.uniform(0.6, 1.05, n)
    failed = truth <= end
    hoses = pd.DataFrame({"hose_id": [f"h{i:02d}" for i in range(n)], "distance_km": np.minimum(truth, end),
                          "status": np.where(failed, "failed", "running"),
                          "failure_mode": np.where(~failed, None, np.where(crossing <= rupture, "leakage", "rupture"))})
    rows = []
    for i in range(n):
        d = np.arange(every_km / 200.0, hoses["distance_km"].iloc[i], every_km / 200.0)
        if failed[i] and crossing[i] <= rupture[i]:
            d = np.append(d, truth[i])
        meas = (w[i] * d) ** GAMMA * np.exp(0.075 * rng.standard_normal(d.size)) + 0.002 * rng.standard_normal(d.size)
        rows += [(f"h{i:02d}", x, y) for x, y in zip(d, np.round(meas / 0.001) * 0.001)]
    points = pd.DataFrame(rows, columns=["hose_id", "distance_km", "leak_l_min"])
    return hoses, points, {"life_km": truth, "wear": w, "leak_first": crossing <= rupture, "rupture_km": rupture}


def _running_outcomes(rul: pd.DataFrame, hoses: pd.DataFrame, truth: dict) -> pd.DataFrame:
    true_of = dict(zip(hoses["hose_id"], truth["life_km"]))
    mode = dict(zip(hoses["hose_id"], np.where(truth.get("leak_first", np.ones(len(hoses), bool)),
                                               "leakage", "rupture")))
    r = rul.assign(truth_km=[true_of[h] for h in rul["hose_id"]], mode=[mode[h] for h in rul["hose_id"]])
    ok = r["rul_median_km"].notna()
    rem = r["truth_km"] - r["distance_km"]
    below, above = ok & (rem < r["rul_lower_km"]), ok & (rem > r["rul_upper_km"])
    return r.assign(made=ok, covered=ok & ~below & ~above, below=below, above=above,
                    width=r["rul_upper_km"] - r["rul_lower_km"])


def run(types: int, every_km: float, seed: int, design=None) -> tuple[pd.DataFrame, pd.DataFrame, list]:
    """Simulate (``design``: :func:`simulate_type` by default) and predict ``types`` hose types;
    (running outcomes, backtest rows, wear-rate estimates)."""
    from analyses.leak_degradation import degradation_fit, leak_crossing_lives
    from analyses.quality import Sensor
    from analyses.remaining_life import RulSettings
    from analyses.remaining_life_group import remaining_life, rul_backtest

    settings = RulSettings(limit_l_min=LIMIT, sensor=Sensor(*SENSOR, source="metadata"), confidence=CONFIDENCE)
    outcomes, backtests, wear = [], [], []
    for t in range(types):
        hoses, points, truth = (design or simulate_type)(np.random.default_rng([seed, t]), every_km)
        rul = remaining_life(hoses, points, settings, seed=seed * 1000 + t)
        outcomes.append(_running_outcomes(rul, hoses, truth).assign(hose_type=t, adjustment="-"))
        backtests.append(rul_backtest(hoses, points, settings, seed=seed * 1000 + t).assign(hose_type=t))
        fit = degradation_fit(points, settings.sensor)
        crossed = leak_crossing_lives(points, LIMIT)
        wear.append((*fit.wear_rate(), int(crossed["crossed"].sum())))
    return pd.concat(outcomes, ignore_index=True), pd.concat(backtests, ignore_index=True), wear


def rupture_outcomes(groups: int, every_km: float, seed: int, truth: str,
                     shape: float | None = None) -> tuple[pd.DataFrame, int]:
    """The rupture model's intervals in the ``rul`` design's groups that logged at most one rupture
    (``truth``: a key of :data:`RUPTURE_TRUTHS`; ``shape``: the plan's ``rupture_shape``, None: not
    known): per running hose its group, ``ruptures`` logged, ``distance_km``, the interval of its
    remaining distance to rupture (``rul_*_km``), the constant hazard's (``const_lower_km``,
    ``const_upper_km``) and ``rupture_left_km`` (the truth); and how many of the ``groups`` simulated
    logged at most one."""
    from analyses.life_posterior import rul_over_shapes, weibayes_posterior, weibull_rul
    from analyses.remaining_life import rupture_model

    rows, kept = [], 0
    k_truth = list(RUPTURE_TRUTHS).index(truth)
    for g in range(groups):
        hoses, _, tr = simulate_rul_type(np.random.default_rng([seed, 7000 + g, k_truth]), every_km,
                                         RUPTURE_TRUTHS[truth])
        life, failed = hoses["distance_km"].to_numpy(float), (hoses["status"] == "failed").to_numpy()
        other = failed & (hoses["failure_mode"] == "rupture").to_numpy()
        if other.sum() > 1:
            continue
        kept += 1
        posts, _ = rupture_model(life, failed, other, shape, CONFIDENCE, seed=seed * 1000 + g)
        const = weibayes_posterior(life, other, 1.0, seed=seed * 1000 + g)
        for i in np.flatnonzero(hoses["status"] == "running"):
            q, _ = rul_over_shapes(lambda p: weibull_rul(p, life[i], CONFIDENCE), posts)
            c, _ = weibull_rul(const, life[i], CONFIDENCE)
            rows.append((g, int(other.sum()), life[i], *q, c[1], c[2], tr["rupture_km"][i] - life[i]))
    cols = ["group", "ruptures", "distance_km", "rul_median_km", "rul_lower_km", "rul_upper_km", "const_lower_km",
            "const_upper_km", "rupture_left_km"]
    return pd.DataFrame(rows, columns=cols), kept


def rupture_report(out: pd.DataFrame, kept: int, groups: int, truth: str, quick: bool, union: bool = False) -> bool:
    """Print the rupture model's coverage (all running hoses, by ruptures logged, one hose a group)
    and widths, and PASS/MISS; True when within 7 points of the nominal level over at least 300
    hoses (``union``: at least 7 points below it, the union being conservative by construction)."""
    made = out[out["rul_median_km"].notna()]
    below = made["rupture_left_km"] < made["rul_lower_km"]
    above = made["rupture_left_km"] > made["rul_upper_km"]
    covered = ~below & ~above
    cov = float(covered.mean()) if len(made) else math.nan
    ok = len(made) >= 300 and (cov >= CONFIDENCE - 0.07 if union else abs(cov - CONFIDENCE) <= 0.07)
    target = f">= {100 * (CONFIDENCE - 0.07):g} (a union)" if union else f"{100 * CONFIDENCE:g} +- 7"
    print(f"rupture model, {truth} truth: {kept} of {groups} groups logged 0-1 ruptures; running hoses {len(out)}, "
          f"with an interval {len(made)}, covered {int(covered.sum())} = {100 * cov:.1f} % ({int(below.sum())} below "
          f"the lower end, {int(above.sum())} above the upper; target {target}, >= 300 hoses)  "
          f"{_verdict(ok, quick)}")
    width, const = made["rul_upper_km"] - made["rul_lower_km"], made["const_upper_km"] - made["const_lower_km"]
    print(f"{'':4s}width [median crossings]: median {width.median():.3g} (constant hazard {const.median():.3g}); "
          f"per hose width / constant hazard's: median {(width / const).median():.2f}, "
          f"lower end / constant's {(made['rul_lower_km'] / made['const_lower_km']).median():.2f}, "
          f"upper end / constant's {(made['rul_upper_km'] / made['const_upper_km']).median():.2f}")
    for r in (0, 1):
        sel = made["ruptures"] == r
        print(f"{'':4s}{r} rupture{'s' if r != 1 else ''} logged: {int(sel.sum())} hoses, covered "
              f"{100 * float(covered[sel].mean()) if sel.any() else math.nan:.1f} %, below {int(below[sel].sum())}, "
              f"above {int(above[sel].sum())}")
    first = ~made.duplicated("group")
    n1, c1 = int(first.sum()), int(covered[first].sum())
    half = 1.96 * math.sqrt(max(c1 * (n1 - c1), 1) / n1 ** 3) if n1 else math.nan
    print(f"{'':4s}one hose a group (independent): {c1} / {n1} = {100 * c1 / max(n1, 1):.1f} % "
          f"(+- {100 * half:.1f}, 95 %)")
    return ok


def misses(made: pd.DataFrame) -> None:
    """Where one method's intervals miss (:func:`benchmarks.bench_rul_e2e.misses`)."""
    from benchmarks.bench_rul_e2e import misses as split

    split(made)


def _verdict(ok: bool, quick: bool) -> str:
    return "(quick: no verdict)" if quick else ("PASS" if ok else "MISS")


def report(outcomes: pd.DataFrame, backtests: pd.DataFrame, wear: list, quick: bool, own_wear: bool = True) -> bool:
    """Print the counts and PASS/MISS; True when every target is met."""
    from analyses.remaining_life_group import backtest_summary

    all_ok = True
    summary = backtest_summary(backtests).set_index("method")
    for method in ("weibull", "degradation"):
        o = outcomes[outcomes["method"] == method]
        made = o[o["made"]]
        cov = float(made["covered"].mean()) if len(made) else math.nan
        ok = len(made) >= 300 and abs(cov - CONFIDENCE) <= 0.07
        all_ok &= ok
        print(f"{method:12s} running hoses: {len(o)}, with an interval {len(made)}, "
              f"covered {int(made['covered'].sum())} = {100 * cov:.1f} % "
              f"(nominal {100 * CONFIDENCE:g} +- 7, >= 300 hoses)  {_verdict(ok, quick)}")
        misses(made)
        b = summary.loc[method]
        ok_b = b["n_predictions"] > 0 and abs(b["coverage"] - cov) <= 0.10
        all_ok &= ok_b
        print(f"{'':12s} backtest: {b['n_predictions']} predictions, coverage {100 * b['coverage']:.1f} %, "
              f"median abs error {b['median_abs_error_km']:.3g} km "
              f"(within 10 points of {100 * cov:.1f} %)  {_verdict(ok_b, quick)}")
    if not own_wear:
        print("wear rate: not this generator's (--design rul): bench_rul_e2e checks it against the simulator's truth")
        return all_ok
    s_log = math.sqrt(math.log1p(WEAR_CV ** 2))
    true_sd = WEAR_MEAN * math.sqrt(math.expm1(s_log ** 2))
    est = np.array([(m, s) for m, s, _ in wear], float)
    est = est[np.isfinite(est).all(axis=1)]
    for j, (name, truth) in enumerate((("mean", WEAR_MEAN), ("sd", true_sd))):
        rel = est[:, j] / truth - 1.0
        ok = len(rel) > 0 and abs(float(np.median(est[:, j])) / truth - 1.0) <= 0.15
        all_ok &= ok
        print(f"wear rate {name:4s}: truth {truth:.3g} 1/km, median estimate {np.median(est[:, j]):.3g} "
              f"over {len(rel)} types ({100 * np.mean(np.abs(rel) <= 0.15):.0f} % of types within 15 %)  "
              f"{_verdict(ok, quick)}")
    both = outcomes[outcomes["made"]].pivot_table(index=["hose_type", "hose_id"], columns="method", values="width")
    both = both.dropna()
    ratio = float(np.median(both["degradation"] / both["weibull"])) if len(both) else math.nan
    ok = ratio <= 0.70
    print(f"narrower: degradation / weibull interval width, median over {len(both)} running hoses with both: "
          f"{ratio:.2f} (target <= 0.70)  {_verdict(ok, quick)}")
    print(f"leak-limit crossings seen in the leak paths: {sum(c for *_, c in wear)}")
    return all_ok and ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 hose type: a look, no verdict")
    ap.add_argument("--types", type=int, default=20, help="simulated hose types of 40 hoses")
    ap.add_argument("--every", type=float, default=40.0, help="km between a hose's leakage runs")
    ap.add_argument("--seed", type=int, default=24)
    ap.add_argument("--design", choices=("default", "rul", "rupture"), default="default",
                    help="rul: the simulator's rul profile in units of a median crossing (simulate_rul_type); "
                         "its wear-rate truth is not this bench's, so those lines do not apply; rupture: the "
                         "rupture model of groups with 0-1 ruptures alone, --groups of that design per truth")
    ap.add_argument("--groups", type=int, default=600, help="--design rupture: groups simulated per truth")
    ap.add_argument("--rupture-shape", type=float, default=None,
                    help="--design rupture: the rupture shape stated (the plan's rupture_shape); default: not known")
    a = ap.parse_args(argv)
    if a.design == "rupture":
        return _rupture_main(20 if a.quick else a.groups, a.every, a.seed, a.quick, a.rupture_shape)
    types = 1 if a.quick else a.types
    t0 = time.perf_counter()
    outcomes, backtests, wear = run(types, a.every, a.seed, simulate_rul_type if a.design == "rul" else None)
    what = (f"{HOSES} hoses, leak test every {a.every:g} km" if a.design == "default" else
            f"25 hoses (the rul profile's design, distances in median crossings), leak test every {a.every / 200:g}")
    print(f"{types} hose types x {what}, seed {a.seed} ({time.perf_counter() - t0:.0f} s)")
    ok = report(outcomes, backtests, wear, a.quick, own_wear=a.design == "default")
    return 0 if ok or a.quick else 1


def _rupture_main(groups: int, every_km: float, seed: int, quick: bool, shape: float | None = None) -> int:
    """``--design rupture``: :func:`rupture_report` under each of :data:`RUPTURE_TRUTHS`."""
    t0 = time.perf_counter()
    results = []
    for truth in RUPTURE_TRUTHS:
        out, kept = rupture_outcomes(groups, every_km, seed, truth, shape)
        results.append((out, kept, truth))
    model = ("the union over shapes 1 to the logbook's upper bound (rupture_shape not known)" if shape is None
             else f"the Weibayes at the stated rupture_shape {shape:g}")
    print(f"{groups} groups a truth x 25 hoses (the rul design), seed {seed}, {model} ({time.perf_counter() - t0:.0f} s)")
    ok = all([rupture_report(out, kept, groups, truth, quick, shape is None) for out, kept, truth in results])
    return 0 if ok or quick else 1


if __name__ == "__main__":
    sys.exit(main())
