"""pipeline/warehouse.py: the samples views do not depend on where the warehouse sits."""
from __future__ import annotations

import shutil
from pathlib import Path

import duckdb
import pytest

from pipeline.serve.query import run_query
from pipeline.rebuild.flow import rebuild
from pipeline.warehouse import DB_NAME, ROOT_VARIABLE
from tests.conftest import STEP_META, RawBuilder

T = [0.0, 0.1, 0.2]


def _step(raw: RawBuilder, rel: str, scale: float = 1.0) -> None:
    raw.csv(rel, STEP_META, {"t[s]": T, "x[m]": [0.0, 1e-3 * scale, 2e-3 * scale], "x_ref[m]": T})


def _build(raw: RawBuilder, wh: Path) -> Path:
    summary = rebuild(raw.root, wh, jobs=1, report=False)
    assert summary.exit_code == 0, summary
    return wh


def _samples(wh: Path) -> list[tuple]:
    return run_query(wh, "SELECT run_id, kind, campaign, t_s, x_m FROM samples_step ORDER BY ALL")[1]


def _expected(runs: dict[str, float]) -> list[tuple]:
    rows = []
    for run_id, scale in runs.items():
        for t, x in zip(T, [0.0, 1e-3 * scale, 2e-3 * scale]):
            rows.append((run_id, "step", run_id.split("/")[0], t, x))
    return sorted(rows)


@pytest.mark.parametrize("where", ["campaign=archive/wh", "run_id=EVIL/t_s=0/wh", "kind=leakage/wh", "wh[1]/w*h"])
def test_folders_above_the_warehouse_change_nothing(tmp_path, where):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / where)
    assert _samples(wh) == _expected({"c/a": 1.0})


def test_campaign_names_read_back_verbatim(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    names = {"lab%41b": 1.0, "rig=2": 2.0, "campaign=x": 3.0, "plain": 4.0, "x*": 5.0, "x1": 6.0, "b[1]": 7.0}
    for name, scale in names.items():
        _step(raw, f"{name}/a.csv", scale)
    wh = _build(raw, tmp_path / "wh")
    assert _samples(wh) == _expected({f"{n}/a": s for n, s in names.items()})
    counts = dict(run_query(wh, "SELECT campaign, count(*) FROM samples_step GROUP BY campaign")[1])
    assert counts == {n: 3 for n in names}


def test_moved_warehouse_reads_its_files(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    moved = tmp_path / "elsewhere" / "wh2"
    moved.parent.mkdir()
    shutil.move(wh, moved)
    assert _samples(moved) == _expected({"c/a": 1.0})


def test_copied_warehouse_reads_its_own_files_after_the_original_is_gone(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    copy = tmp_path / "copy"
    shutil.copytree(wh, copy)
    # the copy's own samples differ from the original's: a copy that read the original would show it
    for f in (wh / "samples").rglob("*.parquet"):
        f.write_bytes(b"not parquet")
    assert _samples(copy) == _expected({"c/a": 1.0})
    shutil.rmtree(wh)
    assert _samples(copy) == _expected({"c/a": 1.0})


def test_rebuild_after_a_move_works(tmp_path):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    shutil.move(wh, tmp_path / "wh2")
    _step(raw, "c/b.csv", 2.0)
    wh2 = _build(raw, tmp_path / "wh2")
    assert _samples(wh2) == _expected({"c/a": 1.0, "c/b": 2.0})


def test_plain_duckdb_client_needs_the_variable_and_says_so(tmp_path, monkeypatch):
    raw = RawBuilder(tmp_path / "raw")
    _step(raw, "c/a.csv")
    wh = _build(raw, tmp_path / "wh")
    monkeypatch.chdir(tmp_path)
    con = duckdb.connect(str(wh / DB_NAME), read_only=True)
    try:
        with pytest.raises(duckdb.Error, match=f"SET VARIABLE {ROOT_VARIABLE}"):
            con.execute("SELECT * FROM samples_step").fetchall()
        con.execute(f"SET VARIABLE {ROOT_VARIABLE} = ?", [str(wh)])
        assert con.execute("SELECT count(*) FROM samples_step").fetchone() == (3,)
        assert con.execute("SELECT count(*) FROM runs").fetchone() == (1,)
    finally:
        con.close()


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

    from pipeline.warehouse import FILES_TABLE, connect_readonly, create_samples_views

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
    from pipeline.warehouse import SAFE_NAME_SQL

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


def test_the_samples_macro_says_in_one_line_when_no_run_has_that_id(tmp_path):
    """A run_id the warehouse has no samples for: a QueryError that says so, not DuckDB's "No files
    found that match the pattern" with the warehouse's glob; through the CLI, one line and exit 2."""
    from click.testing import CliRunner

    from pipeline.cli import main
    from pipeline.serve.query import QueryError, open_query

    raw = RawBuilder(tmp_path / "raw")
    wh = tmp_path / "wh"
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[mm]": [1, 2, 3], "x_ref[mm]": [3] * 3})
    rebuild(raw.root, wh, jobs=1, report=False)
    with pytest.raises(QueryError, match=r"^samples\('<run_id>'\) found no samples file"):
        run_query(wh, "SELECT * FROM samples('c/nope')")
    for arrow in (True, False):
        with pytest.raises(QueryError, match="found no samples file"):
            with open_query(wh, "select count(*) from SAMPLES ('nope')", arrow=arrow) as _:
                pass
    with pytest.raises(duckdb.Error, match="Permission Error"):  # other SQL keeps DuckDB's words
        run_query(wh, "SELECT * FROM read_parquet('samples/none-*.parquet')")
    assert run_query(wh, "SELECT count(*) FROM samples_step WHERE run_id = 'nope'")[1] == [(0,)]
    res = CliRunner().invoke(main, ["query", "--warehouse", str(wh), "SELECT * FROM samples('nope')"])
    assert res.exit_code == 2 and "found no samples file" in res.output and len(res.output.strip().splitlines()) == 1
    assert len(run_query(wh, "SELECT * FROM samples('c/a')")[1]) == 3


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
