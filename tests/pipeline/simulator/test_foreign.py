"""Foreign-rig campaign: it ingests whole, and what lands in samples matches the simulator's truth."""
import hashlib
import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree, discover_runs
from pipeline.simulator import foreign, pla, plpa
from pipeline.simulator.base import HOSE_AREA_M2
from pipeline.simulator.campaign import simulate_campaign

SEED = 3


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    raw = tmp_path_factory.mktemp("foreign") / "raw"
    summary = simulate_campaign(raw, seed=SEED, profile="foreign")
    warehouse = raw.parent / "warehouse"
    tree = RawTree(raw)
    results = {tree.rel(p): ingest_file(tree, p, warehouse) for p in discover_runs(raw)}
    truth = json.loads((raw / "truth.json").read_text())
    return raw, warehouse, summary, results, truth


def test_every_foreign_run_ingests(campaign):
    raw, _, summary, results, truth = campaign
    assert {r.error for r in results.values()} == {None}
    assert len(results) == summary.n_runs == len(truth["runs"]) == len(foreign.plan())
    assert {r.run["run_id"] for r in results.values()} == set(truth["runs"])
    assert summary.by_kind == {"viscous": 14, "pressure_step": 6, "timeseries": 1}  # + pinch valve new/aged, ventilator ramp, laser runs, linear drive, kpa logger


def _samples(campaign, run_id):
    _, warehouse, _, results, _ = campaign
    res = next(r for r in results.values() if r.run["run_id"] == run_id)
    return res, pq.read_table(warehouse / res.run["samples_path"])


@pytest.mark.parametrize("run", foreign.plan(), ids=lambda r: r.stem)
def test_samples_match_truth(campaign, run):
    """Time base, units, derived f and every channel come back as simulated (in SI)."""
    rec = campaign[4]["runs"][run.run_id]
    res, table = _samples(campaign, run.run_id)
    expected = foreign.simulate(run, SEED).data
    units = {f.name: f.metadata[b"unit"].decode() for f in table.schema if f.name != "run_id"}
    assert units == rec["expected"]["columns"]
    assert table.num_rows == len(expected)
    # time: exact where written, i / rate (to rounding) where synthesised from the stated rate
    np.testing.assert_allclose(table.column("t_s").to_numpy(), expected["t_s"].to_numpy(), rtol=1e-12, atol=1e-12)
    for col in units:
        if col == "t_s":
            continue
        got = table.column(col).to_numpy()
        want = expected[col].to_numpy()
        if col == "f_n" and run.stem == "loadcell":
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)       # derived: f_cell - p_b A
        else:   # unit conversion round trip (bar -> Pa) to float rounding
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=0)
    for key, value in rec["expected"]["params"].items():
        assert res.run["params"][key] == pytest.approx(value, rel=1e-12)
    stated = {k for k in res.run["params"] if k.startswith("sensor_")}
    assert stated == set(rec["expected"]["params"])                     # absent where not stated


def test_time_base_and_lookalike_runs(campaign):
    res, table = _samples(campaign, f"{foreign.CAMPAIGN}/analog-20um")
    assert res.run["sample_rate_hz"] == pytest.approx(100.0)
    assert table.column("t_s").to_numpy()[:3] == pytest.approx([0.0, 0.01, 0.02])
    assert any("time from `sample_rate_hz`" in w for w in res.run["warnings"])
    res, _ = _samples(campaign, f"{foreign.CAMPAIGN}/trapezoid")
    assert any("time from `Fs`" in w for w in res.run["warnings"])
    res, table = _samples(campaign, f"{foreign.CAMPAIGN}/shaker-accel")
    assert "f_n" not in table.column_names and "f_g" in table.column_names
    assert any("`F` in `g`" in w for w in res.run["warnings"])


def test_load_cell_force_balance_is_the_drive_force(campaign):
    """The cell reads drive force + p_b A; the derived f is the drive force of the truth."""
    res, table = _samples(campaign, f"{foreign.CAMPAIGN}/loadcell")
    f_cell = table.column("f_cell_n").to_numpy()
    p_b = table.column("p_b_pa").to_numpy()
    np.testing.assert_allclose(table.column("f_n").to_numpy(), f_cell - p_b * HOSE_AREA_M2, rtol=0, atol=1e-12)
    assert np.mean(p_b) == pytest.approx(2e5, rel=0.01)
    assert {c["column"]: c["channel"] for c in res.channels}["f_n"] == "f"


