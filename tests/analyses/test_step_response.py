"""Closed-loop step metrics: hand-checked shapes, then the simulator's noise-free truth."""
import numpy as np
import pytest
from matplotlib.figure import Figure

from analyses.quality import Sensor
from analyses.step_response import find_steps, plot_step_errors, step_metrics, step_response_metrics
from pipeline.simulator.plpa import simulate_step


def _piecewise(t, knots):
    """Linear interpolation through (time, value) knots."""
    kt, kv = zip(*knots)
    return np.interp(t, kt, kv)


def test_hand_checked_piecewise_linear_step():
    # a 10 mm step at t = 0: ramp to 11 mm at 1 s (10 % overshoot), back to 10 mm at 2 s, flat after
    t = np.arange(0, 6, 0.001)
    x = _piecewise(t, [(0, 0), (1, 0.011), (2, 0.010), (6, 0.010)])
    m = step_metrics(t, x, 0.0, 0.0, 0.010)
    assert m.step_mm == pytest.approx(10.0)
    assert m.overshoot_pct == pytest.approx(10.0, abs=1e-6)
    # 10 % at 1/11 s, 90 % at 9/11 s
    assert m.rise_time_s == pytest.approx(8 / 11, abs=1e-6)
    # leaves the 2 % band (10.2 mm) for the last time at 1 + 0.8 s
    assert m.settling_time_s == pytest.approx(1.8, abs=1e-6)
    assert m.steady_state_error_mm == pytest.approx(0.0, abs=1e-9)
    assert m.settled


def test_downward_step_and_signed_steady_state_error():
    t = np.arange(0, 4, 0.001)
    # from 20 mm to 10 mm, ends 0.1 mm short of the reference (at 10.1 mm): no overshoot
    x = _piecewise(t, [(0, 0.020), (1, 0.0101), (4, 0.0101)])
    m = step_metrics(t, x, 0.0, 0.020, 0.010)
    assert m.step_mm == pytest.approx(-10.0)
    assert m.overshoot_pct == 0.0
    assert m.rise_time_s == pytest.approx(0.8 / 0.99, abs=1e-6)
    assert m.steady_state_error_mm == pytest.approx(0.1, abs=1e-9)   # positive: short of the reference
    assert m.settling_time_s == pytest.approx((10 - 0.2) / 10 / 0.99 * 1.0 - 0.0, rel=1e-3)


def test_never_settling_step_has_nan_settling_time():
    t = np.arange(0, 2, 0.001)
    x = 0.01 * (1 - np.exp(-t / 0.3)) + 0.001 * np.sin(2 * np.pi * 3 * t)   # oscillates +-10 % forever
    m = step_metrics(t, x, 0.0, 0.0, 0.01)
    assert np.isnan(m.settling_time_s) and not m.settled


def test_find_steps_and_no_step():
    t = np.arange(0, 3, 0.01)
    r = np.where(t < 1, 0.2, np.where(t < 2, 0.22, 0.2))
    assert find_steps(t, r) == [(100, 200, 0.2, 0.22), (200, 300, 0.22, 0.2)]
    assert step_response_metrics(t, r, np.full_like(t, 0.2)).empty


@pytest.fixture(scope="module")
def sim_step():
    return simulate_step(0)


def test_metrics_equal_the_simulators_noise_free_truth(sim_step):
    run = sim_step
    d = run.data
    got = step_response_metrics(d["t_s"], d["x_m"], d["x_ref_m"])
    truth = run.truth["steps"]
    assert len(got) == len(truth) == 2
    for g, tr in zip(got.itertuples(), truth):
        assert g.t_step_s == pytest.approx(tr["t_step_s"])
        assert g.step_mm == pytest.approx(tr["step_mm"])
        assert g.overshoot_pct == pytest.approx(tr["overshoot_pct"], abs=1.0)
        assert g.settling_time_s == pytest.approx(tr["settling_time_s"], rel=0.10)
        assert g.rise_time_s == pytest.approx(tr["rise_time_s"], rel=0.10)
        assert g.steady_state_error_mm == pytest.approx(tr["steady_state_error_mm"], abs=0.05)


