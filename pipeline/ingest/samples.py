"""A run's samples Parquet: converting record batches to SI and writing the file.

:class:`SamplesPlan` is how one run's export becomes its samples table (columns, schema, time
base, derived channels); :func:`convert_batch` converts one record batch; :func:`samples_file`
and :func:`write_batches` write the file under a temporary name and rename it into place.
The file's name (:meth:`SamplesPlan.file_for`) carries a content key (:func:`ingest_key`), so
output of changed code or input never lands on a live file's name.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import uuid
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import versions as code_version_mod
from pipeline.ingest.columns import ColumnMap
from pipeline.ingest.derived import DerivedChannel, DerivedError
from pipeline.ingest.prefetch import prefetch
from pipeline.ingest.result import IngestError
from pipeline.ingest.timebase import TimeBase, TimeCheck


@dataclass(frozen=True)
class SamplesPlan:
    """How one run's export becomes its samples file."""

    run_id: str
    kind: str
    campaign: str
    #: the run's metadata (part of the file's key)
    meta: dict
    maps: list[ColumnMap]
    derived: list[DerivedChannel]
    #: the stated time base (None when none is stated)
    time_base: TimeBase | None
    #: ``t_s`` is computed from :attr:`time_base` (the export has no time column)
    synth_time: bool
    #: ambient pressure that absolute pressures are made gauge with [Pa]
    p_atm_pa: float
    schema: pa.Schema

    @property
    def folder(self) -> Path:
        """The run's samples folder, relative to the warehouse."""
        return Path("samples") / f"kind={self.kind}" / samples_folder_name(self.campaign)

    def file_for(self, sha: str, code_version: str | None) -> Path:
        """The samples file's path relative to the warehouse, for the source's SHA-256 [hex]."""
        tb = self.time_base
        key_meta = {**self.meta, "__derived": [[d.name, d.expression.text, d.unit] for d in self.derived],
                    "__time_base": None if not self.synth_time else [tb.rate_hz, tb.dt_s, tb.t0_s]}
        key = ingest_key(sha, key_meta, self.maps, code_version)
        return self.folder / f"{safe_file_name(self.run_id)}-{key[:16]}.parquet"

    def convert(self, batch: pa.RecordBatch, row0: int) -> pa.Table:
        """One raw record batch as samples (:func:`convert_batch`); ``row0``: its first row's index."""
        return convert_batch(batch, self.maps, self.schema, self.run_id, self.p_atm_pa, row0,
                             self.time_base if self.synth_time else None, self.derived)

    def channels(self) -> list[dict]:
        """The run's ``channels`` rows: mapped columns, a computed ``t``, derived channels."""
        channels = [dict(run_id=self.run_id, **m.describe()) for m in self.maps]
        if self.synth_time:
            channels.append(dict(run_id=self.run_id, column="t_s", channel="t", raw_name=f"= {self.time_base.source}",
                                 raw_unit=None, unit="s", type="DOUBLE"))
        channels += [dict(run_id=self.run_id, **d.describe()) for d in self.derived]
        return channels


def _float_values(batch: pa.RecordBatch, m: ColumnMap, row0: int) -> np.ndarray:
    """A numeric column of a batch as float64; a value that is no number is an IngestError naming its row."""
    arr = batch.column(m.key)
    if not pa.types.is_floating(arr.type):
        try:
            arr = arr.cast(pa.float64())
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            bad = _first_non_number(arr)
            raise IngestError(f"value {bad[1]!r} in channel `{m.channel or m.column}` at row {row0 + bad[0] + 1} "
                              "is not a number") from None
    values = arr.to_numpy(zero_copy_only=False)
    if values.dtype != np.float64:
        values = values.astype(np.float64)
    return values


def _first_non_number(arr):
    """(index, value) of the first value of ``arr`` that is not a number."""
    for i, v in enumerate(arr.to_pylist()):
        if v is None:
            continue
        try:
            float(v)
        except (TypeError, ValueError):
            return i, v
    return 0, None


def convert_batch(batch: pa.RecordBatch, maps: list[ColumnMap], schema: pa.Schema, run_id: str,
                  p_atm_pa: float, row0: int, time_base: TimeBase | None = None,
                  derived: list[DerivedChannel] | None = None) -> pa.Table:
    """Raw record batch -> samples table in SI (gauge pressures), in ``schema`` order.

    ``time_base`` synthesises ``t_s`` for an export without a time column; ``derived``
    channels are computed last, from the converted values (see :mod:`pipeline.ingest.derived`).
    """
    n = batch.num_rows
    arrays = {"run_id": pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, dtype=np.int32)), pa.array([run_id]))}
    for m in maps:
        if not m.numeric:
            arr = batch.column(m.key)
            arrays[m.column] = arr if pa.types.is_string(arr.type) else arr.cast(pa.string())
            continue
        v = _float_values(batch, m, row0)
        if m.scale != 1.0 or m.offset != 0.0:
            v = v * m.scale + m.offset
        if m.si_divisor:
            v = v / m.si_divisor
        elif m.si_scale != 1.0:
            v = v * m.si_scale
        if m.absolute:
            v = v - p_atm_pa
        arrays[m.column] = pa.array(v, type=pa.float64())
    if time_base is not None and "t_s" not in arrays:
        arrays["t_s"] = pa.array(time_base.times(row0, n), type=pa.float64())
    for d in derived or ():
        values = {name: (arrays[src].to_numpy(zero_copy_only=False) if isinstance(src, str) else src)
                  for name, src in d.inputs.items()}
        try:
            arrays[d.column] = pa.array(d.expression.evaluate(values, n), type=pa.float64())
        except DerivedError as exc:
            raise IngestError(f"rig.toml [derived] `{d.name}`: {exc}") from None
    return pa.Table.from_arrays([arrays[f.name] for f in schema], schema=schema)


