"""The life effect: how much longer force-set hoses live than distance-set ones, with bounds.

Lives are distances [km] (any positive unit works); failed hoses are exact lives, removed and
still-running hoses right-censored. ``group`` is 0 for a distance-set adjustment, 1 for a
force-set one.

Model (Meeker & Escobar 1998, chapter 17: Weibull regression)
------------------------------------------------------------
A Weibull with one shape for both adjustments and a scale per adjustment: ``log life`` is a
smallest-extreme-value variable with location ``mu_distance + theta * group`` and scale
``1 / shape``. ``theta`` is the log of the life ratio ``scale_force / scale_distance``; under a
common shape this is the ratio of every quantile, B10 included. The parameters are estimated by
maximum likelihood with right censoring (:func:`analyses.service_life.weibull_loglik`): for a
given shape each scale is closed form (:func:`analyses.service_life.weibull_scale_given_shape`)
and the shape solves a strictly decreasing score equation (Newton's method kept in a bracket,
:func:`analyses.service_life.newton_root`, started at the estimate or the previous look's shape;
``brentq`` over :data:`analyses.service_life.SHAPE_BOUNDS` when it does not settle inside them).

Bounds and tests (Meeker & Escobar 1998, sections 8.3 and 17.3)
----------------------------------------------------------------
* ``life_ratio_lower`` / ``life_ratio_upper``: profile-likelihood bounds at ``confidence``: the
  ratios where ``2 * (loglik_max - loglik_profile(theta)) = chi2.ppf(confidence, 1)``. For a fixed
  ``theta`` the force lives divided by ``exp(theta)`` share the distance lives' Weibull, so the
  profile is a one-sample fit of the pooled, rescaled lives (minus ``failures_force * theta``, the
  Jacobian).
* ``shape_lower`` / ``shape_upper``: the same for the shape (the scales profiled out in closed
  form), from the profile likelihood adjusted for the two estimated scales (Cox & Reid 1987: minus
  half the log of the scales' observed information, ``-2 log shape`` here; Yang & Xie 2003 for the
  Weibull shape). The plain profile's shape bounds inherit the MLE's small-sample upward bias and
  covered the true shape 84-89 % of the time at 90 % nominal with 8-15 hoses per adjustment; the
  adjusted ones 87-90 % (``benchmarks/bench_life_effect.py``). ``shape`` itself is the MLE.
* ``p_value``: likelihood-ratio test of ``life ratio = 1`` (1 df).
* ``shape_test_p``: likelihood-ratio test of a common shape against a shape per adjustment (1 df;
  each adjustment's own fit is the one-group case of the common-shape solver, the exact profile
  solution :func:`analyses.service_life.weibull_fit` starts from).
* When ``shape_test_p < alpha`` the shapes differ and a ratio of scales is no longer a ratio of
  lives: ``life_ratio`` is then the ratio of the two adjustments' own B10 and ``model`` says
  ``separate shapes``. That model's own bounds come from the profile likelihood of the
  four-parameter model (for a trial ratio ``rho`` the likelihood is maximised over the distance
  B10 ``b`` and both shapes with the force B10 at ``rho * b``; per adjustment the shape at a
  held B10 solves a concave problem exactly, :func:`analyses.service_life.weibull_quantile_profile`,
  the profile service_life's B10 bounds use; :func:`b10_ratio_separate_shapes`). The reported
  bounds are the **union** of that interval and the common-shape one, and ``p_value`` the larger
  of the two models' tests of ratio = 1 (so the interval excludes 1 exactly when
  ``p_value < 1 - confidence``). ``shape`` and its bounds stay the common-shape fit's (the
  column's definition).

  Why the union (measured, ``python -m benchmarks.bench_life_effect --seed 23 7 1 2 3 4 5 6 8 9``:
  equal true shapes, 8-15 hoses per adjustment, 90 % nominal): the separate-shape profile
  interval is not too narrow in itself: used for every hose type it covers the true B10 ratio
  88.6-91.7 % of the time per seed, and its deviance at the truth (:func:`ratio_deviance`)
  averages 0.94-1.14 (a Bartlett factor of about 1: a Bartlett correction or a Cox-Reid
  adjustment would have nothing to correct). It fails after the pre-test: with equal true shapes
  the separate B10 ratio's error is mostly ``log(-log 0.9) * (1/k_force - 1/k_distance)``, the
  estimated shapes' difference, which is what the shape test measures, so the test's false
  alarms (4-7 % of hose types) are the types whose B10 ratio is furthest off: there the deviance
  at the truth averages 3.8-5.3 and the interval covers 81 of 265 (30.6 %), the reported ratio as
  a whole 82.7-87.0 % per seed (an interval chosen after a pre-test is conditioned on it: Leeb &
  Poetscher 2005; Kabaila 2009). Which model is right the test cannot tell; the union covers
  whenever either model's interval does, so its coverage is at least that of the right model's
  interval: the common one covers 89-100 % of the false alarms per seed, the union 255 of 265
  (96.2 %), the reported ratio 86.3-91.5 % per seed. It costs width only when the test rejects.
  It does not help when the shapes truly differ and the test, with a handful of failures, does
  not see it: the common shape is kept and its ratio of scales is not the B10 ratio (the
  benchmark's ``--shape-ratio``).
* ``log_ratio`` and ``se_log_ratio``: the common-shape estimate of ``theta`` and its standard
  error from the observed information (the analytic Hessian of the smallest-extreme-value
  regression, ``CommonShapeFit.cov``): what a group-sequential design reads at each look
  (Jennison & Turnbull 2000, chapter 13), whatever ``model`` the table reports;
  :func:`common_shape_fit` gives them without the bounds, in a few milliseconds.

Profile-likelihood bounds are used rather than Wald (Fisher-matrix) bounds because with a handful
of failures the estimators are far from normal; ``benchmarks/bench_life_effect.py`` measures the
coverage of both by simulation from known truth.

What is not reported
--------------------
A result is right or it is absent: NaN and a one-line ``note`` when an adjustment has fewer
than two failures (no shape can be told), when the common shape's MLE lies at the edge of
``SHAPE_BOUNDS``, and for a bound not reached within the search edge (the life ratio within
``RATIO_SEARCH`` times the estimate either way, the shape within ``SHAPE_BOUNDS``): that bound is
NaN, the interval open on that side.

References
----------
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Cox, D. R. & Reid, N. (1987). Parameter orthogonality and approximate conditional inference.
JRSS B 49, 1-39.
Yang, Z. & Xie, M. (2003). Efficient estimation of the Weibull shape parameter based on a
modified profile likelihood. J. Statist. Comput. Simul. 73, 115-123.
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical
Trials. Chapman & Hall/CRC.
Leeb, H. & Poetscher, B. M. (2005). Model selection and inference: facts and fiction.
Econometric Theory 21, 21-59.
Kabaila, P. (2009). The coverage properties of confidence regions after model selection.
International Statistical Review 77, 405-414.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from analyses.numerics import brentq, chi2_ppf, chi2_sf, fminbound
from analyses.service_life import (SHAPE_BOUNDS, WeibullFit, lr_bound, newton_root, weibull_quantile_profile,
                                   weibull_scale_given_shape)

_NAN = float("nan")

#: ``model`` values: the ratio of scales under one shape, or the ratio of B10 under a shape each.
COMMON, SEPARATE = "common shape", "separate shapes"

#: Search edge of the life ratio's bounds: a bound beyond this factor of the estimate (either
#: way) is not reported. [-]
RATIO_SEARCH = 1e6

#: The quantile compared when the shapes differ (B10). [-]
P_B10 = 0.10


@dataclass(frozen=True)
class LifeEffect:
    """One hose type's life effect (the ``life_effect`` table's columns, plus what a sequential
    design reads).

    Attributes
    ----------
    n_force, n_failed_force, n_distance, n_failed_distance : int
        Hoses and failures per adjustment (positive finite lives only).
    shape, shape_lower, shape_upper : float
        Common Weibull shape [-] and its profile-likelihood bounds.
    life_ratio, life_ratio_lower, life_ratio_upper : float
        Force / distance ratio of B10 [-] (of every quantile under a common shape) and its
        profile-likelihood bounds at ``confidence`` (under ``separate shapes``, the union of both
        models' intervals: module docstring).
    p_value : float
        Likelihood-ratio test of ``life_ratio = 1`` under ``model`` (under ``separate shapes``, the
        larger of both models' p-values).
    shape_test_p : float
        Likelihood-ratio test of a common shape against a shape per adjustment.
    model : str or None
        ``"common shape"`` or ``"separate shapes"`` (whose ``life_ratio`` this is); None when no
        ratio is reported.
    note : str or None
        Why a value is NaN (one line), None when every value is there.
    log_ratio, se_log_ratio : float
        Common-shape ``log(life_ratio)`` and its standard error (observed information).
    """

    n_force: int
    n_failed_force: int
    n_distance: int
    n_failed_distance: int
    shape: float = _NAN
    shape_lower: float = _NAN
    shape_upper: float = _NAN
    life_ratio: float = _NAN
    life_ratio_lower: float = _NAN
    life_ratio_upper: float = _NAN
    p_value: float = _NAN
    shape_test_p: float = _NAN
    model: str | None = None
    note: str | None = None
    log_ratio: float = _NAN
    se_log_ratio: float = _NAN


@dataclass(frozen=True)
class CommonShapeFit:
    """The common-shape Weibull regression at its maximum (no bounds): what each look reads.

    Attributes
    ----------
    shape : float
        Common Weibull shape [-].
    scale_distance, scale_force : float
        Weibull scale of each adjustment [unit of life].
    loglik : float
        Log-likelihood at the estimate.
    log_ratio : float
        ``log(scale_force / scale_distance)``, the log life ratio [-].
    cov : ndarray, shape (3, 3)
        Covariance of (log scale_distance, log_ratio, log shape) from the observed information.
    note : str or None
        Why the values are NaN (one line).
    """

    shape: float = _NAN
    scale_distance: float = _NAN
    scale_force: float = _NAN
    loglik: float = _NAN
    log_ratio: float = _NAN
    cov: np.ndarray = field(default_factory=lambda: np.full((3, 3), _NAN))
    note: str | None = None

    @property
    def se_log_ratio(self) -> float:
        """Standard error of ``log_ratio`` (observed information) [-]."""
        return float(math.sqrt(self.cov[1, 1]))


def split_groups(life, failed, group) -> list[tuple[np.ndarray, np.ndarray]]:
    """The two adjustments' lives apart: ``[(lives, failed) of distance, (lives, failed) of force]``.

    Parameters
    ----------
    life : array_like
        Each hose's distance at failure or at censoring; non-positive or non-finite ones are dropped. [km]
    failed : array_like of bool
        True where the hose failed, False where it is censored (still running or removed).
    group : array_like of int
        0 for distance-set, 1 for force-set.

    Returns
    -------
    list of (ndarray, ndarray)
        Lives [km] and failure flags of the distance-set hoses, then of the force-set ones.

    Raises
    ------
    ValueError
        The three arrays differ in length, or a group is neither 0 nor 1.
    """
    x = np.asarray(life, dtype=np.float64)
    f = np.asarray(failed, dtype=bool)
    g = np.asarray(group)
    if not x.shape == f.shape == g.shape:
        raise ValueError("life, failed and group must have the same length")
    if not ((g == 0) | (g == 1)).all():
        raise ValueError("group must be 0 (distance) or 1 (force)")
    keep = np.isfinite(x) & (x > 0)
    return [(x[keep & (g == v)], f[keep & (g == v)]) for v in (0, 1)]


def _too_few(groups) -> str | None:
    """The note when an adjustment has fewer than two failures (no Weibull shape can be told)."""
    few = [f"{name} {int(f.sum())}" for name, (_, f) in zip(("distance", "force"), groups) if f.sum() < 2]
    return f"too few failures to tell a Weibull: {', '.join(few)} < 2" if few else None


def _shape_score(logk: float, groups) -> float:
    """d loglik / d shape with each group's scale profiled out (strictly decreasing in the shape)."""
    k = math.exp(logk)
    total = 0.0
    for x, f in groups:
        y = np.log(x)
        w = np.exp(k * (y - y.max()))
        r = float(f.sum())
        total += r / k + float(y[f].sum()) - r * float((w * y).sum() / w.sum())
    return total


def _score_slope(logk: float, logs, extra: float = 0.0) -> tuple[float, float]:
    """:func:`_shape_score` minus ``extra / k`` and its derivative in ``log k`` (for :func:`newton_root`).

    ``logs``: :func:`_logs`; d score / d log k = ``-(failures + extra) / k - k * sum(failures * var_w(log life))``
    with the weights ``w = life^k`` of the scale's closed form: strictly negative.
    """
    k = math.exp(logk)
    value, slope = -extra / k, extra / k
    for y, r, syf, _ in logs:
        w = np.exp(k * y)
        sw = float(w.sum())
        m = float(w @ y) / sw
        d = y - m
        value += r / k + syf - r * m
        slope -= r / k + k * r * float(w @ (d * d)) / sw
    return value, slope


def _logs(groups) -> list[tuple[np.ndarray, float, float, float]]:
    """Per group the log lives minus their largest, the failures, the failures' sum of those, the largest."""
    out = []
    for x, f in groups:
        y = np.log(x)
        ymax = float(y.max())
        y = y - ymax
        out.append((y, float(f.sum()), float(y[f].sum()), ymax))
    return out


def _shape_mle(groups, start: float = 0.0) -> tuple[float, bool]:
    """(shape maximising the likelihood with a scale per group, whether it is at a search edge).

    Newton's method on the score in ``log k`` from ``start`` (:func:`newton_root`: the same root
    ``brentq`` finds, in a few steps from a near start); the bracketed search when it does not
    settle inside :data:`SHAPE_BOUNDS` (the MLE at an edge).
    """
    lo, hi = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])
    logs = _logs(groups)
    root = newton_root(lambda t: _score_slope(t, logs), lo, hi, start)
    if root is not None:
        return math.exp(root), False
    if _shape_score(lo, groups) <= 0:
        return SHAPE_BOUNDS[0], True
    if _shape_score(hi, groups) >= 0:
        return SHAPE_BOUNDS[1], True
    return math.exp(brentq(lambda t: _shape_score(t, groups), lo, hi, xtol=1e-13, rtol=1e-13)), False


