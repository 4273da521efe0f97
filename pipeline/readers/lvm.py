"""LVM exports: LabVIEW Measurement files as *Write To Measurement File* writes them.

Layout (NI, "Specification for the LabVIEW Measurement File (.lvm)")::

    LabVIEW Measurement           file header: Separator, Decimal_Separator, X_Columns,
    ...                           Time_Pref, Date, Time, Description, ...
    ***End_of_Header***
    Channels  Samples  Y_Unit_Label  X_Unit_Label  X0  Delta_X ...   segment header
    ***End_of_Header***
    X_Value  name1  name2 ...  Comment                                 column row
    data rows
    (blank line, next segment header, column row, data rows, ...)

Every field of a segment header line sits in the same position as the column it describes in
the column row, so a channel's unit, ``X0``, ``Delta_X`` and ``Samples`` are read at the
channel's own position (this also holds for ``X_Columns = Multi``, where the header has empty
fields under the ``X_Value`` columns).

What the reader makes of it:

* **Separator** ``Tab`` / ``Comma`` and **Decimal_Separator** (``.`` or ``,``) are honoured.
* **Time** is a column ``t`` with the unit of ``X_Unit_Label`` (``s`` when none is given).
  ``X_Columns = No``: synthesised per segment as ``X0 + i * Delta_X`` (``i`` counts the data
  rows of the segment, also beyond the header's ``Samples``: LabVIEW appends later writes
  without a new header when ``Multi_Headings`` is ``No``). LabVIEW puts an empty X field at
  the start of each data row; rows without it are read too. ``X_Columns = One``: the X column.
  ``X_Columns = Multi``: the first X column; every other X column must agree with it (to
  1e-9 relative), else the file is refused naming the line. A channel literally named ``t``
  wins over the X values (as for TDMS), which are then not used.
* **Several segments** are concatenated in time. What LabVIEW writes as a later segment's
  ``X0`` depends on the waveform it was given: continuous DAQ acquisitions carry on (``X0`` of
  segment 2 = end of segment 1, or later after a pause), while waveforms without a start time
  (and ``Time_Pref = Relative`` exports of them) restart at ``X0 = 0`` in every segment.
  Choice: a segment whose first time is after the previous segment's last sample keeps its
  time as written (a real pause stays visible); a segment that would start at or before it
  (a restart) is shifted to start one ``Delta_X`` after the previous segment's last sample.
  With ``Time_Pref = Absolute`` the X values are seconds since 1904; time is then made
  relative to the first sample of the file. Later segments must have the same channels.
* **Comment column**: kept as a string column ``comment`` when any comment is present; it is
  dropped when empty. Emptiness is only known for files read whole while opening (up to
  :data:`HEAD_BYTES`); in larger files the column is kept (possibly all null) so that no comment
  written further down is ever lost.
* **Empty channels** (all cells blank) are all-null columns: ingest flags them.
* **Metadata**: the file header's ``Description`` as ``key=value`` pairs separated by ``;``
  (or new lines; a quoted multi-line description is read whole; text that is not a pair is kept
  as ``description``). ``started_at`` comes from the header's ``Date`` + ``Time`` when the
  description does not give it (LabVIEW writes local time without offset: read as UTC).
* **Encoding**: UTF-8 when it decodes, else Latin-1 (Windows LabVIEW writes the ANSI code
  page), so Latin-1 bytes in labels and units are read.
* Special blocks (``***Start_Special***`` ... ``***End_Special***``) are skipped.
* A ``.lvm`` without a ``LabVIEW Measurement`` header (LabVIEW's "no headers" option) is plain
  delimited text: it is read by the CSV reader and described by ``rig.toml``.

Streaming: the file is read in blocks of :data:`CHUNK_BYTES`; each block's data lines are parsed
with pandas' C parser and yielded as one record batch, so memory stays bounded.
"""
from __future__ import annotations

import io
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import MAX_CHANNELS, MAX_LINE_BYTES, RawColumn, RawExport, ReaderError
from pipeline.readers.csv import read_csv
from schemas.channels import canonical_name

