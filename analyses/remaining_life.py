"""Remaining life of running hoses: what joins the two methods' models, and the other failure modes' model.

Distances are in km, leaks in l/min (ANR) at the plan's test pressure. A hose is ``running``,
``failed`` or ``removed`` (``hoses``: ``hose_id``, ``distance_km``, ``status``, optionally
``failure_mode``); its leak path is its leakage plateaus at its distance (``points``:
``hose_id``, ``distance_km``, ``leak_l_min``, one pressure level, as ``hose_leak_growth`` gives
them). Every prediction is a median and a two-sided **prediction interval** at ``confidence``
for the distance a running hose has left [km], NaN with a one-line ``note`` when the data
cannot tell.

The ``weibull`` method's life model (the Weibull and lognormal predictive posteriors of the hose
type's lives, conditioned on a hose's survival) is :mod:`analyses.life_posterior`; the
``degradation`` method's leak-growth model (each hose's leak path, pooled, run to the limit) and the
leak-limit crossing are :mod:`analyses.leak_degradation`. This module holds what joins them: what a
prediction is asked (:class:`RulSettings`), the seed of its draws (:func:`data_seed`), the tables'
columns, and the other failure modes' model that the ``degradation`` method joins to the leak path.

The other failure modes: a competing risk
-----------------------------------------
Other failure modes (a rupture) end a hose before its leak crosses the limit. They enter as a
competing risk (Meeker & Escobar 1998, ch. 15): a Weibull fitted to the failures that were not
leak failures (the leak failures censored at their distance), with its predictive draws
(:mod:`analyses.life_posterior`), independent of the leak path; the remaining life is
``min(crossing, rupture)``, so the ``degradation`` method is the joint model of the hose's own leak
path and the logbook's ruptures. With one such failure or none the Weibull has no proper posterior;
the mode is then a Weibayes (:func:`weibayes_posterior <analyses.life_posterior.weibayes_posterior>`;
Abernethy 2006, ch. 6; Nelson 1985): a Weibull of known shape whose scale has the Jeffreys
posterior from the exposure, ``Gamma(r + 1/2, sum t^k)`` on ``scale^-k``: a mode seen once or not
yet is bounded by the distance run without it rather than left out (leaving it out covered only a
third of the hoses that then ruptured first). Zero or one rupture cannot tell the shape: the plan's
``rupture_shape`` gives it when the lab knows it (:attr:`RulSettings.rupture_shape`; then the
Weibayes at it, whatever the count). When it does not, the interval must hold for every plausible
shape (:func:`rupture_model`, :func:`rul_over_shapes <analyses.life_posterior.rul_over_shapes>`):
it is the union of the intervals at the shapes of a geometric grid from 1 (the constant hazard) to
the upper ``confidence`` profile bound of the hose type's logbook Weibull shape (all failure modes;
:func:`weibull_shape_bounds <analyses.service_life.weibull_shape_bounds>`), and the row's note says
the shape was not known; its median is the equal mixture's over the grid. Without that bound (fewer
than two failures in the logbook, or a bound the data do not close) the rupture part, and so the
joint prediction, is NaN with the reason.

Backtest
--------
:func:`rul_backtest <analyses.remaining_life_group.rul_backtest>` (with the predictions of one hose type,
:mod:`analyses.remaining_life_group`): for every failed hose, the prediction each method would have made at 50 %
and 80 % of its life from the data there was then: that hose censored at that distance and its
later leak points removed, the model refitted (the Weibull posterior by importance re-weighting
of the same draws, which is exact up to Monte Carlo error: case-deletion importance sampling,
Gelfand, Dey & Chang 1992; the degradation model by refitting). The other hoses keep their data
(the tables carry no calendar order of the hoses' lives). The full data's models are fitted once
for the predictions and their backtest (``group_models``: the same seeds, the same draws).
``backtest_summary``: per method
``n_predictions``, ``coverage`` of the intervals and ``median_abs_error_km`` of the medians.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from analyses.leak_degradation import FLOOR_MULTIPLE, leak_crossing_lives
from analyses.life_posterior import N_DRAWS, weibayes_posterior, weibull_posterior
from analyses.quality import Sensor
from analyses.service_life import WeibullFit, weibull_fit, weibull_shape_bounds

_NAN = float("nan")
#: Shapes of the grid over which the rupture part's interval is united when its shape is not known. [-]
N_RUPTURE_SHAPES = 5
#: Fractions of a failed hose's life at which the backtest predicts. [-]
BACKTEST_FRACTIONS = (0.5, 0.8)
RUL_COLUMNS = ["hose_id", "distance_km", "method", "rul_median_km", "rul_lower_km", "rul_upper_km",
               "leak_now_l_min", "leak_limit_l_min", "n_leak_points", "note"]
BACKTEST_COLUMNS = ["hose_id", "method", "fraction", "at_km", "life_km", "rul_median_km", "rul_lower_km",
                    "rul_upper_km", "covered", "abs_error_km", "note"]


def data_seed(*frames: pd.DataFrame) -> int:
    """A seed from the data's content: the same tables give the same draws. [-]"""
    h = hashlib.sha256()
    for df in frames:
        h.update(pd.util.hash_pandas_object(df.reset_index(drop=True), index=False).to_numpy().tobytes())
    return int.from_bytes(h.digest()[:4], "little")


