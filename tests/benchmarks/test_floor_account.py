"""The floor's accounting (issue 26): one rebuild in a child process, its items, imports and collections timed."""
from benchmarks import floor_account as fa
from pipeline.rebuild.flow import rebuild
from tests.conftest import PROJECT_ROOT, STEP_META

T = [0.0, 0.1, 0.2, 0.3]


def test_one_change_is_accounted_item_by_item_within_the_process_and_its_tree(raw, tmp_path, monkeypatch):
    monkeypatch.setenv("FLOOR_FIRST_IMPORTS", "duckdb,not.a.module")
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4})
    data = tmp_path / "copy"
    data.mkdir()
    (data / "raw").symlink_to(raw.root)
    rebuild(raw.root, data / "warehouse", jobs=1)
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [0, 1, 2, 2], "x_ref[mm]": [3] * 4})
    got = fa._account(PROJECT_ROOT, data, tmp_path / "times.json")
    items = got["items"]
    assert 0 < got["start-up (before pipeline is imported)"] < got["process at exit"] <= got["tree CPU"] + 0.05
    assert 0 < items["rebuild"] < got["process at exit"]
    assert items["_plan"] + items["_ingest"] + items["_stages"] + items["_publish"] <= items["rebuild"] + 1e-6
    assert 0 < items["imports (all)"] < items["rebuild"] and items.get("imports pandas", 0) > 0
    assert got["calls"]["load_stage_folder"] >= 1 or got["calls"].get("_run_stage", 0) >= 1
    assert any(k.startswith("gc (Python's collections, generation ") for k in items)
    assert items["rebuild"] - got["items less imports"]["rebuild"] <= items["imports (all)"] + 1e-6
    # who imported a module first: the last frames that reached the import (importlib and this module left out)
    first = got["first imports"]
    assert set(first) == {"first import duckdb"}
    assert first["first import duckdb"] and all(":" in f for f in first["first import duckdb"])
    assert any(f.split(":")[0].endswith(".py") for f in first["first import duckdb"])
