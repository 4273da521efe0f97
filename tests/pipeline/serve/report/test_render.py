"""The report's flow: the index in order, escaped and self-contained, rendered from the database
and published; a report that cannot be rendered is replaced by a failure page (exit 3); and the
report in a real headless Chromium."""
import os
import re
import shutil

import matplotlib.pyplot as plt
import pytest

from pipeline.rebuild.flow import rebuild
from pipeline.stages import findings as fs
from tests.pipeline.serve.report.conftest import console_lines, flip, needs_chromium, run_chromium


def test_report_order_escaping_and_self_containment(built, warehouse):
    html = (warehouse / "report" / "index.html").read_text()
    assert built.report == warehouse / "report" / "index.html"
    # contents first, the overturned finding, findings, the papers' sections, other figures, rebuild, runs
    order = [html.index(k) for k in ('id="toc"', 'id="overturned"', 'id="findings"', 'id="hoses"', 'id="analyses"',
                                     'id="rebuild"', 'id="runs"')]
    assert order == sorted(order)
    assert "<b>overturned</b>: Breakaway at 0 bar" in html
    # quarantine reason, key table, caption and the hose logbook are all there, escaped
    assert "c/bad.csv" in html and "not accepted for `x`" in html
    assert "<script" not in html.lower() and "&lt;script&gt;alert(&quot;pwned&quot;)&lt;/script&gt;" in html
    assert re.search(r"<b>zz_curve</b> \(2 rows\) \(key table of curve\)", html)
    # self-contained: figures and CSV downloads inline; links only to anchors and to the run pages beside it
    assert re.search(r'<img alt="curve" src="data:image/png;base64,[A-Za-z0-9+/=]{1000,}">', html)
    assert re.search(r'<a download="zz_curve.csv" href="data:text/csv;charset=utf-8;base64,', html)
    targets = re.findall(r'(?:src|href)="([^"]*)"', html)
    assert targets and all(t.startswith(("#", "data:", "runs/")) for t in targets), \
        [t for t in targets if not t.startswith(("#", "data:", "runs/"))]
    # every contents link has its anchor, every run link its page
    ids = set(re.findall(r'id="([^"]+)"', html))
    toc = html[html.index('id="toc"'):html.index("</nav>")]
    assert {a for a in re.findall(r'href="#([^"]+)"', toc)} <= ids
    for rel in {t for t in targets if t.startswith("runs/")}:
        assert (warehouse / "report" / rel).is_file(), rel


@needs_chromium
def test_report_in_headless_chromium(built, warehouse, tmp_path):
    shot = tmp_path / "report.png"
    res = run_chromium((warehouse / "report" / "index.html").resolve().as_uri(), f"--screenshot={shot}")
    assert shot.is_file(), res.stderr[-2000:]
    assert console_lines(res) == []
    if os.environ.get("PNEUBENCH_KEEP_SCREENSHOT"):
        shutil.copy(shot, os.environ["PNEUBENCH_KEEP_SCREENSHOT"])
    img = plt.imread(shot)
    assert img.shape[:2] == (2400, 1280)
    # the page is not blank, and the embedded figure's thick red curve is on it
    rgb = img[..., :3]
    assert rgb.std() > 0.05
    red = (rgb[..., 0] > 0.7) & (rgb[..., 1] < 0.35) & (rgb[..., 2] < 0.35)
    assert red.sum() > 500


