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

This module reads the data; the file's text and headers are :mod:`pipeline.readers.lvm_header`'s.
"""
from __future__ import annotations

import io
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import RawColumn, RawExport, ReaderError
from pipeline.readers.csv import read_csv
from pipeline.readers.lvm_header import (COMMENT_NAME, MAGIC, TAG_LINE, Lvm, Scanner, Segment, decode,
                                         parse_description, row_shift, started_at, to_float)
from schemas.channels import canonical_name

FORMAT = "lvm"
EXTENSIONS = (".lvm",)

#: Bytes read while opening (headers, and the first data rows to look for comments).
HEAD_BYTES = 1 << 20
#: Bytes per parsed block while streaming (about 1e5 rows of a few channels).
CHUNK_BYTES = 1 << 23

def _has_comment(lvm: Lvm, text: str, col: int) -> bool:
    """Whether any data line of ``text`` (all segments in it) has a comment at ``col``."""
    shift = None
    for line in text.split("\n"):
        if TAG_LINE.match(line):
            continue
        line = line.rstrip("\r")
        if not line.strip().strip(lvm.sep).strip():
            continue
        if shift is None:
            shift = row_shift(lvm, line)
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
    if not decode(start)[0].lstrip("\ufeff").startswith(MAGIC):
        export = read_csv(path, read, hints)
        export.format = FORMAT
        return export

    lvm = Lvm(path)
    sc = Scanner(path, chunk=HEAD_BYTES)
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
        metadata.update(parse_description(lvm.header["Description"]))
    if not any(k.strip().casefold() == "started_at" for k in metadata):
        at = started_at(lvm.header.get("Date", ""), lvm.header.get("Time", ""))
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
        columns.append(RawColumn(key=COMMENT_NAME, name=COMMENT_NAME, unit=None, index=seg.comment_col + 1,
                                 dtype="string"))
    export = RawExport(format=FORMAT, columns=columns, metadata=metadata)
    first = seg

    def batches() -> Iterator[pa.RecordBatch]:
        sc = Scanner(path, chunk=CHUNK_BYTES)
        try:
            lvm2 = Lvm(path)
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
    """How far one segment has been read: its keys, rows so far, row shift, timing and time offset."""

    seg: Segment
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

    lvm: Lvm
    columns: list[RawColumn]
    own_t: bool
    keep_comment: bool
    clock: _Clock = field(default_factory=_Clock)


def _stream(ctx: _Stream, sc: Scanner, first: Segment, warnings: list[str]) -> Iterator[pa.RecordBatch]:
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


def _segment_keys(lvm: Lvm, first: Segment, seg: Segment, number: int) -> dict[str, int]:
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
        st.shift = row_shift(lvm, clean.split("\n", 1)[0])
    width = len(seg.names) + 4
    own_t = ctx.own_t
    numeric = sorted({st.keys[c.key] - st.shift for c in ctx.columns if c.key in st.keys}
                     | ({seg.x_cols[0] - st.shift} if seg.x_cols and not own_t and lvm.x_columns != "No" else set())
                     | ({x - st.shift for x in seg.x_cols[1:]} if lvm.x_columns == "Multi" and not own_t else set()))
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
            arrays[COMMENT_NAME] = pa.array(s.to_numpy(dtype=object), type=pa.string(), from_pandas=True)
        else:
            arrays[COMMENT_NAME] = pa.nulls(n, pa.string())
    st.rows += n
    return pa.RecordBatch.from_arrays([arrays[c.key] for c in ctx.columns], names=[c.key for c in ctx.columns])


def _read_frame(lvm: Lvm, st: _SegState, clean: str, block: tuple[str, int], numeric: list[int],
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


def _segment_offset(lvm: Lvm, st: _SegState, clock: _Clock, t: np.ndarray) -> float:
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


def _raise_bad_value(lvm: Lvm, st: _SegState, text: str, line0: int, numeric: list[int]) -> None:
    """Find the first cell that is not a number and raise a ReaderError naming its line."""
    for i, line in enumerate(text.split("\n")):
        line = line.rstrip("\r")
        if not line.strip().strip(lvm.sep).strip():
            continue
        parts = line.split(lvm.sep)
        for j in numeric:
            if j < len(parts):
                cell = parts[j].strip()
                if cell and to_float(cell, lvm.decimal) is None and cell.lower() not in ("nan", "inf", "-inf", "+inf"):
                    col = st.seg.names[j + st.shift] if j + st.shift < len(st.seg.names) else f"{j + st.shift + 1}"
                    raise ReaderError(f"line {line0 + i}: value {cell!r} in column `{col}` is not a number")
