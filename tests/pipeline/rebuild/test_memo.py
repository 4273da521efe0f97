"""The per-item memo of the stages' per-run work: one changed run costs its own analysis, the
result equals a full rebuild, a code change or a damaged memo file recomputes, and memo entries
of runs that are gone are not kept."""
import os
import pickle
import time

import pytest
from pathlib import Path

import pipeline.rebuild.memo as memo_mod
import pipeline.rebuild.flow as rb
import pipeline.rebuild.noop as noop_mod
import pipeline.rebuild.stage_runner as runner
import pipeline.versions as versions_mod
from pipeline.rebuild.memo import Memo, item_key
from pipeline.rebuild.flow import rebuild
from pipeline.stages import StageContext
from pipeline.stages import plpa_characterisation as plpa
from tests.conftest import STEP_META
from tests.pipeline.rebuild.test_state import BREAK, age, dump, step

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


def shard_files(warehouse, stage):
    """``{name: path}`` of a stage's shard files."""
    folder = warehouse / "memo" / stage
    return {p.name: p for p in sorted(folder.glob("*.pkl"))} if folder.is_dir() else {}


def stored(warehouse, stage):
    """Every entry of a stage's memo, all shards merged."""
    out = {}
    for p in shard_files(warehouse, stage).values():
        out.update(pickle.loads(p.read_bytes())["entries"])
    return out


def snapshot(folder, skip=()):
    """``{relative path: (bytes or link target, inode, mtime_ns)}`` of everything under ``folder``
    (symlinks not followed)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = os.path.join(root, name)
            rel = os.path.relpath(p, folder)
            if rel in skip:
                continue
            st = os.lstat(p)
            if os.path.islink(p):
                out[rel] = ("->" + os.readlink(p), st.st_ino, st.st_mtime_ns)
            elif os.path.isfile(p):
                out[rel] = (Path(p).read_bytes(), st.st_ino, st.st_mtime_ns)
    return out


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
    assert len(stored(tmp_path, "s")) == 1 and ctx.memo.unkeyed == 1


def _double(item):
    return item * 2 if isinstance(item, int) else None


class _Keyed(dict):
    def __init__(self, key: dict, payload):
        super().__init__(key, payload=payload)
        self.memo_key = key


def test_an_item_with_a_memo_key_is_keyed_by_it_alone(tmp_path):
    """The decision's looks items carry their parts (objects) but are keyed by the looks item (session 26)."""
    plain = item_key(plpa.analyse_run, {"a": 1}, tmp_path)
    assert item_key(plpa.analyse_run, _Keyed({"a": 1}, object()), tmp_path) == plain
    assert item_key(plpa.analyse_run, _Keyed({"a": 2}, object()), tmp_path) != plain
    ctx = StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=Memo(tmp_path, "s"))
    assert ctx.map(_payload, [_Keyed({"a": 1}, 5)], "t") == [5]
    ctx.memo.save()
    again = Memo(tmp_path, "s")
    assert StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=again).map(
        _payload, [_Keyed({"a": 1}, object())], "t") == [5] and again.hits == 1


def _payload(item):
    return item["payload"]


def test_the_key_changes_with_the_code_version(tmp_path, monkeypatch):
    item = ("breakaway", "c/b", "samples/x.parquet", {})
    before = item_key(plpa.analyse_run, item, tmp_path)
    monkeypatch.setattr(memo_mod, "function_code_version", lambda func: "edited")
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
    assert len(stored(tmp_path, "s")) == 3
    m3 = Memo(tmp_path, "s", read=False)  # --full: computes everything, writes
    StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m3).map(_double, [3, 4])
    assert (m3.hits, m3.computed) == (0, 2)
    m3.save()
    assert sorted(pickle.loads(b) for b in stored(tmp_path, "s").values()) == [6, 8]


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "other pickle", "bad entry", "directory"])
def test_a_damaged_memo_file_is_a_miss_never_a_failure(tmp_path, damage):
    m = Memo(tmp_path, "s")
    StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m).map(_double, [1, 2])
    m.save()
    files = shard_files(tmp_path, "s")
    assert files
    for f in files.values():
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
    m2.save()  # a shard file that is a directory is left alone, without an error
    if damage == "directory":
        assert all(f.is_dir() for f in files.values())
    else:  # the damaged shards are rewritten and hit again
        m3 = Memo(tmp_path, "s")
        StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m3).map(_double, [1, 2])
        assert (m3.hits, m3.computed) == (2, 0)


