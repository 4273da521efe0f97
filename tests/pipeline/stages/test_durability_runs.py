"""The durability runs' own stage: it reads durability runs only, so a changed leakage check reuses its
folder (``durability_runs`` and ``durability_strokes`` not rebuilt) while ``durability`` re-runs on its
tables; a durability run re-runs both; incremental equals full. (Its per-run results: ``test_durability``.)"""
from pipeline.stages import Reads
from pipeline.stages import durability, durability_runs as stage
from tests.conftest import query
from tests.pipeline.stages.test_remaining_life import BOOK, _durability_csv, _leak_check_csv


def test_it_reads_durability_runs_only_and_durability_reads_its_table_not_the_runs():
    assert stage.READS == Reads(kinds=("durability",))
    assert stage.WRITES == ("durability_runs", "durability_strokes")
    assert "durability_runs" in durability.READS.tables and durability.READS.kinds == ("leakage",)
    assert not set(stage.WRITES) & set(durability.WRITES)


def test_a_leakage_change_reuses_the_runs_and_reruns_durability_a_durability_run_reruns_both(raw, warehouse):
    from pipeline.rebuild.flow import rebuild

    raw.write("c/hoses.csv", BOOK)
    _durability_csv(raw, "c/d1.csv", "D1", "2026-01-01T08:00:00")
    _durability_csv(raw, "c/f1.csv", "F1", "2026-01-01T09:00:00")
    _leak_check_csv(raw, "c/check-d1.csv", "D1", "2026-01-01T10:00:00", 3.0, 1)
    ran = lambda **kw: rebuild(raw.root, warehouse, jobs=1, report=False, **kw)  # noqa: E731
    first = ran()
    assert {"durability_runs", "durability"} <= set(first.stages_run)
    tables = ("durability_runs", "durability_strokes", "hose_life", "hose_leak_growth")
    before = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert len(before["durability_runs"]) == 2 and len(before["durability_strokes"]) == 100
    _leak_check_csv(raw, "c/check-d1.csv", "D1", "2026-01-01T10:00:00", 2.5, 2)   # the check changed
    s = ran()
    assert "durability_runs" in s.stages_reused and "durability" in s.stages_run
    now = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert {t: now[t] for t in tables[:3]} == {t: before[t] for t in tables[:3]}
    assert now["hose_leak_growth"] != before["hose_leak_growth"]
    _durability_csv(raw, "c/f2.csv", "F1", "2026-01-02T09:00:00")                  # a durability run
    s = ran()
    assert {"durability_runs", "durability"} <= set(s.stages_run)
    after = {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables}
    assert len(after["durability_runs"]) == 3
    assert {"durability_runs", "durability"} <= set(ran(full=True).stages_run)
    assert {t: query(warehouse, f"SELECT * FROM {t} ORDER BY ALL") for t in tables} == after
