"""The stage runner: stages run in the order their declarations give, re-run only when what they
declared changed (run kinds, tables, logbooks), refuse a circle, and fail on an undeclared read."""
import pandas as pd
import pytest

import pipeline.stages as st
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import RebuildError
from pipeline.rebuild.stage_runner import duration_text
from pipeline.stages import Reads, StageOutput
from tests.conftest import query
from tests.pipeline.rebuild.test_state import BREAK, T, age, step

q = query


class CountingStage:
    """A stage reading step runs; counts its runs."""
    NAME, READS, WRITES = "zz_count", Reads(kinds=("step",)), ("zz_count",)
    calls = 0

    @classmethod
    def run(cls, ctx):
        cls.calls += 1
        n = len(ctx.runs_of("step"))
        return StageOutput(tables={"zz_count": pd.DataFrame({"n_step_runs": [n]})})


def test_stage_reruns_only_when_its_kinds_change(raw, warehouse, monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), CountingStage])
    step(raw, "c/a.csv")
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    age(raw.root)
    CountingStage.calls = 0
    rebuild(raw.root, warehouse, jobs=1)
    rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 1
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": [1, 2, 3, 4], "p_b[bar]": T, "x[mm]": T})  # other kind
    s = rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 1 and "zz_count" in s.stages_reused
    assert "plpa_characterisation" in s.stages_run
    step(raw, "c/c.csv")
    rebuild(raw.root, warehouse, jobs=1)
    assert CountingStage.calls == 2
    assert q(warehouse, "SELECT n_step_runs FROM zz_count") == [(2,)]
    rebuild(raw.root, warehouse, jobs=1, full=True)
    assert CountingStage.calls == 3


def test_logbook_change_reruns_durability_only(raw, warehouse):
    step(raw, "c/a.csv")
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n,failure_mode,distance_km\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858,,\n"
                             "H1,failed,2026-02-01T00:00:00,,,,rupture,80\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert "durability" in s.stages_run and "plpa_characterisation" in s.stages_reused
    assert q(warehouse, "SELECT status FROM rebuild_changes WHERE source_path = 'c/hoses.csv'") == [("changed",)]
    assert q(warehouse, "SELECT hose_id, status FROM hose_life") == [("H1", "failed")]


class PlanReader:
    """Reads the test plan (and step runs); counts its calls, writes a hose type's margin."""
    NAME, READS, WRITES = "zz_plan_reader", Reads(kinds=("step",), plan=True), ("zz_plan",)
    calls = 0

    @classmethod
    def run(cls, ctx):
        cls.calls += 1
        s = ctx.plan.for_hose_type("FLEXIGOM AIR")
        return StageOutput(tables={"zz_plan": pd.DataFrame({"present": [s.present], "margin": [s.margin],
                                                            "source": [s.sources["margin"]]})})


def test_a_stage_that_reads_the_plan_reruns_only_when_what_the_plan_says_changes(raw, warehouse, monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), PlanReader])
    step(raw, "c/a.csv")
    age(raw.root)
    PlanReader.calls = 0
    rebuild(raw.root, warehouse, jobs=1)
    assert PlanReader.calls == 1
    assert q(warehouse, "SELECT present, margin, source FROM zz_plan") == [(False, 1.25, "built-in")]
    raw.write("plan.toml", '[hose_type."FLEXIGOM AIR"]\nmargin = 1.5\n')
    s = rebuild(raw.root, warehouse, jobs=1)
    assert PlanReader.calls == 2 and "zz_plan_reader" in s.stages_run and "plpa_characterisation" in s.stages_reused
    assert q(warehouse, "SELECT present, margin, source FROM zz_plan") == [(True, 1.5, "hose_type")]
    raw.write("plan.toml", '# agreed on 2026-01-05\n[hose_type."FLEXIGOM AIR"]\nmargin = 1.5   # force vs distance\n')
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")  # not declared
    s = rebuild(raw.root, warehouse, jobs=1)
    assert PlanReader.calls == 2 and "zz_plan_reader" in s.stages_reused and "durability" in s.stages_run
    raw.write("plan.toml", '[defaults]\nmargin = 1.3\n')
    s = rebuild(raw.root, warehouse, jobs=1)
    assert PlanReader.calls == 3
    assert q(warehouse, "SELECT present, margin, source FROM zz_plan") == [(True, 1.3, "defaults")]
    (raw.root / "plan.toml").unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert PlanReader.calls == 4 and q(warehouse, "SELECT present, margin FROM zz_plan") == [(False, 1.25)]