def _loglik_at_shape(k: float, groups) -> float:
    """Log-likelihood at shape ``k`` with each group's scale at its MLE.

    :func:`analyses.service_life.weibull_loglik` at :func:`analyses.service_life.weibull_scale_given_shape`,
    in closed form: with ``scale^k = sum(x^k) / r`` the suspensions' and failures' ``(x / scale)^k``
    sum to ``r``, leaving ``r log k - r log(sum(x^k) / r) + (k - 1) sum(log x_failed) - r`` per group
    (the same value to rounding, without the powers' second pass).
    """
    total = 0.0
    for y, r, syf, ymax in _logs(groups):          # y: log lives minus their largest, ymax
        log_sum = k * ymax + math.log(float(np.exp(k * y).sum()))
        total += r * math.log(k) - r * (log_sum - math.log(r)) + (k - 1.0) * (syf + r * ymax) - r
    return total


def _ratio_profile(theta: float, groups, start: float = 0.0) -> float:
    """Common-shape log-likelihood maximised with log(scale_force / scale_distance) held at ``theta``
    (the shape's solve from ``log k = start``)."""
    (xd, fd), (xf, ff) = groups
    pooled = [(np.concatenate([xd, xf * math.exp(-theta)]), np.concatenate([fd, ff]))]
    k, _ = _shape_mle(pooled, start)
    return _loglik_at_shape(k, pooled) - float(ff.sum()) * theta


