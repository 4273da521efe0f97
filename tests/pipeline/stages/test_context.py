"""The context a stage reads through: the plain StageContext, and the DeclaredContext the rebuild
gives a stage, which holds what the stage declared and raises on anything else."""
from pathlib import Path

import pandas as pd
import pytest

from pipeline.stages import Carrying, DeclaredContext, Reads, StageContext, StageOutput, UndeclaredRead

RUNS = pd.DataFrame({"run_id": ["c/b", "c/a", "c/l"], "kind": ["step", "step", "leakage"],
                     "samples_path": ["b.parquet", "a.parquet", "l.parquet"]})
TABLES = {"leakage_map": pd.DataFrame({"x": [1]}), "breakaway": pd.DataFrame({"y": [2]})}


def declared(reads: Reads) -> DeclaredContext:
    return DeclaredContext("demo", reads, raw=Path("/raw"), warehouse=Path("/wh"), runs=RUNS, results=TABLES)


def test_a_plain_context_reads_everything():
    ctx = StageContext(raw=Path("/raw"), warehouse=Path("/wh"), runs=RUNS, results=TABLES)
    assert list(ctx.runs_of("step")["run_id"]) == ["c/a", "c/b"] and ctx.raw == Path("/raw")
    assert ctx.results.get("breakaway") is TABLES["breakaway"] and ctx.samples_file("c/l") == Path("/wh/l.parquet")


def test_a_declared_context_holds_the_declared_runs_tables_and_logbooks():
    ctx = declared(Reads(kinds=("step",), tables=("leakage_map", "absent"), logbooks=True))
    assert list(ctx.runs["run_id"]) == ["c/b", "c/a"] and list(ctx.runs_of("step")["run_id"]) == ["c/a", "c/b"]
    assert ctx.samples_file("c/a") == Path("/wh/a.parquet") and ctx.raw == Path("/raw")
    assert ctx.results["leakage_map"] is TABLES["leakage_map"] and ctx.results.get("absent") is None
    assert "absent" not in ctx.results and list(ctx.results) == ["leakage_map"] and len(ctx.results) == 1
    with pytest.raises(KeyError):
        ctx.samples_file("c/l")  # not a run of a declared kind: not there at all


@pytest.mark.parametrize("read, message", [
    (lambda ctx: ctx.results.get("breakaway"), "stage demo read table 'breakaway', which its READS does not declare"),
    (lambda ctx: ctx.results["breakaway"], "stage demo read table 'breakaway'"),
    (lambda ctx: "breakaway" in ctx.results, "stage demo read table 'breakaway'"),
    (lambda ctx: ctx.runs_of("step", "leakage"), "stage demo read runs of kind leakage, which its READS does not declare"),
    (lambda ctx: ctx.raw, r"stage demo read raw/ \(the hose logbooks\), which its READS does not declare"),
])
def test_a_declared_context_raises_on_what_was_not_declared(read, message):
    with pytest.raises(UndeclaredRead, match=message):
        read(declared(Reads(kinds=("step",), tables=("leakage_map",))))


def test_a_declared_context_of_a_stage_reading_no_runs_has_none():
    ctx = declared(Reads(tables=("leakage_map",)))
    assert ctx.runs.empty and ctx.runs_of().empty


def test_a_stage_output_collects_warnings_and_figure_recipes():
    out = StageOutput()
    out.warn("c/a", "one")
    out.warn("c/a", "two")
    out.draw("fig", dict, 1, caption="A figure.", k=2)
    assert out.warnings == {"c/a": ["one", "two"]} and out.captions == {"fig": "A figure."}
    assert out.figures["fig"].args == (1,) and out.figures["fig"].kwargs == {"k": 2}


class _AllStored:
    """A memo holding a result for every item: nothing is computed."""

    def map(self, compute, func, items, label=""):
        return [f"stored {it}" for it in items]


def test_map_warms_its_modules_only_when_it_computes(tmp_path, monkeypatch):
    """``warm``: imported before the items are computed, not when the memo has every result."""
    import sys

    (tmp_path / "pneubench_warm_probe.py").write_text("LOADED = True\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "pneubench_warm_probe", raising=False)
    ctx = StageContext(raw=Path("/raw"), warehouse=Path("/wh"), runs=RUNS, results=TABLES, memo=_AllStored())
    assert ctx.map(str, [1, 2], warm=("pneubench_warm_probe",)) == ["stored 1", "stored 2"]
    assert "pneubench_warm_probe" not in sys.modules
    assert StageContext(raw=Path("/raw"), warehouse=Path("/wh"), runs=RUNS, results=TABLES).map(
        str, [], warm=("pneubench_warm_probe",)) == []
    assert "pneubench_warm_probe" not in sys.modules
    ctx.memo = None
    assert ctx.map(str, [1, 2], warm=("pneubench_warm_probe",)) == ["1", "2"]
    assert "pneubench_warm_probe" in sys.modules
    monkeypatch.delitem(sys.modules, "pneubench_warm_probe")


def test_an_item_carrying_derived_parts_is_memoised_by_the_item_alone():
    """What an item carries (another memoised map's result) is read by the function, not hashed into its memo key;
    the carrier survives the trip to a worker (pickle) with its key."""
    import pickle

    from pipeline.rebuild.memo import item_key

    item = {"hose_type": "A", "looks": 3}
    carried = Carrying(item, parts=[1.0, 2.0])
    assert carried["parts"] == [1.0, 2.0] and carried["hose_type"] == "A" and "parts" not in item
    key = item_key(test_an_item_carrying_derived_parts_is_memoised_by_the_item_alone, carried, "/wh")
    assert key is not None
    assert key == item_key(test_an_item_carrying_derived_parts_is_memoised_by_the_item_alone,
                           Carrying(item, parts=[9.0]), "/wh")
    assert key != item_key(test_an_item_carrying_derived_parts_is_memoised_by_the_item_alone,
                           Carrying(dict(item, looks=4), parts=[1.0, 2.0]), "/wh")
    back = pickle.loads(pickle.dumps(carried))
    assert back == carried and back.memo_key == item
