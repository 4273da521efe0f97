"""Ingest one raw file: the flow from a file in ``raw/`` to a ``runs`` row and samples Parquet.

``raw file -> run metadata and the opened export (pipeline.raw.metadata) -> column map
(columns) -> time base, derived channels, sensors, checks -> converted record batches
(samples) -> samples Parquet`` (written under a temporary name, then renamed), and an
:class:`~pipeline.ingest.result.IngestResult` with the ``runs`` row or the one-line reason the
file is quarantined. A file of several runs (``sheets = "all"``, ``groups = "all"``) is that flow
once per sheet / channel group.

Data is streamed batch by batch, so memory stays bounded whatever the file size.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa

from pipeline.ingest.checks import check_channels, check_metadata
from pipeline.ingest.columns import map_export_columns
from pipeline.ingest.derived import plan_derived
from pipeline.ingest.hashing import BackgroundHash, hash_whole
from pipeline.ingest.result import IngestError, IngestResult, one_line, read_run_record
from pipeline.ingest.samples import SamplesPlan, samples_file, write_batches
from pipeline.ingest.sensors import resolve_sensors
from pipeline.ingest.timebase import RATE_TOLERANCE, TimeCheck, resolve_time_base
from pipeline.raw.tree import RawTree
from pipeline.raw.metadata import MetadataError, Part, RunMetadata, parts_mode, run_metadata
from pipeline.raw.rawfile import RawFile, RawOpenError, open_raw
from pipeline.readers import list_parts
from schemas.channels import CHANNELS, reserved_clash
from schemas.kinds import samples_schema
from schemas.units import P_ATM_DEFAULT_PA


@dataclass(frozen=True)
class _Job:
    """One raw file to ingest, as :func:`ingest_file` was asked."""

    tree: RawTree
    #: the file's name in the raw tree (rig.toml and manifest rows are found by it)
    path: Path
    #: the path every read goes through: the opened descriptor's file
    src: Path
    warehouse: Path
    #: the file's path relative to the raw tree (``runs.source_path``)
    rel: str
    campaign: str | None
    #: keep an existing samples file of the same content key
    reuse: bool
    #: the ingest code's version for the samples file name (None: computed)
    code_version: str | None


def ingest_file(tree: RawTree, path: Path, warehouse: Path, reuse: bool = True,
                sha256: str | None = None, code_version: str | None = None,
                opened: RawFile | None = None) -> IngestResult:
    """Ingest one raw file into ``warehouse/samples/``; never raises for bad input.

    Parameters
    ----------
    tree : RawTree
        The raw tree (rig.toml and manifests).
    path : Path
        The raw file.
    warehouse : Path
        Warehouse folder; the samples file goes to
        ``samples/kind=<kind>/campaign=<campaign>/<run>-<key>.parquet``
        (:func:`pipeline.ingest.samples.samples_folder_name`).
    reuse : bool
        Keep an existing samples file with the same content key instead of writing it again.
    sha256 : str, optional
        The file's SHA-256 when the caller has just computed it (the rebuild hashes every
        changed file first): it is not read twice.
    code_version : str, optional
        The ingest code's version for the samples file name (default: computed here).
    opened : RawFile, optional
        The file opened by :func:`pipeline.raw.rawfile.open_raw` (the rebuild opens it to hash it
        first); default: opened here. Its hash and its data are read from that descriptor only
        (never the name again: a symlink swapped in later is not followed).

    Returns
    -------
    IngestResult
        With ``run`` set, or ``error`` set to the one-line quarantine reason.
    """
    rel = tree.rel(path)
    result = IngestResult(source_path=rel, campaign=tree.campaign(path))
    if opened is None:
        try:
            opened = open_raw(tree.root, path)
        except OSError as exc:  # RawOpenError: a symlink out of raw/, not a regular file
            result.error = one_line(str(exc) if isinstance(exc, RawOpenError)
                                    else f"cannot read file: {type(exc).__name__}: {exc}")
            result.transient = True
            return result
        with opened:
            return ingest_file(tree, path, warehouse, reuse, sha256, code_version, opened)
    job = _Job(tree, Path(path), opened.source, Path(warehouse), rel, result.campaign, reuse, code_version)
    try:
        keys = parts_mode(tree, Path(path))
    except MetadataError as exc:
        result.fail(exc)
        return result
    if keys is not None:
        return _ingest_parts(job, result, keys, sha256)
    try:
        result.run, result.channels, result.bytes_hashed = _ingest(job, sha256)
    except Exception as exc:  # noqa: BLE001
        # A reader or library (scipy, h5py, npTDMS, pyarrow) tripped over malformed input:
        # still one line, never a crash of the rebuild.
        result.fail(exc)
    return result


def _check_file(job: _Job) -> None:
    """Refuse a file outside a campaign folder or without bytes, before any reader sees it (its
    complaint would be about rows, not bytes)."""
    if job.campaign is None:
        raise IngestError("file is not in a campaign folder (raw/<campaign>/...)")
    if os.stat(job.src).st_size == 0:
        raise IngestError("empty file (0 bytes)")


def _ingest_parts(job: _Job, result: IngestResult, keys: tuple[str, str], sha: str | None) -> IngestResult:
    """Ingest every sheet / channel group of a file of several runs: one part result each, a
    bad part is that part's one-line error (naming the file's sheet or group), the others go on."""
    plural, singular = keys
    try:
        _check_file(job)
        if sha is None:  # hashed once for all its runs, before they are read
            sha, result.bytes_hashed = hash_whole(job.src)
        names = list_parts(job.src)
    except Exception as exc:  # noqa: BLE001 - as ingest_file: one line, never a crash
        result.fail(exc)
        return result
    result.sha256 = sha
    result.parts = []
    for name in names:
        part = IngestResult(source_path=result.source_path, campaign=result.campaign)
        try:
            part.run, part.channels = _ingest_run(job, sha, None, Part(plural, singular, name))
        except Exception as exc:  # noqa: BLE001
            part.fail(exc, prefix=f"{singular} {name!r}: ", unexpected="cannot read")
        result.parts.append(part)
    result.transient = any(p.transient for p in result.parts)
    return result


def _ingest(job: _Job, sha: str | None) -> tuple[dict, list[dict], int | None]:
    """Ingest a file of one run; a file not hashed yet is hashed while it is read.

    Returns
    -------
    run : dict
        The runs row.
    channels : list of dict
        The channels rows.
    bytes_hashed : int or None
        The bytes the ingest hashed itself [B] (None when ``sha`` was given).
    """
    _check_file(job)
    hashing = None if sha else BackgroundHash(job.src)
    try:
        run, channels = _ingest_run(job, sha, hashing)
    finally:
        if hashing is not None:
            hashing.cancel()
    return run, channels, None if hashing is None else hashing.n_bytes


def _ingest_run(job: _Job, sha: str | None, hashing: BackgroundHash | None,
                part: Part | None = None) -> tuple[dict, list[dict]]:
    """Ingest one run (a file, or a part of one): its runs row and channels.

    ``sha`` is the file's SHA-256 when known, else ``hashing`` computes it while the file is read.
    """
    run_meta = run_metadata(job.tree, job.path, job.campaign, job.src, part)
    plan, warnings = _plan(run_meta, job.campaign)
    rel_out = plan.file_for(sha, job.code_version) if sha else None
    run = {
        "run_id": plan.run_id, "kind": plan.kind, "campaign": job.campaign, "rig": plan.meta.get("rig"),
        "started_at": plan.meta.get("started_at"), "source_path": job.rel, "source_sha256": sha,
        "format": run_meta.export.format, "samples_path": rel_out.as_posix() if rel_out else None,
        "params": plan.meta,
    }
    if job.reuse and rel_out is not None and (job.warehouse / rel_out).exists():
        cached = read_run_record(job.warehouse / rel_out)
        if cached is not None:
            return cached["run"], cached["channels"]
    (job.warehouse / plan.folder).mkdir(parents=True, exist_ok=True)
    return _write(job, plan, run_meta, run, warnings, hashing)


def _plan(run_meta: RunMetadata, campaign: str) -> tuple[SamplesPlan, list[str]]:
    """How a run's export becomes samples: its columns, time base, derived channels and sensors,
    checked against what its kind needs. Returns the plan and ingest's own warnings."""
    meta, rig, export = run_meta.meta, run_meta.rig, run_meta.export
    kind = meta["kind"]
    maps, lookalikes = map_export_columns(export.columns, rig["channels"])
    present = {m.channel for m in maps if m.channel}
    time_base = resolve_time_base(meta, export)
    synth_time = "t" not in present and time_base is not None
    if synth_time:
        present.add("t")
    derived, derived_warnings = plan_derived(rig.get("derived", {}), maps, meta, "t" in present)
    present |= {d.channel for d in derived if d.channel}
    check_channels(kind, present, lookalikes, derived_warnings)
    sensors, sensor_warnings = resolve_sensors(rig.get("sensors", {}), meta, present)
    for key in sensors["drop"]:
        meta.pop(key, None)
    meta.update(sensors["set"])
    check_metadata(kind, meta, present, time_base)
    p_atm = float(meta.get("p_atm_pa", P_ATM_DEFAULT_PA))
    extra = [(m.column, m.unit, pa.float64() if m.numeric else pa.string()) for m in maps if m.channel is None]
    extra += [(d.column, d.unit, pa.float64()) for d in derived if d.channel is None]
    plan = SamplesPlan(str(meta["run_id"]), kind, campaign, meta, maps, derived, time_base, synth_time, p_atm,
                       samples_schema(sorted(present), extra))
    return plan, _plan_warnings(plan, lookalikes, derived_warnings + sensor_warnings)