def _covariance(groups, shape: float, scales: tuple[float, float]) -> np.ndarray:
    """Covariance of (log scale_distance, log ratio, log shape): the inverse observed information.

    The analytic Hessian of the smallest-extreme-value regression of log life on the group
    (location ``mu_distance + theta * group``, scale ``sigma = 1 / shape``; Meeker & Escobar 1998,
    section 17.3 and appendix B), inverted, then carried to ``log shape`` (exact for this change of
    one coordinate). All NaN when the information is not positive definite.
    """
    sigma = 1.0 / shape
    sums = []                                   # per group: sum w, sum (w z + w - d), sum (w z^2 + 2 w z - 2 d z - d)
    for (x, f), shift in zip(groups, (0.0, math.log(scales[1] / scales[0]))):
        z = (np.log(x) - math.log(scales[0]) - shift) / sigma
        w = np.exp(z)
        d = f.astype(np.float64)
        wz = w * z
        sums.append((float(w.sum()), float((wz + w - d).sum()), float((wz * z + 2.0 * wz - 2.0 * d * z - d).sum())))
    (w0, a0, b0), (w1, a1, b1) = sums
    info = np.array([[w0 + w1, w1, a0 + a1], [w1, w1, a1], [a0 + a1, a1, b0 + b1]]) / sigma ** 2
    if not np.isfinite(info).all() or np.linalg.eigvalsh(info).min() <= 0:
        return np.full((3, 3), _NAN)
    cov = np.linalg.inv(info)
    cov[2, :] *= -1.0 / sigma                   # d log(shape) / d sigma = -1 / sigma
    cov[:, 2] *= -1.0 / sigma
    return cov


