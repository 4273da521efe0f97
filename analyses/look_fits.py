"""The common-shape Weibull fits of many looks at once, and their repeated confidence intervals by the
profile likelihood.

A hose type's test is read at every failure (:mod:`analyses.decision`); each look is the common-shape
Weibull regression of life on the adjustment (:func:`analyses.life_effect.common_shape_fit`; Meeker &
Escobar 1998, ch. 17) of the hoses at their distances then. Here every look is solved at once, on padded
(look, hose) matrices:

* :func:`look_fits`: each look's maximum (shape, scales, log-likelihood, observed information), the
  same unique root as the look fitted alone (to 1e-13);
* :func:`profile_rci`: each look's repeated confidence interval ``{log ratio : profile deviance <=
  c_k^2}`` (Jennison & Turnbull 2000, ch. 9, with the likelihood ratio in place of the Wald statistic
  as in their sec. 12.1; Meeker & Escobar 1998, sec. 8.3 for profile-likelihood intervals: with the
  shape refitted at each look the Wald interval ``log_ratio -/+ c_k se`` is too narrow with few
  failures). Both ends of every look are found together by Newton's method on the signed root
  deviance ``sign(theta - theta_hat) sqrt(D(theta))`` (nearly linear in ``theta``), started at the
  Wald ends and kept in a bracket; the deviance's slope is closed form (the envelope theorem: at a
  held log ratio ``theta`` the force lives divided by ``exp(theta)`` pool with the distance lives
  into a one-sample Weibull, ``dD/dtheta = 2 k (r_force - r W_force / W)`` with ``W = sum x^k``),
  and each trial's shape solve starts from the previous trial's shape. An end that does not settle
  in a few steps is searched alone by :func:`analyses.service_life.lr_bound` (NaN when the deviance
  stays below ``c_k^2`` up to :data:`analyses.life_effect.RATIO_SEARCH`: the data do not bound it).
* :func:`bartlett_factor`: the profile deviance's mean at the true ratio, ``1 + BARTLETT / r`` with ``r``
  the look's failures (Bartlett 1937; Lawley 1956): the repeated interval is ``{theta : D_k(theta) <=
  b_k c_k^2}``, the deviance divided by its mean (a Bartlett-corrected likelihood ratio;
  Barndorff-Nielsen & Cox 1994, sec. 6.5). Without it the intervals
  of a test read at every failure miss the true ratio more often than ``alpha`` (docs/decision.md,
  "Repeated confidence intervals, calibrated").

References
----------
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical
Trials. Chapman & Hall/CRC.
Bartlett, M. S. (1937). Properties of sufficiency and statistical tests. Proc. R. Soc. Lond. A 160,
268-282.
Lawley, D. N. (1956). A general method for approximating to the distribution of likelihood ratio
criteria. Biometrika 43, 295-303.
Barndorff-Nielsen, O. E. & Cox, D. R. (1994). Inference and Asymptotics. Chapman & Hall.
"""
from __future__ import annotations

import math

import numpy as np

from analyses.life_effect import RATIO_SEARCH, CommonShapeFit, common_shape_fit, ratio_deviance
from analyses.service_life import SHAPE_BOUNDS, lr_bound

#: Newton steps on the signed root deviance before an end is searched alone (``lr_bound``). [-]
NEWTON_STEPS = 12

#: The Bartlett coefficient of the common-shape Weibull regression's profile deviance of the log life ratio:
#: at the true ratio the deviance averages ``1 + BARTLETT / r``, ``r`` the failures of both adjustments [-].
#: A property of the model, not of a data set: the log lives are an extreme-value location-scale sample, so
#: with complete (or failure-censored) samples the deviance at the truth is a pivot whose law depends on the
#: failure counts only; its mean measured by simulation of that pivot (``benchmarks.bench_decision
#: --bartlett``: 3,000 samples a pair of counts, 5-60 failures an adjustment, balanced and 1:3) is
#: ``1 + c / r`` with ``c`` about 3.8, whatever the split between the adjustments (docs/decision.md,
#: "Repeated confidence intervals, calibrated").
BARTLETT = 3.8


