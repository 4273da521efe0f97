"""Stage: PLPA characterisation (seed 000, section 3): leakage maps, static breakaway, viscous friction.

Tables (``schemas/ddl/10_plpa_characterisation.sql``):

- ``leakage_map``: one row per pressure plateau of a leakage run (+ plateau timing and scatter);
- ``seal_envelope``: per roller setting, the highest tested pressure with leak below threshold,
  from the setting's characterisation runs (a leakage run naming a ``hose_id`` is a check on that
  hose: it stays in ``leakage_map`` for the durability stage but is left out of the envelope and
  of Figs. 9/10, unless the setting has nothing else; see ``analyses.leakage``). The macro
  ``seal_envelope_at(threshold)`` gives the same table at another threshold;
- ``breakaway``: one row per breakaway run (force NULL when the carriage never moved);
- ``breakaway_summary``: mean and std per (direction, backpressure, force rate);
- ``breakaway_findings``: the backpressure ratio and the force-rate slope with their CIs;
- ``viscous_points``: one row per constant-velocity pass;
- ``viscous_fits``: Coulomb + viscous per (backpressure, direction);
- ``viscous_transition``: near-zero tanh transition velocity and Stribeck test per backpressure;
- ``friction_dynamic``: per viscous run, mass, Coulomb and viscous friction and force offset by
  inverse-dynamics least squares on the whole record (``analyses.friction_dynamic``).

Detection thresholds come from each run's sensors: ``analyses.quality.sensor_from_params`` reads
``sensor_<channel>_resolution`` / ``sensor_<channel>_noise`` from the run's params (as ingest
stores what the rig states) and estimates what is not stated from the record; the sensors used
are recorded in the result rows (``x_resolution_m``, ``x_noise_m``, ``sensor_source``, or a
``sensors`` text). Fitted results carry a ``note``: NULL when sound, else why values are NULL.

A run that cannot be analysed gives no plateau / pass rows (leakage, viscous) or a NULL force
(breakaway), and a warning on the run; never an exception.
"""
from __future__ import annotations

import math

import pandas as pd
import pyarrow.parquet as pq

from analyses import breakaway as bk
from analyses import friction_dynamic as fd
from analyses import leakage as lk
from analyses import viscous_friction as vf
from analyses.quality import sensor_from_params
from schemas.papers import PLPA_CITATION
from pipeline.stages import Reads, StageContext, StageOutput
from pipeline.stages.values import finite_float, run_params

NAME = "plpa_characterisation"
READS = Reads(kinds=("leakage", "breakaway", "viscous"))
WRITES = ("leakage_map", "seal_envelope", "breakaway", "breakaway_summary", "breakaway_findings",
          "viscous_points", "viscous_fits", "viscous_transition", "friction_dynamic")

#: Seal-envelope leak threshold; a run or rig.toml may not override it (it is a lab-wide choice). [l/min ANR]
LEAK_THRESHOLD_L_MIN = lk.LEAK_THRESHOLD_L_MIN
#: Confidence level of the breakaway findings.
CONFIDENCE = 0.95

LEAKAGE_COLS = ["run_id", "hose_id", "chamber", "adjustment", "z_rollers_mm", "spring_force_n", "pressure_bar",
                "leak_l_min", "plateau", "t_start_s", "t_end_s", "n_samples", "leak_std_l_min", "leak_se_l_min",
                "sensors"]
BREAKAWAY_COLS = ["run_id", "direction", "backpressure_bar", "force_rate_n_s", "breakaway_force_n", "onset_t_s",
                  "measured_rate_n_s", "measured_rate_se_n_s", "x_resolution_m", "x_noise_m", "sensor_source", "note"]
VISCOUS_COLS = ["run_id", "backpressure_bar", "velocity_m_s", "friction_n", "direction", "pass_index",
                "t_start_s", "t_end_s", "n_samples", "friction_std_n", "accel_m_s2", "force_source",
                "velocity_se_m_s", "x_resolution_m", "x_noise_m", "sensor_source"]
