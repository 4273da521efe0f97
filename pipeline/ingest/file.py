"""Ingest one raw export: metadata, channel mapping, unit conversion, validation, Parquet.

``raw file -> RawExport (reader) -> resolved metadata -> column map -> converted, validated
record batches -> samples Parquet`` (written under a temporary name, then renamed), and a
:class:`IngestResult` with the ``runs`` row or the one-line reason the file is quarantined.

Data is streamed batch by batch, so memory stays bounded whatever the file size.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import uuid
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import versions as code_version_mod
from pipeline.versions import INGEST_VERSION  # noqa: F401 (re-exported)
from pipeline.ingest.derived import DerivedError, Expression, parse_expression
from pipeline.raw.problems import ConfigError, display_name
from pipeline.raw.tree import RawTree
from pipeline.ingest.prefetch import prefetch
from pipeline.raw.rawfile import RawFile, RawOpenError, open_raw
from pipeline.readers import RawColumn, ReaderError, list_parts, parts_keys, read_export
from pipeline.readers.base import MAX_CHANNELS
from schemas.channels import (CHANNELS, canonical_name, noncanonical_column, other_dimension,
                              reserved_clash, sanitise_name)
from schemas.kinds import (KINDS, META_KEYS, coerce_value, implausible, missing_channels,
                           missing_metadata, samples_schema)
from schemas.units import P_ATM_DEFAULT_PA, accepted_symbols, lookup_unit


class IngestError(Exception):
    """A raw file that cannot be used; the message is the quarantine's one line."""


@dataclass
class ColumnMap:
    """How one raw column becomes one samples column."""

    key: str
    column: str
    channel: str | None
    raw_name: str
    raw_unit: str | None
    unit: str | None          # unit of the stored values
    scale: float = 1.0        # rig.toml scale
    offset: float = 0.0       # rig.toml offset
    si_scale: float = 1.0     # unit conversion (see schemas.units.Unit.to_si)
    absolute: bool = False    # absolute pressure: subtract p_atm
    si_divisor: float | None = None
    numeric: bool = True
    reserved: str | None = None  # the reserved column name the channel's own name gave (it got ``x_``)

    def describe(self) -> dict:
        return {"column": self.column, "channel": self.channel, "raw_name": self.raw_name,
                "raw_unit": self.raw_unit, "unit": self.unit, "type": "DOUBLE" if self.numeric else "VARCHAR"}


@dataclass
class IngestResult:
    """What ingesting one file produced: a runs row, or an error."""

    source_path: str
    campaign: str | None = None
    run: dict | None = None
    channels: list[dict] = field(default_factory=list)
    error: str | None = None
    #: the error may pass (the file could not be opened or read): look at the file again next time
    transient: bool = False
    #: how many bytes ``source_sha256`` was computed over when ingest hashed the file itself [B]
    bytes_hashed: int | None = None
    #: a file of several runs (``sheets = "all"``, ``groups = "all"``): one result per run, each
    #: with ``run`` or ``error`` (then ``run`` and ``error`` of the file's own result are None)
    parts: list["IngestResult"] | None = None
    #: SHA-256 of a file of several runs (the single-run result has it in ``run``) [hex]
    sha256: str | None = None


def sha256_file(path: Path, chunk: int = 1 << 22, stop=None, counted: list | None = None) -> str | None:
    """SHA-256 of a file, read in chunks. [hex] (None when the ``stop`` event was set.)
    ``counted``: a list the number of bytes hashed is appended to [B]."""
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            if stop is not None and stop.is_set():
                return None
            h.update(block)
            n += len(block)
    if counted is not None:
        counted.append(n)
    return h.hexdigest()


class _BackgroundHash:
    """SHA-256 of a file computed in a thread while the file is parsed (hashlib releases the
    GIL): a new file is read for its hash and for its data at the same time."""

    def __init__(self, path: Path):
        import threading

        self._stop = threading.Event()
        self._out: dict = {}
        self.n_bytes: int | None = None  # bytes hashed, once done
        self._thread = threading.Thread(target=self._run, args=(path,), name="ingest-sha256", daemon=True)
        self._thread.start()

    def _run(self, path):
        counted: list[int] = []
        try:
            self._out["sha"] = sha256_file(path, stop=self._stop, counted=counted)
            self.n_bytes = counted[0] if counted else None
        except BaseException as exc:  # noqa: BLE001 - re-raised by result()
            self._out["error"] = exc

    def result(self) -> str:
        self._thread.join()
        if "error" in self._out:
            raise self._out["error"]
        return self._out["sha"]

    def cancel(self) -> None:
        self._stop.set()


# -- metadata ------------------------------------------------------------------------------
def parse_started_at(value) -> str:
    """ISO 8601 text (or datetime) -> ISO 8601 in UTC; local time without offset is UTC."""
    if isinstance(value, datetime):
        dt = value
    else:
        text = str(value).strip()
        try:
            dt = datetime.fromisoformat(text.replace(" ", "T", 1) if "T" not in text and " " in text else text)
        except ValueError:
            raise IngestError(f"`started_at` is not ISO 8601: {text!r}") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc).isoformat()


def normalise_keys(meta: dict) -> dict:
    """Known keys matched case-insensitively onto their canonical spelling; others kept."""
    known = {k.casefold(): k for k in META_KEYS}
    out = {}
    for k, v in meta.items():
        key = known.get(str(k).strip().casefold(), str(k).strip())
        out[key] = v
    return out


