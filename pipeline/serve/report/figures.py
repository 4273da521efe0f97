"""The report's own figures (a run page's channels, the decision's looks) keyed by what they show and
the code that draws them, and taken from the previous report when their key is unchanged.

A figure is written into its page between two comments that name its key (:func:`marked`):
``<!-- figure: KEY -->...<!-- /figure -->``. The next report reads the previous page (the live
report's: a report folder is published whole and never changed after,
:mod:`~pipeline.serve.report.publish`) and takes each figure whose key it needs from there
(:class:`Figures`) instead of drawing it. The key (:func:`figure_key`) hashes the figure's inputs
(canonical JSON) and :func:`code_key` of the modules that draw it (their source bytes and the
versions of the libraries the drawing uses). Drawing is deterministic (no date or software stamp,
fixed number formats), so a taken figure has the bytes a fresh drawing has. A ``--full`` rebuild
draws every figure (an empty :class:`Figures`). A page's figure is taken as text, not as a file of
its own: the report folder keeps one file per page, and the no-op rebuild links as many files as
before.
"""
from __future__ import annotations

import hashlib
import json
import re
from functools import lru_cache
from pathlib import Path

#: The project's root folder (``pipeline/``, ``analyses/``, ``schemas/``).
ROOT = Path(__file__).resolve().parents[3]
#: A marked figure in a page: its key and its text (what :func:`held_figures` finds, as a pattern).
_MARKED = re.compile(r"<!-- figure: ([0-9a-f]{32}) -->(.*?)<!-- /figure -->", re.DOTALL)
_OPEN, _CLOSE, _KEY = "<!-- figure: ", "<!-- /figure -->", re.compile(r"[0-9a-f]{32} -->")


@lru_cache(maxsize=None)
def code_key(patterns: tuple[str, ...], libraries: tuple[str, ...] = ()) -> str:
    """A key of the project source files matching ``patterns`` (globs relative to the project root,
    e.g. ``"pipeline/serve/**/*.py"``: their paths and bytes) and of the installed ``libraries``'
    versions [32 hex digits]. Computed once per process."""
    h = hashlib.sha256()
    files = sorted({p for pattern in patterns for p in ROOT.glob(pattern) if p.is_file()})
    for p in files:
        h.update(p.relative_to(ROOT).as_posix().encode("utf-8") + b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    for name in libraries:
        h.update(f"{name} {_installed_version(name)}\0".encode("utf-8"))
    return h.hexdigest()[:32]


@lru_cache(maxsize=None)
def _installed_version(name: str) -> str:
    """The installed version of the distribution ``name`` ("-": none), read once per process (its
    metadata file parsed: ~5 ms; the report's keys name numpy or matplotlib several times)."""
    from importlib import metadata  # here: ~0.05 s to import, and the no-op's parts key names no library

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "-"


def figure_key(code: str, *inputs) -> str:
    """The key of a figure drawn by code of :func:`code_key` ``code`` from ``inputs`` (plain data:
    numbers, strings, lists, dicts; anything else by its ``str``) [32 hex digits]."""
    blob = json.dumps([code, inputs], default=str, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode("utf-8", "surrogatepass")).hexdigest()[:32]


def marked(key: str, text: str) -> str:
    """A figure's ``text`` (an SVG element, an ``<img>``) between the comments naming its ``key``."""
    return f"<!-- figure: {key} -->{text}<!-- /figure -->"


def held_figures(text: str) -> list[tuple[str, str]]:
    """(key, text) of every marked figure of a page, in order: the matches of :data:`_MARKED`, found
    with ``str.find`` (the pattern's lazy ``.*?`` tried the closing comment at every character of a
    run page's ~60 kB SVG: ~1 ms a page, a third of redrawing one whose channels are kept; issue 26)."""
    out, at = [], 0
    while (i := text.find(_OPEN, at)) >= 0:
        start = i + len(_OPEN)
        if _KEY.match(text, start):
            body = start + 32 + len(" -->")
            end = text.find(_CLOSE, body)
            if end < 0:  # unclosed: neither this nor any later opening has a closing comment
                break
            out.append((text[start:start + 32], text[body:end]))
            at = end + len(_CLOSE)
        else:
            at = i + 1
    return out


class Figures:
    """The figures a previous report holds, by key: :meth:`figure` takes one from there or draws it.

    Parameters
    ----------
    pages : iterable of path-like
        Pages of the previous report to take figures from (a missing or unreadable one holds none);
        none: every figure is drawn (``--full``).
    """

    def __init__(self, pages=()):
        self.held: dict[str, str] = {}
        self.drawn = 0
        for page in pages:
            try:
                text = Path(page).read_text(encoding="utf-8")
            except (OSError, ValueError):
                continue
            self.held.update(held_figures(text))

    def figure(self, key: str, draw) -> str:
        """The figure of ``key``, marked: the previous report's, else ``draw()`` (its text; "" is
        returned unmarked: nothing was drawn). An exception of ``draw`` goes to the caller."""
        text = self.held.get(key)
        if text is None:
            text = draw()
            if not text:
                return ""
            self.drawn += 1
        return marked(key, text)
