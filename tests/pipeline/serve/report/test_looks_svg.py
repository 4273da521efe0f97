"""The looks figure as SVG, on hand-made looks: scales, ticks, steps and gaps checked by hand, text escaped,
no numeric or plotting library imported."""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import pytest

from pipeline.serve.report import looks_svg as ls
from tests.fresh import loaded_after

SVG = "{http://www.w3.org/2000/svg}"
NAN = math.nan


def _looks(**over) -> ls.Looks:
    base = dict(hose_type="PU <b>8x6</b>", verdict="force longer", failures=[2.0, 3.0, 5.0, 6.0],
                ratio=[1.0, 1.2, NAN, 2.0], rci_lower=[NAN, 0.5, 0.8, 1.2], rci_upper=[NAN, 3.0, 3.2, 3.4],
                efficacy_lower=[0.1, 0.25, 0.4, 0.5], efficacy_upper=[9.0, 4.0, 2.5, 2.0],
                futility_lower=[NAN, NAN, NAN, NAN], futility_upper=[NAN, NAN, NAN, NAN],
                counted=[3], deciding=3, margin=1.5, max_failures=10.0, looks=[1, 2, 3, 4])
    return ls.Looks(**(base | over))


def _inner(svg: ET.Element) -> ET.Element:
    return svg.find(f"{SVG}svg")


def test_the_scales_by_hand():
    # the window: the estimates, 1 and the margins, 2.5 times wider each way
    lo, hi = ls.ratio_window([1.0, 1.2, NAN, 2.0], 1.5)
    assert lo == pytest.approx(1 / 1.5 / 2.5) and hi == pytest.approx(2.0 * 2.5)
    assert ls.ratio_window([0.1], None) == (pytest.approx(0.04), pytest.approx(2.5))
    assert ls.ratio_ticks(lo, hi) == [0.5, 1.0, 2.0, 5.0]     # 5.0 is the window's top
    assert ls.ratio_ticks(0.04, 30.0) == [0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0]
    assert ls.failure_ticks(10.7) == list(range(11))
    assert ls.failure_ticks(16.8) == [0, 2, 4, 6, 8, 10, 12, 14, 16]
    assert ls.failure_ticks(45.4) == list(range(0, 46, 5))
    assert ls.failure_ticks(130.0) == list(range(0, 121, 20))
    assert ls.failure_ticks(0.5) == [0]


def test_points_and_steps_fall_where_the_scales_put_them():
    lk = _looks()
    svg = ET.fromstring(ls.looks_svg(lk))
    top = 10.0 * 1.02 + 0.5                      # the planned maximum, as matplotlib's figure had it
    lo, hi = ls.ratio_window(lk.ratio, 1.5)
    pw, ph = ls.RIGHT - ls.LEFT, ls.BOTTOM - ls.TOP

    def px(x):
        return round(x / top * pw, 1)

    def py(r):
        return round((math.log(hi) - math.log(r)) / (math.log(hi) - math.log(lo)) * ph, 1)

    inner = _inner(svg)
    dots = [e for e in inner.iter(f"{SVG}circle") if e.find(f"{SVG}title") is not None]
    assert [(float(e.get("cx")), float(e.get("cy"))) for e in dots] == [(px(2), py(1.0)), (px(3), py(1.2)),
                                                                         (px(6), py(2.0))]
    # the estimate's line breaks at the look without an estimate
    line = next(e for e in inner.iter(f"{SVG}path") if e.get("stroke") == ls.COLOURS["estimate"])
    assert line.get("d") == f"M{px(2)} {py(1.0)} L{px(3)} {py(1.2)} M{px(6)} {py(2.0)}"
    # the upper efficacy boundary: steps centred on the looks (halfway to each neighbour, the ends at the looks)
    eff = [e.get("d") for e in inner.iter(f"{SVG}path") if e.get("stroke") == ls.COLOURS["efficacy"]]
    edges = [(2, 2.5), (2.5, 4), (4, 5.5), (5.5, 6)]
    want = "M" + " L".join(f"{px(a)} {py(v)} L{px(b)} {py(v)}" for (a, b), v in zip(edges, [9.0, 4.0, 2.5, 2.0]))
    assert want in eff and len(eff) == 2
    # no futility boundary at all: nothing drawn for it
    assert not [e for e in inner.iter(f"{SVG}path") if e.get("stroke") == ls.COLOURS["futility"]]
    # the interval: one closed shape over the three looks that have both bounds
    band = next(e for e in inner.iter(f"{SVG}path") if e.get("fill") == ls.COLOURS["rci"])
    assert band.get("d").count("M") == 1 and band.get("d").endswith("Z")
    assert band.get("d").startswith(f"M{px(2.5)} {py(3.0)} L{px(4)} {py(3.0)}")
    # the plot area clips (the boundary of 9 runs off the axis), the 1-line, both margins dotted
    assert inner.get("overflow") == "hidden" and py(9.0) < 0
    flat = {(e.get("y1"), e.get("stroke")) for e in inner.iter(f"{SVG}line") if e.get("y1") == e.get("y2")}
    assert {(str(py(1.0)), "#000"), (str(py(1.5)), ls.COLOURS["margin"]), (str(py(1 / 1.5)), ls.COLOURS["margin"])} <= flat
    # the deciding look: a vertical line and a star on its estimate; the counted crossing ringed
    assert [e.get("x1") for e in inner.iter(f"{SVG}line") if e.get("stroke") == ls.COLOURS["decides"]] == [str(px(6))]
    rings = [e for e in inner.iter(f"{SVG}circle") if e.get("stroke") == ls.COLOURS["crossed"]]
    assert [(float(e.get("cx")), float(e.get("cy"))) for e in rings] == [(px(6), py(2.0))]
    star = next(e for e in inner.iter(f"{SVG}polygon"))
    xy = [tuple(map(float, p.split(","))) for p in star.get("points").split()]
    assert len(xy) == 10 and xy[0] == (px(6), round(py(2.0) - 9.0, 1))
    # ticks outside the plot area: the y ticks 0.5, 1, 2 at their heights, the x ticks 0..10
    texts = [(e.get("y"), e.text) for e in svg.findall(f"{SVG}text")]
    for v in (0.5, 1.0, 2.0):
        assert (f"{ls.TOP + py(v):.1f}", f"{v:g}") in texts
    assert [t for y, t in texts if y == str(ls.BOTTOM + 15)] == [str(k) for k in range(11)]


