"""The looks of one hose type's decision as a static SVG, for the report's section "The decision".

One plot per hose type: the estimate of the life ratio force / distance at each look (failure) on
a log axis, its repeated confidence interval as a band, the efficacy and futility boundaries as
steps, the margins dotted, the looks whose crossing the verdict counts ringed and the deciding look
starred, against the failures up to the planned maximum. Each estimate carries its look's figures
as a tooltip (``<title>``), so a reader can point at a look instead of reading the tables.

Drawn as SVG text, as the run pages' channels are (:mod:`~pipeline.serve.report.channels`), not
with matplotlib: a plan change redraws up to 20 of these figures in every rebuild, and matplotlib
spent ~0.15 CPU-s on each plus ~0.5 to import (issue 23: the decision stages' share of a rebuild at
200 hose types); this module spends about a millisecond a figure and imports no numeric or plotting
library (the standard library and the report's own escaping, :func:`~pipeline.serve.report.markup.esc`).
The early looks' boundaries (a hundredfold ratio is usual) run off the axis: the plot area is a nested
``<svg>`` viewport, which clips what it draws. The same looks give the same
bytes (fixed number formats, no date).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from pipeline.serve.report.markup import esc

#: Size of a figure [px] (the matplotlib figure it replaces was 9 x 4 in at 100 dpi).
WIDTH, HEIGHT = 900, 400
#: The plot area inside it [px]: room for the labels left and below, the margin's name on the right,
#: the title above and the legend under the axis.
LEFT, RIGHT, TOP, BOTTOM = 77, 810, 36, 300
#: Colours: estimate, repeated interval, efficacy, futility, margin, deciding look, counted crossing.
COLOURS = {"estimate": "#1f3f8f", "rci": "#9db4e8", "efficacy": "#c62828", "futility": "#2e7d32",
           "margin": "#6b7280", "decides": "#e08a00", "crossed": "#8e24aa"}
#: Ink of the axes' text and of the grid.
TEXT, GRID = "#1d2330", "#e3e6ec"
#: The y window: the estimates and the margins widened by this factor each way [-].
ROOM = 2.5
#: Steps of the failures axis (times a power of ten) and the most ticks it shows.
X_STEPS, X_TICKS = (1, 2, 5), 12


@dataclass(frozen=True)
class Looks:
    """What one looks figure shows (each series one value per look; NaN: no value, a gap).

    Attributes
    ----------
    hose_type : str
        The hose type (free text from raw/: escaped where written).
    verdict : str or None
        The verdict, in the title ("no verdict" when None).
    failures : list of float
        Failures (both adjustments) at each look [-]: the x axis.
    ratio, rci_lower, rci_upper, efficacy_lower, efficacy_upper, futility_lower, futility_upper : list of float
        The estimate, its repeated confidence interval and the boundaries at each look, as life ratios
        force / distance [-] (positive, else NaN).
    counted : list of int
        Indices of the looks whose crossing the verdict counts (ringed).
    deciding : int or None
        Index of the look that decided (a vertical line and a star).
    margin : float or None
        The plan's margin [-] (> 1: dotted at it and at its inverse).
    max_failures : float or None
        The planned maximum [-] (the x axis reaches it).
    looks : list
        Each look's number, for its tooltip (None: its index plus one).
    """

    hose_type: str
    verdict: str | None
    failures: list
    ratio: list
    rci_lower: list
    rci_upper: list
    efficacy_lower: list
    efficacy_upper: list
    futility_lower: list
    futility_upper: list
    counted: list
    deciding: int | None
    margin: float | None
    max_failures: float | None
    looks: list


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def _margin(m) -> float | None:
    """The margin if it can be drawn (a finite ratio above 1), else None."""
    return float(m) if _finite(m) and m > 1 else None


def ratio_window(ratio: list, margin) -> tuple[float, float]:
    """The y range [-]: the estimates, 1 and the margins, widened by :data:`ROOM` each way; the early
    looks' boundaries, which can be a hundredfold, run off it."""
    known = [r for r in ratio if _finite(r) and r > 0] + [1.0]
    m = _margin(margin)
    if m is not None:
        known += [m, 1 / m]
    return min(known) / ROOM, max(known) * ROOM


def ratio_ticks(lo: float, hi: float) -> list[float]:
    """Ticks of the log axis from ``lo`` to ``hi``: 1, 2 and 5 times the powers of ten between them [-]."""
    out = []
    for e in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        for s in (1, 2, 5):
            v = float(f"{s}e{e}")
            if lo <= v <= hi:
                out.append(v)
    return out


