"""SHA-256 of a raw file (pipeline.ingest.hashing): in chunks, stoppable, in a thread while parsed."""
import hashlib
import threading

import pytest

from pipeline.ingest.hashing import BackgroundHash, hash_whole, sha256_file


def test_sha256_file_in_chunks_is_hashlibs_and_counts_the_bytes(tmp_path):
    data = bytes(range(256)) * 1000
    (tmp_path / "f").write_bytes(data)
    counted = []
    assert sha256_file(tmp_path / "f", chunk=4096, counted=counted) == hashlib.sha256(data).hexdigest()
    assert counted == [len(data)]
    assert hash_whole(tmp_path / "f") == (hashlib.sha256(data).hexdigest(), len(data))


def test_a_stopped_hash_is_none(tmp_path):
    (tmp_path / "f").write_bytes(b"x" * 10)
    stop = threading.Event()
    stop.set()
    assert sha256_file(tmp_path / "f", stop=stop) is None


def test_background_hash_gives_the_hash_and_its_bytes_or_raises_its_error(tmp_path):
    (tmp_path / "f").write_bytes(b"abc")
    h = BackgroundHash(tmp_path / "f")
    assert h.result() == hashlib.sha256(b"abc").hexdigest() and h.n_bytes == 3
    with pytest.raises(FileNotFoundError):
        BackgroundHash(tmp_path / "missing").result()
