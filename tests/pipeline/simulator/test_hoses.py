"""The durability hoses: logbooks whose events follow each other, runs that add up to each hose's
distance, checks that follow the wear, a hose continued across both campaigns."""
from __future__ import annotations

import dataclasses

import pytest

from pipeline.simulator.hoses import HOSE_TYPE, HOSES_COLUMNS, LoggedHose, plan_hoses
from pipeline.simulator.plan import Planner
from pipeline.simulator.profiles import PROFILES


def _planned(profile="demo", seed=1):
    pl = Planner(PROFILES[profile], seed)
    plan_hoses(pl)
    return pl


def test_every_hose_is_installed_first_and_ends_at_most_once():
    pl = _planned()
    events: dict[str, list] = {}
    for book in pl.logbooks.values():
        for row in sorted(book, key=lambda r: r["at"]):
            events.setdefault(row["hose_id"], []).append(row)
    assert set(events) == set(pl.hoses)
    for hose_id, rows in events.items():
        assert rows[0]["event"] == "installed" and rows[0]["hose_type"] == HOSE_TYPE, hose_id
        ends = [r["event"] for r in rows if r["event"] in ("failed", "removed")]
        assert len(ends) == (pl.hoses[hose_id]["status"] != "running"), hose_id


def test_logged_hoses_runs_add_up_and_checks_follow_the_wear():
    pl = _planned()
    logged = {h: v for h, v in pl.hoses.items() if v["source"] == "runs"}
    assert len(logged) == PROFILES["demo"].logged_hoses
    for hose_id, hose in logged.items():
        runs = [p for p in pl.plans if p.kind == "durability" and p.metadata["hose_id"] == hose_id]
        assert len(runs) == hose["n_runs"]
        planned_km = sum(p.kwargs["distance_m"] for p in runs) / 1e3     # whole strokes are run: within one a run
        assert abs(planned_km - hose["distance_km"]) <= len(runs) * PROFILES["demo"].dur_stroke_m / 1e3
        checks = hose["leakage_checks"]
        assert checks[0]["distance_km"] == 0.0
        assert [c["distance_km"] for c in checks] == sorted(c["distance_km"] for c in checks)
        # the path's seal pressure falls with distance; a check reads it with the hose's seating scatter
        assert [c["p_seal_path_bar"] for c in checks] == sorted((c["p_seal_path_bar"] for c in checks), reverse=True)
        for c in checks[1:]:
            deficit = hose["p_seal_new_bar"] - c["p_seal_bar"]
            assert deficit / (hose["p_seal_new_bar"] - c["p_seal_path_bar"]) == pytest.approx(1.0, abs=0.25)
        assert checks[0]["p_seal_bar"] == hose["p_seal_new_bar"] == pytest.approx(6.0, abs=0.01)
        # the hose ends at its true failure distance when it fails, by the mode that came first
        if hose["status"] == "failed":
            assert hose["distance_km"] == pytest.approx(hose["failure_km"], abs=len(runs) * 1e-3)
            assert hose["failure_mode"] == hose["failure_mode_true"]
        else:
            assert hose["failure_km"] > hose["distance_km"]
    spanning = [h for h in logged.values() if len(h["campaigns"]) == 2]
    assert len(spanning) == 1
    camps = {p.run_id.split("/")[0] for p in pl.plans if p.metadata.get("hose_id") == spanning[0]["hose_id"]}
    assert camps == {"durability-2025", "durability-2026"}


def test_odometer_hoses_have_no_runs_and_the_hoses_are_the_seeds():
    pl = _planned()
    odometer = [h for h in pl.hoses.values() if h["source"] == "odometer"]
    assert len(odometer) == PROFILES["demo"].odometer_hoses
    assert all(h["n_runs"] == 0 and h["campaigns"] == ["durability-2025"] for h in odometer)
    assert _planned().hoses == pl.hoses
    assert _planned(seed=2).hoses != pl.hoses


def test_logged_hose_fields_are_frozen():
    hose = LoggedHose("H101", "distance", 0, "durability-2025", True, 30.0, 30.0, "failed")
    with pytest.raises(dataclasses.FrozenInstanceError):
        hose.outcome = "removed"


def test_hoses_csv_has_a_column_for_every_event_field():
    pl = _planned()
    fields = {k for book in pl.logbooks.values() for row in book for k in row}
    assert fields <= set(HOSES_COLUMNS) and {"wall_thickness_mm", "failure_mode", "notes"} <= fields