def test_tooltips_title_and_legend():
    lk = _looks()
    text = ls.looks_svg(lk)
    svg = ET.fromstring(text)
    # free text from raw/ is escaped: no element named b, the name in the label and the title
    assert not list(svg.iter(f"{SVG}b")) and "<b>" not in text
    assert svg.get("aria-label") == "looks of PU <b>8x6</b>"
    tips = [e.text for e in svg.iter(f"{SVG}title")]
    assert tips[0] == ("look 1, 2 failures: estimate 1 (repeated interval none); efficacy boundaries 0.1 and 9; "
                       "futility boundaries none")
    assert tips[1].startswith("look 2, 3 failures: estimate 1.2 (repeated interval 0.5 to 3); ")
    legend = [e.text for e in svg.iter(f"{SVG}text") if e.text and not re.fullmatch(r"[\d.]+", e.text)]
    assert legend[0] == "PU <b>8x6</b>: force longer"
    assert "crossed (confirmed)" in legend and "decided: force longer" in legend and "margin 1.5" in legend
    # without a deciding look, a counted crossing or a margin: none of their marks
    plain = ET.fromstring(ls.looks_svg(_looks(counted=[], deciding=None, margin=None, verdict=None)))
    words = [e.text for e in plain.iter(f"{SVG}text")]
    assert "PU <b>8x6</b>: no verdict" in words
    assert not any(w and (w.startswith("decided") or w.startswith("margin") or w.startswith("crossed")) for w in words)
    assert not list(plain.iter(f"{SVG}polygon"))


def test_nothing_to_draw_and_the_same_bytes():
    assert ls.looks_svg(_looks(ratio=[NAN, NAN, NAN, NAN])) == ""
    assert ls.looks_svg(_looks(ratio=[0.0, -1.0, NAN, NAN])) == ""
    assert ls.looks_svg(_looks()) == ls.looks_svg(_looks())
    assert ls.looks_svg(_looks()) != ls.looks_svg(_looks(ratio=[1.0, 1.2, NAN, 2.01]))


def test_drawing_imports_no_numeric_or_plotting_library():
    code = ("import math; from pipeline.serve.report.looks_svg import Looks, looks_svg; "
            "s = looks_svg(Looks('t', None, [1.0, 2.0], [1.0, 2.0], *[[math.nan] * 2] * 6, [], None, 1.5, 4.0, [1, 2])); "
            "assert s.startswith('<svg')")
    assert loaded_after(code, ("numpy", "matplotlib", "pandas", "duckdb")) == []
