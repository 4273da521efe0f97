"""The warehouse as the report reads it: the last rebuild is the one with the highest number,
never the one with the latest wall time."""
import pytest

from pipeline.rebuild.flow import rebuild
from tests.conftest import STEP_META


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

    import pipeline.serve.report.render as rp
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


def test_a_rebuild_log_from_before_seq_is_numbered_in_its_stored_order(raw, warehouse, monkeypatch):
    from datetime import datetime, timezone

    import duckdb

    import pipeline.serve.report.render as rp
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


def test_columns_read_at_once_are_those_describe_gives_and_views_are_described(raw, warehouse):
    from pipeline.serve.door import connect_readonly
    from pipeline.serve.report.db import ReportDB

    raw.csv("c/s.csv", {**STEP_META, "run_id": "s"}, {"t[s]": [0, 0.1], "x[mm]": [0, 1], "x_ref[mm]": [1, 1]})
    rebuild(raw.root, warehouse, jobs=1)
    con = connect_readonly(warehouse)
    try:
        db = ReportDB(con)
        assert "samples_step" in db.tables and "runs" in db.tables
        for t in sorted(db.tables):
            assert db.columns(t) == [r[0] for r in con.execute(f'DESCRIBE "{t}"').fetchall()], t
        assert "samples_step" not in db._columns and db.columns("no_such_table") == []
        assert db.columns("runs")[:2] == ["run_id", "kind"]
    finally:
        con.close()
