"""Remaining life of running hoses: from the life model, from each hose's leak growth; backtests.

Distances are in km, leaks in l/min (ANR) at the plan's test pressure. A hose is ``running``,
``failed`` or ``removed`` (``hoses``: ``hose_id``, ``distance_km``, ``status``, optionally
``failure_mode``); its leak path is its leakage plateaus at its distance (``points``:
``hose_id``, ``distance_km``, ``leak_l_min``, one pressure level, as ``hose_leak_growth`` gives
them). Every prediction is a median and a two-sided **prediction interval** at ``confidence``
for the distance a running hose has left [km], NaN with a one-line ``note`` when the data
cannot tell.

``weibull``: the life model conditioned on survival
---------------------------------------------------
The hose type's lives (failures exact, removed and running hoses right-censored) have a
two-parameter Weibull likelihood (:mod:`analyses.service_life`). A running hose at distance
``d`` has the conditional survival ``S(d + r) / S(d)``. Plugging in the estimate ignores the
parameters' uncertainty and gives intervals that are too short with few failures (Meeker &
Escobar 1998, ch. 12; Escobar & Meeker 1999, "Statistical prediction based on censored life
data", Technometrics 41). Here the predictive distribution is the conditional distribution
**integrated over the likelihood** with the prior flat in ``(log shape, log scale)``:
``P(R > r) = E[S(d + r | theta) / S(d | theta) | data]``. ``log T`` is a location-scale variable
(location ``log scale``, scale ``1 / shape``), and this prior is its right-invariant one, whose
prediction intervals for a new unit have exact frequentist coverage with complete and Type II
censored data (Hora & Buehler 1967, "Fiducial theory and invariant prediction"; Lawless 2003,
*Statistical Models and Methods for Lifetime Data*); conditioned on a running unit's distance and
with Type I censoring they are approximate: their calibration is measured in
``benchmarks/bench_remaining_life.py``. The integral is computed by importance sampling: draws
from a Student-t (4 df) around the maximum likelihood estimate with twice its observed-information
covariance, then once more from a Student-t with the first draws' weighted mean and twice their
covariance (adaptive importance sampling), weighted by likelihood over proposal; the predictive
quantiles are found by bisection on the exact mixture of conditional Weibull survivals, so they
carry no sampling noise of their own. The running hose's own survival to ``d`` is in the data
(a suspension), so the posterior is already conditioned on it.

**The family** (:class:`LifeModel`, docs/decision.md "Remaining life: the life model's family"):
a life that ends at the first of a leak crossing (lognormal when the wear rate is) and a rupture is
not Weibull, and a Weibull fitted to its early failures has too short an upper tail. The same
computation is done for the lognormal (also log-location-scale, the same prior), and the predictive
distribution is the mixture of the two families' with their posterior probabilities: the ratio of
their marginal likelihoods under the shared right-invariant prior is a proper Bayes factor (Berger,
Pericchi & Varshavsky 1998; Hoeting et al. 1999, Bayesian model averaging), estimated from the same
importance-sampling draws and re-weighted with them in the backtest. Meeker & Escobar (1998, ch. 6-8)
compare the two families by their probability plots and maximised likelihoods; with the few
early failures a group has seen, that comparison rarely decides (the lognormal fits better in about
two thirds of groups of truly Weibull lives), so the method averages rather than picks. The
``note`` gives the families' shares and the difference of their maximised log-likelihoods when the
lognormal carries 5 % or more.

``degradation``: each hose's leak path, pooled, run to the limit
----------------------------------------------------------------
A random-effects degradation model (Lu & Meeker 1993, Technometrics 35; Meeker & Escobar 1998,
ch. 13): ``log leak_ij = alpha_i + gamma log d_ij + e_ij``, ``alpha_i ~ N(mu, tau^2)`` from hose
to hose, ``e_ij ~ N(0, sigma^2)``. Equivalently ``leak = (w_i d)^gamma`` l/min with a hose's
**wear rate** ``w_i = exp(alpha_i / gamma)`` [1/km] (``1 / w_i`` is the distance at which its leak
reaches 1 l/min), lognormal across hoses. Why this form: the leak through a worn seal goes as a
power (about 1.5, an orifice) of the seal's pressure deficit, and the deficit grows in proportion
to the wear, i.e. to distance at the hose's own rate; the exponent ``gamma`` is a property of the
seal shared by the hoses of a type and is estimated, not assumed (``gamma = 1`` is a linear path).
The crossing distance of the limit ``L`` is ``D_i = L^(1/gamma) / w_i``: lognormal, so the model
has the closed forms Lu & Meeker recommend. Fit: ``gamma`` and ``sigma`` from the within-hose
regression with one intercept per hose (:func:`analyses.quality.linear_lstsq`), ``mu`` and
``tau`` by maximum likelihood of the hoses' intercepts given their sampling variances
``sigma^2 / n_i`` (a one-way random-effects model with unequal counts). Prediction for a running
hose: its intercept's posterior given its own points (the best linear unbiased predictor and
its variance), truncated to "not crossed by now" (it is running). Parameter uncertainty: draws
of ``gamma`` (normal), ``sigma^2`` (scaled inverse chi-square on its degrees of freedom),
``tau^2`` (scaled inverse chi-square on ``tau^4 sum w_i^2`` effective degrees of freedom, from its
observed information), ``mu`` (normal, recomputed for each ``gamma`` drawn) - a large-sample
approximation of the posterior (Meeker & Escobar 1998, ch. 13, use the bootstrap; these draws
are cheaper and their calibration is measured, not assumed).

Other failure modes (a rupture) end a hose before its leak crosses the limit. They enter as a
competing risk (Meeker & Escobar 1998, ch. 15): a Weibull fitted to the failures that were not
leak failures (the leak failures censored at their distance), with its predictive draws as above,
independent of the leak path; the remaining life is ``min(crossing, rupture)``, so this method is
the joint model of the hose's own leak path and the logbook's ruptures. With one such failure or
none the Weibull has no proper posterior; the mode is then a Weibayes (:func:`weibayes_posterior`;
Abernethy 2006, ch. 6; Nelson 1985): a Weibull of known shape whose scale has the Jeffreys
posterior from the exposure, ``Gamma(r + 1/2, sum t^k)`` on ``scale^-k``: a mode seen once or not
yet is bounded by the distance run without it rather than left out (leaving it out covered only a
third of the hoses that then ruptured first). Zero or one rupture cannot tell the shape: the plan's
``rupture_shape`` gives it when the lab knows it (:attr:`RulSettings.rupture_shape`; then the
Weibayes at it, whatever the count). When it does not, the interval must hold for every plausible
shape (:func:`rupture_model`, :func:`rul_over_shapes`): it is the union of the intervals at the
shapes of a geometric grid from 1 (the constant hazard) to the upper ``confidence`` profile bound
of the hose type's logbook Weibull shape (all failure modes; :func:`weibull_shape_bounds
<analyses.service_life.weibull_shape_bounds>`), and the row's note says the shape was not known;
its median is the equal mixture's over the grid. Without that bound (fewer than two failures in the
logbook, or a bound the data do not close) the rupture part, and so the joint prediction, is NaN
with the reason.

Leak points at or below ``floor_multiple`` times the sensor's floor (:meth:`Sensor.floor
<analyses.quality.Sensor.floor>`: the larger of its stated resolution and noise) are left out of
the fit: the log model needs a leak well above the additive sensor noise (at 10 x the floor the
noise adds at most about 0.1 to the log). A hose's prediction is NaN with a note when it has
fewer than :data:`MIN_LEAK_POINTS` points in all, fewer than that above the floor ("noisy at
the sensor floor"), or its own path is falling or flat (its own log-log slope not positive by
twice its standard error, :meth:`Gate.identifiable <analyses.quality.Gate.identifiable>`).

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

Leak-limit crossing
-------------------
:func:`leak_crossing_life`: the first distance at which a hose's leak path reaches a limit,
linearly interpolated between the two plateaus either side; a path that never reaches it is
censored at its last plateau (the last distance it was known to be below the limit).
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
import scipy

from analyses.numerics import fminbound
from analyses.quality import Gate, Sensor, at_bound, linear_lstsq
from analyses.service_life import WeibullFit, weibull_fit, weibull_loglik_many, weibull_shape_bounds
from analyses.service_life_lognormal import lognormal_fit, lognormal_loglik_many

_NAN = float("nan")
#: Leak points a hose needs above the sensor floor for its own prediction: two to draw a path
#: and one to check it. [-]
MIN_LEAK_POINTS = 3
#: Hoses with leak paths (two points or more) needed to pool a degradation model. [-]
MIN_HOSES = 3
#: A leak point enters the fit when it is above this multiple of the sensor's floor. [-]
FLOOR_MULTIPLE = 10.0
#: Draws of the parameters per predictive distribution. [-]
N_DRAWS = 1000
#: Effective sample size below which importance-weighted draws are not trusted. [-]
MIN_ESS = 100.0
#: Rounds of adaptive importance sampling: at least, at most [-], and the effective size, in
#: multiples of :data:`MIN_ESS`, at which the rounds stop early [-].
MIN_ADAPT_ROUNDS, MAX_ADAPT_ROUNDS, ADAPTED_ESS = 2, 8, 3.0
#: Search range of the hose-to-hose variance of the log leak; an estimate at its ends is NaN. [-]
TAU2_BOUNDS = (1e-8, 1e2)
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


# -- the Weibull predictive ------------------------------------------------------------------
@dataclass
class WeibullPosterior:
    """Draws of (shape, scale) weighted to the likelihood of censored lives (flat prior in logs).

    Attributes
    ----------
    shape, scale : numpy.ndarray
        Proposal draws [-], [km].
    log_weight : numpy.ndarray
        Log-likelihood of the data minus the proposal's log density, per draw.
    fit : WeibullFit
        The maximum likelihood fit the proposal is centred on.
    note : str or None
        Why there are no draws (then the arrays are empty).
    fixed_shape : bool
        The shape is not drawn (:func:`weibayes_posterior`: known): one failure, or none, is then
        enough for the model.
    family : str
        ``weibull`` or ``lognormal``. Both are log-location-scale: ``log T = log scale + Z / shape``
        with ``Z`` smallest-extreme-value (Weibull) or standard normal (lognormal: ``scale`` is the
        median, ``shape`` is ``1 / sigma``), so the draws, the prior and :attr:`fit` read alike.
    """

    shape: np.ndarray
    scale: np.ndarray
    log_weight: np.ndarray
    fit: WeibullFit
    note: str | None = None
    fixed_shape: bool = False
    family: str = "weibull"
    parts: tuple = ()

    @property
    def ok(self) -> bool:
        return self.note is None

    @property
    def weibayes(self) -> tuple:
        """The Weibayes fits (:func:`weibayes_posterior`) this posterior is, or is an equal mixture of
        (``parts``); empty when it is not (its draws are re-weighted, or a Weibull): then only the
        draws describe it."""
        fits = []
        for p in self.parts or (self,):
            if not (p.fixed_shape and p.ok and np.all(p.shape == p.fit.shape)
                    and np.all(p.log_weight == p.log_weight[0])):
                return ()
            fits.append(p.fit)
        return tuple(fits)

    def weights(self) -> tuple[np.ndarray, float]:
        """Normalised weights of the draws and their effective sample size (Kish). [-]"""
        lw = np.where(np.isfinite(self.log_weight), self.log_weight, -np.inf)
        w = np.exp(lw - lw.max())
        w /= w.sum()
        return w, float(1.0 / np.sum(w ** 2))

    def log_evidence(self) -> float:
        """Log of the importance-sampling estimate of the data's marginal likelihood under the flat prior
        in (log shape, log scale): the mean of likelihood / proposal density (``log_weight`` is on that
        absolute scale). Comparable between families: they share the parameter space and the prior."""
        lw = self.log_weight[np.isfinite(self.log_weight)]
        if lw.size == 0:
            return -math.inf
        top = float(lw.max())
        return top + math.log(float(np.sum(np.exp(lw - top))) / self.log_weight.size)

    def changed(self, out_life, out_failed, in_life, in_failed) -> "WeibullPosterior":
        """The posterior of the data with the units ``out`` removed and ``in`` added.

        Exact re-weighting of the same draws (case-deletion importance sampling, Gelfand, Dey &
        Chang 1992): no refit. ``*_life`` [km], ``*_failed`` bool, array_like each.
        """
        if not self.ok:
            return self
        n_failed = self.fit.n_failed - int(np.sum(out_failed)) + int(np.sum(in_failed))
        fit = WeibullFit(self.fit.shape, self.fit.scale, _NAN, self.fit.n, n_failed)   # loglik: not refitted
        if n_failed < 2 and not self.fixed_shape:
            empty = np.empty(0)
            return WeibullPosterior(empty, empty, empty, fit, note=f"too few failures: {n_failed} < 2",
                                    family=self.family)
        with np.errstate(invalid="ignore"):   # -inf - -inf: a draw the data rule out stays out
            lw = (self.log_weight - _loglik_many(self.family, self.shape, self.scale, out_life, out_failed)
                  + _loglik_many(self.family, self.shape, self.scale, in_life, in_failed))
        return WeibullPosterior(self.shape, self.scale, lw, fit, fixed_shape=self.fixed_shape, family=self.family)


def _loglik_many(family: str, shape, scale, life, failed) -> np.ndarray:
    """Log-likelihood of censored lives per (shape, scale) draw under ``family`` (see :class:`WeibullPosterior`)."""
    if family == "lognormal":
        with np.errstate(divide="ignore"):
            return lognormal_loglik_many(1.0 / np.asarray(shape, float), scale, life, failed)
    return weibull_loglik_many(shape, scale, life, failed)


def _family_fit(family: str, life, failed) -> WeibullFit:
    """The maximum likelihood fit of ``family``, as (shape, scale) of :class:`WeibullPosterior`."""
    if family == "weibull":
        return weibull_fit(life, failed)
    f = lognormal_fit(life, failed)
    return WeibullFit(1.0 / f.sigma if f.ok else _NAN, f.median, f.loglik, f.n, f.n_failed, note=f.note)


def weibull_posterior(life, failed, n_draws: int = N_DRAWS, seed: int = 0,
                      family: str = "weibull") -> WeibullPosterior:
    """Importance-sampled posterior of the Weibull (or lognormal) parameters of censored lives.

    Parameters
    ----------
    life : array_like
        Lives [km]: failure or censoring distances.
    failed : array_like of bool
        True for a failure.
    n_draws : int
        Proposal draws. [-]
    seed : int
        Seed of the draws.
    family : str
        ``weibull`` or ``lognormal`` (:class:`WeibullPosterior`).

    Returns
    -------
    WeibullPosterior
        Empty with a ``note`` when the fit has no estimate (fewer than two failures, the shape
        at its search bound) or the observed information is not positive definite.
    """
    fit = _family_fit(family, life, failed)
    empty = np.empty(0)
    if not fit.ok:
        return WeibullPosterior(empty, empty, empty, fit, note=f"no {_FAMILY_NAMES[family]} fit: {fit.note}",
                                family=family)
    centre = np.array([math.log(fit.shape), math.log(fit.scale)])
    h = 1e-3
    steps = np.array([[i, j] for i in (-1, 0, 1) for j in (-1, 0, 1)], float) * h
    ll = _loglik_many(family, np.exp(centre[0] + steps[:, 0]), np.exp(centre[1] + steps[:, 1]), life, failed)
    g = ll.reshape(3, 3)
    hess = np.array([[g[2, 1] - 2 * g[1, 1] + g[0, 1], (g[2, 2] - g[2, 0] - g[0, 2] + g[0, 0]) / 4],
                     [0.0, g[1, 2] - 2 * g[1, 1] + g[1, 0]]]) / h ** 2
    hess[1, 0] = hess[0, 1]
    try:
        cov = np.linalg.inv(-hess)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return WeibullPosterior(empty, empty, empty, fit, note="the likelihood is not peaked at its maximum",
                                family=family)
    return _adapted_draws(life, failed, fit, (centre, cov), n_draws, np.random.default_rng(seed), family)


def _adapted_draws(life, failed, fit: WeibullFit, start: tuple, n_draws: int, rng,
                   family: str = "weibull") -> WeibullPosterior:
    """Adaptive importance sampling (Cappe, Guillin, Marin & Robert 2004, "Population Monte Carlo"):
    each proposal a Student-t with the previous round's weighted mean and twice its covariance, at
    least :data:`MIN_ADAPT_ROUNDS` rounds and at most :data:`MAX_ADAPT_ROUNDS`, stopping once the
    effective sample size reaches :data:`ADAPTED_ESS` times :data:`MIN_ESS`; the round of the largest
    effective size is kept. With two or three failures the posterior is skewed (a banana in log shape
    and log scale) and two rounds often left fewer than :data:`MIN_ESS` effective draws."""
    centre, cov = start
    best, best_ess = None, -1.0
    for k in range(MAX_ADAPT_ROUNDS):
        theta, log_w = _t_draws(centre, 2.0 * cov, n_draws, rng)
        with np.errstate(over="ignore"):
            shape, scale = np.exp(theta[:, 0]), np.exp(theta[:, 1])
        log_w = log_w + _loglik_many(family, shape, scale, life, failed)
        post = WeibullPosterior(shape, scale, log_w, fit, family=family)
        w, ess = post.weights()
        if best is None or ess > best_ess:
            best, best_ess = post, ess
        if k + 1 >= MIN_ADAPT_ROUNDS and best_ess >= ADAPTED_ESS * MIN_ESS:
            break
        centre = w @ theta
        cov = (theta - centre).T @ ((theta - centre) * w[:, None])
        try:   # a degenerate round (one draw carries the weight) cannot propose the next
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            break
        if not np.isfinite(centre).all():
            break
    return best


def weibayes_posterior(life, failed, shape: float = 1.0, n_draws: int = N_DRAWS, seed: int = 0) -> WeibullPosterior:
    """Draws of a Weibull life model of known ``shape`` (Weibayes), the scale from the exposure.

    With the shape ``k`` known, ``t^k`` of a Weibull life is exponential with the rate
    ``scale^-k``, so ``r`` failures in the exposure ``T_k = sum t_i^k`` (the lives, failed or
    censored) give the rate the posterior ``Gamma(r + 1/2, T_k)`` with the Jeffreys prior on it
    (Jeffreys 1961; Atwood et al. 2003, NUREG/CR-6823, section 6.2.2): proper with one failure or
    none. This is Weibayes (Abernethy 2006, *The New Weibull Handbook*, ch. 6; Nelson 1985,
    "Weibull analysis of reliability data with few or no failures", J. Quality Technology 17):
    Nelson's confidence bounds on the rate are ``chi2(2r + 2) / 2T_k`` (its upper) and
    ``chi2(2r) / 2T_k`` (its lower); the Jeffreys posterior is ``chi2(2r + 1) / 2T_k``, between the
    two. ``shape = 1`` is the constant hazard: no wear-out claimed where the data cannot show one.

    Parameters
    ----------
    life : array_like
        Lives [km]: failure or censoring distances.
    failed : array_like of bool
        True for a failure.
    shape : float
        The Weibull shape, known [-], > 0.
    n_draws : int
        Draws of the rate. [-]
    seed : int
        Seed of the draws.

    Returns
    -------
    WeibullPosterior
        Equal weights, ``shape`` in every draw, ``fixed_shape``; empty with a note without exposure.
    """
    life = np.asarray(life, float)
    failed = np.asarray(failed, bool)
    keep = np.isfinite(life) & (life > 0)
    life, r = life[keep], int(np.sum(failed[keep]))
    top = float(life.max()) if life.size else 0.0
    exposure = float(np.sum((life / top) ** shape)) if top > 0 else 0.0   # T_k / top^k: no overflow
    empty = np.empty(0)
    fit = WeibullFit(float(shape), top * (exposure / (r + 0.5)) ** (1.0 / shape) if top > 0 else _NAN, _NAN,
                     int(life.size), r)
    if not exposure > 0:
        return WeibullPosterior(empty, empty, empty, fit, note="no exposure: no distance run", fixed_shape=True)
    rate = np.random.default_rng(seed).gamma(r + 0.5, 1.0 / exposure, n_draws)   # of (t / top)^k
    return WeibullPosterior(np.full(n_draws, float(shape)), top * rate ** (-1.0 / shape), np.zeros(n_draws), fit,
                            fixed_shape=True)


def _t_draws(centre, cov, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """(``n`` draws of (log shape, log scale) from a bivariate Student-t with 4 degrees of freedom,
    minus the log proposal density of each: ``log(2 pi) + log|cov| / 2 + 3 log(1 + t't / 4)``, whole,
    so that likelihood / proposal estimates the marginal likelihood, :meth:`WeibullPosterior.log_evidence`)."""
    df = 4.0
    t = rng.standard_normal((n, 2)) / np.sqrt(rng.chisquare(df, n) / df)[:, None]
    chol = np.linalg.cholesky(cov)
    theta = centre + t @ chol.T
    log_norm = math.log(2.0 * math.pi) + float(np.sum(np.log(np.diag(chol))))
    return theta, log_norm + 0.5 * (df + 2.0) * np.log1p(np.sum(t ** 2, axis=1) / df)


def _weibull_survival_at(shape, scale, d: float):
    """``r -> S(d + r) / S(d)`` per draw (rows) and remaining distance ``r > 0`` (columns). [-]

    Computed as ``exp(-(d/s)^k ((1 + r/d)^k - 1))`` in logs, so that a draw under which the unit
    could not have reached ``d`` gives 0 rather than ``inf - inf``. What does not depend on ``r`` is
    computed once: a bisection evaluates the function some forty times (the same operations on the
    same arrays: the same floats as computing it whole each time).
    """
    k, s = np.asarray(shape)[:, None], np.asarray(scale)[:, None]
    with np.errstate(over="ignore", divide="ignore"):
        log_s = np.log(s)
        base = k * (math.log(d) - log_s) if d > 0 else None

    def survival(r):
        r = np.atleast_1d(np.asarray(r, float))[None, :]
        with np.errstate(over="ignore", divide="ignore"):
            log_h = base + np.log(np.expm1(k * np.log1p(r / d))) if d > 0 else k * (np.log(r) - log_s)
            return np.exp(-np.exp(log_h))
    return survival


def _survival_at(post: "WeibullPosterior", d: float):
    """``r -> S(d + r) / S(d)`` per draw of ``post`` (rows) and remaining distance (columns), in its
    family [-]; the survival to ``d`` computed once (:func:`_weibull_survival_at`)."""
    if post.family == "weibull":
        return _weibull_survival_at(post.shape, post.scale, d)
    k, log_s = post.shape[:, None], np.log(post.scale)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        now = scipy.special.log_ndtr(-(math.log(d) - log_s) * k) if d > 0 else np.zeros_like(log_s)

    def survival(r):
        r = np.atleast_1d(np.asarray(r, float))[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            later = scipy.special.log_ndtr(-(np.log(d + r) - log_s) * k)
            return np.exp(np.minimum(np.nan_to_num(later - now, nan=-np.inf), 0.0))
    return survival


@dataclass
class LifeModel:
    """The hose type's life model: the Weibull and the lognormal posteriors, weighed by their evidence.

    Both families are log-location-scale with the same flat prior in (log shape, log scale), the
    right-invariant one, under which the ratio of their marginal likelihoods is a proper Bayes factor
    (Berger, Pericchi & Varshavsky 1998, "Bayes factors and marginal distributions in invariant
    situations", Sankhya A 60): the predictive distribution is the mixture of the two families'
    predictive distributions with their posterior probabilities (equal prior odds; Hoeting, Madigan,
    Raftery & Volinsky 1999, "Bayesian model averaging"). With many failures the family the lives
    follow carries the weight; with a few, both do and the interval holds both.

    Attributes
    ----------
    families : tuple of WeibullPosterior
        One per family (:data:`LIFE_FAMILIES`).
    """

    families: tuple

    def changed(self, out_life, out_failed, in_life, in_failed) -> "LifeModel":
        """Each family's :meth:`WeibullPosterior.changed` (the backtest's data then)."""
        return LifeModel(tuple(p.changed(out_life, out_failed, in_life, in_failed) for p in self.families))

    def usable(self) -> tuple[list, np.ndarray]:
        """(the families with draws that cover their likelihood, their posterior probabilities [-])."""
        ok = [p for p in self.families if p.ok and p.weights()[1] >= MIN_ESS]
        log_z = np.array([p.log_evidence() for p in ok])
        prob = np.exp(log_z - log_z.max()) if ok else log_z
        return ok, prob / prob.sum() if ok else prob

    def family_note(self) -> str | None:
        """Which family carries the prediction, when the lognormal has a share of at least 5 %."""
        ok, prob = self.usable()
        share = dict(zip((p.family for p in ok), prob))
        if share.get("lognormal", 0.0) < 0.05:
            return None
        fits = {p.family: p.fit.loglik for p in self.families}
        diff = fits.get("lognormal", _NAN) - fits.get("weibull", _NAN)
        told = f"; maximised log-likelihood lognormal - Weibull {diff:+.1f}" if math.isfinite(diff) else ""
        return (f"life model: lognormal {share.get('lognormal', 0.0):.2f}, Weibull {share.get('weibull', 0.0):.2f} "
                f"(posterior probabilities{told})")


#: Life families of the ``weibull`` method's :class:`LifeModel`, and their names in notes.
LIFE_FAMILIES = ("weibull", "lognormal")
_FAMILY_NAMES = {"weibull": "Weibull", "lognormal": "lognormal"}


def life_model(life, failed, n_draws: int = N_DRAWS, seed: int = 0) -> LifeModel:
    """The ``weibull`` method's life model of censored lives: :func:`weibull_posterior` of each of
    :data:`LIFE_FAMILIES` (see :class:`LifeModel`).

    Parameters
    ----------
    life : array_like
        Lives [km]: failure or censoring distances.
    failed : array_like of bool
        True for a failure.
    n_draws : int
        Proposal draws per family. [-]
    seed : int
        Seed of the draws.

    Returns
    -------
    LifeModel
    """
    return LifeModel(tuple(weibull_posterior(life, failed, n_draws, seed, family=f) for f in LIFE_FAMILIES))


def _mixture_quantiles(survival, weights, probs, guess: float) -> np.ndarray:
    """Remaining distances where the weighted mixture of ``survival(r)`` reaches ``1 - p``. [km]

    ``survival(r)`` gives one survival per draw (rows) and distance (columns); the mixture's
    quantiles are found by bisection on a log scale, from ``guess * 1e-9`` to ``guess * 1e6``
    (NaN beyond: the data do not bound it).
    """
    probs = np.asarray(probs, float)
    lo = np.full(probs.shape, math.log(guess * 1e-9))
    hi = np.full(probs.shape, math.log(guess * 1e6))
    f_hi = 1.0 - weights @ survival(np.exp(hi))
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        cdf = 1.0 - weights @ survival(np.exp(mid))
        below = cdf < probs
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    q = np.exp(0.5 * (lo + hi))
    return np.where(f_hi >= probs, q, _NAN)


def _probs(confidence: float) -> np.ndarray:
    return np.array([0.5, (1.0 - confidence) / 2.0, (1.0 + confidence) / 2.0])


def weibull_rul(post: "WeibullPosterior | LifeModel", distance_km: float,
                confidence: float = 0.90) -> tuple[np.ndarray, str | None]:
    """Median and prediction interval of the distance left to a unit running at ``distance_km``.

    Parameters
    ----------
    post : WeibullPosterior or LifeModel
        Draws of the hose type's life model (its data include this unit as a suspension); a
        :class:`LifeModel`'s families mixed with their posterior probabilities.
    distance_km : float
        The unit's distance now [km].
    confidence : float
        Two-sided level of the prediction interval. [-]

    Returns
    -------
    (quantiles, note) : (numpy.ndarray, str or None)
        ``[median, lower, upper]`` [km]; NaN with a note when the posterior has no draws; the
        note of a :class:`LifeModel` says which family carries the numbers when not the Weibull.
    """
    model = post if isinstance(post, LifeModel) else LifeModel((post,))
    first = model.families[0]
    if not first.ok and not any(p.ok for p in model.families):
        return np.full(3, _NAN), first.note
    if not distance_km >= 0:
        return np.full(3, _NAN), "no distance now"
    fits = first.weibayes if len(model.families) == 1 else ()
    if len(fits) == 1:
        return _weibayes_quantiles(fits[0], distance_km, _probs(confidence)), None
    if fits:   # an equal mixture of Weibayes: bisection on their exact survivals
        q = _mixture_quantiles(lambda r: _weibayes_survival(fits, distance_km, r), np.full(len(fits), 1.0 / len(fits)),
                               _probs(confidence), float(np.median([f.scale for f in fits])))
        return q, (None if np.isfinite(q).all() else "the prediction interval is open: the data do not bound it")
    ok, prob = model.usable()
    if not ok:
        ess = first.weights()[1] if first.ok else 0.0
        return np.full(3, _NAN), f"the parameter draws do not cover the likelihood (effective {ess:.0f})"
    weights = np.concatenate([pr * p.weights()[0] for p, pr in zip(ok, prob)])
    guess = float(ok[int(np.argmax(prob))].fit.scale)
    survivals = [_survival_at(p, distance_km) for p in ok]
    q = _mixture_quantiles(lambda r: np.vstack([survival(r) for survival in survivals]),
                           weights, _probs(confidence), guess)
    if not np.isfinite(q).all():
        return q, "the prediction interval is open: the data do not bound it"
    return q, model.family_note()


def _weibayes_quantiles(fit: WeibullFit, d: float, probs) -> np.ndarray:
    """Quantiles of the distance left [km] under a Weibayes (:func:`weibayes_posterior`), exact.

    With the rate ``scale^-k ~ Gamma(a, T_k)`` (``a = r + 1/2``, ``T_k = a fit.scale^k``) the
    predictive is ``P(R > r) = (1 + u / a)^-a`` with ``u = ((d + r) / fit.scale)^k - (d / fit.scale)^k``
    (a Lomax in ``u``), so ``r`` at probability ``p`` is ``fit.scale (d_k + u_p)^(1/k) - d`` with
    ``u_p = a ((1 - p)^(-1/a) - 1)`` and ``d_k = (d / fit.scale)^k``: the draws' mixture without
    their Monte Carlo error.
    """
    a, k, s = fit.n_failed + 0.5, fit.shape, fit.scale
    u = a * np.expm1(-np.log1p(-np.asarray(probs, float)) / a)
    return s * ((d / s) ** k + u) ** (1.0 / k) - d


def _weibayes_survival(fits, d: float, r) -> np.ndarray:
    """``P(R > r)`` of each Weibayes fit (rows) at each remaining distance ``r`` (columns), exact
    (:func:`_weibayes_quantiles`). [-]"""
    r = np.atleast_1d(np.asarray(r, float))[None, :]
    out = []
    for f in fits:
        a, k, s = f.n_failed + 0.5, f.shape, f.scale
        with np.errstate(over="ignore"):
            u = ((d + r) / s) ** k - (d / s) ** k
            out.append(np.exp(-a * np.log1p(u / a))[0])
    return np.array(out)


def rul_over_shapes(predict, posts) -> tuple[np.ndarray, str | None]:
    """The prediction that holds for each of several life models (one per rupture shape).

    Parameters
    ----------
    predict : callable
        ``post -> (quantiles, note)``: one model's ``[median, lower, upper]`` [km] (:func:`weibull_rul`,
        or the joint prediction of :func:`degradation_rul`).
    posts : sequence of WeibullPosterior
        The models (:func:`rupture_model`); one alone is its own prediction.

    Returns
    -------
    (quantiles, note) : (numpy.ndarray, str or None)
        ``[median, lower, upper]`` [km]: the union of the intervals (the least lower end, the
        greatest upper end) and the median of the models' equal mixture; NaN with the note when
        there is no model or one of them has no prediction.
    """
    posts = list(posts)
    if not posts:
        return np.full(3, _NAN), "no rupture model"
    if len(posts) == 1:
        return predict(posts[0])
    qs = []
    for post in [*posts, _equal_mixture(posts)]:
        q, note = predict(post)
        if not np.isfinite(q).all():
            return np.full(3, _NAN), note
        qs.append(q)
    qs = np.array(qs)
    return np.array([qs[-1, 0], qs[:-1, 1].min(), qs[:-1, 2].max()]), None


def _equal_mixture(posts: list) -> WeibullPosterior:
    """The models' draws pooled, each model's weights summing to ``1 / len(posts)``."""
    logs = []
    for post in posts:
        w, _ = post.weights()
        with np.errstate(divide="ignore"):
            logs.append(np.log(w / len(posts)))
    return WeibullPosterior(np.concatenate([p.shape for p in posts]), np.concatenate([p.scale for p in posts]),
                            np.concatenate(logs), posts[0].fit, fixed_shape=all(p.fixed_shape for p in posts),
                            parts=tuple(posts))


# -- the degradation model ---------------------------------------------------------------------
@dataclass
class DegradationFit:
    """The pooled leak-growth model ``log leak = alpha_i + gamma log d`` of one hose type.

    Attributes
    ----------
    gamma, gamma_se : float
        Growth exponent of the leak with distance and its standard error. [-]
    sigma : float
        Residual standard deviation of the log leak (measurement and path). [-]
    dof : int
        Degrees of freedom of ``sigma``. [-]
    mu, mu_se : float
        Mean of the hoses' log-leak intercepts ``alpha_i`` [log(l/min)] and its standard error.
    tau : float
        Hose-to-hose standard deviation of ``alpha_i``. [-]
    hoses : DataFrame
        Per hose: ``hose_id``, ``n_points`` (all), ``n_used`` (above the floor), ``x_mean`` (mean
        log distance of the used points), ``z_mean`` (their mean log leak), ``leak_now_l_min``
        (the last point), ``note`` (why its own prediction is NaN).
    floor_l_min : float
        Leak below which points are left out [l/min].
    note : str or None
        Why the model has no estimate.
    """

    gamma: float
    gamma_se: float
    sigma: float
    dof: int
    mu: float
    mu_se: float
    tau: float
    hoses: pd.DataFrame
    floor_l_min: float
    note: str | None = None

    @property
    def ok(self) -> bool:
        return self.note is None

    def wear_rate(self) -> tuple[float, float]:
        """Mean and standard deviation across hoses of the wear rate ``w = exp(alpha / gamma)``. [1/km]"""
        if not self.ok:
            return _NAN, _NAN
        m, s = self.mu / self.gamma, self.tau / self.gamma
        mean = math.exp(m + s * s / 2.0)
        return mean, mean * math.sqrt(math.expm1(s * s))


def _hose_gate(x: np.ndarray, z: np.ndarray, n_all: int, floor: float, min_points: int) -> str | None:
    """Why one hose's own path (``x`` log distance, ``z`` log leak of its points above the floor)
    cannot give a prediction (None when it can)."""
    if n_all < min_points:
        return f"too few leak points: {n_all} < {min_points}"
    if len(x) < min_points:
        return (f"noisy at the sensor floor: {len(x)} of {n_all} leak points above {floor:.3g} l/min "
                f"({min_points} needed)")
    sxx = float(np.sum((x - x.mean()) ** 2))
    if not sxx > 0:
        return "leak path flat: its points are at one distance"
    slope = float(np.sum((x - x.mean()) * (z - z.mean())) / sxx)
    resid = z - z.mean() - slope * (x - x.mean())
    se = math.sqrt(float(np.sum(resid ** 2)) / (len(x) - 2) / sxx)
    if slope <= 0:
        return f"leak path falling (log-log slope {slope:.2g})"
    g = Gate().identifiable(beta=[slope], se=[se], names=["its leak growth"])
    return None if g.ok else f"leak path flat: {g.note}"


def _per_hose(points: pd.DataFrame, floor: float, min_points: int) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(usable points with ``x`` = log distance and ``z`` = log leak, one row per hose)."""
    p = points.dropna(subset=["distance_km", "leak_l_min"]).sort_values(["hose_id", "distance_km"], kind="stable")
    hid = p["hose_id"].to_numpy()
    d, y = p["distance_km"].to_numpy(float), p["leak_l_min"].to_numpy(float)
    good = (y > floor) & (d > 0)
    x, z = np.log(np.where(good, d, 1.0)), np.log(np.where(good, y, 1.0))
    ids, first, counts = np.unique(hid, return_index=True, return_counts=True)
    rows = []
    for h, a, n in zip(ids, first, counts):
        sl = slice(a, a + n)
        k = good[sl]
        xs, zs = x[sl][k], z[sl][k]
        rows.append({"hose_id": h, "n_points": int(n), "n_used": int(k.sum()),
                     "x_mean": xs.mean() if k.any() else _NAN, "z_mean": zs.mean() if k.any() else _NAN,
                     "leak_now_l_min": float(y[a + n - 1]), "note": _hose_gate(xs, zs, int(n), floor, min_points)})
    cols = ["hose_id", "n_points", "n_used", "x_mean", "z_mean", "leak_now_l_min", "note"]
    use = p[good].assign(x=x[good], z=z[good])
    return use, pd.DataFrame(rows, columns=cols)


