"""PLA pressure dynamics: the second-order step response, step splitting, and recovery of Table 2."""
import math

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure
from scipy import signal

from analyses.pressure_dynamics import (ZETA_BOUNDS, RunPart, age_changes,
                                        first_order_step, fit_pressure_dynamics, group_pressure_steps,
                                        plot_pressure_ageing, plot_pressure_steps, second_order_step,
                                        split_pressure_steps, step_threshold)
from analyses.quality import Sensor, sensor_from_params
from pipeline.simulator import simulate_pressure_step


@pytest.mark.parametrize("zeta", [0.3, 0.69, 0.9999999, 1.0, 1.0000001, 1.5, 4.0])
def test_step_response_matches_scipy(zeta):
    t = np.linspace(0, 0.4, 801)
    _, y = signal.step(([52.0 ** 2], [1, 2 * zeta * 52.0, 52.0 ** 2]), T=t)
    np.testing.assert_allclose(second_order_step(t, 1e5, 4e5, 52.0, zeta), 1e5 + 3e5 * y, atol=1e-3)


def test_step_response_hand_values():
    # critically damped: P = Pref - (Pref - P0) e^(-wn t) (1 + wn t); at t = 1/wn: 2/e of the step left
    assert second_order_step(1 / 50.0, 0.0, 1.0, 50.0, 1.0) == pytest.approx(1 - 2 / math.e)
    # under-damped overshoot exp(-pi zeta / sqrt(1 - zeta^2)) at t = pi / wd
    z, wn = 0.5, 40.0
    tp = math.pi / (wn * math.sqrt(1 - z * z))
    assert second_order_step(tp, 0.0, 1.0, wn, z) == pytest.approx(1 + math.exp(-math.pi * z / math.sqrt(1 - z * z)))
    assert second_order_step(0.0, 2.0, 5.0, wn, z) == pytest.approx(2.0)



@pytest.mark.parametrize("zeta", [0.3, 0.69, 1.0, 1.0003, 4.0, 50.0])
def test_the_steps_laid_end_to_end_give_each_steps_model_bit_for_bit(zeta):
    # the fits evaluate the model once over all their steps: the same numbers as one call per step
    from analyses.pressure_dynamics import _model, _model1, _Stacked

    run = simulate_pressure_step("rear", rng=2)
    d = run.data
    steps = split_pressure_steps(d["t_s"], d["p_pa"], d["p_ref_pa"], "r", "rear")
    stacked = _Stacked.of(steps)
    each = np.concatenate([second_order_step(s.t, s.p_start_pa, s.p_ref_pa, 52.0, zeta) for s in steps])
    assert np.array_equal(_model(stacked, 52.0, zeta).view(np.int64), each.view(np.int64))
    each = np.concatenate([first_order_step(s.t, s.p_start_pa, s.p_ref_pa, zeta / 100) for s in steps])
    assert np.array_equal(_model1(stacked, zeta / 100).view(np.int64), each.view(np.int64))

def test_split_finds_charges_and_discharges():
    run = simulate_pressure_step("rear", rng=0)
    d = run.data
    steps = split_pressure_steps(d["t_s"], d["p_pa"], d["p_ref_pa"], "r", "rear")
    truth = run.truth["steps"]
    assert [s.direction for s in steps] == [s["direction"] for s in truth]
    assert [s.t_step_s for s in steps] == pytest.approx([s["t_step_s"] for s in truth])
    assert [s.p_ref_pa for s in steps] == pytest.approx([s["p_to_pa"] for s in truth])
    assert [s.p_start_pa for s in steps] == pytest.approx([s["p_from_pa"] for s in truth], abs=300)
    t = np.arange(100) / 1000
    assert split_pressure_steps(t, np.zeros(100), np.full(100, 2e5)) == []


@pytest.mark.parametrize("chamber,wn,xi", [("rear", 52.0, {"charge": 1.00, "discharge": 0.69}),
                                           ("front", 80.0, {"charge": 0.8, "discharge": 1.3})])
