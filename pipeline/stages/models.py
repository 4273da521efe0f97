"""Stage: models and their NRMSE (issue #5).

PLPA (seed 000): third-order identification from closed-loop runs (section 2.3, Eqs. 10 and 14,
Table 2) and closed-loop step metrics (section 4, Fig. 15). PLA (seed 001): pneumatic spring
model per chamber (Eqs. 3-9, Tables 1 and 3, Figs. 8-13) and chamber pressure dynamics (Eq. 11,
Table 2).

Tables (``schemas/ddl/20_models.sql``): ``identification``, ``step_response``, ``spring_fits``,
``spring_tests``, ``spring_loop_energy``, ``pressure_dynamics``, ``pressure_steps``.

Per-run work (reading samples, decimation, fits of one run) goes through ``ctx.map`` with the
module-level :func:`analyse_run`, memoised per run. A spring run's result is its sufficient statistics
(:class:`analyses.pla_spring_fit.SpringStats`, not its samples): the joint spring fit of a chamber adds
them in this process (milliseconds; one changed run costs its own analysis), and only the runs a
figure draws are read again (:func:`spring_figure_run`, memoised). The pressure fits go through
``ctx.map`` with items naming the runs they read (:func:`fit_pressure_item`): memoised until one of
their runs changes.
A run that cannot be analysed gives NULLs and a warning on the run, never an exception.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re

import numpy as np
import pandas as pd

from analyses import identification as ident
from analyses import pla_spring as spring
from analyses import pla_spring_fit as spring_fit
from analyses import pla_spring_plots as spring_plots
from analyses import pressure_dynamics as pdyn
from analyses import step_response as stepr
from analyses.quality import sensor_from_params
from schemas.papers import PLA_CITATION, PLPA_CITATION
from pipeline.stages import Reads, StageContext, StageOutput, read_samples
from pipeline.stages.values import finite_float, run_params

NAME = "models"
READS = Reads(kinds=("identification", "step", "spring", "pressure_step"))
WRITES = ("identification", "step_response", "spring_fits", "spring_tests", "spring_loop_energy",
          "pressure_dynamics", "pressure_steps")

#: Text columns of the tables (the others are numbers).
TEXT_COLS = ("run_id", "chamber", "direction", "model", "note", "level", "campaign", "rig", "part_kind", "part_id")
#: Identification runs drawn one figure each, at most (sorted by run_id).
MAX_ID_FIGURES = 6
#: Parts at one age drawn one step figure each, at most (in table order).
MAX_PART_FIGURES = 6
#: Steps drawn in the Fig. 15-like figure, at most.
MAX_STEP_CURVES = 12

ID_COLS = ["run_id", "wn_rad_s", "zeta", "k_lin_m_v_s", "fit_pct", "kp_v_m", "id_sample_rate_hz", "n_samples_id",
           "note"]
STEP_COLS = ["run_id", "step_mm", "overshoot_pct", "settling_time_s", "rise_time_s", "steady_state_error_mm",
             "position_resolution_mm", "t_step_s", "settled", "note"]
FIT_COLS = ["chamber", "n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m", "n_tests", "max_nrmse_pct",
            "seed_n_polytropic", "seed_ae_m2", "seed_epsilon_m2", "seed_delta_n_m", "note"]
TEST_COLS = ["run_id", "chamber", "p0_bar_abs", "amplitude_mm", "frequency_hz", "nrmse_pct", "note"]
#: The columns of ``spring_loop_energy`` its figure draws (:func:`analyses.pla_spring_plots.plot_loop_energy`).
ENERGY_DRAWN = ("chamber", "amplitude_mm", "frequency_hz", "loop_energy_j")
ENERGY_COLS = ["run_id", "chamber", "p0_bar_abs", "amplitude_mm", "frequency_hz", "n_cycles", "loop_energy_j",
               "model_loop_energy_j", "structural_energy_j"]
PD_COLS = ["chamber", "direction", "wn_rad_s", "zeta", "nrmse_pct", "n_steps", "tau_s", "model", "note", "level",
           "campaign", "rig", "part_kind", "part_id", "part_age_h", "part_distance_km", "wn_change_pct",
           "zeta_change_pct", "tau_change_pct", "campaigns", "n_runs"]
PSTEP_COLS = ["run_id", "chamber", "direction", "t_step_s", "p_from_bar", "p_to_bar", "nrmse_pct", "p_start_bar",
              "note"]


def _missing(df: pd.DataFrame, cols) -> list[str]:
    return [c for c in cols if c not in df.columns or df[c].isna().all()]


# -- per run -----------------------------------------------------------------------------------

def analyse_run(item: tuple) -> dict:
    """Analyse one run (module level, picklable, for ``ctx.map``).

    Parameters
    ----------
    item : tuple
        ``(kind, run_id, samples_path, params)``, ``params`` a dict or its JSON text
        (:func:`_params_text`).

    Returns
    -------
    dict
        ``kind``, ``run_id``, ``rows`` (for the kind's per-run table), ``warnings`` (list of str) and
        ``extra`` (figure data, prepared spring run or pressure steps).
    """
    kind, run_id, path, params = item
    params = run_params(params)
    try:
        fn = {"identification": _identification, "step": _step, "spring": _spring,
              "pressure_step": _pressure_step}[kind]
        rows, warns, extra = fn(run_id, path, params)
    except Exception as exc:  # an unforeseen input: NULLs and a warning, never a failed rebuild
        rows = [{"run_id": run_id}] if kind in ("identification", "step", "spring") else []
        if kind == "spring":
            rows[0]["chamber"] = params.get("chamber")
        warns, extra = [f"{NAME}: {kind} analysis failed: {type(exc).__name__}: {exc}"], None
    return {"kind": kind, "run_id": run_id, "rows": rows, "warnings": warns, "extra": extra}


def _identification(run_id, path, params):
    kp = finite_float(params.get("kp_v_m"))
    rate = finite_float(params.get("id_sample_rate_hz"), 50.0)
    row = {"run_id": run_id, "wn_rad_s": None, "zeta": None, "k_lin_m_v_s": None, "fit_pct": None,
           "kp_v_m": kp, "id_sample_rate_hz": rate, "n_samples_id": None, "note": None}
    df = read_samples(path, ["t_s", "x_m", "u_d_v", "x_ref_m"])
    miss = _missing(df, ["t_s", "x_m", "u_d_v", "x_ref_m"])
    if miss:
        row["note"] = f"lacks {', '.join(miss)}"
        return [row], [f"{NAME}: identification run lacks {', '.join(miss)}; not identified"], None
    if kp is None or kp <= 0:
        row["note"] = "no positive kp_v_m"
        return [row], [f"{NAME}: identification run without a positive kp_v_m; not identified"], None
    df = df[np.isfinite(df.to_numpy(float)).all(axis=1)]  # no NaN, no +-inf (a logger's overflow; dropna keeps it)
    x, ud = df["x_m"].to_numpy(), df["u_d_v"].to_numpy()
    res = ident.identify_third_order(df["t_s"].to_numpy(), x, ud, df["x_ref_m"].to_numpy(), kp, rate,
                                     x_sensor=sensor_from_params(params, "x", x),
                                     ud_sensor=sensor_from_params(params, "u_d", ud))
    row["n_samples_id"] = len(res.x_m)
    if not res.ok:
        row.update(note=res.note or res.message, fit_pct=finite_float(res.fit_pct))
        return [row], [f"{NAME}: identification: {res.note or res.message}; not identified"], None
    row.update(wn_rad_s=res.wn_rad_s, zeta=res.zeta, k_lin_m_v_s=res.k_lin_m_v_s, fit_pct=finite_float(res.fit_pct),
               id_sample_rate_hz=1.0 / res.dt_s)
    warns = [f"{NAME}: identification: {res.message}"] if res.message else []
    return [row], warns, res


def _step(run_id, path, params):
    null = {"run_id": run_id, **{c: None for c in STEP_COLS[1:]}}
    df = read_samples(path, ["t_s", "x_m", "x_ref_m"])
    miss = _missing(df, ["t_s", "x_m", "x_ref_m"])
    if miss:
        return [dict(null, note=f"lacks {', '.join(miss)}")], [f"{NAME}: step run lacks {', '.join(miss)}; no step metrics"], None
    df = df[np.isfinite(df.to_numpy(float)).all(axis=1)]  # no NaN, no +-inf (a logger's overflow; dropna keeps it)
    if len(df) < 10:
        return [dict(null, note="too short")], [f"{NAME}: step run too short ({len(df)} samples); no step metrics"], None
    t, x, r = (df[c].to_numpy() for c in ("t_s", "x_m", "x_ref_m"))
    m = stepr.step_response_metrics(t, x, r, x_sensor=sensor_from_params(params, "x", x),
                                    ref_sensor=sensor_from_params(params, "x_ref", r))
    if m.empty:
        null["note"] = "no step of the reference beyond its sensor's resolution and noise"
        return [null], [f"{NAME}: no step of the reference found; no step metrics"], None
    rows, curves, warns = [], [], []
    for s in m.itertuples(index=False):
        rows.append({"run_id": run_id, "step_mm": s.step_mm, "overshoot_pct": finite_float(s.overshoot_pct),
                     "settling_time_s": finite_float(s.settling_time_s), "rise_time_s": finite_float(s.rise_time_s),
                     "steady_state_error_mm": finite_float(s.steady_state_error_mm),
                     "position_resolution_mm": finite_float(s.position_resolution_mm), "t_step_s": s.t_step_s,
                     "settled": bool(s.settled), "note": s.note})
        if s.note:
            warns.append(f"{NAME}: step at t={s.t_step_s:g} s: {s.note}")
        if not np.isfinite(s.rise_time_s) and s.note and "sensor floor" in s.note:
            continue
        seg = slice(s.i_start, s.i_end)
        stride = max(1, (s.i_end - s.i_start) // 3000)
        ref = r[s.i_start]
        step_m = s.step_mm / 1e3
        curves.append({"t": (t[seg] - s.t_step_s)[::stride], "error_pct": (100 * (ref - x[seg]) / step_m)[::stride],
                       "label": f"{run_id} @ {s.t_step_s:g} s ({s.step_mm:+g} mm)", "step_mm": s.step_mm})
    return rows, warns, curves


def _spring(run_id, path, params):
    row, warns, run = _spring_prepared(run_id, path, params)
    if run is None:
        return [row], warns, None
    stats = spring_fit.spring_run_stats(run)   # what the joint fit needs of the run, not its samples
    if not stats.ok:
        row["note"] = stats.message
        return [row], [f"{NAME}: spring run: {stats.message}; not fitted"], None
    return [row], [], stats


def _spring_prepared(run_id, path, params):
    """The spring run's ``spring_tests`` row, warnings and :class:`analyses.pla_spring.SpringRun` (None
    when it cannot be used)."""
    chamber = str(params.get("chamber") or "").strip().lower()
    null = {"run_id": run_id, "chamber": chamber or None, "p0_bar_abs": None,
            "amplitude_mm": finite_float(params.get("amplitude_mm")), "frequency_hz": finite_float(params.get("frequency_hz")),
            "nrmse_pct": None, "note": None}
    if chamber not in spring.PRESSURE_SIGN:
        null["note"] = "chamber must be front or rear"
        return null, [f"{NAME}: spring run chamber must be front or rear, got {chamber or 'none'}; not fitted"], None
    df = read_samples(path, ["t_s", "d_m", "f_n", "p_pa"])
    miss = _missing(df, ["t_s", "d_m", "f_n", "p_pa"])
    if miss:
        null["note"] = f"lacks {', '.join(miss)}"
        return null, [f"{NAME}: spring run lacks {', '.join(miss)}; not fitted"], None
    amp = finite_float(params.get("amplitude_mm"))
    d, f = df["d_m"].to_numpy(), df["f_n"].to_numpy()
    run = spring.prepare_spring_run(run_id, df["t_s"].to_numpy(), d, f,
                                    df["p_pa"].to_numpy(), chamber, finite_float(params.get("frequency_hz")),
                                    amp / 1e3 if amp else None, finite_float(params.get("stroke_mm"), 40.0) / 1e3,
                                    finite_float(params.get("p_atm_pa"), spring.P_ATM_PA),
                                    d_sensor=sensor_from_params(params, "d", d),
                                    f_sensor=sensor_from_params(params, "f", f))
    null["p0_bar_abs"] = finite_float(run.p0_abs / 1e5) if np.isfinite(run.p0_abs) else None
    if not run.ok:
        null["note"] = run.message
        return null, [f"{NAME}: spring run: {run.message}; not fitted"], None
    null.update(amplitude_mm=run.amplitude_m * 1e3, frequency_hz=run.frequency_hz)
    return null, [], run


def spring_figure_run(item: tuple) -> spring.SpringRun | None:
    """The prepared spring run (its samples) of one run drawn in a figure (for ``ctx.map``; item as
    :func:`analyse_run`'s)."""
    _, run_id, path, params = item
    try:
        return _spring_prepared(run_id, path, run_params(params))[2]
    except Exception:  # analyse_run said why; the figure goes without the run
        return None


def _pressure_step(run_id, path, params):
    chamber = str(params.get("chamber") or "").strip() or None   # any name the rig gives it
    df = read_samples(path, ["t_s", "p_pa", "p_ref_pa"])
    miss = _missing(df, ["t_s", "p_pa", "p_ref_pa"])
    if miss:
        return [], [f"{NAME}: pressure_step run lacks {', '.join(miss)}; no steps"], None
    df = df[np.isfinite(df.to_numpy(float)).all(axis=1)]  # no NaN, no +-inf (a logger's overflow; dropna keeps it)
    p, p_ref = df["p_pa"].to_numpy(), df["p_ref_pa"].to_numpy()
    steps = pdyn.split_pressure_steps(df["t_s"].to_numpy(), p, p_ref, run_id, chamber or "",
                                      ref_sensor=sensor_from_params(params, "p_ref", p_ref),
                                      p_sensor=sensor_from_params(params, "p", p))
    if not steps:
        return [], [f"{NAME}: no set-point step found in the pressure_step run"], None
    if chamber is None:
        return [], [f"{NAME}: pressure_step run without chamber; its steps are not fitted"], None
    return [], [], steps


# -- per chamber ----------------------------------------------------------------------------

def _memoised_here(ctx, func, items: list, here, label: str = "") -> list:
    """``[func(item) for item in items]``, each from the stage's memo when it holds it, else
    ``here(item)``: in this process, from data the stage already holds (the runs' results, from the
    memo or computed tonight), with the value ``func(item)`` would give from the files (issue 26:
    a joint fit whose runs did not change is not done again, one that must be does not read its
    runs again nor start workers that import scipy again)."""
    memo = getattr(ctx, "memo", None)
    if memo is None:
        return [here(item) for item in items]
    return memo.map(lambda _func, todo, _label: [here(item) for item in todo], func, items, label)


def fit_spring_runs(item: tuple) -> spring_fit.SpringFit:
    """``(chamber, runs)`` -> the chamber's joint fit (:func:`fit_spring_item`) of ``runs`` (items as
    :func:`analyse_run`'s, in run_id order), read from their samples: the memo key of the fit (its
    stage computes it from the runs' statistics it already holds)."""
    chamber, runs = item
    return fit_spring_item((chamber, [r["extra"] for r in map(analyse_run, runs) if r["extra"] is not None]))


class _DigestKeyed(tuple):
    """A :func:`fit_spring_runs` item ``(chamber, runs)`` memoised by ``memo_key``: the chamber and the sha256 of its
    runs' items as JSON (samples relative to the warehouse, as the memo's key names them): the same inputs. The memo's
    walk of ~3,300 items a chamber cost ~0.05 CPU-s a chamber at 10,000 runs; this digest ~5 ms (issue 26)."""


def _fit_item(chamber: str, runs: tuple, warehouse) -> tuple:
    """:class:`_DigestKeyed` ``(chamber, runs)``; the plain tuple (the memo's walk) if a run's params are not JSON."""
    prefix = os.fspath(warehouse).rstrip(os.sep) + os.sep if warehouse is not None else None
    try:
        text = json.dumps([[kind, rid, path[len(prefix):] if prefix and path.startswith(prefix) else ["abs", path],
                            params] for kind, rid, path, params in runs],
                          sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError, AttributeError):
        return (chamber, runs)
    item = _DigestKeyed((chamber, runs))
    item.memo_key = ("spring runs", chamber, hashlib.sha256(text.encode()).hexdigest())
    return item


def fit_spring_item(item: tuple) -> spring_fit.SpringFit:
    """``(chamber, stats)`` -> :class:`analyses.pla_spring_fit.SpringFit` from the runs' sufficient statistics
    (:class:`analyses.pla_spring_fit.SpringStats`): milliseconds, whatever the runs' lengths."""
    chamber, stats = item
    try:
        return spring_fit.fit_spring_stats(stats)
    except Exception as exc:  # never fail the rebuild on a fit
        return spring_fit.SpringFit(chamber, message=f"fit failed: {type(exc).__name__}: {exc}")


def fit_pressure_item(item: tuple) -> pdyn.PressureFit:
    """``(chamber, direction, runs)`` -> :class:`analyses.pressure_dynamics.PressureFit` of the steps in
    that direction of ``runs`` (items as :func:`analyse_run`'s, in the group's order; read again here,
    so the item names every input and the memo keeps the fit until one of its runs changes)."""
    chamber, direction, runs = item
    return _fit_pressure_runs(chamber, direction, runs,
                              lambda run: _pressure_step(run[1], run[2], run_params(run[3]))[2])


def _fit_pressure_runs(chamber: str, direction: str, runs, steps_of) -> pdyn.PressureFit:
    """The fit of :func:`fit_pressure_item`, the steps of each run given by ``steps_of(run item)``."""
    steps = []
    try:
        for run in runs:
            steps += [s for s in (steps_of(run) or []) if s.direction == direction]
        return pdyn.fit_pressure_dynamics(steps, chamber, direction)
    except Exception as exc:
        return pdyn.PressureFit(chamber, direction, n_steps=len(steps),
                                message=f"fit failed: {type(exc).__name__}: {exc}")


def _params_text(params: dict) -> str | dict:
    """A run's params as canonical JSON text (sorted keys: the same dict, the same text), for the
    items of ``ctx.map``: the memo keys a string at once, where a dict costs it a walk of every value
    (issue 26: ~1 s of the stage at 10,000 runs, its items keyed twice: by run and in the joint fits).
    The dict itself when it is not plain JSON."""
    try:
        return json.dumps(params, sort_keys=True, separators=(",", ":"))
    except (TypeError, ValueError):
        return params


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:80]


