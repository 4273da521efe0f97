"""Session fixtures of the pipeline tests: the demo, built once through the ``pneubench demo`` command."""
from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="session")
def demo(tmp_path_factory):
    """``pneubench demo`` (demo profile, seed 1) into a fresh raw tree and warehouse.

    Returns a dict: ``raw``, ``warehouse``, ``truth`` (truth.json), ``result`` (the CliRunner
    result) and ``hint`` (the command the demo told the user to try).
    """
    from click.testing import CliRunner

    from pipeline.cli import main

    root = tmp_path_factory.mktemp("demo")
    raw, wh = root / "raw", root / "warehouse"
    res = CliRunner().invoke(main, ["demo", "--raw", str(raw), "--warehouse", str(wh), "--jobs", "2", "-q"])
    hint = [ln for ln in res.output.splitlines() if ln.startswith("try: ")]
    return {"raw": raw, "warehouse": wh, "truth": json.loads((raw / "truth.json").read_text()), "result": res,
            "hint": hint[0][len("try: "):] if hint else None}
