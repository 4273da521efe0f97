"""Stage: remaining life of every running hose, its backtest, and the verdict under other failure definitions (issue 24).

Three tables, from ``hose_life`` and ``hose_leak_growth`` (the durability stage's),
``leakage_map`` (the leak-flow sensor of each leakage run), ``life_verdict`` (the decision's
``max_failures``) and the plan (``leak_limit_l_min``, ``leak_pressure_bar``, ``confidence``,
``margin``, ``alpha``, ``spending``, ``rupture_shape``):

* ``hose_rul``: per running hose and method (``weibull``, ``degradation``) the median and the
  prediction interval at the plan's confidence of the distance it has left
  (:func:`analyses.remaining_life_group.remaining_life`; Meeker & Escobar 1998, ch. 12 and 13; Lu &
  Meeker 1993);
* ``rul_backtest``: per (hose type, adjustment, method) how often the intervals the models would
  have given each failed hose at 50 % and 80 % of its life held its true remaining life
  (:func:`analyses.remaining_life_group.rul_backtest`, :func:`analyses.remaining_life_group.backtest_summary`);
* ``decision_sensitivity``: per hose type and failure definition (the logbook's failures; the
  leak path's first crossing of the plan's limit, at 0.5x and 2x that limit,
  :func:`analyses.leak_degradation.leak_crossing_lives`) the life ratio with its profile bounds
  (:func:`analyses.life_effect.life_effect`) and the verdict the decision's rule reads on all of
  that definition's data now (:func:`analyses.decision.decide`: the sequential boundary at the
  definition's information fraction in the plan's design with a look at every failure, the
  profile-likelihood check; Lan & DeMets 1983, Jennison & Turnbull 2000). The leak-limit
  definitions are read under the life model the degradation model induces (docs/decision.md,
  "The sensitivity's life model"): a lognormal wear rate makes the crossing distances lognormal
  (Lu & Meeker 1993), so their ratio, bounds and verdict come from the common-sigma lognormal
  (:func:`analyses.life_effect_lognormal.lognormal_life_effect`), the logbook's from
  :func:`analyses.life_effect.life_effect`.

Decisions (docs/decision.md, "Remaining life: the stage")
---------------------------------------------------------
* **Grain.** The models are fitted per (hose type, adjustment): force- and distance-set hoses
  wear at different rates (the lab's question), pooling them would mix two wear populations.
  Each group is two ``ctx.map`` items (plain data naming every input): its ``weibull`` rows
  (:func:`rul_weibull`: the hoses' lives and the confidence) and its ``degradation`` rows
  (:func:`rul_group`: the lives, the leak path, the sensor and the settings), so groups run in
  the stage's worker pool and what did not change is read from the memo: a changed leakage check
  recomputes its group's ``degradation`` rows only (issue 26: the life model's bisections were
  most of such a change's work here). The leak columns of a ``weibull`` row (the leak now, the
  points, the plan's limit and pressure) are the hose's, taken from its ``degradation`` row.
* **The leak path.** Of each (hose, leakage run), the plateau whose ``pressure_bar`` is nearest
  the plan's ``leak_pressure_bar``, accepted when within half the plateau spacing (the median
  step between a run's successive plateaus, over the hose type's runs): the target is then nearer
  this plateau than any neighbour would be. One point per (hose, run), the mean over chambers.
  Runs with one plateau each give no spacing: no path, said in the note.
* **The sensor.** The leak-flow sensor's resolution and noise from the ``sensors`` text the
  PLPA characterisation stage writes on each ``leakage_map`` row (stated by the rig, else
  estimated from the record), converted to l/min ANR; the coarsest among the runs of the path.
* **Plan unset** (``leak_limit_l_min`` or ``leak_pressure_bar`` None for a hose type): the
  ``weibull`` rows as usual, the ``degradation`` rows and the leak definitions NULL with the note
  :data:`NO_LEAK_PLAN`.
* Seeds: :func:`analyses.remaining_life.data_seed` of each group's inputs, so the same raw/
  gives the same bytes: the lives alone for the ``weibull`` rows, the lives and the leak path for
  the ``degradation`` rows (:mod:`analyses.remaining_life_group`).
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from analyses.decision import FROM_RUNS, GROUP, decide, look_estimates
from analyses.life_effect import life_effect
from analyses.life_effect_lognormal import (LOGNORMAL, lognormal_effect_fit, lognormal_life_effect,
                                            lognormal_ratio_deviance)
from analyses.quality import Sensor
from analyses.leak_degradation import leak_crossing_lives
from analyses.remaining_life import RulSettings
from analyses.remaining_life_group import backtest_summary, group_models, remaining_life, rul_backtest
from pipeline.stages import Reads, StageContext, StageOutput
from schemas.sensors_text import sensor_parts
from schemas.units import kg_s_to_l_min_anr

NAME = "remaining_life"
READS = Reads(tables=("hose_life", "hose_leak_growth", "leakage_map", "life_verdict"),
              plan=("leak_limit_l_min", "leak_pressure_bar", "confidence", "margin", "alpha", "spending",
                    "rupture_shape"))
WRITES = ("hose_rul", "rul_backtest", "decision_sensitivity")

RUL_COLUMNS = ["hose_type", "hose_id", "adjustment", "distance_km", "method", "rul_median_km", "rul_lower_km",
               "rul_upper_km", "confidence", "leak_now_l_min", "leak_limit_l_min", "leak_pressure_bar",
               "n_leak_points", "note"]
BACKTEST_COLUMNS = ["hose_type", "adjustment", "method", "n_predictions", "coverage", "coverage_at_50",
                    "coverage_at_80", "confidence", "median_abs_error_km", "note"]
SENSITIVITY_COLUMNS = ["hose_type", "definition", "leak_limit_l_min", "leak_pressure_bar", "n_force",
                       "n_failed_force", "n_distance", "n_failed_distance", "model", "life_ratio", "life_ratio_lower",
                       "life_ratio_upper", "confidence", "verdict", "note"]
#: The failure definitions of ``decision_sensitivity``: name -> multiple of the plan's leak limit (None: the logbook).
DEFINITIONS = (("logbook", None), ("leak limit", 1.0), ("leak limit x0.5", 0.5), ("leak limit x2", 2.0))
#: The life model of the leak-limit definitions: the one the degradation model (a lognormal wear rate) induces.
LEAK_MODEL = LOGNORMAL
#: The note of what a plan without a leak limit leaves NULL.
NO_LEAK_PLAN = "plan.toml sets no leak_limit_l_min / leak_pressure_bar for {}"
NO_PLAN = "no plan"
_HOSE_SPEC = ("hose_id", "adjustment", "distance_km", "status", "failure_mode")
_NAN = float("nan")


def _plain(v):
    """A cell as plain data for a ``ctx.map`` item: str, float or None."""
    if v is None or (isinstance(v, float) and v != v) or v is pd.NA or v is pd.NaT:
        return None
    if isinstance(v, (int, float, np.number)) and not isinstance(v, bool):
        return float(v)
    return str(v)


def _columns(df: pd.DataFrame, names) -> dict:
    return {c: [_plain(v) for v in (df[c].tolist() if c in df else [None] * len(df))] for c in names}


def leak_sensor(sensors) -> list | None:
    """The leak-flow sensor the ``leakage_map.sensors`` texts state
    (:func:`schemas.sensors_text.sensor_parts`): ``[resolution, noise]`` [l/min ANR], the
    coarsest of each among them; None when none states one."""
    stated = [sensor_parts(t).get("q_leak") for t in sensors]
    found = [(r, n) for r, n, _, unit in (s for s in stated if s is not None)
             if unit == "kg/s" and math.isfinite(r) and math.isfinite(n) and r >= 0 and n >= 0]
    if not found:
        return None
    return [float(kg_s_to_l_min_anr(max(r for r, _ in found))), float(kg_s_to_l_min_anr(max(n for _, n in found)))]


def plateau_spacing(growth: pd.DataFrame) -> float:
    """Median step between successive plateaus of a leakage run (per run and chamber) [bar]; NaN when
    every run has one plateau."""
    g = growth.dropna(subset=["pressure_bar"]).sort_values(["run_id", "chamber", "pressure_bar"], kind="stable")
    steps = g.groupby(["run_id", "chamber"], dropna=False)["pressure_bar"].diff()
    steps = steps[steps > 0]
    return float(steps.median()) if len(steps) else _NAN


def leak_paths(growth: pd.DataFrame, pressure_bar: float) -> tuple[pd.DataFrame, str | None]:
    """Each hose's leak path at the plan's pressure: one point per (hose, run).

    Parameters
    ----------
    growth : DataFrame
        ``hose_leak_growth`` rows of one hose type (``hose_id``, ``run_id``, ``chamber``,
        ``distance_km`` [km], ``pressure_bar`` [bar], ``leak_l_min`` [l/min]).
    pressure_bar : float
        The plan's ``leak_pressure_bar`` [bar].

    Returns
    -------
    (points, note) : (DataFrame, str or None)
        ``hose_id``, ``run_id``, ``distance_km``, ``leak_l_min`` (the mean over chambers of each
        chamber's plateau nearest ``pressure_bar``, when within half the plateau spacing), sorted;
        the note says why there are none.
    """
    cols = ["hose_id", "run_id", "distance_km", "leak_l_min"]
    g = growth.dropna(subset=["pressure_bar", "leak_l_min", "distance_km"])
    if g.empty:
        return pd.DataFrame(columns=cols), "no leak plateaus of its hoses in hose_leak_growth"
    spacing = plateau_spacing(g)
    if not math.isfinite(spacing):
        return pd.DataFrame(columns=cols), "its leakage runs have one plateau each: no spacing to match leak_pressure_bar"
    g = g.assign(_off=(g["pressure_bar"] - pressure_bar).abs())
    nearest = g.sort_values("_off", kind="stable").groupby(["hose_id", "run_id", "chamber"], dropna=False).head(1)
    near = nearest[nearest["_off"] <= spacing / 2.0]
    if near.empty:
        return (pd.DataFrame(columns=cols),
                f"no plateau within {spacing / 2.0:.3g} bar (half the plateau spacing) of leak_pressure_bar "
                f"{pressure_bar:g} bar")
    pts = near.groupby(["hose_id", "run_id"], as_index=False).agg(distance_km=("distance_km", "first"),
                                                                   leak_l_min=("leak_l_min", "mean"))
    return pts.sort_values(["hose_id", "distance_km", "run_id"], kind="stable", ignore_index=True)[cols], None


def _type_inputs(ctx: StageContext, hose_type: str, growth: pd.DataFrame, lmap: pd.DataFrame | None) -> dict:
    """A hose type's plan settings, leak path and leak sensor (plain data)."""
    s = ctx.plan.for_hose_type(hose_type)
    limit, pressure = s.leak_limit_l_min, s.leak_pressure_bar
    out = {"limit": None if limit is None else float(limit), "pressure": None if pressure is None else float(pressure),
           "confidence": float(s.confidence),
           "rupture_shape": None if s.rupture_shape is None else float(s.rupture_shape), "points": {"hose_id": [], "distance_km": [], "leak_l_min": []},
           "sensor": None, "path_note": NO_LEAK_PLAN.format(hose_type)}
    if limit is None or pressure is None:
        return out
    pts, note = leak_paths(growth, float(pressure))
    runs = set(pts["run_id"])
    texts = lmap.loc[lmap["run_id"].isin(runs), "sensors"].tolist() if lmap is not None and "sensors" in lmap else []
    sensor = leak_sensor(texts)
    if note is None and sensor is None:
        note = "no leak-flow sensor stated in leakage_map.sensors for its leakage runs: no floor for the leak path"
    out.update(points=_columns(pts, ("hose_id", "distance_km", "leak_l_min")), sensor=sensor, path_note=note)
    return out


def stage_items(ctx: StageContext) -> tuple[list[dict], list[dict]]:
    """(one item per (hose type, adjustment) for the models, one per hose type with both adjustments for
    the sensitivity), sorted."""
    life = ctx.results.get("hose_life")
    if life is None or life.empty:
        return [], []
    growth = ctx.results.get("hose_leak_growth")
    growth = pd.DataFrame(columns=["hose_id", "run_id", "chamber", "distance_km", "pressure_bar", "leak_l_min"]) \
        if growth is None or growth.empty else growth
    verdicts = ctx.results.get("life_verdict")
    verdicts = {} if verdicts is None or verdicts.empty else {
        t: (_plain(m), v) for t, m, v in zip(verdicts["hose_type"], verdicts["max_failures"], verdicts["verdict"])}
    life = life[life["hose_type"].notna() & life["adjustment"].isin(list(GROUP))]
    groups, types = [], []
    for hose_type, g in life.groupby("hose_type", sort=True):
        g = g.sort_values("hose_id", kind="stable")
        inputs = _type_inputs(ctx, str(hose_type), growth[growth["hose_id"].isin(set(g["hose_id"]))],
                              ctx.results.get("leakage_map"))
        for adjustment, h in g.groupby("adjustment", sort=True):
            ids = set(h["hose_id"])
            pts = {c: [v for v, hid in zip(inputs["points"][c], inputs["points"]["hose_id"]) if hid in ids]
                   for c in inputs["points"]}
            groups.append({"hose_type": str(hose_type), "adjustment": str(adjustment),
                           "hoses": _columns(h, _HOSE_SPEC), **inputs, "points": pts})
        if set(GROUP) <= set(g["adjustment"]):
            s = ctx.plan.for_hose_type(str(hose_type))
            max_failures, verdict = verdicts.get(hose_type, (None, None))
            types.append({"hose_type": str(hose_type), "hoses": _columns(g, _HOSE_SPEC), **inputs,
                          "plan": {"present": bool(s.present), "margin": float(s.margin), "alpha": float(s.alpha),
                                   "spending": s.spending},
                          "max_failures": None if max_failures is None else int(max_failures),
                          "life_verdict": verdict if isinstance(verdict, str) else None})
    return groups, types


def _hoses_frame(item: dict) -> pd.DataFrame:
    """An item's hoses as a frame (:data:`_HOSE_SPEC`, the distance as float64)."""
    hoses = pd.DataFrame(item["hoses"], columns=list(_HOSE_SPEC))
    hoses["distance_km"] = pd.to_numeric(hoses["distance_km"]).astype("float64")
    return hoses


def _frames(item: dict) -> tuple[pd.DataFrame, pd.DataFrame, str | None]:
    """A item's hoses and leak points as frames, and why the leak side is NULL (None when it is not)."""
    hoses = _hoses_frame(item)
    points = pd.DataFrame(item["points"], columns=["hose_id", "distance_km", "leak_l_min"])
    points = points.astype({"distance_km": "float64", "leak_l_min": "float64"})
    reason = None
    if item["limit"] is None or item["pressure"] is None or item["sensor"] is None or points.empty:
        reason = item["path_note"] or "no leak points at leak_pressure_bar"
    return hoses, (points.iloc[0:0] if reason else points), reason


#: The columns of a ``hose_rul`` row that are the hose's leak path and the plan's, the same on both methods' rows.
LEAK_ROW_COLUMNS = ("leak_now_l_min", "n_leak_points", "leak_limit_l_min", "leak_pressure_bar")


def _backtest_rows(tested: pd.DataFrame, base: dict, method: str) -> dict:
    """One ``rul_backtest`` row of ``method`` from :func:`analyses.remaining_life_group.rul_backtest`'s
    predictions: both fractions pooled, and each alone."""
    row = {**base, "method": method}
    for col, sel in (("", None), ("_at_50", 0.5), ("_at_80", 0.8)):
        part = tested if sel is None else tested[np.isclose(tested["fraction"].astype(float), sel)]
        summary = backtest_summary(part).set_index("method").loc[method]
        row[f"coverage{col}"] = float(summary["coverage"])
        if sel is None:
            row.update(n_predictions=int(summary["n_predictions"]), note=summary["note"],
                       median_abs_error_km=float(summary["median_abs_error_km"]))
    return row


def weibull_items(groups: list[dict]) -> list[dict]:
    """The :func:`rul_weibull` item of each :func:`stage_items` group: what its ``weibull`` rows read
    (the hoses' lives and the confidence; not the leak path)."""
    return [{k: g[k] for k in ("hose_type", "adjustment", "hoses", "confidence")} for g in groups]


def rul_weibull(item: dict) -> dict:
    """``hose_rul`` and ``rul_backtest`` rows of the ``weibull`` method of one (hose type, adjustment)
    (module level: ``ctx.map``); the leak columns of its ``hose_rul`` rows are the caller's to fill
    (:data:`LEAK_ROW_COLUMNS`, from the ``degradation`` rows).

    Parameters
    ----------
    item : dict
        From :func:`weibull_items`: ``hose_type``, ``adjustment``, ``hoses`` (hose_life columns),
        ``confidence``.

    Returns
    -------
    dict
        ``hose_rul`` and ``rul_backtest`` rows (lists of dicts).
    """
    hoses = _hoses_frame(item)
    points = pd.DataFrame({"hose_id": pd.Series([], dtype=object), "distance_km": pd.Series([], dtype="float64"),
                           "leak_l_min": pd.Series([], dtype="float64")})
    settings = RulSettings(limit_l_min=_NAN, sensor=Sensor(0.0, 0.0, source="metadata"), confidence=item["confidence"])
    base = {"hose_type": item["hose_type"], "adjustment": item["adjustment"], "confidence": item["confidence"]}
    models = group_models(hoses, points, settings, methods=("weibull",))   # seeded by the lives alone
    rul = remaining_life(hoses, points, settings, models=models).assign(**base, leak_pressure_bar=None)
    tested = rul_backtest(hoses, points, settings, models=models)
    return {"hose_rul": rul[RUL_COLUMNS].to_dict("records"), "rul_backtest": [_backtest_rows(tested, base, "weibull")]}


def rul_group(item: dict) -> dict:
    """``hose_rul`` and ``rul_backtest`` rows of the ``degradation`` method of one (hose type,
    adjustment) (module level: ``ctx.map``; the ``weibull`` rows are :func:`rul_weibull`'s).

    Parameters
    ----------
    item : dict
        From :func:`stage_items`: ``hose_type``, ``adjustment``, ``hoses`` (hose_life columns),
        ``points`` (the leak path, :func:`leak_paths`), ``limit`` [l/min], ``pressure`` [bar],
        ``sensor`` (``[resolution, noise]`` [l/min]), ``confidence``, ``rupture_shape`` [-] (None:
        not known), ``path_note``.

    Returns
    -------
    dict
        ``hose_rul`` and ``rul_backtest`` rows (lists of dicts).
    """
    hoses, points, reason = _frames(item)
    sensor = Sensor(*(item["sensor"] or (0.0, 0.0)), source="metadata")
    settings = RulSettings(limit_l_min=_NAN if item["limit"] is None else item["limit"], sensor=sensor,
                           confidence=item["confidence"], rupture_shape=item.get("rupture_shape"))
    base = {"hose_type": item["hose_type"], "adjustment": item["adjustment"], "confidence": item["confidence"]}
    # fitted once for the predictions and their backtest; seeded by the lives and the leak path
    models = group_models(hoses, points, settings, methods=("degradation",))
    rul = remaining_life(hoses, points, settings, models=models)
    if reason:
        rul[["rul_median_km", "rul_lower_km", "rul_upper_km"]] = _NAN
        rul["note"] = reason
    if item["pressure"] is None or item["limit"] is None:
        rul["n_leak_points"] = None
    rul = rul.assign(**base, leak_pressure_bar=item["pressure"],
                     leak_limit_l_min=item["limit"])
    tested = rul_backtest(hoses, points, settings, models=models)
    row = _backtest_rows(tested, base, "degradation")
    if reason:
        row.update(n_predictions=0, coverage=_NAN, coverage_at_50=_NAN, coverage_at_80=_NAN,
                   median_abs_error_km=_NAN, note=reason)
    return {"hose_rul": rul[RUL_COLUMNS].to_dict("records"), "rul_backtest": [row]}


def _with_leak_columns(weibull: list[dict], degradation: list[dict]) -> list[dict]:
    """The ``weibull`` rows with the leak columns (:data:`LEAK_ROW_COLUMNS`) of their hose's ``degradation`` row."""
    leak = {r["hose_id"]: {c: r[c] for c in LEAK_ROW_COLUMNS} for r in degradation}
    return [{**r, **leak.get(r["hose_id"], {})} for r in weibull]


def definition_lives(hoses: pd.DataFrame, points: pd.DataFrame, limit_l_min: float | None) -> tuple[pd.DataFrame, str | None]:
    """Each hose's life under a failure definition: the logbook's (``limit_l_min`` None), else its leak
    path's first crossing of the limit (never crossed: censored at its last plateau) and, without a
    leak path, its logbook distance censored; lives not above 0 are left out.

    Returns
    -------
    (lives, note) : (DataFrame, str or None)
        ``hose_id``, ``adjustment``, ``distance_km`` [km], ``failed``; what the note should say.
    """
    lives = hoses[["hose_id", "adjustment"]].assign(distance_km=hoses["distance_km"].astype(float),
                                                    failed=(hoses["status"] == "failed").to_numpy())
    notes = []
    if limit_l_min is not None:
        cross = leak_crossing_lives(points, limit_l_min).set_index("hose_id")
        has = lives["hose_id"].isin(cross.index).to_numpy()
        ids = lives["hose_id"][has]
        lives.loc[has, "distance_km"] = cross.loc[ids, "life_km"].to_numpy(float)
        lives.loc[has, "failed"] = cross.loc[ids, "crossed"].to_numpy(bool)
        lives.loc[~has, "failed"] = False
        if (~has).any():
            notes.append(f"{int((~has).sum())} hose(s) without a leak path: their logbook distance, censored")
    keep = lives["distance_km"] > 0
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} hose(s) without a positive life left out")
    return lives[keep].reset_index(drop=True), "; ".join(notes) or None


