"""The report folder's names, and how a file goes from one report folder into the next.

``<warehouse>/report`` is a symlink to the live report folder: ``index.html``, ``runs/`` (a
page per run, named by :func:`page_name`), the parts cache and :data:`GENERATION_FILE`. The
patterns here say which files the report wrote (the rest is someone else's and is kept);
:mod:`pipeline.serve.report.publish` stages and swaps whole folders.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
from pathlib import Path

#: The warehouse's report: a symlink to the live report folder.
REPORT_DIR = "report"
#: The database generation a report folder was rendered from (one line).
GENERATION_FILE = ".generation"
#: The report's own files at the top of a report folder (and their temp names).
OWN_FILE = re.compile(r"index\.html|\.generation|\.parts-cache\.json|\.run-keys\.json|"
                      r"\.(index\.html|parts-cache|run-keys\.json)\.tmp-[0-9]+")
#: The report's own files in ``runs/``: the run pages of :func:`page_name` (and their temp names).
OWN_PAGE = re.compile(r"[A-Za-z0-9._-]{1,80}-[0-9a-f]{8}\.html|\.[A-Za-z0-9._-]{1,80}-[0-9a-f]{8}\.html\.tmp-[0-9]+")


def page_name(run_id: str) -> str:
    """File name of a run's page: a readable slug of the id plus a hash of it (ids differing only
    in characters the slug drops, or in case, still get different pages)."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", str(run_id)).strip("._")[:80] or "run"
    return f"{slug}-{hashlib.sha256(str(run_id).encode('utf-8')).hexdigest()[:8]}.html"


def link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src`` (a copy where the file system has none)."""
    try:
        os.link(src, dst)
    except FileExistsError:
        raise
    except OSError:
        shutil.copyfile(src, dst)


def scandir(folder: Path) -> list:
    """The entries of ``folder`` (:func:`os.scandir`), none when it cannot be read."""
    try:
        with os.scandir(folder) as it:
            return list(it)
    except OSError:
        return []
