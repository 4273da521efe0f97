"""Derived-channel expressions: what they compute, and what they refuse (rig.toml is untrusted)."""
import numpy as np
import pytest

from pipeline.ingest.derived import MAX_DEPTH, MAX_DERIVED, MAX_LENGTH, DerivedError, parse_expression
from tests.conftest import STEP_META
from tests.pipeline.ingest.helpers import T, VISCOUS, ingest, quarantine, samples_of


def test_force_balance_on_arrays_and_metadata():
    e = parse_expression("f_cell - p_b * hose_area_m2")
    assert e.names == ("f_cell", "p_b", "hose_area_m2")
    f_cell = np.array([10.0, 20.0, 30.0])
    p_b = np.array([1e5, 2e5, 0.0])
    out = e.evaluate({"f_cell": f_cell, "p_b": p_b, "hose_area_m2": 4.9e-4}, 3)
    np.testing.assert_allclose(out, f_cell - p_b * 4.9e-4)


@pytest.mark.parametrize("text, expected", [
    ("-(a - b) / 2", [-0.5, -1.0]),
    ("abs(b - a) * 2", [2.0, 4.0]),
    ("sqrt(a * a)", [1.0, 2.0]),
    ("a ** 2 + 1e-3", [1.001, 4.001]),
    ("max(a, 1.5) + min(b, 0)", [1.5, 2.0]),
    ("3", [3.0, 3.0]),              # a constant broadcasts to the batch
])
def test_valid_expressions(text, expected):
    a, b = np.array([1.0, 2.0]), np.array([0.0, 0.0])
    np.testing.assert_allclose(parse_expression(text).evaluate({"a": a, "b": b}, 2), expected)


def test_division_by_zero_gives_inf_not_an_exception():
    out = parse_expression("a / b").evaluate({"a": np.array([1.0]), "b": np.array([0.0])}, 1)
    assert np.isinf(out[0])


@pytest.mark.parametrize("text", [
    "__import__('os').system('true')",
    "os.system",
    "x.__class__",
    "(lambda: 1)()",
    "9**9**9",
    "2 ** x",
    "x ** 1000",
    "x[0]",
    "'abc'",
    "[x for x in y]",
    "open('/etc/passwd')",
    "x if y else z",
    "x < y",
    "x // 2",
    "x % 2",
    "True + x",
    "sqrt(*x)",
    "abs(x, y)",
    "_secret * 2",
    "x; y",
    "",
])
def test_hostile_or_unsupported_expressions_are_refused(text):
    with pytest.raises(DerivedError):
        parse_expression(text)


