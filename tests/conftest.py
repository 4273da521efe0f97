"""Shared fixtures: a raw tree builder that writes small synthetic exports (no binaries shipped)."""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest


class RawBuilder:
    """Writes files into a temporary raw tree: ``raw.write("camp/a.csv", text)``."""

    def __init__(self, root: Path):
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def write(self, rel: str, text: str | bytes, dedent: bool = True) -> Path:
        path = self.root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(textwrap.dedent(text).lstrip("\n") if dedent else text, encoding="utf-8")
        return path

    def csv(self, rel: str, meta: dict, columns: dict[str, list], delimiter: str = ",", decimal: str = ".") -> Path:
        """A CSV export with ``# key: value`` metadata and ``name[unit]`` columns."""
        lines = [f"# {k}: {v}" for k, v in meta.items()]
        lines.append(delimiter.join(columns))
        for row in zip(*columns.values()):
            cells = [repr(float(v)) if not isinstance(v, str) else v for v in row]
            if decimal == ",":
                cells = [c.replace(".", ",") for c in cells]
            lines.append(delimiter.join(cells))
        return self.write(rel, "\n".join(lines) + "\n", dedent=False)


@pytest.fixture
def raw(tmp_path) -> RawBuilder:
    return RawBuilder(tmp_path / "raw")


@pytest.fixture
def warehouse(tmp_path) -> Path:
    return tmp_path / "warehouse"


STEP_META = {"kind": "step", "started_at": "2026-01-02T03:04:05", "rig": "plpa-1"}


def query(warehouse: Path, sql: str, frame: bool = False):
    """Rows (or a DataFrame with ``frame=True``) of read-only SQL on a built warehouse."""
    from pipeline.warehouse import connect_readonly

    con = connect_readonly(Path(warehouse))
    try:
        cur = con.execute(sql)
        return cur.df() if frame else cur.fetchall()
    finally:
        con.close()
