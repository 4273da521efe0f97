"""The clean-up: delete what the warehouse wrote and no longer uses, and what a killed rebuild left.

It deletes only what the warehouse itself wrote: a file is a candidate when it lies in the
warehouse's own folders (never through a symlink) AND its name is one the writers use (the names
are listed once, in :mod:`pipeline.warehouse`). Anything else found there (a raw tree placed there
by mistake, a user's notes) is left alone, and so is a folder that still holds something.
"""
from __future__ import annotations

import os
import re
import stat as stat_mod
from pathlib import Path

from pipeline.rebuild.memo import MEMO_DIR
from pipeline.warehouse import (DB_TMP, FIGURE, REPORT_TMP, SAMPLES_FILE, SAMPLES_TMP, SHARD_FILE, SHARD_TMP,
                                STAGE_KEY, STAGE_NAME, STAGE_OUTPUT, STAGE_TABLE, STAGE_TMP)
from schemas.kind_names import KIND_NAMES  # not schemas.kinds: a no-op needs no pyarrow


def _real_dir(path: Path) -> bool:
    """A folder that is not a symlink (the clean-up never follows one)."""
    try:
        return stat_mod.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def _entries(folder: Path):
    """(name, path, is_dir, is_file) of a folder's entries, symlinks neither dir nor file."""
    try:
        with os.scandir(folder) as it:
            ents = sorted(it, key=lambda e: e.name)
    except OSError:
        return []
    return [(e.name, Path(e.path), e.is_dir(follow_symlinks=False), e.is_file(follow_symlinks=False)) for e in ents]


def _file_names(folder: Path) -> list[str]:
    """Names of a folder's regular files (not symlinks), sorted; no Path per entry (a samples
    folder holds thousands)."""
    try:
        with os.scandir(folder) as it:
            return sorted(e.name for e in it if e.is_file(follow_symlinks=False))
    except OSError:
        return []


def _unlink_if(path: Path, is_file: bool, pattern: re.Pattern) -> None:
    if is_file and pattern.fullmatch(path.name):
        path.unlink(missing_ok=True)


def _rmdir(path: Path) -> None:
    try:
        path.rmdir()
    except OSError:
        pass  # not empty: it holds something the warehouse did not write


def remove_stage_folder(folder: Path) -> None:
    """Delete a stage output folder the way the stage store wrote it (``output.json``,
    ``tables/*.parquet``, ``figures/*.png``); anything else in it stays, and so does the folder."""
    if not _real_dir(folder):
        return
    for sub, pattern in (("tables", STAGE_TABLE), ("figures", FIGURE)):
        if _real_dir(folder / sub):
            for _name, path, _is_dir, is_file in _entries(folder / sub):
                _unlink_if(path, is_file, pattern)
            _rmdir(folder / sub)
    for _name, path, _is_dir, is_file in _entries(folder):
        _unlink_if(path, is_file, STAGE_OUTPUT)
    _rmdir(folder)


def _samples_folders(warehouse: Path):
    """``samples/kind=<kind>/campaign=<campaign>/`` folders (real folders only)."""
    samples = warehouse / "samples"
    if not _real_dir(samples):
        return
    for kname, kdir, kis_dir, _ in _entries(samples):
        if not (kis_dir and kname.startswith("kind=") and kname[5:] in KIND_NAMES):
            continue
        for cname, cdir, cis_dir, _ in _entries(kdir):
            if cis_dir and cname.startswith("campaign="):
                yield kdir, cdir


def clean_debris(warehouse: Path) -> None:
    """Remove what a killed rebuild left behind (temp databases, temp stage folders, temp samples,
    memo and report files), by the writers' own temp names only."""
    for _name, path, _is_dir, is_file in _entries(warehouse):
        _unlink_if(path, is_file, DB_TMP)
    if _real_dir(warehouse / "stages"):
        for name, path, is_dir, _ in _entries(warehouse / "stages"):
            if is_dir and STAGE_TMP.fullmatch(name):
                remove_stage_folder(path)
    if _real_dir(warehouse / "report"):
        for _name, path, _is_dir, is_file in _entries(warehouse / "report"):
            _unlink_if(path, is_file, REPORT_TMP)
    for _kdir, cdir in _samples_folders(warehouse):
        for name in _file_names(cdir):
            if SAMPLES_TMP.fullmatch(name):
                (cdir / name).unlink(missing_ok=True)
    if _real_dir(warehouse / MEMO_DIR):
        for name, path, is_dir, _is_file in _entries(warehouse / MEMO_DIR):
            if is_dir and STAGE_NAME.fullmatch(name):
                for _name, spath, _is_dir, s_is_file in _entries(path):
                    _unlink_if(spath, s_is_file, SHARD_TMP)


def split_kept(keep: set[str]) -> tuple[set[str], set[str]]:
    """Paths to keep (relative to the warehouse) as (samples files, stage folders and the rest):
    the arguments of :func:`collect_garbage`."""
    return {p for p in keep if p.startswith("samples/")}, {p for p in keep if not p.startswith("samples/")}


def collect_garbage(warehouse: Path, keep_samples: set[str], keep_stages: set[str]) -> None:
    """Delete samples files and stage folders the warehouse wrote that are not in ``keep_*``
    (paths relative to the warehouse), and the memo of stages none of whose folders is kept.
    Only writer-named files in the writer's folders go."""
    _collect_samples(warehouse, keep_samples)
    _collect_stage_folders(warehouse, keep_stages)
    _collect_memo(warehouse, keep_stages)


def _collect_samples(warehouse: Path, keep_samples: set[str]) -> None:
    for kdir, cdir in list(_samples_folders(warehouse)):
        rel_dir = f"samples/{kdir.name}/{cdir.name}/"
        for name in _file_names(cdir):
            if SAMPLES_FILE.fullmatch(name) and rel_dir + name not in keep_samples:
                (cdir / name).unlink(missing_ok=True)
        _rmdir(cdir)
        _rmdir(kdir)


def _collect_stage_folders(warehouse: Path, keep_stages: set[str]) -> None:
    stages = warehouse / "stages"
    if _real_dir(stages):
        for sname, sdir, s_is_dir, _ in _entries(stages):
            if not (s_is_dir and STAGE_NAME.fullmatch(sname)):
                continue
            for kname, kdir, k_is_dir, _ in _entries(sdir):
                if k_is_dir and STAGE_KEY.fullmatch(kname) and f"stages/{sname}/{kname}" not in keep_stages:
                    remove_stage_folder(kdir)
            _rmdir(sdir)


def _collect_memo(warehouse: Path, keep_stages: set[str]) -> None:
    """A stage's per-item memo (``memo/<stage>/<xx>.pkl``) goes with the last of its stage folders
    that is kept."""
    memo = warehouse / MEMO_DIR
    if _real_dir(memo):
        live = {p.split("/")[1] for p in keep_stages if p.startswith("stages/") and p.count("/") >= 2}
        for name, path, is_dir, _is_file in _entries(memo):
            if is_dir and STAGE_NAME.fullmatch(name) and name not in live:
                for _name, spath, _is_dir, s_is_file in _entries(path):
                    _unlink_if(spath, s_is_file, SHARD_FILE)
                    _unlink_if(spath, s_is_file, SHARD_TMP)
                _rmdir(path)
        _rmdir(memo)
