"""Opening a file of raw/ once, without following a symlink out of raw/, and reading only that.

raw/ is listed first (:func:`pipeline.raw.walk.walk_raw`, where symlinks are checked) and its
files are read later, in worker processes. A file replaced by a symlink to a file outside raw/
between the two must not be read (issue 21). So a file is opened once, here, and every later
read (its hash, the reader, a library that wants a path) goes through that descriptor:

* the path is opened from raw/ down, one folder at a time (``openat`` with ``O_NOFOLLOW``):
  a folder that became a symlink is refused; a last component that is a symlink is followed
  only when it resolves to a file inside raw/ (an alias the walk reads under the link's own
  path) and that target is opened the same way;
* the descriptor is checked with ``fstat``: a regular file (a FIFO swapped in would block,
  ``O_NONBLOCK`` keeps the open itself from blocking), and the inode the scan saw when the
  caller passes it;
* :attr:`RawFile.source` is the path the readers get: a symlink named as the file (same name,
  same extension: libraries that choose a format by extension still do) in a private folder
  (``mkdtemp``, mode 0700, one per process, in ``/dev/shm`` when there is one: a folder made
  and removed per file on a journaling disk costs milliseconds), pointing at
  ``/proc/self/fd/N``. Opening it opens the inode of the descriptor, whatever the name in raw/
  points at by then; it is removed with the descriptor, the folder when the process exits (the
  folder of a process killed with SIGKILL by the next process that makes one).
  Where ``/proc/self/fd`` does not exist (not Linux) it is the path itself.

:class:`RawOpenError` is an ``OSError`` whose message is the one-line quarantine reason.
"""
from __future__ import annotations

import errno
import multiprocessing.util
import os
import shutil
import stat
import tempfile
import threading
from pathlib import Path

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_DIR_FLAGS = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | _NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
_FILE_FLAGS = (os.O_RDONLY | _NOFOLLOW | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
               | getattr(os, "O_CLOEXEC", 0))
_PROC_FD = "/proc/self/fd"

# The private folder of this process (a forked worker makes its own) and its free slots: one
# subfolder per file open at the same time, so that two files of the same name never meet.
_LINKS: dict = {"pid": None, "dir": None, "free": [], "n": 0}
_LINKS_LOCK = threading.Lock()


def _take_slot() -> str:
    with _LINKS_LOCK:
        if _LINKS["pid"] != os.getpid():
            shm = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
            _remove_stale(shm or tempfile.gettempdir())
            folder = tempfile.mkdtemp(prefix=f"pneubench-open-{os.getpid()}-", dir=shm)
            _LINKS.update(pid=os.getpid(), dir=folder, free=[], n=0)
            # at exit, also of a worker of a multiprocessing pool (which skips atexit)
            multiprocessing.util.Finalize(None, shutil.rmtree, args=(folder, True), exitpriority=0)
        if _LINKS["free"]:
            return _LINKS["free"].pop()
        _LINKS["n"] += 1
        slot = os.path.join(_LINKS["dir"], str(_LINKS["n"]))
        os.mkdir(slot, 0o700)
        return slot


def _remove_stale(base: str) -> None:
    """Remove this user's link folders of processes that are gone (a worker killed with
    SIGKILL, a stuck reader's, cannot remove its own)."""
    try:
        entries = list(os.scandir(base))
    except OSError:
        return
    for e in entries:
        parts = e.name.split("-")
        if len(parts) != 4 or e.name[:15] != "pneubench-open-" or not parts[2].isdigit():
            continue
        try:
            if e.stat(follow_symlinks=False).st_uid != os.getuid() or not e.is_dir(follow_symlinks=False):
                continue
            os.kill(int(parts[2]), 0)
        except ProcessLookupError:
            shutil.rmtree(e.path, ignore_errors=True)
        except OSError:
            continue


def _give_slot(slot: str) -> None:
    with _LINKS_LOCK:
        if os.path.dirname(slot) == _LINKS["dir"]:
            _LINKS["free"].append(slot)


class RawOpenError(OSError):
    """A file of raw/ that is not opened; ``str(exc)`` (and ``strerror``) is the one-line reason."""

    def __init__(self, message: str):
        super().__init__(message)
        self.strerror = message


def _kind(mode: int) -> str:
    return ("a folder" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "unknown type")


