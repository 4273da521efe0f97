"""Writers: a run's SI samples as a bench export (CSV/TXT, LVM, TDMS, MAT, XLSX, MF4), per bench-exports.md.

Every writer takes the samples as one DataFrame or an iterable of DataFrames (chunks, for
GB-scale runs) whose columns are warehouse column names in SI (``p_a_pa``, ``x_m`` ...), a list of
:class:`ColumnOut` saying under which raw name and unit each column is exported, and the run
metadata to embed (``None``: nothing embedded, the manifest carries it). Values are converted
from SI to the raw unit with the exact inverse of :meth:`schemas.units.Unit.to_si` and written
with the shortest text that round-trips, so ingest gives back the SI values to float precision.
Columns that are not canonical (e.g. ``temperature_degc`` exported as ``temperature[degC]``) are
written as they are: ingest keeps them unconverted under ``<sanitised name>_<unit suffix>``, with
their unit recorded.

A format's layout is given by keyword (``write_csv(path, data, columns, meta, delimiter=";")``):
the keywords are the fields of its options dataclass (:class:`CsvOptions`, :class:`LvmOptions`,
:class:`TdmsOptions`), so the campaign's variants can keep them as plain dicts.
"""
from __future__ import annotations

import io
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv
from asammdf import MDF, Signal
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
from scipy.io import savemat

from schemas.channels import CHANNELS
from schemas.units import P_ATM_DEFAULT_PA, lookup_unit


@dataclass(frozen=True)
class ColumnOut:
    """How one samples column is exported: ``column`` (warehouse name) as ``name[unit]``."""

    column: str
    name: str
    unit: str


_BY_COLUMN = {c.column: c for c in CHANNELS.values()}


def default_columns(columns: Iterable[str], units: dict[str, str] | None = None,
                    names: dict[str, str] | None = None) -> list[ColumnOut]:
    """Export columns under their canonical channel names; ``units``/``names`` by channel override.

    A column that is no canonical channel's (e.g. ``temperature``) is its own channel name and
    needs its unit in ``units``; its values are exported unconverted.
    """
    units, names = units or {}, names or {}
    out = []
    for col in columns:
        ch = _BY_COLUMN.get(col)
        if ch is None:
            if col not in units:
                raise ValueError(f"column {col!r} is not canonical: give its unit in `units`")
            out.append(ColumnOut(col, names.get(col, col), units[col]))
        else:
            out.append(ColumnOut(col, names.get(ch.name, ch.name), units.get(ch.name, ch.si_unit)))
    return out


def si_to_raw(values, unit: str, p_atm_pa: float = P_ATM_DEFAULT_PA) -> np.ndarray:
    """The exact inverse of ``Unit.to_si``: SI (gauge) values in the raw ``unit``."""
    u = lookup_unit(unit)
    if u is None:
        raise ValueError(f"unit {unit!r} is not an accepted unit")
    v = np.asarray(values, dtype=float)
    if u.absolute:
        v = v + p_atm_pa
    div = u.divisor
    if div:
        return v * div
    return v / u.scale if u.scale != 1.0 else v


def _raw_values(frame: pd.DataFrame, c: ColumnOut, p_atm_pa: float) -> np.ndarray:
    """A column's values in its raw unit (non-canonical columns: as they are)."""
    if c.column not in _BY_COLUMN:
        return np.asarray(frame[c.column].to_numpy(), dtype=float)
    return si_to_raw(frame[c.column].to_numpy(), c.unit, p_atm_pa)


def _frames(data) -> Iterator[pd.DataFrame]:
    if isinstance(data, pd.DataFrame):
        yield data
    else:
        yield from data


def _raw_table(frame: pd.DataFrame, columns: list[ColumnOut], p_atm_pa: float) -> pa.Table:
    return pa.table({f"c{i}": _raw_values(frame, c, p_atm_pa) for i, c in enumerate(columns)})


def _text_block(table: pa.Table, delimiter: str, decimal: str = ".") -> bytes:
    buf = io.BytesIO()
    pacsv.write_csv(table, buf, write_options=pacsv.WriteOptions(include_header=False, delimiter=delimiter,
                                                                  quoting_style="none"))
    data = buf.getvalue()
    if decimal == ",":
        data = data.replace(b".", b",")
    return data


