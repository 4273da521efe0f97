"""The life effect under a lognormal life model with one sigma: :mod:`analyses.life_effect`'s ratio for
lives a lognormal wear rate makes.

Lives are distances [km]; failed hoses exact, the others right-censored; ``group`` 0 for a
distance-set adjustment, 1 for a force-set one (as :func:`analyses.life_effect.life_effect`).

Model (Meeker & Escobar 1998, chapter 17: lognormal regression)
--------------------------------------------------------------
``log life`` is normal with mean ``mu_distance + theta * group`` and one ``sigma`` for both
adjustments (an accelerated-failure-time model): ``theta = mu_force - mu_distance`` is the log of
the force / distance life ratio, the same for every quantile. The likelihood is the censored
lognormal one of :func:`analyses.service_life_lognormal.lognormal_loglik_many` (the distance lives at median
``exp(mu_distance)``, the force lives at ``exp(mu_distance + theta)``); it is maximised over
``(mu_distance, theta, log sigma)`` by BFGS with the analytic score, and the profile at a held
``theta`` over the other two the same way.

Why this family (docs/decision.md, "The sensitivity's life model"): a leak path ``(w d)^gamma``
whose wear rate ``w`` is lognormal from hose to hose crosses a limit ``L`` at
``L^(1/gamma) / w``, a lognormal distance (Lu & Meeker 1993; Meeker & Escobar 1998, section 13.5:
the failure-time distribution a degradation model induces). Fitting a Weibull to such lives gives
a log-ratio standard error too small (the verdict's error rate 7-11 % at alpha 5 %,
``benchmarks/bench_sensitivity.py``).

Bounds and tests (Meeker & Escobar 1998, section 8.3)
-----------------------------------------------------
* ``life_ratio_lower`` / ``life_ratio_upper``: profile-likelihood bounds at ``confidence``
  (:func:`analyses.service_life.lr_bound`), ``p_value`` the likelihood-ratio test of ratio = 1.
* ``log_ratio``, ``se_log_ratio``: ``theta`` and its standard error from the observed
  information (the analytic Hessian of the censored normal regression, Meeker & Escobar 1998,
  appendix B): what the sequential rule reads.
* NaN and a one-line note when an adjustment has fewer than two failures or sigma's MLE is at
  :data:`analyses.service_life.SIGMA_BOUNDS`; a bound not reached within ``RATIO_SEARCH`` is NaN.

References
----------
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Lu, C. J. & Meeker, W. Q. (1993). Using degradation measures to estimate a time-to-failure
distribution. Technometrics 35, 161-174.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy  # its submodules load on first use

from analyses.life_effect import RATIO_SEARCH, LifeEffect, split_groups
from analyses.numerics import chi2_ppf, chi2_sf
from analyses.service_life import lr_bound
from analyses.service_life_lognormal import SIGMA_BOUNDS, lognormal_loglik_many

_NAN = float("nan")

#: ``model`` value of a ratio from this module.
LOGNORMAL = "lognormal, common sigma"


@dataclass(frozen=True)
class LognormalEffectFit:
    """The common-sigma lognormal regression at its maximum.

    Attributes
    ----------
    mu_distance : float
        Mean log life of the distance-set hoses [log km].
    log_ratio : float
        ``mu_force - mu_distance`` [-].
    sigma : float
        Standard deviation of the log life [-].
    loglik : float
        Log-likelihood at the estimate.
    se_log_ratio : float
        Standard error of ``log_ratio`` (observed information) [-]; NaN when not positive definite.
    note : str or None
        Why the values are NaN (one line).
    """

    mu_distance: float = _NAN
    log_ratio: float = _NAN
    sigma: float = _NAN
    loglik: float = _NAN
    se_log_ratio: float = _NAN
    note: str | None = None


def _stack(groups):
    """(log lives, failed, group) of both adjustments, concatenated."""
    (xd, fd), (xf, ff) = groups
    return (np.log(np.concatenate([xd, xf])), np.concatenate([fd, ff]),
            np.concatenate([np.zeros(len(xd)), np.ones(len(xf))]))


def _loglik(groups, mu: float, theta: float, sigma: float) -> float:
    """:func:`analyses.service_life_lognormal.lognormal_loglik_many` of both adjustments."""
    (xd, fd), (xf, ff) = groups
    return float(lognormal_loglik_many(sigma, math.exp(mu), xd, fd) + lognormal_loglik_many(sigma, math.exp(mu + theta),
                                                                                             xf, ff))


def _derivatives(stacked, mu: float, theta: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Score and Hessian of the log-likelihood in ``(mu_distance, theta, sigma)``.

    Per life with ``z = (log x - mu - theta g) / sigma``: a failure contributes ``z / sigma`` and
    ``(z^2 - 1) / sigma`` to the location's and sigma's score, second derivatives ``-1``, ``-2 z``,
    ``1 - 3 z^2`` over ``sigma^2``; a suspension, with the normal hazard ``h = phi(z) / Q(z)``,
    ``h / sigma`` and ``z h / sigma``, and ``-h (h - z)``, ``-(z h (h - z) + h)``,
    ``-(2 z h + z^2 h (h - z))`` over ``sigma^2`` (Meeker & Escobar 1998, appendix B).
    """
    y, f, g = stacked
    z = (y - mu - theta * g) / sigma
    h = np.exp(scipy.stats.norm.logpdf(z) - scipy.special.log_ndtr(-z))
    hz = h * (h - z)
    d_loc = np.where(f, z, h) / sigma
    d_sig = np.where(f, z * z - 1.0, z * h) / sigma
    h_ll = np.where(f, -1.0, -hz) / sigma ** 2
    h_ls = np.where(f, -2.0 * z, -(z * hz + h)) / sigma ** 2
    h_ss = np.where(f, 1.0 - 3.0 * z * z, -(2.0 * z * h + z * z * hz)) / sigma ** 2
    score = np.array([d_loc.sum(), (g * d_loc).sum(), d_sig.sum()])
    hess = np.array([[h_ll.sum(), (g * h_ll).sum(), h_ls.sum()],
                     [(g * h_ll).sum(), (g * h_ll).sum(), (g * h_ls).sum()],
                     [h_ls.sum(), (g * h_ls).sum(), h_ss.sum()]])
    return score, hess


