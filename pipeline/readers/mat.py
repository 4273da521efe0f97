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
* Untrusted bytes: before scipy sees a v5/v7 file, :func:`pipeline.readers.mat_elements.check_v5`
  walks its elements (compressed ones inflated in 1 MiB steps and dropped) and refuses a file
  that inflates to more than :func:`pipeline.readers.base.inflate_cap` of its size (a
  decompression bomb), declares sizes or dimensions its bytes cannot hold, nests arrays too
  deep, uses unknown data types or arrays that lack the parts their class announces (scipy
  allocates what a file declares and crashes on some malformed arrays). v7.3 datasets are
  checked the same way (shape x item size against the cap) before they are read, and HDF5
  links are never followed.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import (INFLATE_CEILING_BYTES, INFLATE_FLOOR_BYTES, MAX_INFLATE_RATIO, RawColumn,
                                   RawExport, ReaderError, check_channel_count, inflate_cap, mib)
from pipeline.readers.mat_elements import check_v5

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
    """Whether a ``.mat`` file is HDF5 (MATLAB v7.3): the HDF5 signature at 0 or 512, or a v7.3 text header."""
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
        """Refuse the file: variable ``name`` is a MATLAB object of class ``cls`` (a re-export hint)."""
        raise ReaderError(reexport_hint(name, cls, self.path.stem))

    def export(self, batches) -> RawExport:
        """The RawExport of the channels gathered (all of one length), reading ``batches``."""
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
        """A channel's unit from ``units`` (case-insensitive), else its matrix variable's unit."""
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