def test_a_memo_folder_that_is_a_symlink_is_neither_read_nor_written(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    m = Memo(elsewhere, "s")  # a real memo, of another warehouse
    StageContext(raw=tmp_path, warehouse=elsewhere, runs=None, memo=m).map(_double, [1, 5])
    m.save()
    before = snapshot(elsewhere / "memo")
    wh = tmp_path / "wh"
    wh.mkdir()
    os.symlink(elsewhere / "memo", wh / "memo")
    m = Memo(wh, "s")
    StageContext(raw=tmp_path, warehouse=wh, runs=None, memo=m).map(_double, [1])
    assert (m.hits, m.computed) == (0, 1)
    m.save()
    assert snapshot(elsewhere / "memo") == before


def _memo_run(warehouse, items, stage="s", read=True):
    m = Memo(warehouse, stage, read=read)
    out = StageContext(raw=warehouse, warehouse=warehouse, runs=None, memo=m).map(_double, items)
    assert out == [_double(i) for i in items]
    m.save()
    return m


def _shard(item, warehouse):
    return memo_mod.shard_of(item_key(_double, item, warehouse)) + ".pkl"


def test_entries_are_stored_in_shards_named_by_the_keys_first_two_hex_digits(tmp_path):
    items = list(range(300))
    _memo_run(tmp_path, items)
    files = shard_files(tmp_path, "s")
    assert 150 < len(files) <= 256 and set(files) == {_shard(i, tmp_path) for i in items}
    for name, f in files.items():
        data = pickle.loads(f.read_bytes())
        assert data["format"] == memo_mod.FORMAT and data["stage"] == "s" and data["shard"] == name[:2]
        assert data["entries"] and all(k.startswith(name[:2]) for k in data["entries"])
    assert len(stored(tmp_path, "s")) == 300
    assert sorted(os.listdir(tmp_path / "memo")) == ["s"] and not any(
        n.startswith(".") for n in os.listdir(tmp_path / "memo" / "s"))  # no temp file left


def test_one_changed_item_rewrites_its_shards_only(tmp_path, monkeypatch):
    items = list(range(200))
    _memo_run(tmp_path, items)
    before = snapshot(tmp_path / "memo")
    # item 7 is replaced by item 1007 (one run's file changed): the shard that loses 7's key and
    # the one that gains 1007's are rewritten, no other file is written
    changed = {_shard(7, tmp_path), _shard(1007, tmp_path)}
    writes = []
    real = Memo._write
    monkeypatch.setattr(Memo, "_write", lambda self, shard, entries: (writes.append(shard), real(self, shard, entries)))
    m = _memo_run(tmp_path, [1007 if i == 7 else i for i in items])
    assert (m.hits, m.computed) == (199, 1)
    after = snapshot(tmp_path / "memo")
    touched = {rel for rel in before.keys() | after.keys() if before.get(rel) != after.get(rel)}
    assert touched == {os.path.join("s", n) for n in changed}
    assert sorted(f"{w}.pkl" for w in writes) == sorted(n for n in changed if n in shard_files(tmp_path, "s"))
    # the same items again: nothing is written at all
    writes.clear()
    before = snapshot(tmp_path / "memo")
    m = _memo_run(tmp_path, [1007 if i == 7 else i for i in items])
    assert (m.hits, m.computed) == (200, 0) and writes == [] and snapshot(tmp_path / "memo") == before


def test_an_entry_whose_run_is_gone_disappears_and_an_emptied_shard_file_is_removed(tmp_path):
    items = list(range(60))
    _memo_run(tmp_path, items)
    by_shard = {}
    for i in items:
        by_shard.setdefault(_shard(i, tmp_path), []).append(i)
    alone = next(v[0] for v in by_shard.values() if len(v) == 1)  # the only entry of its shard
    shared = next(v for v in by_shard.values() if len(v) > 1)     # a shard that keeps an entry
    gone = {alone, shared[0]}
    m = _memo_run(tmp_path, [i for i in items if i not in gone])
    assert (m.hits, m.computed) == (58, 0)
    assert _shard(alone, tmp_path) not in shard_files(tmp_path, "s")
    assert _shard(shared[0], tmp_path) in shard_files(tmp_path, "s")
    keys = stored(tmp_path, "s")
    assert len(keys) == 58 and not {item_key(_double, i, tmp_path) for i in gone} & keys.keys()
    _memo_run(tmp_path, [], stage="s")  # a run without any item leaves nothing behind
    assert not (tmp_path / "memo" / "s").exists()


def test_only_the_shards_of_the_keys_asked_for_are_read(tmp_path, monkeypatch):
    items = list(range(200))
    _memo_run(tmp_path, items)
    assert len(shard_files(tmp_path, "s")) > 100
    opened = []
    real_open = os.open

    def spy(path, *a, **k):
        if "memo" in os.fspath(path):
            opened.append(os.path.basename(os.fspath(path)))
        return real_open(path, *a, **k)

    monkeypatch.setattr(os, "open", spy)
    m = Memo(tmp_path, "s")
    assert StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m).map(_double, [42]) == [84]
    assert (m.hits, m.computed) == (1, 0)
    assert opened == [_shard(42, tmp_path)]
    # the stage's run now has that item only: the other shards are deleted without being read,
    # and the shard of 42 is written again only if it held other entries
    opened.clear()
    m.save()
    mine = [i for i in items if _shard(i, tmp_path) == _shard(42, tmp_path)]
    assert opened == ([] if mine == [42] else [f".{_shard(42, tmp_path)}.tmp-{os.getpid()}"])
    assert list(shard_files(tmp_path, "s")) == [_shard(42, tmp_path)]
    assert list(stored(tmp_path, "s")) == [item_key(_double, 42, tmp_path)]


