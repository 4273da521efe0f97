"""The lab's benches' schedule (``analyses/bench_schedule.py``): the gamma of the exponential's renewal
process by hand, the stop at the decision, the median's Monte Carlo error, the adaptive batches and
several designs read in one pass."""
import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from analyses.bench_schedule import (SCHEDULE_BATCH, BenchSchedule, _drawn, bench_schedule, bench_schedules,
                                     median_se)
from analyses.life_effect import CommonShapeFit
from analyses.test_plan import batch_rng
from tests.analyses.test_test_plan import clear_state, drawn_state, model, state


def test_bench_schedule_to_the_maximum_is_the_exponentials_gamma():
    """Shape 1, equal scales s, boundaries no look can cross: every bench is a Poisson process of rate
    1 / s per bench-km whatever its hose's age (memoryless, a failed hose replaced), so B benches reach
    the r-th failure at Gamma(r, s / B) bench-km, and the hose-km (B x that) is Gamma(r, s): the median
    by hand, for 6 running hoses on 6 benches and for 2 running hoses on 6 (4 new hoses loaded). More
    running hoses than benches share them: the same hose-km. All 20,000 replicates drawn (``rel_se`` 0)."""
    fit = replace(model(shape=1.0, log_ratio=0.0), cov=np.diag([0.0, 0.25, 0.0]))   # singular: the draws plug it in
    r = 12                                                  # failures still to come: maximum 16, 4 so far
    for running, benches in ((3, 6), (1, 6), (5, 4)):
        got = bench_schedule(state(2, running, 300.0), fit, [40.0] * 16, 1.25, benches, 20_000, seed=4, rel_se=0.0)
        assert got.hose_km == pytest.approx(stats.gamma.median(r, scale=1000.0), rel=0.02)
        assert got.note is None and got.n_simulations == 20_000


def test_bench_schedule_stops_at_the_decision():
    """A strong fitted effect decides long before the maximum: the benches' km shrink; the current look
    deciding or the maximum reached is 0 km; no fitted model is NaN. Deterministic per seed."""
    bounds = np.full(100, 2.0)
    (weak_st, weak_fit), (st, fit) = drawn_state(1.0), drawn_state(4.0)
    weak, strong = (bench_schedule(s, f, bounds, 1.25, 20, 300, seed=1) for s, f in ((weak_st, weak_fit), (st, fit)))
    assert 0.0 < strong.hose_km < 0.5 * weak.hose_km
    assert bench_schedule(st, fit, bounds, 1.25, 20, 300, seed=1) == strong
    decided = bench_schedule(clear_state(), model(log_ratio=2.0, se=0.5), [2.0] * 40, 1.25, 20, 100)
    assert (decided.hose_km, decided.note) == (0.0, "the current look decides")
    assert bench_schedule(st, model(), [40.0] * 10, 1.25, 20).hose_km == 0.0
    assert math.isnan(bench_schedule(st, CommonShapeFit(note="too few"), bounds, 1.25, 20).hose_km)


def test_median_se_is_the_normal_medians_error():
    """The sample median of n normal draws has the standard error sqrt(pi / 2) sigma / sqrt(n): the
    order-statistic estimate finds it within 10 % for n = 10,000, and it is NaN for one value."""
    x = np.random.default_rng(3).normal(5.0, 2.0, 10_000)
    assert median_se(x) == pytest.approx(math.sqrt(math.pi / 2.0) * 2.0 / 100.0, rel=0.1)
    assert math.isnan(median_se([1.0]))


def test_the_schedule_stops_when_its_median_is_precise_enough():
    """Batches of SCHEDULE_BATCH until the median's Monte Carlo error is at most rel_se of it: a loose target
    stops after the first batch, a tight one draws every replicate allowed; the first batch's draws are the
    same either way (the batches' seeds are fixed), so the loose figure is the first batch's median."""
    st, fit = drawn_state(1.0)
    bounds = np.full(60, 2.2)
    loose = bench_schedule(st, fit, bounds, 1.25, 20, 3 * SCHEDULE_BATCH, seed=5, rel_se=0.5)
    tight = bench_schedule(st, fit, bounds, 1.25, 20, 3 * SCHEDULE_BATCH, seed=5, rel_se=1e-6)
    assert (loose.n_simulations, tight.n_simulations) == (SCHEDULE_BATCH, 3 * SCHEDULE_BATCH)
    assert loose == bench_schedule(st, fit, bounds, 1.25, 20, SCHEDULE_BATCH, seed=5, rel_se=0.0)
    assert loose.hose_km != tight.hose_km and tight.hose_km == pytest.approx(loose.hose_km, rel=0.25)


def test_several_designs_in_one_pass_are_each_read_alone():
    """bench_schedules reads each design's boundaries on the same replicates as bench_schedule does for that
    design alone (same seed, same draws: the draws follow the longest design), the current look or the
    maximum answered without a simulation."""
    st, fit = drawn_state(2.0)
    short, long_ = np.full(40, 2.3), np.full(70, 2.1)
    both = bench_schedules(st, fit, [short, long_, [40.0] * 10], 1.25, 20, 400, seed=9)
    assert both[2] == BenchSchedule(0.0, "the maximum is reached")
    alone = bench_schedules(st, fit, [long_], 1.25, 20, 400, seed=9)[0]
    assert both[1] == alone
    assert 0.0 < both[0].hose_km < both[1].hose_km


def test_a_bench_that_runs_short_draws_the_rest_of_its_lives():
    """Two benches, one adjustment's lives 50x shorter: its bench sees nearly every failure and runs out of
    the lives drawn at first (1.5 times its share); those replicates go on drawing that bench's lives, so
    the maximum's failure comes in every replicate from lives each bench drew in order (no replicate is
    drawn again, none has a hose on test twice)."""
    fit = CommonShapeFit(2.0, 1000.0, 20.0, 0.0, math.log(0.02), np.diag([0.0, 0.0, 0.0]))
    st = state(3, 1, 10.0)
    start, end, times, base = _drawn(batch_rng(2, 0), (st.distance[st.running], st.group[st.running]), fit, 50, 30,
                                     math.ceil(1.5 * 30 / 2) + 2)
    assert start.shape[1] == 2 * 30 and np.all(np.isfinite(times))
    on = start < 1e299                                      # drawn hoses of each replicate
    failures = (end <= times[:, -1:]) & on
    assert (failures.sum(axis=1) >= 30).all()
    assert np.allclose(np.sort(np.where(failures, end, np.inf), axis=1)[:, :30], times)
