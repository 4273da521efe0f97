"""Every paper value and limit has one home, schemas/papers.py: the findings and the analyses use it."""
from analyses import pla_spring, pressure_dynamics
from pipeline.stages import findings
from schemas import papers


def test_the_papers_nrmse_limit_is_the_one_the_analyses_hold_their_fits_to():
    assert papers.PLA_NRMSE_LIMIT_PCT == 2.5
    assert pla_spring.NRMSE_LIMIT_PCT is papers.PLA_NRMSE_LIMIT_PCT
    assert pressure_dynamics.NRMSE_LIMIT_PCT is papers.PLA_NRMSE_LIMIT_PCT


def test_the_findings_cite_the_papers_and_keep_no_paper_value_of_their_own():
    assert findings.PLPA == f"PLPA: {papers.PLPA_CITATION}" and findings.PLA == f"PLA: {papers.PLA_CITATION}"
    assert papers.PLPA_BREAKAWAY_RATIO_BAND == (1.5, 2.5) and papers.PLPA_SPRING_FORCE_MAX_N == 1300.0
    for name in ("RATIO_BAND", "NRMSE_MAX_PCT", "SPRING_FORCE_MAX_N"):
        assert not hasattr(findings, name)
