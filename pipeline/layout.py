"""The raw tree: which files are runs, and the ``rig.toml`` and ``manifest.csv`` that apply to them.

Run metadata sources, strongest first (bench-exports.md, "Run metadata"):

1. the ``manifest.csv`` row whose ``file`` column names the run (a manifest applies to its
   folder and below; a nearer manifest overrides a farther one key by key);
2. metadata embedded in the file (the reader's job);
3. ``[metadata]`` defaults of the nearest ``rig.toml`` (a subfolder's overrides its parent's).

Nothing here writes to the raw tree.
"""
from __future__ import annotations

import csv
import io
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.readers import READERS
from pipeline.readers.base import decode_text

NOT_RUNS = {"manifest.csv", "hoses.csv", "rig.toml"}
#: Tables a rig.toml may have (docs/inputs.md): each must be a table.
RIG_TABLES = ("read", "channels", "metadata", "sensors", "derived")


@dataclass
class Problem:
    """An input (or a line of one) that cannot be used: a future quarantine row."""

    source_path: str
    error: str
    line: int | None = None
    stage: str = "ingest"


def is_run_file(path: Path) -> bool:
    """Whether a file under raw/ is a run export (not a manifest, logbook, config or dotfile)."""
    return not is_known_non_run(path) and path.suffix.lower() in READERS


def is_known_non_run(path: Path) -> bool:
    """Files the contract names as not runs: manifests, logbooks, rig.toml, TDMS indexes,
    dotfiles and READMEs."""
    name = path.name
    return (name.startswith(".") or name.upper().startswith("README") or name.lower() in NOT_RUNS
            or name.lower().endswith(".tdms_index"))


def discover_runs(raw: Path, ignored: list[Path] | None = None) -> list[Path]:
    """Every run file under ``raw`` (hidden folders skipped), sorted by relative path.

    Files that are neither runs nor :func:`is_known_non_run` (a spreadsheet, a photo) are
    appended to ``ignored`` when a list is given, so the caller can say so.
    """
    out = []
    for p in raw.rglob("*"):
        rel = p.relative_to(raw)
        if any(part.startswith(".") for part in rel.parts[:-1]):
            continue
        if p.is_file() and is_run_file(p):
            out.append(p)
        elif ignored is not None and p.is_file() and not is_known_non_run(p):
            ignored.append(p)
    if ignored is not None:
        ignored.sort(key=lambda p: p.relative_to(raw).as_posix())
    return sorted(out, key=lambda p: p.relative_to(raw).as_posix())


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
    _chains: dict = field(default_factory=dict)

    def __post_init__(self):
        self.root = Path(self.root).resolve()

    def real(self, path: Path) -> Path:
        """``path.resolve()``, cached (a rebuild asks for every file's several times)."""
        key = str(path)
        if key not in self._real:
            self._real[key] = Path(path).resolve()
        return self._real[key]

    def rel(self, path: Path) -> str:
        return self.real(path).relative_to(self.root).as_posix()

    def campaign(self, path: Path) -> str | None:
        parts = Path(self.rel(path)).parts
        return parts[0] if len(parts) > 1 else None

    def _folders(self, path: Path) -> list[Path]:
        """Folders from raw/ down to the file's folder."""
        folder = self.real(path).parent
        if folder not in self._chains:
            chain, f = [folder], folder
            while f != self.root and self.root in f.parents:
                f = f.parent
                chain.append(f)
            self._chains[folder] = list(reversed(chain))
        return self._chains[folder]

    # -- rig.toml ---------------------------------------------------------------------------
    def _rig_file(self, folder: Path) -> dict:
        if folder not in self._rigs:
            f = folder / "rig.toml"
            cfg: dict | ConfigError = {}
            if f.is_file():
                try:
                    cfg = tomllib.loads(decode_text(f.read_bytes())[0])
                except tomllib.TOMLDecodeError as exc:
                    msg = f"invalid TOML: {exc}"
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
        cfg: dict = {}
        for folder in self._folders(path):
            part = self._rig_file(folder)
            if isinstance(part, ConfigError):
                raise part
            cfg = deep_merge(cfg, part)
        return {k: cfg.get(k, {}) for k in RIG_TABLES}

    # -- manifest.csv -------------------------------------------------------------------------
    def _manifest(self, folder: Path) -> dict[str, dict]:
        """Rows of a folder's manifest.csv by the resolved path of the file they name."""
        if folder in self._manifests:
            return self._manifests[folder]
        rows: dict[str, dict] = {}
        f = folder / "manifest.csv"
        if f.is_file():
            rel_manifest = self.rel(f)
            text = decode_text(f.read_bytes())[0]
            sample = text[:4096]
            dialect = csv.excel
            try:
                dialect = csv.Sniffer().sniff(sample.splitlines()[0] if sample else ",", delimiters=",;\t")
            except csv.Error:
                pass
            reader = csv.DictReader(io.StringIO(text), dialect=dialect)
            fields = [h.strip() for h in (reader.fieldnames or [])]
            if "file" not in fields:
                self.problems.append(Problem(rel_manifest, "no `file` column in the header"))
            else:
                reader.fieldnames = fields
                for row in reader:
                    line = reader.line_num
                    name = (row.get("file") or "").strip()
                    if not name:
                        if any((v or "").strip() for v in row.values() if isinstance(v, str)):
                            self.problems.append(Problem(rel_manifest, "row has no `file`", line))
                        continue
                    target = (folder / name).resolve()
                    if target != self.root and self.root not in target.parents:
                        self.problems.append(Problem(rel_manifest, f"entry `{name}` points outside raw/", line))
                        continue
                    if folder not in target.parents:
                        self.problems.append(Problem(rel_manifest, f"entry `{name}` is not in the manifest's folder "
                                                     "or below (a manifest applies only there)", line))
                        continue
                    if not target.is_file():
                        self.problems.append(Problem(rel_manifest, f"entry `{name}`: no such file", line))
                        continue
                    key = target.as_posix()
                    if key in rows:
                        self.problems.append(Problem(rel_manifest, f"entry `{name}` is listed twice; the later row is used", line))
                    meta = {k: v.strip() for k, v in row.items()
                            if k and k != "file" and isinstance(v, str) and v.strip() != ""}
                    rows[key] = meta
        self._manifests[folder] = rows
        return rows

    def manifest_metadata(self, path: Path) -> dict:
        """Metadata the manifests give for a run (nearer manifests override farther ones)."""
        key = self.real(path).as_posix()
        meta: dict = {}
        for folder in self._folders(path):
            meta.update(self._manifest(folder).get(key, {}))
        return meta

    def scan_manifests(self) -> None:
        """Parse every manifest once so that bad entries are reported even if no run uses them."""
        for f in sorted(self.root.rglob("manifest.csv")):
            if not any(p.startswith(".") for p in f.relative_to(self.root).parts[:-1]):
                self._manifest(f.parent.resolve())

    def scan_rigs(self) -> None:
        """Parse every rig.toml once so that a bad one is reported even if no run uses it."""
        for f in sorted(self.root.rglob("rig.toml")):
            if not any(p.startswith(".") for p in f.relative_to(self.root).parts[:-1]):
                self._rig_file(f.parent.resolve())