def bartlett_factor(failures) -> np.ndarray:
    """The Bartlett factor ``b = 1 + BARTLETT / r`` of a look's profile deviance of the log life ratio [-].

    At the true ratio the deviance ``D`` of the common-shape Weibull regression is chi-square(1) to first
    order only: its mean is ``b`` (Lawley 1956), above 1 by about 10 % at 40 failures, and ``D / b`` is
    chi-square(1) to the next order (Bartlett 1937; Barndorff-Nielsen & Cox 1994, sec. 6.5). A repeated
    interval ``{theta : D(theta) <= b c_k^2}`` therefore misses with the probability the spending function
    gives its look.

    Parameters
    ----------
    failures : array_like
        Each look's failures, both adjustments together [-].

    Returns
    -------
    numpy.ndarray
        ``b`` [-]; NaN where there are no failures.
    """
    r = np.asarray(failures, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, 1.0 + BARTLETT / r, math.nan)


def _row_sums(a: np.ndarray) -> np.ndarray:
    """Each row's sum, added in order: numpy's pairwise sum rounds differently as the padding grows, and a
    look's fit and interval must not move (in their last bits) when later looks widen the matrices."""
    return np.cumsum(a, axis=1)[:, -1] if a.shape[1] else np.zeros(a.shape[0])


def _by_look(x: np.ndarray, f: np.ndarray, row: np.ndarray, rows: int):
    """One adjustment's lives of every look as padded (look, hose) matrices: ``(log x, x, failed, present)``."""
    order = np.argsort(row, kind="stable")
    r, xs, fs = row[order], x[order], f[order]
    col = np.arange(r.size) - np.searchsorted(r, r, side="left")
    width = int(col.max()) + 1 if r.size else 1
    lx, xx = np.zeros((rows, width)), np.ones((rows, width))
    ff, mm = np.zeros((rows, width), bool), np.zeros((rows, width), bool)
    lx[r, col], xx[r, col], ff[r, col], mm[r, col] = np.log(xs), xs, fs, True
    return lx, xx, ff, mm


def _look_matrices(x: np.ndarray, f: np.ndarray, g: np.ndarray, lk: np.ndarray, wanted: np.ndarray):
    """:func:`_by_look` of each adjustment (distance, force), a row per look of ``wanted`` (positive finite lives)."""
    order = np.argsort(wanted, kind="stable")
    pos = np.minimum(np.searchsorted(wanted[order], lk), max(wanted.size - 1, 0))
    on = (wanted[order][pos] == lk) & np.isfinite(x) & (x > 0) if wanted.size else np.zeros(lk.size, bool)
    row = order[pos] if wanted.size else pos
    return [_by_look(x[on & (g == v)], f[on & (g == v)], row[on & (g == v)], wanted.size) for v in (0, 1)]


def _batch_score(t: np.ndarray, logs) -> tuple[np.ndarray, np.ndarray]:
    """The common shape's profile score and its slope in ``log k`` (``life_effect``'s ``_score_slope``) of many
    looks at once; ``logs``: per adjustment (y, present, failures, the failures' sum of y), ``y`` the log lives
    minus each look's largest."""
    k = np.exp(t)
    value, slope = np.zeros_like(t), np.zeros_like(t)
    for y, m, r, syf in logs:
        w = np.where(m, np.exp(k[:, None] * y), 0.0)
        sw = _row_sums(w)
        mean = _row_sums(w * y) / sw
        d = y - mean[:, None]
        value += r / k + syf - r * mean
        slope -= r / k + k * r * _row_sums(w * d * d) / sw
    return value, slope


def _rows(logs, i):
    """``logs`` (per adjustment a tuple of per-look arrays) at the rows ``i`` (None: all of them)."""
    return logs if i is None else [tuple(a[i] for a in lg) for lg in logs]


def _batch_newton(value_slope, start: np.ndarray, xtol: float = 1e-13) -> np.ndarray:
    """:func:`analyses.service_life.newton_root` over :data:`~analyses.service_life.SHAPE_BOUNDS` (log shapes) for
    many roots at once, step for step; NaN where it does not settle strictly inside (solved alone then).

    ``value_slope(t, rows)``: the function and its slope at ``t`` of the roots ``rows`` (None: every root), so that
    only the roots still unsettled are evaluated (each row's value is its own: the same bits in any batch)."""
    lo, hi = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])
    a, b = np.full(start.size, lo), np.full(start.size, hi)
    t, root, todo = np.clip(start, lo, hi), np.full(start.size, math.nan), np.ones(start.size, bool)
    for _ in range(100):
        if not todo.any():
            break
        if todo.all():
            v, d = value_slope(t, None)
        else:
            i = np.flatnonzero(todo)
            v, d = np.full(t.size, math.nan), np.full(t.size, math.nan)
            v[i], d[i] = value_slope(t[i], i)
        todo &= np.isfinite(v)
        hit = todo & (v == 0.0)
        root[hit], todo = np.where((lo < t) & (t < hi), t, math.nan)[hit], todo & ~hit
        a, b = np.where(todo & (v > 0), t, a), np.where(todo & (v < 0), t, b)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.where(np.isfinite(d) & (d < 0), v / d, math.nan)
        new = t - step
        done = todo & (np.abs(step) <= 0.1 * math.sqrt(xtol) * (1.0 + np.abs(t)))
        root[done], todo = np.where((lo < new) & (new < hi), new, math.nan)[done], todo & ~done
        out = ~((a < new) & (new < b))
        new = np.where(out, 0.5 * (a + b), new)
        done = todo & out & (b - a <= xtol * (1.0 + np.abs(t)))
        root[done], todo = np.where((lo < a) & (b < hi), new, math.nan)[done], todo & ~done
        t = np.where(todo, new, t)
    return root


