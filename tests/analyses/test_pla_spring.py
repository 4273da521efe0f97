"""PLA spring model: hand-checked equations and signs, then recovery of Table 1 from simulated tests."""
import itertools
import math

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure

from analyses.quality import Sensor
from analyses.quality import nrmse_pct as nrmse_percent
from analyses.pla_spring import (fit_spring_chamber, loop_energy, model_loop_energy,
                                 plot_loop_energy, plot_spring_loops, prepare_spring_run, read_p0, spring_force,
                                 spring_model_force, spring_nrmse, spring_run_stats, fit_spring_stats,
                                 spring_pressure)
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


PAPER_GRID = list(itertools.product((2.0, 3.0, 4.0, 5.0), (3.0, 5.0, 7.0), (0.5, 1.0, 1.5, 2.0, 4.0)))


@pytest.mark.parametrize("chamber", ["rear", "front"])
def test_recovers_table1_over_the_paper_grid(chamber):
    runs, truth = _prepared(chamber, PAPER_GRID)
    assert all(r.ok for r in runs)
    assert [round(r.p0_abs / 1e5, 2) for r in runs[::15]] == [2.0, 3.0, 4.0, 5.0]
    fit = fit_spring_chamber(runs)
    assert fit.ok and fit.n_tests == 60
    assert fit.n_polytropic == pytest.approx(truth["n"], rel=0.02)
    assert fit.ae_m2 == pytest.approx(truth["Ae"], rel=0.02)
    assert fit.epsilon_m2 == pytest.approx(truth["eps"], rel=0.10)
    assert fit.delta_n_m == pytest.approx(truth["delta"], rel=0.10)
    assert len(fit.nrmse_pct) == 60
    assert max(fit.nrmse_pct.values()) < 2.5
    # the paper's seeds are already close (section 3.2)
    assert fit.seeds["ae_m2"] == pytest.approx(truth["Ae"], rel=0.05)
    assert fit.seeds["n_polytropic"] == pytest.approx(truth["n"], rel=0.05)
    assert fit.seeds["delta_n_m"] == pytest.approx(truth["delta"], rel=0.5)


def test_p0_is_read_from_the_run_not_assumed():
    # a run whose true P0 is off the nominal grid: the model uses what the run shows
    runs, truth = _prepared("rear", [(2.0, 5.0, 1.0), (3.3, 5.0, 1.0), (4.7, 7.0, 2.0), (2.6, 3.0, 0.5)])
    assert [r.p0_abs for r in runs] == pytest.approx([2.0e5, 3.3e5, 4.7e5, 2.6e5], abs=300)
    fit = fit_spring_chamber(runs)
    assert fit.ae_m2 == pytest.approx(truth["Ae"], rel=0.02)
    assert max(fit.nrmse_pct.values()) < 2.5


def test_wrong_parameters_give_a_large_nrmse():
    runs, truth = _prepared("front", [(3.0, 5.0, 1.0), (5.0, 7.0, 1.0)])
    fit = fit_spring_chamber(runs)
    from analyses.pla_spring import SpringFit, spring_nrmse
    bad = SpringFit("front", fit.n_polytropic, fit.ae_m2, -fit.epsilon_m2, -fit.delta_n_m)  # loop the wrong way
    assert spring_nrmse(runs[0], bad) > 2 * spring_nrmse(runs[0], fit)


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


def test_figures():
    runs, _ = _prepared("front", [(2.0, 5.0, 1.0), (5.0, 5.0, 1.0), (3.0, 3.0, 1.0), (3.0, 7.0, 1.0)])
    fit = fit_spring_chamber(runs)
    fig = plot_spring_loops(runs, fit)
    assert isinstance(fig, Figure)
    assert sum(ax.get_visible() for ax in fig.axes) == 4
    table = pd.DataFrame({"chamber": "front", "p0_bar_abs": [r.p0_abs / 1e5 for r in runs],
                          "amplitude_mm": [r.amplitude_m * 1e3 for r in runs],
                          "frequency_hz": [r.frequency_hz for r in runs],
                          "loop_energy_j": [r.loop_energy_j for r in runs]})
    fig = plot_loop_energy(table, {"front": fit})
    assert isinstance(fig, Figure)
    # each legend sits off its panel, so it hides no curve (the D = 7 mm lines at 2.5-4 Hz were)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        legend = ax.get_legend()
        assert legend is not None and legend.get_texts()
        box = legend.get_window_extent(renderer)
        assert not box.overlaps(ax.get_window_extent(renderer))
        assert all(not box.overlaps(other.get_window_extent(renderer)) for other in fig.axes)


SMALL_GRID = [(p0, a, 1.0) for p0 in (2.0, 4.0) for a in (3.0, 7.0)]


def test_sound_fit_has_no_note_and_small_standard_errors():
    runs, truth = _prepared("rear", SMALL_GRID)
    fit = fit_spring_chamber(runs)
    assert fit.ok and fit.note is None and fit.test_notes == {}
    for k, v in zip(("n_polytropic", "ae_m2", "epsilon_m2", "delta_n_m"), fit.params):
        assert fit.se[k] < 0.1 * v
    assert all(r.f_noise_n == pytest.approx(2.0, rel=0.1) for r in runs)   # the load cell's 2 N, estimated


def test_parameter_at_a_bound_is_null_with_a_note():
    # friction that helps the motion (eps < 0) is outside the model: eps runs to its lower bound 0
    runs, _ = _prepared("rear", SMALL_GRID, params={"eps_m2": -2e-5})
    fit = fit_spring_chamber(runs)
    assert not fit.ok and np.isnan(fit.params).all()
    assert "epsilon_m2 ran to the optimiser's lower bound" in fit.note
    assert all(np.isfinite(v) for v in fit.nrmse_pct.values())     # the evidence is kept


