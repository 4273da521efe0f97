"""Walking raw/: which entries are runs, which are side files, and why each other entry cannot be used.

:func:`walk_raw` lists raw/ once (one ``os.scandir`` per folder, folder symlinks never followed,
so a link loop cannot make the walk endless); every entry that cannot be used is a quarantine
line, never a silent skip. Nothing here writes to the raw tree.

* **Symlinks.** A symlink to a file *outside* raw/ is quarantined ("symlink to a file outside
  raw/: <target>"): raw/ is the contract, and a link would let the warehouse depend on files
  nobody archives. A dangling link, a link loop and a symlink to a folder anywhere are
  quarantined too (folders are never followed: no loops, no file read twice). A symlink inside
  raw/ to a file inside raw/ is an *alias*: when its target is itself a run (or side file) the
  walk reaches, the link is skipped with a note (the run is read once, under the target's own
  path: no duplicate run); otherwise (its target sits in a dotted folder or has a name that is
  not a run's) the target's bytes are read under the link's own path, and the link's folder's
  rig.toml and manifest apply. The same rules hold for ``rig.toml``, ``manifest.csv``,
  ``hoses.csv`` and ``plan.toml``: a side file linked from outside raw/ is quarantined and not read (runs under a
  quarantined rig.toml or manifest are quarantined too: their metadata cannot be known).
* **Names that are not UTF-8** (Latin-1 bytes from an SMB share): read like any other file;
  wherever the name is shown or stored (``source_path``, ``run_id``, campaign, quarantine,
  report, JSON) each byte that is not UTF-8 is written as ``\\xNN`` (Python's
  ``backslashreplace``: ``b"m\\xe9sure.csv"`` -> ``m\\xe9sure.csv``), and so is a control
  character (a newline in a name would break the one-line quarantine: ``\\x0a``), see
  :func:`pipeline.raw.problems.display_name`.
  Deterministic and valid UTF-8. Should that text collide with another entry's real name in
  the same folder, the non-UTF-8 entry is quarantined.
* **Paths longer than the OS limit** (``PATH_MAX``, 4096 bytes on Linux, including the final
  NUL): quarantined without being opened; a folder that cannot be listed (permissions, a share
  away) is quarantined with the reason.
* **The plan** (``plan.toml``, :mod:`pipeline.raw.plan`) is a side file at the top of raw/ only;
  one in a campaign folder is quarantined (it would otherwise be silently not read).
* **Anything not a regular file** (a FIFO would block the reader forever, a socket, a device)
  is quarantined.
"""
from __future__ import annotations

import errno
import os
import stat
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.raw.problems import Problem, display_name, os_reason
from pipeline.readers import READERS

NOT_RUNS = {"manifest.csv", "hoses.csv", "rig.toml", "plan.toml"}

#: The lab's test plan (:mod:`pipeline.raw.plan`): a side file at the top of raw/ only.
TOP_ONLY = "plan.toml"

try:
    #: Longest path the OS opens [bytes], the terminating NUL included.
    PATH_MAX = os.pathconf("/", "PC_PATH_MAX")
except (OSError, ValueError, AttributeError):  # pragma: no cover - not POSIX
    PATH_MAX = 4096


def is_run_file(path: Path) -> bool:
    """Whether a file under raw/ is a run export (not a manifest, logbook, config or dotfile)."""
    return not is_known_non_run(path) and path.suffix.lower() in READERS


def is_known_non_run(path: Path) -> bool:
    """Files the contract names as not runs: manifests, logbooks, rig.toml, the plan.toml, TDMS
    indexes, dotfiles and READMEs."""
    name = path.name
    return (name.startswith(".") or name.upper().startswith("README") or name.lower() in NOT_RUNS
            or name.lower().endswith(".tdms_index"))


def skip_reason(path: Path) -> str:
    """Why a file under raw/ that is not a known side file is not read as a run."""
    suffix = path.suffix.lower()
    return f"not a supported format: {suffix}" if suffix else "not a supported format: no file extension"


@dataclass
class Listing:
    """What :func:`walk_raw` found under raw/ (paths absolute, each list sorted by relative path).

    Attributes
    ----------
    runs : list of Path
        Run files (regular files, or symlinks read under their own path).
    side : list of Path
        ``manifest.csv``, ``rig.toml`` and ``hoses.csv`` files that can be read, and the
        ``plan.toml`` at the top of raw/.
    ignored : list of Path
        Files that are neither runs nor known non-runs (a spreadsheet, a photo).
    skipped : list of (str, str)
        Entries deliberately not read, with the reason (symlink aliases of files read under
        their own path).
    problems : list of Problem
        Entries that cannot be used (quarantine rows).
    """

    runs: list[Path] = field(default_factory=list)
    side: list[Path] = field(default_factory=list)
    ignored: list[Path] = field(default_factory=list)
    skipped: list[tuple[str, str]] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)


