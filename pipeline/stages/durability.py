"""Durability and hose service life (issue #6).

The durability runs (distance, strokes, a per-stroke summary) are the ``durability_runs`` stage's
tables (:mod:`pipeline.stages.durability_runs`), read here. The hose logbooks (every ``hoses.csv``
under raw/, merged across campaigns, :mod:`pipeline.raw.logbook`) joined with those runs give
``hose_life``; per (hose_type, adjustment) a censored Weibull with likelihood-ratio bounds of shape,
scale, B10, the plan's B-life and the reliability at its mission distance, and median-rank
regression beside it (``service_life``; the plan's ``confidence``, ``b_life``, ``mission_km`` per
hose type), Kaplan-Meier curves (``hose_survival``) and, per hose type, the likelihood-ratio test of
force-set against distance-set rollers (``service_life_test``). Leakage runs naming a hose are placed
at the hose's distance at the time of the run (``hose_leak_growth``), from the ``leakage_map`` rows
of the PLPA characterisation stage (no plateau detection here; none without that table).

Tables: ``hose_life``, ``service_life``, ``hose_survival``, ``service_life_test``,
``hose_leak_growth``. Figures: Weibull probability plot, Kaplan-Meier curves, leak vs distance,
distance per hose.

Decisions
---------
* How runs are matched to hoses, reinstallation, odometer vs runs (2 % warning, in
  ``hose_life.warnings``) and which logbook rows are quarantined: see :mod:`pipeline.raw.logbook`.
* Service life, KM and the LR test use hoses with a known, positive distance: a running hose
  that has not moved yet, or a failed/removed hose without runs or odometer reading (it carries
  a warning in ``hose_life``), is left out; ``n_hoses`` counts the hoses used.
* A durability run that could not be read (NULL distance in ``durability_runs``): its hose's life
  lacks that run (warned in ``hose_life``).
* The stage reads the leakage runs (their start times) and the ``durability_runs`` table, not the
  durability runs themselves: a durability run re-runs it when its row of that table changes.
"""
from __future__ import annotations

import math

import pandas as pd

from analyses.hose_life import hose_life, match_runs
from analyses.service_life import (kaplan_meier, service_life_summary, weibull_fit, weibull_lr_test,
                                   weibull_quantile_bounds)
from analyses.service_life_plots import (plot_hose_distances, plot_kaplan_meier, plot_leak_growth,
                                         plot_weibull_probability)
from pipeline.raw.logbook import merge_logbooks, read_logbooks
from pipeline.raw.plan import Plan
from pipeline.stages import Reads, StageContext, StageOutput
from pipeline.stages.durability_runs import RUN_COLUMNS, STROKE_COLUMNS, analyse_run  # noqa: F401 (their old home)

NAME = "durability"
READS = Reads(kinds=("leakage",), tables=("durability_runs", "leakage_map"), logbooks=True,
              plan=("confidence", "b_life", "mission_km"))
WRITES = ("hose_life", "service_life", "hose_survival", "service_life_test", "hose_leak_growth")

SERVICE_COLUMNS = ["hose_type", "adjustment", "n_hoses", "n_failed", "weibull_shape", "weibull_scale_km", "b10_km",
                   "b10_lower_km", "b10_upper_km", "confidence", "n_suspended", "b10_method", "loglik", "note",
                   "shape_lower", "shape_upper", "scale_lower_km", "scale_upper_km", "b_life_pct", "b_life_km",
                   "b_life_lower_km", "b_life_upper_km", "mission_km", "reliability_at_mission",
                   "reliability_at_mission_lower", "reliability_at_mission_upper", "mrr_shape", "mrr_scale_km",
                   "mrr_b_life_km", "preferred_method", "bounds_note"]
