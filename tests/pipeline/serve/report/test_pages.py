"""The run pages: raw text escaped, channels, metadata, warnings and results; the events the
analyses found marked on the channels of foreign rigs."""
import json
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
    now = datetime(2026, 11, 26, 6, 0, tzinfo=timezone.utc)
    con = duckdb.connect(str(warehouse / DB_NAME))  # the pooled fit moves: its value on every step of the group
    con.execute("UPDATE pressure_steps SET nrmse_pct = coalesce(nrmse_pct, 0) + 1 WHERE run_id = ?", [vent])
    con.execute("UPDATE rebuild_log SET inputs_key = inputs_key || '-pooled'")
    con.close()
    pooled = stage_report(warehouse, now=now)  # not shown on the page: the page is the live one
    assert (pooled / "runs" / page_name(vent)).stat().st_ino == (live / page_name(vent)).stat().st_ino
    assert "nrmse" not in before[vent].split('id="results"')[1].split("Not shown here")[0]
    assert 'href="../index.html#raw-pressure_steps">pressure_steps</a>: nrmse_pct' in before[vent]
    assert 'id="raw-pressure_steps"' in (pooled / "index.html").read_text(encoding="utf-8")
    assert _files(pooled) == _files(stage_report(warehouse, now=now, run_pages="all"))
    read.clear()
    con = duckdb.connect(str(warehouse / DB_NAME))  # a refit: a row of the run changes, not its events
    con.execute("UPDATE pressure_steps SET p_start_bar = coalesce(p_start_bar, 0) + 1 WHERE run_id = ?", [vent])
    con.execute("UPDATE rebuild_log SET inputs_key = inputs_key || '-refit'")  # what a rebuild that refits writes
    con.close()
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


def test_bands_read_ahead_are_taken_once_by_their_own_key_and_a_failure_comes_with_them(tmp_path, monkeypatch):
    """:class:`BandsAhead`: the first :data:`AHEAD_RUNS` runs read in a thread, each read taken by the
    report once under (path, channels, rows); another key is not the same read; a file that cannot
    be read raises where it is taken, as the report's own read would."""
    import numpy as np
    import pyarrow as pa
    import pyarrow.parquet as pq
    import pytest

    from pipeline.serve.report import pages

    for i in range(3):
        pq.write_table(pa.table({"t_s": np.arange(50.0), "x_m": np.arange(50.0) * (i + 1)}), tmp_path / f"{i}.parquet")
    read = []
    real = pages.downsample_minmax
    monkeypatch.setattr(pages, "downsample_minmax", lambda path, *a, **k: read.append(path.name) or real(path, *a, **k))
    monkeypatch.setattr(pages, "AHEAD_RUNS", 2)
    with pages.BandsAhead(tmp_path) as ahead:
        ahead.read([("0.parquet", ["x_m"], 50), ("missing.parquet", ["x_m"], 50), ("2.parquet", ["x_m"], 50)])
        assert ahead.take("0.parquet", ["x_m"], 49) is None  # another key: the report reads it itself
        got = ahead.take("0.parquet", ["x_m"], 50).result()
        want = real(tmp_path / "0.parquet", ["x_m"], 50)
        assert got["t_s"] == want["t_s"] and all(np.array_equal(a, b) for a, b in zip(got["x_m"], want["x_m"]))
        assert ahead.take("0.parquet", ["x_m"], 50) is None  # taken once
        with pytest.raises(OSError):
            ahead.take("missing.parquet", ["x_m"], 50).result()
        assert ahead.take("2.parquet", ["x_m"], 50) is None  # past AHEAD_RUNS: not read ahead
    assert read == ["0.parquet", "missing.parquet"]