def _walked(root: str, target: str) -> bool:
    """Whether the walk reaches ``target`` (a resolved path) as a regular entry: inside
    ``root``, no dotted folder on the way, path within the OS limit."""
    rel = os.path.relpath(target, root)
    parts = rel.split(os.sep)
    return (not rel.startswith("..") and rel != "." and not any(p.startswith(".") for p in parts[:-1])
            and len(os.fsencode(target)) < PATH_MAX)


def walk_raw(raw: Path) -> Listing:
    """Walk the raw tree once, without following folder symlinks; see the module docstring.

    Dotted folders are skipped, dotfiles and READMEs are known non-runs. Every entry that
    cannot be used becomes a :class:`Problem` (never an exception, never a silent skip).

    Parameters
    ----------
    raw : Path
        The raw folder (resolved here); a raw folder that cannot be listed raises OSError.

    Returns
    -------
    Listing
        Runs, side files, ignored files, skipped aliases and problems.
    """
    walk = _Walk(os.path.realpath(raw))
    todo: list[tuple[Path, bytes]] = [(Path(walk.root), b"")]
    while todo:
        folder_p, prefix = todo.pop()
        todo += reversed(walk.folder(folder_p, prefix))
    return walk.sorted_listing()


@dataclass
class _Walk:
    """One walk of raw/ in progress: what it found so far, and each found file's sort key."""

    root: str
    out: Listing = field(default_factory=Listing)
    keys: dict[int, bytes] = field(default_factory=dict)  # id(Path) -> its path relative to raw/ as bytes: the sort key

    def rel_of(self, path: str) -> str:
        """``path`` relative to raw/, ``/``-separated and valid UTF-8."""
        return display_name(os.path.relpath(path, self.root).replace(os.sep, "/"))

    def problem(self, path: str, msg: str) -> None:
        """Record an entry that cannot be used."""
        self.out.problems.append(Problem(self.rel_of(path), msg))

    def classify(self, p: Path, key: bytes) -> None:
        """File a regular file (or a link read under its own path) as side file, run or ignored."""
        name = p.name
        if name.lower() == TOP_ONLY and str(p.parent) != self.root:
            self.problem(str(p), f"a {TOP_ONLY} is read only at the top of raw/ (raw/{TOP_ONLY}); this one is not read")
            return
        if name.lower() in NOT_RUNS and not name.startswith("."):
            dest = self.out.side
        elif is_run_file(p):
            dest = self.out.runs
        elif not is_known_non_run(p):
            dest = self.out.ignored
        else:
            return
        dest.append(p)
        self.keys[id(p)] = key

    def folder(self, folder_p: Path, prefix: bytes) -> list[tuple[Path, bytes]]:
        """List one folder: its files are filed, its subfolders (with their sort-key prefix)
        returned in name order."""
        folder = str(folder_p)
        try:
            with os.scandir(folder) as it:
                entries = sorted(it, key=lambda e: os.fsencode(e.name))
        except OSError as exc:
            if folder == self.root:
                raise
            self.problem(folder, f"folder cannot be listed: {os_reason(exc)}; its files are not read")
            return []
        shown = Counter(display_name(e.name) for e in entries)
        sub = []
        for e in entries:
            found = self.entry(e, folder_p, prefix, shown)
            if found is not None:
                sub.append(found)
        return sub

    def entry(self, e: os.DirEntry, folder_p: Path, prefix: bytes, shown: Counter) -> tuple[Path, bytes] | None:
        """File one folder entry; a subfolder to walk is returned (with its sort-key prefix)."""
        path = e.path
        hidden = e.name.startswith(".")
        if hidden and not e.is_dir(follow_symlinks=False) and e.name not in (".", ".."):
            return None  # a dotfile: never read
        if display_name(e.name) != e.name and shown[display_name(e.name)] > 1:
            self.problem(path, f"name is not valid UTF-8 and its escaped form `{display_name(e.name)}` is "
                               "the name of another entry in the same folder; rename one of them")
            return None
        if len(os.fsencode(path)) >= PATH_MAX:
            if not hidden and e.is_dir(follow_symlinks=False):
                _beyond_path_max(str(folder_p), e.name, self.problem)
            elif not hidden:
                self.problem(path, f"path is {len(os.fsencode(path))} bytes, longer than the OS limit "
                                   f"({PATH_MAX - 1} bytes): it cannot be opened; shorten its folder names")
            return None
        try:
            is_link = e.is_symlink()
            is_dir = not is_link and e.is_dir(follow_symlinks=False)
            is_file = not is_link and e.is_file(follow_symlinks=False)
        except OSError as exc:
            if not hidden:
                self.problem(path, f"cannot be examined: {os_reason(exc)}")
            return None
        if hidden:
            return None  # dotted folders are never read
        key = prefix + os.fsencode(e.name)
        if is_dir:
            return folder_p / e.name, key + b"/"
        if is_file:
            self.classify(folder_p / e.name, key)
        elif is_link:
            check_symlink(path, self.root, self.out, self.problem, lambda p, k=key: self.classify(Path(p), k))
        else:
            self.problem(path, f"not a regular file ({file_kind(path)}): not read")
        return None

    def sorted_listing(self) -> Listing:
        """The listing, each list sorted by relative path (as bytes)."""
        for paths in (self.out.runs, self.out.side, self.out.ignored):
            paths.sort(key=lambda p: self.keys[id(p)])
        return self.out