def definition_model(factor: float | None) -> str | None:
    """The life model a definition is read under: :data:`LEAK_MODEL` for a leak-limit crossing
    (``factor`` a multiple of the plan's limit), None (the logbook: :func:`analyses.life_effect.life_effect`'s
    choice, the common-shape Weibull for the verdict) otherwise."""
    return None if factor is None else LEAK_MODEL


def read_once(lives: pd.DataFrame, max_failures: int, plan: dict, model: str | None = None):
    """The decision's rule read on ``lives`` now: one look with all of them, at the boundary this
    failure count has in the plan's design with a look at every failure (earlier looks without an
    estimate: they set the boundary, they do not decide). ``model`` :data:`LEAK_MODEL` reads the
    common-sigma lognormal's estimate, standard error and profile deviance instead of the
    common-shape Weibull's. Returns :class:`analyses.sequential.SequentialVerdict` (None without
    failures) and the estimate row."""
    failures = int(lives["failed"].sum())
    if failures == 0:
        return None, None
    in_looks = lives.assign(look=failures, distance_from=FROM_RUNS)
    est = look_estimates(in_looks, pd.DataFrame({"look": [failures], "event_at": [None], "hose_id": [None]}))
    deviance = {}
    if model == LEAK_MODEL:
        fit = lognormal_effect_fit(lives["distance_km"].to_numpy(float), lives["failed"].to_numpy(bool),
                                   lives["adjustment"].map(GROUP).to_numpy(int))
        ok = fit.note is None and math.isfinite(fit.se_log_ratio) and fit.se_log_ratio > 0
        est = est.assign(log_ratio=fit.log_ratio if ok else _NAN, se_log_ratio=fit.se_log_ratio if ok else _NAN,
                         note=fit.note or (None if ok else "the fit's information is not positive definite"))
        deviance = {"deviance": lognormal_ratio_deviance}
    k = min(failures, max_failures)
    before = pd.DataFrame({"look": np.arange(1, k), "failures": np.arange(1, k), "log_ratio": _NAN,
                           "se_log_ratio": _NAN})
    looks = pd.concat([before, est[["look", "failures", "log_ratio", "se_log_ratio"]]], ignore_index=True)
    verdict = decide(looks, max_failures, plan["margin"], plan["alpha"], plan["spending"], in_looks, **deviance)
    return verdict, est.iloc[-1]


