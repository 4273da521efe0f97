"""PLA pressure dynamics pooled per rig and per part and age: grouping and the changes with age,
hand-checked (issue 25 item 3)."""
import math

import numpy as np
import pytest

from analyses.pressure_dynamics import PressureFit, PressureStep
from analyses.pressure_groups import RunPart, StepGroup, age_changes, group_pressure_steps


def _step(run_id, direction, chamber="patient"):
    t = np.arange(5) / 100.0
    return PressureStep(run_id, chamber, direction, 0.0, 0.0, 1.0, 0.0, t, np.zeros(5))


def test_grouping_hand_checked():
    """Four runs: a valve new and aged and a run naming no part on one rig, a second campaign's
    rig. Each rig pools its own steps (all parts and ages), each (part, age) has its own group."""
    runs = {"c1/new": RunPart("c1", "vent", "valve", "V1", 0.0, None),
            "c1/aged": RunPart("c1", "vent", "valve", "V1", 594.0, None),
            "c1/plain": RunPart("c1", "vent"),
            "c2/other": RunPart("c2", "lab-b")}
    steps = [_step(r, d) for r in runs for d in ("charge", "discharge")] + [_step("c1/new", "charge")]
    groups = group_pressure_steps(steps, runs)
    by = {(g.level, g.campaign, g.rig, g.direction, g.part_id, g.age_h): sorted(s.run_id for s in v)
          for g, v in groups.items()}
    assert by == {
        ("rig", "c1", "vent", "charge", None, None): ["c1/aged", "c1/new", "c1/new", "c1/plain"],
        ("rig", "c1", "vent", "discharge", None, None): ["c1/aged", "c1/new", "c1/plain"],
        ("part", "c1", "vent", "charge", "V1", 0.0): ["c1/new", "c1/new"],
        ("part", "c1", "vent", "discharge", "V1", 0.0): ["c1/new"],
        ("part", "c1", "vent", "charge", "V1", 594.0): ["c1/aged"],
        ("part", "c1", "vent", "discharge", "V1", 594.0): ["c1/aged"],
        ("rig", "c2", "lab-b", "charge", None, None): ["c2/other"],
        ("rig", "c2", "lab-b", "discharge", None, None): ["c2/other"]}
    assert all(g.chamber == "patient" for g in groups)
    # a run the table does not know is pooled under an unnamed campaign and rig, never dropped
    (g,) = group_pressure_steps([_step("x/unknown", "charge")], {})
    assert (g.level, g.campaign, g.rig) == ("rig", "", "")


def test_age_changes_hand_checked():
    """Change from the youngest fitted age of the same part, rig, chamber and direction, in %;
    NULL (NaN) for the reference and where the models differ."""
    def g(age, direction="charge", part="V1", rig="vent"):
        return StepGroup("part", "c1", rig, "patient", direction, "valve", part, age, None)

    fits = {g(0.0): PressureFit("patient", "charge", wn_rad_s=40.0, zeta=0.5, model="second_order"),
            g(594.0): PressureFit("patient", "charge", wn_rad_s=30.0, zeta=0.6, model="second_order"),
            g(1000.0): PressureFit("patient", "charge", tau_s=0.1, model="first_order"),
            g(0.0, part="V2"): PressureFit("patient", "charge", tau_s=0.2, model="first_order"),
            g(100.0, part="V2"): PressureFit("patient", "charge", tau_s=0.25, model="first_order"),
            StepGroup("rig", "c1", "vent", "patient", "charge"): PressureFit("patient", "charge", tau_s=1.0,
                                                                             model="first_order")}
    ch = age_changes(fits)
    assert ch[g(594.0)]["wn_change_pct"] == pytest.approx(-25.0)
    assert ch[g(594.0)]["zeta_change_pct"] == pytest.approx(20.0)
    assert math.isnan(ch[g(594.0)]["tau_change_pct"])
    assert all(math.isnan(v) for v in ch[g(0.0)].values())            # the reference
    assert all(math.isnan(v) for v in ch[g(1000.0)].values())         # first order against second
    assert ch[g(100.0, part="V2")]["tau_change_pct"] == pytest.approx(25.0)
    assert StepGroup("rig", "c1", "vent", "patient", "charge") not in ch
