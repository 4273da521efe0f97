"""The sequential verdict: a group-sequential design read at every failure.

The life ratio (force / distance) is estimated as ``log_ratio`` with a standard error after each
failure. Reading a fixed-sample 95 % test every morning and stopping at the first significance
declares a difference far more often than 5 % of the time when there is none; this module keeps
the two-sided error rate at ``alpha`` however often it is read (Jennison & Turnbull 2000,
*Group Sequential Methods with Applications to Clinical Trials*, ch. 2, 7, 9 and 19).

Alpha spending (Lan & DeMets 1983)
----------------------------------
The information fraction of a look is ``t = failures / max_failures`` (capped at 1). A spending
function ``alpha(t)`` says how much of the two-sided ``alpha`` may have been spent by ``t``:

* O'Brien-Fleming type: ``alpha(t) = 2 - 2 Phi(z_{1-alpha/2} / sqrt(t))`` (almost nothing early,
  boundaries near the fixed-sample 1.96 at the end);
* Pocock type: ``alpha(t) = alpha ln(1 + (e - 1) t)`` (even spending, wider final boundary).

Boundaries (exact, not simulated)
---------------------------------
The z statistics ``Z_k = log_ratio_k / se_k`` have the canonical joint distribution (J&T
section 3.1): ``Z_k ~ N(theta sqrt(I_k), 1)`` with independent increments of the score
``Z_k sqrt(I_k)``. The two-sided efficacy boundary ``c_k`` of look ``k`` solves
``P(|Z_k| >= c_k, |Z_j| < c_j for j < k | theta = 0) = alpha(t_k) - alpha(t_{k-1})``; that
probability is computed by recursive numerical integration of the density of ``Z_k`` on the
continuation region (Armitage, McPherson & Rowe 1969; J&T ch. 19), Simpson's rule on a grid
finer than the standard deviation of the increment, so boundaries for a look at every one of
hundreds of failures are exact to ~1e-6. Each look's ``c_k`` is Newton's root of that probability
(its derivative is the density at ``+/- c_k``), started from the last looks' boundaries. A design's
boundaries are computed forward only as far as they are asked for and kept per design
(:class:`_Design`): the first looks of an even design ``k / M`` are those of the whole design. The
power at any drift comes from the same null recursion by a change of measure: the likelihood ratio
of Brownian motion with drift ``theta`` against none, ``exp(theta S - theta^2 t / 2)``, depends only
on the score ``S`` at the end of the path (Siegmund 1985, *Sequential Analysis*, Springer, ch. III;
J&T section 19.2), so the sub-density under a drift is the null one reweighted
(:meth:`_Design.upper_power`); the inflation factor's drift search needs no new recursion.

The verdict
-----------
At every look the repeated confidence interval (RCI, J&T ch. 9) is
``log_ratio +/- c_k se_k``: all of them together cover the true log ratio with probability at
least ``1 - alpha``. The verdict is the first look where

* the RCI excludes 0 (``|Z_k| >= c_k``): ``force longer`` (log ratio > 0) or ``distance longer``;
* else the RCI lies inside ``(-ln margin, ln margin)``: ``no practical difference`` (if the true
  ratio is the margin or beyond, this happens with probability at most ``alpha / 2``, since that
  RCI would miss the truth);

once declared it sticks: later looks are reported, the verdict does not change. Stopping for
"no practical difference" can only lower the chance of a false difference (a non-binding
futility rule), so the efficacy error stays at most ``alpha``. Looks with no new information
(``t`` not above the previous look's, e.g. past ``max_failures``) are reported but do not decide.

Maximum information
-------------------
For a margin ``m``, ``alpha`` and ``power``, the fixed-sample design needs information
``I_fix = ((z_{1-alpha/2} + z_power) / ln m)^2``; the sequential design needs ``R * I_fix``
where the inflation factor ``R`` is found exactly: the drift at which the design's probability of
crossing the upper boundary equals ``power`` (J&T section 2.5, Tables 2.4 and 2.6). Information is
converted to failures with the expected information of the common-shape Weibull regression, the
shape estimated (:func:`information_per_failure`). When failures are rare among the hoses at risk
(the default) a fraction ``p = 1 / (1 + margin^shape)`` of them are force-set
hoses' at the margin (the hazard ratio's share), the log hazard ratio ``beta = shape ln margin``
has information ``p (1 - p)`` per failure (Schoenfeld 1983; 1/4 only when the failures split
evenly), the log life ratio is ``beta / shape`` and the estimated shape adds its own variance
(``shape^2 / D``, orthogonal to the log hazard scales at a common censoring distance): per failure
``I / D = shape^2 p (1 - p) / (1 + beta^2 p (1 - p))``. With ``n`` hoses on test at once per
adjustment, a failed hose replaced by a new one (benches that keep running; what the stages pass,
:func:`analyses.test_plan.hoses_on_test`), the full 3x3 expected information (Escobar & Meeker
1994, in the counting-process form with the renewal function's hoses at risk) at the bench
distance where ``D`` failures are expected is inverted instead: many hoses per failure give the
rare limit, few hoses run to many failures nearly complete samples, ``p`` towards
``1 / (1 + margin)`` and ``I / D`` towards ``shape^2 p (1 - p)`` (1.5 instead of 1.03 per failure at
margin 1.5, shape 2.5, 4 hoses each). The canonical process is not the refitted Wald z at the
margin: its SE grows with the estimate, so its spread is below 1, and at a look of ``d`` failures
it cannot exceed about ``sqrt(d)``. With failures rare and at most :data:`DESIGN_LOOKS` failures,
``max_failures`` is therefore the smallest maximum whose exact power reaches the target
(:func:`rare_failure_power`, a binomial recursion over the force-set count); with hoses on test it
is the canonical ``R I_fix / (I / D)``, capped at that rare figure (hoses on test never carry less
information per failure). ``benchmarks/bench_test_plan.py`` checks both against brute-force
simulation with a full refit at every failure (docs/decision.md, "failures_needed, right" and
"Designing from the hoses on test").

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
from dataclasses import dataclass

import numpy as np
import scipy  # its submodules load on first use: a rebuild whose decision stage has no hoses never pays for them

from analyses.numerics import brentq, norm_isf, norm_pdf, norm_sf
from analyses.service_life import newton_root

SPENDING = ("obrien-fleming", "pocock")
VERDICTS = ("force longer", "distance longer", "no practical difference", "undecided")
_NO_BOUNDARY = 40.0   # z: a look that may spend (almost) nothing gets this, i.e. cannot cross
_TAIL = 9.0           # the density grid is cut this many sds from the drift's mean: 1e-19 lost
#: Looks beyond which a design's inflation factor ``R`` is taken as that of this many looks: ``R``
#: grows with the looks towards the continuous-monitoring limit, and from 80 to 160 equally
#: spaced looks it grows by 0.16 % (O'Brien-Fleming-type, 1.0717 -> 1.0734) and 0.21 % (Pocock-
#: type, 1.2818 -> 1.2845) at alpha 0.05, power 0.8; the exact recursion's cost grows as the
#: looks to the power 1.5-2, and a design for a shape near 1 and a margin near 1 asks for hundreds
#: of failures, each a look.
DESIGN_LOOKS = 100
#: Expected failures of the adjustment that lives longer below which ``max_information`` notes
#: that its figure is likely short: at margin 1.75, shape 3 (4 expected of 23) the brute force
#: needed 30 (-23 %) before the decision's likelihood check of a crossing; with it 22 (+5 %, 300
#: trials): the note stays, the Wald interval is too narrow there; at 13 and more expected
#: (margins 1.5-2, shapes 1.5-2, O'Brien-Fleming) within 10 %.
FEW_FAILURES = 10


def alpha_spent(t, alpha: float = 0.05, spending: str = "obrien-fleming") -> np.ndarray:
    """Two-sided alpha spent by information fraction ``t`` (Lan & DeMets 1983).

    Parameters
    ----------
    t : array_like
        Information fractions [-], capped at 1 (``t <= 0`` spends nothing).
    alpha : float
        Two-sided error rate of the whole design [-].
    spending : {"obrien-fleming", "pocock"}
        The Lan-DeMets family.

    Returns
    -------
    numpy.ndarray
        ``alpha(t)`` [-]: 0 at ``t = 0``, ``alpha`` at ``t >= 1``.
    """
    t = np.clip(np.asarray(t, float), 0.0, 1.0)
    if spending == "obrien-fleming":
        with np.errstate(divide="ignore"):
            out = 2.0 * norm_sf(norm_isf(alpha / 2.0) / np.sqrt(t))
    elif spending == "pocock":
        out = alpha * np.log1p((math.e - 1.0) * t)
    else:
        raise ValueError(f"spending must be one of {SPENDING}, not {spending!r}")
    return np.where(t > 0, out, 0.0)


def _simpson(lo: float, hi: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid points and Simpson weights on ``[lo, hi]`` with a step at most ``h``."""
    n = max(2, int(math.ceil((hi - lo) / h)))
    n += n % 2
    z = np.linspace(lo, hi, n + 1)
    w = np.ones(n + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    return z, w * (hi - lo) / (3.0 * n)


class _Recursion:
    """The sub-density of ``Z_k`` on the continuation region, carried look to look.

    ``drift`` is ``theta sqrt(I_max)``: ``E[Z_k] = drift sqrt(t_k)``.
    """

    def __init__(self, t: np.ndarray, drift: float):
        self.t, self.drift, self.k = t, drift, 0
        inc = np.diff(np.concatenate([[0.0], t]))
        # a grid step resolving both the density here and the next look's increment kernel
        sd = np.sqrt(inc / t)
        nxt = np.sqrt(np.append(inc[1:], inc[-1]) / t)
        self.h = np.minimum(0.1, np.minimum(sd, nxt) / 4.0)
        self.z = self.w = self.g = None

    def exit_probabilities(self, c: float) -> tuple[float, float]:
        """(upper, lower) probability of first crossing ``+/- c`` at the current look."""
        t, k, d = self.t, self.k, self.drift
        if k == 0:
            m = d * math.sqrt(t[0])
            return float(norm_sf(c - m)), float(scipy.special.ndtr(-c - m))
        inc = t[k] - t[k - 1]
        mean = self.z * math.sqrt(t[k - 1]) + d * inc
        s = math.sqrt(inc)
        up = scipy.special.ndtr((mean - c * math.sqrt(t[k])) / s)
        lo = scipy.special.ndtr((-c * math.sqrt(t[k]) - mean) / s)
        wg = self.w * self.g
        return float(wg @ up), float(wg @ lo)

    def null_boundary(self, spend: float, start: float) -> float:
        """The boundary ``c`` of the current look at which the probability of first crossing ``+/- c``
        here is ``spend`` (drift 0): Newton's method on that strictly decreasing probability, with its
        derivative (the density at ``+/- c``), kept in a bracket (:func:`analyses.service_life.newton_root`;
        ``brentq`` when it does not settle inside ``(1e-6, _NO_BOUNDARY)``)."""
        t, k = self.t, self.k
        if k == 0:   # the first look: the normal quantile itself
            return float(norm_isf(spend / 2.0))
        score, wg, s, rt = self.z * math.sqrt(t[k - 1]), self.w * self.g, math.sqrt(t[k] - t[k - 1]), math.sqrt(t[k])

        def value_slope(c):
            a, b = (score - c * rt) / s, (-c * rt - score) / s
            return (float(wg @ (scipy.special.ndtr(a) + scipy.special.ndtr(b))) - spend,
                    -float(wg @ (np.exp(-0.5 * a * a) + np.exp(-0.5 * b * b))) * rt / (s * math.sqrt(2 * math.pi)))
        c = newton_root(value_slope, 1e-6, _NO_BOUNDARY, start, xtol=1e-18)
        if c is None:
            c = brentq(lambda c: value_slope(c)[0], 1e-6, _NO_BOUNDARY, xtol=1e-10, rtol=1e-12)
        return c

    def exit_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """The current look's continuation grid as (score ``z sqrt(t)`` at the previous look, mass
        ``w g`` there) [-], for :meth:`_Design.upper_power`."""
        return self.z * math.sqrt(self.t[self.k - 1]), self.w * self.g

    def advance(self, c: float) -> None:
        """Carry the density to the continuation region ``(-c, c)`` of the current look."""
        t, k, d = self.t, self.k, self.drift
        m = d * math.sqrt(t[k])
        lo, hi = max(-c, m - _TAIL), min(c, m + _TAIL)
        if lo >= hi:   # nothing continues: every later look is unreachable
            lo, hi = m - 1e-9, m + 1e-9
        z, w = _simpson(lo, hi, self.h[k])
        if k == 0:
            g = norm_pdf(z - m)
        else:
            inc = t[k] - t[k - 1]
            s = math.sqrt(inc)
            # u = (z sqrt(t_k) - z_prev sqrt(t_k-1) - d inc) / s and exp(-0.5 u u), the same operations in the
            # same order as written out, in one buffer (no temporaries; subtracting a zero drift is skipped)
            u = np.subtract.outer(z * math.sqrt(t[k]), self.z * math.sqrt(t[k - 1]))
            if d:
                u -= d * inc
            u /= s
            e = np.multiply(u, -0.5)
            e *= u
            g = (np.exp(e, out=e) @ (self.w * self.g)) * math.sqrt(t[k]) / (s * math.sqrt(2 * math.pi))
        self.z, self.w, self.g, self.k = z, w, g, k + 1


def _check_fractions(t) -> np.ndarray:
    t = np.asarray(t, float)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)) or t[0] <= 0 or np.any(np.diff(t) <= 0):
        raise ValueError("information fractions must be finite, positive and strictly increasing")
    return t


