"""The decision section's "Running hoses" and the verdict under other failure definitions, on the
hand-made warehouse of ``tests/pipeline/serve/test_remaining_life.py`` (the contract's tables), in
the page and in headless chromium."""
from __future__ import annotations

import base64
import io
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from pipeline.serve.door import connect_readonly  # noqa: E402
from pipeline.serve.remaining_life import NOT_COMPUTED, read_running  # noqa: E402
from pipeline.serve.report import running_hoses as rh  # noqa: E402
from pipeline.serve.report.db import ReportDB  # noqa: E402
from pipeline.serve.report.markup import esc  # noqa: E402
from pipeline.serve.report.render import render_report  # noqa: E402
from tests.pipeline.serve.report.conftest import console_lines, needs_chromium, run_chromium  # noqa: E402
from tests.pipeline.serve.test_decision import DECIDED, OPEN, make_warehouse  # noqa: E402
from tests.pipeline.serve.test_remaining_life import FALLING, FEW, UNSET, make_rul_warehouse  # noqa: E402


@pytest.fixture
def wh(tmp_path):
    return make_rul_warehouse(tmp_path / "wh")


def _part(page: str) -> str:
    i = page.index('<h3 id="running-hoses">')
    return page[i:min(page.index(end, i) for end in ("</section>", '<figure id="decision-looks-') if end in page[i:])]


def _tables(part: str) -> dict[str, list[str]]:
    """Per group heading, the rows of its table as HTML."""
    out = {}
    for head, body in re.findall(r"<h4>(.*?)</h4>.*?<tbody>(.*?)</tbody>", part, flags=re.S):
        out[head] = re.findall(r"<tr>(.*?)</tr>", body, flags=re.S)
    return out


def _cells(row: str) -> list[str]:
    return [re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", row, flags=re.S)]


def _png(src: str):
    return plt.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])), format="png")[..., :3]


def _pixels(img, colour: str) -> int:
    rgb = [int(rh.COLOURS[colour][i:i + 2], 16) / 255 for i in (1, 3, 5)]
    return int((abs(img - rgb) < 0.12).all(axis=-1).sum())


def test_running_hoses_per_type_and_adjustment_nearest_their_end_first(wh):
    page = render_report(wh)
    part = _part(page)
    assert page.index('id="decision"') < page.index('id="running-hoses"') < page.index('id="decision-looks-1"')
    assert "5 running hoses, nearest their end first" in part and "90 % prediction interval" in part
    tables = _tables(part)
    assert list(tables) == [f"{DECIDED}, distance-set: 2 running", f"{DECIDED}, force-set: 2 running",
                            f"{OPEN}, force-set: 1 running"]
    d1, d2 = (_cells(r) for r in tables[f"{DECIDED}, distance-set: 2 running"])
    assert d1[:5] == ["D1", "600", "200 km [40-700]", "260 km [180-390]", "1.1 / 2 l/min" + "at 6 bar, 5 points"]
    assert d2[:4] == ["D2", "50", "—", "—"] and d2[-1] == esc(f"weibull: fewer than two failures of its type; "
                                                             f"degradation: {FALLING}")
    f1, f2 = (_cells(r) for r in tables[f"{DECIDED}, force-set: 2 running"])
    assert f1[0] == "F1" and f2[0] == "F2" and f2[3] == "—" and f2[-1] == f"degradation: {FEW}"
    assert f2[5] == "no leak point at the plan's pressure"
    (p1,) = (_cells(r) for r in tables[f"{OPEN}, force-set: 1 running"])
    assert p1[4] == "no limit in plan.toml" and p1[5] == "no leak pressure in plan.toml"
    assert p1[-1] == f"degradation: {UNSET}"
    # the backtest under each method's name, of that hose type and adjustment
    heads = re.findall(r"<thead>(.*?)</thead>", part, flags=re.S)
    assert "backtest: 75 % of 12 intervals held (nominal 90 %)" in heads[0]
    assert "backtest: no interval to check (no failed hose with 3 leak points)" in heads[0]
    assert ('weibull<br><small>remaining km</small><br><span class="meta" style="font-weight:400">backtest: 86 % of 40 '
            'intervals held (nominal 90 %)</span></th><th>degradation<br><small>remaining km</small><br><span '
            'class="meta" style="font-weight:400">backtest: 92 % of 36') in heads[1]
    assert "backtest: 100 % of 8 intervals held" in heads[2]


