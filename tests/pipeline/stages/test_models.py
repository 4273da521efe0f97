"""Stage models end to end: simulated identification, step, spring and pressure-step runs written as
bench exports (mm, bar, bar(a), kN, mV...), rebuilt into a warehouse whose tables must recover the
simulator's truth; runs that cannot be fitted (no excitation, no step, a still rod, a pressure run
whose set-point never steps) give NULLs and a warning."""
import itertools

import numpy as np
import pandas as pd
import pytest

from pipeline.rebuild.flow import rebuild
from tests.conftest import query
from pipeline.simulator import (simulate_identification, simulate_pressure_step, simulate_spring,
                                simulate_step)
from pipeline.simulator.writers import default_columns, write_csv
from pipeline.stages import models as stage

START = "2025-03-03T08:00:00"
UNITS = {"x": "mm", "x_ref": "mm", "d": "mm", "f": "kN", "u": "V", "u_d": "mV", "p": "bar", "p_ref": "bar"}


def _write(raw, name, run, units=None):
    meta = {**{k: v for k, v in run.metadata.items() if v is not None}, "run_id": f"sim/{name}", "started_at": START}
    write_csv(raw / "sim" / f"{name}.csv", run.data, default_columns(run.data.columns, {**UNITS, **(units or {})}),
              meta, delimiter=";" if len(name) % 2 else ",")


SPRING_TESTS = [(p0, amp, f) for (p0, amp), f in zip(itertools.product((2.0, 3.0, 4.0, 5.0), (3.0, 5.0, 7.0)),
                                                     itertools.cycle((0.5, 1.0, 2.0, 4.0, 1.5)))]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    raw, wh = root / "raw", root / "warehouse"
    truth = {}

    def add(name, run, units=None):
        _write(raw, name, run, units)
        truth[f"sim/{name}"] = run.truth

    add("ident", simulate_identification(11, duration_s=20.0))
    flat = simulate_identification(12, duration_s=5.0)
    flat.data["u_d_v"] = 0.0
    flat.data["x_m"] = flat.data["x_ref_m"]
    add("ident_flat", flat)                                    # no excitation
    add("step", simulate_step(0))
    nostep = simulate_step(0, steps_mm=(0.0,), hold_s=2.0)
    add("step_none", nostep)                                   # the reference never jumps
    for chamber in ("rear", "front"):
        for i, (p0, amp, f) in enumerate(SPRING_TESTS):
            units = {"p": "bar(a)"} if chamber == "front" else None
            add(f"spring_{chamber}_{i:02d}", simulate_spring(chamber, p0, amp, f, rng=100 + i, cycles=2.0), units)
        add(f"pstep_{chamber}", simulate_pressure_step(chamber, rng=7))
    add("pstep_flat", simulate_pressure_step("rear", rng=8, levels_bar=(3.0,), hold_s=3.0))   # p_ref never moves
    still = simulate_spring("rear", 3.0, 5.0, 1.0, rng=1)
    still.data["d_m"] = 0.0
    add("spring_still", still)                                  # the rod never moves
    summary = rebuild(raw, wh, jobs=2, report=False)
    return wh, truth, summary


def q(warehouse, sql):
    return query(warehouse, sql, frame=True)


def _warnings(wh, run_id):
    return list(q(wh, f"SELECT warnings FROM runs WHERE run_id = '{run_id}'")["warnings"].iloc[0])


def test_nothing_quarantined(built):
    wh, truth, summary = built
    assert [p.error for p in summary.quarantine] == []
    assert len(q(wh, "SELECT * FROM runs")) == len(truth)


def test_identification_recovers_table2_and_flags_the_flat_run(built):
    wh, truth, _ = built
    t = q(wh, "SELECT * FROM identification ORDER BY run_id").set_index("run_id")
    good, tr = t.loc["sim/ident"], truth["sim/ident"]
    assert good["wn_rad_s"] == pytest.approx(tr["wn_rad_s"], rel=0.05)
    assert good["zeta"] == pytest.approx(tr["zeta"], rel=0.05)
    assert good["k_lin_m_v_s"] == pytest.approx(tr["k_lin_m_v_s"], rel=0.05)
    assert good["fit_pct"] >= 90
    assert good["id_sample_rate_hz"] == pytest.approx(50.0)
    assert good["n_samples_id"] == 1000
    flat = t.loc["sim/ident_flat"]
    assert flat[["wn_rad_s", "zeta", "k_lin_m_v_s", "fit_pct"]].isna().all()
    assert "no excitation" in flat["note"] and pd.isna(good["note"])
    assert any("no excitation" in w for w in _warnings(wh, "sim/ident_flat"))


