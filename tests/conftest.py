"""Shared fixtures: a raw tree builder that writes small synthetic exports (no binaries shipped),
and a guard that fails any test in which a rebuild changed its raw tree."""
from __future__ import annotations

import functools
import hashlib
import os
import stat
import textwrap
from pathlib import Path

import pytest

#: The project's root folder (holds ``pipeline/``, ``tests/``): the working folder of child processes.
PROJECT_ROOT = Path(__file__).resolve().parent.parent


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
    from pipeline.serve.door import connect_readonly

    con = connect_readonly(Path(warehouse))
    try:
        cur = con.execute(sql)
        return cur.df() if frame else cur.fetchall()
    finally:
        con.close()


# -- raw/ is never modified: checked around every rebuild of the test suite ---------------------
def raw_snapshot(root: str | os.PathLike) -> dict[str, tuple]:
    """Everything under ``root`` (the root included): relative path -> (file mode, SHA-256 of a
    file's bytes / a symlink's target / None for a folder). Symlinks are not followed."""
    root = Path(root)
    out: dict[str, tuple] = {}

    def one(path: Path, rel: str) -> None:
        try:
            st = os.lstat(path)
        except OSError as exc:
            out[rel] = ("gone", type(exc).__name__)
            return
        if stat.S_ISLNK(st.st_mode):
            out[rel] = (st.st_mode, "link", os.readlink(path))
        elif stat.S_ISREG(st.st_mode):
            try:
                digest = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError as exc:  # a test may make a file unreadable on purpose
                digest = f"unreadable: {type(exc).__name__}"
            out[rel] = (st.st_mode, "file", st.st_size, digest)
        else:
            out[rel] = (st.st_mode, "dir" if stat.S_ISDIR(st.st_mode) else "other", None)

    one(root, ".")
    if not root.is_symlink():
        for folder, dirs, files in os.walk(root, followlinks=False):
            for name in sorted(dirs) + sorted(files):
                path = Path(folder) / name
                one(path, path.relative_to(root).as_posix())
    return out


def snapshot_diff(before: dict, after: dict) -> list[str]:
    """One line per path whose entry differs between two snapshots."""
    lines = []
    for rel in sorted(set(before) | set(after)):
        if before.get(rel) != after.get(rel):
            what = ("created" if rel not in before else "deleted" if rel not in after else "changed")
            lines.append(f"{rel}: {what}")
    return lines


#: Paths (relative to raw/) the running test writes itself while a rebuild runs (a bench still
#: writing a file), declared with ``@pytest.mark.raw_written("c/a.csv")``: their changes are the
#: test's, not the rebuild's. Every other path must stay byte-identical.
_WRITTEN_BY_TEST: set[str] = set()


def pytest_configure(config):
    config.addinivalue_line("markers", "raw_written(*paths): raw files the test itself writes during a rebuild")


def assert_raw_unchanged(root, before: dict) -> None:
    diff = [d for d in snapshot_diff(before, raw_snapshot(root)) if d.rsplit(": ", 1)[0] not in _WRITTEN_BY_TEST]
    if diff:
        pytest.fail(f"the rebuild modified its raw tree {root}: " + "; ".join(diff[:10]), pytrace=False)


def guard_raw(func):
    """``func(raw, ...)`` wrapped: fail the test when the raw tree differs afterwards (also when
    ``func`` raised)."""
    @functools.wraps(func)
    def guarded(raw, *args, **kwargs):
        before = raw_snapshot(raw) if os.path.lexists(raw) else None
        try:
            return func(raw, *args, **kwargs)
        finally:
            if before is not None:
                assert_raw_unchanged(raw, before)
    guarded.__wrapped_rebuild__ = func
    return guarded


def _holders(func) -> list:
    """Imported modules whose attribute ``rebuild`` is ``func``."""
    import sys

    out = []
    for mod in list(sys.modules.values()):
        try:
            if mod.__dict__.get("rebuild") is func:
                out.append(mod)
        except Exception:  # noqa: BLE001 - odd module objects
            continue
    return out


def _install_raw_guard() -> list[tuple[object, object]]:
    """Point ``pipeline.rebuild.flow.rebuild`` and every imported module's name bound to it (test
    modules' ``from pipeline.rebuild.flow import rebuild``) at the guarded function; returns what
    to put back."""
    import pipeline.rebuild.flow as rb

    original = getattr(rb.rebuild, "__wrapped_rebuild__", rb.rebuild)
    guarded = guard_raw(original)
    undo = []
    for mod in _holders(original):
        undo.append((mod, original))
        mod.rebuild = guarded
    return undo


@pytest.fixture(scope="session", autouse=True)
def _raw_is_never_modified():
    """Every in-process rebuild of the suite (called directly, through the CLI, from a test
    module or a module-scoped fixture) checks its raw tree before and after. Installed for the
    session (module-scoped fixtures run before function fixtures), checked again per test."""
    undo = _install_raw_guard()
    yield
    for mod, original in undo:
        mod.rebuild = original


@pytest.fixture(autouse=True)
def _raw_guard_per_test(request, monkeypatch):
    """Guards modules imported after the session started, too (monkeypatch undoes it)."""
    import pipeline.rebuild.flow as rb

    marker = request.node.get_closest_marker("raw_written")
    _WRITTEN_BY_TEST.clear()
    _WRITTEN_BY_TEST.update(marker.args if marker else ())
    request.addfinalizer(_WRITTEN_BY_TEST.clear)

    guarded = rb.rebuild
    original = getattr(guarded, "__wrapped_rebuild__", None)
    if original is None:  # pragma: no cover - the session fixture always installs it
        original, guarded = guarded, guard_raw(guarded)
        monkeypatch.setattr(rb, "rebuild", guarded)
    for mod in _holders(original):
        monkeypatch.setattr(mod, "rebuild", guarded)


def segfault() -> None:
    """Crash this process with SIGSEGV, as a reader's C code does, without the dump of
    faulthandler: pytest enables it and a forked worker inherits it, writing past the capture
    to the terminal ("Fatal Python error: Segmentation fault" and every thread's stack)."""
    import faulthandler
    import signal

    faulthandler.disable()
    os.kill(os.getpid(), signal.SIGSEGV)


@pytest.fixture(scope="session")
def designs_table():
    """The even designs of alpha 0.05 and O'Brien-Fleming spending as arrays
    (:func:`analyses.sequential_table.design_table`), computed once for the session with the
    designs' caches cleared before and after (read-only: copy before changing)."""
    from analyses import sequential
    from analyses.sequential_table import design_table

    sequential.clear_caches()
    out = design_table(0.05, "obrien-fleming")
    sequential.clear_caches()
    return out
