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

:func:`first_decision` reads a simulated future: a cheap screen (the shape-known estimate at the current
fitted shape, a closed form in the failures and the sums of ``x^k``), computed for every look of every
replicate at once, picks the looks that may cross (once a replicate was refitted, its screen is corrected by
that refit), and only those are refitted and checked, the next ones of every replicate in one batch a round
(session 23: :data:`LOOK_BLOCK`); a replicate stops at its first confirmed look. The screen's slack
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

#: Screened looks a replicate has refitted in the first round [-], doubled each round after (session 23):
#: every replicate's next screened looks are refitted in one call of :func:`decides` a round (a call's fixed
#: cost was most of a look's); a refit after the replicate's decision is unused, so the first round takes one.
LOOK_BLOCK = 1

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
    benches : int
        0: each column is one hose, on test from its ``start`` until its ``end``; ``B`` > 0: the columns are ``B``
        benches' successive hoses, column ``i B + b`` bench ``b``'s ``(i + 1)``-th (started when the ``i``-th
        fails; the same group as column ``b``) [-]. Either way at most one hose of a column chain runs at a time.
    """

    base: np.ndarray
    start: np.ndarray
    end: np.ndarray
    group: np.ndarray
    benches: int = 0


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
    row iterated until its step is below 1e-6 (relative; the step is taken, and the error after it is of the
    order of its square, 1e-12)."""
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
        done = np.isfinite(step) & (np.abs(step) < 1e-6 * (1.0 + np.abs(t[live])))
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


def _moments(k, groups) -> list:
    """Per group, each row's ``(M0, M1, M2)``: the sums of ``exp(k y)``, ``y exp(k y)`` and ``y^2 exp(k y)`` over
    its hoses on test (``y`` the log lives relative to the row's largest), in one pass."""
    out = []
    for y, on, *_ in groups:
        w = _masked_exp(k, y, on)
        m0 = w.sum(axis=1)
        w *= y
        m1 = w.sum(axis=1)
        w *= y
        out.append((m0, m1, w.sum(axis=1)))
    return out


def _se_log_ratio(k, groups, moments):
    """Observed-information standard error of the log ratio (the 3 x 3 Hessian of
    :func:`analyses.life_effect._covariance`, its (1, 1) cofactor), NaN where not positive definite; its sums
    from each group's moments at the fitted shape (:func:`_moments`): with ``z = k (log x - log scale)`` and
    ``w = exp(z)`` at the group's scale MLE, ``sum w = r``, ``sum w z = r (k m - L)``,
    ``sum w z^2 = r (k^2 v + (k m - L)^2)`` (``m``, ``v`` the ``exp(k y)``-weighted mean and variance of ``y``,
    ``L = log(M0 / r)``) and ``sum_failed z = k sum_failed y - r L``."""
    sums = []
    for (_, _, r, syf, _), (m0, m1, m2) in zip(groups, moments):
        mean = m1 / m0
        var = np.maximum(m2 / m0 - mean ** 2, 0.0)
        ell = np.log(m0 / r)
        wz = r * (k * mean - ell)
        wzz = r * (k ** 2 * var + (k * mean - ell) ** 2)
        fz = k * syf - r * ell
        sums.append((r, wz, wzz + 2.0 * wz - 2.0 * fz - r))
    (w0, a0, b0), (w1, a1, b1) = sums
    m00, m01, m02, m11, m12, m22 = w0 + w1, w1, a0 + a1, w1, a1, b0 + b1
    det = m00 * (m11 * m22 - m12 ** 2) - m01 * (m01 * m22 - m12 * m02) + m02 * (m01 * m12 - m11 * m02)
    pd_ = (m00 > 0) & (m00 * m11 - m01 ** 2 > 0) & (det > 0)
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
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        moments = _moments(k, groups)     # the scales', the standard error's and the log-likelihood's, one pass
        log_scale = [ymax + np.log(m[0] / r) / k for (_, _, r, _, ymax), m in zip(groups, moments)]
        se = _se_log_ratio(k, groups, moments)
        ll = _loglik(k, groups, [m[0] for m in moments])
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


