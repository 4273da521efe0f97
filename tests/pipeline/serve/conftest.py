"""Fixtures of the read-only side's tests: small warehouses built by the real rebuild, and the
``pneubench query`` command run in-process."""
from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.rebuild.assemble import build_database, runs_frame
from pipeline.rebuild.flow import rebuild
from pipeline.warehouse import DB_NAME
from tests.conftest import STEP_META, RawBuilder


T = [0.0, 0.1, 0.2, 0.3]


@pytest.fixture(scope="package")
def built(tmp_path_factory) -> Path:
    """A warehouse with two step runs (one campaign), built by the real rebuild."""
    root = tmp_path_factory.mktemp("q")
    raw = RawBuilder(root / "raw")
    raw.csv("c/a.csv", STEP_META, {"t[s]": T, "x[m]": [0, 1e-3, 2e-3, 3e-3], "x_ref[m]": T})
    raw.csv("c/b.csv", STEP_META, {"t[s]": T, "x[m]": [0, 2e-3, 4e-3, 6e-3], "x_ref[m]": T})
    wh = root / "wh"
    summary = rebuild(raw.root, wh, jobs=1)
    assert summary.exit_code == 0
    (root / "secret.txt").write_text("top secret\n")
    return wh


@pytest.fixture(scope="package")
def long_run(tmp_path_factory) -> Path:
    """A warehouse with one 20 000-sample step run: x is 0 except one spike of 50 mm at t = 12.345 s."""
    root = tmp_path_factory.mktemp("plot")
    raw = RawBuilder(root / "raw")
    n = 20_000
    t = [i / 1000 for i in range(n)]
    x = [0.05 if i == 12_345 else 0.001 * (i % 7) for i in range(n)]
    raw.csv("c/long.csv", STEP_META, {"t[s]": t, "x[m]": x, "x_ref[m]": [0.0] * n})
    wh = root / "wh"
    rebuild(raw.root, wh, jobs=1, report=False)
    return wh


def _cli(built, *args, input=None, env=None):
    return CliRunner().invoke(main, ["query", *args, "--warehouse", str(built)], input=input, env=env)


def _figures_warehouse(tmp_path: Path, rows: list[tuple]) -> Path:
    wh = tmp_path / "wh"
    wh.mkdir()
    for _stage, _name, rel, _cap in rows:
        f = wh / rel
        if not f.exists() and ".." not in rel:
            f.parent.mkdir(parents=True, exist_ok=True)
            f.write_bytes(b"\x89PNG fake " + rel.encode())
    figs = pd.DataFrame(rows, columns=["stage", "name", "path", "caption"])
    build_database(wh / DB_NAME, wh, {"figures": figs}, runs_frame([]))
    return wh