def test_recovers_wn_and_xi_per_direction(chamber, wn, xi):
    run = simulate_pressure_step(chamber, rng=4, wn=wn, xi=xi)
    d = run.data
    steps = split_pressure_steps(d["t_s"], d["p_pa"], d["p_ref_pa"], "r", chamber)
    fits = {}
    for direction in ("charge", "discharge"):
        fit = fit_pressure_dynamics([s for s in steps if s.direction == direction])
        fits[direction] = fit
        assert fit.direction == direction and fit.chamber == chamber
        assert fit.n_steps == sum(s["direction"] == direction for s in run.truth["steps"])
        assert fit.wn_rad_s == pytest.approx(wn, rel=0.05)
        assert fit.zeta == pytest.approx(xi[direction], rel=0.05)
        assert fit.nrmse_pct < 1.0
        assert len(fit.step_nrmse_pct) == fit.n_steps
        assert fit.model == "second_order" and math.isnan(fit.tau_s) and fit.note is None
    assert isinstance(plot_pressure_steps(steps, fits), Figure)


def test_wrong_model_has_a_larger_nrmse():
    run = simulate_pressure_step("rear", rng=5)
    d = run.data
    steps = [s for s in split_pressure_steps(d["t_s"], d["p_pa"], d["p_ref_pa"]) if s.direction == "discharge"]
    fit = fit_pressure_dynamics(steps)
    y = np.concatenate([s.p for s in steps])
    slow = np.concatenate([second_order_step(s.t, s.p_start_pa, s.p_ref_pa, 26.0, 0.69) for s in steps])
    assert 100 * np.sqrt(np.mean((y - slow) ** 2)) / np.ptp(y) > 5 * fit.nrmse_pct


def test_no_steps_gives_nan():
    fit = fit_pressure_dynamics([], "rear", "charge")
    assert not fit.ok and math.isnan(fit.wn_rad_s) and fit.n_steps == 0


# -- first-order responses under closed-loop set-point sweeps (the real rigs' case) ----------------
#: A closed-loop sweep of 5 and 10 kPa set-point steps around 1 bar gauge. [bar]
SWEEP = (1.0, 1.05, 1.15, 1.10, 1.0, 1.10, 1.15, 1.05, 1.0, 1.1, 1.2, 1.15, 1.05)
TAU = {"charge": 0.25, "discharge": 0.4}


def _fits(run, params=None):
    d = run.data
    steps = split_pressure_steps(d["t_s"], d["p_pa"], d["p_ref_pa"], "r", "rear",
                                 ref_sensor=sensor_from_params(params, "p_ref", d["p_ref_pa"]),
                                 p_sensor=sensor_from_params(params, "p", d["p_pa"]))
    return steps, {dr: fit_pressure_dynamics([s for s in steps if s.direction == dr]) for dr in ("charge", "discharge")}


@pytest.mark.parametrize("fs_hz", [20.0, 1000.0])
def test_first_order_sweep_with_5_and_10_kpa_steps(fs_hz):
    run = simulate_pressure_step("rear", rng=1, levels_bar=SWEEP, hold_s=3.0, fs_hz=fs_hz, tau_s=TAU)
    steps, fits = _fits(run)
    truth = run.truth["steps"]
    # every step is found, the 5 kPa ones included, at the right time and size
    assert [round(s.p_ref_pa - s.p_ref_before_pa) for s in steps] == [round(s["p_to_pa"] - s["p_from_pa"])
                                                                       for s in truth]
    assert sorted({abs(round(s.p_ref_pa - s.p_ref_before_pa)) for s in steps}) == [5000, 10000]
    assert [s.t_step_s for s in steps] == pytest.approx([s["t_step_s"] for s in truth])
    assert all(s.usable for s in steps)
    for direction, fit in fits.items():
        assert fit.model == "first_order", fit
        assert fit.tau_s == pytest.approx(TAU[direction], rel=0.05)   # stated tolerance: 5 %
        assert math.isnan(fit.zeta) and math.isnan(fit.wn_rad_s)       # no zeta, at a bound or not
        assert fit.note is None and fit.n_steps == 6
        assert fit.bic["first_order"] < fit.bic["second_order"] + 6.0
    assert isinstance(plot_pressure_steps(steps, fits), Figure)