def test_deep_nesting_and_length_are_bounded():
    with pytest.raises(DerivedError, match="deeper"):
        parse_expression("(" * 200 + "x" + ")" * 200)
    with pytest.raises(DerivedError, match="deeper"):
        parse_expression("-" * (MAX_DEPTH + 5) + "x")
    with pytest.raises(DerivedError, match="longer"):
        parse_expression("x + " * (MAX_LENGTH // 4) + "x")
    # within the bounds it works
    assert parse_expression("-" * (MAX_DEPTH - 2) + "x").names == ("x",)


def test_non_text_and_unknown_names():
    with pytest.raises(DerivedError, match="text"):
        parse_expression(3.0)
    with pytest.raises(DerivedError, match="unknown `q`"):
        parse_expression("x + q").evaluate({"x": np.zeros(2)}, 2)


# -- derived channels of a run (plan_derived, through the ingest) ------------------------------
def test_derived_drive_force_lands_in_samples(raw, warehouse):
    raw.write("c/rig.toml", '[metadata]\nhose_area_m2 = 4.9e-4\n[derived]\nf = "f_cell - p_b * hose_area_m2"\n'
                            'f_net_kn = { expr = "f / 1000", unit = "kN" }\n')
    raw.csv("c/a.csv", VISCOUS, {"t[s]": T, "x[mm]": T, "f_cell[kN]": [0.1, 0.2, 0.3, 0.4], "p_b[bar]": [1, 1, 2, 2]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    # f_cell is not canonical: it enters the expression as recorded (kN); p_b in SI (Pa)
    expected = np.array([0.1, 0.2, 0.3, 0.4]) - np.array([1e5, 1e5, 2e5, 2e5]) * 4.9e-4
    np.testing.assert_allclose(table.column("f_n").to_numpy(), expected)
    np.testing.assert_allclose(table.column("f_net_kn").to_numpy(), expected / 1000)
    assert table.schema.field("f_n").metadata[b"unit"] == b"N"
    assert table.schema.field("f_net_kn").metadata[b"unit"] == b"kN"
    ch = {c["column"]: c for c in res.channels}
    assert ch["f_n"]["channel"] == "f" and ch["f_n"]["raw_name"] == "= f_cell - p_b * hose_area_m2"


def test_derived_channel_whose_inputs_are_absent_is_skipped_with_a_warning(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nload = { expr = "f_cell * 2", unit = "N" }\n')
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    res = ingest(raw, "c/a.csv", warehouse)
    assert "load_n" not in samples_of(res, warehouse).column_names
    assert any("derived channel `load` not computed: no channel or numeric metadata `f_cell`" in w
               for w in res.run["warnings"])


@pytest.mark.parametrize("toml, reason", [
    ('[derived]\nf = "__import__(\'os\').system(\'touch /tmp/pwned\')"\n', "may be called"),
    ('[derived]\nf = "x.__class__"\n', "Attribute not allowed"),
    ('[derived]\nf = "9**9**9"\n', "literal exponent"),
    ('[derived]\nx_ref = "x * 2"\n', "already has channel `x_ref`"),
    ('[derived]\nf = { expression = "x" }\n', "must be an expression or a table with `expr`"),
])
def test_q_hostile_or_conflicting_derived(raw, warehouse, toml, reason):
    raw.write("c/rig.toml", toml)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    err = quarantine(raw, warehouse)
    assert "rig.toml [derived]" in err and reason in err


def test_derived_never_reads_a_lookalike_as_the_canonical_channel(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nload = { expr = "f * 2", unit = "N" }\nacc = { expr = "f_g * 9.81", unit = "m/s2" }\n')
    raw.csv("c/a.csv", {**STEP_META, "kind": "timeseries"}, {"t[s]": T, "F[g]": [1.0, 2.0, 3.0, 4.0]})
    res = ingest(raw, "c/a.csv", warehouse)
    table = samples_of(res, warehouse)
    assert "load_n" not in table.column_names
    assert table.column("acc_m_s2").to_pylist() == pytest.approx([9.81, 19.62, 29.43, 39.24])
    assert any("`load` not computed: no channel or numeric metadata `f`" in w for w in res.run["warnings"])


def test_derived_time_from_a_non_canonical_clock(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nt = "clock_ms / 1000"\n')
    raw.csv("c/a.csv", STEP_META, {"clock[ms]": [10, 20, 30, 40], "x[m]": T, "x_ref[m]": T})
    table = samples_of(ingest(raw, "c/a.csv", warehouse), warehouse)
    assert table.column("t_s").to_pylist() == pytest.approx([0.01, 0.02, 0.03, 0.04])


def test_q_derived_time_and_a_stated_rate_conflict(raw, warehouse):
    raw.write("c/rig.toml", '[derived]\nt = "clock_ms / 1000"\n')
    raw.csv("c/a.csv", {**STEP_META, "sample_rate_hz": 100}, {"clock[ms]": [10, 20, 30, 40], "x[m]": T, "x_ref[m]": T})
    assert "rig.toml [derived] `t`: the file already has channel `t`" in quarantine(raw, warehouse)


def test_q_too_many_derived_channels(raw, warehouse):
    raw.write("c/rig.toml", "[derived]\n" + "".join(f'd{i} = "x * {i}"\n' for i in range(MAX_DERIVED + 1)))
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    assert f"at most {MAX_DERIVED}" in quarantine(raw, warehouse)
