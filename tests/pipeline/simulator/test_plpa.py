"""PLPA generators: the samples carry the physics the truth says."""
import numpy as np
import pytest

from pipeline.simulator import (NEAR_ZERO_SPEEDS_M_S, simulate_breakaway, simulate_identification,
                                simulate_leakage, simulate_step, simulate_viscous)
from pipeline.simulator.base import HOSE_AREA_M2
from pipeline.simulator.plpa import plant_zoh, seal_pressure_bar, step_metrics
from schemas.units import kg_s_to_l_min_anr


def test_seal_pressure_matches_paper_findings():
    assert seal_pressure_bar("distance", 3.0) == 7.5
    assert seal_pressure_bar("distance", 6.0) == 3.0
    assert seal_pressure_bar("force", spring_force_n=429.0) > 5.0   # 33 %: no leak up to 5 bar
    assert seal_pressure_bar("force", spring_force_n=858.0) > 6.0   # 66 %: none up to 6 bar


@pytest.mark.parametrize("chamber,z", [("A", 5.0), ("B", 6.0)])
def test_leakage_plateaus_recover_truth(chamber, z):
    run = simulate_leakage(chamber, "distance", z, rng=3)
    d = run.data
    assert list(d.columns) == ["t_s", "p_supply_pa", "q_leak_kg_s"]
    for plateau in run.truth["plateaus"]:
        m = (d.t_s >= plateau["t_settled_s"]) & (d.t_s < plateau["t_end_s"])
        q = kg_s_to_l_min_anr(d.q_leak_kg_s[m]).mean()
        assert q == pytest.approx(plateau["leak_l_min"], abs=0.02 + 0.01 * plateau["leak_l_min"])
        assert d.p_supply_pa[m].mean() / 1e5 == pytest.approx(plateau["pressure_bar"], abs=0.002)
    assert run.truth["plateaus"][6]["leak_l_min"] > 0 and run.truth["plateaus"][2]["leak_l_min"] == 0
    assert run.metadata["z_rollers_mm"] == z and "spring_force_n" not in run.metadata


def test_leakage_pressure_transients_are_not_instantaneous():
    d = simulate_leakage("A", rng=1).data
    step = d.t_s.searchsorted(6.0)
    assert 0.2e5 < d.p_supply_pa.iloc[step + 10] < 0.6e5  # 0.1 s into a 1 bar step with tau 0.3 s


@pytest.mark.parametrize("direction,bp", [("P", 0.0), ("N", 2.0)])
def test_breakaway_force_at_onset(direction, bp):
    run = simulate_breakaway(direction, bp, 2.0, rng=5)
    d, tr = run.data, run.truth
    sign = 1 if direction == "P" else -1
    force = sign * (d.p_a_pa - d.p_b_pa) * HOSE_AREA_M2
    near = (d.t_s > tr["onset_time_s"] - 0.05) & (d.t_s <= tr["onset_time_s"])
    assert force[near].mean() == pytest.approx(tr["breakaway_force_n"], abs=0.3)
    before = d.t_s < tr["onset_time_s"]
    creep = sign * (d.x_m[before] - tr["x0_m"])
    assert creep.max() <= 5e-6 + 1e-12          # pre-sliding: a few um at most
    assert sign * (d.x_m.iloc[-1] - tr["x0_m"]) > 0.005  # then gross motion
    assert np.allclose(np.round(d.x_m / 5e-6), d.x_m / 5e-6, atol=1e-6)  # 5 um encoder
    assert abs(tr["breakaway_mean_n"] - (10.0 if bp == 0 else 5.0)) < 1e-12


def test_breakaway_noise_is_about_300_pa():
    d = simulate_breakaway("P", 1.0, 2.0, rng=2).data
    hold = d.t_s < 0.9
    assert 250 < d.p_b_pa[hold].std() < 350