def _maximise(groups, stacked, start: np.ndarray, theta: float | None = None) -> tuple[float, np.ndarray]:
    """(maximum log-likelihood, ``(mu, theta, log sigma)`` there); ``theta`` held when given; the
    log-likelihood NaN when the search stopped off a stationary point (a score above 1e-4)."""
    free = [0, 2] if theta is not None else [0, 1, 2]

    def full(p):
        q = start.copy()
        q[free] = p
        if theta is not None:
            q[1] = theta
        return q

    def neg(p):
        mu, th, ls = full(p)
        if not math.isfinite(ls) or abs(ls) > 50.0:
            return math.inf, np.zeros(len(free))
        score, _ = _derivatives(stacked, mu, th, math.exp(ls))
        score[2] *= math.exp(ls)                       # d / d log sigma
        return -_loglik(groups, mu, th, math.exp(ls)), -score[free]

    res = scipy.optimize.minimize(neg, start[free], jac=True, method="BFGS", options={"gtol": 1e-9})
    stationary = bool(res.success) or float(np.abs(res.jac).max()) < 1e-4
    return (-float(res.fun) if stationary else _NAN), full(res.x)


def _start(stacked) -> np.ndarray:
    """Starting ``(mu, theta, log sigma)``: the groups' mean log lives and their pooled spread."""
    y, _, g = stacked
    m0, m1 = float(y[g == 0].mean()), float(y[g == 1].mean())
    spread = float(np.std(y - np.where(g == 1, m1, m0)))
    return np.array([m0, m1 - m0, math.log(spread) if spread > 0 else 0.0])


def _too_few(groups) -> str | None:
    few = [f"{name} {int(f.sum())}" for name, (_, f) in zip(("distance", "force"), groups) if f.sum() < 2]
    return f"too few failures to tell a lognormal: {', '.join(few)} < 2" if few else None