def _fit_groups(groups, start: float = 0.0) -> CommonShapeFit:
    """:func:`common_shape_fit` on the lives already split by adjustment (the shape's solve from ``log k = start``)."""
    note = _too_few(groups)
    if note:
        return CommonShapeFit(note=note)
    k, at_edge = _shape_mle(groups, start)
    if at_edge:
        return CommonShapeFit(note=f"the common Weibull shape MLE is at the search bound ({k:g}): "
                                   "the lives cannot tell a shape")
    scales = (weibull_scale_given_shape(k, *groups[0]), weibull_scale_given_shape(k, *groups[1]))
    return CommonShapeFit(k, scales[0], scales[1], _loglik_at_shape(k, groups), math.log(scales[1] / scales[0]),
                          _covariance(groups, k, scales))


def common_shape_fit(life, failed, group, shape_start: float = 1.0) -> CommonShapeFit:
    """The common-shape Weibull regression of life on the adjustment, by maximum likelihood.

    The estimate alone (no profile bounds, a few milliseconds): what a sequential design reads
    at each look (``log_ratio`` and its standard error), and the Wald bounds the calibration
    benchmark compares with.

    Parameters
    ----------
    life : array_like
        Lives [km] (failure or censoring distance); non-positive or non-finite ones are ignored.
    failed : array_like of bool
        True for a failure, False for a suspension.
    group : array_like of int
        0 for a distance-set adjustment, 1 for a force-set one.
    shape_start : float
        Shape the solve starts from [-] (the previous look's, for the next look): the same answer
        from any start (to 1e-13), fewer steps from a near one.

    Returns
    -------
    CommonShapeFit
        NaN with a ``note`` when an adjustment has fewer than two failures or the shape's MLE is
        at the edge of ``SHAPE_BOUNDS``.
    """
    start = math.log(shape_start) if math.isfinite(shape_start) and shape_start > 0 else 0.0
    return _fit_groups(split_groups(life, failed, group), start)



