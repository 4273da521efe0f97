"""ASAM MDF exports (``.mf4``, ``.mdf``; MDF 3 and 4), as HBK catman, Dewesoft, imc, Vector
or Kistler loggers write them. Read with asammdf.

* **Channel group.** The ``group`` key (run metadata or ``rig.toml`` ``[read] group``) names a
  channel group by its acquisition name or 0-based index; without it the file must hold exactly
  one group with data (the others are listed in the refusal). Groups logged at different rates
  are different groups: name the one that is the run, or set ``groups = "all"`` (``rig.toml``
  ``[read]``, or a manifest / ``[metadata]`` key) to make every group with data a run of its own
  (:func:`list_parts`).
* **Time.** The group's master channel is the time (column ``t``, unit from the file, ``s`` when
  it states none). A group without a master channel is refused; so is a master that is not a
  time (angle or distance synchronised acquisitions).
* **Values.** The file's conversions (linear, rational, tables, formulas) are applied, as
  asammdf does; a channel's unit is the conversion's unit, else the channel's. A channel whose
  conversion gives text (value-to-text tables) is a text column; arrays and structures are
  skipped with a run warning.
* **Metadata.** The header comment: ``key=value`` pairs separated by ``;`` or new lines in its
  text (``<TX>``), and MDF 4 ``<common_properties>`` entries; the header's start time gives
  ``started_at`` when the comment does not.
* **Bus logging.** A CAN (or LIN, FlexRay, Ethernet) bus log holds raw frames: decoding them
  needs the bus database (DBC / ARXML), which pneubench does not apply. Such a group is
  refused with a message that says to export the decoded signals first.
* **Unfinalised files.** An MDF 4 file a logger never finalised (``UnFinMF``) is read from a
  private temporary copy, which asammdf finalises; the raw file is never written.

Samples are read fragment by fragment of the group's data blocks (asammdf's own chunking, as
its ``iter_get`` does) and yielded in record batches, so a large file streams in bounded memory.
"""
from __future__ import annotations

import re
import shutil
import struct
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import RawColumn, RawExport, ReaderError, check_part_count, exc_text

FORMAT = "mdf"
EXTENSIONS = (".mf4", ".mdf")

#: Records per slice read from the file.
BATCH_ROWS = 1 << 18

_BUS_NAME = re.compile(r"^(CAN|LIN|FlexRay|ETH|Ethernet|MOST)_(DataFrame|RemoteFrame|ErrorFrame|Frame)", re.I)
#: MDF 4 channel group flag "bus event" (cg_flags bit 1).
_CG_BUS_EVENT = 1 << 1
#: MDF 4 channel sync types: 1 = time (master channels of other types are not time).
_SYNC_TIME = 1


#: Bytes of data blocks decoded at a time. [bytes]
READ_FRAGMENT_BYTES = 16 << 20


#: Most blocks one linked list of an MDF file may chain (data groups, channel groups, channels).
MAX_CHAINED_BLOCKS = 1_000_000


def check_block_links(fh) -> None:
    """Refuse an MDF file whose data group / channel group / channel lists loop back on
    themselves (a :class:`ReaderError` naming the block), before asammdf walks them: asammdf
    follows them without looking back (``count_channel_groups``), so a damaged link that points
    to an earlier block kept a worker busy forever (found by ``tests/fuzz``). The walk mirrors
    asammdf's: MDF 4 links are 8 bytes (first DG at 88; next at +24, first child at +32), MDF 3
    links 4 bytes (first DG at 68; next at +4, first child at +8)."""
    size = fh.seek(0, 2)
    fh.seek(64)
    head = fh.read(4)
    if head[:2] == b"HD":
        width, first, nxt, child = 4, 68, 4, 8
    elif head == b"##HD":
        width, first, nxt, child = 8, 88, 24, 32
    else:
        return  # not MDF: asammdf says so
    fmt = "<I" if width == 4 else "<Q"

    def link(at: int) -> int:
        fh.seek(at)
        raw = fh.read(width)
        return struct.unpack(fmt, raw)[0] if len(raw) == width else 0

    def chain(addr: int, what: str, inner=None) -> None:
        seen: set[int] = set()
        while addr:
            if addr >= size:
                return  # out of the file: asammdf refuses it itself
            if addr in seen:
                raise ReaderError(f"damaged MDF file: its {what} block links loop back (block at {addr:#x} again)")
            if len(seen) >= MAX_CHAINED_BLOCKS:
                raise ReaderError(f"damaged MDF file: more than {MAX_CHAINED_BLOCKS} {what} blocks in one list")
            seen.add(addr)
            if inner is not None:
                inner(link(addr + child))
            addr = link(addr + nxt)

    channels = lambda a: chain(a, "channel")  # noqa: E731
    groups = lambda a: chain(a, "channel group", channels)  # noqa: E731
    chain(link(first), "data group", groups)
    fh.seek(0)


