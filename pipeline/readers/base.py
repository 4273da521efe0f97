"""What every reader returns, and the helpers readers share.

A reader turns one raw export into a :class:`RawExport`: the file's own column names and
units, its embedded metadata, and a *lazy* stream of Arrow record batches of raw values. It
does no unit conversion and no validation beyond its format; mapping raw columns onto
canonical channels, converting units and validating the kind is the ingest's job
(:mod:`pipeline.ingest.file`), the same for every format.
"""
from __future__ import annotations

import csv
import io
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the readers import pyarrow themselves; the raw tree's walk needs none of it
    import pyarrow as pa


class ReaderError(Exception):
    """The file cannot be read: its message is one line saying what is wrong and where."""


# -- resource limits (what a reader may ask of a worker) ------------------------------------
#: Most channels (data columns) one export may have. A bench logs tens of channels; a file
#: with thousands of columns is malformed or hostile and is refused before any per-column work.
MAX_CHANNELS = 4096

#: Most runs one file may hold (sheets of a workbook, MDF channel groups, in ``sheets`` /
#: ``groups = "all"`` mode). A bench file holds a few runs; each is opened and read on its own,
#: so a file declaring thousands is malformed or hostile and is refused before any is read.
MAX_PARTS = 1024

#: Decompressed (or declared, for sparse / chunked storage) data may be this many times the
#: file's size ...
MAX_INFLATE_RATIO = 100
#: ... or up to this many bytes whatever the ratio (a small file of constant channels
#: compresses very well) [B] ...
INFLATE_FLOOR_BYTES = 64 << 20
#: ... and never more than this many bytes, however large the file (MAT v5 is loaded whole by
#: scipy, so this bounds a worker's memory for one file) [B].
INFLATE_CEILING_BYTES = 4 << 30


#: Time one file may take to read, whatever its size [s] ...
READ_TIME_FLOOR_S = 300.0
#: ... plus its size at this rate [B/s]: 0.5 MB/s is ten times slower than the slowest reader
#: (workbooks, ~5 MB/s) on a slow share. A reader still busy after that is stuck (a loop in a C
#: library on a file whose links point back on themselves): its worker is stopped and the file
#: quarantined, so one file cannot hold up the night.
READ_RATE_FLOOR_B_S = 0.5e6


def read_time_limit(size_bytes: int) -> float:
    """Seconds a file of ``size_bytes`` may take to read (:data:`READ_TIME_FLOOR_S` plus its
    size at :data:`READ_RATE_FLOOR_B_S`)."""
    return READ_TIME_FLOOR_S + max(0, size_bytes) / READ_RATE_FLOOR_B_S


#: Longest line a text reader holds while looking for its end [B]: 4,096 channels of 25
#: characters are 100 KB; a longer "line" is binary data or a file without line breaks.
MAX_LINE_BYTES = 16 << 20


def check_channel_count(n: int, what: str = "columns") -> None:
    """Refuse an export with more than :data:`MAX_CHANNELS` channels (one-line ReaderError)."""
    if n > MAX_CHANNELS:
        raise ReaderError(f"{n} {what}: more than the limit of {MAX_CHANNELS} channels per file")


def check_part_count(n: int, what: str) -> None:
    """Refuse a file of more than :data:`MAX_PARTS` runs (one-line ReaderError)."""
    if n > MAX_PARTS:
        raise ReaderError(f"{n} {what}: more than the limit of {MAX_PARTS} runs per file")


def inflate_cap(file_size: int) -> int:
    """Most bytes a reader may decompress / allocate for the data of a file of ``file_size``
    bytes: ``min(ceiling, max(floor, ratio * file_size))`` (see the constants above). [B]"""
    return int(min(INFLATE_CEILING_BYTES, max(INFLATE_FLOOR_BYTES, MAX_INFLATE_RATIO * int(file_size))))


def mib(n: int) -> str:
    """Bytes as text in MiB for messages (``"12.5 MiB"``)."""
    return f"{n / (1 << 20):.1f} MiB"


@dataclass
class RawColumn:
    """A data column of an export, as the export names it.

    Attributes
    ----------
    key : str
        Name of the column in the reader's record batches (unique within the export).
    name : str
        Channel name as written in the export (header text without the unit).
    unit : str or None
        Unit text as written in the export; None when the export gives none.
    index : int
        1-based position of the column in the file, as ``rig.toml`` addresses headerless files.
    dtype : str
        ``"float"`` (default) or ``"string"`` for a column of text; a canonical channel is
        always read as numbers.
    header : str or None
        The header text exactly as written (``"time(sec)"``) when the reader split a unit off
        it; a ``rig.toml`` ``[channels]`` key may name it. None when there is no such text.
    """

    key: str
    name: str
    unit: str | None
    index: int
    dtype: str = "float"
    header: str | None = None


@dataclass
class RawExport:
    """One raw export opened by a reader.

    ``batches()`` opens the data and yields record batches whose columns are the
    ``RawColumn.key`` of :attr:`columns` (a column may be missing from the batches only if
    the reader documents it). Readers synthesise a time column ``t`` (unit ``s``) when the
    format gives time implicitly (LVM ``Delta_X``, TDMS waveform properties).
    """

    format: str
    columns: list[RawColumn]
    metadata: dict = field(default_factory=dict)
    batches: Callable[[], Iterator[pa.RecordBatch]] = lambda: iter(())
    warnings: list[str] = field(default_factory=list)


