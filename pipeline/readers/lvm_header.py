"""The text and the headers of an LVM file (see :mod:`pipeline.readers.lvm` for the layout).

:class:`Scanner` gives line and block access to the file read in chunks of whole lines (UTF-8
when it decodes, else Latin-1); :class:`Lvm` parses the file header (separator, decimal mark,
``X_Columns``, ``Time_Pref``, ``Description``) and each segment header with its column row into
a :class:`Segment`, whose fields sit under the columns they describe.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.readers.base import MAX_CHANNELS, MAX_LINE_BYTES, ReaderError

_END = "***End_of_Header***"
#: The first line of a LabVIEW Measurement file (without it, a ``.lvm`` is plain delimited text).
MAGIC = "LabVIEW Measurement"
_SEPARATORS = {"tab": "\t", "comma": ","}
# A line that starts a header (a tag such as "Channels"), not data: data lines start with a
# number, a separator (X_Columns = No) or NaN / Inf.
TAG_LINE = re.compile(r"^(?![+-]?(?:nan|inf(?:inity)?)(?:[\t,;\r\n]|$))[A-Za-z_*]", re.M | re.I)
_SPECIAL = "***Start_Special***"
#: Name of the comment column (the last of a column row, case-insensitive), and of its key.
COMMENT_NAME = "comment"
_X_NAME = "X_Value"


def decode(data: bytes, prefer: str | None = None) -> tuple[str, str]:
    """Bytes as ``(text, encoding)``: UTF-8 (a BOM dropped) unless ``prefer`` is ``"latin-1"`` or
    they do not decode, else Latin-1."""
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
    if TAG_LINE.match(buf, pos):
        return pos
    while True:
        m = _TAG_CANDIDATE.search(buf, pos)
        if m is None:
            return len(buf)
        if TAG_LINE.match(buf, m.start() + 1):
            return m.start() + 1
        pos = m.start() + 1


class Scanner:
    """Line / block access to a text file read in chunks of whole lines."""

    def __init__(self, path: Path, chunk: int):
        self.fh = open(path, "rb")
        self.chunk = chunk
        self.rest = b""
        self.buf = ""
        self.pos = 0
        self.lineno = 1          # number of the line starting at self.pos
        self.encoding: str | None = None
        self.bytes_read = 0
        self.eof = False

    def close(self) -> None:
        """Close the file."""
        self.fh.close()

    def _fill(self) -> bool:
        """Read the next chunk of whole lines into the buffer; False at the end of the file."""
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
            text, enc = decode(data, self.encoding)
            if self.encoding is None or enc == "latin-1":
                self.encoding = enc
            self.buf = self.buf[self.pos:] + text
            self.pos = 0
            return True

    def readline(self) -> str | None:
        """The next line (without its line end), or None at the end of the file."""
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
        """The next line without consuming it, or None at the end of the file."""
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
class Segment:
    """One segment's header fields (tag -> fields, indexed like the column row), its column row
    and which of its columns are X values, channels and the comment."""

    number: int
    line: int                              # line of the column row
    fields: dict[str, list[str]]           # segment header tag -> fields (index = column)
    names: list[str]                       # the column row
    x_cols: list[int] = field(default_factory=list)
    channel_cols: list[int] = field(default_factory=list)
    comment_col: int | None = None

    def field_at(self, tag: str, col: int) -> str:
        """The field of header line ``tag`` under column ``col`` (``""`` when there is none)."""
        values = self.fields.get(tag, [])
        return values[col].strip() if col < len(values) else ""


def _skip_special(sc: "Scanner") -> None:
    """Skip a special block (``***Start_Special***`` ... ``***End_Special***``)."""
    start = sc.lineno - 1
    while True:
        line = sc.readline()
        if line is None:
            raise ReaderError(f"line {start}: special block without ***End_Special***")
        if line.startswith("***End_Special***"):
            return


def _split(line: str, sep: str) -> list[str]:
    """The fields of a header line."""
    return line.split(sep)


def to_float(text: str, decimal: str) -> float | None:
    """A header field or cell as a number under the file's decimal mark; None when it is none."""
    text = text.strip()
    if not text:
        return None
    try:
        return float(text.replace(",", ".") if decimal == "," else text)
    except ValueError:
        return None