def _frame(rows, cols, ints=(), bools=()) -> pd.DataFrame:
    df = pd.DataFrame(rows, columns=cols)
    for c in ints:
        df[c] = df[c].astype("Int64")
    for c in bools:
        df[c] = df[c].astype("boolean")
    for c in cols:
        if c not in ints and c not in bools and c not in TEXT_COLS and c != "campaigns":
            df[c] = pd.to_numeric(df[c], errors="coerce").astype("float64")
    return df


def run(ctx: StageContext) -> StageOutput:
    """Identification, step metrics, spring fits and pressure dynamics of every run of the kinds it reads."""
    out = StageOutput()
    runs = ctx.runs_of(*READS.kinds)
    items = [(r.kind, r.run_id, str(ctx.samples_file(r.run_id)), _params_text(run_params(r.params)))
             for r in runs.itertuples(index=False)] if not runs.empty else []
    results = ctx.map(analyse_run, items, label=NAME) if items else []
    by_kind: dict[str, list[dict]] = {k: [] for k in READS.kinds}
    for res in results:
        by_kind[res["kind"]].append(res)
        for w in res["warnings"]:
            out.warn(res["run_id"], w)

    _identification_outputs(out, by_kind["identification"])
    _step_outputs(out, by_kind["step"])
    _spring_outputs(ctx, out, by_kind["spring"], {i[1]: i for i in items if i[0] == "spring"})
    _pressure_outputs(ctx, out, by_kind["pressure_step"], {i[1]: i for i in items if i[0] == "pressure_step"})
    return out