def test_each_step_reports_the_position_resolution_it_was_measured_with(sim_step):
    """The bench's 5 um encoder, found in the record (no metadata), and a sensor given by metadata."""
    d = sim_step.data
    found = step_response_metrics(d["t_s"], d["x_m"], d["x_ref_m"])
    assert list(found["position_resolution_mm"]) == pytest.approx([0.005, 0.005])
    given = step_response_metrics(d["t_s"], d["x_m"], d["x_ref_m"], x_sensor=Sensor(1e-6, 0.0, "metadata"))
    assert list(given["position_resolution_mm"]) == pytest.approx([0.001, 0.001])


def test_metrics_survive_extra_position_noise(sim_step):
    run = sim_step
    d = run.data
    noisy = d["x_m"] + np.random.default_rng(1).normal(0, 30e-6, len(d))   # 30 um, 6 encoder counts
    got = step_response_metrics(d["t_s"], noisy, d["x_ref_m"])
    for g, tr in zip(got.itertuples(), run.truth["steps"]):
        assert g.overshoot_pct == pytest.approx(tr["overshoot_pct"], abs=1.0)
        assert g.settling_time_s == pytest.approx(tr["settling_time_s"], rel=0.10)
        assert g.rise_time_s == pytest.approx(tr["rise_time_s"], rel=0.10)


def test_figure_is_error_in_percent_of_the_step():
    t = np.linspace(0, 5, 100)
    fig = plot_step_errors([{"t": t, "error_pct": 100 * np.exp(-t), "label": "a"}])
    assert isinstance(fig, Figure)
    # Fig. 15: position (here in % of the step, no step_mm given), the error in the inset
    np.testing.assert_allclose(fig.axes[0].get_lines()[0].get_ydata(), 100 - 100 * np.exp(-t))
    np.testing.assert_allclose(fig.axes[0].child_axes[0].get_lines()[0].get_ydata(), 100 * np.exp(-t))


def test_steps_found_from_the_reference_sensor_not_a_fixed_length():
    # 50 um reference steps (under the old fixed 0.1 mm) on a 1 um reference: found
    t = np.arange(0, 3, 0.001)
    r = np.round(np.where(t < 1, 0.2, np.where(t < 2, 0.20005, 0.2)) / 1e-6) * 1e-6
    steps = find_steps(t, r, sensor=Sensor(1e-6, 0.0))
    assert [(i0, i1) for i0, i1, _, _ in steps] == [(1000, 2000), (2000, 3000)]
    # a noisy read-back reference (10 um sigma): 50 um steps are 5 sigma levels, still found; noise is not
    rng = np.random.default_rng(0)
    noisy = np.where(t < 1, 0.2, 0.2002) + rng.normal(0, 10e-6, t.size)
    assert [s[0] for s in find_steps(t, noisy, sensor=Sensor(0.0, 10e-6))] == [1000]
    assert find_steps(t, 0.2 + rng.normal(0, 10e-6, t.size), sensor=Sensor(0.0, 10e-6)) == []


def test_step_under_the_encoder_floor_gives_no_metrics_and_a_note():
    t = np.arange(0, 4, 0.001)
    r = np.where(t < 1, 0.2, 0.20001)                         # a 10 um step on a 5 um encoder
    x = np.round((0.2 + 1e-5 * (t >= 1) * (1 - np.exp(-(t - 1) / 0.2))) / 5e-6) * 5e-6
    m = step_response_metrics(t, x, r, x_sensor=Sensor(5e-6, 0.0), ref_sensor=Sensor(1e-6, 0.0))
    assert len(m) == 1 and "under 5 x the position sensor floor" in m["note"][0]
    assert m[["overshoot_pct", "settling_time_s", "rise_time_s", "steady_state_error_mm"]].isna().all(axis=None)


