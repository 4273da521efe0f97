"""MAT exports: MATLAB v5 / v7 (``scipy.io.loadmat``) and v7.3 (HDF5, ``h5py``).

* Every numeric (or logical) vector, N x 1 or 1 x N with N > 1, is a channel named after its
  variable; all channels must have the same length (else the file is refused, naming the
  lengths). Matrices, cell arrays, complex arrays and structs other than ``meta`` / ``units``
  are not channels: they are skipped with a warning.
* A numeric 2-D array of N x k or k x N (k <= :data:`MAX_MATRIX_CHANNELS`, N > k) is k
  channels ``<name>_1`` .. ``<name>_k`` (the long side is time); ``units.<name>`` gives all k
  their unit unless ``units.<name>_<j>`` says otherwise.
* Numeric scalars, char arrays and the fields of a struct ``meta`` are run metadata (char
  arrays become text; whole-number doubles become integers, since MATLAB stores every number
  as a double). A scalar ``Fs`` / ``fs`` / ``sample_rate_hz`` [Hz] or ``dt`` [s] is the time base
  of a file without a ``t`` vector (applied by :func:`pipeline.ingest.file.resolve_time_base`).
* A struct ``units`` maps a channel name to its unit text (``units.x = 'mm'``). A channel
  without a unit has unit None: ingest rejects it when the channel is canonical.
* MATLAB objects (``timetable``, ``table``, ``string``, ``datetime``, ...) are MCOS objects
  whose data sit in an undocumented subsystem: they are refused with a one-line message that
  says how to re-export them as plain vectors in MATLAB (``table2struct`` / ``timetable2table``
  and ``save(file, '-struct', 's', '-v7')``). This holds for v5/v7 (``loadmat`` returns them as
  ``MatlabOpaque``) and v7.3 (datasets with ``MATLAB_object_decode``).
* v7.3: MATLAB stores arrays transposed (an N x 1 vector is a 1 x N dataset), chars as uint16
  and structs as groups; ``#refs#`` / ``#subsystem#`` are MATLAB's bookkeeping. Channels are
  read in slices, so a large v7.3 file streams in bounded memory; v5/v7 files are loaded whole
  by scipy (the format has no partial reads) and then yielded in batches.
* Untrusted bytes: before scipy sees a v5/v7 file, :func:`check_v5` walks its elements
  (compressed ones inflated in 1 MiB steps and dropped) and refuses a file that inflates to more
  than :func:`pipeline.readers.base.inflate_cap` of its size (a decompression bomb), declares
  sizes or dimensions its bytes cannot hold, nests arrays too deep, uses unknown data types or
  arrays that lack the parts their class announces (scipy allocates what a file declares and
  crashes on some malformed arrays). v7.3 datasets are checked the same way (shape x item
  size against the cap) before they are read, and HDF5 links are never followed.
"""
from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import (INFLATE_CEILING_BYTES, INFLATE_FLOOR_BYTES, MAX_INFLATE_RATIO, RawColumn,
                                   RawExport, ReaderError, check_channel_count, inflate_cap, mib)

FORMAT = "mat"
EXTENSIONS = (".mat",)

#: Rows per record batch.
BATCH_ROWS = 1 << 18
#: Most columns (or rows) of a 2-D array read as that many channels.
MAX_MATRIX_CHANNELS = 16

_NUMERIC_CLASSES = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
                    "logical"}


def reexport_hint(name: str, cls: str, stem: str) -> str:
    """One line: how to re-export a MATLAB object variable as plain vectors (in MATLAB)."""
    save = f"save('{stem}.mat', '-struct', 's', '-v7')"
    if cls == "timetable":
        how = (f"s = table2struct(timetable2table({name}, 'ConvertRowTimes', false), 'ToScalar', true); "
               f"s.t = seconds({name}.Properties.RowTimes - {name}.Properties.RowTimes(1)); "
               f"s.units = struct('t', 's'); {save}")
    elif cls == "table":
        how = f"s = table2struct({name}, 'ToScalar', true); s.units = struct('t', 's'); {save}"
    else:
        how = (f"convert `{name}` to numeric vectors, numbers or char arrays (e.g. double(...), char(...)) "
               f"and save(..., '-v7')")
    return (f"MATLAB {cls} object `{name}` can only be read by MATLAB; re-export it in MATLAB as plain vectors: "
            f"{how} (add each channel's unit to s.units)")