def _identification_outputs(out, results):
    rows = [row for r in results for row in r["rows"]]
    out.tables["identification"] = _frame(rows, ID_COLS, ints=("n_samples_id",))
    fitted = [r for r in results if r["extra"] is not None]
    for r in fitted[:MAX_ID_FIGURES]:
        name = f"identification_{_slug(r['run_id'])}"
        out.draw(name, ident.plot_identification, r["extra"], title=f"{r['run_id']}: measured vs model (Eq. 14)")
        out.captions[name] = (f"Identification run {r['run_id']}: position at the identification rate, measured "
                              "(anti-aliased, decimated) and simulated by the output-error model from the measured "
                              f"u_d and x_ref ({PLPA_CITATION}, section 2.3).")


def _step_outputs(out, results):
    rows = [row for r in results for row in r["rows"]]
    out.tables["step_response"] = _frame(rows, STEP_COLS, bools=("settled",))
    curves = [c for r in results if r["extra"] for c in r["extra"]][:MAX_STEP_CURVES]
    if curves:
        out.draw("step_errors", stepr.plot_step_errors, curves,
                 title=f"Closed-loop steps: position ({PLPA_CITATION}, Fig. 15)")
        out.captions["step_errors"] = ("Closed-loop steps: position vs time since the step; inset: error in % of the "
                                       f"step with the 2 % band ({PLPA_CITATION}, Fig. 15).")