def _shape_bounds(groups, crit: float) -> tuple[float, float]:
    """Bounds of the shape from the Cox-Reid adjusted profile likelihood (NaN beyond ``SHAPE_BOUNDS``).

    ``loglik_profile(k) - len(groups) * log(k)``: each group's scale information at its profiled
    MLE is ``k^2 * failures``, and half its log is subtracted (Cox & Reid 1987; Yang & Xie 2003 for
    the Weibull shape). Its score is the profile's with ``failures / k`` replaced by
    ``(failures - groups) / k``, still strictly decreasing.
    """
    adjusted = lambda t: _loglik_at_shape(math.exp(t), groups) - len(groups) * t  # noqa: E731
    score = lambda t: _shape_score(t, groups) - len(groups) / math.exp(t)  # noqa: E731
    lo, hi = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])
    if score(lo) <= 0 or score(hi) >= 0:
        return _NAN, _NAN
    logs = _logs(groups)
    centre = newton_root(lambda t: _score_slope(t, logs, len(groups)), lo, hi, 0.0)
    if centre is None:
        centre = brentq(score, lo, hi, xtol=1e-13, rtol=1e-13)
    top = adjusted(centre)
    k_lo, k_hi = (lr_bound(lambda t: 2.0 * (top - adjusted(t)) - crit, centre, edge) for edge in (lo, hi))
    return math.exp(k_lo), math.exp(k_hi)


