"""``manifest.csv``: parsing one (header check, rows, parts), and merging the ones that apply to
a run (a manifest applies to its folder and below; a nearer one overrides a farther one key by key).

A manifest with a NUL byte, an unclosed quote, a field over the ``csv`` module's limit
(128 KiB) or another CSV syntax error is quarantined with the line number, and so is every run
under it (the metadata it was to give cannot be known: ingesting those runs with the remaining
sources could silently give them wrong metadata). So are a manifest without a header row
(empty), without a ``file`` column (``File``: the hint says lower case) or with a column named
twice (case-insensitively), and a ``Manifest.csv`` named in another case (the walk knows it is
not a run; unread, it would be a silent skip). A manifest row with a value in a column the
header does not name (its values are shifted) quarantines the run it names. A row
``file = book.xlsx#Sheet2`` gives metadata to one sheet / MDF group of a file of several runs
(a *part*). Nothing here writes to the raw tree.
"""
from __future__ import annotations

import os
from pathlib import Path

from pipeline.raw.problems import ConfigError, Problem, display_name, os_reason
from pipeline.raw.rawfile import read_raw_bytes
from pipeline.readers.base import SideCsvError, side_csv_rows

_PART = "\x00"  # between a file's path and a part's name in a row's key: in no path


class _BadManifest(Exception):
    """args: (message, line or None)."""


def check_header(fields: list[str], line: int) -> None:
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


def unnamed_value(fields: list[str], cells: list[str]) -> str | None:
    """Why a manifest row cannot be read: a value in a column the header does not name (beyond
    its last column, or under an empty name), which shifts the row's values; else None."""
    for i, cell in enumerate(cells):
        if cell.strip() and (i >= len(fields) or not fields[i]):
            return (f"row has a value in column {i + 1} (`{display_name(cell.strip()[:40])}`), which the header "
                    "does not name (an unquoted delimiter in a value?)")
    return None


def merge_row(into: dict, key: str, meta) -> None:
    """A manifest row on top of what farther manifests gave (a nearer one overrides key by key);
    a row that cannot be read (ConfigError) stays an error whichever manifest it is in."""
    old = into.get(key)
    if isinstance(old, ConfigError):
        return
    if isinstance(meta, ConfigError):
        into[key] = meta
    else:
        into.setdefault(key, {}).update(meta)