def _spring_outputs(ctx, out, results, items):
    rows = {r["run_id"]: dict(r["rows"][0]) for r in results if r["rows"]}
    prepared = [r["extra"] for r in results if r["extra"] is not None]
    chambers = sorted({p.chamber for p in prepared})
    groups = [(c, sorted((p for p in prepared if p.chamber == c), key=lambda p: p.run_id)) for c in chambers]
    # a chamber's fit is kept by its runs (every spring run of the chamber: one whose statistics are
    # unusable changes nothing, but names its input), done here from the statistics at hand
    named = {c: tuple(items[rid] for rid in sorted(r["run_id"] for r in results if r["rows"]
                                                   and r["rows"][0].get("chamber") == c)) for c in chambers}
    held = {c: g for c, g in groups}
    wh = getattr(ctx, "warehouse", None)
    fits = dict(zip(chambers, _memoised_here(ctx, fit_spring_runs, [_fit_item(c, named[c], wh) for c in chambers],
                                             lambda item: fit_spring_item((item[0], held[item[0]])),
                                             label=f"{NAME}: spring fits")))
    fit_rows, energy = [], []
    for chamber, group in groups:
        fit = fits[chamber]
        if not fit.ok:
            for p in group:
                out.warn(p.run_id, f"{NAME}: spring fit of the {chamber} chamber not reported: "
                                   f"{fit.note or fit.message}")
        elif fit.message:
            for p in group:
                out.warn(p.run_id, f"{NAME}: spring fit of the {chamber} chamber: {fit.message}")
        seeds = fit.seeds or {}
        nr = [v for v in fit.nrmse_pct.values() if np.isfinite(v)]
        fit_rows.append({"chamber": chamber, "n_polytropic": fit.n_polytropic, "ae_m2": fit.ae_m2,
                         "epsilon_m2": fit.epsilon_m2, "delta_n_m": fit.delta_n_m, "n_tests": fit.n_tests,
                         "max_nrmse_pct": max(nr) if nr else None, "note": fit.note,
                         **{f"seed_{k}": seeds.get(k) for k in ("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m")}})
        for p in group:
            rows[p.run_id]["nrmse_pct"] = finite_float(fit.nrmse_pct.get(p.run_id))
            rows[p.run_id]["note"] = fit.test_notes.get(p.run_id) or (
                None if fit.ok else f"the {chamber} chamber's fit is not reported: {fit.note or fit.message}")
            model_u = fit.model_loop_energy_j.get(p.run_id, float("nan")) if fit.ok else float("nan")
            energy.append({"run_id": p.run_id, "chamber": chamber, "p0_bar_abs": p.p0_abs / 1e5,
                           "amplitude_mm": p.amplitude_m * 1e3, "frequency_hz": p.frequency_hz,
                           "n_cycles": p.cycles, "loop_energy_j": finite_float(p.loop_energy_j),
                           "model_loop_energy_j": finite_float(model_u),
                           "structural_energy_j": finite_float(math.pi * fit.delta_n_m * p.amplitude_m ** 2)})
    out.tables["spring_fits"] = _frame(fit_rows, FIT_COLS, ints=("n_tests",))
    out.tables["spring_tests"] = _frame([rows[k] for k in sorted(rows)], TEST_COLS)
    out.tables["spring_loop_energy"] = _frame(energy, ENERGY_COLS, ints=("n_cycles",))
    for chamber, group in groups:
        fit = fits[chamber]
        if fit.ok:   # only the runs drawn are read again (their prepared samples memoised)
            shown = [items[rid] for rid in spring_plots.figure_runs(group)]
            runs = [r for r in ctx.map(spring_figure_run, shown, label=f"{NAME}: spring figures") if r is not None]
            name = f"spring_loops_{chamber}"
            out.draw(name, spring_plots.plot_spring_loops, runs, _drawn_fit(fit))
            out.captions[name] = (f"PLA {chamber} chamber: force-displacement loops, experimental vs fitted model, "
                                  f"for the tests of {PLA_CITATION}, Figs. 8-13 (closest available runs).")
    if energy:
        out.draw("spring_loop_energy", spring_plots.plot_loop_energy, out.tables["spring_loop_energy"][list(ENERGY_DRAWN)],
                 {c: _drawn_fit(f) for c, f in fits.items()})
        out.captions["spring_loop_energy"] = ("Energy dissipated per cycle (loop area) vs displacement amplitude and "
                                              "vs frequency; lines: structural part pi delta D^2 of the fits.")


