"""Readers, one module per format. Each exposes ``read_<format>(path, read, hints) -> RawExport``.

``read`` is the ``[read]`` table of the applicable ``rig.toml``; ``hints`` is the metadata known
before the file is opened (manifest row over ``rig.toml`` defaults), e.g. the TDMS ``group``.
"""
from __future__ import annotations

import importlib
from pathlib import Path

from pipeline.readers.base import RawColumn, RawExport, ReaderError, split_name_unit

#: File extension -> "module:function" of its reader.
READERS = {
    ".csv": "pipeline.readers.csv:read_csv",
    ".txt": "pipeline.readers.csv:read_csv",
    ".lvm": "pipeline.readers.lvm:read_lvm",
    ".tdms": "pipeline.readers.tdms:read_tdms",
    ".mat": "pipeline.readers.mat:read_mat",
    ".xlsx": "pipeline.readers.excel:read_excel",
    ".xlsm": "pipeline.readers.excel:read_excel",
    ".xls": "pipeline.readers.excel:read_excel",
    ".ods": "pipeline.readers.excel:read_excel",
    ".mf4": "pipeline.readers.mdf:read_mdf",
    ".mdf": "pipeline.readers.mdf:read_mdf",
}


def reader_for(path: str | Path):
    """The reader function for a file, chosen by its extension (case-insensitive)."""
    target = READERS.get(Path(path).suffix.lower())
    if target is None:
        raise ReaderError(f"no reader for extension {Path(path).suffix!r}")
    module, func = target.split(":")
    return getattr(importlib.import_module(module), func)


def read_export(path: str | Path, read: dict | None = None, hints: dict | None = None) -> RawExport:
    """Open any supported export with the reader its extension names."""
    return reader_for(path)(Path(path), read or {}, hints or {})


def parts_keys(path: str | Path) -> tuple[str, str] | None:
    """``(parts key, part key)`` of a format whose files may hold several runs (``("sheets",
    "sheet")`` for workbooks, ``("groups", "group")`` for MDF), None for one-run formats."""
    target = READERS.get(Path(path).suffix.lower())
    module = importlib.import_module(target.split(":")[0]) if target else None
    keys = (getattr(module, "PARTS_KEY", None), getattr(module, "PART_KEY", None))
    return keys if None not in keys and hasattr(module, "list_parts") else None


def list_parts(path: str | Path) -> list[str]:
    """The runs of a several-runs file, each as its part key names it (sheet names, MDF groups)."""
    target = READERS.get(Path(path).suffix.lower())
    if target is None:
        raise ReaderError(f"no reader for extension {Path(path).suffix!r}")
    return importlib.import_module(target.split(":")[0]).list_parts(Path(path))


__all__ = ["READERS", "RawColumn", "RawExport", "ReaderError", "list_parts", "parts_keys", "read_export", "reader_for",
           "split_name_unit"]
