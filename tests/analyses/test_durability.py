"""Durability runs: distance with a reversal deadband, strokes, per-stroke summary, streamed in chunks."""
import numpy as np
import pandas as pd
import pytest

from analyses.durability import StrokeCounter, durability_from_chunks, durability_summary, naive_distance

AREA_M2 = 4.9e-4


def synthetic_durability(n_strokes=400, fs_hz=1000.0, seed=0, noise_m=2e-6, encoder_m=5e-6, pressure_noise_pa=300.0,
                         friction_n=40.0, mass_kg=2.0, dwell_s=(0.05, 0.4), stroke_m=(0.06, 0.12), x0_m=0.05):
    """A local stand-in for the simulator: smooth strokes of random length, time and dwell.

    Position: cosine velocity profile per stroke, dwell at each end, Gaussian noise then encoder
    quantisation. Pressures: ``(p_a - p_b) A = friction * sign(v) + m a`` plus sensor noise.
    Returns t [s], x [m], p_a [Pa], p_b [Pa] and the truth (distance [m], strokes, friction [N]).
    """
    rng = np.random.default_rng(seed)
    xs, vs, accs = [np.full(int(0.3 * fs_hz), x0_m)], [np.zeros(int(0.3 * fs_hz))], [np.zeros(int(0.3 * fs_hz))]
    pos, direction, total = x0_m, 1, 0.0
    for _ in range(n_strokes):
        length = rng.uniform(*stroke_m)
        T = length / rng.uniform(0.1, 0.4) * 2          # mean speed 0.05-0.2 m/s
        n = max(int(T * fs_hz), 4)
        tau = np.arange(1, n + 1) / n
        xs.append(pos + direction * length * (0.5 - 0.5 * np.cos(np.pi * tau)))
        vs.append(direction * length * 0.5 * np.pi / T * np.sin(np.pi * tau))
        accs.append(direction * length * 0.5 * (np.pi / T) ** 2 * np.cos(np.pi * tau))
        pos += direction * length
        total += length
        nd = int(rng.uniform(*dwell_s) * fs_hz)
        xs.append(np.full(nd, pos)), vs.append(np.zeros(nd)), accs.append(np.zeros(nd))
        direction = -direction
    x = np.concatenate(xs)
    v = np.concatenate(vs)
    a = np.concatenate(accs)
    t = np.arange(len(x)) / fs_hz
    x_meas = np.round((x + rng.normal(0.0, noise_m, len(x))) / encoder_m) * encoder_m
    dp = (friction_n * np.sign(v) + mass_kg * a) / AREA_M2
    p_b = 2.0e5 + rng.normal(0.0, pressure_noise_pa, len(x))
    p_a = 2.0e5 + dp + rng.normal(0.0, pressure_noise_pa, len(x))
    return t, x_meas, p_a, p_b, {"distance_m": total, "strokes": n_strokes, "friction_n": friction_n}


def test_hand_checked_zigzag():
    x = np.array([0, 1, 2, 3, 2, 1, 0, 1, 2], float) * 1e-3
    t = np.arange(len(x)) * 0.5
    dp = np.array([1, 1, 1, -2, -2, -2, 4, 4, 4], float)
    s = durability_summary(t, x, dp, np.zeros_like(dp), deadband_m=1e-4)
    assert s.distance_m == pytest.approx(8e-3)
    assert s.strokes == 3 and s.duration_s == 4.0 and s.n_samples == 9
    st = s.stroke_table
    assert list(st["stroke"]) == [0, 1, 2]
    assert list(st["direction"]) == [1, -1, 1]
    assert list(st["t_start_s"]) == [0.0, 1.5, 3.0]
    assert list(st["t_end_s"]) == [1.5, 3.0, 4.0]
    assert st["length_m"].to_numpy() == pytest.approx([3e-3, 3e-3, 2e-3])
    assert st["mean_speed_m_s"].to_numpy() == pytest.approx([2e-3, 2e-3, 2e-3])
    # samples [0, 3), [3, 6), [6, 8): the last stroke ends at the last extreme (index 8)
    assert st["dp_mean_pa"].to_numpy() == pytest.approx([1.0, -2.0, 4.0])
    assert st["dp_friction_pa"].to_numpy() == pytest.approx([1.0, 2.0, 4.0])


def test_noise_under_the_deadband_is_not_motion():
    rng = np.random.default_rng(1)
    t = np.arange(100_000) * 1e-3
    x = 0.02 + np.round(rng.normal(0, 8e-6, len(t)) / 5e-6) * 5e-6   # resting carriage, dithering encoder
    s = durability_summary(t, x, deadband_m=1e-4)
    assert s.distance_m == 0.0 and s.strokes == 0 and len(s.stroke_table) == 0
    assert naive_distance(x) > 0.5                                    # sum |dx| would count half a metre


def test_small_real_reversals_above_the_deadband_count_below_do_not():
    x = np.array([0.0, 10.0, 9.85, 10.5, 10.45, 11.0, 0.0]) * 1e-3    # 0.15 mm back: real; 0.05 mm: noise
    s = durability_summary(np.arange(len(x), dtype=float), x, deadband_m=1e-4)
    assert s.strokes == 4
    assert s.stroke_table["length_m"].to_numpy() == pytest.approx([10e-3, 0.15e-3, 1.15e-3, 11e-3])
    assert s.distance_m == pytest.approx(22.3e-3)


