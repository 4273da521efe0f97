"""The report's first section, "The decision", on warehouses filled by hand with the contract's
tables (a decided hose type, an undecided one with its plan, one without plan.toml, one without
an estimate), in the page and in headless chromium."""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from pipeline.serve.door import connect_readonly  # noqa: E402
from pipeline.serve.decision import read_decisions  # noqa: E402
from pipeline.serve.report import decision as rd  # noqa: E402
from pipeline.serve.report.looks_svg import COLOURS  # noqa: E402
from pipeline.stages.decision import AFTER_VERDICT  # noqa: E402
from pipeline.serve.report.db import ReportDB  # noqa: E402
from pipeline.serve.report.render import render_report  # noqa: E402
from tests.pipeline.serve.report.conftest import console_lines, needs_chromium, run_chromium  # noqa: E402
from tests.pipeline.serve.test_decision import (DECIDED, NO_ESTIMATE, NO_PLAN, OPEN, decision_rows,  # noqa: E402
                                                make_warehouse)


#: The SVG namespace, as ElementTree names its tags.
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture
def wh(tmp_path):
    return make_warehouse(tmp_path / "wh")


def _section(page: str) -> str:
    i = page.index('<section id="decision">')
    return page[i:page.index("</section>", i) + len("</section>")]


def test_the_report_opens_with_the_decision(wh):
    page = render_report(wh)
    order = [page.index(k) for k in ('id="toc"', 'id="decision"', 'id="findings"', 'id="rebuild"', 'id="runs"')]
    assert order == sorted(order)
    toc = page[page.index('id="toc"'):page.index("</nav>")]
    assert re.findall(r'href="#([^"]+)"', toc)[0] == "decision"
    sec = _section(page)
    assert "4 hose types, 1 decided" in sec
    rows = re.findall(r"<tr><td><b>(.*?)</b>.*?</td><td class=\"(\w+)\">(.*?)</td><td>(.*?)</td>", sec, flags=re.S)
    assert [(r[0], r[1], r[2]) for r in rows] == [(DECIDED, "ok", "force longer"), ("NBR &lt;b&gt;10&lt;/b&gt;", "nodata", "no plan"),
                                                  (OPEN, "nodata", "undecided"), (NO_ESTIMATE, "nodata", "undecided")]
    assert rows[0][3].startswith("force-set FLEXIGOM AIR hoses live 1.82x longer (90 % CI 1.31-2.53x); decided on "
                                 "2026-03-02 at the 14th failure")
    assert "<b>10</b>" not in sec  # a hose type from the logbook is text, escaped
    # the information fraction as a bar as wide as the fraction, and the plan in words
    assert '<span style="width:72.5%"></span></span><br><span class="meta">72 % of the information: 29 of 40' in sec
    assert ("<td>11 more failures, about 6 more hoses per adjustment, verdict expected by 2026-08 (80 % power; 45 % chance "
            "of a verdict with the hoses on test now)") in sec
    assert 'title="unknown"' not in sec and sec.count('class="infobar"') == 4


def _svgs(sec: str) -> list[tuple[str, str, ET.Element]]:
    """(anchor, hose type as written, parsed SVG) of each looks figure of a section."""
    found = re.findall(r'<figure id="(decision-looks-\d+)"><!-- figure: [0-9a-f]{32} -->'
                       r'(<svg [^>]*aria-label="looks of ([^"]*)".*?</svg>)<!-- /figure -->', sec, flags=re.S)
    return [(anchor, name, ET.fromstring(svg)) for anchor, svg, name in found]


def _marks(svg: ET.Element, colour: str, tag: str) -> list[ET.Element]:
    """The elements ``tag`` of ``svg`` drawn in the figure's ``colour`` (filled or stroked)."""
    c = COLOURS[colour]
    return [e for e in svg.iter(f"{SVG}{tag}") if c in (e.get("fill"), e.get("stroke"))]


