"""Durability and hose service life (issue #6).

Per durability run (streamed from its samples Parquet in batches, bounded memory, in parallel
through ``ctx.map``): distance, strokes, duration and a per-stroke summary
(:mod:`analyses.durability`). The hose logbooks (every ``hoses.csv`` under raw/, merged across
campaigns, :mod:`pipeline.raw.logbook`) joined with those runs give ``hose_life``; per (hose_type,
adjustment) a censored Weibull with likelihood-ratio bounds of shape, scale, B10, the plan's
B-life and the reliability at its mission distance, and median-rank regression beside it
(``service_life``; the plan's ``confidence``, ``b_life``, ``mission_km`` per hose type), Kaplan-
Meier curves (``hose_survival``) and, per hose type, the likelihood-ratio test of force-set
against distance-set rollers (``service_life_test``). Leakage runs naming a hose are placed at the
hose's distance at the time of the run (``hose_leak_growth``), from the ``leakage_map`` rows of
the PLPA characterisation stage (no plateau detection here; none without that table).

Tables: ``durability_runs``, ``durability_strokes``, ``hose_life``, ``service_life``,
``hose_survival``, ``service_life_test``, ``hose_leak_growth``. Figures: Weibull probability
plot, Kaplan-Meier curves, leak vs distance, distance per hose.

Decisions
---------
* How runs are matched to hoses, reinstallation, odometer vs runs (2 % warning, in
  ``hose_life.warnings``) and which logbook rows are quarantined: see :mod:`pipeline.raw.logbook`.
* Service life, KM and the LR test use hoses with a known, positive distance: a running hose
  that has not moved yet, or a failed/removed hose without runs or odometer reading (it carries
  a warning in ``hose_life``), is left out; ``n_hoses`` counts the hoses used.
* A durability run that cannot be read gives a ``durability_runs`` row with NULL distance and
  strokes and a run warning; its hose's life then lacks that run (warned in ``hose_life``).
* Samples are read in 131k-row Arrow batches (``pre_buffer=False``): memory stays at about one
  decoded row group whatever the run's length.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from analyses.durability import StrokeCounter, stroke_deadband, strokes_note
from analyses.hose_life import hose_life, match_runs
from analyses.quality import describe_sensor_at_rest
from analyses.service_life import (kaplan_meier, service_life_summary, weibull_fit, weibull_lr_test,
                                   weibull_quantile_bounds)
from analyses.service_life_plots import (plot_hose_distances, plot_kaplan_meier, plot_leak_growth,
                                         plot_weibull_probability)
from pipeline.raw.logbook import merge_logbooks, read_logbooks
from pipeline.raw.plan import Plan
from pipeline.ingest.prefetch import prefetch
from pipeline.stages import Reads, StageContext, StageOutput
from pipeline.stages.values import finite_float

NAME = "durability"
READS = Reads(kinds=("durability", "leakage"), tables=("leakage_map",), logbooks=True,
              plan=("confidence", "b_life", "mission_km"))
WRITES = ("durability_runs", "durability_strokes", "hose_life", "service_life", "hose_survival",
          "service_life_test", "hose_leak_growth")

BATCH_ROWS = 1 << 17  # 131k rows: bounded memory (plus one decoded row group), cache friendly
COLUMNS = ("t_s", "x_m", "p_a_pa", "p_b_pa")
PA_PER_BAR = 1e5

RUN_COLUMNS = ["run_id", "hose_id", "distance_km", "strokes", "duration_h", "campaign", "started_at", "n_samples",
               "mean_speed_m_s", "mean_stroke_mm", "dp_friction_bar", "friction_n", "deadband_mm", "note"]
#: Row groups of x sampled (evenly over the run) to describe the position sensor when run
#: metadata does not state it: enough rest and motion for the estimate, bounded memory.
SENSOR_ROW_GROUPS = 5
STROKE_COLUMNS = ["run_id", "hose_id", "stroke", "direction", "t_start_s", "t_end_s", "length_mm", "mean_speed_m_s",
                  "dp_mean_bar", "dp_friction_bar", "friction_n", "n_samples"]
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


def _x_sample(pf) -> np.ndarray:
    """``x_m`` of up to :data:`SENSOR_ROW_GROUPS` row groups spread over the file."""
    n = pf.num_row_groups
    if n == 0:
        return np.empty(0)
    groups = sorted({int(round(i)) for i in np.linspace(0, n - 1, min(n, SENSOR_ROW_GROUPS))})
    return np.concatenate([pf.read_row_group(g, columns=["x_m"]).column("x_m").to_numpy(zero_copy_only=False)
                           .astype(float) for g in groups])


def analyse_run(item) -> dict:
    """Stream one durability run's samples file and count its strokes (module level: picklable).

    Parameters
    ----------
    item : str or (str, dict)
        The samples path, or the path and the run's params (``sensor_x_resolution`` /
        ``sensor_x_noise`` state the encoder; estimated from sampled row groups otherwise).

    Returns a dict with ``distance_m``, ``strokes``, ``duration_s``, ``n_samples``,
    ``stroke_table``, ``deadband_m`` and ``note`` (strokes not detectable), or ``error`` (one
    line) when the run cannot be analysed.
    """
    path, params = (item, None) if isinstance(item, str) else item
    try:
        pf = pq.ParquetFile(path, pre_buffer=False)  # no read-ahead of whole row groups: less memory
        names = set(pf.schema_arrow.names)
        if "t_s" not in names or "x_m" not in names:
            return {"error": "no t_s/x_m columns in the samples"}
        cols = [c for c in COLUMNS if c in names]
        have_dp = "p_a_pa" in names and "p_b_pa" in names
        stated = {k: finite_float(_param(params, f"sensor_x_{k}")) for k in ("resolution", "noise")}
        stated = {k: v for k, v in stated.items() if v is not None and v >= 0}
        xs = _x_sample(pf) if len(stated) < 2 else np.empty(0)
        xs = xs[np.isfinite(xs)]
        # estimated from the samples at rest: a run logged slowly for its strokes has no other
        sensor = describe_sensor_at_rest(xs, resolution=stated.get("resolution"), noise=stated.get("noise"))
        deadband = stroke_deadband(sensor, float(np.max(np.abs(xs))) if xs.size else 1.0)
        sc = StrokeCounter(deadband)
        for batch in prefetch(pf.iter_batches(batch_size=BATCH_ROWS, columns=cols)):  # decode beside counting
            get = lambda c: batch.column(c).to_numpy(zero_copy_only=False)  # noqa: E731
            dp = get("p_a_pa") - get("p_b_pa") if have_dp else None
            sc.update(get("t_s"), get("x_m"), dp)
        s = sc.finish()
        if s.n_samples < 2:
            return {"error": "fewer than two usable samples"}
        return {"distance_m": s.distance_m, "strokes": s.strokes, "duration_s": s.duration_s,
                "n_samples": s.n_samples, "stroke_table": s.stroke_table, "deadband_m": deadband,
                "note": strokes_note(s, deadband)}
    except Exception as exc:  # a run that cannot be analysed gives NULLs and a warning
        return {"error": f"{type(exc).__name__}: {exc}".splitlines()[0]}


def _param(params, key):
    if isinstance(params, dict):
        v = params.get(key)
        return None if v is None or (isinstance(v, float) and math.isnan(v)) else v
    return None


def durability_runs(ctx: StageContext, out: StageOutput) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``durability_runs`` and ``durability_strokes`` for every durability run."""
    runs = ctx.runs_of("durability")
    if runs.empty:
        return pd.DataFrame(columns=RUN_COLUMNS), pd.DataFrame(columns=STROKE_COLUMNS)
    items = [(str(ctx.samples_file(rid)), p if isinstance(p, dict) else None)
             for rid, p in zip(runs["run_id"], runs["params"] if "params" in runs else [None] * len(runs))]
    results = ctx.map(analyse_run, items, label="durability runs")
    rows, strokes = [], []
    for run, res in zip(runs.to_dict("records"), results):
        rid, params = run["run_id"], run.get("params")
        hose = _param(params, "hose_id")
        hose = None if hose is None else str(hose)
        area = finite_float(_param(params, "hose_area_m2"))
        row = {"run_id": rid, "hose_id": hose, "campaign": run.get("campaign"), "started_at": run.get("started_at"),
               "deadband_mm": res["deadband_m"] * 1e3 if "deadband_m" in res else None, "note": None}
        if "error" in res:
            out.warn(rid, f"durability: cannot analyse the run ({res['error']}); distance and strokes NULL")
            rows.append(dict(row, note=f"cannot analyse the run: {res['error']}"))
            continue
        if res.get("note"):
            out.warn(rid, f"durability: {res['note']}; distance and strokes NULL")
            rows.append(dict(row, note=res["note"], n_samples=int(res["n_samples"]), duration_h=res["duration_s"] / 3600.0))
            continue
        st = res["stroke_table"]
        dist_m, dur_s = res["distance_m"], res["duration_s"]
        fric_bar = float(np.nanmean(st["dp_friction_pa"])) / PA_PER_BAR if len(st) and st["dp_friction_pa"].notna().any() else None
        row.update(distance_km=dist_m / 1e3, strokes=int(res["strokes"]), duration_h=dur_s / 3600.0,
                   n_samples=int(res["n_samples"]), mean_speed_m_s=dist_m / dur_s if dur_s > 0 else None,
                   mean_stroke_mm=1e3 * dist_m / res["strokes"] if res["strokes"] else None,
                   dp_friction_bar=fric_bar, friction_n=fric_bar * PA_PER_BAR * area if fric_bar is not None and area else None)
        if res["strokes"] == 0:
            out.warn(rid, "durability: the carriage never moved more than the deadband "
                          f"({res['deadband_m'] * 1e3:.3g} mm); distance 0")
        rows.append(row)
        if len(st):
            strokes.append(pd.DataFrame({
                "run_id": rid, "hose_id": hose, "stroke": st["stroke"].to_numpy(), "direction": st["direction"].to_numpy(),
                "t_start_s": st["t_start_s"].to_numpy(), "t_end_s": st["t_end_s"].to_numpy(),
                "length_mm": st["length_m"].to_numpy() * 1e3, "mean_speed_m_s": st["mean_speed_m_s"].to_numpy(),
                "dp_mean_bar": st["dp_mean_pa"].to_numpy() / PA_PER_BAR,
                "dp_friction_bar": st["dp_friction_pa"].to_numpy() / PA_PER_BAR,
                "friction_n": st["dp_friction_pa"].to_numpy() * area if area else np.nan,
                "n_samples": st["n_samples"].to_numpy()}))
    runs_df = pd.DataFrame(rows, columns=RUN_COLUMNS)
    runs_df["strokes"] = runs_df["strokes"].astype("Int64")
    runs_df["n_samples"] = runs_df["n_samples"].astype("Int64")
    runs_df["started_at"] = pd.to_datetime(runs_df["started_at"], utc=True, format="ISO8601")
    strokes_df = pd.concat(strokes, ignore_index=True) if strokes else pd.DataFrame(columns=STROKE_COLUMNS)
    return runs_df, strokes_df


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


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    runs_df, strokes_df = durability_runs(ctx, out)
    events, problems = read_logbooks(ctx.raw)
    hoses, merge_problems = merge_logbooks(events)
    out.problems += problems + merge_problems
    life, run_warnings = hose_life(hoses, runs_df)
    for rid, ws in run_warnings.items():
        for w in ws:
            out.warn(rid, f"durability: {w}")
    matched, _ = match_runs(hoses, runs_df) if len(runs_df) else (pd.Series([], dtype=object), {})
    out.tables["durability_runs"] = runs_df
    out.tables["durability_strokes"] = strokes_df
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
