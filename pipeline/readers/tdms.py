"""TDMS exports (LabVIEW / DAQmx) via npTDMS, streamed.

* Root (file) properties are the run metadata (timestamps become ISO 8601 text in UTC, the
  TDMS time base).
* Channels come from the group named by the ``group`` key, or from the only group. The key
  is looked up in ``hints`` (manifest row over ``rig.toml`` defaults) first, then in the root
  properties. Several groups and no key, or a key naming a missing group: :class:`ReaderError`.
* A channel's unit is its ``unit_string`` property (a ``name[unit]`` channel name is the
  fallback when the property is missing or empty).
* Time: a channel named ``t`` if there is one; otherwise a column ``t`` [s] is synthesised from
  the waveform properties ``wf_start_offset + i * wf_increment`` of the first channel that has
  them. The waveform ``wf_start_time`` becomes the embedded ``started_at`` unless the root
  properties give one (LabVIEW's "no time" value, the 1904 epoch, is ignored).
* DAQmx raw data is scaled by npTDMS with the scaling properties stored in the file.
* A truncated final segment (the bench crashed while logging) is read up to the last sample
  that is complete in every channel; the export carries a warning (it reaches
  ``runs.warnings``). Channels of unequal length in an intact file are an error.
* Non-numeric channels: strings are kept as string columns; timestamp channels are kept as
  string columns of ISO 8601 UTC text, except a timestamp channel named ``t``, which becomes
  seconds since its first value. Channels of other types (complex numbers, ...) are skipped
  with a warning. A channel with no data at all is kept as an empty (all-null) column.

Data is streamed: :meth:`nptdms.TdmsFile.open` reads the segment metadata only, and batches of
:data:`BATCH_ROWS` rows are read per channel with ``channel.read_data(offset, length)``, so
memory stays bounded by the batch size plus one raw-data chunk of the file (LabVIEW and DAQmx
write a chunk per loop iteration or buffer: small). npTDMS reads whole chunks, so a file written
as one huge chunk is read in batches as large as that chunk (memory of the order of the chunk,
but each chunk read once).

Untrusted bytes: a file must start with a TDMS lead-in (``TDSm``, version 4712 or 4713); npTDMS
reads through :class:`_BoundedReader` (no read past the end of the file, whatever length a
corrupt field gives), a ``.tdms_index`` beside the file is not used, and a channel may not
declare more values than the file has bytes. A sparse file (holes that read back as zeros but
are not stored) may not declare more values than :func:`pipeline.readers.base.inflate_cap` of
the bytes it stores: a 4 KB file whose size says 1 GB is refused, not read as 125 M zeros.
"""
from __future__ import annotations

import errno
import io
import logging
import math
import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import (RawColumn, RawExport, ReaderError, check_channel_count, inflate_cap, mib,
                                   split_name_unit)

FORMAT = "tdms"
EXTENSIONS = (".tdms",)

#: Rows per record batch.
BATCH_ROWS = 1 << 19

#: LabVIEW's timestamp zero (1904-01-01T00:00:00 UTC): a waveform without a start time.
_TDMS_EPOCH = np.datetime64("1904-01-01T00:00:00", "us")


@dataclass
class _Source:
    """How one output column is read: ``read(offset, length) -> pa.Array``."""

    key: str
    read: Callable[[int, int], pa.Array]


