"""The sequential verdict: a group-sequential design read at every failure.

The life ratio (force / distance) is estimated as ``log_ratio`` with a standard error after each
failure. Reading a fixed-sample 95 % test every morning and stopping at the first significance
declares a difference far more often than 5 % of the time when there is none; this module keeps
the two-sided error rate at ``alpha`` however often it is read (Jennison & Turnbull 2000,
*Group Sequential Methods with Applications to Clinical Trials*, ch. 2, 7, 9 and 19; J&T below).
This module searches the design (the failures a test needs: :func:`max_information`, :func:`design_for`)
and reads the verdict at every look (:func:`sequential_verdict`). The spending functions, the boundaries and
a design's power are :mod:`analyses.sequential_boundaries`'s, the information per failure and the
rare-failure power :mod:`analyses.sequential_information`'s; :func:`clear_caches` forgets what all three
keep per process.

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
``I_fix = ((z_{1-alpha/2} + z_power) / ln m)^2``; the sequential design needs ``R * I_fix`` where the
inflation factor ``R`` is found exactly: the drift at which the design's probability of crossing the
upper boundary equals ``power`` (J&T section 2.5, Tables 2.4 and 2.6). Information is converted to
failures with the expected information of the common-shape Weibull regression, the shape estimated
(:func:`information_per_failure`). The canonical process is not the refitted Wald z at the margin: its SE
grows with the estimate, so its spread is below 1, and at a look of ``d`` failures it cannot exceed about
``sqrt(d)``. With failures rare and at most :data:`DESIGN_LOOKS` failures, ``max_failures`` is therefore
the smallest maximum whose exact power reaches the target (:func:`rare_failure_power`, a binomial
recursion over the force-set count); with hoses on test it is the canonical ``R I_fix / (I / D)``, capped
at that rare figure (hoses on test never carry less information per failure).
``benchmarks/bench_test_plan.py`` checks both against brute-force simulation with a full refit at every
failure (docs/decision.md, "failures_needed, right" and "Designing from the hoses on test").
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import scipy  # its submodules load on first use: a rebuild whose decision stage has no hoses never pays for them

from analyses.numerics import norm_isf
from analyses.sequential_boundaries import (_DESIGNS, DESIGN_LOOKS, alpha_spent, efficacy_boundaries,
                                           inflation_factor)
from analyses.sequential_information import information_per_failure, rare_failure_power

VERDICTS = ("force longer", "distance longer", "no practical difference", "undecided")
#: Expected failures of the adjustment that lives longer below which ``max_information`` notes
#: that its figure is likely short: at margin 1.75, shape 3 (4 expected of 23) the brute force
#: needed 30 (-23 %) before the decision's likelihood check of a crossing; with it 22 (+5 %, 300
#: trials): the note stays, the Wald interval is too narrow there; at 13 and more expected
#: (margins 1.5-2, shapes 1.5-2, O'Brien-Fleming) within 10 %.
FEW_FAILURES = 10


def clear_caches() -> None:
    """Forget every design, inflation factor and boundary computed in this process (a cold start:
    ``benchmarks/bench_decision_stage.py`` times a first rebuild)."""
    _DESIGNS.clear()
    inflation_factor.cache_clear()
    information_per_failure.cache_clear()
    _design_on_grid.cache_clear()
    _rare_power.cache_clear()


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
