"""Leakage plateaus, seal envelope and Figs. 9/10: hand-checked cases and recovery from simulated runs."""
import numpy as np
import pandas as pd
import pytest

from analyses.leakage import (characterisation_rows, find_pressure_plateaus, is_hose_check, leakage_map_plot_rows,
                              leakage_plateaus, leakage_power_law, plot_leakage_map, seal_envelope,
                              seal_envelope_rows)
from schemas.units import L_MIN_M3_S, RHO_ANR_KG_M3

KG_S_PER_L_MIN = L_MIN_M3_S * RHO_ANR_KG_M3


def _staircase():
    """10 Hz, 0 bar for 2 s, a 0.3 s ramp, 1 bar to 6 s; the leak overshoots for 0.5 s after the ramp."""
    t = np.round(np.arange(60) * 0.1, 10)
    p = np.where(t < 2.0, 0.0, np.where(t < 2.3, (t - 2.0) / 0.3, 1.0)) * 1e5
    q = np.where(t < 2.3, 0.0, np.where(t < 2.8, 3.0, 1.0)) * KG_S_PER_L_MIN
    return t, p, q


def test_hand_checked_plateaus_exclude_ramp_and_unsettled_leak():
    t, p, q = _staircase()
    got = leakage_plateaus(t, p, q, block_s=0.5, settle_s=0.2, min_duration_s=0.5)
    assert len(got) == 2
    first, second = got.iloc[0], got.iloc[1]
    assert first["t_start_s"] == pytest.approx(0.2) and first["t_end_s"] == pytest.approx(1.9)
    assert first["pressure_bar"] == 0.0 and first["leak_l_min"] == pytest.approx(0.0)
    # the ramp block (2.0-2.4) is not flat; 2.5 + 0.2 settle = 2.7, then the 3 l/min block is dropped
    assert second["t_start_s"] >= 2.8
    assert second["t_end_s"] == pytest.approx(5.9)
    assert second["pressure_bar"] == pytest.approx(1.0)
    assert second["leak_l_min"] == pytest.approx(1.0)


def test_short_plateau_and_empty_input_give_nothing():
    t = np.arange(5) * 0.1
    assert find_pressure_plateaus(t, np.zeros(5)) == []
    assert leakage_plateaus([], [], []).empty


def test_power_law_is_zero_below_seal_pressure():
    q = leakage_power_law([0.0, 3.0, 4.0, 7.0], 2.0, 3.0)
    assert q.tolist() == [0.0, 0.0, 2.0, 2.0 * 4.0**1.5]


def _map(rows):
    return pd.DataFrame(rows, columns=["run_id", "hose_id", "chamber", "adjustment", "z_rollers_mm",
                                       "spring_force_n", "pressure_bar", "leak_l_min"])


def test_seal_envelope_hand_checked():
    rows = []
    for p, q in zip(range(5), [0.0, 0.0, 0.01, 0.2, 1.0]):       # sealed to 2, leaks from 3
        rows.append(("r1", None, "A", "force", None, 429.0, p + 0.004, q))
    for p in range(7):                                          # never leaks
        rows.append(("r2", None, "A", "force", None, 858.0, p - 0.003, 0.0))
    for p, q in zip(range(3), [0.3, 0.4, 0.5]):                 # leaks from the start
        rows.append(("r3", None, "B", "distance", 6.0, None, float(p), q))
    for p, q in zip(range(3), [0.0, 0.1, 0.0]):                 # "stays below": first leak ends it
        rows.append(("r4", None, "B", "distance", 3.0, None, float(p), q))
    env = seal_envelope(_map(rows)).set_index(["chamber", "adjustment", "z_rollers_mm", "spring_force_n"])
    r1 = env.loc[("A", "force", np.nan, 429.0)]
    assert (r1["sealed_up_to_bar"], r1["first_leak_bar"], r1["sealed_at_max"]) == (2.0, 3.0, False)
    assert r1["spring_force_pct"] == pytest.approx(33.0)
    r2 = env.loc[("A", "force", np.nan, 858.0)]
    assert (r2["sealed_up_to_bar"], r2["sealed_at_max"], r2["max_tested_bar"]) == (6.0, True, 6.0)
    assert pd.isna(r2["first_leak_bar"])
    r3 = env.loc[("B", "distance", 6.0, np.nan)]
    assert pd.isna(r3["sealed_up_to_bar"]) and r3["first_leak_bar"] == 0.0
    assert env.loc[("B", "distance", 3.0, np.nan)]["sealed_up_to_bar"] == 0.0
    # the threshold is configurable
    loose = seal_envelope(_map(rows), threshold_l_min=0.5)
    assert loose.loc[loose["spring_force_n"] == 429.0, "sealed_up_to_bar"].item() == 3.0


