"""raw/plan.toml, the lab's test plan: read once, a hose type's table over [defaults] over the
built-in defaults, and each bad value, key or table ONE quarantine line naming file and key while
the rest of the plan and the night go on. Each scenario writes its own small plan.toml."""
import os

import pytest

from pipeline.raw.plan import KEYS, MAX_FAILURES_LIMIT, Plan, read_plan
from pipeline.raw.rig import MAX_RIG_BYTES
from pipeline.raw.tree import RawTree
from pipeline.raw.walk import walk_raw
from tests.conftest import query
from tests.pipeline.raw.conftest import rebuild_checked

BUILT_IN = {"margin": 1.25, "alpha": 0.05, "power": 0.80, "confidence": 0.90, "max_failures": None,
            "spending": "obrien-fleming", "benches": None, "km_per_day": None,
            "leak_limit_l_min": None, "leak_pressure_bar": None, "b_life": 10, "mission_km": None,
            "rupture_shape": None}
RUPTURE_UNSET = ("the default (unset: the rupture shape not known, the intervals hold for every shape from 1 to the "
                 "logbook's bound)")


def plan_of(raw, text: str | None) -> Plan:
    """The plan of a raw tree whose plan.toml is ``text`` (None: no plan.toml)."""
    if text is not None:
        raw.write("plan.toml", text)
    return read_plan(RawTree(raw.root))


def lines(plan: Plan) -> list[str]:
    return [f"{p.source_path}: {p.error}" for p in plan.problems]


def values(settings) -> dict:
    return {k: getattr(settings, k) for k in KEYS}


# -- a good plan, and none ----------------------------------------------------------------------------
def test_without_a_plan_every_hose_type_gets_the_built_in_defaults_and_no_plan(raw):
    raw.write("c/readme.txt", "x")
    plan = plan_of(raw, None)
    assert not plan.present and plan.problems == ()
    assert "no plan" in plan.note
    s = plan.for_hose_type("FLEXIGOM AIR")
    assert values(s) == BUILT_IN and set(s.sources.values()) == {"built-in"} and not s.present


def test_a_hose_types_table_overrides_the_defaults_which_override_the_built_ins(raw):
    plan = plan_of(raw, """
        # the lab's plan, 2026
        [defaults]
        margin = 1.5
        alpha = 0.025
        km_per_day = 40          # an integer is a number
        [hose_type."FLEXIGOM AIR"]
        margin = 1.2
        max_failures = 30
        spending = "pocock"
        benches = 2
        [hose_type.OTHER]
        power = 0.9
        """)
    assert plan.present and plan.problems == ()
    s = plan.for_hose_type("FLEXIGOM AIR")
    assert values(s) == {**BUILT_IN, "margin": 1.2, "alpha": 0.025, "km_per_day": 40, "max_failures": 30,
                         "spending": "pocock", "benches": 2}
    assert s.sources == {"margin": "hose_type", "alpha": "defaults", "power": "built-in", "confidence": "built-in",
                         "max_failures": "hose_type", "spending": "hose_type", "benches": "hose_type",
                         "km_per_day": "defaults", "leak_limit_l_min": "built-in",
                         "leak_pressure_bar": "built-in", "b_life": "built-in", "mission_km": "built-in",
                         "rupture_shape": "built-in"}
    assert s.present and s.hose_type == "FLEXIGOM AIR"
    # a hose type the plan does not name: [defaults] over the built-ins
    other = plan.for_hose_type("NOT NAMED")
    assert values(other) == {**BUILT_IN, "margin": 1.5, "alpha": 0.025, "km_per_day": 40}
    assert values(plan.for_hose_type(None)) == values(other)
    assert plan.for_hose_type("OTHER").power == 0.9


@pytest.mark.parametrize("key, value", [
    ("margin", "1.0001"), ("alpha", "1e-6"), ("alpha", "0.4999"), ("power", "0.5"), ("power", "0.999"),
    ("confidence", "0.501"), ("confidence", "0.99"), ("max_failures", "2"), ("max_failures", str(MAX_FAILURES_LIMIT)),
    ("spending", '"obrien-fleming"'), ("spending", '"pocock"'), ("benches", "1"), ("km_per_day", "0.5"),
    ("leak_limit_l_min", "2.5"), ("leak_pressure_bar", "6"),  # the spec's leakage failure keys
    ("b_life", "0.1"), ("b_life", "1"), ("b_life", "99.9"), ("mission_km", "0.001"), ("mission_km", "2000"),
    ("rupture_shape", "0.5"), ("rupture_shape", "1"), ("rupture_shape", "2.0"), ("rupture_shape", "20"),
])
def test_values_at_the_edges_of_their_ranges_are_taken(raw, key, value):
    plan = plan_of(raw, f"[defaults]\n{key} = {value}\n")
    assert plan.problems == () and plan.for_hose_type("A").sources[key] == "defaults"


