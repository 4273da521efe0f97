"""Calibration of "The decision" (issue 23): the decision stage's ``life_effect``, ``life_verdict``
and ``decision_looks`` on simulated hose types with a known life ratio, counted against the truth.

One command::

    python -m benchmarks.bench_decision            # 3 scenarios x 460 hose types, the stage in-process (~20 min)
    python -m benchmarks.bench_decision --quick    # 3 scenarios x 12 hose types: a look, no verdict
    python -m benchmarks.bench_decision --rebuild --types 24 --shard 24
                                                   # the end-to-end check: whole `pneubench rebuild` processes

Each scenario is ``decision`` campaigns (:mod:`pipeline.simulator.decision`: hose types known by
their logbook odometer, benches at a constant km/day so that a look's distances are exact,
staggered installations, removed and running hoses, a ``plan.toml`` with margin 1.5, alpha 0.05,
power 0.8, O'Brien-Fleming spending and ``max_failures`` left to the design) in shards of
``--shard`` hose types, each its own raw tree, seeded ``(seed + scenario) * 1000 + shard``. Every
hose type runs until it reaches the ``max_failures`` the decision stage freezes
(:class:`benchmarks.decision_inprocess.StageRunTo`: asked at each failure from the logbook as it
stands; capped at 4 times the closed-form design, counted). By default the shards run in a pool of
``--jobs`` processes, each through the decision stage's own ``run`` in-process
(:mod:`benchmarks.decision_inprocess`: the logbook read and merged, ``hose_life``, the plan, the
freeze at a look, looks in logbook order, odometer-linear distances; equal to the warehouse's rows,
``tests/benchmarks/test_decision_inprocess.py``); ``--rebuild`` runs ``pneubench rebuild`` on each
shard instead (minutes a shard: the durability stage's fits and figures) and reads the warehouse.

* ``life_effect``: the 90 % profile-likelihood interval of the life ratio covers the true ratio,
  and that of the shape the true shape (hose types with a common true shape; those with one shape
  per adjustment are counted apart: their true ratio is the B10 ratio). Target 85-95 %
  (Meeker & Escobar 1998, ch. 8, 17).
* ``life_verdict`` (common true shapes) at ratio 1: ``force longer`` or ``distance longer`` in at
  most alpha of the hose types, i.e. a count within the binomial bound (the 97.5 % quantile of
  Binomial(n, alpha)); the naive fixed-sample test read at every failure (a likelihood-ratio
  p < alpha at any look, from ``decision_look_hoses`` as the look saw the hoses; and the Wald |z|
  of ``decision_looks`` over the fixed-sample z) must fail the same bound (Jennison & Turnbull
  2000, ch. 1-2; Lan & DeMets 1983).
* at ratio = margin: ``no practical difference`` within the same bound; ``force longer`` (the
  decision rate) at the plan's power +/- 5 points with ``max_failures`` as the stage freezes it;
  above the margin (margin^1.5): at least power - 5 points. A miss prints its anatomy (the frozen
  look, its shape against the truth, ``max_failures`` against the design at the true shape).
* the repeated confidence intervals (``rci_lower`` / ``rci_upper``, the profile likelihood's,
  Jennison & Turnbull 2000, ch. 9): the true ratio inside the interval of every designed look
  (failures <= ``max_failures``) of a hose type, in at least 1 - alpha of them (misses within the
  binomial bound); the Wald interval ``log ratio -/+ c_k se`` and the profile interval without the
  Bartlett factor (``D_k <= c_k^2``, session 20's) of the same looks counted beside it; per
  information-fraction bin the looks whose own interval misses against their nominal rate (pointwise
  or multiplicity). ``--bartlett REPS``: the Bartlett factor (:func:`analyses.look_fits.bartlett_factor`)
  against the mean deviance at the truth of simulated complete samples.
* the look distances of ``decision_look_hoses`` against the exact ones (odometer linear in time).

Counts are printed with their Monte Carlo SE. Seeded: the same command prints the same counts.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmarks.proc import measure, pneubench_cmd, verdict

COVERAGE = (0.85, 0.95)
#: Hose types a scenario: about a tenth have one shape per adjustment (counted apart), so that
#: at least 400 with a common true shape remain in each scenario (354-378 of 400 at seed 23).
TYPES = 460
POWER_TOLERANCE = 0.05
SCENARIOS = ("no-difference", "at-margin", "above-margin")
DECISION_TABLES = ("life_effect", "life_verdict", "decision_looks", "decision_look_hoses", "test_plan")
DECISION_STAGES = ("decision", "test_plan")
DECLARED = ("force longer", "distance longer")


class MissingTables(Exception):
    """The warehouse lacks the decision tables (the stages that fill them are not in this build)."""


def read_tables(db: Path) -> dict[str, pd.DataFrame]:
    """The decision tables of a warehouse database, read-only; :class:`MissingTables` naming the
    absent ones when any is missing."""
    import duckdb

    con = duckdb.connect(str(db), read_only=True)
    try:
        have = {r[0] for r in con.execute("SELECT table_name FROM information_schema.tables").fetchall()}
        missing = [t for t in DECISION_TABLES if t not in have]
        if missing:
            raise MissingTables(f"{db} has no {', '.join(missing)}: the decision stages (pipeline/stages/decision.py, "
                                "pipeline/stages/test_plan.py) are not in this build, nothing to calibrate")
        return {t: con.execute(f"SELECT * FROM {t}").df() for t in DECISION_TABLES}
    finally:
        con.close()


def covers(lower: float, upper: float, truth: float) -> bool:
    """Whether [lower, upper] holds ``truth``; a NaN bound is an open side."""
    return (pd.isna(lower) or lower <= truth) and (pd.isna(upper) or truth <= upper)


def coverage(life_effect: pd.DataFrame, types: dict) -> dict:
    """Counts of the intervals covering the truth: ``ratio`` and ``shape`` over hose types with a
    common true shape, ``ratio, separate shapes`` over the others (true B10 ratio); ``n`` of each
    and ``absent`` (no estimate: NULL ratio)."""
    out = {"ratio": [0, 0], "shape": [0, 0], "ratio, separate shapes": [0, 0], "absent": 0}
    for r in life_effect.itertuples(index=False):
        t = types.get(r.hose_type)
        if t is None:
            continue
        if pd.isna(r.life_ratio):
            out["absent"] += 1
            continue
        key = "ratio, separate shapes" if t["separate_shapes"] else "ratio"
        out[key][0] += covers(r.life_ratio_lower, r.life_ratio_upper, t["life_ratio"])
        out[key][1] += 1
        if not t["separate_shapes"] and not pd.isna(r.shape):
            out["shape"][0] += covers(r.shape_lower, r.shape_upper, t["shape"])
            out["shape"][1] += 1
    return out


def verdicts(life_verdict: pd.DataFrame, types: dict) -> dict:
    """Over hose types with a common true shape: how many got each verdict, how many reached their
    ``max_failures`` (as the stage froze it) and how many have none (NULL: no look qualified)."""
    v = life_verdict[life_verdict["hose_type"].map(lambda h: h in types and not types[h]["separate_shapes"])]
    return {"n": len(v), "counts": v["verdict"].value_counts().to_dict(),
            "reached": int((v["failures"] >= v["max_failures"]).sum()), "no_max": int(v["max_failures"].isna().sum())}


def naive_lr_declared(look_hoses: pd.DataFrame, alpha: float, limit: int | None = None) -> tuple[int, int]:
    """(declared, hose types): a fixed-sample likelihood-ratio test of ratio 1 at ``alpha``, read at
    every look from the hoses as the look saw them, declaring at its first p < alpha."""
    from scipy import stats

    crit = stats.chi2.isf(alpha, 1)
    names = sorted(look_hoses["hose_type"].unique())[:limit]
    declared = 0
    by_type = look_hoses[look_hoses["hose_type"].isin(names)].groupby("hose_type")
    for _, hoses in by_type:
        for _, look in hoses.groupby("look", sort=True):
            if lr_statistic(look["distance_km"].to_numpy(float), look["failed"].to_numpy(bool),
                            (look["adjustment"] == "force").to_numpy(int)) > crit:
                declared += 1
                break
    return declared, len(names)


def lr_statistic(life: np.ndarray, failed: np.ndarray, force: np.ndarray) -> float:
    """``2 (loglik(common shape, a scale each) - loglik(one Weibull))`` [-]; NaN when the data
    cannot tell (an adjustment with fewer than two failures)."""
    from scipy import optimize

    from analyses.life_effect import common_shape_fit
    from analyses.service_life import weibull_loglik, weibull_scale_given_shape

    fit = common_shape_fit(life, failed, force)
    if math.isnan(fit.loglik):
        return math.nan
    x = np.maximum(life, 1e-9)

    def neg(logk):
        k = math.exp(logk)
        return -weibull_loglik(k, weibull_scale_given_shape(k, x, failed), x, failed)

    res = optimize.minimize_scalar(neg, bounds=(math.log(1e-2), math.log(1e2)), method="bounded",
                                   options={"xatol": 1e-8})
    return 2.0 * (fit.loglik + res.fun)


def naive_wald_declared(looks: pd.DataFrame, alpha: float) -> tuple[int, int]:
    """(declared, hose types): the Wald z of ``decision_looks`` beyond the fixed-sample
    ``z_{1-alpha/2}`` at any look."""
    from scipy import stats

    z = stats.norm.isf(alpha / 2)
    hit = looks.assign(hit=looks["z"].abs() > z).groupby("hose_type")["hit"].any()
    return int(hit.sum()), len(hit)


def look_distance_error(look_hoses: pd.DataFrame, looks: pd.DataFrame, truth_hoses: dict, km_per_day: float) -> float:
    """Largest |distance at a look - exact distance| [km] over every (look, hose): the exact one
    is ``km_per_day`` x days since installation, up to the hose's end or odometer reading."""
    if look_hoses.empty:
        return math.nan
    hoses = pd.DataFrame([{**t, "hose_id": h} for h, t in truth_hoses.items()])
    hoses["end"] = pd.to_datetime(hoses["ended_at"].fillna(hoses.get("odometer_at")), utc=True)
    hoses["installed"] = pd.to_datetime(hoses["installed_at"], utc=True)
    at = looks[["hose_type", "look", "event_at"]]
    rows = look_hoses.merge(at, on=["hose_type", "look"]).merge(hoses[["hose_id", "installed", "end"]], on="hose_id")
    when = pd.to_datetime(rows["event_at"], utc=True)
    days = (when.where(when < rows["end"], rows["end"]) - rows["installed"]).dt.total_seconds() / 86400.0
    return float(np.abs(rows["distance_km"] - km_per_day * days).max())


