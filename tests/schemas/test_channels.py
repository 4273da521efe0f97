"""Channel naming: non-canonical columns end in their unit; units of other dimensions."""
import pytest

from schemas.channels import COLUMN, VIEW_COLUMNS, noncanonical_column, other_dimension, reserved_clash, unit_suffix


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


@pytest.mark.parametrize("name, unit, column, clash", [
    ("FileName", None, "x_filename", "filename"),   # DuckDB's file column, which the views join on
    ("Run ID", None, "x_run_id", "run_id"),
    ("kind", "", "x_kind", "kind"),
    ("x_", "m", "x_x_m", "x_m"),                    # a canonical column
    ("filename_2", None, "filename_2", None),       # the happy cases beside them
    ("x_kind", None, "x_kind", None),
    ("file", "name", "file_name", None),
    ("valve_temp", "degC", "valve_temp_degc", None),
])
def test_names_the_views_use_are_reserved_and_the_clash_is_named(name, unit, column, clash):
    assert noncanonical_column(name, unit) == column
    assert reserved_clash(name, unit) == clash
    assert not VIEW_COLUMNS & {column}


def test_unit_suffix_is_a_clean_identifier():
    assert unit_suffix("kg/s") == "kg_s"
    assert unit_suffix(" [bar] ") == "bar"
    assert unit_suffix(None) == ""


@pytest.mark.parametrize("unit, other", [("g", True), ("m/s2", True), ("degC", True), ("%", True), ("Hz", True),
                                         ("N", False), ("bar", False), ("furlong", False), (None, False)])
def test_other_dimension(unit, other):
    assert other_dimension(unit) is other
