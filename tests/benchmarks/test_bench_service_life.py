"""benchmarks/bench_service_life.py: its simulation is the Type I censoring it says, its counting
treats an open side as covering, and a run is the same for the same seed."""
import math

import numpy as np

from benchmarks import bench_service_life as bs


def test_groups_are_censored_at_the_stated_quantile():
    life, failed = bs.simulate(np.random.default_rng(3), 2000, 2.0, 0.70)
    stop = bs.quantile(2.0, 0.70)
    assert life.max() <= stop and np.all(life[~failed] == stop)
    assert abs(failed.mean() - 0.70) < 0.03                    # 70 % of the population fails by then


def test_an_open_side_covers_and_a_missed_truth_does_not():
    assert bs.covers(1.0, 2.0, 1.5) and not bs.covers(1.0, 2.0, 2.5)
    assert bs.covers(math.nan, 2.0, -1e9) and bs.covers(1.0, math.nan, 1e9) and not bs.covers(math.nan, 2.0, 3.0)


def test_a_seeded_run_is_repeatable_and_flags_every_parameter():
    a, b = bs.run(3, 5), bs.run(3, 5)
    assert a == b and set(a) == set(bs.SCENARIOS)
    row = next(r for r in a["small"] if r is not None)
    assert set(bs.PARAMETERS) <= set(row) and row["mle_bias"] > 0 and row["mrr_bias"] > 0
    assert bs.main(["--quick", "--groups", "2"]) == 0
