"""The refactoring check (benchmarks/same_behaviour.py) on small hand-made cases."""
from __future__ import annotations

from pathlib import Path

import duckdb

from benchmarks.same_behaviour import _mask, compare_tables


def _db(path: Path, rows: list[tuple], log_time: str) -> Path:
    con = duckdb.connect(str(path))
    con.execute("CREATE TABLE runs (run_id VARCHAR, n_samples BIGINT)")
    con.executemany("INSERT INTO runs VALUES (?, ?)", rows)
    con.execute("CREATE TABLE rebuild_log (generation VARCHAR, n_runs BIGINT)")
    con.execute("INSERT INTO rebuild_log VALUES (?, ?)", [log_time, len(rows)])
    con.close()
    return path


def test_equal_tables_are_the_same_and_volatile_columns_are_left_out(tmp_path):
    a = _db(tmp_path / "a.duckdb", [("r1", 10), ("r2", 20)], "gen-1")
    b = _db(tmp_path / "b.duckdb", [("r2", 20), ("r1", 10)], "gen-2")
    diffs, left_out = compare_tables(a, b)
    assert diffs == []
    assert left_out == ["rebuild_log.generation"]


def test_a_changed_value_and_a_duplicated_row_are_found(tmp_path):
    a = _db(tmp_path / "a.duckdb", [("r1", 10), ("r2", 20)], "g")
    b = _db(tmp_path / "b.duckdb", [("r1", 10), ("r2", 21)], "g")
    diffs, _ = compare_tables(a, b)
    assert diffs == ["runs: 1 rows only before, 1 only after (columns ['n_samples'])"]
    c = _db(tmp_path / "c.duckdb", [("r1", 10), ("r1", 10), ("r2", 20)], "g")
    diffs, _ = compare_tables(a, c)
    assert any(d.startswith("runs: 0 rows only before, 1 only after") for d in diffs)


def test_masks_hide_times_generations_durations_and_folders(tmp_path):
    one = f"warehouse {tmp_path}/w, generation 20261125T163620.216183Z-3041, finished 2026-11-25 16:36:20 UTC, 0.35 s"
    two = f"warehouse {tmp_path}/w, generation 20261126T020000.000001Z-12, finished 2026-11-26 02:00:00 UTC, 12 s"
    assert _mask(one, tmp_path) == _mask(two, tmp_path)
    assert _mask("leak 0.35 l/min", tmp_path) != _mask("leak 0.36 l/min", tmp_path)


def _runs_db(wh: Path, paths: dict[str, bytes]) -> Path:
    """A warehouse folder whose ``runs`` names one samples file per run, holding the given bytes."""
    wh.mkdir()
    con = duckdb.connect(str(wh / "pneubench.duckdb"))
    con.execute("CREATE TABLE runs (run_id VARCHAR, samples_path VARCHAR)")
    con.execute("CREATE TABLE ingest_state (source_path VARCHAR, result JSON, samples_paths VARCHAR[])")
    for rel, data in paths.items():
        source = rel.split("/")[-1].rsplit("-", 1)[0] + ".csv"
        con.execute("INSERT INTO ingest_state VALUES (?, ?, ?)", [source, f'{{"samples_path": "{rel}"}}', [rel]])
        (wh / rel).parent.mkdir(parents=True, exist_ok=True)
        (wh / rel).write_bytes(data)
        con.execute("INSERT INTO runs VALUES (?, ?)", [rel.split("/")[-1].rsplit("-", 1)[0], rel])
    con.close()
    return wh


def _samples(rel: str, values: list[float], compression: str = "zstd") -> bytes:
    """A samples file as the ingest writes one: a column and a footer that names its own path."""
    import io
    import json

    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table({"t_s": pa.array(values, pa.float64())})
    table = table.replace_schema_metadata({"pneubench": json.dumps({"samples_path": rel})})
    buf = io.BytesIO()
    pq.write_table(table, buf, compression=compression)
    return buf.getvalue()


def test_samples_renamed_by_a_new_ingest_code_version_are_the_same_and_changed_bytes_are_not(tmp_path):
    from benchmarks.same_behaviour import compare_samples

    def tree(name, files):
        return _runs_db(tmp_path / name, {rel: _samples(rel, *args) for rel, args in files.items()})

    a = tree("a", {"samples/c/r1-0123456789abcdef.parquet": ([1.0],), "samples/c/r2-1111111111111111.parquet": ([2.0],)})
    b = tree("b", {"samples/c/r1-fedcba9876543210.parquet": ([1.0],), "samples/c/r2-2222222222222222.parquet": ([2.0],)})
    assert compare_samples(a, b) == []
    assert compare_tables(a / "pneubench.duckdb", b / "pneubench.duckdb") == ([], [])
    c = tree("c", {"samples/c/r1-0123456789abcdef.parquet": ([1.0],), "samples/c/r2-1111111111111111.parquet": ([2.5],)})
    assert compare_samples(a, c) == ["samples: 1 of 2 runs differ, e.g. ['r2']"]
    e = tree("e", {"samples/c/r1-0123456789abcdef.parquet": ([1.0], "snappy"),
                   "samples/c/r2-1111111111111111.parquet": ([2.0],)})
    assert compare_samples(a, e) == ["samples: 1 of 2 runs differ, e.g. ['r1']"]  # same values, other codec
    d = tree("d", {"samples/c/r1-0123456789abcdef.parquet": ([1.0],),
                   "samples/other/r2-1111111111111111.parquet": ([2.0],)})
    diffs, _ = compare_tables(a / "pneubench.duckdb", d / "pneubench.duckdb")
    assert diffs == ["ingest_state: 1 rows only before, 1 only after (columns ['result', 'samples_paths'])",
                     "runs: 1 rows only before, 1 only after (columns ['samples_path'])"]