def _random_intercepts(a: np.ndarray, s2: np.ndarray) -> tuple[float, float, float, bool]:
    """ML of ``a_i ~ N(mu, tau^2 + s2_i)``: (mu, se of mu, tau^2, tau^2 at a search bound)."""
    def neg(log_t2):
        v = np.exp(log_t2) + s2
        w = 1.0 / v
        mu = np.sum(w * a) / np.sum(w)
        return 0.5 * float(np.sum(np.log(v) + (a - mu) ** 2 / v))

    lo, hi = (math.log(b) for b in TAU2_BOUNDS)
    t2 = math.exp(float(fminbound(neg, lo, hi, xatol=1e-8)))
    w = 1.0 / (t2 + s2)
    return float(np.sum(w * a) / np.sum(w)), float(1.0 / math.sqrt(np.sum(w))), t2, at_bound(t2, *TAU2_BOUNDS)


def degradation_fit(points: pd.DataFrame, sensor: Sensor, floor_multiple: float = FLOOR_MULTIPLE,
                    min_points: int = MIN_LEAK_POINTS) -> DegradationFit:
    """Fit the pooled random-effects leak-growth model to the leak paths of one hose type.

    Parameters
    ----------
    points : DataFrame
        ``hose_id``, ``distance_km`` [km], ``leak_l_min`` [l/min]: the leak paths at one pressure.
    sensor : Sensor
        The leak channel's stated resolution and noise [l/min] (:mod:`analyses.quality`).
    floor_multiple : float
        Points at or below this multiple of ``sensor.floor()`` are left out. [-]
    min_points : int
        Points above the floor a hose needs for its own prediction. [-]

    Returns
    -------
    DegradationFit
        NaN parameters and a ``note`` with fewer than :data:`MIN_HOSES` hoses with two points
        above the floor, a growth exponent the data do not separate from zero or not positive,
        or a hose-to-hose spread at its search bound.
    """
    floor = floor_multiple * sensor.floor()
    use, hoses = _per_hose(points, floor, min_points)
    nan = DegradationFit(_NAN, _NAN, _NAN, 0, _NAN, _NAN, _NAN, hoses, floor)
    paths = hoses.loc[hoses["n_used"] >= 2, "hose_id"].tolist()
    if len(paths) < MIN_HOSES:
        nan.note = f"too few hoses with a leak path above the floor to pool: {len(paths)} < {MIN_HOSES}"
        return nan
    u = use[use["hose_id"].isin(paths)]
    within = u.groupby("hose_id")[["x", "z"]].transform("mean")
    xt, zt = (u["x"] - within["x"]).to_numpy(), (u["z"] - within["z"]).to_numpy()
    fit = linear_lstsq(xt[:, None], zt)            # the within-hose regression (one intercept per hose)
    dof = len(u) - len(paths) - 1
    sigma = float(np.sqrt(np.sum((zt - fit.fitted) ** 2) / dof)) if dof > 0 else _NAN
    gamma, gamma_se = float(fit.beta[0]), sigma / math.sqrt(float(np.sum(xt ** 2)))
    gate = Gate().enough_points(dof, 1, "degrees of freedom for the pooled path's scatter")
    gate.identifiable(beta=[gamma], se=[gamma_se], names=["growth exponent"])
    gate.physical("growth exponent", gamma, lo=0.0)
    if not gate.ok:
        nan.note = f"the pooled leak path: {gate.note}"
        return nan
    h = hoses[hoses["n_used"] >= 1]
    a = (h["z_mean"] - gamma * h["x_mean"]).to_numpy()
    mu, mu_se, t2, bound = _random_intercepts(a, sigma ** 2 / h["n_used"].to_numpy())
    if bound:
        return DegradationFit(gamma, gamma_se, sigma, dof, _NAN, _NAN, _NAN, hoses, floor,
                              note=f"the hose-to-hose spread of the wear rate ran to its search bound "
                                   f"(variance {t2:.2g}): the data cannot tell it")
    return DegradationFit(gamma, gamma_se, sigma, int(dof), mu, mu_se, math.sqrt(t2), hoses, floor)


