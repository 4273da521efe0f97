"""Channel naming: non-canonical columns end in their unit; units of other dimensions."""
import pytest

from schemas.channels import COLUMN, noncanonical_column, other_dimension, unit_suffix


@pytest.mark.parametrize("name, unit, column", [
    ("valve_temp", "degC", "valve_temp_degc"),
    ("Oil Temp", "°C", "oil_temp_degc"),
    ("rel_humidity", "%", "rel_humidity_pct"),
    ("F", "g", "f_g"),
    ("a", "m/s^2", "a_m_s2"),
    ("f_cell", "N", "f_cell_n"),
    ("strain", "µm/m", "strain_um_m"),
    ("valve_temp_degc", "degC", "valve_temp_degc"),     # not suffixed twice
    ("status", None, "status"),
    ("status", "", "status"),
    ("3rd", "V", "c_3rd_v"),
])
def test_noncanonical_column(name, unit, column):
    assert noncanonical_column(name, unit) == column


def test_noncanonical_column_never_shadows_a_canonical_column():
    # `x` in `m` would be x_m, the canonical position column: prefixed instead
    assert noncanonical_column("x_", "m") not in COLUMN.values()
    assert noncanonical_column("p_a", "pa") == "x_p_a_pa"


def test_unit_suffix_is_a_clean_identifier():
    assert unit_suffix("kg/s") == "kg_s"
    assert unit_suffix(" [bar] ") == "bar"
    assert unit_suffix(None) == ""


@pytest.mark.parametrize("unit, other", [("g", True), ("m/s2", True), ("degC", True), ("%", True), ("Hz", True),
                                         ("N", False), ("bar", False), ("furlong", False), (None, False)])
def test_other_dimension(unit, other):
    assert other_dimension(unit) is other