def _drawn_fit(fit: spring_fit.SpringFit) -> spring_fit.SpringFit:
    """The fit as the spring figures use it (its parameters), without the per-test dicts (NRMSE,
    model loop energy, notes: thousands of entries at 10,000 runs) that the figure's key would hash
    (issue 26); the same figure."""
    return dataclasses.replace(fit, seeds={}, nrmse_pct={}, test_notes={}, se={}, model_loop_energy_j={})


def _run_parts(ctx) -> dict:
    """Per pressure_step run: campaign, rig, and the part under test with its age
    (:class:`analyses.pressure_dynamics.RunPart`) from the run's metadata."""
    runs = ctx.runs_of("pressure_step")
    out = {}
    for r in (runs.itertuples(index=False) if not runs.empty else ()):
        params = run_params(getattr(r, "params", None))
        valve, hose = (str(params.get(k) or "").strip() or None for k in ("valve_id", "hose_id"))
        kind = "valve" if valve else "hose" if hose else None
        out[r.run_id] = pdyn.RunPart(str(getattr(r, "campaign", "") or ""), str(getattr(r, "rig", "") or ""),
                                     kind, valve or hose, finite_float(params.get("age_h")) if kind else None,
                                     finite_float(params.get("distance_km")) if kind else None)
    return out