def test_step_response_matches_noise_free_truth(built):
    wh, truth, _ = built
    s = q(wh, "SELECT * FROM step_response WHERE run_id = 'sim/step' ORDER BY t_step_s")
    tr = truth["sim/step"]["steps"]
    assert s["step_mm"].tolist() == pytest.approx([20.0, -20.0])
    for (_, g), t in zip(s.iterrows(), tr):
        assert g["overshoot_pct"] == pytest.approx(t["overshoot_pct"], abs=1.0)
        assert g["settling_time_s"] == pytest.approx(t["settling_time_s"], rel=0.10)
        assert g["rise_time_s"] == pytest.approx(t["rise_time_s"], rel=0.10)
    none = q(wh, "SELECT * FROM step_response WHERE run_id = 'sim/step_none'")
    assert len(none) == 1 and none[["step_mm", "overshoot_pct", "settling_time_s"]].isna().all(axis=None)
    assert any("no step" in w for w in _warnings(wh, "sim/step_none"))
    assert "no step of the reference" in none["note"].iloc[0] and s["note"].isna().all()


def test_spring_fits_recover_table1(built):
    wh, truth, _ = built
    fits = q(wh, "SELECT * FROM spring_fits ORDER BY chamber").set_index("chamber")
    assert list(fits.index) == ["front", "rear"]
    for chamber in ("front", "rear"):
        f, tr = fits.loc[chamber], truth[f"sim/spring_{chamber}_00"]
        assert f["n_tests"] == len(SPRING_TESTS)
        assert f["n_polytropic"] == pytest.approx(tr["n"], rel=0.02)
        assert f["ae_m2"] == pytest.approx(tr["Ae"], rel=0.02)
        assert f["epsilon_m2"] == pytest.approx(tr["eps"], rel=0.10)
        assert f["delta_n_m"] == pytest.approx(tr["delta"], rel=0.10)
        assert f["max_nrmse_pct"] < 2.5
        assert pd.isna(f["note"])


def test_spring_tests_have_p0_from_the_run_and_nrmse_below_the_papers_bound(built):
    wh, truth, _ = built
    t = q(wh, "SELECT * FROM spring_tests ORDER BY run_id").set_index("run_id")
    assert len(t) == 2 * len(SPRING_TESTS) + 1
    fitted = t.drop(index="sim/spring_still")
    for rid, row in fitted.iterrows():
        assert row["p0_bar_abs"] == pytest.approx(truth[rid]["p0_bar_abs"], abs=0.01), rid
        assert row["amplitude_mm"] == pytest.approx(truth[rid]["amplitude_mm"])
        assert row["frequency_hz"] == pytest.approx(truth[rid]["frequency_hz"])
        assert row["chamber"] == truth[rid]["chamber"]
    assert (fitted["nrmse_pct"] < 2.5).all() and (fitted["nrmse_pct"] > 0).all()
    assert pd.isna(t.loc["sim/spring_still", "nrmse_pct"])
    assert fitted["note"].isna().all() and "no displacement" in t.loc["sim/spring_still", "note"]
    assert any("no displacement" in w for w in _warnings(wh, "sim/spring_still"))


def test_spring_loop_energy(built):
    wh, truth, _ = built
    e = q(wh, "SELECT * FROM spring_loop_energy ORDER BY run_id")
    assert len(e) == 2 * len(SPRING_TESTS)
    assert (e["n_cycles"] >= 1).all()
    np.testing.assert_allclose(e["model_loop_energy_j"], e["loop_energy_j"], rtol=0.08)
    # structural part pi delta D^2 is most of the loop at the lowest pressure
    low = e[e["p0_bar_abs"] < 2.5]
    assert ((low["structural_energy_j"] / low["loop_energy_j"]).between(0.6, 1.0)).all()


