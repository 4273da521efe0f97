"""Small-file generators for the CSV, LVM and MAT reader tests (no binaries committed).

* :func:`lvm_bytes` writes an LVM file the way LabVIEW's *Write To Measurement File* lays it
  out (file header, per-segment headers whose fields sit under their columns, the ``X_Value``
  / names / ``Comment`` column row, an empty X field per row when ``X_Columns = No``).
* :func:`mat_v5` saves with :func:`scipy.io.savemat` (v5; ``compress=True`` is the v7 layout).
* :func:`mat_v73` writes the HDF5 layout MATLAB uses for ``-v7.3`` (512-byte user block with
  the MATLAB text header, ``MATLAB_class`` attributes, arrays stored transposed, char arrays as
  uint16, structs as groups).
* :func:`mat_v5_with_object` writes a v5 file holding an MCOS object (a ``timetable``) as MATLAB
  does: an ``mxOPAQUE_CLASS`` matrix with the variable name, type system ``MCOS``, class name
  and the uint32 object reference ``[0xDD000000, 2, 1, 1, 1, 1]``, plus plain variables.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


# -- LVM -----------------------------------------------------------------------------------
@dataclass
class LvmSegment:
    """One call of Write To Measurement File: channels (name -> values) and their header."""

    channels: dict[str, list]
    units: dict[str, str] = field(default_factory=dict)
    x0: float = 0.0
    dt: float = 0.001
    x: list | None = None                 # explicit X values (X_Columns One / Multi)
    x_multi: dict[str, list] | None = None  # per-channel X values (X_Columns Multi)
    x_unit: str | None = None
    comments: dict[int, str] = field(default_factory=dict)   # row -> comment
    samples: int | None = None            # header's Samples (default: number of values)
    header: bool = True                   # False: rows appended without a new segment header


def _num(v, decimal: str) -> str:
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return ""
    text = repr(float(v))
    return text.replace(".", ",") if decimal == "," else text


def lvm_bytes(segments: list[LvmSegment], *, x_columns: str = "No", separator: str = "Tab", decimal: str = ".",
              description: str | None = None, date: str = "2026/01/02", time: str = "03:04:05.25",
              time_pref: str = "Relative", multi_headings: str = "Yes", encoding: str = "utf-8",
              eol: str = "\r\n") -> bytes:
    """An LVM file as LabVIEW writes it."""
    sep = "\t" if separator == "Tab" else ","
    lines = [f"LabVIEW Measurement{sep}", f"Writer_Version{sep}2", f"Reader_Version{sep}2",
             f"Separator{sep}{separator}", f"Decimal_Separator{sep}{decimal}", f"Multi_Headings{sep}{multi_headings}",
             f"X_Columns{sep}{x_columns}", f"Time_Pref{sep}{time_pref}", f"Operator{sep}bench"]
    if description is not None:
        lines.append(f'Description{sep}"{description}"' if "\n" in description else f"Description{sep}{description}")
    lines += [f"Date{sep}{date}", f"Time{sep}{time}", f"***End_of_Header***{sep}", sep]
    for seg in segments:
        names = list(seg.channels)
        n = max(len(v) for v in seg.channels.values())
        if x_columns == "Multi":
            cols = []
            for name in names:
                cols += ["X_Value", name]
        else:
            cols = ["X_Value", *names]
        cols.append("Comment")

        def per_channel(tag: str, value_of) -> str:
            cells = [tag]
            for c in cols[1:-1]:
                cells.append("" if c == "X_Value" else value_of(c))
            return sep.join(cells) + sep

        if seg.header:
            lines.append(f"Channels{sep}{len(names)}" + sep * (len(cols) - 2))
            lines.append(per_channel("Samples", lambda c: str(seg.samples if seg.samples is not None else
                                                              sum(v is not None for v in seg.channels[c]))))
            lines.append(per_channel("Date", lambda c: date))
            lines.append(per_channel("Time", lambda c: time))
            if seg.units:
                lines.append(per_channel("Y_Unit_Label", lambda c: seg.units.get(c, "")))
            if seg.x_unit:
                lines.append(per_channel("X_Unit_Label", lambda c: seg.x_unit))
            lines.append(per_channel("X_Dimension", lambda c: "Time"))
            lines.append(per_channel("X0", lambda c: _num(seg.x0, decimal)))
            lines.append(per_channel("Delta_X", lambda c: _num(seg.dt, decimal)))
            lines.append(f"***End_of_Header***{sep}" + sep * (len(cols) - 2))
            lines.append(sep.join(cols))
        for i in range(n):
            if x_columns == "No":
                cells = [""]
            elif x_columns == "One":
                cells = [_num(seg.x[i] if seg.x is not None else seg.x0 + i * seg.dt, decimal)]
            else:
                cells = []
            for name in names:
                v = seg.channels[name][i] if i < len(seg.channels[name]) else None
                if x_columns == "Multi":
                    xs = (seg.x_multi or {}).get(name)
                    cells.append(_num(xs[i] if xs is not None else seg.x0 + i * seg.dt, decimal))
                cells.append(_num(v, decimal))
            if i in seg.comments:
                cells.append(seg.comments[i])
            lines.append(sep.join(cells))
        lines.append(sep if seg is not segments[-1] else "")
    return eol.join(lines).encode(encoding)


# -- MAT -----------------------------------------------------------------------------------
def mat_v5(path: Path, variables: dict, compress: bool = False, oned_as: str = "column") -> Path:
    """A MAT v5 file (``compress=True``: the zlib-compressed v7 layout) via scipy."""
    from scipy.io import savemat

    savemat(path, variables, do_compression=compress, oned_as=oned_as)
    return path


_V73_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Fri Jan  2 03:04:05 2026 "
               b"HDF5 schema 1.00 .")


def mat_v73(path: Path, variables: dict, objects: dict[str, str] | None = None) -> Path:
    """A MAT v7.3 (HDF5) file laid out as MATLAB writes it.

    ``variables``: name -> numpy array / number / str / dict (struct). ``objects``: name ->
    MATLAB class of an object variable (e.g. ``{"tt": "timetable"}``), stored as MATLAB stores
    MCOS objects (uint32 reference with ``MATLAB_object_decode = 3``).
    """
    import h5py

    def put(parent, name, value):
        if isinstance(value, dict):
            g = parent.create_group(name)
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for k, v in value.items():
                put(g, k, v)
            return
        if isinstance(value, str):
            data = np.array([ord(ch) for ch in value], dtype=np.uint16).reshape(-1, 1)
            ds = parent.create_dataset(name, data=data)
            ds.attrs["MATLAB_class"] = np.bytes_("char")
            ds.attrs["MATLAB_int_decode"] = np.int32(2)
            return
        arr = np.asarray(value)
        if arr.ndim == 0:
            arr = arr.reshape(1, 1)
        elif arr.ndim == 1:
            arr = arr.reshape(-1, 1)        # MATLAB N x 1 column, stored transposed: (1, N)
        cls = {"f": "double", "i": "int32", "u": "uint32", "b": "logical"}[arr.dtype.kind]
        if arr.dtype == np.float32:
            cls = "single"
        elif arr.dtype.kind in "iu":
            cls = f"{'u' if arr.dtype.kind == 'u' else ''}int{arr.dtype.itemsize * 8}"
        data = arr.T.astype(np.uint8) if arr.dtype.kind == "b" else arr.T
        ds = parent.create_dataset(name, data=data)
        ds.attrs["MATLAB_class"] = np.bytes_(cls)
        if arr.dtype.kind == "b":
            ds.attrs["MATLAB_int_decode"] = np.int32(1)

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            put(f, name, value)
        for name, cls in (objects or {}).items():
            ds = f.create_dataset(name, data=np.array([[0xDD000000, 2, 1, 1, 1, 1]], dtype=np.uint32))
            ds.attrs["MATLAB_class"] = np.bytes_(cls)
            ds.attrs["MATLAB_object_decode"] = np.int32(3)
    header = _V73_HEADER.ljust(116, b" ") + b"\0" * 8 + struct.pack("<H", 0x0200) + b"IM"
    with open(path, "r+b") as fh:
        fh.write(header)
    return path


def _tag(mtype: int, data: bytes) -> bytes:
    return struct.pack("<II", mtype, len(data)) + data + b"\0" * ((-len(data)) % 8)


def _int8(text: str) -> bytes:
    return _tag(1, text.encode("ascii"))


def _v5_header() -> bytes:
    text = b"MATLAB 5.0 MAT-file, Platform: GLNXA64, Created on: Fri Jan  2 03:04:05 2026"
    return text.ljust(116, b" ") + b"\0" * 8 + struct.pack("<H", 0x0100) + b"IM"


def _v5_double(name: str, values) -> bytes:
    arr = np.asarray(values, dtype="<f8").reshape(-1)
    flags = _tag(6, struct.pack("<II", 6, 0))            # mxDOUBLE_CLASS
    dims = _tag(5, struct.pack("<2i", arr.size, 1))
    return _tag(14, flags + dims + _int8(name) + _tag(9, arr.tobytes()))


def _v5_opaque(name: str, classname: str) -> bytes:
    flags = _tag(6, struct.pack("<II", 17, 0))           # mxOPAQUE_CLASS
    ref = np.array([0xDD000000, 2, 1, 1, 1, 1], dtype="<u4")
    meta = _tag(14, _tag(6, struct.pack("<II", 13, 0)) + _tag(5, struct.pack("<2i", 6, 1)) + _int8("")
                + _tag(6, ref.tobytes()))               # mxUINT32_CLASS 6 x 1
    return _tag(14, flags + _int8(name) + _int8("MCOS") + _int8(classname) + meta)


def mat_v5_with_object(path: Path, name: str = "tt", classname: str = "timetable",
                       plain: dict[str, list] | None = None) -> Path:
    """A v5 MAT file holding a MATLAB object (MCOS, e.g. a timetable) and plain vectors."""
    body = _v5_opaque(name, classname)
    for k, v in (plain or {}).items():
        body += _v5_double(k, v)
    path.write_bytes(_v5_header() + body)
    return path


def mat_v5_compressed_zeros(path: Path, name: str = "x", n_bytes: int = 256 << 20,
                            dims: tuple[int, int] | None = None) -> Path:
    """A v7 (compressed) MAT file holding one double vector of ``n_bytes`` of zeros: zlib packs
    zeros about 1000:1, so a few hundred KB inflate to ``n_bytes`` (a decompression bomb).
    ``dims`` overrides the declared dimensions (default: ``n_bytes // 8`` x 1). The zeros are
    compressed a MiB at a time, never held in memory."""
    import zlib

    n = n_bytes // 8
    dims = dims or (n, 1)
    flags = _tag(6, struct.pack("<II", 6, 0))            # mxDOUBLE_CLASS
    head = flags + _tag(5, struct.pack("<2i", *dims)) + _int8(name)
    data_tag = struct.pack("<II", 9, n * 8)              # miDOUBLE, then the zeros
    matrix_tag = struct.pack("<II", 14, len(head) + 8 + n * 8)
    z = zlib.compressobj(1)
    parts = [z.compress(matrix_tag + head + data_tag)]
    chunk = bytes(1 << 20)
    left = n * 8
    while left:
        k = min(left, len(chunk))
        parts.append(z.compress(chunk[:k]))
        left -= k
    parts.append(z.flush())
    blob = b"".join(parts)
    path.write_bytes(_v5_header() + struct.pack("<II", 15, len(blob)) + blob)
    return path


def mat_v5_elements(path: Path, body: bytes) -> Path:
    """A v5 MAT file: the 128-byte header, then ``body`` (hand-built elements, see :func:`v5_tag`)."""
    path.write_bytes(_v5_header() + body)
    return path


def v5_tag(mtype: int, data: bytes, nbytes: int | None = None) -> bytes:
    """One v5 data element (tag + data, padded to 8 bytes); ``nbytes`` overrides the declared size."""
    pad = b"\0" * ((-len(data)) % 8)
    return struct.pack("<II", mtype, len(data) if nbytes is None else nbytes) + data + pad


def v5_double(name: str, values) -> bytes:
    """A miMATRIX element: a double N x 1 vector."""
    return _v5_double(name, values)


# -- spreadsheets ----------------------------------------------------------------------------
def xlsx_workbook(path: Path, sheets, meta: dict | None = None, extra=None) -> Path:
    """An ``.xlsx`` written with openpyxl: ``sheets`` maps sheet name -> rows (a plain list of
    rows is one sheet named ``run``); ``meta`` becomes a ``meta`` sheet of key / value rows;
    ``extra(workbook)`` may change anything else (a chart sheet, a second sheet) before saving."""
    import openpyxl

    if not isinstance(sheets, dict):
        sheets = {"run": sheets}
    wb = openpyxl.Workbook()
    wb.remove(wb.active)
    for name, rows in sheets.items():
        ws = wb.create_sheet(name)
        for r in rows:
            ws.append(r)
    if meta:
        ms = wb.create_sheet("meta")
        for k, v in meta.items():
            ms.append([k, v])
    if extra:
        extra(wb)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    wb.save(path)
    return path


# -- MDF bus logging -------------------------------------------------------------------------
#: The ``CAN_DataFrame`` structure of the ASAM MDF bus logging standard (classic CAN, 8 bytes).
CAN_DATAFRAME = np.dtype([("CAN_DataFrame.BusChannel", "<u1"), ("CAN_DataFrame.ID", "<u4"),
                          ("CAN_DataFrame.IDE", "<u1"), ("CAN_DataFrame.DLC", "<u1"),
                          ("CAN_DataFrame.DataLength", "<u1"), ("CAN_DataFrame.DataBytes", "(8,)u1"),
                          ("CAN_DataFrame.Dir", "<u1")])


def mdf_unfinalised(path: Path) -> Path:
    """Leave an uncompressed MDF 4.1x file as a logger leaves it when it never finalises it
    (CAN loggers write so by design): file identifier ``UnFinMF``, standard flags "update the
    cycle counters" and "update the length of the last DT block", every channel group's cycle
    counter 0 and every DT block's length only its 24-byte header. A reader must finalise it
    (asammdf does on opening: it writes the counters and lengths into the file it opened)."""
    data = bytearray(Path(path).read_bytes())
    assert data[:3] == b"MDF" and data[8:12] >= b"4.10", "an MDF 4.10+ file"
    data[0:8] = b"UnFinMF "
    data[60:62] = struct.pack("<H", 0x1 | 0x4)   # FLAG_UNFIN_UPDATE_CG_COUNTER | _LAST_DT_LENGTH
    pos = 64
    while pos + 24 <= len(data):
        block, length, links = data[pos:pos + 4], *struct.unpack_from("<QQ", data, pos + 8)
        if block == b"##CG":
            struct.pack_into("<Q", data, pos + 24 + 8 * links + 8, 0)      # cg_cycle_count
        elif block == b"##DT":
            struct.pack_into("<Q", data, pos + 8, 24)                      # dt length: header only
        pos += (length + 7) // 8 * 8 if block[:2] == b"##" and length >= 24 else 8
    Path(path).write_bytes(bytes(data))
    return Path(path)


def mf4_can_bus_log(path: Path, n_frames: int = 200, unfinalised: bool = True, error_frames: int = 0) -> Path:
    """A CAN bus log as a CAN logger writes it (MDF 4.11): one channel group of
    ``CAN_DataFrame`` records (bus channel, ID, IDE, DLC, data length, 8 data bytes, direction)
    with a CAN bus acquisition source, so the group carries the bus-event flags; the time
    stamps are the master. Two message IDs at 100 Hz whose bytes hold a counter and a ramp (the
    signals a DBC would describe). ``error_frames``: that many ``CAN_ErrorFrame`` records in a
    second group. ``unfinalised``: left as the logger leaves it (:func:`mdf_unfinalised`)."""
    from asammdf import MDF, Signal
    from asammdf.blocks.v4_blocks import SourceInformation
    from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS

    frames = np.zeros(n_frames, dtype=CAN_DATAFRAME)
    k = np.arange(n_frames)
    frames["CAN_DataFrame.BusChannel"] = 1
    frames["CAN_DataFrame.ID"] = np.where(k % 2 == 0, 0x18F, 0x2A0)
    frames["CAN_DataFrame.DLC"] = frames["CAN_DataFrame.DataLength"] = 8
    frames["CAN_DataFrame.DataBytes"][:, 0] = k % 256
    frames["CAN_DataFrame.DataBytes"][:, 1] = (k * 3) % 256
    frames["CAN_DataFrame.DataBytes"][:, 2] = k // 256
    m = MDF(version="4.11")
    m.append(Signal(frames, k * 0.005, name="CAN_DataFrame",
                    source=SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)),
             acq_name="CAN1")
    if error_frames:
        errors = np.zeros(error_frames, dtype=[(n.replace("DataFrame", "ErrorFrame"), *CAN_DATAFRAME.fields[n][:1])
                                               for n in CAN_DATAFRAME.names])
        m.append(Signal(errors, np.arange(error_frames) * 0.37, name="CAN_ErrorFrame",
                        source=SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN)), acq_name="CAN1")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    saved = Path(m.save(path, overwrite=True, compression=0))
    m.close()
    return mdf_unfinalised(saved) if unfinalised else saved
