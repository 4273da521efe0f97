"""The raw tree: which files are runs, and the ``rig.toml`` and ``manifest.csv`` that apply to them.

Run metadata sources, strongest first (bench-exports.md, "Run metadata"):

1. the ``manifest.csv`` row whose ``file`` column names the run (a manifest applies to its
   folder and below; a nearer manifest overrides a farther one key by key);
2. metadata embedded in the file (the reader's job);
3. ``[metadata]`` defaults of the nearest ``rig.toml`` (a subfolder's overrides its parent's).

Nothing here writes to the raw tree.

Walking raw/ (:func:`walk_raw`, one ``os.scandir`` per folder, folder symlinks never followed,
so a link loop cannot make the walk endless); every entry that cannot be used is a quarantine
line, never a silent skip:

* **Symlinks.** A symlink to a file *outside* raw/ is quarantined ("symlink to a file outside
  raw/: <target>"): raw/ is the contract, and a link would let the warehouse depend on files
  nobody archives. A dangling link, a link loop and a symlink to a folder anywhere are
  quarantined too (folders are never followed: no loops, no file read twice). A symlink inside
  raw/ to a file inside raw/ is an *alias*: when its target is itself a run (or side file) the
  walk reaches, the link is skipped with a note (the run is read once, under the target's own
  path: no duplicate run); otherwise (its target sits in a dotted folder or has a name that is
  not a run's) the target's bytes are read under the link's own path, and the link's folder's
  rig.toml and manifest apply. The same rules hold for ``rig.toml``, ``manifest.csv`` and
  ``hoses.csv``: a side file linked from outside raw/ is quarantined and not read (runs under a
  quarantined rig.toml or manifest are quarantined too: their metadata cannot be known).
* **Names that are not UTF-8** (Latin-1 bytes from an SMB share): read like any other file;
  wherever the name is shown or stored (``source_path``, ``run_id``, campaign, quarantine,
  report, JSON) each byte that is not UTF-8 is written as ``\\xNN`` (Python's
  ``backslashreplace``: ``b"m\\xe9sure.csv"`` -> ``m\\xe9sure.csv``), and so is a control
  character (a newline in a name would break the one-line quarantine: ``\\x0a``), see
  :func:`display_name`.
  Deterministic and valid UTF-8. Should that text collide with another entry's real name in
  the same folder, the non-UTF-8 entry is quarantined.
* **Paths longer than the OS limit** (``PATH_MAX``, 4096 bytes on Linux, including the final
  NUL): quarantined without being opened; a folder that cannot be listed (permissions, a share
  away) is quarantined with the reason.
* **Anything not a regular file** (a FIFO would block the reader forever, a socket, a device)
  is quarantined.

rig.toml files over :data:`MAX_RIG_BYTES` or nested too deeply for the TOML parser, and
manifest.csv files with a NUL byte, an unclosed quote, a field over the ``csv`` module's limit
(128 KiB) or another CSV syntax error, are quarantined with the line number, and so is every
run under them (the metadata they were to give cannot be known: ingesting those runs with the
remaining sources could silently give them wrong metadata). So are a manifest without a header
row (empty), without a ``file`` column (``File``: the hint says lower case) or with a column
named twice (case-insensitively), and a ``Manifest.csv`` / ``Rig.toml`` named in another case
(the walk knows it is not a run; unread, it would be a silent skip). A manifest row with a value
in a column the header does not name (its values are shifted) quarantines the run it names.
"""
from __future__ import annotations

import copy
import errno
import json
import os
import re
import stat
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.raw.rawfile import open_raw, read_raw_bytes
from pipeline.readers import READERS
from pipeline.readers.base import SideCsvError, decode_text, side_csv_rows

NOT_RUNS = {"manifest.csv", "hoses.csv", "rig.toml"}
SIDE_NAMES = ("manifest.csv", "hoses.csv", "rig.toml")

#: Largest rig.toml read [bytes] (1 MiB: a real one is a few hundred bytes).
MAX_RIG_BYTES = 1 << 20

try:
    #: Longest path the OS opens [bytes], the terminating NUL included.
    PATH_MAX = os.pathconf("/", "PC_PATH_MAX")
