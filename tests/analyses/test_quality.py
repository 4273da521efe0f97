"""analyses.quality: sensor description from data and metadata; quality gates on fits."""
import numpy as np
import pytest

from analyses.quality import (Gate, Sensor, at_bound, describe_sensor, describe_sensor_at_rest, linear_lstsq, noise_std, nrmse_pct,
                              quantisation_step, scaled_condition, sensor_from_params, setpoint_jumps,
                              setpoint_thresholds, settle_points)


def _motion(n=20_000, fs=1000.0):
    t = np.arange(n) / fs
    return t, 0.05 * np.sin(2 * np.pi * 0.3 * t)


@pytest.mark.parametrize("step", [1e-6, 5e-6, 50e-6])
def test_quantisation_step_recovered_from_encoder(step):
    _, x = _motion()
    xq = np.round(x / step) * step + 0.0123  # an offset does not matter
    assert quantisation_step(xq) == pytest.approx(step, rel=1e-6)


def test_quantisation_step_in_mm_converted_to_m():
    _, x = _motion()
    mm = np.round(x * 1e3 / 0.005) * 0.005  # 5 um counts logged in mm
    assert quantisation_step(mm * 1e-3) == pytest.approx(5e-6, rel=1e-6)


def test_analog_sensor_is_not_quantised_and_its_noise_is_measured():
    rng = np.random.default_rng(3)
    _, x = _motion()
    noisy = x + rng.normal(0, 20e-6, x.size)
    assert quantisation_step(noisy) == 0.0
    assert noise_std(noisy) == pytest.approx(20e-6, rel=0.05)


@pytest.mark.parametrize("sigma", [5e-6, 20e-6, 50e-6])
def test_noise_of_an_analog_sensor_in_trapezoidal_passes_at_100_hz(sigma):
    """Passes at 0.05-0.5 m/s with 2 m/s2 ramps, sampled at 100 Hz: a ramp moves the second
    difference by a dt^2 = 200 um on about a fifth of the samples; the estimate stays within
    10 % of the sensor's noise (second differences gave +25 % at 5 um)."""
    from pipeline.simulator.plpa import evaluate_profile, motion_profile

    speeds = tuple(s * v for v in (0.05, 0.1, 0.2, 0.3, 0.4, 0.5) for s in (1.0, -1.0))
    segs, _, total = motion_profile(speeds, 2.0, 0.25, 2.0, 0.4, 0.3)
    x = 0.4 + evaluate_profile(segs, np.arange(0.0, total, 0.01))[0]
    noisy = x + np.random.default_rng(7).normal(0.0, sigma, x.size)
    assert noise_std(noisy) == pytest.approx(sigma, rel=0.1)


def test_noise_estimate_ignores_steps():
    rng = np.random.default_rng(4)
    y = np.repeat([0.0, 5000.0, 10000.0, 2000.0], 2000) + rng.normal(0, 300.0, 8000)
    assert noise_std(y) == pytest.approx(300.0, rel=0.06)


def test_describe_sensor_prefers_metadata_and_says_so():
    rng = np.random.default_rng(5)
    _, x = _motion()
    noisy = x + rng.normal(0, 10e-6, x.size)
    s = describe_sensor(noisy, resolution=1e-6)
    assert s.resolution == 1e-6 and s.noise == pytest.approx(10e-6, rel=0.05)
    assert s.source == "metadata+estimated"
    assert s.floor() == pytest.approx(s.noise)
    assert describe_sensor([], resolution=5e-6, noise=0.0).source == "metadata"


def test_constant_speed_passes_are_not_taken_for_quantisation():
    """A 1 um encoder at 200 Hz in passes at 5, 10 and 15 mm/s changes by 25, 50 and 75 um per
    sample, all multiples of 25 um, and never by one count: the values' lattice (ramps, rests)
    still gives the 1 um step, not the per-sample travel."""
    from pipeline.simulator.plpa import evaluate_profile, motion_profile

    speeds = tuple(s * v for v in (0.005, 0.010, 0.015) for s in (1.0, -1.0))
    segs, _, total = motion_profile(speeds, 2.0, 0.02, 2.0, 0.4, 0.3)
    t = np.arange(0.0, total, 1 / 200.0)
    x = np.round((0.4 + evaluate_profile(segs, t)[0]) / 1e-6) * 1e-6
    d = np.abs(np.diff(x))
    assert not np.any(np.abs(d - 1e-6) < 1e-9)        # no change of one count in the record
    assert quantisation_step(x) == pytest.approx(1e-6, rel=1e-6)
    assert quantisation_step(x * 1e3) == pytest.approx(1e-3, rel=1e-6)   # logged in mm


