"""The life fits' minimisers without ``scipy.stats`` or ``scipy.optimize``: scipy's Nelder-Mead,
``weibull_min``'s censored negative log-likelihood and Brent's bracketed minimiser, bit for bit.

:func:`analyses.service_life.weibull_fit` polishes its exact profile solution with
``scipy.stats.weibull_min.fit(CensoredData.right_censored(x, ~f), k0, floc=0, scale=s0)``, which,
with censored lives, is ``scipy.optimize.fmin`` (Nelder & Mead 1965, scipy's non-adaptive
coefficients) on ``rv_continuous._penalized_nnlf`` over (shape, scale). Importing ``scipy.stats`` for it
cost about 0.6 CPU-s of a rebuild after one changed leakage check (the remaining-life stage's life
models refit lives the change does not touch; issue 26, the cost of a change). :func:`weibull_polish`
is that call, step for step: the same simplex, the same arithmetic in the same order, the same
evaluation budget and the same failures (non-finite scaled lives raise, as ``CensoredData`` does).
:func:`brent_minimize` is ``scipy.optimize.minimize_scalar(f, bracket=(a, b))`` (the bracket search and
Brent's minimiser), which :func:`analyses.service_life_lognormal.lognormal_fit` needs for the life model's other
family. ``tests/analyses/test_numerics_fmin.py`` holds them to scipy's bits (scipy 1.17).

References
----------
Nelder, J. A. & Mead, R. (1965). A simplex method for function minimization. The Computer
Journal 7(4), 308-313.
Brent, R. P. (1973). Algorithms for Minimization without Derivatives, ch. 5. Prentice-Hall.
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.special (xlogy) loads on first use

#: ``scipy.stats``' penalty per observation outside the support: ``log(finfo(float).max)`` [-].
_LOGXMAX = np.log(np.finfo(float).max)


class _TooManyCalls(Exception):
    """``scipy.optimize``'s ``_MaxFuncCallError``: the evaluation budget is spent."""


def weibull_censored_nll(theta, uncensored: np.ndarray, right: np.ndarray | None):
    """``weibull_min._penalized_nnlf([shape, 0, scale], data)``: ``data`` the ``CensoredData`` of
    ``uncensored`` and ``right``, or, ``right`` None, the plain array ``uncensored`` (scipy's fit of
    censored data without a censored value).

    Parameters
    ----------
    theta : numpy.ndarray
        ``[shape, scale]`` [-, unit of the lives].
    uncensored : numpy.ndarray
        Failure lives [any unit, > 0], float64.
    right : numpy.ndarray or None
        Right-censored lives [any unit, > 0], float64.

    Returns
    -------
    float
        The penalised negative log-likelihood [-] (``inf`` outside the parameter space).

    Raises
    ------
    ValueError
        A scaled life of ``CensoredData`` not finite (its constructor refuses it).
    """
    c, scale = theta[0], theta[1]
    if not np.asarray(c) > 0 or scale <= 0:
        return np.inf
    u = (uncensored - 0) / scale
    n_log_scale = len(u) * np.log(scale)   # (len(x) - x.num_censored()) * log(scale)
    if right is None:                      # an array: rv_continuous._support_mask, closed
        keep = (0.0 <= u) & (u <= np.inf)
        us, rs = (u[keep] if not keep.all() else u), None
    else:                                  # CensoredData._supported, open
        r = (right - 0) / scale
        if not (np.isfinite(u).all() and np.isfinite(r).all()):
            raise ValueError("scaled lives must be finite")
        us, rs = u[(0.0 < u) & (u < np.inf)], r[r < np.inf]
    empty = np.empty(0)
    terms = [np.log(c) + scipy.special.xlogy(c - 1, us) - pow(us, c)]
    if rs is not None:
        terms += [empty, -pow(rs, c), empty]   # logpdf, logcdf (left), logsf (right), interval
    totals, bad = [], len(u) + (0 if rs is None else len(r)) - len(us) - (0 if rs is None else len(rs))
    for term in terms:
        finite = np.isfinite(term)
        totals.append(np.sum(term[finite]))
        bad += finite.size - np.count_nonzero(finite)
    return -sum(totals) + bad * _LOGXMAX * 100 + n_log_scale