@dataclass
class _DegradationDraws:
    """Parameter draws of a :class:`DegradationFit` (one value per draw)."""

    gamma: np.ndarray
    sigma2: np.ndarray
    tau2: np.ndarray
    mu_noise: np.ndarray


def _degradation_draws(fit: DegradationFit, n_draws: int, rng: np.random.Generator) -> _DegradationDraws:
    h = fit.hoses[fit.hoses["n_used"] >= 1]
    s2 = fit.sigma ** 2 / h["n_used"].to_numpy()
    nu_tau = max(fit.tau ** 4 * float(np.sum(1.0 / (fit.tau ** 2 + s2) ** 2)), 1.0)
    return _DegradationDraws(gamma=fit.gamma + fit.gamma_se * rng.standard_normal(n_draws),
                             sigma2=fit.sigma ** 2 * fit.dof / rng.chisquare(fit.dof, n_draws),
                             tau2=fit.tau ** 2 * nu_tau / rng.chisquare(nu_tau, n_draws),
                             mu_noise=rng.standard_normal(n_draws))


def _crossing_survival(fit: DegradationFit, dr: _DegradationDraws, hose_id, d: float, log_limit: float):
    """Per draw: ``r -> P(no crossing by d + r | not crossed by d, its points)``, and the
    probability the path says it has not crossed by ``d`` (median over draws)."""
    h = fit.hoses[fit.hoses["n_used"] >= 1]
    a_all = h["z_mean"].to_numpy()[None, :] - dr.gamma[:, None] * h["x_mean"].to_numpy()[None, :]
    v_all = dr.tau2[:, None] + dr.sigma2[:, None] / h["n_used"].to_numpy()[None, :]
    w = 1.0 / v_all
    mu = np.sum(w * a_all, axis=1) / np.sum(w, axis=1) + dr.mu_noise / np.sqrt(np.sum(w, axis=1))
    i = int(np.flatnonzero(h["hose_id"].to_numpy() == hose_id)[0])
    n_i = float(h["n_used"].iloc[i])
    prec = 1.0 / dr.tau2 + n_i / dr.sigma2
    m = (mu / dr.tau2 + n_i * a_all[:, i] / dr.sigma2) / prec
    sd = 1.0 / np.sqrt(prec)
    log_now = scipy.special.log_ndtr((log_limit - dr.gamma * math.log(d) - m) / sd)

    def survival(r):
        r = np.atleast_1d(np.asarray(r, float))[None, :]
        num = scipy.special.log_ndtr((log_limit - dr.gamma[:, None] * np.log(d + r) - m[:, None]) / sd[:, None])
        return np.exp(np.minimum(num - log_now[:, None], 0.0))

    return survival, float(np.exp(np.median(log_now)))


