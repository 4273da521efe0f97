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