def meta_text(value) -> str:
    """A metadata value as the text a file header carries."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return repr(value)
    return str(value)


@dataclass(frozen=True)
class CsvOptions:
    """How :func:`write_csv` lays out a text export.

    ``decimal=","`` needs ``delimiter`` ``;`` or tab (European spreadsheet export).
    ``header=False`` writes data only (``rig.toml`` must describe the columns). ``p_atm_pa``:
    the atmosphere absolute units are written against [Pa].
    """

    delimiter: str = ","
    decimal: str = "."
    header: bool = True
    p_atm_pa: float = P_ATM_DEFAULT_PA
    newline: str = "\n"


def write_csv(path, data, columns: list[ColumnOut], metadata: dict | None = None, **options) -> Path:
    """CSV / TXT: ``# key: value`` metadata lines, a ``name[unit]`` header row, data.

    ``options`` are the fields of :class:`CsvOptions` (``delimiter``, ``decimal``, ``header``,
    ``p_atm_pa``, ``newline``).
    """
    o = CsvOptions(**options)
    if o.decimal == "," and o.delimiter == ",":
        raise ValueError("a decimal comma needs ';' or tab as delimiter")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        head = []
        if metadata:
            head += [f"# {k}: {meta_text(v)}" for k, v in metadata.items()]
        if o.header:
            head.append(o.delimiter.join(f"{c.name}[{c.unit}]" for c in columns))
        if head:
            fh.write((o.newline.join(head) + o.newline).encode("utf-8"))
        for frame in _frames(data):
            block = _text_block(_raw_table(frame, columns, o.p_atm_pa), o.delimiter, o.decimal)
            if o.newline != "\n":
                block = block.replace(b"\n", o.newline.encode())
            fh.write(block)
    return path


def _lvm_number(v: float) -> str:
    return f"{v:.16E}".replace("E+00", "E+0").replace("E-00", "E-0")


@dataclass(frozen=True)
class LvmOptions:
    """How :func:`write_lvm` lays out an LVM file.

    ``x_columns="One"`` writes the time column ``X_Value`` (needs a ``t_s`` column, not in
    ``columns``); ``"No"`` leaves the X field of every row empty, as LabVIEW does (time from
    ``X0`` + k ``Delta_X``; give ``fs_hz`` [Hz]). ``segments`` splits the samples into that many
    segments, each with its own header. ``date`` (``YYYY/MM/DD``) and ``time`` are the headers'
    start; ``p_atm_pa``: the atmosphere absolute units are written against [Pa].
    """

    x_columns: str = "One"
    segments: int = 1
    p_atm_pa: float = P_ATM_DEFAULT_PA
    date: str = "2025/03/03"
    time: str = "08:00:00.000000"
    fs_hz: float | None = None


def write_lvm(path, data, columns: list[ColumnOut], metadata: dict | None = None, **options) -> Path:
    """LVM as LabVIEW's *Write To Measurement File* writes it (tab separated, ``.`` decimal).

    The file header's ``Description`` carries the metadata as ``key=value`` pairs joined by
    ``;``. ``options`` are the fields of :class:`LvmOptions` (``x_columns``, ``segments``,
    ``p_atm_pa``, ``date``, ``time``, ``fs_hz``).
    """
    o = LvmOptions(**options)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = pd.concat(list(_frames(data)), ignore_index=True)
    n = len(frame)
    t = frame["t_s"].to_numpy()
    dt = (1.0 / o.fs_hz) if o.fs_hz else (float(np.round(1.0 / np.median(np.diff(t)), 6)) ** -1 if n > 1 else 1.0)
    bounds = np.linspace(0, n, o.segments + 1).round().astype(int)
    with open(path, "wb") as fh:
        fh.write(_lvm_file_header(metadata, o))
        for s in range(o.segments):
            a, b = int(bounds[s]), int(bounds[s + 1])
            part = frame.iloc[a:b]
            x0 = float(t[a]) if b > a else 0.0
            fh.write(_lvm_segment_header(columns, b - a, x0, dt, o))
            fh.write(_lvm_rows(part, columns, o))
            if s + 1 < o.segments:
                fh.write(b"\r\n")
    return path


def _lvm_file_header(metadata: dict | None, o: LvmOptions) -> bytes:
    """The LVM file header, metadata in its ``Description``, up to the first segment."""
    lines = ["LabVIEW Measurement\t", "Writer_Version\t2", "Reader_Version\t2", "Separator\tTab",
             "Decimal_Separator\t.", "Multi_Headings\tNo", f"X_Columns\t{o.x_columns}", "Time_Pref\tRelative",
             f"Operator\t{(metadata or {}).get('operator', 'lab')}", f"Date\t{o.date}", f"Time\t{o.time}"]
    if metadata:
        lines.append("Description\t" + ";".join(f"{k}={meta_text(v)}" for k, v in metadata.items()))
    lines += ["***End_of_Header***", "\t"]
    return ("\r\n".join(lines) + "\r\n").encode("utf-8")


def _lvm_segment_header(columns: list[ColumnOut], n: int, x0: float, dt: float, o: LvmOptions) -> bytes:
    """A segment's header: ``n`` samples per channel from ``x0`` [s] every ``dt`` [s], the names row."""
    nch = len(columns)
    rep = lambda v: "\t".join([v] * nch)  # noqa: E731
    seg = [f"Channels\t{nch}\t", "Samples\t" + rep(str(n)), "Date\t" + rep(o.date), "Time\t" + rep(o.time),
           "Y_Unit_Label\t" + "\t".join(c.unit for c in columns), "X_Dimension\t" + rep("Time"),
           "X_Unit_Label\t" + rep("s"), "X0\t" + rep(_lvm_number(x0)), "Delta_X\t" + rep(repr(dt)),
           "***End_of_Header***"]
    names = "\t".join(c.name for c in columns)
    seg.append("X_Value\t" + names + "\tComment")
    return ("\r\n".join(seg) + "\r\n").encode("utf-8")