def failure_ticks(top: float) -> list[int]:
    """Whole-number ticks of the failures axis from 0 to ``top``: the smallest step of :data:`X_STEPS` times a
    power of ten that gives at most :data:`X_TICKS` intervals."""
    step, e = 1, 0
    while True:
        step = next((s * 10 ** e for s in X_STEPS if top / (s * 10 ** e) <= X_TICKS), None)
        if step is not None:
            break
        e += 1
    return list(range(0, int(math.floor(top)) + 1, step))


@dataclass(frozen=True)
class _Axes:
    """The plot area's scales: failures ``0..x_top`` linear, ratios ``y_lo..y_hi`` log; pixel
    coordinates relative to the plot area (the nested viewport)."""

    x_top: float
    y_lo: float
    y_hi: float

    def x(self, v: float) -> float:
        return v / self.x_top * (RIGHT - LEFT)

    def y(self, v: float) -> float:
        return (math.log(self.y_hi) - math.log(v)) / (math.log(self.y_hi) - math.log(self.y_lo)) * (BOTTOM - TOP)


def _num(v: float) -> str:
    """A coordinate as text (0.1 px: the same numbers give the same bytes)."""
    s = f"{v:.1f}"
    return "0.0" if s == "-0.0" else s


def _runs(ok: list[bool]) -> list[tuple[int, int]]:
    """The (first, last) index of each run of consecutive True values."""
    out, start = [], None
    for i, flag in enumerate(ok + [False]):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            out.append((start, i - 1))
            start = None
    return out


def _mid_edges(xs: list[float], i: int) -> tuple[float, float]:
    """The span a step drawn "at the middle" gives the ``i``-th value: halfway to each neighbour, the ends at
    the first and last looks (matplotlib's ``step(where="mid")``)."""
    left = xs[0] if i == 0 else (xs[i - 1] + xs[i]) / 2
    right = xs[-1] if i == len(xs) - 1 else (xs[i] + xs[i + 1]) / 2
    return left, right


def _step_path(ax: _Axes, xs: list[float], ys: list[float]) -> str:
    """A path of horizontal steps centred on the looks, broken where a value is missing."""
    parts = []
    for a, b in _runs([_finite(v) and v > 0 for v in ys]):
        pts = []
        for i in range(a, b + 1):
            left, right = _mid_edges(xs, i)
            y = _num(ax.y(ys[i]))
            pts += [f"{_num(ax.x(left))} {y}", f"{_num(ax.x(right))} {y}"]
        parts.append("M" + " L".join(pts))
    return " ".join(parts)


def _band_path(ax: _Axes, xs: list[float], lo: list[float], hi: list[float]) -> str:
    """The repeated interval as closed steps between its lower and upper bounds, one shape per run of looks
    where both are known."""
    parts = []
    for a, b in _runs([_finite(u) and _finite(v) and u > 0 and v > 0 for u, v in zip(lo, hi)]):
        top, bottom = [], []
        for i in range(a, b + 1):
            left, right = _mid_edges(xs, i)
            top += [f"{_num(ax.x(left))} {_num(ax.y(hi[i]))}", f"{_num(ax.x(right))} {_num(ax.y(hi[i]))}"]
            bottom += [f"{_num(ax.x(left))} {_num(ax.y(lo[i]))}", f"{_num(ax.x(right))} {_num(ax.y(lo[i]))}"]
        parts.append("M" + " L".join(top + bottom[::-1]) + " Z")
    return " ".join(parts)


def _line_path(ax: _Axes, xs: list[float], ys: list[float]) -> str:
    """A polyline through the looks' values, broken where a value is missing."""
    parts = []
    for a, b in _runs([_finite(v) and v > 0 for v in ys]):
        parts.append("M" + " L".join(f"{_num(ax.x(xs[i]))} {_num(ax.y(ys[i]))}" for i in range(a, b + 1)))
    return " ".join(parts)


def _star(cx: float, cy: float, r: float) -> str:
    """A five-pointed star's points centred on ``(cx, cy)`` with outer radius ``r`` [px]."""
    pts = []
    for k in range(10):
        rr = r if k % 2 == 0 else r * 0.4
        a = math.pi / 2 + k * math.pi / 5
        pts.append(f"{_num(cx + rr * math.cos(a))},{_num(cy - rr * math.sin(a))}")
    return " ".join(pts)


def _pair(a, b, joint: str) -> str:
    """Two ratios in a tooltip (3 significant digits), or "none" when either is missing."""
    if not (_finite(a) and _finite(b)):
        return "none"
    return f"{a:.3g}{joint}{b:.3g}"