class MarginReader:
    """Declares only the plan's margin; reads ``key`` (set by the test)."""
    NAME, READS, WRITES = "zz_margin_reader", Reads(kinds=("step",), plan=("margin",)), ("zz_margin",)
    key, calls = "margin", 0

    @classmethod
    def run(cls, ctx):
        cls.calls += 1
        value = getattr(ctx.plan.for_hose_type("FLEXIGOM AIR"), cls.key)
        return StageOutput(tables={"zz_margin": pd.DataFrame({"value": [value], "present": [ctx.plan.present]})})


def test_a_stage_that_declares_plan_keys_reruns_only_when_they_change_and_reads_no_other(raw, warehouse,
                                                                                         monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), MarginReader])
    step(raw, "c/a.csv")
    age(raw.root)
    MarginReader.calls, MarginReader.key = 0, "margin"
    raw.write("plan.toml", "[defaults]\nmargin = 1.5\n")
    rebuild(raw.root, warehouse, jobs=1)
    assert MarginReader.calls == 1 and q(warehouse, "SELECT value, present FROM zz_margin") == [(1.5, True)]
    raw.write("plan.toml", "[defaults]\nmargin = 1.5\nalpha = 0.01\nmax_failures = 40\n")  # not its keys
    s = rebuild(raw.root, warehouse, jobs=1)
    assert MarginReader.calls == 1 and "zz_margin_reader" in s.stages_reused
    raw.write("plan.toml", '[defaults]\nmargin = 1.5\n[hose_type."FLEXIGOM AIR"]\nmargin = 2.0\n')
    s = rebuild(raw.root, warehouse, jobs=1)
    assert MarginReader.calls == 2 and q(warehouse, "SELECT value FROM zz_margin") == [(2.0,)]
    # a hose type's table that sets none of its keys gives that type what any other gets: not re-run
    raw.write("plan.toml", '[defaults]\nmargin = 1.5\n[hose_type."FLEXIGOM AIR"]\nmargin = 2.0\n'
                           '[hose_type."OTHER"]\nalpha = 0.01\n')
    s = rebuild(raw.root, warehouse, jobs=1)
    assert MarginReader.calls == 2 and "zz_margin_reader" in s.stages_reused
    raw.write("plan.toml", '[defaults]\nmargin = 1.5\n[hose_type."FLEXIGOM AIR"]\nmargin = 2.0\n'
                           '[hose_type."OTHER"]\nalpha = 0.01\nmargin = 1.5\n')  # same value, its own table
    s = rebuild(raw.root, warehouse, jobs=1)
    assert MarginReader.calls == 3 and "zz_margin_reader" in s.stages_run
    MarginReader.key = "alpha"
    with pytest.raises(RebuildError, match="read the plan's alpha, which its READS does not declare"):
        rebuild(raw.root, warehouse, jobs=1, full=True)