def test_overdamped_second_order_fit_at_its_bound_is_reported_first_order():
    # 1 kHz first-order data: the second-order fit runs to zeta = 50 (the real rig's discharge)
    run = simulate_pressure_step("rear", rng=3, levels_bar=SWEEP, hold_s=3.0, fs_hz=1000.0, tau_s=0.3)
    _, fits = _fits(run)
    for fit in fits.values():
        assert fit.model == "first_order" and fit.tau_s == pytest.approx(0.3, rel=0.03)
        assert not (fit.zeta == pytest.approx(ZETA_BOUNDS[1]))


def test_noisy_read_back_set_point_with_stated_sensors():
    run = simulate_pressure_step("rear", rng=5, levels_bar=SWEEP, hold_s=3.0, fs_hz=20.0, tau_s=0.3, ref_noise_pa=200.0)
    params = {"sensor_p_ref_noise": 200.0, "sensor_p_ref_resolution": 1.0, "sensor_p_noise": 300.0}
    steps, fits = _fits(run, params)
    assert len(steps) == len(run.truth["steps"]) == 12
    for fit in fits.values():
        assert fit.model == "first_order" and fit.tau_s == pytest.approx(0.3, rel=0.05)


def test_second_order_sampled_too_slowly_is_not_claimed():
    # wn = 52 rad/s, xi = 1 sampled at 20 Hz: the data cannot tell it from a first-order lag
    run = simulate_pressure_step("rear", rng=2, levels_bar=SWEEP, hold_s=3.0, fs_hz=20.0)
    _, fits = _fits(run)
    for fit in fits.values():
        assert fit.model == "first_order" or fit.model is None
        assert math.isnan(fit.zeta)


def test_response_faster_than_the_sampling_is_null_with_a_note():
    run = simulate_pressure_step("rear", rng=3, levels_bar=SWEEP, hold_s=3.0, fs_hz=20.0, tau_s=0.001)
    _, fits = _fits(run)
    fit = fits["discharge"]
    assert not fit.ok and fit.model is None and math.isnan(fit.tau_s) and math.isnan(fit.zeta)
    assert "not identifiable" in fit.note or "bound" in fit.note


def test_steps_under_the_pressure_sensor_floor_are_listed_not_fitted():
    # 0.5 and 1 kPa set-point steps, 300 Pa pressure noise: found on the clean set-point, not fittable
    run = simulate_pressure_step("rear", rng=1, levels_bar=(1.0, 1.005, 1.015, 1.01, 1.0), hold_s=3.0, fs_hz=20.0,
                                 tau_s=0.3)
    steps, fits = _fits(run, {"sensor_p_noise": 300.0})
    assert len(steps) == 4 and not any(s.usable for s in steps)
    assert all("under 5 x the pressure sensor floor (300 Pa)" in s.note for s in steps)
    for fit in fits.values():
        assert not fit.ok and fit.n_steps == 0 and "no step large enough" in fit.note
        assert all(math.isnan(v) for v in fit.step_nrmse_pct) and len(fit.step_nrmse_pct) == 2


