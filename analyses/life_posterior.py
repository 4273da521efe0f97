"""The life model's predictive posterior: the distance a running unit has left, from its type's censored lives.

Distances are in km. The lives of a hose type (failures exact, removed and running hoses
right-censored) give a unit running at ``d`` a median and a two-sided **prediction interval** at
``confidence`` for the distance it has left [km], NaN with a one-line ``note`` when the data cannot
tell. This is the ``weibull`` method of :mod:`analyses.remaining_life`, and the draws of the other
failure modes' model (a Weibull, or a Weibayes of known shape, :func:`weibayes_posterior`) that the
``degradation`` method (:mod:`analyses.leak_degradation`) joins to a hose's leak path.

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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy

from analyses.service_life import WeibullFit, weibull_fit, weibull_loglik_many
from analyses.service_life_lognormal import lognormal_fit, lognormal_loglik_many

_NAN = float("nan")
#: Draws of the parameters per predictive distribution. [-]
N_DRAWS = 1000
#: Effective sample size below which importance-weighted draws are not trusted. [-]
MIN_ESS = 100.0
#: Rounds of adaptive importance sampling: at least, at most [-], and the effective size, in
#: multiples of :data:`MIN_ESS`, at which the rounds stop early [-].
MIN_ADAPT_ROUNDS, MAX_ADAPT_ROUNDS, ADAPTED_ESS = 2, 8, 3.0


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


def weibull_survival_at(shape, scale, d: float):
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
    family [-]; the survival to ``d`` computed once (:func:`weibull_survival_at`)."""
    if post.family == "weibull":
        return weibull_survival_at(post.shape, post.scale, d)
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


def mixture_quantiles(survival, weights, probs, guess: float) -> np.ndarray:
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


def interval_probs(confidence: float) -> np.ndarray:
    """The probabilities a prediction is read at: its median, then the lower and upper ends of its two-sided
    interval at ``confidence`` [-]."""
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
        return _weibayes_quantiles(fits[0], distance_km, interval_probs(confidence)), None
    if fits:   # an equal mixture of Weibayes: bisection on their exact survivals
        q = mixture_quantiles(lambda r: _weibayes_survival(fits, distance_km, r), np.full(len(fits), 1.0 / len(fits)),
                              interval_probs(confidence), float(np.median([f.scale for f in fits])))
        return q, (None if np.isfinite(q).all() else "the prediction interval is open: the data do not bound it")
    ok, prob = model.usable()
    if not ok:
        ess = first.weights()[1] if first.ok else 0.0
        return np.full(3, _NAN), f"the parameter draws do not cover the likelihood (effective {ess:.0f})"
    weights = np.concatenate([pr * p.weights()[0] for p, pr in zip(ok, prob)])
    guess = float(ok[int(np.argmax(prob))].fit.scale)
    survivals = [_survival_at(p, distance_km) for p in ok]
    q = mixture_quantiles(lambda r: np.vstack([survival(r) for survival in survivals]),
                          weights, interval_probs(confidence), guess)
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
        or the joint prediction of :func:`analyses.leak_degradation.degradation_rul`).
    posts : sequence of WeibullPosterior
        The models (:func:`analyses.remaining_life.rupture_model`); one alone is its own prediction.

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


__all__ = ["LIFE_FAMILIES", "LifeModel", "MIN_ESS", "N_DRAWS", "WeibullPosterior", "life_model", "mixture_quantiles",
           "interval_probs", "rul_over_shapes", "weibayes_posterior", "weibull_posterior", "weibull_rul", "weibull_survival_at"]
