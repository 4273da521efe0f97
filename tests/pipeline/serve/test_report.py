"""The morning report: content and order, escaping, and a real headless Chromium rendering it."""
import os
import re
import shutil
import subprocess
import tempfile

import matplotlib
import pandas as pd
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import pipeline.stages as st  # noqa: E402
from pipeline.rebuild.flow import rebuild  # noqa: E402
from pipeline.stages import StageOutput  # noqa: E402
from pipeline.stages import findings as fs  # noqa: E402
from tests.conftest import STEP_META  # noqa: E402

EVIL = '<script>alert("pwned")</script>'


class PictureStage:
    """A stage with a figure and its key table, whose text comes from raw metadata."""
    NAME, READS, WRITES = "zz_pictures", st.Reads(kinds=("step",)), ("zz_curve",)
    KEY_TABLES = {"curve": "zz_curve"}

    @staticmethod
    def run(ctx):
        runs = ctx.runs_of("step")
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot([0, 1, 2, 3], [0, 1, 4, 9], "o-", color="tab:red", lw=4)
        ax.set_title("a curve")
        table = pd.DataFrame({"run_id": runs["run_id"], "value_mm": range(len(runs))})
        return StageOutput(tables={"zz_curve": table}, figures={"curve": fig},
                           captions={"curve": f"caption from {EVIL}"})


def flip(holds):
    def check(ctx):
        return fs._row(fs.Claim("breakaway_0bar_twice", "Breakaway at 0 bar is about twice that at >= 1 bar", fs.PLPA,
                                "1", "ratio 1.5-2.5"), "breakaway", 2.0 if holds else 1.0, 0.05, holds, 30, None, "test")
    return check


@pytest.fixture
def built(raw, warehouse, monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), PictureStage])
    for i in range(2):
        raw.csv(f"c/s{i}.csv", {**STEP_META, "run_id": f"{EVIL}{i}"}, {"t[s]": [0, 0.1], "x[mm]": [0, 1],
                                                                          "x_ref[mm]": [1, 1]})
    raw.csv("c/bad.csv", {**STEP_META, "notes": EVIL}, {"t[s]": [0, 1], "x[furlong]": [0, 1], "x_ref[mm]": [0, 1]})
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             f"H1,installed,2026-01-01T00:00:00,{EVIL.replace(',', ' ')},force,858\n")
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(True)),))
    rebuild(raw.root, warehouse, jobs=1)
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(False)),))
    s = rebuild(raw.root, warehouse, jobs=1, full=True)
    return s


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


def test_run_pages_escape_raw_text_and_show_channels_metadata_warnings_and_results(built, warehouse):
    from pipeline.serve.run_pages import page_name
    from tests.conftest import query

    html = (warehouse / "report" / "index.html").read_text()
    run_id = f"{EVIL}0"
    href = "runs/" + page_name(run_id)
    assert f'href="{href}"' in html
    page = (warehouse / "report" / href).read_text()
    assert "<script" not in page.lower() and "&lt;script&gt;" in page
    assert '<a href="../index.html">' in page and "<svg" in page and "x [mm]" in page
    assert "params.rig" in page and "plpa-1" in page
    assert "zz_curve (1 rows)" in page  # the result rows derived from this run
    pages = sorted(p.name for p in (warehouse / "report" / "runs").iterdir())
    assert pages == sorted(page_name(r) for (r,) in query(warehouse, "SELECT run_id FROM runs"))


def test_page_names_are_safe_and_distinct():
    from pipeline.serve.run_pages import page_name

    ids = ["a/b", "a_b", "A/B", "../../etc/passwd", "x" * 500, "ü/ö", ""]
    names = [page_name(i) for i in ids]
    assert len(set(names)) == len(ids)
    for n in names:
        assert re.fullmatch(r"[A-Za-z0-9._-]+\.html", n) and not n.startswith(".") and len(n) < 100