#: service_life_summary's keys -> the table's new columns (the bounds at the plan's confidence)
SUMMARY_COLUMNS = {"shape_lower": "shape_lower", "shape_upper": "shape_upper", "scale_lower": "scale_lower_km",
                   "scale_upper": "scale_upper_km", "b_life": "b_life_km", "b_life_lower": "b_life_lower_km",
                   "b_life_upper": "b_life_upper_km", "reliability": "reliability_at_mission",
                   "reliability_lower": "reliability_at_mission_lower",
                   "reliability_upper": "reliability_at_mission_upper", "mrr_shape": "mrr_shape",
                   "mrr_scale": "mrr_scale_km", "mrr_b_life": "mrr_b_life_km"}
SURVIVAL_COLUMNS = ["hose_type", "adjustment", "distance_km", "n_at_risk", "n_failed", "n_censored", "survival",
                    "std_err"]
TEST_COLUMNS = ["hose_type", "n_force", "n_failed_force", "n_distance", "n_failed_distance", "shape_force",
                "scale_force_km", "shape_distance", "scale_distance_km", "lr", "df", "p_value"]
LEAK_COLUMNS = ["hose_id", "run_id", "started_at", "distance_km", "adjustment", "chamber", "pressure_bar",
                "leak_l_min", "hose_status"]


def _groups(life: pd.DataFrame, keys):
    """(key tuple, lives [km], failed flags) per group of hoses with a known positive distance."""
    usable = life[pd.to_numeric(life["distance_km"], errors="coerce") > 0]
    for key, g in usable.groupby(list(keys), dropna=False, sort=True):
        key = tuple(None if (isinstance(k, float) and math.isnan(k)) else k for k in key)
        yield key, g["distance_km"].to_numpy(float), (g["status"] == "failed").to_numpy()


def service_life(life: pd.DataFrame, plan: Plan | None = None) -> pd.DataFrame:
    """One ``service_life`` row per (hose_type, adjustment): Weibull by maximum likelihood with
    profile-likelihood bounds of shape, scale, B10 and the plan's B-life, reliability at the plan's
    mission distance, and median-rank regression beside it (:func:`analyses.service_life.service_life_summary`).

    Parameters
    ----------
    life : DataFrame
        ``hose_life``.
    plan : Plan, optional
        The lab's test plan: each hose type's ``confidence``, ``b_life`` [%] and ``mission_km``
        (:meth:`pipeline.raw.plan.Plan.for_hose_type`); None: the built-in defaults.
    """
    plan = plan if plan is not None else Plan()
    rows = []
    for (htype, adj), x, failed in _groups(life, ("hose_type", "adjustment")):
        cfg = plan.for_hose_type(htype)
        r = service_life_summary(x, failed, b_life_pct=cfg.b_life, confidence=cfg.confidence, mission=cfg.mission_km)
        fit = weibull_fit(x, failed)
        b10, b10_lo, b10_hi = weibull_quantile_bounds(fit, x, failed, 0.10, cfg.confidence)
        rows.append({"hose_type": htype, "adjustment": adj, "n_hoses": len(x), "n_failed": int(failed.sum()),
                     "n_suspended": int((~failed).sum()), "weibull_shape": r["shape"],
                     "weibull_scale_km": r["scale"], "b10_km": b10, "b10_lower_km": b10_lo,
                     "b10_upper_km": b10_hi, "confidence": cfg.confidence,
                     "b10_method": "likelihood ratio (profile likelihood), two-sided", "loglik": fit.loglik,
                     "note": r["note"], "b_life_pct": cfg.b_life, "mission_km": cfg.mission_km,
                     "preferred_method": r["preferred_method"], "bounds_note": r["bounds_note"],
                     **{col: r[key] for key, col in SUMMARY_COLUMNS.items()}})
    df = pd.DataFrame(rows, columns=SERVICE_COLUMNS)
    for c in ("weibull_shape", "weibull_scale_km", "b10_km", "b10_lower_km", "b10_upper_km", "loglik", "b_life_pct",
              "mission_km", *SUMMARY_COLUMNS.values()):
        df[c] = pd.to_numeric(df[c]).astype("float64")  # NaN and None -> NULL in the warehouse
    return df