def _profile_bounds(fit: CommonShapeFit, groups, crit: float) -> dict:
    """Profile-likelihood bounds of the shape and the life ratio, and the p-value of ratio = 1."""
    ll, k, theta = fit.loglik, fit.shape, fit.log_ratio
    k_lo, k_hi = _shape_bounds(groups, crit)
    start = math.log(k)
    r_lo, r_hi = (lr_bound(lambda t: 2.0 * (ll - _ratio_profile(t, groups, start)) - crit,
                           theta, theta + side * math.log(RATIO_SEARCH)) for side in (-1.0, 1.0))
    lr = max(0.0, 2.0 * (ll - _ratio_profile(0.0, groups, start)))
    return {"shape": k, "shape_lower": k_lo, "shape_upper": k_hi,
            "life_ratio": math.exp(theta), "life_ratio_lower": math.exp(r_lo), "life_ratio_upper": math.exp(r_hi),
            "p_value": chi2_sf(lr, 1)}


# -- separate shapes: the B10 ratio --------------------------------------------------------------

def _own_fit(x: np.ndarray, f: np.ndarray) -> WeibullFit:
    """One adjustment's own Weibull: the one-group case of :func:`_shape_mle` (as
    :func:`analyses.service_life.weibull_fit` without its optimiser's polish, which costs ten times more)."""
    k, at_edge = _shape_mle([(x, f)])
    n, r = len(x), int(f.sum())
    if at_edge:
        return WeibullFit(_NAN, _NAN, _NAN, n, r, note=f"its shape MLE is at the search bound ({k:g})")
    return WeibullFit(k, weibull_scale_given_shape(k, x, f), _loglik_at_shape(k, [(x, f)]), n, r)


def _separate_profile(log_rho: float, groups, fits) -> float:
    """Four-parameter log-likelihood maximised with log(B10_force / B10_distance) held at ``log_rho``."""
    (xd, fd), (xf, ff) = groups
    ends = sorted((math.log(fits[0].quantile(P_B10)), math.log(fits[1].quantile(P_B10)) - log_rho))

    starts = (math.log(fits[0].shape), math.log(fits[1].shape))

    def neg(log_b):
        return -(weibull_quantile_profile(log_b, P_B10, xd, fd, starts[0])
                 + weibull_quantile_profile(log_b + log_rho, P_B10, xf, ff, starts[1]))

    # each term peaks at its own B10, so their sum peaks between the two
    return -float(neg(fminbound(neg, ends[0] - 0.1, ends[1] + 0.1, xatol=1e-9)))