def decides(logx, failed, on, group, c, margin: float, shape_start=1.0, rows=None) -> tuple[np.ndarray, BatchFit]:
    """Whether each row's look decides as the decision stage declares it: the refitted Wald crossing at
    the boundary ``c`` (per row [-]) confirmed by the profile likelihood (module docstring); the deviances
    of every crossing row and trial ratio in one batch.

    ``rows`` (optional, int array): the data row of each look to decide, when several looks share their data
    (the same replicate read at several designs' boundaries, ``c`` one per entry of ``rows``): each data row
    is refitted once, and its deviance at a trial ratio computed once.

    Returns
    -------
    numpy.ndarray of bool, shape (B,) (or that of ``rows``)
        Whether the row's look decides.
    BatchFit
        The data rows' refits (:func:`batch_fit`).
    """
    fit = batch_fit(logx, failed, on, group, shape_start)
    rows = np.arange(fit.ok.size) if rows is None else np.asarray(rows, int)
    c = np.broadcast_to(np.asarray(c, float), rows.shape)
    lm = math.log(max(margin, 1.0 / margin))
    lr, ok = fit.log_ratio[rows], fit.ok[rows]
    half = c * fit.se[rows]
    with np.errstate(invalid="ignore"):
        longer = ok & (np.abs(lr) > half)
        npd = ok & ~longer & (np.abs(lr) + half < lm)
    out = np.zeros(rows.shape, bool)
    one, both = np.unique(rows[longer]), np.unique(rows[npd])
    idx = np.concatenate([one, both, both])
    if idx.size == 0:
        return out, fit
    ratio = np.concatenate([np.ones(one.size), np.full(both.size, margin), np.full(both.size, 1.0 / margin)])
    sub = BatchFit(*(getattr(fit, f)[idx] for f in ("shape", "loglik", "log_ratio", "se", "ok")))
    dev = batch_deviance(logx[idx], failed[idx], on[idx], group, sub, ratio)
    at_one, at_hi, at_lo = (np.full(fit.ok.size, np.nan) for _ in range(3))
    at_one[one], at_hi[both], at_lo[both] = dev[:one.size], dev[one.size:one.size + both.size], dev[one.size + both.size:]
    with np.errstate(invalid="ignore"):
        out[longer] = at_one[rows[longer]] > c[longer] ** 2
        out[npd] = (at_hi[rows[npd]] > c[npd] ** 2) & (at_lo[rows[npd]] > c[npd] ** 2)
    return out, fit


def _failures(fut: Future, times: np.ndarray, shape: float):
    """Each replicate's failures in look order: (column failing at each look, shape (n, looks); its life
    [km]; its ``life^shape``). ``times`` must be the future's first failures (its ends, sorted)."""
    n, looks = times.shape
    end = fut.end
    if end.shape[1] > 2 * looks:       # only the first ``looks`` ends matter: partition, then sort those
        part = np.argpartition(end, looks - 1, axis=1)[:, :looks]
        col = np.take_along_axis(part, np.argsort(np.take_along_axis(end, part, axis=1), axis=1, kind="stable"), axis=1)
    else:
        col = np.argsort(end, axis=1, kind="stable")[:, :looks]
    ends = np.take_along_axis(end, col, axis=1)
    if not np.array_equal(ends, times):
        raise ValueError("times must be each replicate's first failures (the future's ends, sorted)")
    life = fut.base[col] + ends - np.take_along_axis(fut.start, col, axis=1)
    return col, life, np.exp(shape * np.log(life))


def _running(fut: Future, times: np.ndarray, col: np.ndarray, shape: float):
    """The hoses on test and not failed at each look, one per bench: (distance [km] (n, looks, benches), on
    test, its ``distance^shape`` (0 where not on test)). A bench's current hose is its first not failed by
    the look (:attr:`Future.benches`); it is on test once started (a replacement starts at the failure)."""
    n, looks = times.shape
    H = fut.start.shape[1]
    S = fut.benches or H
    per = H // S
    if per == 1:        # one hose a column: running until the look it fails at
        at = np.full((n, S), looks)
        np.put_along_axis(at, col, np.broadcast_to(np.arange(looks), (n, looks)), axis=1)
        done = np.arange(looks)[None, :, None] >= at[:, None, :]
        st = np.broadcast_to(fut.start[:, None, :], (n, looks, S))
        on = ~done & (st < times[:, :, None])
        x = np.where(on, fut.base + times[:, :, None] - st, 1.0)
    else:
        hit = np.zeros((n, looks, S), np.int32)
        np.put_along_axis(hit, (col % S)[:, :, None], 1, axis=2)
        done = np.cumsum(hit, axis=1)                      # the bench's failures up to and with the look
        valid = done < per
        cur = np.where(valid, done * S + np.arange(S), 0)
        st = np.take_along_axis(fut.start, cur.reshape(n, looks * S), axis=1).reshape(n, looks, S)
        on = valid & (st < times[:, :, None])
        x = np.where(on, fut.base[cur] + times[:, :, None] - st, 1.0)
    powered = np.exp(shape * np.log(x))
    powered *= on
    return x, on, powered, done


