"""Code run in a fresh interpreter, and which modules it loaded: for the tests that a path of the product
imports no library it does not need (scipy's submodules, matplotlib, numpy: seconds of a one-file change)."""
from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterable


def loaded_after(code: str, modules: Iterable[str]) -> list[str]:
    """Which of ``modules`` (names as in ``sys.modules``: ``"scipy.special"``, ``"matplotlib"``) are loaded after
    ``code`` ran in a fresh interpreter, sorted; an error of ``code`` fails the caller's test
    (``subprocess.CalledProcessError``, its stderr attached)."""
    probe = f"{code}\nimport sys as _sys\nprint(sorted(m for m in {sorted(modules)!r} if m in _sys.modules))\n"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return ast.literal_eval(out.stdout.strip().splitlines()[-1])