# -- v5 / v7 -------------------------------------------------------------------------------
# scipy.io is heavy (over a second to import): the functions of this section import it when a
# v5 / v7 file is read, not when a worker loads the readers.
def _read_v5(path: Path) -> RawExport:
    """Read a MAT v5 / v7 file: walked by :func:`check_v5`, then loaded whole by scipy (a v7.3
    file scipy does not read goes to :func:`_read_v73`)."""
    from scipy.io import loadmat

    check_v5(path)
    try:
        data = loadmat(path, squeeze_me=False, struct_as_record=False, chars_as_strings=True)
    except NotImplementedError:
        return _read_v73(path)
    except Exception as exc:  # scipy raises ValueError, TypeError, zlib.error ... on bad input
        raise ReaderError(f"not a readable MAT file: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                          ) from None
    col = _Collect(path)
    for key, v in data.items():
        if key.startswith("__"):
            continue
        _take_v5_variable(col, key, v)
    arrays = {k: data[k] for k in col.channels if k not in col.parts}
    return col.export(lambda: _v5_batches(col, data, arrays))


def _take_v5_variable(col: _Collect, key: str, v) -> None:
    """One variable as scipy loaded it: a channel, metadata, ``meta`` / ``units``, a warning, or
    a refusal (MATLAB objects)."""
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque, mat_struct

    if isinstance(v, MatlabOpaque):
        name, cls = _opaque_info(v, key)
        col.refuse_object(name, cls)
    if isinstance(v, MatlabObject):
        col.refuse_object(key, getattr(v, "classname", "object"))
    if isinstance(v, MatlabFunction):
        col.warnings.append(f"variable `{key}` (function handle) ignored")
        return
    u = _unwrap(v)
    if isinstance(u, mat_struct):
        _take_v5_struct(col, key, {f: getattr(u, f) for f in u._fieldnames})
        return
    if isinstance(v, np.ndarray) and v.dtype.kind in "US":
        col.meta[key] = _v5_value(col, v, key)
        return
    if not isinstance(v, np.ndarray) or v.dtype.kind not in "biufc":
        col.warnings.append(f"variable `{key}` ({type(v).__name__}) ignored")
        return
    if v.dtype.kind == "c":
        col.warnings.append(f"variable `{key}` (complex) ignored")
        return
    shape = v.shape
    if v.size == 0:
        return
    if v.size == 1:
        col.meta[key] = _scalar(v)
    elif v.ndim == 2 and min(shape) == 1 or v.ndim == 1:
        col.channels[key] = v.size
    elif v.ndim == 2:
        col.matrix(key, shape)
    else:
        col.warnings.append(f"variable `{key}` ({' x '.join(map(str, shape))} matrix) ignored")


def _take_v5_struct(col: _Collect, key: str, fields: dict) -> None:
    """A struct variable's fields: ``meta`` is metadata, ``units`` the channels' units; another
    struct is ignored with a warning."""
    if key == "meta":
        for f, fv in fields.items():
            col.meta[f] = _v5_value(col, fv, f"meta.{f}")
    elif key == "units":
        for f, fv in fields.items():
            uv = _v5_value(col, fv, f"units.{f}")
            if uv is not None and str(uv).strip():
                col.units[f] = str(uv)
    else:
        col.warnings.append(f"struct `{key}` ignored (only `meta` and `units` structs are read)")


def _opaque_info(v, key: str) -> tuple[str, str]:
    """``(variable name, class)`` of a MATLAB object (``MatlabOpaque``) variable ``key``."""
    names = v.dtype.names or ()
    rec = v.ravel()[0] if v.size else None

    def get(*fields):
        for f in fields:
            if rec is not None and f in names:
                x = rec[f]
                return x.decode("latin-1") if isinstance(x, bytes) else str(x)
        return None
    return get("_VarName", "s0") or key, get("_Class", "s2") or "object"


def _unwrap(v):
    """A 1 x 1 object array (struct, cell element) -> its content."""
    from scipy.io.matlab import MatlabOpaque

    while isinstance(v, np.ndarray) and v.dtype == object and v.size == 1 and not isinstance(v, MatlabOpaque):
        v = v.ravel()[0]
    return v


def _v5_value(col: _Collect, v, where: str):
    """A metadata value (a ``meta`` / ``units`` field, a char array) as plain Python: text, a
    number, a list of numbers; a MATLAB object at ``where`` is refused."""
    from scipy.io.matlab import MatlabObject, MatlabOpaque

    v = _unwrap(v)
    if isinstance(v, MatlabOpaque):
        col.refuse_object(where, _opaque_info(v, where)[1])
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


def _v5_batches(col: _Collect, data: dict, arrays: dict) -> Iterator[pa.RecordBatch]:
    """The channels of a loaded v5 file in record batches of :data:`BATCH_ROWS` rows."""
    n = next(iter(col.channels.values()))
    flat = {k: (np.asarray(data[col.parts[k][0]]).take(col.parts[k][1], axis=1 - col.parts[k][2])
                if k in col.parts else np.asarray(arrays[k]).reshape(-1)) for k in col.channels}
    for i in range(0, n, BATCH_ROWS):
        yield pa.RecordBatch.from_arrays(
            [pa.array(flat[k][i:i + BATCH_ROWS].astype(np.float64)) for k in flat], names=list(flat))


# -- v7.3 (HDF5) ---------------------------------------------------------------------------
def _cls(obj) -> str:
    """An HDF5 object's ``MATLAB_class`` attribute as text (``""`` without one)."""
    c = obj.attrs.get("MATLAB_class", b"")
    return c.decode("ascii", "replace") if isinstance(c, bytes) else str(c)


def _h5_value(ds):
    """A small v7.3 dataset as a metadata value: text for chars, a plain number or list; None for an
    empty or complex one."""
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
    """Read a MAT v7.3 (HDF5) file; h5py's errors on a corrupt file become a one-line ReaderError."""
    try:
        return _read_v73_unchecked(path)
    except ReaderError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py raises KeyError, RuntimeError, ... on corrupt HDF5
        raise ReaderError(f"not a readable MAT v7.3 (HDF5) file: {type(exc).__name__}: {_first_line(exc)}") from None


def _first_line(exc: BaseException) -> str:
    """The first line of an exception's message (at most 200 characters)."""
    lines = str(exc).strip().splitlines()
    return lines[0][:200] if lines else ""


# h5py is imported by the functions of this section when a v7.3 file is read, not when a
# worker loads the readers.
def _read_v73_unchecked(path: Path) -> RawExport:
    """Read a MAT v7.3 (HDF5) file: its variables now, its channels in slices as batches are
    taken. HDF5 links are never followed."""
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
            _take_v73_variable(col, f[key], key, file_size, datasets)
    return col.export(lambda: _v73_batches(path, col, datasets))


def _take_v73_variable(col: _Collect, obj, key: str, file_size: int, datasets: dict[str, str]) -> None:
    """One top-level HDF5 object: a channel (its dataset then noted in ``datasets``), metadata,
    ``meta`` / ``units``, a warning, or a refusal (MATLAB objects, data in other files, sizes
    past the cap)."""
    import h5py

    cls = _cls(obj)
    if "MATLAB_object_decode" in obj.attrs or (cls and cls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}):
        col.refuse_object(key, cls or "object")
    if isinstance(obj, h5py.Group):
        _take_v73_group(col, obj, key, cls, file_size)
        return
    if cls == "cell" or (cls and cls not in _NUMERIC_CLASSES | {"char"}):
        col.warnings.append(f"variable `{key}` ({cls}) ignored")
        return
    if "MATLAB_empty" in obj.attrs and int(np.asarray(obj.attrs["MATLAB_empty"]).ravel()[0]):
        return
    if not isinstance(obj, h5py.Dataset):
        col.warnings.append(f"variable `{key}` ({type(obj).__name__}) ignored")
        return
    _check_h5_storage(obj, key)
    _check_h5_size(obj, key, file_size)
    if cls == "char":
        col.meta[key] = _h5_value(obj)
        return
    if obj.dtype.names:
        col.warnings.append(f"variable `{key}` (complex) ignored")
        return
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


