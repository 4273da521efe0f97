"""The information per failure on the log life ratio, and the power of the verdict when failures are rare.

A sequential design counts its information in failures (:mod:`analyses.sequential`); this module says how
much information on ``ln(force life / distance life)`` one failure carries, the common Weibull shape estimated,
and gives the exact power of the verdict read at every failure when failures are rare
(:func:`rare_failure_power`, a binomial recursion over the force-set count: the Wald z's small-sample
distribution, which the canonical process is not at the margin). :func:`information_per_failure` is kept per
process (``lru_cache``; cleared by :func:`analyses.sequential.clear_caches`).

When failures are rare among the hoses at risk (the default) a fraction ``p = 1 / (1 + margin^shape)`` of
them are force-set hoses' at the margin (the hazard ratio's share), the log hazard ratio
``beta = shape ln margin`` has information ``p (1 - p)`` per failure (Schoenfeld 1983; 1/4 only when the
failures split evenly), the log life ratio is ``beta / shape`` and the estimated shape adds its own
variance (``shape^2 / D``, orthogonal to the log hazard scales at a common censoring distance): per
failure ``I / D = shape^2 p (1 - p) / (1 + beta^2 p (1 - p))``. With ``n`` hoses on test at once per
adjustment, a failed hose replaced by a new one (benches that keep running; what the stages pass,
:func:`analyses.test_plan.hoses_on_test`), the full 3x3 expected information (Escobar & Meeker 1994, in
the counting-process form with the renewal function's hoses at risk) at the bench distance where ``D``
failures are expected is inverted instead: many hoses per failure give the rare limit, few hoses run to
many failures nearly complete samples, ``p`` towards ``1 / (1 + margin)`` and ``I / D`` towards
``shape^2 p (1 - p)`` (1.5 instead of 1.03 per failure at margin 1.5, shape 2.5, 4 hoses each).

References: Schoenfeld, D. A. (1983). Sample-size formula for the proportional-hazards
regression model. Biometrics 39, 499-503. Escobar, L. A. & Meeker, W. Q. (1994). Fisher
information matrix for the extreme value, normal and logistic distributions and censored data.
Applied Statistics 43, 533-540. Andersen, P. K., Borgan, O., Gill, R. D. & Keiding, N. (1993).
Statistical Models Based on Counting Processes. Springer (ch. VI: the information of a hazard
model as an integral over the numbers at risk).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from analyses.numerics import brentq
from analyses.sequential_boundaries import simpson


def _convolve(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """The first ``n`` coefficients of the product of the power series ``a`` and ``b`` (by FFT)."""
    size = 1 << (a.size + b.size - 1).bit_length()
    return np.fft.irfft(np.fft.rfft(a, size) * np.fft.rfft(b, size), size)[:n]


def _series_inverse(a: np.ndarray) -> np.ndarray:
    """The power series ``b`` with ``a b = 1`` to ``a.size`` terms (``a[0] != 0``), by Newton's
    iteration ``b <- b (2 - a b)``, which doubles the correct terms each step (O(n log n))."""
    b = np.array([1.0 / a[0]])
    while b.size < a.size:
        m = min(2 * b.size, a.size)
        e = -_convolve(a[:m], b, m)
        e[0] += 2.0
        b = _convolve(b, e, m)
    return b


def _renewal_function(t: np.ndarray, scale: float, shape: float) -> np.ndarray:
    """Expected failures ``M(t)`` of one bench by bench distance ``t`` when each failed hose is
    replaced at once: the renewal equation ``M(t) = F(t) + int_0^t M(t - u) dF(u)`` on the uniform
    grid ``t`` from 0, the integral by the trapezoidal rule in ``M`` (error O(step^2)).

    The discretised equation is lower-triangular Toeplitz, ``sum_l a_l M_{i-l} = F_i`` with ``a_0 = 1 -
    dF_0 / 2`` and ``a_l = -(dF_l + dF_{l-1}) / 2``: a product of power series, so ``M = F / a``,
    solved by series inversion in O(n log n) instead of step by step (the same values to ~1e-13)."""
    f = -np.expm1(-(t / scale) ** shape)
    if t.size < 2:
        return np.zeros(t.size)
    df = np.diff(f)
    a = np.empty(t.size)
    a[0] = 1.0 - 0.5 * df[0]
    a[1:] = -0.5 * (np.append(df[1:], 0.0) + df)
    m = _convolve(f, _series_inverse(a), t.size)
    m[0] = 0.0
    return m


def _bench_information(distance: float, scale: float, shape: float, t: np.ndarray,
                       m: np.ndarray) -> np.ndarray:
    """Expected Fisher information on ``(a, shape)`` of one bench run to ``distance`` [km], a failed
    hose replaced at once (``m``: :func:`_renewal_function` on the grid ``t``).

    Weibull cumulative hazard ``H(x) = e^a x^shape`` (``a = -shape ln scale``). In counting-process
    form (Andersen et al. 1993, ch. VI) the information is ``int Y(x) h(x) s(x) s(x)^T dx`` with
    ``s = (1, 1/shape + ln x)`` the score of ``ln h`` and ``Y(x) = S(x) (1 + M(distance - x))`` the
    expected number of hoses at risk at age ``x`` (one per start: the first and each renewal); a
    bench without renewal (``M = 0``) gives Escobar & Meeker's (1994) censored information. The
    integral is taken over ``ln H`` (the integrand vanishes as ``H ln^2 H`` at 0).
    """
    c = (distance / scale) ** shape
    lv, w = simpson(math.log(c) - 40.0, math.log(c), 0.05)
    v = np.exp(lv)
    x = scale * v ** (1.0 / shape)
    s = 1.0 / shape + math.log(scale) + lv / shape        # 1/shape + ln x
    dens = w * v * np.exp(-v) * (1.0 + np.interp(distance - x, t, m))
    return np.array([dens.sum(), dens @ s, dens @ (s * s)])


@functools.lru_cache(maxsize=4096)
def information_per_failure(margin: float, shape: float, failures: float | None = None,
                            hoses_per_adjustment: int | None = None) -> tuple[float, float]:
    """Expected information on the log life ratio per failure, the shape estimated, at ``margin``.

    Parameters
    ----------
    margin : float
        True life ratio force / distance [-] (> 1).
    shape : float
        Common Weibull shape [-].
    failures : float, optional
        Failures (both adjustments) at the look [-]; used with ``hoses_per_adjustment``.
    hoses_per_adjustment : int, optional
        Hoses on test at once per adjustment (the benches), a failed hose replaced by a new one at
        once [-]. None (default): failures rare among the hoses at risk.

    Returns
    -------
    (float, float)
        ``(I / D, p)``: information on ``ln(force life / distance life)`` per failure [-] and the
        expected force-set share of the failures [-]. Failures rare: ``p = 1 / (1 + margin^shape)``
        (the hazard ratio's share) and ``I / D = shape^2 p (1 - p) / (1 + beta^2 p (1 - p))``,
        ``beta = shape ln margin`` the log hazard ratio: Schoenfeld's (1983) ``p (1 - p)`` per failure
        for ``beta`` (1/4 only when the failures split evenly), divided by the shape for the life
        ratio, and the shape's own uncertainty (``Var(shape_hat) = shape^2 / D``) added through
        ``ln ratio = beta / shape``. With ``n`` hoses on test per adjustment, each bench run to the
        distance where ``D`` failures are expected, the 3x3 expected information of the common-shape
        Weibull regression on (both log hazard scales, the shape) is inverted
        (:func:`_bench_information`): many benches give the rare limit, few benches run to many
        failures nearly complete samples (``p`` towards ``1 / (1 + margin)``, the renewal rates'
        share, and ``I / D`` towards ``shape^2 p (1 - p)``).

    Raises
    ------
    NoDesign
        Where the benches' information does not exist in double precision (a shape so steep that
        one adjustment's hoses fail with a probability below it on the renewal grid: the 3x3
        matrix singular, or a power overflowing). The rare-failure figure is no stand-in: it is
        another design's, the least information per failure, larger by an amount unknown there.
    """
    beta = shape * math.log(margin)
    rare = 1.0 / (1.0 + math.exp(beta))
    if hoses_per_adjustment is None or failures is None or not failures > 0:
        q = rare * (1.0 - rare)
        return shape ** 2 * q / (1.0 + beta ** 2 * q), rare
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):   # a non-finite figure is refused below
            info, share = _bench_figure(margin, shape, failures, float(hoses_per_adjustment))
    except (np.linalg.LinAlgError, OverflowError, ZeroDivisionError) as exc:
        raise NoDesign(f"no sequential design at shape {shape:.3g} with {hoses_per_adjustment} hose(s) on test "
                       f"per adjustment: their expected information at {failures:g} failures does not exist in "
                       f"double precision ({type(exc).__name__})") from None
    if not (math.isfinite(info) and info > 0):
        raise NoDesign(f"no sequential design at shape {shape:.3g} with {hoses_per_adjustment} hose(s) on test "
                       f"per adjustment: their expected information at {failures:g} failures is {info:g}")
    return info, share


class NoDesign(ValueError):
    """The sequential design does not exist in double precision for these arguments (the message says
    why); the stages write its maximum NULL with the message as the note."""


def _bench_figure(margin: float, shape: float, failures: float, n: float) -> tuple[float, float]:
    """:func:`information_per_failure` with ``n`` hoses on test per adjustment (may raise where the
    figure does not exist in double precision)."""
    beta = shape * math.log(margin)
    scale_f = margin   # distance-set scale 1: force-set scale = margin
    # the grid reaches past the distance of D failures: without renewals that distance is the
    # largest (renewals add failures); with D near 2n a bench fails about once a mean life
    # (<= 1.2 scales at shape >= 0.5)
    top = 1.5 * scale_f * (failures / n + 3.0) * max(1.0, math.gamma(1.0 + 1.0 / shape))
    if failures < 1.9 * n:
        top = 1.001 * brentq(lambda x: -n * (math.expm1(-x ** shape) + math.expm1(-(x / scale_f) ** shape))
                                      - failures, 0.0, top)
    t = np.linspace(0.0, top, int(min(4001, max(401, 20.0 * top))))
    m_d, m_f = _renewal_function(t, 1.0, shape), _renewal_function(t, scale_f, shape)
    dist = float(np.interp(failures, n * (m_d + m_f), t))   # expected failures increase with the distance
    info_d, info_f = _bench_information(dist, 1.0, shape, t, m_d), _bench_information(dist, scale_f, shape, t, m_f)
    f_d, f_f = np.interp(dist, t, m_d), np.interp(dist, t, m_f)
    mat = np.zeros((3, 3))
    mat[0, 0], mat[1, 1] = info_d[0], info_f[0]
    mat[0, 2] = mat[2, 0] = info_d[1]
    mat[1, 2] = mat[2, 1] = info_f[1]
    mat[2, 2] = info_d[2] + info_f[2]
    grad = np.array([1.0, -1.0, -beta / shape]) / shape   # ln ratio = (a_distance - a_force) / shape
    var = grad @ np.linalg.solve(n * mat, grad)
    return float(1.0 / (var * failures)), float(f_f / (f_d + f_f))


def rare_failure_power(boundaries, margin: float, shape: float) -> float:
    """Power of the verdict read at every failure, failures rare, by the exact binomial recursion.

    When failures are rare among the hoses at risk the common-shape fit at a look of ``d``
    failures, ``f`` of them force-set, is a function of ``(d, f)``: the log hazard ratio is
    ``beta_hat = ln((d - f) / f)`` (the exposures are equal), the log life ratio
    ``beta_hat / shape`` and its variance ``(1 / (d - f) + 1 / f + beta_hat^2 / d) / shape^2``
    (:func:`information_per_failure`). Each failure is force-set with probability
    ``p = 1 / (1 + margin^shape)``, independently, so the distribution of ``f`` among the trials
    still running is carried look to look exactly, and every look's verdict applied as
    :func:`~analyses.sequential.sequential_verdict` does: no estimate until each adjustment has two failures,
    ``force longer`` when ``z >= c_d``, stop at ``distance longer`` or ``no practical difference``.
    This is the Wald z's small-sample distribution, which the canonical ``N(drift sqrt(t), 1)``
    is not at the margin: its SE grows with the estimate, so its spread is below 1 (0.69 at margin
    1.5, shape 2), and it cannot exceed about ``sqrt(d)`` at a look of ``d`` failures.

    Parameters
    ----------
    boundaries : array_like
        ``c_d`` [-] for looks at failures ``1..M``
        (:func:`~analyses.sequential_boundaries.efficacy_boundaries` at ``d / M``).
    margin : float
        True life ratio force / distance [-] (> 1).
    shape : float
        Common Weibull shape [-].

    Returns
    -------
    float
        P(``force longer`` by failure ``M``) [-].
    """
    beta, lm = shape * math.log(margin), math.log(margin)
    p = 1.0 / (1.0 + math.exp(beta))
    c = np.asarray(boundaries, float)
    d, f = np.arange(1, c.size + 1)[:, None], np.arange(c.size + 1)[None, :]   # every look's counts at once
    ok = (f >= 2) & (d - f >= 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        b = np.log((d - f) / f)
        est, half = b / shape, c[:, None] * np.sqrt(1.0 / (d - f) + 1.0 / f + b * b / d) / shape
        ups = ok & (est >= half)
        stops = ok & ((np.abs(est) >= half) | (np.abs(est) + half < lm))
    mass, power = np.zeros(c.size + 1), 0.0
    mass[0] = 1.0
    for up, stop in zip(ups, stops):
        mass[1:] = mass[1:] * (1.0 - p) + mass[:-1] * p
        mass[0] *= 1.0 - p
        power += float(mass[up].sum())
        mass = np.where(stop, 0.0, mass)
    return power
