"""Shared by the raw tree's tests: a tree of two good runs, and a rebuild that checks raw/ is
left byte-identical and returns the quarantine lines."""
import hashlib
import os
import stat

import pytest

from pipeline.progress import Progress
from pipeline.rebuild.flow import rebuild
from pipeline.rebuild.options import EXIT_QUARANTINED
from tests.conftest import STEP_META, query

T = [0.0, 0.1, 0.2, 0.3]
COLS = {"t[s]": T, "x[mm]": [0, 1, 2, 3], "x_ref[mm]": [3] * 4}


class Messages(Progress):
    def __init__(self):
        self.lines = []

    def message(self, text):
        self.lines.append(text)


def snapshot(root) -> dict:
    """Every entry under ``root`` (bytes path -> type, mode, size, mtime, content hash or link
    target), read through directory fds so over-long paths are covered too."""
    out = {}
    for folder, dirs, files, dfd in os.fwalk(os.fsencode(root), follow_symlinks=False):
        for name in dirs + files:
            st = os.lstat(name, dir_fd=dfd)
            key = os.path.join(folder, name)
            if stat.S_ISLNK(st.st_mode):
                out[key] = ("link", os.readlink(name, dir_fd=dfd))
            elif stat.S_ISREG(st.st_mode):
                fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW, dir_fd=dfd)
                with os.fdopen(fd, "rb") as fh:
                    digest = hashlib.sha256(fh.read()).hexdigest()
                out[key] = ("file", st.st_mode, st.st_size, st.st_mtime_ns, digest)
            else:
                out[key] = ("other", st.st_mode, st.st_mtime_ns)
    return out


@pytest.fixture
def tree(raw):
    """Two good runs in two campaigns."""
    raw.csv("c1/a.csv", STEP_META, COLS)
    raw.csv("c2/b.csv", STEP_META, COLS)
    return raw


def rebuild_checked(raw, warehouse, expect_runs=("c1/a", "c2/b"), progress=None):
    """A real rebuild (jobs=1): exit 1, the good runs ingested, raw/ untouched. Returns
    {source_path: [(line, error), ...]} of the quarantine table."""
    before = snapshot(raw.root)
    summary = rebuild(raw.root, warehouse, jobs=1, progress=progress)
    assert snapshot(raw.root) == before
    assert summary.exit_code == EXIT_QUARANTINED
    runs = [r for (r,) in query(warehouse, "SELECT run_id FROM runs ORDER BY run_id")]
    assert set(expect_runs) <= set(runs), runs
    out = {}
    for src, line, err in query(warehouse, "SELECT source_path, line, error FROM quarantine ORDER BY 1, 2"):
        out.setdefault(src, []).append((line, err))
    return out