except (OSError, ValueError, AttributeError):  # pragma: no cover - not POSIX
    PATH_MAX = 4096


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def display_name(text) -> str:
    """A file name or path as valid UTF-8 text on one line: bytes that are not UTF-8 (carried
    by Python as lone surrogates, PEP 383) become ``\\xNN`` (``b"m\\xe9sure"`` ->
    ``"m\\xe9sure"``), and so do control characters (a newline in a name: ``\\x0a``)."""
    text = str(text)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        try:
            text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:  # a surrogate that is not an escaped byte
            text = text.encode("utf-8", "backslashreplace").decode("utf-8")
    if _CONTROL.search(text):
        text = _CONTROL.sub(lambda m: f"\\x{ord(m.group()):02x}", text)
    return text

#: Tables a rig.toml may have (docs/inputs.md): each must be a table.
RIG_TABLES = ("read", "channels", "metadata", "sensors", "derived")


@dataclass
class Problem:
    """An input (or a line of one) that cannot be used: a future quarantine row.

    ``source_path`` and ``error`` are made valid UTF-8 (:func:`display_name`): they land in
    DuckDB, Parquet, JSON and the report.
    """

    source_path: str
    error: str
    line: int | None = None
    stage: str = "ingest"

    def __post_init__(self):
        self.source_path = display_name(self.source_path)
        self.error = display_name(self.error)


def is_run_file(path: Path) -> bool:
    """Whether a file under raw/ is a run export (not a manifest, logbook, config or dotfile)."""
    return not is_known_non_run(path) and path.suffix.lower() in READERS


def is_known_non_run(path: Path) -> bool:
    """Files the contract names as not runs: manifests, logbooks, rig.toml, TDMS indexes,
    dotfiles and READMEs."""
    name = path.name
    return (name.startswith(".") or name.upper().startswith("README") or name.lower() in NOT_RUNS
            or name.lower().endswith(".tdms_index"))


@dataclass
class Listing:
    """What :func:`walk_raw` found under raw/ (paths absolute, each list sorted by relative path).

    Attributes
    ----------
    runs : list of Path
        Run files (regular files, or symlinks read under their own path).
    side : list of Path
        ``manifest.csv``, ``rig.toml`` and ``hoses.csv`` files that can be read.
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


def _os_reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


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
    """
    root = os.path.realpath(raw)
    out = Listing()
    keys: dict[int, bytes] = {}  # id(Path) -> its path relative to raw/ as bytes: the sort key

    def rel_of(path: str) -> str:
        return display_name(os.path.relpath(path, root).replace(os.sep, "/"))

    def problem(path: str, msg: str) -> None:
        out.problems.append(Problem(rel_of(path), msg))

    def classify(p: Path, key: bytes) -> None:
        name = p.name
        if name.lower() in NOT_RUNS and not name.startswith("."):
            dest = out.side
        elif is_run_file(p):
            dest = out.runs
        elif not is_known_non_run(p):
            dest = out.ignored
        else:
            return
        dest.append(p)
        keys[id(p)] = key

    todo: list[tuple[Path, bytes]] = [(Path(root), b"")]
    while todo:
        folder_p, prefix = todo.pop()
        folder = str(folder_p)
        try:
            with os.scandir(folder) as it:
                entries = sorted(it, key=lambda e: os.fsencode(e.name))
        except OSError as exc:
            if folder == root:
                raise
            problem(folder, f"folder cannot be listed: {_os_reason(exc)}; its files are not read")
            continue
        sub = []
        shown = Counter(display_name(e.name) for e in entries)
        for e in entries:
            path = e.path
            hidden = e.name.startswith(".")
            if hidden and not e.is_dir(follow_symlinks=False) and e.name not in (".", ".."):
                continue  # a dotfile: never read
            if display_name(e.name) != e.name and shown[display_name(e.name)] > 1:
                problem(path, f"name is not valid UTF-8 and its escaped form `{display_name(e.name)}` is "
                              "the name of another entry in the same folder; rename one of them")
                continue
            if len(os.fsencode(path)) >= PATH_MAX:
                if not hidden and e.is_dir(follow_symlinks=False):
                    _beyond_path_max(folder, e.name, problem)
                elif not hidden:
                    problem(path, f"path is {len(os.fsencode(path))} bytes, longer than the OS limit "
                                  f"({PATH_MAX - 1} bytes): it cannot be opened; shorten its folder names")
                continue
            try:
                is_link = e.is_symlink()
                is_dir = not is_link and e.is_dir(follow_symlinks=False)
                is_file = not is_link and e.is_file(follow_symlinks=False)
            except OSError as exc:
                if not hidden:
                    problem(path, f"cannot be examined: {_os_reason(exc)}")
                continue
            if hidden:
                continue  # dotted folders are never read
            key = prefix + os.fsencode(e.name)
            if is_dir:
                sub.append((folder_p / e.name, key + b"/"))
            elif is_file:
                classify(folder_p / e.name, key)
            elif is_link:
                _symlink(path, root, out, problem, lambda p, k=key: classify(Path(p), k))
            else:
                problem(path, f"not a regular file ({_file_kind(path)}): not read")
        todo += reversed(sub)
    for paths in (out.runs, out.side, out.ignored):
        paths.sort(key=lambda p: keys[id(p)])
    return out


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
        problem(os.path.join(folder, name), f"folder cannot be listed: {_os_reason(exc)}; its files are not read")
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
                    problem(path, f"folder cannot be listed: {_os_reason(exc)}; its files are not read")
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


