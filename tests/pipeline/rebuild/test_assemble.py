"""pipeline/rebuild/assemble.py: the samples views and the samples() macro read the live files of
the right runs, whatever the names (issue 21), opening one file for a one-run query."""
from __future__ import annotations

import os
import re
from pathlib import Path

import duckdb
import pytest

from pipeline.rebuild.assemble import SAFE_NAME_SQL, create_samples_views
from pipeline.rebuild.flow import rebuild
from pipeline.serve.door import connect_readonly
from pipeline.serve.query import run_query
from pipeline.warehouse import DB_NAME, FILES_TABLE
from tests.conftest import STEP_META, RawBuilder
from tests.pipeline.test_warehouse import T, _expected, _samples, _step


def _files_read(con: duckdb.DuckDBPyConnection, sql: str) -> list[int]:
    """``Total Files Read`` of each Parquet scan in DuckDB's EXPLAIN ANALYZE of ``sql``."""
    import re

    text = "\n".join(r[1] for r in con.execute("EXPLAIN ANALYZE " + sql).fetchall())
    return [int(n) for n in re.findall(r"Total Files Read:\s*(\d+)", text)]


def test_one_run_query_opens_only_that_runs_file(tmp_path):
    """A filter on run_id reaches the Parquet scan as a filter on the file name: of 60 files
    (two column groups) one is opened, and the view holds no (run_id, file) literal list."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.parquet as pq

    wh = tmp_path / "wh"
    folder = wh / "samples" / "kind=step" / "campaign=c"
    folder.mkdir(parents=True)
    runs, channels = [], []
    for i in range(60):
        run_id = f"c/r{i:03d}"
        cols = {"run_id": [run_id] * 3, "t_s": T, "x_m": [float(i)] * 3}
        if i % 2:
            cols["x_ref_m"] = T
        rel = f"samples/kind=step/campaign=c/r{i:03d}-0123456789abcdef.parquet"
        pq.write_table(pa.table(cols), wh / rel)
        runs.append({"run_id": run_id, "kind": "step", "campaign": "c", "samples_path": rel})
        channels += [{"run_id": run_id, "column": c} for c in cols if c != "run_id"]
    runs_df, channels_df = pd.DataFrame(runs), pd.DataFrame(channels)  # noqa: F841 (read by DuckDB)
    con = duckdb.connect(str(wh / DB_NAME))
    con.execute("CREATE TABLE channels AS SELECT * FROM channels_df")
    create_samples_views(con, wh, runs_df)
    view_sql = con.execute("SELECT sql FROM duckdb_views() WHERE view_name = 'samples_step'").fetchone()[0]
    con.close()
    assert "VALUES" not in view_sql and "'c/r007'" not in view_sql  # run ids are in the table only

    con = connect_readonly(wh)
    try:
        assert con.execute(f"SELECT count(*) FROM {FILES_TABLE}").fetchone() == (60,)
        one = "SELECT run_id, kind, campaign, x_m, x_ref_m FROM samples_step WHERE run_id = 'c/r007'"
        assert sorted(con.execute(one).fetchall()) == [("c/r007", "step", "c", 7.0, t) for t in T]
        assert sum(_files_read(con, one)) == 1
        # several runs: DuckDB's join filter is a range of file names, so a few more may be opened
        assert sum(_files_read(con, "SELECT * FROM samples_step WHERE run_id IN ('c/r007', 'c/r008')")) <= 4
        assert sum(_files_read(con, "SELECT * FROM samples_step")) == 60  # the count is real
        assert con.execute("SELECT count(*) FROM samples_step").fetchone() == (180,)
    finally:
        con.close()


@pytest.mark.parametrize("run_id", ["c/plain", "c/with space", "c/..dots..", "c/_x_", "c/été-ü", "c/" + "y" * 100,
                                    "c/a'b", "c/[x]*?"])
def test_the_safe_name_in_sql_is_the_ingests(run_id):
    from pipeline.ingest.samples import safe_file_name

    con = duckdb.connect()
    got = con.execute(f"SELECT {SAFE_NAME_SQL.replace('rid', '$rid')}", {"rid": run_id}).fetchone()[0]
    assert got == safe_file_name(run_id)


def test_the_samples_macro_reads_one_runs_file_and_never_an_earlier_generations(tmp_path):
    """samples('<run_id>') reads the run's live samples file: not a file of another run whose safe
    name is the same, not the run's superseded file kept for earlier readers."""
    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    for rid_file in ("c/a b.csv", "c/a_b.csv", "c/[x]*.csv"):
        raw.csv(rid_file, STEP_META, {"t[s]": T, "x[mm]": [1, 2, 3], "x_ref[mm]": [3] * 3})
    rebuild(raw.root, wh, jobs=1, report=False)
    raw.csv("c/a b.csv", STEP_META, {"t[s]": T, "x[mm]": [7, 8, 9], "x_ref[mm]": [3] * 3})  # a new version
    rebuild(raw.root, wh, jobs=1, report=False)
    assert len(list((wh / "samples").rglob("c_a_b-*.parquet"))) == 3  # a b (old and new), a_b
    cols, rows = run_query(wh, "SELECT run_id, kind, campaign, x_m FROM samples('c/a b') ORDER BY t_s")
    assert rows == [("c/a b", "step", "c", 0.007), ("c/a b", "step", "c", 0.008), ("c/a b", "step", "c", 0.009)]
    assert [r[0] for r in run_query(wh, "SELECT x_m FROM samples('c/a_b') ORDER BY t_s")[1]] == [0.001, 0.002, 0.003]
    assert len(run_query(wh, "SELECT * FROM samples('c/[x]*')")[1]) == 3
    same = run_query(wh, "SELECT * FROM samples_step WHERE run_id = 'c/a b' ORDER BY t_s")
    assert run_query(wh, "SELECT * FROM samples('c/a b') ORDER BY t_s") == same