def test_a_leak_path_per_hose_with_its_limit_and_predicted_crossing(wh):
    part = _part(render_report(wh))
    imgs = dict(re.findall(r'<img class="leakpath" alt="leak path of ([^"]+)" width="360" height="190" '
                           r'src="(data:image/png;base64,[^"]+)"', part))
    assert sorted(imgs) == ["D1", "D2", "F1"]  # F2: no point at 6 bar; P1: no pressure in the plan
    f1 = _png(imgs["F1"])
    assert f1.shape[:2] == (190, 360)  # drawn at the size it is shown
    for colour in ("path", "limit", "crossing"):
        assert _pixels(f1, colour) > 25, colour
    assert _pixels(_png(imgs["D2"]), "crossing") == 0  # no degradation prediction: no crossing drawn
    con = connect_readonly(wh)
    try:
        f1_hose = next(h for h in read_running(con) if h.hose_id == "F1")
    finally:
        con.close()
    assert rh.leak_png([(50.0, 0.1), (400.0, 0.8)], f1_hose) == rh.leak_png([(50.0, 0.1), (400.0, 0.8)], f1_hose)
    assert rh.leak_png([], f1_hose) is None


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_an_unchanged_hose_s_leak_path_is_taken_and_the_incremental_report_equals_full(wh, monkeypatch):
    """Each leak-path plot is keyed by its own inputs: the next report takes an unchanged hose's plot
    from the live one, draws the hose whose leak path changed alone, and its files equal a ``--full``
    report's byte for byte."""
    from datetime import datetime, timezone

    import duckdb

    from pipeline.serve.report.render import stage_report, write_report
    from pipeline.warehouse import DB_NAME

    now = datetime(2026, 11, 26, 6, 0, tzinfo=timezone.utc)
    write_report(wh, now=now)
    drawn = []
    real = rh.leak_png
    monkeypatch.setattr(rh, "leak_png", lambda points, h: drawn.append(h.hose_id) or real(points, h))
    same = stage_report(wh, now=now)
    assert drawn == [] and _files(same) == _files(wh / "report")
    con = duckdb.connect(str(wh / DB_NAME))
    con.execute("UPDATE hose_leak_growth SET leak_l_min = leak_l_min * 1.1 WHERE hose_id = 'D1'")
    con.close()
    incremental = stage_report(wh, now=now)
    assert drawn == ["D1"]
    full = stage_report(wh, run_pages="all", now=now)
    assert sorted(drawn) == ["D1", "D1", "D2", "F1"]
    assert _files(incremental) == _files(full) and _files(full) != _files(same)


def test_the_plots_are_capped_nearest_their_end_first(wh, monkeypatch):
    monkeypatch.setattr(rh, "MAX_LEAK_PLOTS", 2)
    con = connect_readonly(wh)
    try:
        part = rh.running_section(ReportDB(con))
    finally:
        con.close()
    assert re.findall(r'alt="leak path of ([^"]+)"', part) == ["D1", "F1"]
    assert part.count("not drawn (see below)") == 3
    assert "Leak paths drawn for the 2 hoses nearest their end; 3 more listed without one" in part


def test_the_verdict_under_each_failure_definition_flips_highlighted(wh):
    page = render_report(wh)
    sec = page[page.index('<section id="decision">'):page.index('<h3 id="running-hoses">')]
    tables = re.findall(r'<tr class="sensitivity">.*?<tbody>(.*?)</tbody>', sec, flags=re.S)
    assert len(tables) == 2  # FLEXIGOM AIR and PU 8x6; none for the hose types without rows
    rows = re.findall(r'<tr class="(\w+)"( style="[^"]*")?>(.*?)</tr>', tables[0], flags=re.S)
    assert [(_cells(r[2])[0], r[0]) for r in rows] == [("logbook", "same"), ("leak limit", "same"),
                                                       ("leak limit x0.5", "flipped"), ("leak limit x2", "same")]
    flipped = _cells(rows[2][2])
    assert rows[2][1] == ' style="background:#ffe9b3"'
    assert flipped[1:5] == ["1 l/min at 6 bar", "6 of 10 / 8 of 10", "1.3x (90 % CI 0.9-1.9x)",
                            "undecided ⚠ differs from the logbook"]
    assert sec.count("differs from the logbook") == 1
    unset = [_cells(r) for r in re.findall(r"<tr[^>]*>(.*?)</tr>", tables[1], flags=re.S)]
    assert unset[0][4] == "undecided" and [u[4] for u in unset[1:]] == ["—"] * 3 and unset[1][5] == UNSET
    assert [u[1] for u in unset] == ["as logged", "—", "—", "—"]
    # the sensitivity sits right under its hose type's verdict row
    assert sec.index(f"<td><b>{DECIDED}</b>") < sec.index('<tr class="sensitivity">') < sec.index("<td><b>NBR")