def safe_file_name(run_id: str) -> str:
    """A run_id as a file name: runs of other characters than ``A-Za-z0-9._-`` as ``_``, at most 80."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", run_id).strip("._")[:80] or "run"


#: Characters of a campaign name written ``%XX`` in its samples folder name: DuckDB's file glob
#: takes ``\`` for a path separator (``\xNN`` of a Latin-1 name, ``data\[old]``) and
#: ``[ ] * ? { }`` for patterns; ``%`` itself, so that the name stays one-to-one.
_FOLDER_QUOTED = re.compile(r"[%\\\[\]*?{}]")


def samples_folder_name(campaign: str) -> str:
    """Name of a campaign's folder under ``samples/kind=<kind>/``: ``campaign=<campaign>`` with
    :data:`_FOLDER_QUOTED` characters as ``%XX`` (``data\\[old]`` -> ``campaign=data%5C%5Bold%5D``),
    so that the views name their files by plain paths and the ``samples()`` macro's folder glob
    lists every campaign. ``kind`` and ``campaign`` come from ``runs``, never from this name."""
    return "campaign=" + _FOLDER_QUOTED.sub(lambda m: f"%{ord(m.group()):02X}", campaign)


def ingest_key(sha: str, meta: dict, maps: list[ColumnMap], code_version: str | None = None) -> str:
    """Content key of a samples file: source bytes, metadata, column map and the ingest code's
    version (its source hash; the rebuild passes the one it computed, so every worker agrees),
    so output of changed code never lands on a live file's name."""
    if code_version is None:
        code_version = code_version_mod.ingest_code_version()
    blob = json.dumps({"sha": sha, "meta": meta, "maps": [m.__dict__ for m in maps], "v": code_version},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


def parquet_options(schema: pa.Schema) -> dict:
    """Parquet writer options for a samples file.

    Floats are written BYTE_STREAM_SPLIT + zstd level 1 (about twice as fast as the default
    dictionary + snappy, and smaller); dictionary encoding only for ``run_id`` and text columns,
    where it pays. See ``benchmarks/bench_ingest.py``.
    """
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    return {"use_dictionary": [f.name for f in schema if not pa.types.is_floating(f.type)],
            "use_byte_stream_split": floats or False, "compression": "zstd", "compression_level": 1}


class SamplesFile:
    """A samples file being written (:func:`samples_file`)."""

    def __init__(self, writer: pq.ParquetWriter):
        self.writer = writer
        #: where the file goes once finished (None: it is thrown away)
        self.target: Path | None = None

    def finish(self, target: Path, record: dict) -> None:
        """Store ``record`` (the runs row and channels) in the footer; the file goes to ``target``."""
        self.writer.add_key_value_metadata({"pneubench": json.dumps(record, sort_keys=True)})
        self.target = target


@contextmanager
def samples_file(folder: Path, run_id: str, schema: pa.Schema):
    """Write a samples file in ``folder`` under a temporary name; renamed to its target when
    :meth:`SamplesFile.finish` was called, else (an error) removed.

    Yields
    ------
    SamplesFile
    """
    tmp = folder / f".{safe_file_name(run_id)}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp"
    try:
        with pq.ParquetWriter(tmp, schema, **parquet_options(schema)) as writer:
            out = SamplesFile(writer)
            yield out
        if out.target is not None:
            os.replace(tmp, out.target)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_batches(out: SamplesFile, plan: SamplesPlan, batches) -> tuple[TimeCheck, dict]:
    """Convert and write an export's record batches (read ahead in a thread).

    Returns
    -------
    check : TimeCheck
        The time channel's checks, rows, rate and span.
    empty : dict
        Numeric column -> True when it holds no value.
    """
    check = TimeCheck()
    empty = {m.column: True for m in plan.maps if m.numeric}
    for batch in prefetch(batches):
        if batch.num_rows == 0:
            continue
        table = plan.convert(batch, check.n)
        check.update(table.column("t_s").to_numpy())
        for col in [c for c, e in empty.items() if e]:
            if table.column(col).null_count < table.num_rows and not np.all(np.isnan(table.column(col).to_numpy())):
                empty[col] = False
        out.writer.write_table(table)
    return check, empty