def degradation_rul(fit: DegradationFit, hose_id, distance_km: float, limit_l_min: float,
                    rupture=None, confidence: float = 0.90,
                    n_draws: int = N_DRAWS, seed: int = 0) -> tuple[np.ndarray, str | None]:
    """Median and prediction interval of the distance a running hose has left [km].

    Parameters
    ----------
    fit : DegradationFit
        The hose type's pooled model (its data include this hose's points up to now).
    hose_id : str
        The hose.
    distance_km : float
        Its distance now [km].
    limit_l_min : float
        The leak that ends its life [l/min].
    rupture : WeibullPosterior or sequence of WeibullPosterior, optional
        The other failure modes' life model (a competing risk); several (one per shape,
        :func:`rupture_model`): the interval holds for each (:func:`rul_over_shapes`); None leaves
        them out.
    confidence : float
        Two-sided level of the prediction interval. [-]
    n_draws : int
        Parameter draws. [-]
    seed : int
        Seed of the draws.

    Returns
    -------
    (quantiles, note) : (numpy.ndarray, str or None)
        ``[median, lower, upper]`` [km]; NaN with the reason when the model or the hose's own
        path cannot tell.
    """
    nan = np.full(3, _NAN)
    if not fit.ok:
        return nan, fit.note
    row = fit.hoses[fit.hoses["hose_id"] == hose_id]
    if row.empty:
        return nan, "no leak points"
    if isinstance(row["note"].iloc[0], str):
        return nan, row["note"].iloc[0]
    if not (distance_km > 0 and limit_l_min > 0):
        return nan, "no distance or no leak limit"
    dr = _degradation_draws(fit, n_draws, np.random.default_rng(seed))
    survival, p_now = _crossing_survival(fit, dr, hose_id, distance_km, math.log(limit_l_min))
    if p_now < 1e-6:
        return nan, "its leak path is past the limit already (the hose should have failed)"
    weights = np.full(n_draws, 1.0 / n_draws)
    guess = max(distance_km, 1e-3)
    posts = [rupture] if isinstance(rupture, WeibullPosterior) else list(rupture or [])
    posts = [p for p in posts if p.ok]

    def joint(post: WeibullPosterior | None):
        total = survival
        if post is not None:
            w_r, ess = post.weights()
            if ess < MIN_ESS:
                return nan, "the rupture model's draws do not cover its likelihood"
            pick = np.random.default_rng(seed + 1).choice(len(w_r), size=n_draws, p=w_r)
            rupture_survival = _weibull_survival_at(post.shape[pick], post.scale[pick], distance_km)
            total = lambda r: survival(r) * rupture_survival(r)  # noqa: E731
        q = _mixture_quantiles(total, weights, _probs(confidence), guess)
        return q, (None if np.isfinite(q).all() else "the prediction interval is open: the data do not bound it")

    return rul_over_shapes(joint, posts) if posts else joint(None)