def test_an_older_warehouse_says_remaining_life_not_computed(tmp_path):
    part = _part(render_report(make_warehouse(tmp_path / "old")))
    assert part == f'<h3 id="running-hoses">Running hoses</h3><p class="nodata">{esc(NOT_COMPUTED)}</p>'
    empty = _part(render_report(make_rul_warehouse(tmp_path / "empty", {})))
    assert "no running hose" in empty


@needs_chromium
def test_running_hoses_in_headless_chromium(wh, tmp_path):
    index = tmp_path / "index.html"
    index.write_text(render_report(wh), encoding="utf-8")
    probe = ("<script>addEventListener('load',()=>{document.body.insertAdjacentHTML('beforeend','<pre id=m>'+"
             "[...document.querySelectorAll('img.leakpath')].map(i=>i.naturalWidth+'x'+i.width).join(' ')+'|'+"
             "getComputedStyle(document.querySelector('tr.flipped')).backgroundColor+'</pre>')})</script>")
    copy = tmp_path / "probe.html"
    copy.write_text(index.read_text(encoding="utf-8").replace("</body>", probe + "</body>"), encoding="utf-8")
    res = run_chromium(copy.as_uri(), "--dump-dom", size=(1280, 1600))
    imgs, flipped = re.search(r'<pre id="m">(.*?)</pre>', res.stdout, flags=re.S).group(1).split("|")
    assert imgs.split() == ["360x360"] * 3  # every plot at its drawn size: as readable as the table
    assert flipped == "rgb(255, 233, 179)"
    res = run_chromium(index.as_uri(), "--dump-dom", size=(1280, 1600))
    assert console_lines(res) == []


def test_a_leak_now_under_the_flow_sensors_floor_reads_under_it_as_the_leak_tables_do(wh):
    """F2's leak now (0.05 l/min) is under the floor of the flow sensor of its leakage runs
    (leakage_map.sensors, 0.06 l/min here): it reads "< 0.06", by the tables' own rule; F1 (0.8
    l/min, the same sensor) and D1 (no leakage_map rows) show their values."""
    import duckdb

    from pipeline.serve.report.tables import flow_floor_l_min
    from pipeline.warehouse import DB_NAME

    coarse = "q_leak: resolution 1.98e-08, noise 1.2e-06 (estimated) kg/s"
    assert 0.05 < flow_floor_l_min(coarse) < 0.8
    con = duckdb.connect(str(wh / DB_NAME))
    con.execute("CREATE TABLE leakage_map (run_id VARCHAR, hose_id VARCHAR, chamber VARCHAR, adjustment VARCHAR, "
                "z_rollers_mm DOUBLE, spring_force_n DOUBLE, pressure_bar DOUBLE, leak_l_min DOUBLE, sensors VARCHAR)")
    con.execute("INSERT INTO leakage_map VALUES ('F2-L0', 'F2', 'A', 'force', NULL, 858, 6, 0.05, ?), "
                "('F1-L0', 'F1', 'A', 'force', NULL, 858, 6, 0.8, ?)", [coarse, coarse])
    con.close()
    tables = _tables(_part(render_report(wh)))
    f1, f2 = (_cells(r) for r in tables[f"{DECIDED}, force-set: 2 running"])
    assert f2[4] == "&lt; 0.06 / 2 l/min" + "at 6 bar, 2 points"
    assert f1[4].startswith("0.8 / 2 l/min")
    d1 = _cells(tables[f"{DECIDED}, distance-set: 2 running"][0])
    assert d1[4] == "1.1 / 2 l/min" + "at 6 bar, 5 points"