def _batch_covariance(mats, k: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """``life_effect``'s ``_covariance`` (the inverse observed information of (log scale_distance, log ratio,
    log shape)) of many looks at once; ``mats``: :func:`_by_look` per adjustment, ``scales``: (looks, 2)."""
    sigma = 1.0 / k
    sums = []
    for (lx, _, ff, mm), shift in zip(mats, (0.0, np.log(scales[:, 1] / scales[:, 0]))):
        z = np.where(mm, (lx - np.log(scales[:, :1]) - np.reshape(shift, (-1, 1))) / sigma[:, None], 0.0)
        w = np.where(mm, np.exp(z), 0.0)
        d = ff.astype(np.float64)
        wz = w * z
        sums.append((_row_sums(w), _row_sums(wz + w - d), _row_sums(wz * z + 2.0 * wz - 2.0 * d * z - d)))
    (w0, a0, b0), (w1, a1, b1) = sums
    info = np.stack([np.stack([w0 + w1, w1, a0 + a1], -1), np.stack([w1, w1, a1], -1),
                     np.stack([a0 + a1, a1, b0 + b1], -1)], -2) / (sigma ** 2)[:, None, None]
    good = np.isfinite(info).all(axis=(1, 2))
    info[~good] = np.eye(3)
    good &= np.linalg.eigvalsh(info).min(axis=1) > 0
    cov = np.full(info.shape, math.nan)
    if good.any():
        cov[good] = np.linalg.inv(info[good])
    j = (-1.0 / sigma)[:, None]            # d log(shape) / d sigma = -1 / sigma
    cov[:, 2, :] *= j
    cov[:, :, 2] *= j
    return cov


def _batch_fits(k: np.ndarray, mats, logs) -> list[CommonShapeFit]:
    """The fits at the solved shapes ``k`` [-]: each adjustment's scale, the log-likelihood (``life_effect``'s
    closed form) and the covariance of each look."""
    scales, loglik = [], np.zeros_like(k)
    for (_, xx, _, mm), (y, _, r, syf, ymax) in zip(mats, logs):
        s = np.where(mm, xx, -np.inf).max(axis=1)
        scales.append(s * (_row_sums(np.where(mm, (xx / s[:, None]) ** k[:, None], 0.0)) / r) ** (1.0 / k))
        log_sum = k * ymax + np.log(_row_sums(np.where(mm, np.exp(k[:, None] * y), 0.0)))
        loglik += r * np.log(k) - r * (log_sum - np.log(r)) + (k - 1.0) * (syf + r * ymax) - r
    scales = np.stack(scales, -1)
    cov = _batch_covariance(mats, k, scales)
    return [CommonShapeFit(float(k[i]), float(scales[i, 0]), float(scales[i, 1]), float(loglik[i]),
                           math.log(scales[i, 1] / scales[i, 0]), cov[i]) for i in range(k.size)]


def look_fits(life, failed, group, look, looks) -> list[CommonShapeFit]:
    """:func:`analyses.life_effect.common_shape_fit` of every look at once: the same estimates, one solve.

    Each look's common shape solves its own strictly decreasing score equation (the same
    function, so the same unique root to the solver's 1e-13) by Newton's method kept in a
    bracket, all looks together on padded (look, hose) matrices; scales, log-likelihood and
    observed information follow in closed form. A look with fewer than two failures in an
    adjustment, or whose solve does not settle inside the shape's search range, is fitted alone
    by :func:`~analyses.life_effect.common_shape_fit` (the same notes).

    Parameters
    ----------
    life, failed, group : array_like
        Lives [km], failure flags and adjustment (0 distance, 1 force) of every look's hoses.
    look : array_like of int
        Each row's look.
    looks : array_like of int
        The looks wanted (distinct), in the order returned.

    Returns
    -------
    list of CommonShapeFit
        One per ``looks``.
    """
    x, f, g, lk = (np.asarray(life, np.float64), np.asarray(failed, bool), np.asarray(group),
                   np.asarray(look, np.int64))
    wanted = np.asarray(looks, np.int64)
    mats = _look_matrices(x, f, g, lk, wanted)
    logs = []
    for lx, _, ff, mm in mats:
        ymax = np.where(mm, lx, -np.inf).max(axis=1)
        y = np.where(mm, lx - np.where(np.isfinite(ymax), ymax, 0.0)[:, None], 0.0)
        logs.append((y, mm, _row_sums(ff.astype(np.float64)), _row_sums(np.where(ff, y, 0.0)), ymax))
    batch = (logs[0][2] >= 2) & (logs[1][2] >= 2)
    root = np.full(wanted.size, math.nan)
    if batch.any():
        sub = [(y[batch], m[batch], r[batch], syf[batch]) for y, m, r, syf, _ in logs]
        root[batch] = _batch_newton(lambda t, i: _batch_score(t, _rows(sub, i)), np.zeros(int(batch.sum())))
    fits: list = [None] * wanted.size
    ok = np.flatnonzero(np.isfinite(root))
    if ok.size:
        solved = _batch_fits(np.exp(root[ok]), [tuple(a[ok] for a in m) for m in mats],
                             [tuple(a[ok] for a in lg) for lg in logs])
        for i, fit in zip(ok.tolist(), solved):
            fits[i] = fit
    for i in np.flatnonzero(~np.isfinite(root)).tolist():
        m = lk == wanted[i]
        fits[i] = common_shape_fit(x[m], f[m], g[m])
    return fits


def _signed_root(t: np.ndarray, pooled, ll: np.ndarray, centre: np.ndarray, logk: np.ndarray):
    """At trial log ratios ``t`` [-] (one a row), the signed root deviance, its slope in ``t`` and the profile's
    log shape; ``pooled``: (log lives, failed, present, force) padded matrices of each row's look."""
    lx, ff, mm, fm = pooled
    big = np.where(mm, lx - t[:, None] * fm, -np.inf)
    ymax = big.max(axis=1)
    y = np.where(mm, big - ymax[:, None], 0.0)
    r, rf = _row_sums(ff.astype(np.float64)), _row_sums((ff & fm).astype(np.float64))
    syf = _row_sums(np.where(ff, y, 0.0))
    logk = _batch_newton(lambda u, i: _batch_score(u, _rows([(y, mm, r, syf)], i)), logk)
    k = np.exp(logk)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        e = np.where(mm, np.exp(k[:, None] * y), 0.0)
        total = _row_sums(e)
        ell = r * logk - r * (k * ymax + np.log(total) - np.log(r)) + (k - 1.0) * (syf + r * ymax) - r - rf * t
        root = np.sqrt(np.maximum(2.0 * (ll - ell), 0.0))
        sign = np.sign(t - centre)
        slope = sign * 2.0 * k * (rf - r * _row_sums(np.where(fm, e, 0.0)) / total) / (2.0 * root)
    return sign * root, slope, logk


def _newton_ends(mats, fits: list[CommonShapeFit], z: np.ndarray) -> np.ndarray:
    """Both ends (rows: lower, upper; a column per look) of the looks' profile intervals at ``z``; NaN where
    an end did not settle within :data:`NEWTON_STEPS` (searched alone then)."""
    n = len(fits)
    rows, side = np.tile(np.arange(n), 2), np.repeat([-1.0, 1.0], n)
    (lxd, _, fd, md), (lxf, _, ff, mf) = [tuple(a[rows] for a in m) for m in mats]
    pooled = (np.concatenate([lxd, lxf], 1), np.concatenate([fd, ff], 1), np.concatenate([md, mf], 1),
              np.concatenate([np.zeros_like(md), mf], 1))
    centre = np.array([ft.log_ratio for ft in fits])[rows]
    ll, se = np.array([ft.loglik for ft in fits])[rows], np.array([ft.se_log_ratio for ft in fits])[rows]
    logk, target = np.log(np.array([ft.shape for ft in fits]))[rows], side * z[rows]
    edge = math.log(RATIO_SEARCH)
    a, b = np.where(side > 0, centre, centre - edge), np.where(side > 0, centre + edge, centre)
    t = np.clip(centre + target * np.where(np.isfinite(se), se, 0.1), a, b)   # the Wald end
    t = np.where(t == centre, centre + 0.5 * side, t)
    ends, todo = np.full(2 * n, math.nan), np.isfinite(t) & np.isfinite(ll) & np.isfinite(logk)
    for _ in range(NEWTON_STEPS):
        i = np.flatnonzero(todo)
        if not i.size:
            break
        s, slope, logk[i] = _signed_root(t[i], tuple(p[i] for p in pooled), ll[i], centre[i], logk[i])
        a[i], b[i] = np.where(s < target[i], t[i], a[i]), np.where(s > target[i], t[i], b[i])
        with np.errstate(invalid="ignore", divide="ignore"):
            new = t[i] - (s - target[i]) / slope
        inside = np.isfinite(new) & (a[i] < new) & (new < b[i])
        settled = inside & (np.abs(new - t[i]) <= 1e-10 * (1.0 + np.abs(t[i])))
        ends[i[settled]] = new[settled]
        todo[i[settled | ~np.isfinite(logk[i])]] = False
        t[i] = np.where(inside, new, 0.5 * (a[i] + b[i]))
    return ends.reshape(2, n)


def profile_rci(life, failed, group, look, looks, z, centre=None, deviance=ratio_deviance, fits=None):
    """Each look's repeated confidence interval of the log life ratio by the profile likelihood.

    ``{theta : D(theta) <= z_k^2}``, ``D`` the look's profile deviance of ``theta = log(force life /
    distance life)`` and ``z_k`` its boundary (Jennison & Turnbull 2000, ch. 9; module docstring).

    Parameters
    ----------
    life, failed, group, look : array_like
        As :func:`look_fits`: lives [km], failure flags, adjustment (0 distance, 1 force) and look of
        every (look, hose) row.
    looks : array_like of int
        The looks wanted (distinct), in the order returned.
    z : array_like
        Per wanted look the critical value on the normal scale [-] (the efficacy boundary ``c_k``).
    centre : array_like, optional
        Per wanted look the estimate of the model ``deviance`` belongs to [-]; read only for a model
        other than the common-shape Weibull's (whose own fits are solved here).
    deviance : callable, optional
        ``deviance(life, failed, group, ratio)``: the profile deviance of the life model
        (:func:`analyses.life_effect.ratio_deviance`, the common-shape Weibull's, by default and
        fast; any other, e.g. :func:`analyses.life_effect_lognormal.lognormal_ratio_deviance`, is
        searched look by look with :func:`analyses.service_life.lr_bound`).
    fits : list of CommonShapeFit, optional
        Per wanted look its :func:`look_fits` when the caller has them (the same fits: each look is
        solved alone, whatever the other looks), so that they are not solved again; read only with
        the common-shape Weibull's ``deviance``.

    Returns
    -------
    lower, upper : numpy.ndarray
        Per wanted look the interval's ends [-] (log scale); NaN where the look's fit cannot be
        made or the deviance stays below ``z_k^2`` up to :data:`analyses.life_effect.RATIO_SEARCH`
        times the estimate (the data do not bound that side).
    """
    x, f, g, lk = (np.asarray(life, np.float64), np.asarray(failed, bool), np.asarray(group),
                   np.asarray(look, np.int64))
    wanted, z = np.asarray(looks, np.int64), np.asarray(z, np.float64)
    ends = np.full((2, wanted.size), math.nan)
    mid = np.full(wanted.size, math.nan) if centre is None else np.asarray(centre, np.float64).copy()
    if deviance is ratio_deviance and wanted.size:
        fits = look_fits(x, f, g, lk, wanted) if fits is None else list(fits)
        good = np.array([ft.note is None and math.isfinite(ft.loglik) for ft in fits]) & np.isfinite(z) & (z > 0)
        mid = np.array([ft.log_ratio if ok else math.nan for ft, ok in zip(fits, good)])
        if good.any():
            mats = [tuple(a[good] for a in m) for m in _look_matrices(x, f, g, lk, wanted)]
            ends[:, good] = _newton_ends(mats, [ft for ft, ok in zip(fits, good) if ok], z[good])
    edge = math.log(RATIO_SEARCH)
    for side, j in np.argwhere(np.isnan(ends) & np.isfinite(mid) & np.isfinite(z) & (z > 0)).tolist():
        m, crit = lk == wanted[j], float(z[j]) ** 2
        ends[side, j] = lr_bound(lambda t: deviance(x[m], f[m], g[m], math.exp(t)) - crit, float(mid[j]),
                                 float(mid[j]) + (2 * side - 1) * edge)
    return ends[0], ends[1]