DYNAMIC_COLS = ["run_id", "backpressure_bar", "mass_kg", "coulomb_n", "viscous_n_s_m", "offset_n", "mass_se_kg",
                "coulomb_se_n", "viscous_se_n_s_m", "offset_se_n", "nrmse_pct", "n_samples", "cond", "cutoff_hz",
                "lag_s", "lag_se_s", "force_source", "x_resolution_m", "x_noise_m", "sensor_source", "note"]


def _read(path: str, columns=None) -> pd.DataFrame:
    table = pq.read_table(path)
    if "run_id" in table.column_names:
        table = table.drop(["run_id"])
    if columns is not None:
        table = table.select([c for c in columns if c in table.column_names])
    return table.to_pandas()


def analyse_run(item: tuple) -> dict:
    """Analyse one run (module level, picklable, for ``ctx.map``).

    Parameters
    ----------
    item : tuple
        ``(kind, run_id, samples_path, params)``.

    Returns
    -------
    dict
        ``kind``, ``run_id``, ``rows`` (rows for the kind's table), ``warnings`` (list of str).
    """
    kind, run_id, path, params = item
    dynamic, missing = [], []
    try:
        if kind == "leakage":
            rows, warns = _leakage(run_id, path, params)
        elif kind == "breakaway":
            rows, warns = _breakaway(run_id, path, params)
        else:
            rows, dynamic, warns, missing = _viscous(run_id, path, params)
    except Exception as exc:  # an unforeseen input: NULLs and a warning, never a failed rebuild
        rows = [{"run_id": run_id, "direction": params.get("direction"),
                 "backpressure_bar": finite_float(params.get("backpressure_bar")),
                 "force_rate_n_s": finite_float(params.get("force_rate_n_s")), "breakaway_force_n": None}] \
            if kind == "breakaway" else []
        warns = [f"{NAME}: {kind} analysis failed: {type(exc).__name__}: {exc}"]
    return {"kind": kind, "run_id": run_id, "rows": rows, "dynamic": dynamic, "warnings": warns, "missing": missing}


def _sensor_cols(sensor) -> dict:
    return {"x_resolution_m": float(sensor.resolution), "x_noise_m": float(sensor.noise),
            "sensor_source": sensor.source}


def _leakage(run_id, path, params):
    df = _read(path, ["t_s", "p_supply_pa", "q_leak_kg_s"])
    if not {"t_s", "p_supply_pa", "q_leak_kg_s"} <= set(df.columns):
        return [], [f"{NAME}: leakage run lacks p_supply or q_leak; no plateaus"]
    sp = sensor_from_params(params, "p_supply", df["p_supply_pa"].to_numpy(float))
    sq = sensor_from_params(params, "q_leak", df["q_leak_kg_s"].to_numpy(float))
    # only stated values steer the plateau detector (it estimates the noise itself otherwise)
    plat = lk.leakage_plateaus(df["t_s"], df["p_supply_pa"], df["q_leak_kg_s"],
                               sensor_p=sp if sp.source != "estimated" else None,
                               sensor_q=sq if sq.source != "estimated" else None)
    if plat.empty:
        return [], [f"{NAME}: no steady pressure plateau found in the leakage run"]
    setting = {"run_id": run_id, "hose_id": params.get("hose_id"), "chamber": params.get("chamber"),
               "adjustment": params.get("adjustment"), "z_rollers_mm": finite_float(params.get("z_rollers_mm")),
               "spring_force_n": finite_float(params.get("spring_force_n")),
               "sensors": f"p_supply: {sp.describe()} Pa; q_leak: {sq.describe()} kg/s"}
    return [{**setting, **r} for r in plat.to_dict("records")], []


