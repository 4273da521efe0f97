"""The not-a-knot cubic spline of ``scipy.interpolate.CubicSpline`` without importing ``scipy.interpolate``.

:mod:`analyses.friction_dynamic` shifts a filtered force by a fractional delay through a cubic
spline (step 7 of its method). Importing ``scipy.interpolate`` for it (which imports
scipy.linalg, optimize, sparse, spatial and special) cost about half a second of CPU of a rebuild
after one changed viscous run (issue 26, the cost of a change), for a spline that takes
milliseconds. These are scipy's steps: the same banded system of slopes, solved by LAPACK's
``dgtsv`` (Gaussian elimination with partial pivoting, its operations in its order), the Hermite
coefficients by the same numpy operations, and the piecewise polynomial evaluated as
``scipy.interpolate.PPoly`` evaluates it; the tests hold it to scipy's bits
(``tests/analyses/test_numerics_spline.py``).

References
----------
de Boor, C. (1978). A Practical Guide to Splines, ch. IV (the not-a-knot end condition). Springer.
Anderson, E. et al. (1999). LAPACK Users' Guide, 3rd ed., ``xGTSV``. SIAM.
"""
from __future__ import annotations

import numpy as np


class NotAKnotSpline:
    """Cubic spline through ``(x, y)`` with not-a-knot ends, extrapolated by its end pieces: the
    values of ``scipy.interpolate.CubicSpline(x, y)`` to the bit.

    Parameters
    ----------
    x : array_like
        Strictly increasing abscissae, at least 4, finite. [any unit]
    y : array_like
        Ordinates, 1-D, finite, as many as ``x``. [any unit]

    Attributes
    ----------
    x : ndarray
        The breakpoints. [unit of x]
    c : ndarray
        Shape ``(4, len(x) - 1)``: per piece the coefficients of ``(t - x_i)^3, ^2, ^1, ^0``.
    """

    def __init__(self, x, y):
        x = np.asarray(x).astype(np.float64)
        y = np.asarray(y).astype(np.float64, copy=False)
        n = x.shape[0]
        if x.ndim != 1 or y.shape != x.shape:
            raise ValueError("x and y must be 1-D and of the same length")
        if n < 4:
            raise ValueError(f"{n} points: the not-a-knot spline here needs at least 4")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise ValueError("x and y must be finite")
        dx = np.diff(x)
        if np.any(dx <= 0):
            raise ValueError("x must be strictly increasing")
        slope = np.diff(y, axis=0) / dx
        a = np.zeros((3, n))  # banded: upper, diagonal, lower
        b = np.empty(n)
        a[1, 1:-1] = 2 * (dx[:-1] + dx[1:])
        a[0, 2:] = dx[:-1]
        a[-1, :-2] = dx[1:]
        b[1:-1] = 3 * (dx[1:] * slope[:-1] + dx[:-1] * slope[1:])
        a[1, 0] = dx[1]
        a[0, 1] = x[2] - x[0]
        d = x[2] - x[0]
        b[0] = ((dx[0] + 2 * d) * dx[1] * slope[0] + dx[0] ** 2 * slope[1]) / d
        a[1, -1] = dx[-2]
        a[-1, -2] = x[-1] - x[-3]
        d = x[-1] - x[-3]
        b[-1] = ((dx[-1] ** 2 * slope[-2] + (2 * d + dx[-1]) * dx[-2] * slope[-1]) / d)
        s = _gtsv(a[2, :-1], a[1, :], a[0, 1:], b)
        # CubicHermiteSpline's coefficients from the slopes
        t = (s[:-1] + s[1:] - 2 * slope) / dx
        self.x = x
        self.c = np.stack((t / dx, (slope - s[:-1]) / dx - t, s[:-1], y[:-1]))

    def __call__(self, xq) -> np.ndarray:
        """The spline at ``xq`` (outside ``x``: the end piece's polynomial; NaN at NaN). [unit of y]"""
        xq = np.asarray(xq, dtype=np.float64)
        x, c = self.x, self.c
        i = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, x.shape[0] - 2)
        s = xq - x[i]
        # PPoly's evaluation: sum of c[k - kp] s^kp, the powers built by repeated products
        res = 0.0 + c[3, i] * 1.0 * 1.0
        z = 1.0 * s
        res = res + c[2, i] * z * 1.0
        z = z * s
        res = res + c[1, i] * z * 1.0
        z = z * s
        res = res + c[0, i] * z * 1.0
        return np.where(np.isnan(xq), np.nan, res)


def _gtsv(dl: np.ndarray, d: np.ndarray, du: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the tridiagonal system (sub-, main and super-diagonal ``dl``, ``d``, ``du``) for one
    right-hand side ``b``: LAPACK's ``dgtsv`` (partial pivoting, then back substitution), step for
    step. Raises ``numpy.linalg.LinAlgError`` on a singular matrix."""
    dl, d, du, b = dl.tolist(), d.tolist(), du.tolist(), b.tolist()
    n = len(d)
    du.append(0.0)  # DU(N-1) of the pivoted last rows is never read past; room for DU(I+1)
    for i in range(n - 1):
        if abs(d[i]) >= abs(dl[i]):  # no row interchange
            if d[i] == 0.0:
                raise np.linalg.LinAlgError("singular matrix")
            fact = dl[i] / d[i]
            d[i + 1] = d[i + 1] - fact * du[i]
            b[i + 1] = b[i + 1] - fact * b[i]
            dl[i] = 0.0
        else:  # interchange rows i and i + 1
            fact = d[i] / dl[i]
            d[i] = dl[i]
            temp = d[i + 1]
            d[i + 1] = du[i] - fact * temp
            if i < n - 2:
                dl[i] = du[i + 1]
                du[i + 1] = -fact * dl[i]
            du[i] = temp
            temp = b[i]
            b[i] = b[i + 1]
            b[i + 1] = temp - fact * b[i + 1]
    if d[n - 1] == 0.0:
        raise np.linalg.LinAlgError("singular matrix")
    b[n - 1] = b[n - 1] / d[n - 1]
    if n > 1:
        b[n - 2] = (b[n - 2] - du[n - 2] * b[n - 1]) / d[n - 2]
    for i in range(n - 3, -1, -1):
        b[i] = (b[i] - du[i] * b[i + 1] - dl[i] * b[i + 2]) / d[i]
    return np.asarray(b, dtype=np.float64)


__all__ = ["NotAKnotSpline"]
