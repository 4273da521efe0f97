"""Stage declarations: which modules are stages, and the order they run in (writers of what a stage
reads first; a circle refused with one line naming it)."""
import pytest

from pipeline.stages import Reads, StageCircle, discover, reads_of, run_order, writes_of


def stage(name, reads=(), writes=()):
    return type(name, (), {"NAME": name, "READS": Reads(tables=tuple(reads)), "WRITES": tuple(writes)})


def names(stages):
    return [s.NAME for s in stages]


def test_the_real_stages_run_in_the_order_their_old_order_numbers_gave():
    # the decision stages read durability's tables, the findings the decision's verdict, remaining_life both
    assert names(run_order(discover())) == ["plpa_characterisation", "models", "durability_runs", "durability",
                                            "decision", "findings", "remaining_life", "test_plan"]


def test_every_stage_declares_what_it_reads_and_writes_and_no_two_write_one_table():
    mods = discover()
    written = [t for m in mods for t in writes_of(m)]
    assert len(written) == len(set(written)) and all(writes_of(m) for m in mods)
    assert all(isinstance(m.READS, Reads) for m in mods)
    assert reads_of(next(m for m in mods if m.NAME == "durability")).logbooks


def test_a_stage_runs_after_the_writers_of_the_tables_it_reads_whatever_their_names():
    a, z = stage("a", reads=["t"]), stage("z", writes=["t"])
    assert names(run_order([a, z])) == ["z", "a"]


def test_the_writers_run_in_the_order_the_reader_lists_their_tables_and_unrelated_stages_by_name():
    end = stage("end", reads=["from_y", "from_x"])
    x, y, lone = stage("x", writes=["from_x"]), stage("y", writes=["from_y"]), stage("lone")
    assert names(run_order([x, lone, end, y])) == ["y", "x", "end", "lone"]


def test_a_table_no_stage_writes_is_no_dependency_and_a_stage_without_declarations_reads_nothing():
    bare = type("bare", (), {"NAME": "bare"})
    assert reads_of(bare) == Reads() and writes_of(bare) == ()
    assert names(run_order([stage("b", reads=["nobody_writes_it"]), bare])) == ["b", "bare"]


@pytest.mark.parametrize("stages, circle", [
    ([stage("a", reads=["tb"], writes=["ta"]), stage("b", reads=["ta"], writes=["tb"])], "a reads from b reads from a"),
    ([stage("a", reads=["tc"], writes=["ta"]), stage("b", reads=["ta"], writes=["tb"]),
      stage("c", reads=["tb"], writes=["tc"]), stage("d", reads=["ta"])], "a reads from c reads from b reads from a"),
    ([stage("self", reads=["t"], writes=["t"])], "self reads from self"),
])
def test_declarations_that_read_each_other_in_a_circle_are_refused_in_one_line_naming_it(stages, circle):
    with pytest.raises(StageCircle) as exc:
        run_order(stages)
    assert str(exc.value) == f"stages read each other's tables in a circle: {circle}"