def first_decision(past: Past, fut: Future, times, c, margin: float, shape: float,
                   screen: tuple[float, float] = (SCREEN, SCREEN_REFITTED), block: int = LOOK_BLOCK) -> np.ndarray:
    """The first simulated look that the decision stage would declare, per replicate (-1: none).

    Every look of every replicate is screened at once (the failures' and the running hoses' sums of
    ``x^shape``, per adjustment); then, round by round, each replicate's next screened looks (``block`` in the
    first round, twice as many each round after) are refitted in ONE :func:`decides` call for all replicates,
    and read in look order: the first refit that decides is the replicate's decision; a refit that does not
    corrects the replicate's screen of its later looks (the refit's estimate minus the screen's, the ratio of
    their standard errors), and a replicate whose corrected screen passes a look before its next refitted one
    goes back to that look in the next round (its later refits of the round unused). So each look is screened
    with the correction of the latest refit before it, as when the looks are read one by one.

    Parameters
    ----------
    past : Past
        The hoses that no longer run.
    fut : Future
        The simulated future.
    times : numpy.ndarray, shape (n, looks)
        Each replicate's looks: its first ``looks`` failures' times on the future's clock [km], sorted (the
        future's ends; checked).
    c : array_like, shape (looks,), (n, looks) or (copies n, looks)
        The design's boundary of each look [-], or each replicate's, or each replicate's in each of ``copies``
        designs read on the same replicates (rows ``a n + i``: replicate ``i`` at design ``a``; the designs
        with fewer looks padded with ``inf``: their looks end there); a (replicate, look) read by several
        copies is refitted once.
    margin : float
        The design's margin [-].
    shape : float
        The fitted shape now [-]: the screen's known shape and the refits' start.
    screen : (float, float)
        Slack of the screen before a replicate's first refit and after it (:data:`SCREEN`,
        :data:`SCREEN_REFITTED`; ``(0, 0)`` reads every look in full).
    block : int
        Screened looks per replicate refitted in the first round (:data:`LOOK_BLOCK`), doubled each round [-].

    Returns
    -------
    numpy.ndarray of int, shape (n,) or (copies n,)
    """
    times = np.asarray(times, float)
    n0, looks = times.shape
    c = np.asarray(c, float)
    c = np.broadcast_to(c, (n0, looks)) if c.ndim == 1 else c
    n = c.shape[0]                         # copies of the replicates, each read at its own boundaries
    if n0 == 0 or n % n0:
        raise ValueError("c must have one row per replicate, or per replicate of each copy")
    first = np.full(n, -1)
    if looks == 0:
        return first
    last = np.isfinite(c).sum(axis=1)     # each replicate's looks
    lm = math.log(max(margin, 1.0 / margin))
    col, life, pw_f = _failures(fut, times, shape)
    x_run, on_run, pw_r, done = _running(fut, times, col, shape)
    single = fut.benches == 0 or fut.start.shape[1] == fut.benches     # one hose a column: its life or its run
    if single:
        life_col = fut.base + fut.end - fut.start
    g_f = fut.group[col]
    S = on_run.shape[2]
    g_run = fut.group[:S]
    d, s, mine = [], [], []
    for g in (0, 1):
        here = g_f == g
        d.append(int((past.failed & (past.group == g)).sum()) + np.cumsum(here, axis=1))
        s.append(float(np.exp(shape * past.logx[past.group == g]).sum()) + np.cumsum(np.where(here, pw_f, 0.0), axis=1)
                 + pw_r[:, :, g_run == g].sum(axis=2))
        # the group's failed lives in look order, compacted to the left (a refit's columns)
        order = np.argsort(~here, axis=1, kind="stable")
        mine.append(np.log(np.take_along_axis(life, order, axis=1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(1.0 / d[0] + 1.0 / d[1]) / shape
        raw = (np.log(s[1] / d[1]) - np.log(s[0] / d[0])) / shape
    enough = (d[0] >= 2) & (d[1] >= 2)
    offset, ratio, start = np.zeros(n), np.ones(n), np.full(n, float(shape))    # from each replicate's last refit
    slack = np.full(n, float(screen[0]))
    nxt = np.zeros(n, int)                 # each replicate's first look not read yet
    alive = nxt < last
    jj = np.arange(looks)
    past_d = [int((past.failed & (past.group == g)).sum()) for g in (0, 1)]
    run_cols = [np.flatnonzero(g_run == g) for g in (0, 1)]

    def passes(rows):
        b = rows % n0
        est = raw[b] + offset[rows, None]
        half = slack[rows, None] * c[rows] * se[b] * ratio[rows, None]
        with np.errstate(invalid="ignore"):
            return enough[b] & (jj < last[rows, None]) & ((np.abs(est) > half) | (np.abs(est) + half < lm))

    k_round = max(1, int(block))
    while alive.any():
        rows = np.flatnonzero(alive)
        m = passes(rows) & (jj >= nxt[rows, None])
        rank = np.cumsum(m, axis=1)
        pick = m & (rank <= k_round)
        none = ~m.any(axis=1)
        alive[rows[none]] = False
        pr, pj = np.nonzero(pick)
        if pr.size == 0:
            break
        kth = rank[pr, pj] - 1
        pr = rows[pr]
        # each (replicate, look) refitted once, whatever copies read it
        key, once, inv = np.unique((pr % n0) * looks + pj, return_index=True, return_inverse=True)
        ur, uj = key // looks, key % looks
        # the refits' data: past | per adjustment its failed lives so far, then its benches' running hoses
        blocks_x, blocks_f, blocks_on, groups = [np.broadcast_to(past.logx, (ur.size, past.logx.size))], \
            [np.broadcast_to(past.failed, (ur.size, past.logx.size))], [np.ones((ur.size, past.logx.size), bool)], \
            [past.group]
        for g in (0, 1):
            cols = run_cols[g]
            if single:      # each column failed (its life) or running (its distance at the look)
                gone = done[ur, uj][:, cols] > 0
                blocks_x += [np.log(np.where(gone, life_col[ur][:, cols], x_run[ur, uj][:, cols]))]
                blocks_f += [gone]
                blocks_on += [gone | on_run[ur, uj][:, cols]]
                groups += [np.full(cols.size, g)]
                continue
            count = d[g][ur, uj] - past_d[g]
            w = int(count.max()) if count.size else 0
            on_f = np.arange(w) < count[:, None]
            blocks_x += [np.where(on_f, mine[g][ur, :w], 0.0), np.log(x_run[ur, uj][:, cols])]
            blocks_f += [on_f, np.zeros((ur.size, cols.size), bool)]
            blocks_on += [on_f, on_run[ur, uj][:, cols]]
            groups += [np.full(w + cols.size, g)]
        yes, fit = decides(np.concatenate(blocks_x, axis=1), np.concatenate(blocks_f, axis=1),
                           np.concatenate(blocks_on, axis=1), np.concatenate(groups), c[pr, pj], margin,
                           start[pr[once]], rows=inv)
        fit = BatchFit(*(getattr(fit, f)[inv] for f in ("shape", "loglik", "log_ratio", "se", "ok")))
        going = np.ones(n, bool)           # still reading this round's refits
        for k in range(k_round):
            sel = np.flatnonzero((kth == k) & going[pr])
            if sel.size == 0:
                break
            r, j, y = pr[sel], pj[sel], yes[sel]
            first[r[y]], alive[r[y]], going[r[y]] = j[y], False, False
            ok = fit.ok[sel] & ~y
            ro, so = r[ok], sel[ok]
            offset[ro] = fit.log_ratio[so] - raw[ro % n0, j[ok]]
            ratio[ro] = fit.se[so] / se[ro % n0, j[ok]]
            start[ro], slack[ro] = fit.shape[so], screen[1]
            r, j = r[~y], j[~y]
            nxt[r] = j + 1
            alive[r] &= nxt[r] < last[r]
            # a look between this refit and the replicate's next refitted one that the corrected screen passes
            later = np.full(n, looks)
            nk = (kth == k + 1)
            later[pr[nk]] = pj[nk]
            between = passes(r) & (jj > j[:, None]) & (jj < later[r][:, None])
            going[r[between.any(axis=1)]] = False
            going[r[later[r] >= looks]] = False
        k_round *= 2
    return first


__all__ = ["SCREEN", "SCREEN_REFITTED", "LOOK_BLOCK", "Future", "Past", "BatchFit", "batch_fit", "batch_deviance", "decides", "first_decision"]
