"""benchmarks/bench_sensitivity.py: the simulated type has one population split at random, every
definition is read, the binomial bound is the one stated, and a seeded run is repeatable."""
import numpy as np
from scipy import stats

from benchmarks import bench_sensitivity as bs
from pipeline.stages.remaining_life import DEFINITIONS


def test_the_binomial_bound_by_hand():
    assert bs.bound(400, 0.05) == 27                      # P(X <= 27) >= 0.95 > P(X <= 26) for Bin(400, 0.05)
    assert stats.binom.cdf(27, 400, 0.05) >= 0.95 > stats.binom.cdf(26, 400, 0.05)


def test_every_definition_is_read_and_a_run_repeats():
    got = bs.one_type(np.random.default_rng([1, 0]), 40.0)
    exact = [f"{bs.EXACT} ({label})" for label, _ in bs.READS]
    assert set(got) == {name for name, _ in DEFINITIONS} | set(exact)
    assert got[exact[0]][1] == got[exact[1]][1] >= 1                 # the same lives under both models
    assert got["leak limit x0.5"][1] >= got["leak limit"][1] >= got["leak limit x2"][1] > 0   # a lower limit: more cross
    assert all(v[2] in (0.0, 1.0) for v in got.values())            # each interval holds the true ratio or not
    a, b = bs.run(2, 40.0, 3), bs.run(2, 40.0, 3)
    assert a.equals(b) and len(a) == 2 * (len(DEFINITIONS) + len(bs.READS) * (1 + len(bs.CONTROLS)))
    assert bs.main(["--types", "2"]) in (0, 1)


def test_the_controls_are_complete_samples_of_one_population():
    for kind in bs.CONTROLS:
        verdict, failures, covers = bs.control(np.random.default_rng(4), kind, bs.LEAK_MODEL)
        assert covers in (0.0, 1.0)
        assert failures == bs.HOSES and verdict in ("force longer", "distance longer", "no practical difference",
                                                    "undecided")
