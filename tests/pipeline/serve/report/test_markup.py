"""The report's text: numbers to significant digits, a column's name and unit."""


def test_numbers_have_sensible_significant_figures():
    from pipeline.serve.report.markup import fmt, split_unit

    assert fmt(19.999999999999982) == "20"
    assert fmt(0.0001541) == "1.541e-04" and fmt(0.001541) == "0.001541" and fmt(3509.0) == "3509"
    assert fmt(1.976126054271789) == "1.976" and fmt(174544) == "174544" and fmt(float("nan")) == "—"
    assert split_unit("leak_l_min") == ("leak", "l/min") and split_unit("viscous_n_s_m") == ("viscous", "N s/m")
    assert split_unit("p0_bar_abs") == ("p0", "bar abs") and split_unit("hose_id") == ("hose id", "")