def test_truth_has_the_true_values(campaign):
    runs = campaign[4]["runs"]
    lc = runs[f"{foreign.CAMPAIGN}/loadcell"]["truth"]
    assert lc["moving_mass_kg"] == 3.5 and lc["fc_n"] > 0 and lc["ka_n_s_m"] > 0 and lc["x0_m"] == 0.4
    analog = runs[f"{foreign.CAMPAIGN}/analog-50um"]["truth"]
    assert analog["position_noise_m"] == 5e-5 and analog["position_step_m"] is None
    sweep = runs[f"{foreign.CAMPAIGN}/pressure-sweep-05kpa"]["truth"]
    assert sweep["tau_s"] == 0.25 and sweep["fs_hz"] == 20.0
    assert {round(abs(s["p_to_pa"] - s["p_from_pa"])) for s in sweep["steps"]} == {5000}
    trap = runs[f"{foreign.CAMPAIGN}/trapezoid"]["truth"]
    assert {abs(p["velocity_m_s"]) for p in trap["passes"]} == {0.12}
    low = runs[f"{foreign.CAMPAIGN}/lowspeed"]["truth"]
    assert {round(abs(p["velocity_m_s"]) * 1e3) for p in low["passes"]} == {5, 10, 15}


def test_sensors_as_simulated():
    """The analog sensor is noisy and not quantised; encoders are quantised to their step."""
    analog = plpa.simulate_viscous(rng=1, fs_hz=100.0, position_noise_m=20e-6, position_resolution_m=0.0)
    clean = plpa.simulate_viscous(rng=1, fs_hz=100.0, position_resolution_m=0.0)
    err = analog.data["x_m"].to_numpy() - clean.data["x_m"].to_numpy()
    assert np.std(err) == pytest.approx(20e-6, rel=0.1)
    coarse = plpa.simulate_viscous(rng=1, fs_hz=100.0, position_resolution_m=50e-6).data["x_m"].to_numpy()
    np.testing.assert_allclose(coarse / 50e-6, np.round(coarse / 50e-6), atol=1e-6)
    p = pla.simulate_pressure_step(rng=1, levels_bar=(1.0, 1.05), hold_s=2.0, fs_hz=20.0, tau_s=0.25, noise_pa=0.0)
    t, v = p.data["t_s"].to_numpy(), p.data["p_pa"].to_numpy()
    k = np.searchsorted(t, 2.0 + 0.25)   # one time constant after the step: 63.2 % of 5 kPa
    assert v[k] == pytest.approx(1e5 + 5e3 * (1 - np.exp(-1)), abs=1.0)


def _digest(folder):
    h = hashlib.sha256()
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(f.relative_to(folder).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def test_same_seed_same_bytes(campaign, tmp_path):
    raw = campaign[0]
    simulate_campaign(tmp_path / "again", seed=SEED, profile="foreign")
    assert _digest(tmp_path / "again") == _digest(raw)


# Default physics unchanged by the optional parameters (the demo's bytes stay identical): digests
# of default runs, computed with the code before the parameters were added.
DEFAULT_DIGESTS = {
    "viscous": "cd780c19b87fe0b926f94f3a8d7805cef76557159246afb38306de804a328505",
    "viscous_force": "cbca75c49a602a1aa313258c29882da5ffbc34dda4bc5b48c07af50b2b8d2646",
    "pressure_step": "9715c59e1d0d2a402eee09e215e61916670f4ffd4d5fade62846c2084c2bbe8a",
}


def test_default_runs_are_unchanged():
    def digest(run):
        return hashlib.sha256(run.data.to_numpy().tobytes()).hexdigest()

    assert digest(plpa.simulate_viscous(rng=1, fs_hz=200.0)) == DEFAULT_DIGESTS["viscous"]
    assert digest(plpa.simulate_viscous(rng=2, use_force_channel=True, fs_hz=200.0)) == DEFAULT_DIGESTS["viscous_force"]
    assert digest(pla.simulate_pressure_step(rng=3, fs_hz=200.0)) == DEFAULT_DIGESTS["pressure_step"]


def test_logger_headers_map_by_their_text_and_its_comment_is_kept_whole(campaign):
    """Issue 25 items 1 and 4: `time(sec)` / `pressure(kPa)` headers mapped by rig.toml
    `[channels."time(sec)"]`, and `# Captured <date time.us> by unknown user` above the header."""
    raw, _, _, _, truth = campaign
    run_id = f"{foreign.CAMPAIGN}/kpa-logger-steps"
    rec = truth["runs"][run_id]
    lines = (raw / rec["file"]).read_text().splitlines()
    assert lines[5].startswith("# Captured ") and lines[5].endswith(" by unknown user")
    assert lines[6] == "time(sec),pressure(kPa),setpoint(kPa)"
    res, table = _samples(campaign, run_id)
    assert res.run["params"]["comments"] == rec["expected"]["comments"] == [lines[5][2:]]
    assert not any(k.startswith("Captured") for k in res.run["params"])
    raw_names = {c["column"]: c["raw_name"] for c in res.channels}
    assert raw_names == {"t_s": "time", "p_pa": "pressure", "p_ref_pa": "setpoint"}