def test_the_looks_are_a_figure_per_hose_type_with_an_estimate(wh):
    sec = _section(render_report(wh))
    figs = _svgs(sec)
    assert [f[1] for f in figs] == [DECIDED, "NBR &lt;b&gt;10&lt;/b&gt;", OPEN]  # none for the hose type without an estimate
    for anchor, _name, _svg in figs:
        assert f'href="#{anchor}"' in sec
    for name, (_anchor, _n, svg) in zip((DECIDED, "NBR <b>10</b>", OPEN), figs):
        d = read_decisions_of(wh, name)
        assert svg.get("viewBox") == "0 0 900 400" and svg.get("role") == "img"
        # one blue dot per look with an estimate, each with its look's figures as a tooltip
        dots = [e for e in _marks(svg, "estimate", "circle") if e.find(f"{SVG}title") is not None]
        with_estimate = [lk for lk in d.looks if lk["life_ratio"] is not None]
        assert len(dots) == len(with_estimate) > 3
        assert dots[0].find(f"{SVG}title").text.startswith(f"look {with_estimate[0]['look']}, ")
        # the counted crossings ringed, the efficacy boundaries dashed in red
        assert len(_marks(svg, "crossed", "circle")) == len(rd.counted_crossings(d)) + bool(rd.counted_crossings(d))
        assert len(_marks(svg, "efficacy", "path")) == 2
    # the deciding look's orange star and line on the decided hose type only; futility steps on the undecided one
    decided, _, undecided = (f[2] for f in figs)
    assert len(_marks(decided, "decides", "polygon")) == 2 and len(_marks(decided, "decides", "line")) == 1
    assert _marks(undecided, "decides", "polygon") == [] and len(_marks(undecided, "futility", "path")) == 2


def test_only_the_crossings_the_verdict_counts_are_ringed(wh):
    """A crossing after the verdict (its Wald crossing, not checked by the likelihood: its note says so) is not
    ringed; the ones up to the verdict are; the figure's key follows its data."""
    d = read_decisions_of(wh, DECIDED)
    counted = rd.counted_crossings(d)
    assert counted and all(d.looks[i]["crossed"] for i in counted)
    late = [dict(lk, crossed="force longer", note=AFTER_VERDICT) if i > counted[-1] else lk
            for i, lk in enumerate(d.looks)]
    d_late = type(d)(d.hose_type, d.verdict, d.effect, late, d.plans)
    assert len(d.looks) > counted[-1] + 1 and rd.counted_crossings(d_late) == counted
    assert rd.looks_key(d) == rd.looks_key(read_decisions_of(wh, DECIDED)) != rd.looks_key(d_late)


def test_the_same_tables_give_the_same_figure_bytes(wh):
    d = read_decisions_of(wh, DECIDED)
    assert rd.looks_svg(rd.looks_of(d)) == rd.looks_svg(rd.looks_of(read_decisions_of(wh, DECIDED)))
    assert rd.looks_svg(rd.looks_of(read_decisions_of(wh, NO_ESTIMATE))) == ""


def test_a_looks_figure_whose_key_the_live_report_holds_is_taken_not_drawn(wh, monkeypatch):
    """The looks are drawn once; the next report takes each figure whose key is unchanged from the
    live one (same bytes), draws the one whose looks changed, and ``--full`` draws them all."""
    import duckdb

    from pipeline.serve.report.render import write_report
    from pipeline.warehouse import DB_NAME

    write_report(wh)
    first = _section((wh / "report" / "index.html").read_text(encoding="utf-8"))
    drawn = []
    real = rd.looks_svg
    monkeypatch.setattr(rd, "looks_svg", lambda lk: drawn.append(lk.hose_type) or real(lk))
    assert _section(render_report(wh)) == first and drawn == []
    assert _section(render_report(wh, run_pages="all")) == first and len(drawn) == 3
    drawn.clear()
    con = duckdb.connect(str(wh / DB_NAME))
    con.execute("UPDATE decision_looks SET life_ratio = life_ratio * 1.01 WHERE hose_type = ?", [OPEN])
    con.close()
    again = _section(render_report(wh))
    assert drawn == [OPEN] and again != first
    assert again == _section(render_report(wh, run_pages="all"))


def read_decisions_of(wh, hose_type):
    con = connect_readonly(wh)
    try:
        return read_decisions(con, hose_type)[0]
    finally:
        con.close()


def test_absent_or_empty_tables_are_one_line(tmp_path):
    old = make_warehouse(tmp_path / "old", {}, tables=())
    empty = make_warehouse(tmp_path / "empty", {})
    for folder, text in ((old, "no decision tables in this warehouse (built before the decision stage)"),
                         (empty, "no hose type has hoses of both adjustments (force and distance) yet")):
        sec = _section(render_report(folder))
        assert re.fullmatch(r'<section id="decision"><h2>The decision</h2><p class="nodata">([^<]*)</p></section>',
                            sec).group(1).startswith(text)