def hose_survival(life: pd.DataFrame) -> pd.DataFrame:
    """Kaplan-Meier survival per (hose_type, adjustment)."""
    frames = []
    for (htype, adj), x, failed in _groups(life, ("hose_type", "adjustment")):
        km = kaplan_meier(x, failed).rename(columns={"life": "distance_km"})
        km.insert(0, "adjustment", adj)
        km.insert(0, "hose_type", htype)
        frames.append(km)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=SURVIVAL_COLUMNS)


def service_life_test(life: pd.DataFrame) -> pd.DataFrame:
    """Per hose type with both settings: LR test of force-set vs distance-set Weibull lives."""
    groups: dict = {}
    for (htype, adj), x, failed in _groups(life, ("hose_type", "adjustment")):
        if adj in ("force", "distance"):
            groups.setdefault(htype, {})[adj] = (x, failed)
    rows = []
    for htype in sorted(groups, key=lambda k: (k is None, k or "")):
        g = groups[htype]
        if set(g) != {"force", "distance"}:
            continue
        test = weibull_lr_test(g)
        ff, fd = weibull_fit(*g["force"]), weibull_fit(*g["distance"])
        rows.append({"hose_type": htype, "n_force": len(g["force"][0]), "n_failed_force": int(g["force"][1].sum()),
                     "n_distance": len(g["distance"][0]), "n_failed_distance": int(g["distance"][1].sum()),
                     "shape_force": ff.shape, "scale_force_km": ff.scale, "shape_distance": fd.shape,
                     "scale_distance_km": fd.scale, "lr": test["lr"], "df": test["df"], "p_value": test["p_value"]})
    return pd.DataFrame(rows, columns=TEST_COLUMNS)


def leak_growth(ctx: StageContext, life: pd.DataFrame, runs_df: pd.DataFrame, matched: pd.Series) -> pd.DataFrame:
    """Leakage plateaus of runs naming a hose, at that hose's distance when the run started."""
    leak = ctx.results.get("leakage_map")
    if leak is None or len(leak) == 0 or "hose_id" not in leak:
        return pd.DataFrame(columns=LEAK_COLUMNS)
    leak = leak[leak["hose_id"].notna() & (leak["hose_id"].astype(str) != "")]
    if leak.empty:
        return pd.DataFrame(columns=LEAK_COLUMNS)
    lruns = ctx.runs_of("leakage")
    started = dict(zip(lruns["run_id"], pd.to_datetime(lruns["started_at"], utc=True, format="ISO8601"))) if len(lruns) else {}
    runs_of_hose = _runs_by_hose(runs_df, matched)
    status = dict(zip(life["hose_id"], life["status"]))
    adj_of = dict(zip(life["hose_id"], life["adjustment"]))
    rows = []
    for r in leak.to_dict("records"):
        hid = str(r["hose_id"])
        when = started.get(r["run_id"])
        if when is None or pd.isna(when):
            continue
        dist = _distance_at(runs_of_hose.get(hid), when)
        rows.append({"hose_id": hid, "run_id": r["run_id"], "started_at": when, "distance_km": dist,
                     "adjustment": r.get("adjustment") or adj_of.get(hid), "chamber": r.get("chamber"),
                     "pressure_bar": r.get("pressure_bar"), "leak_l_min": r.get("leak_l_min"),
                     "hose_status": status.get(hid)})
    df = pd.DataFrame(rows, columns=LEAK_COLUMNS)
    df["started_at"] = pd.to_datetime(df["started_at"], utc=True, format="ISO8601")
    return df.sort_values(["hose_id", "distance_km", "run_id", "chamber", "pressure_bar"], ignore_index=True)


def _runs_by_hose(runs_df: pd.DataFrame, matched: pd.Series) -> dict:
    """Per matched hose, its durability runs' start times and distances [km] (NaN -> 0), in the
    order of ``runs_df``: what :func:`analyses.hose_life.hose_distance_at` reads of them, split
    once rather than filtered per leakage row (issue 26: a leakage change filtered the runs frame
    once per plateau of a hose check)."""
    if not len(runs_df):
        return {}
    hoses = pd.Series(matched.values, index=runs_df.index)
    out = {}
    for hid, rows in hoses.groupby(hoses, sort=False).groups.items():
        part = runs_df.loc[rows]
        out[hid] = (part["started_at"],
                    pd.to_numeric(part["distance_km"], errors="coerce").fillna(0.0).to_numpy())
    return out


