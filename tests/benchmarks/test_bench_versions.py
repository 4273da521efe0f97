"""Tests of benchmarks/bench_versions.py's shared step: an edit measured by a child, the copy put back."""
import os
import sys
from pathlib import Path

import pytest

from benchmarks.bench_versions import child_after_edit

ROOT = Path(__file__).resolve().parents[2]


def _edit(path: Path) -> bytes:
    old = path.read_bytes()
    path.write_bytes(old + b"changed\n")
    return old


def test_the_child_sees_the_edit_and_the_file_comes_back_with_its_mtime(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    victim = raw / "notes.txt"
    victim.write_bytes(b"original\n")
    os.utime(victim, ns=(1_000_000_000, 2_000_000_000))
    child = [sys.executable, "-c",
             f"import json; print('noise'); print('RESULT ' + json.dumps({{'seen': open({str(victim)!r}).read()}}))"]
    got = child_after_edit(victim, _edit, child, tree=ROOT, data=tmp_path, cwd=tmp_path, label="x")
    assert got == {"seen": "original\nchanged\n"}
    assert victim.read_bytes() == b"original\n"
    assert victim.stat().st_mtime_ns == 2_000_000_000
    assert (tmp_path / "warehouse").is_dir()  # the copy rebuilt by the tree's code after the put-back


def test_a_child_that_prints_no_result_names_its_label_and_still_puts_the_file_back(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    victim = raw / "notes.txt"
    victim.write_bytes(b"original\n")
    child = [sys.executable, "-c", "import sys; sys.stderr.write('the child failed'); sys.exit(3)"]
    with pytest.raises(SystemExit, match="round 2: .*the child failed"):
        child_after_edit(victim, _edit, child, tree=ROOT, data=tmp_path, cwd=tmp_path, label="round 2")
    assert victim.read_bytes() == b"original\n"
