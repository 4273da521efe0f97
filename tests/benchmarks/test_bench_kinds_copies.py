"""Tests of benchmarks.bench_kinds_copies' option parsing (the benchmark itself rebuilds campaigns: not run here)."""
from __future__ import annotations

from pathlib import Path

from benchmarks.bench_kinds_copies import parse_copies


def test_parse_copies_keeps_order_and_resolves_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    got = parse_copies(["main=/src/main-tree:/data/k1-main", "merge=.:copy"])
    assert list(got) == ["main", "merge"]
    assert got["main"] == (Path("/src/main-tree"), Path("/data/k1-main"))
    assert got["merge"] == (tmp_path.resolve(), (tmp_path / "copy").resolve())