def _sensitivity_row(item: dict, definition: str, factor: float | None, hoses, points, reason) -> dict:
    """One ``decision_sensitivity`` row."""
    limit = None if factor is None or item["limit"] is None else item["limit"] * factor
    row = {"hose_type": item["hose_type"], "definition": definition, "leak_limit_l_min": limit,
           "leak_pressure_bar": item["pressure"], "confidence": item["confidence"]}
    if factor is not None and reason:
        return {**row, "note": reason}
    lives, note = definition_lives(hoses, points, limit)
    model = definition_model(factor)
    args = (lives["distance_km"].to_numpy(float), lives["failed"].to_numpy(bool),
            lives["adjustment"].map(GROUP).to_numpy(int))
    le = (lognormal_life_effect(*args, confidence=item["confidence"]) if model == LEAK_MODEL
          else life_effect(*args, confidence=item["confidence"], alpha=item["plan"]["alpha"]))
    row.update({c: getattr(le, c) for c in SENSITIVITY_COLUMNS if c not in row and hasattr(le, c) and c != "note"})
    notes = [note, le.note]
    if item["max_failures"] is None:
        notes.append("no life_verdict row: no max_failures, no verdict")
        return {**row, "note": "; ".join(n for n in notes if n)}
    sv, est = read_once(lives, item["max_failures"], item["plan"], model)
    verdict = "undecided" if sv is None else sv.verdict
    # the looks before this one are placeholders that set its boundary: what the verdict says of them is not news
    notes += ["no failure under this definition"] if sv is None else [
        n for n in (sv.note or "").split("; ") if n and "without an estimate" not in n and "new information" not in n]
    if est is not None and isinstance(est["note"], str):
        notes.append(est["note"])
    if not item["plan"]["present"]:
        notes.insert(0, f"no usable raw/plan.toml: read as {verdict!r}, no verdict declared")
        verdict = NO_PLAN
    if factor is None and item["life_verdict"] not in (None, verdict):
        notes.append(f"life_verdict (read at every failure, sticky) says {item['life_verdict']!r}")
    return {**row, "verdict": verdict, "note": "; ".join(n for n in notes if n) or None}


