"""The report's first section, "The decision", on warehouses filled by hand with the contract's
tables (a decided hose type, an undecided one with its plan, one without plan.toml, one without
an estimate), in the page and in headless chromium."""
from __future__ import annotations

import base64
import io
import re

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pytest  # noqa: E402

from pipeline.serve.door import connect_readonly  # noqa: E402
from pipeline.serve.decision import read_decisions  # noqa: E402
from pipeline.serve.report import decision as rd  # noqa: E402
from pipeline.stages.decision import AFTER_VERDICT  # noqa: E402
from pipeline.serve.report.db import ReportDB  # noqa: E402
from pipeline.serve.report.render import FromRebuild, render_report  # noqa: E402
from tests.pipeline.serve.report.conftest import console_lines, needs_chromium, run_chromium  # noqa: E402
from tests.pipeline.serve.test_decision import (DECIDED, NO_ESTIMATE, NO_PLAN, OPEN, decision_rows,  # noqa: E402
                                                make_warehouse)


@pytest.fixture
def wh(tmp_path):
    return make_warehouse(tmp_path / "wh")


def _section(page: str) -> str:
    i = page.index('<section id="decision">')
    return page[i:page.index("</section>", i) + len("</section>")]


def _png(src: str):
    return plt.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])), format="png")


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


def test_the_looks_are_a_figure_per_hose_type_with_an_estimate(wh):
    sec = _section(render_report(wh))
    figs = re.findall(r'<figure id="(decision-looks-\d+)"><!-- figure: [0-9a-f]{32} -->'
                      r'<img alt="looks of ([^"]*)" src="(data:image/png;base64,[^"]+)"', sec)
    assert [f[1] for f in figs] == [DECIDED, "NBR &lt;b&gt;10&lt;/b&gt;", OPEN]  # none for the hose type without an estimate
    for anchor, _name, _src in figs:
        assert f'href="#{anchor}"' in sec
    img = _png(figs[0][2])[..., :3]
    assert img.shape[:2] == (400, 900)
    # the deciding look's orange star, the red efficacy boundaries, the blue estimate, the counted crossings ringed
    for colour in ("decides", "efficacy", "estimate"):
        assert _pixels(img, colour) > 150, colour
    assert _pixels(img, "crossed") > 40           # rings (and the legend's) are thin
    # the undecided hose type: no deciding look (no star), futility boundaries once its interval is narrow
    img = _png(figs[2][2])[..., :3]
    assert _pixels(img, "decides") == 0 and _pixels(img, "futility") > 150


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


def _pixels(img, colour: str) -> int:
    """Pixels of ``img`` near the figure's ``colour``."""
    rgb = [int(rd.COLOURS[colour][i:i + 2], 16) / 255 for i in (1, 3, 5)]
    return int((abs(img - rgb) < 0.12).all(axis=-1).sum())


def test_the_same_tables_give_the_same_figure_bytes(wh):
    d = read_decisions_of(wh, DECIDED)
    assert rd.looks_png(d) == rd.looks_png(d)
    assert rd.looks_png(read_decisions_of(wh, NO_ESTIMATE)) is None


def test_a_looks_figure_whose_key_the_live_report_holds_is_taken_not_drawn(wh, monkeypatch):
    """The looks are drawn once; the next report takes each figure whose key is unchanged from the
    live one (same bytes), draws the one whose looks changed, and ``--full`` draws them all."""
    import duckdb

    from pipeline.serve.report.render import write_report
    from pipeline.warehouse import DB_NAME

    write_report(wh)
    first = _section((wh / "report" / "index.html").read_text(encoding="utf-8"))
    drawn = []
    real = rd.looks_png
    monkeypatch.setattr(rd, "looks_png", lambda d: drawn.append(d.hose_type) or real(d))
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
             "'#decision figure img')].map(i=>i.naturalWidth+'x'+i.width).join(' ')+'</pre>')})</script>")
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


def test_figures_drawn_in_forked_processes_are_the_bytes_drawn_here(wh, monkeypatch):
    """From PARALLEL_FROM figures to draw (a plan change redraws all), they are drawn in processes forked one
    per core: the same bytes and the same section as drawn one by one here."""
    serial = _section(render_report(wh, run_pages="all"))            # 3 figures: fewer than PARALLEL_FROM
    con = connect_readonly(wh)
    try:
        decisions = [d for d in read_decisions(con) if rd._drawable(d)]
    finally:
        con.close()
    todo = [(d, rd.looks_key(d)) for d in decisions]
    assert rd._draw_elsewhere(todo) == {}
    monkeypatch.setattr(rd, "PARALLEL_FROM", 2)
    monkeypatch.setattr(rd.os, "cpu_count", lambda: 2)
    assert rd._draw_elsewhere(todo) == {}   # no pool given (the report alone, a notebook): drawn here
    from pipeline.rebuild.executors import forked_pool   # the rebuild's kind, as pipeline/rebuild/publish gives it

    drawn = rd._draw_elsewhere(todo, forked_pool)
    assert len(todo) == 3 and drawn == {key: rd._looks_img(d) for d, key in todo}
    assert _section(render_report(wh, run_pages="all")) == serial
    # the report's pool reaches the looks figures (until session 26 decision_section dropped it: all drawn here)
    used = []
    pool = lambda workers: used.append(workers) or forked_pool(workers)   # noqa: E731
    assert _section(render_report(wh, run_pages="all", rebuild=FromRebuild(pool=pool))) == serial
    assert used == [2]
