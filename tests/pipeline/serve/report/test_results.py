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
