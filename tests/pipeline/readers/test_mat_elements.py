"""The MAT v5 / v7 element walk (pipeline/readers/mat_elements.py): decompression bombs, lying
sizes and malformed arrays refused before scipy reads the file; legitimate files pass."""
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from pipeline.ingest.file import ingest_file
from pipeline.raw.tree import RawTree
from pipeline.readers import ReaderError, read_export
from pipeline.readers import mat_elements
from pipeline.readers.base import INFLATE_FLOOR_BYTES, inflate_cap
from tests.pipeline.readers.generators import mat_v5, mat_v5_compressed_zeros, mat_v5_elements, v5_double, v5_tag


def basic(**extra):
    """The variables of a small valid run (as in test_mat.py), with ``extra`` ones."""
    return {"t": np.array([0.0, 0.1, 0.2, 0.3]), "x": np.array([1.5, 2.5, -3.0, 4.0]),
            "meta": {"kind": "step", "rig": "plpa-1", "started_at": "2026-01-02T03:04:05"},
            "units": {"t": "s", "x": "mm"}, **extra}


def test_mat_decompression_bomb_is_quarantined_naming_the_sizes(raw, warehouse):
    (raw.root / "c").mkdir(parents=True)
    path = mat_v5_compressed_zeros(raw.root / "c" / "a.mat", n_bytes=128 << 20)   # ~0.6 MB file
    res = ingest_file(RawTree(raw.root), path, warehouse)
    assert res.run is None
    assert res.error == (f"MAT file of {path.stat().st_size / (1 << 20):.1f} MiB inflates to more than 64.0 MiB "
                         "(limit: 100 x the file size, at least 64.0 MiB, at most 4096.0 MiB): a decompression bomb?")


def test_mat_bomb_is_refused_before_scipy_and_inflates_no_more_than_the_cap(tmp_path, monkeypatch):
    path = mat_v5_compressed_zeros(tmp_path / "a.mat", n_bytes=256 << 20)
    inflated = []
    real = zlib.decompressobj

    class Counting:
        def __init__(self, *a):
            self.z = real(*a)

        def decompress(self, data, max_length=0):
            out = self.z.decompress(data, max_length)
            assert 0 < max_length <= 1 << 20, "inflate in bounded steps"
            inflated.append(len(out))
            return out

        def __getattr__(self, name):
            return getattr(self.z, name)

    monkeypatch.setattr(mat_elements.zlib, "decompressobj", Counting)
    import scipy.io

    monkeypatch.setattr(scipy.io, "loadmat", lambda *a, **k: pytest.fail("scipy must not see a bomb"))
    with pytest.raises(ReaderError, match="decompression bomb"):
        read_export(path)
    cap = inflate_cap(path.stat().st_size)
    assert INFLATE_FLOOR_BYTES <= cap < 256 << 20
    assert cap < sum(inflated) <= cap + (1 << 20)


def test_mat_bomb_peak_memory_stays_bounded(tmp_path):
    """A child process refuses a bomb that inflates to 256 MiB without ever holding it."""
    path = mat_v5_compressed_zeros(tmp_path / "a.mat", n_bytes=256 << 20)
    # VmHWM (peak RSS of this program; ru_maxrss would include the forking pytest's).
    code = ("import sys\nfrom pipeline.readers import ReaderError, read_export\n"
            "try:\n    read_export(sys.argv[1])\nexcept ReaderError as e:\n    print('refused', e)\n"
            "print([l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0])\n")
    root = str(Path(__file__).resolve().parents[3])
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120,
                         cwd=root, env={**os.environ, "PYTHONPATH": root})
    lines = out.stdout.splitlines()
    assert lines and lines[0].startswith("refused MAT file"), out.stderr
    assert int(lines[1]) * 1024 < 200 << 20       # [kB]; the bomb inflates to 256 MiB


def test_mat_compressed_constant_channel_under_the_floor_is_read(tmp_path):
    """1M zeros (8 MiB from a few KB: ratio > 100, but under the 64 MiB floor) are data."""
    ex = read_export(mat_v5_compressed_zeros(tmp_path / "a.mat", n_bytes=8 << 20))
    assert sum(b.num_rows for b in ex.batches()) == 1 << 20


def test_mat_dimensions_larger_than_the_data_are_refused(tmp_path):
    """A 48-byte cell array that declares 65536 x 65536 cells: scipy would allocate them all."""
    flags = v5_tag(6, struct.pack("<II", 1, 0))                      # mxCELL_CLASS
    body = flags + v5_tag(5, struct.pack("<2i", 65536, 65536)) + v5_tag(1, b"c")
    path = mat_v5_elements(tmp_path / "a.mat", v5_tag(14, body) + v5_double("t", [0.0, 1.0]))
    with pytest.raises(ReaderError, match=r"^not a readable MAT file: variable at byte 128: an array declares "
                                          r"65536 x 65536 elements in 48 bytes$"):
        read_export(path)


