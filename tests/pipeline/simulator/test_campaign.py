"""Campaigns: simulate + rebuild quarantines nothing, and every kind in every format ingests to
exactly the samples and metadata the simulator meant (float precision after unit conversion)."""
from __future__ import annotations

import csv
import hashlib
import importlib.util
import json
import math
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from pipeline.simulator.base import SimRun
from pipeline.simulator.campaign import DemoError, plan_campaign, refuse_occupied, simulate_campaign
from pipeline.simulator.runs import channels_of, simulate_plan
from pipeline.simulator.variants import VARIANTS
from pipeline.serve.door import connect_readonly

SEED = 3
MINI_PLANS, _ = plan_campaign(SEED, "mini")
READER_MODULE = {"csv": "csv", "txt": "csv", "lvm": "lvm", "tdms": "tdms", "mat": "mat", "xlsx": "excel", "mf4": "mdf"}


def _meant(plan) -> SimRun:
    """What ingest must give back for a plan's file: the simulated samples (all chunks) in the
    columns the file carries, and the metadata and truth written with it."""
    frames, meta, truth = simulate_plan(plan, SEED)
    data = frames if isinstance(frames, pd.DataFrame) else pd.concat(list(frames), ignore_index=True)
    return SimRun(data[["t_s"] + channels_of(plan)], meta, truth)


def _reader_missing(fmt: str) -> bool:
    return importlib.util.find_spec(f"pipeline.readers.{READER_MODULE[fmt]}") is None


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    from pipeline.rebuild.flow import rebuild

    root = tmp_path_factory.mktemp("campaign")
    raw, wh = root / "raw", root / "warehouse"
    simulate_campaign(raw, SEED, "mini", jobs=2)
    summary = rebuild(raw, wh, jobs=2, report=False)
    con = duckdb.connect(str(wh / "pneubench.duckdb"), read_only=True)
    runs = {r[0]: r[1:] for r in con.execute("SELECT run_id, samples_path, params, source_path FROM runs").fetchall()}
    con.close()
    return raw, wh, summary, runs


def test_rebuild_quarantines_nothing(built):
    raw, wh, summary, runs = built
    missing = {p.fmt for p in MINI_PLANS if _reader_missing(p.fmt)}
    problems = [q for q in summary.quarantine if Path(q.source_path).suffix.lstrip(".") not in missing]
    assert problems == []
    assert len(runs) == len([p for p in MINI_PLANS if p.fmt not in missing])


def _case_id(plan):
    return f"{plan.group}-{plan.fmt}-{VARIANTS[plan.group].index(plan.variant)}"


CASES = {}
for _p in MINI_PLANS:
    CASES.setdefault(_case_id(_p), _p)


@pytest.mark.parametrize("case", sorted(CASES))
def test_ingested_samples_equal_simulated(built, case):
    plan = CASES[case]
    if _reader_missing(plan.fmt):
        pytest.skip(f"no {plan.fmt} reader yet")
    raw, wh, summary, runs = built
    assert plan.run_id in runs, f"{plan.rel_path} was not ingested"
    samples_path, params, source = runs[plan.run_id]
    assert source == plan.rel_path
    table = pq.read_table(wh / samples_path)
    meant = _meant(plan)
    assert len(table) == len(meant.data)
    for col in meant.data.columns:
        got = table.column(col).to_numpy()
        want = meant.data[col].to_numpy()
        scale = max(float(np.max(np.abs(want))), 1e-300)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale, err_msg=f"{case}: {col}")
    extra = set(table.column_names) - set(meant.data.columns) - {"run_id"}
    assert not extra, f"unexpected columns {extra}"
    params = json.loads(params) if isinstance(params, str) else params
    for key, value in meant.metadata.items():
        if key == "started_at":
            assert params[key].startswith(value), key
        elif isinstance(value, float):
            # keys pneubench does not type (e.g. p0_bar_abs) stay as written in text exports
            got = float(params[key]) if isinstance(params[key], str) else params[key]
            assert got == pytest.approx(value), key
        else:
            assert params[key] == value, key