def _file_kind(path: str) -> str:
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return "unknown type"
    return ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "unknown type")


def _symlink(path: str, root: str, out: Listing, problem, classify) -> None:
    """Quarantine, skip or read a symlink (module docstring, "Symlinks")."""
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
            problem(path, f"symlink to {link} cannot be followed: {_os_reason(exc)}")
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
        problem(path, f"symlink to {link}, which is not a regular file ({_file_kind(target)}): not read")
        return
    rel_target = os.path.relpath(target, root)
    if rel_target.startswith(".." + os.sep) or rel_target == "..":
        problem(path, f"symlink to a file outside raw/: {display_name(target)}")
        return
    tname = os.path.basename(target)
    same_role = (tname.lower() == os.path.basename(path).lower() if os.path.basename(path).lower() in NOT_RUNS
                 else is_run_file(Path(target)))
    if inside and same_role and not tname.startswith("."):
        out.skipped.append((display_name(os.path.relpath(path, root)),
                            f"symlink to {display_name(rel_target)}, which is read under its own path"))
        return
    classify(path)


def skip_reason(path: Path) -> str:
    """Why a file under raw/ that is not a known side file is not read as a run."""
    suffix = path.suffix.lower()
    return f"not a supported format: {suffix}" if suffix else "not a supported format: no file extension"


def discover_runs(raw, ignored: list[Path] | None = None) -> list[Path]:
    """Every run file under ``raw`` (a folder, or a :class:`RawTree` whose walk is reused),
    sorted by relative path (see :func:`walk_raw`).

    Files that are neither runs nor :func:`is_known_non_run` (a spreadsheet, a photo) are
    appended to ``ignored`` when a list is given, so the caller can say so.
    """
    listing = raw.listing() if isinstance(raw, RawTree) else walk_raw(Path(raw))
    if ignored is not None:
        ignored += listing.ignored
    return list(listing.runs)


def deep_merge(base: dict, over: dict) -> dict:
    """``over`` on top of ``base``; nested tables merge key by key."""
    out = dict(base)
    for k, v in over.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


class ConfigError(Exception):
    """A rig.toml or manifest that applies to a run cannot be used."""