def test_a_full_rebuild_writes_every_shard_and_drops_the_others_unread(tmp_path, monkeypatch):
    _memo_run(tmp_path, list(range(100)))
    loads = []
    monkeypatch.setattr(Memo, "_load", lambda self, shard: loads.append(shard) or {})
    m = _memo_run(tmp_path, list(range(50, 150)), read=False)
    assert (m.hits, m.computed, loads) == (0, 100, [])
    assert set(shard_files(tmp_path, "s")) == {_shard(i, tmp_path) for i in range(50, 150)}
    assert len(stored(tmp_path, "s")) == 100


def test_the_first_layouts_whole_stage_file_is_not_read(tmp_path):
    # issue 22: the first layout's clean-up is gone (no warehouse of that layout is left); its
    # file is never read, and left alone like any file the memo does not write
    m = _memo_run(tmp_path, [1, 2])
    old = tmp_path / "memo" / "s.pkl"
    old.write_bytes(pickle.dumps({"format": 1, "stage": "s", "entries": {
        item_key(_double, 3, tmp_path): pickle.dumps(-1)}}))
    m = _memo_run(tmp_path, [1, 2, 3])
    assert (m.hits, m.computed) == (2, 1) and old.exists()
    _memo_run(tmp_path, [])
    assert sorted(os.listdir(tmp_path / "memo")) == ["s.pkl"]


