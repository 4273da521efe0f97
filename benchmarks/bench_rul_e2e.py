"""End-to-end calibration of the remaining-life predictions (issue 24): the simulator's ``rul``
campaign, rebuilt by ``pneubench rebuild`` as a process, predicted from the warehouse, compared
with the simulator's truth.

One command::

    python -m benchmarks.bench_rul_e2e            # 10 hose types x 2 adjustments x 25 hoses, ~4,000 runs
    python -m benchmarks.bench_rul_e2e --quick    # 1 hose type of 10 hoses (a look, no verdict)

The campaign (:mod:`pipeline.simulator.rul`): every hose a degradation path (lognormal wear rate,
leak ``(w d)^1.5`` at the pressure it sealed new, read by a leakage check after every short
durability run) and a Weibull rupture; it fails at the first of its leak crossing the plan's limit
and its rupture; the hoses still on their benches at the campaign's end are ``running``, and the
truth holds their failure distance. The rebuild places each check at its hose's distance
(``hose_leak_growth``) and gives ``hose_life``; :func:`predictions_from_warehouse` then does what
the ``remaining_life`` stage is to do (``/work/wt/RUL_CONTRACT.md``) per (hose type, adjustment).

Counted, at the plan's confidence (90 %):

* ``coverage``: per method, the share of running hoses whose true remaining life lies in their
  interval (target: within 7 points of nominal, over at least 300 running hoses with an interval);
* ``backtest``: per method, the pooled coverage of :func:`analyses.remaining_life.rul_backtest`
  (target: within 10 points of the running hoses' coverage);
* ``wear rate``: the degradation model's mean and standard deviation of the wear rate per
  (hose type, adjustment) against the truth: the median ratio over the groups within 15 %;
* ``narrower``: the median over running hoses with both intervals of degradation width / weibull
  width (target: <= 0.70);
* ``demo``: the time the analyses take on the demo's hoses (its durability campaigns simulated
  and rebuilt, or ``--demo-warehouse``), target under 5 s.

A hose without a prediction (NULL, with its note) is counted and left out. Seeded (``--seed``).
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
#: The flow sensor as ``leakage_map.sensors`` states it (kg/s, the warehouse's unit).
_FLOW = re.compile(r"q_leak: resolution (\S+), noise (\S+) \(([^)]*)\) kg/s")


# -- what the remaining_life stage will do (REPLACE by reading hose_rul once the stage lands) -------
def leak_points(growth: pd.DataFrame, pressure_bar: float) -> pd.DataFrame:
    """The contract's leak path: per hose and run the plateau nearest ``pressure_bar`` (within the
    run's plateau spacing), the mean over chambers; ``hose_id``, ``run_id``, ``distance_km``, ``leak_l_min``."""
    g = growth.dropna(subset=["pressure_bar", "leak_l_min", "distance_km"]).copy()
    if g.empty:
        return pd.DataFrame(columns=["hose_id", "run_id", "distance_km", "leak_l_min"])
    g["_off"] = (g["pressure_bar"] - pressure_bar).abs()
    spacing = g.groupby("run_id")["pressure_bar"].transform(
        lambda p: float(np.median(np.diff(np.sort(p.round(1).unique())))) if p.round(1).nunique() > 1 else math.inf)
    g = g[g["_off"] <= spacing / 2.0]
    nearest = g.groupby(["run_id", "chamber"], dropna=False)["_off"].transform("min")
    g = g[g["_off"] == nearest]
    return g.groupby(["hose_id", "run_id"], as_index=False).agg(distance_km=("distance_km", "first"),
                                                                leak_l_min=("leak_l_min", "mean"))


def leak_sensor(sensors: pd.Series):
    """The leak channel's :class:`~analyses.quality.Sensor` [l/min] of a group's leakage runs:
    the coarsest stated or estimated one (as the report's leak floor is read)."""
    from analyses.quality import Sensor
    from schemas.units import kg_s_to_l_min_anr

    found = [(float(m.group(1)), float(m.group(2)), m.group(3)) for s in sensors.dropna()
             if (m := _FLOW.search(str(s)))]
    if not found:
        return None
    res, noise, source = max(found, key=lambda f: max(f[0], f[1]))
    return Sensor(float(kg_s_to_l_min_anr(res)), float(kg_s_to_l_min_anr(noise)), source)