def efficacy_boundaries(t, alpha: float = 0.05, spending: str = "obrien-fleming") -> np.ndarray:
    """Two-sided efficacy boundaries on the z scale for looks at information fractions ``t``.

    Parameters
    ----------
    t : array_like
        Information fractions of the looks [-], strictly increasing, in (0, 1]; a last fraction
        below 1 leaves the rest of ``alpha`` unspent (the test is not over).
    alpha : float
        Two-sided error rate of the whole design [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.

    Returns
    -------
    numpy.ndarray
        ``c_k`` [-]: look ``k`` crosses when ``|log_ratio / se| >= c_k``. ``_NO_BOUNDARY`` (40)
        where the spending allows less than 1e-15 (early O'Brien-Fleming looks).
    """
    tt = tuple(_check_fractions(np.minimum(t, 1.0)).tolist())
    m = _grid_of(tt)   # the first looks of an even design: the whole design's first boundaries
    return np.array(_design_of(tt if m is None else m, alpha, spending).boundaries(len(tt)))


def _grid_of(t: tuple) -> int | None:
    """``M`` when the looks ``t`` are the first of the even design ``(1/M, 2/M, ..., 1)`` (``t_k = k /
    M`` exactly as ``failures / max_failures`` gives them), else None. A boundary depends only on the
    looks up to it (the recursion runs forward: Armitage, McPherson & Rowe 1969), so the first
    looks' boundaries are those of the whole design, computed once per design and only as far as
    they are asked for (:class:`_Design`)."""
    m = round(1.0 / t[0])
    if m < 1 or len(t) > m or any(v != (k + 1) / m for k, v in enumerate(t)):
        return None
    return m