# -- issue 21: names and types the views must survive ---------------------------------------------
def _rebuilt(raw: RawBuilder, wh: Path):
    summary = rebuild(raw.root, wh, jobs=1, report=False)
    assert summary.exit_code == 0, summary
    return summary


@pytest.mark.parametrize("layout", ["csv header", "derived channel"])
def test_a_channel_named_like_a_column_the_views_add_is_renamed_with_a_note(tmp_path, layout):
    """DuckDB's ``filename`` column (the views and samples() join on it) and run_id / kind /
    campaign are the views' own: a raw channel that sanitises to one of them is stored under
    ``x_<name>`` and the run says so; every query works and no value is lost."""
    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    _step(raw, "p/plain.csv")  # the happy case beside it
    if layout == "csv header":
        raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T, "FileName": ["a.tdms", "b", "c"],
                                       "Kind": ["k1", "k2", "k3"], "note": ["n1", "n2", "n3"]})
        expected = ["a.tdms", "b", "c"]
        notes = {"`FileName` is stored as `x_filename`", "`Kind` is stored as `x_kind`"}
    else:
        raw.write("c/rig.toml", '[derived]\nfilename = "x * 2"\n')
        raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": T, "x_ref[m]": T})
        expected = [0.0, 0.2, 0.4]
        notes = {"`filename` is stored as `x_filename`"}
    _rebuilt(raw, wh)
    rows = run_query(wh, "SELECT run_id, x_filename FROM samples_step ORDER BY run_id, t_s")[1]
    assert rows == [("c/a", v) for v in expected] + [("p/plain", None)] * 3
    cols, every = run_query(wh, "SELECT * FROM samples_step ORDER BY run_id, t_s")
    assert "filename" not in cols and len(every) == 6
    assert [r[0] for r in run_query(wh, "SELECT x_filename FROM samples('c/a') ORDER BY t_s")[1]] == expected
    warnings = run_query(wh, "SELECT warnings FROM runs WHERE run_id = 'c/a'")[1][0][0]
    for note in notes:
        assert any(note in w and "name the samples views use" in w for w in warnings), (note, warnings)
    plain = run_query(wh, "SELECT warnings FROM runs WHERE run_id = 'p/plain'")[1][0][0]
    assert not any("samples views" in w for w in plain)