def predictions_from_warehouse(con, plan) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Per (hose type, adjustment), :func:`analyses.remaining_life.remaining_life`,
    :func:`~analyses.remaining_life.rul_backtest` and the degradation fit's wear rate, from the
    warehouse's ``hose_life``, ``hose_leak_growth`` and ``leakage_map`` and the plan (what the
    ``remaining_life`` stage does; to be replaced by reading ``hose_rul`` / ``rul_backtest``).

    Returns (rul rows, backtest rows, wear-rate rows: ``hose_type``, ``adjustment``,
    ``wear_mean_per_km``, ``wear_sd_per_km``, ``gamma``).
    """
    from analyses.remaining_life import RulSettings, data_seed, degradation_fit, remaining_life, rul_backtest

    life = con.sql("SELECT hose_id, hose_type, adjustment, distance_km, status, failure_mode FROM hose_life "
                   "WHERE distance_km > 0 ORDER BY hose_id").df()
    growth = con.sql("SELECT hose_id, run_id, distance_km, chamber, pressure_bar, leak_l_min FROM hose_leak_growth").df()
    sensors = con.sql("SELECT DISTINCT run_id, sensors FROM leakage_map WHERE hose_id IS NOT NULL").df()
    ruls, tests, wear = [], [], []
    for (htype, adj), hoses in life.groupby(["hose_type", "adjustment"], sort=True):
        s = plan.for_hose_type(htype)
        hoses = hoses.reset_index(drop=True)
        tag = {"hose_type": htype, "adjustment": adj}
        if s.leak_limit_l_min is None or s.leak_pressure_bar is None:
            continue   # the stage writes weibull rows and NULL degradation rows; nothing to calibrate here
        pts = leak_points(growth[growth["hose_id"].isin(hoses["hose_id"])], s.leak_pressure_bar)
        sensor = leak_sensor(sensors.loc[sensors["run_id"].isin(pts["run_id"]), "sensors"])
        if sensor is None:
            continue
        settings = RulSettings(limit_l_min=s.leak_limit_l_min, sensor=sensor, confidence=s.confidence)
        frame = hoses[["hose_id", "distance_km", "status", "failure_mode"]]
        path = pts[["hose_id", "distance_km", "leak_l_min"]]
        seed = data_seed(frame, path)
        ruls.append(remaining_life(frame, path, settings, seed=seed).assign(**tag, confidence=s.confidence))
        tests.append(rul_backtest(frame, path, settings, seed=seed).assign(**tag))
        fit = degradation_fit(path, sensor)
        wear.append({**tag, **dict(zip(("wear_mean_per_km", "wear_sd_per_km"), fit.wear_rate())), "gamma": fit.gamma})
    cat = lambda frames: pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()  # noqa: E731
    return cat(ruls), cat(tests), pd.DataFrame(wear)


# -- the campaign, rebuilt ------------------------------------------------------------------------
def build(root: Path, profile, seed: int, jobs: int, campaigns: tuple | None = None) -> tuple[Path, dict, float]:
    """Simulate ``profile`` under ``root/raw`` and rebuild it as a process: (warehouse database,
    truth, rebuild seconds)."""
    from pipeline.simulator.campaign import simulate_campaign

    raw, wh = root / "raw", root / "wh"
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


# -- counting -------------------------------------------------------------------------------------
def running_outcomes(rul: pd.DataFrame, truth_hoses: dict) -> pd.DataFrame:
    """The running hoses' predictions with their true remaining life [km]: ``made``, ``covered``, ``width``."""
    r = rul.assign(truth_km=[truth_hoses[h]["failure_km"] for h in rul["hose_id"]])
    ok = r["rul_median_km"].notna()
    rem = r["truth_km"] - r["distance_km"]
    return r.assign(made=ok, covered=ok & (r["rul_lower_km"] <= rem) & (rem <= r["rul_upper_km"]),
                    width=r["rul_upper_km"] - r["rul_lower_km"])


def line(label: str, ok: bool, quick: bool) -> bool:
    print(f"{label}  {'(quick: no verdict)' if quick else ('PASS' if ok else 'MISS')}")
    return ok


