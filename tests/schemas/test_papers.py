"""Every paper value and limit has one home, schemas/papers.py: each the one docs/physics.md marks
*paper*; the findings, the analyses and the report use it."""
from analyses import pla_spring, pressure_dynamics
from pipeline.stages import findings
from schemas import papers
from schemas.papers import (PLA_NRMSE_LIMIT_PCT, PLA_TABLE1, PLA_TABLE2, PLA_TABLE3_NRMSE_MAX_PCT,
                            PLA_TABLE3_NRMSE_MIN_PCT, PLPA_FIG12, PLPA_FIG15, PLPA_TABLE2)
from tests.conftest import PROJECT_ROOT


def _sci(value: float) -> str:
    """1.541e-3 as docs/physics.md writes it."""
    mantissa, exponent = f"{value:.3e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def test_the_reports_paper_values_are_those_docs_physics_marks_paper():
    doc = " ".join((PROJECT_ROOT / "docs" / "physics.md").read_text(encoding="utf-8").split())
    t2 = PLPA_TABLE2
    assert f"wn = {t2['wn_rad_s']:g} rad/s, zeta = {t2['zeta']:g}, k = {t2['k_lin_m_v_s']:g} m/(V s) (*paper*)" in doc
    f12 = PLPA_FIG12
    assert f"Breakaway force {f12['mean_0bar_n']:g} N at 0 bar backpressure, {f12['mean_ge1bar_n']:g} N at >= 1 bar" in doc
    assert f12["ratio"] == f12["mean_0bar_n"] / f12["mean_ge1bar_n"] and f12["rate_slope"] == 0  # no rate effect
    f15 = PLPA_FIG15
    assert (f"about {f15['overshoot_pct']:g} % overshoot, about {f15['settling_time_s']:g} s to the 2 % band, "
            "zero steady-state error (*paper*)") in doc and f15["steady_state_error_mm"] == 0
    for chamber, t1 in PLA_TABLE1.items():
        assert (f"{chamber} n = {t1['n_polytropic']:g}, Ae = {_sci(t1['ae_m2'])} m2, eps = {_sci(t1['epsilon_m2'])} m2, "
                f"delta = {_sci(t1['delta_n_m'])} N/m") in doc
    charge, discharge = PLA_TABLE2["charge"], PLA_TABLE2["discharge"]
    assert charge["wn_rad_s"] == discharge["wn_rad_s"]
    assert (f"wn = {charge['wn_rad_s']:g} rad/s for charge and discharge, xi = {charge['zeta']:.2f} charge, "
            f"{discharge['zeta']:.2f} discharge (*paper*)") in doc
    assert (f"NRMSE of the fitted model {PLA_TABLE3_NRMSE_MIN_PCT:g}-{PLA_TABLE3_NRMSE_MAX_PCT:g} %, "
            f"all below {PLA_NRMSE_LIMIT_PCT:g} %") in doc


def test_the_papers_nrmse_limit_is_the_one_the_analyses_hold_their_fits_to():
    assert papers.PLA_NRMSE_LIMIT_PCT == 2.5
    assert pla_spring.NRMSE_LIMIT_PCT is papers.PLA_NRMSE_LIMIT_PCT
    assert pressure_dynamics.NRMSE_LIMIT_PCT is papers.PLA_NRMSE_LIMIT_PCT


def test_the_findings_cite_the_papers_and_keep_no_paper_value_of_their_own():
    assert findings.PLPA == f"PLPA: {papers.PLPA_CITATION}" and findings.PLA == f"PLA: {papers.PLA_CITATION}"
    assert papers.PLPA_BREAKAWAY_RATIO_BAND == (1.5, 2.5) and papers.PLPA_SPRING_FORCE_MAX_N == 1300.0
    for name in ("RATIO_BAND", "NRMSE_MAX_PCT", "SPRING_FORCE_MAX_N"):
        assert not hasattr(findings, name)
