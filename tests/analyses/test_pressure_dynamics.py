"""PLA pressure dynamics: the second-order step response, step splitting, and recovery of Table 2."""
import math

import numpy as np
import pytest
from matplotlib.figure import Figure
from scipy import signal

from analyses.pressure_dynamics import (fit_pressure_dynamics, plot_pressure_steps, second_order_step,
                                        split_pressure_steps)
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
