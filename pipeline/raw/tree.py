"""The raw tree as the rebuild sees it: its walk done once, what it says about one entry, folder
chains, miscased side files, and paths as stored (``real``, ``rel``, campaign); its ``rig.toml``
(:mod:`pipeline.raw.rig`) and ``manifest.csv`` (:mod:`pipeline.raw.manifest`) files read once.

Run metadata sources, strongest first (bench-exports.md, "Run metadata"):

1. the ``manifest.csv`` row whose ``file`` column names the run (a manifest applies to its
   folder and below; a nearer manifest overrides a farther one key by key);
2. metadata embedded in the file (the reader's job);
3. ``[metadata]`` defaults of the nearest ``rig.toml`` (a subfolder's overrides its parent's).

Nothing here writes to the raw tree.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.raw.manifest import Manifests
from pipeline.raw.problems import ConfigError, Problem, display_name
from pipeline.raw.rig import RigFiles
from pipeline.raw.walk import PATH_MAX, Listing, check_symlink, file_kind, walk_raw


def discover_runs(raw, ignored: list[Path] | None = None) -> list[Path]:
    """Every run file under ``raw`` (a folder, or a :class:`RawTree` whose walk is reused),
    sorted by relative path (see :func:`pipeline.raw.walk.walk_raw`).

    Files that are neither runs nor :func:`pipeline.raw.walk.is_known_non_run` (a spreadsheet,
    a photo) are appended to ``ignored`` when a list is given, so the caller can say so.
    """
    listing = raw.listing() if isinstance(raw, RawTree) else walk_raw(Path(raw))
    if ignored is not None:
        ignored += listing.ignored
    return list(listing.runs)


@dataclass
class RawTree:
    """The raw tree with its rig.toml and manifest files parsed once (cached per folder).

    Attributes
    ----------
    root : Path
        raw/ (resolved).
    problems : list of Problem
        Every entry, side file or manifest row found unusable so far (quarantine rows), in the
        order found.
    """

    root: Path
    problems: list[Problem] = field(default_factory=list)
    _real: dict = field(default_factory=dict)
    _real_dirs: dict = field(default_factory=dict)
    _rels: dict = field(default_factory=dict)
    _chains: dict = field(default_factory=dict)
    _miscased: dict = field(default_factory=dict)
    _listing: Listing | None = None
    _entries: dict = field(default_factory=dict)
    _root_prefix: str = field(default="", init=False, repr=False)
    _rigs: RigFiles = field(init=False, repr=False, compare=False)
    _manifests: Manifests = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        self.root = Path(self.root).resolve()
        self._root_prefix = str(self.root).rstrip("/") + "/"
        self._rigs = RigFiles(self)
        self._manifests = Manifests(self)

    # -- the walk and its entries ---------------------------------------------------------------
    def listing(self) -> Listing:
        """The walk of the raw tree (:func:`pipeline.raw.walk.walk_raw`), done once; its
        problems join :attr:`problems` the first time."""
        if self._listing is None:
            self._listing = walk_raw(self.root)
            self.problems += self._listing.problems
        return self._listing

    def side_files(self, name: str) -> list[Path]:
        """The walk's side files called ``name`` in any case (``Manifest.csv`` too: refused)."""
        return [p for p in self.listing().side if p.name.lower() == name]

    def entry(self, path: Path) -> Listing:
        """What :func:`pipeline.raw.walk.walk_raw` says about this one entry (without walking
        the tree: worker processes ask about the side files of their runs only)."""
        out = Listing()
        p = str(path)
        if p in self._entries:
            return self._entries[p]
        if self._listing is not None:
            out.problems = [x for x in self._listing.problems if x.source_path == self.rel(path)]
            out.skipped = [x for x in self._listing.skipped if x[0] == self.rel(path)]
        elif os.path.lexists(p):
            def problem(q, msg):
                out.problems.append(Problem(self.rel(path), msg))

            if len(os.fsencode(p)) >= PATH_MAX:
                problem(p, "path longer than the OS limit")
            elif os.path.islink(p):
                check_symlink(p, str(self.root), out, problem, lambda q: None)
            elif not os.path.isfile(p) and not os.path.isdir(p):
                problem(p, f"not a regular file ({file_kind(p)}): not read")
        self._entries[p] = out
        return out

    def entry_problem(self, path: Path) -> str | None:
        """Why the walk cannot use this entry (its first problem), or None."""
        probs = self.entry(path).problems
        return probs[0].error if probs else None

    def miscased(self, folder: Path, name: str) -> ConfigError | None:
        """A side file in ``folder`` whose name is ``name`` in another case (``Manifest.csv``,
        ``RIG.TOML``): the walk knows it is not a run, yet it is not read, so the metadata it was
        to give cannot be known. Each such file is a quarantine line (once) and the returned
        ConfigError quarantines the runs it applies to; None when there is none."""
        key = (str(folder), name)
        if key not in self._miscased:
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
            self._miscased[key] = err
        return self._miscased[key]

    def side_file(self, folder: Path, name: str) -> Path | ConfigError | None:
        """The side file ``name`` (``rig.toml``, ``manifest.csv``) of ``folder`` as the rig and
        manifest readers may use it: its path; None when the folder has none; or the ConfigError
        that quarantines the runs it applies to (the walk cannot use it, or it is named in
        another case: :meth:`miscased`, recorded once either way)."""
        f = folder / name
        blocked = self.entry_problem(f)
        miscased = self.miscased(folder, name)
        if blocked is not None:  # a quarantine row of its own (walk_raw)
            return ConfigError(f"cannot use {self.rel(f)}: {blocked}")
        if miscased is not None:
            return miscased
        return f if os.path.isfile(f) else None

    # -- paths ----------------------------------------------------------------------------------
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
        (:func:`pipeline.raw.problems.display_name`); cached, as :meth:`real` is (a rebuild
        asks for it per file several times)."""
        key = str(path)
        out = self._rels.get(key)
        if out is None:
            real = str(self.real(path))
            if real.startswith(self._root_prefix):
                out = display_name(real[len(self._root_prefix):])
            else:  # raw/ itself, or not under raw/ (a caller's mistake): still one clear line
                try:
                    out = display_name(Path(real).relative_to(self.root).as_posix())
                except ValueError:
                    out = display_name(Path(real).as_posix())
            self._rels[key] = out
        return out

    def campaign(self, path: Path) -> str | None:
        """The campaign of a file: the first folder of its path under raw/ (None at the top)."""
        parts = Path(self.rel(path)).parts
        return parts[0] if len(parts) > 1 else None

    def folders(self, path: Path) -> list[Path]:
        """Folders from raw/ down to the file's folder (resolved), cached by the folder as given."""
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

    # -- run metadata from rig.toml and manifest.csv ---------------------------------------------
    def rig_config(self, path: Path) -> dict:
        """The merged rig.toml (``read``, ``channels``, ``metadata``, ``sensors``, ``derived``) that
        applies to a run (:meth:`pipeline.raw.rig.RigFiles.config`)."""
        return self._rigs.config(path)

    def rig_json(self, path: Path) -> str:
        """:meth:`rig_config` as canonical JSON (sorted keys), computed once per folder."""
        return self._rigs.config_json(path)

    def manifest_metadata(self, path: Path) -> dict:
        """Metadata the manifests give for a run (nearer manifests override farther ones).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        return self._manifests.metadata(path)

    def manifest_parts(self, path: Path) -> dict[str, dict]:
        """Metadata the manifests give for single sheets / MDF groups of a file of several runs
        (rows ``file = book.xlsx#Sheet2``): part name -> metadata (nearer manifests override).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        return self._manifests.parts(path)

    def scan_manifests(self) -> None:
        """Parse every manifest once so that bad entries are reported even if no run uses them."""
        self._manifests.scan()

    def scan_rigs(self) -> None:
        """Parse every rig.toml once so that a bad one is reported even if no run uses it."""
        self._rigs.scan()
