"""The test plan: the chance the running test decides, and what more it takes to decide.

One hose type's durability test is read by a group-sequential design (:mod:`analyses.sequential`):
a look at every failure, information fraction ``t = failures / max_failures``, Lan-DeMets
boundaries. This module answers, from the current censored state (failed hoses, running hoses at
their current distance, removed hoses) and the fitted common-shape Weibull
(:func:`analyses.life_effect.common_shape_fit`):

* ``power_now`` (:func:`power_now`): the probability that the test DECIDES (any of
  ``force longer``, ``distance longer``, ``no practical difference``) if no hose is added and the
  running hoses run on until ``max_failures``, given the data: the predictive power of Jennison &
  Turnbull (2000, sec. 10.3), each replicate its own model (:func:`predictive_draws`), with the
  futility side counted as a decision too: at a fitted ratio near 1 the useful decision is
  ``no practical difference``, and a reader asks "will this test tell me something", not "will it
  show force longer". It is not the design's power (that is ``target_power`` at the margin): it
  moves with the estimate, and a test whose estimate sits between 1 and the margin may have low
  power now although it was designed well. Every look, the current one and each simulated one, decides
  only as the decision stage declares it: the common-shape Weibull refitted to the look's lives, the
  Wald crossing confirmed by the profile likelihood (:func:`analyses.decision.crossing_holds`; the
  simulated looks in batches, :mod:`analyses.plan_check`). Measured against the real future
  (``benchmarks/bench_test_plan_forward.py``, docs/decision.md "power_now with the likelihood check").
  With fewer than ``FEW_FAILURES / 2`` failures in an adjustment it is NaN with the note why (optimistic
  by about 0.2 there: the shape from so few is biased high; the design's freeze of ``max_failures``
  waits for as many).
* ``more_hoses_per_adjustment`` and ``more_km`` (:func:`more_testing`): the fewest hoses to add
  per adjustment (equal allocation, new hoses from the fitted model, running hoses continuing)
  for ``failures_needed`` failures to be reachable, and the expected hose-kilometres of bench
  testing until the ``failures_needed``-th failure (each hose accumulates km until it fails or
  that failure is reached). The fewest hoses means every added hose may have to run to failure:
  adding more shortens the kilometres of elapsed testing but costs hoses; the table gives the
  fewest and the km it takes. The sequential test may stop earlier (that is its point): these
  are the km to the maximum.
* ``expected_decision_date`` (:func:`analyses.bench_schedule.bench_schedule`, :func:`decision_date`): the lab's benches as
  they run (running hoses continuing, a failed hose replaced at once by a new one of its adjustment),
  the same looks as ``power_now``, the median over the replicates of the hose-km until the test
  decides or reaches its maximum, at the bench capacity (the plan's, or measured from the durability
  runs, :func:`measured_capacity`). ``more_km`` is not that: it is the fewest-hoses scenario's km to the
  maximum, all hoses on test at once; on the lab's benches the maximum takes about a quarter more and
  the decision (usually before the maximum) about a fifth less (docs/decision.md).

Simulation: the simulated lives, read as the stage reads them
-------------------------------------------------------------
Each replicate draws its own model from the fit's sampling distribution (:func:`predictive_draws`), then
the remaining life of every running hose from that Weibull conditional on its current distance
(``x_i = scale_g ((c_i / scale_g)^k + E)^(1/k)``, ``E ~ Exp(1)``, Meeker & Escobar 1998, section 4.6;
``more_testing`` keeps the estimate) and orders the failures by the km still to run (the running hoses accumulate km at one
rate: they share the benches). At each coming failure the replicate's data are the past hoses and the
running ones at their distance then; the look decides as the decision stage's looks do
(:func:`analyses.plan_check.first_decision`: a shape-known screen picks the replicates whose look may
cross, those are refitted and their crossing checked by the profile likelihood, all in one vectorised
pass per look; the replicate stops at its first confirmed look). Until session 20 the looks were read on
the Wald scale of the canonical score process (Jennison & Turnbull 2000, sections 3.1 and 11.5) without
the check, and ``power_now`` was optimistic by 0.07 against the stage (docs/decision.md).

Replicates are seeded by the caller (the stage derives the seed from a hash of the data and the
plan): the same data give the same figures. ``mc_se = sqrt(p (1 - p) / n)``. Since session 22 ``power_now``
draws them in batches (:data:`POWER_BATCH`, each its own generator: :func:`batch_rng`) until ``mc_se`` is at
most :data:`POWER_SE_TARGET` (0.01) or ``n_simulations`` are drawn: ``n_simulations`` in its result is what
was drawn (docs/decision.md, "Session 22: test_plan at 200 hose types").

References
----------
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical
Trials. Chapman & Hall/CRC (ch. 3, 7, 10, 11.5).
Lan, K. K. G. & DeMets, D. L. (1983). Discrete sequential boundaries for clinical trials.
Biometrika 70, 659-663.
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley.
Spiegelhalter, D. J., Freedman, L. S. & Blackburn, P. R. (1986). Monitoring clinical trials: conditional
or predictive power? Controlled Clinical Trials 7, 8-17.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from analyses.decision import crossing_holds
from analyses.life_effect import CommonShapeFit, ratio_deviance
from analyses.plan_check import Future, Past, first_decision
from analyses.sequential import FEW_FAILURES

#: The second target power of the test plan (the plan's own power is the first) [-].
TARGET_POWER = 0.9

#: Replicates of each Monte Carlo figure: ``more_km``'s, and the most ``power_now`` draws (mc_se at most 0.008) [-].
N_SIMULATIONS = 4000

#: ``power_now`` draws its replicates in batches of this many [-] and stops after the first batch at which
#: its Monte Carlo standard error is at most :data:`POWER_SE_TARGET` (or at ``n_simulations``).
POWER_BATCH = 1000

#: The Monte Carlo standard error ``power_now`` stops at [-] (session 22: a power of 0.5 takes 2,500
#: replicates, one of 0 or 1 the first batch; the forward calibration's bins are 0.1-0.2 wide).
POWER_SE_TARGET = 0.01

#: Days of durability runs the bench capacity is measured from, before the latest event [d].
CAPACITY_DAYS = 30


def hoses_on_test(installed, ended, group) -> int | None:
    """The most hoses of one adjustment on test at the same time: the design's hoses on test [-].

    The sequential design converts information to failures from the follow-up
    (:func:`analyses.sequential_information.information_per_failure`): ``n`` hoses on test per adjustment, a
    failed one replaced (the benches keep running). That ``n`` is the benches' load, read from the
    logbook: per adjustment the largest number of hoses installed and not yet ended at one moment
    (an end before an installation at the same moment), the larger of the two adjustments (more
    hoses at once, failures rarer among them: fewer information per failure, the more failures).
    It settles as soon as the benches are loaded, so the design does not drift as hoses are
    replaced over the test.

    Parameters
    ----------
    installed, ended : array_like of datetime64 or float
        Each hose's first installation and its end (NaT/NaN while running) [time].
    group : array_like of int
        1 force-set, 0 distance-set.

    Returns
    -------
    int or None
        None when no hose has an installation time.
    """
    start, stop = (epoch_seconds(x) for x in (installed, ended))     # [s]; NaN where unknown
    return hoses_on_test_s(start, stop, group)


def epoch_seconds(times) -> np.ndarray:
    """Times (datetime64, timestamps, ISO text; NaT/None where unknown) as seconds since the epoch, UTC [s]; NaN
    where unknown."""
    return (pd.to_datetime(pd.Series(times), utc=True) - pd.Timestamp(0, tz="UTC")).dt.total_seconds().to_numpy(float)


def hoses_on_test_s(start, stop, group) -> int | None:
    """:func:`hoses_on_test` from the times already in seconds (:func:`epoch_seconds`: the stage converts every
    hose type's once) [s]; the same number."""
    start, stop = np.asarray(start, float), np.asarray(stop, float)
    group = np.asarray(group, int)
    best = 0
    for g in (0, 1):
        known = (group == g) & np.isfinite(start)
        ends = np.where(np.isfinite(stop[known]), stop[known], np.inf)
        times = np.concatenate([ends, start[known]])
        steps = np.concatenate([-np.ones(ends.size), np.ones(ends.size)])
        order = np.lexsort((steps, times))      # at one moment the ends (-1) first
        best = max(best, int(np.cumsum(steps[order]).max(initial=0)))
    return best or None


def target_powers(plan_power: float) -> tuple[float, ...]:
    """The target powers of the plan's rows: the plan's own, and :data:`TARGET_POWER`.

    Parameters
    ----------
    plan_power : float
        The plan's power [-].

    Returns
    -------
    tuple of float
        ``(plan_power, 0.9)``, or ``(plan_power,)`` when they are equal [-].
    """
    return (plan_power,) if math.isclose(plan_power, TARGET_POWER) else (plan_power, TARGET_POWER)


@dataclass(frozen=True)
class HoseState:
    """The current censored state of one hose type's test.

    Attributes
    ----------
    distance : numpy.ndarray
        Each hose's distance so far [km] (its life when failed).
    failed : numpy.ndarray of bool
        Whether it failed.
    running : numpy.ndarray of bool
        Whether it is still on test (continues from ``distance``); removed hoses are neither.
    group : numpy.ndarray of int
        0 distance-set, 1 force-set.
    """

    distance: np.ndarray
    failed: np.ndarray
    running: np.ndarray
    group: np.ndarray

    @property
    def failures(self) -> tuple[int, int]:
        """Failures so far of (distance, force) [-]."""
        return int((self.failed & (self.group == 0)).sum()), int((self.failed & (self.group == 1)).sum())


@dataclass(frozen=True)
class ModelDraws:
    """One common-shape Weibull per replicate (:func:`predictive_draws`), read by :func:`remaining_km` as a fit.

    Attributes
    ----------
    shape, scale_distance, scale_force : numpy.ndarray, shape (n, 1)
        Each replicate's shape [-] and scales [km].
    """

    shape: np.ndarray
    scale_distance: np.ndarray
    scale_force: np.ndarray


def predictive_draws(rng: np.random.Generator, fit: CommonShapeFit, n: int) -> ModelDraws:
    """Each replicate's own model, drawn from the fit's sampling distribution: PREDICTIVE, not plug-in.

    ``(log scale_distance, log ratio, log shape)`` ~ normal at the maximum with the inverse observed
    information ``fit.cov`` (Meeker & Escobar 1998, sec. 8.3, appendix B: the large-sample posterior under
    a flat prior on those coordinates). At the estimate alone a simulation is conditional power there,
    optimistic at the top (Spiegelhalter, Freedman & Blackburn 1986; Jennison & Turnbull 2000, sec. 10.3):
    docs/decision.md "power_now, predictive".

    Parameters
    ----------
    rng : numpy.random.Generator
        The replicates' generator (one standard normal triple per replicate, drawn first).
    fit : CommonShapeFit
        The common-shape fit: its estimate and ``cov``.
    n : int
        Replicates [-].

    Returns
    -------
    ModelDraws
        The ``n`` models; all at the estimate (the plug-in) when ``cov`` is not positive definite
        (singular, as an estimate known exactly; NaN: power_now has no standard error and is NaN before).
    """
    mean = np.array([math.log(fit.scale_distance), fit.log_ratio, math.log(fit.shape)])
    z = rng.standard_normal((n, 3))
    try:
        draw = mean + z @ np.linalg.cholesky(np.asarray(fit.cov, float)).T
    except np.linalg.LinAlgError:
        draw = np.broadcast_to(mean, (n, 3))
    col = [draw[:, i:i + 1] for i in range(3)]
    return ModelDraws(np.exp(col[2]), np.exp(col[0]), np.exp(col[0] + col[1]))


def remaining_km(rng: np.random.Generator, distance, group, fit: CommonShapeFit | ModelDraws, n: int) -> np.ndarray:
    """Km each hose still runs before it fails, drawn from the fitted Weibull given its distance.

    Parameters
    ----------
    rng : numpy.random.Generator
    distance : array_like
        Current distance of each hose [km] (0 for a new hose).
    group : array_like of int
        0 distance-set, 1 force-set.
    fit : CommonShapeFit or ModelDraws
        The fitted common-shape Weibull (its shape and two scales [km]): plug-in; or one model per
        replicate (:func:`predictive_draws`): predictive.
    n : int
        Replicates.

    Returns
    -------
    numpy.ndarray, shape (n, hoses)
        Remaining km [km], conditional on survival to ``distance``.
    """
    c = np.asarray(distance, float)
    scale = np.where(np.asarray(group) == 1, fit.scale_force, fit.scale_distance)
    e = rng.standard_exponential((n, c.size))
    return scale * ((c / scale) ** fit.shape + e) ** (1.0 / fit.shape) - c


def batch_rng(seed: int, batch: int) -> np.random.Generator:
    """The generator of one batch of replicates: batch 0 is ``seed``'s own, batch ``b`` that of ``(seed, b)``:
    each batch's draws are fixed by the seed whatever number of batches is drawn (the same data, the same figures)."""
    return np.random.default_rng(seed if batch == 0 else (seed, batch))


def _decides(est, info, c, log_margin: float):
    """Whether a look crosses on the Wald scale: efficacy ``|Z| >= c`` or the RCI inside ``(-ln m, ln m)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        se = 1.0 / np.sqrt(info)
        half = c * se
        return (info > 0) & ((np.abs(est) > half) | (np.abs(est) + half < log_margin))


def _past(state: HoseState) -> Past:
    """The state's hoses that no longer run (failed or removed, with a positive distance)."""
    m = ~state.running & (state.distance > 0)
    return Past(np.log(state.distance[m]), state.failed[m], state.group[m])


def _current_look_decides(state: HoseState, fit: CommonShapeFit, c: float, margin: float) -> bool:
    """Whether the current look decides as the decision stage reads it: the Wald crossing confirmed by
    the profile likelihood of the state's data (:func:`analyses.decision.crossing_holds`)."""
    lm = math.log(max(margin, 1.0 / margin))
    if not _decides(fit.log_ratio, fit.se_log_ratio ** -2, c, lm):
        return False
    half = c * fit.se_log_ratio
    crossed = ("force longer" if fit.log_ratio > half else "distance longer" if fit.log_ratio < -half
               else "no practical difference")
    return crossing_holds(lambda r: ratio_deviance(state.distance, state.failed, state.group, r), crossed, c, margin)


@dataclass(frozen=True)
class PowerNow:
    """The chance the running test decides (:func:`power_now`).

    Attributes
    ----------
    power : float
        Probability of a decision by ``max_failures`` [-]; NaN when it cannot be told.
    mc_se : float
        Its Monte Carlo standard error [-] (0 when no simulation was needed).
    n_simulations : int
        Replicates drawn [-] (batches of :data:`POWER_BATCH` until ``mc_se`` reaches its target).
    note : str or None
        One line on what was assumed or why ``power`` is NaN.
    """

    power: float
    mc_se: float
    n_simulations: int
    note: str | None = None


def power_now(state: HoseState, fit: CommonShapeFit, boundaries, margin: float, n_simulations: int = N_SIMULATIONS,
              seed: int = 0, target_se: float = POWER_SE_TARGET) -> PowerNow:
    """Probability that the test decides if no hose is added and it runs to ``max_failures``.

    Parameters
    ----------
    state : HoseState
        The current censored state.
    fit : CommonShapeFit
        The common-shape Weibull fitted to ``state`` (NaN: no power, noted).
    boundaries : array_like
        The design's efficacy boundaries on the z scale [-], one per failure up to the test's
        ``max_failures`` (its length): :func:`analyses.sequential_boundaries.efficacy_boundaries` at
        ``t = (1..max_failures) / max_failures``.
    margin : float
        The design's margin (life ratio, > 1) [-].
    n_simulations : int
        The most replicates [-].
    seed : int
        Seed of the replicates (derive it from the data for determinism): batch ``b`` is drawn by
        :func:`batch_rng`.
    target_se : float
        Stop after the first batch (of :data:`POWER_BATCH`) whose running estimate has a Monte Carlo standard
        error at most this [-] (the error taken at ``(decided + 1) / (n + 2)``, so that none or all decided in
        a batch is not an error of 0); 0 draws all ``n_simulations``.

    Returns
    -------
    PowerNow
        Module docstring: "decides" counts all three verdicts, at the fitted effect.
    """
    if fit.note or not np.isfinite(fit.se_log_ratio):
        return PowerNow(math.nan, math.nan, 0, f"no fitted model: {fit.note or 'no standard error'}")
    d0d, d0f = state.failures
    d0 = d0d + d0f
    c = np.asarray(boundaries, float)
    max_failures = c.size
    if d0 >= 1 and d0 <= max_failures and _current_look_decides(state, fit, float(c[d0 - 1]), margin):
        return PowerNow(1.0, 0.0, 0, "the current look decides")
    run = np.flatnonzero(state.running)
    looks = min(max_failures - d0, run.size)
    if looks <= 0:
        why = "max_failures reached" if d0 >= max_failures else "no running hose"
        return PowerNow(0.0, 0.0, 0, f"{why}: no look is left and the test has not decided")
    if min(d0d, d0f) < FEW_FAILURES / 2:
        return PowerNow(math.nan, math.nan, 0, f"not told with fewer than {FEW_FAILURES // 2} failures in an adjustment "
                        "(the shape from so few is biased high and power_now with it, by 0.2 measured; the design's "
                        "max_failures waits for as many: docs/decision.md, the plan's forward figures)")
    decided = n = 0
    while n < n_simulations:
        m = min(POWER_BATCH, n_simulations - n)
        rng = batch_rng(seed, n // POWER_BATCH)
        left = remaining_km(rng, state.distance[run], state.group[run], predictive_draws(rng, fit, m), m)
        fut = Future(state.distance[run], np.zeros_like(left), left, state.group[run])
        first = first_decision(_past(state), fut, np.sort(left, axis=1)[:, :looks], c[d0:d0 + looks], margin, fit.shape)
        decided, n = decided + int((first >= 0).sum()), n + m
        q = (decided + 1.0) / (n + 2.0)
        if math.sqrt(q * (1.0 - q) / n) <= target_se:
            break
    p = decided / n
    notes = [] if looks == max_failures - d0 else [
        f"only {run.size} running hose(s): the test can reach {d0 + run.size} of {max_failures} failures"]
    return PowerNow(p, math.sqrt(p * (1.0 - p) / n), n, "; ".join(notes) or None)


@dataclass(frozen=True)
class MoreTesting:
    """What it takes to reach ``failures_needed`` (:func:`more_testing`).

    Attributes
    ----------
    hoses_per_adjustment : int
        Hoses to add to each adjustment [-].
    km : float
        Expected hose-kilometres of testing still to run [km]; NaN without a fitted model.
    note : str or None
        One line on why ``km`` is NaN or what was assumed.
    """

    hoses_per_adjustment: int
    km: float
    note: str | None = None


def more_testing(state: HoseState, fit: CommonShapeFit, failures_needed: int,
                 n_simulations: int = N_SIMULATIONS, seed: int = 0) -> MoreTesting:
    """The fewest hoses to add per adjustment, and the expected km, to reach ``failures_needed``.

    Parameters
    ----------
    state : HoseState
        The current censored state (running hoses continue from their distance).
    fit : CommonShapeFit
        The fitted common-shape Weibull (new hoses' lives and the running ones' remaining lives).
    failures_needed : int
        Failures (both adjustments) the design needs [-].
    n_simulations : int
        Replicates of the expected km [-].
    seed : int
        Seed of the replicates.

    Returns
    -------
    MoreTesting
        ``km`` is the mean over replicates of ``sum_i min(remaining_i, L)``, ``L`` the remaining
        km of the hose whose failure is the ``failures_needed``-th: every hose (running and
        added) runs until it fails or the test reaches its maximum.
    """
    d0 = sum(state.failures)
    left = failures_needed - d0
    if left <= 0:
        return MoreTesting(0, 0.0, "failures_needed already reached")
    run = np.flatnonzero(state.running)
    add = max(0, math.ceil((left - run.size) / 2))
    if fit.note or not np.isfinite(fit.shape):
        return MoreTesting(add, math.nan, f"km not estimated, no fitted model: {fit.note}")
    distance = np.concatenate([state.distance[run], np.zeros(2 * add)])
    group = np.concatenate([state.group[run], np.repeat([0, 1], add)])
    rng = np.random.default_rng(seed)
    remaining = remaining_km(rng, distance, group, fit, n_simulations)
    last = np.partition(remaining, left - 1, axis=1)[:, left - 1:left]
    km = np.minimum(remaining, last).sum(axis=1)
    return MoreTesting(add, float(km.mean()))


def measured_capacity(runs: pd.DataFrame, today: pd.Timestamp,
                      days: int = CAPACITY_DAYS) -> tuple[int | None, float | None, str | None]:
    """Bench capacity measured from the durability runs of the last ``days`` days.

    Parameters
    ----------
    runs : pandas.DataFrame
        ``started_at`` (UTC timestamps), ``duration_h`` [h] and ``distance_km`` [km] per run.
    today : pandas.Timestamp
        The end of the window (the latest event in the data, for determinism).
    days : int
        Length of the window [d].

    Returns
    -------
    (int or None, float or None, str or None)
        ``benches``: most runs overlapping in time within the window [-]; ``km_per_day``: the
        window's km divided by its length (``days``, or the time since the first run when the
        data are younger) and by ``benches`` [km/d]; and a note when it cannot be measured
        (both None).
    """
    if runs is None or len(runs) == 0:
        return None, None, "no durability runs to measure the bench capacity from"
    start = pd.to_datetime(runs["started_at"], utc=True)
    km = pd.to_numeric(runs["distance_km"], errors="coerce")
    hours = pd.to_numeric(runs["duration_h"], errors="coerce").fillna(0.0)
    end = start + pd.to_timedelta(hours, unit="h")
    since = today - pd.Timedelta(days=days)
    inside = (start >= since) & (start <= today) & (km > 0)
    span_d = min(float(days), (today - start.min()).total_seconds() / 86400.0)
    if not inside.any() or not span_d > 0:
        return None, None, f"no durability run with a distance in the last {days} days: capacity not measured"
    edges = sorted([(t, 1) for t in start[inside]] + [(t, -1) for t in end[inside]], key=lambda e: (e[0], e[1]))
    benches = max(1, int(np.max(np.cumsum([e[1] for e in edges]))))
    return benches, float(km[inside].sum()) / span_d / benches, None


def decision_date(today: pd.Timestamp, more_km: float, benches, km_per_day):
    """The date the remaining km are run at the bench capacity.

    Parameters
    ----------
    today : pandas.Timestamp
        The latest event in the data.
    more_km : float
        Hose-kilometres still to run [km] (the stage: :func:`analyses.bench_schedule.bench_schedule`'s ``hose_km``).
    benches : int or None
        Benches running at once [-].
    km_per_day : float or None
        Kilometres a bench runs a day [km/d].

    Returns
    -------
    datetime.date or None
        ``today + more_km / (benches * km_per_day)`` days; None when any input is missing.
    """
    if benches is None or km_per_day is None or not np.isfinite(more_km) or not benches * km_per_day > 0:
        return None
    return (today + pd.Timedelta(days=more_km / (benches * km_per_day))).date()


__all__ = ["TARGET_POWER", "N_SIMULATIONS", "POWER_BATCH", "POWER_SE_TARGET", "CAPACITY_DAYS", "HoseState", "ModelDraws",
           "PowerNow", "MoreTesting", "target_powers", "batch_rng", "predictive_draws", "remaining_km", "power_now",
           "more_testing", "measured_capacity", "decision_date", "hoses_on_test", "epoch_seconds", "hoses_on_test_s"]
