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


def butter2_lowpass_sos(cutoff_hz: float, fs_hz: float) -> np.ndarray:
    """The second-order Butterworth low-pass section (Butterworth 1930) of
    ``scipy.signal.butter(2, cutoff_hz, fs=fs_hz, output="sos")``, step for step (the analog
    prototype's poles, the pre-warped bilinear transform, ``zpk2sos``'s pairing and polynomial
    products with the same numpy calls: the same bits) without importing ``scipy.signal`` (about a
    second of CPU for a rebuild that changes one step run, issue 26).

    Parameters
    ----------
    cutoff_hz : float
        -3 dB frequency, ``0 < cutoff_hz < fs_hz / 2``. [Hz]
    fs_hz : float
        Sampling frequency. [Hz]

    Returns
    -------
    ndarray
        Shape (1, 6): ``b0, b1, b2, 1, a1, a2``. [-]
    """
    wn = np.asarray(cutoff_hz, dtype=np.float64) / (float(fs_hz) / 2)
    if not 0 < wn < 1:
        raise ValueError(f"cutoff {cutoff_hz!r} Hz is not inside (0, fs/2) for fs = {fs_hz!r} Hz")
    warped = float(2 * 2.0 * np.tan(np.pi * wn / 2.0))
    p = -np.exp(1j * np.pi * np.arange(-1, 2, 2, dtype=np.float64) / (2 * 2))  # buttap(2)
    p = warped * p  # lp2lp_zpk; the prototype has no zeros, its gain 1 * warped ** 2
    k = 1.0 * warped ** 2
    k = k * np.real(np.prod(4.0 - np.asarray([], dtype=np.float64)) / np.prod(4.0 - p))  # bilinear_zpk, fs = 2
    p = (4.0 + p) / (4.0 - p)
    p = p[np.lexsort((abs(p.imag), p.real))]  # _cplxreal: the conjugate pair averaged
    p1 = ((p[p.imag > 0] + p[p.imag < 0].conj()) / 2)[0]
    sos = np.zeros(6)
    sos[0:3] = np.multiply(np.asarray(1.0), _poly(np.asarray([-1.0, -1.0])))
    sos[3:6] = _poly(np.asarray([p1, p1.conj()]))
    sos[:3] *= np.asarray(k).real
    return sos.reshape(1, 6)


def _poly(roots: np.ndarray) -> np.ndarray:
    """The polynomial with these roots, as ``scipy.signal``'s ``poly`` forms it (real when the
    roots are conjugate pairs)."""
    a = np.ones((1,), dtype=roots.dtype)
    one = np.ones_like(roots[0])
    for zero in roots:
        a = np.convolve(a, np.stack((one, -zero)), mode="full")
    if np.iscomplexobj(a):
        a = np.asarray(np.real(a), copy=True)
    return a


def sosfiltfilt2(sos: np.ndarray, x, padtype: str, padlen: int) -> np.ndarray:
    """Zero-phase filtering by one second-order section, forward then backward: the bits of
    ``scipy.signal.sosfiltfilt(sos, x, padtype=padtype, padlen=padlen)`` (its odd or constant
    extension, ``sosfilt_zi``'s steady state by the same linear solve, the C recursion of
    ``sosfilt`` in the same order of operations) without importing ``scipy.signal``.

    Parameters
    ----------
    sos : ndarray
        Shape (1, 6), ``a0 = 1`` (:func:`butter2_lowpass_sos`). [-]
    x : array_like
        Evenly sampled signal, longer than ``padlen``. [any unit]
    padtype : {"odd", "constant"}
        How the ends are extended.
    padlen : int
        Samples added at each end. [samples]

    Returns
    -------
    ndarray
        The filtered signal, as long as ``x``. [unit of x]
    """
    x = np.asarray(x, dtype=np.float64)
    if len(x) <= padlen:
        raise ValueError(f"the signal ({len(x)} samples) must be longer than padlen ({padlen})")
    ext = x
    if padlen > 0:
        if padtype == "odd":
            ext = np.concatenate((2 * x[:1] - x[padlen:0:-1], x, 2 * x[-1:] - x[-2:-(padlen + 2):-1]))
        elif padtype == "constant":
            ones = np.ones(padlen, dtype=x.dtype)
            ext = np.concatenate((ones * x[:1], x, ones * x[-1:]))
        else:
            raise ValueError(f"padtype {padtype!r} is not 'odd' or 'constant'")
    b, a = sos[0, :3], sos[0, 3:]
    companion_t = np.array([[-a[1] / (1.0 * a[0]), 1.0], [-a[2] / (1.0 * a[0]), 0.0]])
    zi = 1.0 * np.linalg.solve(np.eye(2) - companion_t, b[1:] - a[1:] * b[0])
    y = _sosfilt2(sos[0], ext, zi * ext[0])
    y = _sosfilt2(sos[0], y[::-1], zi * y[-1])[::-1]
    return y[padlen:-padlen] if padlen > 0 else y


def _sosfilt2(s: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """One second-order section over ``x`` from the state ``zi``: ``scipy.signal``'s C loop
    (``_sosfilt``), its operations in its order."""
    b0, b1, b2, _, a1, a2 = (float(v) for v in s)
    z0, z1 = float(zi[0]), float(zi[1])
    out = []
    append = out.append
    for xc in x.tolist():
        xn = b0 * xc + z0
        z0 = b1 * xc - a1 * xn + z1
        z1 = b2 * xc - a2 * xn
        append(xn)
    return np.asarray(out, dtype=np.float64)
