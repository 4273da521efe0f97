"""The leak-growth degradation model (``analyses.leak_degradation``): pooled fit, remaining life, leak-limit crossing."""
import math

import numpy as np
import pandas as pd
import pytest

from analyses.leak_degradation import degradation_fit, degradation_rul, leak_crossing_life, leak_crossing_lives
from analyses.life_posterior import weibull_posterior
from analyses.quality import Sensor

SENSOR = Sensor(resolution=0.001, noise=0.005, source="metadata")   # floor 0.005, points above 0.05 used


def leak_paths(rng, n_hoses=40, gamma=1.5, log_w_mean=math.log(1.5e-3), log_w_sd=0.3, noise=0.08, every=50.0,
               end=800.0):
    """Leak paths ``(w_i d)^gamma`` with a lognormal wear rate, measured every ``every`` km to ``end``."""
    w = np.exp(log_w_mean + log_w_sd * rng.standard_normal(n_hoses))
    d = np.arange(every, end + 1e-9, every)
    rows = [(f"h{i:02d}", x, (w[i] * x) ** gamma * math.exp(noise * rng.standard_normal()))
            for i in range(n_hoses) for x in d]
    return pd.DataFrame(rows, columns=["hose_id", "distance_km", "leak_l_min"]), w


# -- leak-limit crossing (hand-checked) ------------------------------------------------------
def test_crossing_is_interpolated_between_the_plateaus_either_side():
    assert leak_crossing_life([300, 100, 200], [2.5, 0.5, 1.5], 2.0) == (250.0, True)


def test_a_path_that_never_reaches_the_limit_is_censored_at_its_last_plateau():
    assert leak_crossing_life([100, 200, 300], [0.5, 1.0, 1.9], 2.0) == (300.0, False)


def test_a_path_at_the_limit_from_its_first_plateau_crosses_there_and_no_points_is_nan():
    assert leak_crossing_life([100, 200], [2.2, 3.0], 2.0) == (100.0, True)
    life, crossed = leak_crossing_life([], [], 2.0)
    assert math.isnan(life) and not crossed


def test_crossing_lives_one_row_per_hose():
    pts = pd.DataFrame({"hose_id": ["a", "a", "b", "b"], "distance_km": [10, 20, 10, 20],
                        "leak_l_min": [1.0, 3.0, 0.1, 0.2]})
    out = leak_crossing_lives(pts, 2.0)
    assert out.to_dict("list") == {"hose_id": ["a", "b"], "life_km": [15.0, 20.0], "crossed": [True, False]}


# -- the degradation model -----------------------------------------------------------------------
def test_degradation_fit_recovers_the_growth_exponent_and_the_wear_rate_distribution():
    pts, w = leak_paths(np.random.default_rng(8), n_hoses=80)
    fit = degradation_fit(pts, SENSOR)
    assert fit.note is None
    assert fit.gamma == pytest.approx(1.5, abs=0.05)
    assert fit.sigma == pytest.approx(0.08, rel=0.15)
    assert fit.tau / fit.gamma == pytest.approx(0.3, rel=0.2)
    mean, sd = fit.wear_rate()
    true_mean = 1.5e-3 * math.exp(0.3 ** 2 / 2)
    assert mean == pytest.approx(true_mean, rel=0.1)
    assert sd == pytest.approx(true_mean * math.sqrt(math.expm1(0.09)), rel=0.25)


def test_degradation_rul_finds_a_hand_checked_crossing():
    """Hoses with one wear rate, no noise: the crossing of 2 l/min is 2^(1/1.5) / w exactly."""
    rng = np.random.default_rng(9)
    pts, w = leak_paths(rng, n_hoses=30, log_w_sd=0.3, noise=0.02)
    fit = degradation_fit(pts, SENSOR)
    d_cross = 2.0 ** (1 / 1.5) / w[0]
    now = pts.loc[pts["hose_id"] == "h00", "distance_km"].max()
    q, note = degradation_rul(fit, "h00", now, 2.0, seed=1)
    if d_cross <= now:
        assert "past the limit" in note
    else:
        assert note is None and q[0] == pytest.approx(d_cross - now, rel=0.05)
        assert q[1] < q[0] < q[2]


def _paths_with(hose_id, distance, leak):
    pts, _ = leak_paths(np.random.default_rng(10), n_hoses=10)
    return pd.concat([pts, pd.DataFrame({"hose_id": hose_id, "distance_km": distance, "leak_l_min": leak})],
                     ignore_index=True)


@pytest.mark.parametrize("distance, leak, reason", [
    ([100.0], [0.5], "too few leak points: 1 < 3"),
    ([100.0, 200.0, 300.0, 400.0], [0.004, 0.012, 0.031, 0.02], "noisy at the sensor floor"),
    ([100.0, 200.0, 300.0, 400.0], [0.9, 0.7, 0.6, 0.4], "leak path falling"),
    ([100.0, 200.0, 300.0, 400.0], [0.45, 0.8, 0.5, 0.6], "leak path flat"),
])
def test_a_hose_whose_own_path_cannot_tell_gets_nan_and_the_reason(distance, leak, reason):
    fit = degradation_fit(_paths_with("odd", distance, leak), SENSOR)
    assert fit.note is None
    q, note = degradation_rul(fit, "odd", max(distance), 2.0)
    assert np.isnan(q).all() and note.startswith(reason)


def test_too_few_hoses_to_pool_give_no_model():
    pts, _ = leak_paths(np.random.default_rng(11), n_hoses=2)
    fit = degradation_fit(pts, SENSOR)
    assert "too few hoses" in fit.note and math.isnan(fit.wear_rate()[0])
    assert "too few hoses" in degradation_rul(fit, "h00", 300.0, 2.0)[1]


def test_a_rupture_mode_shortens_the_remaining_life():
    pts, _ = leak_paths(np.random.default_rng(12), n_hoses=30, end=300.0)
    fit = degradation_fit(pts, SENSOR)
    rng = np.random.default_rng(13)
    rupture = weibull_posterior(np.r_[400 * rng.weibull(2.0, 10), np.full(20, 300.0)],
                                np.r_[np.ones(10, bool), np.zeros(20, bool)], seed=1)
    alone, _ = degradation_rul(fit, "h01", 300.0, 2.0)
    both, note = degradation_rul(fit, "h01", 300.0, 2.0, rupture)
    assert note is None and both[0] < alone[0] and both[2] <= alone[2] * 1.001