def test_numbers_have_sensible_significant_figures():
    from pipeline.serve.report import fmt, split_unit

    assert fmt(19.999999999999982) == "20"
    assert fmt(0.0001541) == "1.541e-04" and fmt(0.001541) == "0.001541" and fmt(3509.0) == "3509"
    assert fmt(1.976126054271789) == "1.976" and fmt(174544) == "174544" and fmt(float("nan")) == "—"
    assert split_unit("leak_l_min") == ("leak", "l/min") and split_unit("viscous_n_s_m") == ("viscous", "N s/m")
    assert split_unit("p0_bar_abs") == ("p0", "bar abs") and split_unit("hose_id") == ("hose id", "")


def test_downsampling_keeps_every_excursion_of_a_long_run(tmp_path):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.serve import run_pages as rp

    n = 250_000
    t = np.arange(n) / 1000.0
    x = np.sin(t)
    x[123_457] = 5.0   # one-sample spike
    x[200_001] = -7.0
    f = tmp_path / "s.parquet"
    pq.write_table(pa.table({"t_s": t, "x_m": x}), f, row_group_size=40_000)
    old = rp.BATCH_ROWS
    rp.BATCH_ROWS = 30_000  # batches that do not line up with the pixel columns
    try:
        b = rp.downsample_minmax(f, ["x_m", "missing"], n, width=500)
    finally:
        rp.BATCH_ROWS = old
    lo, hi = b["x_m"]
    assert lo.size == 500 and "missing" not in b
    assert np.nanmax(hi) == 5.0 and np.nanmin(lo) == -7.0
    assert hi[123_457 * 500 // n] == 5.0 and lo[200_001 * 500 // n] == -7.0
    assert b["t_s"] == (0.0, t[-1])
    svg = rp.channels_svg(b, "t")
    assert svg.startswith("<svg") and "x [mm]" in svg and "5000" in svg and "-7000" in svg


def chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def run_chromium(url: str, *extra: str, size=(1280, 2400)) -> subprocess.CompletedProcess:
    """Headless chromium on ``url`` with a throw-away profile and its console on stderr."""
    profile = tempfile.mkdtemp(prefix="chromium-")
    try:
        return subprocess.run(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
             "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
             "--virtual-time-budget=5000", *extra, f"--window-size={size[0]},{size[1]}", url],
            capture_output=True, text=True, timeout=180)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def console_lines(res) -> list[str]:
    return [line for line in res.stderr.splitlines() if "CONSOLE" in line]


needs_chromium = pytest.mark.skipif(chromium() is None, reason="Debian's chromium is not installed (.ci/run installs it)")


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
    assert any(r[0] == "front, discharge: ξ" and r[2] == "0.69" and r[3].startswith("0.69") for r in t2p)
    t3 = _cells(dom, "PLA Table 3")
    assert any(r[0] == "front: largest NRMSE" and r[2] == "2.39" for r in t3)
    f12 = _cells(dom, "PLPA Fig. 12")
    assert any(r[0] == "breakaway force at 0 bar backpressure" and r[2] == "10" and r[3].startswith(("9.", "10."))
               for r in f12)
    assert "PLPA Fig. 15" in dom
    # one run page: opened from its link, channels drawn, metadata and results there
    from pipeline.serve.run_pages import page_name

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


