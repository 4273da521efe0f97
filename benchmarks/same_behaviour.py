"""Did a refactor change behaviour? The demo warehouse built by two versions of the code, compared.

One command::

    python -m benchmarks.same_behaviour --ref main          # this checkout against main
    python -m benchmarks.same_behaviour --ref HEAD~3 --keep /tmp/cmp

The reference version is exported with ``git archive`` into a temporary folder; each version
simulates the demo campaign (seed 1; the two raw trees must be byte-identical, so the simulator
is compared too) and rebuilds it into its own warehouse as a process (``-q --jobs 2``). Then:

- **tables**: the same tables and views, the same columns and types, and the same rows (DuckDB
  ``EXCEPT ALL`` both ways over every table, both databases attached read-only); columns that
  name the code or the moment (:data:`VOLATILE`: a generation id, timestamps, code versions and
  the hashed stage-folder names derived from them) are left out and listed;
- **samples**: every run's samples Parquet file matched by run_id: schema, every column's value
  buffers, row groups and the footer's metadata, byte for byte, except the file key (it hashes
  the ingest code version, so a refactor of the ingest renames every file and the footer names
  its own path): masked in paths and footers;
- **figures**: every stage figure's PNG bytes, by (stage, name);
- **report**: ``report/index.html`` and every run page, after masking the build's time and
  durations;
- **commands**: exit code, stdout and stderr of a set of commands a user runs (a good query, a
  refused one, a failing one, ``tables``, ``describe``, a bad run id for ``plot``, a rebuild with a
  quarantined file and one with overlapping folders), with times, durations and the temporary
  folders masked.

Prints one line per check (``same`` or what differs) and exits 1 when anything differs.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Columns that legitimately differ between two builds (of the same code or not): when and by
#: which code a row was made, and names hashed from those.
VOLATILE = {
    "rebuild_log": {"generation", "started_at", "finished_at", "duration_s", "inputs_key"},
    "ingest_state": {"code_version", "mtime_ns", "inode"},
    "stage_cache": {"input_key", "folder"},
    "rebuild_inputs": set(),
    "figures": {"path"},
    "superseded_files": {"path", "superseded_at"},
}

#: A samples file is named ``<run>-<key>.parquet``, the key hashing the ingest code version too:
#: a change of the ingest code renames every file (same bytes). Paths are compared with the key
#: masked, and the files by run (``runs.samples_path``).
_KEY = r"-[0-9a-f]{16}\.parquet"
#: Columns holding samples paths, compared with :data:`_KEY` masked: {(table, column): SQL}.
KEYED = {
    ("runs", "samples_path"): "regexp_replace(\"samples_path\", '{key}', '-<key>.parquet', 'g')",
    ("samples_files", "path"): "regexp_replace(\"path\", '{key}', '-<key>.parquet', 'g')",
    ("ingest_state", "samples_paths"):
        "regexp_replace(\"samples_paths\"::VARCHAR, '{key}', '-<key>.parquet', 'g')",
    ("ingest_state", "result"): "regexp_replace(\"result\"::VARCHAR, '{key}', '-<key>.parquet', 'g')",
}

#: Text that changes from one build to the next: times, durations, sizes of timings, temp paths.
_MASKS = (
    (re.compile(r"\b\d{8}T\d{6}(\.\d+)?Z?-\d+\b"), "<gen>"),
    (re.compile(r"\d{4}-\d\d-\d\d[ T]\d\d:\d\d(:\d\d(\.\d+)?)?([+-]\d\d:?\d\d|Z| UTC)?"), "<time>"),
    (re.compile(r"\b\d+(\.\d+)?\s?(s|ms|min|h)\b"), "<dur>"),
    (re.compile(r"\b[0-9a-f]{12,64}\b"), "<hash>"),
)


def _mask(text: str, *folders: Path) -> str:
    for folder in folders:
        text = text.replace(str(folder), "<dir>")
    for pattern, repl in _MASKS:
        text = pattern.sub(repl, text)
    return text


def export(ref: str, dest: Path) -> Path:
    """The tree of ``ref`` (a commit, branch or tag) under ``dest`` via ``git archive``."""
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", "--format=tar", ref], cwd=ROOT, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    return dest


def pneubench(tree: Path, *args: str) -> subprocess.CompletedProcess:
    """``pneubench ARGS`` as a process, importing the code of ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONHASHSEED="0")
    env.pop("PNEUBENCH_RAW", None)
    env.pop("PNEUBENCH_WAREHOUSE", None)
    return subprocess.run([sys.executable, "-c", "from pipeline.cli import main; main()", *args],
                          cwd=tree, env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL)



