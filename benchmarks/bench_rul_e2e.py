"""End-to-end calibration of the remaining-life predictions (issue 24): the simulator's ``rul``
campaign, rebuilt by ``pneubench rebuild`` as a process, predicted from the warehouse, compared
with the simulator's truth.

One command::

    python -m benchmarks.bench_rul_e2e            # 12 hose types x 2 adjustments x 25 hoses, ~4,800 runs
    python -m benchmarks.bench_rul_e2e --quick    # 1 hose type of 10 hoses (a look, no verdict)
    python -m benchmarks.bench_rul_e2e --control  # the life model alone on known life laws (~1-2 min)

The campaign (:mod:`pipeline.simulator.rul`): every hose a degradation path (lognormal wear rate,
leak ``(w d)^1.5`` at the pressure it sealed new, read by a leakage check after every short
durability run) and a Weibull rupture; it fails at the first of its leak crossing the plan's limit
and its rupture; the hoses still on their benches at the campaign's end are ``running``, and the
truth holds their failure distance. The rebuild places each check at its hose's distance
(``hose_leak_growth``) and its ``remaining_life`` stage writes ``hose_rul`` and ``rul_backtest``
per (hose type, adjustment): :func:`stage_tables` reads them as a user would.

Counted, at the plan's confidence (90 %):

* ``coverage``: per method, the share of running hoses whose true remaining life lies in their
  interval (target: within 7 points of nominal, over at least 300 running hoses with an interval);
* ``backtest``: per method, ``rul_backtest.coverage`` pooled over the groups (weighted by
  ``n_predictions``; target: within 10 points of the running hoses' coverage);
* ``wear rate``: the degradation model's mean and standard deviation of the wear rate per
  (hose type, adjustment) against the truth: the median ratio over the groups within 15 %;
* ``narrower``: the median over running hoses with both intervals of degradation width / weibull
  width (target: <= 0.70);
* ``demo``: the time the analyses take on the demo's hoses (its durability campaigns simulated
  and rebuilt, or ``--demo-warehouse``), target under 5 s.

A hose without a prediction (NULL, with its note) is counted and left out. Seeded (``--seed``).

``--control``: the ``weibull`` method's life model alone (:func:`analyses.life_posterior.life_model`,
no rebuild) on the ``rul`` design in units of the median life (25 hoses a group, the campaign ending
for each hose at 0.6-1.05: the groups have seen only their early failures) under three life laws:
Weibull lives (shape 4), lognormal lives (sigma 0.35) and the simulator's competing risks (a
lognormal leak crossing, sigma 0.35, and a Weibull(2, 3) rupture, the first of the two). Per law and
per rule: the Weibull alone, the family with the larger maximised log-likelihood, and the
evidence-weighted mixture the method uses (:class:`analyses.life_posterior.LifeModel`); the running
hoses' coverage (target 90 +- 7) and the median width.
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd

from benchmarks.proc import measure, pneubench_cmd

CONFIDENCE_DEFAULT = 0.90
#: Hose types simulated: the rul profile's 10 leave about 270 running hoses with a degradation
#: interval (the others NULL, with their notes); 12 give the 300 the count needs. [-]
TYPES = 12


# -- what the remaining_life stage wrote ---------------------------------------------------------
def stage_tables(con) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The ``remaining_life`` stage's ``hose_rul`` and ``rul_backtest`` rows, as the rebuild wrote them."""
    return (con.sql("SELECT * FROM hose_rul ORDER BY hose_type, hose_id, method").df(),
            con.sql("SELECT * FROM rul_backtest ORDER BY hose_type, adjustment, method").df())


