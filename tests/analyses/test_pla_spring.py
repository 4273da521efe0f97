"""PLA spring model: hand-checked equations and signs, the loop energy, P0 read from each run, and the runs a fit cannot use."""
import math

import numpy as np
import pandas as pd
import pytest

from analyses.quality import Sensor
from analyses.quality import nrmse_pct as nrmse_percent
from analyses.pla_spring import loop_energy, prepare_spring_run, read_p0, spring_force, spring_pressure
from analyses.pla_spring_fit import fit_spring_chamber, model_loop_energy, spring_run_stats
from pipeline.simulator import simulate_spring

PA = 101325.0


def test_polytropic_pressure_hand_values_and_signs():
    assert spring_pressure(0.0, 3e5, 1.1, "rear") == pytest.approx(3e5)
    # rear: extension enlarges the chamber; front: extension compresses it (C/2 = 20 mm)
    assert spring_pressure(0.005, 3e5, 1.1, "rear") == pytest.approx(3e5 * (20 / 25) ** 1.1)
    assert spring_pressure(0.005, 3e5, 1.1, "front") == pytest.approx(3e5 * (20 / 15) ** 1.1)
    with pytest.raises(ValueError):
        spring_pressure(0.0, 3e5, 1.1, "middle")


def test_force_terms_and_loop_direction():
    # at mid-stroke, moving: elastic (P0 - Pa) Ae plus s_f (eps (P0 - Pa) + delta v / (2 pi f))
    f = spring_force(0.0, 0.01, 3e5, 1.0, 1.1, 1.8e-3, 2e-5, 3000.0, "rear")
    g = 3e5 - PA
    assert f == pytest.approx(g * 1.8e-3 - (2e-5 * g + 3000 * 0.01 / (2 * math.pi)))
    f = spring_force(0.0, 0.01, 3e5, 1.0, 1.1, 1.8e-3, 2e-5, 3000.0, "front")
    assert f == pytest.approx(g * 1.8e-3 + (2e-5 * g + 3000 * 0.01 / (2 * math.pi)))
    # compression is the upper branch: rear compresses while d falls, front while d rises
    t = np.linspace(0, 1, 4001)
    d = 0.005 * np.sin(2 * np.pi * t)
    v = 0.005 * 2 * np.pi * np.cos(2 * np.pi * t)
    for chamber in ("rear", "front"):
        f = spring_force(d, v, 3e5, 1.0, 1.1, 1.8e-3, 2e-5, 3000.0, chamber)
        at0 = np.abs(d) < 1e-5
        compress = (v < 0) if chamber == "rear" else (v > 0)
        assert f[at0 & compress].min() > f[at0 & ~compress].max()


def test_loop_energy_of_structural_damping_is_pi_delta_d_squared():
    t = np.linspace(0, 3, 30001)
    for chamber in ("rear", "front"):
        for amp, freq in ((0.003, 1.0), (0.007, 4.0)):
            d = amp * np.sin(2 * np.pi * freq * t)
            v = amp * 2 * np.pi * freq * np.cos(2 * np.pi * freq * t)
            f = spring_force(d, v, 3e5, freq, 1.1, 1.8e-3, 0.0, 3000.0, chamber)
            energy, cycles = loop_energy(d, f, chamber)
            assert cycles >= round(3 * freq) - 2
            assert energy == pytest.approx(math.pi * 3000.0 * amp ** 2, rel=2e-3)


def test_read_p0_is_the_pressure_at_mid_stroke():
    t = np.linspace(0, 3, 3001)
    d = 0.005 * np.sin(2 * np.pi * t)
    p = spring_pressure(d, 4e5, 1.1, "front") - PA + np.random.default_rng(0).normal(0, 300, len(t))
    assert read_p0(d, p) == pytest.approx(4e5, abs=300)
    assert read_p0(d, p, p_atm=100000.0) == pytest.approx(4e5 - 1325, abs=300)
    assert math.isnan(read_p0(np.full(10, 0.001), np.zeros(10)))


def test_nrmse_definition():
    assert nrmse_percent([0, 10, 0, 10], [1, 9, -1, 11]) == pytest.approx(10.0)


def _prepared(chamber, tests, seed0=0, **kw):
    runs = []
    for i, (p0, amp, freq) in enumerate(tests):
        sim = simulate_spring(chamber, p0, amp, freq, rng=seed0 + i, **kw)
        d = sim.data
        runs.append(prepare_spring_run(f"{chamber}-{i:03d}", d["t_s"], d["d_m"], d["f_n"], d["p_pa"], chamber,
                                       sim.metadata["frequency_hz"], sim.metadata["amplitude_mm"] / 1e3))
    return runs, sim.truth


def test_p0_is_read_from_the_run_not_assumed():
    # a run whose true P0 is off the nominal grid: the model uses what the run shows
    runs, truth = _prepared("rear", [(2.0, 5.0, 1.0), (3.3, 5.0, 1.0), (4.7, 7.0, 2.0), (2.6, 3.0, 0.5)])
    assert [r.p0_abs for r in runs] == pytest.approx([2.0e5, 3.3e5, 4.7e5, 2.6e5], abs=300)
    fit = fit_spring_chamber(runs)
    assert fit.ae_m2 == pytest.approx(truth["Ae"], rel=0.02)
    assert max(fit.nrmse_pct.values()) < 2.5


def test_loop_energy_grows_with_amplitude_not_frequency():
    tests = [(3.0, a, f) for a in (3.0, 5.0, 7.0) for f in (0.5, 1.0, 4.0)]
    runs, truth = _prepared("rear", tests)
    e = pd.DataFrame({"amplitude_mm": [r.amplitude_m * 1e3 for r in runs], "frequency_hz": [r.frequency_hz for r in runs],
                      "loop_energy_j": [r.loop_energy_j for r in runs]})
    by_amp = e.groupby("amplitude_mm")["loop_energy_j"].mean()
    assert by_amp[3.0] < by_amp[5.0] < by_amp[7.0]
    spread = e.groupby("amplitude_mm")["loop_energy_j"].agg(lambda s: s.max() / s.min())
    assert (spread < 1.1).all()   # frequency independent: structural, not viscous
    fit = fit_spring_chamber(runs)
    for r in runs:
        assert model_loop_energy(spring_run_stats(r), fit) == pytest.approx(r.loop_energy_j, rel=0.05)


def test_unusable_runs_are_flagged_not_raised():
    t = np.linspace(0, 1, 500)
    still = prepare_spring_run("s", t, np.zeros_like(t), np.ones_like(t), np.full_like(t, 2e5), "rear", 1.0, 0.005)
    assert not still.ok and "no displacement" in still.message
    short = prepare_spring_run("s", t[:5], t[:5], t[:5], t[:5], "rear", 1.0, 0.005)
    assert not short.ok and "too short" in short.message
    fit = fit_spring_chamber([still])
    assert not fit.ok and math.isnan(fit.n_polytropic)


def test_motion_judged_against_the_displacement_sensor():
    t = np.linspace(0, 3, 3000)
    dither = np.round(np.random.default_rng(0).normal(0, 0.4e-6, t.size) / 1e-6) * 1e-6   # LVDT counts only
    still = prepare_spring_run("s", t, dither, np.ones_like(t), np.full_like(t, 2e5), "rear", 1.0, 0.005,
                               d_sensor=Sensor(1e-6, 0.5e-6))
    assert not still.ok and "no displacement" in still.message


# -- the joint fit from per-run sufficient statistics -------------------------------------------