def parse_description(text: str) -> dict[str, str]:
    """The ``Description``'s ``key=value`` pairs (separated by ``;`` or new lines); other text is
    kept as ``description``."""
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


def started_at(date: str, time: str) -> str | None:
    """ISO 8601 local time from the header's ``Date`` (``2026/01/02``) and ``Time``
    (``03:04:05.25``); None when either is not in that form."""
    m = re.match(r"^\s*(\d{4})[/.-](\d{1,2})[/.-](\d{1,2})\s*$", date or "")
    t = re.match(r"^\s*(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d+))?)?\s*$", time or "")
    if not m or not t:
        return None
    frac = (t.group(4) or "")[:6]
    out = f"{int(m.group(1)):04d}-{int(m.group(2)):02d}-{int(m.group(3)):02d}T" \
          f"{int(t.group(1)):02d}:{t.group(2)}:{t.group(3) or '00'}"
    return out + (f".{frac}" if frac else "")


class Lvm:
    """The parsed headers of an LVM file and its data stream."""

    def __init__(self, path: Path):
        self.path = path
        self.header: dict[str, str] = {}
        self.sep = "\t"
        self.decimal = "."
        self.x_columns = "One"
        self.absolute = False

    # -- headers --------------------------------------------------------------------------
    def read_file_header(self, sc: Scanner) -> None:
        """Read the file header up to its ``***End_of_Header***``; check the separator, decimal
        mark and ``X_Columns`` it gives."""
        first = sc.readline()
        if first is None or not first.lstrip("\ufeff").startswith(MAGIC):
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

    def read_segment_header(self, sc: Scanner, number: int) -> Segment | None:
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
            if not TAG_LINE.match(line):
                if not fields:
                    raise ReaderError(f"line {sc.lineno}: data without a column row ({_X_NAME} ...)")
                raise ReaderError(f"line {sc.lineno}: segment header of segment {number} has no column row")
            sc.readline()
            in_header = True
            if tag == MAGIC:
                raise ReaderError(f"line {sc.lineno - 1}: a second file header (files concatenated?)")
            fields[tag] = parts

    def _segment(self, number: int, line: int, fields: dict, names: list[str]) -> Segment:
        """Segment ``number`` from its header ``fields`` and its column row ``names`` (at ``line``)."""
        names = [n.strip() for n in names]
        while names and not names[-1]:
            names.pop()
        if len(names) > MAX_CHANNELS:
            raise ReaderError(f"line {line}: the column row has {len(names)} columns: more than the limit of "
                              f"{MAX_CHANNELS} channels per file")
        seg = Segment(number, line, fields, names)
        for i, name in enumerate(names):
            if i == len(names) - 1 and name.casefold() == COMMENT_NAME and i > 0:
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

    def x_unit(self, seg: Segment) -> str:
        """The time's unit: the first ``X_Unit_Label`` under a channel, else ``s``."""
        for c in seg.channel_cols:
            u = seg.field_at("X_Unit_Label", c)
            if u:
                return u
        return "s"

    def timing(self, seg: Segment, live: list[int]) -> tuple[float, float | None]:
        """``(X0, Delta_X)`` of a segment, from the channels that have samples."""
        pairs = []
        for c in live or seg.channel_cols:
            x0 = to_float(seg.field_at("X0", c), self.decimal)
            dx = to_float(seg.field_at("Delta_X", c), self.decimal)
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

    def live_channels(self, seg: Segment) -> list[int]:
        """The channel columns whose ``Samples`` is not 0."""
        out = []
        for c in seg.channel_cols:
            n = to_float(seg.field_at("Samples", c), self.decimal)
            if n is None or n > 0:
                out.append(c)
        return out

    def samples(self, seg: Segment) -> int | None:
        """The most ``Samples`` a channel of the segment announces (None when none says)."""
        ns = [to_float(seg.field_at("Samples", c), self.decimal) for c in seg.channel_cols]
        ns = [int(n) for n in ns if n is not None]
        return max(ns) if ns else None


def row_shift(lvm: Lvm, line: str) -> int:
    """1 when an X_Columns = No data row lacks LabVIEW's leading empty X field, else 0."""
    return 1 if lvm.x_columns == "No" and line.split(lvm.sep, 1)[0].strip() != "" else 0