_NAME_UNIT = re.compile(r"^\s*(?P<name>.*?)\s*[\[(](?P<unit>[^\[\]]*)[\])]\s*$")


def split_name_unit(header: str) -> tuple[str, str | None]:
    """Split a ``name[unit]`` header into name and unit (unit None when there is none).

    ``"p_a[bar(a)]"`` -> ``("p_a", "bar(a)")``; ``"x [mm]"`` -> ``("x", "mm")``;
    ``"comment"`` -> ``("comment", None)``.
    """
    text = header.strip().strip('"').strip("'").strip()
    if text.endswith("]") and "[" in text:
        i = text.index("[")
        return text[:i].strip(), text[i + 1:-1].strip() or None
    m = _NAME_UNIT.match(text)
    if m and m.group("name"):
        return m.group("name"), m.group("unit").strip() or None
    return text, None


def decode_text(data: bytes, whole: bool = True) -> tuple[str, str]:
    """Decode bytes as UTF-8 (with or without BOM), else Latin-1. Returns (text, encoding).

    ``whole``: the bytes are the whole file. False when they are only its first bytes: a UTF-8
    character cut by the end of such a read is left out and the text is still UTF-8. A whole
    file whose last bytes are no complete UTF-8 character is Latin-1 (``caf\xe9``), every byte kept.
    """
    if data.startswith(b"\xef\xbb\xbf"):
        return data[3:].decode("utf-8", errors="replace"), "utf-8-sig"
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError as exc:
        if not whole and exc.end == len(data) and exc.reason == "unexpected end of data":
            return data[: exc.start].decode("utf-8"), "utf-8"  # valid up to the cut character
        return data.decode("latin-1"), "latin-1"


def exc_text(exc: BaseException, limit: int = 160) -> str:
    """A library's exception as one short line for a quarantine reason: ``Type: message``."""
    what = " ".join(str(exc).split())[:limit]
    return f"{type(exc).__name__}: {what}" if what else type(exc).__name__


class SideCsvError(Exception):
    """A side file (``manifest.csv``, ``hoses.csv``) that cannot be parsed as CSV text.

    ``args``: (one-line message, 1-based line where the bad row starts, or None).
    """


def side_csv_rows(data: bytes) -> Iterator[tuple[int, int, list[str]]]:
    """Rows of an untrusted CSV side file as ``(first line, last line, cells)`` (1-based).

    The delimiter is the one of ``,`` ``;`` tab that the first non-blank line uses most. Parsing
    is strict, so an unclosed quote is an error rather than a field that swallows the rest of
    the file. Raises :class:`SideCsvError` for a NUL byte (a binary or UTF-16 file), an unclosed
    quote, a field over the csv module's limit, or any other CSV syntax error.
    """
    if b"\x00" in data:
        raise SideCsvError("NUL byte (a binary or UTF-16 file?); save it as UTF-8 CSV",
                           data[: data.index(b"\x00")].count(b"\n") + 1)
    text = decode_text(data)[0]
    first = next((ln for ln in text.splitlines() if ln.strip()), "")
    delim = max((",", ";", "\t"), key=first.count) if first else ","
    reader = csv.reader(io.StringIO(text), delimiter=delim, strict=True)
    while True:
        start = reader.line_num + 1
        try:
            cells = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            msg = str(exc)
            if "unexpected end of data" in msg:
                msg = "unclosed quote (the quoted field runs to the end of the file)"
            elif "field larger than field limit" in msg:
                msg = f"a field is longer than {csv.field_size_limit()} characters (the csv module's limit)"
            else:
                msg = f"CSV syntax error: {msg}"
            raise SideCsvError(msg, start) from None
        yield start, reader.line_num, cells


#: What a metadata key looks like: letters, digits, ``_``, ``.``, ``-``; no spaces.
_META_KEY = re.compile(r"[\w.\-]+")


def parse_key_value(line: str, seps: str = ":=") -> tuple[str, str] | None:
    """``"key: value"`` or ``"key=value"`` -> ``(key, value)``; None when it is not one.

    The key must look like a key (:data:`_META_KEY`): ``"Captured 2020-07-03 03:08:17 by ..."``
    is a comment, not the key ``"Captured 2020-07-03 03"``.
    """
    positions = [line.find(s) for s in seps if line.find(s) > 0]
    if not positions:
        return None
    i = min(positions)
    key, value = line[:i].strip(), line[i + 1:].strip()
    if not key or len(key) > 64 or not _META_KEY.fullmatch(key):
        return None
    return key, value


def add_comment_line(text: str, metadata: dict) -> None:
    """One ``#`` line of a file's head (``text`` after the ``#``): ``key: value`` / ``key = value``
    into ``metadata``, any other non-empty line kept whole, in order, in ``metadata["comments"]``."""
    kv = parse_key_value(text)
    if kv and kv[0].casefold() != "comments":
        metadata[kv[0]] = kv[1]
    elif text.strip():
        metadata.setdefault("comments", []).append(text.strip())