def resolve_metadata(rig: dict, embedded: dict, manifest: dict, campaign: str, path: Path,
                     part: str | None = None) -> dict:
    """Merge the three metadata sources (manifest > embedded > rig.toml), type and check them.
    ``part``: the sheet or channel group of a file of several runs (default run_id
    ``<campaign>/<file stem>/<part>``)."""
    meta = {**normalise_keys(rig), **normalise_keys(embedded), **normalise_keys(manifest)}
    meta = {k: v for k, v in meta.items() if not (isinstance(v, str) and v.strip() == "")}
    default_id = f"{campaign}/{path.stem}" if part is None else f"{campaign}/{path.stem}/{part}"
    meta.setdefault("run_id", display_name(default_id))  # a non-UTF-8 name: \xNN
    for k, spec in META_KEYS.items():
        if spec.default is not None and k not in meta and (k == "p_atm_pa" or _kind_uses(meta.get("kind"), k)):
            meta[k] = spec.default
    try:
        meta = {k: coerce_value(k, v) for k, v in meta.items()}
    except ValueError as exc:
        raise IngestError(f"metadata {exc}") from None
    if meta.get("kind") is None:
        raise IngestError("missing metadata `kind` (one of " + ", ".join(KINDS) + "): " + _where_kind_goes(path))
    if "started_at" in meta:
        meta["started_at"] = parse_started_at(meta["started_at"])
    for k, v in list(meta.items()):
        meta[k] = _jsonable(v)
    return meta


#: Where a file of each format carries its own metadata (docs/bench-exports.md, docs/formats.md),
#: as an example declaring ``kind``.
_EMBEDDED_KIND = {
    **dict.fromkeys((".csv", ".txt"), "CSV: a `# kind: step` line above the header"),
    ".lvm": "LVM: `kind=step` in the header's Description",
    ".tdms": "TDMS: a root property `kind` = `step`",
    ".mat": "MAT: a struct `meta` with `meta.kind = 'step'`",
    **dict.fromkeys((".xlsx", ".xlsm", ".xls", ".ods"), "Excel: a `# kind: step` cell above the header, or a "
                                                        "`meta` sheet row `kind | step`"),
    **dict.fromkeys((".mf4", ".mdf"), "MDF: `kind=step` in the header comment"),
}


def _where_kind_goes(path: Path) -> str:
    """The three places a run's ``kind`` can be declared, each with a one-line example (the
    manifest row names this file)."""
    import csv
    import io

    name = display_name(path.name)
    if not name.isprintable():
        name = "run01" + path.suffix
    row = io.StringIO()
    csv.writer(row, lineterminator="").writerow([name, "step"])
    own = _EMBEDDED_KIND.get(path.suffix.lower())
    return ("declare it in " + (f"the file's own metadata ({own}), " if own else "the file's own metadata, ")
            + f"a manifest.csv row (`file,kind` then `{row.getvalue()}`) or rig.toml (`[metadata]` then "
              '`kind = "step"`)')


def _kind_uses(kind, key) -> bool:
    spec = KINDS.get(kind) if isinstance(kind, str) else None
    return spec is not None and (key in spec.metadata or (kind == "spring" and key == "stroke_mm")
                                 or (kind == "identification" and key == "id_sample_rate_hz"))