def stage_tables_same(ref: str, script: str, args: list[str], prefix: str) -> bool:
    """Whether ``script`` (Python that pickles a dict of DataFrames to the path given as its last
    argument) gives the same tables run in this checkout and in ``ref``'s exported tree, bit for bit;
    prints one line per table."""
    import pickle

    import pandas as pd

    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        got = {}
        for tree in (ROOT, export(ref, Path(tmp) / "ref")):
            out = Path(tmp) / f"{len(got)}.pkl"
            subprocess.run([sys.executable, "-c", script, *args, str(out)], cwd=tree, check=True,
                           env=dict(os.environ, PYTHONPATH=str(tree)), stdin=subprocess.DEVNULL)
            with open(out, "rb") as fh:
                got[len(got)] = pickle.load(fh)
    mine, theirs = got.values()
    ok = True
    for table in sorted(set(mine) | set(theirs)):
        try:
            pd.testing.assert_frame_equal(mine[table], theirs[table], check_exact=True)
            print(f"  {table}: same ({len(mine[table])} rows, every value bit for bit)")
        except (AssertionError, KeyError) as exc:
            ok = False
            print(f"  {table}: DIFFERS from {ref}: {str(exc).splitlines()[0] if str(exc) else 'missing'}")
    return ok

def _digest_tree(folder: Path) -> dict[str, str]:
    out = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            out[str(path.relative_to(folder))] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def compare_raw(a: Path, b: Path) -> list[str]:
    da, db = _digest_tree(a), _digest_tree(b)
    if da == db:
        return []
    diff = sorted(k for k in set(da) | set(db) if da.get(k) != db.get(k))
    return [f"raw trees differ in {len(diff)} files, e.g. {diff[:3]}"]


def compare_tables(db_a: Path, db_b: Path) -> tuple[list[str], list[str]]:
    """(differences, volatile columns left out) between two warehouse databases."""
    import duckdb

    con = duckdb.connect()
    con.execute(f"ATTACH '{db_a}' AS a (READ_ONLY)")
    con.execute(f"ATTACH '{db_b}' AS b (READ_ONLY)")

    def columns(db):
        return {(t, c): d for t, c, d in con.execute(
            "SELECT table_name, column_name, data_type FROM duckdb_columns() WHERE database_name = ? "
            "ORDER BY table_name, column_index", [db]).fetchall()}

    def tables(db):
        return dict(con.execute(
            "SELECT table_name, 'table' FROM duckdb_tables() WHERE database_name = ? UNION ALL "
            "SELECT view_name, 'view' FROM duckdb_views() WHERE database_name = ? AND NOT internal",
            [db, db]).fetchall())

    diffs, left_out = [], []
    ta, tb = tables("a"), tables("b")
    if ta != tb:
        diffs.append(f"tables: only before {sorted(set(ta) - set(tb))}, only after {sorted(set(tb) - set(ta))}, "
                     f"kind changed {sorted(t for t in set(ta) & set(tb) if ta[t] != tb[t])}")
    ca, cb = columns("a"), columns("b")
    if ca != cb:
        changed = sorted(f"{t}.{c}" for (t, c) in set(ca) | set(cb) if ca.get((t, c)) != cb.get((t, c)))
        diffs.append(f"columns differ: {changed[:12]}{' ...' if len(changed) > 12 else ''}")
    for table in sorted(t for t in set(ta) & set(tb) if ta[t] == "table"):
        volatile = VOLATILE.get(table, set())
        cols = [c for (t, c) in ca if t == table and (t, c) in cb and c not in volatile]
        left_out += [f"{table}.{c}" for c in sorted(volatile) if (table, c) in ca]
        if not cols:
            continue
        sel = ", ".join(KEYED[(table, c)].format(key=_KEY) if (table, c) in KEYED else f'"{c}"' for c in cols)
        n_ab = con.execute(f'SELECT count(*) FROM (SELECT {sel} FROM a."{table}" EXCEPT ALL '
                           f'SELECT {sel} FROM b."{table}")').fetchone()[0]
        n_ba = con.execute(f'SELECT count(*) FROM (SELECT {sel} FROM b."{table}" EXCEPT ALL '
                           f'SELECT {sel} FROM a."{table}")').fetchone()[0]
        if n_ab or n_ba:
            def one(c):
                return KEYED[(table, c)].format(key=_KEY) if (table, c) in KEYED else f'"{c}"'
            bad = [c for c in cols if con.execute(
                f'SELECT count(*) FROM (SELECT {one(c)} FROM a."{table}" EXCEPT ALL SELECT {one(c)} FROM b."{table}")'
            ).fetchone()[0]]
            diffs.append(f"{table}: {n_ab} rows only before, {n_ba} only after (columns {bad[:8]})")
    con.close()
    return diffs, left_out