# -- one hose type ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RulSettings:
    """What the remaining-life models are asked.

    Attributes
    ----------
    limit_l_min : float
        Leak that ends a hose's life [l/min].
    sensor : Sensor
        The leak channel's resolution and noise [l/min].
    confidence : float
        Two-sided level of the prediction intervals. [-]
    n_draws : int
        Parameter draws per predictive distribution. [-]
    floor_multiple : float
        Leak points at or below this multiple of the sensor floor are left out. [-]
    rupture_shape : float or None
        The Weibull shape of the other failure modes when the lab knows it (the plan's
        ``rupture_shape``) [-]: their model is then the Weibayes at it; None: not known
        (:func:`rupture_model`).
    """

    limit_l_min: float
    sensor: Sensor
    confidence: float = 0.90
    n_draws: int = N_DRAWS
    floor_multiple: float = FLOOR_MULTIPLE
    rupture_shape: float | None = None


def _lives(hoses: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    return hoses["distance_km"].to_numpy(float), (hoses["status"] == "failed").to_numpy()


def _leak_failures(hoses: pd.DataFrame, points: pd.DataFrame, limit_l_min: float) -> np.ndarray:
    """Which hoses failed by their leak: the logbook's failure mode when it names one ("leak..."),
    else whether the leak path reached the limit."""
    failed = (hoses["status"] == "failed").to_numpy()
    mode = hoses["failure_mode"] if "failure_mode" in hoses else pd.Series([None] * len(hoses), index=hoses.index)
    crossed = dict(leak_crossing_lives(points, limit_l_min)[["hose_id", "crossed"]].itertuples(index=False))
    by_mode = [isinstance(m, str) and m.strip() != "" for m in mode]
    leak = [("leak" in m.lower()) if named else bool(crossed.get(h, False))
            for h, m, named in zip(hoses["hose_id"], mode, by_mode)]
    return failed & np.asarray(leak, bool)


def _rupture_posterior(hoses: pd.DataFrame, points: pd.DataFrame, s: RulSettings,
                       seed: int, logbook_fit: WeibullFit | None = None) -> tuple[list, str | None]:
    """The other failure modes' models (:func:`rupture_model`) and their note."""
    life, failed = _lives(hoses)
    return rupture_model(life, failed, failed & ~_leak_failures(hoses, points, s.limit_l_min), s.rupture_shape,
                         s.confidence, s.n_draws, seed, logbook_fit)


def rupture_shapes(life, failed, confidence: float = 0.90, fit: WeibullFit | None = None) -> tuple[np.ndarray, str]:
    """The shapes a rupture model of unknown shape must hold for, and the note that says so.

    From 1 (the constant hazard) to the upper ``confidence`` likelihood-ratio bound of the Weibull
    shape of all the lives' failures (the logbook's, every mode; :func:`weibull_shape_bounds
    <analyses.service_life.weibull_shape_bounds>`, Meeker & Escobar 1998, section 8.3), a geometric
    grid of :data:`N_RUPTURE_SHAPES` (from the bound to 1 when the bound is below 1).

    Parameters
    ----------
    life : array_like
        Lives [km]: failure or censoring distances.
    failed : array_like of bool
        True for a failure, any mode.
    confidence : float
        Two-sided level of the shape's bounds. [-]
    fit : WeibullFit, optional
        :func:`weibull_fit <analyses.service_life.weibull_fit>` of these lives when the caller has
        it (the life model's); fitted here otherwise.

    Returns
    -------
    (shapes, note) : (numpy.ndarray, str)
        The grid [-], empty when the lives give no upper bound (fewer than two failures, no fit,
        a bound the data do not close); the note says which.
    """
    fit = weibull_fit(life, failed) if fit is None else fit
    upper = weibull_shape_bounds(fit, life, failed, confidence)[1] if fit.ok else _NAN
    unknown = "the rupture shape is not known (plan.toml sets no rupture_shape)"
    if not math.isfinite(upper):
        why = f"no logbook Weibull fit: {fit.note}" if not fit.ok else \
            f"the logbook Weibull shape has no upper {100 * confidence:g} % bound"
        return np.empty(0), f"{unknown} and the logbook cannot bound it ({why})"
    lo, hi = sorted((1.0, upper))
    return np.geomspace(lo, hi, N_RUPTURE_SHAPES), (
        f"{unknown}: the interval holds for every shape from {lo:.3g} to {hi:.3g} (1 and the logbook Weibull "
        f"shape's upper {100 * confidence:g} % bound)")


def rupture_model(life, failed, other, shape: float | None = None, confidence: float = 0.90,
                  n_draws: int = N_DRAWS, seed: int = 0,
                  logbook_fit: WeibullFit | None = None) -> tuple[list, str | None]:
    """The life models of the failure modes other than the leak (a competing risk, Meeker & Escobar
    1998, ch. 15: the leak failures censored at their distance), and their note.

    ``shape`` given (the lab's, the plan's ``rupture_shape``): the Weibayes at it
    (:func:`analyses.life_posterior.weibayes_posterior`), whatever the count. Else a Weibull
    (:func:`analyses.life_posterior.weibull_posterior`) with two such failures or more; with one or
    none, whose shape the data cannot tell, the Weibayes at each shape of :func:`rupture_shapes`,
    whose intervals a prediction unites (:func:`analyses.life_posterior.rul_over_shapes`): a mode
    seen once, or not yet, is bounded by the distance run without it, never assumed absent, and its
    wear-out neither assumed nor ruled out.

    Parameters
    ----------
    life : array_like
        Lives [km]: failure or censoring distances.
    failed : array_like of bool
        True for a failure, any mode (the logbook's: they bound the shape).
    other : array_like of bool
        True for a failure by another mode than the leak.
    shape : float, optional
        The other modes' Weibull shape, known [-].
    confidence : float
        Two-sided level of the logbook shape's bound. [-]
    n_draws : int
        Parameter draws. [-]
    seed : int
        Seed of the draws.
    logbook_fit : WeibullFit, optional
        :func:`weibull_fit <analyses.service_life.weibull_fit>` of ``life`` and ``failed``, when the
        caller has it (:func:`rupture_shapes`).

    Returns
    -------
    (posteriors, note) : (list of WeibullPosterior, str or None)
        One model, or one per shape of the grid; empty with the reason when there is none; the
        note says so when the shape was not known.
    """
    other = np.asarray(other, bool)
    note = None
    if shape is not None:
        posts = [weibayes_posterior(life, other, shape, n_draws, seed)]
    elif int(other.sum()) >= 2:
        posts = [weibull_posterior(life, other, n_draws, seed)]
    else:
        shapes, note = rupture_shapes(life, failed, confidence, logbook_fit)
        posts = [weibayes_posterior(life, other, k, n_draws, seed) for k in shapes]
        if not posts:
            return [], note
    bad = [p.note for p in posts if not p.ok]
    return ([], f"the other failure modes: {bad[0]}") if bad else (posts, note)


__all__ = ["BACKTEST_COLUMNS", "BACKTEST_FRACTIONS", "N_RUPTURE_SHAPES", "RUL_COLUMNS", "RulSettings", "data_seed",
           "rupture_model", "rupture_shapes"]
