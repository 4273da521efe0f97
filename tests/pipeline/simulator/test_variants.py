"""Export variants and rig.toml texts: every kind in two formats or more, every variant's options
accepted by its writer, every rig.toml valid TOML."""
from __future__ import annotations

import tomllib

import pytest

from pipeline.simulator.variants import RIG_TOMLS, VARIANTS
from pipeline.simulator.writers import CsvOptions, LvmOptions, TdmsOptions

OPTIONS = {"csv": CsvOptions, "txt": CsvOptions, "lvm": LvmOptions, "tdms": TdmsOptions}
#: The other writers' keyword options.
KEYWORDS = {"mat": {"scalars", "p_atm_pa", "include_time"}, "xlsx": {"units_row", "p_atm_pa"},
            "mf4": {"group", "p_atm_pa"}}


def test_every_kind_is_exported_in_two_formats_or_more():
    kinds = {"leakage": {"leakage", "leakage_check"}, "viscous": {"viscous", "viscous_force"}}
    for kind, groups in kinds.items():
        assert len({v["fmt"] for g in groups for v in VARIANTS[g]}) >= 2, kind
    for group, variants in VARIANTS.items():
        assert len({v["fmt"] for v in variants}) >= 2, group


@pytest.mark.parametrize("group", sorted(VARIANTS))
def test_every_variants_options_are_its_writers(group):
    for v in VARIANTS[group]:
        opts = v.get("opts", {})
        if v["fmt"] in OPTIONS:
            OPTIONS[v["fmt"]](**opts)
        else:
            assert set(opts) <= KEYWORDS[v["fmt"]], (group, v)
        assert set(v) <= {"fmt", "folder", "units", "names", "embed", "opts", "headerless", "channels"}


def test_every_rig_toml_parses_and_sits_in_a_campaign_folder():
    for rel, text in RIG_TOMLS.items():
        assert rel.endswith("/rig.toml") and rel.split("/")[0] in {"plpa-2025", "pla-2016", "durability-2025",
                                                                   "durability-2026"}
        tomllib.loads(text)
    headerless = tomllib.loads(RIG_TOMLS["plpa-2025/step/headerless/rig.toml"])
    assert headerless["metadata"]["kind"] == "step" and headerless["channels"]["2"]["scale"] == 0.005
