"""The clean-up deletes only what the warehouse wrote, by the writers' names, never through a symlink."""
import os

from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_OK
from tests.conftest import STEP_META, query, raw_snapshot

T = [0.0, 0.1, 0.2, 0.3]
q = query


def test_the_clean_up_deletes_only_files_the_warehouse_wrote(raw, warehouse, tmp_path):
    import os

    from tests.conftest import raw_snapshot

    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
    rebuild(raw.root, warehouse, jobs=1)
    camp = warehouse / "samples" / "kind=step" / "campaign=c"
    # a raw tree copied where the clean-up looks, foreign names in the warehouse's own folders,
    # and a symlink out of the warehouse onto a tree of writer-like names
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (outside / "x-0123456789abcdef.parquet").write_bytes(b"someone's data")
    foreign = {
        "samples/kind=step/campaign=c/b.csv": b"t,x\n0,1\n",
        "samples/kind=step/campaign=c/notes.txt": b"mine",
        "samples/kind=step/campaign=c/run-12.parquet": b"not a writer name",
        "samples/kind=step/campaign=c/sub/z-0123456789abcdef.parquet": b"one folder too deep",
        "samples/c/a.csv": b"a raw tree under samples/",
        "samples/kind=nope/campaign=c/q-0123456789abcdef.parquet": b"not a kind",
        "stages/models/0123456789abcdef0123/tables/data.csv": b"foreign",
        "stages/models/0123456789abcdef0123/output.json.bak": b"foreign",
        "stages/Not-A-Stage/0123456789abcdef0123/output.json": b"{}",
        "stages/.tmp-notes/readme.txt": b"foreign",
        "report/.keep.tmp": b"foreign",
        ".pneubench.duckdb.tmp-old": b"foreign",
        "figures/readme.txt": b"foreign",
    }
    for rel, data in foreign.items():
        (warehouse / rel).parent.mkdir(parents=True, exist_ok=True)
        (warehouse / rel).write_bytes(data)
    os.symlink(outside, warehouse / "samples" / "kind=step" / "campaign=linked")
    orphan = camp / "zz-0123456789abcdef.parquet"       # writer-named, used by no warehouse: collected
    orphan.write_bytes(b"stale")
    debris = camp / ".a.123.0123456789ab.tmp"             # a killed writer's temp file: collected
    debris.write_bytes(b"partial")
    outside_before = raw_snapshot(outside)
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": [1.0] * 4})
    assert rebuild(raw.root, warehouse, jobs=1).exit_code == EXIT_OK
    rebuild(raw.root, warehouse, jobs=1)
    for rel, data in foreign.items():
        assert (warehouse / rel).read_bytes() == data, rel
    assert raw_snapshot(outside) == outside_before
    assert not orphan.exists() and not debris.exists()
    assert q(warehouse, "SELECT count(*) FROM runs") == [(2,)]


def test_the_first_layouts_files_are_left_alone_as_foreign(tmp_path):
    # issue 22: the clean-up of the layout before generations (figures/<stage>/<name>.png,
    # memo/<stage>.pkl) is gone; such files are now foreign, like any name the warehouse does not write
    from pipeline.rebuild.garbage import clean_debris, collect_garbage

    old = [tmp_path / "figures" / "models" / "fit.png", tmp_path / "memo" / "models.pkl",
           tmp_path / "memo" / ".models.pkl.tmp-12"]
    gone = [tmp_path / "memo" / "models" / "ab.pkl", tmp_path / f".pneubench.duckdb.tmp-{os.getpid()}"]
    for p in old + gone:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"x")
    clean_debris(tmp_path)
    collect_garbage(tmp_path, set(), set())
    assert all(p.exists() for p in old) and not any(p.exists() for p in gone)