def test_a_symlinked_stage_folder_or_shard_file_is_neither_read_nor_written(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    _memo_run(elsewhere, [1, 2, 3])  # a real memo, of another warehouse
    before = snapshot(elsewhere)
    wh = tmp_path / "wh"
    (wh / "memo").mkdir(parents=True)
    os.symlink(elsewhere / "memo" / "s", wh / "memo" / "s")
    m = _memo_run(wh, [1, 2, 3])
    assert (m.hits, m.computed) == (0, 3)
    _memo_run(wh, [])
    assert snapshot(elsewhere) == before and (wh / "memo" / "s").is_symlink()
    # a shard file that is a symlink: a miss, and left as it is (the other shards work)
    os.unlink(wh / "memo" / "s")
    _memo_run(wh, [1, 2, 3])
    link = wh / "memo" / "s" / _shard(1, tmp_path)
    os.unlink(link)
    os.symlink(elsewhere / "memo" / "s" / _shard(1, tmp_path), link)
    m = _memo_run(wh, [1, 2, 3])
    share = sum(_shard(i, tmp_path) == _shard(1, tmp_path) for i in (1, 2, 3))
    assert (m.hits, m.computed) == (3 - share, share)
    _memo_run(wh, [4])  # no longer used: a symlink is not a shard file the memo deletes
    assert link.is_symlink() and snapshot(elsewhere) == before


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
    real = versions_mod.stage_code_version

    def edited(module_file):
        return real(module_file) + ("-edited" if module_file.endswith("plpa_characterisation.py") else "")

    monkeypatch.setattr(versions_mod, "stage_code_version", edited)  # what the memo keys use
    monkeypatch.setattr(runner, "stage_code_version", edited)        # what the stage cache uses
    real_project = noop_mod.project_code_version                     # what the no-op fast path uses
    monkeypatch.setattr(noop_mod, "project_code_version", lambda: real_project() + "-edited")
    s = rebuild(raw.root, warehouse, jobs=1)
    assert s.stages_run == ["plpa_characterisation"]
    assert counts(stages_of[-1], "plpa_characterisation") == (0, 4)


def test_a_damaged_memo_file_in_the_warehouse_recomputes(raw, tmp_path, stages_of):
    wh, full = tmp_path / "wh", tmp_path / "full"
    campaign(raw)
    rebuild(raw.root, wh, jobs=1)
    for f in shard_files(wh, "plpa_characterisation").values():
        f.write_bytes(b"\x80\x05\x95 damaged")
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
    def entries():
        return len(stored(warehouse, "plpa_characterisation"))

    assert entries() == 4
    (raw.root / "c/b3.csv").unlink()
    (raw.root / "c/b1.csv").unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert counts(stages_of[-1], "plpa_characterisation") == (2, 0)
    assert entries() == 2
    for rel in ("c/b0.csv", "c/b2.csv"):  # no run of the kind left: no memo file
        (raw.root / rel).unlink()
    rebuild(raw.root, warehouse, jobs=1)
    assert not (warehouse / "memo" / "plpa_characterisation").exists()
    assert shard_files(warehouse, "models")


def test_the_clean_up_collects_memo_folders_of_gone_stages_and_temp_files_only(raw, warehouse, tmp_path):
    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    memo = warehouse / "memo"
    collected = [memo / "zz_removed_stage" / "ab.pkl",       # a stage that no longer exists
                 memo / "zz_removed_stage" / ".ab.pkl.tmp-1",
                 memo / "models" / ".ab.pkl.tmp-12345"]      # a killed rebuild's temp file
    (memo / "zz_removed_stage").mkdir()
    (memo / "zz_empty_stage").mkdir()                         # an empty folder of a gone stage
    for p in collected:
        p.write_bytes(b"x")
    foreign = {memo / "notes.txt": b"mine", memo / "Models.PKL": b"not a writer name",
               # the first layout's whole-stage files: no longer collected (issue 22)
               memo / "models.pkl": b"x", memo / "zz_removed_stage.pkl": b"x", memo / ".models.pkl.tmp-12345": b"x",
               memo / "models" / "notes.txt": b"mine", memo / "models" / "abc.pkl": b"not a shard name",
               memo / "Other" / "ab.pkl": b"not a stage folder name",
               memo / "zz_kept_stage" / "ab.pkl.bak": b"not a shard name"}
    for p, data in foreign.items():
        p.parent.mkdir(exist_ok=True)
        p.write_bytes(data)
    elsewhere = tmp_path / "elsewhere"                        # a symlinked folder is not followed
    elsewhere.mkdir()
    (elsewhere / "ab.pkl").write_bytes(b"elsewhere")
    os.symlink(elsewhere, memo / "zz_linked")
    os.symlink(elsewhere / "ab.pkl", memo / "zz_removed_stage" / "cd.pkl")  # not written by the memo: left
    live = snapshot(memo / "models", skip=("notes.txt", "abc.pkl", ".ab.pkl.tmp-12345"))
    assert live
    rebuild(raw.root, warehouse, jobs=1)
    for p in collected:
        assert not p.exists(), p
    assert not (memo / "zz_empty_stage").exists()
    # the stage was reused: its memo kept as it is
    assert snapshot(memo / "models", skip=("notes.txt", "abc.pkl")) == live
    for p, data in foreign.items():
        assert p.read_bytes() == data
    assert (elsewhere / "ab.pkl").read_bytes() == b"elsewhere" and (memo / "zz_linked").is_symlink()
    assert (memo / "zz_removed_stage" / "cd.pkl").is_symlink()  # not a file the memo wrote


def test_a_memo_file_goes_with_its_stage_folder_after_the_retention(raw, warehouse, monkeypatch):
    import pipeline.stages as st

    step(raw, "c/a.csv")
    age(raw.root)
    rebuild(raw.root, warehouse, jobs=1)
    assert shard_files(warehouse, "models")
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [m for m in real() if m.NAME != "models"])
    step(raw, "c/b.csv")  # a change each time: not a no-op rebuild (removing a stage's file is one)
    rebuild(raw.root, warehouse, jobs=1)  # its last folder is kept for readers (24 h), and so is its memo
    assert shard_files(warehouse, "models")
    step(raw, "c/c.csv")
    rebuild(raw.root, warehouse, jobs=1, clock=lambda: time.time() + 25 * 3600)
    assert not (warehouse / "memo" / "models").exists()