def samples_digest(path: Path) -> str:
    """Digest of a samples Parquet file as a reader sees it: its schema, every column's values
    and the footer's key-value metadata, with the file key (which hashes the ingest code
    version, :data:`_KEY`) masked in the footer (it names the file's own path)."""
    import pyarrow.parquet as pq

    f = pq.ParquetFile(path)
    h = hashlib.sha256()
    # ARROW:schema is the serialised schema (metadata included): compared below, key masked
    meta = {k.decode(): re.sub(_KEY, "-<key>.parquet", v.decode()) for k, v in (f.metadata.metadata or {}).items()
            if k != b"ARROW:schema"}
    h.update(repr(sorted(meta.items())).encode())
    h.update(re.sub(_KEY, "-<key>.parquet", f.schema_arrow.to_string(show_schema_metadata=True, truncate_metadata=False)).encode())
    for i in range(f.num_row_groups):  # the layout a reader meets: rows, codecs, encodings per chunk
        rg = f.metadata.row_group(i)
        h.update(repr([rg.num_rows] + [(rg.column(j).compression, rg.column(j).encodings)
                                       for j in range(rg.num_columns)]).encode())
    table = f.read()
    for name in table.column_names:
        for chunk in table[name].combine_chunks().buffers():
            h.update(b"" if chunk is None else chunk.to_pybytes())
    return h.hexdigest()


def compare_samples(wa: Path, wb: Path) -> list[str]:
    """Every run's samples Parquet file (schema, values, row groups and footer metadata, the
    file key masked: :func:`samples_digest`), matched by run_id through each database's ``runs``."""
    import duckdb

    def digests(wh: Path) -> dict[str, str]:
        con = duckdb.connect(str(wh / "pneubench.duckdb"), read_only=True)
        try:
            rows = con.execute("SELECT run_id, samples_path FROM runs").fetchall()
        finally:
            con.close()
        return {r: samples_digest(wh / p) if p else "" for r, p in rows}

    da, db = digests(wa), digests(wb)
    diff = sorted(k for k in set(da) | set(db) if da.get(k) != db.get(k))
    return [f"samples: {len(diff)} of {len(set(da) | set(db))} runs differ, e.g. {diff[:3]}"] if diff else []


def compare_files(a: Path, b: Path, label: str, mask: bool = False) -> list[str]:
    if not a.exists() and not b.exists():
        return []
    if mask:
        def read(p):
            return _mask(p.read_text(encoding="utf-8", errors="replace"), a.parent, b.parent)
        fa = {str(p.relative_to(a)): read(p) for p in sorted(a.rglob("*.html"))}
        fb = {str(p.relative_to(b)): read(p) for p in sorted(b.rglob("*.html"))}
    else:
        fa, fb = _digest_tree(a), _digest_tree(b)
    diff = sorted(k for k in set(fa) | set(fb) if fa.get(k) != fb.get(k))
    return [f"{label}: {len(diff)} of {len(set(fa) | set(fb))} files differ, e.g. {diff[:3]}"] if diff else []


def compare_figures(wa: Path, wb: Path) -> list[str]:
    """Every figure's PNG bytes, matched by (stage, name) through each warehouse's ``figures`` table."""
    import duckdb

    def digests(wh: Path) -> dict[tuple[str, str], str]:
        con = duckdb.connect(str(wh / "pneubench.duckdb"), read_only=True)
        try:
            rows = con.execute("SELECT stage, name, path FROM figures").fetchall()
        finally:
            con.close()
        return {(s, n): hashlib.sha256((wh / p).read_bytes()).hexdigest() for s, n, p in rows}

    da, db = digests(wa), digests(wb)
    diff = sorted(k for k in set(da) | set(db) if da.get(k) != db.get(k))
    return [f"figures: {len(diff)} of {len(set(da) | set(db))} differ, e.g. {diff[:3]}"] if diff else []


