"""The ``decision`` profile: hose types with a known life ratio, known by their odometer, whose
logbook reads back as the truth says, and a plan.toml the plan reader takes whole."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pandas as pd
import pytest

from analyses.life_effect import common_shape_fit
from pipeline.raw.logbook import merge_logbooks, read_logbooks
from pipeline.raw.plan import read_plan
from pipeline.raw.tree import RawTree
from pipeline.simulator.campaign import simulate_campaign
from pipeline.simulator.decision import (DECISION_CAMPAIGN, DecisionProfile, design_failures, hose_type_truth,
                                         simulate_decision)

SMALL = DecisionProfile(hose_types=12, scenario="mixed", separate_shapes=0.25)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    raw = tmp_path_factory.mktemp("decision")
    simulate_campaign(raw, seed=3, profile=SMALL)
    return raw, json.loads((raw / "truth.json").read_text())


def test_the_tree_is_a_logbook_a_plan_and_the_truth(campaign):
    raw, truth = campaign
    assert sorted(p.name for p in raw.iterdir()) == [DECISION_CAMPAIGN, "plan.toml", "truth.json"]
    assert [p.name for p in (raw / DECISION_CAMPAIGN).iterdir()] == ["hoses.csv"]
    assert truth["profile"] == "decision" and truth["seed"] == 3 and len(truth["hose_types"]) == 12


def test_the_plan_is_read_without_a_problem_and_says_the_profiles_settings(campaign):
    raw, _ = campaign
    plan = read_plan(RawTree(raw.resolve()))
    assert plan.present and not plan.problems
    s = plan.for_hose_type("SIM-0001")
    assert (s.margin, s.alpha, s.power, s.confidence, s.spending) == (1.5, 0.05, 0.8, 0.9, "obrien-fleming")
    assert (s.benches, s.km_per_day, s.max_failures) == (8, 20.0, None)
    assert s.sources["margin"] == "defaults" and s.sources["max_failures"] == "built-in"


def test_the_logbook_reads_back_as_the_truth_without_a_quarantined_row(campaign):
    """Every hose's status and odometer as the logbook reader merges them are the truth's; the
    running hoses' odometer reading (a removal and reinstallation) leaves them running."""
    raw, truth = campaign
    events, problems = read_logbooks(raw)
    hoses, merge_problems = merge_logbooks(events)
    assert not problems and not merge_problems
    hoses = hoses.set_index("hose_id")
    assert set(hoses.index) == set(truth["hoses"])
    for hid, t in truth["hoses"].items():
        h = hoses.loc[hid]
        assert h["status"] == t["status"] and h["hose_type"] == t["hose_type"] and h["adjustment"] == t["adjustment"]
        assert h["odometer_km"] == pytest.approx(t["distance_km"], rel=1e-12)
    statuses = pd.Series([t["status"] for t in truth["hoses"].values()]).value_counts()
    assert statuses["failed"] > statuses["running"] > 0 and statuses["removed"] > 0


def test_distance_is_linear_in_time_at_the_bench_speed(campaign):
    """distance = km_per_day x days since installation, to the float, for every hose's end (so a
    look's distances interpolated linearly in time are exact)."""
    _, truth = campaign
    for t in truth["hoses"].values():
        end = t["ended_at"] or t["odometer_at"]
        days = (pd.Timestamp(end) - pd.Timestamp(t["installed_at"])).total_seconds() / 86400
        assert t["distance_km"] == pytest.approx(20.0 * days, rel=1e-12, abs=1e-12)
        if t["status"] == "failed":
            assert t["distance_km"] == pytest.approx(t["life_km_drawn"], abs=20.0 / 86400)


def test_installations_are_staggered_and_each_bench_runs_one_hose_at_a_time(campaign):
    _, truth = campaign
    hoses = pd.DataFrame(truth["hoses"].values())
    one = hoses[hoses["hose_type"] == "SIM-0001"]
    assert one["installed_at"].nunique() == len(one)   # no two hoses installed at once
    running = one[one["status"] == "running"]
    assert 0 < len(running) <= SMALL.benches


def test_each_type_runs_to_its_target_failures_and_the_truth_holds_its_scenario(campaign):
    _, truth = campaign
    for j, (name, t) in enumerate(sorted(truth["hose_types"].items())):
        assert name == f"SIM-{j + 1:04d}"
        assert t["scenario"] == ("no-difference", "at-margin", "above-margin")[j % 3]
        assert t["life_ratio"] == pytest.approx({"no-difference": 1.0, "at-margin": 1.5,
                                                 "above-margin": 1.5 ** 1.5}[t["scenario"]])
        assert t["b10_force_km"] / t["b10_distance_km"] == pytest.approx(t["life_ratio"])
        assert t["n_failed"] >= t["target_failures"] == math.ceil(1.5 * design_failures(1.5, 0.05, 0.8,
                                                                                        t["shape_distance"]))
        assert t["n_hoses"] == t["n_failed"] + t["n_removed"] + t["n_running"]
    separate = [t for t in truth["hose_types"].values() if t["separate_shapes"]]
    assert separate and all(t["shape"] is None and t["shape_force"] == pytest.approx(1.6 * t["shape_distance"])
                            for t in separate)


def test_separate_shapes_keep_the_ratio_of_b10_lives():
    """With one shape per adjustment the true ratio is that of the B10 lives, by the Weibull quantile."""
    p = DecisionProfile(separate_shapes=1.0, scenario="at-margin")
    t = hose_type_truth(0, p, np.random.default_rng(1))
    b10 = {a: t[f"scale_{a}_km"] * (-math.log(0.9)) ** (1 / t[f"shape_{a}"]) for a in ("distance", "force")}
    assert b10["force"] / b10["distance"] == pytest.approx(1.5)


