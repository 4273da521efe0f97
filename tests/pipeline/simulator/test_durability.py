"""Durability generator: strokes, distance, chunking and hose wear."""
import numpy as np
import pandas as pd
import pytest

from pipeline.simulator import draw_wear_path, iter_durability_chunks, simulate_durability, stroke_plan
from pipeline.simulator import durability as dur


def test_distance_and_strokes_from_samples():
    run = simulate_durability("H-1", "distance", distance_m=30.0, fs_hz=500, rng=1)
    x = run.data.x_m.to_numpy()
    assert np.abs(np.diff(x)).sum() == pytest.approx(run.truth["distance_m"], abs=1e-6)
    assert run.truth["strokes"] == 60
    reversals = np.count_nonzero(np.diff(np.sign(np.diff(x)[np.abs(np.diff(x)) > 0])) != 0)
    assert reversals + 1 == run.truth["strokes"]
    assert list(run.data.columns) == ["t_s", "x_m", "p_a_pa", "p_b_pa"]


def test_low_rate_logging_still_sees_every_turn():
    plan = stroke_plan(distance_m=500.0, stroke_m=1.0, speed_m_s=1.0, accel_m_s2=4.0, dwell_s=0.25, fs_hz=5.0)
    d = pd.concat(iter_durability_chunks(plan, 1, chunk_rows=777), ignore_index=True)
    assert len(d) == plan.n_samples and np.all(np.diff(d.t_s) > 0)
    assert np.abs(np.diff(d.x_m)).sum() == pytest.approx(500.0, abs=1e-6)


def test_chunks_equal_one_piece():
    plan = stroke_plan(duration_s=20.0, fs_hz=200.0)
    a = pd.concat(iter_durability_chunks(plan, 3, chunk_rows=1000), ignore_index=True)
    b = pd.concat(iter_durability_chunks(plan, 3, chunk_rows=10 ** 6), ignore_index=True)
    pd.testing.assert_frame_equal(a[["t_s", "x_m"]], b[["t_s", "x_m"]])


def test_wear_distance_set_leaks_more_with_distance_force_set_flat():
    rng = np.random.default_rng(5)
    d = [draw_wear_path("distance", {"z_rollers_mm": 4.0}, rng) for _ in range(400)]
    f = [draw_wear_path("force", {"spring_force_n": 536.0}, rng) for _ in range(400)]
    assert np.median([p.p_seal_new_bar - p.seal_pressure_bar(40) for p in d]) > 1.0
    assert np.median([p.p_seal_new_bar - p.seal_pressure_bar(40) for p in f]) < 0.4


def test_the_leak_at_the_new_seal_pressure_is_a_power_law_through_the_origin():
    """At the pressure the new hose seals, leak = (w d)^1.5 exactly (the remaining-life model's
    family), and the leak reaches the limit at the crossing distance."""
    setting = dur.sealing_setting("distance", 6.0)
    assert setting == {"z_rollers_mm": 4.0}
    path = dur.WearPath("distance", 6.0, 0.03, 1.0, 2.0, 1e9)
    for d_km in (1.0, 10.0, 33.0):
        assert path.leak_l_min(6.0, d_km) == pytest.approx((path.wear_rate_per_km * d_km) ** 1.5)
    cross = path.crossing_km(2.0, 6.0)
    assert cross == pytest.approx(1.0 / 0.03) and path.leak_l_min(6.0, cross) == pytest.approx(2.0)
    assert path.failure(2.0, 6.0) == (pytest.approx(cross), "leakage")
    # below the new seal pressure the path starts late (an offset); without a limit only a rupture ends it
    assert path.crossing_km(2.0, 5.0) == pytest.approx(2.0 / 0.03)
    assert dur.WearPath("force", 6.0, 0.01, 1.0, 2.0, 50.0).failure(None, None) == (50.0, "rupture")


def test_wear_rates_are_lognormal_with_the_stated_mean_and_spread():
    rng = np.random.default_rng(11)
    k = np.array([draw_wear_path("distance", {"z_rollers_mm": 4.0}, rng).seal_wear_bar_km for _ in range(4000)])
    assert k.mean() == pytest.approx(dur.SEAL_WEAR_BAR_KM["distance"], rel=0.03)
    assert k.std() / k.mean() == pytest.approx(dur.WEAR_CV, rel=0.08)


def test_the_true_b10_is_the_quantile_of_the_simulated_lives():
    rng = np.random.default_rng(12)
    setting = dur.sealing_setting("distance")
    lives = [draw_wear_path("distance", setting, rng).failure(2.0, 6.0)[0] for _ in range(6000)]
    assert np.quantile(lives, 0.10) == pytest.approx(dur.life_b10_km("distance", 2.0, 6.0), rel=0.04)
