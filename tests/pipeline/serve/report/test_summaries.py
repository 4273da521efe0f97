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
    # the hose checks' plateaus copied into hose_leak_growth (no sensors there) read by their run's floor too
    growth = html[html.index('id="raw-hose_leak_growth"'):]
    t = growth[growth.index("<table>"):growth.index("</table>")]
    heads = [re.sub(r"<[^>]+>", " ", h).split()[0] for h in re.findall(r"<th>(.*?)</th>", t, flags=re.S)]
    cells = [r[heads.index("leak")] for r in table_cells(t)]
    assert not any(c.startswith("-") for c in cells) and any(c.startswith("&lt; ") for c in cells), cells
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


def _service_life_db(columns=None):
    """An in-memory database with the durability stage's service_life of two hose types (one with a
    single failure) at the plan's B5 and a 500 km mission."""
    import duckdb
    import pandas as pd

    from pipeline.raw.plan import Plan
    from pipeline.stages.durability import service_life

    life = pd.DataFrame({"hose_type": ["A"] * 7 + ["B"] * 3, "adjustment": ["force"] * 7 + ["distance"] * 3,
                         "distance_km": [412.0, 655.3, 760.0, 998.1, 1210.4, 1300.0, 1300.0, 100.0, 200.0, 300.0],
                         "status": ["failed"] * 5 + ["removed"] * 2 + ["failed", "running", "running"]})
    plan = Plan(present=True, defaults={"b_life": 5, "mission_km": 500.0})
    df = service_life(life, plan)
    if columns is not None:
        df = df[list(columns)]
    con = duckdb.connect()
    con.execute("CREATE TABLE service_life AS SELECT * FROM df")
    return con


def test_service_life_shows_the_fit_with_its_bounds_and_the_plans_b_life_and_mission():
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.summaries import SERVICE_LIFE_FIT, SERVICE_LIFE_LIFE, summary_service_life

    html = summary_service_life(ReportDB(_service_life_db()))
    fit_t, life_t = re.findall(r"<table>(.*?)</table>", html, flags=re.S)
    heads = [" ".join(re.sub(r"<[^>]+>", " ", h).split()) for h in re.findall(r"<th>(.*?)</th>", fit_t, flags=re.S)]
    assert heads == [c.replace("_km", " [km]").replace("_", " ") for c in SERVICE_LIFE_FIT if c != "campaigns"]
    assert heads[10] == "scale upper [km]"                              # the unit from the suffix
    a, b = table_cells(fit_t)
    assert a[:5] == ["A", "force", "7", "5", "2"] and a[13] == "MRR" and b[13] == "—"
    assert b[5] == "—" and b[-1] == "too few failures: 1 &lt; 2"        # NULL fit, the note why
    # one number format per column, the bounds around their estimate
    for j in range(5, 13):
        assert len({_number_format(c) for c in (a[j], b[j]) if _number_format(c)}) <= 1
    assert float(a[6]) < float(a[5]) < float(a[7]) and float(a[9]) < float(a[8]) < float(a[10])
    life_heads = [" ".join(re.sub(r"<[^>]+>", " ", h).split()) for h in re.findall(r"<th>(.*?)</th>", life_t, flags=re.S)]
    assert life_heads == [c.replace("_km", " [km]").replace("_pct", " [%]").replace("_", " ") for c in SERVICE_LIFE_LIFE]
    a, b = table_cells(life_t)
    assert a[2:4] == ["0.9", "5"] and a[8] == "500" and float(a[10]) < float(a[9]) < float(a[11])
    assert "profile likelihood" in html and "Abernethy 2006" in html


def test_a_warehouse_from_before_the_plans_b_life_shows_its_b10_table():
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.summaries import SERVICE_LIFE_BEFORE, summary_service_life

    html = summary_service_life(ReportDB(_service_life_db([c for c in SERVICE_LIFE_BEFORE if c != "campaigns"])))
    assert html.count("<table>") == 1 and "Weibull life and B10" in html and "b10 lower" in html


def test_the_steady_state_error_is_uncertain_by_the_position_resolution_however_many_steps():
    """Six identical steps have no spread; their mean is still uncertain by the encoder's count
    (resolution / sqrt(12), GUM F.2.2.1), combined in quadrature with the steps' standard error."""
    import math

    import duckdb

    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.summaries import summary_step

    con = duckdb.connect()
    con.execute("CREATE TABLE step_response (overshoot_pct DOUBLE, settling_time_s DOUBLE, "
                "steady_state_error_mm DOUBLE, position_resolution_mm DOUBLE, step_mm DOUBLE)")
    con.execute("INSERT INTO step_response VALUES (1.0, 4.0, -0.005, 0.005, 20), (1.0, 4.0, -0.005, 0.005, -20), "
                "(1.2, 4.2, -0.004, 0.005, 20), (1.2, 4.2, -0.004, 0.005, -5)")
    rows = {r[0]: r for r in table_cells(summary_step(ReportDB(con)))}
    sse = rows["steady-state error"]
    se = math.sqrt(sum((x + 0.0045) ** 2 for x in (-0.005, -0.005, -0.004, -0.004)) / 3) / 2  # 0.00029 mm
    u = math.sqrt(se ** 2 + 0.005 ** 2 / 12)                  # 0.00150 mm: the count dominates the spread
    assert sse[3] == f"-0.0045 ± {float(f'{u:.2g}'):g}" == "-0.0045 ± 0.0015"
    assert "resolution 5 µm as resolution/√12" in sse[5]
    # the overshoot: the resolution in % of the smallest step (5 um of 5 mm: 0.1 %), the settling time: the s.e.
    u_os = math.sqrt((0.2 / math.sqrt(3) / 2) ** 2 + (0.1 / math.sqrt(12)) ** 2)  # 0.0645 %
    assert rows["overshoot"][3] == f"1.1 ± {float(f'{u_os:.2g}'):g}" == "1.1 ± 0.065"
    assert "resolution 5 µm" in rows["overshoot"][5]
    assert rows["settling time (2 % band)"][3] == "4.1 ± 0.058" and rows["settling time (2 % band)"][5] == "mean of 4 steps ± s.e."
    # a warehouse from before the column: the standard error alone, and the caption says so
    con.execute("ALTER TABLE step_response DROP COLUMN position_resolution_mm")
    rows = {r[0]: r for r in table_cells(summary_step(ReportDB(con)))}
    assert rows["steady-state error"][3] == "-0.0045 ± 2.9e-04" and rows["overshoot"][3] == "1.1 ± 0.058"
    assert "resolution not known: not included" in rows["steady-state error"][5]