def _separate_shapes(groups, fits, crit: float) -> dict:
    """B10 ratio of a shape per adjustment with its profile-likelihood bounds and p-value."""
    ll = fits[0].loglik + fits[1].loglik
    log_rho = math.log(fits[1].quantile(P_B10) / fits[0].quantile(P_B10))
    lo, hi = (lr_bound(lambda t: 2.0 * (ll - _separate_profile(t, groups, fits)) - crit,
                       log_rho, log_rho + side * math.log(RATIO_SEARCH)) for side in (-1.0, 1.0))
    lr = max(0.0, 2.0 * (ll - _separate_profile(0.0, groups, fits)))
    return {"life_ratio": math.exp(log_rho), "life_ratio_lower": math.exp(lo), "life_ratio_upper": math.exp(hi),
            "p_value": chi2_sf(lr, 1)}


def _separate_or_common(common: dict, separate: dict) -> dict:
    """The separate-shape B10 ratio with the union of both models' intervals, and the matching p-value.

    After the shape test chose separate shapes, the interval covers whenever either model's
    profile interval does (a NaN bound, open on its side, stays open), and ``p_value`` is the
    larger of the two tests of ratio = 1, so that the interval excludes 1 exactly when
    ``p_value < 1 - confidence`` (module docstring: why).
    """
    def either(name, pick):
        a, b = common[name], separate[name]
        return _NAN if math.isnan(a) or math.isnan(b) else pick(a, b)

    return {"life_ratio": separate["life_ratio"], "life_ratio_lower": either("life_ratio_lower", min),
            "life_ratio_upper": either("life_ratio_upper", max), "p_value": max(common["p_value"], separate["p_value"])}


def b10_ratio_separate_shapes(life, failed, group, confidence: float = 0.90) -> dict:
    """Force / distance B10 ratio under a Weibull shape per adjustment, with its own profile bounds.

    What :func:`life_effect` reports as ``separate shapes`` before the union with the
    common-shape interval: for a notebook, and for the calibration benchmark, which counts the
    coverage of these bounds alone after the shape test (the cause of the union).

    Parameters
    ----------
    life, failed, group : array_like
        As :func:`life_effect`.
    confidence : float
        Two-sided confidence of the bounds [-].

    Returns
    -------
    dict
        ``life_ratio``, ``life_ratio_lower``, ``life_ratio_upper`` [-], ``p_value`` (ratio = 1) and
        ``note``; NaN values with the ``note`` when an adjustment's own fit cannot be made.
    """
    groups = split_groups(life, failed, group)
    nan = {"life_ratio": _NAN, "life_ratio_lower": _NAN, "life_ratio_upper": _NAN, "p_value": _NAN}
    note = _too_few(groups)
    if note:
        return {**nan, "note": note}
    fits = [_own_fit(x, f) for x, f in groups]
    bad = [f"the {name} fit: {ft.note}" for name, ft in zip(("distance", "force"), fits) if not ft.ok]
    if bad:
        return {**nan, "note": "; ".join(bad)}
    return {**_separate_shapes(groups, fits, chi2_ppf(confidence, 1)), "note": None}