def check_record_layout(mdf, index: int) -> None:
    """Refuse a channel group whose channels lie past the end of its records (a damaged byte
    offset): asammdf's C code copies such a channel's bytes without a bounds check and crashed
    the worker (found by ``tests/fuzz``). MDF 4 channels that hold bytes in the record (fixed
    length, variable length, master, sync, maximum length) must end within the record."""
    if not str(getattr(mdf, "version", "")).startswith("4"):
        return
    group = mdf.groups[index]
    record = int(group.channel_group.samples_byte_nr)
    for ch in group.channels:
        if int(getattr(ch, "channel_type", 0)) in (3, 6):  # virtual: no bytes in the record
            continue
        start = int(ch.byte_offset)
        end = start + (int(ch.bit_offset) + int(ch.bit_count) + 7) // 8
        if end > record:
            raise ReaderError(f"damaged MDF file: channel `{ch.name}` of channel group {index} lies past the end "
                              f"of its {record}-byte records (bytes {start} to {end})")


#: Bytes copied at a time when an unfinalised MDF 4 file is copied for asammdf to finalise.
COPY_CHUNK_BYTES = 1 << 20


def is_unfinalised(fh) -> bool:
    """Whether an MDF 4.10+ file is unfinalised (``id_unfin_flags`` set in its identification
    block, as CAN loggers and interrupted recordings leave them). asammdf finalises such a file
    on opening by writing the missing cycle counters and block lengths into the file it reads."""
    fh.seek(0)
    ident = fh.read(64)
    fh.seek(0)
    if len(ident) < 64:
        return False
    version = ident[8:16].decode("latin-1").strip(" \n\t\r\0")
    return version >= "4.10" and int.from_bytes(ident[60:62], "little") != 0


def _private_copy(fh):
    """A writable temporary copy of ``fh`` (deleted when closed): asammdf finalises it there,
    never in raw/."""
    copy = tempfile.TemporaryFile()
    try:
        fh.seek(0)
        shutil.copyfileobj(fh, copy, COPY_CHUNK_BYTES)
        copy.seek(0)
    except BaseException:
        copy.close()
        raise
    return copy


class _Opened:
    """An MDF opened from a file object: asammdf then reads with ordinary reads, not a memory
    map of the whole file (whose pages count as the process's resident memory: 1.1 GB for a
    1 GB file, against 0.17 GB this way). Closing closes both.

    An unfinalised MDF 4 file (:func:`is_unfinalised`) is read from a private temporary copy:
    asammdf finalises the file it reads in place, and a read-only raw file made it fail with
    ``UnsupportedOperation: write`` (a CAN logger's MF4, issue 25)."""

    def __init__(self, path: Path):
        from asammdf import MDF   # heavy (seconds to import): only when an MDF file is opened

        self.fh = open(path, "rb")
        try:
            check_block_links(self.fh)
            if is_unfinalised(self.fh):
                raw, self.fh = self.fh, None
                try:
                    self.fh = _private_copy(raw)
                finally:
                    raw.close()
        except BaseException:
            if self.fh is not None:
                self.fh.close()
            raise
        try:
            self.mdf = MDF(self.fh)
        except Exception as exc:  # asammdf raises many kinds on damaged files
            self.fh.close()
            raise ReaderError(f"not a readable MDF file (truncated or damaged?): {exc_text(exc, 200)}") from None
        self.mdf.configure(read_fragment_size=READ_FRAGMENT_BYTES)

    def close(self) -> None:
        """Close the MDF and its file."""
        try:
            self.mdf.close()
        finally:
            self.fh.close()


def _open(path: Path) -> _Opened:
    """The MDF file at ``path`` opened for reading (see :class:`_Opened`)."""
    return _Opened(path)


def _text(elem) -> str:
    """The text of an XML element and its children (``""`` for None)."""
    return "".join(elem.itertext()) if elem is not None else ""