def test_mat_element_larger_than_its_container_is_refused(tmp_path):
    """A data element that claims 4 GB inside a 64-byte array (scipy allocates the claim first)."""
    head = v5_tag(6, struct.pack("<II", 6, 0)) + v5_tag(5, struct.pack("<2i", 2, 1)) + v5_tag(1, b"x")
    body = head + struct.pack("<II", 9, 0xFFFFFFF0) + b"\0" * 16
    path = mat_v5_elements(tmp_path / "a.mat", v5_tag(14, body))
    with pytest.raises(ReaderError, match=r"an element declares 4294967280 bytes where its container has 16 left"):
        read_export(path)


def test_mat_variable_cut_short_is_refused(tmp_path):
    blob = v5_double("t", [0.0, 1.0, 2.0])
    path = mat_v5_elements(tmp_path / "a.mat", blob[:-8])
    with pytest.raises(ReaderError, match=r"^MAT file cut short: the variable at byte 128 declares 80 bytes, "
                                          r"the file has 72 left$"):
        read_export(path)


def test_mat_v4_or_headerless_file_is_not_a_mat_file(tmp_path):
    path = tmp_path / "a.mat"
    path.write_bytes(struct.pack("<5i", 0, 2, 1, 0, 2) + b"x\0" + b"\0" * 16)    # a MAT v4 matrix header
    with pytest.raises(ReaderError, match=r"^not a MAT file \(no MAT v5/v7 header or HDF5 signature; "
                                          r"MAT v4 is not read\)$"):
        read_export(path)


def test_mat_complex_flag_without_imaginary_part_is_refused_before_scipy(tmp_path):
    """scipy reads an imaginary part past the array's end and segfaults (found by tests/fuzz)."""
    flags = v5_tag(6, struct.pack("<II", 6 | 0x0800, 0))               # mxDOUBLE_CLASS, complex
    body = flags + v5_tag(5, struct.pack("<2i", 2, 1)) + v5_tag(1, b"z") + v5_tag(9, struct.pack("<2d", 1.0, 2.0))
    path = mat_v5_elements(tmp_path / "a.mat", v5_tag(14, body) + v5_double("t", [0.0, 1.0]))
    with pytest.raises(ReaderError, match=r"^not a readable MAT file: variable at byte 128: a complex numeric "
                                          r"array has 1 data elements \(expected 2\)$"):
        read_export(path)


def test_mat_struct_with_fewer_fields_than_announced_is_refused(tmp_path):
    flags = v5_tag(6, struct.pack("<II", 2, 0))                         # mxSTRUCT_CLASS 1 x 1
    names = v5_tag(1, b"a".ljust(8, b"\0") + b"b".ljust(8, b"\0"))       # two fields of 8 characters
    body = (flags + v5_tag(5, struct.pack("<2i", 1, 1)) + v5_tag(1, b"meta")
            + struct.pack("<HHi", 5, 4, 8) + names + v5_double("", [1.0, 2.0]))
    path = mat_v5_elements(tmp_path / "a.mat", v5_tag(14, body) + v5_double("t", [0.0, 1.0]))
    with pytest.raises(ReaderError, match=r"a struct of 1 x 2 fields holds 1 arrays$"):
        read_export(path)


def test_mat_legit_complex_and_struct_variables_pass_the_walk(tmp_path):
    path = mat_v5(tmp_path / "a.mat", basic(z=np.array([1 + 2j, 3 - 4j]), cells=np.array([[1.0], "ab"], dtype=object),
                                            s={"a": 1.0, "b": {"c": "deep"}}), compress=True)
    mat_elements.check_v5(path)
    assert [c.name for c in read_export(path).columns] == ["t", "x"]


@pytest.mark.parametrize("mtype", [0, 8, 10, 11, 0x2C09], ids=["zero", "8", "10", "11", "garbage"])
def test_mat_unknown_data_type_is_refused_before_scipy(tmp_path, mtype):
    """scipy crashes (or loops) on some unknown data types (found by tests/fuzz, seed 7)."""
    head = v5_tag(6, struct.pack("<II", 6, 0)) + v5_tag(5, struct.pack("<2i", 2, 1)) + v5_tag(1, b"x")
    path = mat_v5_elements(tmp_path / "a.mat", v5_tag(14, head + v5_tag(mtype, struct.pack("<2d", 1.0, 2.0))))
    with pytest.raises(ReaderError, match=rf"^not a readable MAT file: variable at byte 128: "
                                          rf"unknown data type {mtype}$"):
        read_export(path)