class _Design:
    """One design's boundaries, computed forward look by look as far as they are asked for, and kept.

    ``record``: keep every look's continuation grid (:meth:`_Recursion.exit_terms`), from which
    :meth:`upper_power` gives the power at any drift without a new recursion.
    """

    def __init__(self, t: np.ndarray, alpha: float, spending: str, record: bool = False):
        self.t = t
        self.spend = np.diff(np.concatenate([[0.0], alpha_spent(t, alpha, spending)]))
        self.rec, self.c = _Recursion(t, 0.0), []
        self.terms = [] if record else None
        self._flat = None

    def boundaries(self, looks: int) -> list:
        """The first ``looks`` boundaries ``c_k`` [-] (:func:`efficacy_boundaries`)."""
        while len(self.c) < looks:
            k = len(self.c)
            if self.spend[k] < 1e-15:
                c = _NO_BOUNDARY
            else:   # Newton from the last looks' boundaries, extrapolated (they move little and smoothly)
                c = self.rec.null_boundary(float(self.spend[k]), _next_start(self.c))
            if self.terms is not None and k:
                self.terms.append(self.rec.exit_terms())
            self.c.append(c)
            self.rec.advance(c)
        return self.c[:looks]

    def upper_power(self, drift: float) -> float:
        """P(cross the upper boundary at some look | ``drift``) [-], the design's power, by a change of
        measure: under a drift ``d`` the sub-density of the score ``S = Z sqrt(t)`` on the continuation
        region is the null one times the likelihood ratio ``exp(d S - d^2 t / 2)`` of Brownian motion
        with drift, which depends only on the path's end (J&T section 19.2; Siegmund 1985, ch. III),
        so one null recursion serves every drift. Agrees with :func:`crossing_probabilities` to ~1e-9."""
        if not abs(drift) <= _MAX_DRIFT:
            raise ValueError(f"drift must be within +/- {_MAX_DRIFT}, not {drift}")
        if self._flat is None:
            self.boundaries(self.t.size)
            t, c, parts = self.t, np.array(self.c), self.terms
            sizes = [p[0].size for p in parts]
            per_look = np.stack([t[:-1], np.diff(t), c[1:] * np.sqrt(t[1:])])
            flat = np.vstack([np.concatenate([p[0] for p in parts] or [np.zeros(0)]),
                              np.concatenate([p[1] for p in parts] or [np.zeros(0)]),
                              np.repeat(per_look, sizes, axis=1)])
            # grid points too far below the upper boundary to reach it at any drift up to _MAX_DRIFT: their
            # term is below 1e-35 of their mass times the likelihood ratio, itself below e^40.5 (|z| <= 9)
            far = (flat[4] - flat[0]) / np.sqrt(flat[3]) > 13.0 + _MAX_DRIFT * np.sqrt(flat[3])
            self._flat, self.terms = flat[:, ~far], []
        score, mass, t_prev, inc, bound = self._flat
        first = float(norm_sf(self.c[0] - drift * math.sqrt(self.t[0])))
        ratio = np.exp(drift * score - 0.5 * drift * drift * t_prev)
        return first + float(mass @ (ratio * scipy.special.ndtr((score + drift * inc - bound) / np.sqrt(inc))))