def test_repeat_runs_of_a_setting_are_averaged_per_tested_pressure():
    rows = [("a", None, "A", "force", None, 429.0, 5.0, 0.04), ("b", None, "A", "force", None, 429.0, 5.02, 0.08)]
    env = seal_envelope(_map(rows))
    assert env["first_leak_bar"].item() == 5.0 and env["max_leak_l_min"].item() == pytest.approx(0.06)


@pytest.mark.parametrize("chamber, adjustment, z, force, seed", [
    ("A", "distance", 3.0, None, 1), ("B", "distance", 4.5, None, 2), ("A", "distance", 6.0, None, 3),
    ("B", "force", None, 429.0, 4), ("A", "force", None, 858.0, 5)])
def test_recovers_simulated_leak_per_plateau(chamber, adjustment, z, force, seed):
    from pipeline.simulator.plpa import simulate_leakage

    run = simulate_leakage(chamber, adjustment, z, force, rng=seed)
    d = run.data
    got = leakage_plateaus(d["t_s"], d["p_supply_pa"], d["q_leak_kg_s"])
    truth = pd.DataFrame(run.truth["plateaus"])
    assert len(got) == len(truth) == 7
    err = np.abs(got["leak_l_min"].to_numpy() - truth["leak_l_min"].to_numpy())
    assert np.all((err <= 0.05) | (err <= 0.05 * truth["leak_l_min"].to_numpy()))
    assert np.allclose(got["pressure_bar"], truth["pressure_bar"], atol=0.02)
    # steady part only: each plateau lies inside its set-point window, after the valve transient
    assert np.all(got["t_start_s"].to_numpy() >= truth["t_start_s"].to_numpy() + 0.2)
    assert np.all(got["t_end_s"].to_numpy() < truth["t_end_s"].to_numpy())


def test_simulated_force_settings_give_the_papers_conclusions():
    from pipeline.simulator.plpa import FORCE_SETTINGS_N, simulate_leakage

    maps = []
    for i, force in enumerate(FORCE_SETTINGS_N):
        run = simulate_leakage("A", "force", None, force, rng=10 + i)
        d = run.data
        m = leakage_plateaus(d["t_s"], d["p_supply_pa"], d["q_leak_kg_s"])
        maps.append(m.assign(run_id=f"r{i}", hose_id=None, chamber="A", adjustment="force", z_rollers_mm=None,
                             spring_force_n=force))
    env = seal_envelope(pd.concat(maps, ignore_index=True)).sort_values("spring_force_n")
    assert env["sealed_up_to_bar"].tolist() == [5.0, 6.0, 6.0]       # >= 33 %: 5 bar; >= 66 %: 6 bar
    assert env["sealed_at_max"].tolist() == [False, True, True]


def _curves(ax):
    """The setting curves of a panel (the threshold line has no marker)."""
    return [ln for ln in ax.get_lines() if ln.get_marker() not in (None, "None", "")]


def test_figure_has_one_panel_per_chamber_and_one_curve_per_setting():
    rows = [("r", None, ch, "distance", z, None, float(p), max(0.0, p - 8 + z)) for ch in "AB"
            for z in (3.0, 4.5, 6.0) for p in range(7)]
    fig = plot_leakage_map(_map(rows), "distance")
    a, b = fig.axes
    assert a.get_title() == "(a) chamber A" and b.get_title() == "(b) chamber B"
    assert "[bar]" in a.get_xlabel() and "[l/min ANR]" in a.get_ylabel()
    curves = _curves(a)
    assert len(curves) == 3 and len({ln.get_marker() for ln in curves}) == 3      # each visible on the zero line
    assert all(ln.get_markerfacecolor() == "none" for ln in curves)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[:3] == ["z = 3.0 mm", "z = 4.5 mm", "z = 6.0 mm"]


def test_legend_lists_settings_of_both_panels():
    rows = [("r", None, "A", "force", None, 858.0, float(p), 0.0) for p in range(7)]
    rows += [("s", None, "B", "force", None, 429.0, float(p), max(0.0, p - 5.0)) for p in range(7)]
    fig = plot_leakage_map(_map(rows), "force")
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["F = 429 N (33 %)", "F = 858 N (66 %)", "threshold 0.05 l/min"]


