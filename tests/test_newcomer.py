"""A newcomer's first minutes: a fresh clone, the README's first command exactly as printed, then
the command the demo says to try, exactly as printed. And the hand-written examples ingest.

The clone is of the repository's committed HEAD (what a newcomer gets), not of the working tree.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.conftest import query

REPO = Path(__file__).resolve().parents[1]


def readme_first_command(readme: str) -> str:
    """The first indented command of README.md (the one that installs and runs the demo)."""
    for line in readme.splitlines():
        if line.startswith("    ") and line.strip():
            return line.strip()
    raise AssertionError("README.md has no indented command")


def test_the_readme_starts_with_one_line_that_installs_and_runs_the_demo():
    cmd = readme_first_command((REPO / "README.md").read_text(encoding="utf-8"))
    assert "pip install" in cmd and cmd.endswith("pneubench demo") and "\n" not in cmd


def test_the_handwritten_examples_ingest_into_their_own_campaign(tmp_path):
    from pipeline.rebuild.flow import rebuild

    before = {p.relative_to(REPO / "examples"): p.read_bytes() for p in (REPO / "examples").rglob("*") if p.is_file()}
    summary = rebuild(REPO / "examples", tmp_path / "wh", jobs=1, report=False)
    assert summary.exit_code == 0 and summary.quarantine == []
    wh = tmp_path / "wh"
    assert sorted(query(wh, "SELECT kind, campaign FROM runs")) == [
        ("breakaway", "handwritten"), ("leakage", "handwritten"), ("step", "handwritten")]
    # the hand-written leakage run leaks from 5 bar (chamber A at z = 4 mm), the breakaway run breaks away
    leak = dict(query(wh, "SELECT round(pressure_bar), leak_l_min FROM leakage_map"))
    assert leak[4.0] < 0.05 < leak[5.0] < leak[6.0]
    assert query(wh, "SELECT count(*) FROM breakaway WHERE breakaway_force_n > 0") == [(1,)]
    after = {p.relative_to(REPO / "examples"): p.read_bytes() for p in (REPO / "examples").rglob("*") if p.is_file()}
    assert after == before  # read only


def _run(cmd: str, cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PNEUBENCH_RAW",
                                                            "PNEUBENCH_WAREHOUSE")}
    return subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("git") is None or not (REPO / ".git").exists(), reason="needs git and a checkout")
def test_newcomer_clones_runs_the_readme_command_and_the_printed_hint(tmp_path):
    clone = tmp_path / "pneubench"
    subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True, capture_output=True, timeout=120)
    cmd = readme_first_command((clone / "README.md").read_text(encoding="utf-8"))
    res = _run(cmd, clone, timeout=900)
    out = res.stdout + res.stderr
    assert res.returncode == 0, out[-3000:]
    assert re.search(r"demo: \d+ runs in warehouse/pneubench\.duckdb, 0 quarantined", out), out[-3000:]
    assert (clone / "warehouse" / "report" / "index.html").is_file()
    assert sorted(p.name for p in (clone / "raw").iterdir()) == [
        "durability-2025", "durability-2026", "pla-2016", "plan.toml", "plpa-2025", "truth.json"]
    hints = [ln[len("try: "):] for ln in out.splitlines() if ln.startswith("try: ")]
    assert len(hints) == 1, out[-3000:]
    res = _run(hints[0], clone, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    # the service-life table: both roller adjustments with their B10
    assert "b10_km" in res.stdout and "distance" in res.stdout and "force" in res.stdout