def nelder_mead(func, x0, args=(), xatol: float = 1e-4, fatol: float = 1e-4) -> np.ndarray:
    """``scipy.optimize.fmin(func, x0, args, xatol, fatol, disp=0)``: the downhill simplex with
    scipy's coefficients (reflection 1, expansion 2, contraction 0.5, shrink 0.5), its initial
    simplex (each coordinate times 1.05, or 0.00025 where it is 0) and budget (200 evaluations
    and 200 iterations per coordinate).

    Parameters
    ----------
    func : callable
        ``func(x, *args) -> float``.
    x0 : array_like
        The start [unit of each coordinate].
    xatol, fatol : float
        Stop when the simplex spans at most ``xatol`` in every coordinate and its values at most
        ``fatol``.

    Returns
    -------
    numpy.ndarray
        The best vertex.
    """
    x0 = np.atleast_1d(x0).flatten()
    x0 = np.asarray(x0, dtype=x0.dtype if np.issubdtype(x0.dtype, np.inexact) else np.float64)
    n = len(x0)
    sim = np.empty((n + 1, n), dtype=x0.dtype)
    sim[0] = x0
    for k in range(n):
        y = np.array(x0, copy=True)
        y[k] = (1 + 0.05) * y[k] if y[k] != 0 else 0.00025
        sim[k + 1] = y
    maxfun = maxiter = n * 200
    calls = [0]

    def f(x):
        if calls[0] >= maxfun:
            raise _TooManyCalls
        calls[0] += 1
        fx = func(np.copy(x), *args)
        return fx if np.isscalar(fx) else np.asarray(fx).item()

    fsim = np.full((n + 1,), np.inf, dtype=float)
    try:
        for k in range(n + 1):
            fsim[k] = f(sim[k])
    except _TooManyCalls:
        pass
    for _ in range(2):
        ind = np.argsort(fsim)
        sim, fsim = np.take(sim, ind, 0), np.take(fsim, ind, 0)
    iterations = 1
    while calls[0] < maxfun and iterations < maxiter:
        try:
            if (np.max(np.ravel(np.abs(sim[1:] - sim[0]))) <= xatol
                    and np.max(np.abs(fsim[0] - fsim[1:])) <= fatol):
                break
            _step(f, sim, fsim, np.add.reduce(sim[:-1], 0) / n)
            iterations += 1
        except _TooManyCalls:
            pass
        ind = np.argsort(fsim)
        sim, fsim = np.take(sim, ind, 0), np.take(fsim, ind, 0)
    return sim[0]


def _step(f, sim: np.ndarray, fsim: np.ndarray, xbar: np.ndarray) -> None:
    """One Nelder-Mead step in place (``_minimize_neldermead``'s, ``rho, chi, psi, sigma = 1, 2, 0.5, 0.5``)."""
    rho, chi, psi, sigma = 1, 2, 0.5, 0.5
    xr = (1 + rho) * xbar - rho * sim[-1]
    fxr = f(xr)
    if fxr < fsim[0]:
        xe = (1 + rho * chi) * xbar - rho * chi * sim[-1]
        fxe = f(xe)
        sim[-1], fsim[-1] = (xe, fxe) if fxe < fxr else (xr, fxr)
        return
    if fxr < fsim[-2]:
        sim[-1], fsim[-1] = xr, fxr
        return
    if fxr < fsim[-1]:
        xc = (1 + psi * rho) * xbar - psi * rho * sim[-1]
        fxc = f(xc)
        if fxc <= fxr:
            sim[-1], fsim[-1] = xc, fxc
            return
    else:
        xcc = (1 - psi) * xbar + psi * sim[-1]
        fxcc = f(xcc)
        if fxcc < fsim[-1]:
            sim[-1], fsim[-1] = xcc, fxcc
            return
    for j in range(1, len(sim)):
        sim[j] = sim[0] + sigma * (sim[j] - sim[0])
        fsim[j] = f(sim[j])


