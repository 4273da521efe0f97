"""Numerical kernels the analyses need without importing ``scipy.signal`` or ``scipy.optimize``.

A rebuild after one changed spring test runs one Savitzky-Golay derivative and a few Brent roots;
importing the scipy subpackages for them cost about a second of CPU per rebuild (issue 26, the cost
of a change). These are scipy's own algorithms, step for step, and the tests hold them to scipy's
bits (``tests/analyses/test_numerics.py``); where a fit may import scipy anyway, it still may.

References
----------
Savitzky, A. & Golay, M. J. E. (1964). Smoothing and differentiation of data by simplified least
squares procedures. Analytical Chemistry 36(8), 1627-1639.
Brent, R. P. (1973). Algorithms for Minimization without Derivatives, ch. 4. Prentice-Hall.
"""
from __future__ import annotations

import math

import numpy as np


_EPS = float(np.finfo(float).eps)


def _lstsq(a, b):
    """Least squares by LAPACK's gelsd, as scipy's Savitzky-Golay filter solves it (same bits)."""
    return np.linalg.lstsq(a, b, rcond=_EPS * max(a.shape))[0]


def savgol_derivative(x, window: int, delta: float, order: int = 3):
    """First derivative by a Savitzky-Golay filter (Savitzky & Golay 1964), ends fitted by a polynomial.

    The bits of ``scipy.signal.savgol_filter(x, window, order, deriv=1, delta=delta)`` (mode
    ``"interp"``: the same least-squares coefficients, the convolution summed in the order of
    ``scipy.ndimage.convolve1d``, the ends from ``polyfit`` of the first and last windows) without
    importing ``scipy.signal`` (about a second of CPU for a rebuild that changes one spring test,
    issue 26).

    Parameters
    ----------
    x : array_like
        Evenly sampled signal, at least ``window`` samples. [any unit]
    window : int
        Odd window length, more than ``order``. [samples]
    delta : float
        Sample spacing. [s]
    order : int, optional
        Polynomial order. [-]

    Returns
    -------
    ndarray
        dx/dt. [unit of x / s]
    """
    x = np.asarray(x, float)
    half = window // 2
    taps = np.arange(-half, window - half, dtype=float)[::-1]
    rhs = np.zeros(order + 1)
    rhs[1] = 1.0 / delta
    coeffs = _lstsq(taps ** np.arange(order + 1, dtype=float).reshape(-1, 1), rhs)
    y = _correlate_constant(x, coeffs[::-1])
    n = len(x)
    for start, lo, hi in ((0, 0, half), (n - window, n - half, n)):
        t = np.arange(0, window, dtype=float)
        lhs = t[:, None] ** np.arange(order, -1, -1, dtype=float)[None, :]
        scale = np.sqrt(np.sum(lhs * lhs, axis=0))
        lhs /= scale
        poly = (_lstsq(lhs, x[start:start + window]) / scale)[:-1] * np.arange(order, 0, -1)
        at = np.arange(lo - start, hi - start, dtype=float)
        v = np.zeros_like(at)
        for c in poly:
            v = v * at + c
        y[lo:hi] = v / delta
    return y


def _correlate_constant(x: np.ndarray, fw: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.correlate1d(x, fw, mode="constant")`` with its order of summation (symmetric
    and antisymmetric odd filters folded, as ``NI_Correlate1D`` does): the same bits."""
    size, n = len(fw), len(x)
    s1 = size // 2
    s2 = size - s1 - 1
    padded = np.concatenate([np.zeros(s1), x, np.zeros(s2)])

    def at(j):
        return padded[s1 + j:s1 + j + n]

    sym = 0
    if size % 2:
        if all(abs(fw[s1 + i] - fw[s1 - i]) <= _EPS for i in range(1, s1 + 1)):
            sym = 1
        elif all(abs(fw[s1 + i] + fw[s1 - i]) <= _EPS for i in range(1, s1 + 1)):
            sym = -1
    if sym:
        y = x * fw[s1]
        for j in range(-s1, 0):
            y += ((at(j) + at(-j)) if sym > 0 else (at(j) - at(-j))) * fw[s1 + j]
        return y
    y = at(s2) * fw[s1 + s2]
    for j in range(-s1, s2):
        y += at(j) * fw[s1 + j]
    return y


def brentq(f, a: float, b: float, xtol: float = 2e-12, rtol: float = 4 * _EPS, maxiter: int = 100) -> float:
    """A root of ``f`` in ``[a, b]`` by Brent's method (Brent 1973, Algorithms for Minimization
    without Derivatives, ch. 4): the steps of ``scipy.optimize.brentq`` (its C code, same bits)
    without importing ``scipy.optimize`` (half a second of CPU for a spring fit that takes
    milliseconds, issue 26).

    Parameters
    ----------
    f : callable
        ``f(x) -> float``, of opposite signs at ``a`` and ``b``.
    a, b : float
        The bracket. [unit of x]
    xtol, rtol : float, optional
        Converged when half the bracket is under ``(xtol + rtol |x|) / 2``. [unit of x], [-]
    maxiter : int, optional
        Iterations at most.

    Returns
    -------
    float
        The root. [unit of x]

    Raises
    ------
    ValueError
        ``f`` has the same sign at both ends, or gave NaN.
    RuntimeError
        Not converged in ``maxiter`` iterations.
    """
    def call(x):
        v = float(f(x))
        if math.isnan(v):
            raise ValueError(f"the function gave NaN at {x!r}")
        return v

    xpre, xcur = float(a), float(b)
    fpre, fcur = call(xpre), call(xcur)
    if fpre == 0:
        return xpre
    if fcur == 0:
        return xcur
    if math.copysign(1.0, fpre) == math.copysign(1.0, fcur):
        raise ValueError("f(a) and f(b) must have different signs")
    xblk = fblk = spre = scur = 0.0
    for _ in range(maxiter):
        if fpre != 0 and fcur != 0 and math.copysign(1.0, fpre) != math.copysign(1.0, fcur):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * abs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or abs(sbis) < delta:
            return xcur
        spre, scur = _brent_step(xpre, xcur, xblk, fpre, fcur, fblk, spre, scur, sbis, delta)
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0 else -delta)
        fcur = call(xcur)
    raise RuntimeError(f"Brent's method did not converge in {maxiter} iterations")


def _brent_step(xpre, xcur, xblk, fpre, fcur, fblk, spre, scur, sbis, delta) -> tuple[float, float]:
    """The next (previous step, step) of :func:`brentq`: inverse interpolation when it is a good
    short step, else bisection."""
    if abs(spre) > delta and abs(fcur) < abs(fpre):
        if xpre == xblk:
            stry = -fcur * (xcur - xpre) / (fcur - fpre)
        else:
            dpre = (fpre - fcur) / (xpre - xcur)
            dblk = (fblk - fcur) / (xblk - xcur)
            stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
        if 2 * abs(stry) < min(abs(spre), 3 * abs(sbis) - delta):
            return scur, stry
    return sbis, sbis