FORMAT = "lvm"
EXTENSIONS = (".lvm",)

#: Bytes read while opening (headers, and the first data rows to look for comments).
HEAD_BYTES = 1 << 20
#: Bytes per parsed block while streaming (about 1e5 rows of a few channels).
CHUNK_BYTES = 1 << 23

_END = "***End_of_Header***"
_MAGIC = "LabVIEW Measurement"
_SEPARATORS = {"tab": "\t", "comma": ","}
# A line that starts a header (a tag such as "Channels"), not data: data lines start with a
# number, a separator (X_Columns = No) or NaN / Inf.
_TAG_LINE = re.compile(r"^(?![+-]?(?:nan|inf(?:inity)?)(?:[\t,;\r\n]|$))[A-Za-z_*]", re.M | re.I)
_SPECIAL = "***Start_Special***"
_COMMENT_NAME = "comment"
_X_NAME = "X_Value"


def _decode(data: bytes, prefer: str | None = None) -> tuple[str, str]:
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    if prefer != "latin-1":
        try:
            return data.decode("utf-8"), "utf-8"
        except UnicodeDecodeError:
            pass
    return data.decode("latin-1"), "latin-1"


# Candidates for a header line: a line break followed by a letter (fast: literal prefix).
_TAG_CANDIDATE = re.compile(r"\n[A-Za-z_*]")


def _next_tag_line(buf: str, pos: int) -> int:
    """Offset of the first header line at or after ``pos`` (``pos`` starts a line), else len(buf)."""
    if _TAG_LINE.match(buf, pos):
        return pos
    while True:
        m = _TAG_CANDIDATE.search(buf, pos)
        if m is None:
            return len(buf)
        if _TAG_LINE.match(buf, m.start() + 1):
            return m.start() + 1
        pos = m.start() + 1


class _Scanner:
    """Line / block access to a text file read in chunks of whole lines."""

    def __init__(self, path: Path, chunk: int | None = None):
        self.fh = open(path, "rb")
        self.chunk = chunk or CHUNK_BYTES
        self.rest = b""
        self.buf = ""
        self.pos = 0
        self.lineno = 1          # number of the line starting at self.pos
        self.encoding: str | None = None
        self.bytes_read = 0
        self.eof = False

    def close(self) -> None:
        self.fh.close()

    def _fill(self) -> bool:
        while True:
            data = self.fh.read(self.chunk)
            self.bytes_read += len(data)
            if not data:
                self.eof = True
                if not self.rest:
                    return False
                data, self.rest = self.rest + b"\n", b""
            else:
                data = self.rest + data
                cut = data.rfind(b"\n")
                if cut < 0:
                    if len(data) > MAX_LINE_BYTES:
                        raise ReaderError(f"a line longer than {MAX_LINE_BYTES >> 20} MiB (no line break from byte "
                                          f"{self.bytes_read - len(data)}): not an LVM text file")
                    self.rest = data
                    continue
                data, self.rest = data[: cut + 1], data[cut + 1:]
            text, enc = _decode(data, self.encoding)
            if self.encoding is None or enc == "latin-1":
                self.encoding = enc
            self.buf = self.buf[self.pos:] + text
            self.pos = 0
            return True

    def readline(self) -> str | None:
        while True:
            i = self.buf.find("\n", self.pos)
            if i >= 0:
                line = self.buf[self.pos:i].rstrip("\r")
                self.pos = i + 1
                self.lineno += 1
                return line
            if not self._fill():
                return None

    def peekline(self) -> str | None:
        while True:
            i = self.buf.find("\n", self.pos)
            if i >= 0:
                return self.buf[self.pos:i].rstrip("\r")
            if not self._fill():
                return None

    def data_block(self) -> tuple[str, int] | None:
        """Data lines from here to the next header line or the end of the buffer.

        Returns ``(text, line number of its first line)``; the text is empty when the next line
        is a header line; None at the end of the file.
        """
        while self.pos >= len(self.buf):
            if not self._fill():
                return None
        end = _next_tag_line(self.buf, self.pos)
        text = self.buf[self.pos:end]
        start = self.lineno
        self.lineno += text.count("\n")
        self.pos = end
        return text, start