def _breakaway(run_id, path, params):
    row = {"run_id": run_id, "direction": params.get("direction"),
           "backpressure_bar": finite_float(params.get("backpressure_bar")),
           "force_rate_n_s": finite_float(params.get("force_rate_n_s")), "breakaway_force_n": None,
           "onset_t_s": None, "measured_rate_n_s": None, "measured_rate_se_n_s": None, "note": None}
    area = finite_float(params.get("hose_area_m2"))
    if row["direction"] not in ("P", "N"):
        row["note"] = "no direction P/N"
        return [row], [f"{NAME}: breakaway run without direction P/N; no breakaway force"]
    if area is None or area <= 0:
        row["note"] = "no valid hose_area_m2"
        return [row], [f"{NAME}: breakaway run without a valid hose_area_m2; no breakaway force"]
    df = _read(path, ["t_s", "x_m", "p_a_pa", "p_b_pa"])
    if not {"t_s", "x_m", "p_a_pa", "p_b_pa"} <= set(df.columns):
        row["note"] = "lacks x, p_a or p_b"
        return [row], [f"{NAME}: breakaway run lacks x, p_a or p_b; no breakaway force"]
    sensor = sensor_from_params(params, "x", df["x_m"].to_numpy(float))
    res = bk.breakaway_force(df["t_s"], df["x_m"], df["p_a_pa"], df["p_b_pa"], area, row["direction"], sensor)
    row.update({k: res[k] for k in ("breakaway_force_n", "onset_t_s", "measured_rate_n_s", "measured_rate_se_n_s",
                                    "note")})
    row.update(_sensor_cols(sensor))
    return [row], ([f"{NAME}: {res['warning']}"] if res["warning"] else [])


def _viscous(run_id, path, params):
    df = _read(path, ["t_s", "x_m", "p_a_pa", "p_b_pa", "f_n"])
    bp = finite_float(params.get("backpressure_bar"))
    if not {"t_s", "x_m"} <= set(df.columns):
        return [], [], [f"{NAME}: viscous run lacks t or x; no passes"], []
    try:
        force = vf.friction_from_run(df, finite_float(params.get("hose_area_m2")))
    except ValueError as exc:
        return [], [], [f"{NAME}: viscous run: {exc}; no passes"], []
    source = "f" if "f_n" in df.columns and df["f_n"].notna().any() else "pressures"
    x = df["x_m"].to_numpy(float)
    sensor = sensor_from_params(params, "x", x)
    if source == "f":
        fsens = sensor_from_params(params, "f", force)
    else:
        a = sensor_from_params(params, "p_a", df["p_a_pa"].to_numpy(float))
        b = sensor_from_params(params, "p_b", df["p_b_pa"].to_numpy(float))
        area = finite_float(params.get("hose_area_m2"))
        fsens = type(a)(resolution=area * max(a.resolution, b.resolution),
                        noise=area * math.hypot(a.noise, b.noise), source=a.source)
    common = {"run_id": run_id, "backpressure_bar": bp, "force_source": source, **_sensor_cols(sensor)}
    dyn = fd.friction_dynamic(df["t_s"], x, force, sensor, fsens)
    dynamic = [{**common, **{k: dyn[k] for k in fd.COLUMNS}}]
    warns = [f"{NAME}: friction_dynamic: {dyn['note']}"] if dyn["note"] else []
    pts = vf.viscous_points(df["t_s"], x, force, sensor)
    # a direction the carriage moved in without a pass: why, for viscous_fits' note (issue 25)
    why = vf.missing_directions(df["t_s"], x, set(pts["direction"]), sensor)
    missing = [{"backpressure_bar": bp, "direction": d, "note": f"{run_id}: {n}"} for d, n in why.items()]
    warns = warns + [f"{NAME}: {n}" for n in why.values()]
    if pts.empty:
        return [], dynamic, warns + [f"{NAME}: no constant-velocity pass found in the viscous run "
                                     f"(position sensor {sensor.describe()})"], missing
    return [{**common, **r} for r in pts.to_dict("records")], dynamic, warns, missing


def _frame(rows: list[dict], cols: list[str]) -> pd.DataFrame:
    df = pd.DataFrame(rows, columns=cols)
    for c in ("n_samples", "plateau", "pass_index"):
        if c in df.columns:
            df[c] = df[c].astype("Int64")
    return df