def test_pressure_dynamics_recover_table2(built):
    wh, truth, _ = built
    pdy = q(wh, "SELECT * FROM pressure_dynamics ORDER BY chamber, direction")
    assert pdy[["chamber", "direction"]].values.tolist() == [["front", "charge"], ["front", "discharge"],
                                                              ["rear", "charge"], ["rear", "discharge"]]
    tr = truth["sim/pstep_rear"]
    for _, r in pdy.iterrows():
        assert r["model"] == "second_order" and pd.isna(r["tau_s"]) and pd.isna(r["note"])
        assert r["wn_rad_s"] == pytest.approx(tr["wn_rad_s"], rel=0.05)
        assert r["zeta"] == pytest.approx(tr[f"xi_{r['direction']}"], rel=0.05)
        assert r["nrmse_pct"] < 1.0
        assert r["n_steps"] == 3
    steps = q(wh, "SELECT * FROM pressure_steps WHERE run_id = 'sim/pstep_front' ORDER BY t_step_s")
    expect = truth["sim/pstep_front"]["steps"]
    assert steps["direction"].tolist() == [s["direction"] for s in expect]
    assert steps["p_to_bar"].tolist() == pytest.approx([s["p_to_pa"] / 1e5 for s in expect])


def test_pressure_step_run_without_a_step_gives_nulls_and_a_warning(built):
    wh, _, summary = built
    # the rebuild went through (stage run, nothing quarantined) and the run is in the warehouse
    assert "models" in summary.stages_run and summary.exit_code == 0
    got = q(wh, "SELECT r.run_id, s.direction, s.t_step_s, s.nrmse_pct FROM runs r "
                "LEFT JOIN pressure_steps s USING (run_id) WHERE r.run_id = 'sim/pstep_flat'")
    assert len(got) == 1 and got[["direction", "t_step_s", "nrmse_pct"]].isna().all(axis=None)
    assert any("no set-point step" in w for w in _warnings(wh, "sim/pstep_flat"))
    # and it does not enter the rear chamber's fit (the good run's 3 steps per direction)
    rear = q(wh, "SELECT n_steps FROM pressure_dynamics WHERE chamber = 'rear'")
    assert rear["n_steps"].tolist() == [3, 3]
    assert not any("no set-point step" in w for w in _warnings(wh, "sim/pstep_rear"))


