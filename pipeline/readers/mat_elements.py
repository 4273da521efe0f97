"""MAT v5 / v7 files walked element by element before scipy reads them (:func:`check_v5`).

scipy allocates what a file declares and crashes on some malformed arrays (a complex flag
without an imaginary part is a segfault), so a v5 / v7 file is walked first (see the MAT-File
Format, "Data Element Format"): compressed elements are inflated in 1 MiB steps and dropped, and
a file is refused (:class:`pipeline.readers.base.ReaderError`) that inflates to more than
:func:`pipeline.readers.base.inflate_cap` of its size (a decompression bomb), declares sizes or
dimensions its bytes cannot hold, nests arrays too deep, uses unknown data types, or has arrays
that lack the parts their class announces.
"""
from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

from pipeline.readers.base import (INFLATE_CEILING_BYTES, INFLATE_FLOOR_BYTES, MAX_INFLATE_RATIO, ReaderError,
                                   inflate_cap, mib)

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
        """The next ``n`` bytes of content (an element that ends early is :class:`_Bad`)."""
        while len(self.buf) < n:
            piece = self._piece()
            if not piece:
                raise _Bad("an element ends early")
            self.buf += piece
        out, self.buf = self.buf[:n], self.buf[n:]
        self.pos += n
        return out

    def skip(self, n: int) -> None:
        """Skip ``n`` bytes of content (dropped as they come)."""
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
