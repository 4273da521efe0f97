"""Incremental state of the rebuild: what each raw file and each analysis stage was built from.

The state lives *inside* the warehouse database (tables ``ingest_state`` and ``stage_cache``,
DDL in ``schemas/ddl/96_rebuild.sql``), so it is swapped in atomically with the data it
describes: after a crash the state and the warehouse still agree.

Raw files
    One record per input file under raw/: its stat fingerprint ``(size, mtime_ns, inode)``, the
    SHA-256 of its content, a hash of the metadata that applies to it from outside the file
    (the merged ``rig.toml`` and its ``manifest.csv`` rows) and the code version of ingest.
    A run file is *unchanged* when all of these match the previous record; its runs row (or
    its quarantine reason) is then taken from the record and the file is not read at all. When
    only the stat fingerprint differs the file is hashed (a ``touch`` re-ingests nothing).
Stages
    A stage's outputs are cached in an immutable folder ``stages/<name>/<key>/`` keyed by a
    hash of the stage's code, the runs of every kind it reads, the hose logbooks and the test
    plan (for stages that read them) and the content of the earlier stages' tables it read. It
    re-runs when any of them changed.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.raw.problems import ConfigError
from pipeline.raw.rawfile import open_raw
from pipeline.raw.tree import RawTree
from pipeline.serve.door import connect_readonly
from pipeline.warehouse import log_order

if TYPE_CHECKING:  # pandas and the ingest are imported where used: a no-op rebuild needs neither
    import pandas as pd

#: Raw files that are not runs but change what the runs mean (their changes are reported).
SIDE_FILES = {"manifest.csv": "manifest", "rig.toml": "rig", "hoses.csv": "logbook", "plan.toml": "plan"}

#: A file modified this recently is hashed again next time (mtime granularity, "racy" files).
RACY_S = 2.0

def stat_key(st: os.stat_result) -> tuple[int, int, int]:
    """``(size, mtime_ns, inode)``, the fingerprint git and rsync trust too: bytes rewritten in
    place at the same size with the old mtime put back are not noticed (``--full`` hashes
    every file)."""
    return int(st.st_size), int(st.st_mtime_ns), int(st.st_ino)


def metadata_hash(tree: RawTree, path: Path) -> str:
    """Hash of the metadata that applies to a run from outside the file (rig.toml, manifests)."""
    try:
        # json.dumps({"rig": ..., "manifest": ..., "parts": ...}, sort_keys=True), built from the
        # rig part's JSON made once per folder (10,000 runs: 2 s -> 0.2 s)
        rig = tree.rig_json(path)
        text = '{"manifest": ' + json.dumps(tree.manifest_metadata(path), sort_keys=True, default=str)
        parts = tree.manifest_parts(path)  # rows for one sheet / group (`book.xlsx#Sheet2`)
        if parts:
            text += ', "parts": ' + json.dumps(parts, sort_keys=True, default=str)
        text += ', "rig": ' + rig + "}"
    except ConfigError as exc:
        text = json.dumps({"error": str(exc)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:32]


@dataclass
class FileRecord:
    """The state of one raw input file."""

    source_path: str
    role: str                      # run, manifest, rig, logbook, plan
    size_bytes: int
    mtime_ns: int
    inode: int
    source_sha256: str | None
    meta_hash: str | None = None
    code_version: str | None = None
    result: dict | None = None     # {"run": runs row, "channels": [...]} for an ingested run, or
    #                                {"parts": [{"run", "channels"} or {"error"}, ...]} for a file of
    #                                several runs (sheets / MDF groups, see pipeline.ingest.file.parts_mode)
    error: str | None = None       # quarantine reason for a run file that could not be used
    #: samples files of the record's runs (read with the record; None: take them from ``result``)
    samples: tuple[str, ...] | None = field(default=None, compare=False, repr=False)

    def __getattr__(self, name):
        # a record read back from the warehouse decodes its ``result`` on first use: a no-op
        # rebuild of 10,000 files never needs it (0.3 s of JSON)
        if name == "result" and "_result_json" in self.__dict__:
            text = self.__dict__.pop("_result_json")
            self.result = decode_result(text) if text else None
            if self.result is not None:  # as_row writes it back as read (the same text: json.dumps, sorted keys)
                self.__dict__["_result_text"] = (text, self.result)
            return self.result
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @classmethod
    def stored(cls, row: tuple) -> "FileRecord":
        """A record from a row of ``ingest_state`` (``source_path, role, size_bytes, mtime_ns, inode,
        source_sha256, meta_hash, code_version, result, error, samples_paths``), its ``result``
        JSON decoded when first used."""
        *fields, result_json, error, samples = row
        rec = cls(*fields, None, error, tuple(samples) if samples is not None else None)
        del rec.result
        rec._result_json = result_json
        return rec

    def samples_paths(self) -> list[str]:
        """Samples files (relative to the warehouse) of the runs this record holds."""
        if self.samples is not None:
            return list(self.samples)
        return [r.get("samples_path") for r in result_runs(self.result)]

    def as_row(self) -> dict:
        return {"source_path": self.source_path, "role": self.role, "size_bytes": self.size_bytes,
                "mtime_ns": self.mtime_ns, "inode": self.inode, "source_sha256": self.source_sha256,
                "meta_hash": self.meta_hash, "code_version": self.code_version, "result": self.result_text(),
                "error": self.error, "samples_paths": self.samples_paths() if self.role == "run" else None}

    def result_text(self) -> str | None:
        """``result`` as ``ingest_state`` stores it (JSON, sorted keys). A record read back from the
        warehouse gives the text it was read from, unless its ``result`` was replaced since: not
        encoded again (issue 26: 10,000 records' JSON re-encoded on every change, ~0.3 CPU-s). Stored text is ``json.dumps(..., sort_keys=True)`` of the same
        value, which reads back and encodes to the same text."""
        result = self.result  # (decoded here if it was not yet)
        kept = self.__dict__.get("_result_text")
        if kept is not None and kept[1] is result:
            return kept[0]
        return json.dumps(result, sort_keys=True) if result is not None else None


class StoredRun(dict):
    """A runs row decoded from its state record, with the JSON text it was stored as (``encoded``,
    UTF-8): ``json.dumps(row, sort_keys=True)``, the bytes :func:`encoded_runs` would make of it
    (issue 26: 10,000 rows encoded again on every change, ~0.13 CPU-s). The rebuild reads the rows
    it takes from records and does not change them before the stages' keys are made."""

    __slots__ = ("encoded",)


_DECODER = json.JSONDecoder()
_HEAD, _RUN = '{"channels": ', ', "run": '


def decode_result(text: str) -> dict | None:
    """A record's stored ``result`` (``json.dumps({"channels": [...], "run": {...}}, sort_keys=True)``,
    or ``{"parts": ...}``) decoded; the runs row of a one-run result as a :class:`StoredRun` holding
    its own text. Any other text is decoded as it is (the same values)."""
    if text.startswith(_HEAD) and text.endswith("}"):
        try:
            channels, end = _DECODER.raw_decode(text, len(_HEAD))
            if text.startswith(_RUN, end) and text.startswith("{", end + len(_RUN)):
                run_text = text[end + len(_RUN):-1]
                run = StoredRun(json.loads(run_text))
                run.encoded = run_text.encode()
                return {"channels": channels, "run": run}
        except ValueError:
            pass
    return json.loads(text)


# ``result`` has a default in __init__ but no class attribute, so that a record made by
# FileRecord.stored() without it reaches __getattr__ (and decodes its JSON) on first use
del FileRecord.result


@dataclass
class StageRecord:
    """A stage's cached outputs from the previous rebuild."""

    stage: str
    input_key: str
    folder: str
    kinds_read: list[str] = field(default_factory=list)
    all_runs_read: bool = False
    results_read: dict[str, str] = field(default_factory=dict)

    def as_row(self) -> dict:
        return {"stage": self.stage, "input_key": self.input_key, "folder": self.folder,
                "kinds_read": sorted(self.kinds_read), "all_runs_read": self.all_runs_read,
                "results_read": json.dumps(self.results_read, sort_keys=True)}


@dataclass
class PreviousState:
    """What the live warehouse was built from (empty when there is none)."""

    files: dict[str, FileRecord] = field(default_factory=dict)
    stages: dict[str, StageRecord] = field(default_factory=dict)
    samples: set[str] = field(default_factory=set)
    stage_folders: set[str] = field(default_factory=set)
    findings: dict[str, bool | None] = field(default_factory=dict)
    #: finding_id -> (change, changed_at) of the previous warehouse (sticky alerts)
    finding_changes: dict[str, tuple] = field(default_factory=dict)
    generation: str | None = None
    #: ``rebuild_log`` of the live warehouse, read when first asked for (:attr:`history`)
    history_loader: object = field(default=None, repr=False, compare=False)
    #: files of earlier warehouses still kept for their readers: path -> superseded at [s since epoch]
    superseded: dict[str, float] = field(default_factory=dict)
    #: :func:`pipeline.rebuild.noop.inputs_key` of the last rebuild (None before the column existed)
    inputs_key: str | None = None

    @property
    def history(self) -> "pd.DataFrame | None":
        """``rebuild_log`` of the live warehouse as a DataFrame (None without one)."""
        if "_history" not in self.__dict__:
            self.__dict__["_history"] = self.history_loader() if callable(self.history_loader) else None
        return self.__dict__["_history"]


def load_previous(warehouse: Path) -> PreviousState:
    """Read the state of the live warehouse; an unreadable or missing one gives an empty state."""
    prev = PreviousState()
    try:
        con = connect_readonly(warehouse)
    except Exception:
        return prev
    try:
        tables = {r[0] for r in con.execute("SELECT table_name FROM duckdb_tables()").fetchall()}
        if "runs" in tables:
            prev.samples = {r[0] for r in con.execute("SELECT samples_path FROM runs").fetchall() if r[0]}
        if "ingest_state" in tables:
            # a record's JSON is decoded only if the record is used (FileRecord.stored); its
            # samples files are a column of their own (None in a warehouse from before it)
            cols = {r[0] for r in con.execute("DESCRIBE ingest_state").fetchall()}
            samples = "samples_paths" if "samples_paths" in cols else "NULL"
            for row in con.execute("SELECT source_path, role, size_bytes, mtime_ns, inode, source_sha256, meta_hash, "
                                   f"code_version, result, error, {samples} FROM ingest_state").fetchall():
                rec = FileRecord.stored(row)
                prev.files[rec.source_path] = rec
        if "stage_cache" in tables:
            for stage, key, folder, kinds, all_runs, results in con.execute(
                    "SELECT stage, input_key, folder, kinds_read, all_runs_read, results_read FROM stage_cache").fetchall():
                prev.stages[stage] = StageRecord(stage, key, folder, list(kinds or []), bool(all_runs),
                                                 json.loads(results) if results else {})
                prev.stage_folders.add(folder)
        if "findings" in tables:
            prev.findings = dict(con.execute("SELECT finding_id, holds FROM findings").fetchall())
            cols = {r[0] for r in con.execute("DESCRIBE findings").fetchall()}
            if {"change", "changed_at"} <= cols:
                prev.finding_changes = {fid: (ch, at) for fid, ch, at in con.execute(
                    "SELECT finding_id, change, changed_at FROM findings").fetchall()}
        if "superseded_files" in tables:
            prev.superseded = {p: float(at) for p, at in con.execute(
                "SELECT path, epoch_us(superseded_at) / 1e6 FROM superseded_files").fetchall()}
        if "rebuild_log" in tables:
            cols = {r[0] for r in con.execute("DESCRIBE rebuild_log").fetchall()}
            # the last rebuild by its number, never by its clock (set back by NTP, a battery)
            last = con.execute(f"SELECT generation, {'inputs_key' if 'inputs_key' in cols else 'NULL'} "
                               f"FROM rebuild_log ORDER BY {log_order(cols)} LIMIT 1").fetchone()
            if last is not None:
                prev.generation = str(last[0])
                prev.inputs_key = last[1] if isinstance(last[1], str) else None

            def history(warehouse=warehouse):
                # the rebuild holds the warehouse's lock: the live database is the one read above
                c = connect_readonly(warehouse)
                try:
                    return c.sql("SELECT * FROM rebuild_log").to_arrow_table().to_pandas()
                finally:
                    c.close()

            prev.history_loader = history
    except Exception:
        # A warehouse from an older version: no usable state, everything is rebuilt.
        return PreviousState(samples=prev.samples, stage_folders=prev.stage_folders, superseded=prev.superseded)
    finally:
        con.close()
    return prev


# -- planning the ingest ---------------------------------------------------------------------
@dataclass
class FilePlan:
    """What to do with one run file."""

    path: Path
    rel: str
    stat: tuple[int, int, int]
    meta_hash: str
    status: str                    # new, changed, unchanged (decided), or "check" (hash it)
    reason: str = ""               # content, metadata, code, full
    previous: FileRecord | None = None


def plan_runs(tree: RawTree, files: list[Path], prev: PreviousState, code_version: str,
              warehouse: Path, full: bool = False) -> list[FilePlan]:
    """Decide per run file: unchanged (reuse its record), or to be hashed / ingested.

    Cheap: one ``stat`` per file and the metadata hash (rig.toml and manifests are parsed once
    per folder); no file is opened here.
    """
    plans = []
    root = os.fspath(warehouse)
    listed: dict[str, set[str]] = {}

    def present(rel: str | None) -> bool:
        """A samples file is there: its folder is listed once (10,000 files: one scandir per
        folder instead of a stat per file, 0.6 s -> 0.02 s on a cold cache)."""
        if rel is None:
            return False
        folder, _, name = rel.rpartition("/")
        names = listed.get(folder)
        if names is None:
            try:
                with os.scandir(os.path.join(root, folder)) as it:
                    names = {e.name for e in it if e.is_file(follow_symlinks=False)}
            except OSError:
                names = set()
            listed[folder] = names
        return name in names

    for path in files:
        rel = tree.rel(path)
        st = stat_key(os.stat(path))
        mh = metadata_hash(tree, path)
        old = prev.files.get(rel)
        if old is None or old.role != "run":
            plans.append(FilePlan(path, rel, st, mh, "new", "", old))
            continue
        if full:
            plans.append(FilePlan(path, rel, st, mh, "check", "full", old))
            continue
        same_stat = (old.size_bytes, old.mtime_ns, old.inode) == st
        same_ctx = old.meta_hash == mh and old.code_version == code_version
        samples_ok = all(present(p) for p in old.samples_paths())
        if same_stat and same_ctx and samples_ok:
            plans.append(FilePlan(path, rel, st, mh, "unchanged", "", old))
        else:
            reason = ("metadata" if old.meta_hash != mh else "code" if old.code_version != code_version
                      else "samples" if not samples_ok else "content")
            plans.append(FilePlan(path, rel, st, mh, "check", reason, old))
    return plans


def result_runs(result: dict | None) -> list[dict]:
    """The runs rows of a file's state record ``result`` (none, one, or one per part)."""
    if result is None:
        return []
    if "parts" in result:
        return [p["run"] for p in result["parts"] if p.get("run") is not None]
    return [result["run"]]


def record_result(res) -> dict | None:
    """A file's :class:`pipeline.ingest.file.IngestResult` as its state record's ``result``."""
    if res.parts is not None:
        return {"parts": [{"run": p.run, "channels": p.channels} if p.run is not None else {"error": p.error}
                          for p in res.parts]}
    return {"run": res.run, "channels": res.channels} if res.run is not None else None


def record_for(plan: FilePlan, sha: str | None, code_version: str, result: dict | None, error: str | None,
               now: float | None = None, retry: bool = False) -> FileRecord:
    """The new state record of a run file. A racy mtime, or ``retry`` (the file changed while
    it was read, or its reader crashed), is stored as -1: the next rebuild looks at it again."""
    size, mtime_ns, inode = plan.stat
    now = time.time() if now is None else now
    if retry or now - mtime_ns / 1e9 < RACY_S:
        mtime_ns = -1
    return FileRecord(plan.rel, "run", size, mtime_ns, inode, sha, plan.meta_hash, code_version, result, error)


def side_files(tree: RawTree) -> list[Path]:
    """manifest.csv, rig.toml and hoses.csv files of the raw tree that can be read, and the
    plan.toml at its top (hidden folders skipped; the walk of :func:`pipeline.raw.walk.walk_raw`)."""
    return [p for p in tree.listing().side if p.name.lower() in SIDE_FILES]


def side_records(tree: RawTree, prev: PreviousState) -> tuple[list[FileRecord], list[dict]]:
    """State records of the side files and their change rows (new / changed / unchanged)."""
    records, changes = [], []
    now = time.time()
    for p in side_files(tree):
        rel = tree.rel(p)
        st = stat_key(p.stat())
        old = prev.files.get(rel)
        if old is not None and (old.size_bytes, old.mtime_ns, old.inode) == st:
            sha = old.source_sha256
        else:
            from pipeline.ingest.hashing import sha256_file

            try:  # hashed through one descriptor, no symlink out of raw/ followed (pipeline.raw.rawfile)
                with open_raw(tree.root, p) as opened:
                    sha = sha256_file(opened.source)
            except OSError:
                sha = None  # not read: reading it for its metadata says why (a quarantine row)
        mtime = st[1] if now - st[1] / 1e9 >= RACY_S else -1
        records.append(FileRecord(rel, SIDE_FILES[p.name.lower()], st[0], mtime, st[2], sha))
        status = "new" if old is None else ("unchanged" if old.source_sha256 == sha else "changed")
        changes.append({"source_path": rel, "role": SIDE_FILES[p.name.lower()], "status": status,
                        "reason": "content" if status == "changed" else None})
    return records, changes


def logbook_hash(records: list[FileRecord]) -> str:
    """Hash of every hose logbook's path and content."""
    blob = sorted((r.source_path, r.source_sha256) for r in records if r.role == "logbook")
    return hashlib.sha256(json.dumps(blob).encode()).hexdigest()[:32]


# -- stage keys -------------------------------------------------------------------------------
def encoded_runs(runs: list[dict]) -> list[tuple[str, bytes]]:
    """``(kind, JSON of the row)`` of every runs row, sorted by ``run_id``: what
    :func:`runs_fingerprint` hashes, encoded once for all the stages of a rebuild (issue 26: each
    stage's key encoded every row of its kinds again, ~0.2 CPU-s at 10,000 runs); a row taken from
    its state record (:class:`StoredRun`) is the text it was stored as, not encoded again."""
    return [(r["kind"], r.encoded if type(r) is StoredRun else json.dumps(r, sort_keys=True, default=str).encode())
            for r in sorted(runs, key=lambda r: r["run_id"])]


def runs_fingerprint(runs: list[dict], kinds: set[str] | None,
                     encoded: list[tuple[str, bytes]] | None = None) -> str:
    """Hash of the runs rows of some kinds (all kinds when ``kinds`` is None); ``encoded``: the
    rows as :func:`encoded_runs` gives them (the same hash, without encoding them again)."""
    h = hashlib.sha256()
    for kind, blob in encoded_runs(runs) if encoded is None else encoded:
        if kinds is None or kind in kinds:
            h.update(blob)
    return h.hexdigest()[:32]


def frame_hash(df: pd.DataFrame | None) -> str:
    """Content hash of a DataFrame (columns, types and values)."""
    import pandas as pd

    if df is None:
        return "absent"
    h = hashlib.sha256(json.dumps([[str(c), str(t)] for c, t in df.dtypes.items()]).encode())
    if len(df) == 0:  # no values to hash (hash_pandas_object would add no bytes): ~1 ms saved per table
        return h.hexdigest()[:32]
    try:
        h.update(pd.util.hash_pandas_object(df, index=False).to_numpy().tobytes())
    except TypeError:
        h.update(df.to_json(orient="split", index=False, date_format="iso", default_handler=str).encode())
    return h.hexdigest()[:32]


def stage_input_key(name: str, code: str, runs: list[dict], kinds: set[str], logbooks: str | None,
                    plan: str | None = None, encoded: list[tuple[str, bytes]] | None = None) -> str:
    """A stage's cache key from what it declared: its code version, the runs of the kinds it
    reads, the logbooks' hash and the plan's (:attr:`pipeline.raw.plan.Plan.digest`; None when
    not declared). The tables it reads are compared apart. ``encoded``: the runs as
    :func:`encoded_runs` gives them (the same key)."""
    blob = {"stage": name, "code": code, "runs": runs_fingerprint(runs, kinds, encoded), "kinds": sorted(kinds),
            "logbooks": logbooks}
    if plan is not None:  # only then: the keys of stages that do not read the plan stay what they were
        blob["plan"] = plan
    return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:32]