class _BracketError(RuntimeError):
    """``scipy.optimize``'s ``BracketError``, with the last three points and values."""


def _bracket(func, xa: float, xb: float, grow_limit: float = 110.0, maxiter: int = 1000) -> tuple:
    """``scipy.optimize.bracket(func, xa, xb)``: three points downhill-bracketing a minimum and their
    values, and the evaluations made."""
    _gold, _verysmall_num = 1.618034, 1e-21
    xa, xb = np.asarray([xa, xb])
    fa, fb = func(xa), func(xb)
    if fa < fb:
        xa, xb, fa, fb = xb, xa, fb, fa
    xc = xb + _gold * (xb - xa)
    fc = func(xc)
    funcalls, it = 3, 0
    while fc < fb:
        tmp1, tmp2 = (xb - xa) * (fb - fc), (xb - xc) * (fb - fa)
        val = tmp2 - tmp1
        denom = 2.0 * _verysmall_num if np.abs(val) < _verysmall_num else 2.0 * val
        w = xb - ((xb - xc) * tmp2 - (xb - xa) * tmp1) / denom
        wlim = xb + grow_limit * (xc - xb)
        if it > maxiter:
            raise RuntimeError("No valid bracket was found before the iteration limit was reached.")
        it += 1
        if (w - xc) * (xb - w) > 0.0:
            fw = func(w)
            funcalls += 1
            if fw < fc:
                xa, xb, fa, fb = xb, w, fb, fw
                break
            if fw > fb:
                xc, fc = w, fw
                break
            w = xc + _gold * (xc - xb)
            fw = func(w)
            funcalls += 1
        elif (w - wlim) * (wlim - xc) >= 0.0:
            w = wlim
            fw = func(w)
            funcalls += 1
        elif (w - wlim) * (xc - w) > 0.0:
            fw = func(w)
            funcalls += 1
            if fw < fc:
                xb, xc = xc, w
                w = xc + _gold * (xc - xb)
                fb, fc = fc, fw
                fw = func(w)
                funcalls += 1
        else:
            w = xc + _gold * (xc - xb)
            fw = func(w)
            funcalls += 1
        xa, xb, xc, fa, fb, fc = xb, xc, w, fb, fc, fw
    ok = ((fb < fc and fb <= fa) or (fb < fa and fb <= fc)) and (xa < xb < xc or xc < xb < xa) \
        and np.isfinite(xa) and np.isfinite(xb) and np.isfinite(xc)
    if not ok:
        raise _BracketError(xa, xb, xc, fa, fb, fc)
    return xa, xb, xc, fa, fb, fc


