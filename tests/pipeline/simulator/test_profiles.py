"""Campaign profiles: the sizes the docstring promises."""
from __future__ import annotations

import dataclasses

import pytest

from pipeline.simulator.profiles import PROFILES, Profile


def test_the_profiles_and_their_names():
    assert set(PROFILES) == {"demo", "full", "mini"}
    assert all(p.name == name for name, p in PROFILES.items())
    with pytest.raises(dataclasses.FrozenInstanceError):
        PROFILES["demo"].dur_fs_hz = 1.0


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_every_durability_turn_is_sampled_and_both_adjustments_stop(name):
    """A dwell at each end of a stroke lasts at least one sample period (so distance and stroke
    counts are exact from the record), and the hoses of both adjustments have a stop distance."""
    p = PROFILES[name]
    assert p.dur_dwell_s >= 1.0 / p.dur_fs_hz
    assert set(p.stop_km) == {"distance", "force"}
    assert p.logged_hoses >= 2 and p.check_every >= 1


def test_demo_is_the_default_and_mini_keeps_one_run_per_variant():
    assert PROFILES["demo"] == Profile("demo")
    assert PROFILES["mini"].limit_per_variant == 1 and PROFILES["demo"].limit_per_variant is None
    assert PROFILES["full"].dur_fs_hz == 1000.0 and PROFILES["full"].chunk_rows == 2_000_000


def test_the_demo_carries_a_plan_the_reader_takes_whole_and_mini_none(tmp_path):
    """The demo's plan.toml is read without a quarantine line: FLEXIGOM AIR's margin 1.5 from its
    own table, the rest from [defaults]; max_failures is left to the design."""
    from pipeline.raw.plan import read_plan
    from pipeline.raw.tree import RawTree

    (tmp_path / "plan.toml").write_text(PROFILES["demo"].plan)
    plan = read_plan(RawTree(tmp_path.resolve()))
    assert plan.present and not plan.problems
    s = plan.for_hose_type("FLEXIGOM AIR")
    assert (s.margin, s.sources["margin"]) == (1.5, "hose_type")
    assert (s.alpha, s.power, s.confidence, s.spending, s.benches, s.km_per_day) == (0.05, 0.8, 0.9,
                                                                                     "obrien-fleming", 2, 30.0)
    assert s.max_failures is None and plan.for_hose_type("other").margin == 1.25
    assert PROFILES["full"].plan == PROFILES["demo"].plan and PROFILES["mini"].plan is None


def test_the_demos_hoses_show_a_real_difference_under_its_plan():
    """The demo's hoses (force-set ones drawn to live ~3x longer) give a life-ratio interval above
    the plan's margin: the verdict has something real to declare (the stages decide when)."""
    import numpy as np

    from analyses.life_effect import life_effect
    from pipeline.simulator.campaign import plan_campaign

    _, planner = plan_campaign(1, "demo")
    hoses = list(planner.hoses.values())
    r = life_effect(np.array([h["distance_km"] for h in hoses]), np.array([h["status"] == "failed" for h in hoses]),
                    np.array([h["adjustment"] == "force" for h in hoses], int), confidence=0.9)
    assert r.n_failed_force >= 2 and r.n_failed_distance >= 2
    assert r.life_ratio_lower > 1.5 and r.p_value < 0.05