def parse_header_comment(comment: str) -> dict:
    """Run metadata from an MDF header comment: ``key=value`` pairs in its text and MDF 4
    ``<common_properties>`` ``<e name="key">value</e>`` entries (plain text comments too)."""
    out: dict = {}
    text = comment or ""
    props = {}
    if text.lstrip().startswith("<"):
        try:
            root = ET.fromstring(text)
        except ET.ParseError:
            root = None
        if root is not None:
            tx = root.find("TX")
            text = _text(tx)
            for e in root.iter("e"):
                key = (e.get("name") or "").strip()
                if key:
                    props[key] = (e.text or "").strip()
    for part in re.split(r"[;\n]", text):
        if "=" in part:
            k, v = part.split("=", 1)
            if k.strip():
                out[k.strip()] = v.strip()
    out.update(props)
    return out


def _groups(mdf) -> list[tuple[int, str, int]]:
    """(index, acquisition name, records) of the groups that hold data channels."""
    out = []
    for i, g in enumerate(mdf.groups):
        cg = g.channel_group
        n_data = len(g.channels) - (1 if mdf.masters_db.get(i) is not None else 0)
        if getattr(cg, "cycles_nr", 0) and n_data > 0:
            out.append((i, str(getattr(cg, "acq_name", "") or ""), int(cg.cycles_nr)))
    return out


def _is_bus_log(mdf, index: int) -> bool:
    """Whether channel group ``index`` is a bus log: flagged a bus event, or holding frame channels."""
    g = mdf.groups[index]
    if int(getattr(g.channel_group, "flags", 0) or 0) & _CG_BUS_EVENT:
        return True
    return any(_BUS_NAME.match(ch.name or "") for ch in g.channels)


#: Bus type of a bus log -> the database its frames need to become signals.
_BUS_DATABASE = {"CAN": "a DBC database", "LIN": "an LDF database", "FLEXRAY": "a FIBEX or ARXML database",
                 "ETH": "an ARXML database", "ETHERNET": "an ARXML database", "MOST": "a MOST function catalog"}
#: MDF 4 source bus types (si_bus_type) by name.
_SI_BUS = {2: "CAN", 3: "LIN", 4: "MOST", 5: "FlexRay", 7: "Ethernet"}


def _bus_log_refusal(mdf, index: int) -> str:
    """The one-line refusal of bus-log group ``index``: which bus, and what its frames need."""
    g = mdf.groups[index]
    bus = None
    for ch in g.channels:
        m = _BUS_NAME.match(ch.name or "")
        if m:
            bus = m.group(1)
            break
    if bus is None:
        source = getattr(g.channel_group, "acq_source", None)
        bus = _SI_BUS.get(int(getattr(source, "bus_type", 0) or 0)) if source is not None else None
    bus = {"CAN": "CAN", "LIN": "LIN", "FLEXRAY": "FlexRay", "ETH": "Ethernet", "ETHERNET": "Ethernet",
           "MOST": "MOST"}.get((bus or "").upper(), bus)
    database = _BUS_DATABASE.get((bus or "").upper(), "its bus database (DBC, LDF, ARXML)")
    what = f"{bus} frames" if bus else "bus frames"
    return (f"channel group {index} is an MDF bus log ({what}): its signals need {database}, which pneubench "
            "does not decode; export the decoded signals instead (e.g. asammdf's extract_bus_logging with the "
            "database, saved as MF4)")


#: ``[read]`` / metadata key that makes every channel group a run, and the key naming one group.
PARTS_KEY, PART_KEY = "groups", "group"


def list_parts(path: str | Path) -> list[str]:
    """The channel groups with data, as the ``group`` key names them, when ``groups = "all"``:
    the acquisition name when the group has one that no other group with data shares (and
    that is not a number, which would read as an index), else the 0-based group index.

    Raises
    ------
    ReaderError
        The file cannot be opened, or holds no group with samples.
    """
    opened = _open(Path(path))
    mdf = opened.mdf
    try:
        groups = _groups(mdf)
    except Exception as exc:
        raise ReaderError(f"MDF file cannot be read: {exc_text(exc)}") from None
    finally:
        opened.close()
    if not groups:
        raise ReaderError("MDF file holds no channel group with samples")
    check_part_count(len(groups), "channel groups with data")
    names = [name for _, name, _ in groups]
    return [name if name and name == name.strip() and names.count(name) == 1 and not name.isdigit() else str(i)
            for i, name, _ in groups]


