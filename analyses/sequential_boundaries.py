"""Alpha spending and the exact group-sequential boundaries: where a design of looks crosses, and its power.

A group-sequential design keeps the two-sided error rate at ``alpha`` however often it is read by spending
``alpha`` over its looks (Jennison & Turnbull 2000, *Group Sequential Methods with Applications to Clinical
Trials*, ch. 2, 7 and 19; J&T below). This module computes what depends only on the looks, ``alpha`` and the
spending function: the spending itself, each look's two-sided efficacy boundary, the probabilities of
crossing under any drift and the inflation factor of a design of equally spaced looks. Designs and inflation
factors are kept per process (``_DESIGNS``, the ``lru_cache`` of :func:`inflation_factor`; both cleared by
:func:`analyses.sequential.clear_caches`); :mod:`analyses.sequential_table` gives and takes the even designs as
arrays. The design search and the verdict that read them are :mod:`analyses.sequential`'s.

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
"""
from __future__ import annotations

import functools
import math

import numpy as np
import scipy  # its submodules load on first use: a rebuild whose decision stage has no hoses never pays for them

from analyses.numerics import brentq, norm_isf, norm_pdf, norm_sf
from analyses.service_life import newton_root

SPENDING = ("obrien-fleming", "pocock")
_NO_BOUNDARY = 40.0   # z: a look that may spend (almost) nothing gets this, i.e. cannot cross
_TAIL = 9.0           # the density grid is cut this many sds from the drift's mean: 1e-19 lost
#: Looks beyond which a design's inflation factor ``R`` is taken as that of this many looks: ``R``
#: grows with the looks towards the continuous-monitoring limit, and from 80 to 160 equally
#: spaced looks it grows by 0.16 % (O'Brien-Fleming-type, 1.0717 -> 1.0734) and 0.21 % (Pocock-
#: type, 1.2818 -> 1.2845) at alpha 0.05, power 0.8; the exact recursion's cost grows as the
#: looks to the power 1.5-2, and a design for a shape near 1 and a margin near 1 asks for hundreds
#: of failures, each a look.
DESIGN_LOOKS = 100


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


def simpson(lo: float, hi: float, h: float) -> tuple[np.ndarray, np.ndarray]:
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
        z, w = simpson(lo, hi, self.h[k])
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