def test_the_design_failures_are_the_closed_form_inflated():
    """Margin 1.25, alpha 0.05, power 0.8, shape 2: 157.6 failures fixed sample (docs/decision.md),
    1.1 times that is 173.3 -> 174."""
    assert design_failures(1.25, 0.05, 0.8, 2.0) == 174


def test_the_ratio_and_shape_are_recovered_from_the_simulated_lives():
    """Pooled over 60 common-shape hose types at the margin, the fitted log ratio is unbiased and
    the shape within its MLE's small upward bias (~2-3 % at ~50 failures) plus 3 Monte Carlo SE:
    the simulated lives are the truth's Weibull, censored independently of their life."""
    p = DecisionProfile(hose_types=60, scenario="at-margin", separate_shapes=0.0)
    _, _, truth = simulate_decision(7, p)
    hoses = pd.DataFrame(truth["hoses"].values())
    logr, dshape = [], []
    for name, h in hoses.groupby("hose_type"):
        fit = common_shape_fit(h["distance_km"].to_numpy(), (h["status"] == "failed").to_numpy(),
                               (h["adjustment"] == "force").astype(int).to_numpy())
        logr.append(fit.log_ratio)
        dshape.append(math.log(fit.shape / truth["hose_types"][name]["shape"]))
    se = np.std(logr) / math.sqrt(len(logr))
    assert abs(np.mean(logr) - math.log(1.5)) < 3 * se
    assert abs(np.mean(dshape)) < 0.03 + 3 * np.std(dshape) / math.sqrt(len(dshape))


def test_same_seed_same_bytes_and_a_type_does_not_depend_on_how_many_there_are(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    simulate_campaign(a, seed=5, profile=DecisionProfile(hose_types=3))
    simulate_campaign(b, seed=5, profile=DecisionProfile(hose_types=3))
    for rel in (f"{DECISION_CAMPAIGN}/hoses.csv", "plan.toml", "truth.json"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes()
    _, _, five = simulate_decision(5, DecisionProfile(hose_types=5))
    three = json.loads((a / "truth.json").read_text())
    assert three["hose_types"]["SIM-0002"] == pytest.approx(five["hose_types"]["SIM-0002"])
    _, _, other = simulate_decision(6, DecisionProfile(hose_types=3))
    assert other["hose_types"]["SIM-0001"]["shape_distance"] != three["hose_types"]["SIM-0001"]["shape_distance"]


def test_a_plan_with_max_failures_and_an_unknown_scenario():
    _, plan, _ = simulate_decision(1, DecisionProfile(hose_types=1, max_failures=40))
    assert "max_failures = 40" in plan
    with pytest.raises(ValueError, match="unknown scenario"):
        simulate_decision(1, dataclasses.replace(SMALL, scenario="huge"))


class _RunTo:
    """A ``run_to`` that records the logbooks it is shown: None until ``after`` failures, then ``to``."""

    def __init__(self, after: int, to: int | None):
        self.after, self.to, self.seen = after, to, []

    def __call__(self, rows, truth):
        self.seen.append(rows)
        failed = sum(r["event"] == "failed" for r in rows)
        return self.to if failed >= self.after else None


def test_run_to_stops_a_type_half_a_day_after_the_number_it_returns():
    hook = _RunTo(8, 20)
    p = DecisionProfile(hose_types=1, scenario="at-margin", separate_shapes=0.0, run_to=hook)
    rows, _, truth = simulate_decision(2, p)
    t = truth["hose_types"]["SIM-0001"]
    assert t["run_to"] == 20 and t["stopped_by"] == "max_failures" and truth["settings"]["run_to"] == "_RunTo"
    failed = sorted(pd.Timestamp(h["ended_at"]) for h in truth["hoses"].values() if h["status"] == "failed")
    assert len(failed) == t["n_failed"] >= 20
    cutoff = failed[19] + pd.Timedelta(hours=12)   # half a day after the 20th failure
    assert failed[-1] <= cutoff
    odometer = {pd.Timestamp(h["odometer_at"]) for h in truth["hoses"].values() if h["status"] == "running"}
    assert odometer == {cutoff}
    # it was asked at each failure until it answered (the 8th), with the logbook as it stood then
    assert [sum(r["event"] == "failed" for r in rows_then) for rows_then in hook.seen] == list(range(1, 9))
    last = hook.seen[-1]
    at = max(r["at"] for r in last if r["event"] == "failed")
    running = {r["hose_id"] for r in last if r["event"] == "removed" and r["notes"] == "odometer read; test continues"}
    assert running and all(r["at"] > at for r in last if r["hose_id"] in running and r["event"] == "removed")
    assert [r["at"] for r in last] == sorted(r["at"] for r in last)
    # the prefix of the logbook is the same as without the hook: the same hoses, the same lives
    _, _, plain = simulate_decision(2, dataclasses.replace(p, run_to=None))
    common = set(truth["hoses"]) & set(plain["hoses"])
    assert len(common) >= 20 and all(truth["hoses"][h]["life_km_drawn"] == plain["hoses"][h]["life_km_drawn"]
                                     for h in common)


def test_run_to_without_an_answer_stops_at_the_cap():
    p = DecisionProfile(hose_types=1, scenario="no-difference", separate_shapes=0.0, run_to=_RunTo(10 ** 6, None))
    _, _, truth = simulate_decision(3, p)
    t = truth["hose_types"]["SIM-0001"]
    assert t["stopped_by"] == "cap" and t["run_to"] is None
    assert t["target_failures"] == math.ceil(4.0 * design_failures(1.5, 0.05, 0.8, t["shape_distance"]))
    assert t["n_failed"] >= t["target_failures"]
