"""The decision stage's rule on many simulated looks at once: the refitted Wald crossing and its likelihood check.

The decision stage declares a verdict at a look only when the common-shape Weibull refitted to the look's
data crosses a boundary on the Wald scale AND its profile likelihood agrees
(:func:`analyses.decision.likelihood_check`, :func:`analyses.decision.crossing_holds`: the profile
deviance :func:`analyses.life_effect.ratio_deviance` above ``c^2`` at ratio 1 for a longer life, at both
margins for ``no practical difference``; Meeker & Escobar 1998, sec. 8.3). The test plan's forward
figures (:mod:`analyses.test_plan`) simulate the test's future from the fitted model; to be calibrated
against the stage they must read each simulated look by the same rule, on the simulated lives.

This module does that for a batch of simulated looks (one row each: the hoses' distances and whether each
failed, a mask of the hoses on test) in one vectorised pass: the common-shape MLE by Newton's method in
``log k`` kept in a bracket (the score of :func:`analyses.life_effect.common_shape_fit` with each scale
profiled out, the same root), the observed-information standard error of the log ratio (the
smallest-extreme-value regression's Hessian, Meeker & Escobar 1998, sec. 17.3 and appendix B) and the
profile deviance at the trial ratios (the pooled one-group fit of the lives with the force-set ones
divided by the ratio). The same numbers as the scalar functions to ~1e-8 (tested), 30-40 times
cheaper per look in a batch of hundreds.

:func:`first_decision` reads a simulated future look by look: a cheap screen (the shape-known estimate at
the current fitted shape, a closed form in the failures and the sums of ``x^k``) picks the replicates
whose look may cross (once a replicate was refitted, the screen is corrected by that refit), and only
those are refitted and checked; a replicate stops at its first confirmed look. Looks are screened in blocks
of :data:`LOOK_BLOCK` whose refits are one batch (session 22: a batch's fixed cost is most of a look's). The
screen's slack
(:data:`SCREEN`, :data:`SCREEN_REFITTED`) is measured: ``benchmarks/bench_test_plan_forward.py`` (d)
counts the replicates whose first deciding look differs from reading every look in full.

References
----------
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical Trials.
Chapman & Hall/CRC (ch. 10: conditional power by simulation of the future).
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley (sec. 4.6, 8.3, 17.3).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analyses.service_life import SHAPE_BOUNDS

#: A look is refitted when the shape-known estimate crosses a boundary scaled by this factor [-]:
#: the refitted estimate's standard error (shape unknown) is wider than the screen's, so the screen misses
#: nothing it should find when it is looser than 1 (measured: benchmarks/bench_test_plan_forward.py).
SCREEN = 0.75

#: The same for a replicate refitted at an earlier look [-]: its screen is corrected by that refit (the
#: refit's estimate minus the screen's, the ratio of their standard errors), which one more failure
#: changes little, so a tighter factor finds the same looks with fewer refits (measured as SCREEN).
SCREEN_REFITTED = 0.85

#: Looks screened together [-]: their refits are one batch (one call of :func:`decides` for ``block`` looks:
#: the calls' fixed cost is most of a look's), each look screened with the corrections of the refits before
#: the block; a replicate that decides at a look of the block is refitted at its later looks too (unused).
LOOK_BLOCK = 4

_LO, _HI = math.log(SHAPE_BOUNDS[0]), math.log(SHAPE_BOUNDS[1])


@dataclass(frozen=True)
class Future:
    """A simulated future of one hose type's test, ``n`` replicates of ``H`` hoses.

    Attributes
    ----------
    base : numpy.ndarray, shape (H,)
        Each hose's distance when it goes on test [km] (a running hose's distance now, 0 for a new one).
    start, end : numpy.ndarray, shape (n, H)
        When it goes on test and when it fails, on the clock of the looks [km of testing from now].
    group : numpy.ndarray of int, shape (H,)
        1 force-set, 0 distance-set.
    """

    base: np.ndarray
    start: np.ndarray
    end: np.ndarray
    group: np.ndarray


@dataclass(frozen=True)
class Past:
    """The hoses whose lives are known and fixed (failed or removed): log distance [log km], failed, group."""

    logx: np.ndarray
    failed: np.ndarray
    group: np.ndarray


def _prep(logx, d, on):
    """Per row of one group: (log lives minus the row's largest, on-test mask, failures, their sum of those, largest)."""
    ymax = np.where(on, logx, -np.inf).max(axis=1)
    ymax = np.where(np.isfinite(ymax), ymax, 0.0)
    y = np.where(on, logx - ymax[:, None], 0.0)
    d = d & on
    return y, on, d.sum(axis=1).astype(float), (y * d).sum(axis=1), ymax


def _masked_exp(k, y, on):
    """``exp(k y)`` per row's ``k`` where ``on``, else 0 (``y`` is 0 there, so nothing overflows), in one buffer."""
    w = k[:, None] * y
    np.exp(w, out=w)
    w *= on
    return w


def _value_slope(t, groups):
    """The shape score with the scales profiled and its derivative in ``log k``, per row."""
    k = np.exp(t)
    value, slope = np.zeros_like(t), np.zeros_like(t)
    for y, on, r, syf, _ in groups:
        w = _masked_exp(k, y, on)
        sw = w.sum(axis=1)
        w *= y                              # w y
        mean = w.sum(axis=1) / sw
        w *= y                              # w y^2
        var = np.maximum(w.sum(axis=1) / sw - mean ** 2, 0.0)
        value += r / k + syf - r * mean
        slope -= r / k + k * r * var
    return value, slope


def _shape_mle(groups, start: float):
    """(log shape per row, whether it settled strictly inside SHAPE_BOUNDS): bracketed Newton steps
    (:func:`analyses.service_life.newton_root` row by row: a step leaving the bracket is a bisection), each
    row iterated until its step is below 1e-8 (relative; the error after it is of the order of its square)."""
    n = groups[0][2].size
    a, b, t = np.full(n, _LO), np.full(n, _HI), np.clip(np.broadcast_to(np.asarray(start, float), n), _LO, _HI)
    live = np.arange(n)
    for _ in range(100):
        sub = groups if live.size == n else [tuple(v[live] for v in grp) for grp in groups]
        v, s = _value_slope(t[live], sub)
        a[live], b[live] = np.where(v > 0, t[live], a[live]), np.where(v < 0, t[live], b[live])
        with np.errstate(divide="ignore", invalid="ignore"):
            step = -v / s
        nxt = t[live] + step
        done = np.isfinite(step) & (np.abs(step) < 1e-8 * (1.0 + np.abs(t[live])))
        bad = ~done & (~np.isfinite(nxt) | (nxt <= a[live]) | (nxt >= b[live]))
        t[live] = np.where(bad, 0.5 * (a[live] + b[live]), nxt)
        live = live[~done]
        if live.size == 0:
            break
    return t, np.isfinite(t) & (t > _LO + 1e-6) & (t < _HI - 1e-6)


def _power_sums(k, groups) -> list:
    """Per group, each row's sum of ``exp(k y)`` over its hoses on test (``x^k`` relative to the largest)."""
    return [_masked_exp(k, y, on).sum(axis=1) for y, on, *_ in groups]


def _loglik(k, groups, sums=None):
    """Log-likelihood at shape ``k`` with each group's scale at its MLE (closed form), per row (``sums``:
    :func:`_power_sums` at ``k``, when computed already)."""
    total = np.zeros_like(k)
    for (y, on, r, syf, ymax), sw in zip(groups, _power_sums(k, groups) if sums is None else sums):
        log_sum = k * ymax + np.log(sw)
        total += r * np.log(k) - r * (log_sum - np.log(r)) + (k - 1.0) * (syf + r * ymax) - r
    return total


@dataclass(frozen=True)
class BatchFit:
    """The common-shape fit of each row (:func:`batch_fit`): shape, log-likelihood, log ratio and its
    standard error [-]; ``ok`` False where :func:`analyses.life_effect.common_shape_fit` has a note
    (fewer than two failures in an adjustment, the shape at a search bound, no positive information)."""

    shape: np.ndarray
    loglik: np.ndarray
    log_ratio: np.ndarray
    se: np.ndarray
    ok: np.ndarray


def _se_log_ratio(logx, d, on, group, k, log_scale):
    """Observed-information standard error of the log ratio (the 3 x 3 Hessian of
    :func:`analyses.life_effect._covariance`, its (1, 1) cofactor), NaN where not positive definite."""
    sums = []
    for g in (0, 1):
        m = on[:, group == g]
        z = np.where(m, k[:, None] * (logx[:, group == g] - log_scale[g][:, None]), 0.0)
        w = np.where(m, np.exp(z), 0.0)
        f = (d[:, group == g] & m).astype(float)
        sums.append(((w).sum(axis=1), (w * z + w - f).sum(axis=1), (w * z * z + 2.0 * w * z - 2.0 * f * z - f).sum(axis=1)))
    (w0, a0, b0), (w1, a1, b1) = sums
    m00, m01, m02, m11, m12, m22 = w0 + w1, w1, a0 + a1, w1, a1, b0 + b1
    det = m00 * (m11 * m22 - m12 ** 2) - m01 * (m01 * m22 - m12 * m02) + m02 * (m01 * m12 - m11 * m02)
    pd_ = (m00 > 0) & (m00 * m11 - m01 ** 2 > 0) & (det > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        var = (m00 * m22 - m02 ** 2) / det / k ** 2
    return np.where(pd_ & (var > 0), np.sqrt(np.abs(var)), np.nan)


def batch_fit(logx, failed, on, group, shape_start: float = 1.0) -> BatchFit:
    """:func:`analyses.life_effect.common_shape_fit` of every row at once.

    Parameters
    ----------
    logx : numpy.ndarray, shape (B, H)
        Log lives [log km] (failure or censoring distance) where ``on``.
    failed, on : numpy.ndarray of bool, shape (B, H)
        Failure; the hose is in the row's data.
    group : numpy.ndarray of int, shape (H,)
        1 force-set, 0 distance-set.
    shape_start : float or numpy.ndarray
        Shape the Newton steps start from [-], one or per row (the same root from any start).

    Returns
    -------
    BatchFit
    """
    groups = [_prep(logx[:, group == g], failed[:, group == g], on[:, group == g]) for g in (0, 1)]
    t, inside = _shape_mle(groups, np.log(shape_start))
    k = np.exp(t)
    enough = (groups[0][2] >= 2) & (groups[1][2] >= 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        sums = _power_sums(k, groups)     # the scales' and the log-likelihood's, computed once
        log_scale = [ymax + np.log(sw / r) / k for (_, _, r, _, ymax), sw in zip(groups, sums)]
        se = _se_log_ratio(logx, failed, on, group, k, log_scale)
        ll = _loglik(k, groups, sums)
    ok = enough & inside & np.isfinite(se)
    return BatchFit(k, ll, log_scale[1] - log_scale[0], se, ok)


def batch_deviance(logx, failed, on, group, fit: BatchFit, ratio) -> np.ndarray:
    """:func:`analyses.life_effect.ratio_deviance` (common shape) of every row at the trial ``ratio`` [-]
    (one, or one per row).

    The force-set lives divided by ``ratio`` and pooled into one Weibull (the profile over the shape and
    the distance-set scale at that ratio; Newton's steps from each row's fitted shape), minus the force-set
    failures times ``log ratio``; NaN where ``fit`` is not ok.
    """
    theta = np.broadcast_to(np.log(np.asarray(ratio, float)), fit.ok.shape)
    pooled = [_prep(logx - theta[:, None] * (group == 1), failed, on)]
    with np.errstate(divide="ignore", invalid="ignore"):
        start = np.where(np.isfinite(fit.shape) & (fit.shape > 0), np.log(fit.shape), 0.0)
    t, inside = _shape_mle(pooled, start)
    with np.errstate(divide="ignore", invalid="ignore"):
        profile = _loglik(np.exp(t), pooled) - (failed & on & (group == 1)).sum(axis=1) * theta
    return np.where(fit.ok & inside, np.maximum(0.0, 2.0 * (fit.loglik - profile)), np.nan)


def decides(logx, failed, on, group, c, margin: float, shape_start=1.0) -> tuple[np.ndarray, BatchFit]:
    """Whether each row's look decides as the decision stage declares it: the refitted Wald crossing at
    the boundary ``c`` (per row [-]) confirmed by the profile likelihood (module docstring); the deviances
    of every crossing row and trial ratio in one batch.

    Returns
    -------
    numpy.ndarray of bool, shape (B,)
        Whether the row's look decides.
    BatchFit
        The rows' refits (:func:`batch_fit`).
    """
    fit = batch_fit(logx, failed, on, group, shape_start)
    c = np.broadcast_to(np.asarray(c, float), fit.ok.shape)
    lm = math.log(max(margin, 1.0 / margin))
    half = c * fit.se
    with np.errstate(invalid="ignore"):
        longer = fit.ok & (np.abs(fit.log_ratio) > half)
        npd = fit.ok & ~longer & (np.abs(fit.log_ratio) + half < lm)
    out = np.zeros(fit.ok.shape, bool)
    one, both = np.flatnonzero(longer), np.flatnonzero(npd)
    rows = np.concatenate([one, both, both])
    if rows.size == 0:
        return out, fit
    ratio = np.concatenate([np.ones(one.size), np.full(both.size, margin), np.full(both.size, 1.0 / margin)])
    sub = BatchFit(*(getattr(fit, f)[rows] for f in ("shape", "loglik", "log_ratio", "se", "ok")))
    holds = batch_deviance(logx[rows], failed[rows], on[rows], group, sub, ratio) > c[rows] ** 2
    out[one] = holds[:one.size]
    out[both] = holds[one.size:one.size + both.size] & holds[one.size + both.size:]
    return out, fit


def _look(fut: Future, rows, at, first_start=None):
    """(log x, failed, on, columns) of the future's hoses for the replicates ``rows`` at ``at`` [km of testing
    from now]: the hoses on test then, in the columns (of ``fut``) of the hoses on test in at least one of the
    rows; the other columns would add nothing to any sum (a hose not yet on a bench is in no row's data).
    ``first_start``: each column's earliest start over the replicates [km], to compare only the columns that
    may be on test (a bench's later hoses are most of the columns and on test in no row for most looks)."""
    may = np.arange(fut.start.shape[1]) if first_start is None else np.flatnonzero(first_start < at.max())
    at = at[:, None]
    on = fut.start[np.ix_(rows, may)] < at
    keep = on.any(axis=0)
    on, cols = on[:, keep], may[keep]
    start, end = fut.start[np.ix_(rows, cols)], fut.end[np.ix_(rows, cols)]
    x = fut.base[cols] + np.minimum(end, at) - start
    return np.log(np.where(on, x, 1.0)), on & (end <= at), on, cols


def _with_past(past: Past, logx, failed, on):
    """The rows' look with the past hoses' columns in front."""
    n = logx.shape[0]
    return (np.concatenate([np.broadcast_to(past.logx, (n, past.logx.size)), logx], axis=1),
            np.concatenate([np.broadcast_to(past.failed, (n, past.failed.size)), failed], axis=1),
            np.concatenate([np.ones((n, past.logx.size), bool), on], axis=1))


def first_decision(past: Past, fut: Future, times, c, margin: float, shape: float,
                   screen: tuple[float, float] = (SCREEN, SCREEN_REFITTED), block: int = LOOK_BLOCK) -> np.ndarray:
    """The first simulated look that the decision stage would declare, per replicate (-1: none).

    Parameters
    ----------
    past : Past
        The hoses that no longer run.
    fut : Future
        The simulated future.
    times : numpy.ndarray, shape (n, looks)
        Each replicate's looks: the failures' times on the future's clock [km], sorted.
    c : array_like, shape (looks,) or (n, looks)
        The design's boundary of each look [-], or each replicate's (the replicates of designs with fewer
        looks padded with ``inf``: their looks end there, so that several designs share one pass).
    margin : float
        The design's margin [-].
    shape : float
        The fitted shape now [-]: the screen's known shape and the refits' start.
    screen : (float, float)
        Slack of the screen before a replicate's first refit and after it (:data:`SCREEN`,
        :data:`SCREEN_REFITTED`; ``(0, 0)`` reads every look in full).
    block : int
        Looks screened and refitted together (:data:`LOOK_BLOCK`; 1: look by look, each screen corrected by
        the refit just before) [-].

    Returns
    -------
    numpy.ndarray of int, shape (n,)
    """
    n, looks = times.shape
    c = np.asarray(c, float)
    c = np.broadcast_to(c, (n, looks)) if c.ndim == 1 else c
    last = np.isfinite(c).sum(axis=1)     # each replicate's looks
    first_start = fut.start.min(axis=0) if n else None
    lm = math.log(max(margin, 1.0 / margin))
    past_sum = [float(np.exp(shape * past.logx[past.group == g]).sum()) for g in (0, 1)]
    past_d = [int((past.failed & (past.group == g)).sum()) for g in (0, 1)]
    first = np.full(n, -1)
    offset, ratio, start = np.zeros(n), np.ones(n), np.full(n, float(shape))    # from each replicate's last refit
    refitted = np.zeros(n, bool)
    for j0 in range(0, looks, block):
        if not ((first < 0) & (last > j0)).any():
            break
        screened = []           # per look of the block: (look, its rows refitted, their screen's raw estimate, se)
        for j in range(j0, min(j0 + block, looks)):
            rows = np.flatnonzero((first < 0) & (last > j))
            if rows.size == 0:
                break
            logx, failed, on, cols = _look(fut, rows, times[rows, j], first_start)
            group = fut.group[cols]
            powered = np.where(on, np.exp(shape * logx), 0.0)
            d = [past_d[g] + failed[:, group == g].sum(axis=1) for g in (0, 1)]
            s = [past_sum[g] + powered[:, group == g].sum(axis=1) for g in (0, 1)]
            with np.errstate(divide="ignore", invalid="ignore"):
                se = np.sqrt(1.0 / d[0] + 1.0 / d[1]) / shape
                raw = (np.log(s[1] / d[1]) - np.log(s[0] / d[0])) / shape
                est = raw + offset[rows]
                half = np.where(refitted[rows], screen[1], screen[0]) * c[rows, j] * se * ratio[rows]
                maybe = (d[0] >= 2) & (d[1] >= 2) & ((np.abs(est) > half) | (np.abs(est) + half < lm))
            idx = np.flatnonzero(maybe)
            if idx.size:
                screened.append((j, rows[idx], raw[idx], se[idx], cols[on[idx].any(axis=0)]))
        if not screened:
            continue
        mine = np.unique(np.concatenate([x[4] for x in screened]))     # the hoses on test in the rows refitted
        at_rows = np.concatenate([x[1] for x in screened])
        at = np.concatenate([times[x[1], x[0]] for x in screened])[:, None]
        start_, end_ = fut.start[np.ix_(at_rows, mine)], fut.end[np.ix_(at_rows, mine)]
        on = start_ < at
        logx = np.log(np.where(on, fut.base[mine] + np.minimum(end_, at) - start_, 1.0))
        yes, fit = decides(*_with_past(past, logx, on & (end_ <= at), on), np.concatenate([past.group, fut.group[mine]]),
                           np.concatenate([c[x[1], x[0]] for x in screened]), margin, start[at_rows])
        k = 0
        for j, r, raw, se, _ in screened:         # in look order: a replicate's first deciding look is kept,
            y, f = yes[k:k + r.size], slice(k, k + r.size)      # its latest refit corrects its screen
            first[r[y & (first[r] < 0)]] = j
            ok = fit.ok[f]
            offset[r[ok]] = fit.log_ratio[f][ok] - raw[ok]
            ratio[r[ok]] = fit.se[f][ok] / se[ok]
            start[r[ok]], refitted[r[ok]] = fit.shape[f][ok], True
            k += r.size
    return first


__all__ = ["SCREEN", "SCREEN_REFITTED", "LOOK_BLOCK", "Future", "Past", "BatchFit", "batch_fit", "batch_deviance", "decides", "first_decision"]