def _with_worn_check(extra=()):
    """z = 4.0 mm in chamber A: a sealed characterisation run and a worn-hose check leaking from 3 bar."""
    rows = [("char", None, "A", "distance", 4.0, None, float(p), 0.0) for p in range(7)]
    rows += [("durability-2026/check-H104-00", "H104", "A", "distance", 4.0, None, float(p),
              [0.0, 0.0, 0.0, 0.2, 0.5, 1.0, 1.8][p]) for p in range(7)]
    return _map(rows + list(extra))


def test_hose_check_does_not_change_the_setting_envelope():
    both = _with_worn_check()
    char_only = both[both["hose_id"].isna()]
    env = seal_envelope(both)
    assert len(env) == 1 and "hose_id" not in env.columns
    r = env.iloc[0]
    # averaged with the worn hose it would leak from 3 bar (0.1 l/min) and peak at 0.9 l/min
    assert (r["sealed_up_to_bar"], r["sealed_at_max"], r["max_leak_l_min"]) == (6.0, True, 0.0)
    assert (r["runs_used"], r["n_runs"]) == ("characterisation", 1)
    pd.testing.assert_frame_equal(env, seal_envelope(char_only))
    # without the rule the check would count (the per-hose envelope stays available)
    mixed = seal_envelope(both, characterisation_only=False).iloc[0]
    assert (mixed["first_leak_bar"], mixed["max_leak_l_min"], mixed["runs_used"]) == (3.0, 0.9, "mixed")
    per_hose = seal_envelope(both, by=("hose_id", "chamber", "adjustment", "z_rollers_mm"),
                             characterisation_only=False).set_index("hose_id")
    assert per_hose.loc["H104", "sealed_up_to_bar"] == 2.0


def test_the_envelope_of_its_rows_is_the_envelope_and_a_check_of_a_characterised_setting_is_none_of_them():
    only = [("check-H1-00", "H1", "B", "force", None, 429.0, float(p), [0.0, 0.0, 0.3][p]) for p in range(3)]
    both = _with_worn_check(only)   # a characterised setting with a worn check, a setting of checks only
    rows = seal_envelope_rows(both)
    pd.testing.assert_frame_equal(seal_envelope(rows), seal_envelope(both))
    assert set(rows["hose_id"].dropna()) == {"H1"}   # the fallback's checks are read, H104's is not
    worse = both.assign(leak_l_min=np.where(both["hose_id"] == "H104", both["leak_l_min"] * 2, both["leak_l_min"]))
    pd.testing.assert_frame_equal(seal_envelope_rows(worse), rows)
    assert seal_envelope_rows(both.iloc[0:0]).empty and seal_envelope(seal_envelope_rows(both.iloc[0:0])).empty


def test_setting_with_only_hose_checks_falls_back_to_them():
    only = [("check-H1-00", "H1", "B", "force", None, 429.0, float(p), [0.0, 0.0, 0.3][p]) for p in range(3)]
    only += [("check-H2-00", "H2", "B", "force", None, 429.0, float(p), [0.0, 0.1, 0.5][p]) for p in range(3)]
    rows = _with_worn_check(only)
    sel = characterisation_rows(rows)
    assert sorted(sel["run_id"].unique()) == ["char", "check-H1-00", "check-H2-00"]
    env = seal_envelope(rows).set_index("chamber")
    b = env.loc["B"]
    # levels 0, 0.05, 0.4: 0.05 >= threshold, so sealed up to 0 bar, first leak at 1 bar
    assert (b["sealed_up_to_bar"], b["first_leak_bar"], b["runs_used"], b["n_runs"]) == (0.0, 1.0, "hose_checks", 2)
    assert b["max_leak_l_min"] == pytest.approx(0.4)
    assert env.loc["A", "runs_used"] == "characterisation"


def test_empty_hose_id_is_a_characterisation_run():
    rows = _map([("r", "", "A", "force", None, 858.0, 1.0, 0.0), ("c", "H9", "A", "force", None, 858.0, 1.0, 0.4)])
    assert is_hose_check(rows).tolist() == [False, True]
    assert seal_envelope(rows)["max_leak_l_min"].item() == 0.0


def test_figure_curve_ignores_worn_hose_checks():
    fig = plot_leakage_map(_with_worn_check(), "distance")
    a, b = fig.axes
    (line,) = _curves(a)
    assert line.get_ydata().tolist() == [0.0] * 7 and line.get_linestyle() == "-"
    assert [t.get_text() for t in fig.legends[0].get_texts()][0] == "z = 4.0 mm"