def test_model_that_misses_the_data_is_null_and_each_test_says_so():
    # rear-chamber runs labelled front: the polytropic term bends the wrong way
    runs = []
    for i, (p0, amp, freq) in enumerate(SMALL_GRID):
        d = simulate_spring("rear", p0, amp, freq, rng=i).data
        runs.append(prepare_spring_run(f"x-{i}", d["t_s"], d["d_m"], d["f_n"], d["p_pa"], "front", freq, amp / 1e3))
    fit = fit_spring_chamber(runs)
    assert not fit.ok and fit.note
    assert set(fit.test_notes) == {r.run_id for r in runs}
    assert all("model misses the data" in n for n in fit.test_notes.values())


def test_motion_judged_against_the_displacement_sensor():
    t = np.linspace(0, 3, 3000)
    dither = np.round(np.random.default_rng(0).normal(0, 0.4e-6, t.size) / 1e-6) * 1e-6   # LVDT counts only
    still = prepare_spring_run("s", t, dither, np.ones_like(t), np.full_like(t, 2e5), "rear", 1.0, 0.005,
                               d_sensor=Sensor(1e-6, 0.5e-6))
    assert not still.ok and "no displacement" in still.message


# -- the joint fit from per-run sufficient statistics -------------------------------------------

def _direct_fit(runs):
    """The chamber's weighted nonlinear least squares on the samples themselves (scipy, tight)."""
    import scipy.optimize

    from analyses.pla_spring import FORCE_SIGN, PRESSURE_SIGN

    sf = FORCE_SIGN[runs[0].chamber]

    def residual(x):
        n, ae, eps, delta = x
        out = []
        for r in runs:
            half = 0.5 * r.stroke_m
            pg = r.p0_abs * (half / (half + PRESSURE_SIGN[r.chamber] * r.d)) ** n - r.p_atm
            model = pg * ae + sf * (np.sign(r.v) * eps * pg + delta * r.v / (2 * np.pi * r.frequency_hz))
            out.append((model - r.f) / (np.ptp(r.f) * np.sqrt(len(r.d))))
        return np.concatenate(out)

    x0 = [1.2, 1.5e-3, 2e-5, 3e3]
    return scipy.optimize.least_squares(residual, x0, x_scale=x0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x


def test_the_fit_from_sums_is_the_least_squares_fit_of_the_samples():
    runs, _ = _prepared("front", SMALL_GRID + [(3.0, 5.0, 2.0)])
    fit = fit_spring_chamber(runs)
    np.testing.assert_allclose(fit.params, _direct_fit(runs), rtol=1e-8)
    for r in runs:   # each test's NRMSE and model loop energy, from its sums, as from its samples
        assert fit.nrmse_pct[r.run_id] == pytest.approx(spring_nrmse(r, fit), rel=1e-8)
        direct = loop_energy(r.d, spring_model_force(r, fit), r.chamber)[0]
        assert fit.model_loop_energy_j[r.run_id] == pytest.approx(direct, rel=1e-10)


def test_runs_combine_in_run_id_order_bit_for_bit_and_survive_a_pickle():
    import pickle

    runs, _ = _prepared("rear", SMALL_GRID)
    stats = [spring_run_stats(r) for r in runs]
    a = fit_spring_stats(stats)
    b = fit_spring_stats([pickle.loads(pickle.dumps(s)) for s in reversed(stats)])   # as read from the memo
    assert a.params == b.params and a.nrmse_pct == b.nrmse_pct and a.se == b.se
    assert fit_spring_chamber(runs).params == a.params
    assert all(not k.startswith("_") and isinstance(v, np.ndarray) and v.size < 64
               for s in stats for part in (s.fit, s.all, s.cycle) for k, v in part.items())   # sums, not samples
    # pickled as one array: the same polynomials, bit for bit, and the same scalars
    for s in stats:
        back = pickle.loads(pickle.dumps(s))
        for part in ("fit", "all", "cycle"):
            mine, read = getattr(s, part), getattr(back, part)
            assert list(mine) == list(read)
            assert all(np.array_equal(mine[k].view(np.int64), read[k].view(np.int64)) for k in mine)
        assert {k: v for k, v in vars(back).items() if k not in ("fit", "all", "cycle")} == \
               {k: v for k, v in vars(s).items() if k not in ("fit", "all", "cycle")}


def test_a_run_at_the_stroke_end_is_outside_the_model():
    t = np.linspace(0, 3, 3000)
    d = 0.0199 * np.sin(2 * np.pi * t)            # 19.9 mm of a 20 mm half stroke
    pg = spring_pressure(d, 3e5, 1.1, "rear") - PA
    run = prepare_spring_run("end", t, d, pg * 1.5e-3, pg, "rear", 1.0, 0.0199)
    assert run.ok
    stats = spring_run_stats(run)
    assert not stats.ok and "stroke's end" in stats.message
    fit = fit_spring_stats([stats])
    assert not fit.ok and fit.note == "no usable run"


def test_a_spring_run_is_analysed_and_fitted_without_importing_scipy():
    import subprocess
    import sys

    code = ("import sys, numpy as np\n"
            "from analyses.pla_spring import prepare_spring_run, spring_pressure, spring_run_stats, fit_spring_stats\n"
            "t = np.linspace(0, 3, 3000); d = 0.005 * np.sin(2 * np.pi * t)\n"
            "pg = spring_pressure(d, 3e5, 1.2, 'rear') - 101325.0\n"
            "run = prepare_spring_run('r', t, d, pg * 1.5e-3, pg, 'rear', 1.0, 0.005)\n"
            "fit = fit_spring_stats([spring_run_stats(run)])\n"
            "print(run.ok, [m for m in sys.modules if m.startswith('scipy')])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "[]"]