def _cells(dom: str, caption: str) -> list[list[str]]:
    """Text of the cells of the table with ``caption`` in a DOM dump."""
    i = dom.index(caption)
    table = dom[i:dom.index("</table>", i)]
    rows = re.findall(r"<tr>(.*?)</tr>", table, flags=re.S)
    return [[re.sub(r"<[^>]+>", "", c).strip() for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", r, flags=re.S)]
            for r in rows]


@needs_chromium
def test_demo_report_in_chromium_contents_paper_tables_and_a_run_page(demo, tmp_path):
    report = demo["warehouse"] / "report"
    index = (report / "index.html").resolve()
    res = run_chromium(index.as_uri(), "--dump-dom")
    dom, console = res.stdout, console_lines(res)
    assert "<h1>pneubench morning report</h1>" in dom, res.stderr[-2000:]
    # every contents link leads to an element of the rendered page
    toc = dom[dom.index('id="toc"'):dom.index("</nav>")]
    anchors = re.findall(r'href="#([^"]+)"', toc)
    assert {"findings", "plpa", "leakage", "breakaway", "identification", "step", "pla", "spring", "pressure",
            "durability", "service-life", "rebuild", "runs"} <= set(anchors)
    for a in anchors:
        assert f'id="{a}"' in dom, a
    # ... and followed, each shows a page that is not blank (an iframe per link, one screenshot)
    band = 420
    frames = "".join(f'<iframe src="{index.as_uri()}#{a}" style="display:block;border:0;width:1200px;height:{band}px">'
                     "</iframe>" for a in anchors)
    wrapper = tmp_path / "follow.html"
    wrapper.write_text(f'<!DOCTYPE html><html><body style="margin:0">{frames}</body></html>')
    shot = tmp_path / "follow.png"
    res = run_chromium(wrapper.as_uri(), f"--screenshot={shot}", size=(1200, band * len(anchors)))
    console += console_lines(res)
    img = plt.imread(shot)[..., :3]
    for k, a in enumerate(anchors):
        assert img[k * band:(k + 1) * band].std() > 0.03, f"#{a} shows a blank page"
    # the papers' tables: paper value beside the measured one, with its uncertainty and the difference
    t2 = _cells(dom, "PLPA Table 2")
    assert t2[0][:5] == ["quantity", "unit", "paper", "measured ± std. uncertainty", "differencemeasured − paper"]
    wn = next(r for r in t2 if r[0].startswith("natural frequency"))
    assert wn[2] == "16.7" and re.fullmatch(r"16\.\d+ ± [0-9.e-]+", wn[3]) and wn[4].endswith("%)")
    t1 = _cells(dom, "PLA Table 1")
    assert ["front: polytropic index n", "", "1.123"] == t1[1][:3] and t1[1][3].startswith("1.12")
    assert any(r[0] == "rear: δ (structural damping)" and r[2] == "2963" for r in t1)
    t2p = _cells(dom, "PLA Table 2")
    # measured within 0.01 of the paper's 0.69 (its last digits are the simulated noise's: 0.6899 is fine)
    assert any(r[0] == "front, discharge: ξ" and r[2] == "0.69" and abs(float(r[3].split()[0]) - 0.69) < 0.01
               for r in t2p)
    t3 = _cells(dom, "PLA Table 3")
    assert any(r[0] == "front: largest NRMSE" and r[2] == "2.39" for r in t3)
    f12 = _cells(dom, "PLPA Fig. 12")
    assert any(r[0] == "breakaway force at 0 bar backpressure" and r[2] == "10" and r[3].startswith(("9.", "10."))
               for r in f12)
    assert "PLPA Fig. 15" in dom
    # one run page: opened from its link, channels drawn, metadata and results there
    from pipeline.serve.report.folders import page_name

    href = "runs/" + page_name("plpa-2025/leak-A-z4.0")
    assert f'href="{href}"' in dom
    page = (report / href).resolve()
    res = run_chromium(page.as_uri(), "--dump-dom")
    console += console_lines(res)
    assert "<h1>Run plpa-2025/leak-A-z4.0</h1>" in res.stdout and "params.z_rollers_mm" in res.stdout
    assert "leakage_map (7 rows)" in res.stdout
    shot = tmp_path / "run.png"
    res = run_chromium(page.as_uri(), f"--screenshot={shot}", size=(1100, 900))
    console += console_lines(res)
    rgb = plt.imread(shot)[..., :3]
    blue = (rgb[..., 2] > 0.6) & (rgb[..., 0] < 0.45) & (rgb[..., 1] < 0.65) & (rgb[..., 1] > 0.3)
    assert blue.sum() > 300  # the first channel's band
    assert console == []


def test_an_overturned_finding_stays_first_for_24_hours(built, raw, warehouse, monkeypatch):
    from datetime import datetime, timedelta, timezone

    import pipeline.serve.report.render as rp
    from tests.conftest import query

    changed_at = query(warehouse, "SELECT change, changed_at FROM findings")
    assert changed_at[0][0] == "overturned" and changed_at[0][1] is not None
    at = changed_at[0][1]
    # a second rebuild the same night (nothing changed): the alert and the time of the change stay
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.generation != built.generation
    assert query(warehouse, "SELECT holds, previous_holds, change, changed_at FROM findings") == [
        (False, False, "overturned", at)]
    html = (warehouse / "report" / "index.html").read_text()
    assert 'id="overturned"' in html and "<b>overturned</b>: Breakaway at 0 bar" in html
    assert "in the last 24 hours" in html
    # 23 h later it is still news, 25 h later it is not (the finding still says when it changed)
    monkeypatch.setattr(rp, "_now", lambda: at + timedelta(hours=23))
    assert 'id="overturned"' in rp.render_report(warehouse)
    monkeypatch.setattr(rp, "_now", lambda: at + timedelta(hours=25))
    rebuild(raw.root, warehouse, jobs=1)
    html = (warehouse / "report" / "index.html").read_text()
    assert 'id="overturned"' not in html
    assert 'id="changes">No finding changed its result in the last 24 hours' in html
    assert query(warehouse, "SELECT change, changed_at FROM findings") == [("overturned", at)]
    # it holds again: a new change, at the new rebuild's time, back in the alert box
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(True)),))
    monkeypatch.setattr(rp, "_now", lambda: datetime.now(timezone.utc))
    rebuild(raw.root, warehouse, jobs=1, full=True)  # full: the stage cache does not see CHECKS
    (change, later), = query(warehouse, "SELECT change, changed_at FROM findings")
    assert change == "now holds" and later > at
    assert "<b>now holds</b>: Breakaway at 0 bar" in (warehouse / "report" / "index.html").read_text()


