"""The ``rul`` profile: hoses whose runs add up, a leak check after every run that reads the hose's
path, failures at the truth's distance by the truth's mode, running hoses whose future is known,
and a plan.toml the reader takes whole."""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from pipeline.simulator.campaign import simulate_campaign
from pipeline.simulator.rul import RUL_CAMPAIGN, RulProfile, group_truth, plan_rul, plan_toml

SMALL = RulProfile(hose_types=2, hoses=12)


def _by_hose(plans):
    out: dict[str, list] = {}
    for p in plans:
        out.setdefault(p.metadata["hose_id"], []).append(p)
    return out


def test_runs_add_up_checks_follow_each_run_and_failures_come_at_the_truths_distance():
    pl, rows, truth = plan_rul(3, SMALL)
    assert len(truth["hoses"]) == 2 * 2 * 12 and set(_by_hose(pl.plans)) == set(truth["hoses"])
    for hose_id, plans in _by_hose(pl.plans).items():
        h = truth["hoses"][hose_id]
        runs = [p for p in plans if p.kind == "durability"]
        assert sum(math.ceil(p.kwargs["distance_m"] - 1e-6) for p in runs) / 1e3 == pytest.approx(h["distance_km"])
        assert [p.metadata["started_at"] for p in plans] == sorted(p.metadata["started_at"] for p in plans)
        km = [p.metadata["distance_km_so_far"] for p in plans if p.kind == "leakage"]
        assert km == sorted(km) and all(0 < k <= h["distance_km"] + 1e-9 for k in km)
        if h["status"] == "failed":
            assert h["distance_km"] == pytest.approx(h["failure_km"], abs=1e-3 * len(runs))
            assert h["failure_mode_true"] in ("leakage", "rupture")
        else:
            assert h["failure_km"] > h["distance_km"] - 1e-9 and h["distance_km"] == pytest.approx(h["end_km"], abs=0.01)
    failed = {r["hose_id"]: r["failure_mode"] for r in rows if r["event"] == "failed"}
    assert failed == {k: h["failure_mode_true"] for k, h in truth["hoses"].items() if h["status"] == "failed"}


def test_a_check_reads_the_hose_path_at_the_plans_pressure_a_power_law_through_the_origin():
    """The check's seal pressure is the path's, its deficit scattered by the seating only: the leak
    at the plan's pressure is (w d)^1.5 within the seating scatter."""
    pl, _, truth = plan_rul(4, SMALL)
    ratios = []
    for p in pl.plans:
        if p.kind != "leakage":
            continue
        h = truth["hoses"][p.metadata["hose_id"]]
        d = p.metadata["distance_km_so_far"]
        assert h["p_seal_new_bar"] == pytest.approx(SMALL.leak_pressure_bar, abs=1e-3)  # 536 N: 0.6 mbar short
        leak = h["leak_c"] * (SMALL.leak_pressure_bar - p.kwargs["p_seal_bar"]) ** 1.5
        ratios.append(math.log(leak / (h["wear_rate_per_km"] * d) ** 1.5))
    assert abs(np.mean(ratios)) < 0.03 and np.std(ratios) == pytest.approx(1.5 * 0.05, rel=0.25)


def test_the_groups_wear_rate_truth_is_the_distribution_the_hoses_are_drawn_from():
    p = RulProfile(hose_types=1, hoses=600)
    _, _, truth = plan_rul(5, p)
    for key, g in truth["groups"].items():
        w = np.array([h["wear_rate_per_km"] for h in truth["hoses"].values()
                      if f"{h['hose_type']}/{h['adjustment']}" == key])
        assert w.mean() == pytest.approx(g["wear_rate_mean_per_km"], rel=0.05)
        assert w.std() == pytest.approx(g["wear_rate_sd_per_km"], rel=0.15)
        crossing = np.array([h["leak_crossing_km"] for h in truth["hoses"].values()
                             if f"{h['hose_type']}/{h['adjustment']}" == key])
        assert np.median(crossing) == pytest.approx(g["median_crossing_km"], rel=0.08)


def test_group_truth_hand_checked():
    g = group_truth("T", "distance", 2.0, 0.0, RulProfile())
    # limit 2 l/min with c = 2: a deficit of 1 bar; reached at 2 km by a hose losing 0.5 bar/km
    assert g["seal_wear_bar_km"] == pytest.approx(0.5) and g["wear_rate_sd_per_km"] == 0.0
    assert g["wear_rate_mean_per_km"] == pytest.approx(2 ** (2 / 3) * 0.5)
    assert g["setting"] == {"z_rollers_mm": 4.0} and g["check_every_km"] == pytest.approx(0.4)


def test_the_campaign_is_written_with_its_logbook_rig_plan_and_truth(tmp_path):
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    p = RulProfile(hose_types=1, hoses=2)
    s = simulate_campaign(tmp_path, seed=2, profile=p, jobs=1)
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert s.n_runs == len(truth["runs"]) > 0 and set(s.by_kind) == {"durability", "leakage"}
    assert (tmp_path / RUL_CAMPAIGN / "rig.toml").read_text().count("[sensors.q_leak]") == 1
    rows = list(csv.DictReader(open(tmp_path / RUL_CAMPAIGN / "hoses.csv")))
    assert {r["hose_id"] for r in rows} == set(truth["hoses"])
    assert (tmp_path / "plan.toml").read_text() == plan_toml(p)
    plan = read_plan(RawTree(tmp_path.resolve()))
    s1 = plan.for_hose_type("RUL-01")
    assert not plan.problems and (s1.leak_limit_l_min, s1.leak_pressure_bar, s1.confidence) == (2.0, 6.0, 0.9)