#: The largest drift :meth:`_Design.upper_power` is asked about [-]: ``3 (z_{1-alpha/2} + z_power)``, the
#: top of :func:`inflation_factor`'s bracket, is 17 at alpha 0.001 and power 0.99.
_MAX_DRIFT = 25.0


def _next_start(c: list) -> float:
    """A start for the next look's boundary: the last two extrapolated (2.0 before any finite one)."""
    if not c or c[-1] >= _NO_BOUNDARY:
        return 2.0
    if len(c) < 2 or c[-2] >= _NO_BOUNDARY:
        return c[-1]
    return 2.0 * c[-1] - c[-2]


#: Designs computed in this process (:func:`_design_of`), oldest first; at most :data:`_KEPT_DESIGNS`.
_DESIGNS: dict = {}
_KEPT_DESIGNS = 512


def _design_of(key, alpha: float, spending: str, record: bool = False) -> _Design:
    """The :class:`_Design` of ``key`` (``M``: the even design ``k / M``; else a tuple of fractions),
    kept in this process. One of at most :data:`DESIGN_LOOKS` looks keeps its grids (its power is
    asked for by :func:`inflation_factor`, its boundaries by the rare-failure design); ``record``:
    keep them whatever the looks (replacing one that did not)."""
    k = (key, alpha, spending)
    design = _DESIGNS.get(k)
    if design is None or (record and design.terms is None):
        t = np.arange(1, key + 1) / key if isinstance(key, int) else np.array(key)
        design = _DESIGNS[k] = _Design(t, alpha, spending, record or t.size <= DESIGN_LOOKS)
        while len(_DESIGNS) > _KEPT_DESIGNS:
            del _DESIGNS[next(iter(_DESIGNS))]
    return design


