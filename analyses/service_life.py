"""Hose service life: Weibull by maximum likelihood with right-censoring, B-lives, reliability and
their likelihood-ratio bounds, median-rank regression, Kaplan-Meier.

Life is a distance [km] (any positive unit works; the functions do not care). Failed hoses are
exact lives; removed and still-running hoses are right-censored (suspensions).

Weibull fit
-----------
Two-parameter Weibull, ``F(x) = 1 - exp(-(x / scale)^shape)``, fitted by maximum likelihood
with ``scipy.stats.weibull_min.fit`` on a ``scipy.stats.CensoredData`` (location fixed at 0; its
bits without importing ``scipy.stats``: ``analyses.numerics_fmin.weibull_polish``).
The optimiser is started from the exact profile-likelihood solution (for a given shape the
scale MLE is closed form, and the shape solves a monotone score equation, found with
``brentq``); whichever of the two has the higher likelihood is kept, so the estimate does not
depend on the optimiser's tolerance. On Nelson's 70 diesel-engine fans this gives the
published SAS values shape 1.0584, scale 26.2968 (tests).

With fewer than two failures the Weibull parameters are not identifiable in any useful sense:
every Weibull output is NaN (NULL in the warehouse), never invented. The same holds when the
shape's maximum likelihood lies at the edge of the search range ``SHAPE_BOUNDS`` (e.g. every
failure at the same distance: the shape runs to infinity): NaN, and ``note`` says why.

B10 and its confidence bounds (method)
--------------------------------------
``B10 = scale * (-ln 0.9)^(1/shape)``, the distance by which 10 % of hoses have failed.
Two-sided bounds at ``confidence`` (default 0.90) are **likelihood-ratio (profile likelihood)
bounds**: the model is reparametrised by (shape, Bp); for a trial value ``b`` the likelihood is
maximised over the shape with ``Bp = b`` held fixed, and the bounds are the two values of ``b``
where ``2 * (loglik_max - loglik_profile(b)) = chi2.ppf(confidence, 1)``. Each bound is thus a
one-sided ``(1 + confidence) / 2`` bound (Meeker & Escobar 1998, section 8.3). Unlike Wald
(Fisher-matrix) bounds, they need no normal approximation of the estimator, which is poor with
a handful of failures. A bound that does not exist within 1e-6..1e6 times the estimate is NaN.

Shape, scale and reliability bounds; the service-life row
---------------------------------------------------------
The same likelihood-ratio construction bounds the shape (:func:`weibull_shape_bounds`: the scale
profiled out in closed form), the scale (the 63.2 % quantile, :data:`SCALE_FRACTION`), any
B-life (:func:`weibull_quantile_bounds`) and the reliability at a mission life
(:func:`weibull_reliability_bounds`: holding ``R(t)`` is holding ``t`` as the ``1 - R``
quantile, Meeker & Escobar 1998, section 8.3). :func:`service_life_summary` gives them all in
one row, as the ``service_life`` table holds them. Their coverage, measured by simulation
(``python -m benchmarks.bench_service_life``, 600 groups): 87.7 % (shape), 88.0 % (scale),
90.0 % (B10), 90.3 % (R) for 90 % intervals.

Small-sample bias of the shape
------------------------------
:func:`reduced_bias_shape`: Abernethy's reduced-bias adjustment ``shape * C4^3.5`` (Abernethy 2006,
The New Weibull Handbook, 5th ed., sec. 5.5), for whoever designs from a shape fitted to few
failures (:func:`analyses.decision.freeze_look`); the fitted rows keep the MLE.

Median-rank regression
----------------------
:func:`weibull_rank_regression`: the Weibull plot's line fitted by least squares of ln(life) on
the plot's ordinate (rank regression on X, "RRX" in Weibull++), at Benard's median ranks with
Johnson's adjusted ranks for suspensions (:func:`median_ranks`; Abernethy 2006, The New Weibull
Handbook, 5th ed., ch. 2 and 5). :func:`preferred_method` is Abernethy's rule for which point
estimate to quote: MRR up to :data:`MRR_MAX_FAILURES` failures, the MLE beyond (docs/analyses.md).

Comparing groups
----------------
:func:`weibull_lr_test`: the likelihood-ratio test of "the groups share one Weibull" against
"each group has its own shape and scale": ``LR = 2 * (sum loglik_g - loglik_pooled)``,
chi-square with ``2 * (groups - 1)`` degrees of freedom. NaN when a group has fewer than two
failures.

The lognormal beside it
-----------------------
The censored lognormal fit is in :mod:`analyses.service_life_lognormal`; the figures of these
fits (Weibull probability plot, Kaplan-Meier, leak growth, hose distances) in
:mod:`analyses.service_life_plots`.

Kaplan-Meier
------------
:func:`kaplan_meier`: the product-limit survival estimate with Greenwood's standard error; at a
tied distance failures are taken before suspensions (the usual convention).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from analyses.numerics import brentq, chi2_ppf, chi2_sf
from analyses.numerics_fmin import weibull_polish
from analyses.quality import at_bound

_NAN = float("nan")


@dataclass
class WeibullFit:
    """A two-parameter Weibull fitted to right-censored lives.

    Attributes
    ----------
    shape : float
        Weibull shape (beta); NaN with fewer than two failures.
    scale : float
        Weibull scale (eta), in the unit of the lives.
    loglik : float
        Log-likelihood at the estimate (density for failures, survival for suspensions).
    n : int
        Units.
    n_failed : int
        Failures.
    """

    shape: float
    scale: float
    loglik: float
    n: int
    n_failed: int
    note: str | None = None

    @property
    def ok(self) -> bool:
        return math.isfinite(self.shape) and math.isfinite(self.scale)

    def quantile(self, p: float) -> float:
        """Life by which a fraction ``p`` has failed (same unit as the lives)."""
        if not self.ok:
            return _NAN
        return self.scale * (-math.log1p(-p)) ** (1.0 / self.shape)


def _as_arrays(life, failed) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(life, dtype=np.float64)
    f = np.asarray(failed, dtype=bool)
    if x.shape != f.shape:
        raise ValueError("life and failed must have the same length")
    keep = np.isfinite(x) & (x > 0)
    return x[keep], f[keep]


def weibull_loglik(shape: float, scale: float, life, failed) -> float:
    """Log-likelihood of right-censored lives under a Weibull(shape, scale).

    Parameters
    ----------
    shape, scale : float
        Weibull parameters (scale in the unit of ``life``).
    life : array_like
        Lives (failure or censoring distance) [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension.
    """
    x, f = _as_arrays(life, failed)
    if not (shape > 0 and scale > 0):
        return -math.inf
    z = x / scale
    zk = z ** shape
    return float(np.sum(np.log(shape / scale) + (shape - 1.0) * np.log(z[f])) - np.sum(zk))


#: Search range of the Weibull shape; an MLE at either end is not reported. [-]
SHAPE_BOUNDS = (1e-3, 1e3)


def _profile_mle(x: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """Exact MLE: for a shape k the scale is (sum x^k / r)^(1/k); k solves the score equation."""
    s = x.max()
    y = x / s
    ly = np.log(y)
    mean_lf = ly[f].mean()

    def score(logk):
        k = math.exp(logk)
        w = y ** k
        return float((w * ly).sum() / w.sum() - 1.0 / k - mean_lf)

    lo, hi = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])
    if score(lo) > 0 or score(hi) < 0:
        side = "lower" if score(lo) > 0 else "upper"
        raise ValueError(f"the Weibull shape MLE is at the search's {side} bound "
                         f"({SHAPE_BOUNDS[0 if side == 'lower' else 1]:g}): the lives cannot tell a shape")
    k = math.exp(brentq(score, lo, hi, xtol=1e-14, rtol=1e-14))
    return k, weibull_scale_given_shape(k, x, f)


def weibull_scale_given_shape(shape: float, life, failed) -> float:
    """The scale's MLE for a given shape: ``(sum(x^shape) / failures)^(1/shape)`` [unit of life].

    Closed form (the scale's score equation; Meeker & Escobar 1998, section 8.2): it profiles the
    scale out of the likelihood, which leaves a one-dimensional problem in the shape. Lives are
    divided by the largest before the power, so that large shapes do not overflow.

    Parameters
    ----------
    shape : float
        Weibull shape [-], > 0.
    life, failed : array_like
        Lives [any unit, > 0] and failure flags; at least one failure.
    """
    x, f = _as_arrays(life, failed)
    s = x.max()
    return float(s * (((x / s) ** shape).sum() / f.sum()) ** (1.0 / shape))


def weibull_fit(life, failed) -> WeibullFit:
    """Two-parameter Weibull MLE with right-censoring (``scipy.stats.weibull_min.fit`` on ``CensoredData``, ported).

    Parameters
    ----------
    life : array_like
        Lives [any unit, > 0]; non-positive or non-finite values are ignored.
    failed : array_like of bool
        True for a failure, False for a suspension (removed or still running).

    Returns
    -------
    WeibullFit
        NaN shape, scale and loglik with a ``note`` with fewer than two failures or without a
        finite MLE inside :data:`SHAPE_BOUNDS`.
    """
    x, f = _as_arrays(life, failed)
    n, r = int(len(x)), int(f.sum())
    if r < 2:
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note=f"too few failures: {r} < 2")
    try:
        k0, s0 = _profile_mle(x, f)
    except (ValueError, FloatingPointError) as exc:
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note=str(exc).splitlines()[0])
    best = (k0, s0, weibull_loglik(k0, s0, x, f))
    try:
        with np.errstate(all="ignore"):
            k1, s1 = weibull_polish(x, f, k0, s0)   # weibull_min.fit's bits, without importing scipy.stats
        ll1 = weibull_loglik(k1, s1, x, f)
        if math.isfinite(ll1) and ll1 > best[2]:
            best = (float(k1), float(s1), ll1)
    except Exception:  # scipy's optimiser failing leaves the exact profile solution
        pass
    if at_bound(best[0], *SHAPE_BOUNDS):
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note=f"the Weibull shape MLE ({best[0]:.3g}) is at the search "
                                                      "bound: the lives cannot tell a shape")
    return WeibullFit(float(best[0]), float(best[1]), float(best[2]), n, r)


def reduced_bias_shape(shape: float, failures: int) -> float:
    """The Weibull shape MLE with Abernethy's reduced-bias adjustment (RBA).

    The shape MLE from few failures is biased upward (with 10 complete failures its median is
    about 11 % high, its mean 16 %: tests); the RBA multiplies it by ``C4^3.5``, ``C4 =
    sqrt(2 / (r - 1)) * Gamma(r / 2) / Gamma((r - 1) / 2)`` the unbiasing factor of a normal
    standard deviation, with ``r`` the number of failures (with suspensions too: Abernethy 2006,
    The New Weibull Handbook, 5th ed., sec. 5.5), which makes it about median-unbiased (tests:
    1.006 of the truth from 10 failures). For a design that should not rest on a shape biased
    steep; the shape a fit reports stays the MLE.

    Parameters
    ----------
    shape : float
        Weibull shape MLE [-].
    failures : int
        Failures the MLE rests on [-].

    Returns
    -------
    float
        ``shape * C4(failures)^3.5`` [-]; NaN with fewer than two failures or a non-finite shape.
    """
    if failures < 2 or not math.isfinite(shape):
        return _NAN
    r = float(failures)
    log_c4 = 0.5 * math.log(2.0 / (r - 1.0)) + math.lgamma(r / 2.0) - math.lgamma((r - 1.0) / 2.0)
    return float(shape * math.exp(3.5 * log_c4))


def newton_root(value_slope, lo: float, hi: float, start: float, xtol: float = 1e-13) -> float | None:
    """Root of a strictly decreasing function inside ``(lo, hi)``: Newton steps kept in a bracket.

    A step that would leave the bracket known so far (the last points where the function was
    positive and negative, ``lo`` and ``hi`` until then) is replaced by bisection, so the
    iteration cannot diverge; near the root it converges quadratically, in 3-6 evaluations from
    a good start where ``brentq`` over the whole range takes 12-18. The answer is the same root
    (to ``xtol``, as ``brentq(..., xtol=1e-13)`` finds it). The edges are not evaluated: a strictly
    decreasing function has a root inside the range exactly when the iteration settles inside it.

    Parameters
    ----------
    value_slope : callable
        ``t -> (value, slope)``, the function and its derivative at ``t``.
    lo, hi : float
        The range searched.
    start : float
        First point (clipped into the range).
    xtol : float
        Accuracy of the root [-]: the iteration stops after a Newton step below
        ``0.1 * sqrt(xtol) * (1 + |t|)`` (Newton's error after a step is of the order of the
        step squared).

    Returns
    -------
    float or None
        The root; None when the iteration does not settle strictly inside ``(lo, hi)`` (the root
        is at or beyond an edge, or the function misbehaves): the caller then brackets as before.
    """
    a, b = lo, hi
    t = min(max(start, lo), hi)
    for _ in range(100):
        v, d = value_slope(t)
        if not math.isfinite(v):
            return None
        if v == 0.0:
            return t if lo < t < hi else None
        if v > 0:
            a = t
        else:
            b = t
        step = v / d if math.isfinite(d) and d < 0 else math.nan
        new = t - step
        if abs(step) <= 0.1 * math.sqrt(xtol) * (1.0 + abs(t)):   # converged: quadratically, this step's error ~ step^2
            return new if lo < new < hi else None
        if not a < new < b:              # NaN too: bisect the bracket
            new = 0.5 * (a + b)
            if b - a <= xtol * (1.0 + abs(t)):
                return new if lo < a and b < hi else None
        t = new
    return None


def weibull_quantile_profile(log_q: float, p: float, life, failed, start: float = 0.0) -> float:
    """Log-likelihood maximised over the shape with the p-quantile held at ``exp(log_q)``.

    The profile likelihood of a Weibull quantile (Meeker & Escobar 1998, section 8.3): with
    ``log scale = log_q - log(c) / k``, ``c = -log(1 - p)``, the log-likelihood is strictly
    concave in the shape ``k`` (second derivative ``-r / k^2 - c * sum(u^2 * exp(k * u))``,
    ``u = log(life) - log_q``), so the shape solves its score equation exactly (:func:`newton_root`,
    ``brentq`` as the fallback); at the edge of :data:`SHAPE_BOUNDS` that edge is taken. Used for the B10 bounds here and for the
    B10 ratio of separate shapes in :mod:`analyses.life_effect`.

    Parameters
    ----------
    log_q : float
        Log of the quantile held [log of the unit of ``life``].
    p : float
        Fraction failed by that quantile [-] (0.10 for B10).
    life, failed : array_like
        Lives [any unit, > 0] and failure flags.
    start : float
        Log of the shape the solve starts from (the shape MLE, for a profile near it) [-]: the
        same answer from any start, fewer steps from a near one (:func:`newton_root`).

    Returns
    -------
    float
        The profile log-likelihood.
    """
    x, f = _as_arrays(life, failed)
    u = np.log(x) - log_q
    r, sum_uf = float(f.sum()), float(u[f].sum())
    c = -math.log1p(-p)

    def score(logk):
        k = math.exp(logk)
        return r / k + sum_uf - c * float((u * np.exp(np.minimum(k * u, 600.0))).sum())

    def score_slope(logk):
        k = math.exp(logk)
        ue = u * np.exp(np.minimum(k * u, 600.0))
        return r / k + sum_uf - c * float(ue.sum()), -r / k - c * k * float(ue @ u)

    lo, hi = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])
    logk = newton_root(score_slope, lo, hi, start, xtol=1e-12)
    if logk is None:
        if score(lo) <= 0 or score(hi) >= 0:
            logk = lo if score(lo) <= 0 else hi
        else:
            logk = brentq(score, lo, hi, xtol=1e-12)
    k, log_c = math.exp(logk), math.log(c)
    # weibull_loglik at scale exp(log_q) / c^(1/k), written in u: log(life / scale) = u + log(c) / k
    with np.errstate(over="ignore"):
        return (r * (logk - log_q + log_c / k) + (k - 1.0) * (sum_uf + r * log_c / k)
                - c * float(np.exp(k * u).sum()))


def weibull_quantile_bounds(fit: WeibullFit, life, failed, p: float = 0.10,
                            confidence: float = 0.90) -> tuple[float, float, float]:
    """The p-quantile with two-sided likelihood-ratio confidence bounds.

    Parameters
    ----------
    fit : WeibullFit
        The MLE (from :func:`weibull_fit` on the same data).
    life, failed : array_like
        The data the fit was made on.
    p : float
        Fraction failed (0.10 for B10).
    confidence : float
        Two-sided confidence level of the interval.

    Returns
    -------
    (estimate, lower, upper) : tuple of float
        In the unit of ``life``; all NaN when the fit is not available.
    """
    if not fit.ok:
        return _NAN, _NAN, _NAN
    x, f = _as_arrays(life, failed)
    est = fit.quantile(p)
    crit = chi2_ppf(confidence, 1)

    def g(logb):
        return 2.0 * (fit.loglik - weibull_quantile_profile(logb, p, x, f, start=math.log(fit.shape))) - crit

    centre = math.log(est)
    lo, hi = (math.exp(lr_bound(g, centre, centre + side * math.log(1e6))) for side in (-1.0, 1.0))
    return est, lo, hi


def lr_bound(excess, centre: float, edge: float) -> float:
    """Where a profile deviance reaches its critical value, searched from the estimate outwards.

    The parameter is stepped from ``centre`` towards ``edge`` by 0.05, 0.1, 0.2, ... (doubling,
    the last step at ``edge`` itself) until ``excess`` turns positive; the root inside that step
    is found with ``brentq``. Used for every likelihood-ratio bound (Meeker & Escobar 1998,
    section 8.3): B10 here, the life ratio and the common shape in :mod:`analyses.life_effect`.

    Parameters
    ----------
    excess : callable
        ``excess(t) = 2 * (loglik_max - loglik_profile(t)) - chi2.ppf(confidence, 1)``, negative
        at ``centre``; ``t`` is the parameter on the scale searched (a log for positive ones). A pure
        function of ``t``: each point is evaluated once (``brentq`` starts from the ends of the step
        that bracketed the bound, which the search has already evaluated: a profile solve each).
    centre : float
        The estimate.
    edge : float
        The search edge (below or above ``centre``).

    Returns
    -------
    float
        The bound, NaN when the deviance stays below the critical value up to ``edge`` (the data
        do not bound the parameter on that side).
    """
    excess = functools.cache(excess)
    sign = 1.0 if edge > centre else -1.0
    span = abs(edge - centre)
    a, step = centre, 0.05
    while True:
        b = centre + sign * min(step, span)
        if excess(b) > 0:
            lo, hi = sorted((a, b))
            return float(brentq(excess, lo, hi, xtol=1e-12))
        if step >= span:
            return _NAN
        a, step = b, step * 2.0


def b10(life, failed, confidence: float = 0.90) -> dict:
    """Weibull fit, B10 and its likelihood-ratio bounds in one dict (NaN when unavailable).

    Returns
    -------
    dict
        ``n``, ``n_failed``, ``shape``, ``scale``, ``b10``, ``b10_lower``, ``b10_upper``,
        ``confidence``, ``loglik`` (lives' unit for scale and B10), ``note`` (None when sound).
    """
    fit = weibull_fit(life, failed)
    est, lo, hi = weibull_quantile_bounds(fit, life, failed, 0.10, confidence)
    return {"n": fit.n, "n_failed": fit.n_failed, "shape": fit.shape, "scale": fit.scale, "b10": est,
            "b10_lower": lo, "b10_upper": hi, "confidence": confidence, "loglik": fit.loglik, "note": fit.note}


#: Failures up to which median-rank regression is the preferred point estimate (Abernethy 2006,
#: ch. 5: "20 failures or less"); from 21 failures on, maximum likelihood. [-]
MRR_MAX_FAILURES = 20

#: Benard's median-rank offset: ``F = (rank - 0.3) / (n + 0.4)`` (Abernethy 2006, ch. 2). [-]
BENARD_OFFSET = 0.3


def median_ranks(life, failed) -> pd.DataFrame:
    """Failure plotting positions as Weibull++ and Abernethy compute them: Johnson's adjusted ranks
    for suspensions and Benard's approximation of the median rank.

    Units are ordered by life, a failure before a suspension at the same life (as
    :func:`kaplan_meier`). Each failure's adjusted rank is the previous one plus
    ``(n + 1 - previous) / (1 + units at or beyond it)`` (Johnson 1964, the "mean order number";
    without suspensions the ranks are 1, 2, ..., n); its median rank is
    ``(adjusted rank - 0.3) / (n + 0.4)`` (Benard 1953; Abernethy 2006, sections 2.4 and 2.9).

    Parameters
    ----------
    life : array_like
        Lives [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension.

    Returns
    -------
    DataFrame
        One row per failure, by life: ``life``, ``adjusted_rank`` [-], ``median_rank`` (fraction
        failed [-]).
    """
    x, f = _as_arrays(life, failed)
    order = np.lexsort((~f, x))          # by life, failures first at a tie
    x, f = x[order], f[order]
    n = len(x)
    beyond = n - np.arange(n)            # units at or beyond each position (its reverse rank)
    ranks, prev = [], 0.0
    for reverse in beyond[f]:
        prev += (n + 1.0 - prev) / (1.0 + reverse)
        ranks.append(prev)
    ranks = np.asarray(ranks, float)
    return pd.DataFrame({"life": x[f], "adjusted_rank": ranks,
                         "median_rank": (ranks - BENARD_OFFSET) / (n + 1.0 - 2.0 * BENARD_OFFSET)})


def weibull_rank_regression(life, failed) -> WeibullFit:
    """Median-rank regression (MRR), rank regression on X, as Weibull++ (RRX) and Abernethy do it.

    The Weibull plot's straight line ``ln(life) = ln(scale) + ln(-ln(1 - F)) / shape`` fitted by
    least squares of ``ln(life)`` on ``y = ln(-ln(1 - F))`` at the failures' median ranks
    (:func:`median_ranks`): the life is the variable with the scatter, so its deviations are the
    ones minimised (Abernethy 2006, section 5.3, "X on Y"). ``shape = 1 / slope``,
    ``scale = exp(intercept)``.

    Parameters
    ----------
    life : array_like
        Lives [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension (it shifts the failures' ranks only).

    Returns
    -------
    WeibullFit
        ``loglik`` is the censored log-likelihood at the MRR estimate (below the MLE's); NaN with
        a ``note`` with fewer than two failures or when the failures' lives do not spread (a
        slope that is not positive, or a shape outside :data:`SHAPE_BOUNDS`).
    """
    x, f = _as_arrays(life, failed)
    n, r = int(len(x)), int(f.sum())
    if r < 2:
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note=f"too few failures: {r} < 2")
    mr = median_ranks(x, f)
    y = np.log(-np.log1p(-mr["median_rank"].to_numpy()))
    lx = np.log(mr["life"].to_numpy())
    dy = y - y.mean()
    slope = float(dy @ (lx - lx.mean()) / (dy @ dy))
    shape = 1.0 / slope if slope > 0 else _NAN
    if not (math.isfinite(shape) and SHAPE_BOUNDS[0] < shape < SHAPE_BOUNDS[1]):
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note="the failures' lives do not spread: the rank regression "
                                                      "cannot tell a shape")
    scale = float(math.exp(lx.mean() - slope * y.mean()))
    with np.errstate(over="ignore"):          # a suspension far beyond a steep line: -inf, as it is
        return WeibullFit(shape, scale, weibull_loglik(shape, scale, x, f), n, r)


def preferred_method(n_failed: int) -> str | None:
    """The point estimate Abernethy (2006, ch. 5) would quote: ``"MRR"`` up to
    :data:`MRR_MAX_FAILURES` failures, ``"MLE"`` beyond; None with fewer than two.

    His reasoning: with few failures the MLE of the shape is biased high (too steep) and so early
    B-lives are optimistic,
    while the median-rank line is nearly median-unbiased and is read on the plot, where a
    mixture or an outlier shows; with many failures the MLE is the more precise (smaller
    scatter) and it uses the suspensions' exact lives rather than their effect on the ranks."""
    if n_failed < 2:
        return None
    return "MRR" if n_failed <= MRR_MAX_FAILURES else "MLE"


def weibull_shape_bounds(fit: WeibullFit, life, failed, confidence: float = 0.90) -> tuple[float, float]:
    """Two-sided likelihood-ratio (profile likelihood) bounds of the Weibull shape.

    For a shape ``k`` the scale's MLE is closed form (:func:`weibull_scale_given_shape`), so the
    profile is ``weibull_loglik(k, scale(k))``; the bounds are where its deviance reaches
    ``chi2.ppf(confidence, 1)`` (Meeker & Escobar 1998, section 8.3), searched with
    :func:`lr_bound` on ``log k`` up to :data:`SHAPE_BOUNDS`.

    Parameters
    ----------
    fit : WeibullFit
        The MLE (from :func:`weibull_fit` on the same data).
    life, failed : array_like
        The data the fit was made on.
    confidence : float
        Two-sided confidence level [-].

    Returns
    -------
    (lower, upper) : tuple of float
        [-]; NaN when the fit is not available or the data do not bound that side.
    """
    if not fit.ok:
        return _NAN, _NAN
    x, f = _as_arrays(life, failed)
    crit = chi2_ppf(confidence, 1)

    def excess(logk):
        k = math.exp(logk)
        with np.errstate(over="ignore"):      # a far shape overflows to a -inf likelihood: outside the bounds
            return 2.0 * (fit.loglik - weibull_loglik(k, weibull_scale_given_shape(k, x, f), x, f)) - crit

    centre = math.log(fit.shape)
    lo, hi = (lr_bound(excess, centre, math.log(edge)) for edge in SHAPE_BOUNDS)
    return math.exp(lo), math.exp(hi)


#: The fraction failed at the scale (the characteristic life): ``1 - exp(-1)``. [-]
SCALE_FRACTION = -math.expm1(-1.0)


def weibull_reliability_bounds(fit: WeibullFit, life, failed, mission: float,
                               confidence: float = 0.90) -> tuple[float, float, float]:
    """Reliability at a mission life, ``R(t) = exp(-(t / scale)^shape)``, with likelihood-ratio bounds.

    Holding ``R(t) = R`` is holding ``t`` as the ``1 - R`` quantile, so the profile likelihood of
    ``R`` is :func:`weibull_quantile_profile` at ``log t`` with ``p = 1 - R`` (Meeker & Escobar
    1998, section 8.3: the profile of a function of the parameters). It is searched (with
    :func:`lr_bound`) on ``u = ln(-ln R)``, the Weibull plot's ordinate, from the estimate out to
    ``R = exp(-e^3.3) = 1e-12`` and to ``u - 40`` (R within 1e-17 of 1): a bound beyond is NaN.

    Parameters
    ----------
    fit : WeibullFit
        The MLE (from :func:`weibull_fit` on the same data).
    life, failed : array_like
        The data the fit was made on.
    mission : float
        The mission life [unit of ``life``, > 0].
    confidence : float
        Two-sided confidence level [-].

    Returns
    -------
    (estimate, lower, upper) : tuple of float
        Reliabilities [-]; all NaN when the fit is not available or the mission is not positive.
    """
    if not (fit.ok and mission > 0 and math.isfinite(mission)):
        return _NAN, _NAN, _NAN
    x, f = _as_arrays(life, failed)
    crit = chi2_ppf(confidence, 1)
    log_t, start = math.log(mission), math.log(fit.shape)
    u_hat = fit.shape * (log_t - math.log(fit.scale))
    top = math.log(-math.log(1e-12))

    def excess(u):
        p = -math.expm1(-math.exp(u))
        return 2.0 * (fit.loglik - weibull_quantile_profile(log_t, p, x, f, start=start)) - crit

    if u_hat >= top:
        return math.exp(-math.exp(u_hat)), _NAN, _NAN
    u_hi = lr_bound(excess, u_hat, top)            # more failed: the lower bound of R
    u_lo = lr_bound(excess, u_hat, u_hat - 40.0)
    rel = lambda u: math.exp(-math.exp(u)) if math.isfinite(u) else _NAN  # noqa: E731
    return rel(u_hat), rel(u_hi), rel(u_lo)


def service_life_summary(life, failed, b_life_pct: float = 10.0, confidence: float = 0.90,
                         mission: float | None = None) -> dict:
    """The service-life row a Weibull++ user expects, for one group of lives.

    Parameters
    ----------
    life : array_like
        Lives [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension.
    b_life_pct : float
        The B-life's fraction failed [%] (10: B10).
    confidence : float
        Two-sided confidence of every interval [-].
    mission : float or None
        Mission life [unit of ``life``]; None: no reliability.

    Returns
    -------
    dict
        MLE ``shape`` / ``scale`` with profile-likelihood bounds (``shape_lower`` ...
        ``scale_upper``), ``b_life`` with bounds, ``reliability`` (at ``mission``) with bounds, the
        median-rank regression's ``mrr_shape``, ``mrr_scale``, ``mrr_b_life``, the
        ``preferred_method`` (:func:`preferred_method`), ``note`` (why the MLE is NaN) and
        ``bounds_note`` (which bounds the data do not reach); NaN where unavailable.
    """
    fit = weibull_fit(life, failed)
    mrr = weibull_rank_regression(life, failed)
    p = b_life_pct / 100.0
    s_lo, s_hi = weibull_shape_bounds(fit, life, failed, confidence)
    _, c_lo, c_hi = weibull_quantile_bounds(fit, life, failed, SCALE_FRACTION, confidence)
    b, b_lo, b_hi = weibull_quantile_bounds(fit, life, failed, p, confidence)
    rel = (weibull_reliability_bounds(fit, life, failed, mission, confidence) if mission is not None
           else (_NAN, _NAN, _NAN))
    out = {"n": fit.n, "n_failed": fit.n_failed, "shape": fit.shape, "shape_lower": s_lo, "shape_upper": s_hi,
           "scale": fit.scale, "scale_lower": c_lo, "scale_upper": c_hi, "b_life": b, "b_life_lower": b_lo,
           "b_life_upper": b_hi, "reliability": rel[0], "reliability_lower": rel[1], "reliability_upper": rel[2],
           "mrr_shape": mrr.shape, "mrr_scale": mrr.scale, "mrr_b_life": mrr.quantile(p),
           "preferred_method": preferred_method(fit.n_failed) if fit.ok or mrr.ok else None,
           "note": fit.note if fit.note else (f"median-rank regression: {mrr.note}" if mrr.note else None)}
    open_sides = [name for name in ("shape_lower", "shape_upper", "scale_lower", "scale_upper", "b_life_lower",
                                    "b_life_upper") + (("reliability_lower", "reliability_upper") if mission else ())
                  if fit.ok and not math.isfinite(out[name])]
    out["bounds_note"] = ("the data do not bound " + ", ".join(open_sides)) if open_sides else None
    return out


def weibull_lr_test(groups: dict) -> dict:
    """Likelihood-ratio test that groups of lives share one Weibull distribution.

    Parameters
    ----------
    groups : dict of str to (life, failed)
        Lives and failure flags per group (e.g. ``"force"``, ``"distance"``).

    Returns
    -------
    dict
        ``lr`` (statistic), ``df``, ``p_value``, ``loglik_pooled``, ``loglik_separate``; NaN
        values when fewer than two groups or a group (or the pool) has fewer than two failures.
    """
    names = sorted(groups)
    out = {"lr": _NAN, "df": 2 * (len(names) - 1), "p_value": _NAN, "loglik_pooled": _NAN,
           "loglik_separate": _NAN, "groups": ",".join(names)}
    if len(names) < 2:
        return out
    fits = [weibull_fit(*groups[g]) for g in names]
    lives = np.concatenate([np.asarray(groups[g][0], float) for g in names])
    fails = np.concatenate([np.asarray(groups[g][1], bool) for g in names])
    pooled = weibull_fit(lives, fails)
    if not pooled.ok or not all(ft.ok for ft in fits):
        return out
    sep = sum(ft.loglik for ft in fits)
    lr = max(0.0, 2.0 * (sep - pooled.loglik))
    out.update(lr=lr, p_value=chi2_sf(lr, out["df"]), loglik_pooled=pooled.loglik,
               loglik_separate=sep)
    return out


def kaplan_meier(life, failed) -> pd.DataFrame:
    """Kaplan-Meier (product-limit) survival estimate with Greenwood's standard error.

    Parameters
    ----------
    life : array_like
        Lives [any unit].
    failed : array_like of bool
        True for a failure, False for a suspension.

    Returns
    -------
    DataFrame
        One row per distinct life: ``life``, ``n_at_risk``, ``n_failed``, ``n_censored``,
        ``survival`` (just after that life), ``std_err`` (Greenwood).
    """
    x, f = _as_arrays(life, failed)
    cols = ["life", "n_at_risk", "n_failed", "n_censored", "survival", "std_err"]
    if len(x) == 0:
        return pd.DataFrame(columns=cols)
    u, inv = np.unique(x, return_inverse=True)
    d = np.bincount(inv, weights=f.astype(float), minlength=len(u))
    c = np.bincount(inv, weights=(~f).astype(float), minlength=len(u))
    at_risk = len(x) - np.concatenate([[0.0], np.cumsum(d + c)[:-1]])
    with np.errstate(divide="ignore", invalid="ignore"):
        surv = np.cumprod(1.0 - d / at_risk)
        gw = np.cumsum(np.where(at_risk > d, d / (at_risk * (at_risk - d)), 0.0))
        se = surv * np.sqrt(gw)
    return pd.DataFrame({"life": u, "n_at_risk": at_risk.astype(np.int64), "n_failed": d.astype(np.int64),
                         "n_censored": c.astype(np.int64), "survival": surv, "std_err": se})


def weibull_plotting_positions(life, failed) -> pd.DataFrame:
    """Failure plotting positions for a Weibull plot of censored data.

    Uses the Kaplan-Meier estimate averaged across each failure step (Meeker & Escobar's
    "midpoint" convention), so that suspensions shift the failures' positions.

    Returns
    -------
    DataFrame
        ``life`` and ``F`` (fraction failed) per failure.
    """
    km = kaplan_meier(life, failed)
    if km.empty:
        return pd.DataFrame(columns=["life", "F"])
    before = np.concatenate([[1.0], km["survival"].to_numpy()[:-1]])
    F = 1.0 - 0.5 * (before + km["survival"].to_numpy())
    keep = km["n_failed"].to_numpy() > 0
    return pd.DataFrame({"life": km["life"].to_numpy()[keep], "F": F[keep]})


__all__ = ["SHAPE_BOUNDS", "MRR_MAX_FAILURES", "WeibullFit", "weibull_fit", "median_ranks", "weibull_rank_regression",
           "preferred_method", "reduced_bias_shape", "weibull_shape_bounds", "weibull_reliability_bounds", "service_life_summary", "weibull_loglik", "weibull_scale_given_shape",
           "weibull_quantile_bounds", "weibull_quantile_profile", "lr_bound", "b10", "weibull_lr_test",
           "kaplan_meier", "weibull_plotting_positions", "weibull_loglik_many"]


def weibull_loglik_many(shape, scale, life, failed) -> np.ndarray:
    """:func:`weibull_loglik` at many parameter pairs at once (vectorised over the pairs).

    Used to weigh thousands of parameter draws against the likelihood (the predictive
    distributions of :mod:`analyses.life_posterior`), where one call per pair is too slow.

    Parameters
    ----------
    shape, scale : array_like
        Weibull parameters, broadcast against each other (scale in the unit of ``life``).
    life : array_like
        Lives (failure or censoring distance) [any unit, > 0].
    failed : array_like of bool
        True for a failure, False for a suspension.

    Returns
    -------
    numpy.ndarray
        Log-likelihood per pair (shape of the broadcast parameters); -inf where a parameter is
        not positive.
    """
    x, f = _as_arrays(life, failed)
    k, s = np.broadcast_arrays(np.asarray(shape, dtype=float), np.asarray(scale, dtype=float))
    good = (k > 0) & (s > 0)
    kk, ss = np.where(good, k, 1.0)[..., None], np.where(good, s, 1.0)[..., None]
    z = x / ss
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        ll = (np.sum(np.where(f, np.log(kk / ss) + (kk - 1.0) * np.log(z), 0.0), axis=-1)
              - np.sum(z ** kk, axis=-1))
    return np.where(good, ll, -np.inf)