def test_step_threshold_from_the_set_point_sensor():
    r = np.repeat([1e5, 1.05e5, 1.15e5], 50)
    # a quantised, noise-free set-point: one count is a change (5 kPa steps with a 5 kPa count)
    jump, level = step_threshold(r, Sensor(resolution=5000.0, noise=0.0))
    assert jump == level == pytest.approx(4995.0)
    assert len(split_pressure_steps(np.arange(r.size) * 0.05, r, r, ref_sensor=Sensor(5000.0, 0.0))) == 2
    # a noisy read-back: 5 sigma of a difference (sqrt 2 sigma) for a jump, 5 sigma for a level
    jump, level = step_threshold(r, Sensor(resolution=1.0, noise=100.0))
    assert jump == pytest.approx(500 * math.sqrt(2)) and level == pytest.approx(500.0)
    # nothing stated, a clean set-point: any change beyond float round-off
    jump, _ = step_threshold(r)
    assert jump < 1.0


def test_noise_spike_on_the_set_point_is_not_a_step():
    t = np.arange(300) * 0.05
    r = np.where(t < 7.5, 1e5, 1.05e5)
    r[50] += 3000.0        # one glitch, back the next sample
    p = first_order_step(t - 7.5, 1e5, 1.05e5, 0.2) * (t >= 7.5) + 1e5 * (t < 7.5)
    steps = split_pressure_steps(t, p, r, p_sensor=Sensor(1.0, 100.0), ref_sensor=Sensor(1.0, 100.0))
    assert [(s.t_step_s, s.direction) for s in steps] == [(pytest.approx(7.5), "charge")]


def test_first_order_step_hand_values():
    assert first_order_step(0.2, 1e5, 2e5, 0.2) == pytest.approx(2e5 - 1e5 / math.e)
    assert first_order_step(0.0, 1e5, 2e5, 0.2) == pytest.approx(1e5)


#: A roller pinch valve on peristaltic tubing, new and after 594 h: softer tubing, lower wn, more damping.
VALVE = {0.0: (40.0, {"charge": 0.5, "discharge": 0.7}), 594.0: (31.0, {"charge": 0.65, "discharge": 0.85})}


def test_recovers_wn_and_zeta_per_age_from_noisy_steps():
    """Noisy 1 kHz steps of one valve at two ages on one rig: each age's (wn, zeta) within 5 %,
    the change between ages within 5 points of the truth, the rig's pooled row beside them."""
    levels = (0.005, 0.025, 0.005, 0.02, 0.005, 0.03, 0.005)       # PEEP <-> PIP, bar gauge
    steps, runs = [], {}
    for k, (age, (wn, xi)) in enumerate(VALVE.items()):
        run = simulate_pressure_step("patient", rng=40 + k, levels_bar=levels, hold_s=1.0, wn=wn, xi=xi,
                                     noise_pa=5.0)
        rid = f"c/valve-{age:g}h"
        runs[rid] = RunPart("c", "vent", "valve", "V1", age, None)
        steps += split_pressure_steps(run.data["t_s"], run.data["p_pa"], run.data["p_ref_pa"], rid, "patient")
    groups = group_pressure_steps(steps, runs)
    fits = {g: fit_pressure_dynamics(s, g.chamber, g.direction) for g, s in groups.items()}
    for g, f in fits.items():
        if g.level == "part":
            wn, xi = VALVE[g.age_h]
            assert f.model == "second_order" and f.note is None, (g, f.note)
            assert f.wn_rad_s == pytest.approx(wn, rel=0.05) and f.zeta == pytest.approx(xi[g.direction], rel=0.05)
            assert f.n_steps == 3
    assert sorted(g.level for g in fits) == ["part"] * 4 + ["rig"] * 2
    ch = age_changes(fits)
    for g, c in ch.items():
        if g.age_h == 594.0:
            assert c["wn_change_pct"] == pytest.approx(100 * (31.0 / 40.0 - 1), abs=5)
            xi0, xi1 = VALVE[0.0][1][g.direction], VALVE[594.0][1][g.direction]
            assert c["zeta_change_pct"] == pytest.approx(100 * (xi1 / xi0 - 1), abs=5)
    table = pd.DataFrame([{"level": g.level, "rig": g.rig, "chamber": g.chamber, "direction": g.direction,
                           "part_kind": g.part_kind, "part_id": g.part_id, "part_age_h": g.age_h,
                           "part_distance_km": g.distance_km, "wn_rad_s": f.wn_rad_s, "zeta": f.zeta,
                           "tau_s": f.tau_s} for g, f in fits.items()])
    fig = plot_pressure_ageing(table)
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    assert fig.axes[0].get_xlabel() == "age of the part [h]"
    assert {len(line.get_xdata()) for line in fig.axes[0].lines} == {2}    # new and aged, per direction


