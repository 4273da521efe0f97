"""The house's rules, measured on the source (nothing is imported): file and function sizes,
parameter counts, and code that nothing calls. See docs/CONTRIBUTING.md, "The map"."""
from __future__ import annotations

import ast
import collections
import re
from pathlib import Path

import pytest

from tests.conftest import PROJECT_ROOT

PACKAGES = ("pipeline", "schemas", "analyses")
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80
MAX_PARAMETERS = 8

#: Files that may be longer than MAX_FILE_LINES, and why.
LONG_FILES: dict[str, str] = {}

#: Where long functions and long parameter lists are allowed: numeric kernels and physics,
#: whose parameters are the model's (a dataclass would only rename them).
KERNELS = ("analyses/", "pipeline/simulator/plpa.py", "pipeline/simulator/pla.py",
           "pipeline/simulator/durability.py", "pipeline/simulator/ambient.py", "pipeline/simulator/base.py")


def _sources() -> dict[str, str]:
    return {p.relative_to(PROJECT_ROOT).as_posix(): p.read_text(encoding="utf-8")
            for pkg in PACKAGES for p in sorted((PROJECT_ROOT / pkg).rglob("*.py"))}


def _functions(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def _parameters(fn: ast.FunctionDef) -> int:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    return len(names) - (names[:1] in (["self"], ["cls"])) + bool(a.vararg) + bool(a.kwarg)


def test_no_file_in_pipeline_is_over_600_lines_unless_its_format_demands_it():
    long = {f: t.count("\n") for f, t in _sources().items()
            if f.startswith("pipeline/") and t.count("\n") > MAX_FILE_LINES}
    assert set(long) <= set(LONG_FILES), {f: n for f, n in long.items() if f not in LONG_FILES}


def test_no_function_is_over_80_lines_or_takes_more_than_8_parameters_outside_the_kernels():
    bad = []
    for f, text in _sources().items():
        if f.startswith(KERNELS):
            continue
        for fn in _functions(ast.parse(text)):
            lines = fn.end_lineno - fn.lineno + 1
            if lines > MAX_FUNCTION_LINES or _parameters(fn) > MAX_PARAMETERS:
                bad.append(f"{f}:{fn.lineno} {fn.name}: {lines} lines, {_parameters(fn)} parameters")
    assert not bad, "\n".join(bad)


def test_every_function_and_class_is_used_somewhere_in_the_code():
    """Dead code: a top-level name (or method) that no module of the project, benchmark or the
    command line names besides its own definition. Tests alone do not keep code alive."""
    sources = _sources()
    others = [p.read_text(encoding="utf-8") for p in sorted((PROJECT_ROOT / "benchmarks").rglob("*.py"))]
    words = collections.Counter(w for t in [*sources.values(), *others]
                                for w in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", t))
    dead = []
    for f, text in sources.items():
        for node in ast.parse(text).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and words[node.name] <= 1:
                dead.append(f"{f}:{node.lineno} {node.name}")
            if isinstance(node, ast.ClassDef):
                dead += [f"{f}:{m.lineno} {node.name}.{m.name}" for m in node.body
                         if isinstance(m, ast.FunctionDef) and not m.name.startswith("__") and words[m.name] <= 1]
    assert not dead, "\n".join(dead)


@pytest.mark.parametrize("package", ["pipeline", "schemas", "analyses"])
def test_tests_mirror_the_package(package):
    """Every module that defines a function or a class has its test module at the mirrored path
    (tests/<pkg>/.../test_<name>.py); a module of constants only (a table, citations) is tested
    where it is used."""
    missing = []
    for p in sorted((PROJECT_ROOT / package).rglob("*.py")):
        rel = p.relative_to(PROJECT_ROOT)
        defines = any(isinstance(n, (ast.FunctionDef, ast.ClassDef)) for n in ast.parse(p.read_text()).body)
        if p.name in ("__init__.py", "__main__.py") or not defines:
            continue
        mirror = PROJECT_ROOT / "tests" / rel.parent / f"test_{p.name}"
        if not mirror.is_file():
            missing.append(f"{rel} -> {mirror.relative_to(PROJECT_ROOT)}")
    assert not missing, "\n".join(missing)


#: What each folder may import (docs/CONTRIBUTING.md, "The map"): the flow runs one way.
MAY_IMPORT = {
    "schemas": set(),
    "analyses": {"schemas"},
    "pipeline.versions": set(),
    "pipeline.progress": set(),
    "pipeline.own_files": set(),
    "pipeline.warehouse": {"pipeline.own_files", "schemas"},
    "pipeline.readers": {"schemas"},
    "pipeline.raw": {"pipeline.readers", "schemas"},
    "pipeline.ingest": {"pipeline.raw", "pipeline.readers", "pipeline.versions", "schemas"},
    "pipeline.stages": {"analyses", "pipeline.ingest", "pipeline.own_files", "pipeline.raw", "pipeline.progress",
                        "pipeline.versions", "schemas"},
    "pipeline.serve": {"pipeline.stages", "pipeline.warehouse", "schemas"},
    "pipeline.simulator": {"pipeline.progress", "schemas"},
    "pipeline.schedule": set(),
    "pipeline.rebuild": {"pipeline.ingest", "pipeline.progress", "pipeline.raw", "pipeline.readers",
                         "pipeline.serve", "pipeline.stages", "pipeline.versions", "pipeline.warehouse", "schemas"},
}


def _folder(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] in ("schemas", "analyses"):
        return parts[0]
    if parts[0] != "pipeline" or len(parts) == 1:
        return None
    return "pipeline." + parts[1]


def test_each_folder_imports_only_the_folders_below_it():
    wrong = []
    for f, text in _sources().items():
        own = _folder(f[:-3].replace("/", "."))
        if own == "pipeline.cli" or own is None:
            continue
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] if node.module != "pipeline" else [f"pipeline.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                other = _folder(name)
                if other and other != own and other not in MAY_IMPORT.get(own, set()):
                    wrong.append(f"{f}:{node.lineno} {own} imports {name}")
    assert not wrong, "\n".join(wrong)
