"""CSV / TXT exports: ``# key: value`` metadata lines, a ``name[unit]`` header, then data.

* Delimiter detected among ``,`` ``;`` and tab (``rig.toml`` ``[read] delimiter`` overrides,
  and may say ``"whitespace"`` for runs of blanks).
* With ``;`` or tab, a decimal comma is detected from the first data rows (European
  spreadsheet exports); ``[read] decimal`` overrides.
* Files without a header are described by ``rig.toml`` (``header = false``; columns are then
  addressed by their 1-based index); ``skip_rows`` drops lines before the header / data.

Data is streamed with pyarrow's incremental CSV reader (bounded memory, multi-threaded
parsing); whitespace-separated files go through pandas' C parser in chunks.
"""
from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv

from pipeline.readers.base import RawColumn, RawExport, ReaderError, decode_text, parse_key_value, split_name_unit

FORMAT = "csv"
EXTENSIONS = (".csv", ".txt")

#: Bytes read to find metadata, header and the first data rows.
HEAD_BYTES = 1 << 16
#: Bytes per block of the streaming parser.
BLOCK_BYTES = 1 << 23

_DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "\\t": "\t", "whitespace": "whitespace", " ": "whitespace"}
_DECIMAL_COMMA = re.compile(r"^[+-]?\d+,\d+([eE][+-]?\d+)?$")


def _head_lines(path: Path) -> tuple[list[str], str, bool]:
    with open(path, "rb") as fh:
        data = fh.read(HEAD_BYTES)
        complete = len(data) < HEAD_BYTES
    text, encoding = decode_text(data)
    lines = text.splitlines()
    if not complete and lines:
        lines = lines[:-1]  # the last line may be cut
    return lines, encoding, complete


def _detect_delimiter(header: str, samples: list[str]) -> str:
    best, best_score = ",", -1
    for cand in (",", ";", "\t"):
        n = header.count(cand)
        if n == 0:
            continue
        consistent = sum(1 for s in samples if s.count(cand) == n)
        score = n + 1000 * consistent
        if score > best_score:
            best, best_score = cand, score
    return best


def _detect_decimal(delimiter: str, samples: list[str]) -> str:
    if delimiter in (",",):
        return "."
    fields = [f.strip() for s in samples for f in (s.split() if delimiter == "whitespace" else s.split(delimiter))]
    if any(_DECIMAL_COMMA.match(f) for f in fields):
        return ","
    return "."


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
    lines, encoding, complete = _head_lines(path)
    metadata: dict[str, str] = {}
    i = 0
    # Leading "# key: value" lines (blank lines between them are allowed).
    while i < len(lines) and (lines[i].lstrip().startswith("#") or not lines[i].strip()):
        kv = parse_key_value(lines[i].lstrip()[1:]) if lines[i].lstrip().startswith("#") else None
        if kv:
            metadata[kv[0]] = kv[1]
        i += 1
    skip = int(read.get("skip_rows", 0) or 0)
    i += skip
    has_header = bool(read.get("header", True))
    if i >= len(lines):
        raise ReaderError("no header or data rows" if complete else f"no header within the first {HEAD_BYTES} bytes")

    delim_opt = read.get("delimiter")
    if delim_opt is not None and delim_opt not in _DELIMITERS:
        raise ReaderError(f"rig.toml delimiter {delim_opt!r} is not one of ',' ';' '\\t' 'whitespace'")
    header_line = lines[i] if has_header else None
    data_start = i + 1 if has_header else i
    samples = [ln for ln in lines[data_start:data_start + 20] if ln.strip()]
    delimiter = _DELIMITERS[delim_opt] if delim_opt is not None else _detect_delimiter(header_line or samples[0] if samples else "", samples)
    decimal = read.get("decimal") or _detect_decimal(delimiter, samples)
    if decimal not in (".", ","):
        raise ReaderError(f"rig.toml decimal {decimal!r} is not '.' or ','")
    if decimal == "," and delimiter == ",":
        raise ReaderError("decimal comma with a comma delimiter cannot be parsed")

    def split(line: str) -> list[str]:
        return line.split() if delimiter == "whitespace" else line.split(delimiter)

    if has_header:
        names = [h.strip() for h in split(header_line)]
    else:
        width = max((len(split(s)) for s in samples), default=0)
        names = [str(k + 1) for k in range(width)]
    if not names or all(not n for n in names):
        raise ReaderError("empty header row")

    columns: list[RawColumn] = []
    keys: list[str] = []
    for k, header in enumerate(names):
        key = f"c{k + 1}"
        keys.append(key)
        if has_header and not header:
            continue  # trailing delimiter: an unnamed, empty column
        name, unit = split_name_unit(header) if has_header else (header, None)
        values = [row[k].strip() for row in map(split, samples) if k < len(row) and row[k].strip()]
        dtype = "float" if all(_is_number(v, decimal) for v in values) else "string"
        columns.append(RawColumn(key=key, name=name, unit=unit, index=k + 1, dtype=dtype))
    # Physical lines before the first data row (comment lines, skipped rows, header).
    lines_before = data_start

    def batches() -> Iterator[pa.RecordBatch]:
        if delimiter == "whitespace":
            yield from _whitespace_batches(path, keys, columns, lines_before, encoding, decimal)
            return
        ropts = pacsv.ReadOptions(skip_rows=lines_before, column_names=keys, block_size=BLOCK_BYTES,
                                  encoding="utf8" if encoding.startswith("utf-8") else encoding)
        popts = pacsv.ParseOptions(delimiter=delimiter, invalid_row_handler=None)
        copts = pacsv.ConvertOptions(include_columns=[c.key for c in columns], decimal_point=decimal,
                                     column_types={c.key: pa.float64() if c.dtype == "float" else pa.string()
                                                   for c in columns},
                                     strings_can_be_null=True)
        try:
            reader = pacsv.open_csv(path, read_options=ropts, parse_options=popts, convert_options=copts)
            for batch in reader:
                yield batch
        except pa.ArrowInvalid as exc:
            raise ReaderError(_explain_arrow_error(str(exc), lines_before)) from None

    return RawExport(format=FORMAT, columns=columns, metadata=metadata, batches=batches)


def _whitespace_batches(path, keys, columns, lines_before, encoding, decimal) -> Iterator[pa.RecordBatch]:
    import pandas as pd

    wanted = [c.key for c in columns]
    try:
        chunks = pd.read_csv(path, sep=r"\s+", header=None, names=keys, skiprows=lines_before,
                             usecols=wanted, dtype={c.key: "float64" if c.dtype == "float" else "string" for c in columns}, decimal=decimal, chunksize=1 << 20,
                             encoding="utf-8" if encoding.startswith("utf-8") else encoding, engine="c")
        for chunk in chunks:
            yield pa.RecordBatch.from_pandas(chunk, preserve_index=False)
    except (ValueError, pd.errors.ParserError) as exc:
        raise ReaderError(f"cannot parse data: {str(exc).splitlines()[0]}") from None


_NULLS = {"", "nan", "NaN", "NAN", "NA", "N/A", "null", "NULL", "-nan", "inf", "-inf", "Inf", "-Inf"}


def _is_number(text: str, decimal: str) -> bool:
    if text in _NULLS:
        return True
    try:
        float(text.replace(",", ".") if decimal == "," else text)
        return True
    except ValueError:
        return False


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
