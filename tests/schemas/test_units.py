import numpy as np
import pytest

from schemas.units import (L_MIN_M3_S, RHO_ANR_KG_M3, RHO_DIN1343_KG_M3, accepted_symbols, kg_s_to_l_min_anr,
                           lookup_unit)


@pytest.mark.parametrize("text, raw, si", [
    ("bar", 2.5, 2.5e5), ("mbar", 250.0, 2.5e4), ("kPa", 250.0, 2.5e5), ("MPa", 0.25, 2.5e5),
    ("psi", 1.0, 6894.757293168361), ("barg", 2.0, 2e5), ("bar(g)", 2.0, 2e5), ("Pa", 7.0, 7.0),
    ("ms", 1500.0, 1.5), ("us", 2e6, 2.0), ("mm", 12.5, 0.0125), ("um", 5.0, 5e-6),
    ("kN", 1.2, 1200.0), ("mV", 250.0, 0.25), ("g/s", 3.0, 3e-3),
])
def test_gauge_and_plain_units_convert_to_si(text, raw, si):
    assert lookup_unit(text).to_si(raw) == pytest.approx(si, rel=1e-12)


@pytest.mark.parametrize("text", ["bara", "bar(a)", "kPa(a)", "Pa(a)"])
def test_absolute_pressures_become_gauge_with_the_runs_atmosphere(text):
    unit = lookup_unit(text)
    scale = {"bara": 1e5, "bar(a)": 1e5, "kPa(a)": 1e3, "Pa(a)": 1.0}[text]
    assert unit.absolute
    assert unit.to_si(300000.0 / scale, p_atm_pa=98000.0) == pytest.approx(202000.0)


def test_flow_units_use_their_reference_densities():
    # 1 l/min ANR = 1e-3/60 m3/s * 1.185 kg/m3; Nl/min uses 1.293 kg/m3 (DIN 1343)
    assert lookup_unit("l/min").to_si(1.0) == pytest.approx(1e-3 / 60 * 1.185)
    assert lookup_unit("Nl/min").to_si(1.0) == pytest.approx(1e-3 / 60 * 1.293)
    q = lookup_unit("Nl/min").to_si(np.array([10.0]))
    assert kg_s_to_l_min_anr(q)[0] == pytest.approx(10.0 * RHO_DIN1343_KG_M3 / RHO_ANR_KG_M3)
    assert L_MIN_M3_S * RHO_ANR_KG_M3 == lookup_unit("l/min").scale


def test_unit_spelling_tolerance_and_refusals():
    assert lookup_unit("[bar]").symbol == "bar"
    assert lookup_unit("KPA").symbol == "kPa"
    assert lookup_unit("L/min").symbol == "l/min"
    assert lookup_unit("MPA").symbol == "MPa"
    assert lookup_unit("BAR(A)").symbol == "bar(a)"
    # milli and mega differ by case alone: a wrong case there is refused, not guessed
    for wrong in ("mPa", "MV", "Mm", "Ms", "Mbar", "M", "MS"):
        assert lookup_unit(wrong) is None, wrong
    assert lookup_unit("furlong") is None
    assert lookup_unit("") is None
    assert "bar(a)" in accepted_symbols("pressure")


# -- issue 25 item 10: one display convention for people, SI in storage -------------------------------
def test_display_convention_bar_mm_l_min_from_si_columns():
    from schemas.units import to_display

    v, name, unit = to_display("p_a_pa", np.array([2.5e5, -1e4]))
    assert (name, unit) == ("p_a", "bar (gauge)") and v.tolist() == [2.5, -0.1]
    v, name, unit = to_display("x_m", np.array([0.0125]))
    assert (name, unit) == ("x", "mm") and v[0] == pytest.approx(12.5)
    v, name, unit = to_display("q_leak_kg_s", np.array([L_MIN_M3_S * RHO_ANR_KG_M3]))
    assert (name, unit) == ("q_leak", "l/min (ANR)") and v[0] == pytest.approx(1.0)
    assert to_display("f_n", 3.0) == (3.0, "f", "N") and to_display("t_s", 7.0) == (7.0, "t", "s")
    # a velocity ends in _s but is no time, a column without unit keeps its name
    assert to_display("v_m_s", 0.1) == (0.1, "v", "m/s") and to_display("hose_id", "H1") == ("H1", "hose_id", "")


def test_one_unit_table_for_describe_and_the_report():
    import pipeline.serve.catalogue as q
    import pipeline.serve.report.markup as r
    from schemas.units import COLUMN_UNITS

    assert q.unit_of("leak_l_min") == "l/min (ANR)" and r.split_unit("leak_l_min") == ("leak", "l/min")
    assert q.unit_of("mass_kg") == "kg" and r.split_unit("mass_kg") == ("mass", "kg")  # once only in query's
    assert all(r.split_unit("x" + s)[1] == u[1] for s, u in COLUMN_UNITS.items())


def test_sensors_text_reads_in_display_units():
    from schemas.units import display_sensors_text

    q_res = 0.01 * L_MIN_M3_S * RHO_ANR_KG_M3  # 0.01 l/min ANR in kg/s
    text = f"p_supply: resolution 100, noise 40 (metadata) Pa; q_leak: resolution {q_res!r}, noise 0 (estimated) kg/s"
    assert display_sensors_text(text) == ("p_supply: resolution 0.001 bar, noise 0.0004 bar (metadata); "
                                          "q_leak: resolution 0.01 l/min, noise 0 l/min (estimated)")
    # what does not read that way stays as it is
    assert display_sensors_text("hand-made note; x: resolution 1, noise 2 (metadata) furlong") == \
        "hand-made note; x: resolution 1, noise 2 (metadata) furlong"