def _kilobytes(item):
    return bytes([item % 256]) * 100_000


def test_computed_results_wait_on_disk_until_saved_and_a_saved_memo_holds_nothing(tmp_path):
    """Issue 26: a stage's memory does not grow with its items: what it computed waits, pickled,
    in an unnamed file in the warehouse, read back shard by shard when saved; nothing is left."""
    m = Memo(tmp_path, "s")
    out = StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m).map(_kilobytes, list(range(40)))
    assert out == [_kilobytes(i) for i in range(40)]
    assert not any(isinstance(v, bytes) for v in m._new.values())  # no pickled copy in memory
    assert os.fstat(m._spill.fileno()).st_size > 40 * 100_000
    assert sorted(os.listdir(tmp_path)) == []  # the spill file has no name: a killed rebuild leaves none
    m.save()
    assert m._new == {} and m._stored == {} and m._spill is None and m.summary().endswith("40 computed")
    assert sorted(os.listdir(tmp_path)) == ["memo"]
    assert sorted(pickle.loads(b)[0] for b in stored(tmp_path, "s").values()) == list(range(40))
    m2 = Memo(tmp_path, "s")  # read back: hits, equal to what was computed
    again = StageContext(raw=tmp_path, warehouse=tmp_path, runs=None, memo=m2).map(_kilobytes, list(range(40)))
    assert again == out and (m2.hits, m2.computed) == (40, 0)
    m2.save()
    assert len(stored(tmp_path, "s")) == 40