def sensitivity_of(item: dict) -> list[dict]:
    """The ``decision_sensitivity`` rows of one hose type, one per :data:`DEFINITIONS`: those of
    :func:`sensitivity_logbook` and :func:`sensitivity_leak`, in the order of :data:`DEFINITIONS`."""
    rows = {r["definition"]: r for r in (*sensitivity_logbook(logbook_item(item)), *sensitivity_leak(item))}
    return [rows[name] for name, _factor in DEFINITIONS]


#: What the logbook definition's row reads of a sensitivity item: not the leak path (issue 26).
_LOGBOOK_KEYS = ("hose_type", "hoses", "pressure", "confidence", "plan", "max_failures", "life_verdict")


def logbook_item(item: dict) -> dict:
    """The :func:`sensitivity_logbook` item of a :func:`stage_items` sensitivity item: its hoses, plan
    and verdict, without the leak path, so that a leakage change takes its row from the memo."""
    return {k: item[k] for k in _LOGBOOK_KEYS}


def sensitivity_logbook(item: dict) -> list[dict]:
    """The ``decision_sensitivity`` rows of the definitions without a leak limit (the logbook's) of one
    hose type (module level: ``ctx.map``; ``item`` from :func:`logbook_item`)."""
    hoses = _hoses_frame(item)
    return [_sensitivity_row(item, name, None, hoses, None, None) for name, factor in DEFINITIONS if factor is None]


