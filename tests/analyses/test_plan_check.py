"""The decision stage's rule on many simulated looks: the batch fit and deviance against the scalar
functions the stage uses, and the first deciding look against reading each look one by one."""
import math

import numpy as np
import pytest

from analyses.decision import crossing_holds
from analyses.life_effect import common_shape_fit, ratio_deviance
from analyses.plan_check import Future, Past, batch_deviance, batch_fit, decides, first_decision


def censored(rng, rows=60, hoses=24, ratio=1.3):
    """Weibull(2.5) lives, force-set ones ``ratio`` times longer, random censoring, a tenth of the hoses off."""
    group = np.repeat([0, 1], hoses // 2)
    life = rng.weibull(2.5, (rows, hoses)) * 1000.0 * np.where(group == 1, ratio, 1.0)
    stop = rng.uniform(300.0, 2000.0, (rows, hoses))
    return np.log(np.minimum(life, stop)), life <= stop, rng.random((rows, hoses)) > 0.1, group


def test_batch_fit_and_deviance_are_the_scalar_functions():
    """Every row's shape, log ratio, its standard error, log-likelihood and the profile deviance at 1 and
    1.5 equal common_shape_fit / ratio_deviance on that row's hoses; a row with one force-set failure is
    not ok (the scalar fit has a note)."""
    logx, failed, on, group = censored(np.random.default_rng(1))
    failed[0, group == 1] = False
    failed[0, -1] = True                        # row 0: one force-set failure
    fit = batch_fit(logx, failed, on, group, 2.0)
    dev = {r: batch_deviance(logx, failed, on, group, fit, r) for r in (1.0, 1.5)}
    assert not fit.ok[0] and math.isnan(dev[1.0][0])
    for i in range(1, len(logx)):
        m = on[i]
        x, f, g = np.exp(logx[i, m]), failed[i, m], group[m]
        one = common_shape_fit(x, f, g)
        assert one.note is None and fit.ok[i]
        assert fit.shape[i] == pytest.approx(one.shape, rel=1e-8)
        assert fit.log_ratio[i] == pytest.approx(one.log_ratio, abs=1e-8)
        assert fit.se[i] == pytest.approx(one.se_log_ratio, rel=1e-8)
        assert fit.loglik[i] == pytest.approx(one.loglik, abs=1e-8)
        for r in (1.0, 1.5):
            assert dev[r][i] == pytest.approx(ratio_deviance(x, f, g, r), abs=1e-7)


def scalar_decides(x, f, g, c, margin):
    """The decision stage's rule on one look (sequential_verdict's crossing, then crossing_holds)."""
    fit = common_shape_fit(x, f, g)
    if fit.note or not math.isfinite(fit.se_log_ratio):
        return False, False
    half, lm = c * fit.se_log_ratio, math.log(margin)
    crossed = ("force longer" if fit.log_ratio - half > 0 else "distance longer" if fit.log_ratio + half < 0
               else "no practical difference" if abs(fit.log_ratio) + half < lm else None)
    if crossed is None:
        return False, False
    return True, crossing_holds(lambda r: ratio_deviance(x, f, g, r), crossed, c, margin)


def test_decides_is_the_stage_rule_with_its_vetoes():
    """At a boundary near the rows' z some rows cross on the Wald scale and the likelihood vetoes some of
    those: decides() agrees with the scalar rule row by row, and every outcome occurs."""
    logx, failed, on, group = censored(np.random.default_rng(2), rows=150, ratio=1.6)
    c = np.full(len(logx), 2.0)
    got, _ = decides(logx, failed, on, group, c, 1.25, 2.0)
    want = [scalar_decides(np.exp(logx[i, on[i]]), failed[i, on[i]], group[on[i]], 2.0, 1.25) for i in range(len(logx))]
    assert got.tolist() == [w[1] for w in want]
    assert {(w[0], w[1]) for w in want} == {(False, False), (True, False), (True, True)}   # a veto occurs


def test_first_decision_reads_every_look_as_the_stage():
    """A small future (6 running hoses each adjustment continuing, past failures), looks at each coming
    failure: the first look the scalar rule declares, replicate by replicate, is first_decision's, with
    the screen (at the current fit's shape, as the test plan passes it) and without it."""
    rng = np.random.default_rng(3)
    group_run = np.repeat([0, 1], 6)
    base = rng.uniform(100.0, 400.0, 12)
    n = 40
    left = rng.weibull(2.0, (n, 12)) * 900.0 * np.where(group_run == 1, 1.8, 1.0)
    fut = Future(base, np.zeros((n, 12)), left, group_run)
    px = np.r_[rng.uniform(200.0, 700.0, 6), rng.uniform(400.0, 1200.0, 6)]
    past = Past(np.log(px), np.ones(12, bool), np.repeat([0, 1], 6))
    times = np.sort(left, axis=1)[:, :10]
    c = np.linspace(2.6, 2.0, 10)
    want = []
    for r in range(n):
        first = -1
        for j in range(10):
            x = np.r_[px, base + np.minimum(left[r], times[r, j])]
            f = np.r_[np.ones(12, bool), left[r] <= times[r, j]]
            if scalar_decides(x, f, np.r_[past.group, group_run], c[j], 1.5)[1]:
                first = j
                break
        want.append(first)
    assert 0 < sum(w >= 0 for w in want) < n
    shape = common_shape_fit(np.r_[px, base], np.r_[np.ones(12, bool), np.zeros(12, bool)],
                             np.r_[past.group, group_run]).shape
    assert first_decision(past, fut, times, c, 1.5, shape, screen=(0.0, 0.0)).tolist() == want
    assert first_decision(past, fut, times, c, 1.5, shape, ).tolist() == want


def test_hoses_not_yet_on_test_change_nothing():
    """A bench's next hoses (columns that go on test only after a replicate's failure) enter a look only once
    on test: a future with extra columns starting after every look gives the same first deciding looks as
    without them, and one whose extra hoses start at 0 km (on test from the first look) differs."""
    rng = np.random.default_rng(4)
    group_run = np.repeat([0, 1], 6)
    base = rng.uniform(100.0, 400.0, 12)
    n = 60
    left = rng.weibull(2.0, (n, 12)) * 900.0 * np.where(group_run == 1, 1.8, 1.0)
    px = np.r_[rng.uniform(200.0, 700.0, 6), rng.uniform(400.0, 1200.0, 6)]
    past = Past(np.log(px), np.ones(12, bool), np.repeat([0, 1], 6))
    times = np.sort(left, axis=1)[:, :10]
    c = np.linspace(2.6, 2.0, 10)
    first = first_decision(past, Future(base, np.zeros((n, 12)), left, group_run), times, c, 1.5, 2.0)
    late = times[:, -1:] + rng.uniform(1.0, 50.0, (n, 8))       # each replicate's extra hoses start after its last look
    extra = Future(np.r_[base, np.zeros(8)], np.c_[np.zeros((n, 12)), late], np.c_[left, late + 500.0],
                   np.r_[group_run, np.repeat([0, 1], 4)])
    assert 0 < (first >= 0).sum() < n
    assert first_decision(past, extra, times, c, 1.5, 2.0).tolist() == first.tolist()
    early = Future(extra.base, np.c_[np.zeros((n, 12)), np.zeros((n, 8))], np.c_[left, np.full((n, 8), 1e6)], extra.group)
    assert first_decision(past, early, times, c, 1.5, 2.0).tolist() != first.tolist()


def renewal(rng, n=80, benches=6, per=8):
    """Benches' successive hoses (column ``i benches + b``: bench ``b``'s ``(i + 1)``-th, started when the
    ``i``-th fails), the first running from a distance, and their first 14 failures' times."""
    group = np.tile(np.repeat([0, 1], benches // 2), per)
    life = rng.weibull(2.0, (n, per, benches)) * 700.0 * np.where(group[:benches] == 1, 1.6, 1.0)
    end = np.cumsum(life, axis=1)
    start = np.concatenate([np.zeros((n, 1, benches)), end[:, :-1]], axis=1).reshape(n, -1)
    end = end.reshape(n, -1)
    base = np.r_[rng.uniform(100.0, 300.0, benches), np.zeros(benches * (per - 1))]
    return base, start, end, group, np.sort(end, axis=1)[:, :14]


def test_a_bench_chain_is_read_as_its_hoses():
    """A renewal future read as benches (Future.benches: one running hose per bench at a look) gives the same
    first deciding looks as the same columns read one by one (each hose on test from its start to its end),
    screened and in full; and times that are not the future's failures are refused."""
    rng = np.random.default_rng(5)
    base, start, end, group, times = renewal(rng)
    past = Past(np.log(rng.uniform(200.0, 900.0, 8)), np.ones(8, bool), np.repeat([0, 1], 4))
    c = np.linspace(2.8, 2.0, 14)
    chain = first_decision(past, Future(base, start, end, group, 6), times, c, 1.5, 2.0)
    assert 0 < (chain >= 0).sum() < len(chain)
    assert chain.tolist() == first_decision(past, Future(base, start, end, group), times, c, 1.5, 2.0).tolist()
    full = first_decision(past, Future(base, start, end, group), times, c, 1.5, 2.0, screen=(0.0, 0.0))
    assert full.tolist() == first_decision(past, Future(base, start, end, group, 6), times, c, 1.5, 2.0,
                                           screen=(0.0, 0.0)).tolist()
    with pytest.raises(ValueError):
        first_decision(past, Future(base, start, end, group, 6), times * 1.01, c, 1.5, 2.0)


def test_two_designs_on_one_set_of_replicates_are_each_read_alone():
    """Boundaries of two designs for the same replicates (c with 2 n rows, the shorter design padded with inf)
    give each design's first deciding looks as reading it alone; decides with rows gives each entry its data
    row's verdict at its own boundary."""
    rng = np.random.default_rng(6)
    base, start, end, group, times = renewal(rng)
    past = Past(np.log(rng.uniform(200.0, 900.0, 8)), np.ones(8, bool), np.repeat([0, 1], 4))
    fut = Future(base, start, end, group, 6)
    a, b = np.linspace(2.8, 2.0, 14), np.r_[np.linspace(2.6, 1.9, 10), np.full(4, np.inf)]
    both = first_decision(past, fut, times, np.r_[np.tile(a, (80, 1)), np.tile(b, (80, 1))], 1.5, 2.0)
    assert both[:80].tolist() == first_decision(past, fut, times, a, 1.5, 2.0).tolist()
    assert both[80:].tolist() == first_decision(past, fut, times, np.tile(b, (80, 1)), 1.5, 2.0).tolist()
    logx, failed, on, grp = censored(np.random.default_rng(7), rows=40, ratio=1.6)
    rows = np.r_[np.arange(40), np.arange(40)[::-1]]
    c = np.r_[np.full(40, 2.0), np.full(40, 1.5)]
    got, fit = decides(logx, failed, on, grp, c, 1.25, 2.0, rows=rows)
    want = np.r_[decides(logx, failed, on, grp, 2.0, 1.25, 2.0)[0], decides(logx, failed, on, grp, 1.5, 1.25, 2.0)[0][::-1]]
    assert fit.ok.shape == (40,) and got.tolist() == want.tolist() and got.any() and not got.all()