def test_long_input_lists_are_folded_and_quarantine_comes_first(raw, warehouse):
    from pipeline.serve.report import FOLD_INPUT_ROWS, render_report

    for i in range(FOLD_INPUT_ROWS + 1):
        raw.csv(f"c/s{i:02d}.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    raw.csv("c/bad.csv", STEP_META, {"t[s]": [0, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    page = render_report(warehouse)
    assert f"<details><summary><b>New, changed and deleted inputs ({FOLD_INPUT_ROWS + 2})</b>" in page
    assert page.index("Quarantined inputs (1)") < page.index("New, changed and deleted inputs")
    (raw.root / "c" / "s00.csv").unlink()
    rebuild(raw.root, warehouse, jobs=1)
    page = render_report(warehouse)
    assert "<details open><summary><b>New, changed and deleted inputs (1)</b>: 1 deleted" in page
    # a deleted run has no page, so its id is not a link; a run that is there is
    from pipeline.serve.run_pages import page_name
    assert "<td>c/s00</td>" in page and page_name("c/s00") not in page
    assert f'href="runs/{page_name("c/s01")}"' in page


def test_run_ids_in_finding_details_link_to_their_pages():
    from pipeline.serve.report import _linkify
    from pipeline.serve.run_pages import page_name

    html = _linkify("worst 0.1 l/min (429 N, run c/a<b>); also run gone/x, run c/z.", {"c/a<b>", "c/z"})
    assert f'run <a href="runs/{page_name("c/a<b>")}">c/a&lt;b&gt;</a>)' in html
    assert "run gone/x," in html and f'<a href="runs/{page_name("c/z")}">c/z</a>.' in html


def test_an_overturned_finding_stays_first_for_24_hours(built, raw, warehouse, monkeypatch):
    import pipeline.serve.report as rp
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
    monkeypatch.setattr(rp, "_now", lambda: at + rp.timedelta(hours=23))
    assert 'id="overturned"' in rp.render_report(warehouse)
    monkeypatch.setattr(rp, "_now", lambda: at + rp.timedelta(hours=25))
    rebuild(raw.root, warehouse, jobs=1)
    html = (warehouse / "report" / "index.html").read_text()
    assert 'id="overturned"' not in html
    assert 'id="changes">No finding changed its result in the last 24 hours' in html
    assert query(warehouse, "SELECT change, changed_at FROM findings") == [("overturned", at)]
    # it holds again: a new change, at the new rebuild's time, back in the alert box
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(True)),))
    monkeypatch.setattr(rp, "_now", lambda: rp.datetime.now(rp.timezone.utc))
    rebuild(raw.root, warehouse, jobs=1, full=True)  # full: the stage cache does not see CHECKS
    (change, later), = query(warehouse, "SELECT change, changed_at FROM findings")
    assert change == "now holds" and later > at
    assert "<b>now holds</b>: Breakaway at 0 bar" in (warehouse / "report" / "index.html").read_text()


def test_pneubench_report_replaces_a_page_it_cannot_render_and_never_leaves_yesterdays(built, warehouse,
                                                                                      monkeypatch):
    import pipeline.serve.report as rp
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
    import pipeline.serve.report as rp

    page = warehouse / "report" / "index.html"
    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    monkeypatch.setattr(rp, "failure_page", lambda *a, **k: 1 / 0)
    with pytest.raises(rp.ReportError) as err:
        rp.write_report(warehouse)
    assert err.value.page is None and err.value.error == "ZeroDivisionError: division by zero"
    assert not page.exists()


def test_no_warehouse_is_not_a_report_failure(tmp_path):
    from pipeline.serve.report import write_report

    with pytest.raises(FileNotFoundError):
        write_report(tmp_path / "none")
    assert not (tmp_path / "none" / "report").exists()


def test_pneubench_report_command_exits_3_when_the_page_cannot_be_rendered(built, warehouse, monkeypatch):
    from click.testing import CliRunner

    import pipeline.serve.report as rp
    from pipeline.cli import main

    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    res = CliRunner().invoke(main, ["report", "--warehouse", str(warehouse)])
    assert res.exit_code == 3
    assert "pneubench report: failed: ZeroDivisionError: division by zero" in res.output


def test_csv_downloads_neutralise_formulas_and_keep_numbers():
    """Issue 21, item 9: a run id such as =HYPERLINK(...) is text in a spreadsheet, not a formula
    (OWASP: a leading '), and numbers (-1.5) stay numbers."""
    import base64
    import csv
    import io

    from pipeline.serve.report import _csv_uri

    uri = _csv_uri(["run_id", "x", "warnings", "=h"], [("=HYPERLINK(\"http://x\",\"y\")", -1.5, ["@a", "b"], 1),
                                                       ("+1", None, [], -2), ("-2+3", 2.0, None, 3),
                                                       ("\tx", 0.5, None, 4), ("c/a", -0.0, None, 5)])
    text = base64.b64decode(uri.split(",", 1)[1]).decode("utf-8")
    rows = list(csv.reader(io.StringIO(text)))
    assert rows == [["run_id", "x", "warnings", "'=h"],
                    ["'=HYPERLINK(\"http://x\",\"y\")", "-1.5", "'@a;b", "1"],
                    ["'+1", "", "", "-2"], ["'-2+3", "2.0", "", "3"], ["'\tx", "0.5", "", "4"],
                    ["c/a", "-0.0", "", "5"]]


