"""When the lab's benches reach the decision: the schedule behind ``test_plan``'s ``expected_decision_date``.

The lab's benches as they run (:func:`bench_schedule`): the running hoses continue from their distance, a
free bench takes a new hose, and each failed hose is replaced at once by a new one of its adjustment (a
renewal process per bench, lives from the fitted common-shape Weibull, one model per replicate:
:func:`analyses.test_plan.predictive_draws`). The failures are read in bench-km order as
:func:`analyses.test_plan.power_now` reads its looks (:func:`analyses.plan_check.first_decision`: each
simulated look as the decision stage reads it); a replicate stops at its first deciding look, else at the
maximum. The figure is the median over the replicates of the hose-km until then.

Replicates (session 22): batches of :data:`SCHEDULE_BATCH`, each drawn by its own generator
(:func:`analyses.test_plan.batch_rng`: fixed by the seed), until the median's Monte Carlo standard error
(:func:`median_se`) is at most :data:`SCHEDULE_REL_SE` of it, or :data:`SCHEDULE_SIMULATIONS` are drawn. A
bench whose drawn lives run out before the maximum's failure (a replicate where one bench sees far more
than its share of the failures) draws the rest of its lives (until session 21 such a replicate was drawn
again in full, which favoured the replicates where no bench ran short). Docs: docs/decision.md, "Session
22: test_plan at 200 hose types".

References
----------
Jennison, C. & Turnbull, B. W. (2000). Group Sequential Methods with Applications to Clinical Trials.
Chapman & Hall/CRC (ch. 10).
Maritz, J. S. & Jarrett, R. G. (1978). A note on estimating the variance of the sample median. Journal of
the American Statistical Association 73, 194-196.
Meeker, W. Q. & Escobar, L. A. (1998). Statistical Methods for Reliability Data. Wiley (sec. 4.6).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analyses.life_effect import CommonShapeFit
from analyses.plan_check import Future, first_decision
from analyses.test_plan import (HoseState, ModelDraws, _current_look_decides, _past, batch_rng, predictive_draws,
                                remaining_km)

#: The most replicates of the benches' schedule [-] (each replicate's looks are read by the decision stage's
#: rule, refits at the crossings: the schedule costs most of the stage).
SCHEDULE_SIMULATIONS = 500

#: Replicates a batch [-]: the schedule stops after the first batch whose median is precise enough.
SCHEDULE_BATCH = 200

#: The median's Monte Carlo standard error the schedule stops at, relative to it [-]: 5 %, against a spread
#: of the single test's realised decision day of about +/- 25 % for half the tests (docs/decision.md): the
#: date's total error grows by about 1 % of the spread's.
SCHEDULE_REL_SE = 0.05


@dataclass(frozen=True)
class BenchSchedule:
    """When the lab's benches reach the decision (:func:`bench_schedule`).

    Attributes
    ----------
    hose_km : float
        Median over the replicates of the hose-kilometres the benches run from now until the test
        decides or reaches its maximum [km] (every hose on the benches accumulates km; at ``benches``
        benches of ``km_per_day``, ``hose_km / (benches km_per_day)`` days:
        :func:`analyses.test_plan.decision_date`); NaN when it cannot be told.
    note : str or None
        One line on what was assumed or why it is NaN.
    n_simulations : int
        Replicates drawn [-] (0 when none was needed).
    """

    hose_km: float
    note: str | None = None
    n_simulations: int = 0


def median_se(values) -> float:
    """Monte Carlo standard error of the sample median [unit of ``values``]: the half-width of the
    distribution-free 95 % interval of the median (the order statistics ``n / 2 +/- 1.96 sqrt(n) / 2``)
    over ``2 x 1.96``; NaN for fewer than 2 values."""
    x = np.sort(np.asarray(values, float))
    n = x.size
    if n < 2:
        return math.nan
    h = 1.96 * math.sqrt(n) / 2.0
    lo, hi = max(0, math.floor(n / 2.0 - h)), min(n - 1, math.ceil(n / 2.0 + h) - 1)
    return float(x[hi] - x[lo]) / (2.0 * 1.96)


def _bench_slots(state: HoseState, benches: int) -> tuple[np.ndarray, np.ndarray]:
    """The benches' hoses now: (distance [km], group) of the running hoses, and new hoses (0 km) on the
    benches they leave free, each to the adjustment with fewer hoses on the benches."""
    run = np.flatnonzero(state.running)
    group = list(state.group[run])
    for _ in range(max(0, benches - run.size)):
        group.append(int(group.count(1) < group.count(0)))
    distance = np.concatenate([state.distance[run], np.zeros(len(group) - run.size)])
    return distance, np.asarray(group, int)


def _lives(rng: np.random.Generator, distance, group, model: ModelDraws, count: int, fresh: bool) -> np.ndarray:
    """The benches' next ``count`` lives each, per replicate of ``model``: shape (n, count, benches) [km]; the
    first of each bench its hose's remaining life from ``distance`` unless ``fresh`` (all new hoses)."""
    n, benches = model.shape.shape[0], group.size
    if fresh:
        return remaining_km(rng, np.zeros(benches * count), np.tile(group, count), model, n).reshape(n, count, benches)
    first = remaining_km(rng, distance, group, model, n)
    later = remaining_km(rng, np.zeros(benches * (count - 1)), np.tile(group, count - 1), model, n)
    return np.concatenate([first, later], axis=1).reshape(n, count, benches)