def _take_v73_group(col: _Collect, obj, key: str, cls: str, file_size: int) -> None:
    """A group (a MATLAB struct): the fields of ``meta`` / ``units``; other groups are ignored
    with a warning."""
    if cls != "struct" or "MATLAB_sparse" in obj.attrs:
        col.warnings.append(f"variable `{key}` ({cls or 'group'}) ignored")
    elif key in ("meta", "units"):
        for field_name in obj:
            _take_v73_field(col, obj, key, field_name, file_size)
    else:
        col.warnings.append(f"struct `{key}` ignored (only `meta` and `units` structs are read)")


def _take_v73_field(col: _Collect, obj, key: str, field_name: str, file_size: int) -> None:
    """One field of the ``meta`` or ``units`` struct ``obj``: a metadata value or a unit."""
    import h5py

    if not isinstance(obj.get(field_name, getlink=True), h5py.HardLink):
        col.warnings.append(f"field `{key}.{field_name}` (an HDF5 link) ignored")
        return
    fobj = obj[field_name]
    fcls = _cls(fobj)
    if "MATLAB_object_decode" in fobj.attrs or fcls not in _NUMERIC_CLASSES | {"char"}:
        if fcls and fcls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}:
            col.refuse_object(f"{key}.{field_name}", fcls)
        col.warnings.append(f"field `{key}.{field_name}` ({fcls}) ignored")
        return
    if isinstance(fobj, h5py.Group):
        col.warnings.append(f"field `{key}.{field_name}` (group) ignored")
        return
    _check_h5_storage(fobj, f"{key}.{field_name}")
    _check_h5_size(fobj, f"{key}.{field_name}", file_size)
    v = _h5_value(fobj)
    if key == "meta":
        col.meta[field_name] = v
    elif v is not None and str(v).strip():
        col.units[field_name] = str(v)


def _v73_batches(path: Path, col: _Collect, datasets: dict[str, str]) -> Iterator[pa.RecordBatch]:
    """The channels of a v7.3 file in record batches; h5py's errors on corrupt chunks become a
    ReaderError."""
    try:
        yield from _v73_slices(path, col, datasets)
    except ReaderError:
        raise
    except Exception as exc:  # noqa: BLE001 - h5py on corrupt chunks
        raise ReaderError(f"cannot read MAT v7.3 data: {type(exc).__name__}: {_first_line(exc)}") from None


def _v73_slices(path: Path, col: _Collect, datasets: dict[str, str]) -> Iterator[pa.RecordBatch]:
    """Slices of :data:`BATCH_ROWS` rows of every channel, read from the file opened again."""
    import h5py

    n = next(iter(col.channels.values()))
    with h5py.File(path, "r") as h:
        ds = {k: h[k] for k in datasets}
        for i in range(0, n, BATCH_ROWS):
            j = min(n, i + BATCH_ROWS)
            arrays = [pa.array(np.asarray(_v73_slice(h, ds, col, name, i, j), dtype=np.float64))
                      for name in col.channels]
            yield pa.RecordBatch.from_arrays(arrays, names=list(col.channels))


def _v73_slice(h, ds: dict, col: _Collect, name: str, i: int, j: int):
    """Rows ``i`` to ``j`` of channel ``name`` (HDF5 holds the MATLAB array transposed)."""
    if name in col.parts:
        var, c, axis = col.parts[name]
        d = h[var]
        return d[c, i:j] if axis == 0 else d[i:j, c]
    d = ds[name]
    if len(d.shape) == 1:
        return d[i:j]
    if d.shape[0] == 1:
        return d[0, i:j]
    return d[i:j, 0]


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
