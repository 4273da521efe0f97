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
from pipeline.rebuild import rebuild  # noqa: E402
from pipeline.stages import StageOutput  # noqa: E402
from pipeline.stages import findings as fs  # noqa: E402
from tests.conftest import STEP_META  # noqa: E402

EVIL = '<script>alert("pwned")</script>'


class PictureStage:
    """A stage with a figure and its key table, whose text comes from raw metadata."""
    NAME, ORDER, KINDS, TABLES = "zz_pictures", 80, ("step",), ("zz_curve",)
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
        return fs._row("breakaway_0bar_twice", "Breakaway at 0 bar is about twice that at >= 1 bar", fs.PLPA, "1",
                       "ratio 1.5-2.5", "breakaway", 2.0 if holds else 1.0, 0.05, holds, 30, None, "test")
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
    # the overturned finding comes first, then findings, rebuild, hoses, analyses
    order = [html.index(k) for k in ('id="overturned"', 'id="findings"', 'id="rebuild"', 'id="hoses"', 'id="analyses"')]
    assert order == sorted(order)
    assert "<b>overturned</b>: Breakaway at 0 bar" in html
    # quarantine reason, key table, caption and the hose logbook are all there, escaped
    assert "c/bad.csv" in html and "not accepted for `x`" in html
    assert "<script" not in html.lower() and "&lt;script&gt;alert(&quot;pwned&quot;)&lt;/script&gt;" in html
    assert "zz_curve (key table of curve)" in html
    # self-contained: figures inline, nothing fetched
    assert re.search(r'<img alt="curve" src="data:image/png;base64,[A-Za-z0-9+/=]{1000,}">', html)
    assert not re.search(r'(src|href)="(?!data:)', html)


def chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.mark.skipif(chromium() is None, reason="Debian's chromium is not installed (.ci/run installs it)")
def test_report_in_headless_chromium(built, warehouse, tmp_path):
    shot = tmp_path / "report.png"
    profile = tempfile.mkdtemp(prefix="chromium-")
    try:
        res = subprocess.run(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
             f"--screenshot={shot}", "--window-size=1280,2400", (warehouse / "report" / "index.html").resolve().as_uri()],
            capture_output=True, text=True, timeout=120)
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    assert shot.is_file(), res.stderr[-2000:]
    console = [line for line in res.stderr.splitlines() if "CONSOLE" in line]
    assert console == []
    if os.environ.get("PNEUBENCH_KEEP_SCREENSHOT"):
        shutil.copy(shot, os.environ["PNEUBENCH_KEEP_SCREENSHOT"])
    img = plt.imread(shot)
    assert img.shape[:2] == (2400, 1280)
    # the page is not blank, and the embedded figure's thick red curve is on it
    rgb = img[..., :3]
    assert rgb.std() > 0.05
    red = (rgb[..., 0] > 0.7) & (rgb[..., 1] < 0.35) & (rgb[..., 2] < 0.35)
    assert red.sum() > 500


def test_long_input_lists_are_folded_and_quarantine_comes_first(raw, warehouse):
    from pipeline.report import FOLD_INPUT_ROWS, render_report

    for i in range(FOLD_INPUT_ROWS + 1):
        raw.csv(f"c/s{i:02d}.csv", STEP_META, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    raw.csv("c/bad.csv", STEP_META, {"t[s]": [0, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    page = render_report(warehouse)
    assert f"<details><summary><b>New, changed and deleted inputs ({FOLD_INPUT_ROWS + 2})</b>" in page
    assert page.index("Quarantined inputs (1)") < page.index("New, changed and deleted inputs")
    (raw.root / "c" / "s00.csv").unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert "<details open><summary><b>New, changed and deleted inputs (1)</b>: 1 deleted" in render_report(warehouse)


def test_an_overturned_finding_stays_first_for_24_hours(built, raw, warehouse, monkeypatch):
    import pipeline.report as rp
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
    import pipeline.report as rp
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
    import pipeline.report as rp

    page = warehouse / "report" / "index.html"
    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    monkeypatch.setattr(rp, "failure_page", lambda *a, **k: 1 / 0)
    with pytest.raises(rp.ReportError) as err:
        rp.write_report(warehouse)
    assert err.value.page is None and err.value.error == "ZeroDivisionError: division by zero"
    assert not page.exists()


def test_no_warehouse_is_not_a_report_failure(tmp_path):
    from pipeline.report import write_report

    with pytest.raises(FileNotFoundError):
        write_report(tmp_path / "none")
    assert not (tmp_path / "none" / "report").exists()


def test_pneubench_report_command_exits_3_when_the_page_cannot_be_rendered(built, warehouse, monkeypatch):
    from click.testing import CliRunner

    import pipeline.report as rp
    from pipeline.cli import main

    monkeypatch.setattr(rp, "render_report", lambda *a, **k: 1 / 0)
    res = CliRunner().invoke(main, ["report", "--warehouse", str(warehouse)])
    assert res.exit_code == 3
    assert "pneubench report: failed: ZeroDivisionError: division by zero" in res.output