# -- one bad value: one line, the default instead, the rest kept --------------------------------------
@pytest.mark.parametrize("key, value, shown, rule, instead", [
    ("margin", '"big"', '"big"', "a number > 1", "the default 1.25"),
    ("margin", "1", "1", "a number > 1", "the default 1.25"),
    ("margin", "inf", "inf", "a number > 1", "the default 1.25"),
    ("margin", "true", "true", "a number > 1", "the default 1.25"),
    ("alpha", "0.5", "0.5", "a number with 0 < alpha < 0.5", "the default 0.05"),
    ("alpha", "0", "0", "a number with 0 < alpha < 0.5", "the default 0.05"),
    ("alpha", "nan", "nan", "a number with 0 < alpha < 0.5", "the default 0.05"),
    ("power", "1.0", "1.0", "a number with 0.5 <= power < 1", "the default 0.8"),
    ("power", "0.49", "0.49", "a number with 0.5 <= power < 1", "the default 0.8"),
    ("confidence", "0.5", "0.5", "a number with 0.5 < confidence < 1", "the default 0.9"),
    ("confidence", "[0.9]", "an array", "a number with 0.5 < confidence < 1", "the default 0.9"),
    ("max_failures", "1", "1", f"an integer from 2 to {MAX_FAILURES_LIMIT}",
     "the default (unset: the sequential design's failures_needed)"),
    ("max_failures", "30.0", "30.0", f"an integer from 2 to {MAX_FAILURES_LIMIT}",
     "the default (unset: the sequential design's failures_needed)"),
    ("max_failures", "1_000_000_000", "1000000000", f"an integer from 2 to {MAX_FAILURES_LIMIT}",
     "the default (unset: the sequential design's failures_needed)"),
    ("spending", '"haybittle"', '"haybittle"', '"obrien-fleming" or "pocock"', 'the default "obrien-fleming"'),
    ("spending", "{ family = 1 }", "a table", '"obrien-fleming" or "pocock"', 'the default "obrien-fleming"'),
    ("benches", "0", "0", "an integer from 1 to 1000",
     "the default (unset: measured from the durability runs of the last 30 days)"),
    ("km_per_day", "-3", "-3", "a number > 0",
     "the default (unset: measured from the durability runs of the last 30 days)"),
    ("km_per_day", "2026-01-02", "the date/time 2026-01-02", "a number > 0",
     "the default (unset: measured from the durability runs of the last 30 days)"),
    ("leak_limit_l_min", "0", "0", "a number > 0", "the default (unset: no failure by leakage)"),
    ("leak_pressure_bar", '"6 bar"', '"6 bar"', "a number > 0", "the default (unset: no failure by leakage)"),
    ("b_life", "0", "0", "a number with 0 < b_life < 100 (percent failed)", "the default 10 (B10)"),
    ("b_life", "100", "100", "a number with 0 < b_life < 100 (percent failed)", "the default 10 (B10)"),
    ("b_life", '"B10"', '"B10"', "a number with 0 < b_life < 100 (percent failed)", "the default 10 (B10)"),
    ("mission_km", "0", "0", "a number > 0", "the default (unset: no reliability at a mission distance)"),
    ("mission_km", "-1500.0", "-1500.0", "a number > 0", "the default (unset: no reliability at a mission distance)"),
    *[("rupture_shape", v, shown, "a number with 0 < rupture_shape <= 20", RUPTURE_UNSET) for v, shown in (
        ("0", "0"), ("-2", "-2"), ("20.5", "20.5"), ("1e308", "1e+308"), ("inf", "inf"), ("nan", "nan"), ("true", "true"),
        ('"2"', '"2"'), ('"weibull 2"', '"weibull 2"'), ("[2.0]", "an array"), ("{ shape = 2 }", "a table"),
        ("1979-05-27", "the date/time 1979-05-27"))],
])
def test_a_bad_value_is_one_line_naming_file_table_and_key_and_the_default_is_used(raw, key, value, shown, rule,
                                                                                   instead):
    rest = "margin = 1.4\n" if key != "margin" else ""
    plan = plan_of(raw, f'[defaults]\nconfidence = 0.95\n[hose_type."FLEXIGOM AIR"]\n{key} = {value}\n{rest}')
    if key == "confidence":  # [defaults] has a valid one: that is what the hose type falls back to
        instead = "the [defaults] value 0.95"
    assert lines(plan) == [f'plan.toml: [hose_type."FLEXIGOM AIR"] {key}: must be {rule}, got {shown}; using {instead}']
    s = plan.for_hose_type("FLEXIGOM AIR")
    assert plan.present and s.sources[key] == ("defaults" if key == "confidence" else "built-in")
    assert getattr(s, key) == (0.95 if key == "confidence" else BUILT_IN[key])
    assert s.confidence == 0.95 and (key == "margin" or s.margin == 1.4)  # the rest of the plan is used


