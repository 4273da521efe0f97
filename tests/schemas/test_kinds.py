import pyarrow as pa
import pytest

from schemas.channels import COLUMN, sanitise_name
from schemas.kinds import KINDS, coerce_value, missing_channels, missing_metadata, samples_schema


def test_every_kind_of_the_spec_is_declared():
    assert set(KINDS) == {"leakage", "breakaway", "viscous", "identification", "step", "spring",
                          "pressure_step", "durability", "timeseries"}


def test_viscous_accepts_pressures_or_a_force():
    assert missing_channels("viscous", {"t", "x", "f"}) == []
    assert missing_channels("viscous", {"t", "x", "p_a", "p_b"}) == []
    assert missing_channels("viscous", {"t", "x", "p_a"}) == ["p_b"]


def test_conditional_metadata():
    base = {"kind": "leakage", "run_id": "r", "started_at": "x", "rig": "r", "chamber": "A"}
    assert missing_metadata("leakage", {**base, "adjustment": "force"}, set()) == ["spring_force_n"]
    assert missing_metadata("leakage", {**base, "adjustment": "distance"}, set()) == ["z_rollers_mm"]
    vbase = {"kind": "viscous", "run_id": "r", "started_at": "x", "rig": "r", "backpressure_bar": 1.0}
    assert missing_metadata("viscous", vbase, {"t", "x", "p_a", "p_b"}) == ["hose_area_m2"]
    assert missing_metadata("viscous", vbase, {"t", "x", "f"}) == []


def test_coercion():
    assert coerce_value("backpressure_bar", "1,5") == 1.5
    assert coerce_value("chamber", "a") == "A"
    assert coerce_value("chamber", "Front") == "front"
    assert coerce_value("hose_id", 7.0) == "7"
    with pytest.raises(ValueError, match="backpressure_bar"):
        coerce_value("backpressure_bar", "high")
    with pytest.raises(ValueError, match="one of P, N"):
        coerce_value("direction", "up")


def test_samples_schema_carries_units():
    schema = samples_schema(["x", "t", "p_a"], [("temp", "degC")])
    assert schema.names == ["run_id", "t_s", "p_a_pa", "x_m", "temp"]
    assert schema.field("p_a_pa").metadata[b"unit"] == b"Pa"
    assert schema.field("temp").metadata[b"unit"] == b"degC"
    assert schema.field("t_s").type == pa.float64()


def test_sanitised_names_never_shadow_canonical_columns():
    assert sanitise_name("Valve Temp (°C)") == "valve_temp_c"
    assert sanitise_name("x_m") == "x_x_m"
    assert sanitise_name("kind") == "x_kind"
    assert sanitise_name("3rd") == "c_3rd"
    assert COLUMN["q_leak"] == "q_leak_kg_s"


def test_p0_bar_abs_is_typed_whatever_the_source():
    assert coerce_value("p0_bar_abs", "3,0") == 3.0


def test_a_metadata_number_that_reads_two_ways_is_refused():
    """`1,250` was read as 1.25 (decimal comma) though it may be 1250 with a thousands separator
    (issue 21, item 16, for metadata); `1,5`, `0,250` and `1250` read one way only."""
    for text in ("1,250", "12,500"):
        with pytest.raises(ValueError, match=r"reads as .* with a decimal comma or .* with a thousands separator"):
            coerce_value("force_rate_n_s", text)
    with pytest.raises(ValueError, match=r"'1,250,000' has thousands separators: .* \(1250000\)"):
        coerce_value("force_rate_n_s", "1,250,000")
    assert [coerce_value("force_rate_n_s", t) for t in ("1,5", "0,250", "1250", "1.250")] == [1.5, 0.25, 1250.0, 1.25]