def sensitivity_leak(item: dict) -> list[dict]:
    """The ``decision_sensitivity`` rows of the leak-limit definitions of one hose type (module level:
    ``ctx.map``; ``item`` from :func:`stage_items`)."""
    hoses, points, reason = _frames(item)
    return [_sensitivity_row(item, name, factor, hoses, points, reason)
            for name, factor in DEFINITIONS if factor is not None]


def _typed(rows: list[dict], columns: list[str], ints=()) -> pd.DataFrame:
    """A table's frame: its columns in order, BIGINT columns as nullable integers, numbers as float64."""
    df = pd.DataFrame(rows, columns=columns)
    for c in columns:
        if c in ints:
            df[c] = pd.array([None if v is None or pd.isna(v) else int(v) for v in df[c]], dtype="Int64")
        elif c.endswith(("_km", "_l_min", "_bar")) or c in ("confidence", "coverage", "coverage_at_50",
                                                             "coverage_at_80", "life_ratio", "life_ratio_lower",
                                                             "life_ratio_upper"):
            df[c] = pd.to_numeric(df[c], errors="coerce").astype("float64")
        else:
            df[c] = pd.Series([None if v is None or (isinstance(v, float) and v != v) else str(v) for v in df[c]],
                              dtype=object, index=df.index)
    return df


