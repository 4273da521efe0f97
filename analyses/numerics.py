"""Numerical kernels the analyses need without importing ``scipy.signal`` or ``scipy.optimize``.

A rebuild after one changed spring test runs one Savitzky-Golay derivative and a few Brent roots
(the Butterworth filters are :mod:`analyses.numerics_iir`'s), one after a changed breakaway run a bounded scalar minimisation, Student t quantiles and Welch's test, one that re-runs
the decision or remaining-life stage the normal's and chi-square's tails and quantiles (``norm_sf``,
``norm_isf``, ``norm_pdf``, ``chi2_sf``, ``chi2_ppf``: the ``scipy.special`` calls scipy.stats makes); importing the
scipy subpackages for them cost about a second of CPU per rebuild (issue 26, the cost of a change). These are scipy's own algorithms, step for step, and the tests hold them to scipy's
bits (``tests/analyses/test_numerics.py``); where a fit may import scipy anyway, it still may.

References
----------
Savitzky, A. & Golay, M. J. E. (1964). Smoothing and differentiation of data by simplified least
squares procedures. Analytical Chemistry 36(8), 1627-1639.
Brent, R. P. (1973). Algorithms for Minimization without Derivatives, ch. 4 and 5. Prentice-Hall.
Welch, B. L. (1947). The generalization of "Student's" problem when several different population
variances are involved. Biometrika 34(1-2), 28-35.
"""
from __future__ import annotations

import math

import numpy as np

from analyses.numerics_special import chi2_sf_integer, ndtr, ndtri, ndtri_scalar

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


def fminbound(f, lo: float, hi: float, xatol: float = 1e-5, maxiter: int = 500) -> float:
    """The minimiser of ``f`` on ``[lo, hi]`` by Brent's bounded golden-section / parabolic search
    (Brent 1973, ch. 5): the steps of ``scipy.optimize.minimize_scalar(f, bounds=(lo, hi),
    method="bounded", options={"xatol": xatol})`` (its Python code, the same bits) without importing
    ``scipy.optimize``.

    Parameters
    ----------
    f : callable
        ``f(x) -> float``.
    lo, hi : float
        The bounds, finite, ``lo <= hi``. [unit of x]
    xatol : float, optional
        Absolute tolerance of the minimiser. [unit of x]
    maxiter : int, optional
        Evaluations at most (scipy's ``maxiter``).

    Returns
    -------
    float
        The minimiser found. [unit of x]
    """
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"bounds ({lo!r}, {hi!r}) are not finite and ordered")
    sqrt_eps, golden_mean = np.sqrt(2.2e-16), 0.5 * (3.0 - np.sqrt(5.0))  # numpy scalars, as scipy's: f sees its types
    a, b = lo, hi
    fulc = a + golden_mean * (b - a)
    nfc = xf = fulc
    rat = e = 0.0
    fx = f(xf)
    num = 1
    ffulc = fnfc = fx
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
    tol2 = 2.0 * tol1
    while np.abs(xf - xm) > (tol2 - 0.5 * (b - a)):
        rat, e = _bounded_step(a, b, xf, nfc, fulc, fx, fnfc, ffulc, xm, tol1, tol2, rat, e)
        x = xf + (np.sign(rat) + (rat == 0)) * np.maximum(np.abs(rat), tol1)
        fu = f(x)
        num += 1
        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc, nfc, fnfc, xf, fx = nfc, fnfc, xf, fx, x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if (fu <= fnfc) or (nfc == xf):
                fulc, ffulc, nfc, fnfc = nfc, fnfc, x, fu
            elif (fu <= ffulc) or (fulc == xf) or (fulc == nfc):
                fulc, ffulc = x, fu
        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
        tol2 = 2.0 * tol1
        if num >= maxiter:
            break
    return xf