def test_figure_marks_a_setting_with_only_hose_checks():
    rows = [("c", "H7", "B", "distance", 5.0, None, float(p), 0.1 * p) for p in range(7)]
    rows += [("r", None, "A", "distance", 5.0, None, float(p), 0.0) for p in range(7)]
    fig = plot_leakage_map(_map(rows), "distance")
    a, b = fig.axes
    (la,), (lb,) = _curves(a), _curves(b)
    assert la.get_linestyle() == "-" and lb.get_linestyle() == "--"
    assert lb.get_ydata() == pytest.approx([0.1 * p for p in range(7)])
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[:2] == ["z = 5.0 mm", "z = 5.0 mm (hose checks)"]


def _png(fig) -> bytes:
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=50, metadata={"Software": None})
    return buf.getvalue()


def test_the_figure_is_drawn_from_its_own_rows_and_a_hose_check_of_a_characterised_setting_is_none_of_them():
    only = [("c", "H7", "B", "distance", 5.0, None, float(p), 0.1 * p) for p in range(7)]  # B: hose checks only
    force = [("f", None, "A", "force", None, 429.0, float(p), 0.0) for p in range(3)]
    full = _with_worn_check(only + force)
    rows = leakage_map_plot_rows(full, "distance")
    assert sorted(rows["hose_id"].fillna("-").unique()) == ["-", "H7"] and "run_id" not in rows.columns
    assert list(rows.index) == list(range(len(rows)))
    assert _png(plot_leakage_map(rows, "distance")) == _png(plot_leakage_map(full, "distance"))
    worn = full.copy()  # the worn check leaks more: not drawn, the same rows (the figure's key unchanged)
    worn.loc[worn["hose_id"] == "H104", "leak_l_min"] += 0.5
    pd.testing.assert_frame_equal(leakage_map_plot_rows(worn, "distance"), rows)
    moved = full.copy()  # the fallback setting's check is drawn: its rows change
    moved.loc[moved["hose_id"] == "H7", "leak_l_min"] += 0.5
    assert not leakage_map_plot_rows(moved, "distance").equals(rows)


# -- sensors and the undecided seal level ------------------------------------------------------------
def test_stated_sensors_give_the_same_plateaus_and_a_standard_error():
    from analyses.quality import Sensor
    from pipeline.simulator.plpa import simulate_leakage

    d = simulate_leakage("A", "distance", 4.0, rng=12).data
    est = leakage_plateaus(d["t_s"], d["p_supply_pa"], d["q_leak_kg_s"])
    stated = leakage_plateaus(d["t_s"], d["p_supply_pa"], d["q_leak_kg_s"], sensor_p=Sensor(1.0, 300.0, "metadata"))
    assert len(est) == len(stated) == 7
    assert np.allclose(est["leak_l_min"], stated["leak_l_min"], atol=0.005)
    # the simulated flow noise is 0.02 l/min (+1 %) per sample; a plateau has hundreds of samples
    assert (stated["leak_se_l_min"] > 0).all() and (stated["leak_se_l_min"] < 0.01).all()


def test_seal_envelope_level_within_two_standard_errors_of_the_threshold_is_undecided():
    rows = [("u", None, "A", "force", None, 429.0, float(p), q, se)
            for p, q, se in zip(range(4), [0.0, 0.01, 0.048, 0.3], [0.001, 0.001, 0.002, 0.01])]
    df = pd.DataFrame(rows, columns=["run_id", "hose_id", "chamber", "adjustment", "z_rollers_mm", "spring_force_n",
                                     "pressure_bar", "leak_l_min", "leak_se_l_min"])
    env = seal_envelope(df).iloc[0]
    # 0.048 +- 0.002 at 2 bar: 0.05 is within 2 standard errors, sealed or leaking cannot be told
    assert pd.isna(env["sealed_up_to_bar"]) and pd.isna(env["first_leak_bar"]) and pd.isna(env["sealed_at_max"])
    assert env["note"] == "the leak at 2.0 bar cannot be told from the threshold (within 2 standard errors)"
    # a precise plateau decides it: sealed up to 2 bar, leaking from 3
    env = seal_envelope(df.assign(leak_se_l_min=0.0005)).iloc[0]
    assert (env["sealed_up_to_bar"], env["first_leak_bar"], env["note"]) == (2.0, 3.0, None)