def binomial_bound(n: int, p: float) -> int:
    """The largest count of ``n`` trials consistent with a rate ``p``: the 97.5 % quantile of
    Binomial(n, p)."""
    from scipy import stats

    return int(stats.binom.ppf(0.975, n, p))


def line(label: str, k: int, n: int, target: str, ok: bool | None) -> bool:
    """Print one count, its rate and Monte Carlo SE against its target; returns ``ok`` (None: shown,
    not judged)."""
    rate = f"{k / n:.3f} (MC SE {math.sqrt(k / n * (1 - k / n) / n):.3f})" if n else "  n/a"
    mark = "" if ok is None else verdict(ok)
    print(f"  {label:<62} {k:5d}/{n:<5d} = {rate}  target {target} {mark}".rstrip())
    return ok is not False


def rci_coverage(looks: pd.DataFrame, life_verdict: pd.DataFrame, types: dict,
                 ends: tuple[str, str] = ("rci_lower", "rci_upper")) -> dict:
    """Simultaneous coverage of the repeated confidence intervals (``rci_lower`` / ``rci_upper``,
    Jennison & Turnbull 2000, ch. 9): per hose type, whether the true ratio lies in the interval of
    every look that has one, over the designed looks (failures <= ``max_failures``) and over all.
    Counts ``[covered, n]`` for common true shapes (``designed``, ``all looks``) and separate ones
    (``separate shapes``, designed looks, the true B10 ratio); ``none``: types without an interval;
    ``first_miss``: per common-shape type not covered, (failures at its first missing look, at its first
    look with an interval, ``max_failures``). ``ends``: the columns of the interval's ends (the Wald
    interval's, :func:`wald_ends`, to compare)."""
    out = {"designed": [0, 0], "all looks": [0, 0], "separate shapes": [0, 0], "none": 0, "first_miss": []}
    top = dict(zip(life_verdict["hose_type"], life_verdict["max_failures"]))
    has = looks.dropna(subset=list(ends), how="all")
    for h, g in has.groupby("hose_type"):
        t = types.get(h)
        if t is None:
            continue
        inside = [covers(lo, up, t["life_ratio"]) for lo, up in zip(g[ends[0]], g[ends[1]])]
        m = top.get(h)
        designed = all(c for c, f in zip(inside, g["failures"]) if pd.isna(m) or f <= m)
        if not designed and not t["separate_shapes"]:
            out["first_miss"].append((g["failures"].iloc[inside.index(False)], g["failures"].iloc[0], m))
        key = "separate shapes" if t["separate_shapes"] else "designed"
        out[key] = [out[key][0] + designed, out[key][1] + 1]
        if not t["separate_shapes"]:
            out["all looks"] = [out["all looks"][0] + all(inside), out["all looks"][1] + 1]
    out["none"] = sum(h in types for h in set(looks["hose_type"]) - set(has["hose_type"]))
    return out