def _bounded_step(a, b, xf, nfc, fulc, fx, fnfc, ffulc, xm, tol1, tol2, rat, e) -> tuple:
    """The next ``(rat, e)`` of :func:`fminbound`: a parabolic step when it is acceptable, else golden."""
    if np.abs(e) > tol1:
        r = (xf - nfc) * (fx - ffulc)
        q = (xf - fulc) * (fx - fnfc)
        p = (xf - fulc) * q - (xf - nfc) * r
        q = 2.0 * (q - r)
        if q > 0.0:
            p = -p
        q = np.abs(q)
        r, e = e, rat
        if (np.abs(p) < np.abs(0.5 * q * r)) and (p > q * (a - xf)) and (p < q * (b - xf)):
            rat = (p + 0.0) / q
            x = xf + rat
            if ((x - a) < tol2) or ((b - x) < tol2):
                rat = tol1 * (np.sign(xm - xf) + ((xm - xf) == 0))
            return rat, e
    e = (a - xf) if xf >= xm else (b - xf)
    return 0.5 * (3.0 - np.sqrt(5.0)) * e, e


def student_t_ppf(q: float, df: float) -> float:
    """``scipy.stats.t.ppf(q, df)`` (the same ``scipy.special.stdtrit``, the same bits) without
    importing ``scipy.stats`` (about a second of CPU, issue 26).

    Parameters
    ----------
    q : float
        Probability. [-]
    df : float
        Degrees of freedom, > 0 (inf allowed). [-]

    Returns
    -------
    float
        The quantile; NaN for ``df`` not positive or ``q`` outside [0, 1]. [-]
    """
    from scipy.special import stdtrit

    if not df > 0 or not 0 <= q <= 1:
        return float("nan")
    if q == 0 or q == 1:
        return -math.inf if q == 0 else math.inf
    return float(stdtrit(df, q) * 1 + 0)


def student_t_sf(x: float, df: float) -> float:
    """``scipy.stats.t.sf(x, df)`` (``scipy.special.stdtr(df, -x)``, the same bits) without importing
    ``scipy.stats``.

    Parameters
    ----------
    x : float
        The statistic. [-]
    df : float
        Degrees of freedom, > 0 (inf allowed). [-]

    Returns
    -------
    float
        P(T > x); NaN for ``df`` not positive or ``x`` NaN. [-]
    """
    from scipy.special import stdtr

    if not df > 0 or math.isnan(x):
        return float("nan")
    if math.isinf(x):
        return 0.0 if x > 0 else 1.0
    return float(stdtr(df, -x))


def welch_t_test_p(a, b) -> float:
    """Two-sided p-value of Welch's t-test of equal means (unequal variances): the bits of
    ``scipy.stats.ttest_ind(a, b, equal_var=False).pvalue`` (its variance as the mean squared
    deviation times ``n / (n - 1)``, its Welch-Satterthwaite degrees of freedom, ``stdtr``)
    without importing ``scipy.stats``.

    Parameters
    ----------
    a, b : array_like
        The two samples, 1-D. [any unit, the same]

    Returns
    -------
    float
        The p-value; NaN when a sample is empty. [-]
    """
    from scipy.special import stdtr

    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.size == 0 or b.size == 0:
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        vn = []
        for x in (a, b):
            n = np.asarray(x.size, dtype=x.dtype)
            v = np.mean((x - np.mean(x, axis=0, keepdims=True)) ** 2, axis=0)
            v *= n / (n - 1)
            vn.append(v / x.size)
        df = (vn[0] + vn[1]) ** 2 / (vn[0] ** 2 / (a.size - 1) + vn[1] ** 2 / (b.size - 1))
        df = np.where(np.isnan(df), 1.0, df)
        t = np.divide(np.mean(a, axis=0) - np.mean(b, axis=0), np.sqrt(vn[0] + vn[1]))
    return float((2 * stdtr(np.asarray(df, dtype=t.dtype), -np.abs(t)))[()])


