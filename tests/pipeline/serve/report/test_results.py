"""The results: CSV downloads that a spreadsheet cannot run, figures drawn near their full size."""
import re

from tests.pipeline.serve.report.conftest import needs_chromium, run_chromium


def test_csv_downloads_neutralise_formulas_and_keep_numbers():
    """Issue 21, item 9: a run id such as =HYPERLINK(...) is text in a spreadsheet, not a formula
    (OWASP: a leading '), and numbers (-1.5) stay numbers."""
    import base64
    import csv
    import io

    from pipeline.serve.report.results import _csv_uri

    uri = _csv_uri(["run_id", "x", "warnings", "=h"], [("=HYPERLINK(\"http://x\",\"y\")", -1.5, ["@a", "b"], 1),
                                                       ("+1", None, [], -2), ("-2+3", 2.0, None, 3),
                                                       ("\tx", 0.5, None, 4), ("c/a", -0.0, None, 5)])
    text = base64.b64decode(uri.split(",", 1)[1]).decode("utf-8")
    rows = list(csv.reader(io.StringIO(text)))
    assert rows == [["run_id", "x", "warnings", "'=h"],
                    ["'=HYPERLINK(\"http://x\",\"y\")", "-1.5", "'@a;b", "1"],
                    ["'+1", "", "", "-2"], ["'-2+3", "2.0", "", "3"], ["'\tx", "0.5", "", "4"],
                    ["c/a", "-0.0", "", "5"]]


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


def test_a_topic_is_taken_when_its_figures_moved_to_a_new_stage_folder_with_the_same_bytes(tmp_path):
    """A stage that runs again links its unchanged figures into a new folder: the topic showing them
    is taken from the live report (keyed by the PNG bytes it embeds, not by the folder); a changed
    PNG, caption or a missing file renders it again, and what it renders is what it embeds."""
    import os

    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.keyed import KeyedParts
    from pipeline.serve.report.results import _img, _part
    from tests.pipeline.serve.report.test_keyed import _db

    wh = tmp_path / "wh"
    (wh / "stages/models/k1/figures").mkdir(parents=True)
    (wh / "stages/models/k2/figures").mkdir(parents=True)
    old, new = wh / "stages/models/k1/figures/step_a.png", wh / "stages/models/k2/figures/step_a.png"
    old.write_bytes(b"\x89PNG one")
    os.link(old, new)
    calls = []

    def topic(figures):
        def render(db):
            calls.append(1)
            return "".join(_img(wh, rel) for _s, _n, rel, _c in figures) + str(db.rows("SELECT sum(x) FROM a")[1])
        return render

    row = ("models", "step_a", "stages/models/k1/figures/step_a.png", "caption")
    first = KeyedParts(ReportDB(_db()), "code")
    html = _part(first, "topic-step", topic([row]), [row], first.db, wh)
    moved = (*row[:2], "stages/models/k2/figures/step_a.png", row[3])
    again = KeyedParts(ReportDB(_db()), "code", first.kept)
    assert _part(again, "topic-step", topic([moved]), [moved], again.db, wh) == html and len(calls) == 1
    new.unlink()
    new.write_bytes(b"\x89PNG two")  # the figure drawn again, other bytes
    assert _part(KeyedParts(ReportDB(_db()), "code", first.kept), "topic-step", topic([moved]), [moved],
                 first.db, wh) != html and len(calls) == 2
    recaptioned = (*row[:3], "another caption")
    assert _part(KeyedParts(ReportDB(_db()), "code", first.kept), "topic-step", topic([recaptioned]), [recaptioned],
                 first.db, wh) == html and len(calls) == 3  # rendered again (its caption is shown)
    gone = (*row[:2], "stages/models/k3/figures/step_a.png", row[3])
    assert "figure file missing" in _part(KeyedParts(ReportDB(_db()), "code", first.kept), "topic-step",
                                          topic([gone]), [gone], first.db, wh) and len(calls) == 4


def test_the_hoses_topics_leak_growth_rows_read_under_the_floor_of_their_runs_sensor_and_the_csv_keeps_the_values(
        tmp_path):
    """hose_leak_growth's rows behind "Hoses and durability runs" (plateaus copied from leakage_map
    without the sensors) read "< floor" where leakage_map's rows of the same plateaus do; the
    seal_envelope's max leak too; the CSV download has the stored numbers."""
    import base64

    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.results import results_sections
    from tests.pipeline.serve.report.conftest import table_cells
    from tests.pipeline.serve.report.test_tables import leak_floor_db

    html, _toc = results_sections(ReportDB(leak_floor_db()), tmp_path)
    hoses = html[html.index('<section id="hoses">'):]
    part = hoses[hoses.index('id="raw-hose_leak_growth"'):]
    part = part[:part.index("</details>")]
    assert [r[-1] for r in table_cells(part)] == ["&lt; 0.0199", "0.6670", "-0.0044"]  # the last run states no sensor
    csv_text = base64.b64decode(re.search(r'base64,([^"]+)"', part).group(1)).decode()
    assert "-0.0044" in csv_text and "&lt;" not in csv_text and "< " not in csv_text
    leak = html[html.index('id="raw-leakage_map"'):]
    assert table_cells(leak[:leak.index("</details>")])[0][7] == "&lt; 0.020"
    seal = html[html.index('id="raw-seal_envelope"'):]
    assert [r[6] for r in table_cells(seal[:seal.index("</details>")])] == ["&lt; 0.040", "0.030", "0.001"]
