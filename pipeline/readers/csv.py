"""CSV / TXT exports: ``# key: value`` metadata lines, a ``name[unit]`` header, then data.

* Delimiter detected among ``,`` ``;`` and tab (``rig.toml`` ``[read] delimiter`` overrides,
  and may say ``"whitespace"`` for runs of blanks).
* With ``;``, tab or blanks, the decimal mark is decided from every numeric cell of the data
  rows in the first 64 KiB (:func:`_detect_decimal`): a comma is a decimal comma only when no
  cell says it groups thousands, and a file whose numbers read differently under both marks
  (``1,250`` beside ``998``; ``0,5`` beside ``1.5``) is refused with the column and a value,
  never read half one way. ``[read] decimal`` overrides.
* Files without a header are described by ``rig.toml`` (``header = false``; columns are then
  addressed by their 1-based index); ``skip_rows`` drops lines before the header / data.

Data is streamed in blocks of lines parsed by pyarrow in parallel threads (bounded memory;
files with lone ``\r`` line ends or not in UTF-8 use pyarrow's incremental reader);
whitespace-separated files go through pandas' C parser in chunks.
"""
from __future__ import annotations

import csv as _csv
import os
import re
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.readers.base import (MAX_LINE_BYTES, RawColumn, RawExport, ReaderError, add_comment_line,
                                   check_channel_count, decode_text, split_name_unit)
from schemas.channels import canonical_name

FORMAT = "csv"
EXTENSIONS = (".csv", ".txt")

#: Bytes read to find metadata, header and the first data rows.
HEAD_BYTES = 1 << 16
#: Bytes per block of the streaming parser.
BLOCK_BYTES = 1 << 23

_DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "\\t": "\t", "whitespace": "whitespace", " ": "whitespace"}
# Line breaks as the CSV parsers see them (str.splitlines also breaks at \x85, \x0c, ...,
# which a Latin-1 file may contain inside a line).
_LINE_BREAK = re.compile(r"\r\n|\r|\n")