def wald_ends(looks: pd.DataFrame) -> pd.DataFrame:
    """``looks`` with the Wald repeated interval ``life_ratio * exp(-/+ boundary_z * se_log_ratio)``
    (``wald_lower`` / ``wald_upper``; what ``rci_lower`` / ``rci_upper`` held before the profile
    likelihood's) at the looks that show a repeated interval (a look before the frozen one has a
    boundary and an estimate but decides nothing and shows none); NaN elsewhere."""
    half = looks["boundary_z"].astype(float) * looks["se_log_ratio"].astype(float)
    ratio = looks["life_ratio"].astype(float).where(looks[["rci_lower", "rci_upper"]].notna().any(axis=1))
    return looks.assign(wald_lower=ratio * np.exp(-half), wald_upper=ratio * np.exp(half))


def uncorrected_ends(looks: pd.DataFrame, look_hoses: pd.DataFrame) -> pd.DataFrame:
    """``looks`` with the profile-likelihood repeated interval without the Bartlett factor, ``{theta :
    D_k(theta) <= c_k^2}`` (``prof_lower`` / ``prof_upper``; what ``rci_lower`` / ``rci_upper`` held in
    session 20) at the looks that show a repeated interval, from ``decision_look_hoses``; NaN elsewhere."""
    from analyses.look_fits import profile_rci

    out = looks.assign(prof_lower=math.nan, prof_upper=math.nan)
    shown = looks[["rci_lower", "rci_upper"]].notna().any(axis=1) & looks["boundary_z"].notna()
    hoses = dict(tuple(look_hoses.groupby("hose_type")))
    for h, g in looks[shown].groupby("hose_type"):
        lh = hoses.get(h)
        if lh is None:
            continue
        lo, hi = profile_rci(lh["distance_km"].to_numpy(float), lh["failed"].to_numpy(bool),
                             (lh["adjustment"] == "force").to_numpy(int), lh["look"].to_numpy(np.int64),
                             g["look"].to_numpy(np.int64), g["boundary_z"].to_numpy(float))
        out.loc[g.index, "prof_lower"], out.loc[g.index, "prof_upper"] = np.exp(lo), np.exp(hi)
    return out