def _tooltip(lk: Looks, i: int) -> str:
    """The figures of look ``i`` in words."""
    n = lk.looks[i] if lk.looks[i] is not None else i + 1
    r = lk.ratio[i]
    return esc(f"look {n}, {lk.failures[i]:g} failures: estimate {r:.3g} "
                       f"(repeated interval {_pair(lk.rci_lower[i], lk.rci_upper[i], ' to ')}); "
                       f"efficacy boundaries {_pair(lk.efficacy_lower[i], lk.efficacy_upper[i], ' and ')}; "
                       f"futility boundaries {_pair(lk.futility_lower[i], lk.futility_upper[i], ' and ')}")


def _legend(entries: list[tuple[str, str]]) -> list[str]:
    """The legend under the axis, five entries a row: (swatch markup at the origin, text)."""
    out = []
    for k, (swatch, text) in enumerate(entries):
        x, y = 60 + (k % 5) * 162, 362 + (k // 5) * 18
        out.append(f'<g transform="translate({x},{y})">{swatch}<text x="26" y="4" font-size="10" fill="{TEXT}">'
                   f"{esc(text)}</text></g>")
    return out


def looks_svg(lk: Looks) -> str:
    """The looks figure of ``lk`` as one ``<svg>`` element ("" when no look has an estimate).

    Parameters
    ----------
    lk : Looks
        What the figure shows.

    Returns
    -------
    str
        The SVG text: scalable (``viewBox``), as wide as the page allows up to :data:`WIDTH` px.
    """
    if not any(_finite(r) and r > 0 for r in lk.ratio):
        return ""
    xs = [float(v) for v in lk.failures]
    top = max([*xs, float(lk.max_failures) if _finite(lk.max_failures) else 0.0]) * 1.02 + 0.5
    margin = _margin(lk.margin)
    ax = _Axes(top, *ratio_window(lk.ratio, margin))
    deciding = lk.deciding if lk.deciding is not None and 0 <= lk.deciding < len(xs) else None
    counted = [i for i in lk.counted if 0 <= i < len(xs) and _finite(lk.ratio[i]) and lk.ratio[i] > 0]
    name = esc(lk.hose_type)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{HEIGHT}" '
           f'viewBox="0 0 {WIDTH} {HEIGHT}" role="img" aria-label="looks of {name}" '
           'style="max-width:100%;height:auto" font-family="sans-serif">',
           f'<rect width="{WIDTH}" height="{HEIGHT}" fill="#fff"/>',
           f'<text x="{(LEFT + RIGHT) / 2:.1f}" y="{TOP - 10}" font-size="13" text-anchor="middle" fill="{TEXT}">'
           f'{name}: {esc(lk.verdict or "no verdict")}</text>']
    out += _axes(ax)
    out += _plot_area(ax, lk, xs, margin, deciding, counted)
    out.append(f'<rect x="{LEFT}" y="{TOP}" width="{RIGHT - LEFT}" height="{BOTTOM - TOP}" fill="none" '
               f'stroke="{TEXT}" stroke-width="0.8"/>')
    if margin is not None:
        out.append(f'<text x="{RIGHT + 4}" y="{_num(TOP + ax.y(margin))}" dy="3" font-size="9" '
                   f'fill="{COLOURS["margin"]}">margin {margin:g}</text>')
    out += _legend(_entries(lk.verdict, bool(counted), deciding is not None))
    out.append("</svg>")
    return "".join(out)


def _axes(ax: _Axes) -> list[str]:
    """The grid, the ticks and the axes' labels (outside the plot area's viewport)."""
    out = []
    for v in ratio_ticks(ax.y_lo, ax.y_hi):
        y = _num(TOP + ax.y(v))
        out.append(f'<line x1="{LEFT}" y1="{y}" x2="{RIGHT}" y2="{y}" stroke="{GRID}"/>'
                   f'<text x="{LEFT - 6}" y="{y}" dy="3.5" font-size="10" text-anchor="end" fill="{TEXT}">{v:g}</text>')
    for v in failure_ticks(ax.x_top):
        x = _num(LEFT + ax.x(v))
        out.append(f'<line x1="{x}" y1="{TOP}" x2="{x}" y2="{BOTTOM}" stroke="{GRID}"/>'
                   f'<text x="{x}" y="{BOTTOM + 15}" font-size="10" text-anchor="middle" fill="{TEXT}">{v}</text>')
    out.append(f'<text x="{(LEFT + RIGHT) / 2:.1f}" y="{BOTTOM + 34}" font-size="11" text-anchor="middle" '
               f'fill="{TEXT}">failures (both adjustments)</text>'
               f'<text transform="translate(20,{(TOP + BOTTOM) / 2:.1f}) rotate(-90)" font-size="11" '
               f'text-anchor="middle" fill="{TEXT}">life ratio force / distance</text>')
    return out


