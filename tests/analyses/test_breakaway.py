"""Breakaway: motion onset on hand-built encoder records, force and sign convention, findings, and
recovery of the simulator's breakaway forces."""
import numpy as np
import pandas as pd
import pytest

from analyses.breakaway import (backpressure_ratio, breakaway_findings, breakaway_force, breakaway_summary,
                                detect_motion_onset, drive_force, force_rate_slope, plot_breakaway, ramp_rate)

RES = 5e-6
DT = 1e-3


def _record(counts, x0=0.1):
    counts = np.asarray(counts, dtype=float)
    return np.arange(counts.size) * DT, x0 + counts * RES


def test_onset_walks_back_to_the_first_departure_from_the_baseline():
    # 300 ms at rest, a short creep dither (1 count for 5 ms), then gross motion
    counts = [0] * 300 + [1, 0, 1, 1, 1] + [1] * 5 + [2, 3, 5, 8, 12, 17, 23, 30] + [30 + 8 * i for i in range(60)]
    t, x = _record(counts)
    # gross threshold (> 4 counts) first crossed at index 312; back along the rise and the short
    # creep flat to the last sample at the baseline, index 301
    assert detect_motion_onset(t, x, "P") == 301
    assert detect_motion_onset(t, x, None) == 301


def test_onset_stops_at_a_long_creep_level():
    # creep holds 1 count for 200 ms (> flat_s = 0.1 s): the onset is the end of that flat stretch
    counts = [0] * 300 + [1] * 200 + [2, 4, 7, 11] + [11 + 6 * i for i in range(60)]
    t, x = _record(counts)
    assert detect_motion_onset(t, x, "P") == 499


def test_glitches_and_creep_are_not_motion_and_direction_matters():
    counts = [0] * 300 + [9] + [0] * 300 + [1, 2, 2, 1, 2] * 40    # one-sample spike, 2-count creep
    t, x = _record(counts)
    assert detect_motion_onset(t, x, "P") is None
    # motion toward -x is not a P breakaway, but is an N one
    counts = [0] * 300 + [-i for i in range(200)]
    t, x = _record(counts)
    assert detect_motion_onset(t, x, "P") is None
    assert detect_motion_onset(t, x, "N") == 300


def test_creep_of_two_counts_with_dither_and_pressure_noise_hand_checked():
    """2 N/s from t = 1 s; creep of 1 count at 2 s and 2 counts (10 um) at 3 s with lone dither
    samples (3 counts at 3.95 s, 1 count at 3.5 s and 3.97 s); breakaway at 4 s (F = 6 N), then
    2 counts per ms; 300 Pa noise on each pressure.

    By hand: gross motion (> 4 counts) first at 4.002 s (6 counts); the walk back passes 4.001 s
    (4 counts) to 4.000 s, then along the 2-count level through the lone dither samples; that
    level is held for more than flat_s = 0.1 s, so the onset is 4.000 s, the last sample at the
    creep level. (Stopping at the 3-count dither would put it 50 ms early, 0.1 N low.)
    """
    area = 4.9e-4
    rng = np.random.default_rng(7)
    t = np.round(np.arange(0, 5.0, DT), 9)
    counts = np.where(t >= 3.0, 2, np.where(t >= 2.0, 1, 0)).astype(float)
    for at, c in ((3.5, 1), (3.95, 3), (3.97, 1)):
        counts[int(round(at / DT))] = c
    counts = np.where(t > 4.0, 2 + 2 * np.round((t - 4.0) / DT), counts)
    x = 0.2 + counts * RES
    assert detect_motion_onset(t, x, "P") == 4000
    force = np.clip(t - 1.0, 0, None) * 2.0
    bp = 1e5
    p_a = bp + force / area + rng.normal(0, 300.0, t.size)
    p_b = bp + rng.normal(0, 300.0, t.size)
    res = breakaway_force(t, x, p_a, p_b, area, "P")
    assert res["onset_t_s"] == pytest.approx(4.0, abs=1e-9)
    # line fit over 250 samples of 0.2 N noise: a few hundredths of a newton
    assert res["breakaway_force_n"] == pytest.approx(6.0, abs=0.05)
    assert res["measured_rate_n_s"] == pytest.approx(2.0, rel=0.1)
    # N: the mirror image
    res = breakaway_force(t, 0.2 - counts * RES, p_b, p_a, area, "N")
    assert res["onset_t_s"] == pytest.approx(4.0, abs=1e-9)
    assert res["breakaway_force_n"] == pytest.approx(6.0, abs=0.05)


