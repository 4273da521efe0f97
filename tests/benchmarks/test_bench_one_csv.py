"""benchmarks/bench_one_csv.py: the steps of a rebuild read from its stamped progress lines, and the verdicts."""
import pytest

from benchmarks import bench_one_csv as bench

STAMPED = """\
0.400 0.200 0.000 imported
0.410 0.205 0.000 rebuild 20261126T000000.000000Z-1 (incremental): 1 run files under raw, 0 unchanged at a glance
0.500 0.250 0.000 ingest: 1 of 1 run files to read
some line a worker printed
2.000 1.100 0.000 stage plpa_characterisation ran: breakaway 0 rows (200 ms)
2.100 1.150 0.000 stage models reused: spring_fits 0 rows (12 ms)
3.100 1.900 0.000 stage durability ran: durability_runs 1 rows (1.0 s)
3.200 1.950 0.000 warehouse: writing 42 tables
3.900 2.300 0.000 figures: 3 drawn in a worker beside the stages and the database (waited 235 ms for them)
4.500 2.800 1.700 report: /wh/report/index.html
4.500 2.800 1.700 rebuild: 1 runs (1 new, 0 changed, 0 deleted, 0 unchanged), 0 quarantined, 4.1 s
4.510 2.800 2.100 end
"""


def test_each_step_ends_at_its_line_and_the_ingest_is_named_before_the_first_stage():
    got = bench.steps(STAMPED)
    names = [s for s, _, _ in got]
    assert names == ["start-up: imports of the command", "plan (walk raw/, previous state)",
                     "ingest (workers) + the stages' imports, then stage plpa_characterisation ran",
                     "stage models reused", "stage durability ran", "after the stages (assemble the tables)",
                     "database write (figures drawn, the new runs' channels read beside it)", "report",
                     "the rest (summary, exit)"]
    wall = dict((s, w) for s, w, _ in got)
    cpu = dict((s, c) for s, _, c in got)
    assert wall["stage durability ran"] == pytest.approx(1.0)
    assert cpu["database write (figures drawn, the new runs' channels read beside it)"] == pytest.approx(0.35)
    assert sum(w for _, w, _ in got) == pytest.approx(4.51)  # the steps add up to the whole
    assert bench._children_cpu(STAMPED) == pytest.approx(2.1)


def test_the_target_and_the_no_slower_check_pass_and_miss_on_their_thresholds(capsys):
    def res(pandas_s, after_s, after_cpu, before_cpu):
        t = {"after": (after_s, after_cpu), "before": (4.0, before_cpu), "pandas": (pandas_s, 2.0), "duckdb": (1.5, 1.7)}
        return {"mb": 106.0, "breakdown": {},
                "times": {n: {"wall_s": w, "cpu_s": c, "tree_peak_mb": 100.0} for n, (w, c) in t.items()}}

    assert [ok for _, _, ok in bench.report(res(3.0, 2.0, 3.0, 3.0), 1)] == [True, True]
    assert [ok for _, _, ok in bench.report(res(3.0, 2.1, 3.2, 3.0), 1)] == [False, False]
    out = capsys.readouterr().out
    assert "| pandas | 3.00 | 2.00 | 100 |" in out