#: Information-fraction bins of the pointwise reading (failures / max_failures).
FRACTION_BINS = (0.0, 0.4, 0.6, 0.8, 0.9, 1.0)


def pointwise(looks: pd.DataFrame, life_verdict: pd.DataFrame, types: dict) -> pd.DataFrame:
    """Per information-fraction bin (:data:`FRACTION_BINS`), the designed looks with a repeated interval of
    common-shape hose types: ``looks``, ``misses`` (the true ratio outside that look's interval) and
    ``expected`` (the sum of each look's nominal miss probability ``2 Phi(-c_k sqrt(b_k))``, ``b_k`` the
    Bartlett factor of its failures): a pointwise miss (the look's own level) tells apart from multiplicity."""
    from scipy import stats

    from analyses.look_fits import bartlett_factor

    top = dict(zip(life_verdict["hose_type"], life_verdict["max_failures"]))
    common = looks["hose_type"].map(lambda h: h in types and not types[h]["separate_shapes"])
    frac = looks["failures"] / looks["hose_type"].map(top).astype(float)
    rows = looks[common & looks["rci_lower"].notna() & looks["rci_upper"].notna() & (frac <= 1.0)]
    truth = rows["hose_type"].map(lambda h: types[h]["life_ratio"])
    miss = ~((rows["rci_lower"] <= truth) & (truth <= rows["rci_upper"]))
    z = rows["boundary_z"].to_numpy(float) * np.sqrt(bartlett_factor(rows["failures"].to_numpy(float)))
    out = pd.DataFrame({"bin": pd.cut(frac[rows.index], FRACTION_BINS, include_lowest=True), "miss": miss,
                        "expected": 2.0 * stats.norm.sf(z)})
    return out.groupby("bin", observed=False).agg(looks=("miss", "size"), misses=("miss", "sum"),
                                                  expected=("expected", "sum"))


def bartlett_table(reps: int, seed: int) -> list[tuple[int, int, float, float, float]]:
    """The Bartlett factor against the mean profile deviance at the true ratio of ``reps`` simulated
    complete two-sample Weibull data sets (the pivot ``BARTLETT`` is measured on) per pair of failure
    counts: rows ``(r_distance, r_force, mean D, its MC SE, bartlett_factor(r))``; seeded ``seed``."""
    from analyses.life_effect import ratio_deviance
    from analyses.look_fits import bartlett_factor

    out = []
    for rd, rf in ((5, 5), (5, 15), (8, 8), (7, 20), (10, 10), (15, 15), (10, 30), (20, 20), (30, 30), (15, 45)):
        rng = np.random.default_rng([seed, rd, rf])
        g, f = np.r_[np.zeros(rd, int), np.ones(rf, int)], np.ones(rd + rf, bool)
        d = np.array([ratio_deviance(rng.weibull(2.0, rd + rf), f, g, 1.0) for _ in range(reps)])
        d = d[np.isfinite(d)]
        out.append((rd, rf, float(d.mean()), float(d.std() / math.sqrt(d.size)), float(bartlett_factor(rd + rf))))
    return out


FROZEN = re.compile(r"max_failures frozen at look (\d+) \([^)]*\): designed from that look's common shape ([0-9.]+)")


def anatomy(label: str, rows: pd.DataFrame, types: dict, design_at_truth) -> None:
    """The anatomy of a set of ``life_verdict`` rows (a target's misses): quartiles of the deciding
    look, of ``max_failures`` against the design at the true shape (``design_at_truth(shape)``), of
    the look that froze it and of that look's fitted shape over the true one; how many had a design
    below the frozen look's count (the test ends at that look)."""
    if rows.empty:
        return
    frozen = rows["note"].fillna("").str.extract(FROZEN).astype(float)
    truth = rows["hose_type"].map(lambda h: types[h]["shape"]).astype(float)
    cols = {"decided at look": rows["decided_at_look"].astype(float), "failures": rows["failures"].astype(float),
            "max_failures": rows["max_failures"].astype(float),
            "design at the true shape": truth.map(design_at_truth).astype(float),
            "frozen at look": frozen[0], "frozen shape / true shape": frozen[1].to_numpy() / truth.to_numpy()}
    print(f"    anatomy of {label} ({len(rows)} hose types): quartiles (25 / 50 / 75 %)")
    for name, x in cols.items():
        q = pd.Series(np.asarray(x, float)).dropna().quantile([0.25, 0.5, 0.75]).tolist()
        print(f"      {name:<28} " + (" / ".join(f"{v:.3g}" for v in q) if q else "none"))
    print(f"      max_failures = the freezing look's count (design below it): "
          f"{int((rows['max_failures'].astype(float) == frozen[0]).sum())}; reached max_failures: "
          f"{int((rows['failures'] >= rows['max_failures']).sum())}")