def test_force_at_onset_and_sign_convention_hand_checked():
    area = 4.9e-4
    t = np.arange(0, 6.0, DT)
    ramp = np.clip(t - 1.0, 0, None) * 2.0                          # 2 N/s from t = 1 s
    bp = 1e5
    onset = 4.0                                                     # F = 6 N at 4 s
    move = np.where(t > onset, np.floor((t - onset) / DT) * 2, 0)   # 2 counts per ms once moving
    # P: A ramps above the backpressure in B, carriage toward +x
    res = breakaway_force(t, 0.2 + move * RES, bp + ramp / area, np.full_like(t, bp), area, "P")
    assert res["breakaway_force_n"] == pytest.approx(6.0, abs=0.01)
    assert res["onset_t_s"] == pytest.approx(onset, abs=2 * DT)
    assert res["measured_rate_n_s"] == pytest.approx(2.0, rel=1e-6)
    assert res["warning"] is None
    # N: B ramps, carriage toward -x; the breakaway force is still a positive magnitude
    res = breakaway_force(t, 0.2 - move * RES, np.full_like(t, bp), bp + ramp / area, area, "N")
    assert res["breakaway_force_n"] == pytest.approx(6.0, abs=0.01)
    assert drive_force([2e5], [1e5], area)[0] == pytest.approx(49.0)


def test_never_moving_run_gives_none_and_a_warning():
    t = np.arange(0, 3.0, DT)
    p = 1e5 + t * 1e4
    res = breakaway_force(t, np.full_like(t, 0.25), p, np.zeros_like(t), 4.9e-4, "P")
    assert res["breakaway_force_n"] is None
    assert "never moved" in res["warning"]
    res = breakaway_force(t[:2], [0.1, 0.1], [0, 0], [0, 0], 4.9e-4, "N")
    assert res["breakaway_force_n"] is None


def _events():
    rows = []
    resid = [0.2, -0.2, 0.1, -0.1]
    for d in "PN":
        for bp, base in ((0.0, 10.0), (1.0, 5.0), (2.0, 5.0)):
            for i, rate in enumerate((0.25, 1.0, 2.0, 4.0)):
                for k in range(2):
                    rows.append({"run_id": f"{d}{bp}{rate}{k}", "direction": d, "backpressure_bar": bp,
                                 "force_rate_n_s": rate,
                                 "breakaway_force_n": base + 0.1 * rate + resid[i] * (1 if k else -1)})
    rows.append({"run_id": "never", "direction": "P", "backpressure_bar": 0.0, "force_rate_n_s": 1.0,
                 "breakaway_force_n": None})
    return pd.DataFrame(rows)


def test_summary_hand_checked():
    s = breakaway_summary(_events())
    assert len(s) == 24 and s["n"].eq(2).all()          # the never-moving event is not counted
    row = s[(s["direction"] == "P") & (s["backpressure_bar"] == 1.0) & (s["force_rate_n_s"] == 0.25)].iloc[0]
    vals = _events().query("direction == 'P' and backpressure_bar == 1.0 and force_rate_n_s == 0.25")
    assert sorted(vals["breakaway_force_n"]) == pytest.approx([4.825, 5.225])   # 5 + 0.025 -/+ 0.2
    assert row["mean_force_n"] == pytest.approx(5.025)
    assert row["std_force_n"] == pytest.approx(0.4 / np.sqrt(2))