@dataclass
class RawTree:
    """The raw tree with its rig.toml and manifest files parsed once (cached per folder)."""

    root: Path
    problems: list[Problem] = field(default_factory=list)
    _rigs: dict = field(default_factory=dict)
    _manifests: dict = field(default_factory=dict)
    _real: dict = field(default_factory=dict)
    _real_dirs: dict = field(default_factory=dict)
    _rig_cache: dict = field(default_factory=dict)
    _rels: dict = field(default_factory=dict)
    _chains: dict = field(default_factory=dict)

    _listing: Listing | None = None
    _entries: dict = field(default_factory=dict)

    def __post_init__(self):
        self.root = Path(self.root).resolve()

    def listing(self) -> Listing:
        """The walk of the raw tree (:func:`walk_raw`), done once; its problems join
        :attr:`problems` the first time."""
        if self._listing is None:
            self._listing = walk_raw(self.root)
            self.problems += self._listing.problems
        return self._listing

    def _entry(self, path: Path) -> Listing:
        """What :func:`walk_raw` says about this one entry (without walking the tree: worker
        processes ask about the side files of their runs only)."""
        out = Listing()
        p = str(path)
        if p in self._entries:
            return self._entries[p]
        if self._listing is not None:
            out.problems = [x for x in self._listing.problems if x.source_path == self.rel(path)]
            out.skipped = [x for x in self._listing.skipped if x[0] == self.rel(path)]
        elif os.path.lexists(p):
            root = str(self.root)

            def problem(q, msg):
                out.problems.append(Problem(self.rel(path), msg))

            if len(os.fsencode(p)) >= PATH_MAX:
                problem(p, "path longer than the OS limit")
            elif os.path.islink(p):
                _symlink(p, root, out, problem, lambda q: None)
            elif not os.path.isfile(p) and not os.path.isdir(p):
                problem(p, f"not a regular file ({_file_kind(p)}): not read")
        self._entries[p] = out
        return out

    def _entry_problem(self, path: Path) -> str | None:
        probs = self._entry(path).problems
        return probs[0].error if probs else None

    def _miscased(self, folder: Path, name: str) -> ConfigError | None:
        """A side file in ``folder`` whose name is ``name`` in another case (``Manifest.csv``,
        ``RIG.TOML``): the walk knows it is not a run, yet it is not read, so the metadata it was
        to give cannot be known. Each such file is a quarantine line (once) and the returned
        ConfigError quarantines the runs it applies to; None when there is none."""
        cache = self.__dict__.setdefault("_miscased_cache", {})
        key = (str(folder), name)
        if key not in cache:
            try:
                found = sorted(n for n in os.listdir(folder) if n.lower() == name and n != name)
            except OSError:
                found = []
            err = None
            for n in found:
                what = "a manifest" if name == "manifest.csv" else f"a {name}"
                msg = f"named `{display_name(n)}`: {what} must be named `{name}` (lower case); it is not read"
                self.problems.append(Problem(self.rel(folder / n), msg))
                err = err or ConfigError(f"cannot use {self.rel(folder / n)}: {msg}")
            cache[key] = err
        return cache[key]

    def real(self, path: Path) -> Path:
        """The path with its folders resolved but not its last component (a symlink inside raw/
        keeps its own path), cached (a rebuild asks for every file's several times)."""
        key = str(path)
        out = self._real.get(key)
        if out is None:
            parent, name = os.path.split(key)
            folder = self._real_dirs.get(parent)
            if folder is None:  # one realpath per folder, not per file (10,000 files: 0.5 s)
                folder = self._real_dirs[parent] = Path(os.path.realpath(parent or "."))
            out = self._real[key] = folder / name if name else Path(os.path.realpath(key))
        return out

    def rel(self, path: Path) -> str:
        """Path relative to raw/ as shown and stored: ``/``-separated, valid UTF-8
        (:func:`display_name`); cached, as :meth:`real` is (a rebuild asks for it per file
        several times)."""
        key = str(path)
        out = self._rels.get(key)
        if out is None:
            real = str(self.real(path))
            prefix = self.__dict__.get("_root_prefix") or self.__dict__.setdefault(
                "_root_prefix", str(self.root).rstrip("/") + "/")
            if real.startswith(prefix):
                out = display_name(real[len(prefix):])
            else:  # raw/ itself, or not under raw/ (a caller's mistake): still one clear line
                try:
                    out = display_name(Path(real).relative_to(self.root).as_posix())
                except ValueError:
                    out = display_name(Path(real).as_posix())
            self._rels[key] = out
        return out

    def campaign(self, path: Path) -> str | None:
        parts = Path(self.rel(path)).parts
        return parts[0] if len(parts) > 1 else None

    def _folders(self, path: Path) -> list[Path]:
        """Folders from raw/ down to the file's folder."""
        key = os.path.dirname(str(path))  # cached by the folder as given: no Path built per call
        chain = self._chains.get(key)
        if chain is None:
            folder = self.real(path).parent
            chain, f = [folder], folder
            while f != self.root and self.root in f.parents:
                f = f.parent
                chain.append(f)
            chain = self._chains[key] = list(reversed(chain))
        return chain

    # -- rig.toml ---------------------------------------------------------------------------
    def _rig_file(self, folder: Path) -> dict:
        if folder not in self._rigs:
            f = folder / "rig.toml"
            cfg: dict | ConfigError = {}
            blocked = self._entry_problem(f)
            miscased = self._miscased(folder, "rig.toml")
            if blocked is not None:  # a quarantine row of its own (walk_raw)
                cfg = ConfigError(f"cannot use {self.rel(f)}: {blocked}")
            elif miscased is not None:
                cfg = miscased
            elif os.path.isfile(f):
                msg = None
                try:
                    with open_raw(self.root, f) as opened:  # no symlink out of raw/ followed since the walk
                        size = opened.size
                        if size > MAX_RIG_BYTES:
                            msg = f"{size} bytes, larger than the {MAX_RIG_BYTES} bytes a rig.toml may have"
                        else:
                            cfg = tomllib.loads(decode_text(opened.read_bytes())[0])
                except tomllib.TOMLDecodeError as exc:
                    msg = f"invalid TOML: {exc}"
                except (RecursionError, MemoryError):
                    msg = "invalid TOML: too deeply nested (arrays or inline tables inside each other)"
                except OSError as exc:
                    msg = f"cannot read: {_os_reason(exc)}"
                if msg is not None:
                    self.problems.append(Problem(self.rel(f), msg))
                    cfg = ConfigError(f"cannot use {self.rel(f)}: {msg}")
                else:
                    bad = [k for k in cfg if k not in RIG_TABLES]
                    for k in RIG_TABLES:
                        if k in cfg and not isinstance(cfg[k], dict):
                            bad.append(k)
                    if bad:
                        msg = (f"unknown or malformed table(s) {', '.join(sorted(set(bad)))} "
                               f"(expected {', '.join(f'[{t}]' for t in RIG_TABLES)})")
                        self.problems.append(Problem(self.rel(f), msg))
                        cfg = ConfigError(f"cannot use {self.rel(f)}: {msg}")
            self._rigs[folder] = cfg
        return self._rigs[folder]

    def rig_config(self, path: Path) -> dict:
        """The merged rig.toml (``read``, ``channels``, ``metadata``, ``sensors``, ``derived``) that
        applies to a run."""
        folder = self.real(path).parent
        cfg = self._rig_cache.get(folder)
        if cfg is None:  # the same for every run of a folder: merged once
            cfg = {}
            for f in self._folders(path):
                part = self._rig_file(f)
                if isinstance(part, ConfigError):
                    cfg = part
                    break
                cfg = deep_merge(cfg, part)
            if not isinstance(cfg, ConfigError):
                cfg = {k: cfg.get(k, {}) for k in RIG_TABLES}
            self._rig_cache[folder] = cfg
        if isinstance(cfg, ConfigError):
            raise cfg
        return copy.deepcopy(cfg)

    def rig_json(self, path: Path) -> str:
        """:meth:`rig_config` as canonical JSON (sorted keys), computed once per folder."""
        folder = self.real(path).parent
        cache = self.__dict__.setdefault("_rig_json", {})
        if folder not in cache:
            try:
                cache[folder] = json.dumps(self.rig_config(path), sort_keys=True, default=str)
            except ConfigError as exc:
                cache[folder] = exc
        out = cache[folder]
        if isinstance(out, ConfigError):
            raise out
        return out

    # -- manifest.csv -------------------------------------------------------------------------
    def _manifest(self, folder: Path) -> dict[str, dict] | ConfigError:
        """Rows of a folder's manifest.csv by the path of the file they name (folders resolved),
        or a ConfigError when the manifest cannot be read (its problem is recorded once)."""
        if folder in self._manifests:
            return self._manifests[folder]
        rows: dict[str, dict] | ConfigError = {}
        f = folder / "manifest.csv"
        blocked = self._entry_problem(f)
        miscased = self._miscased(folder, "manifest.csv")
        if blocked is not None:  # a quarantine row of its own (walk_raw)
            rows = ConfigError(f"cannot use {self.rel(f)}: {blocked}")
        elif miscased is not None:
            rows = miscased
        elif os.path.isfile(f):
            try:
                rows = self._parse_manifest(folder, f)
            except _BadManifest as exc:
                msg, line = exc.args
                self.problems.append(Problem(self.rel(f), msg, line))
                rows = ConfigError(f"cannot use {self.rel(f)}: line {line}: {msg}" if line
                                   else f"cannot use {self.rel(f)}: {msg}")
        self._manifests[folder] = rows
        return rows

    def _parse_manifest(self, folder: Path, f: Path) -> dict[str, dict]:
        rel_manifest = self.rel(f)
        try:
            data = read_raw_bytes(self.root, f)  # no symlink out of raw/ followed since the walk
        except OSError as exc:
            raise _BadManifest(f"cannot read: {_os_reason(exc)}", None) from None
        rows: dict[str, dict] = {}
        parsed = side_csv_rows(data)
        try:
            fields = None
            for _first, line, cells in parsed:
                if fields is None:
                    if not any(c.strip() for c in cells):
                        continue  # blank lines before the header
                    fields = [h.strip() for h in cells]
                    _check_manifest_header(fields, line)
                    continue
                extra = _unnamed_value(fields, cells)
                row = dict(zip(fields, cells))
                self._manifest_row(folder, rel_manifest, rows, row, line, extra)
        except SideCsvError as exc:
            raise _BadManifest(*exc.args) from None
        if fields is None:
            raise _BadManifest("no header row (an empty manifest: a header naming the `file` column comes first)",
                               None)
        return rows

    def _manifest_row(self, folder: Path, rel_manifest: str, rows: dict, row: dict, line: int,
                      extra: str | None = None) -> None:
        """Record one manifest row (or the problem with it) in ``rows``. ``extra``: why the row's
        values cannot be known (a value under no header name); the run it names then gets a
        ConfigError instead of metadata."""
        name = (row.get("file") or "").strip()
        if not name:
            if any((v or "").strip() for v in row.values() if isinstance(v, str)):
                self.problems.append(Problem(rel_manifest, "row has no `file`", line))
            return
        part = None  # `book.xlsx#Sheet2`: one sheet / MDF group of a file of several runs
        if "#" in name and not os.path.isfile(folder / name):
            name, part = name.rsplit("#", 1)
            if not part.strip():
                self.problems.append(Problem(rel_manifest, f"entry `{name}#` names no sheet or group after `#`", line))
                return
        try:
            named = folder / name
            target = (Path(os.path.realpath(named)) if named.name in ("", ".", "..")
                      else self.real(named))
        except (OSError, ValueError) as exc:
            self.problems.append(Problem(rel_manifest, f"entry `{name}` cannot be a file name: {exc}", line))
            return
        if target != self.root and self.root not in target.parents:
            self.problems.append(Problem(rel_manifest, f"entry `{name}` points outside raw/", line))
            return
        if folder not in target.parents:
            self.problems.append(Problem(rel_manifest, f"entry `{name}` is not in the manifest's folder "
                                         "or below (a manifest applies only there)", line))
            return
        if not os.path.isfile(target):
            self.problems.append(Problem(rel_manifest, f"entry `{name}`: no such file", line))
            return
        if os.path.islink(target):
            alias = [why for _rel, why in self._entry(target).skipped]
            if alias:
                self.problems.append(Problem(rel_manifest, f"entry `{name}` is a {alias[0]}; "
                                             "name that file instead", line))
                return
        key = target.as_posix() if part is None else f"{target.as_posix()}\x00{part}"  # NUL: in no path
        if key in rows:
            self.problems.append(Problem(rel_manifest, f"entry `{name}` is listed twice; the later row is used", line))
        if extra is not None:
            self.problems.append(Problem(rel_manifest, extra, line))
            rows[key] = ConfigError(f"cannot use {rel_manifest}: line {line}: {extra}")
            return
        meta = {k: v.strip() for k, v in row.items()
                if k and k != "file" and isinstance(v, str) and v.strip() != ""}
        rows[key] = meta

    def _manifest_chain(self, path: Path) -> tuple[dict, dict]:
        """The manifests that apply to a folder, merged once per folder (nearer manifests
        override farther ones): (file -> metadata, file -> part -> metadata). Raises ConfigError
        when a manifest of the folder or above cannot be read."""
        key = os.path.dirname(str(path))
        cache = self.__dict__.setdefault("_manifest_chains", {})
        hit = cache.get(key)
        if hit is None:
            metas: dict[str, dict] = {}
            parts: dict[str, dict[str, dict]] = {}
            try:
                for folder in self._folders(path):
                    rows = self._manifest(folder)
                    if isinstance(rows, ConfigError):
                        raise rows
                    for k, meta in rows.items():
                        if "\x00" in k:
                            file, part = k.split("\x00", 1)
                            _merge_row(parts.setdefault(file, {}), part, meta)
                        else:
                            _merge_row(metas, k, meta)
                hit = (metas, parts)
            except ConfigError as exc:
                hit = exc
            cache[key] = hit
        if isinstance(hit, ConfigError):
            raise hit
        return hit

    def manifest_metadata(self, path: Path) -> dict:
        """Metadata the manifests give for a run (nearer manifests override farther ones).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        metas, _parts = self._manifest_chain(path)
        meta = metas.get(str(self.real(path)), {})
        if isinstance(meta, ConfigError):  # its row cannot be read: the run waits for it
            raise meta
        return dict(meta)

    def manifest_parts(self, path: Path) -> dict[str, dict]:
        """Metadata the manifests give for single sheets / MDF groups of a file of several runs
        (rows ``file = book.xlsx#Sheet2``): part name -> metadata (nearer manifests override).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        _metas, parts = self._manifest_chain(path)
        out = parts.get(str(self.real(path)), {})
        for meta in out.values():
            if isinstance(meta, ConfigError):
                raise meta
        return {part: dict(meta) for part, meta in out.items()}

    def _side(self, name: str) -> list[Path]:
        return [p for p in self.listing().side if p.name.lower() == name]  # `Manifest.csv` too: refused

    def scan_manifests(self) -> None:
        """Parse every manifest once so that bad entries are reported even if no run uses them."""
        for f in self._side("manifest.csv"):
            self._manifest(self.real(f).parent)

    def scan_rigs(self) -> None:
        """Parse every rig.toml once so that a bad one is reported even if no run uses it."""
        for f in self._side("rig.toml"):
            self._rig_file(self.real(f).parent)


class _BadManifest(Exception):
    """args: (message, line or None)."""


def _check_manifest_header(fields: list[str], line: int) -> None:
    """Refuse a manifest header that cannot say which value is which key: no `file` column, or a
    column named twice (keys are matched case-insensitively, so `notes` and `Notes` too)."""
    if "file" not in fields:
        hint = next((f for f in fields if f.casefold() == "file"), None)
        raise _BadManifest("no `file` column in the header" + (
            f" (`{hint}` is not `file`: the column is named in lower case)" if hint else ""), None)
    seen: dict[str, int] = {}
    for i, name in enumerate(fields, start=1):
        if not name:
            continue
        first = seen.setdefault(name.casefold(), i)
        if first != i:
            raise _BadManifest(f"column `{name}` appears twice in the header (columns {first} and {i}; "
                               "names are matched case-insensitively)", line)


def _unnamed_value(fields: list[str], cells: list[str]) -> str | None:
    """Why a manifest row cannot be read: a value in a column the header does not name (beyond
    its last column, or under an empty name), which shifts the row's values; else None."""
    for i, cell in enumerate(cells):
        if cell.strip() and (i >= len(fields) or not fields[i]):
            return (f"row has a value in column {i + 1} (`{display_name(cell.strip()[:40])}`), which the header "
                    "does not name (an unquoted delimiter in a value?)")
    return None


def _merge_row(into: dict, key: str, meta) -> None:
    """A manifest row on top of what farther manifests gave (a nearer one overrides key by key);
    a row that cannot be read (ConfigError) stays an error whichever manifest it is in."""
    old = into.get(key)
    if isinstance(old, ConfigError):
        return
    if isinstance(meta, ConfigError):
        into[key] = meta
    else:
        into.setdefault(key, {}).update(meta)