def _lvm_rows(part: pd.DataFrame, columns: list[ColumnOut], o: LvmOptions) -> bytes:
    """A segment's data rows (CRLF), with the time as ``X_Value`` or the X field left empty."""
    table = _raw_table(part, columns, o.p_atm_pa)
    if o.x_columns == "One":
        table = pa.table([pa.array(part["t_s"].to_numpy())] + table.columns,
                         names=["t"] + table.column_names)
        return _text_block(table, "\t").replace(b"\n", b"\r\n")
    # LabVIEW leaves the X field of every data row empty
    block = _text_block(table, "\t")
    if block:
        return b"\t" + block[:-1].replace(b"\n", b"\r\n\t") + b"\r\n"
    return b""


def _tdms_value(v):
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return float(v)
    return v


@dataclass(frozen=True)
class TdmsOptions:
    """How :func:`write_tdms` lays out a TDMS file.

    ``group``: the data group's name. ``waveform=True`` writes no time channel:
    ``wf_increment`` = 1/``fs_hz`` [Hz] and ``wf_start_offset`` = 0 carry the timing.
    ``extra_group`` adds a second group (a settings log) before the data group; the metadata then
    needs ``group`` naming the data group. ``p_atm_pa``: the atmosphere absolute units are written
    against [Pa].
    """

    group: str = "Data"
    waveform: bool = False
    fs_hz: float | None = None
    extra_group: str | None = None
    p_atm_pa: float = P_ATM_DEFAULT_PA


def write_tdms(path, data, columns: list[ColumnOut], metadata: dict | None = None, **options) -> Path:
    """TDMS with nptdms: metadata as root properties, ``unit_string`` per channel.

    Each chunk of ``data`` becomes one TDMS segment (bounded memory). ``options`` are the fields
    of :class:`TdmsOptions` (``group``, ``waveform``, ``fs_hz``, ``extra_group``, ``p_atm_pa``).
    """
    o = TdmsOptions(**options)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    first = True
    with TdmsWriter(str(path)) as writer:
        for frame in _frames(data):
            objs = _tdms_head(metadata, o) if first else []
            if not o.waveform:
                props = {"unit_string": "s"} if first else {}
                objs.append(ChannelObject(o.group, "t", frame["t_s"].to_numpy(), properties=props))
            for c in columns:
                props = {}
                if first:
                    props = {"unit_string": c.unit}
                    if o.waveform:
                        props.update(wf_increment=1.0 / o.fs_hz, wf_start_offset=0.0, wf_samples=len(frame))
                objs.append(ChannelObject(o.group, c.name, _raw_values(frame, c, o.p_atm_pa), properties=props))
            writer.write_segment(objs)
            first = False
    return path