def test_a_new_runs_channels_are_read_once_beside_the_database_and_its_page_is_the_one_drawn_alone(
        raw, warehouse, monkeypatch):
    """A rebuild reads a new run's channel bands while it writes its database, and its report takes
    them: the samples are read once, and the run page is byte for byte the page the report draws
    on its own (``--full`` report, no read ahead)."""
    import threading
    from datetime import datetime, timezone

    from pipeline.serve.report import pages
    from pipeline.serve.report.folders import page_name
    from pipeline.serve.report.render import stage_report

    raw.csv("c/s0.csv", {**STEP_META, "run_id": "s0"},
            {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 1, 1], "x_ref[mm]": [1, 1, 1]})
    threads = []
    real = pages.downsample_minmax
    monkeypatch.setattr(pages, "downsample_minmax",
                        lambda path, *a, **k: threads.append(threading.current_thread().name) or real(path, *a, **k))
    rebuild(raw.root, warehouse, jobs=1)
    assert len(threads) == 1 and threads[0].startswith("report-bands")
    page = (warehouse / "report" / "runs" / page_name("s0")).read_bytes()
    alone = stage_report(warehouse, now=datetime(2026, 11, 26, tzinfo=timezone.utc), run_pages="all")
    assert (alone / "runs" / page_name("s0")).read_bytes() == page and len(threads) == 2
    rebuild(raw.root, warehouse, jobs=1, report=False)  # nothing new, no report: nothing read ahead
    assert len(threads) == 2


def test_unchanged_pages_are_taken_over_by_their_keys_in_the_index_and_a_page_the_index_gives_another_key_is_drawn(
        raw, warehouse, monkeypatch):
    """The run pages' keys are written beside them (``RUN_KEYS``); the next report takes an unchanged
    page over from the index without opening it, draws a page whose key there differs, and reads the
    key line of a page the index does not name (a report from before it)."""
    from pipeline.serve.report import pages
    from pipeline.serve.report.folders import page_name

    for i in range(3):
        raw.csv(f"c/s{i}.csv", {**STEP_META, "run_id": f"s{i}"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 1, 1],
                                                                 "x_ref[mm]": [1, 1, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    report = warehouse / "report"
    keys = pages.read_run_keys(report)
    assert set(keys) - {pages._DEPS} == {page_name(f"s{i}") for i in range(3)} == {p.name for p in (report / "runs").iterdir()}
    for name, key in ((n, k) for n, k in keys.items() if n != pages._DEPS):
        assert f"<!-- key: {key} -->" in (report / "runs" / name).read_text().split("\n", 1)[0]

    opened = []
    real = pages._take_over
    monkeypatch.setattr(pages, "_take_over", lambda old, *a: opened.append(old.name) or real(old, *a))
    raw.csv("c/s1.csv", {**STEP_META, "run_id": "s1"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 2, 2],
                                                       "x_ref[mm]": [2, 2, 2]})
    rebuild(raw.root, warehouse, jobs=1)
    assert opened == []  # every page known by the index: none opened for its key line
    new = pages.read_run_keys(report)
    assert new[page_name("s1")] != keys[page_name("s1")]
    assert {n: k for n, k in new.items() if n not in (page_name("s1"), pages._DEPS)} == \
        {n: k for n, k in keys.items() if n not in (page_name("s1"), pages._DEPS)}
    assert f"<!-- key: {new[page_name('s1')]} -->" in (report / "runs" / page_name("s1")).read_text()

    # an index that names a page with another key, and not what it was keyed from: that page is drawn
    lied = dict({n: k for n, k in new.items() if n != pages._DEPS}, **{page_name("s0"): "0" * 24})
    (report / pages.RUN_KEYS).write_text(json.dumps(lied))
    before = (report / "runs" / page_name("s0")).stat().st_ino
    raw.csv("c/s2.csv", {**STEP_META, "run_id": "s2"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 3, 3],
                                                       "x_ref[mm]": [3, 3, 3]})
    rebuild(raw.root, warehouse, jobs=1)
    assert (report / "runs" / page_name("s0")).stat().st_ino != before
    assert pages.read_run_keys(report)[page_name("s0")] == new[page_name("s0")]

    (report / pages.RUN_KEYS).unlink()  # a report from before the index: pages read for their key lines
    raw.csv("c/s2.csv", {**STEP_META, "run_id": "s2"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, 4, 4],
                                                       "x_ref[mm]": [4, 4, 4]})
    rebuild(raw.root, warehouse, jobs=1)
    assert sorted(opened) == sorted(page_name(f"s{i}") for i in range(3))
    assert set(pages.read_run_keys(report)) == {page_name(f"s{i}") for i in range(3)} | {pages._DEPS}


def _key_lines(folder) -> dict[str, str]:
    """Each page's key line in ``folder``."""
    return {p.name: p.read_text().split("\n", 1)[0] for p in sorted(folder.iterdir())}


