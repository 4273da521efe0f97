"""``add_run_columns`` (pipeline/stages/__init__.py): the columns a person filters result tables by."""
import pandas as pd

from pipeline.stages import add_run_columns

RUNS = pd.DataFrame({
    "run_id": ["c1/leak", "c2/check-H7", "c1/brk", "c3/spring-a", "c3/spring-b"],
    "campaign": ["c1", "c2", "c1", "c3", "c3"],
    "params": [{"kind": "leakage"}, '{"kind": "leakage", "hose_id": "H7"}', {}, {}, {}],
})


def test_run_level_tables_get_campaign_and_hose_where_their_runs_name_one():
    tables = {
        "leakage_map": pd.DataFrame({"run_id": ["c1/leak", "c2/check-H7", "gone"], "pressure_bar": [1.0, 2.0, 3.0]}),
        "breakaway": pd.DataFrame({"run_id": ["c1/brk"], "campaign": ["kept"]}),
        "summary": pd.DataFrame({"x": [1]}),
    }
    out = add_run_columns(tables, RUNS)
    lm = out["leakage_map"]
    assert lm["campaign"].tolist()[:2] == ["c1", "c2"] and pd.isna(lm["campaign"].iloc[2])
    assert pd.isna(lm["hose_id"].iloc[0]) and lm["hose_id"].iloc[1] == "H7"
    assert str(lm["campaign"].dtype) == "string"  # typed: an empty table still says VARCHAR
    assert out["breakaway"]["campaign"].tolist() == ["kept"] and "hose_id" not in out["breakaway"]
    assert list(out["summary"].columns) == ["x"]
    assert "campaign" not in tables["leakage_map"]  # inputs untouched


def test_pooled_tables_state_their_campaigns_and_runs_and_the_envelope_leaves_hose_checks_out():
    tables = {
        "leakage_map": pd.DataFrame({"run_id": ["c1/leak", "c1/leak", "c2/check-H7", "c2/check-H7"],
                                     "hose_id": [None, None, "H7", "H7"], "chamber": ["A", "A", "A", "B"],
                                     "adjustment": ["distance"] * 4, "z_rollers_mm": [4.0, 4.0, 4.0, 4.5],
                                     "spring_force_n": [None] * 4}),
        "seal_envelope": pd.DataFrame({"chamber": ["A", "B", "A"], "adjustment": ["distance"] * 3,
                                       "z_rollers_mm": [4.0, 4.5, 9.0], "spring_force_n": [None] * 3,
                                       "runs_used": ["characterisation", "hose_checks", "characterisation"],
                                       "n_runs": [1, 1, 0]}),
        "spring_tests": pd.DataFrame({"run_id": ["c3/spring-a", "c3/spring-b"], "chamber": ["front", "front"]}),
        "spring_fits": pd.DataFrame({"chamber": ["front", "rear"]}),
    }
    out = add_run_columns(tables, RUNS)
    env = out["seal_envelope"]
    assert list(env["campaigns"].iloc[0]) == ["c1"]  # the hose check of the same setting is not pooled
    assert list(env["campaigns"].iloc[1]) == ["c2"]  # a setting with only hose checks says so
    assert env["campaigns"].iloc[2] is None           # nothing matches: NULL, not a guess
    assert env["n_runs"].tolist() == [1, 1, 0]        # the stage's own count is kept
    fits = out["spring_fits"]
    assert list(fits["campaigns"].iloc[0]) == ["c3"] and fits["n_runs"].iloc[0] == 2
    assert fits["campaigns"].iloc[1] is None and pd.isna(fits["n_runs"].iloc[1])


def test_no_runs_leaves_tables_as_they_are():
    tables = {"leakage_map": pd.DataFrame({"run_id": ["a"]})}
    assert add_run_columns(tables, RUNS.iloc[0:0]) is tables


def test_an_empty_table_gets_the_columns_and_dtypes_a_table_with_rows_gets():
    """The shortcut for tables without rows (a reused stage with nothing to do) types them as the
    general path does: ``campaign`` a string column, no ``hose_id`` (no run names a hose)."""
    rows = pd.DataFrame({"run_id": ["c1/leak"], "pressure_bar": [1.0]})
    tables = {"leakage_map": rows.iloc[0:0], "breakaway": pd.DataFrame({"run_id": pd.Series([], dtype="str"),
                                                                         "campaign": pd.Series([], dtype="str")})}
    out = add_run_columns(tables, RUNS)
    full = add_run_columns({"leakage_map": rows}, RUNS)["leakage_map"]
    assert list(out["leakage_map"].columns) == ["run_id", "pressure_bar", "campaign"]
    assert out["leakage_map"].dtypes.to_dict() == full.dtypes.to_dict() and out["leakage_map"].empty
    assert out["breakaway"].dtypes.to_dict() == tables["breakaway"].dtypes.to_dict()
    assert out["breakaway"] is not tables["breakaway"] and "campaign" not in tables["leakage_map"]


def test_a_source_whose_index_labels_repeat_pools_each_of_its_rows_once():
    """The pooled rows are found by position: a source table concatenated without a new index (labels 0, 0, 1)
    gives the same campaigns and run counts as the same rows indexed 0..n-1."""
    rows = {"run_id": ["c3/spring-a", "c3/spring-b", "c1/brk"], "chamber": ["front", "front", "rear"]}
    fits = pd.DataFrame({"chamber": ["front", "rear"]})
    plain = add_run_columns({"spring_tests": pd.DataFrame(rows), "spring_fits": fits}, RUNS)["spring_fits"]
    repeated = pd.DataFrame(rows, index=[0, 0, 1])
    again = add_run_columns({"spring_tests": repeated, "spring_fits": fits}, RUNS)["spring_fits"]
    assert [list(c) for c in again["campaigns"]] == [["c3"], ["c1"]] and again["n_runs"].tolist() == [2, 1]
    pd.testing.assert_frame_equal(again, plain)