def _tdms_head(metadata: dict | None, o: TdmsOptions) -> list:
    """The first segment's root (the metadata), the settings group if any, and the data group."""
    objs = [RootObject(properties={k: _tdms_value(v) for k, v in (metadata or {}).items()})]
    if o.extra_group:
        objs.append(GroupObject(o.extra_group, properties={"description": "valve settings"}))
        objs.append(ChannelObject(o.extra_group, "valve_gain", np.array([1.0, 1.0]),
                                  properties={"unit_string": "V"}))
    objs.append(GroupObject(o.group, properties={}))
    return objs


def write_mat(path, data, columns: list[ColumnOut], metadata: dict | None = None, *, scalars: bool = False,
              p_atm_pa: float = P_ATM_DEFAULT_PA, include_time: bool = True) -> Path:
    """MAT v5 (scipy.io.savemat): one N x 1 double per channel, ``meta`` and ``units`` structs.

    ``scalars=True`` stores numeric metadata as top-level scalars instead of ``meta`` fields.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = pd.concat(list(_frames(data)), ignore_index=True)
    out: dict = {}
    units: dict = {}
    if include_time:
        out["t"] = frame["t_s"].to_numpy().reshape(-1, 1)
        units["t"] = "s"
    for c in columns:
        out[c.name] = _raw_values(frame, c, p_atm_pa).reshape(-1, 1)
        units[c.name] = c.unit
    meta = {}
    for k, v in (metadata or {}).items():
        if scalars and isinstance(v, (int, float)) and not isinstance(v, bool):
            out[k] = float(v)
        else:
            meta[k] = v
    if meta:
        out["meta"] = meta
    out["units"] = units
    buf = io.BytesIO()
    savemat(buf, out, do_compression=True, oned_as="column")
    blob = bytearray(buf.getvalue())
    # The v5 header's 116 text bytes carry the creation time: fix them so output is reproducible.
    text = b"MATLAB 5.0 MAT-file, Platform: pneubench simulator"
    blob[:116] = text.ljust(116, b" ")
    path.write_bytes(bytes(blob))
    return path


def _xml_cell(ref: str, v) -> str:
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        return f'<c r="{ref}"><v>{float(v)!r}</v></c>' if np.isfinite(v) else ""
    return f'<c r="{ref}" t="inlineStr"><is><t>{escape(str(v))}</t></is></c>'


def _col_letters(j: int) -> str:
    out = ""
    j += 1
    while j:
        j, r = divmod(j - 1, 26)
        out = chr(65 + r) + out
    return out


def _sheet_xml(rows: Iterable[list]) -> bytes:
    body = []
    for i, row in enumerate(rows, start=1):
        cells = "".join(_xml_cell(f"{_col_letters(j)}{i}", v) for j, v in enumerate(row) if v is not None)
        body.append(f'<row r="{i}">{cells}</row>')
    return ('<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<worksheet xmlns='
            '"http://schemas.openxmlformats.org/spreadsheetml/2006/main"><sheetData>'
            + "".join(body) + "</sheetData></worksheet>").encode("utf-8")


def write_xlsx(path, data, columns: list[ColumnOut], metadata: dict | None = None, *, units_row: bool = False,
               p_atm_pa: float = P_ATM_DEFAULT_PA) -> Path:
    """XLSX as a spreadsheet program saves it: sheet ``run`` with a header row (``name[unit]``, or
    names with a units row under them when ``units_row``), metadata in a sheet ``meta``.

    Written directly as Office Open XML (a zip of a few XML parts) with fixed zip time stamps,
    so the same run gives the same bytes. Excel holds at most 1,048,576 rows per sheet.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = pd.concat(list(_frames(data)), ignore_index=True)
    if len(frame) + 2 > 1_048_576:
        raise ValueError(f"{len(frame)} rows do not fit in one Excel sheet")
    table = _raw_table(frame, columns, p_atm_pa)
    arrays = [frame["t_s"].to_numpy()] + [table.column(i).to_numpy() for i in range(table.num_columns)]
    names = ["t"] + [c.name for c in columns]
    units = ["s"] + [c.unit for c in columns]
    head = [names, units] if units_row else [[f"{n}[{u}]" for n, u in zip(names, units)]]
    rows = head + [list(r) for r in zip(*arrays)]
    sheets = [("run", _sheet_xml(rows))]
    if metadata:
        sheets.append(("meta", _sheet_xml([[k, v if isinstance(v, (int, float)) else str(v)]
                                            for k, v in metadata.items()])))
    ns = "http://schemas.openxmlformats.org"
    parts = {
        "[Content_Types].xml": (
            '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<Types xmlns="' + ns + '/package/2006/content-types">'
            '<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
            '<Default Extension="xml" ContentType="application/xml"/>'
            '<Override PartName="/xl/workbook.xml" ContentType="application/vnd.openxmlformats-officedocument.'
            'spreadsheetml.sheet.main+xml"/>'
            + "".join(f'<Override PartName="/xl/worksheets/sheet{i}.xml" ContentType="application/vnd.openxmlformats-'
                      'officedocument.spreadsheetml.worksheet+xml"/>' for i in range(1, len(sheets) + 1))
            + "</Types>"),
        "_rels/.rels": (
            '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<Relationships xmlns="' + ns
            + '/package/2006/relationships"><Relationship Id="rId1" Type="' + ns
            + '/officeDocument/2006/relationships/officeDocument" Target="xl/workbook.xml"/></Relationships>'),
        "xl/workbook.xml": (
            '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<workbook xmlns="' + ns
            + '/spreadsheetml/2006/main" xmlns:r="' + ns + '/officeDocument/2006/relationships"><sheets>'
            + "".join(f'<sheet name="{n}" sheetId="{i}" r:id="rId{i}"/>' for i, (n, _) in enumerate(sheets, 1))
            + "</sheets></workbook>"),
        "xl/_rels/workbook.xml.rels": (
            '<?xml version="1.0" encoding="UTF-8" standalone="yes"?>\n<Relationships xmlns="' + ns
            + '/package/2006/relationships">'
            + "".join(f'<Relationship Id="rId{i}" Type="' + ns + '/officeDocument/2006/relationships/worksheet" '
                      f'Target="worksheets/sheet{i}.xml"/>' for i in range(1, len(sheets) + 1))
            + "</Relationships>"),
    }
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, text in parts.items():
            zf.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), text.encode("utf-8"),
                        compress_type=zipfile.ZIP_DEFLATED)
        for i, (_, xml) in enumerate(sheets, 1):
            zf.writestr(zipfile.ZipInfo(f"xl/worksheets/sheet{i}.xml", date_time=(1980, 1, 1, 0, 0, 0)), xml,
                        compress_type=zipfile.ZIP_DEFLATED)
    return path


