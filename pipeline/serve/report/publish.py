"""Publishing the report: it is one folder, staged beside the live one and swapped in whole.

``<warehouse>/report`` is a symlink to the live report folder (``.report-<pid>-<hex>/``: the
index, ``runs/``, the parts cache and :data:`~pipeline.serve.report.folders.GENERATION_FILE`). A
new report is written into a folder of its own (``.report-tmp-<pid>-<hex>/``), renamed to its
final name once complete (:func:`stage_folder`), and published by renaming a new symlink over
``report`` (rename(2): atomic; :func:`publish_report`). A reader following ``report/`` sees the
previous index and its pages, or the new ones, never a mix. Files someone else put into the
report folder go on into the next one; :func:`settle_report` tidies up after a killed rebuild.
"""
from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from pipeline.serve.report.db import ReportDB
from pipeline.serve.report.folders import (GENERATION_FILE, OWN_FILE, OWN_PAGE, REPORT_DIR, link_or_copy,
                                           scandir)
from pipeline.serve.door import connect_readonly

#: A complete report folder, and one being written (staging names: ``<pid>-<8 hex>``).
_FOLDER = re.compile(r"\.report-[0-9]+-[0-9a-f]{8}")
_STAGING = re.compile(r"\.report-tmp-[0-9]+-[0-9a-f]{8}")
#: The new symlink before it is renamed over ``report``.
_LINK_TMP = re.compile(r"\.report\.link-tmp-[0-9]+")


def _carry_foreign(live: Path, new: Path) -> None:
    """Files someone else put into the live report folder (or its ``runs/``) go on into the new
    one (hard links): publishing a report never takes a user's file away."""
    for sub, own in (("", OWN_FILE), ("runs", OWN_PAGE)):
        for entry in scandir(live / sub):
            if entry.is_file(follow_symlinks=False) and not own.fullmatch(entry.name) and \
                    not (new / sub / entry.name).exists():
                (new / sub).mkdir(parents=True, exist_ok=True)
                link_or_copy(Path(entry.path), new / sub / entry.name)


def remove_report_folder(folder: Path, live: Path | None = None) -> None:
    """Delete a report folder the way it was written (index, run pages, cache, temp names). A
    file someone else put there goes only when it was carried into ``live`` (the same inode); a
    folder of theirs is moved into ``live``. Whatever is left keeps the folder."""
    for sub, own in (("runs", OWN_PAGE), ("", OWN_FILE)):
        for entry in scandir(folder / sub):
            if entry.is_file(follow_symlinks=False):
                if own.fullmatch(entry.name) or (live is not None and _same_file(entry.path, live / sub / entry.name)):
                    try:
                        os.unlink(entry.path)
                    except FileNotFoundError:
                        pass
            elif sub == "" and entry.is_dir(follow_symlinks=False) and entry.name != "runs" and live is not None \
                    and not os.path.lexists(live / entry.name):
                try:
                    os.rename(entry.path, live / entry.name)
                except OSError:
                    pass
        try:
            (folder / sub).rmdir()
        except OSError:
            pass  # not empty: it holds something the report did not write


def _same_file(a, b) -> bool:
    """Whether ``a`` and ``b`` are the same file (False when either is missing)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _folder_generation(folder: Path) -> str | None:
    """The generation a report folder was rendered from (None: not known)."""
    try:
        return (folder / GENERATION_FILE).read_text(encoding="utf-8").strip() or None
    except OSError:
        return None


def _live_target(warehouse: Path) -> str | None:
    """Name of the folder ``report`` links to (None: no link, or a folder of the old layout)."""
    try:
        return os.readlink(warehouse / REPORT_DIR)
    except OSError:
        return None


def live_generation(warehouse: Path) -> str | None:
    """The generation of the warehouse's live database (None when there is none, or it cannot be read)."""
    try:
        con = connect_readonly(warehouse)
        try:
            return ReportDB(con).generation() or None
        finally:
            con.close()
    except Exception:
        return None