def report(outcomes: pd.DataFrame, backtests: pd.DataFrame, wear: pd.DataFrame, groups: dict, quick: bool) -> bool:
    """Print the counts and PASS/MISS; True when every target is met."""
    from analyses.remaining_life import backtest_summary

    conf = float(outcomes["confidence"].iloc[0]) if len(outcomes) else CONFIDENCE_DEFAULT
    ok = True
    summary = backtest_summary(backtests).set_index("method")
    for method in ("weibull", "degradation"):
        o = outcomes[outcomes["method"] == method]
        made = o[o["made"]]
        cov = float(made["covered"].mean()) if len(made) else math.nan
        notes = o.loc[~o["made"], "note"].value_counts()
        ok &= line(f"{method:12s} running hoses {len(o)}, with an interval {len(made)}, covered "
                   f"{int(made['covered'].sum())} = {100 * cov:.1f} % (nominal {100 * conf:g} +- 7, >= 300)"
                   + (f"; NULL mostly: {notes.index[0]}" if len(notes) else ""),
                   len(made) >= 300 and abs(cov - conf) <= 0.07, quick)
        b = summary.loc[method]
        ok &= line(f"{'':12s} backtest {b['n_predictions']} predictions, coverage {100 * b['coverage']:.1f} %, "
                   f"median abs error {b['median_abs_error_km']:.3g} km (within 10 points of {100 * cov:.1f} %)",
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
    """Time :func:`predictions_from_warehouse` on the demo's hoses (target: under 5 s)."""
    raw = root / "demo" / "raw"
    if warehouse is None:
        db, _, _ = build(root / "demo", "demo", seed, jobs, campaigns=("durability-2025", "durability-2026"))
    else:   # a demo's warehouse: its raw tree held the demo's plan
        from pipeline.simulator.profiles import DEMO_PLAN

        db = Path(warehouse) / "pneubench.duckdb"
        raw.mkdir(parents=True, exist_ok=True)
        (raw / "plan.toml").write_text(DEMO_PLAN, encoding="utf-8")
    plan = read_plan(raw)
    with duckdb.connect(str(db), read_only=True) as con:
        t0 = time.perf_counter()
        rul, tests, _ = predictions_from_warehouse(con, plan)
        dt = time.perf_counter() - t0
    return line(f"demo's hoses: {rul['hose_id'].nunique() if len(rul) else 0} running hoses, "
                f"{len(tests)} backtest predictions, analyses {dt:.2f} s (target < 5 s)", dt < 5.0, False)


def main(argv=None) -> int:
    from pipeline.simulator.rul import RulProfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 hose type of 10 hoses per adjustment: a look, no verdict")
    ap.add_argument("--types", type=int, default=RulProfile.hose_types, help="hose types (two adjustments each)")
    ap.add_argument("--hoses", type=int, default=RulProfile.hoses, help="hoses per hose type and adjustment")
    ap.add_argument("--seed", type=int, default=24)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--demo-warehouse", help="time the analyses on this demo warehouse instead of building one")
    ap.add_argument("--keep", help="build under this folder and keep it (default: a temporary one)")
    a = ap.parse_args(argv)
    profile = RulProfile(hose_types=1, hoses=10) if a.quick else RulProfile(hose_types=a.types, hoses=a.hoses)
    with tempfile.TemporaryDirectory(prefix="bench_rul_e2e-") as tmp:
        root = Path(a.keep) if a.keep else Path(tmp)
        t0 = time.perf_counter()
        db, truth, rebuild_s = build(root / "rul", profile, a.seed, a.jobs)
        print(f"rul campaign: {profile.hose_types} hose types x 2 adjustments x {profile.hoses} hoses, "
              f"{len(truth['runs'])} runs, seed {a.seed}: simulated and rebuilt in {time.perf_counter() - t0:.0f} s "
              f"(rebuild {rebuild_s:.0f} s)")
        t1 = time.perf_counter()
        with duckdb.connect(str(db), read_only=True) as con:
            rul, tests, wear = predictions_from_warehouse(con, read_plan(root / "rul" / "raw"))
        print(f"predictions and backtests of {rul['hose_id'].nunique()} running hoses: {time.perf_counter() - t1:.0f} s")
        ok = report(running_outcomes(rul, truth["hoses"]), tests, wear, truth["groups"], a.quick)
        ok &= time_demo(root, a.seed, a.jobs, a.demo_warehouse)
    return 0 if ok or a.quick else 1


if __name__ == "__main__":
    sys.exit(main())
