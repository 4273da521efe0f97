"""Where a run's metadata is decided: every source, its precedence, and the typed result.

A run's metadata comes from four places, weakest first::

    rig.toml [metadata]  <  the file's own (embedded) metadata  <  manifest.csv row  <  part

- ``rig.toml`` ``[metadata]`` of the run's folder and its parents (nearer files override farther
  ones; merged by :meth:`pipeline.raw.tree.RawTree.rig_config`);
- metadata embedded in the export (a CSV ``# key: value`` line, a TDMS root property, a MAT
  ``meta`` struct ...), read by the format's reader;
- the run's ``manifest.csv`` row (:meth:`~pipeline.raw.tree.RawTree.manifest_metadata`);
- for one sheet / channel group of a file of several runs (:func:`parts_mode`), the manifest row
  naming that part (``file = book.xlsx#Sheet2``) over the file's row (:func:`_part_context`).

The reader is opened with hints in the same precedence (:func:`_open_export`): manifest keys
first, rig.toml keys only when the file cannot be read without them.

The ingest asks :func:`run_metadata` once per run and gets the decided metadata, the rig.toml
config the data is read with, and the opened export.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from pipeline.raw.problems import ConfigError, display_name
from pipeline.raw.tree import RawTree
from pipeline.readers import RawExport, ReaderError, parts_keys, read_export
from schemas.kinds import KINDS, META_KEYS, coerce_value


class MetadataError(Exception):
    """A run's metadata that cannot be used; the message is the quarantine's one line."""


@dataclass(frozen=True)
class Part:
    """One run of a file of several runs: a workbook's sheet or an MDF file's channel group."""

    plural: str     # the parts key: ``sheets`` / ``groups``
    singular: str   # the part key: ``sheet`` / ``group``
    name: str       # the sheet / group name, as the file spells it


@dataclass(frozen=True)
class RunMetadata:
    """A run's metadata as decided, with the rig.toml config and the export it was read from."""

    #: typed metadata in precedence (``run_id``, ``kind``, ``started_at`` in UTC ...)
    meta: dict
    #: the rig.toml config that applies to the run (``read``, ``channels``, ``metadata``,
    #: ``sensors``, ``derived``); of a part: the part's (:func:`_part_context`)
    rig: dict
    #: the export, opened with the hints of :func:`_open_export` (its data not read yet)
    export: RawExport


def run_metadata(tree: RawTree, path: Path, campaign: str, src: Path | None = None,
                 part: Part | None = None) -> RunMetadata:
    """Decide a run's metadata: rig.toml, the manifest, the file's own metadata and its part.

    Parameters
    ----------
    tree : RawTree
        The raw tree (rig.toml and manifests).
    path : Path
        The raw file's name in the tree (rig.toml and manifest rows are found by it).
    campaign : str
        The run's campaign (default ``run_id`` ``<campaign>/<file stem>``).
    src : Path, optional
        The path the data is read through (the opened file, under the same name); default ``path``.
    part : Part, optional
        The sheet / channel group of a file of several runs.

    Returns
    -------
    RunMetadata

    Raises
    ------
    MetadataError, ConfigError, ReaderError
        With the one-line reason the run is quarantined.
    """
    rig = tree.rig_config(path)
    manifest = tree.manifest_metadata(path)
    if part is not None:
        rig, manifest = _part_context(rig, manifest, part, tree.manifest_parts(path).get(part.name, {}))
    export = _open_export(src or path, rig, manifest)
    meta = resolve_metadata(rig["metadata"], export.metadata, manifest, campaign, path,
                            part=None if part is None else part.name)
    if part is not None:  # a sheet / group name is the file's text: one line, valid UTF-8
        meta["run_id"] = display_name(meta["run_id"])
    return RunMetadata(meta, rig, export)


def parse_started_at(value) -> str:
    """ISO 8601 text (or datetime) -> ISO 8601 in UTC; local time without offset is UTC."""
    if isinstance(value, datetime):
        dt = value
    else:
        text = str(value).strip()
        try:
            dt = datetime.fromisoformat(text.replace(" ", "T", 1) if "T" not in text and " " in text else text)
        except ValueError:
            raise MetadataError(f"`started_at` is not ISO 8601: {text!r}") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc).isoformat()


def normalise_keys(meta: dict) -> dict:
    """Known keys matched case-insensitively onto their canonical spelling; others kept."""
    known = {k.casefold(): k for k in META_KEYS}
    out = {}
    for k, v in meta.items():
        key = known.get(str(k).strip().casefold(), str(k).strip())
        out[key] = v
    return out


def resolve_metadata(rig: dict, embedded: dict, manifest: dict, campaign: str, path: Path,
                     part: str | None = None) -> dict:
    """Merge the three metadata sources (manifest > embedded > rig.toml), type and check them.
    ``part``: the sheet or channel group of a file of several runs (default run_id
    ``<campaign>/<file stem>/<part>``)."""
    meta = {**normalise_keys(rig), **normalise_keys(embedded), **normalise_keys(manifest)}
    meta = {k: v for k, v in meta.items() if not (isinstance(v, str) and v.strip() == "")}
    default_id = f"{campaign}/{path.stem}" if part is None else f"{campaign}/{path.stem}/{part}"
    meta.setdefault("run_id", display_name(default_id))  # a non-UTF-8 name: \xNN
    for k, spec in META_KEYS.items():
        if spec.default is not None and k not in meta and (k == "p_atm_pa" or _kind_uses(meta.get("kind"), k)):
            meta[k] = spec.default
    try:
        meta = {k: coerce_value(k, v) for k, v in meta.items()}
    except ValueError as exc:
        raise MetadataError(f"metadata {exc}") from None
    if meta.get("kind") is None:
        raise MetadataError("missing metadata `kind` (one of " + ", ".join(KINDS) + "): " + _where_kind_goes(path))
    if "started_at" in meta:
        meta["started_at"] = parse_started_at(meta["started_at"])
    for k, v in list(meta.items()):
        meta[k] = _jsonable(v)
    return meta