def test_only_the_runs_whose_rows_changed_are_keyed_and_their_keys_are_those_a_whole_keying_gives(
        raw, warehouse, tmp_path, monkeypatch):
    """A change of one run keys that run's page alone (the others keep their key in ``RUN_KEYS``: none of
    their rows changed since); every page has the key and bytes of pages drawn anew from the same database.
    A live report keyed from another database than the live one (a rebuild without the report between)
    keys every page."""
    from pipeline.serve.door import connect_readonly
    from pipeline.serve.report import pages
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.folders import page_name

    def step(i: int, x: float) -> None:
        raw.csv(f"c/s{i}.csv", {**STEP_META, "run_id": f"s{i}"}, {"t[s]": [0, 0.1, 0.2], "x[mm]": [0, x, x],
                                                                 "x_ref[mm]": [1, 1, 1]})

    for i in range(3):
        step(i, 1.0)
    rebuild(raw.root, warehouse, jobs=1)
    keyed = []
    real = pages._page_key
    monkeypatch.setattr(pages, "_page_key", lambda run, res: keyed.append(run["run_id"]) or real(run, res))
    step(1, 2.0)
    rebuild(raw.root, warehouse, jobs=1)
    assert keyed == ["s1"]

    def whole() -> dict[str, bytes]:  # every page drawn in place from the live database (every key computed)
        folder = tmp_path / f"whole-{len(keyed)}"
        con = connect_readonly(warehouse)
        try:
            pages.write_run_pages(ReportDB(con), warehouse, folder, full=True)
        finally:
            con.close()
        return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}

    runs = warehouse / "report" / "runs"
    assert {p.name: p.read_bytes() for p in sorted(runs.iterdir())} == whole()
    keys = pages.read_run_keys(warehouse / "report")
    assert {n: k for n, k in keys.items() if n != pages._DEPS} == {
        n: line.split("key: ")[1].split(" ")[0] for n, line in _key_lines(runs).items()}
    step(2, 3.0)
    rebuild(raw.root, warehouse, jobs=1, report=False)  # the live report now of an earlier database
    step(0, 4.0)
    keyed.clear()
    rebuild(raw.root, warehouse, jobs=1)
    assert sorted(keyed) == ["s0", "s1", "s2"]
    assert {p.name: p.read_bytes() for p in sorted(runs.iterdir())} == whole()
    assert pages.read_run_keys(warehouse / "report")[page_name("s2")] != keys[page_name("s2")]


def test_a_run_pages_leak_growth_rows_read_under_the_floor_of_the_runs_flow_sensor_as_its_leakage_rows_do(tmp_path):
    """hose_leak_growth copies a hose check's plateaus without the sensors: on the run's page its
    rows read "< floor" where the run's leakage_map rows do (the floor of the run's sensors); a
    run whose rows state no sensor shows its values."""
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.folders import page_name
    from pipeline.serve.report.pages import write_run_pages
    from tests.pipeline.serve.report.conftest import table_cells
    from tests.pipeline.serve.report.test_tables import leak_floor_db

    con = leak_floor_db()
    con.execute("CREATE TABLE runs (run_id VARCHAR, kind VARCHAR, samples_path VARCHAR, warnings VARCHAR[], "
                "params VARCHAR)")
    con.execute("INSERT INTO runs VALUES ('c/check-H1', 'leakage', NULL, NULL, NULL), "
                "('c/char', 'leakage', NULL, NULL, NULL), ('c/elsewhere', 'leakage', NULL, NULL, NULL)")
    assert write_run_pages(ReportDB(con), tmp_path) == 3

    def leaks(run_id: str, table: str) -> list[str]:
        page = (tmp_path / "report" / "runs" / page_name(run_id)).read_text()
        part = page[page.index(f"<h3>{table} ("):]
        part = part[:part.index("</table>")]
        head = [re.sub(r"<[^>]+>", " ", h).split()[0] for h in re.findall(r"<th>(.*?)</th>", part, flags=re.S)]
        return [r[head.index("leak")] for r in table_cells(part)]

    assert leaks("c/check-H1", "hose_leak_growth") == leaks("c/check-H1", "leakage_map") == ["&lt; 0.020", "0.667"]
    assert leaks("c/elsewhere", "hose_leak_growth") == ["-0.0044"]