# -- leak-limit crossing ---------------------------------------------------------------------
def leak_crossing_life(distance_km, leak_l_min, limit_l_min: float) -> tuple[float, bool]:
    """First distance at which a leak path reaches ``limit_l_min``, and whether it did.

    Parameters
    ----------
    distance_km : array_like
        Distances of the leak plateaus [km].
    leak_l_min : array_like
        Their leaks [l/min].
    limit_l_min : float
        The limit [l/min].

    Returns
    -------
    (life_km, crossed) : (float, bool)
        Linearly interpolated between the last plateau below and the first at or above the limit;
        the first plateau's distance when that one is already at the limit (the crossing lies
        before it, the path does not say where); the last plateau's distance and False when the
        path never reaches the limit (censored); NaN and False without points.
    """
    d = np.asarray(distance_km, float)
    y = np.asarray(leak_l_min, float)
    keep = np.isfinite(d) & np.isfinite(y)
    d, y = d[keep], y[keep]
    if d.size == 0:
        return _NAN, False
    order = np.argsort(d, kind="stable")
    d, y = d[order], y[order]
    hit = np.flatnonzero(y >= limit_l_min)
    if hit.size == 0:
        return float(d[-1]), False
    j = int(hit[0])
    if j == 0:
        return float(d[0]), True
    frac = (limit_l_min - y[j - 1]) / (y[j] - y[j - 1])
    return float(d[j - 1] + frac * (d[j] - d[j - 1])), True


