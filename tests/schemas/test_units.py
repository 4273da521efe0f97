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
