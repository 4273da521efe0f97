"""Versions of the project's own code: a hash of the source files a result depends on.

Used by ingest (samples file names) and by the incremental state (what to re-read, which
stages to re-run); a module of its own so that neither has to import the other for it.
"""
from __future__ import annotations

import hashlib
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
    no-op fast path (:func:`pipeline.rebuild.flow.inputs_key`) may reuse the previous database as it
    is only when none of the code that wrote it has changed.
    """
    files = [p for d in ("pipeline", "analyses", "schemas") for p in (ROOT / d).rglob("*")
             if p.suffix in (".py", ".sql", ".toml") and "__pycache__" not in p.parts and p.is_file()]
    return hash_sources(files)