def run(ctx: StageContext) -> StageOutput:
    out = StageOutput()
    groups, types = stage_items(ctx)
    # the sensitivity first: one hose type's runs here and imports scipy's optimisers and distributions,
    # which the workers then forked for the groups inherit instead of each importing them again; the
    # logbook's rows apart, keyed by the hoses and the plan alone: a leakage change reads them from the memo
    logbook = ctx.map(sensitivity_logbook, [logbook_item(t) for t in types],
                      label="remaining life: sensitivity (logbook)") if types else []
    leak = ctx.map(sensitivity_leak, types, label="remaining life: sensitivity") if types else []
    order = {name: i for i, (name, _factor) in enumerate(DEFINITIONS)}
    sens = [sorted((*a, *b), key=lambda r: order[r["definition"]]) for a, b in zip(logbook, leak)]
    weib = ctx.map(rul_weibull, weibull_items(groups), label="remaining life: weibull") if groups else []
    deg = ctx.map(rul_group, groups, label="remaining life") if groups else []
    rul = [r for w, d in zip(weib, deg) for r in (*_with_leak_columns(w["hose_rul"], d["hose_rul"]), *d["hose_rul"])]
    out.tables["hose_rul"] = _typed(sorted(rul, key=lambda r: (r["hose_type"], r["hose_id"], r["method"])),
                                    RUL_COLUMNS, ints=("n_leak_points",))
    backtest = [r for w, d in zip(weib, deg) for r in (*w["rul_backtest"], *d["rul_backtest"])]
    out.tables["rul_backtest"] = _typed(backtest, BACKTEST_COLUMNS, ints=("n_predictions",))
    out.tables["decision_sensitivity"] = _typed([r for rows in sens for r in rows], SENSITIVITY_COLUMNS,
                                                ints=("n_force", "n_failed_force", "n_distance", "n_failed_distance"))
    return out