class Manifests:
    """The manifest.csv files of a raw tree, each parsed once, merged once per folder.

    Parameters
    ----------
    tree : pipeline.raw.tree.RawTree
        The tree they are in: its paths (``root``, ``real``, ``rel``, ``folders``), what the
        walk says about an entry (``entry``, ``entry_problem``, ``miscased``) and its
        ``problems``, where a manifest (or row) that cannot be used is recorded once.
    """

    def __init__(self, tree):
        self.tree = tree
        self._rows: dict[Path, dict[str, dict] | ConfigError] = {}  # folder -> its manifest's rows
        self._chains: dict[str, tuple[dict, dict] | ConfigError] = {}  # a run's folder as given -> merged rows

    def rows(self, folder: Path) -> dict[str, dict] | ConfigError:
        """Rows of a folder's manifest.csv by the path of the file they name (folders resolved),
        or a ConfigError when the manifest cannot be read (its problem is recorded once)."""
        if folder not in self._rows:
            self._rows[folder] = self._load(folder)
        return self._rows[folder]

    def _load(self, folder: Path) -> dict[str, dict] | ConfigError:
        tree = self.tree
        f = tree.side_file(folder, "manifest.csv")
        if f is None or isinstance(f, ConfigError):
            return {} if f is None else f
        try:
            return self._parse(folder, f)
        except _BadManifest as exc:
            msg, line = exc.args
            tree.problems.append(Problem(tree.rel(f), msg, line))
            return ConfigError(f"cannot use {tree.rel(f)}: line {line}: {msg}" if line
                               else f"cannot use {tree.rel(f)}: {msg}")

    def _parse(self, folder: Path, f: Path) -> dict[str, dict]:
        rel_manifest = self.tree.rel(f)
        try:
            data = read_raw_bytes(self.tree.root, f)  # no symlink out of raw/ followed since the walk
        except OSError as exc:
            raise _BadManifest(f"cannot read: {os_reason(exc)}", None) from None
        rows: dict[str, dict] = {}
        parsed = side_csv_rows(data)
        try:
            fields = None
            for _first, line, cells in parsed:
                if fields is None:
                    if not any(c.strip() for c in cells):
                        continue  # blank lines before the header
                    fields = [h.strip() for h in cells]
                    check_header(fields, line)
                    continue
                extra = unnamed_value(fields, cells)
                row = dict(zip(fields, cells))
                self._row(folder, rel_manifest, rows, row, line, extra)
        except SideCsvError as exc:
            raise _BadManifest(*exc.args) from None
        if fields is None:
            raise _BadManifest("no header row (an empty manifest: a header naming the `file` column comes first)",
                               None)
        return rows

    def _problem(self, rel_manifest: str, msg: str, line: int) -> None:
        self.tree.problems.append(Problem(rel_manifest, msg, line))

    def _row(self, folder: Path, rel_manifest: str, rows: dict, row: dict, line: int,
             extra: str | None = None) -> None:
        """Record one manifest row (or the problem with it) in ``rows``. ``extra``: why the row's
        values cannot be known (a value under no header name); the run it names then gets a
        ConfigError instead of metadata."""
        name = (row.get("file") or "").strip()
        if not name:
            if any((v or "").strip() for v in row.values() if isinstance(v, str)):
                self._problem(rel_manifest, "row has no `file`", line)
            return
        named = self._named_file(folder, rel_manifest, name, line)
        if named is None:
            return
        name, target, part = named
        key = target.as_posix() if part is None else f"{target.as_posix()}{_PART}{part}"
        if key in rows:
            self._problem(rel_manifest, f"entry `{name}` is listed twice; the later row is used", line)
        if extra is not None:
            self._problem(rel_manifest, extra, line)
            rows[key] = ConfigError(f"cannot use {rel_manifest}: line {line}: {extra}")
            return
        meta = {k: v.strip() for k, v in row.items()
                if k and k != "file" and isinstance(v, str) and v.strip() != ""}
        rows[key] = meta

    def _named_file(self, folder: Path, rel_manifest: str, name: str, line: int) -> tuple[str, Path, str | None] | None:
        """The file a row's ``file`` names: (the name without its part, the path with folders
        resolved, the part or None); None when it names no file the manifest may speak for
        (the problem recorded)."""
        part = None  # `book.xlsx#Sheet2`: one sheet / MDF group of a file of several runs
        if "#" in name and not os.path.isfile(folder / name):
            name, part = name.rsplit("#", 1)
            if not part.strip():
                self._problem(rel_manifest, f"entry `{name}#` names no sheet or group after `#`", line)
                return None
        try:
            named = folder / name
            target = (Path(os.path.realpath(named)) if named.name in ("", ".", "..")
                      else self.tree.real(named))
        except (OSError, ValueError) as exc:
            self._problem(rel_manifest, f"entry `{name}` cannot be a file name: {exc}", line)
            return None
        why = self._not_a_file_here(folder, name, target)
        if why is not None:
            self._problem(rel_manifest, why, line)
            return None
        return name, target, part

    def _not_a_file_here(self, folder: Path, name: str, target: Path) -> str | None:
        """Why a row's resolved ``target`` cannot be given metadata by the manifest of ``folder``
        (outside raw/ or the manifest's folder, no such file, a skipped alias), or None."""
        root = self.tree.root
        if target != root and root not in target.parents:
            return f"entry `{name}` points outside raw/"
        if folder not in target.parents:
            return f"entry `{name}` is not in the manifest's folder or below (a manifest applies only there)"
        if not os.path.isfile(target):
            return f"entry `{name}`: no such file"
        if os.path.islink(target):
            alias = [why for _rel, why in self.tree.entry(target).skipped]
            if alias:
                return f"entry `{name}` is a {alias[0]}; name that file instead"
        return None

    def chain(self, path: Path) -> tuple[dict, dict]:
        """The manifests that apply to a folder, merged once per folder (nearer manifests
        override farther ones): (file -> metadata, file -> part -> metadata). Raises ConfigError
        when a manifest of the folder or above cannot be read."""
        key = os.path.dirname(str(path))
        hit = self._chains.get(key)
        if hit is None:
            try:
                hit = self._merge(path)
            except ConfigError as exc:
                hit = exc
            self._chains[key] = hit
        if isinstance(hit, ConfigError):
            raise hit
        return hit

    def _merge(self, path: Path) -> tuple[dict, dict]:
        metas: dict[str, dict] = {}
        parts: dict[str, dict[str, dict]] = {}
        for folder in self.tree.folders(path):
            rows = self.rows(folder)
            if isinstance(rows, ConfigError):
                raise rows
            for k, meta in rows.items():
                if _PART in k:
                    file, part = k.split(_PART, 1)
                    merge_row(parts.setdefault(file, {}), part, meta)
                else:
                    merge_row(metas, k, meta)
        return metas, parts

    def metadata(self, path: Path) -> dict:
        """Metadata the manifests give for a run (nearer manifests override farther ones).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        metas, _parts = self.chain(path)
        meta = metas.get(str(self.tree.real(path)), {})
        if isinstance(meta, ConfigError):  # its row cannot be read: the run waits for it
            raise meta
        return dict(meta)

    def parts(self, path: Path) -> dict[str, dict]:
        """Metadata the manifests give for single sheets / MDF groups of a file of several runs
        (rows ``file = book.xlsx#Sheet2``): part name -> metadata (nearer manifests override).

        Raises ConfigError when a manifest of its folder or above cannot be read."""
        _metas, parts = self.chain(path)
        out = parts.get(str(self.tree.real(path)), {})
        for meta in out.values():
            if isinstance(meta, ConfigError):
                raise meta
        return {part: dict(meta) for part, meta in out.items()}

    def scan(self) -> None:
        """Parse every manifest once so that bad entries are reported even if no run uses them."""
        for f in self.tree.side_files("manifest.csv"):
            self.rows(self.tree.real(f).parent)