@dataclass
class _Segment:
    number: int
    line: int                              # line of the column row
    fields: dict[str, list[str]]           # segment header tag -> fields (index = column)
    names: list[str]                       # the column row
    x_cols: list[int] = field(default_factory=list)
    channel_cols: list[int] = field(default_factory=list)
    comment_col: int | None = None

    def field_at(self, tag: str, col: int) -> str:
        values = self.fields.get(tag, [])
        return values[col].strip() if col < len(values) else ""


def _skip_special(sc: "_Scanner") -> None:
    """Skip a special block (``***Start_Special***`` ... ``***End_Special***``)."""
    start = sc.lineno - 1
    while True:
        line = sc.readline()
        if line is None:
            raise ReaderError(f"line {start}: special block without ***End_Special***")
        if line.startswith("***End_Special***"):
            return


def _split(line: str, sep: str) -> list[str]:
    return line.split(sep)


def _to_float(text: str, decimal: str) -> float | None:
    text = text.strip()
    if not text:
        return None
    try:
        return float(text.replace(",", ".") if decimal == "," else text)
    except ValueError:
        return None


def _parse_description(text: str) -> dict[str, str]:
    meta: dict[str, str] = {}
    free: list[str] = []
    for part in re.split(r"[;\n]", text):
        part = part.strip()
        if not part:
            continue
        if "=" in part and part.index("=") > 0:
            k, v = part.split("=", 1)
            meta[k.strip()] = v.strip()
        else:
            free.append(part)
    if free:
        meta.setdefault("description", "; ".join(free))
    return meta


def _started_at(date: str, time: str) -> str | None:
    m = re.match(r"^\s*(\d{4})[/.-](\d{1,2})[/.-](\d{1,2})\s*$", date or "")
    t = re.match(r"^\s*(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d+))?)?\s*$", time or "")
    if not m or not t:
        return None
    frac = (t.group(4) or "")[:6]
    out = f"{int(m.group(1)):04d}-{int(m.group(2)):02d}-{int(m.group(3)):02d}T" \
          f"{int(t.group(1)):02d}:{t.group(2)}:{t.group(3) or '00'}"
    return out + (f".{frac}" if frac else "")


