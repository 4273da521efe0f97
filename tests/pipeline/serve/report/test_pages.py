"""The run pages: raw text escaped, channels, metadata, warnings and results; the events the
analyses found marked on the channels of foreign rigs."""
import re

from pipeline.rebuild.flow import rebuild
from tests.conftest import STEP_META
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


def _files(folder) -> dict[str, bytes]:
    """Every file of a report folder by its path inside it."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_page_drawn_again_takes_its_unchanged_channels_and_is_the_page_a_full_report_draws(raw, warehouse,
                                                                                            monkeypatch):
    """A run's result rows change but not its samples nor the events on them: its page is drawn
    again, its channels are taken from the previous page (not read, not drawn), and the report is,
    file by file, the one ``--full`` draws. A changed event draws that run's channels only."""
    from datetime import datetime, timezone

    import duckdb

    from pipeline.serve.report import pages
    from pipeline.serve.report.folders import page_name
    from pipeline.serve.report.publish import publish_report
    from pipeline.serve.report.render import stage_report
    from pipeline.simulator.foreign import CAMPAIGN, RIG_TOMLS, plan, write_run
    from pipeline.warehouse import DB_NAME
    from tests.conftest import query

    runs = [r for r in plan() if r.stem in ("ventilator-ramp", "laser-050um")]
    for r in runs:
        write_run(raw.root, r, 1)
        raw.write(f"{CAMPAIGN}/{r.folder}/rig.toml", RIG_TOMLS[f"{r.folder}/rig.toml"], dedent=False)
    rebuild(raw.root, warehouse, jobs=1)
    vent, laser = (next(r.run_id for r in runs if r.stem == s) for s in ("ventilator-ramp", "laser-050um"))
    live = warehouse / "report" / "runs"
    before = {rid: (live / page_name(rid)).read_text(encoding="utf-8") for rid in (vent, laser)}
    assert all(p.count("<!-- figure: ") == 1 and "<svg" in p for p in before.values())

    read = []
    real = pages.downsample_minmax
    monkeypatch.setattr(pages, "downsample_minmax", lambda path, *a, **k: read.append(path) or real(path, *a, **k))
    con = duckdb.connect(str(warehouse / DB_NAME))  # a refit: a row of the run changes, not its events
    con.execute("UPDATE pressure_steps SET nrmse_pct = coalesce(nrmse_pct, 0) + 1 WHERE run_id = ?", [vent])
    con.execute("UPDATE rebuild_log SET inputs_key = inputs_key || '-refit'")  # what a rebuild that refits writes
    con.close()
    now = datetime(2026, 11, 26, 6, 0, tzinfo=timezone.utc)
    incremental = stage_report(warehouse, now=now)
    assert read == []  # neither run's samples read: the vent page's channels taken from its previous page
    page = (incremental / "runs" / page_name(vent)).read_text(encoding="utf-8")
    assert page != before[vent] and page.split("\n", 1)[1] != before[vent].split("\n", 1)[1]
    svg = page[page.index("<!-- figure: "):page.index("<!-- /figure -->")]
    assert svg in before[vent]
    assert (incremental / "runs" / page_name(laser)).stat().st_ino == (live / page_name(laser)).stat().st_ino
    full = stage_report(warehouse, now=now, run_pages="all")
    assert len(read) == 2  # --full: every run's channels drawn
    assert _files(incremental) == _files(full)

    publish_report(warehouse, incremental)
    read.clear()
    con = duckdb.connect(str(warehouse / DB_NAME))  # an event moves: that run's channels are drawn again
    con.execute("UPDATE pressure_steps SET t_step_s = t_step_s + 0.001 WHERE run_id = ?", [vent])
    con.execute("UPDATE rebuild_log SET inputs_key = inputs_key || '-moved'")
    con.close()
    again = stage_report(warehouse, now=now)
    assert read == [warehouse / query(warehouse, f"SELECT samples_path FROM runs WHERE run_id = '{vent}'")[0][0]]
    assert _files(again) == _files(stage_report(warehouse, now=now, run_pages="all"))


def test_a_full_rebuild_draws_every_channels_figure_again(raw, warehouse, monkeypatch):
    from pipeline.serve.report import pages

    for i in range(2):
        raw.csv(f"c/s{i}.csv", {**STEP_META, "run_id": f"s{i}"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 1, 1],
                                                                 "x_ref[mm]": [1, 1, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    read = []
    real = pages.downsample_minmax
    monkeypatch.setattr(pages, "downsample_minmax", lambda path, *a, **k: read.append(path) or real(path, *a, **k))
    rebuild(raw.root, warehouse, jobs=1)  # nothing changed: nothing drawn
    assert read == []
    rebuild(raw.root, warehouse, jobs=1, full=True)
    assert len(read) == 2