# -- files of earlier warehouses ------------------------------------------------------------------
#: Default retention of superseded samples files and stage folders [h].
KEEP_SUPERSEDED_H = 24.0


def superseded_files(prev: PreviousState, in_use: set[str], now: float,
                     keep_h: float) -> tuple[dict[str, float], set[str]]:
    """Which files of earlier warehouses to keep for their readers, and which to collect.

    Parameters
    ----------
    prev : PreviousState
        The live warehouse's files (``samples``, ``stage_folders``) and the files it kept
        (``superseded``, with the time each was superseded).
    in_use : set of str
        Files the new warehouse uses (paths relative to the warehouse).
    now : float
        The rebuild's clock [s since epoch].
    keep_h : float
        Retention [h]: a file is kept this long after the first rebuild that stopped using it.

    Returns
    -------
    (kept, expired)
        ``kept``: path -> superseded at [s since epoch] (recorded in the new warehouse);
        ``expired``: paths whose retention has passed (to be collected).
    """
    superseded = {p: at for p, at in prev.superseded.items() if p not in in_use}
    for p in sorted((prev.samples | prev.stage_folders) - in_use):
        superseded.setdefault(p, now)
    expired = {p for p, at in superseded.items() if now - at >= keep_h * 3600.0}
    return {p: at for p, at in superseded.items() if p not in expired}, expired
