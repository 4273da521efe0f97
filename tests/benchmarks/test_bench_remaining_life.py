"""benchmarks/bench_remaining_life.py: the rupture model's count (``--design rupture``): its truth, the
interval it checks (hand-checked against the closed form) and its --quick run."""
import math

import numpy as np

from analyses.life_posterior import weibayes_posterior, weibull_rul
from benchmarks import bench_remaining_life as bench


def test_the_rul_design_keeps_every_hose_s_true_rupture_distance():
    hoses, _, truth = bench.simulate_rul_type(np.random.default_rng(3), 40.0, bench.RUPTURE_TRUTHS["constant"])
    rupture, d = truth["rupture_km"], hoses["distance_km"].to_numpy()
    ruptured = (hoses["failure_mode"] == "rupture").to_numpy()
    assert np.allclose(d[ruptured], rupture[ruptured])
    assert (rupture[(hoses["status"] == "running").to_numpy()] > d[(hoses["status"] == "running").to_numpy()]).all()
    # the default truth is the design's Weibull(2, 3): the same draws as before the option
    a = bench.simulate_rul_type(np.random.default_rng(5), 40.0)[2]["rupture_km"]
    rng = np.random.default_rng(5)
    rng.uniform(0.25, 0.45), rng.standard_normal(25)
    assert np.allclose(a, 3.0 * rng.weibull(2.0, 25))


def test_no_rupture_gives_the_jeffreys_predictive_interval():
    """With no rupture in an exposure T the remaining distance to rupture is Lomax: P(R > r) = (T / (T + r))^0.5,
    whatever the distance now (a constant hazard); its 5 % and 95 % points are T (0.95^-2 - 1) and T (0.05^-2 - 1)."""
    life = np.array([2.0, 3.0, 5.0])
    q, note = weibull_rul(weibayes_posterior(life, np.zeros(3, bool), 1.0, n_draws=20000, seed=1), 4.0, 0.90)
    assert note is None
    t = life.sum()
    assert math.isclose(q[1], t * (0.95 ** -2 - 1), rel_tol=1e-9) and math.isclose(q[2], t * (0.05 ** -2 - 1), rel_tol=1e-9)
    assert math.isclose(q[0], t * 3.0, rel_tol=1e-9)   # the median: (T / (T + r))^0.5 = 1/2


def test_the_count_keeps_groups_of_at_most_one_rupture_and_runs_quick(capsys):
    out, kept = bench.rupture_outcomes(12, 40.0, 24, "wear-out")
    assert 0 < kept <= 12 and set(out["ruptures"]) <= {0, 1} and out["group"].nunique() == kept
    assert (out["rupture_left_km"] > 0).all() and (out["rul_lower_km"] < out["rul_upper_km"]).all()
    # the union over shapes holds the constant hazard's interval (shape 1 is in it)
    assert (out["rul_lower_km"] <= out["const_lower_km"] * (1 + 1e-9)).all()
    assert (out["rul_upper_km"] >= out["const_upper_km"] * (1 - 1e-9)).all()
    assert bench.main(["--design", "rupture", "--quick"]) == 0
    text = capsys.readouterr().out
    assert "rupture model, wear-out truth:" in text and "rupture model, constant truth:" in text
    assert "one hose a group (independent)" in text and "(quick: no verdict)" in text and "width" in text
