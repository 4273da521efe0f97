"""Stage: the durability runs, one by one (issue #6; its own stage since issue 26).

Per durability run (streamed from its samples Parquet in batches, bounded memory, in parallel
through ``ctx.map``, each run's result kept in the stage's memo): distance, strokes, duration and
a per-stroke summary (:mod:`analyses.durability`). The hoses' lives, service life and leak growth
that read these runs are the ``durability`` stage's (:mod:`pipeline.stages.durability`).

Tables: ``durability_runs``, ``durability_strokes``. No figures.

Why a stage of its own: it reads durability runs only, so a changed leakage check (which re-runs
``durability`` for ``hose_leak_growth``) reuses this stage's folder: its two tables, 188,000
stroke rows at 1,000 runs, are neither rebuilt from the memo, written, given their run columns
nor keyed again (~0.4 CPU-s of a leakage change; issue 26).

Decisions
---------
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
from analyses.quality import describe_sensor_at_rest
from pipeline.ingest.prefetch import prefetch
from pipeline.stages import Reads, StageContext, StageOutput
from pipeline.stages.values import finite_float

NAME = "durability_runs"
READS = Reads(kinds=("durability",))
WRITES = ("durability_runs", "durability_strokes")

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


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    runs_df, strokes_df = durability_runs(ctx, out)
    out.tables["durability_runs"] = runs_df
    out.tables["durability_strokes"] = strokes_df
    return out