def test_a_bad_value_in_defaults_falls_back_to_the_built_in_also_for_the_hose_types(raw):
    plan = plan_of(raw, '[defaults]\nmargin = 0.8\n[hose_type."A"]\nmargin = "x"\n')
    assert lines(plan) == ["plan.toml: [defaults] margin: must be a number > 1, got 0.8; using the default 1.25",
                           'plan.toml: [hose_type."A"] margin: must be a number > 1, got "x"; using the default 1.25']
    assert plan.for_hose_type("A").margin == 1.25 and plan.for_hose_type("A").sources["margin"] == "built-in"


def test_long_strings_and_names_are_shown_cut(raw):
    plan = plan_of(raw, f'[defaults]\nspending = "{"p" * 500}"\n[hose_type."{"h" * 500}"]\n{"k" * 500} = 1\n')
    spending, key = lines(plan)
    assert f'got "{"p" * 40}..."' in spending and len(spending) < 200
    assert key.startswith(f'plan.toml: [hose_type."{"h" * 40}..."] {"k" * 40}...: unknown key') and len(key) < 300


@pytest.mark.parametrize("text, line", [
    ("[defaults]\nmarign = 1.3\n", "[defaults] marign: unknown key (did you mean margin?); ignored"),
    ('[hose_type."A"]\nwhatever = 1\n',
     '[hose_type."A"] whatever: unknown key (expected margin, alpha, power, confidence, max_failures, spending, '
     "benches, km_per_day, leak_limit_l_min, leak_pressure_bar, b_life, mission_km, rupture_shape); ignored"),
    ("[hoses]\nmargin = 1.3\n",
     '[hoses]: unknown table (expected [defaults] and [hose_type."<hose type>"]); ignored'),
    ("margin = 1.3\n[defaults]\n",
     'margin: a key outside any table (put it under [defaults] or [hose_type."<hose type>"]); ignored'),
    ("defaults = 3\n", "defaults: must be a table ([defaults]), got 3; ignored"),
    ('hose_type = "A"\n',
     'hose_type: must be tables of hose types ([hose_type."<hose type>"]), got "A"; ignored'),
    ("[hose_type]\nA = 1.3\n", '[hose_type."A"]: must be a table, got 1.3; ignored'),
])
def test_an_unknown_key_or_table_is_one_line_and_the_rest_is_used(raw, text, line):
    rest = '[hose_type."B"]\nmargin = 1.6\n' if "hose_type" not in text else "[defaults]\nmargin = 1.6\n"
    plan = plan_of(raw, text + rest)
    assert lines(plan) == [f"plan.toml: {line}"]
    assert plan.present and plan.for_hose_type("B").margin == 1.6


# -- a file that cannot be used: one line, no plan ------------------------------------------------------
def test_invalid_toml_is_one_line_and_no_plan(raw):
    plan = plan_of(raw, "[defaults]\nmargin = = 1.3\n")
    (line,) = lines(plan)
    assert line.startswith("plan.toml: invalid TOML: ") and "(at line 2" in line
    assert line.endswith("; the plan is not used: built-in defaults, the verdicts say `no plan`")
    assert not plan.present and values(plan.for_hose_type("A")) == BUILT_IN


def test_a_duplicated_key_is_invalid_toml(raw):
    plan = plan_of(raw, "[defaults]\nmargin = 1.3\nmargin = 1.4\n")
    assert not plan.present and len(plan.problems) == 1 and "invalid TOML" in plan.problems[0].error