def _beyond_path_max(folder: str, name: str, problem) -> None:
    """The run and side files under ``folder/name``, a folder whose path is longer than the OS
    limit: each is a quarantine row naming its own path (the folder's files are never read).

    Listed through folder descriptors (``openat``: one name per call, so no path is too long),
    one descriptor open per level of the folder being listed; no symlink is followed. A folder
    that cannot be listed (permissions, more levels than open files allow) is a row itself.
    """
    def too_long(path: str) -> str:
        return (f"path is {len(os.fsencode(path))} bytes, longer than the OS limit ({PATH_MAX - 1} bytes): "
                "it cannot be opened; shorten its folder names")

    flags = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0)
    try:
        top = os.open(folder, flags)
    except OSError as exc:
        problem(os.path.join(folder, name), f"folder cannot be listed: {os_reason(exc)}; its files are not read")
        return
    stack: list = []  # (fd, its path, iterator over its subfolders' names)
    todo = [(top, name, os.path.join(folder, name))]
    try:
        while todo or stack:
            if todo:
                parent, sub, path = todo.pop()
                try:
                    fd = os.open(sub, flags, dir_fd=parent)
                    with os.scandir(fd) as it:
                        entries = sorted(it, key=lambda x: os.fsencode(x.name))
                except OSError as exc:
                    problem(path, f"folder cannot be listed: {os_reason(exc)}; its files are not read")
                    continue
                subs = []
                for x in entries:
                    if x.name.startswith("."):
                        continue  # dotfiles and dotted folders: never read
                    try:
                        is_dir = x.is_dir(follow_symlinks=False)
                    except OSError:
                        is_dir = False
                    if is_dir:
                        subs.append(x.name)
                    elif x.name.lower() in NOT_RUNS or is_run_file(Path(x.name)):
                        problem(os.path.join(path, x.name), too_long(os.path.join(path, x.name)))
                stack.append((fd, path, iter(subs)))
            fd, path, subs = stack[-1]
            sub = next(subs, None)
            if sub is None:
                os.close(stack.pop()[0])
            else:
                todo.append((fd, sub, os.path.join(path, sub)))
    finally:
        for fd, _path, _subs in stack:
            os.close(fd)
        os.close(top)

def file_kind(path: str) -> str:
    """What an entry that is not a regular file is (``a FIFO (named pipe)``, ``a socket``...)."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return "unknown type"
    return ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "unknown type")

def check_symlink(path: str, root: str, out: Listing, problem, classify) -> None:
    """Quarantine, skip or read a symlink (module docstring, "Symlinks").

    Parameters
    ----------
    path : str
        The link.
    root : str
        raw/, resolved.
    out : Listing
        Where an alias that is not read is noted (``skipped``).
    problem : callable
        ``problem(path, message)``: records a link that cannot be used.
    classify : callable
        ``classify(path)``: files a link whose target is read under the link's own path.
    """
    try:
        link = display_name(os.readlink(path))
    except OSError:
        link = "?"
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            problem(path, f"symlink loop (-> {link}): not read")
        elif exc.errno in (errno.ENOENT, errno.ENOTDIR):
            problem(path, f"dangling symlink: its target {link} does not exist")
        else:
            problem(path, f"symlink to {link} cannot be followed: {os_reason(exc)}")
        return
    target = os.path.realpath(path)
    inside = _walked(root, target)
    if stat.S_ISDIR(st.st_mode):
        if inside or target == root:
            out.skipped.append((display_name(os.path.relpath(path, root)),
                                f"symlink to the folder {display_name(os.path.relpath(target, root))}, "
                                "whose files are read under their own paths"))
        else:
            where = "outside raw/ " if os.path.relpath(target, root).startswith("..") else ""
            problem(path, f"symlink to a folder {where}({display_name(target)}): folders are not followed; "
                          "copy or move the files into raw/")
        return
    if not stat.S_ISREG(st.st_mode):
        problem(path, f"symlink to {link}, which is not a regular file ({file_kind(target)}): not read")
        return
    rel_target = os.path.relpath(target, root)
    if rel_target.startswith(".." + os.sep) or rel_target == "..":
        problem(path, f"symlink to a file outside raw/: {display_name(target)}")
        return
    tname = os.path.basename(target)
    same_role = (tname.lower() == os.path.basename(path).lower() if os.path.basename(path).lower() in NOT_RUNS
                 else is_run_file(Path(target)))
    if tname.lower() == TOP_ONLY and os.path.dirname(target) != root:
        same_role = False  # a plan.toml deeper down is not read: the link is, under its own path
    if inside and same_role and not tname.startswith("."):
        out.skipped.append((display_name(os.path.relpath(path, root)),
                            f"symlink to {display_name(rel_target)}, which is read under its own path"))
        return
    classify(path)