def _breaths(fs_hz=1000.0, ramp_s=0.1, peep_pa=500.0, pip_pa=2000.0, mid_pa=None, hold_s=1.0):
    """A ventilator's set-point at ``fs_hz``: PEEP, a ramp to PIP over ``ramp_s`` in one-sample
    plateaus (a new value every sample), PIP, back to PEEP; or, with ``mid_pa``, a two-level staircase
    PEEP -> mid -> PIP, each level held ``hold_s``."""
    n_hold = int(round(hold_s * fs_hz))
    if mid_pa is None:
        n_ramp = int(round(ramp_s * fs_hz))
        ramp = peep_pa + (pip_pa - peep_pa) * np.arange(1, n_ramp + 1) / n_ramp
        r = np.concatenate([np.full(n_hold, peep_pa), ramp, np.full(n_hold - n_ramp, pip_pa), np.full(n_hold, peep_pa)])
    else:
        r = np.repeat([peep_pa, mid_pa, pip_pa, peep_pa], n_hold)
    t = np.arange(r.size) / fs_hz
    return t, r


@pytest.mark.parametrize("ref_noise, ref_res, stated", [(0.0, 0.0, False), (5.0, 10.0, True), (10.0, 10.0, True),
                                                     (20.0, 0.0, False)])
def test_ramped_set_point_is_one_step_starting_where_the_ramp_starts(ref_noise, ref_res, stated):
    # PEEP 500 Pa -> PIP 2000 Pa over 100 ms in one-sample plateaus at 1 kHz (15 Pa a sample):
    # one charge step at 1.0 s, not one per change (before: the clean ramp gave 20 charge steps,
    # a read-back with 5 Pa noise in 10 Pa counts 6, with 10 Pa noise 17); a read-back noisier
    # than the ramp's rate (20 Pa a sample) too, its sensor estimated from the record
    t, r = _breaths()
    rng = np.random.default_rng(3)
    ref = r + rng.normal(0, ref_noise, r.size) if ref_noise else r
    ref = np.round(ref / ref_res) * ref_res if ref_res else ref
    p = r + rng.normal(0, 20.0, r.size)
    steps = split_pressure_steps(t, p, ref, ref_sensor=Sensor(ref_res, ref_noise) if stated else None)
    assert [s.direction for s in steps] == ["charge", "discharge"]
    assert steps[0].t_step_s == pytest.approx(1.0, abs=0.005 if ref_noise else 1e-9)
    assert steps[0].p_ref_before_pa == pytest.approx(500.0, abs=10)
    assert steps[0].p_ref_pa == pytest.approx(2000.0, abs=10)
    assert steps[1].t_step_s == pytest.approx(2.0, abs=0.002)


def test_two_level_staircase_stays_two_steps():
    # the hostile neighbour: PEEP -> 1250 Pa -> 2000 Pa, each level held 1 s, is two charge steps
    for fs_hz, hold_s in ((1000.0, 1.0), (1000.0, 0.02), (20.0, 1.5)):
        t, r = _breaths(fs_hz=fs_hz, mid_pa=1250.0, hold_s=hold_s)
        steps = split_pressure_steps(t, r, r)
        assert [(s.direction, s.p_ref_pa) for s in steps] == [("charge", 1250.0), ("charge", 2000.0),
                                                              ("discharge", 500.0)], (fs_hz, hold_s)