def _is_v73(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(128)
        fh.seek(512)
        sig = fh.read(8)
    return sig == b"\x89HDF\r\n\x1a\n" or head.startswith(b"\x89HDF") or (
        head[:10] == b"MATLAB 7.3" and len(head) >= 128)


def _scalar(v):
    """numpy / MATLAB scalar -> plain Python value (whole-number doubles -> int)."""
    if isinstance(v, np.ndarray):
        v = v.item() if v.size == 1 else [_scalar(x) for x in v.ravel().tolist()]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and v.is_integer() and abs(v) < 2 ** 53:
        return int(v)
    return v


class _Collect:
    """Channels, metadata, units and warnings gathered from the variables of a file."""

    def __init__(self, path: Path):
        self.path = path
        self.channels: dict[str, int] = {}       # name -> length
        self.parts: dict[str, tuple[str, int, int]] = {}  # channel of a 2-D array -> (variable, j, time axis)
        self.meta: dict = {}
        self.units: dict[str, str] = {}
        self.warnings: list[str] = []

    def refuse_object(self, name: str, cls: str):
        raise ReaderError(reexport_hint(name, cls, self.path.stem))

    def export(self, batches) -> RawExport:
        if not self.channels:
            raise ReaderError("no channel: the file has no numeric vector (N x 1 or 1 x N, N > 1)")
        check_channel_count(len(self.channels), "channels (numeric vectors)")
        lengths = set(self.channels.values())
        if len(lengths) > 1:
            listed = ", ".join(f"`{k}` {n}" for k, n in self.channels.items())
            raise ReaderError(f"channels have different lengths ({listed[:300]})")
        folded = {k.casefold(): v for k, v in self.units.items()}
        columns = [RawColumn(key=name, name=name, unit=self._unit(name, folded), index=i + 1)
                   for i, name in enumerate(self.channels)]
        unknown = sorted(set(self.units) - set(self.channels) - {v for v, _, _ in self.parts.values()})
        if unknown:
            self.warnings.append(f"`units` names no channel {', '.join(unknown)}")
        return RawExport(format=FORMAT, columns=columns, metadata=self.meta, batches=batches, warnings=self.warnings)

    def _unit(self, name: str, folded: dict) -> str | None:
        unit = self.units.get(name, folded.get(name.casefold()))
        if unit is None and name in self.parts:
            var = self.parts[name][0]
            unit = self.units.get(var, folded.get(var.casefold()))
        return unit

    def matrix(self, key: str, shape: tuple) -> bool:
        """Take a 2-D array of MATLAB shape ``shape`` as k channels ``key_1 .. key_k``; False
        (and a warning) when it is not N x k / k x N with k <= MAX_MATRIX_CHANNELS and N > k."""
        k, n = min(shape), max(shape)
        names = [f"{key}_{j + 1}" for j in range(k)]
        if len(shape) != 2 or k > MAX_MATRIX_CHANNELS or n <= k or any(m in self.channels for m in names):
            self.warnings.append(f"variable `{key}` ({' x '.join(map(str, shape))} matrix) ignored")
            return False
        axis = 0 if shape[0] == n else 1
        for j, name in enumerate(names):
            self.channels[name] = n
            self.parts[name] = (key, j, axis)
        return True


# -- v5 / v7: the element structure, checked before scipy allocates anything ---------------
_MI_MATRIX, _MI_COMPRESSED, _MI_INT32, _MI_UINT32 = 14, 15, 5, 6
_MX_CELL, _MX_STRUCT, _MX_OBJECT, _MX_CHAR, _MX_SPARSE, _MX_OPAQUE = 1, 2, 3, 4, 5, 17
_NUMERIC = set(range(6, 16))                 # double, single, int8 ... uint64
#: miINT8 ... miUINT32, miSINGLE, miDOUBLE, miINT64, miUINT64, miUTF8, miUTF16, miUTF32.
_DATA_TYPES = {1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 16, 17, 18}
_CLASSES = {1, 2, 3, 4, 5, 16, 17} | _NUMERIC
#: Deepest nesting of arrays (cells in cells, struct fields) read.
MAX_DEPTH = 64
#: Most arrays (variables, cells, struct fields) in one file: each becomes a Python object.
MAX_ARRAYS = 100_000
#: Bytes inflated per step (``zlib.decompressobj(...).decompress(data, max_length)``).
_INFLATE_STEP = 1 << 20


class _Bad(Exception):
    """The element structure is not a MAT v5 file's (message: what is wrong)."""


class _Source:
    """The bytes of one top-level element's content, read sequentially: straight from the file,
    or inflated step by step (at most :data:`_INFLATE_STEP` at a time) with every inflated byte
    counted against ``budget``. Skipped bytes are dropped as they come: memory stays at a step."""

    def __init__(self, fh, nbytes: int, compressed: bool, budget: list[int]):
        self.fh, self.left, self.compressed, self.budget = fh, nbytes, compressed, budget
        self.pos = 0               # content bytes consumed
        self.buf = b""
        self.z = zlib.decompressobj() if compressed else None
        self.tail = b""

    def _piece(self) -> bytes:
        """The next piece of content (b"" at its end)."""
        if not self.compressed:
            data = self.fh.read(min(self.left, _INFLATE_STEP)) if self.left > 0 else b""
            self.left -= len(data)
            return data
        while True:
            if not self.tail:
                if self.left <= 0 or self.z.eof:
                    return b""
                self.tail = self.fh.read(min(self.left, 1 << 18))
                if not self.tail:
                    return b""
                self.left -= len(self.tail)
            try:
                out = self.z.decompress(self.tail, _INFLATE_STEP)
            except zlib.error as exc:
                raise _Bad(f"compressed data is corrupt ({exc})") from None
            self.tail = b"" if self.z.eof else self.z.unconsumed_tail
            if out:
                self.budget[0] -= len(out)
                if self.budget[0] < 0:
                    raise _Bomb()
                return out

    def read(self, n: int) -> bytes:
        while len(self.buf) < n:
            piece = self._piece()
            if not piece:
                raise _Bad("an element ends early")
            self.buf += piece
        out, self.buf = self.buf[:n], self.buf[n:]
        self.pos += n
        return out

    def skip(self, n: int) -> None:
        k = min(n, len(self.buf))
        self.buf, self.pos, n = self.buf[k:], self.pos + k, n - k
        if n and not self.compressed:
            if n > self.left:
                raise _Bad("an element ends early")
            self.fh.seek(n, 1)
            self.left -= n
            self.pos += n
            return
        while n:
            piece = self._piece()
            if not piece:
                raise _Bad("an element ends early")
            if len(piece) > n:
                self.buf = piece[n:]
                self.pos += n
                return
            self.pos += len(piece)
            n -= len(piece)


class _Bomb(Exception):
    """More inflated bytes than the file may honestly hold."""


class _V5Walk:
    """Walks every element of a v5 file (see the MAT-File Format, "Data Element Format")."""

    def __init__(self, order: str):
        self.order = order
        self.arrays = 0

    def tag(self, src: _Source, end: int) -> tuple[int, int, bytes | None]:
        """``(type, nbytes, data)`` of the next element inside ``[src.pos, end)``; ``data`` is the
        content of a small data element (None for a normal element, whose content follows)."""
        if end - src.pos < 8:
            raise _Bad("an element tag is cut short")
        raw = src.read(8)
        w1, w2 = struct.unpack(self.order + "II", raw)
        if w1 >> 16:                                     # small data element: 4 bytes of data inside
            size = w1 >> 16
            if size > 4:
                raise _Bad(f"a small data element claims {size} bytes (at most 4)")
            if w1 & 0xFFFF not in _DATA_TYPES:
                raise _Bad(f"unknown data type {w1 & 0xFFFF}")
            return w1 & 0xFFFF, size, raw[4:4 + size]
        if w1 not in _DATA_TYPES and w1 not in (_MI_MATRIX, _MI_COMPRESSED):
            raise _Bad(f"unknown data type {w1}")      # scipy segfaults on some (found by tests/fuzz)
        if w2 > end - src.pos:
            raise _Bad(f"an element declares {w2} bytes where its container has {end - src.pos} left")
        return w1, w2, None

    def elements(self, src: _Source, end: int, depth: int) -> list[tuple[int, int, bytes | None]]:
        """The elements of a container's content up to ``end`` (nested arrays walked too):
        ``(type, nbytes, data)`` each, ``data`` kept for elements of at most 8 bytes."""
        out = []
        while end - src.pos >= 8:
            mtype, size, data = self.tag(src, end)
            if data is None:
                if mtype == _MI_MATRIX:
                    self.matrix(src, size, depth + 1)
                elif mtype == _MI_COMPRESSED:
                    raise _Bad("compressed data inside an array")
                elif size <= 8:
                    data = src.read(size)
                else:
                    src.skip(size)
                src.skip(min((-size) % 8, end - src.pos))
            out.append((mtype, size, data))
        src.skip(end - src.pos)
        return out

    def matrix(self, src: _Source, size: int, depth: int) -> None:
        """One miMATRIX element's content: flags, dimensions, name, data or nested arrays, as
        many as the class and flags say (scipy reads what they say, past the array's end, and
        crashes on some such files: a complex flag without an imaginary part is a segfault)."""
        self.arrays += 1
        if self.arrays > MAX_ARRAYS:
            raise _Bad(f"more than {MAX_ARRAYS} arrays (variables, cells, struct fields)")
        if depth > MAX_DEPTH:
            raise _Bad(f"arrays nested more than {MAX_DEPTH} deep")
        if size == 0:
            return                                        # an empty cell / field
        end = src.pos + size
        mtype, n, data = self.tag(src, end)
        if mtype != _MI_UINT32 or n != 8 or data is not None:
            raise _Bad("an array does not start with its flags")
        flags = struct.unpack(self.order + "II", src.read(8))[0]
        cls, complex_ = flags & 0xFF, bool(flags & 0x0800)
        if cls not in _CLASSES:
            raise _Bad(f"unknown array class {cls}")
        count = 1
        if cls != _MX_OPAQUE:
            mtype, n, data = self.tag(src, end)
            if mtype != _MI_INT32 or data is not None or n < 8 or n % 4:
                raise _Bad("an array has no dimensions")
            if n > 4 * MAX_DEPTH:
                raise _Bad(f"an array has {n // 4} dimensions")
            dims = struct.unpack(self.order + f"{n // 4}i", src.read(n))
            src.skip(min((-n) % 8, end - src.pos))
            if min(dims) < 0:
                raise _Bad(f"an array has a negative dimension {' x '.join(map(str, dims))}")
            count = math.prod(dims)
            # Every element takes at least a byte of data (8 for a cell / struct element, a
            # nested array): dimensions beyond that are a lie scipy would allocate for.
            per = 8 if cls in (_MX_CELL, _MX_STRUCT, _MX_OBJECT) else 1
            if cls != _MX_SPARSE and count * per > size:
                raise _Bad(f"an array declares {' x '.join(map(str, dims))} elements in {size} bytes")
        parts = self.elements(src, end, depth)
        self._check_parts(cls, complex_, count, parts)

    def _check_parts(self, cls: int, complex_: bool, count: int, parts: list) -> None:
        """The elements after the dimensions are the ones the class and flags announce."""
        kinds = [t for t, _, _ in parts]
        if not parts or kinds[0] != 1:
            raise _Bad("an array has no name (miINT8)")
        if cls in _NUMERIC or cls == _MX_CHAR:
            want = 2 + (complex_ and cls != _MX_CHAR)     # name, real part (, imaginary part)
            if len(parts) != want or _MI_MATRIX in kinds:
                raise _Bad(f"a {'complex ' if complex_ else ''}numeric array has {len(parts) - 1} data "
                           f"elements (expected {want - 1})")
        elif cls == _MX_SPARSE:
            if len(parts) < 4 + complex_ or _MI_MATRIX in kinds:
                raise _Bad("a sparse array lacks its indices or values")
        elif cls == _MX_CELL:
            if len(parts) != 1 + count or any(t != _MI_MATRIX for t in kinds[1:]):
                raise _Bad(f"a cell array of {count} cells holds {kinds[1:].count(_MI_MATRIX)} arrays")
        elif cls in (_MX_STRUCT, _MX_OBJECT):
            head = 3 if cls == _MX_STRUCT else 4           # name, (class name,) field name length, names
            if len(parts) < head or parts[head - 2][2] is None:
                raise _Bad("a struct has no field names")
            length = struct.unpack(self.order + "i", parts[head - 2][2].ljust(4, b"\0"))[0]
            if length <= 0:
                raise _Bad(f"a struct has field names of length {length}")
            fields = parts[head - 1][1] // length
            if len(parts) != head + count * fields or any(t != _MI_MATRIX for t in kinds[head:]):
                raise _Bad(f"a struct of {count} x {fields} fields holds {kinds[head:].count(_MI_MATRIX)} arrays")
        else:                                              # function handle, opaque object
            if _MI_MATRIX not in kinds:
                raise _Bad("a function handle / object holds no array")


def check_v5(path: Path) -> None:
    """Walk a MAT v5 / v7 file's elements before scipy reads it; refuse (ReaderError) a file
    that is not one, whose declared sizes exceed what holds them, or whose compressed elements
    inflate to more than :func:`pipeline.readers.base.inflate_cap` of its size (a
    decompression bomb). Compressed data are inflated step by step and dropped, so this
    needs no more memory than one step, and it stops as soon as the cap is passed."""
    size = path.stat().st_size
    cap = inflate_cap(size)
    budget = [cap]
    with open(path, "rb") as fh:
        head = fh.read(128)
        if len(head) < 128 or 0 in head[:4] or head[126:128] not in (b"IM", b"MI"):
            raise ReaderError("not a MAT file (no MAT v5/v7 header or HDF5 signature; MAT v4 is not read)")
        order = "<" if head[126:128] == b"IM" else ">"
        version = struct.unpack(order + "H", head[124:126])[0]
        if version != 0x0100:
            raise ReaderError(f"not a MAT file (header version 0x{version:04x}, expected 0x0100 for v5/v7)")
        walk = _V5Walk(order)
        pos = 128
        while pos < size:
            if size - pos < 8:
                raise ReaderError(f"MAT file ends inside an element tag at byte {pos}")
            mtype, nbytes = struct.unpack(order + "II", fh.read(8))
            if mtype not in (_MI_MATRIX, _MI_COMPRESSED) or nbytes == 0:
                raise ReaderError(f"not a readable MAT file: element at byte {pos} has type {mtype} and "
                                  f"{nbytes} bytes (expected a variable: miMATRIX or miCOMPRESSED)")
            if nbytes > size - pos - 8:
                raise ReaderError(f"MAT file cut short: the variable at byte {pos} declares {nbytes} bytes, "
                                  f"the file has {size - pos - 8} left")
            src = _Source(fh, nbytes, mtype == _MI_COMPRESSED, budget)
            try:
                if mtype == _MI_MATRIX:
                    walk.matrix(src, nbytes, 1)
                else:
                    inner = 1 << 62
                    t, n, small = walk.tag(src, inner)
                    if t != _MI_MATRIX or small is not None:
                        raise _Bad(f"compressed element holds type {t}, not an array")
                    walk.matrix(src, n, 1)
            except _Bomb:
                raise ReaderError(f"MAT file of {mib(size)} inflates to more than {mib(cap)} (limit: "
                                  f"{MAX_INFLATE_RATIO} x the file size, at least {mib(INFLATE_FLOOR_BYTES)}, "
                                  f"at most {mib(INFLATE_CEILING_BYTES)}): a decompression bomb?") from None
            except _Bad as exc:
                raise ReaderError(f"not a readable MAT file: variable at byte {pos}: {exc}") from None
            pos += 8 + nbytes
            fh.seek(pos)


# -- v5 / v7 -------------------------------------------------------------------------------
def _read_v5(path: Path) -> RawExport:
    from scipy.io import loadmat
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque, mat_struct

    check_v5(path)
    try:
        data = loadmat(path, squeeze_me=False, struct_as_record=False, chars_as_strings=True)
    except NotImplementedError:
        return _read_v73(path)
    except Exception as exc:  # scipy raises ValueError, TypeError, zlib.error ... on bad input
        raise ReaderError(f"not a readable MAT file: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                          ) from None
    col = _Collect(path)

    def opaque_info(v, key) -> tuple[str, str]:
        names = v.dtype.names or ()
        rec = v.ravel()[0] if v.size else None

        def get(*fields):
            for f in fields:
                if rec is not None and f in names:
                    x = rec[f]
                    return x.decode("latin-1") if isinstance(x, bytes) else str(x)
            return None
        return get("_VarName", "s0") or key, get("_Class", "s2") or "object"

    def unwrap(v):
        """A 1 x 1 object array (struct, cell element) -> its content."""
        while isinstance(v, np.ndarray) and v.dtype == object and v.size == 1 and not isinstance(v, MatlabOpaque):
            v = v.ravel()[0]
        return v

    def value(v, where: str):
        v = unwrap(v)
        if isinstance(v, MatlabOpaque):
            col.refuse_object(where, opaque_info(v, where)[1])
        if isinstance(v, MatlabObject):
            col.refuse_object(where, getattr(v, "classname", "object"))
        if isinstance(v, str):
            return v
        if isinstance(v, np.ndarray) and v.dtype.kind in "US":
            return "".join(str(x) for x in v.ravel())
        if isinstance(v, np.ndarray) and v.dtype.kind in "biuf" and v.size <= 1 and v.ndim <= 2:
            return _scalar(v) if v.size else None
        if isinstance(v, np.ndarray) and v.dtype.kind in "biuf":
            return _scalar(v)
        return str(v)

    for key, v in data.items():
        if key.startswith("__"):
            continue
        if isinstance(v, MatlabOpaque):
            name, cls = opaque_info(v, key)
            col.refuse_object(name, cls)
        if isinstance(v, MatlabObject):
            col.refuse_object(key, getattr(v, "classname", "object"))
        if isinstance(v, MatlabFunction):
            col.warnings.append(f"variable `{key}` (function handle) ignored")
            continue
        u = unwrap(v)
        if isinstance(u, mat_struct):
            fields = {f: getattr(u, f) for f in u._fieldnames}
            if key == "meta":
                for f, fv in fields.items():
                    col.meta[f] = value(fv, f"meta.{f}")
            elif key == "units":
                for f, fv in fields.items():
                    uv = value(fv, f"units.{f}")
                    if uv is not None and str(uv).strip():
                        col.units[f] = str(uv)
            else:
                col.warnings.append(f"struct `{key}` ignored (only `meta` and `units` structs are read)")
            continue
        if isinstance(v, np.ndarray) and v.dtype.kind in "US":
            col.meta[key] = value(v, key)
            continue
        if not isinstance(v, np.ndarray) or v.dtype.kind not in "biufc":
            col.warnings.append(f"variable `{key}` ({type(v).__name__}) ignored")
            continue
        if v.dtype.kind == "c":
            col.warnings.append(f"variable `{key}` (complex) ignored")
            continue
        shape = v.shape
        if v.size == 0:
            continue
        if v.size == 1:
            col.meta[key] = _scalar(v)
        elif v.ndim == 2 and min(shape) == 1 or v.ndim == 1:
            col.channels[key] = v.size
        elif v.ndim == 2:
            col.matrix(key, shape)
        else:
            col.warnings.append(f"variable `{key}` ({' x '.join(map(str, shape))} matrix) ignored")
    arrays = {k: data[k] for k in col.channels if k not in col.parts}

    def batches() -> Iterator[pa.RecordBatch]:
        n = next(iter(col.channels.values()))
        flat = {k: (np.asarray(data[col.parts[k][0]]).take(col.parts[k][1], axis=1 - col.parts[k][2])
                    if k in col.parts else np.asarray(arrays[k]).reshape(-1)) for k in col.channels}
        for i in range(0, n, BATCH_ROWS):
            yield pa.RecordBatch.from_arrays(
                [pa.array(flat[k][i:i + BATCH_ROWS].astype(np.float64)) for k in flat], names=list(flat))

    return col.export(batches)


# -- v7.3 (HDF5) ---------------------------------------------------------------------------
def _cls(obj) -> str:
    c = obj.attrs.get("MATLAB_class", b"")
    return c.decode("ascii", "replace") if isinstance(c, bytes) else str(c)


def _h5_value(ds):
    cls = _cls(ds)
    if "MATLAB_empty" in ds.attrs and int(np.asarray(ds.attrs["MATLAB_empty"]).ravel()[0]):
        return None
    arr = ds[()]
    if cls == "char":
        return "".join(chr(c) for c in np.asarray(arr).T.ravel() if c)
    arr = np.asarray(arr)
    if arr.dtype.names:   # complex: compound (real, imag)
        return None
    if cls == "logical":
        arr = arr.astype(bool)
    return _scalar(arr)


def _check_h5_storage(obj, name: str) -> None:
    """Refuse a dataset whose bytes are not in this file: HDF5 external storage (raw bytes in any
    file named by path) or a virtual dataset (mapped from other HDF5 files). h5py would open those
    files by name, wherever they are: outside raw/, not the file that was opened."""
    how = ("HDF5 virtual dataset" if getattr(obj, "is_virtual", False)
           else "HDF5 external storage" if obj.id.get_create_plist().get_external_count() else None)
    if how is not None:
        raise ReaderError(f"variable `{name}` keeps its data in another file ({how}): not read")


def _check_h5_size(obj, name: str, file_size: int) -> None:
    """Refuse a dataset whose shape x item size exceeds :func:`inflate_cap` of the file size
    (HDF5 stores unwritten chunks as nothing and compresses chunks: a small file may declare
    terabytes), before any of it is read."""
    shape = obj.shape or ()
    logical = math.prod(int(n) for n in shape) * int(obj.dtype.itemsize)
    cap = inflate_cap(file_size)
    if logical > cap:
        raise ReaderError(f"MAT v7.3 variable `{name}` declares {' x '.join(map(str, reversed(shape)))} values "
                          f"({mib(logical)}) in a file of {mib(file_size)}: more than the limit of {mib(cap)} "
                          f"({MAX_INFLATE_RATIO} x the file size, at least {mib(INFLATE_FLOOR_BYTES)}, at most "
                          f"{mib(INFLATE_CEILING_BYTES)})")


def _read_v73(path: Path) -> RawExport:
    try:
        return _read_v73_unchecked(path)
    except ReaderError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises KeyError, RuntimeError, ... on corrupt HDF5
        raise ReaderError(f"not a readable MAT v7.3 (HDF5) file: {type(exc).__name__}: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0][:200] if lines else ""


def _read_v73_unchecked(path: Path) -> RawExport:
    import h5py

    col = _Collect(path)
    file_size = path.stat().st_size
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ReaderError(f"not a readable MAT v7.3 (HDF5) file: {exc}") from None
    datasets: dict[str, str] = {}
    with f:
        for key in f:
            if key.startswith("#"):
                continue                       # #refs#, #subsystem#: MATLAB's bookkeeping
            if not isinstance(f.get(key, getlink=True), h5py.HardLink):
                col.warnings.append(f"variable `{key}` (an HDF5 link) ignored")   # never follow a link out
                continue
            obj = f[key]
            cls = _cls(obj)
            if "MATLAB_object_decode" in obj.attrs or (cls and cls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}):
                col.refuse_object(key, cls or "object")
            if isinstance(obj, h5py.Group):
                if cls != "struct" or "MATLAB_sparse" in obj.attrs:
                    col.warnings.append(f"variable `{key}` ({cls or 'group'}) ignored")
                elif key in ("meta", "units"):
                    for field_name in obj:
                        if not isinstance(obj.get(field_name, getlink=True), h5py.HardLink):
                            col.warnings.append(f"field `{key}.{field_name}` (an HDF5 link) ignored")
                            continue
                        fobj = obj[field_name]
                        fcls = _cls(fobj)
                        if "MATLAB_object_decode" in fobj.attrs or fcls not in _NUMERIC_CLASSES | {"char"}:
                            if fcls and fcls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}:
                                col.refuse_object(f"{key}.{field_name}", fcls)
                            col.warnings.append(f"field `{key}.{field_name}` ({fcls}) ignored")
                            continue
                        if isinstance(fobj, h5py.Group):
                            col.warnings.append(f"field `{key}.{field_name}` (group) ignored")
                            continue
                        _check_h5_storage(fobj, f"{key}.{field_name}")
                        _check_h5_size(fobj, f"{key}.{field_name}", file_size)
                        v = _h5_value(fobj)
                        if key == "meta":
                            col.meta[field_name] = v
                        elif v is not None and str(v).strip():
                            col.units[field_name] = str(v)
                else:
                    col.warnings.append(f"struct `{key}` ignored (only `meta` and `units` structs are read)")
                continue
            if cls == "cell" or (cls and cls not in _NUMERIC_CLASSES | {"char"}):
                col.warnings.append(f"variable `{key}` ({cls}) ignored")
                continue
            if "MATLAB_empty" in obj.attrs and int(np.asarray(obj.attrs["MATLAB_empty"]).ravel()[0]):
                continue
            if not isinstance(obj, h5py.Dataset):
                col.warnings.append(f"variable `{key}` ({type(obj).__name__}) ignored")
                continue
            _check_h5_storage(obj, key)
            _check_h5_size(obj, key, file_size)
            if cls == "char":
                col.meta[key] = _h5_value(obj)
                continue
            if obj.dtype.names:
                col.warnings.append(f"variable `{key}` (complex) ignored")
                continue
            shape = obj.shape
            size = int(np.prod(shape)) if shape else 1
            if size == 1:
                col.meta[key] = _h5_value(obj)
            elif len(shape) == 1 or (len(shape) == 2 and min(shape) == 1):
                col.channels[key] = size
                datasets[key] = key
            elif len(shape) == 2 and col.matrix(key, tuple(reversed(shape))):   # MATLAB shape
                pass
            else:
                col.warnings.append(f"variable `{key}` ({' x '.join(map(str, reversed(shape)))} matrix) ignored")

    def batches() -> Iterator[pa.RecordBatch]:
        try:
            yield from _v73_batches()
        except ReaderError:
            raise
        except Exception as exc:  # noqa: BLE001 - h5py on corrupt chunks
            raise ReaderError(f"cannot read MAT v7.3 data: {type(exc).__name__}: {_first_line(exc)}") from None

    def _v73_batches() -> Iterator[pa.RecordBatch]:
        n = next(iter(col.channels.values()))
        with h5py.File(path, "r") as h:
            ds = {k: h[k] for k in datasets}
            for i in range(0, n, BATCH_ROWS):
                j = min(n, i + BATCH_ROWS)
                arrays = []
                for name in col.channels:
                    if name in col.parts:     # HDF5 holds the MATLAB array transposed
                        var, c, axis = col.parts[name]
                        d = h[var]
                        part = d[c, i:j] if axis == 0 else d[i:j, c]
                        arrays.append(pa.array(np.asarray(part, dtype=np.float64)))
                        continue
                    d = ds[name]
                    if len(d.shape) == 1:
                        part = d[i:j]
                    elif d.shape[0] == 1:
                        part = d[0, i:j]
                    else:
                        part = d[i:j, 0]
                    arrays.append(pa.array(np.asarray(part, dtype=np.float64)))
                yield pa.RecordBatch.from_arrays(arrays, names=list(col.channels))

    return col.export(batches)


def read_mat(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open a MAT export (v5, v7 or v7.3; see the module docstring).

    Parameters
    ----------
    path : path-like
        The export.
    read, hints : dict, optional
        Unused; accepted for the common reader signature.

    Returns
    -------
    RawExport
    """
    path = Path(path)
    if _is_v73(path):
        return _read_v73(path)
    return _read_v5(path)