def stage_folder(warehouse: Path, render) -> Path:
    """A new complete report folder beside the live one: ``render(folder)`` writes its run pages
    and returns the index; the files others put into the live folder are carried over. A failure
    removes the folder and raises (the live report is untouched)."""
    token = f"{os.getpid()}-{secrets.token_hex(4)}"
    tmp = warehouse / f".report-tmp-{token}"
    tmp.mkdir()
    try:
        text = render(tmp)
        (tmp / "index.html").write_text(text, encoding="utf-8")
        _carry_foreign(warehouse / REPORT_DIR, tmp)
        final = warehouse / f".report-{token}"
        os.rename(tmp, final)  # complete: a rebuild killed after this rolls it forward (settle_report)
    except BaseException:
        remove_report_folder(tmp)
        raise
    return final


def publish_report(warehouse: str | Path, staged: Path) -> Path:
    """Point ``report`` at the staged folder ``staged`` (one rename(2) of a new symlink over it)
    and remove the report folders before it. Returns ``report/index.html``.

    A ``report/`` folder of the old layout (a real folder) is first renamed aside: a crash in
    that moment leaves no ``report`` at all until :func:`settle_report` puts the link in."""
    warehouse = Path(warehouse)
    link = warehouse / REPORT_DIR
    tmp = warehouse / f".report.link-tmp-{os.getpid()}"
    tmp.unlink(missing_ok=True)
    try:
        os.symlink(staged.name, tmp)
    except OSError:  # a file system without symlinks (vfat, exFAT, some SMB shares): two renames
        return _publish_by_rename(warehouse, staged)
    if os.path.isdir(link) and not os.path.islink(link):
        os.rename(link, warehouse / f".report-{os.getpid()}-{secrets.token_hex(4)}")
    os.replace(tmp, link)
    _remove_old_folders(warehouse, staged.name)
    return link / "index.html"


def _publish_by_rename(warehouse: Path, staged: Path) -> Path:
    """:func:`publish_report` without symlinks: ``report`` is a folder, the live one renamed aside."""
    link = warehouse / REPORT_DIR
    aside = warehouse / f".report-{os.getpid()}-{secrets.token_hex(4)}"
    if os.path.isdir(link) and not os.path.islink(link):
        os.rename(link, aside)  # killed before the next rename: settle_report renames staged in
    os.rename(staged, link)
    _remove_old_folders(warehouse, None, live=link)
    return link / "index.html"


def _remove_old_folders(warehouse: Path, keep: str | None, live: Path | None = None) -> None:
    """Remove every report folder but ``keep`` (files of others go into ``live``) and stray link temps."""
    live = live or (warehouse / keep if keep else None)
    for entry in scandir(warehouse):
        if entry.name != keep and entry.is_dir(follow_symlinks=False) and \
                (_FOLDER.fullmatch(entry.name) or _STAGING.fullmatch(entry.name)):
            remove_report_folder(Path(entry.path), live)
        elif entry.is_symlink() and _LINK_TMP.fullmatch(entry.name):
            Path(entry.path).unlink(missing_ok=True)


def settle_report(warehouse: str | Path) -> None:
    """Bring the report folders in order after a killed rebuild (the caller holds the rebuild
    lock): a complete report of the live database that was not yet published (killed between
    the database swap and the report's) is published; every other report folder but the live
    one, and the temp folders and links, are removed."""
    warehouse = Path(warehouse)
    target = _live_target(warehouse)
    others = [Path(e.path) for e in scandir(warehouse)
              if e.is_dir(follow_symlinks=False) and _FOLDER.fullmatch(e.name) and e.name != target]
    if others:
        live_gen = live_generation(warehouse)
        current = _folder_generation(warehouse / REPORT_DIR)  # a link, or a folder (no symlinks)
        if live_gen is not None and current != live_gen:
            for folder in others:
                if _folder_generation(folder) == live_gen:
                    publish_report(warehouse, folder)
                    return
    link = warehouse / REPORT_DIR
    _remove_old_folders(warehouse, target, live=link if os.path.isdir(link) else None)
