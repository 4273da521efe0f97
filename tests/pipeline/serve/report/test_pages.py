"""The run pages: raw text escaped, channels, metadata, warnings and results; the events the
analyses found marked on the channels of foreign rigs."""
import re

from pipeline.rebuild.flow import rebuild
from tests.pipeline.serve.report.conftest import EVIL


def test_run_pages_escape_raw_text_and_show_channels_metadata_warnings_and_results(built, warehouse):
    from pipeline.serve.report.folders import page_name
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


def _svg_texts(page: str) -> list[str]:
    svg = page[page.index("<svg"):page.index("</svg>")]
    return re.findall(r"<text[^>]*>([^<]*)</text>", svg)


def test_run_pages_of_foreign_rigs_mark_passes_and_steps_on_round_ticks_in_bar_and_mm(raw, warehouse):
    """A ventilator's set-point at 1 kHz in mbar and a laser-sensor cylinder at 100 Hz in mm, as
    those rigs wrote them: their pages mark the steps and passes the analyses found."""
    from pipeline.serve.report.folders import page_name
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