def test_a_plan_over_the_size_limit_is_not_parsed(raw):
    plan = plan_of(raw, "[defaults]\n# " + "x" * MAX_RIG_BYTES + "\n")
    size = (raw.root / "plan.toml").stat().st_size
    assert lines(plan) == [f"plan.toml: {size} bytes, larger than the {MAX_RIG_BYTES} bytes a plan.toml may have; "
                           "the plan is not used: built-in defaults, the verdicts say `no plan`"]
    assert not plan.present


def test_a_plan_named_in_another_case_is_one_line_and_no_plan(raw):
    raw.write("Plan.toml", "[defaults]\nmargin = 1.3\n")
    tree = RawTree(raw.root)
    plan = read_plan(tree)
    assert lines(plan) == ["Plan.toml: named `Plan.toml`: a plan.toml must be named `plan.toml` (lower case); "
                           "it is not read"]
    assert tree.problems == list(plan.problems) and not plan.present and plan.for_hose_type("A").margin == 1.25


# -- in a rebuild: the quarantine, the walk, the state ----------------------------------------------
def test_a_bad_key_is_one_quarantine_line_and_the_night_goes_on(tree, warehouse):
    tree.write("plan.toml", '[defaults]\nalpha = 0.05\n[hose_type."FLEXIGOM AIR"]\nmargin = "big"\n')
    q = rebuild_checked(tree, warehouse)
    assert q == {"plan.toml": [(None, '[hose_type."FLEXIGOM AIR"] margin: must be a number > 1, got "big"; '
                                      "using the default 1.25")]}
    assert query(warehouse, "SELECT role, status, quarantined FROM rebuild_inputs WHERE source_path = 'plan.toml'") == [
        ("plan", "new", True)]


def test_a_plan_linked_from_outside_raw_is_one_line_and_not_read(tree, warehouse, tmp_path):
    (tmp_path / "shared-plan.toml").write_text("[defaults]\nmargin = 1.3\n")
    os.symlink(tmp_path / "shared-plan.toml", tree.root / "plan.toml")
    q = rebuild_checked(tree, warehouse)
    assert q == {"plan.toml": [(None, f"symlink to a file outside raw/: {tmp_path / 'shared-plan.toml'}")]}
    plan = read_plan(RawTree(tree.root))
    assert not plan.present and plan.problems == () and "symlink to a file outside raw/" in plan.note


def test_only_the_plan_at_the_top_of_raw_is_a_side_file_one_deeper_is_one_line(tree, warehouse):
    tree.write("plan.toml", "[defaults]\nmargin = 1.3\n")
    tree.write("c1/plan.toml", "[defaults]\nmargin = 1.5\n")
    listing = walk_raw(tree.root)
    assert [p.relative_to(tree.root).as_posix() for p in listing.side] == ["plan.toml"]
    assert "plan.toml" not in {p.name for p in listing.runs + listing.ignored}
    q = rebuild_checked(tree, warehouse)
    assert q == {"c1/plan.toml": [(None, "a plan.toml is read only at the top of raw/ (raw/plan.toml); "
                                         "this one is not read")]}
    assert read_plan(RawTree(tree.root)).for_hose_type("A").margin == 1.3


def test_a_link_at_the_top_to_a_plan_deeper_down_is_read_under_its_own_name(tree):
    tree.write("c1/plan.toml", "[defaults]\nmargin = 1.5\n")
    os.symlink(tree.root / "c1" / "plan.toml", tree.root / "plan.toml")
    listing = walk_raw(tree.root)
    assert [p.relative_to(tree.root).as_posix() for p in listing.side] == ["plan.toml"] and not listing.skipped
    assert read_plan(RawTree(tree.root)).for_hose_type("A").margin == 1.5


# -- the digest the stages' cache keys take -------------------------------------------------------
def test_the_digest_follows_what_the_plan_says_not_its_comments(raw):
    a = plan_of(raw, "[defaults]\nmargin = 1.3\n")
    assert plan_of(raw, "# our plan\n[defaults]\nmargin = 1.3   # agreed\n").digest == a.digest
    assert plan_of(raw, "[defaults]\nmargin = 1.31\n").digest != a.digest
    assert plan_of(raw, '[defaults]\nmargin = 1.3\n[hose_type."A"]\n').digest != a.digest  # names a hose type
    assert plan_of(raw, "[defaults]\n").digest != a.digest
    assert Plan().digest not in (a.digest, plan_of(raw, "[defaults]\n").digest)  # present or not