def _group_label(g) -> str:
    where = f"{g.rig or 'no rig'} in {g.campaign or 'no campaign'}"
    if g.level == "part":
        age = ", ".join(x for x in (f"{g.age_h:g} h" if g.age_h is not None else "",
                                    f"{g.distance_km:g} km" if g.distance_km is not None else "") if x)
        where = f"{g.part_kind} {g.part_id}{' at ' + age if age else ''}, {where}"
    return f"({g.chamber}, {g.direction}; {where})"


def _pressure_outputs(ctx, out, results, items):
    """``pressure_dynamics`` and ``pressure_steps``, and their figures, from the pressure_step runs' steps."""
    grouped, fits = _pressure_fits(ctx, results, items)
    _pressure_tables(out, grouped, fits)
    _draw_rig_pressures(out, grouped, fits)
    _draw_part_pressures(out, grouped, fits)
    _draw_pressure_ageing(out)


def _pressure_fits(ctx, results, items) -> tuple[dict, dict]:
    """The steps grouped (:class:`analyses.pressure_dynamics.StepGroup` -> steps, by its sort key) and
    each group's :class:`analyses.pressure_dynamics.PressureFit`."""
    steps = [s for r in results if r["extra"] for s in r["extra"]]
    parts = _run_parts(ctx)
    grouped = pdyn.group_pressure_steps(steps, parts)
    # a rig that logged a chamber in one direction only still gets a row for the other
    for g in [g for g in grouped if g.level == "rig"]:
        for d in ("charge", "discharge"):
            grouped.setdefault(pdyn.StepGroup("rig", g.campaign, g.rig, g.chamber, d), [])
    grouped = {g: grouped[g] for g in sorted(grouped, key=pdyn.StepGroup.sort_key)}
    todo = [(g, (g.chamber, g.direction, [items[rid] for rid in dict.fromkeys(s.run_id for s in v)]))
            for g, v in grouped.items() if v]
    steps_of = {r["run_id"]: r["extra"] for r in results}
    fits = dict(zip((g for g, _ in todo), _memoised_here(
        ctx, fit_pressure_item, [i for _, i in todo],
        lambda i: _fit_pressure_runs(i[0], i[1], i[2], lambda run: steps_of.get(run[1])),
        label=f"{NAME}: pressure fits")))
    for g in grouped:
        fits.setdefault(g, pdyn.PressureFit(g.chamber, g.direction, message="no steps",
                                            note=f"no {g.direction} step in the runs"))
    return grouped, fits


