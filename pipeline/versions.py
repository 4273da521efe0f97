"""Versions of the project's own code: a hash of the source files a result depends on.

The one home of every code version: the ingest's (samples file names, what to re-read), a
stage's and a memoised function's (which stages and items to compute again; the project modules
they import found by reading import lines, nothing imported), and the whole project's (the
no-op fast path). A module of its own so that ingest and the rebuild need not import each other.
"""
from __future__ import annotations

import hashlib
import re
import sys
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

#: Bump when ingest output changes for the same input; part of every samples file's key.
INGEST_VERSION = "1"

#: The project's root folder (holds ``pipeline/``, ``analyses/``, ``schemas/``).
ROOT = Path(__file__).resolve().parent.parent


def hash_sources(paths: list[Path], root: Path | None = None) -> str:
    """Hash of the paths (relative to ``root``) and bytes of source files [16 hex digits]."""
    root = ROOT if root is None else root
    h = hashlib.sha256()
    for p in sorted(paths):
        h.update(p.relative_to(root).as_posix().encode())
        try:
            h.update(p.read_bytes())
        except OSError:
            pass
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def ingest_code_version() -> str:
    """Version of everything that turns a raw file into a runs row and samples Parquet.

    ``INGEST_VERSION`` plus a hash of the schemas, readers, layout, derived-channel, prefetch and
    ingest source (``pipeline/raw/``, ``pipeline/ingest/``), so that a code change re-reads the files it may affect.
    """
    files = [*ROOT.glob("schemas/*.py"), *ROOT.glob("pipeline/readers/*.py"), *ROOT.glob("pipeline/raw/*.py"),
             *ROOT.glob("pipeline/ingest/*.py"), ROOT / "pipeline" / "versions.py"]
    return f"{INGEST_VERSION}-{hash_sources([f for f in files if f.is_file()])}"


@lru_cache(maxsize=1)
def project_code_version() -> str:
    """Version of all of the project's code: every ``.py``, ``.sql`` and ``.toml`` file under
    ``pipeline/``, ``analyses/`` and ``schemas/`` [16 hex digits].

    A superset of :func:`ingest_code_version` and of every stage's code version: the rebuild's
    no-op fast path (:func:`pipeline.rebuild.noop.inputs_key`) may reuse the previous database as it
    is only when none of the code that wrote it has changed.
    """
    files = [p for d in ("pipeline", "analyses", "schemas") for p in (ROOT / d).rglob("*")
             if p.suffix in (".py", ".sql", ".toml") and "__pycache__" not in p.parts and p.is_file()]
    return hash_sources(files)


# -- a stage's and a memoised function's code: what their module imports ---------------------------
#: Top-level packages of this project: a stage's version covers what it imports from them.
_PROJECT_PACKAGES = ("pipeline", "analyses", "schemas")

_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+([\w.]+)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)|import[ \t]+([^\n#]*))",
                     re.MULTILINE)


@lru_cache(maxsize=None)
def _direct_imports(module_file: Path) -> tuple[Path, ...]:
    """Project source files a file imports (at any indentation: lazy imports count too)."""
    out = []
    for m in _IMPORT.finditer(module_file.read_text(encoding="utf-8")):
        if m.group(1):
            if m.group(1).startswith("."):
                continue
            names = [m.group(1)] + [f"{m.group(1)}.{n.split()[0]}" for n in m.group(2).strip("()").split(",")
                                    if n.strip()]
        else:
            names = [n.split()[0] for n in m.group(3).split(",") if n.strip()]
        for name in names:
            if name.split(".")[0] not in _PROJECT_PACKAGES:
                continue
            base = ROOT.joinpath(*name.split("."))
            out += [c.resolve() for c in (base.with_suffix(".py"), base / "__init__.py") if c.is_file()]
    return tuple(out)


@lru_cache(maxsize=None)
def project_imports(module_file: Path) -> frozenset[Path]:
    """Source files of this project that ``module_file`` imports, transitively (read as text,
    nothing is imported), the file itself included."""
    seen: set[Path] = set()
    todo = [Path(module_file).resolve()]
    while todo:
        f = todo.pop()
        if f in seen or not f.is_file():
            continue
        seen.add(f)
        todo += _direct_imports(f)
    return frozenset(seen)


@lru_cache(maxsize=None)
def stage_code_version(module_file: str) -> str:
    """Version of a stage: its module, the stage framework, every ``analyses`` module and
    every project module any of them imports (e.g. ``pipeline.raw.logbook``, ``schemas.units``)."""
    roots = [Path(module_file), *_framework_sources()]
    files = set().union(*(project_imports(f) for f in roots if f.is_file()))
    return hash_sources(sorted(files))


@lru_cache(maxsize=1)
def _framework_sources() -> tuple[Path, ...]:
    """What every stage's version covers besides its own module: the stage framework and the analyses."""
    return (ROOT / "pipeline" / "stages" / "__init__.py", *sorted(ROOT.glob("analyses/**/*.py")))


def function_code_version(func: Callable) -> str | None:
    """Version of ``func``'s module and the project code it imports (as :func:`stage_code_version`);
    None: not memoisable (a function without a module file)."""
    mod = sys.modules.get(getattr(func, "__module__", None) or "")
    file = getattr(mod, "__file__", None)
    if not file:
        return None
    return stage_code_version(file)
