"""Tests of pipeline.own_files: a file the warehouse wrote is read back only when it is what it should be."""
from __future__ import annotations

import os

import pytest

from pipeline.own_files import read_own_file


def test_reads_a_regular_file_within_the_limit(tmp_path):
    p = tmp_path / "cache.json"
    p.write_bytes(b"0123456789")
    assert read_own_file(p, 10) == b"0123456789"
    assert read_own_file(p, 9) is None                 # one byte over the limit


def test_missing_file_is_none(tmp_path):
    assert read_own_file(tmp_path / "nope", 100) is None


def test_symlinked_file_is_not_followed(tmp_path):
    target = tmp_path / "secret"
    target.write_bytes(b"not ours")
    link = tmp_path / "cache.json"
    link.symlink_to(target)
    assert read_own_file(link, 100) is None


def test_file_in_a_symlinked_folder_is_not_read(tmp_path):
    real = tmp_path / "real"
    real.mkdir()
    (real / "cache.json").write_bytes(b"x")
    (tmp_path / "cache").symlink_to(real, target_is_directory=True)
    assert read_own_file(tmp_path / "cache" / "cache.json", 100) is None
    assert read_own_file(real / "cache.json", 100) == b"x"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_fifo_is_not_read_and_does_not_block(tmp_path):
    fifo = tmp_path / "cache.json"
    os.mkfifo(fifo)
    assert read_own_file(fifo, 100) is None            # O_NONBLOCK: no writer, no hang


def test_a_folder_is_none(tmp_path):
    (tmp_path / "cache.json").mkdir()
    assert read_own_file(tmp_path / "cache.json", 100) is None