def test_first_move_down_and_nan_samples():
    x = np.array([5.0, 5.0, np.nan, 4.0, 3.0, 3.0, 4.0, 6.0]) * 1e-3
    t = np.arange(len(x), dtype=float)
    s = durability_summary(t, x, deadband_m=1e-4)
    assert list(s.stroke_table["direction"]) == [-1, 1]
    assert s.distance_m == pytest.approx(5e-3) and s.n_samples == 7
    assert s.stroke_table["t_start_s"].tolist() == [0.0, 4.0]


@pytest.mark.parametrize("chunk", [1, 7, 1000, 4097])
def test_result_does_not_depend_on_chunking(chunk):
    t, x, pa, pb, _ = synthetic_durability(n_strokes=30, seed=3)
    whole = durability_summary(t, x, pa, pb)
    parts = durability_summary(t, x, pa, pb, chunk=chunk)
    assert parts.strokes == whole.strokes and parts.n_samples == whole.n_samples
    pd.testing.assert_frame_equal(parts.stroke_table, whole.stroke_table, rtol=1e-9)


def test_uneven_chunks_through_the_iterator():
    t, x, pa, pb, _ = synthetic_durability(n_strokes=20, seed=4)
    cuts = np.sort(np.random.default_rng(0).choice(len(t), 40, replace=False))
    chunks = [(t[a:b], x[a:b], (pa - pb)[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(t)])]
    got = durability_from_chunks(chunks)
    pd.testing.assert_frame_equal(got.stroke_table, durability_summary(t, x, pa, pb).stroke_table, rtol=1e-9)


@pytest.mark.parametrize("seed,noise_m,fs_hz", [(0, 2e-6, 1000.0), (1, 5e-6, 1000.0), (2, 10e-6, 5000.0)])
def test_distance_recovered_within_half_a_percent_on_noisy_runs(seed, noise_m, fs_hz):
    t, x, pa, pb, truth = synthetic_durability(n_strokes=200, seed=seed, noise_m=noise_m, fs_hz=fs_hz)
    s = durability_summary(t, x, pa, pb, chunk=65536)
    assert s.distance_m == pytest.approx(truth["distance_m"], rel=0.005)
    assert s.strokes == truth["strokes"]
    assert s.duration_s == pytest.approx(t[-1])
    # sum |dx| counts the noise: it is the reason for the deadband
    assert naive_distance(x) > s.distance_m


def test_stroke_pressure_difference_recovers_friction():
    t, x, pa, pb, truth = synthetic_durability(n_strokes=60, seed=5, dwell_s=(0.0, 0.002))
    s = durability_summary(t, x, pa, pb)
    friction = s.stroke_table["dp_friction_pa"].to_numpy() * AREA_M2
    # inertia averages out over a stroke from rest to rest; dwell would dilute the mean
    assert np.median(friction) == pytest.approx(truth["friction_n"], rel=0.05)
    assert (s.stroke_table["dp_mean_pa"] * s.stroke_table["direction"] > 0).all()


def test_invalid_deadband():
    with pytest.raises(ValueError):
        StrokeCounter(0.0)


def test_empty_run():
    s = durability_summary([], [])
    assert s.strokes == 0 and s.distance_m == 0.0 and np.isnan(s.duration_s)


def test_missing_pressure_samples_are_left_out_of_the_stroke_means():
    x = np.array([0, 1, 2, 3, 2, 1, 0], float) * 1e-3
    t = np.arange(len(x), dtype=float)
    p_a = np.array([1.0, np.nan, 3.0, -1.0, -3.0, np.nan, 0.0])
    st = durability_summary(t, x, p_a, np.zeros_like(p_a), deadband_m=1e-4, chunk=2).stroke_table
    assert st["dp_mean_pa"].tolist() == [2.0, -2.0]          # (1 + 3) / 2 and (-1 - 3) / 2
    assert st["n_samples"].tolist() == [3, 3]
    assert durability_summary(t, x).stroke_table["dp_mean_pa"].isna().all()


def test_deadband_is_twenty_sensor_floors():
    from analyses.durability import stroke_deadband
    from analyses.quality import Sensor

    assert stroke_deadband(Sensor(5e-6, 1e-6)) == pytest.approx(1e-4)        # the bench's encoder: 0.1 mm
    assert stroke_deadband(Sensor(1e-6, 20e-6)) == pytest.approx(4e-4)       # an analog sensor: its noise
    assert stroke_deadband(Sensor(0.0, 0.0), x_scale_m=0.5) == pytest.approx(5e-10)


def test_strokes_note_when_the_deadband_is_near_the_stroke():
    from analyses.durability import strokes_note

    t = np.arange(0, 20, 0.001)
    x = 0.002 * np.sign(np.sin(2 * np.pi * 0.5 * t)) * np.minimum(1, np.abs(np.sin(2 * np.pi * 0.5 * t)) * 5)
    s = durability_summary(t, x, deadband_m=1e-4)
    assert s.strokes > 10 and strokes_note(s, 1e-4) is None                 # 4 mm strokes, 0.1 mm deadband
    assert "strokes not detectable" in strokes_note(s, 1.5e-3)              # over a quarter of 4 mm
    still = durability_summary(t, np.zeros_like(t), deadband_m=1e-4)
    assert still.strokes == 0 and strokes_note(still, 1e-4) is None         # nothing to tell apart
