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


def test_fresh_edits_skip_what_a_copy_has_seen(tmp_path):
    from benchmarks.bench_kinds_copies import SEEN_EDITS, _note_edit, fresh_edits, seen_edits

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    assert fresh_edits([a, b], "spring", 3, 10) == ([1, 2, 3], 0)        # new copies: 1, 2, 3
    for by in (1, 2, 3):
        _note_edit(a, "spring", by)
    _note_edit(b, "spring", 4)
    assert seen_edits(a) == {"spring": [1, 2, 3]}
    assert fresh_edits([a, b], "spring", 3, 10) == ([5, 6, 7], 0)        # seen on either copy: skipped
    assert fresh_edits([a, b], "plan.toml", 2, None) == ([1, 2], 0)      # per kind
    for by in (5, 6, 7, 8):
        _note_edit(b, "spring", by)
    assert fresh_edits([a, b], "spring", 3, 10) == ([9, 1, 2], 2)        # a last digit has 9 edits: 2 stale, seen ones
    _note_edit(a, "plan.toml", 1)
    assert fresh_edits([a], "plan.toml", 2, None) == ([2, 3], 0)         # unbounded kinds never run out
    c = tmp_path / "c"
    c.mkdir()
    for by in range(2, 10):
        _note_edit(c, "step", by)
    assert fresh_edits([c], "step", 3, 10) == ([1, 2, 3], 2)             # the one new edit, then seen ones: no repeat
    (a / SEEN_EDITS).write_text("not json")
    assert seen_edits(a) == {}                                           # damaged: as new
