"""The findings and the last rebuild's sections: long input lists folded, quarantine first, run
ids in the findings linked to their pages."""
from pipeline.rebuild.flow import rebuild
from tests.conftest import STEP_META


def test_long_input_lists_are_folded_and_quarantine_comes_first(raw, warehouse):
    from pipeline.serve.report.render import render_report
    from pipeline.serve.report.sections import FOLD_INPUT_ROWS

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
    from pipeline.serve.report.folders import page_name
    assert "<td>c/s00</td>" in page and page_name("c/s00") not in page
    assert f'href="runs/{page_name("c/s01")}"' in page


def test_run_ids_in_finding_details_link_to_their_pages():
    from pipeline.serve.report.sections import _linkify
    from pipeline.serve.report.folders import page_name

    html = _linkify("worst 0.1 l/min (429 N, run c/a<b>); also run gone/x, run c/z.", {"c/a<b>", "c/z"})
    assert f'run <a href="runs/{page_name("c/a<b>")}">c/a&lt;b&gt;</a>)' in html
    assert "run gone/x," in html and f'<a href="runs/{page_name("c/z")}">c/z</a>.' in html