class _Lvm:
    """The parsed headers of an LVM file and its data stream."""

    def __init__(self, path: Path):
        self.path = path
        self.header: dict[str, str] = {}
        self.sep = "\t"
        self.decimal = "."
        self.x_columns = "One"
        self.absolute = False

    # -- headers --------------------------------------------------------------------------
    def read_file_header(self, sc: _Scanner) -> None:
        first = sc.readline()
        if first is None or not first.lstrip("\ufeff").startswith(_MAGIC):
            raise ReaderError("not a LabVIEW Measurement file")
        while True:
            line = sc.readline()
            if line is None:
                raise ReaderError(f"file header has no {_END} line")
            if line.startswith(_END):
                break
            if line.startswith(_SPECIAL):
                _skip_special(sc)
                continue
            parts = re.split(r"[\t,]", line, maxsplit=1)
            tag = parts[0].strip()
            value = parts[1] if len(parts) > 1 else ""
            if tag == "Description" and value.strip().startswith('"'):
                value = value.strip()
                while not (len(value) > 1 and value.rstrip("\t,").endswith('"')):
                    nxt = sc.readline()
                    if nxt is None or nxt.startswith(_END):
                        raise ReaderError("the Description in the file header has no closing quote")
                    value += "\n" + nxt
                value = value.rstrip("\t,")[1:-1].replace('""', '"')
            else:
                value = value.rstrip("\t ").strip()
            if tag:
                self.header[tag] = value
        if self.header.get("Separator", "").strip(", ").lower() == "comma":
            # Comma files pad header lines with commas. LabVIEW always writes a Decimal_Separator,
            # so a value that starts with a comma is a decimal comma (refused below), not padding.
            decimal_comma = self.header.get("Decimal_Separator", "").startswith(",")
            self.header = {k: (v if k == "Description" else v.rstrip(", ")) for k, v in self.header.items()}
            if decimal_comma:
                self.header["Decimal_Separator"] = ","
        sep = self.header.get("Separator", "Tab").strip().lower()
        if sep not in _SEPARATORS:
            raise ReaderError(f"Separator {self.header.get('Separator')!r} is not Tab or Comma")
        self.sep = _SEPARATORS[sep]
        self.decimal = self.header.get("Decimal_Separator", ".").strip() or "."
        if self.decimal not in (".", ","):
            raise ReaderError(f"Decimal_Separator {self.decimal!r} is not '.' or ','")
        if self.decimal == "," and self.sep == ",":
            raise ReaderError("Decimal_Separator ',' with Separator Comma cannot be parsed")
        xc = self.header.get("X_Columns", "One").strip().capitalize()
        if xc not in ("No", "One", "Multi"):
            raise ReaderError(f"X_Columns {self.header.get('X_Columns')!r} is not No, One or Multi")
        self.x_columns = xc
        self.absolute = self.header.get("Time_Pref", "").strip().lower() == "absolute"

    def read_segment_header(self, sc: _Scanner, number: int) -> _Segment | None:
        """Segment header (optional) and column row; None at the end of the file."""
        fields: dict[str, list[str]] = {}
        in_header = False
        while True:
            line = sc.peekline()
            if line is None:
                return None
            stripped = line.strip().strip(self.sep).strip()
            if not stripped:
                sc.readline()
                continue
            parts = _split(line, self.sep)
            tag = parts[0].strip()
            if tag == _X_NAME and not in_header:
                sc.readline()
                return self._segment(number, sc.lineno - 1, fields, parts)
            if tag.startswith(_END):
                sc.readline()
                in_header = False
                continue
            if tag.startswith(_SPECIAL):
                sc.readline()
                _skip_special(sc)
                continue
            if not _TAG_LINE.match(line):
                if not fields:
                    raise ReaderError(f"line {sc.lineno}: data without a column row ({_X_NAME} ...)")
                raise ReaderError(f"line {sc.lineno}: segment header of segment {number} has no column row")
            sc.readline()
            in_header = True
            if tag == _MAGIC:
                raise ReaderError(f"line {sc.lineno - 1}: a second file header (files concatenated?)")
            fields[tag] = parts

    def _segment(self, number: int, line: int, fields: dict, names: list[str]) -> _Segment:
        names = [n.strip() for n in names]
        while names and not names[-1]:
            names.pop()
        if len(names) > MAX_CHANNELS:
            raise ReaderError(f"line {line}: the column row has {len(names)} columns: more than the limit of "
                              f"{MAX_CHANNELS} channels per file")
        seg = _Segment(number, line, fields, names)
        for i, name in enumerate(names):
            if i == len(names) - 1 and name.casefold() == _COMMENT_NAME and i > 0:
                seg.comment_col = i
            elif name == _X_NAME:
                seg.x_cols.append(i)
            else:
                seg.channel_cols.append(i)
        if not seg.channel_cols:
            raise ReaderError(f"line {line}: the column row names no channel")
        if self.x_columns == "Multi":
            for c in seg.channel_cols:
                if c - 1 not in seg.x_cols:
                    raise ReaderError(f"line {line}: X_Columns is Multi but channel `{names[c]}` has no "
                                      f"{_X_NAME} column before it")
        return seg

    def x_unit(self, seg: _Segment) -> str:
        for c in seg.channel_cols:
            u = seg.field_at("X_Unit_Label", c)
            if u:
                return u
        return "s"

    def timing(self, seg: _Segment, live: list[int]) -> tuple[float, float | None]:
        """``(X0, Delta_X)`` of a segment, from the channels that have samples."""
        pairs = []
        for c in live or seg.channel_cols:
            x0 = _to_float(seg.field_at("X0", c), self.decimal)
            dx = _to_float(seg.field_at("Delta_X", c), self.decimal)
            pairs.append((c, x0, dx))
        known = [p for p in pairs if p[2] is not None]
        if known:
            c0, _, d0 = known[0]
            for c, _, d in known[1:]:
                if not math.isclose(d, d0, rel_tol=1e-9, abs_tol=0.0) and self.x_columns == "No":
                    raise ReaderError(f"line {seg.line}: channels have different Delta_X ({d0:g} for "
                                      f"`{seg.names[c0]}`, {d:g} for `{seg.names[c]}`); one time column per run "
                                      "is needed")
        x0 = next((p[1] for p in pairs if p[1] is not None), 0.0)
        dx = known[0][2] if known else None
        return x0, dx

    def live_channels(self, seg: _Segment) -> list[int]:
        out = []
        for c in seg.channel_cols:
            n = _to_float(seg.field_at("Samples", c), self.decimal)
            if n is None or n > 0:
                out.append(c)
        return out

    def samples(self, seg: _Segment) -> int | None:
        ns = [_to_float(seg.field_at("Samples", c), self.decimal) for c in seg.channel_cols]
        ns = [int(n) for n in ns if n is not None]
        return max(ns) if ns else None