def test_findings_ratio_and_slope():
    ev = _events()
    r = backpressure_ratio(ev)
    m0 = ev.loc[ev.backpressure_bar == 0, "breakaway_force_n"].mean()
    m1 = ev.loc[ev.backpressure_bar >= 1, "breakaway_force_n"].mean()
    assert r["estimate"] == pytest.approx(m0 / m1)
    assert r["ci_low"] < m0 / m1 < r["ci_high"] and r["ci_high"] - r["ci_low"] < 0.2
    s = force_rate_slope(ev)
    # built with a common slope of 0.1 N per N/s and residuals that cancel at every rate
    assert s["estimate"] == pytest.approx(0.1, abs=1e-9)
    assert s["ci_low"] < 0.1 < s["ci_high"] and s["p_value"] < 0.05
    f = breakaway_findings(ev)
    assert set(zip(f["finding"], f["direction"])) == {(a, b) for a in ("backpressure_ratio", "force_rate_slope")
                                                       for b in ("P", "N", "all")}
    assert f.loc[(f.finding == "force_rate_slope") & (f.direction == "all"), "significant"].item() is True


def test_findings_without_data_are_null_not_errors():
    f = breakaway_findings(pd.DataFrame(columns=["direction", "backpressure_bar", "force_rate_n_s",
                                                 "breakaway_force_n"]))
    assert f["estimate"].isna().all()
    assert f["note"].eq("no breakaway forces").sum() == 3          # the slope rows
    assert f.loc[f.finding == "backpressure_ratio", "note"].str.startswith("too few breakaway forces").all()


def test_findings_say_why_a_design_gives_no_estimate():
    ev = _events()
    one_rate = ev[ev.force_rate_n_s == ev.force_rate_n_s.iloc[0]]
    assert force_rate_slope(one_rate)["estimate"] is None
    assert force_rate_slope(one_rate)["note"] == "one force rate only: no slope"
    only_high = ev[ev.backpressure_bar >= 1]
    r = backpressure_ratio(only_high)
    assert r["estimate"] is None and r["note"].startswith("too few breakaway forces for a ratio: 0 at 0 bar")
    f = breakaway_findings(ev)
    assert f["note"].isna().all() and f["estimate"].notna().all()


def test_recovers_simulated_breakaway_forces_and_findings():
    from pipeline.simulator.plpa import simulate_breakaway

    rows, errors = [], []
    seed = 100
    for d in "PN":
        for bp in (0.0, 1.0, 3.0):
            for rate in (0.25, 1.0, 4.0):
                for _ in range(2):
                    seed += 1
                    run = simulate_breakaway(d, bp, rate, rng=seed)
                    x = run.data
                    res = breakaway_force(x["t_s"], x["x_m"], x["p_a_pa"], x["p_b_pa"], 4.9e-4, d)
                    errors.append(res["breakaway_force_n"] - run.truth["breakaway_force_n"])
                    rows.append({"direction": d, "backpressure_bar": bp, "force_rate_n_s": rate,
                                 "breakaway_force_n": res["breakaway_force_n"]})
    assert np.max(np.abs(errors)) < 0.5
    ev = pd.DataFrame(rows)
    r = backpressure_ratio(ev)
    assert r["ci_low"] < 2.0 < r["ci_high"]                      # 10 N / 5 N
    s = force_rate_slope(ev)
    assert s["ci_low"] < 0.0 < s["ci_high"]                      # no rate effect
    fig = plot_breakaway(ev)
    assert [a.get_title()[:11] for a in fig.axes] == ["direction P", "direction N"]
    assert "[N]" in fig.axes[0].get_ylabel() and "[bar]" in fig.axes[0].get_xlabel()
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["0.25 N/s", "1 N/s", "4 N/s"]


# -- other position sensors; the force rate over the whole ramp ---------------------------------------
def test_ramp_rate_hand_checked():
    # flat at 1 N to t = 2 s, then 0.25 N/s: the hinge puts the start at 2 s and the rate exactly
    t = np.arange(0, 10, 0.01)
    f = 1.0 + 0.25 * np.clip(t - 2.0, 0, None)
    r = ramp_rate(t, f, 9.0)
    assert r["note"] is None
    assert r["rate_n_s"] == pytest.approx(0.25, rel=1e-6) and r["ramp_start_s"] == pytest.approx(2.0, abs=0.011)
    # no ramp: the rate is not distinguishable from zero
    flat = ramp_rate(t, 1.0 + np.random.default_rng(0).normal(0, 0.1, t.size), 9.0)
    assert flat["rate_n_s"] is None and flat["note"]


