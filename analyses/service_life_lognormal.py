"""Hose service life under a lognormal: the censored lognormal likelihood and its fit.

:func:`lognormal_fit` and :func:`lognormal_loglik_many`: the censored lognormal likelihood
(``log T ~ N(log median, sigma^2)``), the other log-location-scale family of life data (Meeker &
Escobar 1998, ch. 4 and 8), beside the Weibull of :mod:`analyses.service_life`. Weibull and
lognormal have two parameters each, so their maximised log-likelihoods compare directly (Meeker &
Escobar 1998, sections 6.4 and 8.3; Dumonceaux & Antle 1973, "Discrimination between the
log-normal and the Weibull distributions", Technometrics 15): :mod:`analyses.life_posterior`
weighs the two for its life model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy  # its submodules load on first use

from analyses.numerics import fminbound
from analyses.numerics_fmin import brent_minimize
from analyses.quality import at_bound
from analyses.service_life import _NAN, _as_arrays


#: Search range of the lognormal's sigma (the sd of log life); an MLE at either end is not reported. [-]
SIGMA_BOUNDS = (1e-3, 1e3)


@dataclass
class LognormalFit:
    """A lognormal fitted to right-censored lives: ``log T ~ N(log median, sigma^2)``.

    Attributes
    ----------
    median : float
        Median life, in the unit of the lives; NaN with fewer than two failures.
    sigma : float
        Standard deviation of the log life [-].
    loglik : float
        Log-likelihood at the estimate (density for failures, survival for suspensions), on the
        same scale as :attr:`WeibullFit.loglik` (densities in the unit of the lives).
    n, n_failed : int
        Units, failures.
    note : str or None
        Why there is no estimate.
    """

    median: float
    sigma: float
    loglik: float
    n: int
    n_failed: int
    note: str | None = None

    @property
    def ok(self) -> bool:
        return math.isfinite(self.median) and math.isfinite(self.sigma)


def lognormal_loglik_many(sigma, median, life, failed) -> np.ndarray:
    """Log-likelihood of right-censored lives under lognormals, vectorised over parameter pairs.

    Parameters
    ----------
    sigma, median : array_like
        Standard deviation of the log life [-] and median life (unit of ``life``), broadcast.
    life : array_like
        Lives (failure or censoring distance) [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension.

    Returns
    -------
    numpy.ndarray
        Log-likelihood per pair; -inf where a parameter is not positive.
    """
    x, f = _as_arrays(life, failed)
    sg, md = np.broadcast_arrays(np.asarray(sigma, dtype=float), np.asarray(median, dtype=float))
    good = (sg > 0) & (md > 0)
    ss, mm = np.where(good, sg, 1.0)[..., None], np.where(good, md, 1.0)[..., None]
    lx = np.log(x)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        z = (lx - np.log(mm)) / ss
        dens = -0.5 * z ** 2 - np.log(ss) - lx - 0.5 * math.log(2.0 * math.pi)
        ll = np.sum(np.where(f, dens, scipy.special.log_ndtr(-z)), axis=-1)
    return np.where(good, ll, -np.inf)


def lognormal_fit(life, failed) -> LognormalFit:
    """Lognormal MLE with right-censoring.

    Profile likelihood: for each sigma the log median maximises the censored normal
    log-likelihood, which is concave in it (Brent's search from the range of the log lives); sigma
    by a bounded search in its log over :data:`SIGMA_BOUNDS`.

    Parameters
    ----------
    life : array_like
        Lives [any unit, > 0]; non-positive or non-finite values are ignored.
    failed : array_like of bool
        True for a failure, False for a suspension.

    Returns
    -------
    LognormalFit
        NaN with a ``note`` with fewer than two failures or sigma at :data:`SIGMA_BOUNDS`.
    """
    x, f = _as_arrays(life, failed)
    n, r = int(len(x)), int(f.sum())
    if r < 2:
        return LognormalFit(_NAN, _NAN, _NAN, n, r, note=f"too few failures: {r} < 2")
    lx = np.log(x)

    def neg(log_s):   # scipy.optimize.minimize_scalar(..., bracket=...)'s bits
        mu, fun = brent_minimize(lambda m: -float(lognormal_loglik_many(math.exp(log_s), math.exp(m), x, f)),
                                 lx.min(), lx.max() + 1.0)
        return float(fun), float(mu)

    lo, hi = (math.log(b) for b in SIGMA_BOUNDS)
    best = float(fminbound(lambda v: neg(v)[0], lo, hi, xatol=1e-10))   # minimize_scalar(method="bounded")'s bits
    sigma = math.exp(best)
    ll, mu = neg(best)
    if at_bound(sigma, *SIGMA_BOUNDS):
        return LognormalFit(_NAN, _NAN, _NAN, n, r, note=f"the lognormal sigma MLE ({sigma:.3g}) is at the search "
                                                         "bound: the lives cannot tell a spread")
    return LognormalFit(math.exp(mu), sigma, -ll, n, r)


__all__ = ["SIGMA_BOUNDS", "LognormalFit", "lognormal_fit", "lognormal_loglik_many"]