def _row_shift(lvm: _Lvm, line: str) -> int:
    """1 when an X_Columns = No data row lacks LabVIEW's leading empty X field, else 0."""
    return 1 if lvm.x_columns == "No" and line.split(lvm.sep, 1)[0].strip() != "" else 0


def _has_comment(lvm: _Lvm, text: str, col: int) -> bool:
    """Whether any data line of ``text`` (all segments in it) has a comment at ``col``."""
    shift = None
    for line in text.split("\n"):
        if _TAG_LINE.match(line):
            continue
        line = line.rstrip("\r")
        if not line.strip().strip(lvm.sep).strip():
            continue
        if shift is None:
            shift = _row_shift(lvm, line)
        parts = line.split(lvm.sep)
        if len(parts) > col - shift and parts[col - shift].strip():
            return True
    return False


def read_lvm(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open an LVM export (see the module docstring for what is read and how).

    Parameters
    ----------
    path : path-like
        The export.
    read : dict, optional
        The ``[read]`` table of the applicable ``rig.toml``; only used for ``.lvm`` files
        without a LabVIEW header (read as delimited text).
    hints : dict, optional
        Unused; accepted for the common reader signature.

    Returns
    -------
    RawExport
    """
    path = Path(path)
    with open(path, "rb") as fh:
        start = fh.read(64)
    if not _decode(start)[0].lstrip("\ufeff").startswith(_MAGIC):
        export = read_csv(path, read, hints)
        export.format = FORMAT
        return export

    lvm = _Lvm(path)
    sc = _Scanner(path, chunk=HEAD_BYTES)
    try:
        lvm.read_file_header(sc)
        seg = lvm.read_segment_header(sc, 1)
        if seg is None:
            raise ReaderError("no column row (X_Value ...) after the file header")
        head_text = sc.buf[sc.pos:]
        # Whether the whole file is in hand (then an empty Comment column can be dropped).
        whole = not sc.rest and (sc.eof or sc.bytes_read >= path.stat().st_size)
    finally:
        sc.close()

    metadata: dict[str, str] = {}
    if lvm.header.get("Description"):
        metadata.update(_parse_description(lvm.header["Description"]))
    if not any(k.strip().casefold() == "started_at" for k in metadata):
        at = _started_at(lvm.header.get("Date", ""), lvm.header.get("Time", ""))
        if at:
            metadata["started_at"] = at

    # Columns: t, the channels of the first segment, the comment.
    chan_names = [seg.names[c] for c in seg.channel_cols]
    own_t = any(canonical_name(n) == "t" for n in chan_names)
    columns: list[RawColumn] = []
    if not own_t:
        columns.append(RawColumn(key="t", name="t", unit=lvm.x_unit(seg), index=(seg.x_cols[0] + 1) if seg.x_cols else 1))
    for c in seg.channel_cols:
        unit = seg.field_at("Y_Unit_Label", c) or None
        columns.append(RawColumn(key=f"c{c + 1}", name=seg.names[c], unit=unit, index=c + 1))
    keep_comment = seg.comment_col is not None and (not whole or _has_comment(lvm, head_text, seg.comment_col))
    if keep_comment:
        columns.append(RawColumn(key=_COMMENT_NAME, name=_COMMENT_NAME, unit=None, index=seg.comment_col + 1,
                                 dtype="string"))
    export = RawExport(format=FORMAT, columns=columns, metadata=metadata)
    first = seg

    def batches() -> Iterator[pa.RecordBatch]:
        sc = _Scanner(path)
        try:
            lvm2 = _Lvm(path)
            lvm2.read_file_header(sc)
            yield from _stream(_Stream(lvm2, columns, own_t, keep_comment), sc, first, export.warnings)
        finally:
            sc.close()

    export.batches = batches
    return export


@dataclass
class _Clock:
    """Time across segments: the file's origin and the last time handed out."""

    origin: float | None = None
    last: float | None = None


@dataclass
class _SegState:
    seg: _Segment
    keys: dict[str, int]           # column key -> index in the segment's column row
    rows: int = 0
    shift: int | None = None       # 1 when rows lack the leading X field (X_Columns = No)
    x0: float = 0.0
    dx: float | None = None
    offset: float | None = None    # added to this segment's times


@dataclass
class _Stream:
    """What every block of a file's data is read with: the headers, the export's columns,
    whether a channel ``t`` gives the time, whether the comment column is kept, and the clock
    that carries time across segments."""

    lvm: _Lvm
    columns: list[RawColumn]
    own_t: bool
    keep_comment: bool
    clock: _Clock = field(default_factory=_Clock)


def _stream(ctx: _Stream, sc: _Scanner, first: _Segment, warnings: list[str]) -> Iterator[pa.RecordBatch]:
    """Every segment's data blocks as record batches; a later segment must have the first's
    channels (in any order) and units. A segment with fewer rows than its header's ``Samples``
    adds a warning."""
    lvm = ctx.lvm
    number = 0
    while True:
        number += 1
        seg = lvm.read_segment_header(sc, number)
        if seg is None:
            break
        st = _SegState(seg, _segment_keys(lvm, first, seg, number))
        st.x0, st.dx = lvm.timing(seg, lvm.live_channels(seg))
        while True:
            block = sc.data_block()
            if block is None or not block[0]:
                break
            batch = _parse_block(ctx, st, block[0], block[1])
            if batch is not None:
                yield batch
        expected = lvm.samples(seg)
        if expected is not None and st.rows < expected:
            warnings.append(f"segment {number} has {st.rows} rows where its header says Samples {expected} "
                            "(file cut short?)")
        if block is None:
            break


def _segment_keys(lvm: _Lvm, first: _Segment, seg: _Segment, number: int) -> dict[str, int]:
    """Column key -> index in segment ``seg``'s column row, for the channels of the ``first``
    segment; refused when ``seg`` has other channels, or changes a unit or the X unit."""
    first_names = [first.names[c] for c in first.channel_cols]
    first_units = [first.field_at("Y_Unit_Label", c) for c in first.channel_cols]
    t_unit = lvm.x_unit(first)
    names = [seg.names[c] for c in seg.channel_cols]
    if names == first_names:
        order = list(seg.channel_cols)
    elif sorted(names) == sorted(first_names) and len(set(names)) == len(names):
        where = dict(zip(names, seg.channel_cols))        # one pass, not names.index per channel
        order = [where[n] for n in first_names]
    else:
        raise ReaderError(f"line {seg.line}: segment {number} has channels {names} where segment 1 has "
                          f"{first_names}")
    for n, u0, c in zip(first_names, first_units, order):
        u = seg.field_at("Y_Unit_Label", c)
        if u and u0 and u != u0:
            raise ReaderError(f"line {seg.line}: unit of `{n}` changes from {u0!r} to {u!r} in segment {number}")
    if seg.fields.get("X_Unit_Label") and lvm.x_unit(seg) != t_unit:
        raise ReaderError(f"line {seg.line}: X_Unit_Label changes from {t_unit!r} to {lvm.x_unit(seg)!r} "
                          f"in segment {number}")
    return {f"c{c0 + 1}": c for c0, c in zip(first.channel_cols, order)}


# Lines of separators only, each matched from the line break before it (literal prefix: fast).
_BLANK_LINES = {"\t": re.compile(r"\n[\t \r]*(?=\n)"), ",": re.compile(r"\n[, \r]*(?=\n)")}


def _parse_block(ctx: _Stream, st: _SegState, text: str, line0: int) -> pa.RecordBatch | None:
    """One block of data lines (``text``, from line ``line0``) of the segment ``st`` as a record
    batch of the export's columns; None when the block holds no samples."""
    lvm, seg = ctx.lvm, st.seg
    # Lines of separators only (LabVIEW writes one between segments) are not samples.
    clean = _BLANK_LINES[lvm.sep].sub("", "\n" + text)[1:]
    if not clean.strip():
        return None
    if st.shift is None:
        st.shift = _row_shift(lvm, clean.split("\n", 1)[0])
    width = len(seg.names) + 4
    numeric = sorted({st.keys[c.key] - st.shift for c in ctx.columns if c.key in st.keys}
                     | ({seg.x_cols[0] - st.shift} if seg.x_cols and not ctx.own_t and lvm.x_columns != "No" else set())
                     | ({x - st.shift for x in seg.x_cols[1:]} if lvm.x_columns == "Multi" and not ctx.own_t else set()))
    numeric = [i for i in numeric if 0 <= i < width]
    comment = seg.comment_col - st.shift if ctx.keep_comment and seg.comment_col is not None else None
    df = _read_frame(lvm, st, clean, (text, line0), numeric, comment)
    n = len(df)
    arrays: dict[str, pa.Array] = {}
    if not ctx.own_t:
        arrays["t"] = pa.array(_block_time(ctx, st, df, text, line0), type=pa.float64())
    for c in ctx.columns:
        if c.key in st.keys:
            arrays[c.key] = pa.array(_field_values(df, st, st.keys[c.key]), type=pa.float64())
    if ctx.keep_comment:
        if comment is not None:
            s = df[f"f{comment}"]
            s = s.where(s.notna() & (s.astype(str).str.strip() != ""), None)
            arrays[_COMMENT_NAME] = pa.array(s.to_numpy(dtype=object), type=pa.string(), from_pandas=True)
        else:
            arrays[_COMMENT_NAME] = pa.nulls(n, pa.string())
    st.rows += n
    return pa.RecordBatch.from_arrays([arrays[c.key] for c in ctx.columns], names=[c.key for c in ctx.columns])


def _read_frame(lvm: _Lvm, st: _SegState, clean: str, block: tuple[str, int], numeric: list[int],
                comment: int | None):
    """The data lines ``clean`` (``block``: the block's text as read and its first line, for
    messages) parsed by pandas into fields ``f0``, ``f1`` ...; a bad value or field count is a
    ReaderError naming its line."""
    import pandas as pd   # heavy: imported when the first block is parsed, not when a worker loads the readers

    text, line0 = block
    seg = st.seg
    # Numbers are left to pandas' type inference: an explicit float64 dtype would ignore the
    # decimal comma. A numeric column that comes back as text holds a bad value.
    dtype = {f"f{comment}": str} if comment is not None else None
    # No usecols: pandas then refuses rows shorter than the names (trailing empty fields
    # are not written by LabVIEW); a few spare names absorb trailing separators.
    opts = dict(sep=lvm.sep, header=None, names=[f"f{i}" for i in range(len(seg.names) + 4)], index_col=False,
                decimal=lvm.decimal, engine="c", skip_blank_lines=True)
    try:
        df = pd.read_csv(io.StringIO(clean), dtype=dtype, **opts)
    except (ValueError, pd.errors.ParserError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", msg)
        if m:
            k = _text_line(text, int(m.group(2)) - 1, lvm.sep)
            raise ReaderError(f"line {line0 + k - 1}: {m.group(3)} fields where the column row has "
                              f"{len(seg.names)}") from None
        _raise_bad_value(lvm, st, text, line0, numeric)
        raise ReaderError(f"segment {seg.number}: cannot parse data: {msg}") from None
    for i in numeric:
        if f"f{i}" in df and df[f"f{i}"].dtype.kind not in "fiub":
            _raise_bad_value(lvm, st, text, line0, [i])
            raise ReaderError(f"segment {seg.number}: column {i + st.shift + 1} is not numeric")
    return df


def _field_values(df, st: _SegState, i: int) -> np.ndarray:
    """Column ``i`` of the column row as floats (NaN where the rows have no such field)."""
    j = i - st.shift
    if f"f{j}" in df:
        return df[f"f{j}"].to_numpy(dtype=np.float64)
    return np.full(len(df), np.nan)


def _block_time(ctx: _Stream, st: _SegState, df, text: str, line0: int) -> np.ndarray:
    """The block's times: ``X0 + i * Delta_X`` (``X_Columns = No``) or the first X column (the
    others must agree with it), moved on by the segment's offset; the clock keeps the last."""
    lvm, seg, n = ctx.lvm, st.seg, len(df)
    if lvm.x_columns == "No":
        if st.dx is None:
            raise ReaderError(f"line {seg.line}: X_Columns is No but segment {seg.number} has no Delta_X")
        t = st.x0 + np.arange(st.rows, st.rows + n, dtype=np.float64) * st.dx
    else:
        t = _field_values(df, st, seg.x_cols[0])
        if lvm.x_columns == "Multi":
            for xc in seg.x_cols[1:]:
                other = _field_values(df, st, xc)
                ok = np.isnan(other) | np.isclose(other, t, rtol=1e-9, atol=0.0)
                if not ok.all():
                    k = _text_line(text, int(np.flatnonzero(~ok)[0]), lvm.sep)
                    ch = seg.names[xc + 1] if xc + 1 < len(seg.names) else f"column {xc + 1}"
                    raise ReaderError(
                        f"line {line0 + k - 1}: the X column of `{ch}` ({other[~ok][0]:g}) disagrees with the "
                        f"first X column ({t[~ok][0]:g}); channels with different timing cannot share one "
                        "time column")
    if st.offset is None:
        st.offset = _segment_offset(lvm, st, ctx.clock, t)
    if st.offset:
        t = t + st.offset
    finite = t[np.isfinite(t)]
    if finite.size:
        ctx.clock.last = float(finite.max())
    return t


def _segment_offset(lvm: _Lvm, st: _SegState, clock: _Clock, t: np.ndarray) -> float:
    """What to add to a segment's times so that time runs on (see the module docstring)."""
    finite = t[np.isfinite(t)]
    if not finite.size:
        return 0.0
    t_first = float(finite[0])
    if clock.origin is None:
        clock.origin = t_first if lvm.absolute else 0.0
    if clock.last is not None and t_first - clock.origin <= clock.last:
        step = st.dx
        if not step:
            d = np.diff(finite)
            step = float(np.median(d[d > 0])) if (d > 0).any() else 0.0
        return clock.last + step - t_first
    return -clock.origin


def _text_line(text: str, k: int, sep: str) -> int:
    """1-based line in ``text`` of its k-th (0-based) data line (blank lines skipped)."""
    seen = -1
    lines = text.split("\n")
    for i, line in enumerate(lines):
        if line.strip().strip(sep).strip():
            seen += 1
            if seen == k:
                return i + 1
    return len(lines)


def _raise_bad_value(lvm: _Lvm, st: _SegState, text: str, line0: int, numeric: list[int]) -> None:
    """Find the first cell that is not a number and raise a ReaderError naming its line."""
    for i, line in enumerate(text.split("\n")):
        line = line.rstrip("\r")
        if not line.strip().strip(lvm.sep).strip():
            continue
        parts = line.split(lvm.sep)
        for j in numeric:
            if j < len(parts):
                cell = parts[j].strip()
                if cell and _to_float(cell, lvm.decimal) is None and cell.lower() not in ("nan", "inf", "-inf", "+inf"):
                    col = st.seg.names[j + st.shift] if j + st.shift < len(st.seg.names) else f"{j + st.shift + 1}"
                    raise ReaderError(f"line {line0 + i}: value {cell!r} in column `{col}` is not a number")