def ratio_deviance(life, failed, group, ratio: float, model: str = COMMON) -> float:
    """Profile deviance of a trial life ratio: ``2 * (loglik_max - loglik_profile(ratio))``.

    The statistic whose crossing of ``chi2.ppf(confidence, 1)`` gives the bounds of ``model``'s
    interval (the interval holds ``ratio`` exactly when the deviance is below it); about
    chi-square with 1 degree of freedom at the true ratio (mean 1). The calibration benchmark
    reads it at the true ratio to tell a small-sample miscalibration (a mean above 1, the
    Bartlett factor) from a selection effect.

    Parameters
    ----------
    life, failed, group : array_like
        As :func:`life_effect`.
    ratio : float
        Trial force / distance ratio [-]: of every quantile under ``COMMON``, of B10 under ``SEPARATE``.
    model : str
        :data:`COMMON` or :data:`SEPARATE`.

    Returns
    -------
    float
        The deviance [-]; NaN when the model's fit cannot be made (as :func:`life_effect`).
    """
    groups = split_groups(life, failed, group)
    if _too_few(groups):
        return _NAN
    if model == COMMON:
        fit = _fit_groups(groups)
        return _NAN if fit.note else max(0.0, 2.0 * (fit.loglik - _ratio_profile(math.log(ratio), groups)))
    fits = [_own_fit(x, f) for x, f in groups]
    if not all(ft.ok for ft in fits):
        return _NAN
    return max(0.0, 2.0 * (fits[0].loglik + fits[1].loglik - _separate_profile(math.log(ratio), groups, fits)))


def _missing_bounds(values: dict) -> str | None:
    """One line naming the bounds that were not reached within the search edge."""
    missing = [name for name in ("life_ratio_lower", "life_ratio_upper", "shape_lower", "shape_upper")
               if math.isnan(values[name])]
    if not missing:
        return None
    return f"{', '.join(missing)} not reached within the search edge: the data do not bound it"


def life_effect(life, failed, group, confidence: float = 0.90, alpha: float = 0.05) -> LifeEffect:
    """Force / distance life ratio of one hose type, common-shape Weibull by maximum likelihood.

    Parameters
    ----------
    life : array_like
        Lives [km] (failure or censoring distance); non-positive or non-finite ones are ignored.
    failed : array_like of bool
        True for a failure, False for a suspension (removed or still running).
    group : array_like of int
        0 for a distance-set adjustment, 1 for a force-set one.
    confidence : float
        Two-sided confidence of the bounds [-].
    alpha : float
        Level of the shape test below which the ratio comes from separate shapes [-].

    Returns
    -------
    LifeEffect
        NaN values with a one-line ``note`` where the data cannot tell (module docstring).
    """
    groups = split_groups(life, failed, group)
    counts = {"n_distance": len(groups[0][0]), "n_failed_distance": int(groups[0][1].sum()),
              "n_force": len(groups[1][0]), "n_failed_force": int(groups[1][1].sum())}
    fit = _fit_groups(groups)
    if fit.note:
        return LifeEffect(**counts, note=fit.note)
    crit = chi2_ppf(confidence, 1)
    values = {**_profile_bounds(fit, groups, crit), "model": COMMON, "log_ratio": fit.log_ratio,
              "se_log_ratio": fit.se_log_ratio}
    fits = [_own_fit(x, f) for x, f in groups]
    notes = [f"no shape test, the {name} fit: {ft.note}" for name, ft in zip(("distance", "force"), fits) if not ft.ok]
    if not notes:
        lr = max(0.0, 2.0 * (fits[0].loglik + fits[1].loglik - fit.loglik))
        values["shape_test_p"] = chi2_sf(lr, 1)
        if values["shape_test_p"] < alpha:
            values.update(_separate_or_common(values, _separate_shapes(groups, fits, crit)), model=SEPARATE)
    notes.append(_missing_bounds(values))
    return LifeEffect(**counts, **values, note="; ".join(n for n in notes if n) or None)


__all__ = ["COMMON", "SEPARATE", "RATIO_SEARCH", "LifeEffect", "CommonShapeFit", "common_shape_fit", "life_effect", "split_groups",
           "b10_ratio_separate_shapes", "ratio_deviance"]