def leak_crossing_lives(points: pd.DataFrame, limit_l_min: float) -> pd.DataFrame:
    """:func:`leak_crossing_life` of every hose in ``points``.

    Parameters
    ----------
    points : DataFrame
        ``hose_id``, ``distance_km`` [km], ``leak_l_min`` [l/min].
    limit_l_min : float
        The limit [l/min].

    Returns
    -------
    DataFrame
        ``hose_id``, ``life_km`` [km], ``crossed`` (False: censored at ``life_km``).
    """
    rows = [(hid, *leak_crossing_life(g["distance_km"], g["leak_l_min"], limit_l_min))
            for hid, g in points.groupby("hose_id", sort=True)]
    return pd.DataFrame(rows, columns=["hose_id", "life_km", "crossed"])


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
    (:func:`weibayes_posterior`), whatever the count. Else a Weibull (:func:`weibull_posterior`)
    with two such failures or more; with one or none, whose shape the data cannot tell, the
    Weibayes at each shape of :func:`rupture_shapes`, whose intervals a prediction unites
    (:func:`rul_over_shapes`): a mode seen once, or not yet, is bounded by the distance run without
    it, never assumed absent, and its wear-out neither assumed nor ruled out.

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


__all__ = ["BACKTEST_COLUMNS", "BACKTEST_FRACTIONS", "DegradationFit", "FLOOR_MULTIPLE", "LIFE_FAMILIES", "LifeModel",
           "life_model", "MIN_HOSES", "MIN_LEAK_POINTS", "N_DRAWS", "RUL_COLUMNS",
           "RulSettings", "WeibullPosterior", "data_seed", "degradation_fit", "degradation_rul",
           "N_RUPTURE_SHAPES", "rul_over_shapes", "rupture_model", "rupture_shapes", "weibayes_posterior",
           "leak_crossing_life", "leak_crossing_lives", "weibull_posterior", "weibull_rul"]
