"""pipeline/serve/plots.py: one run's channels as a plot (min and max per pixel column, display
units, h:mm:ss past an hour, the analyses' events) and the figures copied out of the warehouse."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from pipeline.cli import main
from pipeline.rebuild.flow import rebuild
from pipeline.serve.plots import copy_figures, run_traces
from pipeline.serve.query import QueryError
from tests.conftest import STEP_META, RawBuilder, query
from tests.pipeline.serve.conftest import _figures_warehouse


def test_run_traces_keep_min_and_max_per_pixel_column(long_run):
    kind, traces = run_traces(long_run, "c/long", columns=100)
    assert kind == "step" and set(traces) == {"x_m", "x_ref_m"}
    t, x = traces["x_m"]
    assert len(t) <= 202 and t == sorted(t)
    assert max(x) == 0.05 and t[x.index(0.05)] == pytest.approx(12.345)  # the spike survives
    assert min(x) == 0.0 and t[0] == 0.0 and t[-1] == pytest.approx(19.999)
    kind, traces = run_traces(long_run, "c/long", ["x_m"], columns=20_000)  # short enough: every sample
    assert len(traces["x_m"][0]) == 20_000


@pytest.mark.parametrize("suffix, magic", [(".png", b"\x89PNG"), (".svg", b"<svg"), (".html", b"<!DOCTYPE html")])
def test_plot_command_writes_png_svg_html(long_run, tmp_path, suffix, magic):
    out = tmp_path / f"p{suffix}"
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    data = out.read_bytes()
    assert magic in data[:400]
    if suffix != ".png":
        assert b"<svg" in data and b"c/long" in data


def test_plot_refuses_unknown_runs_and_channels(long_run, tmp_path):
    res = CliRunner().invoke(main, ["plot", "c/lung", "--warehouse", str(long_run), "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 2 and "no run 'c/lung'; did you mean c/long?" in res.stderr
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "p_a_pa",
                                    "-o", str(tmp_path / "a.png")])
    assert res.exit_code == 2 and "no channel p_a_pa" in res.stderr and "x_m" in res.stderr
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-o", str(tmp_path / "a.pdf")])
    assert res.exit_code == 2 and ".png, .svg or .html" in res.stderr
    assert not list(tmp_path.iterdir())


def test_figures_are_copied_out_of_their_hashed_folders(tmp_path):
    rows = [("durability", "kaplan_meier", "stages/durability/0a1b2c/figures/kaplan_meier.png", "KM curve"),
            ("models", "step", "stages/models/9f8e7d/figures/step.png", "Step responses")]
    wh = _figures_warehouse(tmp_path, rows)
    out = tmp_path / "figs"
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["durability-kaplan_meier.png", "models-step.png"]
    assert (out / "models-step.png").read_bytes() == (wh / rows[1][2]).read_bytes()
    assert "KM curve" in res.stdout


def test_figures_never_copy_from_outside_the_warehouse(tmp_path):
    (tmp_path / "secret.png").write_bytes(b"secret")
    wh = _figures_warehouse(tmp_path, [("x", "evil", "../secret.png", "")])
    with pytest.raises(QueryError, match="not a file of the warehouse"):
        copy_figures(wh, tmp_path / "out")
    assert not (tmp_path / "out" / "x-evil.png").exists()


# -- issue 25 items 10, 13: `plot` shows the report's units and reads h:mm:ss past an hour ---------------
@pytest.fixture(scope="module")
def hour_run(tmp_path_factory) -> Path:
    """A step run logged at 1 Hz for 2 h 10 min, position written in mm (x 0..40 mm)."""
    root = tmp_path_factory.mktemp("hplot")
    raw = RawBuilder(root / "raw")
    n = 7_800
    raw.csv("c/hour.csv", STEP_META, {"t[s]": list(range(n)), "x[mm]": [40.0 * (i % 600 > 300) for i in range(n)],
                                      "x_ref[mm]": [40.0 * (i % 600 > 300) for i in range(n)]})
    wh = root / "wh"
    rebuild(raw.root, wh, jobs=1, report=False)
    return wh


def _svg_text(path: Path) -> list[str]:
    """The texts of a matplotlib SVG (each glyph run is preceded by a comment with its text)."""
    return [t.strip() for t in re.findall(r"<!-- (.*?) -->", path.read_text(), flags=re.S)]


def test_plot_shows_mm_and_h_mm_ss_past_an_hour(hour_run, long_run, tmp_path):
    out = tmp_path / "h.svg"
    res = CliRunner().invoke(main, ["plot", "c/hour", "--warehouse", str(hour_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    texts = _svg_text(out)
    assert ["x", "[mm]"] == texts[texts.index("x"):texts.index("x") + 2]
    assert "t [h:mm:ss]" in texts and {"0:00:00", "1:00:00", "2:00:00"} <= set(texts)
    assert "40" in texts and not any("e+" in t or "1e4" in t or "[m]" in t for t in texts), texts
    steps = query(hour_run, "SELECT count(*) FROM step_response WHERE run_id = 'c/hour'")[0][0]
    assert steps > 0 and "set-point step" in texts  # the steps the analysis found, with a legend
    assert out.read_text().count('stroke-dasharray') >= steps
    out = tmp_path / "s.svg"  # a short run keeps seconds
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    texts = _svg_text(out)
    assert "t [s]" in texts and "[mm]" in texts and "40" in texts and not any(":" in t for t in texts[1:])


# -- session 29 (clifix): outputs are written through a temporary file, bad paths are one line ------------
def test_figures_replace_a_symlink_at_a_name_never_what_it_points_at(tmp_path):
    rows = [("durability", "kaplan_meier", "stages/durability/0a1b2c/figures/kaplan_meier.png", "KM curve")]
    wh = _figures_warehouse(tmp_path, rows)
    (tmp_path / "precious.txt").write_text("precious\n")
    out = tmp_path / "figs"
    out.mkdir()
    (out / "durability-kaplan_meier.png").symlink_to(tmp_path / "precious.txt")
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "precious.txt").read_text() == "precious\n"
    target = out / "durability-kaplan_meier.png"
    assert not target.is_symlink() and target.read_bytes() == (wh / rows[0][2]).read_bytes()
    assert sorted(p.name for p in out.iterdir()) == ["durability-kaplan_meier.png"]  # no temporary file left


def test_plot_replaces_a_symlink_at_its_output_never_what_it_points_at(long_run, tmp_path):
    (tmp_path / "precious.txt").write_text("precious\n")
    out = tmp_path / "p.png"
    out.symlink_to(tmp_path / "precious.txt")
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m", "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "precious.txt").read_text() == "precious\n"
    assert not out.is_symlink() and out.read_bytes()[:4] == b"\x89PNG"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png", "precious.txt"]


def test_a_file_where_the_output_folder_should_be_is_one_line(long_run, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    res = CliRunner().invoke(main, ["plot", "c/long", "--warehouse", str(long_run), "-c", "x_m",
                                    "-o", str(afile / "x.png")])
    assert res.exit_code == 2, res.output
    assert res.stderr == f"pneubench plot: cannot write {afile / 'x.png'}: {afile} is not a folder\n"
    wh = _figures_warehouse(tmp_path, [("x", "f", "stages/x/0a/figures/f.png", "")])
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(afile / "sub")])
    assert res.exit_code == 2, res.output
    assert res.stderr == f"pneubench figures: cannot write {afile / 'sub'}: {afile} is not a folder\n"
    (tmp_path / "loopA").symlink_to(tmp_path / "loopB")
    (tmp_path / "loopB").symlink_to(tmp_path / "loopA")
    res = CliRunner().invoke(main, ["figures", "--warehouse", str(wh), "-o", str(tmp_path / "loopA")])
    assert res.exit_code == 2 and "loopA is a symlink loop" in res.stderr
