"""A chamber's spring parameters fitted over its runs from their sufficient statistics: Table 1
recovered over the paper's grid, the quality gates (bounds, standard errors, a model that misses),
the fit from sums equal to the least-squares fit of the samples, and its bits in run_id order."""
import itertools

import numpy as np
import pytest

from analyses.pla_spring import loop_energy, prepare_spring_run, spring_pressure
from analyses.pla_spring_fit import fit_spring_chamber, fit_spring_stats, spring_model_force, spring_nrmse, spring_run_stats
from pipeline.simulator import simulate_spring
from tests.analyses.test_pla_spring import PA, _prepared


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


def test_wrong_parameters_give_a_large_nrmse():
    runs, truth = _prepared("front", [(3.0, 5.0, 1.0), (5.0, 7.0, 1.0)])
    fit = fit_spring_chamber(runs)
    from analyses.pla_spring_fit import SpringFit, spring_nrmse
    bad = SpringFit("front", fit.n_polytropic, fit.ae_m2, -fit.epsilon_m2, -fit.delta_n_m)  # loop the wrong way
    assert spring_nrmse(runs[0], bad) > 2 * spring_nrmse(runs[0], fit)


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
    # pickled as one block of bytes and a layout string: the same polynomials, bit for bit, and the same scalars
    for s in stats:
        layout, blob = s.__getstate__()["_packed"]
        assert isinstance(layout, str) and isinstance(blob, bytes)
        assert len(blob) == 8 * sum(len(c) for part in (s.fit, s.all, s.cycle) for c in part.values())
        back = pickle.loads(pickle.dumps(s))
        for part in ("fit", "all", "cycle"):
            mine, read = getattr(s, part), getattr(back, part)
            assert list(mine) == list(read)
            assert all(np.array_equal(mine[k].view(np.int64), read[k].view(np.int64)) for k in mine)
        assert {k: v for k, v in vars(back).items() if k not in ("fit", "all", "cycle")} == \
               {k: v for k, v in vars(s).items() if k not in ("fit", "all", "cycle")}
        # unpacked when a section is first read: pickled again before that, the same polynomials
        again = pickle.loads(pickle.dumps(pickle.loads(pickle.dumps(s))))
        assert "_packed" in vars(again) and again.p0_abs == s.p0_abs and again.ok == s.ok
        assert all(np.array_equal(getattr(again, part)[k].view(np.int64), getattr(s, part)[k].view(np.int64))
                   for part in ("fit", "all", "cycle") for k in getattr(s, part))
        assert "_packed" not in vars(again)


def _bits(x) -> bytes:
    return np.asarray(x, float).tobytes()


def test_every_test_at_once_gives_the_bits_of_one_test_at_a_time():
    """The chamber's sums (added in run_id order) and each test's polynomials at n evaluated for all
    tests at once: numpy's polyval and an in-order sum, run by run, bit for bit (issue 26)."""
    from analyses.pla_spring import FORCE_SIGN
    from analyses.pla_spring_fit import _FIT_SUMS, N_CENTRE, _Sums, _values_each, model_loop_energy

    runs, _ = _prepared("front", SMALL_GRID + [(3.0, 5.0, 2.0), (2.0, 7.0, 0.5)])
    stats = sorted((spring_run_stats(r) for r in runs), key=lambda s: s.run_id)
    assert len({len(s.all["pp1"]) for s in stats}) > 1          # polynomials of several lengths: padded
    joined = _Sums([s.fit for s in stats])
    for name in stats[0].fit:                                    # the loop the sums were made by
        acc = np.array(stats[0].fit[name], float)
        for s in stats[1:]:
            c = s.fit[name]
            if len(c) > len(acc):
                acc = np.concatenate([acc, np.zeros(len(c) - len(acc))])
            acc[:len(c)] += c
        assert _bits(joined.poly[name]) == _bits(acc)
    fit = fit_spring_stats(stats)
    assert fit.ok
    for n in (fit.n_polytropic, 0.5, 2.5, 1.0 + 1e-9):
        each = _values_each([s.all for s in stats], _FIT_SUMS, n)
        for i, s in enumerate(stats):
            for name in _FIT_SUMS:
                one = np.polynomial.polynomial.polyval(n - N_CENTRE, np.array(s.all[name], float))
                assert _bits(each[name][i]) == _bits(one)
    th = np.array(fit.params[1:])
    for s in stats:   # each test's NRMSE and model loop energy as the per-test sums give them
        rms = float(np.sqrt(_Sums([s.all]).sum_sq(fit.n_polytropic, th, FORCE_SIGN[s.chamber]) / s.n_all))
        assert fit.nrmse_pct[s.run_id] == 100.0 * rms / s.f_span_n
        assert _bits(fit.model_loop_energy_j[s.run_id]) == _bits(model_loop_energy(s, fit))


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
            "from analyses.pla_spring import prepare_spring_run, spring_pressure\n"
            "from analyses.pla_spring_fit import spring_run_stats, fit_spring_stats\n"
            "t = np.linspace(0, 3, 3000); d = 0.005 * np.sin(2 * np.pi * t)\n"
            "pg = spring_pressure(d, 3e5, 1.2, 'rear') - 101325.0\n"
            "run = prepare_spring_run('r', t, d, pg * 1.5e-3, pg, 'rear', 1.0, 0.005)\n"
            "fit = fit_spring_stats([spring_run_stats(run)])\n"
            "print(run.ok, [m for m in sys.modules if m.startswith('scipy')])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["True", "[]"]
