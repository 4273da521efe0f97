"""The summaries: one format per column, leaks under the floor, the papers cited by name."""
import re

from tests.pipeline.serve.report.conftest import table_cells


def _number_format(cell: str) -> str | None:
    """'sci', 'fixed<decimals>', or None for a cell that is no plain number ("< 0.02", text, a dash)."""
    if re.fullmatch(r"-?\d\.\d+e[+-]\d+", cell):
        return "sci"
    m = re.fullmatch(r"-?\d+(?:\.(\d+))?", cell)
    return None if m is None else f"fixed{len(m.group(1) or '')}"


def test_demo_report_columns_floors_figures_and_citations(demo):
    from schemas.papers import PLA_CITATION, PLPA_CITATION

    html = (demo["warehouse"] / "report" / "index.html").read_text()
    # every table but the papers' comparisons: a column of numbers keeps one format
    for table in re.findall(r"<table>(.*?)</table>", html, flags=re.S):
        heads = [re.sub(r"<[^>]+>", " ", h).split()[0:3] for h in re.findall(r"<th>(.*?)</th>", table, flags=re.S)]
        rows = table_cells(table)
        for j, head in enumerate(heads):
            kinds = {k for r in rows if j < len(r) and (k := _number_format(r[j])) is not None}
            assert len(kinds) <= 1, (head, kinds, [r[j] for r in rows][:12])
    # the leakage summary and rows: no negative leak, the tiny ones read "< floor"
    leak = html[html.index('<section id="leakage">'):html.index('<section id="breakaway">')]
    t = leak[leak.index("<table>"):leak.index("</table>")]
    heads = [re.sub(r"<[^>]+>", "", h) for h in re.findall(r"<th>(.*?)</th>", t, flags=re.S)]
    leak_cols = [j for j, h in enumerate(heads) if h.startswith("leak at")]
    cells = [r[j] for r in table_cells(t) for j in leak_cols]
    assert leak_cols and not any(c.startswith("-") for c in cells), cells
    assert any(c.startswith("&lt; ") for c in cells) and not any("e-" in c for c in cells), cells
    # figures one per row, no empty "Other figures", the papers cited by name (from one place in the code)
    assert 'class="pair"' not in html and "Other figures" not in html
    assert "seed 00" not in html
    assert PLPA_CITATION in html and PLA_CITATION in html
    assert PLPA_CITATION == "Carneiro et al. 2020, Information 11(2):76"
    assert PLA_CITATION == "Palomares et al. 2017, Mechatronics 45"


def test_the_spring_tests_at_or_above_the_papers_nrmse_bound_are_counted_with_the_named_limit():
    import duckdb

    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.summaries import summary_spring
    from schemas.papers import PLA_NRMSE_LIMIT_PCT, PLA_TABLE3_NRMSE_MAX_PCT, PLA_TABLE3_NRMSE_MIN_PCT

    con = duckdb.connect()
    con.execute("CREATE TABLE spring_tests (chamber VARCHAR, nrmse_pct DOUBLE)")
    con.execute("INSERT INTO spring_tests VALUES ('front', 1.2), ('front', ?), ('front', 3.1), ('rear', NULL)",
                [PLA_NRMSE_LIMIT_PCT])
    html = summary_spring(ReportDB(con))
    assert "PLA Table 3" in html and "PLA Table 1" not in html  # no spring_fits: no Table 1
    assert f"2 of 3 tests at or above {PLA_NRMSE_LIMIT_PCT:g} % (the paper&#x27;s bound)" in html  # escaped
    assert "0 of 0 tests at or above" in html
    rows = {r[0]: r for r in table_cells(html)}
    assert rows["front: smallest NRMSE"][2:4] == [f"{PLA_TABLE3_NRMSE_MIN_PCT:g}", "1.2"]
    assert rows["front: largest NRMSE"][2:4] == [f"{PLA_TABLE3_NRMSE_MAX_PCT:g}", "3.1"]