def _open_below(root: str, parts: list[str]) -> int:
    """Descriptor of ``root/parts...``, no symlink followed on the way (ELOOP when the last
    component is one)."""
    fd = os.open(root, _DIR_FLAGS & ~_NOFOLLOW)  # raw/ itself may be reached through a link
    try:
        for i, part in enumerate(parts[:-1]):
            try:
                nfd = os.open(part, _DIR_FLAGS, dir_fd=fd)
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR) and os.path.islink(os.path.join(root, *parts[:i + 1])):
                    raise RawOpenError(f"folder {'/'.join(parts[:i + 1])} is a symlink: folders are not "
                                       "followed (replaced after raw/ was listed)") from None
                raise
            os.close(fd)
            fd = nfd
        return os.open(parts[-1], _FILE_FLAGS, dir_fd=fd)
    finally:
        os.close(fd)


def open_raw(root, path, inode: int | None = None) -> "RawFile":
    """Open ``path``, a file under the raw folder ``root`` (resolved), as described in the
    module docstring; ``inode``: the one the scan saw (refused when another file is there).

    Raises
    ------
    RawOpenError
        A symlink out of raw/, a folder that became a symlink, not a regular file, another
        inode than the scan saw.
    OSError
        The file cannot be opened (gone, permissions).
    """
    root, path = os.fspath(root), os.fspath(path)
    rel = os.path.relpath(path, root)
    if rel == ".." or rel.startswith(".." + os.sep):  # given through a symlink above raw/ (a caller's path)
        rel = os.path.relpath(os.path.join(os.path.realpath(os.path.dirname(path)), os.path.basename(path)), root)
    if rel in (".", "..") or rel.startswith(".." + os.sep):
        raise RawOpenError(f"not a file under raw/: {path}")
    try:
        fd = _open_below(root, rel.split(os.sep))
    except OSError as exc:
        if isinstance(exc, RawOpenError) or exc.errno != errno.ELOOP:
            raise
        # the last component is a symlink: read only a target inside raw/ (an alias)
        target = os.path.realpath(os.path.join(root, rel))
        rel_target = os.path.relpath(target, root)
        if rel_target in (".", "..") or rel_target.startswith(".." + os.sep):
            raise RawOpenError(f"symlink to a file outside raw/: {target}") from None
        try:
            fd = _open_below(root, rel_target.split(os.sep))
        except OSError as exc2:
            if isinstance(exc2, RawOpenError) or exc2.errno != errno.ELOOP:
                raise
            raise RawOpenError(f"symlink {rel} changed while it was opened: not read") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise RawOpenError(f"not a regular file ({_kind(st.st_mode)}): not read")
        if inode is not None and st.st_ino != inode:
            raise RawOpenError("file was replaced after raw/ was listed; will be read again at the next rebuild")
    except BaseException:
        os.close(fd)
        raise
    return RawFile(Path(path), fd, st)


class RawFile:
    """A file of raw/ opened by :func:`open_raw`: its descriptor, its ``fstat`` and the path to
    give readers (:attr:`source`). A context manager; :meth:`close` removes :attr:`source`."""

    def __init__(self, path: Path, fd: int, st: os.stat_result):
        self.path, self.fd, self.stat = path, fd, st
        self._dir: str | None = None
        self._source: Path | None = None

    @property
    def size(self) -> int:
        """Size of the opened file when it was opened [B]."""
        return self.stat.st_size

    @property
    def source(self) -> Path:
        """Path that opens this descriptor's file: ``<private folder>/<file name>`` ->
        ``/proc/self/fd/N`` (made on first use)."""
        if self._source is None:
            if not os.path.isdir(_PROC_FD):  # pragma: no cover - not Linux
                self._source = self.path
            else:
                self._dir = _take_slot()
                link = os.path.join(self._dir, self.path.name)
                os.symlink(f"{_PROC_FD}/{self.fd}", link)
                self._source = Path(link)
        return self._source

    def read_bytes(self) -> bytes:
        """The whole file, read from the descriptor (``pread``: the offset is not moved)."""
        chunks, off = [], 0
        while True:
            block = os.pread(self.fd, 1 << 20, off)
            if not block:
                return b"".join(chunks)
            chunks.append(block)
            off += len(block)

    def close(self) -> None:
        if self._dir is not None:
            try:
                os.unlink(os.path.join(self._dir, self.path.name))
                _give_slot(self._dir)
            except OSError:
                pass
            self._dir = None
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def __enter__(self) -> "RawFile":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_raw_bytes(root, path) -> bytes:
    """The bytes of a side file of raw/ (manifest.csv, rig.toml, hoses.csv), opened by
    :func:`open_raw`."""
    with open_raw(root, path) as f:
        return f.read_bytes()