def test_pooled_tables_of_unchanged_rows_are_taken_and_equal_a_full_rebuild(raw, tmp_path, stages_of, monkeypatch):
    """A changed breakaway run re-runs ``plpa_characterisation``: its breakaway findings are computed
    again, its viscous tables (no viscous rows changed) and its seal envelope (no leakage rows
    changed) are taken from the previous folder; the database equals a full rebuild's, which takes
    none."""
    import pipeline.rebuild.stage_store as store_mod

    taken = []
    real_take = store_mod.PooledTables.take

    def spy(self, table, func, key_args):
        df = real_take(self, table, func, key_args)
        taken.append((table, df is not None))
        return df

    monkeypatch.setattr(store_mod.PooledTables, "take", spy)
    inc, full = tmp_path / "inc", tmp_path / "full"
    campaign(raw)
    rebuild(raw.root, inc, jobs=1)
    assert ("breakaway_findings", False) in taken and ("viscous_fits", False) in taken
    taken.clear()
    breakaway(raw, "c/b2.csv", scale=9.0)
    age(raw.root)
    s = rebuild(raw.root, inc, jobs=1)
    assert "plpa_characterisation" in s.stages_run
    assert dict(taken) == {"breakaway_findings": False, "viscous_fits": True, "viscous_transition": True,
                           "seal_envelope": True}
    taken.clear()
    rebuild(raw.root, full, jobs=1, full=True)
    assert set(dict(taken).values()) == {False} and "viscous_fits" in dict(taken)  # --full takes none
    a, b = dump(inc), dump(full)
    for table in a:
        assert a[table] == b[table], table


def test_the_shards_of_a_save_are_fsynced_together_before_any_replaces_and_a_failed_fsync_keeps_the_old_file(
        tmp_path, monkeypatch):
    """Session 25: ``save`` writes every changed shard to its temporary file, fsyncs them (concurrently), then puts
    each in place; a shard whose fsync fails keeps its previous file (its items are then misses or old entries,
    never a torn file) and leaves no temporary file."""
    first = Memo(tmp_path, "unit")
    first.map(lambda f, items, label: [f(i) for i in items], _double, list(range(40)))
    first.save()
    before = {name: p.read_bytes() for name, p in shard_files(tmp_path, "unit").items()}
    assert len(before) > 5

    events = []
    real_fsync, real_replace = os.fsync, os.replace
    bad = {}

    def fsync(fd):
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        events.append(("fsync", name))
        if name.startswith(".") and name[1:3] == bad.get("shard"):
            raise OSError("disk full")
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", os.path.basename(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(memo_mod.os, "fsync", fsync)
    monkeypatch.setattr(memo_mod.os, "replace", replace)
    # the new items: 40..59 and the first item from 60 on whose shard the first save wrote (keys hash the
    # environment, so which shards the new items share with the old ones differs between machines)
    old_shards = {n[:2] for n in before}
    extra = next(i for i in range(60, 100_000) if item_key(_double, i, tmp_path)[:2] in old_shards)
    items = list(range(20, 60)) + [extra]
    second = Memo(tmp_path, "unit")
    got = second.map(lambda f, items, label: [f(i) for i in items], _double, items)
    assert got == [2 * i for i in items]
    keys = {item_key(_double, i, tmp_path) for i in items[20:]}      # new items
    bad["shard"] = sorted({k[:2] for k in keys} & old_shards)[0]
    second.save()
    kinds = [k for k, _ in events]
    assert "fsync" in kinds and kinds.index("replace") > max(i for i, k in enumerate(kinds) if k == "fsync")
    files = shard_files(tmp_path, "unit")
    assert files[f"{bad['shard']}.pkl"].read_bytes() == before[f"{bad['shard']}.pkl"]   # the old file, whole
    assert not list((tmp_path / "memo" / "unit").glob(".*tmp*"))
    monkeypatch.undo()
    third = Memo(tmp_path, "unit")
    calls = []
    again = third.map(lambda f, items, label: (calls.extend(items), [f(i) for i in items])[1], _double, items)
    assert again == [2 * i for i in items]
    # only the new items of the shard whose fsync failed are misses; its old entries still hit
    assert calls and all(i >= 40 and item_key(_double, i, tmp_path)[:2] == bad["shard"] for i in calls)
