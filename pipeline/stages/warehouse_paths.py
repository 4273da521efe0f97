"""Paths under the warehouse written relative to it, so that a moved warehouse keeps its keys.

One rule for the per-run memo's keys (:mod:`pipeline.rebuild.memo`) and the digest of a chamber's
spring fit (:func:`pipeline.stages.models._fit_item`): a samples file named by its absolute path
is keyed by its path under the warehouse. A leaf module: the stages may not import
``pipeline.rebuild``, and a module every stage imports would change every stage's code version.
"""
from __future__ import annotations

import os

__all__ = ["warehouse_prefix", "under_warehouse"]


def warehouse_prefix(warehouse: str | os.PathLike) -> str:
    """The prefix of every path under ``warehouse``: its path with one trailing separator."""
    return os.fspath(warehouse).rstrip(os.sep) + os.sep


def under_warehouse(path: str, prefix: str | None) -> str | None:
    """``path`` relative to the warehouse whose :func:`warehouse_prefix` is ``prefix``; None when it
    is not under it (or there is no prefix)."""
    return path[len(prefix):] if prefix and path.startswith(prefix) else None