def _future(distance, group, life: np.ndarray, left: int) -> tuple[Future, np.ndarray, np.ndarray]:
    """The renewal schedule of ``life`` (n, per bench, benches) [km]: (the :class:`~analyses.plan_check.Future`
    on the bench-km clock, the next ``left`` failures' bench-km, sorted, whether a bench's last drawn failure
    comes before the ``left``-th: then its lives ran out too early)."""
    n, per_bench, _ = life.shape
    end = np.cumsum(life, axis=1)
    start = np.concatenate([np.zeros((n, 1, group.size)), end[:, :-1]], axis=1)
    flat = end.reshape(n, -1)
    times = np.sort(np.partition(flat, left - 1, axis=1)[:, :left], axis=1)
    short = (end[:, -1, :] < times[:, -1:]).any(axis=1) if per_bench < left else np.zeros(n, bool)
    base = np.concatenate([distance, np.zeros(group.size * (per_bench - 1))])
    return Future(base, start.reshape(n, -1), flat, np.tile(group, per_bench)), times, short


def _drawn(rng: np.random.Generator, slots, fit: CommonShapeFit, n: int, left: int, per_bench: int):
    """One batch's renewal schedule up to the ``left``-th failure: (start, end [km], shape (n, benches x
    lives), the first ``left`` failures' bench-km, sorted, base [km]). Each bench draws its next ``per_bench``
    lives (1.5 times its share of the coming failures, plus 2); in the replicates where a bench ran short,
    every bench draws the rest of its lives up to ``left``; the other replicates' columns beyond theirs never
    go on test (start and end at :data:`_NEVER`)."""
    distance, group = slots
    model = predictive_draws(rng, fit, n)
    life = _lives(rng, distance, group, model, per_bench, fresh=False)
    fut, times, short = _future(distance, group, life, left)
    if not short.any():
        return fut.start, fut.end, times, fut.base
    rows = np.flatnonzero(short)
    sub = ModelDraws(model.shape[rows], model.scale_distance[rows], model.scale_force[rows])
    more = np.concatenate([life[rows], _lives(rng, distance, group, sub, left - per_bench, fresh=True)], axis=1)
    ext, ext_times, _ = _future(distance, group, more, left)
    start, end = np.full((n, ext.start.shape[1]), _NEVER), np.full((n, ext.start.shape[1]), _NEVER)
    start[:, :fut.start.shape[1]], end[:, :fut.start.shape[1]] = fut.start, fut.end
    start[rows], end[rows], times[rows] = ext.start, ext.end, ext_times
    return start, end, times, ext.base


#: Start and end of a drawn hose that never goes on test [km] (finite: its sums stay finite).
_NEVER = 1e300