#: Campaign (folder) names with DuckDB's glob characters and backslashes before them.
GLOB_NAMES = ["data\\[old]", "b\\x", "c[1]", "br]", "x*", "a\\*", "q?", "{e}", "f{a,b}", "end\\", "m\\?x", "plain"]


def test_campaign_and_file_names_with_glob_characters_and_backslashes_read_back(tmp_path):
    """A backslash in a folder name made DuckDB's glob split the path there (its file glob takes
    ``\\`` for a separator), so ``data\\[old]`` was never found and every rebuild exited 3: the
    samples folders are written without those characters and the views list plain paths."""
    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    for i, name in enumerate(GLOB_NAMES):
        _step(raw, f"{name}/{name}.csv", float(i + 1))
    _rebuilt(raw, wh)
    assert _samples(wh) == _expected({f"{n}/{n}": float(i + 1) for i, n in enumerate(GLOB_NAMES)})
    for i, name in enumerate(GLOB_NAMES):
        rid = f"{name}/{name}"
        rows = run_query(wh, f"SELECT run_id, campaign, x_m FROM samples({_sql_lit(rid)}) ORDER BY t_s")[1]
        assert rows == [(rid, name, x) for x in (0.0, 1e-3 * (i + 1), 2e-3 * (i + 1))], name
    again = rebuild(raw.root, wh, jobs=1, report=False)  # and the next night too
    assert again.exit_code == 0 and again.n_unchanged == len(GLOB_NAMES)