def test_same_seed_same_bytes(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    simulate_campaign(a, 5, "mini", jobs=1)
    simulate_campaign(b, 5, "mini", jobs=2)

    def digest(root):
        return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    da, db = digest(a), digest(b)
    assert da == db and len(da) > 30
    c = tmp_path / "c"
    simulate_campaign(c, 6, "mini", jobs=2)
    assert digest(c) != da


def test_demo_plan_has_the_papers_matrices_and_every_format():
    plans, planner = plan_campaign(1, "demo")
    by_kind: dict[str, set] = {}
    for p in plans:
        by_kind.setdefault(p.kind, set()).add(p.fmt)
    assert all(len(f) >= 2 for f in by_kind.values()), by_kind
    assert set(by_kind) == {"leakage", "breakaway", "viscous", "identification", "step", "spring",
                            "pressure_step", "durability", "timeseries"}
    char_leak = [p for p in plans if p.group == "leakage"]
    assert len(char_leak) == 2 * (7 + 3)                        # both chambers, all settings
    brk = [p for p in plans if p.kind == "breakaway"]
    assert len(brk) == 5 * 5 * 2 * 2                              # two repetitions of the matrix
    cells: dict[tuple, int] = {}
    for p in brk:
        key = (p.kwargs["direction"], p.kwargs["backpressure_bar"], p.kwargs["force_rate_n_s"])
        cells[key] = cells.get(key, 0) + 1
    assert len(cells) == 50 and set(cells.values()) == {2}       # every cell has a mean +/- std
    assert len([p for p in plans if p.kind == "spring"]) == 120
    near = [p for p in plans if p.kind == "viscous" and "nearzero" in p.run_id]
    assert near and max(abs(v) for v in near[0].kwargs["speeds_m_s"]) == pytest.approx(7e-3)
    assert len({p.run_id for p in plans}) == len(plans)
    status = {h["status"] for h in planner.hoses.values()}
    assert status == {"failed", "removed", "running"}
    assert any(h["source"] == "odometer" for h in planner.hoses.values())
    assert any(len(h["campaigns"]) == 2 for h in planner.hoses.values())
    checks = [p for p in plans if p.group == "leakage_check"]
    assert len({p.metadata["hose_id"] for p in checks}) == sum(h["source"] == "runs" for h in planner.hoses.values())


def test_lab_format_mix_and_logbook(built):
    raw = built[0]
    eu = next((raw / "plpa-2025/leakage/eu").glob("*.csv")).read_text()
    header = [ln for ln in eu.splitlines() if not ln.startswith("#")][0]
    assert ";" in header and "Nl/min" in header and "kPa" in header
    assert "," in eu.splitlines()[-1]                             # decimal comma
    assert "bara" in next((raw / "plpa-2025/breakaway").glob("*.csv")).read_text()
    lvm = next(p for p in (raw / "plpa-2025/breakaway").glob("*.lvm") if "X_Columns\tOne" in p.read_text())
    assert lvm.read_text().count("***End_of_Header***") == 3      # file header + two segments
    assert (raw / "plpa-2025/step/headerless/rig.toml").is_file()
    rows = {camp: list(csv.DictReader(open(raw / camp / "hoses.csv"))) for camp in ("durability-2025", "durability-2026")}
    events = {r["event"] for rs in rows.values() for r in rs}
    assert {"installed", "inspected"} <= events
    assert any(r["wall_thickness_mm"] for rs in rows.values() for r in rs if r["event"] == "inspected")
    ids = [{r["hose_id"] for r in rs} for rs in rows.values()]
    assert ids[0] & ids[1]                                        # a hose in both campaigns
    truth = json.loads((raw / "truth.json").read_text())
    assert set(truth["runs"]) == {p.run_id for p in MINI_PLANS}
    assert truth["parameters"]["durability"]["rupture_life"]["force"] == {"shape": 2.4, "scale_km": 90.0}
    # every hose carries its path's truth, the running ones too
    for hose in truth["hoses"].values():
        assert hose["failure_km"] == pytest.approx(min(hose["leak_crossing_km"] or math.inf, hose["rupture_km"]))
        assert hose["wear_rate_per_km"] > 0


TIMESERIES = [p for p in MINI_PLANS if p.kind == "timeseries"]


def test_timeseries_logger_keeps_non_canonical_channels_with_their_units(built):
    """The ambient logger (kind timeseries, no analysis): both runs catalogued and queryable in
    samples_timeseries, temperature [degC] and rel_humidity [%] kept unconverted with their units
    under columns that end in them (temperature_degc, rel_humidity_pct),
    p_supply converted from bar, and the samples are what truth.json says was logged."""
    raw, wh, summary, runs = built
    assert {p.fmt for p in TIMESERIES} == {"csv", "tdms"}
    truth = json.loads((raw / "truth.json").read_text())["runs"]
    con = connect_readonly(wh)
    try:
        cols = {r[0] for r in con.execute("DESCRIBE samples_timeseries").fetchall()}
        counts = dict(con.execute("SELECT run_id, count(*) FROM samples_timeseries GROUP BY run_id").fetchall())
    finally:
        con.close()
    assert {"run_id", "t_s", "p_supply_pa", "temperature_degc", "rel_humidity_pct"} <= cols
    for plan in TIMESERIES:
        if _reader_missing(plan.fmt):
            continue
        rec = truth[plan.run_id]
        assert rec["kind"] == "timeseries" and rec["file"] == plan.rel_path
        t = rec["truth"]
        assert counts[plan.run_id] == t["n_samples"] == round(t["duration_s"] * t["fs_hz"])
        table = pq.read_table(wh / runs[plan.run_id][0])
        units = {f.name: (f.metadata or {}).get(b"unit", b"").decode() for f in table.schema}
        assert units["temperature_degc"] == "degC" and units["rel_humidity_pct"] == "%"
        meant = _meant(plan).data
        for col, stats in t["channels"].items():
            got = table.column(col).to_numpy()
            if col == "p_supply_pa":                               # bar -> Pa: float precision
                np.testing.assert_allclose(got, meant[col].to_numpy(), rtol=1e-12)
            else:                                                 # not converted: exact
                np.testing.assert_array_equal(got, meant[col].to_numpy())
            assert (got.min(), got.max()) == pytest.approx((stats["min"], stats["max"]), rel=1e-12)
            assert got.mean() == pytest.approx(stats["mean"], rel=1e-12)
        assert abs(float(np.mean(table.column("temperature_degc").to_numpy())) - t["temperature_c"]) < 0.5
        if "p_supply_pa" in t["channels"]:
            p = table.column("p_supply_pa").to_numpy() / 1e5
            assert t["supply_low_bar"] - 0.05 < p.min() and p.max() < t["supply_high_bar"] + 0.05


def test_refuse_occupied_passes_a_new_or_empty_folder_and_names_what_is_in_the_way(tmp_path):
    """One rule for `demo` and `simulate`: hidden entries and the caller's own names aside, nothing."""
    refuse_occupied(tmp_path / "new", "why")
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / ".hidden").write_text("")
    (folder / "plan.toml").write_text("")
    refuse_occupied(folder, "why", allowed=("plan.toml",))
    with pytest.raises(DemoError, match=r"f already holds plan.toml: why$"):
        refuse_occupied(folder, "why")
    for name in "abcd":
        (folder / name).write_text("")
    with pytest.raises(DemoError, match=r"already holds a, b, c, \.\.\.: why$"):
        refuse_occupied(folder, "why", allowed=("plan.toml",))
    (tmp_path / "loopA").symlink_to(tmp_path / "loopB")
    (tmp_path / "loopB").symlink_to(tmp_path / "loopA")
    with pytest.raises(DemoError, match="loopA cannot be listed"):
        refuse_occupied(tmp_path / "loopA", "why")