def brent_minimize(func, xa: float, xb: float, tol: float = 1.48e-8, maxiter: int = 500) -> tuple[float, float]:
    """``scipy.optimize.minimize_scalar(func, bracket=(xa, xb))``'s ``(x, fun)``: Brent's
    minimiser (Brent 1973, ch. 5) from :func:`_bracket`'s bracket, scipy's steps; without a valid
    bracket the best of its last three points (NaN when one is NaN), as scipy returns it.

    Parameters
    ----------
    func : callable
        ``func(x) -> float``.
    xa, xb : float
        The two starting points of the bracket search [unit of x].
    tol : float
        Relative tolerance in x (scipy's ``xtol``). [-]
    maxiter : int
        Iterations at most.

    Returns
    -------
    (x, fun) : (float, float)
        The minimiser and its value (numpy floats).
    """
    try:
        xa, xb, xc, fa, fb, fc = _bracket(func, xa, xb)
    except _BracketError as e:
        xs, fs = list(e.args[:3]), list(e.args[3:])
        if np.any(np.isnan([xs, fs])):
            return np.nan, np.nan
        i = np.argmin(fs)
        return np.asarray(xs[i])[()], np.asarray(fs[i])[()]
    x = w = v = xb
    fw = fv = fx = fb
    a, b = (xa, xc) if xa < xc else (xc, xa)
    deltax, it, rat = 0.0, 0, 0.0
    while it < maxiter:
        tol1 = tol * np.abs(x) + 1.0e-11
        tol2 = 2.0 * tol1
        xmid = 0.5 * (a + b)
        if np.abs(x - xmid) < (tol2 - 0.5 * (b - a)):
            break
        deltax, rat = _brent_step(x, w, v, fx, fw, fv, a, b, xmid, tol1, tol2, deltax, rat)
        u = (x + tol1 if rat >= 0 else x - tol1) if np.abs(rat) < tol1 else x + rat
        fu = func(u)
        if fu > fx:
            if u < x:
                a = u
            else:
                b = u
            if (fu <= fw) or (w == x):
                v, w, fv, fw = w, u, fw, fu
            elif (fu <= fv) or (v == x) or (v == w):
                v, fv = u, fu
        else:
            if u >= x:
                a = x
            else:
                b = x
            v, w, x, fv, fw, fx = w, x, u, fw, fx, fu
        it += 1
    return np.asarray(x)[()], np.asarray(fx)[()]


def _brent_step(x, w, v, fx, fw, fv, a, b, xmid, tol1, tol2, deltax, rat) -> tuple:
    """``Brent.optimize``'s choice of step: parabolic when useful, else golden section; ``(deltax, rat)``."""
    _cg = 0.3819660
    if np.abs(deltax) <= tol1:
        deltax = a - x if x >= xmid else b - x
        return deltax, _cg * deltax
    tmp1 = (x - w) * (fx - fv)
    tmp2 = (x - v) * (fx - fw)
    p = (x - v) * tmp2 - (x - w) * tmp1
    tmp2 = 2.0 * (tmp2 - tmp1)
    if tmp2 > 0.0:
        p = -p
    tmp2 = np.abs(tmp2)
    dx_temp, deltax = deltax, rat
    if (p > tmp2 * (a - x)) and (p < tmp2 * (b - x)) and (np.abs(p) < np.abs(0.5 * tmp2 * dx_temp)):
        rat = p * 1.0 / tmp2
        u = x + rat
        if (u - a) < tol2 or (b - u) < tol2:
            rat = tol1 if xmid - x >= 0 else -tol1
        return deltax, rat
    deltax = a - x if x >= xmid else b - x
    return deltax, _cg * deltax


def weibull_polish(x: np.ndarray, f: np.ndarray, shape: float, scale: float) -> tuple[float, float]:
    """``weibull_min.fit(CensoredData.right_censored(x, ~f), shape, floc=0, scale=scale)``'s shape
    and scale (without a censored life scipy fits the plain lives: the same minimisation of the
    lives' own likelihood, its penalty counting lives outside the closed support).

    Parameters
    ----------
    x : numpy.ndarray
        Lives [any unit, > 0, finite], float64.
    f : numpy.ndarray of bool
        True for a failure.
    shape, scale : float
        The start [-, unit of ``x``].

    Returns
    -------
    (shape, scale) : (numpy.float64, numpy.float64)

    Raises
    ------
    ValueError
        Where scipy raises: a non-finite scaled censored life, an end outside the parameter space.
    """
    data = (x, None) if f.all() else (x[f], x[~f])
    k, s = nelder_mead(weibull_censored_nll, [shape, scale], args=data)
    if not (k > 0 and s > 0):
        raise ValueError("Optimization converged to parameters outside the range allowed by the distribution.")
    return k, s


__all__ = ["brent_minimize", "nelder_mead", "weibull_censored_nll", "weibull_polish"]