def stage_seconds(stderr: str) -> dict[str, float]:
    """Each stage's time [s] from the rebuild's ``stage <name> ran: ... (3.4 s)`` lines."""
    out = {}
    for name, value, unit in re.findall(r"^stage (\S+) (?:ran|reused): .*\((\d+(?:\.\d+)?) (ms|s)[;)]", stderr, re.M):
        out[name] = float(value) / (1e3 if unit == "ms" else 1.0)
    return out


@dataclass
class Scenario:
    """One simulated and rebuilt campaign: its truth, tables, rebuild time and stage times."""

    name: str
    truth: dict
    tables: dict
    wall_s: float
    stages: dict
    verdicts: dict | None = None
    naive: tuple | None = None   # (declared, hose types) of the naive LR test, when counted in the workers


def _merged(name: str, parts: list[Scenario]) -> Scenario:
    """One scenario from its shards: truths, tables and naive counts pooled, times summed."""
    truth = {**parts[0].truth, "hose_types": {}, "hoses": {}}
    for p in parts:
        truth["hose_types"].update(p.truth["hose_types"])
        truth["hoses"].update(p.truth["hoses"])
    tables = {t: pd.concat([p.tables[t] for p in parts], ignore_index=True) for t in parts[0].tables}
    stages = {n: sum(p.stages.get(n, math.nan) for p in parts) for n in parts[0].stages}
    naive = None if parts[0].naive is None else tuple(np.sum([p.naive for p in parts], axis=0).tolist())
    return Scenario(name, truth, tables, sum(p.wall_s for p in parts), stages, naive=naive)


def _tagged(truth: dict, tables: dict, k: int) -> tuple[dict, dict]:
    """A shard's truth and tables with its hose types and hoses named ``<k>/<name>``."""
    tag = f"{k}/"
    truth["hose_types"] = {tag + h: t for h, t in truth["hose_types"].items()}
    truth["hoses"] = {tag + h: t for h, t in truth["hoses"].items()}
    for t in tables.values():
        for col in ("hose_type", "hose_id"):
            if col in t:
                t[col] = tag + t[col].astype(str)
    return truth, tables


def _shards(name: str, types: int, seed: int, shard: int) -> list[tuple[int, int, int]]:
    """``(k, hose types, seed)`` of each shard of a scenario: shard ``k`` is seeded ``seed * 1000 + k``."""
    return [(k, min(shard, types - k * shard), seed * 1000 + k) for k in range(math.ceil(types / shard))]


def run_scenario(root: Path, name: str, types: int, seed: int, args) -> Scenario:
    """Simulate ``types`` hose types of scenario ``name`` in shards of ``args.shard`` (each its own
    raw tree, rebuilt as a process), read the tables; hose types are named ``<shard>/<type>``."""
    return _merged(name, [_rebuild_shard(root, name, k, n, s, args.jobs) for k, n, s in _shards(name, types, seed,
                                                                                                 args.shard)])


def _rebuild_shard(root: Path, name: str, k: int, types: int, seed: int, jobs: int) -> Scenario:
    """One shard: simulate (each type run to its frozen ``max_failures``), rebuild as a process, read."""
    from benchmarks.decision_inprocess import write_campaign

    raw, wh = root / f"raw-{name}-{k}", root / f"wh-{name}-{k}"
    truth = write_campaign(raw, name, types, seed)
    m = measure([*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--no-report",
                 "--jobs", str(jobs)])
    truth, tables = _tagged(truth, read_tables(wh / "pneubench.duckdb"), k)
    return Scenario(name, truth, tables, m.wall_s, stage_seconds(m.stderr))


def _inprocess_shard(job: tuple) -> Scenario:
    """One shard in a worker: simulate, the decision stage in-process (:mod:`benchmarks.decision_inprocess`),
    and at ratio 1 the naive test over its common-shape types; the raw tree is removed after."""
    import time

    from benchmarks.decision_inprocess import stage_tables, write_campaign

    root, name, k, types, seed, alpha = job
    start = time.process_time()
    raw = root / f"raw-{name}-{k}"
    truth = write_campaign(raw, name, types, seed)
    truth, tables = _tagged(truth, stage_tables(raw), k)
    shutil.rmtree(raw, ignore_errors=True)
    naive = None
    if name == "no-difference":
        common = [h for h, t in truth["hose_types"].items() if not t["separate_shapes"]]
        lh = tables["decision_look_hoses"]
        naive = naive_lr_declared(lh[lh["hose_type"].isin(common)], alpha)
    return Scenario(name, truth, tables, time.process_time() - start, {}, naive=naive)