@pytest.mark.parametrize("rate", [0.25, 1.0, 4.0])
def test_measured_rate_recovers_the_simulated_ramp(rate):
    from pipeline.simulator.plpa import simulate_breakaway

    run = simulate_breakaway("P", 1.0, rate, rng=40)
    x = run.data
    res = breakaway_force(x["t_s"], x["x_m"], x["p_a_pa"], x["p_b_pa"], 4.9e-4, "P")
    assert res["measured_rate_n_s"] == pytest.approx(rate, rel=0.01)
    assert 0 < res["measured_rate_se_n_s"] < 0.01 * rate
    assert abs(res["measured_rate_n_s"] - rate) < 4 * res["measured_rate_se_n_s"] + 1e-3 * rate


@pytest.mark.parametrize("kw", [dict(fs_hz=100.0, position_resolution_m=0.0, position_noise_m=20e-6),
                                dict(fs_hz=100.0, position_resolution_m=0.0, position_noise_m=50e-6),
                                dict(position_resolution_m=1e-6), dict(position_resolution_m=50e-6)])
def test_breakaway_with_other_position_sensors(kw):
    """Analog 20/50 um at 100 Hz (onset within the noise), a 1 um encoder that resolves the 4 um
    pre-sliding creep (not taken for the breakaway), a coarse 50 um encoder."""
    from pipeline.simulator.plpa import simulate_breakaway

    errs = []
    for seed, (d, bp, rate) in enumerate([("P", 0.0, 1.0), ("N", 1.0, 4.0), ("P", 3.0, 0.25)]):
        run = simulate_breakaway(d, bp, rate, rng=60 + seed, **kw)
        x = run.data
        res = breakaway_force(x["t_s"], x["x_m"], x["p_a_pa"], x["p_b_pa"], 4.9e-4, d)
        assert res["note"] is None
        errs.append(res["breakaway_force_n"] - run.truth["breakaway_force_n"])
    assert np.max(np.abs(errs)) < 0.3


def test_no_motion_the_sensor_can_tell_gives_a_note():
    from analyses.quality import Sensor

    t = np.arange(0, 3.0, DT)
    x = 0.25 + np.where(t > 2.0, 30e-6, 0.0)            # 30 um: motion for an encoder ...
    p = 1e5 + t * 1e4
    assert breakaway_force(t, x, p, np.zeros_like(t), 4.9e-4, "P", Sensor(5e-6, 0.0))["breakaway_force_n"]
    res = breakaway_force(t, x, p, np.zeros_like(t), 4.9e-4, "P", Sensor(0.0, 20e-6, "metadata"))
    assert res["breakaway_force_n"] is None                # ... not for a sensor with 20 um of noise
    assert "no motion the position sensor can tell" in res["note"] and "noise 2e-05" in res["note"]


def test_ramp_rate_and_findings_import_neither_scipy_optimize_nor_stats():
    """The bounded minimiser, the t quantiles and Welch's test are scipy's, ported bit for bit
    (analyses.numerics): a rebuild that re-analyses one breakaway run pays for neither import."""
    import subprocess
    import sys

    code = ("import sys, numpy as np, pandas as pd\n"
            "from analyses.breakaway import breakaway_findings, ramp_rate\n"
            "t = np.arange(0, 10, 0.01)\n"
            "r = ramp_rate(t, 1.0 + 0.25 * np.clip(t - 2.0, 0, None), 9.0)\n"
            "rng = np.random.default_rng(1)\n"
            "ev = pd.DataFrame({'direction': ['P', 'N'] * 20, 'backpressure_bar': [0.0] * 20 + [2.0] * 20,\n"
            "                   'force_rate_n_s': np.tile([1.0, 1.0, 4.0, 4.0], 10),\n"
            "                   'breakaway_force_n': 10 + rng.normal(0, 0.5, 40) + np.repeat([0.0, 3.0], 20)})\n"
            "f = breakaway_findings(ev)\n"
            "print(round(r['rate_n_s'], 6), len(f) > 0,\n"
            "      sorted({m.split('.')[1] for m in sys.modules if m.startswith('scipy.')} & {'optimize', 'stats', 'signal'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["0.25", "True", "[]"]