def test_durability_reruns_on_a_plan_key_it_reads_and_not_on_one_only_the_verdict_reads(raw, warehouse):
    """Issue 26: stages are keyed by the plan keys they declare. ``power`` and ``max_failures`` are read
    by ``decision`` and ``test_plan`` (the whole plan), not by ``durability`` (``confidence``, ``b_life``,
    ``mission_km``)."""
    from pipeline.stages import durability

    assert "power" not in durability.READS.plan_keys() and "confidence" in durability.READS.plan_keys()
    step(raw, "c/a.csv")
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             "H1,installed,2026-01-01T00:00:00,FLEXIGOM AIR,force,858\n")
    raw.write("plan.toml", "[defaults]\npower = 0.8\nconfidence = 0.9\n")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    raw.write("plan.toml", '[defaults]\npower = 0.85\nconfidence = 0.9\n[hose_type."FLEXIGOM AIR"]\n'
                           "max_failures = 30\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert "durability" in s.stages_reused and {"decision", "test_plan"} <= set(s.stages_run)
    raw.write("plan.toml", '[defaults]\npower = 0.85\nconfidence = 0.95\n[hose_type."FLEXIGOM AIR"]\n'
                           "max_failures = 30\n")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert "durability" in s.stages_run and "plpa_characterisation" in s.stages_reused


@pytest.mark.parametrize("where", ["absolute", "dot-dot", "another stage's", "a link out"])
def test_a_stage_record_naming_a_folder_outside_its_own_is_never_reused(raw, warehouse, tmp_path, where):
    """A warehouse reuses only its own stage folders (``stages/<stage>/<key>``, real folders): a
    record naming one elsewhere (an absolute path to another warehouse, ``..``, another stage's name,
    a folder that is a link out) re-runs the stage, and the next rebuild records its own folder."""
    import shutil

    import duckdb

    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    other = tmp_path / "other"
    shutil.copytree(warehouse, other, symlinks=True)
    own = q(warehouse, "SELECT folder FROM stage_cache WHERE stage = 'models'")[0][0]
    key = own.rsplit("/", 1)[1]
    if where == "a link out":
        shutil.rmtree(warehouse / own)
        (warehouse / own).symlink_to(other / own, target_is_directory=True)
        folder = own
    else:
        folder = {"absolute": str(other / own), "dot-dot": f"stages/../../other/{own}",
                  "another stage's": f"stages/durability/{key}"}[where]
        con = duckdb.connect(str(warehouse / "pneubench.duckdb"))
        con.execute("UPDATE stage_cache SET folder = ? WHERE stage = 'models'", [folder])
        con.close()
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.mode == "incremental" and "models" in s.stages_run and "plpa_characterisation" in s.stages_reused
    assert q(warehouse, "SELECT folder FROM stage_cache WHERE stage = 'models'") == [(own,)]
    assert rebuild(raw.root, warehouse, jobs=1).mode == "no-op"


class SneakyStage:
    """Declares step runs; reads what ``read`` says (set by the test)."""
    NAME, READS, WRITES = "zz_sneaky", Reads(kinds=("step",)), ("zz_sneaky",)
    read = None

    @classmethod
    def run(cls, ctx):
        cls.read(ctx)
        return StageOutput(tables={"zz_sneaky": pd.DataFrame({"n": [len(ctx.runs_of("step"))]})})


@pytest.mark.parametrize("read, what", [
    (lambda ctx: ctx.results.get("leakage_map"), "table 'leakage_map'"),
    (lambda ctx: "breakaway" in ctx.results, "table 'breakaway'"),
    (lambda ctx: ctx.runs_of("breakaway"), "runs of kind breakaway"),
    (lambda ctx: ctx.raw, "raw/ \\(the hose logbooks\\)"),
    (lambda ctx: ctx.plan, "the test plan \\(raw/plan.toml\\)"),
])
def test_a_stage_that_reads_what_it_did_not_declare_fails_the_rebuild(raw, warehouse, monkeypatch, read, what):
    step(raw, "c/a.csv")
    rebuild(raw.root, warehouse, jobs=1)
    before = q(warehouse, "SELECT generation FROM rebuild_log")
    monkeypatch.setattr(SneakyStage, "read", staticmethod(read))
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), SneakyStage])
    step(raw, "c/b.csv")
    with pytest.raises(RebuildError, match=f"stage zz_sneaky failed: UndeclaredRead: stage zz_sneaky read {what}, "
                                           "which its READS does not declare"):
        rebuild(raw.root, warehouse, jobs=1)
    assert q(warehouse, "SELECT generation FROM rebuild_log") == before  # the previous warehouse stays


def test_a_declared_read_runs_and_sees_only_its_kinds(raw, warehouse, monkeypatch):
    seen = {}
    monkeypatch.setattr(SneakyStage, "read", staticmethod(lambda ctx: seen.update(kinds=set(ctx.runs["kind"]))))
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), SneakyStage])
    step(raw, "c/a.csv")
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    s = rebuild(raw.root, warehouse, jobs=1)
    assert "zz_sneaky" in s.stages_run and seen["kinds"] == {"step"}
    assert q(warehouse, "SELECT n FROM zz_sneaky") == [(1,)]


class First:
    NAME, READS, WRITES = "zz_first", Reads(tables=("zz_second_t",)), ("zz_first_t",)

    @staticmethod
    def run(ctx):
        return StageOutput()


class Second:
    NAME, READS, WRITES = "zz_second", Reads(tables=("zz_first_t",)), ("zz_second_t",)

    @staticmethod
    def run(ctx):
        return StageOutput()


def test_stages_that_read_each_other_in_a_circle_are_refused_before_any_stage_runs(raw, warehouse, monkeypatch):
    step(raw, "c/a.csv")
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), First, Second])
    with pytest.raises(RebuildError, match="^stages read each other's tables in a circle: "
                                           "zz_first reads from zz_second reads from zz_first$"):
        rebuild(raw.root, warehouse, jobs=1)


def test_the_real_stages_run_in_the_order_they_always_had(raw, warehouse):
    """The four stages keep their order; the decision stages (issue 23) come after durability,
    the findings after the decision (they read its verdict), remaining life after both (issue 24)."""
    step(raw, "c/a.csv")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.stages_run == ["plpa_characterisation", "models", "durability_runs", "durability", "decision", "findings",
                            "remaining_life", "test_plan"]


def test_durations_read_in_ms_below_a_second():
    assert duration_text(0.0123) == "12 ms" and duration_text(3.44) == "3.4 s"


class TableReader:
    """Reads the ``breakaway`` table of an earlier stage, no runs; counts its calls."""
    NAME, READS, WRITES = "zz_table_reader", Reads(tables=("breakaway",)), ("zz_breakaways",)
    calls = 0

    @classmethod
    def run(cls, ctx):
        cls.calls += 1
        return StageOutput(tables={"zz_breakaways": pd.DataFrame({"n": [len(ctx.results["breakaway"])]})})