def run_inprocess(root: Path, names: list[str], types: int, args) -> list[Scenario]:
    """Every scenario's shards in a pool of ``args.jobs`` processes (the decision stage in-process), each
    scenario merged; scenario ``i`` of :data:`SCENARIOS` is seeded ``args.seed + i``."""
    from concurrent.futures import ProcessPoolExecutor

    from pipeline.simulator.decision import DecisionProfile

    alpha = DecisionProfile().alpha
    jobs = [(root, name, k, n, s, alpha) for name in names
            for k, n, s in _shards(name, types, args.seed + SCENARIOS.index(name), args.shard)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        parts = list(pool.map(_inprocess_shard, jobs))
    return [_merged(name, [p for p in parts if p.name == name]) for name in names]


def report_coverage(scenarios: list[Scenario]) -> bool:
    """Coverage of the ratio and shape intervals, per scenario and pooled; True when both PASS."""
    print("\nlife_effect: 90 % intervals covering the truth (target 85-95 %)")
    pooled = {"ratio": [0, 0], "shape": [0, 0], "ratio, separate shapes": [0, 0], "absent": 0}
    for s in scenarios:
        c = coverage(s.tables["life_effect"], s.truth["hose_types"])
        for key in ("ratio", "shape", "ratio, separate shapes"):
            pooled[key] = [a + b for a, b in zip(pooled[key], c[key])]
            line(f"{s.name}: {key}", *c[key], "85-95 %", None)
        pooled["absent"] += c["absent"]
    ok = True
    for key in ("ratio", "shape"):
        k, n = pooled[key]
        ok &= line(f"all scenarios: {key}", k, n, "85-95 %", n > 0 and COVERAGE[0] <= k / n <= COVERAGE[1])
    line("all scenarios: ratio, separate true shapes (B10 ratio; shown)", *pooled["ratio, separate shapes"],
         "85-95 %", None)
    print(f"  hose types without an estimate: {pooled['absent']}")
    return ok


def _common(s: Scenario) -> pd.DataFrame:
    """The scenario's ``life_verdict`` rows of hose types with a common true shape."""
    v, types = s.tables["life_verdict"], s.truth["hose_types"]
    return v[v["hose_type"].map(lambda h: h in types and not types[h]["separate_shapes"])]


def report_verdicts(by_name: dict, settings: dict, naive_types: int) -> bool:
    """The verdict's error rates and decision rate against the targets, the misses' anatomy; True when all PASS."""
    from analyses.sequential import design_for
    from analyses.sequential_information import NoDesign

    alpha, power = settings["alpha"], settings["power"]

    def at_truth(shape):
        try:
            return design_for(settings["margin"], alpha, power, settings["spending"], shape,
                              settings["benches"] // 2).failures
        except NoDesign:
            return math.nan

    ok = True
    print("\nlife_verdict (hose types with a common true shape; a look at every failure; max_failures as frozen)")
    for s in by_name.values():
        v = verdicts(s.tables["life_verdict"], s.truth["hose_types"])
        stopped = pd.Series([t.get("stopped_by") for t in s.truth["hose_types"].values()
                             if not t["separate_shapes"]]).value_counts().to_dict()
        print(f"  {s.name}: {v['n']} hose types, verdicts {dict(sorted(v['counts'].items()))}; reached max_failures "
              f"{v['reached']}/{v['n']} (none frozen: {v['no_max']}); simulation stopped by {stopped}")
        s.verdicts = v
    if "no-difference" in by_name:
        ok &= _report_null(by_name["no-difference"], alpha, naive_types, at_truth)
    if "at-margin" in by_name:
        s = by_name["at-margin"]
        v, rows = s.verdicts, _common(s)
        n, bound = v["n"], binomial_bound(v["n"], alpha)
        k = v["counts"].get("no practical difference", 0)
        if not line("ratio = margin: no practical difference", k, n, f"<= {bound} (alpha {alpha})", k <= bound):
            ok = False
            anatomy("no practical difference at ratio = margin", rows[rows["verdict"] == "no practical difference"],
                    s.truth["hose_types"], at_truth)
        k = v["counts"].get("force longer", 0)
        if not line("ratio = margin: force longer (power)", k, n, f"{power:.2f} +/- {POWER_TOLERANCE:.2f}",
                    n > 0 and abs(k / n - power) <= POWER_TOLERANCE):
            ok = False
            anatomy("force longer at ratio = margin", rows[rows["verdict"] == "force longer"], s.truth["hose_types"],
                    at_truth)
            anatomy("not force longer at ratio = margin", rows[rows["verdict"] != "force longer"],
                    s.truth["hose_types"], at_truth)
        _power_by_design(rows, s.truth["hose_types"], at_truth)   # shown on a PASS too: the design's share
    if "above-margin" in by_name:
        s = by_name["above-margin"]
        k, n = s.verdicts["counts"].get("force longer", 0), s.verdicts["n"]
        if not line("ratio = margin^1.5: force longer", k, n, f">= {power - POWER_TOLERANCE:.2f}",
                    n > 0 and k / n >= power - POWER_TOLERANCE):
            ok = False
            rows = _common(s)
            anatomy("not force longer above the margin", rows[rows["verdict"] != "force longer"],
                    s.truth["hose_types"], at_truth)
    return ok


def _power_by_design(rows: pd.DataFrame, types: dict, at_truth) -> None:
    """The decision rate split by whether the frozen ``max_failures`` reaches the design at the true shape."""
    need = rows["hose_type"].map(lambda h: at_truth(types[h]["shape"])).astype(float)
    enough = rows["max_failures"].astype(float).to_numpy() >= need.to_numpy()
    for label, m in (("max_failures >= the design at the true shape", enough), ("max_failures below it", ~enough)):
        line(f"    force longer when {label}", int((rows["verdict"][m] == "force longer").sum()), int(m.sum()),
             "shown", None)


def _report_null(s: Scenario, alpha: float, naive_types: int, at_truth) -> bool:
    """Ratio 1: the sequential verdict's error rate (PASS/MISS) and the naive readings (must MISS)."""
    n = s.verdicts["n"]
    bound = binomial_bound(n, alpha)
    k = sum(s.verdicts["counts"].get(d, 0) for d in DECLARED)
    ok = line("ratio 1: force or distance longer (sequential)", k, n, f"<= {bound} (alpha {alpha})", k <= bound)
    if not ok:
        rows = _common(s)
        anatomy("declared at ratio 1", rows[rows["verdict"].isin(DECLARED)], s.truth["hose_types"], at_truth)
    common = set(_common(s)["hose_type"])
    if s.naive is not None:
        kl, nl = s.naive
    else:
        lh = s.tables["decision_look_hoses"]
        kl, nl = naive_lr_declared(lh[lh["hose_type"].isin(common)], alpha, naive_types)
    line("ratio 1: naive LR p < alpha at any look (must MISS)", kl, nl, f"<= {binomial_bound(nl, alpha)}",
         kl <= binomial_bound(nl, alpha))
    looks = s.tables["decision_looks"]
    kw, nw = naive_wald_declared(looks[looks["hose_type"].isin(common)], alpha)
    line("ratio 1: naive Wald |z| > z(1-alpha/2) at any look (must MISS)", kw, nw,
         f"<= {binomial_bound(nw, alpha)}", kw <= binomial_bound(nw, alpha))
    return ok


def report_rci(scenarios: list[Scenario], alpha: float) -> bool:
    """Simultaneous coverage of the repeated confidence intervals (nominal 1 - alpha): a type misses
    when any designed look's interval misses the true ratio; PASS when the misses are within the
    binomial bound."""
    print(f"\nrepeated confidence intervals: the true ratio inside every look's interval (nominal {1 - alpha:.2f})")
    pooled = {"designed": [0, 0], "all looks": [0, 0], "separate shapes": [0, 0], "none": 0, "first_miss": []}
    for s in scenarios:
        c = rci_coverage(s.tables["decision_looks"], s.tables["life_verdict"], s.truth["hose_types"])
        pooled["first_miss"] += c["first_miss"]
        for key in ("designed", "all looks", "separate shapes"):
            pooled[key] = [a + b for a, b in zip(pooled[key], c[key])]
        line(f"{s.name}: every designed look covers", *c["designed"], f">= {1 - alpha:.2f}", None)
        pooled["none"] += c["none"]
    k, n = pooled["designed"]
    bound = binomial_bound(n, alpha)
    ok = line("all scenarios: every designed look covers (failures <= max_failures)", k, n,
              f">= {1 - alpha:.2f} (misses <= {bound})", n > 0 and n - k <= bound)
    line("all scenarios: every look covers (also past max_failures; shown)", *pooled["all looks"], "", None)
    if all({"life_ratio", "se_log_ratio", "boundary_z"} <= set(s.tables["decision_looks"]) for s in scenarios):
        wald = [rci_coverage(wald_ends(s.tables["decision_looks"]), s.tables["life_verdict"], s.truth["hose_types"],
                             ("wald_lower", "wald_upper"))["designed"] for s in scenarios]
        line("all scenarios: the Wald interval (log ratio -/+ c_k se) instead (shown)",
             sum(w[0] for w in wald), sum(w[1] for w in wald), "", None)
    if all("decision_look_hoses" in s.tables and "boundary_z" in s.tables["decision_looks"] for s in scenarios):
        prof = [rci_coverage(uncorrected_ends(s.tables["decision_looks"], s.tables["decision_look_hoses"]),
                             s.tables["life_verdict"], s.truth["hose_types"], ("prof_lower", "prof_upper"))["designed"]
                for s in scenarios]
        for s, p in zip(scenarios, prof):
            line(f"{s.name}: without the Bartlett factor (D_k <= c_k^2; shown)", *p, "", None)
        line("all scenarios: the profile interval without the Bartlett factor instead (shown)",
             sum(p[0] for p in prof), sum(p[1] for p in prof), "", None)
    line("all scenarios: separate true shapes, designed looks (B10 ratio; shown)", *pooled["separate shapes"], "",
         None)
    print("  pointwise: designed looks whose own interval misses, against the sum of their nominal miss "
          "probabilities 2 Phi(-c_k sqrt(b_k)), by failures / max_failures")
    for s in scenarios if all("boundary_z" in s.tables["decision_looks"] for s in scenarios) else []:
        pw = pointwise(s.tables["decision_looks"], s.tables["life_verdict"], s.truth["hose_types"])
        print(f"    {s.name}: " + "; ".join(f"{b} {int(r.misses)}/{int(r.looks)} (expected {r.expected:.1f})"
                                          for b, r in pw.iterrows()))
    print(f"  hose types without a repeated interval (no look decides): {pooled['none']}")
    if not ok and pooled["first_miss"]:
        miss = pd.DataFrame(pooled["first_miss"], columns=["at", "first", "max"]).astype(float)
        for name, x in (("failures at the first missing look", miss["at"]),
                        ("... after the first look with an interval", miss["at"] - miss["first"]),
                        ("... as a fraction of max_failures", miss["at"] / miss["max"])):
            q = x.quantile([0.25, 0.5, 0.75]).tolist()
            print(f"    misses ({len(miss)}): {name:<44} " + " / ".join(f"{v:.3g}" for v in q))
        print(f"    misses at the first look with an interval: {int((miss['at'] == miss['first']).sum())}")
    return ok


def report_looks(scenarios: list[Scenario]) -> None:
    """The look distances against the exact ones."""
    for s in scenarios:
        err = look_distance_error(s.tables["decision_look_hoses"], s.tables["decision_looks"], s.truth["hoses"],
                                  s.truth["settings"]["km_per_day"])
        print(f"  {s.name}: largest |look distance - exact| {err:.3g} km over "
              f"{len(s.tables['decision_look_hoses'])} (look, hose) rows")


def report_timing(scenarios: list[Scenario], timing: Scenario | None) -> None:
    """Rebuild times and the decision stages' share (nothing without a rebuild)."""
    if not scenarios and timing is None:
        return
    print("\nrebuild as a process (wall time; decision stages from the rebuild's log)")
    for s in [*scenarios, *([timing] if timing else [])]:
        dec = sum(s.stages.get(n, math.nan) for n in DECISION_STAGES)
        types = len(s.truth["hose_types"])
        print(f"  {s.name} ({types} hose types): rebuild {s.wall_s:.1f} s, decision stages {dec:.1f} s "
              f"({', '.join(f'{n} {s.stages.get(n, math.nan):.1f} s' for n in DECISION_STAGES)})"
              + (f"  target < 10 s: {verdict(dec < 10.0)}" if s is timing else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.bench_decision", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="12 hose types a scenario, no timing run (a look)")
    ap.add_argument("--types", type=int, default=None, help=f"hose types a scenario (default {TYPES}; 12 quick)")
    ap.add_argument("--rebuild", action="store_true",
                    help="whole `pneubench rebuild` processes (the end-to-end check, e.g. --rebuild --types 24) "
                         "instead of the decision stage in-process")
    ap.add_argument("--timing-types", type=int, default=0, help="hose types of a timing rebuild (0: none)")
    ap.add_argument("--naive-types", type=int, default=200, help="hose types the naive LR test reads (--rebuild)")
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--shard", type=int, default=None,
                    help="hose types per raw tree (default 25 in-process, 50 with --rebuild)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the raw trees and warehouses here (--rebuild)")
    ap.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS),
                    help="only these scenarios (each keeps its seed: the same hose types as in a full run)")
    ap.add_argument("--bartlett", type=int, default=0, metavar="REPS",
                    help="only the Bartlett factor against simulated complete samples, REPS a pair of failure counts")
    args = ap.parse_args(argv)
    if args.bartlett:
        print("the profile deviance at the true ratio, complete two-sample Weibull samples: mean (MC SE) "
              "against bartlett_factor(r)")
        for rd, rf, mean, se, b in bartlett_table(args.bartlett, args.seed):
            print(f"  {rd:3d} + {rf:3d} failures: {mean:.3f} ({se:.3f})  b = {b:.3f}  {verdict(abs(mean - b) <= 3 * se)}")
        return 0
    types = args.types or (12 if args.quick else TYPES)
    args.shard = args.shard or (50 if args.rebuild else 25)
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-decision-"))
    root.mkdir(parents=True, exist_ok=True)
    names = [n for n in SCENARIOS if n in args.scenarios]
    start = time.perf_counter()
    try:
        if args.rebuild:
            scenarios = [run_scenario(root, n, types, args.seed + SCENARIOS.index(n), args) for n in names]
        else:
            scenarios = run_inprocess(root, names, types, args)
        one = argparse.Namespace(shard=max(args.timing_types, 1), jobs=args.jobs)   # the timing run: one rebuild
        timing = run_scenario(root, "mixed", args.timing_types, args.seed + 9, one) if args.timing_types else None
    except MissingTables as exc:
        print(f"bench_decision: {exc}", file=sys.stderr)
        return 2
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    settings = scenarios[0].truth["settings"]
    how = "whole rebuilds" if args.rebuild else f"the decision stage in-process, {args.jobs} worker(s)"
    print(f"decision: {types} hose types a scenario ({how}; shards of {args.shard}), seed {args.seed}; plan margin "
          f"{settings['margin']}, alpha {settings['alpha']}, power {settings['power']}, {settings['spending']}, "
          f"max_failures frozen by the stage; {time.perf_counter() - start:.0f} s")
    ok = report_coverage(scenarios)
    ok &= report_verdicts({s.name: s for s in scenarios}, settings, args.naive_types)
    ok &= report_rci(scenarios, settings["alpha"])
    report_looks(scenarios)
    report_timing(scenarios if args.rebuild else [], timing)
    if args.quick:
        print("\n--quick: too few hose types for the targets; counts shown only")
        return 0
    print(f"\n{verdict(ok)}: the decision's intervals and verdicts keep their rates end to end")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