def test_pneubench_report_replaces_a_page_it_cannot_render_and_never_leaves_yesterdays(built, warehouse,
                                                                                      monkeypatch):
    import pipeline.serve.report.render as rp
    from tests.conftest import query

    page = warehouse / "report" / "index.html"
    assert 'id="findings"' in page.read_text()
    (gen,), = query(warehouse, "SELECT generation FROM rebuild_log ORDER BY finished_at DESC LIMIT 1")

    def broken(*a, **k):
        raise ValueError("renderer broke\non two lines")

    monkeypatch.setattr(rp, "render_report", broken)
    with pytest.raises(rp.ReportError) as err:
        rp.write_report(warehouse)
    assert err.value.error == "ValueError: renderer broke on two lines"
    html = page.read_text()
    assert 'id="findings"' not in html and "Breakaway" not in html  # not the previous report
    assert 'id="report-failed"' in html and f"report for generation {gen} could not be written" in html
    assert "ValueError: renderer broke on two lines" in html and "warehouse itself is in place" in html
    assert not re.search(r'(src|href)="', html) and "<script" not in html
    assert not [p for p in page.parent.iterdir() if ".tmp" in p.name]
    # after the fix the real report again
    monkeypatch.undo()
    assert 'id="findings"' in rp.write_report(warehouse).read_text()


def test_when_not_even_the_failure_page_can_be_written_the_stale_page_is_removed(built, warehouse, monkeypatch):
    import pipeline.serve.report.render as rp

    page = warehouse / "report" / "index.html"
    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    monkeypatch.setattr(rp, "failure_page", lambda *a, **k: 1 / 0)
    with pytest.raises(rp.ReportError) as err:
        rp.write_report(warehouse)
    assert err.value.page is None and err.value.error == "ZeroDivisionError: division by zero"
    assert not page.exists()


def test_no_warehouse_is_not_a_report_failure(tmp_path):
    from pipeline.serve.report.render import write_report

    with pytest.raises(FileNotFoundError):
        write_report(tmp_path / "none")
    assert not (tmp_path / "none" / "report").exists()


def test_pneubench_report_command_exits_3_when_the_page_cannot_be_rendered(built, warehouse, monkeypatch):
    from click.testing import CliRunner

    import pipeline.serve.report.render as rp
    from pipeline.cli import main

    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    res = CliRunner().invoke(main, ["report", "--warehouse", str(warehouse)])
    assert res.exit_code == 3
    assert "pneubench report: failed: ZeroDivisionError: division by zero" in res.output
