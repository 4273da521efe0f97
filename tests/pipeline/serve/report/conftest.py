"""What the report's tests share: a warehouse whose raw text is hostile (``built``), a stage with a
figure of no paper, and a headless Chromium to open pages in."""
import re
import shutil
import subprocess
import tempfile

import matplotlib
import pandas as pd
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import pipeline.stages as st  # noqa: E402
from pipeline.rebuild.flow import rebuild  # noqa: E402
from pipeline.stages import StageOutput  # noqa: E402
from pipeline.stages import findings as fs  # noqa: E402
from tests.conftest import STEP_META  # noqa: E402

EVIL = '<script>alert("pwned")</script>'


class PictureStage:
    """A stage with a figure and its key table, whose text comes from raw metadata."""
    NAME, READS, WRITES = "zz_pictures", st.Reads(kinds=("step",)), ("zz_curve",)
    KEY_TABLES = {"curve": "zz_curve"}

    @staticmethod
    def run(ctx):
        runs = ctx.runs_of("step")
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.plot([0, 1, 2, 3], [0, 1, 4, 9], "o-", color="tab:red", lw=4)
        ax.set_title("a curve")
        table = pd.DataFrame({"run_id": runs["run_id"], "value_mm": range(len(runs))})
        return StageOutput(tables={"zz_curve": table}, figures={"curve": fig},
                           captions={"curve": f"caption from {EVIL}"})


def flip(holds):
    def check(ctx):
        return fs._row(fs.Claim("breakaway_0bar_twice", "Breakaway at 0 bar is about twice that at >= 1 bar", fs.PLPA,
                                "1", "ratio 1.5-2.5"), "breakaway", 2.0 if holds else 1.0, 0.05, holds, 30, None, "test")
    return check


@pytest.fixture
def built(raw, warehouse, monkeypatch):
    real = st.discover
    monkeypatch.setattr(st, "discover", lambda: [*real(), PictureStage])
    for i in range(2):
        raw.csv(f"c/s{i}.csv", {**STEP_META, "run_id": f"{EVIL}{i}"}, {"t[s]": [0, 0.1], "x[mm]": [0, 1],
                                                                          "x_ref[mm]": [1, 1]})
    raw.csv("c/bad.csv", {**STEP_META, "notes": EVIL}, {"t[s]": [0, 1], "x[furlong]": [0, 1], "x_ref[mm]": [0, 1]})
    raw.write("c/hoses.csv", "hose_id,event,at,hose_type,adjustment,spring_force_n\n"
                             f"H1,installed,2026-01-01T00:00:00,{EVIL.replace(',', ' ')},force,858\n")
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(True)),))
    rebuild(raw.root, warehouse, jobs=1)
    monkeypatch.setattr(fs, "CHECKS", (("breakaway_0bar_twice", flip(False)),))
    s = rebuild(raw.root, warehouse, jobs=1, full=True)
    return s


def chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def run_chromium(url: str, *extra: str, size=(1280, 2400)) -> subprocess.CompletedProcess:
    """Headless chromium on ``url`` with a throw-away profile and its console on stderr."""
    profile = tempfile.mkdtemp(prefix="chromium-")
    try:
        return subprocess.run(
            [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
             "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
             "--virtual-time-budget=5000", *extra, f"--window-size={size[0]},{size[1]}", url],
            capture_output=True, text=True, timeout=180)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def console_lines(res) -> list[str]:
    return [line for line in res.stderr.splitlines() if "CONSOLE" in line]


needs_chromium = pytest.mark.skipif(chromium() is None, reason="Debian's chromium is not installed (.ci/run installs it)")


def table_cells(html: str) -> list[list[str]]:
    """Text of the body cells of the first table in ``html``, per row."""
    body = html[html.index("<tbody>"):]
    return [[re.sub(r"<[^>]+>", "", c) for c in re.findall(r"<td[^>]*>(.*?)</td>", r, flags=re.S)]
            for r in re.findall(r"<tr>(.*?)</tr>", body, flags=re.S)]