def read_tdms(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open a TDMS export.

    Parameters
    ----------
    path : path-like
        The export.
    read : dict, optional
        The ``[read]`` table of ``rig.toml``; unused (TDMS is self-describing).
    hints : dict, optional
        Metadata known before the file is opened (manifest row over ``rig.toml`` defaults);
        ``group`` names the group to read.

    Returns
    -------
    RawExport
        Columns in the group's channel order (``index`` is the 1-based position in the group),
        then a synthesised ``t`` when time comes from waveform properties.
    """
    path = Path(path)
    opened = _open(path)
    with opened as tdms:
        plan = _plan(tdms, hints or {}, path.stat().st_size, opened.fh.stored)
        columns, n_rows = plan.columns, plan.n_rows
        # npTDMS reads whole raw-data chunks: never re-read a big chunk once per batch.
        rows_per_batch = max(1, min(n_rows, max(BATCH_ROWS, _largest_chunk(tdms))))

    def batches() -> Iterator[pa.RecordBatch]:
        with _open(path) as tdms:
            group = tdms[plan.group_name]
            sources = [_source(group, c) for c in columns]
            try:
                for start in range(0, n_rows, rows_per_batch):
                    length = min(rows_per_batch, n_rows - start)
                    arrays = [s.read(start, length) for s in sources]
                    yield pa.RecordBatch.from_arrays(arrays, names=[s.key for s in sources])
            except ReaderError:
                raise
            except Exception as exc:  # noqa: BLE001 - npTDMS raises many kinds on malformed data
                raise ReaderError(f"cannot read TDMS data: {_first_line(exc)}") from None

    return RawExport(format=FORMAT, columns=[c.raw for c in columns], metadata=plan.metadata,
                     batches=batches, warnings=plan.warnings)


# -- opening and planning ------------------------------------------------------------------
class _BoundedReader(io.BufferedReader):
    """A buffered file whose ``read(n)`` never asks for more than the bytes left in the file.

    npTDMS reads a string property with ``file.read(length)`` where ``length`` is the (maybe
    corrupt) 32-bit length written before it, and a buffered read allocates ``length`` bytes
    before it finds the file too short: a few flipped bits would ask for 4 GB.
    """

    def __init__(self, path: Path):
        super().__init__(io.FileIO(path, "rb"))
        self._size = os.fstat(self.fileno()).st_size
        self.stored = _stored_bytes(self.fileno(), self._size)

    def read(self, size: int | None = -1) -> bytes:
        """Read at most the bytes left in the file (see the class docstring)."""
        if size is not None and size > 1 << 16:          # small reads cannot allocate much: no tell()
            size = max(0, min(size, self._size - self.tell()))
            if size == 0:
                return b""
        return super().read(size)


def _stored_bytes(fd: int, size: int) -> int:
    """Bytes of a file that are stored, not holes: the sum of its data extents (``SEEK_DATA`` /
    ``SEEK_HOLE``); ``st_blocks * 512`` where the file system cannot tell, else ``size``. [B]

    A sparse file reads back zeros from its holes without storing them: its size says nothing
    of what it holds. The descriptor's position is left at 0.
    """
    try:
        stored = pos = 0
        while pos < size:
            try:
                start = os.lseek(fd, pos, os.SEEK_DATA)
            except OSError as exc:
                if exc.errno == errno.ENXIO:        # no data past pos: a hole to the end
                    break
                raise
            pos = os.lseek(fd, start, os.SEEK_HOLE)
            stored += pos - start
        return min(stored, size)
    except (OSError, AttributeError):               # no SEEK_DATA here (EINVAL) or on this platform
        blocks = getattr(os.fstat(fd), "st_blocks", None)
        return size if blocks is None else min(size, blocks * 512)
    finally:
        os.lseek(fd, 0, os.SEEK_SET)


class _open:
    """``TdmsFile.open`` with npTDMS' own log warnings silenced and errors as ReaderError.

    npTDMS is handed a :class:`_BoundedReader` (so a ``.tdms_index`` beside the file is not
    used: the metadata are read from the data file itself, which is what the rebuild hashed).
    """

    def __init__(self, path: Path):
        self.path = path
        self.tdms = None
        self.fh = None

    def __enter__(self):
        from nptdms import TdmsFile   # heavy: imported only when a TDMS file is opened

        _check_lead_in(self.path)
        log = logging.getLogger("nptdms")
        level = log.level
        log.setLevel(logging.ERROR)  # truncation is reported by us, as a run warning
        self.fh = _BoundedReader(self.path)
        try:
            self.tdms = TdmsFile.open(self.fh)
        except Exception as exc:  # noqa: BLE001 - npTDMS raises many kinds on malformed input
            self.fh.close()
            if isinstance(exc, struct.error):   # a length or count points past the end of the file
                raise ReaderError("not a readable TDMS file: its metadata is corrupt or cut short (a field runs "
                                  "past the end of the file)") from None
            raise ReaderError(f"not a readable TDMS file: {_first_line(exc)}") from None
        finally:
            log.setLevel(level)
        return self.tdms

    def __exit__(self, *exc):
        if self.tdms is not None:
            self.tdms.close()
        if self.fh is not None:
            self.fh.close()
        return False


#: Bytes of a TDMS segment lead-in: tag, ToC mask, version, next segment offset, raw data offset.
_LEAD_IN = 28
_VERSIONS = (4712, 4713)


def _check_lead_in(path: Path) -> None:
    """Refuse, in one line, a file that does not start with a TDMS lead-in."""
    with open(path, "rb") as fh:
        lead = fh.read(_LEAD_IN)
    if not lead:
        raise ReaderError("not a TDMS file (empty file)")
    if lead[:4] != b"TDSm":
        raise ReaderError(f"not a TDMS file (no TDSm lead-in; starts with {lead[:8]!r})")
    if len(lead) < _LEAD_IN:
        raise ReaderError(f"TDMS file cut inside its first lead-in ({len(lead)} of {_LEAD_IN} bytes): no data")
    order = "<" if not int.from_bytes(lead[4:8], "little") & (1 << 6) else ">"   # kTocBigEndian
    version = int.from_bytes(lead[8:12], "little" if order == "<" else "big")
    if version not in _VERSIONS:
        raise ReaderError(f"not a TDMS file (lead-in version {version}, expected 4712 or 4713)")


@dataclass
class _Col:
    """One output column: its RawColumn, how it is read (``kind``), its TDMS channel and start (``t0``)."""

    raw: RawColumn
    kind: str             # "number", "string", "timestamp", "elapsed" (timestamp t), "wf_time", "empty"
    channel: str | None   # TDMS channel name (None for the synthesised time)
    t0: object = None     # elapsed: first timestamp; wf_time: (offset, increment)


@dataclass(frozen=True)
class _Plan:
    """What a TDMS export is: its columns, metadata and warnings, the rows every column has and
    the group they come from."""

    columns: list[_Col]
    metadata: dict
    warnings: list[str]
    n_rows: int
    group_name: str


@dataclass
class _Channels:
    """What the channels of the group say, gathered in one pass: the columns, each channel's
    length, the channel named ``t``, the first waveform properties and a timestamp ``t``'s
    first value (as ISO text)."""

    cols: list[_Col] = field(default_factory=list)
    lengths: dict[str, int] = field(default_factory=dict)
    time_channel: str | None = None
    wf: object = None
    first_time: object = None


def _plan(tdms, hints: dict, file_size: int, stored: int | None = None) -> _Plan:
    """Plan the export of an opened TDMS file: the group, its channels, the rows and the time."""
    root = dict(tdms.properties)
    metadata = {str(k): _plain(v) for k, v in root.items()}
    group = _select_group(tdms, hints, metadata)
    warnings: list[str] = []
    found = _channel_columns(group, file_size, warnings)
    if not found.cols:
        raise ReaderError(f"TDMS group `{group.name}` has no channels")
    if not found.lengths:
        raise ReaderError(f"TDMS group `{group.name}` has no data")
    _check_sparse(group, found.lengths, file_size, stored)
    n_rows = _row_count(tdms, group, found.lengths, warnings)
    _add_time(found, metadata)
    return _Plan(found.cols, metadata, warnings, n_rows, group.name)


def _channel_columns(group, file_size: int, warnings: list[str]) -> _Channels:
    """One column per channel of ``group`` (unit, kind, length); channels of other types are
    skipped with a warning."""
    found = _Channels()
    check_channel_count(len(group.channels()), f"channels in TDMS group `{group.name}`")
    for index, ch in enumerate(group.channels(), start=1):
        name = ch.name
        unit = _text(ch.properties.get("unit_string"))
        if unit is None:
            name, unit = split_name_unit(ch.name) if ch.name.rstrip().endswith("]") else (ch.name, None)
        n = len(ch)
        if n > file_size:   # every value takes at least one byte of the file
            raise ReaderError(f"TDMS channel `{ch.name}` declares {n} values in a file of {file_size} bytes "
                              "(corrupt metadata)")
        is_t = name.strip().casefold() == "t"
        kind = _channel_kind(ch, n, is_t)
        if kind is None:
            warnings.append(f"TDMS channel `{ch.name}` of type {_dtype(ch)} skipped (not numbers, text or timestamps)")
            continue
        t0 = None
        if kind == "elapsed":
            t0 = ch.read_data(0, 1)[0]
            unit = "s"
            found.first_time = _plain(t0)
        raw = RawColumn(key=f"c{index}", name=name, unit=unit, index=index,
                        dtype="string" if kind in ("string", "timestamp") else "float", header=ch.name)
        found.cols.append(_Col(raw, kind, ch.name, t0))
        if n:
            found.lengths[ch.name] = n
        if is_t:
            found.time_channel = ch.name
        if found.wf is None and "wf_increment" in ch.properties and n:
            found.wf = ch.properties
    return found


def _dtype(ch) -> np.dtype:
    """A channel's numpy dtype (object when npTDMS gives none)."""
    return np.dtype(ch.dtype) if ch.dtype is not None else np.dtype(object)


def _channel_kind(ch, n: int, is_t: bool) -> str | None:
    """How a channel of ``n`` values is read (see :class:`_Col`); None for a type not read."""
    dtype = _dtype(ch)
    if n == 0:
        return "empty"
    if np.issubdtype(dtype, np.datetime64):
        return "elapsed" if is_t else "timestamp"
    if dtype == np.dtype(object) or dtype.kind in "US":
        return "string"
    if dtype.kind in "biuf":
        return "number"
    return None


def _check_sparse(group, lengths: dict[str, int], file_size: int, stored: int | None) -> None:
    """A sparse file: what its channels declare must come from the bytes it stores, as for
    compressed data (inflate_cap), not from holes that read back as zeros."""
    stored = file_size if stored is None else stored
    declared = sum(n * max(4, np.dtype(group[k].dtype or object).itemsize) for k, n in lengths.items())
    if stored < file_size and declared > max(stored, inflate_cap(stored)):
        raise ReaderError(f"TDMS channels of group `{group.name}` declare {mib(declared)} of values but the file "
                          f"stores {stored:,} bytes of its {mib(file_size)} (a sparse file whose holes read as zeros): "
                          f"more than the {mib(inflate_cap(stored))} it may declare")


def _row_count(tdms, group, lengths: dict[str, int], warnings: list[str]) -> int:
    """Rows: every channel as long as the others; a crash may cut the last segment short (then
    the complete rows, with a warning)."""
    n_rows = min(lengths.values())
    truncated = _truncated(tdms)
    if len(set(lengths.values())) > 1 and not truncated:
        shown = ", ".join(f"`{k}` {v}" for k, v in lengths.items())
        raise ReaderError(f"TDMS channels of group `{group.name}` have different lengths ({shown})")
    if truncated:
        dropped = sum(lengths.values()) - n_rows * len(lengths)
        warnings.append(f"TDMS file truncated (final segment incomplete): ingested the first {n_rows} "
                        f"complete samples, dropped {dropped} trailing values")
    return n_rows


def _add_time(found: _Channels, metadata: dict) -> None:
    """Time: a channel ``t`` wins; else a ``t`` column from waveform timing. ``started_at`` from
    the waveform start time or the first timestamp of ``t``, unless the metadata give it."""
    wf = found.wf
    if found.time_channel is None and wf is not None:
        inc = _number(wf.get("wf_increment"))
        off = _number(wf.get("wf_start_offset", 0.0))
        if inc is None or not inc > 0:
            raise ReaderError(f"TDMS waveform property wf_increment is not a positive number: {wf.get('wf_increment')!r}")
        found.cols.append(_Col(RawColumn(key="t", name="t", unit="s", index=len(found.cols) + 1), "wf_time", None,
                               (off or 0.0, inc)))
    if wf is not None and not any(k.strip().casefold() == "started_at" for k in metadata):
        start = wf.get("wf_start_time")
        if isinstance(start, np.datetime64) and start.astype("datetime64[us]") != _TDMS_EPOCH:
            metadata["started_at"] = _plain(start)
    if found.first_time is not None and not any(k.strip().casefold() == "started_at" for k in metadata):
        metadata["started_at"] = found.first_time


def _select_group(tdms, hints: dict, root: dict):
    """The group the ``group`` key names (``hints`` first, then the root properties), else the only group."""
    groups = tdms.groups()
    names = [g.name for g in groups]
    wanted = _lookup(hints, "group")
    if wanted is None:
        wanted = _lookup(root, "group")
    shown = ", ".join(f"`{n}`" for n in names)
    if wanted is not None:
        wanted = str(wanted)
        for g in groups:
            if g.name == wanted:
                return g
        folded = [g for g in groups if g.name.strip().casefold() == wanted.strip().casefold()]
        if len(folded) == 1:
            return folded[0]
        raise ReaderError(f"TDMS group `{wanted}` (the `group` key) not found; the file has {shown or 'no groups'}")
    if not groups:
        raise ReaderError("TDMS file has no groups (no channels)")
    if len(groups) > 1:
        raise ReaderError(f"TDMS file has several groups ({shown}); set the `group` key "
                          "(manifest.csv, rig.toml or a root property) to the one to read")
    return groups[0]


def _truncated(tdms) -> bool:
    """Whether the file ends with an incomplete segment (or bytes npTDMS could not use)."""
    try:
        if tdms.file_status.incomplete_final_segment:
            return True
    except Exception:  # noqa: BLE001 - file_status is informational
        pass
    reader = getattr(tdms, "_reader", None)
    segments = getattr(reader, "_segments", None)
    size = getattr(reader, "_data_file_size", None)
    if segments and size:
        return segments[-1].next_segment_pos < size  # a final segment whose lead-in was cut
    return False


def _largest_chunk(tdms) -> int:
    """Most values of one channel in one raw-data chunk (0 when npTDMS does not tell)."""
    try:
        return max((int(obj.number_values) for seg in tdms._reader._segments
                    for obj in seg.ordered_objects if obj.has_data), default=0)
    except (AttributeError, TypeError, ValueError):  # npTDMS internals changed: keep BATCH_ROWS
        return 0


# -- reading -------------------------------------------------------------------------------
def _source(group, col: _Col) -> _Source:
    """How column ``col`` is read from ``group`` (see :class:`_Col` for the kinds)."""
    key = col.raw.key
    if col.kind == "wf_time":
        off, inc = col.t0
        return _Source(key, lambda s, n: pa.array(off + np.arange(s, s + n, dtype=np.float64) * inc))
    if col.kind == "empty":
        typ = pa.string() if col.raw.dtype == "string" else pa.float64()
        return _Source(key, lambda s, n: pa.nulls(n, type=typ))
    ch = group[col.channel]
    if col.kind == "number":
        def read_number(s, n):
            v = ch.read_data(s, n)
            return pa.array(v if v.dtype.kind == "f" else v.astype(np.float64))
        return _Source(key, read_number)
    if col.kind == "elapsed":
        t0 = col.t0
        return _Source(key, lambda s, n: pa.array((ch.read_data(s, n) - t0) / np.timedelta64(1, "s")))
    if col.kind == "timestamp":
        return _Source(key, lambda s, n: pa.array(
            [None if np.isnat(x) else _iso(x) for x in ch.read_data(s, n)], type=pa.string()))
    return _Source(key, lambda s, n: pa.array([None if x is None else str(x) for x in ch.read_data(s, n)],
                                              type=pa.string()))


# -- values --------------------------------------------------------------------------------
def _iso(value: np.datetime64) -> str:
    """A timestamp as ISO 8601 UTC text with microseconds."""
    return np.datetime_as_string(value.astype("datetime64[us]"), unit="us") + "+00:00"


def _plain(value):
    """A property value as plain Python (timestamps -> ISO 8601 UTC text)."""
    if isinstance(value, np.datetime64):
        return None if np.isnat(value) else _iso(value)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        return value.decode("latin-1")
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _text(value) -> str | None:
    """A property as stripped text; None when missing or blank."""
    if value is None:
        return None
    text = str(value).strip()
    return text or None


def _number(value) -> float | None:
    """A property as a float; None when it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _lookup(meta: dict, key: str):
    """The value of ``key`` in ``meta`` (keys compared stripped and case-folded), None when missing or blank."""
    for k, v in meta.items():
        if str(k).strip().casefold() == key and v is not None and str(v).strip() != "":
            return v
    return None


def _first_line(exc: BaseException) -> str:
    """The first line of a npTDMS exception (named when it has no words), at most 200 characters."""
    text = str(exc).strip().splitlines()
    line = text[0] if text else ""
    if not any(c.isalpha() for c in line):  # KeyError(119) says "119": name the error instead
        line = f"{type(exc).__name__}({line}) in npTDMS: an unknown data type or corrupt metadata"
    return line[:200]
