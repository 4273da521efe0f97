"""Reading back a file the warehouse wrote for itself (a cache, a stage's stored designs), trusting nothing.

The warehouse folder is the lab's disk: a file there may have been replaced by a symlink, a FIFO or
something huge. :func:`read_own_file` reads one only when it is a regular file, not larger than the
caller's limit, in a folder that is not a symlink, opened without following a symlink and without
blocking on a FIFO; otherwise it answers None and the caller builds the content again.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path


def read_own_file(path: Path, max_bytes: int) -> bytes | None:
    """The bytes of ``path``, or None when it is missing, not a regular file, larger than
    ``max_bytes`` [B], in a symlinked folder, a symlink itself, or unreadable."""
    try:
        if not stat.S_ISDIR(os.lstat(path.parent).st_mode):   # a symlinked folder is not followed
            return None
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        with os.fdopen(fd, "rb") as fh:
            st = os.fstat(fh.fileno())
            if not stat.S_ISREG(st.st_mode) or st.st_size > max_bytes:
                return None
            return fh.read(max_bytes + 1)
    except OSError:
        return None