def _sql_lit(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


def test_samples_macro_finds_runs_of_a_latin1_campaign_folder(tmp_path):
    """A campaign folder whose name is not UTF-8 (``caf\\xe9``) is written with a backslash: the
    macro's folder glob never listed it, so samples('<run_id>') found nothing that samples_step had."""
    import os

    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    _step(raw, "plain/a.csv")
    _step(raw, "tmp/a.csv", 2.0)
    root = os.fsencode(raw.root)
    os.rename(root + b"/tmp", root + b"/caf\xe9")
    _step(raw, "tmp/r.csv", 3.0)
    os.rename(root + b"/tmp/r.csv", root + b"/tmp/r\xfcn.csv")
    os.rename(root + b"/tmp", root + b"/\xe9t\xe9")
    _rebuilt(raw, wh)
    for rid in ("plain/a", "caf\\xe9/a", "\\xe9t\\xe9/r\\xfcn"):
        view = run_query(wh, f"SELECT * FROM samples_step WHERE run_id = {_sql_lit(rid)} ORDER BY t_s")
        assert len(view[1]) == 3
        assert run_query(wh, f"SELECT * FROM samples({_sql_lit(rid)}) ORDER BY t_s") == view, rid


def test_a_channel_numeric_in_one_run_and_text_in_another_is_text_in_the_view(tmp_path):
    """``note`` holds numbers in one file and words in another: one type per view, VARCHAR, with
    the numbers as DuckDB writes a DOUBLE; a channel that is numeric everywhere stays DOUBLE and one
    that is text everywhere VARCHAR; the column's comment says so."""
    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    base = {"t[s]": T, "x[m]": T, "x_ref[m]": T}
    raw.csv("c/a.csv", STEP_META, {**base, "note": ["1.5", "2", "3"], "gain": [1, 2, 3], "label": ["p", "q", "r"]})
    raw.csv("c/b.csv", STEP_META, {**base, "note": ["x", "y", "z"], "gain": [4, 5, 6], "label": ["s", "t", "u"]})
    raw.csv("d/c.csv", STEP_META, {**base, "note": ["7", "8", "9"]})
    _rebuilt(raw, wh)
    cols, rows = run_query(wh, "SELECT * FROM samples_step ORDER BY run_id, t_s")
    assert len(rows) == 9
    got = run_query(wh, "SELECT run_id, note, gain, label FROM samples_step ORDER BY run_id, t_s")[1]
    assert got == [("c/a", "1.5", 1.0, "p"), ("c/a", "2.0", 2.0, "q"), ("c/a", "3.0", 3.0, "r"),
                   ("c/b", "x", 4.0, "s"), ("c/b", "y", 5.0, "t"), ("c/b", "z", 6.0, "u"),
                   ("d/c", "7.0", None, None), ("d/c", "8.0", None, None), ("d/c", "9.0", None, None)]
    types = dict((r[0], r[1]) for r in run_query(wh, "DESCRIBE samples_step")[1])
    assert (types["note"], types["gain"], types["label"]) == ("VARCHAR", "DOUBLE", "VARCHAR")
    comment = run_query(wh, "SELECT comment FROM duckdb_columns() WHERE table_name = 'samples_step' "
                            "AND column_name = 'note'")[1][0][0]
    assert "text in some runs" in comment and "VARCHAR" in comment
    assert run_query(wh, "SELECT note FROM samples('d/c') ORDER BY t_s")[1] == [(7.0,), (8.0,), (9.0,)]
    from click.testing import CliRunner

    from pipeline.cli import main

    res = CliRunner().invoke(main, ["query", "--warehouse", str(wh), "--format", "csv",
                                    "SELECT run_id, note FROM samples_step ORDER BY run_id, t_s"])
    assert res.exit_code == 0 and res.output.splitlines()[1:4] == ["c/a,1.5", "c/a,2.0", "c/a,3.0"], res.output


# -- issue 26: the database written into a copy of the live one -----------------------------------
def _objects(con: duckdb.DuckDBPyConnection, db: str) -> dict[str, tuple]:
    """name -> (TABLE/VIEW, comment, [(column, type, comment)]) of every table and view of ``db``;
    the macros as ``macro <name>`` -> their definition."""
    out = {}
    for name, what, comment in con.execute(
            "SELECT table_name, 'TABLE', comment FROM duckdb_tables() WHERE database_name = $1 UNION ALL "
            "SELECT view_name, 'VIEW', comment FROM duckdb_views() WHERE database_name = $1 AND NOT internal",
            [db]).fetchall():
        cols = con.execute("SELECT column_name, data_type, comment FROM duckdb_columns() WHERE database_name = $1 "
                           "AND table_name = $2 ORDER BY column_index", [db, name]).fetchall()
        out[name] = (what, comment, cols)
    for name, definition in con.execute("SELECT function_name, macro_definition FROM duckdb_functions() "
                                        "WHERE database_name = $1 AND function_type = 'table_macro'", [db]).fetchall():
        # DuckDB prints an EXCLUDE list in no fixed order (a set): compared as a set
        out[f"macro {name}"] = re.sub(r"EXCLUDE \(([^)]*)\)",
                                      lambda m: "EXCLUDE (" + ", ".join(sorted(m.group(1).split(", "))) + ")", definition)
    return out


def assert_same_database(a: Path, b: Path, warehouse: Path, skip_rows: set[str] = frozenset()) -> int:
    """Databases ``a`` and ``b`` hold the same tables, views and macros, with the same column
    names, types and comments, and (but for ``skip_rows``) the same rows: ``EXCEPT ALL`` both
    ways on every table and view. Returns how many tables and views were compared row by row."""
    con = duckdb.connect()
    try:
        con.execute(f"ATTACH '{a}' AS a (READ_ONLY)")
        con.execute(f"ATTACH '{b}' AS b (READ_ONLY)")
        con.execute("SET VARIABLE pneubench_warehouse = ?", [str(warehouse.resolve())])
        oa, ob = _objects(con, "a"), _objects(con, "b")
        assert sorted(oa) == sorted(ob)
        for name in oa:
            assert oa[name] == ob[name], name
        compared = 0
        for name in sorted(n for n in oa if not n.startswith("macro ") and n not in skip_rows):
            for x, y in (("a", "b"), ("b", "a")):
                extra = con.execute(f'SELECT count(*) FROM (FROM {x}.main."{name}" EXCEPT ALL '
                                    f'FROM {y}.main."{name}")').fetchone()[0]
                assert extra == 0, (name, f"{extra} rows of {x} not in {y}")
            compared += 1
        return compared
    finally:
        con.close()


def _bump(path: Path) -> None:
    """One value of a run file changed: its last digit + 1 (mod 10)."""
    data = bytearray(path.read_bytes())
    i = max(i for i, b in enumerate(data) if 48 <= b <= 57)
    data[i] = 48 + (data[i] - 47) % 10
    path.write_bytes(bytes(data))


@pytest.fixture
def checked_writes(monkeypatch, tmp_path):
    """Every database a rebuild writes is also built whole from the same tables beside it and
    compared with it (:func:`assert_same_database`, every row of every table); yields the log
    lines that say how each was written."""
    import pipeline.rebuild.flow as rb
    from pipeline.rebuild.assemble import build_database, write_database

    lines = []

    def checked(path, warehouse, tables, runs, live, unchanged=frozenset()):
        line = write_database(path, warehouse, tables, runs, live, unchanged)
        whole = tmp_path / f"whole-{len(lines)}.duckdb"
        build_database(whole, warehouse, tables, runs)
        assert assert_same_database(path, whole, warehouse) > 40
        lines.append(line)
        return line

    monkeypatch.setattr(rb, "write_database", checked)
    return lines


def test_the_database_written_into_a_copy_equals_one_built_whole_after_changes_of_every_sort(raw, tmp_path,
                                                                                           checked_writes):
    """Changes of several kinds (a step and a breakaway run at once), a run deleted, a plan.toml
    change, a no-op between them: each database written into a copy of the live one holds exactly
    what one built whole from the same tables holds (rows, types, comments), only the tables whose
    rows changed are written again, and the last equals a ``--full`` rebuild's table by table."""
    from tests.pipeline.rebuild.test_memo import breakaway, campaign
    from tests.pipeline.rebuild.test_state import REBUILD_ONLY, age

    wh = tmp_path / "wh"
    campaign(raw)
    raw.write("plan.toml", "[defaults]\nmargin = 1.5\n")
    age(raw.root)
    rebuild(raw.root, wh, jobs=1, report=False)
    assert checked_writes[-1].startswith("warehouse: built whole (no live database), ")
    _bump(raw.root / "c/s1.csv")
    breakaway(raw, "c/b2.csv", scale=9.0)
    age(raw.root)
    for change in ("two kinds", "no-op", "deleted", "plan"):
        if change == "deleted":
            (raw.root / "c/s3.csv").unlink()
        elif change == "plan":
            raw.write("plan.toml", "[defaults]\nmargin = 1.3\n")
            age(raw.root)
        s = rebuild(raw.root, wh, jobs=1, report=False)
        assert s.mode == ("no-op" if change == "no-op" else "incremental"), change
        if change != "no-op":
            line = checked_writes[-1]
            assert line.startswith("warehouse: the live database copied"), (change, line)
            written = int(line.split("copied, ")[1].split(" of ")[0])
            assert 0 < written < 30, (change, line)
    deleted = checked_writes[-2].split("(")[1]  # the run deleted: its rows gone, the other kind's kept
    assert {"runs", "channels", "step_response"} <= set(deleted.rstrip(")").split(", ")) and "breakaway" not in deleted
    full = tmp_path / "full"
    rebuild(raw.root, full, jobs=1, report=False, full=True)
    assert "built whole (--full)" in checked_writes[-1]
    skip = REBUILD_ONLY | {"figures", "rebuild_changes"}  # the rebuild's own records: its time, mode, folders
    assert assert_same_database(wh / DB_NAME, full / DB_NAME, wh, skip_rows=skip) > 30
    rebuild(raw.root, wh, jobs=1, report=False, full=True)  # a live database, and --full: built whole, saying why
    assert "built whole (--full)" in checked_writes[-1]


def test_a_live_database_that_cannot_be_updated_is_rebuilt_whole_and_says_why(raw, tmp_path, monkeypatch):
    """No live database, another DDL/code version, a live file that is not a database, and a copy
    grown past 1.5x the blocks it uses (by more than MIN_FREE_BYTES): the database is built whole,
    one line saying why."""
    import pipeline.rebuild.assemble as asm
    from pipeline.rebuild.assemble import build_database, runs_frame, write_database

    import numpy as np
    import pandas as pd

    wh = tmp_path / "wh"
    wh.mkdir()
    tables = {"runs": runs_frame([]), "channels": pd.DataFrame(), "notes": pd.DataFrame({"note": ["a"]})}
    live, new = wh / DB_NAME, wh / "new.duckdb"
    assert write_database(new, wh, tables, tables["runs"], live) == \
        "warehouse: built whole (no live database), 3 tables"
    os.replace(new, live)
    copied = write_database(new, wh, tables, tables["runs"], live)
    assert copied == "warehouse: the live database copied, 0 of 3 tables written again"
    assert assert_same_database(new, live, wh) > 40
    new.unlink()
    con = duckdb.connect(str(live))  # the live database edited by something other than the rebuild
    con.execute("UPDATE notes SET note = 'edited'")
    con.close()
    assert write_database(new, wh, tables, tables["runs"], live).endswith("1 of 3 tables written again (notes)")
    con = duckdb.connect(str(new), read_only=True)
    assert con.execute("SELECT note FROM notes").fetchall() == [("a",)]
    con.close()
    new.unlink()
    real = asm.database_version
    monkeypatch.setattr(asm, "database_version", lambda: real() + "-edited")
    assert "(the live database is of another DDL/code version)" in write_database(new, wh, tables, tables["runs"], live)
    monkeypatch.setattr(asm, "database_version", real)
    new.unlink()
    live.write_bytes(b"not a database" * 1000)
    line = write_database(new, wh, tables, tables["runs"], live)
    assert line.startswith("warehouse: built whole (its copy could not be updated: ") and new.is_file()
    assert not list(wh.glob("*.wal"))
    # grown: a big table dropped leaves free blocks DuckDB keeps in the file
    big = {**tables, "notes": pd.DataFrame({"note": np.random.default_rng(1).random(1_000_000)})}
    build_database(live, wh, big, big["runs"])
    shrunk = {**tables, "notes": pd.DataFrame({"note": ["b"]})}
    new.unlink()
    assert write_database(new, wh, shrunk, shrunk["runs"], live).startswith("warehouse: the live database copied")
    os.replace(new, live)
    line = write_database(new, wh, shrunk, shrunk["runs"], live)
    assert line.startswith("warehouse: built whole (the copy is ") and "free blocks" in line
    assert new.stat().st_size < 0.5 * live.stat().st_size


def test_frame_keys_tell_apart_what_the_database_would_store_apart():
    import numpy as np
    import pandas as pd

    from pipeline.rebuild.assemble import frame_key

    a = pd.DataFrame({"x": [1.0, 2.0], "s": ["a", "b"], "l": [[1.0], [2.0]]})
    assert frame_key(a) == frame_key(a.copy()) and len(frame_key(a)) == 32
    assert frame_key(a) != frame_key(a.assign(x=[1.0, 2.0 + 1e-12]))
    assert frame_key(a) != frame_key(a.assign(l=[[1.0], [2.0 + 1e-12]]))
    assert frame_key(a) != frame_key(a.rename(columns={"x": "y"}))
    assert frame_key(a) != frame_key(a.assign(x=np.array([1, 2], dtype="float32")))
    assert frame_key(pd.DataFrame({"v": [1, "1"]})) != frame_key(pd.DataFrame({"v": ["1", "1"]}))
    assert frame_key(pd.DataFrame({"v": [1, 2]})) != frame_key(pd.DataFrame({"v": [1, 2]}, dtype="Int64"))
    assert frame_key(None) == frame_key(pd.DataFrame()) == "none"


def test_only_the_views_of_the_kinds_whose_files_changed_are_made_again(raw, tmp_path, checked_writes, monkeypatch):
    """A changed step run re-creates ``samples_step`` alone (its file list changed); the other kinds'
    views are kept as the copy has them, and ``samples_files`` is written again in place; the database
    equals one built whole (``checked_writes``, which builds one: every kind's view once more). A plan
    change re-creates none."""
    import pipeline.rebuild.assemble as asm
    from schemas.kinds import KINDS
    from tests.pipeline.rebuild.test_memo import campaign
    from tests.pipeline.rebuild.test_state import age

    made = []
    kind_view_sql = asm._kind_view_sql
    monkeypatch.setattr(asm, "_kind_view_sql", lambda kind, *a: made.append(kind) or kind_view_sql(kind, *a))
    wh = tmp_path / "wh"
    campaign(raw)
    raw.write("plan.toml", "[defaults]\nmargin = 1.5\n")
    age(raw.root)
    rebuild(raw.root, wh, jobs=1, report=False)
    assert sorted(made) == sorted(2 * list(KINDS))  # built whole, and the whole build it is compared with
    made.clear()
    _bump(raw.root / "c/s1.csv")
    age(raw.root)
    rebuild(raw.root, wh, jobs=1, report=False)
    assert made[:-len(KINDS)] == ["step"] and "runs" in checked_writes[-1]
    con = connect_readonly(wh)
    try:
        n = con.execute("SELECT count(*) FROM samples_step").fetchone()[0]
        files = con.execute(f"SELECT path FROM {FILES_TABLE}").fetchall()
    finally:
        con.close()
    assert n > 0 and [p for (p,) in files] == sorted(p for (p,) in files)
    made.clear()
    raw.write("plan.toml", "[defaults]\nmargin = 1.3\n")
    age(raw.root)
    rebuild(raw.root, wh, jobs=1, report=False)
    assert made[:-len(KINDS)] == []


def test_tables_said_unchanged_take_the_copys_keys_only_while_the_runs_are_the_same(tmp_path, monkeypatch):
    """``unchanged`` tables are not keyed again when the ``runs`` frame has the copy's key (their keys are
    the copy's, the database the one built whole); when the runs changed they are keyed and written as any."""
    import pipeline.rebuild.assemble as asm
    from pipeline.rebuild.assemble import build_database, runs_frame, write_database

    import pandas as pd

    wh = tmp_path / "wh"
    wh.mkdir()
    tables = {"runs": runs_frame([]), "channels": pd.DataFrame(), "notes": pd.DataFrame({"note": ["a", "b"]})}
    live, new = wh / DB_NAME, wh / "new.duckdb"
    write_database(new, wh, tables, tables["runs"], live)
    os.replace(new, live)
    keyed = []
    real = asm.frame_key
    monkeypatch.setattr(asm, "frame_key", lambda df: keyed.append(df) or real(df))
    line = write_database(new, wh, tables, tables["runs"], live, {"notes"})
    assert line == "warehouse: the live database copied, 0 of 3 tables written again"
    assert not any(df is tables["notes"] for df in keyed)   # its key read from the copy, not computed
    whole = tmp_path / "whole.duckdb"
    build_database(whole, wh, tables, tables["runs"])
    assert assert_same_database(new, whole, wh) > 40
    new.unlink()
    # the runs changed (or the copy has no key of the table): a table said unchanged is keyed again
    frames = {"notes": pd.DataFrame({"note": ["a", "c"]})}
    old = {"runs": "r1:3-5", "notes": "n1:2-7"}
    assert asm._keys_of(frozenset({"notes"}), old, {"runs": "r1"}, frames) == {"notes": "n1"}
    assert asm._keys_of(frozenset({"notes"}), old, {"runs": "r2"}, frames) == {"notes": real(frames["notes"])}
    assert asm._keys_of(frozenset({"notes"}), {"runs": "r1:3-5"}, {"runs": "r1"}, frames) == \
        {"notes": real(frames["notes"])}


def test_tables_said_unchanged_keep_the_copys_keys_when_a_run_changed_but_not_its_run_columns(tmp_path, monkeypatch):
    """A changed run whose ``run_id``, ``campaign`` and ``params`` are the same (a new value in its samples:
    another source hash) leaves :func:`run_columns_key`: the ``unchanged`` tables take the copy's keys though
    the ``runs`` frame's key changed, and the database is the one built whole; a run's campaign or parameters
    changed, or a copy without the row (a database from before it), keys them again."""
    import pandas as pd

    import pipeline.rebuild.assemble as asm
    from pipeline.rebuild.assemble import build_database, run_columns_key, runs_frame, write_database

    def run(sha: str, campaign: str = "c", hose: str = "H1") -> dict:
        return {"run_id": "c/s1", "kind": "step", "campaign": campaign, "rig": "r", "started_at": "2025-01-01T00:00:00Z",
                "source_path": "c/s1.csv", "source_sha256": sha, "n_samples": 3, "sample_rate_hz": 1.0,
                "params": {"hose_id": hose}, "warnings": [], "format": "csv", "duration_s": 2.0, "samples_path": None}

    before = runs_frame([run("a")])
    assert run_columns_key(before) == run_columns_key(runs_frame([run("b")]))  # its source hash: not a run column
    assert run_columns_key(before) != run_columns_key(runs_frame([run("a", campaign="d")]))
    assert run_columns_key(before) != run_columns_key(runs_frame([run("a", hose="H2")]))
    wh = tmp_path / "wh"
    wh.mkdir()
    notes = pd.DataFrame({"run_id": ["c/s1"], "note": ["a"]})
    live, new = wh / DB_NAME, wh / "new.duckdb"
    write_database(new, wh, {"runs": before, "channels": pd.DataFrame(), "notes": notes}, before, live)
    os.replace(new, live)
    keyed = []
    real = asm.frame_key
    monkeypatch.setattr(asm, "frame_key", lambda df: keyed.append(df) or real(df))
    after = runs_frame([run("b")])
    tables = {"runs": after, "channels": pd.DataFrame(), "notes": notes}
    line = write_database(new, wh, tables, after, live, {"notes"})
    assert line == "warehouse: the live database copied, 1 of 3 tables written again (runs)"
    assert not any(df is notes for df in keyed)   # its key read from the copy, not computed
    whole = tmp_path / "whole.duckdb"
    build_database(whole, wh, tables, after)
    assert assert_same_database(new, whole, wh) > 40
    with duckdb.connect(str(new), read_only=True) as con:  # the row written with the keys, never read as a table
        assert con.execute("SELECT content_key FROM table_keys WHERE table_name = ?",
                           [asm.RUN_COLUMNS_ROW]).fetchall() == [(run_columns_key(after),)]
    old = {"runs": "r1:1-5", "notes": "n1:1-7", asm.RUN_COLUMNS_ROW: run_columns_key(before)}
    assert asm._keys_of(frozenset({"notes"}), old, {"runs": "r2"}, {"notes": notes}, run_columns_key(after)) == \
        {"notes": "n1"}
    moved = run_columns_key(runs_frame([run("b", campaign="d")]))
    assert asm._keys_of(frozenset({"notes"}), old, {"runs": "r2"}, {"notes": notes}, moved) == {"notes": real(notes)}
    del old[asm.RUN_COLUMNS_ROW]
    assert asm._keys_of(frozenset({"notes"}), old, {"runs": "r2"}, {"notes": notes}, run_columns_key(after)) == \
        {"notes": real(notes)}
