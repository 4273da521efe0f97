"""One hose type's remaining-life predictions and their backtest, from the models of
:mod:`analyses.life_posterior`, :mod:`analyses.leak_degradation` and :mod:`analyses.remaining_life` (the
methods, their references and their decisions are described there).

:func:`group_models` fits a hose type's models once, :func:`remaining_life` predicts every running
hose's remaining life by each method asked, :func:`rul_backtest` makes the predictions each method
would have made for every failed hose part-way through its life, :func:`backtest_summary` counts
how often they held. Distances in km, leaks in l/min (ANR).

Seeds (issue 26): the ``weibull`` method reads the hoses' lives only, so its draws are seeded by the
lives alone (:func:`analyses.remaining_life.data_seed` of ``hoses``); the ``degradation`` method and
the other failure modes' models by the lives and the leak points (``data_seed(hoses, points)``, as
before). A changed leak point then leaves the ``weibull`` rows as they were, and a caller may compute
the two methods apart (``methods``) and keep the ``weibull`` rows of unchanged lives. A ``seed``
given seeds both, as before.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from analyses.leak_degradation import DegradationFit, degradation_fit, degradation_rul
from analyses.life_posterior import LifeModel, life_model, weibull_rul
from analyses.remaining_life import (BACKTEST_COLUMNS, BACKTEST_FRACTIONS, RUL_COLUMNS, RulSettings, _leak_failures,
                                     _lives, _rupture_posterior, data_seed, rupture_model)
from analyses.service_life import weibull_fit

_NAN = float("nan")
#: The methods of a prediction, in the order of their rows. [-]
METHODS = ("weibull", "degradation")


@dataclass(frozen=True)
class GroupModels:
    """What :func:`remaining_life` and :func:`rul_backtest` both fit on one hose type's data.

    Attributes
    ----------
    seed : int
        The seed of the degradation and rupture draws (:func:`data_seed` of the hoses and the leak
        points, unless given).
    life : LifeModel or None
        The ``weibull`` method's life model of the hoses' lives (:func:`life_model`, seeded by
        :func:`data_seed` of the hoses alone, or the ``seed`` given); None when ``weibull`` was not asked.
    rupture : tuple
        The other failure modes' models and their note (:func:`rupture_model`, ``seed + 1``; the
        logbook's Weibull fit that bounds an unknown shape is the life model's); ``([], None)`` when
        ``degradation`` was not asked.
    degradation : DegradationFit
        The degradation model of all the leak points (:func:`degradation_fit`; also what the rows
        say of each hose's leak path).
    methods : tuple of str
        The methods these models serve (:data:`METHODS`).
    """

    seed: int
    life: LifeModel | None
    rupture: tuple
    degradation: DegradationFit
    methods: tuple = METHODS


def group_models(hoses: pd.DataFrame, points: pd.DataFrame, settings: RulSettings,
                 seed: int | None = None, methods=METHODS) -> GroupModels:
    """The life and rupture models of one hose type's data, fitted once for the predictions and
    their backtest (the same draws: the same numbers as each fitting its own).

    Parameters
    ----------
    hoses, points, settings, seed
        As :func:`remaining_life`.
    methods : sequence of str
        The methods to fit for (:data:`METHODS`): the life model for ``weibull``, the rupture
        models for ``degradation``; the degradation model of ``points`` always.

    Returns
    -------
    GroupModels
    """
    methods = tuple(m for m in METHODS if m in methods)
    life_seed = data_seed(hoses) if seed is None else seed   # the life model reads the lives only
    seed = data_seed(hoses, points) if seed is None else seed
    life, failed = _lives(hoses)
    model = life_model(life, failed, settings.n_draws, life_seed) if "weibull" in methods else None
    rupture = ([], None)
    if "degradation" in methods:
        logbook = next(p.fit for p in model.families if p.family == "weibull") if model is not None \
            else weibull_fit(life, failed)   # the same fit: the life model's Weibull family is weibull_fit's
        rupture = _rupture_posterior(hoses, points, settings, seed + 1, logbook)
    return GroupModels(seed, model, rupture, degradation_fit(points, settings.sensor, settings.floor_multiple),
                       methods)


def remaining_life(hoses: pd.DataFrame, points: pd.DataFrame, settings: RulSettings,
                   seed: int | None = None, models: "GroupModels | None" = None, methods=METHODS) -> pd.DataFrame:
    """Remaining life of every running hose of one hose type, by both methods (or those asked).

    Parameters
    ----------
    hoses : DataFrame
        The hose type's hoses: ``hose_id``, ``distance_km`` [km], ``status`` (``failed``,
        ``removed``, ``running``), optionally ``failure_mode``.
    points : DataFrame
        Their leak paths: ``hose_id``, ``distance_km`` [km], ``leak_l_min`` [l/min] at one pressure.
    settings : RulSettings
        Limit, sensor, confidence.
    seed : int, optional
        Seed of the draws; default: from the data (:func:`data_seed`), so the same data give the
        same numbers.
    models : GroupModels, optional
        :func:`group_models` of the same arguments, when the caller has them (the backtest
        shares them); ``seed`` and ``methods`` are then theirs.
    methods : sequence of str
        The methods whose rows are made (:data:`METHODS`).

    Returns
    -------
    DataFrame
        :data:`RUL_COLUMNS`, one row per running hose and method (``weibull``, ``degradation``).
    """
    models = group_models(hoses, points, settings, seed, methods) if models is None else models
    seed, post, deg, methods = models.seed, models.life, models.degradation, models.methods
    rupture, r_note = models.rupture
    info = deg.hoses.set_index("hose_id")
    rows = []
    for hid, d in hoses.loc[hoses["status"] == "running", ["hose_id", "distance_km"]].itertuples(index=False):
        leak = info.loc[hid] if hid in info.index else None
        base = {"hose_id": hid, "distance_km": d, "leak_limit_l_min": settings.limit_l_min,
                "leak_now_l_min": float(leak["leak_now_l_min"]) if leak is not None else _NAN,
                "n_leak_points": int(leak["n_points"]) if leak is not None else 0}
        if "weibull" in methods:
            q, note = weibull_rul(post, d, settings.confidence)
            rows.append({**base, "method": "weibull", **_quantile_columns(q), "note": note})
        if "degradation" in methods:
            q, note = _degradation_with_rupture(deg, hid, d, settings, (rupture, r_note), seed)
            rows.append({**base, "method": "degradation", **_quantile_columns(q), "note": note})
    return pd.DataFrame(rows, columns=RUL_COLUMNS)


def _quantile_columns(q: np.ndarray) -> dict:
    ok = np.isfinite(q).all()
    return dict(zip(("rul_median_km", "rul_lower_km", "rul_upper_km"), q if ok else np.full(3, _NAN)))


def _degradation_with_rupture(deg: DegradationFit, hose_id, distance_km: float, s: RulSettings,
                              rupture: tuple, seed: int) -> tuple[np.ndarray, str | None]:
    """:func:`degradation_rul` with the other failure modes' models (``(posteriors, note)``, of
    :func:`rupture_model`); NaN with the note when either model has none; the rupture models' note
    (the shape not known) on a prediction."""
    posts, r_note = rupture
    if not deg.ok:
        return np.full(3, _NAN), deg.note
    if not posts:
        return np.full(3, _NAN), r_note
    q, note = degradation_rul(deg, hose_id, distance_km, s.limit_l_min, posts, s.confidence, s.n_draws, seed)
    return q, (r_note if note is None else note)


# -- backtest --------------------------------------------------------------------------------
def rul_backtest(hoses: pd.DataFrame, points: pd.DataFrame, settings: RulSettings,
                 fractions=BACKTEST_FRACTIONS, seed: int | None = None,
                 models: "GroupModels | None" = None, methods=METHODS) -> pd.DataFrame:
    """The prediction each method would have made for every failed hose part-way through its life.

    For a failed hose of life ``L`` and a fraction ``f``: the hose censored at ``f L``, its leak
    points beyond ``f L`` removed, the models refitted (see the module docstring), and its
    remaining life predicted at ``f L``; the truth is ``L - f L``.

    Parameters
    ----------
    hoses, points, settings, seed, models, methods
        As :func:`remaining_life`.
    fractions : sequence of float
        Fractions of each failed hose's life at which to predict. [-]

    Returns
    -------
    DataFrame
        :data:`BACKTEST_COLUMNS`, one row per failed hose, fraction and method; ``covered`` and
        ``abs_error_km`` [km] NaN where the prediction is (``note`` says why).
    """
    models = group_models(hoses, points, settings, seed, methods) if models is None else models
    seed, post, rupture, methods = models.seed, models.life, models.rupture, models.methods
    life, failed = _lives(hoses)
    degradation_asked = "degradation" in methods
    leak_failed = _leak_failures(hoses, points, settings.limit_l_min) if degradation_asked else None
    rows = []
    for i in np.flatnonzero(failed):
        hid, total = hoses["hose_id"].iloc[i], float(life[i])
        for f in fractions:
            at = f * total
            if "weibull" in methods:
                q, note = weibull_rul(post.changed([total], [True], [at], [False]), at, settings.confidence)
                rows.append(_backtest_row(hid, "weibull", f, at, total, q, note))
            if not degradation_asked:
                continue
            mine = (points["hose_id"] == hid) & (points["distance_km"] > at)
            deg = degradation_fit(points[~mine], settings.sensor, settings.floor_multiple) if mine.any() \
                else models.degradation   # no point of its to cut: the same fit
            # the rupture models only where the degradation model has a prediction to join them to
            cut = _rupture_cut_short(rupture, (life, failed, failed & ~leak_failed), i, at, settings, seed + 1) \
                if deg.ok else ([], None)
            q, note = _degradation_with_rupture(deg, hid, at, settings, cut, seed + 2 + i)
            rows.append(_backtest_row(hid, "degradation", f, at, total, q, note))
    return pd.DataFrame(rows, columns=BACKTEST_COLUMNS)


def _rupture_cut_short(rupture: tuple, lives: tuple, i: int, at: float, s: RulSettings,
                       seed: int) -> tuple[list, str | None]:
    """The other failure modes' models (``(posteriors, note)``) with hose ``i`` censored at ``at``
    (``lives``: life, failed, failed by another mode): the Weibull draws re-weighted; made afresh
    (:func:`rupture_model`) when the Weibull loses its second failure or the models are Weibayes
    (their draws are exact and cheap, the logbook's shape bound changes with the cut, and
    re-weighting a Gamma posterior to one failure fewer has an infinite variance)."""
    posts, note = rupture
    life, failed, other = lives
    if not posts:
        return rupture
    if len(posts) == 1 and not posts[0].fixed_shape:
        cut = posts[0].changed([life[i]], [other[i]], [at], [False])
        if cut.ok:
            return [cut], note
    keep = np.arange(len(life)) != i
    return rupture_model(np.where(keep, life, at), failed & keep, other & keep, s.rupture_shape, s.confidence,
                         s.n_draws, seed)


def _backtest_row(hose_id, method: str, fraction: float, at: float, total: float, q, note) -> dict:
    cols = _quantile_columns(np.asarray(q, float))
    ok = np.isfinite(cols["rul_median_km"])
    truth = total - at
    return {"hose_id": hose_id, "method": method, "fraction": fraction, "at_km": at, "life_km": total, **cols,
            "covered": (cols["rul_lower_km"] <= truth <= cols["rul_upper_km"]) if ok else None,
            "abs_error_km": abs(cols["rul_median_km"] - truth) if ok else _NAN, "note": note}


def backtest_summary(predictions: pd.DataFrame) -> pd.DataFrame:
    """Per method: how many backtest predictions there are, how often their intervals held.

    Parameters
    ----------
    predictions : DataFrame
        :func:`rul_backtest`'s rows (of one hose type, or pooled).

    Returns
    -------
    DataFrame
        ``method``, ``n_predictions`` (with a number), ``coverage`` (fraction of intervals that
        held the true remaining life) [-], ``median_abs_error_km`` [km], ``note`` (NULL when
        sound; how many were NaN and the commonest reason; "no failed hose" when empty).
    """
    rows = []
    for method in ("weibull", "degradation"):
        p = predictions[predictions["method"] == method]
        made = p[p["abs_error_km"].notna()]
        note = None
        missing = p[p["abs_error_km"].isna()]
        if p.empty:
            note = "no failed hose to backtest"
        elif len(missing):
            note = f"{len(missing)} of {len(p)} without a prediction (mostly: {missing['note'].mode().iloc[0]})"
        rows.append({"method": method, "n_predictions": len(made),
                     "coverage": float(made["covered"].astype(float).mean()) if len(made) else _NAN,
                     "median_abs_error_km": float(made["abs_error_km"].median()) if len(made) else _NAN,
                     "note": note})
    return pd.DataFrame(rows, columns=["method", "n_predictions", "coverage", "median_abs_error_km", "note"])


__all__ = ["GroupModels", "METHODS", "backtest_summary", "group_models", "remaining_life", "rul_backtest"]
