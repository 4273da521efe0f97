"""Durability generator: strokes, distance, chunking and hose wear."""
import numpy as np
import pandas as pd
import pytest

from pipeline.simulator import iter_durability_chunks, simulate_durability, stroke_plan, worn_seal_pressure_bar


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
    d0, d40 = (worn_seal_pressure_bar("distance", km, z_rollers_mm=4.0) for km in (0, 40))
    f0, f40 = (worn_seal_pressure_bar("force", km, spring_force_n=429.0) for km in (0, 40))
    assert d0 - d40 > 1.0 and f0 - f40 < 0.3