def _plan_warnings(plan: SamplesPlan, lookalikes: dict, warnings: list[str]) -> list[str]:
    """Ingest's own warnings about a run, before its data is read: look-alike columns kept
    non-canonical, ``warnings`` (derived channels, sensors), names the samples views use, and a
    time base computed from a stated rate."""
    out = [f"column `{raw}` in `{unit}` looks like channel `{ch}` but is not a "
           f"{CHANNELS[ch].quantity}: kept as non-canonical `{m.column}`"
           for m in plan.maps if m.key in lookalikes for raw, ch, unit in [lookalikes[m.key]]]
    out += warnings
    out += [f"channel `{name}` is stored as `{column}`: `{clash}` is a name the samples views use"
            for name, column, clash in [(m.raw_name, m.column, m.reserved) for m in plan.maps]
            + [(d.name, d.column, None if d.channel else reserved_clash(d.name, d.unit)) for d in plan.derived]
            if clash]
    if plan.synth_time:
        out.append(f"time from `{plan.time_base.source}` ({plan.time_base.stated_rate_hz:.6g} Hz): the export has no "
                   "time column")
    return out


def _write(job: _Job, plan: SamplesPlan, run_meta: RunMetadata, run: dict, warnings: list[str],
           hashing: BackgroundHash | None) -> tuple[dict, list[dict]]:
    """Read the export's data into the samples file; complete ``run`` with what the data gave
    (rows, rate, span, the reader's warnings and the data's) and, when it was hashed while read,
    the file's SHA-256 and the samples file's name."""
    export = run_meta.export
    with samples_file(job.warehouse / plan.folder, plan.run_id, plan.schema) as out:
        check, empty = write_batches(out, plan, export.batches())
        warnings = warnings + _data_warnings(plan, check, empty)
        run.update(n_samples=check.n, sample_rate_hz=check.sample_rate_hz,
                   duration_s=(check.last - check.first), warnings=list(export.warnings) + warnings)
        channels = plan.channels()
        if hashing is None:
            rel_out = Path(run["samples_path"])
        else:  # hashed while parsing: the name and the record need it now
            sha = hashing.result()
            rel_out = plan.file_for(sha, job.code_version)
            run.update(source_sha256=sha, samples_path=rel_out.as_posix())
        out.finish(job.warehouse / rel_out, {"run": run, "channels": channels})
    return run, channels


def _data_warnings(plan: SamplesPlan, check: TimeCheck, empty: dict) -> list[str]:
    """Warnings about the data as read: repeated times, empty channels, a time column whose rate
    disagrees with the stated one. A run without rows is refused."""
    if check.n == 0:
        raise IngestError("no data rows")
    warnings = []
    if check.repeats:
        warnings.append(f"time repeats at {check.repeats} rows")
    warnings += [f"channel `{c}` is empty" for c, e in empty.items() if e]
    time_base = plan.time_base
    if time_base is not None and not plan.synth_time and check.sample_rate_hz:
        stated, seen = time_base.stated_rate_hz, check.sample_rate_hz
        if abs(seen - stated) > RATE_TOLERANCE * stated:
            warnings.append(f"time column's rate {seen:.6g} Hz disagrees with `{time_base.source}` "
                            f"{stated:.6g} Hz; the time column is used")
    return warnings