def _distance_at(hose_runs, when) -> float:
    """Cumulative distance [km] of a hose's runs (:func:`_runs_by_hose`) started before ``when``:
    :func:`analyses.hose_life.hose_distance_at`, the same sum of the same values in the same order."""
    if hose_runs is None:
        return 0.0
    started, dist = hose_runs
    return float(dist[(started < when).to_numpy()].sum())


def _leak_plot_points(df: pd.DataFrame) -> pd.DataFrame:
    """One point per (hose, run): the leak at the highest pressure level each hose was tested at."""
    d = df.dropna(subset=["leak_l_min", "pressure_bar"]).copy()
    if d.empty:
        return d
    d["_p"] = d["pressure_bar"].round(0)
    top = d.groupby("hose_id")["_p"].transform("max")
    d = d[d["_p"] == top]
    return d.groupby(["hose_id", "run_id"], as_index=False).agg(
        distance_km=("distance_km", "first"), leak_l_min=("leak_l_min", "mean"), adjustment=("adjustment", "first"),
        pressure_bar=("pressure_bar", "mean"))


def durability_runs_of(ctx: StageContext) -> pd.DataFrame:
    """The ``durability_runs`` table (:mod:`pipeline.stages.durability_runs`), its columns
    (:data:`RUN_COLUMNS`) in their order; without one (no durability runs), no rows."""
    runs = ctx.results.get("durability_runs")
    if runs is None or runs.empty:
        return pd.DataFrame(columns=RUN_COLUMNS)
    return runs[RUN_COLUMNS]


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    runs_df = durability_runs_of(ctx)
    events, problems = read_logbooks(ctx.raw)
    hoses, merge_problems = merge_logbooks(events)
    out.problems += problems + merge_problems
    life, run_warnings = hose_life(hoses, runs_df)
    for rid, ws in run_warnings.items():
        for w in ws:
            out.warn(rid, f"durability: {w}")
    matched, _ = match_runs(hoses, runs_df) if len(runs_df) else (pd.Series([], dtype=object), {})
    out.tables["hose_life"] = life
    # pooled over the hoses' lives only: taken from the previous run when they did not change (a leakage check)
    out.tables["service_life"] = ctx.pooled("service_life", service_life, life, ctx.plan)
    out.tables["hose_survival"] = ctx.pooled("hose_survival", hose_survival, life)
    out.tables["service_life_test"] = ctx.pooled("service_life_test", service_life_test, life)
    growth = leak_growth(ctx, life, runs_df, matched)
    out.tables["hose_leak_growth"] = growth

    groups = {f"{t or '?'} / {a or '?'}": (x, f) for (t, a), x, f in _groups(life, ("hose_type", "adjustment"))}
    if groups:
        out.draw("weibull_probability", plot_weibull_probability, groups, "km", ctx.plan.for_hose_type(None).confidence)
        out.captions["weibull_probability"] = ("Weibull probability plot of hose life per hose type / roller "
                                               "adjustment; | marks suspensions (removed or running hoses).")
        out.draw("kaplan_meier", plot_kaplan_meier, groups)
        out.captions["kaplan_meier"] = "Kaplan-Meier survival of hoses vs distance, force- vs distance-set rollers."
    if len(life):
        out.draw("hose_distance", plot_hose_distances, life)
        out.captions["hose_distance"] = "Distance per hose, coloured by status (failed / removed / running)."
    pts = _leak_plot_points(growth) if len(growth) else growth
    if len(pts):
        out.draw("leak_growth", plot_leak_growth, pts)
        out.captions["leak_growth"] = ("Leak vs hose distance at the time of each leakage run (highest pressure "
                                       "level per hose): the wall-thinning signature.")
    return out