#: Where a file of each format carries its own metadata (docs/bench-exports.md, docs/formats.md),
#: as an example declaring ``kind``.
_EMBEDDED_KIND = {
    **dict.fromkeys((".csv", ".txt"), "CSV: a `# kind: step` line above the header"),
    ".lvm": "LVM: `kind=step` in the header's Description",
    ".tdms": "TDMS: a root property `kind` = `step`",
    ".mat": "MAT: a struct `meta` with `meta.kind = 'step'`",
    **dict.fromkeys((".xlsx", ".xlsm", ".xls", ".ods"), "Excel: a `# kind: step` cell above the header, or a "
                                                        "`meta` sheet row `kind | step`"),
    **dict.fromkeys((".mf4", ".mdf"), "MDF: `kind=step` in the header comment"),
}


def _where_kind_goes(path: Path) -> str:
    """The three places a run's ``kind`` can be declared, each with a one-line example (the
    manifest row names this file)."""
    name = display_name(path.name)
    if not name.isprintable():
        name = "run01" + path.suffix
    row = io.StringIO()
    csv.writer(row, lineterminator="").writerow([name, "step"])
    own = _EMBEDDED_KIND.get(path.suffix.lower())
    return ("declare it in " + (f"the file's own metadata ({own}), " if own else "the file's own metadata, ")
            + f"a manifest.csv row (`file,kind` then `{row.getvalue()}`) or rig.toml (`[metadata]` then "
              '`kind = "step"`)')


def _kind_uses(kind, key) -> bool:
    """Whether runs of ``kind`` use the metadata ``key`` (so that its default applies)."""
    spec = KINDS.get(kind) if isinstance(kind, str) else None
    return spec is not None and (key in spec.metadata or (kind == "spring" and key == "stroke_mm")
                                 or (kind == "identification" and key == "id_sample_rate_hz"))


def _jsonable(v):
    """A metadata value as JSON can hold it (numpy scalars and arrays, datetimes; non-finite -> None)."""
    if isinstance(v, (np.generic,)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    if isinstance(v, datetime):
        return v.isoformat()
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    return str(v)


def _open_export(path: Path, rig: dict, manifest: dict) -> RawExport:
    """Open the export with hints in metadata precedence: manifest > file > rig.toml.

    A reader sees the manifest's keys first, so a key embedded in the file (e.g. a TDMS root
    property ``group``) beats a rig.toml default; only when that fails and rig.toml would add
    hints is the file opened again with them.
    """
    strong = normalise_keys(manifest)
    weak = {**normalise_keys(rig["metadata"]), **strong}
    try:
        return read_export(path, rig["read"], strong)
    except ReaderError:
        if weak == strong:
            raise
    return read_export(path, rig["read"], weak)


# -- files of several runs ---------------------------------------------------------------------
def parts_mode(tree: RawTree, path: Path) -> tuple[str, str] | None:
    """``(parts key, part key)`` when a file is several runs, else None (one file, one run).

    A workbook is one run per sheet, and an MDF file one run per channel group, when its
    manifest row, ``rig.toml`` ``[metadata]`` or ``rig.toml`` ``[read]`` (in that precedence)
    set ``sheets = "all"`` / ``groups = "all"``. Formats with one run per file ignore the keys.

    Raises
    ------
    MetadataError
        The key has another value than ``"all"``.
    """
    keys = parts_keys(path)
    if keys is None:
        return None
    try:
        rig = tree.rig_config(path)
        manifest = normalise_keys(tree.manifest_metadata(path))
    except ConfigError:
        return None  # the one-run ingest reports it, as for any file
    plural, singular = keys
    value = manifest.get(plural, normalise_keys(rig["metadata"]).get(plural, rig["read"].get(plural)))
    if value is None or (isinstance(value, str) and value.strip() == ""):
        return None
    if str(value).strip().casefold() != "all":
        raise MetadataError(f"`{plural} = {value!r}`: the only value is \"all\" (one run per {singular}); "
                            f"to read one {singular}, name it with the `{singular}` key")
    return keys


def _part_context(rig: dict, manifest: dict, part: Part, own: dict) -> tuple[dict, dict]:
    """rig.toml config and manifest metadata of one sheet / group of a file of several runs:
    the part key names it, the parts key is dropped (it is not run metadata), a run_id the
    manifest gives the file becomes ``<run_id>/<part>``, and the manifest row of the part
    itself (``own``, ``file = book.xlsx#Sheet2``) overrides the file's row."""
    drop = {part.plural, part.singular}
    rig = {**rig, "read": {**rig["read"], part.plural: "all"},
           "metadata": {k: v for k, v in rig["metadata"].items() if str(k).strip().casefold() not in drop}}
    out = {}
    for k, v in manifest.items():
        key = str(k).strip().casefold()
        if key in drop:
            continue
        out[k] = f"{v}/{part.name}" if key == "run_id" and not (isinstance(v, str) and v.strip() == "") else v
    for k, v in own.items():
        key = str(k).strip().casefold()
        if key in drop:
            continue
        for old in [o for o in out if str(o).strip().casefold() == key]:
            del out[old]
        out[k] = v
    out[part.singular] = part.name
    return rig, out
