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
  of a file without a ``t`` vector (applied by :func:`pipeline.ingest.resolve_time_base`).
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
"""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa

from pipeline.readers.base import RawColumn, RawExport, ReaderError

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


# -- v5 / v7 -------------------------------------------------------------------------------
def _read_v5(path: Path) -> RawExport:
    from scipy.io import loadmat
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque, mat_struct

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


def _read_v73(path: Path) -> RawExport:
    import h5py

    col = _Collect(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ReaderError(f"not a readable MAT v7.3 (HDF5) file: {exc}") from None
    datasets: dict[str, str] = {}
    with f:
        for key in f:
            if key.startswith("#"):
                continue                       # #refs#, #subsystem#: MATLAB's bookkeeping
            obj = f[key]
            cls = _cls(obj)
            if "MATLAB_object_decode" in obj.attrs or (cls and cls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}):
                col.refuse_object(key, cls or "object")
            if isinstance(obj, h5py.Group):
                if cls != "struct" or "MATLAB_sparse" in obj.attrs:
                    col.warnings.append(f"variable `{key}` ({cls or 'group'}) ignored")
                elif key in ("meta", "units"):
                    for field_name in obj:
                        fobj = obj[field_name]
                        fcls = _cls(fobj)
                        if "MATLAB_object_decode" in fobj.attrs or fcls not in _NUMERIC_CLASSES | {"char"}:
                            if fcls and fcls not in _NUMERIC_CLASSES | {"char", "struct", "cell"}:
                                col.refuse_object(f"{key}.{field_name}", fcls)
                            col.warnings.append(f"field `{key}.{field_name}` ({fcls}) ignored")
                            continue
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