def _pressure_tables(out, grouped, fits) -> None:
    """The rows of ``pressure_dynamics`` (one per group) and ``pressure_steps`` (each step in its finest group)."""
    changes = pdyn.age_changes(fits)
    finest = {}   # (run_id, direction) -> its finest group (the part's age when it names one)
    for g, group in grouped.items():
        for s in group:
            if g.level == "part" or (s.run_id, g.direction) not in finest:
                finest[(s.run_id, g.direction)] = g
    rows, step_rows = [], []
    for g, group in grouped.items():
        f = fits[g]
        mine = sorted({s.run_id for s in group if finest.get((s.run_id, g.direction)) == g})
        if group and not f.ok:
            for rid in mine:
                out.warn(rid, f"{NAME}: pressure dynamics {_group_label(g)} not reported: {f.note or f.message}")
        ch = changes.get(g, {})
        rows.append({"chamber": g.chamber, "direction": g.direction, "wn_rad_s": finite_float(f.wn_rad_s),
                     "zeta": finite_float(f.zeta), "nrmse_pct": finite_float(f.nrmse_pct), "n_steps": f.n_steps,
                     "tau_s": finite_float(f.tau_s), "model": f.model, "note": f.note, "level": g.level,
                     "campaign": g.campaign, "rig": g.rig, "part_kind": g.part_kind, "part_id": g.part_id,
                     "part_age_h": g.age_h, "part_distance_km": g.distance_km,
                     **{k: finite_float(ch.get(k)) for k in ("wn_change_pct", "zeta_change_pct", "tau_change_pct")},
                     "campaigns": [g.campaign], "n_runs": len({s.run_id for s in group})})
        for s, nr in zip(group, f.step_nrmse_pct or [None] * len(group)):
            if finest.get((s.run_id, g.direction)) != g:
                continue
            note = s.note or (None if f.ok else f"the {_group_label(g)} fit is not reported")
            step_rows.append({"run_id": s.run_id, "chamber": g.chamber, "direction": g.direction,
                              "t_step_s": s.t_step_s, "p_from_bar": s.p_ref_before_pa / 1e5,
                              "p_to_bar": s.p_ref_pa / 1e5, "nrmse_pct": finite_float(nr),
                              "p_start_bar": s.p_start_pa / 1e5, "note": note})
    out.tables["pressure_dynamics"] = _frame(rows, PD_COLS, ints=("n_steps", "n_runs"))
    out.tables["pressure_steps"] = _frame(sorted(step_rows, key=lambda r: (r["run_id"], r["t_step_s"])), PSTEP_COLS)