def _fit(groups) -> tuple[LognormalEffectFit, np.ndarray]:
    """The fit and its ``(mu, theta, log sigma)`` (the profiles' start)."""
    note = _too_few(groups)
    if note:
        return LognormalEffectFit(note=note), np.zeros(3)
    stacked = _stack(groups)
    ll, p = _maximise(groups, stacked, _start(stacked))
    sigma = math.exp(p[2])
    if not (math.isfinite(ll) and SIGMA_BOUNDS[0] < sigma < SIGMA_BOUNDS[1]):
        return LognormalEffectFit(note=f"the common lognormal sigma MLE ({sigma:.3g}) is outside its search range or "
                                       "no maximum was found: "
                                       "the lives cannot tell a spread"), p
    _, hess = _derivatives(stacked, p[0], p[1], sigma)
    info = -hess
    ok = np.isfinite(info).all() and np.linalg.eigvalsh(info).min() > 0
    se = math.sqrt(np.linalg.inv(info)[1, 1]) if ok else _NAN
    return LognormalEffectFit(float(p[0]), float(p[1]), sigma, ll, se), p


def lognormal_effect_fit(life, failed, group) -> LognormalEffectFit:
    """The common-sigma lognormal regression of life on the adjustment, by maximum likelihood.

    Parameters
    ----------
    life : array_like
        Lives [km]; non-positive or non-finite ones are ignored.
    failed : array_like of bool
        True for a failure, False for a suspension.
    group : array_like of int
        0 for a distance-set adjustment, 1 for a force-set one.

    Returns
    -------
    LognormalEffectFit
        NaN with a ``note`` when an adjustment has fewer than two failures or sigma cannot be told.
    """
    return _fit(split_groups(life, failed, group))[0]


def lognormal_ratio_deviance(life, failed, group, ratio: float) -> float:
    """Profile deviance ``2 * (loglik_max - loglik_profile(ratio))`` of a trial force / distance life
    ratio [-] (as :func:`analyses.life_effect.ratio_deviance`); NaN when the fit cannot be made."""
    groups = split_groups(life, failed, group)
    fit, p = _fit(groups)
    if fit.note:
        return _NAN
    return max(0.0, 2.0 * (fit.loglik - _maximise(groups, _stack(groups), p, math.log(ratio))[0]))


def lognormal_life_effect(life, failed, group, confidence: float = 0.90) -> LifeEffect:
    """Force / distance life ratio of one hose type under a common-sigma lognormal, with its
    profile-likelihood bounds and the likelihood-ratio test of ratio = 1.

    Parameters
    ----------
    life, failed, group : array_like
        As :func:`lognormal_effect_fit`.
    confidence : float
        Two-sided confidence of the bounds [-].

    Returns
    -------
    LifeEffect
        ``model`` :data:`LOGNORMAL`; the shape columns NaN (no Weibull shape); NaN values with a
        one-line ``note`` where the data cannot tell.
    """
    groups = split_groups(life, failed, group)
    counts = {"n_distance": len(groups[0][0]), "n_failed_distance": int(groups[0][1].sum()),
              "n_force": len(groups[1][0]), "n_failed_force": int(groups[1][1].sum())}
    fit, p = _fit(groups)
    if fit.note:
        return LifeEffect(**counts, note=fit.note)
    stacked, crit, theta = _stack(groups), chi2_ppf(confidence, 1), fit.log_ratio
    dev = lambda t: 2.0 * (fit.loglik - _maximise(groups, stacked, p, t)[0])  # noqa: E731
    lo, hi = (lr_bound(lambda t: dev(t) - crit, theta, theta + side * math.log(RATIO_SEARCH)) for side in (-1.0, 1.0))
    missing = [n for n, b in (("life_ratio_lower", lo), ("life_ratio_upper", hi)) if math.isnan(b)]
    note = f"{', '.join(missing)} not reached within the search edge: the data do not bound it" if missing else None
    return LifeEffect(**counts, life_ratio=math.exp(theta), life_ratio_lower=math.exp(lo),
                      life_ratio_upper=math.exp(hi),
                      p_value=chi2_sf(max(0.0, dev(0.0)), 1), model=LOGNORMAL, note=note,
                      log_ratio=theta, se_log_ratio=fit.se_log_ratio)


__all__ = ["LOGNORMAL", "LognormalEffectFit", "lognormal_effect_fit", "lognormal_ratio_deviance",
           "lognormal_life_effect"]