def read_csv(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open a CSV / TXT export.

    Parameters
    ----------
    path : path-like
        The export.
    read : dict, optional
        The ``[read]`` table of the applicable ``rig.toml``: ``delimiter``, ``decimal``,
        ``skip_rows``, ``header``.
    hints : dict, optional
        Unused; accepted for the common reader signature.

    Returns
    -------
    RawExport
    """
    path = Path(path)
    read = dict(read or {})
    metadata: dict = {}
    head = _open_head(path, read, metadata)
    samples = [ln for ln in head.lines[head.data_start:head.data_start + 20] if ln.strip()]
    dialect = _dialect(read, head, samples)
    rows = [dialect.split(s) for s in samples]     # split once: header parsing stays linear in the width
    names = _header_names(head, dialect, rows)
    columns, keys = _columns(names, rows, head.has_header, dialect.decimal)
    data = _Data(path, head.encoding, head.data_start, keys, columns, dialect)
    return RawExport(format=FORMAT, columns=columns, metadata=metadata, batches=lambda: _batches(data))


@dataclass(frozen=True)
class _Dialect:
    """How the data lines are cut: ``delimiter`` (a character or ``"whitespace"``) and the
    ``decimal`` mark (``"."`` or ``","``)."""

    delimiter: str
    decimal: str

    def split(self, line: str) -> list[str]:
        """The fields of one line."""
        if self.delimiter == "whitespace":
            return line.split()
        return next(_csv.reader([line], delimiter=self.delimiter), [])   # honours quoted fields


@dataclass(frozen=True)
class _Head:
    """The head of the file as opened: its lines, whether they are the whole file, and where
    the header / data start in them."""

    lines: list[str]
    encoding: str
    has_header: bool
    header_line: str | None
    data_start: int          # index of the first data line = physical lines before it


@dataclass(frozen=True)
class _Data:
    """What streaming the data needs: the file, its encoding, the lines before the data, the
    parser's column names (``c1`` ...), the columns read and the dialect."""

    path: Path
    encoding: str
    lines_before: int
    keys: list[str]
    columns: list[RawColumn]
    dialect: _Dialect


def _open_head(path: Path, read: dict, metadata: dict) -> _Head:
    """Read the head of the file: leading ``#`` lines into ``metadata``, ``skip_rows`` skipped,
    then where the header (if any) and the data start."""
    lines, encoding, complete = _head_lines(path)
    i = 0
    # Leading "# key: value" lines (blank lines between them are allowed); other "#" lines are
    # comments, kept whole under "comments".
    while i < len(lines) and (lines[i].lstrip().startswith("#") or not lines[i].strip()):
        if lines[i].lstrip().startswith("#"):
            add_comment_line(lines[i].lstrip()[1:], metadata)
        i += 1
    skip = int(read.get("skip_rows", 0) or 0)
    i += skip
    has_header = bool(read.get("header", True))
    if i >= len(lines):
        raise ReaderError("no header or data rows" if complete else f"no header within the first {HEAD_BYTES} bytes")
    return _Head(lines, encoding, has_header, lines[i] if has_header else None, i + 1 if has_header else i)


def _head_lines(path: Path) -> tuple[list[str], str, bool]:
    """The first :data:`HEAD_BYTES` as ``(lines, encoding, whether that is the whole file)``; a
    last line the read may have cut is left out."""
    with open(path, "rb") as fh:
        data = fh.read(HEAD_BYTES)
        complete = len(data) < HEAD_BYTES
    text, encoding = decode_text(data, whole=complete)
    lines = _LINE_BREAK.split(text)
    if lines and lines[-1] == "":
        lines.pop()
    if not complete and lines:
        lines = lines[:-1]  # the last line may be cut
    return lines, encoding, complete


def _dialect(read: dict, head: _Head, samples: list[str]) -> _Dialect:
    """Delimiter and decimal mark: ``rig.toml`` ``[read]`` where it says, else detected from
    the header and the data rows of the head."""
    delim_opt = read.get("delimiter")
    if delim_opt is not None and delim_opt not in _DELIMITERS:
        raise ReaderError(f"rig.toml delimiter {delim_opt!r} is not one of ',' ';' '\\t' 'whitespace'")
    head_rows = [ln for ln in head.lines[head.data_start:] if ln.strip()]   # every data row of the head: the decimal
    if delim_opt is not None:
        delimiter = _DELIMITERS[delim_opt]
    else:
        header_line = head.header_line
        delimiter = _detect_delimiter(header_line if header_line is not None else (samples[0] if samples else ""),
                                      samples)
    decimal = read.get("decimal") or _detect_decimal(delimiter, head_rows, head.header_line)
    if decimal not in (".", ","):
        raise ReaderError(f"rig.toml decimal {decimal!r} is not '.' or ','")
    if decimal == "," and delimiter == ",":
        raise ReaderError("decimal comma with a comma delimiter cannot be parsed")
    return _Dialect(delimiter, decimal)


def _detect_delimiter(header: str, samples: list[str]) -> str:
    """The one of tab, ``;`` and ``,`` that the header has and most sample rows have as often."""
    best, best_score = ",", -1
    # On a tie ";" and tab win: with them a "," is a decimal comma ("0;1,5").
    for cand in ("\t", ";", ","):
        n = header.count(cand)
        if n == 0:
            continue
        consistent = sum(1 for s in samples if s.count(cand) == n)
        score = n + 1000 * consistent
        if score > best_score:
            best, best_score = cand, score
    return best


# A number under one of the marks: plain (`1.5`, `1,5`, `.5`, `1e3`) or with digit grouping
# (`1,250`, `1,250,000.5`, `1.250,5`). Dates (`02.01.2026`) and versions (`1.2.3`) are not.
_NUMBER_CELL = re.compile(r"^[+-]?((\d+([.,]\d*)?|[.,]\d+)([eE][+-]?\d+)?"
                          r"|[1-9]\d{0,2}(,\d{3})+(\.\d*)?|[1-9]\d{0,2}(\.\d{3})+(,\d*)?)$")
_GROUPED = {",": re.compile(r"^[+-]?[1-9]\d{0,2}(,\d{3})+$"), ".": re.compile(r"^[+-]?[1-9]\d{0,2}(\.\d{3})+$")}
_INTEGER = re.compile(r"^[+-]?\d+([eE][+-]?\d+)?$")


def _detect_decimal(delimiter: str, samples: list[str], header: str | None = None) -> str:
    """The decimal mark of a ``;`` / tab / whitespace file, decided from every numeric cell of
    ``samples`` (columns whose every cell is a number under one of the marks; text columns do
    not vote). Returns ``","`` when a cell is a decimal comma that no grouping explains (``1,25``,
    ``0,250``, ``998,5``) and nothing contradicts it, else ``"."`` when that reads every cell.

    Raises ReaderError (naming the column and a value) when the numbers cannot be read one way:
    digit grouping (``1,250`` beside ``998`` in one column: a decimal-comma writer gives
    ``998,000`` or ``1,25``; ``1,250,000``; ``1,250`` beside a decimal point; ``1.250`` beside a
    decimal comma), a decimal comma and a decimal point in one file, or only values like
    ``1,250`` that read as 1.25 or as 1250 with nothing to decide (rig.toml ``[read] decimal``
    then says which).
    """
    if delimiter in (",",):
        return "."
    by_column, names = _cells_by_column(delimiter, samples, header)
    return _decide_decimal(_decimal_evidence(by_column, names))


def _cells_by_column(delimiter: str, samples: list[str], header: str | None) -> tuple[dict[int, list[str]], list[str]]:
    """The non-null cells of ``samples`` by 0-based column, and the header's names (``[]``
    without a header), split at ``delimiter``."""
    if delimiter == "whitespace":
        table = [s.split() for s in samples]
        names = header.split() if header is not None else []
    else:
        table = [next(_csv.reader([s], delimiter=delimiter), []) for s in samples]
        names = next(_csv.reader([header], delimiter=delimiter), []) if header is not None else []
    by_column: dict[int, list[str]] = {}   # one pass over the cells (rows may differ in width)
    for r in table:
        for k, cell in enumerate(r):
            cell = cell.strip()
            if cell and cell not in _NULLS:
                by_column.setdefault(k, []).append(cell)
    return by_column, names


def _decimal_evidence(by_column: dict[int, list[str]], names: list[str]) -> dict[str, tuple[str, str]]:
    """What the numeric columns say of the decimal mark: evidence (``"comma decimal"``, ``"dot
    groups"``, ``"comma groups beside 998"``, ...) -> its first ``(value, column name)``."""
    first: dict[str, tuple[str, str]] = {}   # evidence -> (value, column)
    for k, cells in sorted(by_column.items()):
        if not all(_NUMBER_CELL.match(c) for c in cells):
            continue  # a text column (or an empty one): it does not vote
        column = (split_name_unit(names[k])[0] if k < len(names) and names[k].strip() else "") or str(k + 1)
        integer = next((c for c in cells if _INTEGER.match(c)), None)
        for c in cells:
            what = _cell_evidence(c, integer)
            if what is not None:
                first.setdefault(what, (c, column))
    return first


def _cell_evidence(c: str, integer: str | None) -> str | None:
    """What one numeric cell says of the decimal mark (None: nothing); ``integer`` is the first
    whole number of its column, if any."""
    comma, dot = "," in c, "." in c
    if comma and dot:
        return "both"
    if comma:
        if c.count(",") > 1:
            return "comma groups"
        if not _GROUPED[","].match(c):
            return "comma decimal"
        if integer is not None and c.endswith("0"):
            return "comma groups beside " + integer
        return "comma ambiguous"
    if dot:
        if c.count(".") > 1:
            return "dot groups"
        if not _GROUPED["."].match(c):
            return "dot decimal"
        return "dot ambiguous"
    return None


def _decide_decimal(first: dict[str, tuple[str, str]]) -> str:
    """The decimal mark the evidence of :func:`_decimal_evidence` allows, else a ReaderError
    naming the value and column that make the file ambiguous."""
    def at(what: str) -> str:
        value, column = first[what]
        return f"`{value}` in column `{column}`"

    unread = "digit grouping is not read; export the numbers without thousands separators"
    for what, sep in (("both", None), ("comma groups", ","), ("dot groups", ".")):
        if what in first:
            how = ("mixes `,` and `.`" if sep is None else f"groups thousands with `{sep}`")
            why = "" if sep is None else " (a decimal comma appears once in a number)" if sep == "," else \
                " (a decimal point appears once in a number)"
            raise ReaderError(f"{at(what)} {how}{why}: {unread}")
    if "comma decimal" in first and "dot decimal" in first:
        raise ReaderError(f"{at('comma decimal')} is a decimal comma but {at('dot decimal')} a decimal point: "
                          "the file mixes decimal marks; export it with one")
    if "comma decimal" in first:
        if "dot ambiguous" in first:
            raise ReaderError(f"{at('dot ambiguous')} groups thousands with `.` ({at('comma decimal')} is a "
                              f"decimal comma): {unread}")
        return ","
    ambiguous = first.get("comma ambiguous")
    beside = next((w for w in first if w.startswith("comma groups beside ")), None)
    if "dot decimal" in first and (ambiguous or beside):
        what = beside or "comma ambiguous"
        raise ReaderError(f"{at(what)} groups thousands with `,` ({at('dot decimal')} has a decimal point): {unread}")
    if beside is not None:
        integer = beside.rsplit(" ", 1)[1]
        as_decimal = f"{float(first[beside][0].replace(',', '.')):g}".replace(".", ",")
        raise ReaderError(f"{at(beside)} groups thousands with `,` (beside `{integer}` in the same column, a decimal "
                          f"comma would have given `{integer},000` or `{as_decimal}`): {unread}")
    if ambiguous is not None:
        value = ambiguous[0]
        raise ReaderError(f"{at('comma ambiguous')} reads as {float(value.replace(',', '.')):g} with a decimal "
                          f"comma or {value.replace(',', '')} with a thousands separator, and no number in the first "
                          "rows decides; set rig.toml [read] decimal = \",\" if it is a decimal comma, or export "
                          "without thousands separators")
    return "."


def _header_names(head: _Head, dialect: _Dialect, rows: list[list[str]]) -> list[str]:
    """The header's column names (``"1"``, ``"2"`` ... without a header); ``""`` for an
    unnamed column the rows fill with nothing but a trailing delimiter."""
    width = max((len(r) for r in rows), default=0)
    check_channel_count(width, "columns in the first data rows")
    if head.has_header:
        names = [h.strip() for h in dialect.split(head.header_line)]
        check_channel_count(len(names), "columns in the header")
        # Rows that end with a delimiter the header does not have: extra, unnamed columns.
        if width > len(names) and all(not f.strip() for row in rows for f in row[len(names):]):
            names += [""] * (width - len(names))
    else:
        names = [str(k + 1) for k in range(width)]
    if not names or all(not n for n in names):
        raise ReaderError("empty header row")
    return names


def _columns(names: list[str], rows: list[list[str]], has_header: bool,
             decimal: str) -> tuple[list[RawColumn], list[str]]:
    """The export's columns (unnamed empty ones left out) and the parser's names for every
    column of the file (``c1``, ``c2`` ...)."""
    columns: list[RawColumn] = []
    keys: list[str] = []
    for k, header in enumerate(names):
        key = f"c{k + 1}"
        keys.append(key)
        if has_header and not header:
            continue  # trailing delimiter: an unnamed, empty column
        name, unit = split_name_unit(header) if has_header else (header, None)
        values = [row[k].strip() for row in rows if k < len(row) and row[k].strip()]
        # A canonical channel is always numbers: a bad value is then reported with its line.
        numeric = canonical_name(name) is not None or all(_is_number(v, decimal) for v in values)
        dtype = "float" if numeric else "string"
        columns.append(RawColumn(key=key, name=name, unit=unit, index=k + 1, dtype=dtype,
                                 header=header if has_header else None))
    return columns, keys


def _batches(data: _Data) -> Iterator[pa.RecordBatch]:
    """The data as record batches; a parse error becomes a ReaderError naming the line."""
    if data.dialect.delimiter == "whitespace":
        try:
            yield from _whitespace_batches(data)
        except ReaderError:
            found = _find_bad_line(data)
            if found:
                raise ReaderError(found) from None
            raise
        return
    encoding, decimal = data.encoding, data.dialect.decimal
    ropts = pacsv.ReadOptions(skip_rows=data.lines_before, column_names=data.keys, block_size=BLOCK_BYTES,
                              encoding="utf8" if encoding.startswith("utf-8") else encoding)
    popts = pacsv.ParseOptions(delimiter=data.dialect.delimiter, invalid_row_handler=None)
    copts = pacsv.ConvertOptions(include_columns=[c.key for c in data.columns], decimal_point=decimal,
                                 column_types={c.key: pa.float64() if c.dtype == "float" else pa.string()
                                               for c in data.columns},
                                 strings_can_be_null=True)
    try:
        start = _data_offset(data.path, data.lines_before) if encoding.startswith("utf-8") else None
        if start is not None:  # the common case: parse blocks of lines in parallel
            yield from _parallel_batches(data.path, start, data.keys, popts, copts)
            return
        reader = pacsv.open_csv(data.path, read_options=ropts, parse_options=popts, convert_options=copts)
        for batch in reader:
            yield batch
    except pa.ArrowInvalid as exc:
        found = _find_bad_line(data)
        raise ReaderError(found or _explain_arrow_error(str(exc), data.lines_before)) from None


def _data_offset(path: Path, lines_before: int) -> int | None:
    """Byte offset of the first data line, or None when blocks cannot be cut at ``\\n`` safely
    (lines ending in a lone ``\\r``)."""
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
        if b"\r" in head.replace(b"\r\n", b""):
            return None
        fh.seek(0)
        for _ in range(lines_before):
            if not fh.readline():
                break
        offset = fh.tell()
    return 3 if offset == 0 and head.startswith(b"\xef\xbb\xbf") else offset


def _parallel_batches(path: Path, start: int, keys: list[str], popts, copts) -> Iterator[pa.RecordBatch]:
    """Parse the data from byte ``start`` in blocks of about :data:`BLOCK_BYTES` cut at line ends,
    one block per worker thread (pyarrow releases the GIL), yielded in file order.

    Memory stays bounded: at most ``workers + 1`` blocks are read ahead.
    """
    workers = max(1, min(4, os.cpu_count() or 1))

    def parse(block: bytes) -> pa.Table:
        ropts = pacsv.ReadOptions(column_names=keys, use_threads=False, block_size=len(block) + 1)
        return pacsv.read_csv(pa.BufferReader(block), read_options=ropts, parse_options=popts, convert_options=copts)

    def blocks() -> Iterator[bytes]:
        with open(path, "rb") as fh:
            fh.seek(start)
            rest = b""
            while data := fh.read(BLOCK_BYTES):
                data = rest + data if rest else data
                cut = data.rfind(b"\n") + 1
                if cut == 0:
                    if len(data) > MAX_LINE_BYTES:
                        raise ReaderError(f"a line longer than {MAX_LINE_BYTES >> 20} MiB (no line break from byte "
                                          f"{fh.tell() - len(data)}): not delimited text")
                    rest = data
                    continue
                rest = data[cut:]
                yield data[:cut]
            if rest.strip():
                yield rest

    pool = ThreadPoolExecutor(workers, thread_name_prefix="csv-parse")
    try:
        pending = []
        for block in blocks():
            pending.append(pool.submit(parse, block))
            if len(pending) > workers:
                yield from pending.pop(0).result().to_batches()
        for fut in pending:
            yield from fut.result().to_batches()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _whitespace_batches(data: _Data) -> Iterator[pa.RecordBatch]:
    """A whitespace-separated file's data through pandas' C parser, in chunks of 2**20 rows."""
    import pandas as pd   # only blank-separated files need it: kept off the import of every CSV worker

    columns, encoding = data.columns, data.encoding
    wanted = [c.key for c in columns]
    try:
        chunks = pd.read_csv(data.path, sep=r"\s+", header=None, names=data.keys, skiprows=data.lines_before,
                             usecols=wanted, dtype={c.key: "float64" if c.dtype == "float" else "string" for c in columns},
                             decimal=data.dialect.decimal, chunksize=1 << 20,
                             encoding="utf-8" if encoding.startswith("utf-8") else encoding, engine="c")
        for chunk in chunks:
            yield pa.RecordBatch.from_pandas(chunk, preserve_index=False)
    except (ValueError, pd.errors.ParserError) as exc:
        raise ReaderError(f"cannot parse data: {str(exc).splitlines()[0]}") from None


_NULLS = {"", "nan", "NaN", "NAN", "NA", "N/A", "null", "NULL", "-nan", "inf", "-inf", "Inf", "-Inf"}


def _is_number(text: str, decimal: str) -> bool:
    """Whether a cell is a number (or a null such as ``nan``) under the decimal mark."""
    if text in _NULLS:
        return True
    try:
        float(text.replace(",", ".") if decimal == "," else text)
        return True
    except ValueError:
        return False


def _find_bad_line(data: _Data) -> str | None:
    """Scan the data for the first row the parser refused: a bad number or a wrong field count.

    Only run after a parse error, so the normal path stays fast. Returns the one-line message
    naming the (1-based, physical) line, or None when nothing is found.
    """
    floats = [c for c in data.columns if c.dtype == "float"]
    width, decimal = len(data.keys), data.dialect.decimal
    enc = "utf-8-sig" if data.encoding.startswith("utf-8") else data.encoding
    with open(data.path, encoding=enc, errors="replace", newline=None) as fh:
        for lineno, line in enumerate(fh, start=1):
            if lineno <= data.lines_before:
                continue
            line = line.rstrip("\n")
            if not line.strip():
                continue
            fields = data.dialect.split(line)
            if len(fields) > width:
                return f"line {lineno}: {len(fields)} fields where the header has {width}: {line[:60]!r}"
            for c in floats:
                k = c.index - 1
                if k < len(fields):
                    v = fields[k].strip()
                    if v and not _is_number(v, decimal):
                        return f"line {lineno}: value {v!r} in column `{c.name}` is not a number"
    return None


def _explain_arrow_error(message: str, lines_before: int) -> str:
    """One line from a pyarrow CSV error, naming the column and the line where possible."""
    first = message.splitlines()[0]
    m = re.search(r"In CSV column #(\d+): Row #(\d+): CSV conversion error to double: invalid value '([^']*)'", message)
    if m:
        col, row, value = int(m.group(1)) + 1, int(m.group(2)), m.group(3)
        return f"value {value!r} in column {col} at line {row + lines_before} is not a number"
    m = re.search(r"Expected (\d+) columns, got (\d+): (.*)", first)
    if m:
        return f"a data row has {m.group(2)} fields where the header has {m.group(1)}: {m.group(3)[:60]!r}"
    return f"cannot parse data: {first}"