def clear_caches() -> None:
    """Forget every design, inflation factor and boundary computed in this process (a cold start:
    ``benchmarks/bench_decision_stage.py`` times a first rebuild)."""
    _DESIGNS.clear()
    inflation_factor.cache_clear()
    information_per_failure.cache_clear()
    _design_on_grid.cache_clear()
    _rare_power.cache_clear()


def crossing_probabilities(boundaries, t, drift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Probability of first crossing each look's upper and lower boundary, exactly.

    Parameters
    ----------
    boundaries : array_like
        Two-sided boundaries ``c_k`` on the z scale [-].
    t : array_like
        Information fractions of the looks [-], strictly increasing.
    drift : float
        ``theta sqrt(I_max)`` [-]: the expected z statistic at ``t = 1`` (0 under no difference).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Per look, P(stop at this look through ``+c_k``) and through ``-c_k`` [-].
    """
    t = _check_fractions(t)
    rec, up, lo = _Recursion(t, float(drift)), [], []
    for c in np.asarray(boundaries, float):
        u, low = rec.exit_probabilities(c)
        up.append(u)
        lo.append(low)
        rec.advance(c)
    return np.array(up), np.array(lo)


@dataclass(frozen=True)
class MaxInformation:
    """What a sequential design needs to reach ``power`` at ``margin``.

    Attributes
    ----------
    failures : int
        Failures (both adjustments together) at which the test ends: ``max_failures`` [-]. With
        failures rare (the default) and at most :data:`DESIGN_LOOKS`, the smallest maximum whose
        exact power (:func:`rare_failure_power`) reaches the target; else ``ceil(R I_fix / (I /
        D))`` from the canonical process (with hoses on test, at most the rare figure).
    failures_fixed : float
        Failures a fixed-sample test read once would need [-] (canonical process).
    inflation : float
        ``R``: the sequential design's maximum information over the fixed sample's [-].
    drift : float
        ``theta sqrt(I_max)`` at the margin [-].
    looks : int
        Equally spaced looks assumed (``failures`` when every failure is a look) [-].
    note : str or None
        Set when fewer than :data:`FEW_FAILURES` failures of the adjustment that lives longer are
        expected by ``failures``, or the spending is Pocock-type: the refitted Wald interval is
        too narrow at few failures and ``failures`` is likely short of what the test needs
        (docs/decision.md, "failures_needed, right").
    """

    failures: int
    failures_fixed: float
    inflation: float
    drift: float
    looks: int
    note: str | None = None


@functools.lru_cache(maxsize=1024)
def inflation_factor(looks: int, alpha: float = 0.05, power: float = 0.8,
                     spending: str = "obrien-fleming") -> tuple[float, float]:
    """``(R, drift)`` of a design with ``looks`` equally spaced looks, computed exactly.

    ``drift`` solves P(cross the upper boundary | drift) = ``power`` (:meth:`_Design.upper_power`:
    one null recursion, each drift a weighted sum over its grids);
    ``R = (drift / (z_{1-alpha/2} + z_power))^2`` [-]. ``R`` is 1 for one look and below ~1.3
    (O'Brien-Fleming ~1.07, Pocock ~1.29 at a look per failure), so the root is bracketed in
    ``R`` 0.99..1.69 first. Shared by every design of these looks, alpha, power and spending,
    whatever their margin, shape and hoses on test.
    """
    design = _design_of(int(looks), alpha, spending, record=True)
    fixed = norm_isf(alpha / 2) + scipy.special.ndtri(power)

    def excess(d):
        return design.upper_power(d) - power

    lo, hi = 0.995 * fixed, 1.3 * fixed
    if excess(hi) < 0:
        lo, hi = hi, 3.0 * fixed
    drift = brentq(excess, lo, hi, xtol=1e-7)
    return (drift / fixed) ** 2, drift


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
    lv, w = _simpson(math.log(c) - 40.0, math.log(c), 0.05)
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
    :func:`sequential_verdict` does: no estimate until each adjustment has two failures,
    ``force longer`` when ``z >= c_d``, stop at ``distance longer`` or ``no practical difference``.
    This is the Wald z's small-sample distribution, which the canonical ``N(drift sqrt(t), 1)``
    is not at the margin: its SE grows with the estimate, so its spread is below 1 (0.69 at margin
    1.5, shape 2), and it cannot exceed about ``sqrt(d)`` at a look of ``d`` failures.

    Parameters
    ----------
    boundaries : array_like
        ``c_d`` [-] for looks at failures ``1..M`` (:func:`efficacy_boundaries` at ``d / M``).
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


@functools.lru_cache(maxsize=8192)
def _rare_power(m: int, margin: float, alpha: float, spending: str, shape: float) -> float:
    """:func:`rare_failure_power` of the even design of ``m`` looks, kept per arguments: the bisections of
    designs that differ only in their hoses on test or target power (one grid shape) visit the same
    maxima, and take the same figure instead of computing it again."""
    return rare_failure_power(efficacy_boundaries(np.arange(1, m + 1) / m, alpha, spending), margin, shape)


def _smallest_rare_maximum(start: int, margin: float, alpha: float, power: float, spending: str,
                           shape: float) -> int | None:
    """Smallest ``M`` whose :func:`rare_failure_power` reaches ``power``, by bisection from ``start``
    (None when none up to :data:`DESIGN_LOOKS` does)."""
    def reaches(m):
        return _rare_power(m, margin, alpha, spending, shape) >= power

    lo, hi = max(4, start // 2), min(DESIGN_LOOKS, max(8, start))
    while not reaches(hi):
        if hi == DESIGN_LOOKS:
            return None
        lo, hi = hi, min(DESIGN_LOOKS, 2 * hi)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if reaches(mid) else (mid, hi)
    return hi


def max_information(margin: float, alpha: float = 0.05, power: float = 0.8,
                    spending: str = "obrien-fleming", shape: float = 1.0, looks: int | None = None,
                    hoses_per_adjustment: int | None = None) -> MaxInformation:
    """The failures a sequential test needs to decide at ``margin`` with ``power``.

    Parameters
    ----------
    margin : float
        Smallest life ratio worth acting on [-], > 1 (a ratio ``1 / margin`` is the same).
    alpha : float
        Two-sided error rate [-].
    power : float
        Probability of declaring ``force longer`` when the true ratio is ``margin`` [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.
    shape : float
        Weibull shape [-] (common to both adjustments): information per failure is
        ``shape^2 p (1 - p)``, ``p`` the force-set share of the failures (:func:`information_per_failure`).
    looks : int, optional
        Equally spaced looks; None (default) means a look at every failure, found as the fixed
        point ``looks = failures``. Above :data:`DESIGN_LOOKS` looks ``R`` is that of
        :data:`DESIGN_LOOKS` looks (within 0.3 % of the exact value, slightly below it).
    hoses_per_adjustment : int, optional
        Hoses on test at once per adjustment, a failed hose replaced by a new one (the benches keep
        running; the stages pass :func:`analyses.test_plan.hoses_on_test`): the information per
        failure of that follow-up (:func:`information_per_failure`) and the canonical process,
        capped at the rare-failure design's exact figure. None: failures rare among the hoses at
        risk, ``p = 1 / (1 + margin^shape)``, the fewest information per failure, so the most
        failures.

    Returns
    -------
    MaxInformation
        ``failures_fixed = I_fix / (shape^2 p (1 - p))``.
    """
    margin = max(margin, 1.0 / margin)
    if not margin > 1.0 or not shape > 0:
        raise ValueError("margin must differ from 1 and shape be positive")
    i_fix = ((norm_isf(alpha / 2) + scipy.special.ndtri(power)) / math.log(margin)) ** 2

    def per_failure(d):
        return information_per_failure(margin, shape, d, hoses_per_adjustment)[0]

    fixed = i_fix / per_failure(None)
    k = looks or max(1, math.ceil(fixed))
    for _ in range(40):
        r, drift = inflation_factor(min(k, DESIGN_LOOKS), alpha, power, spending)
        fixed = i_fix / per_failure(k)
        failures = math.ceil(r * fixed - 1e-9)
        if looks or failures == k:
            break
        k = failures
    if looks is None and failures <= DESIGN_LOOKS:
        # hoses on test carry at least the rare failures' information per failure: never more failures
        exact = _smallest_rare_maximum(failures, margin, alpha, power, spending, shape)
        if exact is not None:
            failures = k = exact if hoses_per_adjustment is None else min(failures, exact)
    return MaxInformation(failures, fixed, r, drift, k, _short_note(failures, margin, shape, spending,
                                                                    hoses_per_adjustment))



#: Step, in log shape, of the grid the stages' designs are computed on (:func:`design_for`): 2 %,
#: so that 200 hose types whose shapes lie within a factor 1.5 share about 20 designs instead of
#: computing 200 (each 10-50 ms once the process holds the boundaries of its looks, which every
#: design of the same alpha and spending shares); the failures move by about twice the shape's rounding
#: (<= 2 %), where the fitted shape's own 90 % interval is +/- 30 % or more.
DESIGN_SHAPE_STEP = 0.02


def design_shape(shape: float) -> float:
    """``shape`` [-] rounded to the design grid (:data:`DESIGN_SHAPE_STEP` in log shape)."""
    return round(math.exp(round(math.log(shape) / DESIGN_SHAPE_STEP) * DESIGN_SHAPE_STEP), 9)


def design_for(margin: float, alpha: float, power: float, spending: str, shape: float,
               hoses_per_adjustment: int | None = None) -> MaxInformation:
    """:func:`max_information` with looks at every failure, at :func:`design_shape` of ``shape`` and
    ``hoses_per_adjustment`` on test (None: failures rare), cached per grid shape: the design both
    the decision and the test-plan stages read (the same arguments give the same ``max_failures``
    in both)."""
    return _design_on_grid(margin, alpha, power, spending, design_shape(shape), hoses_per_adjustment)


@functools.lru_cache(maxsize=1024)
def _design_on_grid(margin: float, alpha: float, power: float, spending: str, shape: float,
                    hoses: int | None) -> MaxInformation:
    return max_information(margin, alpha, power, spending, shape, hoses_per_adjustment=hoses)


def _short_note(failures: int, margin: float, shape: float, spending: str, hoses: int | None) -> str | None:
    """Why ``failures`` is likely short of what the refitted test needs, or None (FEW_FAILURES)."""
    fewer = failures * information_per_failure(margin, shape, failures, hoses)[1]
    if fewer < FEW_FAILURES:
        return (f"about {fewer:.0f} failures of the adjustment that lives longer expected by {failures}: the Wald "
                f"interval is too narrow at so few (the shape's small-sample bias), {failures} is likely short")
    if spending == "pocock":
        return ("Pocock-type spending decides at early looks, where the refitted Wald interval is too narrow: "
                f"{failures} may be short")
    return None


@dataclass(frozen=True)
class SequentialVerdict:
    """The verdict over a sequence of looks, and every look's boundaries.

    Per-look arrays (one entry a look, in the order given):

    Attributes
    ----------
    verdict : str
        One of ``VERDICTS``; sticks from ``decided_at`` on.
    decided_at : int or None
        Index of the deciding look; None while undecided.
    information_fraction : numpy.ndarray
        ``t`` [-], capped at 1.
    alpha_spent : numpy.ndarray
        Two-sided alpha spent by each look [-].
    boundary_z : numpy.ndarray
        Efficacy boundary ``c_k`` on the z scale [-].
    efficacy_lower, efficacy_upper : numpy.ndarray
        The log ratio beyond which the look crosses: ``-/+ c_k se`` [-].
    futility_lower, futility_upper : numpy.ndarray
        The log ratio between which "no practical difference" holds:
        ``-/+ (ln margin - c_k se)``; NaN where that range is empty [-].
    rci_lower, rci_upper : numpy.ndarray
        Repeated confidence interval of the log ratio, ``log_ratio -/+ c_k se`` [-].
    crossed : tuple of str
        Per look what its data showed: ``force longer``, ``distance longer``,
        ``no practical difference`` or ``""`` (also for a look without an estimate).
    note : str
        Why a look did not count, if any did not.
    """

    verdict: str
    decided_at: int | None
    information_fraction: np.ndarray
    alpha_spent: np.ndarray
    boundary_z: np.ndarray
    efficacy_lower: np.ndarray
    efficacy_upper: np.ndarray
    futility_lower: np.ndarray
    futility_upper: np.ndarray
    rci_lower: np.ndarray
    rci_upper: np.ndarray
    crossed: tuple
    note: str


def _look_boundaries(t: np.ndarray, alpha: float, spending: str) -> tuple[np.ndarray, np.ndarray]:
    """Boundary per look and whether the look brings new information (may decide)."""
    new = np.zeros(t.size, bool)
    last = 0.0
    for i, ti in enumerate(t):
        new[i] = ti > last
        last = max(last, ti)
    c = np.full(t.size, np.nan)
    if new.any():
        c[new] = efficacy_boundaries(t[new], alpha, spending)
    idx = np.maximum.accumulate(np.where(new, np.arange(t.size), -1))
    c = np.where(idx >= 0, c[np.maximum(idx, 0)], np.nan)   # no new information: the last boundary
    return c, new


def sequential_verdict(log_ratio, se, information_fraction, margin: float, alpha: float = 0.05,
                       spending: str = "obrien-fleming", confirm=None) -> SequentialVerdict:
    """The sticky verdict of a test read at every look.

    Parameters
    ----------
    log_ratio : array_like
        Per look, the estimated ln(force life / distance life) [-]; NaN where the data cannot
        tell yet (the look is reported, it does not decide).
    se : array_like
        Its standard error [-] (NaN or <= 0: no estimate).
    information_fraction : array_like
        ``failures / max_failures`` [-] per look (capped at 1), nondecreasing.
    margin : float
        Smallest life ratio worth acting on [-] (> 1).
    alpha : float
        Two-sided error rate of the verdict [-].
    spending : {"obrien-fleming", "pocock"}
        Lan-DeMets spending family.
    confirm : callable, optional
        ``confirm(index, crossed, boundary_z) -> bool``: a second check of a look that crossed on
        the Wald scale, e.g. the profile likelihood's deviance at the crossed value against
        ``boundary_z ** 2``; a look crosses only when both say so (with a refitted Weibull shape
        the Wald interval is too narrow in small samples: docs/decision.md).

    Returns
    -------
    SequentialVerdict
    """
    est, s = np.asarray(log_ratio, float), np.asarray(se, float)
    t = np.minimum(np.asarray(information_fraction, float), 1.0)
    if not (est.shape == s.shape == t.shape and est.ndim == 1):
        raise ValueError("log_ratio, se and information_fraction must be 1-d arrays of one length")
    if np.any(np.diff(t) < 0) or np.any(~np.isfinite(t)):
        raise ValueError("information fractions must be finite and nondecreasing")
    c, new = _look_boundaries(t, alpha, spending)
    lm = math.log(max(margin, 1.0 / margin))
    ok = np.isfinite(est) & np.isfinite(s) & (s > 0) & np.isfinite(c)
    with np.errstate(invalid="ignore"):
        half = np.where(ok, c * s, np.nan)
        lo, hi = est - half, est + half
        fut = np.where(lm - half > 0, lm - half, np.nan)
        crossed = np.select([ok & (lo > 0), ok & (hi < 0), ok & (lo > -lm) & (hi < lm)],
                            ["force longer", "distance longer", "no practical difference"], "")
    notes = []
    if confirm is not None:
        unconfirmed = [i for i in np.flatnonzero(crossed != "") if not confirm(int(i), str(crossed[i]), float(c[i]))]
        crossed[unconfirmed] = ""
        if unconfirmed:
            notes.append(f"{len(unconfirmed)} look(s) crossed on the Wald scale but not by the profile likelihood")
    deciding = np.flatnonzero((crossed != "") & new)
    at = int(deciding[0]) if deciding.size else None
    if (~ok).any():
        notes.append(f"{int((~ok).sum())} look(s) without an estimate")
    if (~new).any():
        notes.append(f"{int((~new).sum())} look(s) without new information (t not above the last) do not decide")
    return SequentialVerdict(
        verdict=str(crossed[at]) if at is not None else "undecided", decided_at=at,
        information_fraction=t, alpha_spent=alpha_spent(t, alpha, spending), boundary_z=c,
        efficacy_lower=-half, efficacy_upper=half, futility_lower=-fut, futility_upper=fut,
        rci_lower=lo, rci_upper=hi, crossed=tuple(str(x) for x in crossed), note="; ".join(notes))