def test_figures_are_written(built):
    wh, _, _ = built
    figs = q(wh, "SELECT name, path FROM figures WHERE stage = 'models' ORDER BY name")
    assert figs["name"].tolist() == ["identification_sim_ident", "pressure_steps_front", "pressure_steps_rear",
                                     "spring_loop_energy", "spring_loops_front", "spring_loops_rear", "step_errors"]
    for p in figs["path"]:
        assert (wh / p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unreadable_or_incomplete_runs_warn_instead_of_raising(tmp_path):
    missing = str(tmp_path / "missing.parquet")
    for kind in ("identification", "step", "spring"):
        out = stage.analyse_run((kind, "x/1", missing, {"chamber": "rear", "kp_v_m": 5.0}))
        assert out["rows"][0]["run_id"] == "x/1" and "analysis failed" in out["warnings"][0]
    out = stage.analyse_run(("pressure_step", "x/2", missing, {"chamber": "rear"}))
    assert out["rows"] == [] and out["warnings"]
    # a parquet without the needed channels
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = tmp_path / "t.parquet"
    pq.write_table(pa.table({"t_s": np.arange(10.0), "x_m": np.zeros(10)}), path)
    out = stage.analyse_run(("identification", "x/3", str(path), {"kp_v_m": 5.0}))
    assert out["rows"][0]["wn_rad_s"] is None and "lacks u_d_v, x_ref_m" in out["warnings"][0]


def test_an_infinite_sample_is_left_out_like_a_missing_one(tmp_path):
    """A logger's overflow written as ``inf`` (pandas reads it as a number, ``dropna`` keeps it) gave a
    step run overshoot 0, settling 0 and no note, silently (a reviewer's finding). It is left out, as
    a NaN sample is: the metrics are those of the run without it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    d = simulate_step(0).data
    out = {}
    for bad in (None, float("inf"), float("nan"), -float("inf")):
        x = np.array(d["x_m"], float)
        if bad is not None:
            x[50] = bad
        path = tmp_path / f"step-{bad}.parquet"
        pq.write_table(pa.table({"t_s": d["t_s"], "x_m": x, "x_ref_m": d["x_ref_m"]}), path)
        rows = stage.analyse_run(("step", "x/s", str(path), {}))["rows"]
        out[str(bad)] = [(r["overshoot_pct"], r["settling_time_s"], r["steady_state_error_mm"]) for r in rows]
    assert out["inf"] == out["nan"] == out["-inf"]
    flat = [v for row in out["inf"] for v in row]
    assert flat == pytest.approx([v for row in out["None"] for v in row], rel=1e-3) and all(o > 0.5 for o, _, _ in out["inf"])


#: A closed-loop set-point sweep of 5 and 10 kPa steps (the real rigs' pressure steps). [bar gauge]
SWEEP = (1.0, 1.05, 1.15, 1.10, 1.0, 1.10, 1.15, 1.05, 1.0, 1.1, 1.2, 1.15, 1.05)


@pytest.fixture(scope="module")
def sweep_built(tmp_path_factory):
    """First-order pressure loops logged at 20 Hz in kPa: rear states its sensors, front does not;
    a second front run's steps are all under the pressure sensor's floor."""
    root = tmp_path_factory.mktemp("sweep")
    raw, wh = root / "raw", root / "warehouse"
    runs = {"sweep_rear": simulate_pressure_step("rear", rng=21, levels_bar=SWEEP, hold_s=3.0, fs_hz=20.0,
                                                 tau_s={"charge": 0.25, "discharge": 0.4},
                                                 sensor_p_noise=300.0, sensor_p_ref_resolution=10.0),
            "sweep_front": simulate_pressure_step("front", rng=22, levels_bar=SWEEP, hold_s=3.0, fs_hz=20.0,
                                                  tau_s=0.3),
            "sweep_tiny": simulate_pressure_step("front", rng=23, levels_bar=(1.0, 1.005, 1.0), hold_s=3.0,
                                                 fs_hz=20.0, tau_s=0.3)}
    for name, run in runs.items():
        _write(raw, name, run, {"p": "kPa", "p_ref": "kPa"})
    summary = rebuild(raw, wh, jobs=1, report=False)
    return wh, {f"sim/{k}": v.truth for k, v in runs.items()}, summary


def test_first_order_sweep_at_20_hz_recovers_tau_and_every_5_kpa_step(sweep_built):
    wh, truth, summary = sweep_built
    assert [p.error for p in summary.quarantine] == []
    pdy = q(wh, "SELECT * FROM pressure_dynamics ORDER BY chamber, direction")
    fitted = pdy
    assert fitted["model"].tolist() == ["first_order"] * 4
    assert fitted["zeta"].isna().all() and fitted["wn_rad_s"].isna().all() and fitted["note"].isna().all()
    tau = {("rear", "charge"): 0.25, ("rear", "discharge"): 0.4, ("front", "charge"): 0.3, ("front", "discharge"): 0.3}
    for _, r in fitted.iterrows():
        assert r["tau_s"] == pytest.approx(tau[(r["chamber"], r["direction"])], rel=0.05)
        assert r["n_steps"] == 6      # the tiny run's steps are listed, not fitted
    steps = q(wh, "SELECT * FROM pressure_steps WHERE run_id = 'sim/sweep_rear' ORDER BY t_step_s")
    expect = truth["sim/sweep_rear"]["steps"]
    assert ((steps["p_to_bar"] - steps["p_from_bar"]) * 1e5).round().tolist() == [
        round(s["p_to_pa"] - s["p_from_pa"]) for s in expect]          # 5 kPa steps included
    assert steps["note"].isna().all() and steps["nrmse_pct"].notna().all()
    tiny = q(wh, "SELECT * FROM pressure_steps WHERE run_id = 'sim/sweep_tiny'")
    assert len(tiny) == 2 and tiny["nrmse_pct"].isna().all() and tiny["note"].str.contains("sensor floor").all()


# -- grouping per rig, and per part and age (issue 25 item 3) ---------------------------------------
#: A roller pinch valve, new and after 594 h: (wn [rad/s], zeta per direction).
VALVE = {0: (40.0, {"charge": 0.5, "discharge": 0.7}), 594: (31.0, {"charge": 0.65, "discharge": 0.85})}
PEEP_PIP = (0.005, 0.025, 0.005, 0.02, 0.005, 0.03, 0.005)   # bar gauge


@pytest.fixture(scope="module")
def valve_built(tmp_path_factory):
    """One rig `vent` in campaign `vent`: valve V1 new and aged on chamber `patient` (in mbar),
    and a run naming no part on the same chamber; a second campaign's rig `pla-1` (rear) beside."""
    root = tmp_path_factory.mktemp("valve")
    raw, wh = root / "raw", root / "warehouse"
    truth = {}
    for k, (age, (wn, xi)) in enumerate(VALVE.items()):
        run = simulate_pressure_step("patient", rng=60 + k, levels_bar=PEEP_PIP, hold_s=1.0, wn=wn, xi=xi,
                                     noise_pa=5.0, valve_id="V1", age_h=age)
        run.metadata["rig"] = "vent"
        meta = {**run.metadata, "run_id": f"vent/v1-{age}h", "started_at": START}
        write_csv(raw / "vent" / f"v1-{age}h.csv", run.data,
                  default_columns(run.data.columns, {"p": "mbar", "p_ref": "mbar"}), meta)
        truth[age] = run.truth
    plain = simulate_pressure_step("patient", rng=62, levels_bar=PEEP_PIP, hold_s=1.0, wn=40.0,
                                   xi=VALVE[0][1], noise_pa=5.0)
    plain.metadata["rig"] = "vent"
    write_csv(raw / "vent" / "plain.csv", plain.data,
              default_columns(plain.data.columns, {"p": "mbar", "p_ref": "mbar"}),
              {**plain.metadata, "run_id": "vent/plain", "started_at": START})
    _write(raw, "pstep_rear", simulate_pressure_step("rear", rng=7))
    summary = rebuild(raw, wh, jobs=1, report=False)
    return wh, truth, summary


def test_pressure_dynamics_per_part_and_age_beside_a_pooled_row_per_rig(valve_built):
    wh, truth, summary = valve_built
    assert [p.error for p in summary.quarantine] == []
    pdy = q(wh, "SELECT * FROM pressure_dynamics ORDER BY campaign, rig, chamber, direction, level DESC, "
                "part_age_h NULLS FIRST")
    key = pdy[["campaign", "rig", "chamber", "direction", "level", "part_id", "part_age_h", "n_runs"]]
    assert key.astype(object).where(key.notna(), None).values.tolist() == [
        ["sim", "pla-1", "rear", "charge", "rig", None, None, 1],
        ["sim", "pla-1", "rear", "discharge", "rig", None, None, 1],
        ["vent", "vent", "patient", "charge", "rig", None, None, 3],
        ["vent", "vent", "patient", "charge", "part", "V1", 0.0, 1],
        ["vent", "vent", "patient", "charge", "part", "V1", 594.0, 1],
        ["vent", "vent", "patient", "discharge", "rig", None, None, 3],
        ["vent", "vent", "patient", "discharge", "part", "V1", 0.0, 1],
        ["vent", "vent", "patient", "discharge", "part", "V1", 594.0, 1]]
    part = pdy[pdy["level"] == "part"]
    for _, r in part.iterrows():
        wn, xi = VALVE[int(r["part_age_h"])]
        assert r["model"] == "second_order" and pd.isna(r["note"]) and r["part_kind"] == "valve"
        assert r["wn_rad_s"] == pytest.approx(wn, rel=0.05) and r["zeta"] == pytest.approx(xi[r["direction"]], rel=0.05)
        if r["part_age_h"] == 594:
            assert r["wn_change_pct"] == pytest.approx(100 * (31 / 40 - 1), abs=5)
            assert r["zeta_change_pct"] == pytest.approx(100 * (VALVE[594][1][r["direction"]]
                                                                / VALVE[0][1][r["direction"]] - 1), abs=5)
        else:
            assert pd.isna(r["wn_change_pct"]) and pd.isna(r["zeta_change_pct"])
    # the query every existing user runs still finds the rig's pooled row first, labelled
    got = q(wh, "SELECT level, rig, n_steps FROM pressure_dynamics WHERE chamber = 'patient' AND direction = 'charge'")
    assert sorted(got["level"]) == ["part", "part", "rig"] and (got["rig"] == "vent").all()
    assert got.loc[got["level"] == "rig", "n_steps"].item() == 9
    # steps carry the NRMSE of their finest group: the valve's age, or the rig's for the plain run
    steps = q(wh, "SELECT run_id, count(*) AS n, count(nrmse_pct) AS fitted FROM pressure_steps "
                  "WHERE run_id LIKE 'vent/%' GROUP BY run_id ORDER BY run_id")
    assert steps.values.tolist() == [["vent/plain", 6, 6], ["vent/v1-0h", 6, 6], ["vent/v1-594h", 6, 6]]


def test_pressure_figures_per_rig_and_the_ageing_figure(valve_built):
    wh, _, _ = valve_built
    figs = q(wh, "SELECT name, caption FROM figures WHERE stage = 'models' ORDER BY name")
    assert figs["name"].tolist() == ["pressure_ageing", "pressure_steps_patient", "pressure_steps_patient_V1_0h",
                                     "pressure_steps_patient_V1_594h", "pressure_steps_rear"]
    assert "age" in figs["caption"].iloc[0]


def test_hostile_chamber_and_part_names_are_stored_as_written_and_never_name_a_path(tmp_path):
    """A chamber and valve named like paths and markup: stored as written, figure names slugged,
    every figure inside the stage's folder."""
    raw, wh = tmp_path / "raw", tmp_path / "warehouse"
    chamber, valve = "../../evil <b>x</b>", "../V/1"
    run = simulate_pressure_step(chamber, rng=70, levels_bar=PEEP_PIP, hold_s=1.0, wn=40.0, xi=VALVE[0][1],
                                 noise_pa=5.0, valve_id=valve, age_h=3)
    write_csv(raw / "h" / "a.csv", run.data, default_columns(run.data.columns, {"p": "mbar", "p_ref": "mbar"}),
              {**run.metadata, "run_id": "h/a", "started_at": START})
    summary = rebuild(raw, wh, jobs=1, report=False)
    assert [p.error for p in summary.quarantine] == []
    pdy = q(wh, "SELECT DISTINCT chamber, part_id FROM pressure_dynamics WHERE level = 'part'")
    assert pdy.values.tolist() == [[chamber, valve]]
    figs = q(wh, "SELECT name, path FROM figures WHERE stage = 'models' ORDER BY name")
    assert figs["name"].tolist() == ["pressure_ageing", "pressure_steps_evil_b_x_b", "pressure_steps_evil_b_x_b_V_1_3h"]
    for p in figs["path"]:
        f = (wh / p).resolve()
        assert f.is_relative_to((wh / "stages" / "models").resolve()) and f.read_bytes()[:4] == b"\x89PNG"


def test_one_changed_spring_run_refits_from_the_memo_and_equals_a_full_rebuild(tmp_path, monkeypatch):
    import pipeline.rebuild.flow as rb
    from tests.pipeline.rebuild.test_state import age, dump

    seen = []
    real = rb.run_stages_cached
    monkeypatch.setattr(rb, "run_stages_cached", lambda *a, **k: seen.append(real(*a, **k)) or seen[-1])
    raw, inc, full = tmp_path / "raw", tmp_path / "inc", tmp_path / "full"
    for chamber in ("rear", "front"):
        for i, (p0, amp, f) in enumerate(SPRING_TESTS[:4]):
            _write(raw, f"spring_{chamber}_{i}", simulate_spring(chamber, p0, amp, f, rng=i, cycles=2.0))
    _write(raw, "pstep", simulate_pressure_step("rear", rng=7))
    age(raw)
    rebuild(raw, inc, jobs=2, report=False)
    before = q(inc, "SELECT * FROM spring_fits ORDER BY chamber")
    _write(raw, "spring_front_3", simulate_spring("front", 4.4, 5.0, 1.0, rng=99, cycles=2.0))
    age(raw)
    rebuild(raw, inc, jobs=2, report=False)
    memo = seen[-1].memos["models"]
    # computed: the changed run's analysis, the front chamber's joint fit (from the runs' sums) and the
    # front figure's runs read again (at most the changed run and one it displaced); the rear fit and
    # the pressure fits come from the memo
    assert memo.computed <= 4 and memo.hits >= 10
    after = q(inc, "SELECT * FROM spring_fits ORDER BY chamber")
    assert after["n_polytropic"].iloc[1] == before["n_polytropic"].iloc[1]            # rear: the same bits
    assert after["n_polytropic"].iloc[0] != before["n_polytropic"].iloc[0]            # front: refitted
    # a changed pressure-step run: its analysis and its chamber's two fits, done here from its steps;
    # both spring fits from the memo
    _write(raw, "pstep", simulate_pressure_step("rear", rng=17))
    age(raw)
    rebuild(raw, inc, jobs=2, report=False)
    memo = seen[-1].memos["models"]
    assert memo.computed == 3 and memo.hits >= 10
    rebuild(raw, full, jobs=2, full=True, report=False)
    a, b = dump(inc), dump(full)
    for table in ("spring_fits", "spring_tests", "spring_loop_energy", "pressure_dynamics", "pressure_steps"):
        assert a[table] and a[table] == b[table], table


def test_a_chambers_fit_is_keyed_by_a_digest_of_its_runs_items(tmp_path):
    """The joint fit's memo item names its runs by a digest of their items (issue 26: not the memo's walk of
    ~3,300 items): any run's kind, id, samples file or params changes the key, a moved warehouse does not,
    and the fit computed from it is the item's."""
    from pipeline.rebuild.memo import item_key
    from pipeline.stages.models import _fit_item, fit_spring_runs

    def runs(wh, **change):
        base = [("spring", f"r{i}", f"{wh}/samples/{i:02d}.parquet", '{"chamber":"front"}') for i in range(3)]
        return tuple(tuple(change.get(f"{j}{i}", v) for j, v in enumerate(r)) for i, r in enumerate(base))

    a, b = tmp_path / "a", tmp_path / "b"
    key = lambda wh, r, chamber="front": item_key(fit_spring_runs, _fit_item(chamber, r, wh), wh)  # noqa: E731
    k = key(a, runs(a))
    assert k is not None and k == key(b, runs(b))                                    # moved: the same key
    changed = [runs(a, **{"01": "r9"}), runs(a, **{"21": f"{a}/samples/99.parquet"}), runs(a, **{"32": "{}"}),
               runs(a, **{"00": "step"}), runs(a)[:2], runs(a)[::-1]]
    assert len({k, key(a, runs(a), "rear"), *(key(a, r) for r in changed)}) == 2 + len(changed)
    item = _fit_item("front", runs(a), a)
    assert tuple(item) == ("front", runs(a)) and item.memo_key[1] == "front"
    odd = _fit_item("front", (("spring", "r0", f"{a}/s.parquet", {"x": object()}),), a)   # not plain JSON
    assert type(odd) is tuple and not hasattr(odd, "memo_key")


def test_the_spring_figures_get_the_fit_they_draw_and_draw_the_same_bytes():
    """The figures' recipes hold the fit's parameters, not its per-test dicts (their keys hash what is
    drawn: issue 26), and the loop energy table's drawn columns; the PNG is the same bytes either way."""
    import io

    from analyses.pla_spring_fit import fit_spring_chamber
    from analyses.pla_spring_plots import plot_loop_energy, plot_spring_loops
    from tests.analyses.test_pla_spring import _prepared

    runs, _ = _prepared("front", [(3.0, 5.0, 1.0), (2.0, 3.0, 0.5), (4.0, 7.0, 2.0)])
    fit = fit_spring_chamber(runs)
    slim = stage._drawn_fit(fit)
    assert fit.ok and fit.nrmse_pct and slim.params == fit.params and slim.chamber == fit.chamber
    assert not (slim.nrmse_pct or slim.model_loop_energy_j or slim.test_notes or slim.se or slim.seeds)
    table = pd.DataFrame([{"run_id": r.run_id, "chamber": "front", "p0_bar_abs": r.p0_abs / 1e5,
                           "amplitude_mm": r.amplitude_m * 1e3, "frequency_hz": r.frequency_hz, "n_cycles": r.cycles,
                           "loop_energy_j": r.loop_energy_j, "model_loop_energy_j": 1.0, "structural_energy_j": 2.0}
                          for r in runs])

    def png(fig):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=60, metadata={"Software": None})
        return buf.getvalue()

    assert png(plot_spring_loops(runs, fit)) == png(plot_spring_loops(runs, slim))
    assert png(plot_loop_energy(table, {"front": fit})) == \
        png(plot_loop_energy(table[list(stage.ENERGY_DRAWN)], {"front": slim}))
