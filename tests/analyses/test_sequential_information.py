"""The information per failure on the log life ratio (closed form when failures are rare, the benches' full
expected information with hoses on test, against refitted variances), the renewal function, and the exact
rare-failure power of the verdict."""
import math

import numpy as np
import pytest

from analyses.sequential import max_information
from analyses.sequential_information import information_per_failure, rare_failure_power


def test_information_per_failure_hand_checked_limits():
    # rare failures, margin 1.5, shape 2: p = 1 / (1 + 2.25) = 0.30769, p (1 - p) = 0.21302,
    # beta^2 = (2 ln 1.5)^2 = 0.65753: I / D = 4 * 0.21302 / (1 + 0.65753 * 0.21302) = 0.74738
    per, p = information_per_failure(1.5, 2.0)
    assert p == pytest.approx(0.30769, abs=1e-5) and per == pytest.approx(0.74738, abs=1e-5)
    # the full expected information tends to the closed form as the hoses on test grow, and with one
    # hose on test each run to many failures to a complete sample's: the failures split as the
    # renewal rates, 1 / (1 + margin) force-set, and I / D = shape^2 p (1 - p) = 4 * 0.24
    big, p_big = information_per_failure(1.5, 2.0, 72, 1_000_000)
    assert big == pytest.approx(per, rel=1e-3) and p_big == pytest.approx(p, rel=1e-3)
    one, p_one = information_per_failure(1.5, 2.0, 500, 1)
    assert p_one == pytest.approx(0.4, abs=2e-3) and one == pytest.approx(0.96, rel=5e-3)
    # no effect: the shape is orthogonal whatever the follow-up, shape^2 / 4 per failure
    assert information_per_failure(1.0 + 1e-9, 1.5, 30, 50)[0] == pytest.approx(1.5 ** 2 / 4, rel=1e-5)
    # fewer hoses on test per failure, more information per failure: fewer failures, never more than rare
    rare = max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0).failures
    few = [max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0, hoses_per_adjustment=n).failures for n in (4, 32)]
    assert few[0] < few[1] < rare
    assert max_information(1.5, 0.05, 0.8, "obrien-fleming", 2.0, hoses_per_adjustment=10_000).failures == rare


def test_renewal_function_of_exponential_lives_is_linear():
    """Shape 1: failures come as a Poisson process, M(t) = t / scale exactly; shape 2: the mean
    count of failures of 200,000 simulated benches by t = 1 and 3 (a replaced hose may fail again)."""
    from analyses.sequential_information import _renewal_function
    t = np.linspace(0.0, 6.0, 601)
    assert _renewal_function(t, 2.0, 1.0) == pytest.approx(t / 2.0, abs=1e-4)
    ends = np.cumsum(np.random.default_rng(1).weibull(2.0, (200_000, 12)), axis=1)
    m = _renewal_function(np.linspace(0.0, 3.0, 601), 1.0, 2.0)
    for i, at in ((200, 1.0), (600, 3.0)):
        count = (ends <= at).sum(axis=1)
        assert m[i] == pytest.approx(count.mean(), abs=3 * count.std() / math.sqrt(count.size) + 1e-3)


def test_renewal_function_solves_the_trapezoidal_recursion():
    """The series inversion gives what the discretised renewal equation gives step by step."""
    from analyses.sequential_information import _renewal_function
    t = np.linspace(0.0, 7.0, 300)
    for scale, shape in ((1.0, 2.0), (1.5, 0.7), (0.8, 3.5)):
        f = -np.expm1(-(t / scale) ** shape)
        df, m = np.diff(f), np.zeros(t.size)
        for i in range(1, t.size):   # M_i = F_i + sum_j (M(t_i - u_j) + M(t_i - u_{j+1})) / 2 dF_j
            m[i] = (f[i] + sum(0.5 * (m[i - j] + m[i - j - 1]) * df[j] for j in range(1, i))
                    + 0.5 * m[i - 1] * df[0]) / (1.0 - 0.5 * df[0])
        assert _renewal_function(t, scale, shape) == pytest.approx(m, abs=1e-12)


def _bench_trial(rng, benches: int, failures: int, margin: float, shape: float):
    """Hoses on ``benches`` benches per adjustment, each failed hose replaced at once, at the
    ``failures``-th failure: (distance, failed, force)."""
    group = np.repeat([0, 1], benches)
    life = np.where(group[:, None] == 1, margin, 1.0) * rng.weibull(shape, (2 * benches, failures + 2))
    start = np.cumsum(life, axis=1) - life
    end, group = (start + life).ravel(), np.repeat(group, failures + 2)
    start, life = start.ravel(), life.ravel()
    now = np.sort(end)[failures - 1]
    on = start < now
    return np.minimum(life, now - start)[on], (end <= now)[on], group[on]


@pytest.mark.parametrize("benches, failures", [(200, 60), (4, 40)])
def test_information_per_failure_matches_the_refitted_variance(benches, failures):
    """Var of the common-shape MLE of the log ratio over simulated trials, against 1 / I: failures
    rare among 200 hoses on test each, and 4 hoses on test each run to 40 failures (replaced)."""
    from analyses.life_effect import common_shape_fit
    rng = np.random.default_rng(5)
    est, share = [], []
    for _ in range(400):
        x, failed, force = _bench_trial(rng, benches, failures, 1.5, 2.0)
        est.append(common_shape_fit(x, failed, force).log_ratio)
        share.append(force[failed].mean())
    per, p = information_per_failure(1.5, 2.0, failures, benches)
    # sampling error of a variance from 400 draws: ~7 %; with 4 hoses each the rare figure
    # (0.747 per failure) is 34 % smaller, the even split's shape^2 / 4 = 1 is 14 % larger
    assert np.var(est) * per * failures == pytest.approx(1.0, abs=0.15)
    assert np.mean(share) == pytest.approx(p, abs=0.01)


def test_rare_failure_power_hand_checked():
    """Looks 1-4 cannot decide (no estimate before two failures each; c = 40 at look 4); at look 5
    with c = 0.4 the split 3 distance / 2 force gives ln ratio ln(1.5) / 2 = 0.2027 above
    0.4 sqrt(1/3 + 1/2 + ln(1.5)^2 / 5) / 2 = 0.1861: force longer; 2 / 3 gives distance longer.
    P(2 force-set of 5) = 10 p^2 (1 - p)^3 = 10 * 16 * 729 / 13^5 at p = 1 / 3.25 = 4 / 13."""
    assert rare_failure_power([40.0] * 4 + [0.4], 1.5, 2.0) == pytest.approx(10 * 16 * 729 / 13 ** 5, abs=1e-9)
    assert rare_failure_power([40.0] * 5, 1.5, 2.0) == 0.0
