"""The per-item memo of the stages' per-run work: one changed run costs its own analysis, the
result equals a full rebuild, a code change or a damaged memo file recomputes, and memo entries
of runs that are gone are not kept."""
import os
import pickle
import time

import pytest

import pipeline.memo as memo_mod
import pipeline.rebuild as rb
import pipeline.state as state_mod
from pipeline.memo import Memo, item_key
from pipeline.rebuild import rebuild
from pipeline.stages import StageContext
from pipeline.stages import plpa_characterisation as plpa
from tests.conftest import STEP_META
from tests.pipeline.test_state import BREAK, age, dump, step

T = [0.0, 0.1, 0.2, 0.3]


def breakaway(raw, rel, scale=1.0):
    return raw.csv(rel, BREAK, {"t[s]": T, "p_a[bar]": [v * scale for v in T], "p_b[bar]": T, "x[mm]": T})


@pytest.fixture
def stages_of(monkeypatch):
    """The StageResults of every rebuild (memo hits and computed items per stage)."""
    seen = []
    real = rb.run_stages_cached

    def spy(*a, **k):
        seen.append(real(*a, **k))
        return seen[-1]

    monkeypatch.setattr(rb, "run_stages_cached", spy)
    return seen


def counts(res, stage):
    m = res.memos[stage]
    return m.hits, m.computed


def campaign(raw, n=4):
    for i in range(n):
        breakaway(raw, f"c/b{i}.csv", scale=1 + i)
        step(raw, f"c/s{i}.csv", scale=1 + i)
    age(raw.root)


# -- keys --------------------------------------------------------------------------------------
def test_the_key_holds_samples_paths_relative_to_the_warehouse(tmp_path):
    a = item_key(plpa.analyse_run, ("breakaway", "c/b", str(tmp_path / "w1" / "samples/x-0123.parquet"), {"p": 1.5}),
                 tmp_path / "w1")
    b = item_key(plpa.analyse_run, ("breakaway", "c/b", str(tmp_path / "w2" / "samples/x-0123.parquet"), {"p": 1.5}),
                 tmp_path / "w2")
    assert a == b and len(a) == 64
    other = item_key(plpa.analyse_run, ("breakaway", "c/b", str(tmp_path / "w1" / "samples/y-0123.parquet"),
                                        {"p": 1.5}), tmp_path / "w1")
    assert other != a
    # dict order does not matter; types do (a tuple is not a list, 1 is not 1.0 or True)
    assert item_key(plpa.analyse_run, {"a": 1, "b": 2}, tmp_path) == item_key(plpa.analyse_run, {"b": 2, "a": 1},
                                                                              tmp_path)
    keys = {item_key(plpa.analyse_run, v, tmp_path) for v in ((1,), [1], 1, 1.0, True, "1", {"x": float("nan")})}
    assert len(keys) == 7


def test_items_that_cannot_be_serialised_canonically_are_not_memoised(tmp_path):
    assert item_key(plpa.analyse_run, ("x", object()), tmp_path) is None
    assert item_key(plpa.analyse_run, {1: "int key"}, tmp_path) is None
    assert item_key(lambda x: x, "x", tmp_path) is None
    ctx = StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=Memo(tmp_path, "s"))
    assert ctx.map(_double, [(1, object()), 2], "t") == [None, 4]
    ctx.memo.save()
    stored = pickle.loads((tmp_path / "memo" / "s.pkl").read_bytes())["entries"]
    assert len(stored) == 1 and ctx.memo.unkeyed == 1


def _double(item):
    return item * 2 if isinstance(item, int) else None


def test_the_key_changes_with_the_code_version(tmp_path, monkeypatch):
    item = ("breakaway", "c/b", "samples/x.parquet", {})
    before = item_key(plpa.analyse_run, item, tmp_path)
    monkeypatch.setattr(memo_mod, "code_version", lambda func: "edited")
    assert item_key(plpa.analyse_run, item, tmp_path) != before