def _plot_area(ax: _Axes, lk: Looks, xs: list[float], margin: float | None, deciding: int | None,
               counted: list[int]) -> list[str]:
    """The plot area, a nested viewport that clips the boundaries running off the axis: the interval, the
    boundaries, the 1-line and the margins, the deciding look's line, the estimate, the rings and the star."""
    pw, ph = RIGHT - LEFT, BOTTOM - TOP
    out = [f'<svg x="{LEFT}" y="{TOP}" width="{pw}" height="{ph}" viewBox="0 0 {pw} {ph}" overflow="hidden">']
    band = _band_path(ax, xs, lk.rci_lower, lk.rci_upper)
    if band:
        out.append(f'<path d="{band}" fill="{COLOURS["rci"]}" fill-opacity="0.45" stroke="none"/>')
    for kind, dash in (("efficacy", "6 3"), ("futility", "7 3 1.5 3")):
        for side in ("lower", "upper"):
            d = _step_path(ax, xs, getattr(lk, f"{kind}_{side}"))
            if d:
                out.append(f'<path d="{d}" fill="none" stroke="{COLOURS[kind]}" stroke-width="1.3" '
                           f'stroke-dasharray="{dash}"/>')
    y1 = _num(ax.y(1.0))
    out.append(f'<line x1="0" y1="{y1}" x2="{pw}" y2="{y1}" stroke="#000" stroke-width="0.7"/>')
    for m in (margin, 1 / margin) if margin is not None else ():
        y = _num(ax.y(m))
        out.append(f'<line x1="0" y1="{y}" x2="{pw}" y2="{y}" stroke="{COLOURS["margin"]}" stroke-width="0.8" '
                   'stroke-dasharray="1.5 2.5"/>')
    if deciding is not None:
        x = _num(ax.x(xs[deciding]))
        out.append(f'<line x1="{x}" y1="0" x2="{x}" y2="{ph}" stroke="{COLOURS["decides"]}" stroke-width="1.2"/>')
    out.append(f'<path d="{_line_path(ax, xs, lk.ratio)}" fill="none" stroke="{COLOURS["estimate"]}" '
               'stroke-width="1.4"/>')
    for i, r in enumerate(lk.ratio):
        if _finite(r) and r > 0:
            out.append(f'<circle cx="{_num(ax.x(xs[i]))}" cy="{_num(ax.y(r))}" r="2.6" fill="{COLOURS["estimate"]}">'
                       f"<title>{_tooltip(lk, i)}</title></circle>")
    for i in counted:
        out.append(f'<circle cx="{_num(ax.x(xs[i]))}" cy="{_num(ax.y(lk.ratio[i]))}" r="6.3" fill="none" '
                   f'stroke="{COLOURS["crossed"]}" stroke-width="1.6"/>')
    if deciding is not None and _finite(lk.ratio[deciding]) and lk.ratio[deciding] > 0:
        out.append(f'<polygon points="{_star(ax.x(xs[deciding]), ax.y(lk.ratio[deciding]), 9.0)}" '
                   f'fill="{COLOURS["decides"]}"><title>{_tooltip(lk, deciding)}</title></polygon>')
    return out + ["</svg>"]


def _entries(verdict: str | None, ringed: bool, decided: bool) -> list[tuple[str, str]]:
    """The legend's entries: (swatch markup at the origin, text); the rings and the star only when drawn."""
    line = '<line x1="0" y1="0" x2="20" y2="0" stroke="{}" stroke-width="{}"{}/>'
    entries = [(f'<rect x="0" y="-5" width="20" height="10" fill="{COLOURS["rci"]}" fill-opacity="0.45"/>',
                "repeated confidence interval"),
               (line.format(COLOURS["efficacy"], 1.3, ' stroke-dasharray="6 3"'), "efficacy boundary"),
               (line.format(COLOURS["futility"], 1.3, ' stroke-dasharray="7 3 1.5 3"'), "futility boundary"),
               (line.format(COLOURS["estimate"], 1.4, "") + f'<circle cx="10" cy="0" r="2.6" fill="{COLOURS["estimate"]}"/>',
                "estimate force / distance")]
    if ringed:
        entries.append((f'<circle cx="10" cy="0" r="6.3" fill="none" stroke="{COLOURS["crossed"]}" '
                        'stroke-width="1.6"/>', "crossed (confirmed)"))
    if decided:
        entries.append((f'<polygon points="{_star(10, 0, 7.0)}" fill="{COLOURS["decides"]}"/>', f"decided: {verdict}"))
    return entries


__all__ = ["Looks", "looks_svg", "ratio_window", "ratio_ticks", "failure_ticks", "COLOURS", "WIDTH", "HEIGHT"]