def test_unquantised_passes_at_commensurate_speeds_are_not_quantised():
    """The same passes from a continuous (noise-free, unquantised) sensor: every change but the
    few ramp samples is a multiple of 25 um, yet the passes start from ramps at other phases, so
    the values sit on no lattice: 0, not the per-sample travel."""
    from pipeline.simulator.plpa import evaluate_profile, motion_profile

    speeds = tuple(s * v for v in (0.005, 0.010, 0.015) for s in (1.0, -1.0))
    segs, _, total = motion_profile(speeds, np.sqrt(20.0), 0.02, 2.0, 0.4, 0.3)  # ramps of sqrt(20) m/s2
    x = 0.4 + evaluate_profile(segs, np.arange(0.0, total, 1 / 200.0))[0]
    d = np.abs(np.diff(x))
    k = d[d > 1e-12] / 25e-6
    assert np.mean(np.abs(k - np.round(k)) < 1e-6) > 0.99     # the differences alone look quantised
    assert quantisation_step(x) == 0.0


def test_quantised_noise_free_encoder_has_noise_below_half_a_step():
    _, x = _motion()
    s = describe_sensor(np.round(x / 5e-6) * 5e-6)
    assert s.resolution == pytest.approx(5e-6, rel=1e-6)
    assert s.noise <= 5e-6 / np.sqrt(12) + 1e-12
    assert s.floor() == pytest.approx(5e-6, rel=1e-6)


def test_sensor_from_params_reads_ingest_keys():
    s = sensor_from_params({"sensor_x_resolution": 5e-5, "sensor_x_noise": "2e-5"}, "x")
    assert (s.resolution, s.noise, s.source) == (5e-5, 2e-5, "metadata")
    bad = sensor_from_params({"sensor_x_resolution": "junk"}, "x", np.round(_motion()[1] / 1e-6) * 1e-6)
    assert bad.source == "estimated" and bad.resolution == pytest.approx(1e-6, rel=1e-6)


def test_nrmse_hand_checked():
    assert nrmse_pct([0, 1, 2, 3], [0, 1, 2, 4]) == pytest.approx(100 * 0.5 / 3)
    assert np.isnan(nrmse_pct([1, 1], [1, 1]))


def test_one_speed_level_cannot_separate_coulomb_from_viscous():
    v = np.full(200, 0.12) + np.random.default_rng(1).normal(0, 1e-9, 200)
    f = 3.0 + 25 * v
    fit = linear_lstsq(np.column_stack([np.ones_like(v), v]), f)
    g = Gate().identifiable(fit, names=("coulomb_n", "viscous_n_s_m"))
    assert not g.ok and ("ill-conditioned" in g.note or "rank" in g.note or "not identifiable" in g.note)
    row = g.apply({"coulomb_n": fit.beta[0], "viscous_n_s_m": fit.beta[1]}, ("coulomb_n", "viscous_n_s_m"))
    assert row["coulomb_n"] is None and row["viscous_n_s_m"] is None and row["note"]


def test_two_speed_levels_identify_both_with_standard_errors():
    rng = np.random.default_rng(2)
    v = np.repeat([0.05, 0.3], 50)
    f = 3.0 + 25 * v + rng.normal(0, 0.1, v.size)
    fit = linear_lstsq(np.column_stack([np.ones_like(v), v]), f)
    assert Gate().identifiable(fit).ok
    assert fit.beta == pytest.approx([3.0, 25.0], abs=0.2)
    assert fit.se[0] == pytest.approx(0.1 * np.sqrt(1 / 50 + 0.175 ** 2 / (100 * 0.125 ** 2)), rel=0.3)


def test_scaled_condition_is_unit_free():
    v = np.linspace(0.01, 0.5, 50)
    X = np.column_stack([np.ones_like(v), v])
    assert scaled_condition(X) == pytest.approx(scaled_condition(X * [1.0, 1e6]), rel=1e-9)
    assert scaled_condition(np.column_stack([v, 2 * v])) > 1e12


@pytest.mark.parametrize("value,lo,hi,expected", [
    (50.0, 0.02, 50.0, True), (0.02, 0.02, 50.0, True), (1.0, 0.02, 50.0, False),
    (1e3, 0.1, 1e5, False), (99990.0, 0.1, 1e5, True), (0.5, 0.0, 1.0, False), (float("nan"), 0, 1, True)])
def test_at_bound(value, lo, hi, expected):
    assert at_bound(value, lo, hi) is expected


def test_gate_bound_nrmse_physical_and_points():
    assert "upper bound" in Gate().within_bounds([52.0, 50.0], [0.1, 0.02], [1e5, 50.0], ("wn", "zeta")).note
    assert Gate().within_bounds([52.0, 0.7], [0.1, 0.02], [1e5, 50.0]).ok
    assert "misses the data" in Gate().follows_data(8.0, 2.5).note
    assert Gate().follows_data(8.0, 2.5, rms=0.9, noise=0.5).ok  # residuals at the noise level
    assert "physically impossible" in Gate().physical("coulomb_n", -203429.0, lo=0).note
    assert "too few points: 2 < 5" == Gate().enough_points(2, 5).note
    g = Gate().physical("mass_kg", 2.0, lo=0)
    assert g.ok and g.apply({"mass_kg": 2.0}, ("mass_kg",)) == {"mass_kg": 2.0, "note": None}