def _clock_at(monkeypatch, when):
    """The rebuild's wall clock (``datetime.now``) set to ``when``."""
    from datetime import datetime

    import pipeline.rebuild.flow as rb

    class Fixed(datetime):
        @classmethod
        def now(cls, tz=None):
            return when

    monkeypatch.setattr(rb, "datetime", Fixed)


@pytest.mark.parametrize("back", [False, True])
def test_the_report_shows_the_last_rebuild_even_when_the_clock_went_back(raw, warehouse, monkeypatch, back):
    """Issue 21.5: generations are ordered by their number, never by wall time (NTP, a dead
    battery): a rebuild whose clock went back is still the last one."""
    from datetime import datetime, timezone

    import pipeline.serve.report as rp
    from pipeline.rebuild.state import load_previous
    from tests.conftest import query

    raw.csv("c/a.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    _clock_at(monkeypatch, datetime(2026, 3, 2, 2, 30, tzinfo=timezone.utc))
    first = rebuild(raw.root, warehouse, jobs=1)
    raw.csv("c/b.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    _clock_at(monkeypatch, datetime(2026, 3, 1 if back else 3, 2, 30, tzinfo=timezone.utc))
    second = rebuild(raw.root, warehouse, jobs=1)
    assert first.generation != second.generation
    assert query(warehouse, "SELECT generation, seq FROM rebuild_log ORDER BY seq") == [
        (first.generation, 1), (second.generation, 2)]
    assert load_previous(warehouse).generation == second.generation
    html = (warehouse / "report" / "index.html").read_text()
    assert f"generation {second.generation}" in html and first.generation not in html
    assert ": 2 runs, 1 new, 0 changed" in html
    assert rp.render_report(warehouse).count(f"generation {second.generation}") == 2  # header and rebuild section
    # the next rebuild (a no-op when nothing is in doubt) is the last one too, with the next number
    _clock_at(monkeypatch, datetime(2026, 2, 1, tzinfo=timezone.utc))
    third = rebuild(raw.root, warehouse, jobs=1)
    assert query(warehouse, "SELECT generation, seq FROM rebuild_log ORDER BY seq DESC LIMIT 1") == [
        (third.generation, 3)]
    assert f"generation {third.generation}" in (warehouse / "report" / "index.html").read_text()
    assert load_previous(warehouse).generation == third.generation
    raw.csv("c/a.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 2], "x_ref[mm]": [1, 1]})
    _clock_at(monkeypatch, datetime(2025, 1, 1, tzinfo=timezone.utc))
    fourth = rebuild(raw.root, warehouse, jobs=1)
    assert load_previous(warehouse).generation == fourth.generation
    assert [r[0] for r in query(warehouse, "SELECT seq FROM rebuild_log ORDER BY seq")] == [1, 2, 3, 4]
    assert f"generation {fourth.generation}" in (warehouse / "report" / "index.html").read_text()


def test_a_new_report_reuses_unchanged_run_pages_and_keeps_what_others_put_in_the_report_folder(raw, warehouse):
    """The report folder is swapped whole (issue 21.4): an unchanged run's page is the same file
    (a hard link, not drawn again); a report/ folder of the old layout becomes the first
    generation; files and folders a user put there stay readable under report/."""
    import os

    from pipeline.serve.run_pages import page_name

    meta = {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]}
    raw.csv("c/a.csv", STEP_META, meta)
    raw.csv("c/b.csv", STEP_META, meta)
    rebuild(raw.root, warehouse, jobs=1)
    report = warehouse / "report"
    assert os.path.islink(report)
    # back to the old layout: report/ a real folder, with a user's notes in it
    folder = report.resolve()
    report.unlink()
    folder.rename(report)
    (report / "notes.txt").write_text("mine")
    (report / "extra").mkdir()
    (report / "extra" / "x.txt").write_text("also mine")
    (report / "runs" / "README").write_text("mine too")
    ino = {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")}
    raw.csv("c/b.csv", STEP_META, {**meta, "x[mm]": [0, 2]})
    rebuild(raw.root, warehouse, jobs=1)
    assert os.path.islink(report)
    assert os.stat(report / "runs" / page_name("c/a")).st_ino == ino["c/a"]  # taken over, not redrawn
    assert os.stat(report / "runs" / page_name("c/b")).st_ino != ino["c/b"]
    assert (report / "notes.txt").read_text() == "mine" and (report / "extra" / "x.txt").read_text() == "also mine"
    assert (report / "runs" / "README").read_text() == "mine too"
    assert [p.name for p in warehouse.iterdir() if p.name.startswith(".report")] == [os.readlink(report)]
    # a no-op rebuild: the same pages again, the same files
    ino = {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")}
    rebuild(raw.root, warehouse, jobs=1)
    assert {r: os.stat(report / "runs" / page_name(r)).st_ino for r in ("c/a", "c/b")} == ino
    assert (report / "notes.txt").read_text() == "mine" and (report / "extra" / "x.txt").read_text() == "also mine"
    assert [p.name for p in warehouse.iterdir() if p.name.startswith(".report")] == [os.readlink(report)]


def test_a_rebuild_log_from_before_seq_is_numbered_in_its_stored_order(raw, warehouse, monkeypatch):
    from datetime import datetime, timezone

    import duckdb

    import pipeline.serve.report as rp
    from pipeline.rebuild.state import load_previous
    from tests.conftest import query

    raw.csv("c/a.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    _clock_at(monkeypatch, datetime(2026, 3, 2, tzinfo=timezone.utc))
    first = rebuild(raw.root, warehouse, jobs=1)
    raw.csv("c/b.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    _clock_at(monkeypatch, datetime(2026, 3, 1, tzinfo=timezone.utc))  # the clock went back
    second = rebuild(raw.root, warehouse, jobs=1)
    con = duckdb.connect(str(warehouse / "pneubench.duckdb"))  # as an earlier version wrote it
    con.execute("ALTER TABLE rebuild_log DROP COLUMN seq")
    con.close()
    assert load_previous(warehouse).generation == second.generation
    assert f"generation {second.generation}" in rp.write_report(warehouse).read_text()
    raw.csv("c/c.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    third = rebuild(raw.root, warehouse, jobs=1)
    assert query(warehouse, "SELECT generation, seq FROM rebuild_log ORDER BY seq") == [
        (first.generation, 1), (second.generation, 2), (third.generation, 3)]


def test_on_a_file_system_without_symlinks_the_report_folder_is_swapped_by_rename(raw, warehouse, monkeypatch):
    import os

    from pipeline.serve.run_pages import page_name

    real_symlink = os.symlink

    def no_symlinks(src, dst, *a, **k):  # the warehouse's file system has none (raw/'s links live elsewhere)
        if str(dst).startswith(str(warehouse)):
            raise PermissionError(1, "Operation not permitted")
        return real_symlink(src, dst, *a, **k)

    monkeypatch.setattr(os, "symlink", no_symlinks)
    meta = {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]}
    raw.csv("c/a.csv", STEP_META, meta)
    raw.csv("c/b.csv", STEP_META, meta)
    rebuild(raw.root, warehouse, jobs=1)
    (raw.root / "c/b.csv").unlink()
    raw.csv("c/c.csv", STEP_META, meta)
    s = rebuild(raw.root, warehouse, jobs=1)
    report = warehouse / "report"
    assert report.is_dir() and not os.path.islink(report)
    assert f"generation {s.generation}" in (report / "index.html").read_text()
    assert {p.name for p in (report / "runs").iterdir()} == {page_name("c/a"), page_name("c/c")}
    assert not [p.name for p in warehouse.iterdir() if p.name.startswith(".report")]


# -- issue 25, items 11 and 12: one format per column, leaks under the sensor floor, figures, citations ---------
Q_SENSORS = ("p_supply: resolution 1, noise 307 (estimated) Pa; "
             "q_leak: resolution 1.98e-08, noise 3.93e-07 (estimated) kg/s")  # as leakage_map.sensors holds it


def _table_cells(html: str) -> list[list[str]]:
    body = html[html.index("<tbody>"):]
    return [[re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", r, flags=re.S)]
            for r in re.findall(r"<tr>(.*?)</tr>", body, flags=re.S)]


def test_a_leak_under_the_flow_sensors_floor_reads_below_it_and_a_column_keeps_one_format():
    from analyses.leakage import kg_s_to_l_min_anr
    from pipeline.serve.report import html_table

    floor = float(kg_s_to_l_min_anr(3.93e-07))  # max(resolution, noise) of the flow sensor, in l/min ANR
    assert 0.019 < floor < 0.021
    cols = ["run_id", "pressure_bar", "leak_l_min", "leak_se_l_min", "sensors"]
    rows = [("r1", 5.0, -0.0019, 0.0027, Q_SENSORS), ("r2", 5.0, 4.313e-04, 0.002, Q_SENSORS),
            ("r3", 6.0, 0.7043, 0.003, Q_SENSORS), ("r4", 6.0, 14.7068, 0.01, Q_SENSORS)]
    cells = _table_cells(html_table(cols, rows))
    # under the floor (the negative one too): "< floor"; the rest in the column's one format (3 decimals here)
    assert [r[2] for r in cells] == ["&lt; 0.020", "&lt; 0.020", "0.704", "14.707"]
    assert [r[1] for r in cells] == ["5", "5", "6", "6"]
    assert [r[3] for r in cells] == ["0.0027", "0.0020", "0.0030", "0.0100"]  # an uncertainty is never floored
    # without the sensors the floor is unknown: the values are shown, still in one format, no scientific notation
    cells = _table_cells(html_table(cols[:4], [r[:4] for r in rows]))
    assert [r[2] for r in cells] == ["-0.002", "0.000", "0.704", "14.707"]
    # a sensors text that states no usable flow sensor gives no floor (the value is shown)
    from pipeline.serve.report import flow_floor_l_min
    assert flow_floor_l_min(Q_SENSORS) == pytest.approx(floor)
    for bad in (None, "", "p_supply: resolution 1, noise 307 (estimated) Pa", "q_leak: resolution x, noise y (estimated) kg/s",
                "q_leak: resolution nan, noise nan (estimated) kg/s", "q_leak: resolution 0, noise 0 (estimated) kg/s"):
        assert flow_floor_l_min(bad) is None, bad
    cells = _table_cells(html_table(cols, [("r1", 5.0, -0.0019, 0.0027, "q_leak: resolution x, noise y (estimated) kg/s")]))
    assert cells[0][2] == "-0.0019"
    # a column of tiny values alone is scientific throughout; one too wide for fixed notation as well
    cells = _table_cells(html_table(["ae_m2"], [(1.541e-5,), (2.1e-6,)]))
    assert [r[0] for r in cells] == ["1.541e-05", "2.100e-06"]
    cells = _table_cells(html_table(["n", "setting"], [(3, 3.5), (174544, 1300.0), (7, -0.0001)]))
    assert [r[0] for r in cells] == ["3", "174544", "7"] and [r[1] for r in cells] == ["3.5", "1300.0", "0.0"]


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
        rows = _table_cells(table)
        for j, head in enumerate(heads):
            kinds = {k for r in rows if j < len(r) and (k := _number_format(r[j])) is not None}
            assert len(kinds) <= 1, (head, kinds, [r[j] for r in rows][:12])
    # the leakage summary and rows: no negative leak, the tiny ones read "< floor"
    leak = html[html.index('<section id="leakage">'):html.index('<section id="breakaway">')]
    t = leak[leak.index("<table>"):leak.index("</table>")]
    heads = [re.sub(r"<[^>]+>", "", h) for h in re.findall(r"<th>(.*?)</th>", t, flags=re.S)]
    leak_cols = [j for j, h in enumerate(heads) if h.startswith("leak at")]
    cells = [r[j] for r in _table_cells(t) for j in leak_cols]
    assert leak_cols and not any(c.startswith("-") for c in cells), cells
    assert any(c.startswith("&lt; ") for c in cells) and not any("e-" in c for c in cells), cells
    # figures one per row, no empty "Other figures", the papers cited by name (from one place in the code)
    assert 'class="pair"' not in html and "Other figures" not in html
    assert "seed 00" not in html
    assert PLPA_CITATION in html and PLA_CITATION in html
    assert PLPA_CITATION == "Carneiro et al. 2020, Information 11(2):76"
    assert PLA_CITATION == "Palomares et al. 2017, Mechatronics 45"


@needs_chromium
def test_demo_report_figures_are_drawn_near_their_full_size(demo, tmp_path):
    """Each figure is drawn at least at 85 % of its pixel width (or the page's), measured in chromium on a
    copy of the page with a measuring script added (the report itself has none)."""
    html = (demo["warehouse"] / "report" / "index.html").read_text()
    assert "<script" not in html
    probe = ("<script>addEventListener('load',()=>{document.body.insertAdjacentHTML('beforeend','<pre id=widths>'+"
             "[...document.querySelectorAll('figure img')].map(i=>i.alt+' '+i.naturalWidth+' '+i.width).join(';')"
             "+'</pre>')})</script>")
    copy = tmp_path / "index.html"
    copy.write_text(html.replace("</body>", probe + "</body>"))
    res = run_chromium(copy.as_uri(), "--dump-dom", size=(1280, 900))
    m = re.search(r'<pre id="widths">(.*?)</pre>', res.stdout, flags=re.S)
    assert m, res.stderr[-2000:]
    widths = [w.rsplit(" ", 2) for w in m.group(1).split(";")]
    assert len(widths) >= 10
    small = [(a, n, w) for a, n, w in widths if int(w) < 0.85 * min(int(n), 1100)]
    assert not small, small


# -- issue 25 items 10, 13: run pages read like the report, with what the analyses saw ------------------
def _svg_texts(page: str) -> list[str]:
    svg = page[page.index("<svg"):page.index("</svg>")]
    return re.findall(r"<text[^>]*>([^<]*)</text>", svg)


def test_run_pages_of_foreign_rigs_mark_passes_and_steps_on_round_ticks_in_bar_and_mm(raw, warehouse):
    """A ventilator's set-point at 1 kHz in mbar and a laser-sensor cylinder at 100 Hz in mm, as
    those rigs wrote them: their pages mark the steps and passes the analyses found."""
    from pipeline.serve.run_pages import page_name
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS, plan, write_run
    from tests.conftest import query

    runs = [r for r in plan() if r.stem in ("ventilator-ramp", "laser-050um")]
    for r in runs:
        write_run(raw.root, r, 1)
        raw.write(f"{CAMPAIGN}/{r.folder}/rig.toml", RIG_TOMLS[f"{r.folder}/rig.toml"], dedent=False)
    summary = rebuild(raw.root, warehouse, jobs=1)
    assert summary.quarantine == []
    vent, laser = (next(r.run_id for r in runs if r.stem == s) for s in ("ventilator-ramp", "laser-050um"))
    steps = query(warehouse, f"SELECT count(*) FROM pressure_steps WHERE run_id = '{vent}'")[0][0]
    passes = query(warehouse, f"SELECT count(*) FROM viscous_points WHERE run_id = '{laser}'")[0][0]
    assert steps > 0 and passes > 0

    page = (warehouse / "report" / "runs" / page_name(vent)).read_text()
    texts = _svg_texts(page)
    assert f"set-point step ({steps})" in texts and "p [bar (gauge)]" in texts
    assert page.count('stroke-dasharray="4 2">') >= steps  # one dashed line per step and panel
    # pressure ticks: round values in bar gauge (PEEP 5 mbar, PIP 20 mbar), not Pa, more than min and max
    ticks = [t for t in texts if re.fullmatch(r"-?\d+\.\d+", t)]
    assert {"0.005", "0.010", "0.015", "0.020"} <= set(ticks), texts
    assert "t [s]" in texts and not any("e+" in t or "Pa" in t for t in texts)

    page = (warehouse / "report" / "runs" / page_name(laser)).read_text()
    texts = _svg_texts(page)
    assert f"constant-velocity pass ({passes})" in texts and "x [mm]" in texts
    assert len(re.findall(r'<rect [^>]*fill-opacity="0.16"><title>constant-velocity pass', page)) == 3 * passes
    assert sum(re.fullmatch(r"-?\d+", t) is not None for t in texts) >= 3 * 3  # ticks on p_a, p_b and x


def test_a_long_runs_time_axis_reads_h_mm_ss_and_a_breakaway_onset_is_marked(tmp_path):
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.serve import run_pages as rp

    n = 11_251  # an hour-long durability record at 1 Hz, to 3:07:30
    t = np.arange(n, dtype=float)
    f = tmp_path / "s.parquet"
    pq.write_table(pa.table({"t_s": t, "p_a_pa": 2e5 + 3e4 * np.sin(t / 7), "x_m": 0.1 + 0.5 * np.sin(t / 5)}), f)
    svg = rp.channels_svg(rp.downsample_minmax(f, ["p_a_pa", "x_m"], n), "long")
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", svg)
    assert "t [h:mm:ss]" in texts and {"0:00:00", "1:00:00", "2:00:00", "3:00:00"} <= set(texts)
    assert not any("e+" in x for x in texts)
    assert {"1.8", "2.0", "2.2"} <= set(texts) and {"-250", "0", "250", "500"} <= set(texts)  # bar, mm
    # a short run stays in seconds; a breakaway onset (and nothing of other tables) is drawn with a legend
    res = [("breakaway", ["run_id", "direction", "onset_t_s"], ("r", "P", 12.5)),
           ("breakaway_findings", ["run_id", "onset_t_s"], ("r", 3.0)),
           ("step_response", ["run_id", "t_step_s"], ("r", float("nan")))]
    ev = rp.run_events(res)
    assert ev == [("onset", 12.5, None, "breakaway onset P")]
    bands = {"t_s": (0.0, 40.0), "x_m": (np.linspace(0, 0.01, 100), np.linspace(0, 0.01, 100))}
    svg = rp.channels_svg(bands, "brk", ev)
    texts = re.findall(r"<text[^>]*>([^<]*)</text>", svg)
    assert "breakaway onset (1)" in texts and "t [s]" in texts and {"0", "10", "20", "30", "40"} <= set(texts)
    x_onset = 70 + 12.5 / 40 * rp.WIDTH
    assert f'x1="{x_onset:.1f}"' in svg and "<title>breakaway onset P: 12.5 s</title>" in svg


def test_the_sensors_column_is_shown_in_bar_and_l_min_but_stored_in_si():
    from pipeline.serve.report import html_table

    stored = "p_supply: resolution 100, noise 40 (metadata) Pa; q_leak: resolution 1.975e-07, noise 0 (estimated) kg/s"
    cell = html_table(["run_id", "sensors"], [("r", stored)])
    assert "p_supply: resolution 0.001 bar, noise 0.0004 bar (metadata); q_leak: resolution 0.01 l/min" in cell
    assert " Pa" not in cell and "kg/s" not in cell


def test_a_run_with_thousands_of_events_draws_a_bounded_page():
    import numpy as np

    from pipeline.serve import run_pages as rp

    n = 5 * rp.MAX_EVENTS
    res = [("viscous_points", ["run_id", "pass_index", "t_start_s", "t_end_s"], ("r", i, i + 0.2, i + 0.7))
           for i in range(n)] + [("viscous_points", ["run_id", "t_start_s", "t_end_s"], ("r", None, 3.0))]
    ev = rp.run_events(res)
    assert len(ev) == n  # a pass without a start is not drawn
    bands = {"t_s": (0.0, float(n)), "x_m": (np.zeros(rp.WIDTH), np.ones(rp.WIDTH)),
             "p_a_pa": (np.zeros(rp.WIDTH), np.ones(rp.WIDTH))}
    svg = rp.channels_svg(bands, "many", ev)
    assert svg.count("<title>constant-velocity pass") == 2 * rp.MAX_EVENTS
    assert f"constant-velocity pass ({rp.MAX_EVENTS})" in svg
    assert f"(first {rp.MAX_EVENTS} drawn, {n - rp.MAX_EVENTS} more in the tables)" in svg
    assert len(svg) < 300_000