def test_a_stage_reruns_when_a_table_it_reads_changes_and_only_then(raw, warehouse, monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), TableReader])
    step(raw, "c/a.csv")
    raw.csv("c/b.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})
    age(raw.root)
    TableReader.calls = 0
    rebuild(raw.root, warehouse, jobs=1)
    assert TableReader.calls == 1
    step(raw, "c/c.csv")  # another step run: not what it reads
    s = rebuild(raw.root, warehouse, jobs=1)
    assert TableReader.calls == 1 and "zz_table_reader" in s.stages_reused
    raw.csv("c/d.csv", BREAK, {"t[s]": T, "p_a[bar]": T, "p_b[bar]": T, "x[mm]": T})  # one more breakaway row
    s = rebuild(raw.root, warehouse, jobs=1)
    assert TableReader.calls == 2 and "zz_table_reader" in s.stages_run
    assert q(warehouse, "SELECT n FROM zz_breakaways") == [(2,)]
    assert q(warehouse, "SELECT results_read FROM stage_cache WHERE stage = 'zz_table_reader'")[0][0].startswith(
        '{"breakaway": ')


def test_the_run_columns_read_from_the_runs_once_are_the_ones_read_from_the_runs_frame():
    """Every stage's tables get their run columns from the runs read out once into object columns
    (issue 26): the same columns, types and values as from the runs frame itself (Arrow strings)."""
    from pipeline.rebuild.stage_runner import _run_columns_source
    from pipeline.stages import add_run_columns

    runs = pd.DataFrame({"run_id": pd.array(["a", "b", "c", "d"], dtype="str"),
                         "campaign": pd.array(["c1", None, "c2", "c1"], dtype="str"),
                         "kind": ["leakage"] * 4,
                         "params": [{"hose_id": "H1"}, {}, {"hose_id": float("nan")}, {"hose_id": 7}]})
    tables = {"leakage_map": pd.DataFrame({"run_id": ["a", "b", "d", "x"], "chamber": ["A"] * 4,
                                           "adjustment": ["force"] * 4, "z_rollers_mm": [1.0] * 4,
                                           "spring_force_n": [2.0, 2.0, 3.0, 3.0], "runs_used": ["runs"] * 4}),
              "seal_envelope": pd.DataFrame({"chamber": ["A", "A"], "adjustment": ["force", "force"],
                                             "z_rollers_mm": [1.0, 1.0], "spring_force_n": [2.0, 3.0],
                                             "runs_used": ["runs", "hose_checks"]}),
              "empty": pd.DataFrame({"run_id": pd.array([], dtype="str")}), "no_runs": pd.DataFrame({"v": [1]})}
    from pipeline.stages.run_columns import run_lookup

    slim = _run_columns_source(runs)
    assert list(slim.columns) == ["run_id", "campaign", "params"] and (slim.dtypes == object).all()
    # and read out once into a lookup for every stage (what the rebuild passes): the same columns again
    a, b, c = add_run_columns(tables, runs), add_run_columns(tables, slim), add_run_columns(tables, run_lookup(slim))
    assert list(a) == list(b) == list(c)
    for t in a:
        pd.testing.assert_frame_equal(a[t], b[t], check_exact=True)
        pd.testing.assert_frame_equal(a[t], c[t], check_exact=True)
    assert run_lookup(slim).hose == {"a": "H1", "d": "7"} and run_lookup(runs.head(0)) is None
    plain = lambda col: [None if pd.isna(v) else v for v in a["leakage_map"][col]]  # noqa: E731
    assert plain("hose_id") == ["H1", None, "7", None] and plain("campaign") == ["c1", None, "c1", None]
    assert list(a["seal_envelope"]["n_runs"]) == [1, 1] and "campaign" in a["empty"]
    assert _run_columns_source(runs.head(0)).empty
    assert _run_columns_source(runs[["run_id"]]) is not None and len(_run_columns_source(runs[["run_id"]]).columns) == 1


def test_reused_tables_are_those_only_reused_stages_wrote_while_the_stages_are_the_previous_ones():
    from pipeline.rebuild.stage_runner import StageResults, reused_tables
    from pipeline.rebuild.state import PreviousState

    res = StageResults(ran=["b"], reused=["a", "c"],
                       origins={"t_a": {"a"}, "t_b": {"b"}, "t_ab": {"a", "b"}, "t_ac": {"a", "c"}})
    prev = PreviousState(stages={"a": None, "b": None, "c": None})
    assert reused_tables(res, prev) == {"t_a", "t_ac"}
    assert reused_tables(res, PreviousState(stages={"a": None, "b": None})) == set()   # a stage added
    assert reused_tables(res, PreviousState()) == set()                                 # no previous rebuild