def _draw_rig_pressures(out, grouped, fits) -> None:
    """Per rig and chamber: every step of the rig pooled, measured vs the chosen models."""
    rigs = sorted({(g.campaign, g.rig, g.chamber) for g in grouped if g.level == "rig"})
    for campaign, rig, c in rigs:
        mine = [g for g in grouped if g.level == "rig" and (g.campaign, g.rig, g.chamber) == (campaign, rig, c)]
        cf = {g.direction: fits[g] for g in mine if grouped[g]}
        if any(f.ok for f in cf.values()):
            alone = sum(1 for r in rigs if r[2] == c) == 1
            pla = alone and c in ("front", "rear")   # the paper's chambers: the figure they always had
            name = f"pressure_steps_{_slug(c)}" + ("" if alone else f"_{_slug(campaign)}_{_slug(rig)}")
            out.draw(name, pdyn.plot_pressure_steps, [s for g in mine for s in grouped[g]], cf,
                     title="" if pla else f"{c} chamber of {rig} ({campaign}), every step of the rig pooled: "
                                          "measured vs the chosen model (first order or Eq. 11)")
            out.captions[name] = (f"{'PLA ' + c + ' chamber' if pla else f'{c} chamber of {rig} ({campaign})'}: "
                                  "pressure (bar gauge) after set-point steps, measured vs the "
                                  "model chosen per direction by BIC: first order or the second order of Eq. 11 "
                                  f"({PLA_CITATION}, Fig. 14, Table 2), every step of the rig pooled (level 'rig'). Grey: "
                                  "steps too small for the pressure sensor.")


def _draw_part_pressures(out, grouped, fits) -> None:
    """Per part under test and age (at most MAX_PART_FIGURES): measured vs the part's own models."""
    parts = sorted({(g.campaign, g.rig, g.chamber, g.part_kind, g.part_id, g.age_h, g.distance_km)
                    for g in grouped if g.level == "part"}, key=lambda k: pdyn.StepGroup("part", *k[:3], "", *k[3:])
                   .sort_key())
    drawn = 0
    for key in parts:
        mine = [g for g in grouped if g.level == "part"
                and (g.campaign, g.rig, g.chamber, g.part_kind, g.part_id, g.age_h, g.distance_km) == key]
        cf = {g.direction: fits[g] for g in mine if grouped[g]}
        if not any(f.ok for f in cf.values()) or drawn >= MAX_PART_FIGURES:
            continue
        drawn += 1
        g0 = mine[0]
        age = "_".join(x for x in (f"{g0.age_h:g}h" if g0.age_h is not None else "",
                                   f"{g0.distance_km:g}km" if g0.distance_km is not None else "") if x)
        name = f"pressure_steps_{_slug(g0.chamber)}_{_slug(g0.part_id)}" + (f"_{_slug(age)}" if age else "")
        if name in out.figures:   # the same part at the same age on another rig or in another campaign
            name += f"_{_slug(g0.campaign)}_{_slug(g0.rig)}"
        label = _group_label(g0).split("; ", 1)[1].rstrip(")")
        out.draw(name, pdyn.plot_pressure_steps, [s for g in mine for s in grouped[g]], cf,
                 title=f"{g0.chamber} chamber, {label}: measured vs the chosen model (first order or Eq. 11)")
        out.captions[name] = (f"{g0.chamber} chamber, {label}: pressure (bar gauge) after set-point steps, measured "
                              "vs the model fitted to this part at this age alone (level 'part').")


def _draw_pressure_ageing(out) -> None:
    """wn, zeta and tau of each part against its age, when any part was fitted at an age."""
    table = out.tables["pressure_dynamics"]
    aged = table[(table["level"] == "part") & (table["part_age_h"].notna() | table["part_distance_km"].notna())
                 & (table["wn_rad_s"].notna() | table["tau_s"].notna())]
    if len(aged):
        out.draw("pressure_ageing", pdyn.plot_pressure_ageing, aged.reset_index(drop=True))
        out.captions["pressure_ageing"] = (
            "Pressure dynamics of each part under test (the runs' valve_id / hose_id) against its age (the runs' "
            "age_h, else distance_km): wn, zeta (second order) and tau (first order) fitted per part, age, chamber "
            "and direction (solid: charge, dashed: discharge); table pressure_dynamics, level = 'part'.")