def test_band_finer_than_the_encoder_gives_no_settling_time():
    t = np.arange(0, 4, 0.001)
    r = np.where(t < 1, 0.2, 0.2002)                          # 0.2 mm step: 2 % band = 4 um < 5 um encoder
    x = np.round((0.2 + 2e-4 * (t >= 1) * (1 - np.exp(-np.clip(t - 1, 0, None) / 0.2))) / 5e-6) * 5e-6
    m = step_response_metrics(t, x, r, x_sensor=Sensor(5e-6, 0.0), ref_sensor=Sensor(1e-6, 0.0))
    assert len(m) == 1 and "finer than the position sensor floor" in m["note"][0]
    assert np.isnan(m["settling_time_s"][0]) and np.isnan(m["overshoot_pct"][0])
    assert m["rise_time_s"][0] == pytest.approx(0.2 * np.log(9), rel=0.1)


def test_unsettled_step_has_a_note(sim_step):
    d = sim_step.data
    cut = d[d["t_s"] < 2.0]                                   # the record ends 1 s after the 20 mm step
    m = step_response_metrics(cut["t_s"], cut["x_m"], cut["x_ref_m"])
    assert len(m) == 1 and not m["settled"][0] and np.isnan(m["settling_time_s"][0])
    assert "did not settle" in m["note"][0]
    full = step_response_metrics(d["t_s"], d["x_m"], d["x_ref_m"])
    assert full["note"].isna().all()


def test_repeated_identical_steps_are_told_apart_and_go_their_own_ways():
    t = np.linspace(0, 5, 100)
    err = 100 * np.exp(-t)
    steps = [{"t": t, "error_pct": err, "label": f"run{k} {m:+g}", "step_mm": m} for k in range(3) for m in (20, -20)]
    fig = plot_step_errors(steps)
    lines = fig.axes[0].get_lines()[:6]
    # up and down steps end at +20 and -20 mm
    assert sorted(round(ln.get_ydata()[-1]) for ln in lines) == [-20, -20, -20, 20, 20, 20]
    # no two curves share colour, line style and marker
    looks = {(ln.get_color(), ln.get_linestyle(), ln.get_marker()) for ln in lines}
    assert len(looks) == 6
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert labels == [s["label"] for s in steps]


def test_ramped_reference_is_one_step_and_a_staircase_two():
    # a position reference ramped over 100 ms in one-sample plateaus at 1 kHz: one step from the first
    # sample off the level (the ramp starts at the 1.0 s knot, sample 1001 is its first change)
    t = np.arange(0, 3, 0.001)
    r = np.interp(t, [0, 1.0, 1.1, 2.0, 2.0005, 3.0], [0.2, 0.2, 0.21, 0.21, 0.2, 0.2])
    r = np.round(r / 1e-6) * 1e-6
    steps = find_steps(t, r, sensor=Sensor(1e-6, 0.0))
    assert [(i0, round(before, 6), round(after, 6)) for i0, _, before, after in steps] == [(1001, 0.2, 0.21),
                                                                                         (2001, 0.21, 0.2)]
    stairs = np.round(np.where(t < 1, 0.2, np.where(t < 2, 0.205, 0.21)) / 1e-6) * 1e-6
    assert [s[0] for s in find_steps(t, stairs, sensor=Sensor(1e-6, 0.0))] == [1000, 2000]


def test_a_step_run_is_analysed_without_importing_scipy_signal(sim_step, tmp_path):
    """The zero-phase smoothing is scipy's Butterworth filter ported bit for bit (analyses.numerics):
    a rebuild that re-analyses one step run imports no scipy.signal (nor scipy.stats, which it imports)."""
    import subprocess
    import sys

    d = sim_step.data  # simulated here: the simulator itself may import scipy
    np.save(tmp_path / "run.npy", np.stack([np.asarray(d[c], float) for c in ("t_s", "x_m", "x_ref_m")]))
    code = ("import sys, numpy as np\n"
            "from analyses.step_response import step_response_metrics\n"
            f"t, x, r = np.load({str(tmp_path / 'run.npy')!r})\n"
            "m = step_response_metrics(t, x, r)\n"
            "print(len(m), sorted({m.split('.')[1] for m in sys.modules if m.startswith('scipy.')} & {'signal', 'stats', 'optimize'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["2", "[]"]
    assert step_response_metrics(d["t_s"], d["x_m"], d["x_ref_m"]).notna().sum().sum() > 0