def chi2_sf(x: float, df: float) -> float:
    """``scipy.stats.chi2.sf(x, df)`` (the same ``scipy.special.chdtrc``, the same bits) without
    importing ``scipy.stats`` (about a second of CPU, issue 26).

    Parameters
    ----------
    x : float
        The statistic. [-]
    df : float
        Degrees of freedom, > 0. [-]

    Returns
    -------
    float
        P(X > x): 1 for ``x <= 0``; NaN for ``df`` not positive or ``x`` NaN. [-]
    """
    if not df > 0 or math.isnan(x):
        return float("nan")
    if x <= 0:
        return 1.0
    p = chi2_sf_integer(x, df)   # integer df 1-40: Cephes' igamc ported (analyses.numerics_special), no scipy import
    if p is not None:
        return p
    from scipy.special import chdtrc

    return float(chdtrc(df, x))


def chi2_ppf(q: float, df: float) -> float:
    """``scipy.stats.chi2.ppf(q, df)`` (``2 gammaincinv(df / 2, q)``, the same bits) without importing
    ``scipy.stats``.

    Parameters
    ----------
    q : float
        Probability. [-]
    df : float
        Degrees of freedom, > 0. [-]

    Returns
    -------
    float
        The quantile; 0 at ``q = 0``, inf at ``q = 1``, NaN for ``df`` not positive or ``q`` outside
        [0, 1]. [-]
    """
    from scipy.special import gammaincinv

    if not df > 0 or not 0 <= q <= 1:
        return float("nan")
    if q == 0 or q == 1:
        return 0.0 if q == 0 else math.inf
    return float(2 * gammaincinv(df / 2, q) * 1 + 0)


def norm_sf(x):
    """``scipy.stats.norm.sf(x)``: ``ndtr(-x)``, the same bits, without importing ``scipy.stats``.

    Parameters
    ----------
    x : float or array_like
        Standard normal deviate. [-]

    Returns
    -------
    numpy.float64 or numpy.ndarray
        P(Z > x). [-]
    """
    return ndtr(-np.asarray(x, dtype=float))   # Cephes' steps (analyses.numerics_special): no scipy.special import


def norm_isf(q):
    """``scipy.stats.norm.isf(q)``: ``-ndtri(q)``, the same bits (inf at 0, -inf at 1, NaN outside
    [0, 1]), without importing ``scipy.stats``.

    Parameters
    ----------
    q : float or array_like
        Upper-tail probability. [-]

    Returns
    -------
    numpy.float64 or numpy.ndarray
        The deviate with P(Z > x) = q. [-]
    """
    return -ndtri(np.asarray(q, dtype=float))   # Cephes' steps (analyses.numerics_special): no scipy.special import


def two_sided_z(confidence: float) -> float:
    """The two-sided normal quantile of a confidence, ``ndtri(0.5 + confidence / 2)``.

    Parameters
    ----------
    confidence : float
        Confidence of the interval [-], 0 < confidence < 1.

    Returns
    -------
    float
        z [-] with ``P(|Z| < z) = confidence``, by ``ndtri`` (:mod:`analyses.numerics_special`:
        norm.ppf's bits without importing scipy).
    """
    return ndtri_scalar(0.5 + confidence / 2)


def norm_pdf(x):
    """``scipy.stats.norm.pdf(x)``: ``exp(-x**2 / 2) / sqrt(2 pi)`` in scipy's order, the same bits.

    Parameters
    ----------
    x : float or array_like
        Standard normal deviate. [-]

    Returns
    -------
    numpy.float64 or numpy.ndarray
        The density. [-]
    """
    x = np.asarray(x, dtype=float)
    return (np.exp(-x ** 2 / 2.0) / _NORM_PDF_C)[()]


#: scipy.stats' constant of the normal density, sqrt(2 pi), computed as scipy computes it.
_NORM_PDF_C = np.sqrt(2 * np.pi)