def run(ctx: StageContext) -> StageOutput:
    """Analyse every leakage, breakaway and viscous run; tables and Figs. 9, 10, 12, 13, 14."""
    out = StageOutput()
    runs = ctx.runs_of(*READS.kinds)
    items = []
    if not runs.empty:
        for r in runs.itertuples(index=False):
            items.append((r.kind, r.run_id, str(ctx.samples_file(r.run_id)), run_params(r.params)))
    results = ctx.map(analyse_run, items, label=NAME) if items else []
    rows = {k: [] for k in READS.kinds}
    dynamic, missing = [], []
    for res in results:
        rows[res["kind"]] += res["rows"]
        dynamic += res.get("dynamic", [])
        missing += res.get("missing", [])
        for w in res["warnings"]:
            out.warn(res["run_id"], w)

    leak = _frame(rows["leakage"], LEAKAGE_COLS)
    # the envelope of unchanged leakage rows is taken from the previous run too (a breakaway or viscous
    # change: its per-setting groupby was ~0.3 CPU-s of such a rebuild), keyed by the rows it reads: a
    # changed hose check of a characterised setting leaves it as it was (issue 26)
    env = ctx.pooled("seal_envelope", lk.seal_envelope, lk.seal_envelope_rows(leak), LEAK_THRESHOLD_L_MIN)
    brk = _frame(rows["breakaway"], BREAKAWAY_COLS)
    summ = bk.breakaway_summary(brk)
    # pooled tables of unchanged rows are taken from the previous run (their scipy.stats import too)
    findings = ctx.pooled("breakaway_findings", bk.breakaway_findings, brk, CONFIDENCE)
    pts = _frame(rows["viscous"], VISCOUS_COLS)
    fits = ctx.pooled("viscous_fits", vf.viscous_fits, pts, missing=missing)
    trans = ctx.pooled("viscous_transition", vf.viscous_transition, pts)  # scipy.stats too
    out.tables = {"leakage_map": leak, "seal_envelope": env, "breakaway": brk, "breakaway_summary": summ,
                  "breakaway_findings": findings, "viscous_points": pts, "viscous_fits": fits,
                  "viscous_transition": trans, "friction_dynamic": _frame(dynamic, DYNAMIC_COLS)}

    for adj, name, fig_no in (("distance", "leakage_distance", 9), ("force", "leakage_force", 10)):
        if not leak.empty and (leak["adjustment"] == adj).any():
            # the rows it draws, not the table: its key is of them (a hose check is not drawn)
            out.draw(name, lk.plot_leakage_map, lk.leakage_map_plot_rows(leak, adj), adj, LEAK_THRESHOLD_L_MIN)
            sub = env[env["adjustment"] == adj]
            fallback = bool((sub["runs_used"] == lk.RUNS_HOSE_CHECKS).any())
            out.captions[name] = (f"Leak vs pressure with {adj} adjustment, one curve per setting from its "
                                  f"characterisation runs (hose checks left out), one panel per chamber "
                                  f"({PLPA_CITATION}, Fig. {fig_no}); dotted: seal threshold {LEAK_THRESHOLD_L_MIN:g} "
                                  f"l/min ANR" + ("; dashed, hollow: settings with only hose-check runs."
                                                  if fallback else "."))
    if brk["breakaway_force_n"].notna().any():
        out.draw("breakaway", bk.plot_breakaway, brk)
        out.captions["breakaway"] = ("Breakaway force vs backpressure, one series per force rate, directions P "
                                     f"and N ({PLPA_CITATION}, Fig. 12); mean +/- std.")
    if not pts.empty:
        out.draw("viscous", vf.plot_viscous, pts, fits)
        out.captions["viscous"] = ("Friction vs velocity per backpressure with Coulomb + viscous fits "
                                   f"({PLPA_CITATION}, Fig. 13).")
        if (pts["velocity_m_s"].abs() <= vf.NEAR_ZERO_MAX_M_S).any():
            out.draw("viscous_near_zero", vf.plot_near_zero, pts, trans)
            out.captions["viscous_near_zero"] = ("Friction around zero velocity with the tanh fit "
                                                 f"({PLPA_CITATION}, Fig. 14).")
    return out