@pytest.mark.parametrize("use_force", [False, True])
def test_viscous_passes_measure_friction(use_force):
    run = simulate_viscous(1.0, use_force_channel=use_force, rng=4)
    d = run.data
    for p in run.truth["passes"]:
        m = (d.t_s >= p["t_settled_s"]) & (d.t_s <= p["t_end_s"])
        f = d.f_n[m] if use_force else (d.p_a_pa[m] - d.p_b_pa[m]) * HOSE_AREA_M2
        assert f.mean() == pytest.approx(p["friction_n"], abs=0.1)
        v = np.polyfit(d.t_s[m], d.x_m[m], 1)[0]
        assert v == pytest.approx(p["velocity_m_s"], rel=0.01)
    assert ("f_n" in d) == use_force and ("p_a_pa" in d) != use_force


def test_near_zero_viscous_run_is_slow_and_symmetric():
    run = simulate_viscous(0.0, speeds_m_s=NEAR_ZERO_SPEEDS_M_S, rng=1)
    fr = {p["velocity_m_s"]: p["friction_n"] for p in run.truth["passes"]}
    assert max(abs(v) for v in fr) <= 7e-3
    assert fr[0.0005] == pytest.approx(-fr[-0.0005]) and fr[0.0005] == pytest.approx(3.0 * np.tanh(1) + 25 * 5e-4)


def test_identification_is_exact_zoh_closed_loop():
    run = simulate_identification(rng=1, duration_s=20.0)
    d, tr = run.data, run.truth
    assert np.allclose(d.u_v, tr["kp_v_m"] * (d.x_ref_m - d.x_m) + d.u_d_v, atol=2e-6)
    held = np.diff(d.u_d_v.to_numpy()[:2000].reshape(-1, 100), axis=1)
    assert np.all(held == 0)  # held for 0.02 s at 5 kHz
    assert d.u_d_v.to_numpy()[::100].var() == pytest.approx(0.25, rel=0.15)
    # the plant of Table 1, discretised ZOH at the log rate, reproduces the position from u
    ad, bd = plant_zoh(1 / tr["fs_hz"], tr["wn_rad_s"], tr["zeta"], tr["k_lin_m_v_s"])
    s = np.array([tr["x_ref_m"], 0.0, 0.0])
    xs = []
    for u in d.u_v.to_numpy():
        xs.append(s[0])
        s = ad @ s + bd * u
    assert np.max(np.abs(np.array(xs) - d.x_m)) <= 2.5e-6 + 1e-9


def test_step_metrics_match_paper():
    run = simulate_step()
    for s in run.truth["steps"]:
        assert s["overshoot_pct"] == pytest.approx(1.2, abs=0.2)
        assert s["settling_time_s"] == pytest.approx(4.0, abs=0.3)
        assert abs(s["steady_state_error_mm"]) < 0.005
    d = run.data
    end = (d.t_s >= 10.5) & (d.t_s < 11.0)
    assert np.abs(d.x_m[end] - d.x_ref_m[end]).max() <= 10e-6


def test_step_metrics_of_a_reference_that_never_jumps_are_nan_without_warnings():
    """A zero step (0/0 when normalising by the step) or an empty window has nothing to measure."""
    import math
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run = simulate_step(0, steps_mm=(0.0,), hold_s=2.0)
        (s,) = run.truth["steps"]
        t = np.arange(10) * 0.1
        empty = step_metrics(t, np.zeros(10), 5.0, 0.0, 0.02, 6.0)       # no sample in [5, 6) s
    for met in (s, empty):
        for key in ("overshoot_pct", "settling_time_s", "rise_time_s", "steady_state_error_mm"):
            assert math.isnan(met[key]), key
    assert s["step_mm"] == 0.0
    good = step_metrics(t, np.minimum(t, 0.5) * 0.04, 0.0, 0.0, 0.02, 1.0)   # ramp to 20 mm at 0.5 s
    assert good["overshoot_pct"] == 0.0 and good["steady_state_error_mm"] == pytest.approx(0.0)