def _pick_group(mdf, selector) -> tuple[int, str, int]:
    """``(index, acquisition name, records)`` of the group ``selector`` names (a name or a 0-based
    index), else of the only group with data."""
    groups = _groups(mdf)
    listing = ", ".join(f"{i} {name!r}" if name else str(i) for i, name, _ in groups)
    if selector is None or str(selector).strip() == "":
        if len(groups) == 1:
            return groups[0]
        if not groups:
            raise ReaderError("MDF file holds no channel group with samples")
        raise ReaderError(f"MDF file has {len(groups)} channel groups with data ({listing}): "
                          "name the run's with the `group` key (acquisition name or 0-based index)")
    text = str(selector).strip()
    for g in groups:
        if g[1] == text:
            return g
    if text.isdigit():
        i = int(text)
        for g in groups:
            if g[0] == i:
                return g
    raise ReaderError(f"no channel group {text!r} with data in the MDF file (groups: {listing or 'none'})")


def read_mdf(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open an ASAM MDF 3 / 4 export.

    Parameters
    ----------
    path : path-like
        The file.
    read : dict, optional
        ``rig.toml`` ``[read]``: ``group``.
    hints : dict, optional
        Run metadata known before opening (manifest over rig.toml): ``group``.

    Returns
    -------
    RawExport
    """
    path = Path(path)
    read = dict(read or {})
    hints = dict(hints or {})
    opened = _open(path)
    mdf = opened.mdf
    try:
        index, acq_name, _records = _select_group(mdf, hints.get("group", read.get("group")))
        master, mch = _time_master(mdf, index)
        metadata = _metadata(mdf, read, hints, index, acq_name)
        warnings: list[str] = []
        plan = _plan_channels(mdf, index, master, mch, warnings)
    except ReaderError:
        raise
    except Exception as exc:
        raise ReaderError(f"MDF file cannot be read: {exc_text(exc)}") from None
    finally:
        opened.close()  # batches() opens the file again: nothing stays open between the two
    return RawExport(format=FORMAT, columns=plan.columns, metadata=metadata, batches=lambda: _batches(path, plan),
                     warnings=warnings)


def _select_group(mdf, selector) -> tuple[int, str, int]:
    """``(index, acquisition name, records)`` of the run's channel group; a bus log is refused
    (a file of bus-log groups only, without a ``group`` key, is one bus log)."""
    if selector is None or str(selector).strip() == "":
        # a logger's file of data, error and remote frames: a bus log, not a choice of groups
        logs = [i for i, _, _ in _groups(mdf) if _is_bus_log(mdf, i)]
        if len(logs) > 1 and len(logs) == len(_groups(mdf)):
            raise ReaderError(_bus_log_refusal(mdf, logs[0]))
    index, acq_name, n_records = _pick_group(mdf, selector)
    if _is_bus_log(mdf, index):
        raise ReaderError(_bus_log_refusal(mdf, index))
    return index, acq_name, n_records


def _time_master(mdf, index: int) -> tuple[int, object]:
    """``(channel index, channel)`` of group ``index``'s master, refused when there is none,
    when the group's records are damaged or when the master is not a time."""
    master = mdf.masters_db.get(index)
    if master is None:
        raise ReaderError(f"channel group {index} has no master (time) channel")
    check_record_layout(mdf, index)
    mch = mdf.groups[index].channels[master]
    sync = getattr(mch, "sync_type", _SYNC_TIME)
    if mdf.version >= "4.00" and sync not in (0, _SYNC_TIME):
        raise ReaderError(f"channel group {index}: the master channel `{mch.name}` is not a time "
                          f"(sync type {sync}: angle or distance); pneubench needs time")
    return master, mch


def _metadata(mdf, read: dict, hints: dict, index: int, acq_name: str) -> dict:
    """Run metadata: the header comment, ``started_at`` from the header's start time, and the
    ``group`` read (``run_id`` made ``<run_id>/<group>`` with ``groups = "all"``)."""
    metadata = parse_header_comment(getattr(mdf.header, "comment", "") or "")
    start = getattr(mdf.header, "start_time", None)
    if "started_at" not in metadata and start is not None:
        metadata["started_at"] = start.isoformat()
    if str(read.get(PARTS_KEY, "")).strip().casefold() == "all":
        # one run per group: the header's run_id is the file's, each group's is `<run_id>/<group>`
        for k in [k for k in metadata if k.strip().casefold() == "run_id"]:
            metadata[k] = f"{metadata[k]}/{hints.get(PART_KEY, acq_name or index)}"
    metadata.setdefault("group", acq_name or str(index))
    return metadata


@dataclass(frozen=True)
class _Plan:
    """What to read of group ``index``: the export's columns (``c_master`` first) and the data
    channels as ``(key, channel name, channel index)``."""

    index: int
    columns: list[RawColumn]
    fetch: list[tuple[str, str, int]]


def _plan_channels(mdf, index: int, master: int, mch, warnings: list[str]) -> _Plan:
    """The group's time and its data channels, each probed by reading its first record:
    arrays, structures and samples that are not numbers or text are skipped with a warning."""
    columns = [RawColumn(key="c_master", name="t", unit=(mch.unit or "s").strip() or "s", index=1)]
    fetch: list[tuple[str, str, int]] = []  # (key, channel name, channel index)
    for ci, ch in enumerate(mdf.groups[index].channels):
        if ci == master:
            continue
        try:
            probe = mdf.get(ch.name, index, ci, record_offset=0, record_count=1)
        except Exception as exc:
            warnings.append(f"MDF channel `{ch.name}` skipped: cannot be read ({type(exc).__name__})")
            continue
        samples = probe.samples
        if samples.ndim != 1 or samples.dtype.names:
            warnings.append(f"MDF channel `{ch.name}` skipped: arrays and structures are not channels")
            continue
        kind = samples.dtype.kind
        dtype = "string" if kind in "SUO" else "float"
        if kind not in "SUObiuf":
            warnings.append(f"MDF channel `{ch.name}` skipped: samples of type {samples.dtype} are not numbers")
            continue
        unit = (probe.unit or ch.unit or "").strip() or None
        key = f"c{ci}"
        columns.append(RawColumn(key=key, name=ch.name, unit=unit, index=ci + 1, dtype=dtype))
        fetch.append((key, ch.name, ci))
    return _Plan(index, columns, fetch)


def _batches(path: Path, plan: _Plan) -> Iterator[pa.RecordBatch]:
    """The group's samples as record batches of at most :data:`BATCH_ROWS` rows, read fragment
    by fragment of its data blocks from the file opened again."""
    opened = _open(path)
    mdf = opened.mdf
    offset = 0
    try:
        # asammdf's own chunking (as its public iter_get does): the group's data blocks in
        # fragments of bounded size, every channel decoded from the same fragment. Reading by
        # record_offset instead re-scans the blocks for every slice (and fails on some files).
        fragments = mdf._mdf._load_data(mdf.groups[plan.index])
        while True:
            try:
                fragment = next(fragments, None)
                if fragment is None:
                    break
                arrays = _decode_fragment(mdf, plan, fragment)
            except Exception as exc:
                raise ReaderError(f"MDF samples cannot be read at record {offset}: {exc_text(exc)}") from None
            n = len(arrays["c_master"])
            for a in range(0, n, BATCH_ROWS):
                yield _batch(plan.columns, arrays, a)
            offset += n
    finally:
        opened.close()


def _decode_fragment(mdf, plan: _Plan, fragment) -> dict[str, np.ndarray]:
    """Every column's samples in one fragment of the group's data: column key -> samples."""
    t = mdf.get_master(plan.index, data=fragment)
    arrays = {"c_master": np.asarray(t, dtype=float)}
    for key, _name, ci in plan.fetch:
        arrays[key] = mdf.get(group=plan.index, index=ci, data=fragment, samples_only=True,
                              ignore_invalidation_bits=True)[0]
    return arrays


def _batch(columns: list[RawColumn], arrays: dict[str, np.ndarray], a: int) -> pa.RecordBatch:
    """Rows ``a`` to ``a + BATCH_ROWS`` of a fragment's samples as a record batch (text columns
    decoded as UTF-8)."""
    out = []
    for c in columns:
        part = arrays[c.key][a:a + BATCH_ROWS]
        if c.dtype == "string":
            out.append(pa.array([v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
                                 for v in part], type=pa.string()))
        else:
            out.append(pa.array(np.asarray(part, dtype=float)))
    return pa.RecordBatch.from_arrays(out, names=[c.key for c in columns])