def commands(tree: Path, work: Path, raw: Path) -> dict[str, tuple[int, str, str]]:
    """What a user sees from a set of commands, masked: {name: (exit code, stdout, stderr)}."""
    wh = work / "warehouse"
    bad_raw = work / "bad-raw"
    shutil.copytree(raw / "plpa-2025", bad_raw / "plpa-2025")
    (bad_raw / "plpa-2025" / "broken.csv").write_text("t[s],p_a[bar]\n0,1\n1,oops\n")
    cases = {
        "query": ("query", "SELECT kind, count(*) AS n FROM runs GROUP BY kind ORDER BY kind", "--warehouse", str(wh)),
        "query_csv": ("query", "SELECT run_id, n_samples FROM runs ORDER BY run_id LIMIT 5", "--format", "csv",
                      "--warehouse", str(wh)),
        "query_refused": ("query", "COPY runs TO '/tmp/x.csv'", "--warehouse", str(wh)),
        "query_failing": ("query", "SELECT no_such_column FROM runs", "--warehouse", str(wh)),
        "tables": ("tables", "--warehouse", str(wh)),
        "describe": ("describe", "leakage_map", "--warehouse", str(wh)),
        "plot_bad_run": ("plot", "no/such-run", "--warehouse", str(wh), "-o", str(work / "x.png")),
        "rebuild_noop": ("rebuild", "--raw", str(raw), "--warehouse", str(wh), "-q"),
        "rebuild_quarantine": ("rebuild", "--raw", str(bad_raw), "--warehouse", str(work / "wh-bad"), "-q"),
        "rebuild_overlap": ("rebuild", "--raw", str(raw), "--warehouse", str(raw / "wh"), "-q"),
    }
    out = {}
    for name, args in cases.items():
        res = pneubench(tree, *args)
        out[name] = (res.returncode, _mask(res.stdout, work, raw, tree), _mask(res.stderr, work, raw, tree))
    return out


def build(tree: Path, work: Path) -> tuple[Path, Path]:
    raw, wh = work / "raw", work / "warehouse"
    sim = pneubench(tree, "simulate", str(raw), "--profile", "demo", "--seed", "1", "-q")
    if sim.returncode:
        raise SystemExit(f"simulate failed in {tree}:\n{sim.stderr[-2000:]}")
    res = pneubench(tree, "rebuild", "--raw", str(raw), "--warehouse", str(wh), "--jobs", "2", "-q")
    if res.returncode not in (0, 1):
        raise SystemExit(f"rebuild failed in {tree} (exit {res.returncode}):\n{res.stderr[-2000:]}")
    return raw, wh


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.same_behaviour", description=__doc__.splitlines()[0])
    ap.add_argument("--ref", default="main", help="the version to compare this checkout with (default: main)")
    ap.add_argument("--keep", type=Path, help="build in this (new) folder and keep it, instead of a temporary one")
    args = ap.parse_args(argv)
    top = args.keep or Path(tempfile.mkdtemp(prefix="pneubench-same-"))
    try:
        before = export(args.ref, top / "ref")
        trees = {"before": before, "after": ROOT}
        built = {}
        for label, tree in trees.items():
            print(f"{label}: simulating and rebuilding the demo with {tree}", flush=True)
            built[label] = build(tree, top / label)
        checks = {"raw (simulator)": compare_raw(built["before"][0], built["after"][0])}
        (wa, wb) = built["before"][1], built["after"][1]
        diffs, left_out = compare_tables(wa / "pneubench.duckdb", wb / "pneubench.duckdb")
        checks["tables"] = diffs
        checks["samples Parquet"] = compare_samples(wa, wb)
        checks["figures"] = compare_figures(wa, wb)
        checks["report"] = compare_files(wa / "report", wb / "report", "report", mask=True)
        ca = commands(before, top / "before", built["before"][0])
        cb = commands(ROOT, top / "after", built["after"][0])
        checks["commands"] = [f"{n}: before {ca[n]!r}, after {cb[n]!r}"[:600] for n in ca if ca[n] != cb[n]]
        failed = False
        for name, problems in checks.items():
            print(f"{name}: {'same' if not problems else 'DIFFERENT'}")
            for p in problems:
                print(f"    {p}")
            failed = failed or bool(problems)
        print(f"left out as volatile: {', '.join(left_out) or 'nothing'}")
        return 1 if failed else 0
    finally:
        if not args.keep:
            shutil.rmtree(top, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