def test_setpoint_thresholds_from_resolution_and_noise():
    r = np.repeat([0.0, 5000.0, 15000.0], 40)
    assert setpoint_thresholds(r, Sensor(5000.0, 0.0)) == pytest.approx((4995.0, 4995.0))
    assert setpoint_thresholds(r, Sensor(1.0, 100.0)) == pytest.approx((500 * np.sqrt(2), 500.0))
    assert setpoint_thresholds(r, Sensor(0.0, 0.0))[0] == pytest.approx(15000.0 * 1e-9)


def test_setpoint_jumps_merge_glitches_and_ramps():
    r = np.repeat([0.0, 5.0, 15.0], 40)
    assert setpoint_jumps(r, 0.5, 0.5, 5) == [40, 80]
    glitch = np.zeros(100)
    glitch[30] = 3.0                          # one sample off and back: no step
    assert setpoint_jumps(glitch, 0.5, 0.5, 5) == []
    ramp = np.concatenate([np.zeros(40), [1.0, 2.0, 3.0], np.full(40, 4.0)])
    assert setpoint_jumps(ramp, 0.5, 0.5, 5) == [40]   # the step starts where the ramp starts
    assert setpoint_jumps([1.0], 0.5, 0.5) == []


def test_sensor_at_rest_ignores_motion_the_sampling_does_not_resolve():
    # 1 m strokes logged at 5 Hz with dwells, 5 um encoder with 3 um jitter: the differences are the motion
    rng = np.random.default_rng(0)
    one = np.concatenate([np.full(6, 0.1), np.linspace(0.1, 1.1, 6)[1:-1], np.full(6, 1.1),
                          np.linspace(1.1, 0.1, 6)[1:-1]])
    x = np.round((np.tile(one, 200) + rng.normal(0, 3e-6, one.size * 200)) / 5e-6) * 5e-6
    at_rest = describe_sensor_at_rest(x)
    assert at_rest.resolution == pytest.approx(5e-6, rel=1e-3) and at_rest.floor() == pytest.approx(5e-6, rel=1e-3)
    assert describe_sensor(x).floor() > 100 * at_rest.floor()              # fooled by the motion
    stated = describe_sensor_at_rest(x, resolution=1e-5, noise=2e-6)
    assert (stated.resolution, stated.noise, stated.source) == (1e-5, 2e-6, "metadata")
    # analog noise at rest between slow moves: the noise is measured
    y = np.repeat([0.0, 0.05, 0.0, 0.05], 2000) + rng.normal(0, 20e-6, 8000)
    assert describe_sensor_at_rest(y).noise == pytest.approx(20e-6, rel=0.1)


def test_time_base_gap_names_a_jump_of_the_clock_and_passes_lost_samples():
    from analyses.quality import time_base_gap

    t = np.arange(1000) * 0.01
    assert time_base_gap(t, 0.01) is None
    assert time_base_gap(np.delete(t, np.arange(0, 1000, 3)), 0.01) is None   # a third lost: 1.5 x
    t[600:] += 1e6
    assert time_base_gap(t, 0.01) == ("time base has a gap of 1e+06 s (1e+08 x the median step) at t = 5.99 s: "
                                      "a uniform grid would need 1e+08 points for 1000 samples (at most 2 x)")


def test_setpoint_jumps_on_settled_levels_not_on_every_change():
    # 1 kHz: a ramp of 100 samples, each its own value (15 a sample, one count of 15), then a hold
    r = np.concatenate([np.zeros(1000), 15.0 * np.arange(1, 101), np.full(900, 1500.0), np.zeros(1000)])
    assert setpoint_jumps(r, 14.985, 14.985, 5) == [1000, 2000]
    # a noisy read-back of it (5 sigma thresholds of 10 noise), settled over 12 samples
    noisy = r + np.random.default_rng(0).normal(0, 10.0, r.size)
    jumps = setpoint_jumps(noisy, 50 * np.sqrt(2), 50.0, 5, settle_points=settle_points(Sensor(0.0, 10.0), 5))
    assert len(jumps) == 2 and 1000 <= jumps[0] <= 1005 and jumps[1] == 2000
    # a two-level staircase stays two steps
    stairs = np.repeat([0.0, 750.0, 1500.0], 1000)
    assert setpoint_jumps(stairs, 14.985, 14.985, 5) == [1000, 2000]
    assert settle_points(Sensor(0.0, 10.0), 5) == 12 and settle_points(Sensor(1.0, 0.0), 5) == 5


def test_gram_se_is_jacobian_se_from_the_sums():
    from analyses.quality import gram_se, jacobian_se

    rng = np.random.default_rng(3)
    J = rng.normal(size=(200, 3)) * [1e5, 1.0, 1e-3]      # units ten decades apart
    J[:, 2] += 1e-3 * J[:, 1]
    r = rng.normal(0, 0.5, 200)
    se, cond = jacobian_se(J, r)
    se2, cond2 = gram_se(J.T @ J, float(np.sum(r ** 2)), 200 - 3)
    np.testing.assert_allclose(se2, se, rtol=1e-10)
    assert cond2 == pytest.approx(cond, rel=1e-8)
    J[:, 2] = 0.0                                        # a parameter the data cannot see
    assert gram_se(J.T @ J, 1.0, 197)[1] == float("inf") and np.isnan(gram_se(J.T @ J, 1.0, 197)[0]).all()