def stage_in_process(db: Path, raw: Path, jobs: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``hose_rul`` and ``rul_backtest`` as the ``remaining_life`` stage's ``run`` makes them, called in this
    process on the inputs it declares, read from the rebuilt warehouse (``--in-process``: a change to
    the models measured without a rebuild, whose ingest and other stages it would not change)."""
    from pipeline.stages import StageContext
    from pipeline.stages import remaining_life as stage

    with duckdb.connect(str(db), read_only=True) as con:
        results = {t: con.sql(f"SELECT * FROM {t}").df() for t in stage.READS.tables}
    out = stage.run(StageContext(raw=raw, warehouse=db.parent, runs=pd.DataFrame(), results=results, jobs=jobs,
                                 plan=read_plan(raw)))
    return (out.tables["hose_rul"].sort_values(["hose_type", "hose_id", "method"], ignore_index=True),
            out.tables["rul_backtest"].sort_values(["hose_type", "adjustment", "method"], ignore_index=True))


def wear_rates(con, plan) -> pd.DataFrame:
    """Per (hose type, adjustment), the degradation model's wear-rate mean and spread [1/km] and
    growth exponent, fitted on the points the stage fitted (its own :func:`leak_paths` and
    :func:`leak_sensor`; the tables do not carry the wear-rate distribution)."""
    from analyses.quality import Sensor
    from analyses.leak_degradation import degradation_fit
    from pipeline.stages.remaining_life import leak_paths, leak_sensor

    life = con.sql("SELECT hose_id, hose_type, adjustment FROM hose_life ORDER BY hose_id").df()
    growth = con.sql("SELECT hose_id, run_id, distance_km, chamber, pressure_bar, leak_l_min FROM hose_leak_growth").df()
    sensors = con.sql("SELECT DISTINCT run_id, sensors FROM leakage_map").df()
    rows = []
    for (htype, adj), hoses in life.groupby(["hose_type", "adjustment"], sort=True):
        s = plan.for_hose_type(htype)
        if s.leak_limit_l_min is None or s.leak_pressure_bar is None:
            continue
        of_type = life.loc[life["hose_type"] == htype, "hose_id"]
        pts, _ = leak_paths(growth[growth["hose_id"].isin(of_type)], float(s.leak_pressure_bar))
        pts = pts[pts["hose_id"].isin(hoses["hose_id"])]
        sensor = leak_sensor(sensors.loc[sensors["run_id"].isin(pts["run_id"]), "sensors"].tolist())
        if sensor is None:
            continue
        fit = degradation_fit(pts[["hose_id", "distance_km", "leak_l_min"]], Sensor(*sensor))
        rows.append({"hose_type": htype, "adjustment": adj,
                     **dict(zip(("wear_mean_per_km", "wear_sd_per_km"), fit.wear_rate())), "gamma": fit.gamma})
    return pd.DataFrame(rows)


# -- the campaign, rebuilt ------------------------------------------------------------------------
def build(root: Path, profile, seed: int, jobs: int, campaigns: tuple | None = None) -> tuple[Path, dict, float]:
    """Simulate ``profile`` under ``root/raw`` and rebuild it as a process: (warehouse database,
    truth, rebuild seconds)."""
    from pipeline.simulator.campaign import simulate_campaign

    raw, wh = root / "raw", root / "wh"
    if (raw / "truth.json").exists():   # --keep of an earlier run: its campaign, rebuilt incrementally
        print(f"{raw}: simulated before (--keep), not again")
    else:
        simulate_campaign(raw, seed=seed, profile=profile, jobs=jobs, campaigns=campaigns)
    m = measure([*pneubench_cmd(), "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--no-report",
                 "--jobs", str(jobs), "-q"], check=False)
    if m.exit_code != 0:
        raise SystemExit(f"rebuild of {raw} failed ({m.exit_code}): {m.stderr[-2000:]}")
    return wh / "pneubench.duckdb", json.loads((raw / "truth.json").read_text()), m.wall_s


def read_plan(raw: Path):
    """The campaign's plan.toml as the rebuild reads it."""
    from pipeline.raw.plan import read_plan as read
    from pipeline.raw.tree import RawTree

    return read(RawTree(raw.resolve()))


# -- the life model on known life laws (--control) -----------------------------------------------
#: Life laws of the control: name -> lives of ``n`` hoses in units of the median life.
CONTROL_LAWS = {
    "Weibull lives (shape 4)": lambda rng, n: rng.weibull(4.0, n) / math.log(2.0) ** 0.25,
    "lognormal lives (sigma 0.35)": lambda rng, n: np.exp(0.35 * rng.standard_normal(n)),
    "competing: lognormal crossing, Weibull(2, 3) rupture": lambda rng, n: np.minimum(
        np.exp(0.35 * rng.standard_normal(n)), 3.0 * rng.weibull(2.0, n)),
}


def control_group(rng: np.random.Generator, law, confidence: float) -> pd.DataFrame:
    """One simulated group of 25 hoses under ``law``: per running hose and rule (``weibull only``,
    ``better fit``, ``mixture``) whether its interval held its true remaining life, and its width."""
    from analyses.life_posterior import life_model, weibull_rul

    n = 25
    truth, end = law(rng, n), rng.uniform(0.6, 1.05, n)
    life, failed = np.minimum(truth, end), truth <= end
    model = life_model(life, failed, seed=int(rng.integers(2 ** 31)))
    better = max(model.families, key=lambda p: p.fit.loglik if p.ok else -math.inf)
    rules = {"weibull only": model.families[0], "better fit": better, "mixture": model}
    rows = []
    for i in np.flatnonzero(~failed):
        for rule, post in rules.items():
            q, _ = weibull_rul(post, float(life[i]), confidence)
            rem = truth[i] - life[i]
            rows.append({"rule": rule, "made": bool(np.isfinite(q).all()), "covered": bool(q[1] <= rem <= q[2]),
                         "width": q[2] - q[1], "lognormal_better": better.family == "lognormal"})
    return pd.DataFrame(rows)


def control(groups: int, seed: int, confidence: float = CONFIDENCE_DEFAULT) -> bool:
    """Print the control's coverage per life law and rule; True when the mixture is within 7 points
    of nominal under every law (over at least 300 running hoses)."""
    ok = True
    for k, (name, law) in enumerate(CONTROL_LAWS.items()):
        t0 = time.perf_counter()
        out = pd.concat([control_group(np.random.default_rng([seed, k, g]), law, confidence)
                         for g in range(groups)], ignore_index=True)
        print(f"{name}: {groups} groups of 25, {len(out) // 3} running hoses ({time.perf_counter() - t0:.0f} s); "
              f"the lognormal fits better in {100 * out['lognormal_better'].mean():.0f} % of them")
        for rule, g in out.groupby("rule", sort=False):
            made = g[g["made"]]
            cov = float(made["covered"].mean())
            good = len(made) >= 300 and abs(cov - confidence) <= 0.07
            ok &= good or rule != "mixture"
            print(f"    {rule:13s} with an interval {len(made):4d}, covered {int(made['covered'].sum()):4d} = "
                  f"{100 * cov:5.1f} %, median width {made['width'].median():.3f} median lives"
                  + (f"  {'PASS' if good else 'MISS'}" if rule == "mixture" else ""))
    return ok


# -- counting -------------------------------------------------------------------------------------
def running_outcomes(rul: pd.DataFrame, truth_hoses: dict) -> pd.DataFrame:
    """The running hoses' predictions with their true remaining life [km]: ``made``, ``covered``,
    ``width``, ``below`` (the truth under the lower end), ``above`` (over the upper end), ``mode``
    (how the simulator ends the hose: leakage or rupture)."""
    r = rul.assign(truth_km=[truth_hoses[h]["failure_km"] for h in rul["hose_id"]],
                   mode=[truth_hoses[h].get("failure_mode_true", "?") for h in rul["hose_id"]])
    ok = r["rul_median_km"].notna()
    rem = r["truth_km"] - r["distance_km"]
    below, above = ok & (rem < r["rul_lower_km"]), ok & (rem > r["rul_upper_km"])
    return r.assign(made=ok, covered=ok & ~below & ~above, below=below, above=above,
                    width=r["rul_upper_km"] - r["rul_lower_km"])


def misses(made: pd.DataFrame) -> None:
    """Print where one method's intervals miss: the truth below the lower end or above the upper end,
    by quartile of the distance now relative to its group's median (the groups wear at different
    rates) and by the simulator's failure mode."""
    rel = made["distance_km"] / made.groupby(["hose_type", "adjustment"])["distance_km"].transform("median")
    parts = [(f"distance now / group median, quartile {q + 1}", g)
             for q, g in made.groupby(pd.qcut(rel.rank(method="first"), 4, labels=False), sort=True)]
    parts += [(f"ends by {mode}", g) for mode, g in made.groupby("mode", sort=True)]
    for label, g in parts:
        print(f"{'':14s}{label:44s} {len(g):4d} hoses: covered {int(g['covered'].sum()):4d} "
              f"({100 * g['covered'].mean():5.1f} %), truth below the lower end {int(g['below'].sum()):3d}, "
              f"above the upper end {int(g['above'].sum()):3d}")


def line(label: str, ok: bool, quick: bool) -> bool:
    print(f"{label}  {'(quick: no verdict)' if quick else ('PASS' if ok else 'MISS')}")
    return ok


def report(outcomes: pd.DataFrame, backtests: pd.DataFrame, wear: pd.DataFrame, groups: dict, quick: bool) -> bool:
    """Print the counts and PASS/MISS; True when every target is met."""
    conf = float(outcomes["confidence"].iloc[0]) if len(outcomes) else CONFIDENCE_DEFAULT
    ok = True
    pooled = backtests.dropna(subset=["coverage"]).assign(held=lambda t: t["coverage"] * t["n_predictions"])
    summary = pooled.groupby("method").agg(n_predictions=("n_predictions", "sum"), held=("held", "sum"),
                                           median_abs_error_km=("median_abs_error_km", "median"))
    summary["coverage"] = summary["held"] / summary["n_predictions"]
    for method in ("weibull", "degradation"):
        o = outcomes[outcomes["method"] == method]
        made = o[o["made"]]
        cov = float(made["covered"].mean()) if len(made) else math.nan
        notes = o.loc[~o["made"], "note"].value_counts()
        ok &= line(f"{method:12s} running hoses {len(o)}, with an interval {len(made)}, covered "
                   f"{int(made['covered'].sum())} = {100 * cov:.1f} % (nominal {100 * conf:g} +- 7, >= 300)"
                   + (f"; NULL mostly: {notes.index[0]}" if len(notes) else ""),
                   len(made) >= 300 and abs(cov - conf) <= 0.07, quick)
        misses(made)
        b = summary.loc[method] if method in summary.index else {"n_predictions": 0, "coverage": math.nan,
                                                                 "median_abs_error_km": math.nan}
        ok &= line(f"{'':12s} rul_backtest {int(b['n_predictions'])} predictions, coverage {100 * b['coverage']:.1f} %, "
                   f"median of the groups' median abs error {b['median_abs_error_km']:.3g} km "
                   f"(within 10 points of {100 * cov:.1f} %)",
                   b["n_predictions"] > 0 and abs(b["coverage"] - cov) <= 0.10, quick)
    truth = pd.DataFrame([{"hose_type": g["hose_type"], "adjustment": g["adjustment"],
                           "true_mean": g["wear_rate_mean_per_km"], "true_sd": g["wear_rate_sd_per_km"]}
                          for g in groups.values()])
    w = wear.merge(truth, on=["hose_type", "adjustment"]).dropna(subset=["wear_mean_per_km"])
    for name in ("mean", "sd"):
        rel = w[f"wear_{name}_per_km"] / w[f"true_{name}"]
        med = float(rel.median()) if len(rel) else math.nan
        ok &= line(f"wear rate {name:4s}: estimate / truth, median over {len(rel)} groups {med:.3f} "
                   f"({int((abs(rel - 1) <= 0.15).sum())} groups within 15 %; growth exponent median "
                   f"{w['gamma'].median():.3f}, truth 1.5)", abs(med - 1.0) <= 0.15, quick)
    both = outcomes[outcomes["made"]].pivot_table(index="hose_id", columns="method", values="width").dropna()
    ratio = float(np.median(both["degradation"] / both["weibull"])) if len(both) else math.nan
    ok &= line(f"narrower: degradation / weibull interval width, median over {len(both)} running hoses: "
               f"{ratio:.2f} (target <= 0.70)", ratio <= 0.70, quick)
    return ok


def time_demo(root: Path, seed: int, jobs: int, warehouse: Path | None) -> bool:
    """Time the ``remaining_life`` stage on the demo's hoses (target: under 5 s of CPU):
    :func:`benchmarks.bench_remaining_life_stage.timed` on the demo warehouse's tables (built from
    the demo's durability campaigns, or ``--demo-warehouse``), under the demo's plan's leak limit."""
    from benchmarks.bench_remaining_life_stage import from_warehouse, timed
    from pipeline.simulator.profiles import DEMO_PLAN

    raw = root / "demo" / "raw"
    if warehouse is None:
        db, _, _ = build(root / "demo", "demo", seed, jobs, campaigns=("durability-2025", "durability-2026"))
        warehouse = db.parent
    else:   # a demo's warehouse: its raw tree held the demo's plan
        raw.mkdir(parents=True, exist_ok=True)
        (raw / "plan.toml").write_text(DEMO_PLAN, encoding="utf-8")
    limit = read_plan(raw).for_hose_type(None).leak_limit_l_min
    tables = from_warehouse(str(warehouse))
    wall, cpu = timed(tables, limit)["the whole stage"]
    life = tables.get("hose_life", pd.DataFrame({"status": []}))
    return line(f"demo's hoses: {len(life)} hoses, {int((life['status'] == 'running').sum())} running: the stage "
                f"{cpu:.2f} s CPU ({wall:.2f} s wall; target < 5 s CPU)", cpu < 5.0, False)


def main(argv=None) -> int:
    from pipeline.simulator.rul import RulProfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 hose type of 10 hoses per adjustment: a look, no verdict")
    ap.add_argument("--types", type=int, default=TYPES, help="hose types (two adjustments each)")
    ap.add_argument("--hoses", type=int, default=RulProfile.hoses, help="hoses per hose type and adjustment")
    ap.add_argument("--seed", type=int, default=24)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--demo-warehouse", help="time the analyses on this demo warehouse instead of building one")
    ap.add_argument("--keep", help="build under this folder and keep it (default: a temporary one); a folder "
                                   "kept before is not simulated again, only rebuilt (incrementally)")
    ap.add_argument("--control", action="store_true",
                    help="the life model alone on Weibull, lognormal and competing-risk lives (no rebuild)")
    ap.add_argument("--groups", type=int, default=40, help="--control: simulated groups per life law")
    ap.add_argument("--in-process", action="store_true",
                    help="with --keep of a rebuilt campaign: no rebuild, the remaining_life stage's run called in "
                         "this process on the warehouse's inputs (a change to the models only)")
    a = ap.parse_args(argv)
    if a.control:
        return 0 if control(2 if a.quick else a.groups, a.seed) else 1
    profile = RulProfile(hose_types=1, hoses=10) if a.quick else RulProfile(hose_types=a.types, hoses=a.hoses)
    with tempfile.TemporaryDirectory(prefix="bench_rul_e2e-") as tmp:
        root = Path(a.keep) if a.keep else Path(tmp)
        t0 = time.perf_counter()
        if a.in_process and a.keep:
            db, truth, rebuild_s = (root / "rul" / "wh" / "pneubench.duckdb",
                                    json.loads((root / "rul" / "raw" / "truth.json").read_text()), 0.0)
        else:
            db, truth, rebuild_s = build(root / "rul", profile, a.seed, a.jobs)
        print(f"rul campaign: {profile.hose_types} hose types x 2 adjustments x {profile.hoses} hoses, "
              f"{len(truth['runs'])} runs, seed {a.seed}: simulated and rebuilt in {time.perf_counter() - t0:.0f} s "
              f"(rebuild {rebuild_s:.0f} s)")
        t1 = time.perf_counter()
        with duckdb.connect(str(db), read_only=True) as con:
            rul, tests = stage_tables(con)
            wear = wear_rates(con, read_plan(root / "rul" / "raw"))
        if a.in_process and a.keep:
            rul, tests = stage_in_process(db, root / "rul" / "raw", a.jobs)
            print("hose_rul and rul_backtest: the remaining_life stage run in this process (--in-process)")
        print(f"hose_rul of {rul['hose_id'].nunique()} running hoses read, wear rates refitted: "
              f"{time.perf_counter() - t1:.0f} s")
        ok = report(running_outcomes(rul, truth["hoses"]), tests, wear, truth["groups"], a.quick)
        ok &= time_demo(root, a.seed, a.jobs, a.demo_warehouse)
    return 0 if ok or a.quick else 1


if __name__ == "__main__":
    sys.exit(main())