def bench_schedules(state: HoseState, fit: CommonShapeFit, boundaries: list, margin: float, benches: int,
                    n_simulations: int = SCHEDULE_SIMULATIONS, seed: int = 0,
                    rel_se: float = SCHEDULE_REL_SE) -> list[BenchSchedule]:
    """:func:`bench_schedule` for several designs of one hose type at once (the stage's two target powers):
    the same replicates (common random numbers) read at each design's boundaries in one pass
    (:func:`analyses.plan_check.first_decision` with each replicate's boundaries), each design's batches
    until its own median is precise enough.

    Parameters
    ----------
    boundaries : list of array_like
        Each design's boundaries (one per failure up to its maximum) [-].
    state, fit, margin, benches, n_simulations, seed, rel_se
        As :func:`bench_schedule`.

    Returns
    -------
    list of BenchSchedule
        One per design, as :func:`bench_schedule` gives it.
    """
    out: list = [None] * len(boundaries)
    if fit.note or not np.isfinite(fit.se_log_ratio):
        return [BenchSchedule(math.nan, f"no fitted model: {fit.note or 'no standard error'}") for _ in boundaries]
    d0 = sum(state.failures)
    cs = [np.asarray(b, float)[d0:] for b in boundaries]
    for i, b in enumerate(boundaries):
        if cs[i].size <= 0:
            out[i] = BenchSchedule(0.0, "the maximum is reached")
        elif d0 >= 1 and _current_look_decides(state, fit, float(np.asarray(b, float)[d0 - 1]), margin):
            out[i] = BenchSchedule(0.0, "the current look decides")
    todo = [i for i, o in enumerate(out) if o is None]
    slots = _bench_slots(state, int(benches))
    if todo and slots[1].size == 0:
        for i in todo:
            out[i] = BenchSchedule(math.nan, "no bench and no running hose")
        todo = []
    if not todo:
        return out
    left = max(cs[i].size for i in todo)
    per_bench = min(left, math.ceil(1.5 * left / slots[1].size) + 2)
    km = {i: np.empty(0) for i in todo}
    while todo:
        done = min(km[i].size for i in todo)
        m = min(SCHEDULE_BATCH, n_simulations - done)
        start, end, times, base = _drawn(batch_rng(seed, done // SCHEDULE_BATCH), slots, fit, m, left, per_bench)
        k = len(todo)
        c = np.full((k * m, left), np.inf)
        for a, i in enumerate(todo):
            c[a * m:(a + 1) * m, :cs[i].size] = cs[i]
        fut = Future(base, start, end, np.tile(slots[1], base.size // slots[1].size), slots[1].size)
        stop = first_decision(_past(state), fut, times, c, margin, fit.shape).reshape(k, m)    # c: k copies
        for a, i in enumerate(list(todo)):
            km[i] = np.concatenate([km[i], times[np.arange(m), np.where(stop[a] >= 0, stop[a], cs[i].size - 1)]])
            if km[i].size >= n_simulations or median_se(km[i]) <= rel_se * float(np.median(km[i])):
                out[i] = BenchSchedule(slots[1].size * float(np.median(km[i])), None, int(km[i].size))
                todo.remove(i)
    return out


def bench_schedule(state: HoseState, fit: CommonShapeFit, boundaries, margin: float, benches: int,
                   n_simulations: int = SCHEDULE_SIMULATIONS, seed: int = 0,
                   rel_se: float = SCHEDULE_REL_SE) -> BenchSchedule:
    """The hose-km the lab's benches run until the test decides or reaches its maximum.

    The lab's schedule, which the design's information per failure assumes too
    (:func:`analyses.sequential_information.information_per_failure`): ``benches`` benches run at one rate, the
    running hoses continue from their distance (a free bench takes a new hose, to the adjustment with
    fewer), and each failed hose is replaced at once by a new one of its adjustment (a renewal
    process per bench; lives from the fitted model, :func:`analyses.test_plan.remaining_km`). The failures
    are read in bench-km order as :func:`analyses.test_plan.power_now` reads its looks, at the design's
    ``boundaries``; a replicate stops at its first deciding look
    (:func:`analyses.plan_check.first_decision`), else at the maximum (the last boundary's failure).

    Parameters
    ----------
    state, fit, boundaries, margin
        As :func:`analyses.test_plan.power_now` (``boundaries``: one per failure up to the maximum the
        schedule runs to).
    benches : int
        Benches testing the hose type, both adjustments [-]. With more running hoses than benches the
        running hoses share them (each advances at the same rate; the hose-km are the same).
    n_simulations : int
        The most replicates [-].
    seed : int
        Seed of the replicates: batch ``b`` is drawn by :func:`analyses.test_plan.batch_rng`.
    rel_se : float
        Stop after the first batch (of :data:`SCHEDULE_BATCH`) whose median's Monte Carlo standard error
        (:func:`median_se`) is at most this share of it [-]; 0 draws all ``n_simulations``.

    Returns
    -------
    BenchSchedule
        The median hose-km [km] (0 when the current look decides or the maximum is reached); each
        simulated look read as the decision stage reads it, as in :func:`analyses.test_plan.power_now`.
    """
    return bench_schedules(state, fit, [boundaries], margin, benches, n_simulations, seed, rel_se)[0]


__all__ = ["SCHEDULE_SIMULATIONS", "SCHEDULE_BATCH", "SCHEDULE_REL_SE", "BenchSchedule", "median_se", "bench_schedule",
           "bench_schedules"]