def _jsonable(v):
    if isinstance(v, (np.generic,)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    if isinstance(v, datetime):
        return v.isoformat()
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    return str(v)


# -- columns -------------------------------------------------------------------------------
def _rig_entry(col: RawColumn, channels_cfg: dict) -> dict | None:
    # The bare name, name[unit], the header text exactly as written (`time(sec)`, `Time (s)`),
    # then the 1-based index (headerless files) and the reader's key.
    for key in (col.name, f"{col.name}[{col.unit}]" if col.unit else None, col.header, str(col.index), col.key):
        if key is not None and key in channels_cfg:
            entry = channels_cfg[key]
            return entry if isinstance(entry, dict) else {"channel": str(entry)}
    return None


def map_columns(columns: list[RawColumn], channels_cfg: dict) -> list[ColumnMap]:
    """Map raw columns onto canonical channels (rig.toml ``[channels]`` first, then names).

    Linear in the number of columns (a dict of names taken and, per sanitised name, the next
    free suffix); more than :data:`pipeline.readers.base.MAX_CHANNELS` columns are refused.
    """
    if len(columns) > MAX_CHANNELS:
        raise IngestError(f"{len(columns)} columns: more than the limit of {MAX_CHANNELS} channels per file")
    maps: list[ColumnMap] = []
    seen: dict[str, str] = {}
    next_suffix: dict[str, int] = {}   # sanitised name -> next suffix to try
    for col in columns:
        entry = _rig_entry(col, channels_cfg or {})
        name = col.name
        unit_text = col.unit
        scale, offset = 1.0, 0.0
        if entry is not None:
            name = str(entry.get("channel", name))
            unit_text = entry.get("unit", unit_text)
            try:
                scale = float(entry.get("scale", 1.0))
                offset = float(entry.get("offset", 0.0))
            except (TypeError, ValueError):
                raise IngestError(f"rig.toml scale/offset of column `{col.name}` is not a number") from None
        channel = canonical_name(name)
        label = f"`{col.name}`" if col.name == str(col.index) or not col.name else f"`{col.name}` (column {col.index})"
        if channel is None:
            column = noncanonical_column(name, unit_text)
            base, k = column, next_suffix.get(column, 2)
            while column in seen:  # "Foo Bar" and "foo-bar" both sanitise to foo_bar: keep both
                column, k = f"{base}_{k}", k + 1
            next_suffix[base] = k
            maps.append(ColumnMap(col.key, column, None, col.name, col.unit, unit_text, scale, offset,
                                  numeric=col.dtype != "string", reserved=reserved_clash(name, unit_text)))
        else:
            quantity = CHANNELS[channel].quantity
            if unit_text is None or str(unit_text).strip() == "":
                raise IngestError(f"no unit for channel `{channel}` in column {label} "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            unit = lookup_unit(unit_text)
            if unit is None or unit.quantity != quantity:
                raise IngestError(f"unit `{unit_text}` not accepted for `{channel}` "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            column = CHANNELS[channel].column
            maps.append(ColumnMap(col.key, column, channel, col.name, unit_text, CHANNELS[channel].si_unit,
                                  scale, offset, unit.scale, unit.absolute, unit.divisor))
        if column in seen:
            raise IngestError(f"channel `{channel or column}` appears twice (`{seen[column]}` and `{col.name}`)")
        seen[column] = col.name
    return maps


# -- channels that only look canonical -------------------------------------------------------
def set_aside_lookalikes(columns: list[RawColumn], channels_cfg: dict) -> tuple[list[RawColumn], dict]:
    """Raw columns named like a canonical channel but recorded in a unit of another dimension.

    ``F`` in ``g`` is an accelerometer, not the force: without a rig.toml ``[channels]`` entry
    for it, such a column is renamed to its non-canonical column name (``f_g``) so that
    :func:`map_columns` keeps it as a non-canonical channel. Units in no table at all (a typo
    such as ``psig``) are not set aside: on a canonical name they stay an error.

    Returns
    -------
    columns : list of RawColumn
        The columns, look-alikes renamed.
    lookalikes : dict
        Column key -> (raw name, canonical channel it looks like, raw unit).
    """
    out, looks = [], {}
    for col in columns:
        channel = canonical_name(col.name)
        if channel is not None and _rig_entry(col, channels_cfg or {}) is None and other_dimension(col.unit):
            looks[col.key] = (col.name, channel, col.unit)
            col = RawColumn(key=col.key, name=noncanonical_column(col.name, col.unit), unit=col.unit,
                            index=col.index, dtype=col.dtype, header=col.header)
        out.append(col)
    return out, looks


def _lookalike_hint(channel: str, looks: dict) -> str:
    for raw_name, ch, unit in looks.values():
        if ch == channel:
            si = CHANNELS[channel].si_unit
            return (f"; column `{raw_name}` is in `{unit}`, not a {CHANNELS[channel].quantity}: if it is `{channel}`, "
                    f"map it in rig.toml: [channels.\"{raw_name}\"] channel = \"{channel}\" unit = \"{si}\"")
    return ""


# -- time base -------------------------------------------------------------------------------
#: MAT scalars that state the sample rate [Hz] or interval [s] of a MAT export.
MAT_RATE_KEYS = ("Fs", "fs", "sample_rate_hz")
MAT_DT_KEYS = ("dt",)
#: Relative disagreement between a ``t`` column's rate and a stated rate that is warned about.
RATE_TOLERANCE = 0.01


@dataclass(frozen=True)
class TimeBase:
    """Time of an export without a time column: ``t = t0_s + i / rate_hz`` (or ``+ i * dt_s``)."""

    rate_hz: float | None
    dt_s: float | None
    t0_s: float
    source: str

    @property
    def stated_rate_hz(self) -> float:
        return self.rate_hz if self.rate_hz is not None else 1.0 / self.dt_s

    def times(self, row0: int, n: int) -> np.ndarray:
        """Times of rows ``row0 .. row0 + n - 1``. [s]"""
        i = np.arange(row0, row0 + n, dtype=np.float64)
        t = i / self.rate_hz if self.rate_hz is not None else i * self.dt_s
        return t + self.t0_s if self.t0_s else t


def _positive(value, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise IngestError(f"{what} must be a number, got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(v) or v <= 0:
        raise IngestError(f"{what} must be a positive finite number, got {value!r}")
    return v


def resolve_time_base(meta: dict, export) -> TimeBase | None:
    """The stated time base of a run: metadata ``sample_rate_hz`` or ``dt_s`` (and ``t0_s``),
    else a MAT scalar ``Fs`` / ``fs`` / ``sample_rate_hz`` / ``dt``; None when none is stated."""
    t0 = float(meta.get("t0_s") or 0.0)
    if meta.get("sample_rate_hz") is not None:
        return TimeBase(_positive(meta["sample_rate_hz"], "metadata `sample_rate_hz`"), None, t0, "sample_rate_hz")
    if meta.get("dt_s") is not None:
        return TimeBase(None, _positive(meta["dt_s"], "metadata `dt_s`"), t0, "dt_s")
    if export.format == "mat":
        for k in MAT_RATE_KEYS:
            if k in export.metadata:
                return TimeBase(_positive(export.metadata[k], f"MAT scalar `{k}`"), None, t0, k)
        for k in MAT_DT_KEYS:
            if k in export.metadata:
                return TimeBase(None, _positive(export.metadata[k], f"MAT scalar `{k}`"), t0, k)
    return None


def check_plausible(meta: dict, time_base: TimeBase | None = None) -> None:
    """Refuse a stated value outside its physical range (:data:`schemas.kinds.PLAUSIBLE`): one
    line naming the key, the value and the range. A MAT scalar rate is held to the range of
    ``sample_rate_hz`` / ``dt_s``."""
    for key in sorted(meta):
        why = implausible(key, meta[key])
        if why is not None:
            raise IngestError(f"metadata `{key}` = {why}")
    mat_scalar = time_base is not None and time_base.source in MAT_RATE_KEYS + MAT_DT_KEYS
    if mat_scalar and time_base.source not in META_KEYS:  # `sample_rate_hz` is checked above
        key, value = (("sample_rate_hz", time_base.rate_hz) if time_base.rate_hz is not None
                      else ("dt_s", time_base.dt_s))
        why = implausible(key, value)
        if why is not None:
            raise IngestError(f"MAT scalar `{time_base.source}` = {why}")


# -- sensor characteristics -------------------------------------------------------------------
SENSOR_FIELDS = ("resolution", "noise")
_SENSOR_KEY = re.compile(r"^sensor_(?P<channel>.+)_(?P<what>resolution|noise)$", re.IGNORECASE)
_NUMBER_UNIT = re.compile(r"^\s*(?P<num>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(?P<unit>\S.*)?$")


def sensor_value_si(value, channel: str, what: str, where: str) -> float:
    """A sensor resolution or noise (``"5 um"``, ``"0.01 bar"``, or a number in the channel's SI
    unit) -> float in SI. A pressure step or noise is a difference: no gauge offset.

    Zero is allowed and means what :class:`analyses.quality.Sensor` means by it: a resolution of 0
    is a sensor that is not quantised (an analog sensor), a noise of 0 an ideal signal (a
    commanded set-point). Raises IngestError naming ``where`` when the value is negative, not
    finite, or not a quantity of the channel's dimension.
    """
    quantity = CHANNELS[channel].quantity
    si = CHANNELS[channel].si_unit
    if isinstance(value, bool):
        raise IngestError(f"{where}: {what} must be a number or a number with a unit, got {value!r}")
    if isinstance(value, (int, float)):
        v, scale = float(value), 1.0
    else:
        m = _NUMBER_UNIT.match(str(value))
        if not m:
            raise IngestError(f"{where}: {what} {value!r} is not a number with a unit (e.g. \"5 um\")")
        v, unit_text = float(m.group("num")), m.group("unit")
        scale = 1.0
        if unit_text:
            unit = lookup_unit(unit_text)
            if unit is None or unit.quantity != quantity:
                raise IngestError(f"{where}: unit `{unit_text}` is not a {quantity} unit "
                                  f"(accepted: {', '.join(accepted_symbols(quantity))})")
            scale = unit.scale
    if not math.isfinite(v) or v < 0:
        raise IngestError(f"{where}: {what} must be zero or positive and finite, got {value!r}")
    out = v * scale
    div = round(1.0 / scale) if scale < 1.0 else 0
    if div > 1 and abs(div * scale - 1.0) < 1e-12:
        out = v / div        # 5 um -> 5e-06 exactly as the literal
    if not math.isfinite(out) or out < 0:
        raise IngestError(f"{where}: {what} must be zero or positive and finite in {si}, got {value!r}")
    why = implausible(f"sensor:{quantity}", out)
    if why is not None:
        raise IngestError(f"{where}: {what} {why}")
    return out


def resolve_sensors(sensors_cfg: dict, meta: dict, present: set[str]) -> tuple[dict, list[str]]:
    """Sensor resolution / noise of a run, in SI, under ``sensor_<channel>_resolution|noise``.

    Sources: run metadata keys ``sensor_<channel>_resolution`` / ``_noise`` (any channel
    spelling, case-insensitive) override rig.toml ``[sensors.<channel>]``; rig.toml values are
    kept only for channels the run has.

    Returns
    -------
    params : dict
        ``{"set": {sensor key: SI float}, "drop": [metadata keys as spelled, replaced by "set"]}``
    warnings : list of str
    """
    out: dict = {}
    warnings: list[str] = []
    for name, table in sorted((sensors_cfg or {}).items()):
        channel = canonical_name(name)
        if not isinstance(table, dict):
            raise IngestError(f"rig.toml [sensors.{name}] must be a table with `resolution` and/or `noise`")
        if channel is None:
            warnings.append(f"rig.toml [sensors.{name}] ignored: `{name}` is not a canonical channel")
            continue
        unknown = sorted(set(table) - set(SENSOR_FIELDS))
        if unknown:
            raise IngestError(f"rig.toml [sensors.{name}]: unknown key(s) {', '.join(unknown)} "
                              f"(expected {', '.join(SENSOR_FIELDS)})")
        for what in SENSOR_FIELDS:
            if what in table:
                v = sensor_value_si(table[what], channel, what, f"rig.toml [sensors.{name}]")
                if channel in present:
                    out[f"sensor_{channel}_{what}"] = v
    drop = []
    for key in sorted(meta):
        m = _SENSOR_KEY.match(str(key))
        if not m or meta[key] is None:
            continue
        channel = canonical_name(m.group("channel"))
        if channel is None:
            continue   # a non-canonical channel's: kept as written (unknown keys are kept)
        what = m.group("what").lower()
        out[f"sensor_{channel}_{what}"] = sensor_value_si(meta[key], channel, what, f"metadata `{key}`")
        drop.append(key)
    return {"set": out, "drop": drop}, warnings


# -- derived channels -------------------------------------------------------------------------
#: Most derived channels a rig.toml may state (rig.toml is untrusted: bounded work per batch).
MAX_DERIVED = 64

@dataclass
class DerivedChannel:
    """A rig.toml ``[derived]`` channel of one run: its column and where each name comes from."""

    name: str
    channel: str | None
    column: str
    unit: str | None
    expression: Expression
    inputs: dict            # name -> samples column (str) or metadata value (float)

    def describe(self) -> dict:
        return {"column": self.column, "channel": self.channel, "raw_name": f"= {self.expression.text}",
                "raw_unit": None, "unit": self.unit, "type": "DOUBLE"}


def plan_derived(derived_cfg: dict, maps: list[ColumnMap], meta: dict,
                 time_column: bool) -> tuple[list[DerivedChannel], list[str]]:
    """Check rig.toml ``[derived]`` against a run: which channels it can compute.

    Names in an expression are, in this order: canonical channels (in SI), non-canonical
    channels by their sanitised raw name (as recorded), channels derived before it, numeric
    metadata values. A derived channel whose names the run does not have is skipped with a
    warning (its rig.toml may serve other files); a derived canonical channel that the file
    also carries is an error.
    """
    names: dict = {}
    for key, v in meta.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v)):
            names[key] = float(v)
    for m in maps:
        if m.numeric and m.channel is None:
            alias = sanitise_name(m.raw_name)
            if canonical_name(alias) is None:   # a look-alike `F[g]` is `f_g`, never `f`
                names[alias] = m.column
            names[m.column] = m.column
    for m in maps:
        if m.channel is not None:
            names[m.channel] = m.column
    if time_column:
        names["t"] = "t_s"
    taken = {m.column for m in maps} | ({"t_s"} if time_column else set())
    if len(derived_cfg or {}) > MAX_DERIVED:
        raise IngestError(f"rig.toml [derived] has {len(derived_cfg)} channels (at most {MAX_DERIVED})")
    out, warnings = [], []
    for name, entry in (derived_cfg or {}).items():
        unit = None
        text = entry
        if isinstance(entry, dict):
            unknown = sorted(set(entry) - {"expr", "unit"})
            if unknown or "expr" not in entry:
                raise IngestError(f"rig.toml [derived] `{name}` must be an expression or a table with `expr` "
                                  "(and optional `unit`)")
            text, unit = entry["expr"], entry.get("unit")
        try:
            expr = parse_expression(text)
        except DerivedError as exc:
            raise IngestError(f"rig.toml [derived] `{name}`: {exc}") from None
        channel = canonical_name(name)
        if channel is not None:
            column, unit = CHANNELS[channel].column, CHANNELS[channel].si_unit
        else:
            column = noncanonical_column(name, unit)
        if column in taken:
            raise IngestError(f"rig.toml [derived] `{name}`: the file already has channel `{channel or column}`")
        missing = [k for k in expr.names if k not in names]
        if missing:
            warnings.append(f"derived channel `{name}` not computed: no channel or numeric metadata "
                            + ", ".join(f"`{k}`" for k in missing))
            continue
        out.append(DerivedChannel(name, channel, column, None if unit is None else str(unit), expr,
                                  {k: names[k] for k in expr.names}))
        taken.add(column)
        names[channel or sanitise_name(name)] = column
        names[column] = column
    return out, warnings


# -- data ----------------------------------------------------------------------------------
def _float_values(batch: pa.RecordBatch, m: ColumnMap, row0: int) -> np.ndarray:
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


class _TimeCheck:
    """Streaming checks of the time channel: present, finite, never backwards; rate and span."""

    def __init__(self):
        self.last = None
        self.first = None
        self.n = 0
        self.repeats = 0
        self.dt_sample: np.ndarray | None = None

    def update(self, t: np.ndarray) -> None:
        if t.size == 0:
            return
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise IngestError(f"time is missing at row {self.n + bad[0] + 1}")
        if self.first is None:
            self.first = float(t[0])
        prev = np.concatenate(([self.last], t)) if self.last is not None else t
        dt = np.diff(prev)
        back = np.flatnonzero(dt < 0)
        if back.size:
            row = self.n + back[0] + (1 if self.last is not None else 2)
            raise IngestError(f"time goes backwards at row {row} ({prev[back[0]]:.6g} s -> {prev[back[0] + 1]:.6g} s)")
        self.repeats += int(np.count_nonzero(dt == 0))
        if self.dt_sample is None and dt.size >= 1:
            self.dt_sample = dt[: 100_000]
        self.last = float(t[-1])
        self.n += t.size

    @property
    def sample_rate_hz(self) -> float | None:
        if self.dt_sample is None:
            return None
        pos = self.dt_sample[self.dt_sample > 0]
        if pos.size == 0:
            return None
        return float(1.0 / np.median(pos))


def safe_file_name(run_id: str) -> str:
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
        ``samples/kind=<kind>/campaign=<campaign>/<run>-<key>.parquet`` (:func:`samples_folder_name`).
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
            result.error = _one_line(str(exc) if isinstance(exc, RawOpenError)
                                     else f"cannot read file: {type(exc).__name__}: {exc}")
            result.transient = True
            return result
        with opened:
            return ingest_file(tree, path, warehouse, reuse, sha256, code_version, opened)
    src = opened.source  # the path every read goes through: the opened descriptor's file
    try:
        keys = parts_mode(tree, Path(path))
    except IngestError as exc:
        result.error = _one_line(str(exc))
        return result
    if keys is not None:
        return _ingest_parts(tree, Path(path), Path(warehouse), result, keys, reuse, sha256, code_version, src)
    hashed: list = []
    try:
        run, channels = _ingest(tree, Path(path), Path(warehouse), rel, result.campaign, reuse, sha256, code_version,
                                hashed, src)
        result.run, result.channels = run, channels
        result.bytes_hashed = hashed[0] if hashed else None
    except (IngestError, ReaderError, ConfigError) as exc:
        result.error = _one_line(str(exc))
    except Exception as exc:  # noqa: BLE001
        # A reader or library (scipy, h5py, npTDMS, pyarrow) tripped over malformed input:
        # still one line, never a crash of the rebuild.
        result.error = _one_line(f"cannot read file: {type(exc).__name__}: {exc}")
        result.transient = isinstance(exc, OSError) and not isinstance(exc, pa.ArrowException)
    return result


def _one_line(text: str) -> str:
    return " ".join(str(text).split())[:500]


# -- files of several runs ---------------------------------------------------------------------
def parts_mode(tree: RawTree, path: Path) -> tuple[str, str] | None:
    """``(parts key, part key)`` when a file is several runs, else None (one file, one run).

    A workbook is one run per sheet, and an MDF file one run per channel group, when its
    manifest row, ``rig.toml`` ``[metadata]`` or ``rig.toml`` ``[read]`` (in that precedence)
    set ``sheets = "all"`` / ``groups = "all"``. Formats with one run per file ignore the keys.

    Raises
    ------
    IngestError
        The key has another value than ``"all"``.
    """
    keys = parts_keys(path)
    if keys is None:
        return None
    try:
        rig = tree.rig_config(path)
        manifest = normalise_keys(tree.manifest_metadata(path))
    except ConfigError:
        return None  # the one-run ingest reports it, as for any file
    plural, singular = keys
    value = manifest.get(plural, normalise_keys(rig["metadata"]).get(plural, rig["read"].get(plural)))
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return None
    if str(value).strip().casefold() != "all":
        raise IngestError(f"`{plural} = {value!r}`: the only value is \"all\" (one run per {singular}); "
                          f"to read one {singular}, name it with the `{singular}` key")
    return keys


def _ingest_parts(tree: RawTree, path: Path, warehouse: Path, result: IngestResult, keys: tuple[str, str],
                  reuse: bool, sha: str | None, code_version: str | None, src: Path | None = None) -> IngestResult:
    """Ingest every sheet / channel group of a file of several runs: one part result each, a
    bad part is that part's one-line error (naming the file's sheet or group), the others go on."""
    plural, singular = keys
    src = src or path
    try:
        if result.campaign is None:
            raise IngestError("file is not in a campaign folder (raw/<campaign>/...)")
        if os.stat(src).st_size == 0:
            raise IngestError("empty file (0 bytes)")
        if sha is None:  # hashed once for all its runs, before they are read
            counted: list[int] = []
            sha = sha256_file(src, counted=counted)
            result.bytes_hashed = counted[0] if counted else None
        names = list_parts(src)
    except (IngestError, ReaderError, ConfigError) as exc:
        result.error = _one_line(str(exc))
        return result
    except Exception as exc:  # noqa: BLE001 - as ingest_file: one line, never a crash
        result.error = _one_line(f"cannot read file: {type(exc).__name__}: {exc}")
        result.transient = isinstance(exc, OSError) and not isinstance(exc, pa.ArrowException)
        return result
    result.sha256 = sha
    result.parts = []
    for name in names:
        part = IngestResult(source_path=result.source_path, campaign=result.campaign)
        try:
            part.run, part.channels = _ingest_hashed(tree, path, warehouse, result.source_path, result.campaign,
                                                     reuse, sha, None, code_version, part=(plural, singular, name),
                                                     src=src)
        except (IngestError, ReaderError, ConfigError) as exc:
            part.error = _one_line(f"{singular} {name!r}: {exc}")
        except Exception as exc:  # noqa: BLE001
            part.error = _one_line(f"{singular} {name!r}: cannot read: {type(exc).__name__}: {exc}")
            part.transient = isinstance(exc, OSError) and not isinstance(exc, pa.ArrowException)
        result.parts.append(part)
    result.transient = any(p.transient for p in result.parts)
    return result


def _part_context(rig: dict, manifest: dict, part: tuple[str, str, str], own: dict) -> tuple[dict, dict]:
    """rig.toml config and manifest metadata of one sheet / group of a file of several runs:
    the part key names it, the parts key is dropped (it is not run metadata), a run_id the
    manifest gives the file becomes ``<run_id>/<part>``, and the manifest row of the part
    itself (``own``, ``file = book.xlsx#Sheet2``) overrides the file's row."""
    plural, singular, name = part
    drop = {plural, singular}
    rig = {**rig, "read": {**rig["read"], plural: "all"},
           "metadata": {k: v for k, v in rig["metadata"].items() if str(k).strip().casefold() not in drop}}
    out = {}
    for k, v in manifest.items():
        key = str(k).strip().casefold()
        if key in drop:
            continue
        out[k] = f"{v}/{name}" if key == "run_id" and not (isinstance(v, str) and v.strip() == "") else v
    for k, v in own.items():
        key = str(k).strip().casefold()
        if key in drop:
            continue
        for old in [o for o in out if str(o).strip().casefold() == key]:
            del out[old]
        out[k] = v
    out[singular] = name
    return rig, out


def _ingest(tree: RawTree, path: Path, warehouse: Path, rel: str, campaign: str | None, reuse: bool,
            sha: str | None = None, code_version: str | None = None, bytes_hashed: list | None = None,
            src: Path | None = None):
    src = src or path
    if campaign is None:
        raise IngestError("file is not in a campaign folder (raw/<campaign>/...)")
    if os.stat(src).st_size == 0:  # before any reader: its complaint would be about rows, not bytes
        raise IngestError("empty file (0 bytes)")
    hashing = None if sha else _BackgroundHash(src)
    try:
        return _ingest_hashed(tree, path, warehouse, rel, campaign, reuse, sha, hashing, code_version, src=src)
    finally:
        if hashing is not None:
            hashing.cancel()
            if bytes_hashed is not None:
                bytes_hashed.append(hashing.n_bytes)


def _ingest_hashed(tree, path, warehouse, rel, campaign, reuse, sha, hashing, code_version, part=None, src=None):
    rig = tree.rig_config(path)
    manifest = tree.manifest_metadata(path)
    if part is not None:
        rig, manifest = _part_context(rig, manifest, part, tree.manifest_parts(path).get(part[2], {}))
    export = _open_export(src or path, rig, manifest)  # src: the opened file, under the same name
    meta = resolve_metadata(rig["metadata"], export.metadata, manifest, campaign, path,
                            part=None if part is None else part[2])
    if part is not None:  # a sheet / group name is the file's text: one line, valid UTF-8
        meta["run_id"] = display_name(meta["run_id"])
    kind = meta["kind"]
    raw_columns, lookalikes = set_aside_lookalikes(export.columns, rig["channels"])
    maps = map_columns(raw_columns, rig["channels"])
    for m in maps:
        if m.key in lookalikes:
            m.raw_name = lookalikes[m.key][0]
    present = {m.channel for m in maps if m.channel}
    time_base = resolve_time_base(meta, export)
    synth_time = "t" not in present and time_base is not None
    if synth_time:
        present.add("t")
    derived, derived_warnings = plan_derived(rig.get("derived", {}), maps, meta, "t" in present)
    present |= {d.channel for d in derived if d.channel}
    gaps = missing_channels(kind, present)
    if gaps:
        hint = "".join(_lookalike_hint(c, lookalikes) for c in gaps)
        if "t" in gaps:
            hint += "; no time column: state `sample_rate_hz` or `dt_s` (and `t0_s`) in the run's metadata"
        hint += "".join(f"; {w}" for w in derived_warnings
                        if any(f"`{c}`" in w.split(" not computed")[0] for c in gaps))
        raise IngestError(f"missing channel {', '.join(f'`{c}`' for c in gaps)} (kind {kind} needs "
                          + " or ".join(", ".join(s) for s in KINDS[kind].channel_sets) + ")" + hint)
    sensors, sensor_warnings = resolve_sensors(rig.get("sensors", {}), meta, present)
    for key in sensors["drop"]:
        meta.pop(key, None)
    meta.update(sensors["set"])
    miss = missing_metadata(kind, meta, present)
    if miss:
        raise IngestError(f"missing metadata {', '.join(f'`{k}`' for k in miss)} (kind {kind})")
    if KINDS[kind].chambers and meta.get("chamber") not in KINDS[kind].chambers:
        raise IngestError(f"metadata `chamber` must be one of {', '.join(KINDS[kind].chambers)} "
                          f"for kind {kind}, got {meta.get('chamber')!r}")
    check_plausible(meta, time_base)
    p_atm = float(meta.get("p_atm_pa", P_ATM_DEFAULT_PA))
    extra = [(m.column, m.unit, pa.float64() if m.numeric else pa.string()) for m in maps if m.channel is None]
    extra += [(d.column, d.unit, pa.float64()) for d in derived if d.channel is None]
    schema = samples_schema(sorted(present), extra)
    run_id = str(meta["run_id"])
    folder = Path("samples") / f"kind={kind}" / samples_folder_name(campaign)

    def samples_path(sha: str) -> Path:
        key_meta = {**meta, "__derived": [[d.name, d.expression.text, d.unit] for d in derived],
                    "__time_base": None if not synth_time else [time_base.rate_hz, time_base.dt_s, time_base.t0_s]}
        return folder / f"{safe_file_name(run_id)}-{ingest_key(sha, key_meta, maps, code_version)[:16]}.parquet"

    rel_out = samples_path(sha) if sha else None
    # ingest's own warnings; the reader's are taken after its data is read
    warnings: list[str] = [f"column `{raw}` in `{unit}` looks like channel `{ch}` but is not a "
                           f"{CHANNELS[ch].quantity}: kept as non-canonical `{m.column}`"
                           for m in maps if m.key in lookalikes for raw, ch, unit in [lookalikes[m.key]]]
    warnings += derived_warnings + sensor_warnings
    warnings += [f"channel `{name}` is stored as `{column}`: `{clash}` is a name the samples views use"
                 for name, column, clash in [(m.raw_name, m.column, m.reserved) for m in maps]
                 + [(d.name, d.column, None if d.channel else reserved_clash(d.name, d.unit)) for d in derived]
                 if clash]
    if synth_time:
        warnings.append(f"time from `{time_base.source}` ({time_base.stated_rate_hz:.6g} Hz): the export has no "
                        "time column")
    run = {
        "run_id": run_id, "kind": kind, "campaign": campaign, "rig": meta.get("rig"),
        "started_at": meta.get("started_at"), "source_path": rel, "source_sha256": sha,
        "format": export.format, "samples_path": rel_out.as_posix() if rel_out else None, "params": meta,
    }
    if reuse and rel_out is not None and (warehouse / rel_out).exists():
        cached = read_run_record(warehouse / rel_out)
        if cached is not None:
            return cached["run"], cached["channels"]
    (warehouse / folder).mkdir(parents=True, exist_ok=True)
    tmp = warehouse / folder / f".{safe_file_name(run_id)}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp"
    check = _TimeCheck()
    empty = {m.column: True for m in maps if m.numeric}
    try:
        with pq.ParquetWriter(tmp, schema, **parquet_options(schema)) as writer:
            for batch in prefetch(export.batches()):
                if batch.num_rows == 0:
                    continue
                table = convert_batch(batch, maps, schema, run_id, p_atm, check.n,
                                      time_base if synth_time else None, derived)
                check.update(table.column("t_s").to_numpy())
                for col in [c for c, e in empty.items() if e]:
                    if table.column(col).null_count < table.num_rows and not np.all(np.isnan(table.column(col).to_numpy())):
                        empty[col] = False
                writer.write_table(table)
            if check.n == 0:
                raise IngestError("no data rows")
            if check.repeats:
                warnings.append(f"time repeats at {check.repeats} rows")
            warnings += [f"channel `{c}` is empty" for c, e in empty.items() if e]
            if time_base is not None and not synth_time and check.sample_rate_hz:
                stated, seen = time_base.stated_rate_hz, check.sample_rate_hz
                if abs(seen - stated) > RATE_TOLERANCE * stated:
                    warnings.append(f"time column's rate {seen:.6g} Hz disagrees with `{time_base.source}` "
                                    f"{stated:.6g} Hz; the time column is used")
            run.update(n_samples=check.n, sample_rate_hz=check.sample_rate_hz,
                       duration_s=(check.last - check.first), warnings=list(export.warnings) + warnings)
            channels = [dict(run_id=run_id, **m.describe()) for m in maps]
            if synth_time:
                channels.append(dict(run_id=run_id, column="t_s", channel="t", raw_name=f"= {time_base.source}",
                                     raw_unit=None, unit="s", type="DOUBLE"))
            channels += [dict(run_id=run_id, **d.describe()) for d in derived]
            if rel_out is None:  # hashed while parsing: the name and the record need it now
                sha = hashing.result()
                rel_out = samples_path(sha)
                run.update(source_sha256=sha, samples_path=rel_out.as_posix())
            writer.add_key_value_metadata({"pneubench": json.dumps({"run": run, "channels": channels}, sort_keys=True)})
        os.replace(tmp, warehouse / rel_out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return run, channels


def parquet_options(schema: pa.Schema) -> dict:
    """Parquet writer options for a samples file.

    Floats are written BYTE_STREAM_SPLIT + zstd level 1 (about twice as fast as the default
    dictionary + snappy, and smaller); dictionary encoding only for ``run_id`` and text columns,
    where it pays. See ``benchmarks/bench_ingest.py``.
    """
    floats = [f.name for f in schema if pa.types.is_floating(f.type)]
    return {"use_dictionary": [f.name for f in schema if not pa.types.is_floating(f.type)],
            "use_byte_stream_split": floats or False, "compression": "zstd", "compression_level": 1}


def _open_export(path: Path, rig: dict, manifest: dict):
    """Open the export with hints in metadata precedence: manifest > file > rig.toml.

    A reader sees the manifest's keys first, so a key embedded in the file (e.g. a TDMS root
    property ``group``) beats a rig.toml default; only when that fails and rig.toml would add
    hints is the file opened again with them.
    """
    strong = normalise_keys(manifest)
    weak = {**normalise_keys(rig["metadata"]), **strong}
    try:
        return read_export(path, rig["read"], strong)
    except ReaderError:
        if weak == strong:
            raise
    return read_export(path, rig["read"], weak)


def read_run_record(path: Path) -> dict | None:
    """The runs row and channel list stored in a samples file's footer, or None."""
    try:
        meta = pq.read_metadata(path).metadata or {}
    except (OSError, pa.ArrowException):
        return None
    blob = meta.get(b"pneubench")
    return json.loads(blob) if blob else None