# -- the memo on its own -----------------------------------------------------------------------
def test_a_context_without_a_memo_maps_as_before_and_with_one_computes_only_new_items(tmp_path):
    plain = StageContext(raw=tmp_path, warehouse=tmp_path, runs=None)
    assert plain.map(_double, [1, 2, 3]) == [2, 4, 6]
    m = Memo(tmp_path, "s")
    assert StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m).map(_double, [1, 2, 3]) == [2, 4, 6]
    m.save()
    m2 = Memo(tmp_path, "s")
    assert StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m2).map(_double, [3, 4, 1]) == [6, 8, 2]
    assert (m2.hits, m2.computed) == (2, 1)
    m2.save()  # only the entries of this run are kept
    assert len(pickle.loads((tmp_path / "memo" / "s.pkl").read_bytes())["entries"]) == 3
    m3 = Memo(tmp_path, "s", read=False)  # --full: computes everything, writes
    StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m3).map(_double, [3, 4])
    assert (m3.hits, m3.computed) == (0, 2)


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "other pickle", "bad entry", "directory"])
def test_a_damaged_memo_file_is_a_miss_never_a_failure(tmp_path, damage):
    m = Memo(tmp_path, "s")
    StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m).map(_double, [1, 2])
    m.save()
    f = tmp_path / "memo" / "s.pkl"
    good = f.read_bytes()
    if damage == "garbage":
        f.write_bytes(b"\x80\x05not a pickle at all")
    elif damage == "truncated":
        f.write_bytes(good[: len(good) // 2])
    elif damage == "empty":
        f.write_bytes(b"")
    elif damage == "other pickle":
        f.write_bytes(pickle.dumps(["a", "list"]))
    elif damage == "bad entry":
        data = pickle.loads(good)
        data["entries"] = {k: b"\x80\x05broken" for k in data["entries"]}
        f.write_bytes(pickle.dumps(data))
    else:
        f.unlink()
        f.mkdir()
    m2 = Memo(tmp_path, "s")
    assert StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m2).map(_double, [1, 2]) == [2, 4]
    assert (m2.hits, m2.computed) == (0, 2)
    m2.save()  # a file that is a directory is left alone, without an error


def test_a_memo_folder_that_is_a_symlink_is_neither_read_nor_written(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "s.pkl").write_bytes(pickle.dumps({"format": memo_mod.FORMAT, "entries": {}}))
    wh = tmp_path / "wh"
    wh.mkdir()
    os.symlink(elsewhere, wh / "memo")
    m = Memo(wh, "s")
    StageContext(raw=tmp_path, warehouse=wh, runs=None, memo=m).map(_double, [1])
    m.save()
    assert sorted(p.name for p in elsewhere.iterdir()) == ["s.pkl"]
    assert pickle.loads((elsewhere / "s.pkl").read_bytes())["entries"] == {}


# -- in the rebuild ----------------------------------------------------------------------------
def test_one_changed_run_computes_only_its_item_and_equals_a_full_rebuild(raw, tmp_path, stages_of):
    inc, full = tmp_path / "inc", tmp_path / "full"
    campaign(raw)
    rebuild(raw.root, inc, jobs=1)
    assert counts(stages_of[-1], "plpa_characterisation") == (0, 4)
    breakaway(raw, "c/b2.csv", scale=9.0)
    age(raw.root)
    s = rebuild(raw.root, inc, jobs=2)
    assert "plpa_characterisation" in s.stages_run and "models" in s.stages_reused
    assert counts(stages_of[-1], "plpa_characterisation") == (3, 1)
    rebuild(raw.root, full, jobs=2, full=True)
    assert counts(stages_of[-1], "plpa_characterisation") == (0, 4)  # --full does not read the memo
    a, b = dump(inc), dump(full)
    assert set(a) == set(b)
    for table in a:
        assert a[table] == b[table], table
    assert a["breakaway"] and a["step_response"]
    # a moved warehouse still hits
    os.rename(inc, tmp_path / "moved")
    step(raw, "c/s0.csv", scale=5.0)
    age(raw.root)
    rebuild(raw.root, tmp_path / "moved", jobs=1)
    assert counts(stages_of[-1], "models") == (3, 1)


def test_a_code_change_of_the_analysis_recomputes_every_item(raw, warehouse, stages_of, monkeypatch):
    campaign(raw)
    rebuild(raw.root, warehouse, jobs=1)
    real = state_mod.stage_code_version

    def edited(module_file):
        return real(module_file) + ("-edited" if module_file.endswith("plpa_characterisation.py") else "")

    monkeypatch.setattr(state_mod, "stage_code_version", edited)  # what the memo keys use
    monkeypatch.setattr(rb, "stage_code_version", edited)         # what the stage cache uses
    if hasattr(rb, "project_code_version"):                       # what the no-op fast path uses
        real_project = rb.project_code_version
        monkeypatch.setattr(rb, "project_code_version", lambda: real_project() + "-edited")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.stages_run == ["plpa_characterisation"]
    assert counts(stages_of[-1], "plpa_characterisation") == (0, 4)


def test_a_damaged_memo_file_in_the_warehouse_recomputes(raw, tmp_path, stages_of):
    wh, full = tmp_path / "wh", tmp_path / "full"
    campaign(raw)
    rebuild(raw.root, wh, jobs=1)
    (wh / "memo" / "plpa_characterisation.pkl").write_bytes(b"\x80\x05\x95 damaged")
    breakaway(raw, "c/b0.csv", scale=3.0)
    age(raw.root)
    s = rebuild(raw.root, wh, jobs=1)
    assert s.exit_code == 0
    assert counts(stages_of[-1], "plpa_characterisation") == (0, 4)
    rebuild(raw.root, full, jobs=1, full=True)
    assert dump(wh) == dump(full)
    breakaway(raw, "c/b1.csv", scale=3.0)  # and the rewritten memo is used again
    age(raw.root)
    rebuild(raw.root, wh, jobs=1)
    assert counts(stages_of[-1], "plpa_characterisation") == (3, 1)


def test_memo_entries_of_runs_that_are_gone_are_not_kept(raw, warehouse, stages_of):
    campaign(raw)
    rebuild(raw.root, warehouse, jobs=1)
    f = warehouse / "memo" / "plpa_characterisation.pkl"

    def entries():
        return len(pickle.loads(f.read_bytes())["entries"])

    assert entries() == 4
    (raw.root / "c/b3.csv").unlink()
    (raw.root / "c/b1.csv").unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert counts(stages_of[-1], "plpa_characterisation") == (2, 0)
    assert entries() == 2
    for rel in ("c/b0.csv", "c/b2.csv"):  # no run of the kind left: no memo file
        (raw.root / rel).unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert not f.exists()
    assert (warehouse / "memo" / "models.pkl").is_file()


def test_the_clean_up_collects_memo_files_of_gone_stages_and_temp_files_only(raw, warehouse):
    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    memo = warehouse / "memo"
    gone = memo / "zz_removed_stage.pkl"                # a stage that no longer exists: collected
    gone.write_bytes(b"x")
    debris = memo / ".models.pkl.tmp-12345"              # a killed rebuild's temp file: collected
    debris.write_bytes(b"partial")
    foreign = {memo / "notes.txt": b"mine", memo / "Models.PKL": b"not a writer name"}
    for p, data in foreign.items():
        p.write_bytes(data)
    live = (memo / "models.pkl").read_bytes()
    rebuild(raw.root, warehouse, jobs=1)
    assert not gone.exists() and not debris.exists()
    assert (memo / "models.pkl").read_bytes() == live  # the stage was reused: its memo kept as it is
    for p, data in foreign.items():
        assert p.read_bytes() == data


def test_a_memo_file_goes_with_its_stage_folder_after_the_retention(raw, warehouse, monkeypatch):
    import pipeline.stages as st

    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    assert (warehouse / "memo" / "models.pkl").is_file()
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [m for m in real() if m.NAME != "models"])
    step(raw, "c/b.csv")  # a change each time: not a no-op rebuild (removing a stage's file is one)
    rebuild(raw.root, warehouse, jobs=1)  # its last folder is kept for readers (24 h), and so is its memo
    assert (warehouse / "memo" / "models.pkl").is_file()
    step(raw, "c/c.csv")
    rebuild(raw.root, warehouse, jobs=1, clock=lambda: time.time() + 25 * 3600)
    assert not (warehouse / "memo" / "models.pkl").exists()