def write_mf4(path, data, columns: list[ColumnOut], metadata: dict | None = None, *, group: str = "Data",
              p_atm_pa: float = P_ATM_DEFAULT_PA) -> Path:
    """ASAM MDF 4.10 with asammdf: one channel group (acquisition name ``group``), the time as its
    master channel, metadata as MDF 4 ``common_properties`` of the header comment, ``started_at`` as the
    header's start time. The file history's time stamp is set to the start time too, so the same
    run gives the same bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    frame = pd.concat(list(_frames(data)), ignore_index=True)
    t = frame["t_s"].to_numpy()
    sigs = [Signal(_raw_values(frame, c, p_atm_pa), t, name=c.name, unit=c.unit) for c in columns]
    meta = dict(metadata or {})
    start = datetime(2000, 1, 1, tzinfo=timezone.utc)
    if meta.get("started_at"):
        start = datetime.fromisoformat(str(meta["started_at"])).replace(tzinfo=timezone.utc)
    mdf = MDF(version="4.10")
    mdf.header.start_time = start
    mdf.header.comment = ("<HDcomment><TX>pneubench simulator</TX><common_properties>"
                          + "".join(f"<e name={quoteattr(str(k))}>{escape(meta_text(v))}</e>" for k, v in meta.items())
                          + "</common_properties></HDcomment>")
    mdf.append(sigs, acq_name=group, comment="")
    mdf.save(path, overwrite=True)
    mdf.close()
    blob = bytearray(path.read_bytes())
    fh = blob.find(b"##FH")  # FH block: 24-byte header, 2 links, then fh_time_ns
    if fh >= 0:
        blob[fh + 40:fh + 48] = int(start.timestamp() * 1e9).to_bytes(8, "little")
    path.write_bytes(bytes(blob))
    return path