def test_hose_types_beyond_the_plot_limit_are_named(wh, monkeypatch):
    monkeypatch.setattr(rd, "MAX_LOOK_PLOTS", 1)
    con = connect_readonly(wh)
    try:
        sec = rd.decision_section(ReportDB(con))
    finally:
        con.close()
    assert sec.count("<figure") == 1
    assert ("Looks not drawn for 2 more hose types (NBR &lt;b&gt;10&lt;/b&gt;, PU 8x6): "
            "<code>pneubench decision --hose-type T</code> lists them.") in sec


@needs_chromium
def test_the_decision_in_headless_chromium(wh, tmp_path):
    index = tmp_path / "index.html"
    index.write_text(render_report(wh), encoding="utf-8")
    res = run_chromium(index.as_uri(), "--dump-dom", size=(1280, 1600))
    dom = res.stdout
    assert '<section id="decision"><h2>The decision</h2>' in dom, res.stderr[-2000:]
    console = console_lines(res)
    # the bars are drawn as wide as their fraction: measured on a copy of the page with a probe added
    probe = ("<script>addEventListener('load',()=>{document.body.insertAdjacentHTML('beforeend','<pre id=m>'+"
             "[...document.querySelectorAll('.infobar')].map(b=>b.firstChild.getBoundingClientRect().width/"
             "b.getBoundingClientRect().width).map(x=>x.toFixed(2)).join(' ')+'|'+[...document.querySelectorAll("
             "'#decision figure > svg')].map(i=>i.getAttribute('width')+'x'+i.getBoundingClientRect().width).join(' ')+'</pre>')})</script>")
    copy = tmp_path / "probe.html"
    copy.write_text(index.read_text(encoding="utf-8").replace("</body>", probe + "</body>"), encoding="utf-8")
    res = run_chromium(copy.as_uri(), "--dump-dom", size=(1280, 1600))
    bars, imgs = re.search(r'<pre id="m">(.*?)</pre>', res.stdout, flags=re.S).group(1).split("|")
    fractions = [r["information_fraction"] for r in sorted(decision_rows()["life_verdict"], key=lambda r: r["hose_type"])]
    assert [float(b) for b in bars.split()] == pytest.approx(fractions, abs=0.02)
    assert imgs.split() == ["900x900"] * 3  # every figure drawn, at its full width
    # the section is the first thing on the page: the verdict's green cell and the bars in the first screen
    shot = tmp_path / "top.png"
    res = run_chromium(index.as_uri(), f"--screenshot={shot}", size=(1280, 900))
    console += console_lines(res)
    rgb = plt.imread(shot)[..., :3]
    green = (abs(rgb - [0xe3 / 255, 0xf5 / 255, 0xe6 / 255]) < 0.02).all(axis=-1)
    blue = (abs(rgb - [0x2a / 255, 0x4d / 255, 0x8f / 255]) < 0.04).all(axis=-1)
    assert green.sum() > 500 and blue.sum() > 300
    assert console == []


@needs_chromium
def test_a_looks_figure_in_headless_chromium(wh, tmp_path):
    """The decided hose type's figure as chromium draws it: the estimate in blue, the efficacy boundaries in red,
    the deciding look's star and line in orange, the counted crossings' rings in purple."""
    svg = rd.looks_svg(rd.looks_of(read_decisions_of(wh, DECIDED)))
    page = tmp_path / "fig.html"
    page.write_text(f"<!doctype html><html><body style='margin:0'>{svg}</body></html>", encoding="utf-8")
    shot = tmp_path / "fig.png"
    res = run_chromium(page.as_uri(), f"--screenshot={shot}", size=(900, 400))
    assert console_lines(res) == []
    rgb = plt.imread(shot)[..., :3]

    def pixels(colour: str) -> int:
        want = [int(COLOURS[colour][i:i + 2], 16) / 255 for i in (1, 3, 5)]
        return int((abs(rgb - want) < 0.12).all(axis=-1).sum())

    for colour in ("decides", "efficacy", "estimate"):
        assert pixels(colour) > 150, colour
    assert pixels("crossed") > 40
